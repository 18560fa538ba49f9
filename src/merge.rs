//! Stage 4, merging (paper section 4.2, `docs/method.md` section 4): the photographs'
//! resampled layers combined into one atlas without seams. In: the mesh with its atlas, the
//! [`Binding`] (with its gains), the photographs. Out: [`Resampled`] (atlas colour, texel
//! sources, best photograph per texel).
//!
//! [`Merge::Multiband`] is Burt and Adelson's multiresolution spline: every photograph's layer
//! is split into Laplacian bands, each band is the mask-weighted mean of the photographs'
//! bands with the masks reduced to that band's level, and one more layer, the vertex-colour
//! texture under the complement of the masks' union, fills what no mask covers (those texels
//! are also the ones restoration must fill). Chart-aware: every chart is its own image (its
//! bounding rectangle), texels outside the chart and texels a photograph does not see are
//! given smooth values by push-pull before the pyramid is built, so no level mixes colour
//! across charts or pulls in empty gutter. Photographs are processed one at a time; memory is
//! the charts' band accumulators (about 18 bytes per texel of chart rectangles with best-view
//! masks, 28 with the others), whatever the number of photographs.

use crate::bind::{for_each_photo, Binding};
use crate::error::{Error, Result};
use crate::level;
use crate::mesh::Mesh;
use crate::progress::Progress;
use crate::pyramid::{self, Plane};
use crate::resample::{
    check_photo_count, resample, PhotoSampler, Prepared, ResampleOptions, Resampled, TexelSource,
    NO_PHOTO,
};
use crate::scene::Photo;
use half::f16;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};

/// How the photographs seen at a texel become its colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Merge {
    /// The photograph with the largest weight, alone (seams where it changes).
    None,
    /// The weighted mean of every photograph that sees the texel (stage 3 as is).
    Average,
    /// Multiresolution spline (default).
    Multiband,
}

impl std::str::FromStr for Merge {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "none" => Ok(Merge::None),
            "average" => Ok(Merge::Average),
            "multiband" => Ok(Merge::Multiband),
            _ => Err(Error::Invalid(format!(
                "unknown merge '{s}' (expected none, average or multiband)"
            ))),
        }
    }
}

/// The photographs' masks for [`Merge::Multiband`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Masks {
    /// The paper's: a photograph's mask is 1 on the triangles whose three vertices it sees,
    /// minus the outermost ring of triangles of that region; overlapping masks average.
    Paper,
    /// Every texel a photograph sees, weighted by its view weight relative to the face's best
    /// (so a grazing view counts little in every band).
    Weighted,
    /// As `Weighted` for every band but the finest, which comes from the photograph with the
    /// largest weight alone: coarse bands blend, fine detail is never averaged across
    /// slightly misregistered photographs (default).
    BestView,
}

impl std::str::FromStr for Masks {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "paper" => Ok(Masks::Paper),
            "weighted" => Ok(Masks::Weighted),
            "best-view" => Ok(Masks::BestView),
            _ => Err(Error::Invalid(format!(
                "unknown masks '{s}' (expected paper, weighted or best-view)"
            ))),
        }
    }
}

/// Options for [`merge`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MergeOptions {
    /// Default: [`Merge::Multiband`].
    pub merge: Merge,
    /// Default: [`Masks::BestView`].
    pub masks: Masks,
    /// Most pyramid levels (reductions) per chart; a chart gets `log2(its longer side) - 3`
    /// up to this (a 32-texel chart 2, a 512-texel one 6). Default: 2: with the exposure and
    /// lighting solve in front, deeper levels lower held-out PSNR on the corset (26.99 dB at
    /// 2, 26.67 at 6) and raise both seam ratios (`docs/decisions.md`,
    /// `benches/merge_compare.py`).
    pub levels: u32,
    /// Centre weight of the 5-tap generating kernel. Default: 0.4 (the paper's; OpenCV's is
    /// 0.375).
    pub a: f32,
    /// Level chart borders after blending ([`crate::level`]; multiband only). Default: true.
    pub level_seams: bool,
}

impl Default for MergeOptions {
    fn default() -> Self {
        MergeOptions {
            merge: Merge::Multiband,
            masks: Masks::BestView,
            levels: 2,
            a: 0.4,
            level_seams: true,
        }
    }
}

