//! Stage 4, merging (paper section 4.2, `docs/method.md` section 4): the photographs'
//! resampled layers combined into one atlas without seams. In: the mesh with its [`Atlas`], the
//! [`Binding`] and its [`Gains`], the photographs. Out: [`Resampled`] (atlas colour, texel
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
    check_photo_count, resample_with, PhotoSampler, ResampleOptions, Resampled, Sampler,
    TexelSource, NO_PHOTO,
};
use crate::resample::{face_runs, FaceLists};
use crate::scene::Photo;
use half::f16;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};

mod accum;
mod layer;
mod photo;
use accum::*;
use layer::*;
use photo::*;

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
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "none" => Ok(Merge::None),
            "average" => Ok(Merge::Average),
            "multiband" => Ok(Merge::Multiband),
            _ => Err(format!(
                "unknown merge '{s}' (expected none, average or multiband)"
            )),
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
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "paper" => Ok(Masks::Paper),
            "weighted" => Ok(Masks::Weighted),
            "best-view" => Ok(Masks::BestView),
            _ => Err(format!(
                "unknown masks '{s}' (expected paper, weighted or best-view)"
            )),
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
    /// Texturing with restoration levels once, after restoration ([`relevel`]), instead.
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

/// What a multiband merge measured (zero and `None` for `--merge none|average`).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct MergeStats {
    /// Thread-seconds spent sampling texels from photographs (the rest of stage 3's
    /// `seconds_texels` is building and adding the bands).
    pub cpu_seconds_sampling: f64,
    /// Seconds of the complement layers, the collapse of every chart and its copy into the
    /// atlas.
    pub seconds_collapse: f64,
    /// Photographs decoded for this page: those some face on it samples (the others have
    /// nothing to give it).
    pub photos_decoded: usize,
    /// Chart-border levelling after the merge, if it ran (texturing without restoration).
    pub seam_levelling: Option<level::LevelStats>,
    /// The same on the restored atlas ([`relevel`]), if it ran (set by the caller).
    pub seam_levelling_after_restore: Option<level::LevelStats>,
}

/// Stage 4: the photographs resampled into `atlas` and merged as `mopts` says. `normals` are
/// unit vertex normals of `mesh`; `binding` and `gains` are stage 2b's.
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
) -> Result<(Resampled, MergeStats)> {
    mopts.validate()?;
    let prep = Sampler::new(mesh, atlas, normals, binding, gains, ropts)?;
    let plain = |winner| {
        Ok((
            resample_with(&prep, photos, ropts, winner, progress)?,
            MergeStats::default(),
        ))
    };
    match mopts.merge {
        Merge::None => plain(true),
        Merge::Average => plain(false),
        Merge::Multiband => multiband(&prep, photos, ropts, mopts, progress),
    }
}

