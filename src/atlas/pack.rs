//! Packing flattened charts into square atlas pages (issue 4, step 3). Each chart is turned to
//! its minimum-area rectangle, then rasterised conservatively (every texel its triangles touch)
//! in four quarter turns; charts go largest first to the first free position, row by row, of
//! the turn whose top edge ends lowest, tested against the exact occupancy of the page with the
//! new chart's footprint dilated by the gutter. Small charts thus fill holes and bays of large
//! ones. The density is the largest that fits one page (bisection), or fixed, with as many
//! pages as needed. A page keeps its free texels as intervals per row, so a row is tested for
//! every x at once; per-band summaries skip rows where a chart cannot fit. A square map (per
//! texel, the largest free square starting there) lets a search skip rows, and list the few
//! x, where the chart's own inscribed squares do not fit: on a filled page most of the rows a
//! search used to visit are holes too small for the chart.

use super::param::ChartMap;
use crate::mesh::{Mesh, UvMap};
use nalgebra::Vector2;
use rayon::prelude::*;
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
    /// Instead of a density, the texels the charts should cover in all (their packed area):
    /// the density follows, and charts fill as many pages as they need. Ignored when
    /// `texels_per_unit` is set. Default: `None`.
    pub chart_texels: Option<f64>,
    /// With a fixed density (`texels_per_unit` or `chart_texels`), at most this many pages:
    /// the density is lowered until the charts fit them. Default: `None` (no limit).
    pub max_pages: Option<u32>,
}

