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

use crate::atlas::{Atlas, ChartRect};
use crate::bind::Binding;
use crate::error::{Error, Result};
use crate::level;
use crate::mesh::Mesh;
use crate::photometric::Gains;
use crate::photos::for_each_photo_with;
use crate::progress::Progress;
use crate::pyramid::{self, Plane};
use crate::resample::{
    check_photo_count, resample_with, PhotoSampler, Prepared, ResampleOptions, Resampled,
    TexelSource, NO_PHOTO,
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

impl std::fmt::Display for Merge {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Merge::None => "none",
            Merge::Average => "average",
            Merge::Multiband => "multiband",
        })
    }
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
    /// As `Weighted` for every band but the finest, which comes from the photographs of
    /// largest weight only ([`MergeOptions::full_views`] per face), blended by their view
    /// weights raised to [`MergeOptions::fine_exponent`]: coarse bands blend, fine detail is
    /// never averaged across many slightly misregistered photographs (default).
    BestView,
}

impl std::fmt::Display for Masks {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Masks::Paper => "paper",
            Masks::Weighted => "weighted",
            Masks::BestView => "best-view",
        })
    }
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
    /// [`Masks::BestView`]: per face, the photographs of largest weight sampled at every
    /// texel; the others are sampled at every other texel in both directions (a quarter of
    /// the samples) and enter only the coarser bands, which is all best-view masks take from
    /// them. 0 = every photograph at every texel. Default: 2 (`docs/decisions.md`).
    pub full_views: usize,
    /// [`Masks::BestView`]: the finest band is the mean of the photographs sampled at every
    /// texel weighted by their view weights to this power: 0 weights them equally, larger
    /// values favour the best view, infinity takes it alone (winner-take-all, which leaves a
    /// step wherever the best photograph changes). Default: 2 (`docs/decisions.md`: on the
    /// corset view-boundary ratio 1.19 with the best view alone, 1.09 at 2, held-out 1 - NCC
    /// unchanged).
    pub fine_exponent: f32,
}

impl Default for MergeOptions {
    fn default() -> Self {
        MergeOptions {
            merge: Merge::Multiband,
            masks: Masks::BestView,
            levels: 2,
            a: 0.4,
            level_seams: true,
            full_views: 2,
            fine_exponent: 2.0,
        }
    }
}

/// Pyramid levels per chart [`MergeOptions::validate`] accepts.
pub const LEVELS_RANGE: std::ops::RangeInclusive<u32> = 1..=12;
/// Centre weights of the 5-tap kernel [`MergeOptions::validate`] accepts (the kernel stays
/// positive).
pub const KERNEL_A_RANGE: std::ops::RangeInclusive<f32> = 0.2..=0.5;

impl MergeOptions {
    /// Checks the ranges; the error names the option.
    pub fn validate(&self) -> Result<()> {
        if !LEVELS_RANGE.contains(&self.levels) {
            return Err(Error::option(
                "levels",
                format!(
                    "merge levels = {} must lie in {LEVELS_RANGE:?}",
                    self.levels
                ),
            ));
        }
        if self.fine_exponent.is_nan() || self.fine_exponent < 0.0 {
            return Err(Error::option(
                "fine_exponent",
                format!(
                    "fine exponent = {} must be 0 or more (inf: the best view alone)",
                    self.fine_exponent
                ),
            ));
        }
        if !KERNEL_A_RANGE.contains(&self.a) {
            return Err(Error::option(
                "kernel_a",
                format!(
                    "kernel weight a = {} must lie in [0.2, 0.5] (the kernel must stay positive)",
                    self.a
                ),
            ));
        }
        Ok(())
    }
}

/// One chart's image: its faces and bounding rectangle in the atlas, and the pyramid levels
/// it is merged with.
struct Chart<'a> {
    faces: &'a [u32],
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    levels: usize,
}

impl<'a> Chart<'a> {
    /// The chart's image for `r`, with as many levels as its larger side allows (down to about
    /// 8 texels), at most `max_levels`.
    fn new(r: &'a ChartRect, max_levels: u32) -> Self {
        let side = r.w.max(r.h).max(1) as f64;
        Chart {
            faces: &r.faces,
            x0: r.x0,
            y0: r.y0,
            w: r.w,
            h: r.h,
            levels: (side.log2().floor() as i64 - 3).clamp(0, max_levels as i64) as usize,
        }
    }
}