impl MergeOptions {
    /// Checks the ranges; the error names the option.
    pub fn validate(&self) -> Result<()> {
        if self.levels > 12 {
            return Err(Error::Invalid(format!(
                "merge levels = {} must lie in 0..=12",
                self.levels
            )));
        }
        if !(0.2..=0.5).contains(&self.a) {
            return Err(Error::Invalid(format!(
                "kernel weight a = {} must lie in [0.2, 0.5] (the kernel must stay positive)",
                self.a
            )));
        }
        Ok(())
    }
}

/// One chart's image: its faces and bounding rectangle in the atlas.
struct Chart {
    faces: Vec<u32>,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    levels: usize,
}

/// Charts as UV islands (faces joined through shared texture-coordinate indices), so that
/// atlases from other tools work too. Also returns each face's chart (`u32::MAX` off the page).
fn find_charts(prep: &Prepared, mesh: &Mesh, max_levels: u32) -> (Vec<Chart>, Vec<u32>) {
    let uv = mesh.uv.as_ref().expect("Prepared checked the UVs");
    let mut parent: Vec<u32> = (0..uv.coords.len() as u32).collect();
    fn find(p: &mut [u32], mut i: u32) -> u32 {
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }
    for c in &uv.faces {
        for k in 1..3 {
            let (a, b) = (find(&mut parent, c[0]), find(&mut parent, c[k]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut index_of_root = vec![u32::MAX; uv.coords.len()];
    let mut charts: Vec<Chart> = Vec::new();
    let mut face_chart = vec![u32::MAX; mesh.num_faces()];
    for (f, slot) in face_chart.iter_mut().enumerate() {
        let Some(((r0, r1), (c0, c1))) = prep.face_rect(f) else {
            continue;
        };
        let root = find(&mut parent, uv.faces[f][0]) as usize;
        if index_of_root[root] == u32::MAX {
            index_of_root[root] = charts.len() as u32;
            charts.push(Chart {
                faces: Vec::new(),
                x0: c0,
                y0: r0,
                w: c1 + 1,
                h: r1 + 1,
                levels: 0,
            });
        }
        let ci = index_of_root[root];
        *slot = ci;
        let ch = &mut charts[ci as usize];
        ch.faces.push(f as u32);
        // w and h hold the exclusive right and bottom edges until the end.
        ch.x0 = ch.x0.min(c0);
        ch.y0 = ch.y0.min(r0);
        ch.w = ch.w.max(c1 + 1);
        ch.h = ch.h.max(r1 + 1);
    }
    for ch in &mut charts {
        ch.w -= ch.x0;
        ch.h -= ch.y0;
        let side = ch.w.max(ch.h).max(1) as f64;
        ch.levels = (side.log2().floor() as i64 - 3).clamp(0, max_levels as i64) as usize;
    }
    (charts, face_chart)
}

/// Per vertex, the photographs valid at it and at all its neighbours (sorted): a face is in a
/// photograph's shrunk mask when its three vertices have it here (the region's outermost ring
/// of triangles touches a vertex with an invalid neighbour).
fn ring_valid(mesh: &Mesh, b: &Binding) -> Vec<Vec<u32>> {
    let nv = mesh.num_vertices();
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for f in &mesh.faces {
        for k in 0..3 {
            let (a, c) = (f[k].0, f[(k + 1) % 3].0);
            nbr[a as usize].push(c);
            nbr[c as usize].push(a);
        }
    }
    (0..nv)
        .into_par_iter()
        .map(|v| {
            let mut own: Vec<u32> = b.views(v).iter().map(|s| s.photo).collect();
            own.sort_unstable();
            own.retain(|p| {
                nbr[v]
                    .iter()
                    .all(|&u| b.views(u as usize).iter().any(|s| s.photo == *p))
            });
            own
        })
        .collect()
}

/// Side of the tiles [`ChartAcc::add`] splits large layers into, texels.
const TILE: usize = 1024;

/// A tile: its region (x0, y0, x1, y1) and its core in region coordinates.
type Tile = ((usize, usize, usize, usize), (usize, usize, usize, usize));

/// The tiles [`ChartAcc::add`] splits a `w` x `h` layer into: cores of `tile` texels (rounded
/// to the coarsest grid) covering the layer once, regions widened by 8 coarsest-level texels,
/// beyond the reach of the reductions and expansions. One tile when the layer is small.
fn tiles(w: usize, h: usize, levels: usize, tile: usize) -> Vec<Tile> {
    let step = 1usize << levels;
    let tile = tile.div_ceil(step) * step;
    let margin = 8 * step;
    if w <= tile + 2 * margin && h <= tile + 2 * margin {
        return vec![((0, 0, w, h), (0, 0, w, h))];
    }
    let mut out = Vec::new();
    for ty in (0..h).step_by(tile) {
        for tx in (0..w).step_by(tile) {
            let (rx0, ry0) = (tx.saturating_sub(margin), ty.saturating_sub(margin));
            let (rx1, ry1) = ((tx + tile + margin).min(w), (ty + tile + margin).min(h));
            let core = (
                tx - rx0,
                ty - ry0,
                (tx + tile).min(w) - rx0,
                (ty + tile).min(h) - ry0,
            );
            out.push(((rx0, ry0, rx1, ry1), core));
        }
    }
    out
}

/// A chart's band accumulators.
struct ChartAcc {
    /// Per level: mask-weighted band sums (3 channels); for [`Masks::BestView`] level 0 is
    /// empty (see `finest`).
    num: Vec<Plane>,
    /// Per level: mask sums (level 0 empty for [`Masks::BestView`]).
    den: Vec<Vec<f32>>,
    /// [`Masks::BestView`]: the best photograph's finest band, in half precision (an error
    /// under 5e-4 for bands within +-1, below half a step of 8-bit output), NaN where no
    /// layer has won yet. At 8192 this and the dropped level-0 mask sums save 10 bytes per
    /// chart texel, about 0.5 GB.
    finest: Vec<[f16; 3]>,
    /// [`TILE`] (smaller in tests).
    tile: usize,
    /// Largest view weight so far and its photograph, photographs seen, per texel.
    best_w: Vec<f32>,
    best: Vec<u16>,
    views: Vec<u8>,
    /// [`Masks::Paper`]: the weighted mean of the photographs (stage 3's texture), which the
    /// complement of the masks carries.
    avg: Option<Vec<[f32; 4]>>,
}

impl ChartAcc {
    fn new(ch: &Chart, paper: bool, winner_mode: bool) -> Self {
        let mut num = Vec::new();
        let mut den = Vec::new();
        let (mut w, mut h) = (ch.w, ch.h);
        for l in 0..=ch.levels {
            if l == 0 && winner_mode {
                num.push(Plane {
                    w,
                    h,
                    c: 3,
                    d: Vec::new(),
                });
                den.push(Vec::new());
            } else {
                num.push(Plane::zeros(w, h, 3));
                den.push(vec![0f32; w * h]);
            }
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
        }
        let n = ch.w * ch.h;
        ChartAcc {
            num,
            den,
            finest: if winner_mode {
                vec![[f16::NAN; 3]; n]
            } else {
                Vec::new()
            },
            tile: TILE,
            best_w: vec![0.0; n],
            best: vec![NO_PHOTO; n],
            views: vec![0; n],
            avg: paper.then(|| vec![[0.0; 4]; n]),
        }
    }

    /// Adds a layer known where `valid` is positive under `mask` (zero wherever `valid` is);
    /// `finest` gives, for [`Masks::BestView`], the texels where this layer's finest band
    /// wins. The layer covers the chart's texels from (`ox`, `oy`), both multiples of
    /// `2^levels` so that every level's grid lines up with the chart's.
    ///
    /// The layer's pyramid is a normalised-convolution one: every level is the reduced
    /// `valid`-weighted colour over the reduced `valid`, and every band is a level minus the
    /// likewise normalised expansion of the next. Unknown texels thus never enter a band, and
    /// no separate hole filling is needed (the mask's support lies inside `valid`'s at every
    /// level, the kernel being positive).
    ///
    /// Large layers are processed in tiles of [`TILE`] texels (plus a margin the pyramid's
    /// reductions and expansions cannot see across), each adding only its core: the same
    /// values, with transient memory bounded by the tile instead of the chart (one chart of
    /// the 8192 speed scene spans 16.5M texels, and its pyramid took 1.1 GB).
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        layer: &Plane,
        valid: &[f32],
        mask: Vec<f32>,
        (ox, oy): (usize, usize),
        levels: usize,
        a: f32,
        finest: &[bool],
    ) {
        let (w, h) = (layer.w, layer.h);
        let tiles = tiles(w, h, levels, self.tile);
        if tiles.len() == 1 {
            self.add_region(layer, valid, mask, (ox, oy), tiles[0].1, levels, a, finest);
            return;
        }
        for ((rx0, ry0, rx1, ry1), core) in tiles {
            let (rw, rh) = (rx1 - rx0, ry1 - ry0);
            let idx = |x: usize, y: usize| (ry0 + y) * w + rx0 + x;
            let mut tm = Vec::with_capacity(rw * rh);
            let mut tv = Vec::with_capacity(rw * rh);
            let mut tf = Vec::with_capacity(if finest.is_empty() { 0 } else { rw * rh });
            let mut tl = Vec::with_capacity(rw * rh * 3);
            for y in 0..rh {
                for x in 0..rw {
                    let i = idx(x, y);
                    tm.push(mask[i]);
                    tv.push(valid[i]);
                    tl.extend_from_slice(&layer.d[3 * i..3 * i + 3]);
                    if !finest.is_empty() {
                        tf.push(finest[i]);
                    }
                }
            }
            if !tm.iter().any(|&m| m > 0.0) && !tf.iter().any(|&f| f) {
                continue;
            }
            let tl = Plane::from_vec(rw, rh, 3, tl).expect("sized");
            self.add_region(&tl, &tv, tm, (ox + rx0, oy + ry0), core, levels, a, &tf);
        }
    }

    /// [`ChartAcc::add`] on one region (origin (`ox`, `oy`) in the chart, aligned to the
    /// coarsest grid), adding only the texels whose full-resolution position lies in `core`
    /// (x0, y0, x1, y1, region coordinates; x0 and y0 on the coarsest grid).
    #[allow(clippy::too_many_arguments)]
    fn add_region(
        &mut self,
        layer: &Plane,
        valid: &[f32],
        mask: Vec<f32>,
        (ox, oy): (usize, usize),
        core: (usize, usize, usize, usize),
        levels: usize,
        a: f32,
        finest: &[bool],
    ) {
        let (w, h) = (layer.w, layer.h);
        let mut pm = Plane::zeros(w, h, 4);
        for (i, &v) in valid.iter().enumerate() {
            if v > 0.0 {
                for k in 0..3 {
                    pm.d[4 * i + k] = v * layer.d[3 * i + k];
                }
                pm.d[4 * i + 3] = v;
            }
        }
        let g = pyramid::gaussian(pm, levels, a);
        let masks = pyramid::gaussian(Plane::from_vec(w, h, 1, mask).expect("sized"), levels, a);
        let winner_mode = !finest.is_empty();
        const EPS: f32 = 1e-12;
        for l in 0..=levels {
            let (gl, m) = (&g[l], &masks[l]);
            let up = (l < levels).then(|| pyramid::expand(&g[l + 1], gl.w, gl.h, a));
            let cw = self.num[l].w;
            let (lx, ly) = (ox >> l, oy >> l);
            let num = &mut self.num[l].d;
            let den = &mut self.den[l];
            let best = &mut self.finest;
            let (cx0, cy0) = (core.0 >> l, core.1 >> l);
            let (cx1, cy1) = (
                core.2.div_ceil(1 << l).min(m.w),
                core.3.div_ceil(1 << l).min(m.h),
            );
            for y in cy0..cy1 {
                for x in cx0..cx1 {
                    let i = y * m.w + x;
                    let mw = m.d[i];
                    let fin = l == 0 && winner_mode && finest[i];
                    if mw <= 0.0 && !fin {
                        continue;
                    }
                    let wg = gl.d[4 * i + 3];
                    if wg <= EPS {
                        continue;
                    }
                    let mut band: [f32; 3] = std::array::from_fn(|k| gl.d[4 * i + k] / wg);
                    if let Some(u) = &up {
                        let wu = u.d[4 * i + 3];
                        if wu > EPS {
                            for (k, b) in band.iter_mut().enumerate() {
                                *b -= u.d[4 * i + k] / wu;
                            }
                        }
                    }
                    let gi = (ly + y) * cw + lx + x;
                    if fin {
                        best[gi] = band.map(f16::from_f32);
                    }
                    if mw <= 0.0 || (l == 0 && winner_mode) {
                        continue;
                    }
                    den[gi] += mw;
                    for k in 0..3 {
                        num[3 * gi + k] += mw * band[k];
                    }
                }
            }
        }
    }

    /// The blended chart image; the band sums are freed, the per-texel bookkeeping stays.
    fn collapse(&mut self, a: f32, winner_mode: bool) -> Plane {
        let top = self.num.len() - 1;
        for l in 0..=top {
            if l == 0 && winner_mode {
                continue;
            }
            let (num, den) = (&mut self.num[l], &self.den[l]);
            for (i, &d) in den.iter().enumerate() {
                for k in 0..3 {
                    let v = &mut num.d[3 * i + k];
                    *v = if d > 1e-6 { *v / d } else { 0.0 };
                }
            }
        }
        if winner_mode && top == 0 {
            // A chart too small for a pyramid: its one level is the winners' colours, known
            // where some layer won.
            let (w, h) = (self.num[0].w, self.num[0].h);
            let finest = std::mem::take(&mut self.finest);
            self.den[0] = finest.iter().map(|b| f32::from(!b[0].is_nan())).collect();
            let d: Vec<f32> = finest
                .iter()
                .flat_map(|b| b.map(|v| if v.is_nan() { 0.0 } else { v.to_f32() }))
                .collect();
            self.num[0] = Plane::from_vec(w, h, 3, d).expect("sized");
        }
        // The coarsest level is a colour, not a band: where no mask reaches it, extend the
        // colours around rather than expand zeros into the chart's border.
        let weights: Vec<f32> = self.den[top].iter().map(|&d| f32::from(d > 1e-6)).collect();
        pyramid::fill_holes(&mut self.num[top], &weights, a);
        self.den = Vec::new();
        if winner_mode && top > 0 {
            // Collapse the coarser levels, expand, and add the half-precision finest band
            // in place (no full-precision copy of it: 12 bytes per texel less at the peak).
            let (w, h) = (self.num[0].w, self.num[0].h);
            let coarse = pyramid::collapse(self.num.split_off(1), a);
            self.num = Vec::new();
            let mut up = pyramid::expand(&coarse, w, h, a);
            drop(coarse);
            for (v, b) in up.d.chunks_mut(3).zip(std::mem::take(&mut self.finest)) {
                for k in 0..3 {
                    if !b[k].is_nan() {
                        v[k] += b[k].to_f32();
                    }
                }
            }
            return up;
        }
        pyramid::collapse(std::mem::take(&mut self.num), a)
    }
}

/// Stage 4: the photographs resampled into a `size` x `size` atlas and merged as `mopts`
/// says. `normals` are unit vertex normals of `mesh`; the binding carries the gains.
#[allow(clippy::too_many_arguments)]
pub fn merge(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    binding: &Binding,
    photos: &[Photo],
    size: u32,
    ropts: &ResampleOptions,
    mopts: &MergeOptions,
    progress: &dyn Progress,
) -> Result<Resampled> {
    mopts.validate()?;
    match mopts.merge {
        Merge::None => resample(mesh, normals, binding, photos, size, ropts, true, progress),
        Merge::Average => resample(mesh, normals, binding, photos, size, ropts, false, progress),
        Merge::Multiband => multiband(mesh, normals, binding, photos, size, ropts, mopts, progress),
    }
}

#[allow(clippy::too_many_arguments)]
fn multiband(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    binding: &Binding,
    photos: &[Photo],
    size: u32,
    ropts: &ResampleOptions,
    mopts: &MergeOptions,
    progress: &dyn Progress,
) -> Result<Resampled> {
    let prep = Prepared::new(mesh, normals, binding, size, ropts)?;
    check_photo_count(photos.len())?;
    let n = prep.size();
    let a = mopts.a;
    let paper = mopts.masks == Masks::Paper;
    let winner_mode = mopts.masks == Masks::BestView;
    let (charts, face_chart) = find_charts(&prep, mesh, mopts.levels);
    let ring = paper.then(|| ring_valid(mesh, binding));
    // A face's reference weight: its best photograph's mean vertex weight, so relative masks
    // are about 1 for the best view whatever the units of the weights.
    let face_ref: Vec<f32> = (0..mesh.num_faces())
        .into_par_iter()
        .map(|f| {
            let fv = mesh.faces[f];
            let mut best = 0f32;
            for &p in prep.common.of(f) {
                let s: f32 = fv
                    .iter()
                    .map(|v| {
                        binding
                            .views(v.idx())
                            .iter()
                            .find(|s| s.photo == p)
                            .map_or(0.0, |s| s.weight)
                    })
                    .sum();
                best = best.max(s / 3.0);
            }
            best
        })
        .collect();
    let mut accs: Vec<ChartAcc> = charts
        .par_iter()
        .map(|ch| ChartAcc::new(ch, paper, winner_mode))
        .collect();
    let (mut seconds_setup, mut seconds_charts) = (0.0, 0.0);
    let cpu_sampling = AtomicU64::new(0);
    progress.start("merging", photos.len() as u64);
    for_each_photo(photos, progress, |pi, rgb, mask| {
        let t = std::time::Instant::now();
        let ph = prep.photo(photos, pi, rgb, mask);
        seconds_setup += t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        accs.par_iter_mut()
            .zip(charts.par_iter())
            .for_each(|(acc, ch)| {
                add_photo(
                    &prep,
                    &ph,
                    ch,
                    acc,
                    ring.as_deref(),
                    &face_ref,
                    mopts,
                    &cpu_sampling,
                )
            });
        seconds_charts += t.elapsed().as_secs_f64();
        Ok(())
    })?;
    progress.finish();
    // The complement layer, then collapse, a batch of charts at a time so that finished
    // charts' accumulators are freed as the atlas fills.
    let mut color = vec![0f32; n * n * 3];
    let mut source = vec![TexelSource::Empty as u8; n * n];
    let mut views = vec![0u8; n * n];
    let mut best = vec![NO_PHOTO; n * n];
    let mut accs: Vec<Option<ChartAcc>> = accs.into_iter().map(Some).collect();
    let batch = 64;
    for start in (0..charts.len()).step_by(batch) {
        let end = (start + batch).min(charts.len());
        let done: Vec<(Plane, ChartAcc)> = accs[start..end]
            .par_iter_mut()
            .zip(&charts[start..end])
            .enumerate()
            .map(|(j, (acc, ch))| {
                let mut acc = acc.take().expect("each chart once");
                let ci = (start + j) as u32;
                add_complement(&prep, ch, ci, &face_chart, &mut acc, a, winner_mode);
                (acc.collapse(a, winner_mode), acc)
            })
            .collect();
        for ((img, acc), (j, ch)) in done.into_iter().zip(charts[start..end].iter().enumerate()) {
            let ci = (start + j) as u32;
            for y in 0..ch.h {
                for x in 0..ch.w {
                    let (gx, gy) = (ch.x0 + x, ch.y0 + y);
                    let gi = gy * n + gx;
                    let Some(f) = prep.owner(gi) else {
                        continue;
                    };
                    if face_chart[f as usize] != ci {
                        continue;
                    }
                    let li = y * ch.w + x;
                    color[3 * gi..3 * gi + 3].copy_from_slice(&img.d[3 * li..3 * li + 3]);
                    views[gi] = acc.views[li];
                    best[gi] = acc.best[li];
                    source[gi] = if acc.best_w[li] > 0.0 {
                        TexelSource::Photos as u8
                    } else {
                        prep.fallback_source(f) as u8
                    };
                }
            }
        }
    }
    let t = std::time::Instant::now();
    let levelling = mopts.level_seams.then(|| {
        let owner = |i: usize| prep.owner(i);
        let mut st =
            level::level_seams(mesh, n, &owner, &face_chart, &mut color, level::SMOOTHNESS);
        st.seconds = t.elapsed().as_secs_f64();
        st
    });
    let mut out = prep.finish(
        color,
        source,
        views,
        best,
        ropts,
        (seconds_setup, seconds_charts),
    );
    out.stats.cpu_seconds_sampling = cpu_sampling.load(Ordering::Relaxed) as f64 * 1e-9;
    out.stats.seam_levelling = levelling;
    Ok(out)
}

/// Photograph `ph`'s layer on chart `ch`: sampled, holes filled, split into bands and added
/// under its mask.
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
fn add_photo(
    prep: &Prepared,
    ph: &PhotoSampler,
    ch: &Chart,
    acc: &mut ChartAcc,
    ring: Option<&[Vec<u32>]>,
    face_ref: &[f32],
    mopts: &MergeOptions,
    cpu_sampling: &AtomicU64,
) {
    let photo = ph.index as u32;
    if !ch.faces.iter().any(|&f| prep.samples(f as usize, photo)) {
        return;
    }
    let t = std::time::Instant::now();
    // Only the part of the chart near what the photograph sees: its faces' rectangle, padded
    // by the coarsest level's reach (beyond it the mask is zero at every level) and aligned to
    // that level's grid.
    let (mut bx0, mut by0, mut bx1, mut by1) = (usize::MAX, usize::MAX, 0, 0);
    for &f in &ch.faces {
        if prep.samples(f as usize, photo) {
            let ((r0, r1), (c0, c1)) = prep.face_rect(f as usize).expect("chart faces rasterise");
            (bx0, by0) = (bx0.min(c0 - ch.x0), by0.min(r0 - ch.y0));
            (bx1, by1) = (bx1.max(c1 + 1 - ch.x0), by1.max(r1 + 1 - ch.y0));
        }
    }
    let step = 1usize << ch.levels;
    let pad = 4 * step;
    let ox = bx0.saturating_sub(pad) / step * step;
    let oy = by0.saturating_sub(pad) / step * step;
    let (w, h) = ((bx1 + pad).min(ch.w) - ox, (by1 + pad).min(ch.h) - oy);
    let (cx, cy) = (ch.x0 + ox, ch.y0 + oy);
    let mut layer = Plane::zeros(w, h, 3);
    let mut valid = vec![0f32; w * h];
    let mut mask = vec![0f32; w * h];
    let mut weight = vec![0f32; w * h];
    let n = prep.size();
    for &f in &ch.faces {
        if !prep.samples(f as usize, photo) {
            continue;
        }
        let in_mask = match ring {
            Some(r) => prep.mesh.faces[f as usize]
                .iter()
                .all(|v| r[v.idx()].binary_search(&photo).is_ok()),
            None => true,
        };
        let reference = face_ref[f as usize];
        prep.sample_face(ph, f, 0, n, |x, y, c, wt| {
            let i = (y - cy) * w + (x - cx);
            layer.d[3 * i..3 * i + 3].copy_from_slice(&c);
            valid[i] = 1.0;
            weight[i] = wt;
            mask[i] = match mopts.masks {
                Masks::Paper => f32::from(in_mask),
                _ if reference > 0.0 => (wt / reference).min(1.0),
                _ => 1.0,
            };
        });
    }
    cpu_sampling.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
    let winner_mode = mopts.masks == Masks::BestView;
    let mut finest = if winner_mode {
        vec![false; w * h]
    } else {
        Vec::new()
    };
    let mut any = false;
    for i in 0..w * h {
        if valid[i] == 0.0 {
            continue;
        }
        any = true;
        // The chart-wide bookkeeping index.
        let i_local = i;
        let i = (oy + i / w) * ch.w + ox + i % w;
        acc.views[i] = acc.views[i].saturating_add(1);
        if weight[i_local] > acc.best_w[i] {
            // Photographs come in order, so ties keep the first: deterministic.
            acc.best_w[i] = weight[i_local];
            acc.best[i] = photo as u16;
            if winner_mode {
                finest[i_local] = true;
            }
        }
        if let Some(avg) = &mut acc.avg {
            for k in 0..3 {
                avg[i][k] += weight[i_local] * layer.d[3 * i_local + k];
            }
            avg[i][3] += weight[i_local];
        }
    }
    if !any || !mask.iter().any(|&m| m > 0.0) {
        return;
    }
    acc.add(&layer, &valid, mask, (ox, oy), ch.levels, mopts.a, &finest);
}

/// The complement of the photographs' masks, carrying the vertex-colour texture (the paper's
/// mask), or with paper masks stage 3's texture where photographs saw the texel.
fn add_complement(
    prep: &Prepared,
    ch: &Chart,
    ci: u32,
    face_chart: &[u32],
    acc: &mut ChartAcc,
    a: f32,
    winner_mode: bool,
) {
    let n = prep.size();
    let levels = acc.num.len() - 1;
    // No photograph's mask covers the texel (best-view masks are positive exactly where a
    // view weight is). Decided before any tile adds to the level-0 sums.
    let uncovered: Vec<bool> = if winner_mode {
        acc.best_w.iter().map(|&b| b <= 0.0).collect()
    } else {
        acc.den[0].iter().map(|&d| d <= 0.0).collect()
    };
    // Tile by tile, as [`ChartAcc::add`] would split the whole chart's layer, without ever
    // holding that layer (the largest chart of the 8192 speed scene spans 16.5M texels).
    for ((rx0, ry0, rx1, ry1), core) in tiles(ch.w, ch.h, levels, acc.tile) {
        let (w, h) = (rx1 - rx0, ry1 - ry0);
        let mut layer = Plane::zeros(w, h, 3);
        let mut inside = vec![0f32; w * h];
        let mut mask = vec![0f32; w * h];
        let mut finest = if winner_mode {
            vec![false; w * h]
        } else {
            Vec::new()
        };
        let mut any = false;
        for y in 0..h {
            for x in 0..w {
                let (cx, cy) = (rx0 + x, ry0 + y);
                let gi = (ch.y0 + cy) * n + ch.x0 + cx;
                let Some(f) = prep.owner(gi) else {
                    continue;
                };
                if face_chart[f as usize] != ci {
                    continue;
                }
                let i = y * w + x;
                let ci_ = cy * ch.w + cx;
                inside[i] = 1.0;
                let c = match &acc.avg {
                    Some(avg) if avg[ci_][3] > 0.0 => {
                        let s = avg[ci_][3];
                        [avg[ci_][0] / s, avg[ci_][1] / s, avg[ci_][2] / s]
                    }
                    _ => prep.vertex_color_at(f, ch.x0 + cx, ch.y0 + cy),
                };
                layer.d[3 * i..3 * i + 3].copy_from_slice(&c);
                if uncovered[ci_] {
                    mask[i] = 1.0;
                    any = true;
                    if winner_mode {
                        finest[i] = true;
                    }
                }
            }
        }
        if any {
            acc.add_region(&layer, &inside, mask, (rx0, ry0), core, levels, a, &finest);
        }
    }
    acc.avg = None;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiled_accumulation_equals_the_whole_layer() {
        let ch = Chart {
            faces: Vec::new(),
            x0: 0,
            y0: 0,
            w: 300,
            h: 260,
            levels: 2,
        };
        let (w, h) = (ch.w, ch.h);
        let mut s = 7u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        let layer = Plane::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd()).collect()).unwrap();
        // Unknown columns and rows, a soft mask, winners almost everywhere.
        let valid: Vec<f32> = (0..w * h)
            .map(|i| f32::from(i % w > 20 && (i / w) % 50 != 3))
            .collect();
        let mask: Vec<f32> = (0..w * h)
            .map(|i| valid[i] * (i % w) as f32 / w as f32)
            .collect();
        let finest: Vec<bool> = (0..w * h).map(|i| valid[i] > 0.0 && i % 7 != 0).collect();
        for winner in [false, true] {
            let f: &[bool] = if winner { &finest } else { &[] };
            let mut whole = ChartAcc::new(&ch, false, winner);
            let mut tiled = ChartAcc::new(&ch, false, winner);
            tiled.tile = 64;
            whole.add(&layer, &valid, mask.clone(), (0, 0), ch.levels, 0.4, f);
            tiled.add(&layer, &valid, mask.clone(), (0, 0), ch.levels, 0.4, f);
            for l in 0..=ch.levels {
                assert_eq!(whole.num[l].d, tiled.num[l].d, "level {l} bands");
                assert_eq!(whole.den[l], tiled.den[l], "level {l} mask sums");
            }
            let bits = |a: &ChartAcc| -> Vec<u16> {
                a.finest.iter().flat_map(|b| b.map(f16::to_bits)).collect()
            };
            assert_eq!(bits(&whole), bits(&tiled), "finest band");
            assert!(
                whole.num[1].d.iter().any(|&v| v != 0.0),
                "something was added"
            );
        }
    }
}
