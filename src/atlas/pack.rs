//! Packing flattened charts into one square atlas (issue 4, step 3, first version): each chart
//! rotated to its minimum-area bounding rectangle (a hull edge direction), all charts at one
//! texel density, rectangles placed on shelves (tallest first) with a gutter between them; the
//! density is the largest that fits, found by bisection. Rectangles keep gutters by
//! construction, so charts never overlap.

use super::param::ChartMap;
use crate::mesh::{Mesh, UvMap};
use nalgebra::Vector2;

/// Options for [`pack`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PackOptions {
    /// Atlas width and height in texels. Default: 4096.
    pub size: u32,
    /// Empty texels between charts (and around the border). Default: 4.
    pub gutter: u32,
}

impl Default for PackOptions {
    fn default() -> Self {
        PackOptions {
            size: 4096,
            gutter: 4,
        }
    }
}

/// The packed atlas.
#[derive(Debug, Clone)]
pub struct Packed {
    /// Per-corner texture coordinates for every mesh face (origin lower-left, [0, 1]).
    pub uv: UvMap,
    /// Texels per unit of 3D length.
    pub texels_per_unit: f64,
    /// For each face, its chart.
    pub face_chart: Vec<u32>,
}

fn hull(points: &[Vector2<f64>]) -> Vec<Vector2<f64>> {
    let mut p: Vec<Vector2<f64>> = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let cross = |o: Vector2<f64>, a: Vector2<f64>, b: Vector2<f64>| (a - o).perp(&(b - o));
    let mut h: Vec<Vector2<f64>> = Vec::new();
    for pass in 0..2 {
        let start = h.len();
        let it: Box<dyn Iterator<Item = &Vector2<f64>>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in it {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], q) <= 0.0 {
                h.pop();
            }
            h.push(q);
        }
        h.pop();
    }
    h
}