/// Per vertex, the photographs valid at it and at all its neighbours (sorted): a face is in a
/// photograph's shrunk mask when its three vertices have it here (the region's outermost ring
/// of triangles touches a vertex with an invalid neighbour).
fn ring_valid(mesh: &Mesh, b: &Binding) -> Vec<Vec<u32>> {
    let nv = mesh.num_vertices();
    let nbr = crate::mesh::topology::one_rings(mesh);
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

/// `ChartAcc::best_w` of a texel only coarse samples saw (no photograph's finest band).
const COARSE_SEEN: f16 = f16::NEG_ONE;

/// Chart texels (of bounding rectangles) collapsed in one parallel batch: bounds the
/// collapsed images held before they are copied into the atlas.
const COLLAPSE_BATCH: usize = 1 << 22;

/// A photograph's weight in the best-view finest band lies within these (half precision
/// holds sums of a few of them, `ChartAcc::finest_w`); the upper one bounds sums too.
const FINE_WEIGHT_MIN: f32 = 1.0 / 4096.0;
const FINE_WEIGHT_MAX: f32 = 16384.0;

/// A photograph's weight in the best-view finest band: its view weight `wt` relative to the
/// face's best view, to the power `exponent` (finite), clamped to what half precision holds.
#[inline]
fn fine_weight(wt: f32, reference: f32, exponent: f32) -> f32 {
    let r = if reference > 0.0 { wt / reference } else { 1.0 };
    // The default exponent without `powf` in the sampling loop.
    let m = if exponent == 2.0 {
        r * r
    } else {
        r.powf(exponent)
    };
    m.clamp(FINE_WEIGHT_MIN, FINE_WEIGHT_MAX)
}

/// A texel's view weight `wt` relative to its face's best view `reference` (the weight
/// itself where no reference), in half precision for `ChartAcc::best_w`: a texel belongs
/// to one face, so the order of its photographs is kept but for weights within 5e-4 of each
/// other, where the first stays the best.
#[inline]
fn relative_weight(wt: f32, reference: f32) -> f16 {
    let r = if reference > 0.0 { wt / reference } else { wt };
    if r > 0.0 {
        // Positive weights stay positive (0 means unseen).
        f16::from_f32(r).max(f16::from_bits(1))
    } else {
        f16::ZERO
    }
}

/// Fixed-point scale of the colours a layer holds for its finest band: steps of 1.2e-4
/// (far below 8-bit output's 3.9e-3, and finer than half precision's 4.9e-4 near 1), up
/// to 8 (photographs' values are at most 1 before the gains scale them; a colour beyond 8
/// would be clipped in the finest band only).
const FINE_COLOUR_SCALE: f32 = 8192.0;

/// Below this a sum of weights counts as nothing.
const EPS: f32 = 1e-12;

/// The texels of the next coarser level a texel `x` of a level `n` texels wide reaches in a
/// reduction, with their kernel weights (reflect-101 at the chart's borders, as
/// [`pyramid::reduce`]): `(index, weight)` pairs, `count` of them used.
#[inline(always)]
fn down_taps(x: usize, n: usize, k: &[f32; 5]) -> ([usize; 6], [f32; 6], usize) {
    let mut idx = [0usize; 6];
    let mut wt = [0f32; 6];
    let j = x / 2;
    if x >= 3 && x + 4 <= n {
        // Interior: source 2X + t - 2 = x.
        if x.is_multiple_of(2) {
            idx[..3].copy_from_slice(&[j - 1, j, j + 1]);
            wt[..3].copy_from_slice(&[k[4], k[2], k[0]]);
            return (idx, wt, 3);
        }
        idx[..2].copy_from_slice(&[j, j + 1]);
        wt[..2].copy_from_slice(&[k[3], k[1]]);
        return (idx, wt, 2);
    }
    // Near a border the reflected taps reach `x` too.
    let mut c = 0;
    for big in j.saturating_sub(3)..(j + 4).min(n.div_ceil(2)) {
        let s: f32 = (0..5)
            .filter(|&t| pyramid::reflect101(2 * big as isize + t as isize - 2, n) == x)
            .map(|t| k[t])
            .sum();
        if s > 0.0 && c < 6 {
            idx[c] = big;
            wt[c] = s;
            c += 1;
        }
    }
    (idx, wt, c)
}

/// The texels of level `n` texels wide an expansion reads for texel `x` of the next finer
/// level, with their weights (twice the kernel's; reflect-101 on the doubled grid, as
/// [`pyramid::expand`]).
#[inline]
fn up_taps(x: usize, n: usize, k: &[f32; 5]) -> ([usize; 3], [f32; 3], usize) {
    let j = (x / 2) as isize;
    let u = |i: isize| pyramid::up_src(i, n);
    if x.is_multiple_of(2) {
        (
            [u(j - 1), u(j), u(j + 1)],
            [2.0 * k[0], 2.0 * k[2], 2.0 * k[4]],
            3,
        )
    } else {
        ([u(j), u(j + 1), 0], [2.0 * k[1], 2.0 * k[3], 0.0], 2)
    }
}

/// Calls `f(index, weight)` for the products of the column taps `(xi, xw, xn)` and row taps
/// `(yi, yw, yn)` (level coordinates) that fall inside a `w` x `h` buffer whose origin is
/// (`bx`, `by`) on that level.
#[inline(always)]
fn for_taps_in<const NX: usize, const NY: usize>(
    (xi, xw, xn): ([usize; NX], [f32; NX], usize),
    (yi, yw, yn): ([usize; NY], [f32; NY], usize),
    (bx, by): (usize, usize),
    (w, h): (usize, usize),
    mut f: impl FnMut(usize, f32),
) {
    for b in 0..yn {
        let Some(yy) = yi[b].checked_sub(by).filter(|&v| v < h) else {
            continue;
        };
        for a in 0..xn {
            let Some(xx) = xi[a].checked_sub(bx).filter(|&v| v < w) else {
                continue;
            };
            f(yy * w + xx, xw[a] * yw[b]);
        }
    }
}

/// One splat contribution of weight `wt`: colour sums and weight into `d`, mask sum into
/// `mask` (both splat paths share it, so that they add the same numbers).
#[inline(always)]
fn add_splat(d: &mut [f32], mask: &mut f32, wt: f32, c: [f32; 3], m: f32) {
    d[0] += wt * c[0];
    d[1] += wt * c[1];
    d[2] += wt * c[2];
    d[3] += wt;
    if m > 0.0 {
        *mask += wt * m;
    }
}

/// [`Layer::splat`]'s sums for taps `xw` x `yw` from texel `(x0, y0)` of a level-1 buffer
/// `gw` wide (colour sums and weight in `g`, mask sums in `mask`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn splat_block<const NX: usize, const NY: usize>(
    g: &mut [f32],
    mask: &mut [f32],
    gw: usize,
    (x0, y0): (usize, usize),
    xw: [f32; NX],
    yw: [f32; NY],
    c: [f32; 3],
    m: f32,
    w: f32,
) {
    for (b, &wy) in yw.iter().enumerate() {
        let row = (y0 + b) * gw + x0;
        let d = &mut g[4 * row..4 * (row + NX)];
        let ms = &mut mask[row..row + NX];
        for (a, &wx) in xw.iter().enumerate() {
            add_splat(&mut d[4 * a..4 * a + 4], &mut ms[a], wx * wy * w, c, m);
        }
    }
}

/// One layer (a photograph's, or the complement's) on part of a chart, as its pyramid is
/// built. Level-0 texels are splatted straight into level 1 as they are sampled, so no
/// level-0 image is ever held: the photographs are sampled where they see the chart only, and
/// the transient memory is a quarter of the part's texels. The pyramid is a
/// normalised-convolution one: every level is the reduced colour sums over the reduced known
/// weight, every band a level minus the likewise normalised expansion of the next, so texels
/// the layer does not know never enter a band. Borders are reflect-101 at the chart's edges,
/// as [`pyramid::reduce`] and [`pyramid::expand`]; the part is padded beyond the reach of the
/// kernels, so elsewhere nothing lies outside it.
struct Layer {
    /// Level-0 origin of the part in the chart, a multiple of `2^levels` so that every
    /// level's grid lines up with the chart's.
    ox: usize,
    oy: usize,
    /// The chart's size per level (`chart[0]` = level 0).
    chart: Vec<(usize, usize)>,
    /// Levels 1..=levels: colour sums and known weight (4 channels).
    g: Vec<Plane>,
    /// Levels 1..=levels: the reduced mask.
    m: Vec<Vec<f32>>,
    k: [f32; 5],
}

impl Layer {
    /// A layer on the `w` x `h` texels of the chart from (`ox`, `oy`); `chart` is the
    /// chart's size per level, `levels + 1` entries.
    fn new(
        (ox, oy): (usize, usize),
        (w, h): (usize, usize),
        chart: Vec<(usize, usize)>,
        a: f32,
    ) -> Self {
        let (mut g, mut m) = (Vec::new(), Vec::new());
        if chart.len() > 1 {
            let (w1, h1) = (w.div_ceil(2), h.div_ceil(2));
            g.push(Plane::zeros(w1, h1, 4));
            m.push(vec![0f32; w1 * h1]);
        }
        Layer {
            ox,
            oy,
            chart,
            g,
            m,
            k: pyramid::kernel(a),
        }
    }

    fn levels(&self) -> usize {
        self.chart.len() - 1
    }