impl Default for PackOptions {
    fn default() -> Self {
        PackOptions {
            size: 4096,
            gutter: 4,
            texels_per_unit: None,
            chart_texels: None,
            max_pages: None,
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
    /// Squares inside the dilated spans (sides capped at [`SQUARE_CAP`]) as (top row, left
    /// column, side): the largest first, then the largest whose top row lies in each other
    /// third of the rows. Wherever the mask fits, a free square of each side starts there on
    /// the page.
    squares: Vec<(usize, usize, usize)>,
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
        // A triangle inside one texel meets that texel's square and no other: marked without
        // the edge tests.
        if x0 == x1 && y0 == y1 {
            foot[y0 * w + x0] = true;
            continue;
        }
        let (area, edges) = edge_tests(&q);
        let meets = |x: usize, y: usize| {
            let c = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
            area == 0.0 || edges.iter().all(|(p, n, r)| n.dot(&(c - p)) + r >= 0.0)
        };
        for y in y0..=y1 {
            let row = &mut foot[y * w..(y + 1) * w];
            let each = |row: &mut [bool]| {
                for (x, t) in (x0..=x1).zip(&mut row[x0..=x1]) {
                    *t |= meets(x, y);
                }
            };
            if x1.saturating_sub(x0) < 4 || area == 0.0 {
                each(row);
                continue;
            }
            // The texels a row meets are one run (the test is three half-planes, each
            // monotone in x also in floating point): its ends from the edges' equations, then
            // moved to where the exact test changes, so the run is the per-texel loop's.
            let cy = y as f64 + 0.5;
            let (mut a, mut b) = (x0 as f64, x1 as f64);
            for (p, n, r) in &edges {
                let k = n.y * (cy - p.y) + r;
                if n.x > 0.0 {
                    a = a.max((p.x - k / n.x - 0.5).ceil());
                } else if n.x < 0.0 {
                    b = b.min((p.x - k / n.x - 0.5).floor());
                }
            }
            let mid = ((a + b) * 0.5).clamp(x0 as f64, x1 as f64) as usize;
            if !(a <= b && meets(mid, y)) {
                // Empty or a sliver the estimate missed: test every texel.
                each(row);
                continue;
            }
            let mut lo = (a.max(x0 as f64) as usize).min(mid);
            if meets(lo, y) {
                while lo > x0 && meets(lo - 1, y) {
                    lo -= 1;
                }
            } else {
                while !meets(lo, y) {
                    lo += 1;
                }
            }
            let mut hi = (b.min(x1 as f64) as usize).max(mid);
            if meets(hi, y) {
                while hi < x1 && meets(hi + 1, y) {
                    hi += 1;
                }
            } else {
                while !meets(hi, y) {
                    hi -= 1;
                }
            }
            row[lo..=hi].fill(true);
        }
    }
    (foot, w, h, offset)
}

/// A point on a triangle's edge, its inward normal and a texel square's reach along it.
type EdgeTest = (Vector2<f64>, Vector2<f64>, f64);

/// A triangle's signed area and, per edge, a point on it, its inward normal and the reach of
/// a texel's square along that normal: the square centred at `c` meets the triangle iff, for
/// every edge, `n . (c - p) + r >= 0` (its best corner is inside; the box test is the loop
/// range).
fn edge_tests(q: &[Vector2<f64>; 3]) -> (f64, [EdgeTest; 3]) {
    let area = (q[1] - q[0]).perp(&(q[2] - q[0]));
    let edges = std::array::from_fn(|k| {
        let (p, r) = (q[k], q[(k + 1) % 3]);
        let e = r - p;
        let n = Vector2::new(-e.y, e.x) * area.signum();
        (p, n, 0.5 * (n.x.abs() + n.y.abs()) + 1e-9 * n.norm())
    });
    (area, edges)
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
    let spans: Vec<Option<(u32, u32)>> = (0..rh)
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
    let squares = inscribed_squares(&spans);
    Mask {
        w: rw,
        h: rh,
        spans,
        runs,
        offset: off,
        rot,
        squares,
    }
}

/// The largest square in the row spans, then the largest whose top row lies in each other
/// third of the rows (sides at most [`SQUARE_CAP`]), as (top row, left column, side).
fn inscribed_squares(spans: &[Option<(u32, u32)>]) -> Vec<(usize, usize, usize)> {
    let h = spans.len();
    let thirds = [0, h / 3, 2 * h / 3, h];
    let mut out: Vec<(usize, usize, usize)> = (0..3)
        .filter(|&t| thirds[t] < thirds[t + 1])
        .map(|t| inscribed_square(spans, thirds[t], thirds[t + 1]))
        .filter(|q| q.2 > 0)
        .collect();
    // The largest first (the earliest on ties): it lists the candidates, the others filter.
    let first = (0..out.len())
        .max_by_key(|&i| (out[i].2, std::cmp::Reverse(i)))
        .unwrap_or(0);
    if !out.is_empty() {
        out.swap(0, first);
    }
    out
}

/// The largest square (side at most [`SQUARE_CAP`]) inside the row spans whose top row lies in
/// `from..to`: its top row, left column and side (0 when there is none).
fn inscribed_square(spans: &[Option<(u32, u32)>], from: usize, to: usize) -> (usize, usize, usize) {
    let mut best = (from, 0, 0);
    for r0 in from..to {
        if spans.len() - r0 <= best.2 || best.2 == SQUARE_CAP {
            break;
        }
        // Rows r0..r0 + s hold a square of side s iff their common run has s texels.
        let (mut lo, mut hi) = (0u32, u32::MAX);
        for s in 1..=SQUARE_CAP.min(spans.len() - r0) {
            let Some((a, b)) = spans[r0 + s - 1] else {
                break;
            };
            lo = lo.max(a);
            hi = hi.min(b);
            if hi < lo || ((hi - lo + 1) as usize) < s {
                break;
            }
            if s > best.2 {
                best = (r0, lo as usize, s);
            }
        }
    }
    best
}

/// One atlas page: per row, its free texels as sorted, disjoint half-open intervals, and the
/// longest of them. A mask's valid positions in one row are then a few x ranges, so a row of
/// the page is tested for every x at once by intersecting range lists, instead of texel by
/// texel through a page-sized array (which missed the cache on every probe).
struct Page {
    size: usize,
    /// Per row, the free texels as sorted, disjoint half-open intervals `[start, end)`.
    free: Vec<Vec<(u32, u32)>>,
    /// Per row, the longest free interval.
    max_free: Vec<u32>,
    /// For each band height `BANDS[l]`, per aligned band of that many rows, the longest run
    /// free in all of them.
    band_free: Vec<Vec<u32>>,
    /// Texels per side of a block of the square map (1 up to 8192 texels, so that the map
    /// stays within 64 MB).
    block: usize,
    /// Blocks per side: the blocks wholly inside the page.
    blocks: usize,
    /// Per block, row-major, the side (in blocks, at most [`SQUARE_CAP`]) of the largest
    /// square of wholly free blocks whose top-left block it is.
    square: Vec<u8>,
    /// Per block row, per group of [`SQUARE_GROUP`] blocks, the largest of `square`.
    square_group: Vec<u8>,
    /// Per block row, the largest of `square`: a mask whose inscribed square starts in this
    /// row needs it to be large enough. Most rows of a filled page fail this one look.
    square_row: Vec<u8>,
    /// For each side k up to [`SQUARE_CAP`], the first block row whose `square_row` is at
    /// least k (`blocks` if none). Squares only shrink as charts are placed, so this only
    /// moves down, and a find starts there instead of at the top of a filled page.
    first_row: Vec<usize>,
}

/// Largest square side the square map records (blocks), and the largest looked for in a mask:
/// a placement changes the map up to this far above and left of the chart.
const SQUARE_CAP: usize = 64;

/// Candidates are listed from the square map only where at most this many groups of a row
/// hold a large enough square; elsewhere (an open page) the intervals are cheaper.
const SELECTIVE_GROUPS: usize = 4;

/// One bit per entry of `row[start..start + 64]` (entries outside the row: 0) that is at least
/// `k` (at most [`SQUARE_CAP`]), bit i for entry start + i. Eight entries at a time: adding
/// 128 - k to an entry (at most 64) sets its top bit iff it is at least k, and never carries
/// into the next byte.
fn at_least(row: &[u8], start: i64, k: usize) -> u64 {
    let mut buf = [0u8; 64];
    let (from, to) = (start.max(0), (start + 64).min(row.len() as i64));
    if from >= to {
        return 0;
    }
    let (from, to) = (from as usize, to as usize);
    let off = (from as i64 - start) as usize;
    buf[off..off + (to - from)].copy_from_slice(&row[from..to]);
    let add = u64::from_le_bytes([(128 - k) as u8; 8]);
    let mut bits = 0u64;
    for (i, word) in buf.chunks_exact(8).enumerate() {
        let w = u64::from_le_bytes(word.try_into().expect("eight bytes"));
        let top = ((w + add) & 0x8080_8080_8080_8080) >> 7;
        bits |= (top.wrapping_mul(0x0102_0408_1020_4080) >> 56) << (8 * i);
    }
    bits
}

/// Blocks per group in [`Page::square_group`] (at most 64: a group's candidates are one
/// machine word). The tests use smaller groups, so that their small pages have several.
const SQUARE_GROUP: usize = if cfg!(test) { 8 } else { 64 };

/// Rows per band in [`Page::band_free`]. Any window of `2 * B - 1` rows holds a whole band of
/// `B`, so a span common to that many rows of a mask must lie in a run free across a band.
const BANDS: [usize; 2] = [4, 16];

/// The longest run free in every row of `rows`.
fn common_free(rows: &[Vec<(u32, u32)>]) -> u32 {
    let mut cur = rows[0].clone();
    let mut next = Vec::new();
    for row in &rows[1..] {
        next.clear();
        let (mut i, mut j) = (0, 0);
        while i < cur.len() && j < row.len() {
            let (l, h) = (cur[i].0.max(row[j].0), cur[i].1.min(row[j].1));
            if l < h {
                next.push((l, h));
            }
            if cur[i].1 < row[j].1 {
                i += 1;
            } else {
                j += 1;
            }
        }
        std::mem::swap(&mut cur, &mut next);
        if cur.is_empty() {
            return 0;
        }
    }
    cur.iter().map(|iv| iv.1 - iv.0).max().unwrap_or(0)
}

/// Intersects the sorted, disjoint inclusive ranges `cur` with the x positions where a span of
/// `need` texels starting `a` texels right of x lies inside one free interval of `row`, writing
/// the result to `out`.
fn intersect(cur: &[(u32, u32)], row: &[(u32, u32)], a: u32, need: u32, out: &mut Vec<(u32, u32)>) {
    out.clear();
    let (Some(&(first, _)), Some(&(_, last))) = (cur.first(), cur.last()) else {
        return;
    };
    // Only the intervals that can hold a span starting in [first, last] matter.
    let from = row.partition_point(|iv| iv.1 < first + a + need);
    let mut k = 0;
    for &(s, e) in &row[from..] {
        if s > last + a {
            break;
        }
        if e - s < need || e < a + need {
            continue;
        }
        // x with s <= x + a and x + a + need <= e.
        let (lo, hi) = (s.saturating_sub(a), e - need - a);
        if lo > hi {
            continue;
        }
        while k < cur.len() && cur[k].1 < lo {
            k += 1;
        }
        let mut j = k;
        while j < cur.len() && cur[j].0 <= hi {
            let (l, h) = (cur[j].0.max(lo), cur[j].1.min(hi));
            if l <= h {
                out.push((l, h));
            }
            j += 1;
        }
    }
}

impl Page {
    fn new(size: usize) -> Page {
        Page::with_block(size, size.div_ceil(8192))
    }

