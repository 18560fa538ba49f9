//! Packing flattened charts into square atlas pages (issue 4, step 3). Each chart is turned to
//! its minimum-area rectangle, then rasterised conservatively (every texel its triangles touch)
//! in four quarter turns; charts go largest first to the first free position, row by row, of
//! the turn whose top edge ends lowest, tested against the exact occupancy of the page with the
//! new chart's footprint dilated by the gutter. Small charts thus fill holes and bays of large
//! ones. The density is the largest that fits one page (bisection), or fixed, with as many
//! pages as needed.

use super::param::ChartMap;
use crate::mesh::{Mesh, UvMap};
use nalgebra::Vector2;
use std::cmp::Reverse;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Options for [`pack`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PackOptions {
    /// Atlas width and height in texels. Default: 4096.
    pub size: u32,
    /// Empty texels between charts (and around the border). Default: 4.
    pub gutter: u32,
    /// Fixed texel density (texels per unit of 3D length): charts fill as many pages as they
    /// need. Default: `None`, the largest density that fits one page.
    pub texels_per_unit: Option<f64>,
}

impl Default for PackOptions {
    fn default() -> Self {
        PackOptions {
            size: 4096,
            gutter: 4,
            texels_per_unit: None,
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
    /// Number of pages; page `p` holds the faces whose u lies in `[p, p + 1]` (UDIM tiles).
    pub pages: u32,
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
    // Tall charts lie down: the first of the turns the packer tries is the flat one.
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

/// A chart rasterised at one scale and rotation: its footprint (every texel its triangles touch)
/// as runs per row, and for each row the span of the footprint dilated by the gutter.
#[derive(Debug, Clone)]
struct Mask {
    /// Width and height of the dilated footprint's box.
    w: usize,
    h: usize,
    /// Per row of the box, the dilated footprint's first and last texel (`None`: empty row).
    spans: Vec<Option<(u32, u32)>>,
    /// Footprint runs `(row, first, last)`, inclusive, in box coordinates.
    runs: Vec<(u32, u32, u32)>,
    /// Offset of chart coordinates in the box (texels).
    offset: Vector2<f64>,
    /// Quarter turns applied to the chart.
    rot: u8,
}

fn rotate(p: Vector2<f64>, rot: u8) -> Vector2<f64> {
    match rot % 4 {
        0 => p,
        1 => Vector2::new(-p.y, p.x),
        2 => -p,
        _ => Vector2::new(p.y, -p.x),
    }
}

/// Rasterises a chart (UVs scaled to texels) conservatively: a texel belongs to the footprint
/// if its square meets a triangle (exact separating-axis test). Returns the footprint grid,
/// its width and height, and the offset of chart coordinates in it; the grid has a margin of
/// `gutter` texels on every side.
fn footprint(
    uv: &[Vector2<f64>],
    faces: &[[u32; 3]],
    gutter: usize,
) -> (Vec<bool>, usize, usize, Vector2<f64>) {
    let lo = uv
        .iter()
        .fold(Vector2::repeat(f64::INFINITY), |a, p| a.inf(p));
    let hi = uv
        .iter()
        .fold(Vector2::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
    let g = gutter as f64;
    let offset = Vector2::new(g, g) - lo;
    let w = (hi.x - lo.x + g).floor() as usize + 1 + gutter;
    let h = (hi.y - lo.y + g).floor() as usize + 1 + gutter;
    let mut foot = vec![false; w * h];
    for t in faces {
        let q = t.map(|i| uv[i as usize] + offset);
        let a = q[0].inf(&q[1]).inf(&q[2]);
        let b = q[0].sup(&q[1]).sup(&q[2]);
        let (x0, y0) = (a.x.floor().max(0.0) as usize, a.y.floor().max(0.0) as usize);
        let (x1, y1) = (
            (b.x.floor() as usize).min(w - 1),
            (b.y.floor() as usize).min(h - 1),
        );
        let area = (q[1] - q[0]).perp(&(q[2] - q[0]));
        // Edge functions, positive inside; the square meets the triangle iff, for every edge,
        // its best corner is inside (the box test is the loop range).
        let edges: [(Vector2<f64>, Vector2<f64>, f64); 3] = std::array::from_fn(|k| {
            let (p, r) = (q[k], q[(k + 1) % 3]);
            let e = r - p;
            let n = Vector2::new(-e.y, e.x) * area.signum();
            (p, n, 0.5 * (n.x.abs() + n.y.abs()) + 1e-9 * n.norm())
        });
        for y in y0..=y1 {
            for x in x0..=x1 {
                let c = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
                if area == 0.0 || edges.iter().all(|(p, n, r)| n.dot(&(c - p)) + r >= 0.0) {
                    foot[y * w + x] = true;
                }
            }
        }
    }
    (foot, w, h, offset)
}

/// The mask of a footprint turned by `rot` quarter turns. Quarter turns map the texel grid onto
/// itself, so the turned grid is exactly the footprint of the turned chart.
fn mask(foot: &[bool], w: usize, h: usize, offset: Vector2<f64>, rot: u8, gutter: usize) -> Mask {
    // Box coordinates q of a chart point p, turned: rotate(p) + offset_r; and texel (x, y) of the
    // turned grid reads texel src(x, y) of the original.
    let (rw, rh) = if rot.is_multiple_of(2) {
        (w, h)
    } else {
        (h, w)
    };
    let (wf, hf) = (w as f64, h as f64);
    let off = match rot % 4 {
        0 => offset,
        1 => Vector2::new(hf - offset.y, offset.x),
        2 => Vector2::new(wf - offset.x, hf - offset.y),
        _ => Vector2::new(offset.y, wf - offset.x),
    };
    let at = |x: usize, y: usize| -> bool {
        let (sx, sy) = match rot % 4 {
            0 => (x, y),
            1 => (y, h - 1 - x),
            2 => (w - 1 - x, h - 1 - y),
            _ => (w - 1 - y, x),
        };
        foot[sy * w + sx]
    };
    let mut runs = Vec::new();
    for y in 0..rh {
        let mut x = 0;
        while x < rw {
            if at(x, y) {
                let s = x;
                while x < rw && at(x, y) {
                    x += 1;
                }
                runs.push((y as u32, s as u32, x as u32 - 1));
            } else {
                x += 1;
            }
        }
    }
    // Dilate by the gutter: each footprint run widens by g, then rows spread g up and down.
    let mut row_span: Vec<Option<(u32, u32)>> = vec![None; rh];
    for &(y, a, b) in &runs {
        let s = &mut row_span[y as usize];
        let (a, b) = (a.saturating_sub(gutter as u32), b + gutter as u32);
        *s = Some(s.map_or((a, b), |(l, r)| (l.min(a), r.max(b))));
    }
    let spans = (0..rh)
        .map(|y| {
            let lo = y.saturating_sub(gutter);
            let hi = (y + gutter).min(rh - 1);
            row_span[lo..=hi]
                .iter()
                .flatten()
                .fold(None, |acc: Option<(u32, u32)>, &(a, b)| {
                    Some(acc.map_or((a, b), |(l, r)| (l.min(a), r.max(b))))
                })
        })
        .collect();
    Mask {
        w: rw,
        h: rh,
        spans,
        runs,
        offset: off,
        rot,
    }
}

/// Texels per block of a page row in [`Page::block_max`].
const BLOCK: usize = 32;

/// One atlas page: occupancy and, per texel, the length of the free (positive) or occupied
/// (negative) run that starts there, so the search skips whole runs; per row, the longest free
/// run, and per block of [`BLOCK`] texels of a row the longest free run starting in it, so the
/// search skips whole blocks of a fragmented row.
struct Page {
    size: usize,
    occ: Vec<bool>,
    run: Vec<i32>,
    max_free: Vec<u32>,
    /// `size.div_ceil(BLOCK)` values per row.
    block_max: Vec<u32>,
}

impl Page {
    fn new(size: usize) -> Page {
        let mut run = vec![0i32; size * size];
        for row in run.chunks_mut(size) {
            for (x, r) in row.iter_mut().enumerate() {
                *r = (size - x) as i32;
            }
        }
        let blocks = size.div_ceil(BLOCK);
        let block_max = (0..size)
            .flat_map(|_| (0..blocks).map(|b| (size - b * BLOCK) as u32))
            .collect();
        Page {
            size,
            occ: vec![false; size * size],
            run,
            max_free: vec![size as u32; size],
            block_max,
        }
    }

    /// The first texel `x >= from` of row `y` where a free run of at least `need` starts.
    fn next_fit(&self, y: usize, from: usize, need: usize) -> Option<usize> {
        let n = self.size;
        let blocks = n.div_ceil(BLOCK);
        let (run, bmax) = (
            &self.run[y * n..y * n + n],
            &self.block_max[y * blocks..y * blocks + blocks],
        );
        let mut x = from;
        while x < n {
            let b = x / BLOCK;
            if (bmax[b] as usize) < need {
                x = (b + 1) * BLOCK;
                continue;
            }
            let v = run[x];
            if v > 0 && v as usize >= need {
                return Some(x);
            }
            // Inside a free run every later start is shorter: jump to its end; an occupied run:
            // past it.
            x += v.unsigned_abs() as usize;
        }
        None
    }

    /// The first position (row-major, top-left corner of the mask's box) where the dilated
    /// footprint meets no occupied texel and stays inside the page, among those whose bottom
    /// edge `y + m.h` is at most `bottom` (read as it goes: other searches lower it).
    fn find(&self, m: &Mask, bottom: &AtomicUsize) -> Option<(usize, usize)> {
        let n = self.size;
        if m.w > n || m.h > n {
            return None;
        }
        let rows: Vec<(usize, usize, usize)> = m
            .spans
            .iter()
            .enumerate()
            .filter_map(|(r, s)| s.map(|(a, b)| (r, a as usize, (b - a + 1) as usize)))
            .collect();
        // The widest row leads: candidates are where it fits, found through the block index.
        let Some(&(pr, pa, pneed)) = rows.iter().max_by_key(|r| (r.2, Reverse(r.0))) else {
            return Some((0, 0));
        };
        let mut first = 0;
        for y in 0..=n - m.h {
            if y + m.h > bottom.load(Ordering::Relaxed) {
                return None;
            }
            if rows
                .iter()
                .any(|&(r, _, need)| (self.max_free[y + r] as usize) < need)
            {
                continue;
            }
            let mut x = 0;
            'scan: while x + m.w <= n {
                let Some(c) = self.next_fit(y + pr, x + pa, pneed) else {
                    break;
                };
                x = c - pa;
                if x + m.w > n {
                    break;
                }
                for k in 0..rows.len() {
                    let (r, a, need) = rows[(first + k) % rows.len()];
                    let v = self.run[(y + r) * n + x + a];
                    if v as usize >= need && v > 0 {
                        continue;
                    }
                    first = (first + k) % rows.len();
                    // A free run too short: every shift that keeps this row's span over the
                    // occupied texel ending it fails too. An occupied run: skip past it.
                    x += if v > 0 { v as usize + 1 } else { (-v) as usize };
                    continue 'scan;
                }
                return Some((x, y));
            }
        }
        None
    }

    /// Marks the footprint of `m` at `(x, y)` occupied and updates the runs of its rows.
    fn place(&mut self, m: &Mask, x: usize, y: usize) {
        let n = self.size;
        let blocks = n.div_ceil(BLOCK);
        let mut row_end: Vec<Option<(usize, usize)>> = vec![None; m.h];
        for &(r, a, b) in &m.runs {
            let row = (y + r as usize) * n;
            for c in a as usize..=b as usize {
                self.occ[row + x + c] = true;
            }
            let e = &mut row_end[r as usize];
            let (a, b) = (x + a as usize, x + b as usize);
            *e = Some(e.map_or((a, b), |(l, h)| (l.min(a), h.max(b))));
        }
        for (r, e) in row_end.iter().enumerate() {
            let Some((first, last)) = *e else { continue };
            let row = (y + r) * n;
            let (occ, run) = (&self.occ[row..row + n], &mut self.run[row..row + n]);
            // Runs depend on the texel to the right only, so they change from `last` leftwards
            // until a recomputed value left of the placement equals the old one.
            let mut lowest = 0;
            for c in (0..=last).rev() {
                let next = if c + 1 < n { run[c + 1] } else { 0 };
                let v = match (occ[c], c + 1 < n && occ[c + 1]) {
                    (true, true) => next - 1,
                    (true, false) => -1,
                    (false, false) => next.max(0) + 1,
                    (false, true) => 1,
                };
                if c < first && run[c] == v {
                    lowest = c + 1;
                    break;
                }
                run[c] = v;
            }
            let bmax = &mut self.block_max[(y + r) * blocks..(y + r + 1) * blocks];
            for b in lowest / BLOCK..=last / BLOCK {
                bmax[b] = run[b * BLOCK..((b + 1) * BLOCK).min(n)]
                    .iter()
                    .map(|&v| v.max(0) as u32)
                    .max()
                    .unwrap_or(0);
            }
            self.max_free[y + r] = bmax.iter().copied().max().unwrap_or(0);
        }
    }
}

/// A chart ready to pack: UVs in texels and faces in local vertex indices.
type ScaledChart<'a> = (Vec<Vector2<f64>>, &'a [[u32; 3]]);

/// Where a chart went.
#[derive(Debug, Clone, Copy)]
struct Placement {
    page: u32,
    x: usize,
    y: usize,
    rot: u8,
    offset: Vector2<f64>,
}

/// The rotations tried for every chart (quarter turns of its minimum-area rectangle).
const ROTATIONS: [u8; 4] = [0, 1, 2, 3];

/// Packs the charts (UVs in texels already) into pages of `size`; with `one_page`, fails as soon
/// as a chart does not fit the first page. `None` when it fails.
fn attempt(
    charts: &[ScaledChart],
    order: &[usize],
    size: usize,
    gutter: usize,
    one_page: bool,
) -> Option<(Vec<Placement>, u32)> {
    use rayon::prelude::*;
    // Masks are made in batches in packing order: an attempt that fails (most of a density
    // search) stops early and does not rasterise the charts it never reached.
    let mut masks: Vec<Vec<Mask>> = vec![Vec::new(); charts.len()];
    let mut made = 0;
    let mut pages = vec![Page::new(size)];
    let mut out = vec![
        Placement {
            page: 0,
            x: 0,
            y: 0,
            rot: 0,
            offset: Vector2::zeros()
        };
        charts.len()
    ];
    for (j, &i) in order.iter().enumerate() {
        if j == made {
            let batch = &order[made..(made + (2 * made).clamp(16, 256)).min(order.len())];
            let new: Vec<Vec<Mask>> = batch
                .par_iter()
                .map(|&c| {
                    let (uv, faces) = &charts[c];
                    let (foot, w, h, offset) = footprint(uv, faces, gutter);
                    ROTATIONS
                        .iter()
                        .map(|&r| mask(&foot, w, h, offset, r, gutter))
                        .collect()
                })
                .collect();
            for (&c, m) in batch.iter().zip(new) {
                masks[c] = m;
            }
            made += batch.len();
        }
        let mut placed = false;
        for (p, page) in pages.iter_mut().enumerate() {
            // Lowest top edge wins: it keeps the filled region flat.
            // Each turn stops searching below the lowest bottom edge another turn has found
            // (ties go on, to compare x): the winner does not depend on timing.
            let bottom = AtomicUsize::new(usize::MAX);
            let best = masks[i]
                .par_iter()
                .enumerate()
                .filter_map(|(k, m)| {
                    let (x, y) = page.find(m, &bottom)?;
                    bottom.fetch_min(y + m.h, Ordering::Relaxed);
                    Some(((y + m.h, x, k), (x, y)))
                })
                .min_by_key(|(key, _)| *key);
            if let Some(((_, _, k), (x, y))) = best {
                let m = &masks[i][k];
                page.place(m, x, y);
                out[i] = Placement {
                    page: p as u32,
                    x,
                    y,
                    rot: m.rot,
                    offset: m.offset,
                };
                placed = true;
                break;
            }
        }
        if !placed {
            if one_page {
                return None;
            }
            let mut page = Page::new(size);
            let (k, m) = masks[i]
                .iter()
                .enumerate()
                .min_by_key(|(_, m)| m.w.max(m.h))
                .expect("four rotations");
            let (x, y) = page.find(m, &AtomicUsize::new(usize::MAX))?;
            page.place(m, x, y);
            out[i] = Placement {
                page: pages.len() as u32,
                x,
                y,
                rot: ROTATIONS[k],
                offset: m.offset,
            };
            pages.push(page);
        }
    }
    Some((out, pages.len() as u32))
}

/// Packs `maps` (charts of `mesh`) into the atlas. `chart_scale` multiplies each chart's size
/// (the texel budget across charts; 1 for all charts gives one uniform density). Without a
/// fixed density the largest density that fits one page is found by bisection; with
/// `texels_per_unit` set, charts go onto as many pages as they need (UDIM tiles: page `p` has
/// u in `[p, p + 1]`). Deterministic.
pub fn pack(
    mesh: &Mesh,
    maps: &[ChartMap],
    chart_scale: &[f64],
    opts: &PackOptions,
) -> crate::Result<Packed> {
    let size = opts.size as usize;
    let gutter = opts.gutter as usize;
    if size < 2 * gutter + 1 || size > 32768 {
        return Err(crate::Error::option(
            "size",
            format!(
                "atlas size {} must be between {} and 32768 with a gutter of {}",
                opts.size,
                2 * gutter + 1,
                opts.gutter
            ),
        ));
    }
    let mut charts: Vec<ChartMap> = maps.to_vec();
    for (c, &k) in charts.iter_mut().zip(chart_scale) {
        orient(&mut c.uv);
        for p in c.uv.iter_mut() {
            *p *= k;
        }
    }
    let area: f64 = charts
        .iter()
        .map(|c| {
            c.faces
                .iter()
                .map(|t| super::param::uv_area(t.map(|i| c.uv[i as usize])).abs())
                .sum::<f64>()
        })
        .sum::<f64>()
        .max(1e-300);
    // Largest charts first; ties by index, so the order is deterministic.
    let mut order: Vec<usize> = (0..charts.len()).collect();
    let chart_area: Vec<f64> = charts
        .iter()
        .map(|c| {
            let lo =
                c.uv.iter()
                    .fold(Vector2::repeat(f64::INFINITY), |a, p| a.inf(p));
            let hi =
                c.uv.iter()
                    .fold(Vector2::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
            (hi - lo).x * (hi - lo).y
        })
        .collect();
    order.sort_by(|&a, &b| chart_area[b].total_cmp(&chart_area[a]).then(a.cmp(&b)));
    let scaled = |s: f64| -> Vec<ScaledChart> {
        charts
            .iter()
            .map(|c| (c.uv.iter().map(|p| p * s).collect(), c.faces.as_slice()))
            .collect()
    };
    let (scale, (placements, pages)) = match opts.texels_per_unit {
        Some(s) => {
            if !(s.is_finite() && s > 0.0) {
                return Err(crate::Error::option(
                    "texel_density",
                    format!("texel density {s} must be a positive number"),
                ));
            }
            let r = attempt(&scaled(s), &order, size, gutter, false).ok_or_else(|| {
                crate::Error::option(
                    "texel_density",
                    format!(
                        "a chart is larger than a {size}-texel page at {s} texels per unit: lower \
                     the texel density or raise the atlas size"
                    ),
                )
            })?;
            (s, r)
        }
        None => {
            // Texels per unit at full utilisation bounds the density from above.
            let upper = size as f64 / area.sqrt();
            // The density is searched coarse to fine: bisection on a page of a quarter of the
            // size (a quarter of the gutter, rounded up), then refinement at half and full size
            // starting from the coarse answer. A packing that succeeds places every chart and
            // costs far more than one that fails early, and coarse packings are 4-16 times
            // cheaper; the coarse footprints are larger, so the coarse answer nearly always
            // fits at full size.
            let levels = (0..=2)
                .rev()
                .filter(|&l| l == 0 || size >> l >= 512)
                .collect::<Vec<u32>>();
            let at = |level: u32, s: f64| {
                let k = (1u32 << level) as f64;
                attempt(
                    &scaled(s / k),
                    &order,
                    size >> level,
                    gutter.div_ceil(1 << level),
                    true,
                )
            };
            let mut found: Option<(f64, (Vec<Placement>, u32))> = None;
            for &level in &levels {
                let (mut lo, mut best, mut hi) = match found.take() {
                    None => {
                        let mut s = upper * 0.8;
                        let mut fit = None;
                        for _ in 0..60 {
                            if let Some(r) = at(level, s) {
                                fit = Some((s, r));
                                break;
                            }
                            s /= 1.15;
                        }
                        let Some((lo, best)) = fit else { break };
                        let hi = if lo == upper * 0.8 { upper } else { lo * 1.15 };
                        (lo, best, hi)
                    }
                    Some((mut s, _)) => {
                        let mut fit = None;
                        for _ in 0..200 {
                            if let Some(r) = at(level, s) {
                                fit = Some((s, r));
                                break;
                            }
                            s /= 1.01;
                        }
                        let Some((lo, best)) = fit else { break };
                        (lo, best, lo * if level == 0 { 1.0 } else { 1.04 })
                    }
                };
                while hi / lo > 1.004 {
                    let mid = (lo * hi).sqrt();
                    match at(level, mid) {
                        Some(r) => {
                            lo = mid;
                            best = r;
                        }
                        None => hi = mid,
                    }
                }
                found = Some((lo, best));
            }
            let Some((lo, (placements, pages))) = found else {
                return Err(crate::Error::option(
                    "size",
                    format!(
                        "{} charts do not fit a {size}-texel atlas with a {gutter}-texel gutter: \
                     raise the atlas size or lower the gutter",
                        charts.len()
                    ),
                ));
            };
            (lo, (placements, pages))
        }
    };
    let n = size as f64;
    let mut coords = Vec::new();
    let mut faces = vec![[0u32; 3]; mesh.num_faces()];
    let mut face_chart = vec![0u32; mesh.num_faces()];
    for (ci, c) in charts.iter().enumerate() {
        let base = coords.len() as u32;
        let pl = placements[ci];
        let corner = Vector2::new(pl.x as f64, pl.y as f64) + pl.offset;
        for p in &c.uv {
            let t = (rotate(p * scale, pl.rot) + corner) / n + Vector2::new(pl.page as f64, 0.0);
            coords.push(t.cast::<f32>());
        }
        for (t, f) in c.faces.iter().zip(&c.face_ids) {
            faces[f.idx()] = t.map(|i| base + i);
            face_chart[f.idx()] = ci as u32;
        }
    }
    Ok(Packed {
        uv: UvMap { coords, faces },
        texels_per_unit: scale,
        face_chart,
        pages,
    })
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

/// The UDIM page (0 for tile 1001) of face `f`: the integer part of its centroid's u.
pub fn face_page(uv: &UvMap, f: usize) -> u32 {
    let u: f32 = uv.faces[f]
        .iter()
        .map(|&i| uv.coords[i as usize].x)
        .sum::<f32>()
        / 3.0;
    u.floor().max(0.0) as u32
}

/// Rasterises the UV triangles at `size` x `size` texels per page (texel centres) and returns,
/// per texel of `pages` pages (page after page), how many charts cover it (0, 1, or more if
/// charts overlap). A face belongs to the page of its centroid's u ([`face_page`]).
pub fn coverage(uv: &UvMap, face_chart: &[u32], size: u32, pages: u32) -> Vec<u8> {
    let per = (size * size) as usize;
    let mut owner = vec![u32::MAX; per * pages as usize];
    let mut count = vec![0u8; per * pages as usize];
    let n = size as f64;
    for (f, t) in uv.faces.iter().enumerate() {
        let page = (face_page(uv, f) as usize).min(pages as usize - 1);
        let q = t.map(|i| {
            let c = uv.coords[i as usize].cast::<f64>();
            Vector2::new(c.x - page as f64, c.y) * n
        });
        raster_triangle(q, size, size, |x, y| {
            let i = page * per + (y * size + x) as usize;
            if owner[i] != face_chart[f] {
                count[i] = count[i].saturating_add(1);
                owner[i] = face_chart[f];
            }
        });
    }
    count
}