    /// Adds level-0 texel (`x`, `y`) (chart coordinates) of colour `c`, known with weight
    /// `w` (the texels it stands for), under mask `m`, to level 1.
    #[inline(always)]
    fn splat(&mut self, x: usize, y: usize, c: [f32; 3], m: f32, w: f32) {
        let Some(g) = self.g.first_mut() else {
            return;
        };
        let (nw, nh) = self.chart[0];
        let mask = &mut self.m[0];
        let (gw, gh) = (g.w, g.h);
        let (bx, by) = (self.ox / 2, self.oy / 2);
        // Away from the chart's border the taps are the kernel's, by parity alone, and (the
        // part being padded) inside the part: the same sums without the general tap lists.
        if x >= 3 && x + 4 <= nw && y >= 3 && y + 4 <= nh {
            let k = &self.k;
            let first = |v: usize| {
                if v.is_multiple_of(2) {
                    v / 2 - 1
                } else {
                    v / 2
                }
            };
            let (x0, y0) = (first(x), first(y));
            if x0 >= bx && x0 + 3 <= bx + gw && y0 >= by && y0 + 3 <= by + gh {
                let at = (x0 - bx, y0 - by);
                let (even, odd) = ([k[4], k[2], k[0]], [k[3], k[1]]);
                let (g, m_) = (&mut g.d[..], &mut mask[..]);
                match (x.is_multiple_of(2), y.is_multiple_of(2)) {
                    (true, true) => splat_block(g, m_, gw, at, even, even, c, m, w),
                    (false, true) => splat_block(g, m_, gw, at, odd, even, c, m, w),
                    (true, false) => splat_block(g, m_, gw, at, even, odd, c, m, w),
                    (false, false) => splat_block(g, m_, gw, at, odd, odd, c, m, w),
                }
                return;
            }
        }
        for_taps_in(
            down_taps(x, nw, &self.k),
            down_taps(y, nh, &self.k),
            (self.ox / 2, self.oy / 2),
            (gw, gh),
            |i, kw| add_splat(&mut g.d[4 * i..4 * i + 4], &mut mask[i], kw * w, c, m),
        );
    }

    /// Builds levels 2 and up from level 1 (separable, reflect-101 at the chart's edges, zero
    /// beyond the part elsewhere).
    fn reduce(&mut self) {
        for l in 1..self.levels() {
            let (src, (nw, nh)) = (&self.g[l - 1], self.chart[l]);
            let (ox, oy) = (self.ox >> l, self.oy >> l);
            let g = reduce_part(src, (ox, oy), (nw, nh), &self.k);
            let ms = Plane::from_vec(src.w, src.h, 1, std::mem::take(&mut self.m[l - 1]))
                .expect("sized");
            let m = reduce_part(&ms, (ox, oy), (nw, nh), &self.k);
            self.m[l - 1] = ms.d;
            self.g.push(g);
            self.m.push(m.d);
        }
    }

    /// The expansion of level `l + 1` at texel (`x`, `y`) of level `l` (chart coordinates),
    /// normalised; `None` where it knows nothing.
    #[inline]
    fn expanded(&self, l: usize, x: usize, y: usize) -> Option<[f32; 3]> {
        let g = &self.g[l];
        let (nw, nh) = self.chart[l + 1];
        let mut s = [0f32; 4];
        for_taps_in(
            up_taps(x, nw, &self.k),
            up_taps(y, nh, &self.k),
            (self.ox >> (l + 1), self.oy >> (l + 1)),
            (g.w, g.h),
            |i, wt| {
                for (sk, v) in s.iter_mut().zip(&g.d[4 * i..4 * i + 4]) {
                    *sk += wt * v;
                }
            },
        );
        (s[3] > EPS).then(|| [s[0] / s[3], s[1] / s[3], s[2] / s[3]])
    }

    /// Band `l` at texel (`x`, `y`) of level `l` (chart coordinates) whose level value is
    /// `v`: `v` minus the normalised expansion of the next level, `v` itself at the top.
    #[inline]
    fn band(&self, l: usize, x: usize, y: usize, mut v: [f32; 3]) -> [f32; 3] {
        if l < self.levels() {
            if let Some(u) = self.expanded(l, x, y) {
                for k in 0..3 {
                    v[k] -= u[k];
                }
            }
        }
        v
    }

    /// Adds the layer's bands under its mask to `acc`: levels 1 and up from the reduced
    /// planes, level 0 from `fine`, the level-0 texels (chart coordinates, colour, mask) that
    /// enter it (with best-view masks, into the running mean `finest`, which a mask of
    /// infinity replaces).
    fn accumulate(
        &self,
        acc: &mut ChartAcc,
        winner_mode: bool,
        fine: impl Iterator<Item = (usize, usize, [f32; 3], f32)>,
    ) {
        for l in 1..=self.levels() {
            let (g, m) = (&self.g[l - 1], &self.m[l - 1]);
            let (ox, oy) = (self.ox >> l, self.oy >> l);
            let cw = acc.num[l].w;
            let (num, den) = (&mut acc.num[l].d, &mut acc.den[l]);
            for y in 0..g.h {
                for x in 0..g.w {
                    let i = y * g.w + x;
                    let (mw, wg) = (m[i], g.d[4 * i + 3]);
                    if mw <= 0.0 || wg <= EPS {
                        continue;
                    }
                    let v = std::array::from_fn(|k| g.d[4 * i + k] / wg);
                    let band = self.band(l, ox + x, oy + y, v);
                    let gi = (oy + y) * cw + ox + x;
                    den[gi] += mw;
                    for k in 0..3 {
                        num[3 * gi + k] += mw * band[k];
                    }
                }
            }
        }
        let cw = acc.num[0].w;
        for (x, y, c, mw) in fine {
            let band = self.band(0, x, y, c);
            let gi = y * cw + x;
            if winner_mode {
                let mean = &mut acc.finest[3 * gi..3 * gi + 3];
                if mw == f32::INFINITY {
                    for (m, b) in mean.iter_mut().zip(band) {
                        *m = f16::from_f32(b);
                    }
                    // The weights may be gone already (`multiband` frees them after the
                    // photographs, before the complement).
                    if let Some(sum) = acc.finest_w.get_mut(gi) {
                        *sum = f16::ONE;
                    }
                } else if mw > 0.0 {
                    // Weights stay within half precision's range (`fine_weight`).
                    let sum = &mut acc.finest_w[gi];
                    let total = sum.to_f32() + mw;
                    let share = mw / total;
                    for (m, b) in mean.iter_mut().zip(band) {
                        let v = m.to_f32();
                        *m = f16::from_f32(v + share * (b - v));
                    }
                    *sum = f16::from_f32(total.min(FINE_WEIGHT_MAX));
                }
            } else if mw > 0.0 {
                acc.den[0][gi] += mw;
                for (v, b) in acc.num[0].d[3 * gi..3 * gi + 3].iter_mut().zip(band) {
                    *v += mw * b;
                }
            }
        }
    }
}