    fn with_block(size: usize, block: usize) -> Page {
        let blocks = size / block;
        // An empty page: a block's square reaches the right or bottom edge, or the cap. The
        // largest in a group is its first block's, in a row its first group's.
        let mut square = vec![0u8; blocks * blocks];
        for (by, row) in square.chunks_mut(blocks.max(1)).enumerate() {
            let cap = (blocks - by).min(SQUARE_CAP);
            row[..blocks - cap].fill(cap as u8);
            for (v, side) in row[blocks - cap..].iter_mut().zip((1..=cap).rev()) {
                *v = side as u8;
            }
        }
        let groups = blocks.div_ceil(SQUARE_GROUP);
        let square_group: Vec<u8> = (0..blocks * groups)
            .map(|i| square[(i / groups) * blocks + (i % groups) * SQUARE_GROUP])
            .collect();
        let square_row: Vec<u8> = (0..blocks).map(|by| square[by * blocks]).collect();
        Page {
            size,
            free: vec![vec![(0, size as u32)]; size],
            max_free: vec![size as u32; size],
            band_free: BANDS.iter().map(|&b| vec![size as u32; size / b]).collect(),
            block,
            blocks,
            square,
            square_group,
            first_row: (0..=SQUARE_CAP)
                .map(|k| {
                    square_row
                        .iter()
                        .position(|&v| v as usize >= k)
                        .unwrap_or(blocks)
                })
                .collect(),
            square_row,
        }
    }

    /// Brings the square map up to date after the footprint of `m` was placed at `(x, y)`:
    /// the blocks it touches are no longer free. A block's square depends only on its right,
    /// lower and lower-right neighbours, so the map is recomputed from the bottom row of the
    /// chart upwards, in each row only from the right end of what changed in it or below it
    /// and leftwards while values keep changing; it stops at the first row above the chart
    /// where nothing changed (at most [`SQUARE_CAP`] rows up).
    fn update_squares(&mut self, m: &Mask, x: usize, y: usize) {
        let (b, nb) = (self.block, self.blocks);
        if nb == 0 || y / b >= nb || x / b >= nb {
            return;
        }
        let (by0, by1) = (y / b, ((y + m.h - 1) / b).min(nb - 1));
        // Per block row of the chart, the columns it made occupied.
        let mut occupied: Vec<Option<(usize, usize)>> = vec![None; by1 - by0 + 1];
        for &(r, a, e) in &m.runs {
            let by = (y + r as usize) / b;
            if by >= nb || (x + a as usize) / b >= nb {
                continue;
            }
            let (b0, b1) = ((x + a as usize) / b, ((x + e as usize) / b).min(nb - 1));
            self.square[by * nb + b0..=by * nb + b1].fill(0);
            let o = &mut occupied[by - by0];
            *o = Some(o.map_or((b0, b1), |(l, h)| (l.min(b0), h.max(b1))));
        }
        let groups = nb.div_ceil(SQUARE_GROUP);
        // Columns that changed in the row below (inclusive).
        let mut below: Option<(usize, usize)> = None;
        for by in (0..=by1).rev() {
            let occ = if by >= by0 { occupied[by - by0] } else { None };
            // Candidates: the occupied columns, and those whose lower or lower-right
            // neighbour changed.
            let cand = match (occ, below) {
                (Some(o), Some(d)) => Some((o.0.min(d.0.saturating_sub(1)), o.1.max(d.1))),
                (Some(o), None) => Some(o),
                (None, Some(d)) => Some((d.0.saturating_sub(1), d.1)),
                (None, None) => None,
            };
            let Some((lo, hi)) = cand else {
                if by < by0 {
                    break;
                }
                below = None;
                continue;
            };
            let row = by * nb;
            let mut changed = occ;
            let mut prev_changed = false;
            let mut bx = hi as isize;
            while bx >= 0 {
                let c = bx as usize;
                if c < lo && !prev_changed {
                    break;
                }
                let i = row + c;
                let old = self.square[i];
                prev_changed = occ.is_some_and(|(l, h)| (l..=h).contains(&c));
                if old != 0 {
                    let right = if c + 1 < nb { self.square[i + 1] } else { 0 };
                    let (down, diag) = if by + 1 < nb {
                        let diag = if c + 1 < nb {
                            self.square[i + nb + 1]
                        } else {
                            0
                        };
                        (self.square[i + nb], diag)
                    } else {
                        (0, 0)
                    };
                    let new = (1 + right.min(down).min(diag)).min(SQUARE_CAP as u8);
                    if new != old {
                        self.square[i] = new;
                        prev_changed = true;
                        changed = Some(changed.map_or((c, c), |(l, h)| (l.min(c), h.max(c))));
                    }
                }
                bx -= 1;
            }
            below = changed;
            let Some((l, h)) = changed else {
                if by < by0 {
                    break;
                }
                continue;
            };
            for g in l / SQUARE_GROUP..=h / SQUARE_GROUP {
                self.square_group[by * groups + g] = self.square
                    [row + g * SQUARE_GROUP..row + ((g + 1) * SQUARE_GROUP).min(nb)]
                    .iter()
                    .copied()
                    .max()
                    .unwrap_or(0);
            }
            self.square_row[by] = self.square_group[by * groups..(by + 1) * groups]
                .iter()
                .copied()
                .max()
                .unwrap_or(0);
        }
        for (k, f) in self.first_row.iter_mut().enumerate() {
            while *f < nb && (self.square_row[*f] as usize) < k {
                *f += 1;
            }
        }
    }