/// Rotates a chart to its minimum-area bounding rectangle and moves it to the origin;
/// returns the rectangle's size.
fn orient(uv: &mut [Vector2<f64>]) -> Vector2<f64> {
    let h = hull(uv);
    let mut best = (f64::INFINITY, 0.0);
    for i in 0..h.len().max(1) {
        let e = if h.len() >= 2 {
            h[(i + 1) % h.len()] - h[i]
        } else {
            Vector2::x()
        };
        let a = e.y.atan2(e.x);
        let (c, s) = (a.cos(), a.sin());
        let (mut lo, mut hi) = (
            Vector2::repeat(f64::INFINITY),
            Vector2::repeat(f64::NEG_INFINITY),
        );
        for p in &h {
            let r = Vector2::new(c * p.x + s * p.y, -s * p.x + c * p.y);
            lo = lo.inf(&r);
            hi = hi.sup(&r);
        }
        let area = (hi - lo).x * (hi - lo).y;
        if area < best.0 {
            best = (area, a);
        }
    }
    let (c, s) = (best.1.cos(), best.1.sin());
    for p in uv.iter_mut() {
        *p = Vector2::new(c * p.x + s * p.y, -s * p.x + c * p.y);
    }
    let lo = uv
        .iter()
        .fold(Vector2::repeat(f64::INFINITY), |a, p| a.inf(p));
    let hi = uv
        .iter()
        .fold(Vector2::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
    let mut size = hi - lo;
    // Tall charts lie down: shelves pack wide, low rectangles better.
    if size.y > size.x {
        for p in uv.iter_mut() {
            *p = Vector2::new(p.y, -p.x);
        }
        size = Vector2::new(size.y, size.x);
    }
    let lo = uv
        .iter()
        .fold(Vector2::repeat(f64::INFINITY), |a, p| a.inf(p));
    for p in uv.iter_mut() {
        *p -= lo;
    }
    size
}

/// Shelf placement of rectangles (texels) in a square of side `size`; `None` if they do not fit.
fn shelves(
    rects: &[(u32, u32)],
    order: &[usize],
    size: u32,
    gutter: u32,
) -> Option<Vec<(u32, u32)>> {
    let mut pos = vec![(0, 0); rects.len()];
    let (mut x, mut y, mut row) = (gutter, gutter, 0u32);
    for &i in order {
        let (w, h) = rects[i];
        if x + w + gutter > size {
            x = gutter;
            y += row + gutter;
            row = 0;
        }
        if x + w + gutter > size || y + h + gutter > size {
            return None;
        }
        pos[i] = (x, y);
        x += w + gutter;
        row = row.max(h);
    }
    Some(pos)
}

/// Packs `maps` (charts of `mesh`) into one atlas. Deterministic.
pub fn pack(mesh: &Mesh, maps: &[ChartMap], opts: &PackOptions) -> Packed {
    let mut charts: Vec<ChartMap> = maps.to_vec();
    let sizes: Vec<Vector2<f64>> = charts.iter_mut().map(|c| orient(&mut c.uv)).collect();
    let total: f64 = sizes.iter().map(|s| s.x * s.y).sum::<f64>().max(1e-300);
    let rects_at = |scale: f64| -> Vec<(u32, u32)> {
        sizes
            .iter()
            .map(|s| {
                (
                    (s.x * scale).ceil() as u32 + 1,
                    (s.y * scale).ceil() as u32 + 1,
                )
            })
            .collect()
    };
    let n = opts.size as f64;
    let (mut lo, mut hi) = (0.0, n / total.sqrt());
    let mut order: Vec<usize> = (0..charts.len()).collect();
    order.sort_by(|&a, &b| sizes[b].y.total_cmp(&sizes[a].y).then(a.cmp(&b)));
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if shelves(&rects_at(mid), &order, opts.size, opts.gutter).is_some() {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let scale = lo;
    let pos = shelves(&rects_at(scale), &order, opts.size, opts.gutter)
        .expect("the lower bound of the bisection always fits");
    let mut coords = Vec::new();
    let mut faces = vec![[0u32; 3]; mesh.num_faces()];
    let mut face_chart = vec![0u32; mesh.num_faces()];
    for (ci, c) in charts.iter().enumerate() {
        let base = coords.len() as u32;
        let (px, py) = pos[ci];
        for p in &c.uv {
            // Half a texel in from the rectangle's corner, then to [0, 1].
            let t = Vector2::new(px as f64 + 0.5 + p.x * scale, py as f64 + 0.5 + p.y * scale) / n;
            coords.push(t.cast::<f32>());
        }
        for (t, f) in c.faces.iter().zip(&c.face_ids) {
            faces[f.idx()] = t.map(|i| base + i);
            face_chart[f.idx()] = ci as u32;
        }
    }
    Packed {
        uv: UvMap { coords, faces },
        texels_per_unit: scale,
        face_chart,
    }
}

/// Calls `visit(x, y)` for every texel centre `(x + 0.5, y + 0.5)` of a `width` x `height`
/// grid inside the triangle `q` (texel units, either orientation, edges inclusive).
pub fn raster_triangle(
    q: [Vector2<f64>; 3],
    width: u32,
    height: u32,
    mut visit: impl FnMut(u32, u32),
) {
    let area = (q[1] - q[0]).perp(&(q[2] - q[0]));
    if area == 0.0 || width == 0 || height == 0 {
        return;
    }
    let lo = q[0].inf(&q[1]).inf(&q[2]);
    let hi = q[0].sup(&q[1]).sup(&q[2]);
    // Texel centres inside the bounding box, clipped to the grid; empty if it misses the grid.
    let span = |a: f64, b: f64, n: u32| {
        let first = (a - 0.5).ceil().max(0.0);
        let last = (b - 0.5).floor().min(n as f64 - 1.0);
        (first <= last).then_some((first as u32, last as u32))
    };
    let (Some((x0, x1)), Some((y0, y1))) = (span(lo.x, hi.x, width), span(lo.y, hi.y, height))
    else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let c = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
            if (0..3).all(|k| (q[(k + 1) % 3] - c).perp(&(q[(k + 2) % 3] - c)) / area >= 0.0) {
                visit(x, y);
            }
        }
    }
}

/// Rasterises the UV triangles at `size` x `size` (texel centres) and returns, per texel, how
/// many charts cover it (0, 1, or more if charts overlap).
pub fn coverage(uv: &UvMap, face_chart: &[u32], size: u32) -> Vec<u8> {
    let mut owner = vec![u32::MAX; (size * size) as usize];
    let mut count = vec![0u8; (size * size) as usize];
    let n = size as f64;
    for (f, t) in uv.faces.iter().enumerate() {
        let q = t.map(|i| uv.coords[i as usize].cast::<f64>() * n);
        raster_triangle(q, size, size, |x, y| {
            let i = (y * size + x) as usize;
            if owner[i] != face_chart[f] {
                count[i] = count[i].saturating_add(1);
                owner[i] = face_chart[f];
            }
        });
    }
    count
}