#[allow(clippy::too_many_arguments)]
fn multiband(
    prep: &Sampler,
    photos: &[Photo],
    ropts: &ResampleOptions,
    mopts: &MergeOptions,
    progress: &dyn Progress,
) -> Result<(Resampled, MergeStats)> {
    let (mesh, atlas, binding) = (prep.mesh(), prep.atlas(), prep.binding());
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
    // In runs of faces, flat: a list per face was three allocations per face per page (56
    // bytes and a malloc each, at 1.17M faces).
    let nf = mesh.num_faces();
    let parts: Vec<(Vec<f32>, FaceLists)> = face_runs(nf)
        .into_par_iter()
        .map(|run| {
            let mut refs = Vec::with_capacity(run.len());
            let mut full = FaceLists::default();
            let mut ws: Vec<(f32, u32)> = Vec::new();
            let mut top: Vec<u32> = Vec::new();
            for f in run {
                let fv = mesh.faces[f];
                ws.clear();
                ws.extend(prep.photos_of(f).iter().map(|&p| {
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
                }));
                refs.push(ws.iter().map(|w| w.0).fold(0f32, f32::max));
                if k_full == 0 || ws.len() <= k_full {
                    full.push(&mut []);
                    continue;
                }
                ws.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
                top.clear();
                top.extend(ws[..k_full].iter().map(|w| w.1));
                full.push(&mut top);
            }
            (refs, full)
        })
        .collect();
    let mut face_ref = Vec::with_capacity(nf);
    let mut face_full = FaceLists::default();
    for (r, l) in parts {
        face_ref.extend(r);
        face_full.append(l);
    }
    let mut accs: Vec<ChartAcc> = charts
        .par_iter()
        .map(|ch| ChartAcc::new(ch, paper, winner_mode))
        .collect();
    let (mut seconds_setup, mut seconds_charts) = (0.0, 0.0);
    let cpu_sampling = AtomicU64::new(0);
    progress.start("merging", photos.len() as u64);
    let heap = crate::io::LargeBlocksInHeap::new();
    // The next photograph's depth map and mip levels are built while this one is sampled.
    let wanted = prep.photos_on_page(photos.len());
    let spare = crate::resample::SpareLevels::for_loop(wanted.iter().filter(|&&w| w).count());
    let setup =
        |pi: usize, rgb: &crate::io::image::PhotoPixels, mask: Option<&image::GrayImage>| {
            prep.photo_setup(photos, pi, rgb, mask, &spare)
        };
    for_each_photo_with(
        photos,
        Some(&wanted),
        progress,
        setup,
        |pi, rgb, _mask, setup| {
            seconds_setup += setup.seconds;
            let ph = prep.photo_with(photos, pi, rgb, setup);
            let t = std::time::Instant::now();
            // One task per chart, largest first: rayon's adaptive split hands each core a run of
            // charts, and a run holding the largest ones left the other core idle (the corset's
            // photo loop took 3.6 s on two cores and 3.3 s on one).
            let mut jobs: Vec<(&mut ChartAcc, &Chart)> = accs.iter_mut().zip(&charts).collect();
            jobs.sort_by_key(|(_, ch)| std::cmp::Reverse(ch.w * ch.h));
            jobs.into_par_iter().with_max_len(1).for_each(|(acc, ch)| {
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
            spare.give(ph);
            Ok(())
        },
    )?;
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
    let levelling = mopts.level_seams.then(|| {
        let owner = |i: usize| prep.owner(i);
        level::level_seams(mesh, n, &owner, face_chart, &mut color, level::SMOOTHNESS)
    });
    let out = prep.finish(
        color,
        source,
        views,
        best,
        ropts,
        (seconds_setup, seconds_charts),
    );
    let stats = MergeStats {
        cpu_seconds_sampling: cpu_sampling.load(Ordering::Relaxed) as f64 * 1e-9,
        seconds_collapse,
        photos_decoded: wanted.iter().filter(|&&w| w).count(),
        seam_levelling: levelling,
        seam_levelling_after_restore: None,
    };
    Ok((out, stats))
}

/// Writes chart `ch` (number `ci`) into the atlas arrays `out` (colour, source, views, best
/// photograph) at the texels it owns, a stripe of rows at a time in parallel. `img` is the
/// collapsed chart, or with `expand` (best-view masks, coarser levels) its level 1, expanded
/// by [`blended_rows`] with the finest band in `acc`: the same arithmetic as
/// [`pyramid::expand`] on the whole chart, without a chart-sized image.
#[allow(clippy::too_many_arguments)]
fn write_chart(
    prep: &Sampler,
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
/// gutter is left as it was (the caller fills it again after the last step that changes chart
/// colours, [`crate::resample::refill_gutter`]).
pub fn relevel(mesh: &Mesh, atlas: &Atlas, res: &mut Resampled) -> Result<level::LevelStats> {
    let n = res.color.width() as usize;
    if n != atlas.size as usize {
        return Err(Error::Internal(
            "levelling an atlas with the texels of another size".into(),
        ));
    }
    let own = |i: usize| atlas.owner(i);
    let color: &mut [f32] = &mut res.color;
    Ok(level::level_seams(
        mesh,
        n,
        &own,
        &atlas.face_chart,
        color,
        level::SMOOTHNESS,
    ))
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

    /// The expansion taps worked out once per column and row of a layer are, texel by
    /// texel, those of the kernel's rule ([`up_taps`] clipped to the layer, [`for_taps_in`]),
    /// in the same order (so the same sums), for a part of a chart away from its origin and
    /// reaching its far border, at every level.
    #[test]
    fn expansion_taps_per_row_and_column_are_the_per_texel_ones() {
        let (w, h, levels) = (45, 38, 2);
        let acc = ChartAcc::new(&chart(w, h, levels), false, false);
        let (ox, oy) = (8, 4);
        let mut layer = Layer::new((ox, oy), (w - ox, 29), acc.sizes(), 0.4);
        layer.splat(20, 20, [0.5; 3], 1.0, 1.0);
        layer.reduce();
        let k = pyramid::kernel(0.4);
        let mut checked = 0;
        for l in 0..levels {
            let up = layer.up_grid(l);
            let g = &layer.g[l];
            let (nw, nh) = layer.chart[l + 1];
            // The level-l texels of the part.
            let (pw, ph) = if l == 0 {
                (w - ox, 29)
            } else {
                (layer.g[l - 1].w, layer.g[l - 1].h)
            };
            for y in (oy >> l)..(oy >> l) + ph {
                for x in (ox >> l)..(ox >> l) + pw {
                    let mut rule = Vec::new();
                    for_taps_in(
                        up_taps(x, nw, &k),
                        up_taps(y, nh, &k),
                        (ox >> (l + 1), oy >> (l + 1)),
                        (g.w, g.h),
                        |i, wt| rule.push((i, wt)),
                    );
                    let (xi, xw, xn) = up.cols[x - up.origin.0];
                    let (yi, yw, yn) = up.rows[y - up.origin.1];
                    let mut grid = Vec::new();
                    for b in 0..yn {
                        for a in 0..xn {
                            grid.push((yi[b] * g.w + xi[a], xw[a] * yw[b]));
                        }
                    }
                    assert_eq!(rule, grid, "level {l} texel ({x}, {y})");
                    assert!(!grid.is_empty());
                    checked += 1;
                }
            }
        }
        assert!(checked > 1000, "{checked}");
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