/// One reduction of `src`, which covers the texels from (`ox`, `oy`) (even) of a level
/// `nw` x `nh` texels: reflect-101 at that level's edges, zero beyond `src` elsewhere. The
/// result covers the next level from (`ox / 2`, `oy / 2`).
fn reduce_part(
    src: &Plane,
    (ox, oy): (usize, usize),
    (nw, nh): (usize, usize),
    k: &[f32; 5],
) -> Plane {
    let (w, h, c) = (src.w, src.h, src.c);
    let (dw, dh) = (w.div_ceil(2), h.div_ceil(2));
    // Source offsets (within `src`) and weights of output column/row `d`.
    let taps = |d: usize, o: usize, n: usize, len: usize| -> ([usize; 5], [f32; 5], usize) {
        let mut idx = [0usize; 5];
        let mut wt = [0f32; 5];
        let mut cnt = 0;
        let centre = 2 * (o / 2 + d) as isize;
        for (t, &kt) in k.iter().enumerate() {
            let s = pyramid::reflect101(centre + t as isize - 2, n) as isize - o as isize;
            if s >= 0 && (s as usize) < len {
                idx[cnt] = s as usize;
                wt[cnt] = kt;
                cnt += 1;
            }
        }
        (idx, wt, cnt)
    };
    let cols: Vec<_> = (0..dw).map(|x| taps(x, ox, nw, w)).collect();
    let mut tmp = vec![0f32; dw * h * c];
    // The channel count as a constant, so that the tap loops unroll (a layer's colour sums
    // have 4, its mask 1).
    match c {
        4 => reduce_rows::<4>(&src.d, w, &cols, &mut tmp),
        1 => reduce_rows::<1>(&src.d, w, &cols, &mut tmp),
        _ => reduce_rows_any(&src.d, w, c, &cols, &mut tmp),
    }
    let mut out = vec![0f32; dw * dh * c];
    let rl = dw * c;
    for y in 0..dh {
        let (idx, wt, n) = taps(y, oy, nh, h);
        let row = &mut out[y * rl..(y + 1) * rl];
        for t in 0..n {
            let r = &tmp[idx[t] * rl..(idx[t] + 1) * rl];
            for (o, v) in row.iter_mut().zip(r) {
                *o += wt[t] * v;
            }
        }
    }
    Plane::from_vec(dw, dh, c, out).expect("sized")
}

/// Column taps of one output texel of a reduction: source indices, weights, count.
type Taps = ([usize; 5], [f32; 5], usize);

/// The horizontal pass of [`reduce_part`] for `C` channels: each row of `src` (`w` texels)
/// into `tmp` through the column taps `cols`; all-zero rows are skipped (most of a layer).
fn reduce_rows<const C: usize>(src: &[f32], w: usize, cols: &[Taps], tmp: &mut [f32]) {
    let dw = cols.len();
    for (s, row) in src.chunks_exact(w * C).zip(tmp.chunks_exact_mut(dw * C)) {
        if s.iter().all(|&v| v == 0.0) {
            continue;
        }
        for ((idx, wt, n), o) in cols.iter().zip(row.chunks_exact_mut(C)) {
            let mut acc = [0f32; C];
            for t in 0..*n {
                let v = &s[idx[t] * C..idx[t] * C + C];
                for ch in 0..C {
                    acc[ch] += wt[t] * v[ch];
                }
            }
            o.copy_from_slice(&acc);
        }
    }
}

/// [`reduce_rows`] for any channel count.
fn reduce_rows_any(src: &[f32], w: usize, c: usize, cols: &[Taps], tmp: &mut [f32]) {
    let dw = cols.len();
    for (s, row) in src.chunks_exact(w * c).zip(tmp.chunks_exact_mut(dw * c)) {
        if s.iter().all(|&v| v == 0.0) {
            continue;
        }
        for ((idx, wt, n), o) in cols.iter().zip(row.chunks_exact_mut(c)) {
            for t in 0..*n {
                for ch in 0..c {
                    o[ch] += wt[t] * s[idx[t] * c + ch];
                }
            }
        }
    }
}

/// `n` half-precision zeros, from zeroed memory: pages the merge never writes (parts of
/// chart rectangles that are other charts' texels or gutter) are never made resident.
fn zeros_f16(n: usize) -> Vec<f16> {
    use half::vec::HalfBitsVecExt;
    vec![0u16; n].reinterpret_into()
}

/// A chart's band accumulators.
struct ChartAcc {
    /// Per level: mask-weighted band sums (3 channels); for [`Masks::BestView`] level 0 is
    /// empty (see `finest`).
    num: Vec<Plane>,
    /// Per level: mask sums (level 0 empty for [`Masks::BestView`]).
    den: Vec<Vec<f32>>,
    /// [`Masks::BestView`]: the finest band's running weighted mean, in half precision (an
    /// error under 5e-4 for bands within +-1, below half a step of 8-bit output), 0 where
    /// no layer has entered it. At 8192 this and its weights in place of full-precision
    /// level-0 sums save 8 bytes per chart texel, about 0.4 GB.
    finest: Vec<f16>,
    /// [`Masks::BestView`]: the weights summed into `finest` (1 once some layer entered it,
    /// with the best view alone, which replaces rather than averages). Freed after the
    /// photographs on charts with coarser levels (`multiband`), before the peak.
    finest_w: Vec<f16>,
    /// Largest view weight so far (relative to the face's best view, `relative_weight`) and
    /// its photograph, photographs seen, per texel.
    best_w: Vec<f16>,
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
                zeros_f16(3 * n)
            } else {
                Vec::new()
            },
            finest_w: if winner_mode {
                zeros_f16(n)
            } else {
                Vec::new()
            },
            best_w: zeros_f16(n),
            best: vec![NO_PHOTO; n],
            views: vec![0; n],
            avg: paper.then(|| vec![[0.0; 4]; n]),
        }
    }

    /// The chart's size per level.
    fn sizes(&self) -> Vec<(usize, usize)> {
        self.num.iter().map(|p| (p.w, p.h)).collect()
    }

    /// The blended chart image, or with best-view masks on a chart with coarser levels its
    /// level 1 (the finest band stays in `finest`, for [`write_chart`]); the band sums are
    /// freed, the per-texel bookkeeping stays.
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
            // A chart too small for a pyramid: its one level is the blended colours, known
            // where some layer entered.
            let (w, h) = (self.num[0].w, self.num[0].h);
            let finest = std::mem::take(&mut self.finest);
            let weights = std::mem::take(&mut self.finest_w);
            self.den[0] = weights.iter().map(|&b| f32::from(b > f16::ZERO)).collect();
            let d: Vec<f32> = finest.iter().map(|v| v.to_f32()).collect();
            self.num[0] = Plane::from_vec(w, h, 3, d).expect("sized");
        }
        // The coarsest level is a colour, not a band: where no mask reaches it, extend the
        // colours around rather than expand zeros into the chart's border.
        let weights: Vec<f32> = self.den[top].iter().map(|&d| f32::from(d > 1e-6)).collect();
        pyramid::fill_holes(&mut self.num[top], &weights, a);
        self.den = Vec::new();
        if winner_mode && top > 0 {
            // The coarser levels collapsed; `write_chart` expands them a stripe at a time
            // and adds the half-precision finest band (no chart-sized full-precision image:
            // 12 bytes per texel less at the peak).
            let coarse = pyramid::collapse(self.num.split_off(1), a);
            self.num = Vec::new();
            return coarse;
        }
        pyramid::collapse(std::mem::take(&mut self.num), a)
    }
}

/// Stage 4: the photographs resampled into `atlas` and merged as `mopts` says. `normals` are
/// unit vertex normals of `mesh`; the binding carries the gains.
#[allow(clippy::too_many_arguments)]
pub fn merge(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    atlas: &Atlas,
    binding: &Binding,
    gains: &Gains,
    photos: &[Photo],
    ropts: &ResampleOptions,
    mopts: &MergeOptions,
    progress: &dyn Progress,
) -> Result<Resampled> {
    mopts.validate()?;
    let prep = Prepared::new(mesh, atlas, normals, binding, gains, ropts)?;
    match mopts.merge {
        Merge::None => resample_with(&prep, photos, ropts, true, progress),
        Merge::Average => resample_with(&prep, photos, ropts, false, progress),
        Merge::Multiband => multiband(&prep, photos, ropts, mopts, progress),
    }
}