    /// The first position (row-major, top-left corner of the mask's box) where the dilated
    /// footprint meets no occupied texel and stays inside the page, among those whose bottom
    /// edge `y + m.h` is at most `bottom` (read as it goes: other searches lower it).
    fn find(&self, m: &Mask, bottom: &AtomicUsize) -> Option<(usize, usize)> {
        let n = self.size;
        if m.w > n || m.h > n {
            return None;
        }
        let rows: Vec<(usize, u32, u32)> = m
            .spans
            .iter()
            .enumerate()
            .filter_map(|(r, s)| s.map(|(a, b)| (r, a, b - a + 1)))
            .collect();
        // The widest row is tested first; rows far apart fail for different reasons, so the
        // others follow in bisection order, and a row that empties the candidates moves to the
        // front.
        let Some((lead, _)) = rows
            .iter()
            .enumerate()
            .max_by_key(|(_, r)| (r.2, Reverse(r.0)))
        else {
            return Some((0, 0));
        };
        let mut order: Vec<usize> = Vec::with_capacity(rows.len());
        order.push(lead);
        let mut seen = vec![false; rows.len()];
        seen[lead] = true;
        let mut step = rows.len().next_power_of_two();
        while step >= 1 {
            for i in (0..rows.len()).step_by(step) {
                if !seen[i] {
                    seen[i] = true;
                    order.push(i);
                }
            }
            if step == 1 {
                break;
            }
            step /= 2;
        }
        // Per band height, the widest span common to 2 * B - 1 consecutive rows of the mask: a
        // cheap necessary test per row of the page.
        let cores: Vec<(usize, usize, u32)> = BANDS
            .iter()
            .enumerate()
            .filter(|&(_, &b)| m.spans.len() >= 2 * b - 1)
            .filter_map(|(l, &b)| {
                let win = 2 * b - 1;
                (0..=m.spans.len() - win)
                    .map(|r0| {
                        let c = m.spans[r0..r0 + win]
                            .iter()
                            .try_fold((0u32, u32::MAX), |acc, s| {
                                s.map(|(a, b)| (acc.0.max(a), acc.1.min(b)))
                            });
                        (l, r0, c.map_or(0, |(a, b)| (b + 1).saturating_sub(a)))
                    })
                    .max_by_key(|&(_, r0, len)| (len, Reverse(r0)))
                    .filter(|c| c.2 > 0)
            })
            .collect();
        // The mask's inscribed squares as top row, left column and side in whole blocks of the
        // square map: a texel square of side q contains an aligned square of (q + 1) / b - 1
        // blocks, starting in the block row that holds or follows its top row.
        let b = self.block;
        let squares: Vec<(usize, usize, usize)> = m
            .squares
            .iter()
            .map(|&(r, c, s)| (r, c, ((s + 1) / b).saturating_sub(1)))
            .filter(|q| q.2 > 0)
            .collect();
        let (sq_row, sq_col, need_blocks) = squares.first().copied().unwrap_or((0, 0, 0));
        let full = [(0u32, (n - m.w) as u32)];
        let mut cur: Vec<(u32, u32)> = Vec::new();
        let mut next: Vec<(u32, u32)> = Vec::new();
        let groups = self.blocks.div_ceil(SQUARE_GROUP);
        // Rows above the first block row holding a large enough square cannot take the mask:
        // ceil((y + r) / b) >= F needs y >= (F - 1) b + 1 - r.
        let start = squares
            .iter()
            .map(|&(r, _, k)| match self.first_row[k] {
                0 => 0,
                f => ((f - 1) * b + 1).saturating_sub(r),
            })
            .max()
            .unwrap_or(0);
        for y in start..=n - m.h {
            if y + m.h > bottom.load(Ordering::Relaxed) {
                return None;
            }
            if squares
                .iter()
                .any(|&(r, _, k)| (self.square_row[(y + r).div_ceil(b)] as usize) < k)
            {
                continue;
            }
            if cores
                .iter()
                .any(|&(l, r0, len)| self.band_free[l][(y + r0).div_ceil(BANDS[l])] < len)
            {
                continue;
            }
            cur.clear();
            // The block row of the first square (only read when there is one: it is inside
            // the page then).
            let by = (y + sq_row).div_ceil(b);
            let row_groups: &[u8] = if need_blocks > 0 {
                &self.square_group[by * groups..(by + 1) * groups]
            } else {
                &[]
            };
            let selective = need_blocks > 0 && {
                let k = need_blocks as u8;
                row_groups.iter().filter(|&&gm| gm >= k).count() <= SELECTIVE_GROUPS
            };
            if selective {
                // The candidates are the x whose inscribed square's top-left texel lies in a
                // block that starts a free square large enough: block bx holds that texel's
                // ceiling, so the texel lies in ((bx - 1) b, bx b]. With one texel per block,
                // the other squares filter them in the same pass (x's block for a square at
                // column c is x + c).
                let row = &self.square[by * self.blocks..(by + 1) * self.blocks];
                let others: &[(usize, usize, usize)] = if b == 1 { &squares[1..] } else { &[] };
                let last = (n - m.w) as i64;
                for (g, &gm) in row_groups.iter().enumerate() {
                    if (gm as usize) < need_blocks {
                        continue;
                    }
                    let base = g * SQUARE_GROUP;
                    let mut bits = at_least(row, base as i64, need_blocks);
                    if SQUARE_GROUP < 64 {
                        bits &= (1u64 << SQUARE_GROUP) - 1;
                    }
                    for &(r, c, k) in others {
                        if bits == 0 {
                            break;
                        }
                        let other = &self.square[(y + r) * self.blocks..][..self.blocks];
                        bits &= at_least(other, base as i64 + c as i64 - sq_col as i64, k);
                    }
                    while bits != 0 {
                        let start = bits.trailing_zeros() as usize;
                        let len = (!(bits >> start)).trailing_zeros() as usize;
                        bits &= if start + len >= 64 {
                            0
                        } else {
                            !0u64 << (start + len)
                        };
                        // Blocks base + start .. base + start + len.
                        let lo = ((base + start) as i64 - 1) * b as i64 + 1 - sq_col as i64;
                        let hi = ((base + start + len - 1) * b) as i64 - sq_col as i64;
                        let (lo, hi) = (lo.max(0), hi.min(last));
                        if lo > hi {
                            continue;
                        }
                        let (lo, hi) = (lo as u32, hi as u32);
                        match cur.last_mut() {
                            Some((_, h)) if *h + 1 >= lo => *h = (*h).max(hi),
                            _ => cur.push((lo, hi)),
                        }
                    }
                }
                if cur.is_empty() {
                    continue;
                }
            } else {
                if rows.iter().any(|&(r, _, need)| self.max_free[y + r] < need) {
                    continue;
                }
                cur.extend_from_slice(&full);
            }
            for k in 0..order.len() {
                let (r, a, need) = rows[order[k]];
                intersect(&cur, &self.free[y + r], a, need, &mut next);
                std::mem::swap(&mut cur, &mut next);
                if cur.is_empty() {
                    // This row goes first at the next y: neighbouring rows of the page look
                    // alike.
                    order[..=k].rotate_right(1);
                    break;
                }
            }
            if let Some(&(x, _)) = cur.first() {
                return Some((x as usize, y));
            }
        }
        None
    }