#[allow(clippy::too_many_arguments)]
fn multiband(
    prep: &Prepared,
    photos: &[Photo],
    ropts: &ResampleOptions,
    mopts: &MergeOptions,
    progress: &dyn Progress,
) -> Result<Resampled> {
    let (mesh, atlas, binding) = (prep.mesh, prep.atlas, prep.binding);
    check_photo_count(photos.len())?;
    let n = prep.size();
    let a = mopts.a;
    let paper = mopts.masks == Masks::Paper;
    let winner_mode = mopts.masks == Masks::BestView;
    let charts: Vec<Chart> = atlas
        .charts
        .iter()
        .map(|r| Chart::new(r, mopts.levels))
        .collect();
    let face_chart = &atlas.face_chart;
    let ring = paper.then(|| ring_valid(mesh, binding));
    // A face's reference weight: its best photograph's mean vertex weight, so relative masks
    // are about 1 for the best view whatever the units of the weights. And, with best-view
    // masks, the `full_views` photographs of largest weight, the only ones sampled at every
    // texel (the others enter the coarser bands only).
    let k_full = if winner_mode { mopts.full_views } else { 0 };
    let per_face: Vec<(f32, Vec<u32>)> = (0..mesh.num_faces())
        .into_par_iter()
        .map(|f| {
            let fv = mesh.faces[f];
            let mut ws: Vec<(f32, u32)> = prep
                .common
                .of(f)
                .iter()
                .map(|&p| {
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
                    (s / 3.0, p)
                })
                .collect();
            let best = ws.iter().map(|w| w.0).fold(0f32, f32::max);
            if k_full == 0 || ws.len() <= k_full {
                return (best, Vec::new());
            }
            ws.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            let mut top: Vec<u32> = ws[..k_full].iter().map(|w| w.1).collect();
            top.sort_unstable();
            (best, top)
        })
        .collect();
    let (face_ref, face_full): (Vec<f32>, Vec<Vec<u32>>) = per_face.into_iter().unzip();
    let mut accs: Vec<ChartAcc> = charts
        .par_iter()
        .map(|ch| ChartAcc::new(ch, paper, winner_mode))
        .collect();
    let (mut seconds_setup, mut seconds_charts) = (0.0, 0.0);
    let cpu_sampling = AtomicU64::new(0);
    progress.start("merging", photos.len() as u64);
    let heap = crate::io::LargeBlocksInHeap::new();
    // The next photograph's depth map and mip levels are built while this one is sampled.
    let setup = |pi: usize, rgb: &crate::io::image::PhotoPixels| prep.photo_setup(photos, pi, rgb);
    for_each_photo_with(photos, progress, setup, |pi, rgb, mask, setup| {
        seconds_setup += setup.seconds;
        let ph = prep.photo_with(photos, pi, rgb, mask, setup);
        let t = std::time::Instant::now();
        accs.par_iter_mut()
            .zip(charts.par_iter())
            .for_each(|(acc, ch)| {
                add_photo(
                    prep,
                    &ph,
                    ch,
                    acc,
                    ring.as_deref(),
                    &face_ref,
                    &face_full,
                    mopts,
                    &cpu_sampling,
                )
            });
        seconds_charts += t.elapsed().as_secs_f64();
        Ok(())
    })?;
    progress.finish();
    drop(heap);
    // The finest band's weights matter no more but for the coverage of charts without
    // coarser levels (`ChartAcc::collapse`): 2 bytes per chart texel less at the peak.
    for (acc, ch) in accs.iter_mut().zip(&charts) {
        if ch.levels > 0 {
            acc.finest_w = Vec::new();
        }
    }
    crate::io::release_freed_memory();
    // The complement layer, then collapse, a batch of charts at a time so that finished
    // charts' accumulators are freed as the atlas fills: largest first (their accumulators
    // are the most memory), batches of at most COLLAPSE_BATCH chart texels or two charts,
    // so that both cores work even while the largest charts go.
    let t_collapse = std::time::Instant::now();
    let mut color = vec![0f32; n * n * 3];
    let mut source = vec![TexelSource::Empty as u8; n * n];
    let mut views = vec![0u8; n * n];
    let mut best = vec![NO_PHOTO; n * n];
    let mut accs: Vec<Option<ChartAcc>> = accs.into_iter().map(Some).collect();
    let mut order: Vec<usize> = (0..charts.len()).collect();
    order.sort_by_key(|&c| std::cmp::Reverse(charts[c].w * charts[c].h));
    let mut rest = &order[..];
    while !rest.is_empty() {
        let mut take = 0;
        let mut area = 0;
        while take < rest.len()
            && (take < 2 || area + charts[rest[take]].w * charts[rest[take]].h <= COLLAPSE_BATCH)
        {
            area += charts[rest[take]].w * charts[rest[take]].h;
            take += 1;
        }
        let (batch, tail) = rest.split_at(take);
        rest = tail;
        let mut work: Vec<(usize, ChartAcc)> = batch
            .iter()
            .map(|&ci| (ci, accs[ci].take().expect("each chart once")))
            .collect();
        let done: Vec<Plane> = work
            .par_iter_mut()
            .map(|(ci, acc)| {
                let ch = &charts[*ci];
                add_complement(prep, ch, *ci as u32, face_chart, acc, a, winner_mode);
                acc.collapse(a, winner_mode)
            })
            .collect();
        for (img, (ci, acc)) in done.into_iter().zip(work) {
            let ch = &charts[ci];
            let expand = winner_mode && ch.levels > 0;
            let out = (
                &mut color[..],
                &mut source[..],
                &mut views[..],
                &mut best[..],
            );
            write_chart(prep, ch, ci as u32, face_chart, &img, expand, &acc, a, out);
        }
        crate::io::release_freed_memory();
    }
    let seconds_collapse = t_collapse.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let levelling = mopts.level_seams.then(|| {
        let owner = |i: usize| prep.owner(i);
        let mut st = level::level_seams(mesh, n, &owner, face_chart, &mut color, level::SMOOTHNESS);
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
    out.stats.seconds_collapse = seconds_collapse;
    Ok(out)
}

/// Writes chart `ch` (number `ci`) into the atlas arrays `out` (colour, source, views, best
/// photograph) at the texels it owns, a stripe of rows at a time in parallel. `img` is the
/// collapsed chart, or with `expand` (best-view masks, coarser levels) its level 1, expanded
/// by [`blended_rows`] with the finest band in `acc`: the same arithmetic as
/// [`pyramid::expand`] on the whole chart, without a chart-sized image.
#[allow(clippy::too_many_arguments)]
fn write_chart(
    prep: &Prepared,
    ch: &Chart,
    ci: u32,
    face_chart: &[u32],
    img: &Plane,
    expand: bool,
    acc: &ChartAcc,
    a: f32,
    (color, source, views, best): (&mut [f32], &mut [u8], &mut [u8], &mut [u16]),
) {
    const STRIPE: usize = 32;
    let n = prep.size();
    let rows = ch.y0 * n..(ch.y0 + ch.h) * n;
    color[3 * rows.start..3 * rows.end]
        .par_chunks_mut(3 * STRIPE * n)
        .zip(source[rows.clone()].par_chunks_mut(STRIPE * n))
        .zip(views[rows.clone()].par_chunks_mut(STRIPE * n))
        .zip(best[rows].par_chunks_mut(STRIPE * n))
        .enumerate()
        .for_each(|(si, (((crow, srow), vrow), brow))| {
            let (ly0, ly1) = (si * STRIPE, ((si + 1) * STRIPE).min(ch.h));
            let mut write = |ly: usize, line: &[f32]| {
                let base = (ly - ly0) * n + ch.x0;
                for x in 0..ch.w {
                    let Some(f) = prep.owner((ch.y0 + ly) * n + ch.x0 + x) else {
                        continue;
                    };
                    if face_chart[f as usize] != ci {
                        continue;
                    }
                    let li = ly * ch.w + x;
                    let gi = base + x;
                    crow[3 * gi..3 * gi + 3].copy_from_slice(&line[3 * x..3 * x + 3]);
                    vrow[gi] = acc.views[li];
                    brow[gi] = acc.best[li];
                    srow[gi] = if acc.best_w[li] != f16::ZERO {
                        TexelSource::Photos as u8
                    } else {
                        prep.fallback_source(f) as u8
                    };
                }
            };
            if expand {
                blended_rows(img, &acc.finest, ch.w, a, (ly0, ly1), &mut write);
            } else {
                let rl = 3 * ch.w;
                for ly in ly0..ly1 {
                    write(ly, &img.d[ly * rl..(ly + 1) * rl]);
                }
            }
        });
}

/// Rows `ly0..ly1` of a best-view chart `w` texels wide: its collapsed level 1 `coarse`
/// expanded (the arithmetic of [`pyramid::expand`] on the whole chart) plus the finest band
/// `finest`; calls `row(y, rgb values)` for each.
fn blended_rows(
    coarse: &Plane,
    finest: &[f16],
    w: usize,
    a: f32,
    (ly0, ly1): (usize, usize),
    mut row: impl FnMut(usize, &[f32]),
) {
    let k = pyramid::kernel(a).map(|v| 2.0 * v);
    let (sw, sh) = (coarse.w, coarse.h);
    let rl = w * 3;
    // The level-1 rows these rows read (reflected ones included), widened.
    let (lo, hi) = ((ly0 / 2).saturating_sub(1), ((ly1 - 1) / 2 + 1).min(sh - 1));
    let mut tmp = vec![0f32; (hi - lo + 1) * rl];
    for (sy, r) in (lo..=hi).zip(tmp.chunks_exact_mut(rl)) {
        pyramid::expand_row(&coarse.d[sy * sw * 3..(sy + 1) * sw * 3], 3, &k, r);
    }
    let mut line = vec![0f32; rl];
    for ly in ly0..ly1 {
        let src = |sy: usize| &tmp[(sy - lo) * rl..(sy - lo + 1) * rl];
        pyramid::expand_col(ly, sh, &k, src, &mut line);
        // Zero where no layer entered the finest band.
        for (v, b) in line.iter_mut().zip(&finest[ly * rl..(ly + 1) * rl]) {
            *v += b.to_f32();
        }
        row(ly, &line);
    }
}

/// Levels chart borders again, on `res`'s current colours: restoration fills texels on both
/// sides of chart borders independently, and the steps it leaves there are what levelling
/// removes (`docs/decisions.md`). `mesh` and `atlas` are the ones `res` was merged for; the
/// gutter is filled again, `gutter_fill` texels deep.
pub fn relevel(
    mesh: &Mesh,
    atlas: &Atlas,
    res: &mut Resampled,
    gutter_fill: u32,
) -> Result<level::LevelStats> {
    let t = std::time::Instant::now();
    let n = res.color.width() as usize;
    if n != atlas.size as usize {
        return Err(Error::Invalid(
            "levelling an atlas with the texels of another size".into(),
        ));
    }
    let own = |i: usize| atlas.owner(i);
    let color: &mut [f32] = &mut res.color;
    let mut st = level::level_seams(mesh, n, &own, &atlas.face_chart, color, level::SMOOTHNESS);
    crate::resample::refill_gutter(res, gutter_fill);
    st.seconds = t.elapsed().as_secs_f64();
    res.stats.seam_levelling_after_restore = Some(st);
    Ok(st)
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
    face_full: &[Vec<u32>],
    mopts: &MergeOptions,
    cpu_sampling: &AtomicU64,
) {
    let photo = ph.index as u32;
    if !ch.faces.iter().any(|&f| ph.samples(f)) {
        return;
    }
    let t = std::time::Instant::now();
    // Only the part of the chart near what the photograph sees: its faces' rectangle, padded
    // by the coarsest level's reach (beyond it the mask is zero at every level) and aligned to
    // that level's grid.
    let (mut bx0, mut by0, mut bx1, mut by1) = (usize::MAX, usize::MAX, 0, 0);
    for &f in ch.faces {
        if ph.samples(f) {
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
    let mut layer = Layer::new((ox, oy), (w, h), acc.sizes(), mopts.a);
    let winner_mode = mopts.masks == Masks::BestView;
    let fine_alone = mopts.fine_exponent == f32::INFINITY;
    // The level-0 texels that enter the finest band (chart x | y << 16, colour, mask), held
    // until the layer's coarser levels are built, in 12 bytes: with blended finest bands a
    // photograph keeps every texel it samples at full resolution, up to millions on one
    // chart. Colours in fixed point (`FINE_COLOUR_SCALE`).
    let mut fine: Vec<(u32, [u16; 3], f16)> = Vec::new();
    let fine_texel = |x: usize, y: usize, c: [f32; 3], m: f32| {
        // Charts are at most 32768 texels wide and high (the atlas's limit).
        let c = c.map(|v| (v * FINE_COLOUR_SCALE + 0.5).clamp(0.0, 65535.0) as u16);
        ((x | y << 16) as u32, c, f16::from_f32(m))
    };
    let mut any_mask = false;
    let n = prep.size();
    for &f in ch.faces {
        if !ph.samples(f) {
            continue;
        }
        let in_mask = match ring {
            Some(r) => prep.mesh.faces[f as usize]
                .iter()
                .all(|v| r[v.idx()].binary_search(&photo).is_ok()),
            None => true,
        };
        let reference = face_ref[f as usize];
        let mask_of = |wt: f32| match mopts.masks {
            Masks::Paper => f32::from(in_mask),
            _ if reference > 0.0 => (wt / reference).min(1.0),
            _ => 1.0,
        };
        let full = &face_full[f as usize];
        if ch.levels > 0 && !full.is_empty() && full.binary_search(&photo).is_err() {
            // Coarse: one sample per 2 x 2 texels, for the coarser bands; these texels count
            // as seen (never in the finest band: theirs is not known).
            prep.sample_face(ph, f, 0, n, Some((ch.x0, ch.y0)), |x, y, c, wt| {
                let (x, y) = (x - ch.x0, y - ch.y0);
                for (bx, by) in [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)] {
                    // Texels of any face this photograph samples (a neighbour's texels
                    // whose own block anchor lies in this face); texels of other charts in
                    // the rectangle are never copied out, so marking them is harmless.
                    if bx >= ch.w || by >= ch.h {
                        continue;
                    }
                    match prep.owner((ch.y0 + by) * n + ch.x0 + bx) {
                        Some(g) if g == f || ph.samples(g) => {}
                        _ => continue,
                    }
                    let i = by * ch.w + bx;
                    acc.views[i] = acc.views[i].saturating_add(1);
                    if acc.best_w[i] == f16::ZERO {
                        acc.best_w[i] = COARSE_SEEN;
                        acc.best[i] = photo as u16;
                    }
                }
                let m = mask_of(wt);
                layer.splat(x, y, c, m, 4.0);
                any_mask |= m > 0.0;
            });
            continue;
        }
        prep.sample_face(ph, f, 0, n, None, |x, y, c, wt| {
            let (x, y) = (x - ch.x0, y - ch.y0);
            let m = mask_of(wt);
            let i = y * ch.w + x;
            acc.views[i] = acc.views[i].saturating_add(1);
            // Photographs come in order, so ties keep the first: deterministic.
            let rel = relative_weight(wt, reference);
            let wins = rel > acc.best_w[i];
            if wins {
                acc.best_w[i] = rel;
                acc.best[i] = photo as u16;
            }
            if let Some(avg) = &mut acc.avg {
                for k in 0..3 {
                    avg[i][k] += wt * c[k];
                }
                avg[i][3] += wt;
            }
            layer.splat(x, y, c, m, 1.0);
            any_mask |= m > 0.0;
            if winner_mode {
                // Into the finest band's running mean, or with an infinite exponent in place
                // of it where this photograph wins.
                if fine_alone {
                    if wins {
                        fine.push(fine_texel(x, y, c, f32::INFINITY));
                    }
                } else {
                    let mf = fine_weight(wt, reference, mopts.fine_exponent);
                    fine.push(fine_texel(x, y, c, mf));
                }
            } else if m > 0.0 {
                fine.push(fine_texel(x, y, c, m));
            }
        });
    }
    cpu_sampling.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
    if !any_mask {
        return;
    }
    layer.reduce();
    let fine = fine.into_iter().map(|(xy, c, m)| {
        let (x, y) = ((xy & 0xffff) as usize, (xy >> 16) as usize);
        (x, y, c.map(|v| v as f32 / FINE_COLOUR_SCALE), m.to_f32())
    });
    layer.accumulate(acc, winner_mode, fine);
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
    // No photograph's mask covers the texel (best-view masks are positive exactly where a
    // view weight is). Decided before the layer adds to the level-0 sums.
    let uncovered: Vec<bool> = if winner_mode {
        acc.best_w.iter().map(|&b| b == f16::ZERO).collect()
    } else {
        acc.den[0].iter().map(|&d| d <= 0.0).collect()
    };
    let avg = acc.avg.take();
    // The layer's colour at chart texel (x, y), if the chart owns it.
    let colour = |x: usize, y: usize| -> Option<[f32; 3]> {
        let f = prep.owner((ch.y0 + y) * n + ch.x0 + x)?;
        if face_chart[f as usize] != ci {
            return None;
        }
        let i = y * ch.w + x;
        Some(match &avg {
            Some(avg) if avg[i][3] > 0.0 => {
                let s = avg[i][3];
                [avg[i][0] / s, avg[i][1] / s, avg[i][2] / s]
            }
            _ => prep.vertex_color_at(f, ch.x0 + x, ch.y0 + y),
        })
    };
    // Only the part of the chart within the coarsest level's reach of an uncovered texel
    // matters (beyond it the mask is zero at every level), as for the photographs' layers.
    let owned = |x: usize, y: usize| {
        prep.owner((ch.y0 + y) * n + ch.x0 + x)
            .is_some_and(|f| face_chart[f as usize] == ci)
    };
    let rows: Vec<Option<(usize, usize)>> = (0..ch.h)
        .into_par_iter()
        .map(|y| {
            let mut xs = (0..ch.w).filter(|&x| uncovered[y * ch.w + x] && owned(x, y));
            let first = xs.next()?;
            Some((first, xs.next_back().unwrap_or(first) + 1))
        })
        .collect();
    let Some(by0) = rows.iter().position(Option::is_some) else {
        // No texel left for the complement.
        return;
    };
    let by1 = rows.iter().rposition(Option::is_some).expect("one found") + 1;
    let (bx0, bx1) = rows
        .iter()
        .flatten()
        .fold((usize::MAX, 0), |(a, b), &(x0, x1)| (a.min(x0), b.max(x1)));
    let step = 1usize << ch.levels;
    let pad = 4 * step;
    let ox = bx0.saturating_sub(pad) / step * step;
    let oy = by0.saturating_sub(pad) / step * step;
    let (ex, ey) = ((bx1 + pad).min(ch.w), (by1 + pad).min(ch.h));
    // Colours are computed in parallel a block of rows at a time (the largest chart of the
    // 8192 speed scene spans 16.5M texels, alone in its batch), and added in order.
    const ROWS: usize = 64;
    let block = |y0: usize, only_uncovered: bool| -> Vec<(usize, usize, [f32; 3])> {
        (y0..(y0 + ROWS).min(ey))
            .into_par_iter()
            .flat_map_iter(|y| {
                let colour = &colour;
                let uncovered = &uncovered;
                (ox..ex).filter_map(move |x| {
                    if only_uncovered && !uncovered[y * ch.w + x] {
                        return None;
                    }
                    colour(x, y).map(|c| (x, y, c))
                })
            })
            .collect()
    };
    let mut layer = Layer::new((ox, oy), (ex - ox, ey - oy), acc.sizes(), a);
    for y0 in (oy..ey).step_by(ROWS) {
        for (x, y, c) in block(y0, false) {
            let m = f32::from(uncovered[y * ch.w + x]);
            layer.splat(x, y, c, m, 1.0);
        }
    }
    layer.reduce();
    // The finest band again from the colours (recomputing them costs less than holding a
    // chart's worth).
    let fine = (oy..ey)
        .step_by(ROWS)
        .flat_map(|y0| block(y0, true))
        // With best-view masks it replaces the finest band: it enters only texels no
        // photograph did.
        .map(|(x, y, c)| (x, y, c, if winner_mode { f32::INFINITY } else { 1.0 }));
    layer.accumulate(acc, winner_mode, fine);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_layer(w: usize, h: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut s = seed;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..w * h).map(|_| [rnd(), rnd(), rnd()]).collect()
    }

    fn chart(w: usize, h: usize, levels: usize) -> Chart<'static> {
        Chart {
            faces: &[],
            x0: 0,
            y0: 0,
            w,
            h,
            levels,
        }
    }

    fn max_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    /// Splatting texels into level 1 and reducing from there gives the dense pyramid of
    /// `pyramid` (tested against OpenCV) on the same premultiplied layer, borders included,
    /// whether the layer covers the whole chart or a padded part of it.
    #[test]
    fn splatted_pyramid_equals_the_dense_one() {
        let (w, h, levels) = (45, 38, 3);
        let acc = ChartAcc::new(&chart(w, h, levels), false, false);
        let colours = random_layer(w, h, 7);
        // Known on the whole chart, then only in a window away from the chart's edges.
        for (x0, y0, x1, y1) in [(0, 0, w, h), (17, 19, 25, 24)] {
            let known = |x: usize, y: usize| x >= x0 && x < x1 && y >= y0 && y < y1;
            let mut dense = Plane::zeros(w, h, 4);
            for y in 0..h {
                for x in 0..w {
                    if known(x, y) {
                        let c = colours[y * w + x];
                        dense.d[4 * (y * w + x)..4 * (y * w + x) + 4]
                            .copy_from_slice(&[c[0], c[1], c[2], 1.0]);
                    }
                }
            }
            let g = pyramid::gaussian(dense, levels, 0.4);
            // The part: the window padded by four coarsest texels, aligned to them.
            let step = 1 << levels;
            let (ox, oy) = (
                x0.saturating_sub(4 * step) / step * step,
                y0.saturating_sub(4 * step) / step * step,
            );
            let (pw, ph) = ((x1 + 4 * step).min(w) - ox, (y1 + 4 * step).min(h) - oy);
            let mut layer = Layer::new((ox, oy), (pw, ph), acc.sizes(), 0.4);
            for y in y0..y1 {
                for x in x0..x1 {
                    layer.splat(x, y, colours[y * w + x], 1.0, 1.0);
                }
            }
            layer.reduce();
            for (l, part) in (1..=levels).zip(&layer.g) {
                let (bx, by) = (ox >> l, oy >> l);
                let mut expect = Vec::new();
                for y in 0..part.h {
                    for x in 0..part.w {
                        let i = 4 * ((by + y) * g[l].w + bx + x);
                        expect.extend_from_slice(&g[l].d[i..i + 4]);
                    }
                }
                let d = max_diff(&part.d, &expect);
                assert!(d < 1e-5, "window {x0},{y0}: level {l} differs by {d}");
                // Outside the part the dense pyramid is zero: nothing was lost.
                let inside: f32 = part.d.iter().skip(3).step_by(4).sum();
                let all: f32 = g[l].d.iter().skip(3).step_by(4).sum();
                assert!(
                    (inside - all).abs() < 1e-3 * all,
                    "level {l}: {inside} of {all}"
                );
            }
        }
    }

    /// One layer known everywhere, alone under its mask, collapses back to itself (borders
    /// included): the bands and the collapse agree.
    #[test]
    fn a_lone_layer_collapses_back_to_itself() {
        let (w, h, levels) = (70, 53, 2);
        let colours = random_layer(w, h, 11);
        for winner in [false, true] {
            let mut acc = ChartAcc::new(&chart(w, h, levels), false, winner);
            let mut layer = Layer::new((0, 0), (w, h), acc.sizes(), 0.4);
            for y in 0..h {
                for x in 0..w {
                    layer.splat(x, y, colours[y * w + x], 1.0, 1.0);
                }
            }
            layer.reduce();
            let fine = (0..w * h).map(|i| (i % w, i / w, colours[i], 1.0));
            layer.accumulate(&mut acc, winner, fine);
            let mut out = acc.collapse(0.4, winner);
            if winner {
                // The coarser levels only: expanded with the finest band, a stripe of rows
                // at a time as `write_chart` does, they give the image back.
                assert_eq!((out.w, out.h), (w.div_ceil(2), h.div_ceil(2)));
                let mut img = vec![0f32; w * h * 3];
                for y0 in (0..h).step_by(7) {
                    blended_rows(&out, &acc.finest, w, 0.4, (y0, (y0 + 7).min(h)), |y, l| {
                        img[y * w * 3..(y + 1) * w * 3].copy_from_slice(l)
                    });
                }
                out = Plane::from_vec(w, h, 3, img).unwrap();
            }
            let flat: Vec<f32> = colours.iter().flatten().copied().collect();
            let d = max_diff(&out.d, &flat);
            // Half precision holds the finest band with best-view masks.
            let tol = if winner { 1e-3 } else { 1e-5 };
            assert!(d < tol, "winner {winner}: {d}");
        }
    }

    /// Best-view masks: the finest band is the mean of the layers' finest bands weighted by
    /// their fine weights (whatever order they come in), while the coarser bands follow the
    /// coarse masks; an infinite weight replaces what came before.
    #[test]
    fn the_finest_band_is_the_fine_weighted_mean_of_the_layers() {
        let (w, h, levels) = (40, 36, 2);
        let layers = [random_layer(w, h, 3), random_layer(w, h, 5)];
        // Each layer's own finest band, from a lone run.
        let finest_of = |fine_w: &[f32]| {
            let mut acc = ChartAcc::new(&chart(w, h, levels), false, true);
            for (colours, &mf) in layers.iter().zip(fine_w) {
                let mut layer = Layer::new((0, 0), (w, h), acc.sizes(), 0.4);
                for y in 0..h {
                    for x in 0..w {
                        layer.splat(x, y, colours[y * w + x], 1.0, 1.0);
                    }
                }
                layer.reduce();
                let fine = (0..w * h).map(|i| (i % w, i / w, colours[i], mf));
                layer.accumulate(&mut acc, true, fine);
            }
            acc.finest.iter().map(|v| v.to_f32()).collect::<Vec<f32>>()
        };
        let alone_a = finest_of(&[1.0, 0.0]);
        let alone_b = finest_of(&[0.0, 1.0]);
        assert!(max_diff(&alone_a, &alone_b) > 0.05, "the layers differ");
        let expect: Vec<f32> = alone_a
            .iter()
            .zip(&alone_b)
            .map(|(a, b)| 0.75 * a + 0.25 * b)
            .collect();
        // Half-precision running means: a few units of 5e-4.
        for fine_w in [[3.0, 1.0], [0.75, 0.25]] {
            let d = max_diff(&finest_of(&fine_w), &expect);
            assert!(d < 2e-3, "weights {fine_w:?}: {d}");
        }
        let d = max_diff(&finest_of(&[1.0, f32::INFINITY]), &alone_b);
        assert!(d == 0.0, "an infinite weight replaces: {d}");
        // The weights: view weight relative to the face's best, to the exponent.
        assert_eq!(fine_weight(0.5, 2.0, 2.0), 0.0625);
        assert!((fine_weight(3.0, 2.0, 1.5) - 1.5f32.powf(1.5)).abs() < 1e-6);
        assert_eq!(fine_weight(0.3, 2.0, 0.0), 1.0);
        assert_eq!(fine_weight(1e-6, 1.0, 2.0), FINE_WEIGHT_MIN);
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn reduction_taps_match_the_kernel_everywhere() {
        let k = pyramid::kernel(0.4);
        for n in [1usize, 2, 3, 4, 5, 9, 16] {
            // Every source's taps, summed per destination, give the gather weights.
            let n1 = n.div_ceil(2);
            let mut w = vec![vec![0f32; n]; n1];
            for x in 0..n {
                let (idx, wt, c) = down_taps(x, n, &k);
                for j in 0..c {
                    w[idx[j]][x] += wt[j];
                }
            }
            for (big, row) in w.iter().enumerate() {
                let mut expect = vec![0f32; n];
                for (t, kt) in k.iter().enumerate() {
                    expect[pyramid::reflect101(2 * big as isize + t as isize - 2, n)] += kt;
                }
                assert!(max_diff(row, &expect) < 1e-7, "n {n}, destination {big}");
            }
        }
    }
}