    /// Marks the footprint of `m` at `(x, y)` occupied.
    fn place(&mut self, m: &Mask, x: usize, y: usize) {
        self.update_squares(m, x, y);
        for &(r, a, b) in &m.runs {
            let row = &mut self.free[y + r as usize];
            let (a, b) = (x as u32 + a, x as u32 + b + 1);
            // The free intervals meeting [a, b) are cut; a placed footprint lies in free space
            // (the dilated mask was tested), but a cut that spans several is handled anyway.
            let i = row.partition_point(|iv| iv.1 <= a);
            let j = row.partition_point(|iv| iv.0 < b);
            if i >= j {
                continue;
            }
            let mut keep = Vec::with_capacity(2);
            if row[i].0 < a {
                keep.push((row[i].0, a));
            }
            if row[j - 1].1 > b {
                keep.push((b, row[j - 1].1));
            }
            row.splice(i..j, keep);
        }
        let mut last = usize::MAX;
        for &(r, _, _) in &m.runs {
            if r as usize != last {
                last = r as usize;
                let row = y + last;
                self.max_free[row] = self.free[row]
                    .iter()
                    .map(|iv| iv.1 - iv.0)
                    .max()
                    .unwrap_or(0);
            }
        }
        for (l, &band) in BANDS.iter().enumerate() {
            let bands = &mut self.band_free[l];
            if bands.is_empty() {
                continue;
            }
            let (top, bottom) = (y / band, ((y + m.h) / band).min(bands.len() - 1));
            for (b, v) in bands.iter_mut().enumerate().take(bottom + 1).skip(top) {
                *v = common_free(&self.free[b * band..(b + 1) * band]);
            }
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

/// A packing: where each chart went, and the number of pages.
type Packing = (Vec<Placement>, u32);

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
) -> Option<Packing> {
    use rayon::prelude::*;
    // A chart wider or taller than the page fits in none of its four turns: fail before its
    // footprint is rasterised (at a huge density, that raster alone would not fit in memory).
    let too_large = charts.iter().any(|(uv, _)| {
        let (lo, hi) = uv.iter().fold(
            (
                Vector2::repeat(f64::INFINITY),
                Vector2::repeat(f64::NEG_INFINITY),
            ),
            |(lo, hi), p| (lo.inf(p), hi.sup(p)),
        );
        let d = hi - lo;
        !(d.x.is_finite() && d.y.is_finite()) || d.x.max(d.y) > size as f64
    });
    if too_large {
        return None;
    }
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
    // A fixed density: from the option, or from the texels the charts should cover.
    let fixed = match (opts.texels_per_unit, opts.chart_texels) {
        (Some(s), _) => Some(("texel_density", s)),
        (None, Some(t)) => Some(("chart_texels", (t / area).sqrt())),
        (None, None) => None,
    };
    let mut chosen = None;
    if let Some((name, s0)) = fixed {
        if !(s0.is_finite() && s0 > 0.0) {
            return Err(crate::Error::option(
                name,
                format!("texel density {s0} must be a positive number"),
            ));
        }
        let too_large = |s: f64| {
            crate::Error::option(
                name,
                format!(
                    "a chart is larger than a {size}-texel page at {s} texels per unit: lower \
                 the texel density or raise the atlas size"
                ),
            )
        };
        let mut s = s0;
        let mut r = attempt(&scaled(s), &order, size, gutter, false);
        // A density derived from a texel count is a wish, not an order: when a chart is larger
        // than a page at it, the density goes down until the largest chart fits.
        if name == "chart_texels" {
            for _ in 0..100 {
                if r.is_some() {
                    break;
                }
                s /= 1.1;
                r = attempt(&scaled(s), &order, size, gutter, false);
            }
        }
        let mut r = r.ok_or_else(|| too_large(s))?;
        // Over a page limit above one: scale the density by the square root of the pages'
        // ratio (the charts' area goes with its square), a little more each time it misses.
        // A limit of one page is the density search below.
        let mut shrink = 0.99;
        while let Some(limit) = opts.max_pages.filter(|&m| r.1 > m && m > 1) {
            s *= (limit as f64 / r.1 as f64).sqrt().min(0.99) * shrink;
            shrink *= 0.98;
            r = attempt(&scaled(s), &order, size, gutter, false).ok_or_else(|| too_large(s))?;
        }
        if r.1 <= opts.max_pages.unwrap_or(u32::MAX) {
            chosen = Some((s, r));
        }
    }
    let (scale, (placements, pages)) = match chosen {
        Some(c) => c,
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
            // Only the last level's placements are kept; coarser levels bracket the density.
            let mut found: Option<(f64, Option<Packing>)> = None;
            for &level in &levels {
                // The least density that failed at this level: no later point above it is tried.
                let mut failed = f64::INFINITY;
                if let (Some((s, _)), true) = (&found, level > 0) {
                    // The coarser answer nearly always fits here too: assume it and bisect the
                    // window above it first. A packing that fits costs the most, so this saves
                    // the check of the coarser answer whenever a point above it fits.
                    let (mut lo, mut hi) = (*s, *s * 1.04);
                    let mut above = false;
                    while hi / lo > 1.004 {
                        let mid = (lo * hi).sqrt();
                        if at(level, mid).is_some() {
                            lo = mid;
                            above = true;
                        } else {
                            hi = mid;
                            failed = mid;
                        }
                    }
                    if above {
                        found = Some((lo, None));
                        continue;
                    }
                }
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
                    Some((s0, _)) => {
                        let mut s = s0;
                        let mut fit = None;
                        for _ in 0..200 {
                            if let Some(r) = at(level, s) {
                                fit = Some((s, r));
                                break;
                            }
                            failed = s;
                            s /= 1.01;
                        }
                        let Some((lo, best)) = fit else { break };
                        // Above an answer that fitted at once, every point was tried already.
                        let window = if level == 0 || lo == s0 { 1.0 } else { 1.04 };
                        (lo, best, (lo * window).min(failed))
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
                found = Some((lo, Some(best)));
            }
            let Some((lo, Some((placements, pages)))) = found else {
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

/// Rows of a band of [`coverage_counts`].
const COVERAGE_BAND: u32 = 128;

/// The texels of `pages` pages of `size` x `size` covered by one chart or more and by two or
/// more (overlapping), rasterising the UV triangles at texel centres; a face belongs to the
/// page of its centroid's u ([`UvMap::face_page`]). Counted in bands of rows in parallel:
/// each band sees its faces in face order and holds only its own rows' owners (a serial pass
/// over a whole-page grid held 5 bytes per texel, 335 MB at 8192, on one core).
pub fn coverage_counts(uv: &UvMap, face_chart: &[u32], size: u32, pages: u32) -> (usize, usize) {
    if size == 0 || pages == 0 {
        return (0, 0);
    }
    let n = size as f64;
    let bands_per_page = size.div_ceil(COVERAGE_BAND) as usize;
    let corners = |f: usize| {
        let page = (uv.face_page(f) as usize).min(pages as usize - 1);
        let q = uv.faces[f].map(|i| {
            let c = uv.coords[i as usize].cast::<f64>();
            Vector2::new(c.x - page as f64, c.y) * n
        });
        (page, q)
    };
    // Each face into the bands its rows may touch (a row range a little wider than the
    // rasteriser's, so that no face a band needs is missed).
    let spans: Vec<(usize, usize, usize)> = (0..uv.faces.len())
        .into_par_iter()
        .map(|f| {
            let (page, q) = corners(f);
            let lo = q[0].y.min(q[1].y).min(q[2].y);
            let hi = q[0].y.max(q[1].y).max(q[2].y);
            let clamp = |v: f64| (v.floor().max(0.0) as usize).min(size as usize - 1);
            (page, clamp(lo - 1.0), clamp(hi + 1.0))
        })
        .collect();
    let mut bands: Vec<Vec<u32>> = vec![Vec::new(); bands_per_page * pages as usize];
    for (f, &(page, y0, y1)) in spans.iter().enumerate() {
        let (b0, b1) = (y0 / COVERAGE_BAND as usize, y1 / COVERAGE_BAND as usize);
        for b in b0..=b1 {
            bands[page * bands_per_page + b].push(f as u32);
        }
    }
    drop(spans);
    bands
        .par_iter()
        .enumerate()
        .map(|(bi, faces)| {
            let (page, band) = (bi / bands_per_page, (bi % bands_per_page) as u32);
            let y0 = band * COVERAGE_BAND;
            let rows = COVERAGE_BAND.min(size - y0);
            let cells = (rows * size) as usize;
            let mut owner = vec![u32::MAX; cells];
            let mut count = vec![0u8; cells];
            for &f in faces {
                let (p, q) = corners(f as usize);
                debug_assert_eq!(p, page);
                let chart = face_chart[f as usize];
                raster_triangle(q, size, size, |x, y| {
                    if y < y0 || y >= y0 + rows {
                        return;
                    }
                    let i = ((y - y0) * size + x) as usize;
                    if owner[i] != chart {
                        count[i] = count[i].saturating_add(1);
                        owner[i] = chart;
                    }
                });
            }
            let covered = count.iter().filter(|&&c| c > 0).count();
            let overlapping = count.iter().filter(|&&c| c > 1).count();
            (covered, overlapping)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// The serial pass [`coverage_counts`] replaced, its reference: per texel of `pages`
    /// pages (page after page), how many charts cover it (0, 1, or more if charts overlap).
    fn coverage(uv: &UvMap, face_chart: &[u32], size: u32, pages: u32) -> Vec<u8> {
        let per = (size * size) as usize;
        let mut owner = vec![u32::MAX; per * pages as usize];
        let mut count = vec![0u8; per * pages as usize];
        let n = size as f64;
        for (f, t) in uv.faces.iter().enumerate() {
            let page = (uv.face_page(f) as usize).min(pages as usize - 1);
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

    #[test]
    fn coverage_counts_in_bands_equal_the_serial_pass() {
        // Random triangles over two pages of 300 texels (bands of 128 rows: three per page,
        // the last one short), many crossing band borders and overlapping each other.
        let mut rng = SplitMix64::new(11);
        let (size, pages) = (300u32, 2u32);
        let mut uv = UvMap {
            coords: Vec::new(),
            faces: Vec::new(),
        };
        let mut face_chart = Vec::new();
        for f in 0..400u32 {
            let page = (f % 2) as f64;
            let (cx, cy) = (rng.range(0.0, 1.0), rng.range(-0.05, 1.05));
            for _ in 0..3 {
                uv.coords.push(Vector2::new(
                    (page + (cx + rng.range(-0.08, 0.08)).clamp(0.01, 0.99)) as f32,
                    (cy + rng.range(-0.08, 0.08)) as f32,
                ));
            }
            uv.faces.push([3 * f, 3 * f + 1, 3 * f + 2]);
            face_chart.push(f / 3);
        }
        let cov = coverage(&uv, &face_chart, size, pages);
        let serial = (
            cov.iter().filter(|&&c| c > 0).count(),
            cov.iter().filter(|&&c| c > 1).count(),
        );
        assert!(serial.0 > 10_000 && serial.1 > 1_000, "{serial:?}");
        assert_eq!(coverage_counts(&uv, &face_chart, size, pages), serial);
    }

    /// The texel-by-texel footprint [`footprint`] fills by row runs: every texel whose square
    /// meets a triangle, by the separating-axis test on each texel.
    fn footprint_per_texel(uv: &[Vector2<f64>], faces: &[[u32; 3]], gutter: usize) -> Vec<bool> {
        let (_, w, h, offset) = footprint(uv, &[], gutter);
        let mut foot = vec![false; w * h];
        for t in faces {
            let q = t.map(|i| uv[i as usize] + offset);
            let (area, edges) = edge_tests(&q);
            let a = q[0].inf(&q[1]).inf(&q[2]);
            let b = q[0].sup(&q[1]).sup(&q[2]);
            for y in a.y.floor().max(0.0) as usize..=(b.y.floor() as usize).min(h - 1) {
                for x in a.x.floor().max(0.0) as usize..=(b.x.floor() as usize).min(w - 1) {
                    let c = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
                    if area == 0.0 || edges.iter().all(|(p, n, r)| n.dot(&(c - p)) + r >= 0.0) {
                        foot[y * w + x] = true;
                    }
                }
            }
        }
        foot
    }

    /// Footprints by row runs are the per-texel test's, texel for texel: triangles of every
    /// size from a tenth of a texel to forty, slivers, degenerate ones and ones on texel
    /// edges included.
    #[test]
    fn footprints_by_row_runs_are_the_per_texel_test() {
        let mut rng = SplitMix64::new(5);
        for case in 0..40 {
            let scale = [0.1, 0.7, 3.0, 12.0, 40.0][case % 5];
            let mut uv = Vec::new();
            let mut faces = Vec::new();
            for f in 0..60u32 {
                let c = Vector2::new(rng.range(0.0, 80.0), rng.range(0.0, 80.0));
                let mut p: Vec<Vector2<f64>> = (0..3)
                    .map(|_| c + Vector2::new(rng.range(-scale, scale), rng.range(-scale, scale)))
                    .collect();
                match f % 6 {
                    // A sliver: the third corner almost on the first edge.
                    0 => p[2] = p[0] + (p[1] - p[0]) * 0.37 + Vector2::new(1e-7, -1e-7),
                    // Degenerate: a repeated corner.
                    1 => p[2] = p[0],
                    // Corners on texel edges and centres.
                    2 => p
                        .iter_mut()
                        .for_each(|q| *q = q.map(|v| (v * 2.0).round() / 2.0)),
                    _ => {}
                }
                uv.extend(p);
                faces.push([3 * f, 3 * f + 1, 3 * f + 2]);
            }
            let gutter = case % 3;
            let (foot, ..) = footprint(&uv, &faces, gutter);
            assert_eq!(
                foot,
                footprint_per_texel(&uv, &faces, gutter),
                "case {case}"
            );
            assert!(foot.iter().any(|&b| b));
        }
    }

    /// The first position (row-major) where every texel of the mask's dilated spans is free
    /// and the mask's box lies in the page, found texel by texel on a plain grid.
    fn first_fit(occ: &[bool], n: usize, m: &Mask) -> Option<(usize, usize)> {
        if m.w > n || m.h > n {
            return None;
        }
        (0..=n - m.h)
            .flat_map(|y| (0..=n - m.w).map(move |x| (x, y)))
            .find(|&(x, y)| {
                m.spans.iter().enumerate().all(|(r, s)| {
                    s.is_none_or(|(a, b)| {
                        (a as usize..=b as usize).all(|c| !occ[(y + r) * n + x + c])
                    })
                })
            })
    }

    /// A random blob: a footprint grown from its centre, so that rows have holes and bays.
    fn blob(rng: &mut SplitMix64, gutter: usize) -> (Vec<bool>, usize, usize) {
        let (w, h) = (
            2 * gutter + 1 + (rng.next_u64() % 14) as usize,
            2 * gutter + 1 + (rng.next_u64() % 14) as usize,
        );
        let mut foot = vec![false; w * h];
        let (mut x, mut y) = (w / 2, h / 2);
        for _ in 0..(w * h) {
            foot[y * w + x] = true;
            match rng.next_u64() % 4 {
                0 if x > gutter => x -= 1,
                1 if x + gutter + 1 < w => x += 1,
                2 if y > gutter => y -= 1,
                3 if y + gutter + 1 < h => y += 1,
                _ => {}
            }
        }
        (foot, w, h)
    }

    /// The page's square map against one computed from scratch on the texel grid: a block is
    /// free when all its texels are, and each block holds the side of the largest square of
    /// free blocks below and right of it (capped).
    fn assert_squares(page: &Page, occ: &[bool], n: usize) {
        let (b, nb) = (page.block, page.blocks);
        let free = |bx: usize, by: usize| {
            (by * b..(by + 1) * b).all(|y| (bx * b..(bx + 1) * b).all(|x| !occ[y * n + x]))
        };
        for by in 0..nb {
            for bx in 0..nb {
                let mut side = 0;
                while side < SQUARE_CAP
                    && bx + side < nb
                    && by + side < nb
                    && (0..=side).all(|k| free(bx + side, by + k) && free(bx + k, by + side))
                {
                    side += 1;
                }
                assert_eq!(
                    page.square[by * nb + bx] as usize,
                    side,
                    "block ({bx}, {by})"
                );
            }
            let row = &page.square[by * nb..(by + 1) * nb];
            assert_eq!(page.square_row[by], row.iter().copied().max().unwrap_or(0));
            let groups = nb.div_ceil(SQUARE_GROUP);
            for (g, part) in row.chunks(SQUARE_GROUP).enumerate() {
                let want = part.iter().copied().max().unwrap_or(0);
                assert_eq!(
                    page.square_group[by * groups + g],
                    want,
                    "group {g} of row {by}"
                );
            }
        }
        for (k, &f) in page.first_row.iter().enumerate() {
            let want = (0..nb).find(|&by| page.square_row[by] as usize >= k);
            assert_eq!(f, want.unwrap_or(nb), "first row with a square of {k}");
        }
    }

    #[test]
    fn inscribed_square_is_the_largest_square_inside_the_spans() {
        let mut rng = SplitMix64::new(11);
        for _ in 0..300 {
            let (foot, w, h) = blob(&mut rng, 1);
            let m = mask(&foot, w, h, Vector2::zeros(), (rng.next_u64() % 4) as u8, 1);
            let inside = |r: usize, c: usize, s: usize| {
                r + s <= m.h
                    && (r..r + s).all(|y| {
                        m.spans[y].is_some_and(|(a, b)| a as usize <= c && c + s <= b as usize + 1)
                    })
            };
            for &(r, c, s) in &m.squares {
                assert!(
                    s >= 1 && inside(r, c, s),
                    "{:?} in {:?}",
                    m.squares,
                    m.spans
                );
            }
            let (_, _, s) = m.squares[0];
            let larger = (0..m.h).any(|r| (0..m.w).any(|c| inside(r, c, s + 1)));
            assert!(!larger, "a square of {} fits {:?}", s + 1, m.spans);
        }
    }

    #[test]
    fn interval_page_finds_the_same_first_fit_as_a_texel_grid() {
        // Every find is checked against the texel-by-texel search on a grid that the same
        // placements filled: the intervals, the move-to-front row order and the band
        // summaries may only make the search faster, never change where a chart goes.
        let mut rng = SplitMix64::new(7);
        for (n, gutter, block) in [
            (48usize, 1usize, 1usize),
            (64, 2, 1),
            (80, 0, 1),
            (66, 1, 2),
            (81, 2, 3),
        ] {
            let mut page = Page::with_block(n, block);
            let mut occ = vec![false; n * n];
            assert_squares(&page, &occ, n);
            let (mut placed, mut full) = (0, 0);
            for _ in 0..400 {
                let (foot, w, h) = blob(&mut rng, gutter);
                let rot = (rng.next_u64() % 4) as u8;
                let m = mask(&foot, w, h, Vector2::zeros(), rot, gutter);
                let want = first_fit(&occ, n, &m);
                let got = page.find(&m, &AtomicUsize::new(usize::MAX));
                assert_eq!(got, want, "page {n}, mask {}x{} turned {rot}", m.w, m.h);
                let Some((x, y)) = got else {
                    full += 1;
                    continue;
                };
                // The footprint is inside its dilated spans, so it lands on free texels only.
                for &(r, a, b) in &m.runs {
                    for c in a..=b {
                        let i = (y + r as usize) * n + x + c as usize;
                        assert!(!occ[i]);
                        occ[i] = true;
                    }
                }
                page.place(&m, x, y);
                placed += 1;
                assert_squares(&page, &occ, n);
            }
            // Both outcomes were exercised: the page filled up.
            assert!(placed > 10 && full > 10, "placed {placed}, refused {full}");
            for y in 0..n {
                let free: usize = page.free[y].iter().map(|iv| (iv.1 - iv.0) as usize).sum();
                let want = occ[y * n..(y + 1) * n].iter().filter(|&&o| !o).count();
                assert_eq!(free, want, "row {y} of page {n}");
            }
        }
    }
}
