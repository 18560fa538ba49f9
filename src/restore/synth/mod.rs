//! Multiresolution synthesis of the high band (§5.3-5.4): a Gaussian pyramid of the band and
//! of the mask, then, coarsest level first, non-parametric sampling of every masked texel
//! (Wei and Levoy 2000) with the neighbourhood vector of a 5x5 causal kernel at the level, a
//! 3x3 kernel one level up and 1x1 above; shrinking fill order by Manhattan distance; eight
//! orientations of the causal kernel, each with its own kd-tree (kiddo); coherence candidates
//! (Ashikhmin 2001) against the tree's match with Hertzmann et al.'s switch.
//!
//! Holes are independent when their kernels cannot touch (components of the mask at
//! Chebyshev distance 2), so they run in parallel. The source of a hole is the known texels in
//! a window around it (windows that overlap are merged into one cluster with one set of
//! trees), which keeps synthesis local on a large atlas and makes it global on a small image.

// Pixel loops index several parallel arrays by the same texel: ranges read clearer here.
#![allow(clippy::needless_range_loop)]

use crate::mesh::UnionFind;
use crate::rng::SplitMix64;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde::Serialize;
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::num::NonZero;
use std::time::Instant;

mod schedule;
mod search;
use schedule::*;
pub(crate) use search::MAX_DIMS;
use search::*;

/// One level of the high-band pyramid.
#[derive(Debug, Clone)]
pub(crate) struct Level {
    pub w: usize,
    pub h: usize,
    /// Interleaved channels.
    pub data: Vec<f32>,
    /// Texels that exist (chart texels of an atlas; everything in a plain image).
    pub domain: Vec<bool>,
    /// Texels to synthesise (a subset of the domain).
    pub mask: Vec<bool>,
    /// The domain without the mask: texels a source may read. Kept beside the two because
    /// testing a source reads it thirteen times; private, so that only [`Level::new`] sets
    /// it from them.
    known: Vec<bool>,
}

impl Level {
    fn new(w: usize, h: usize, data: Vec<f32>, domain: Vec<bool>, mask: Vec<bool>) -> Level {
        let known = domain.iter().zip(&mask).map(|(&d, &m)| d && !m).collect();
        Level {
            w,
            h,
            data,
            domain,
            mask,
            known,
        }
    }

    #[inline]
    fn known(&self, i: usize) -> bool {
        self.known[i]
    }
}

const W5: [f32; 5] = [0.05, 0.25, 0.4, 0.25, 0.05];

/// Gaussian pyramid (5x5, a = 0.4) of the band and of the mask, `levels` levels in all.
/// Reduction is normalised over the domain, so gutter never enters a chart's values; a
/// coarse texel is in the domain if any texel of its 2x2 block is, and masked if any masked
/// texel falls under its kernel (the paper's "any value above 0").
pub(crate) fn pyramid(
    band: Vec<f32>,
    w: usize,
    h: usize,
    ch: usize,
    mask: &[bool],
    domain: &[bool],
    levels: usize,
) -> Vec<Level> {
    let mut out = vec![Level::new(
        w,
        h,
        band,
        domain.to_vec(),
        mask.iter().zip(domain).map(|(&m, &d)| m && d).collect(),
    )];
    while out.len() < levels {
        let l = out.last().expect("level 0 exists");
        let (w2, h2) = (l.w.div_ceil(2), l.h.div_ceil(2));
        let rows: Vec<(Vec<f32>, Vec<bool>, Vec<bool>)> = (0..h2)
            .into_par_iter()
            .map(|y2| {
                let mut d = vec![0f32; w2 * ch];
                let mut dom = vec![false; w2];
                let mut m = vec![false; w2];
                for x2 in 0..w2 {
                    for y in 2 * y2..(2 * y2 + 2).min(l.h) {
                        for x in 2 * x2..(2 * x2 + 2).min(l.w) {
                            dom[x2] |= l.domain[y * l.w + x];
                        }
                    }
                    if !dom[x2] {
                        continue;
                    }
                    let mut acc = [0f32; 4];
                    let (mut ws, mut ms) = (0f32, 0f32);
                    for (v, wv) in W5.iter().enumerate() {
                        let y = 2 * y2 as i64 + v as i64 - 2;
                        if y < 0 || y >= l.h as i64 {
                            continue;
                        }
                        for (u, wu) in W5.iter().enumerate() {
                            let x = 2 * x2 as i64 + u as i64 - 2;
                            if x < 0 || x >= l.w as i64 {
                                continue;
                            }
                            let i = y as usize * l.w + x as usize;
                            if !l.domain[i] {
                                continue;
                            }
                            let k = wu * wv;
                            for c in 0..ch {
                                acc[c] += k * l.data[i * ch + c];
                            }
                            ws += k;
                            if l.mask[i] {
                                ms += k;
                            }
                        }
                    }
                    for c in 0..ch {
                        d[x2 * ch + c] = acc[c] / ws;
                    }
                    m[x2] = ms > 0.0;
                }
                (d, dom, m)
            })
            .collect();
        let (mut data, mut dm, mut mk) = (
            Vec::with_capacity(w2 * h2 * ch),
            Vec::with_capacity(w2 * h2),
            Vec::with_capacity(w2 * h2),
        );
        for (d, dom, m) in rows {
            data.extend(d);
            dm.extend(dom);
            mk.extend(m);
        }
        out.push(Level::new(w2, h2, data, dm, mk));
    }
    out
}

/// The causal half of a 5x5 kernel in scanline order: two rows above, two texels to the left.
const CAUSAL: [(i32, i32); 12] = [
    (-2, -2),
    (-1, -2),
    (0, -2),
    (1, -2),
    (2, -2),
    (-2, -1),
    (-1, -1),
    (0, -1),
    (1, -1),
    (2, -1),
    (-2, 0),
    (-1, 0),
];

/// Offset `d` of the causal kernel in orientation `o` (0..8: the symmetries of the square).
const fn orient(o: usize, d: (i32, i32)) -> (i32, i32) {
    let (a, b) = if o & 4 != 0 { (d.1, d.0) } else { d };
    (
        if o & 1 != 0 { -a } else { a },
        if o & 2 != 0 { -b } else { b },
    )
}

/// One orientation's kernel offsets and their bounding box (see [`KERNELS`]).
type Kernel = ([(i32, i32); 12], [i32; 4]);

/// The causal kernel's offsets in each orientation, and their bounding box (min x, min y,
/// max x, max y): a texel's kernel lies inside the level when the box does, so finding its
/// twelve texels is one bounds test and twelve additions instead of twelve divisions.
const KERNELS: [Kernel; 8] = {
    let mut out: [Kernel; 8] = [([(0, 0); 12], [0; 4]); 8];
    let mut o = 0;
    while o < 8 {
        let mut n = 0;
        let mut b = [i32::MAX, i32::MAX, i32::MIN, i32::MIN];
        while n < 12 {
            let d = orient(o, CAUSAL[n]);
            out[o].0[n] = d;
            if d.0 < b[0] {
                b[0] = d.0;
            }
            if d.1 < b[1] {
                b[1] = d.1;
            }
            if d.0 > b[2] {
                b[2] = d.0;
            }
            if d.1 > b[3] {
                b[3] = d.1;
            }
            n += 1;
        }
        out[o].1 = b;
        o += 1;
    }
    out
};

/// The texels of the causal kernel of `i` in orientation `o` ([`CAUSAL`] order), if all lie
/// inside the level.
#[inline]
fn kernel(l: &Level, i: usize, o: usize) -> Option<[usize; 12]> {
    let (x, y) = ((i % l.w) as i64, (i / l.w) as i64);
    let (k, b) = &KERNELS[o];
    if x + (b[0] as i64) < 0
        || y + (b[1] as i64) < 0
        || x + b[2] as i64 >= l.w as i64
        || y + b[3] as i64 >= l.h as i64
    {
        return None;
    }
    let w = l.w as i64;
    Some(std::array::from_fn(|n| {
        (i as i64 + k[n].1 as i64 * w + k[n].0 as i64) as usize
    }))
}

/// How nearest neighbours are found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Params {
    /// Exact kd-tree search on the full neighbourhood vectors (the paper); otherwise PCA
    /// (95% of the variance, at most 8 components) with exact re-ranking of `rerank`.
    pub exact: bool,
    /// Hertzmann's coherence parameter.
    pub coherence: f32,
    /// Seeds the choice of source texels when a window holds more than `max_sources`.
    pub seed: u64,
    /// Source texels per orientation and window (0 = all).
    pub max_sources: usize,
    /// Window margin around a hole, in texels of level 0.
    pub margin: usize,
    /// Candidates re-ranked on full vectors (fast search).
    pub rerank: usize,
}

/// What synthesis did at one level.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LevelStats {
    /// Level (0 = full resolution).
    pub level: usize,
    /// Size of the level (on an atlas: of the first crop).
    pub width: usize,
    /// Size of the level.
    pub height: usize,
    /// Texels synthesised.
    pub texels: u64,
    /// Of those, taken from a coherence candidate.
    pub coherent: u64,
    /// Texels that ran the exact tree search (the others were settled by the coherent
    /// candidate against the tree's descent, [`DESCENT_MARGIN`]).
    pub searched: u64,
    /// Texels no kernel orientation ever fitted (left at zero detail: low band only).
    pub stalled: u64,
    /// Source windows (sets of trees).
    pub windows: usize,
    /// Source texels in all trees.
    pub sources: u64,
    /// Length of the neighbourhood vector.
    pub dims: usize,
    /// Mean length of the reduced vector (fast search; equal to `dims` for exact search).
    pub reduced_dims: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Synthesises the masked texels of every level, coarsest first.
pub(crate) fn synthesize(levels: &mut [Level], ch: usize, p: &Params) -> Vec<LevelStats> {
    let n = levels.len();
    let mut stats = Vec::new();
    for i in (0..n).rev() {
        let t = Instant::now();
        let (fine, coarse) = levels.split_at_mut(i + 1);
        let cur = &fine[i];
        let (results, mut st) = synthesize_level(cur, coarse, i, ch, p);
        let cur = &mut fine[i];
        for (idx, v) in results {
            cur.data[idx * ch..idx * ch + ch].copy_from_slice(&v[..ch]);
        }
        st.seconds = t.elapsed().as_secs_f64();
        stats.push(st);
    }
    stats
}

/// Neighbourhood layout of level `i` of `n`.
fn dims(i: usize, n: usize, ch: usize) -> usize {
    let above = n - 1 - i;
    ch * (12 + if above >= 1 { 9 } else { 0 } + above.saturating_sub(1))
}

/// Appends texel `j`'s `ch` channels of `data` to `out`. Three channels (every atlas) are
/// copied as a fixed-size array: a slice of run-time length is a call to `memcpy`, which was
/// the largest single item of building the sources' vectors (`perf` on the corset scene).
#[inline(always)]
fn push_texel(out: &mut Vec<f32>, data: &[f32], j: usize, ch: usize) {
    if ch == 3 {
        let t: &[f32; 3] = data[j * 3..j * 3 + 3].try_into().expect("three channels");
        out.extend_from_slice(t);
    } else {
        out.extend_from_slice(&data[j * ch..j * ch + ch]);
    }
}

/// Appends the coarser levels' part of the neighbourhood of level-`i` texel (x, y).
fn context(coarse: &[Level], x: usize, y: usize, ch: usize, out: &mut Vec<f32>) {
    for (k, l) in coarse.iter().enumerate() {
        let s = k + 1;
        let (px, py) = ((x >> s).min(l.w - 1), (y >> s).min(l.h - 1));
        let centre = py * l.w + px;
        if k == 0 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let xx = (px as i64 + dx).clamp(0, l.w as i64 - 1) as usize;
                    let yy = (py as i64 + dy).clamp(0, l.h as i64 - 1) as usize;
                    let mut j = yy * l.w + xx;
                    // Outside the domain stands the centre (which is inside): no gutter.
                    if !l.domain[j] {
                        j = centre;
                    }
                    push_texel(out, &l.data, j, ch);
                }
            }
        } else {
            push_texel(out, &l.data, centre, ch);
        }
    }
}

/// Level-`i` texel at offset `d` from `idx`, if inside the image.
#[inline]
fn offset(l: &Level, idx: usize, d: (i32, i32)) -> Option<usize> {
    let x = (idx % l.w) as i64 + d.0 as i64;
    let y = (idx / l.w) as i64 + d.1 as i64;
    if x < 0 || y < 0 || x >= l.w as i64 || y >= l.h as i64 {
        None
    } else {
        Some(y as usize * l.w + x as usize)
    }
}

/// Whether `q` can be a source for orientation `o`: it and its causal kernel are known.
fn valid_source(l: &Level, q: usize, o: usize) -> bool {
    l.known(q) && kernel(l, q, o).is_some_and(|k| k.iter().all(|&j| l.known(j)))
}

/// Full neighbourhood vector of source texel `q` for orientation `o`.
fn source_vector(l: &Level, coarse: &[Level], q: usize, o: usize, ch: usize, out: &mut Vec<f32>) {
    out.clear();
    for j in kernel(l, q, o).expect("valid source") {
        push_texel(out, &l.data, j, ch);
    }
    context(coarse, q % l.w, q / l.w, ch, out);
}

/// A 64-bit key of a vector's bits for finding repeated vectors: FNV-1a in four lanes (the
/// dimensions modulo 4), combined in order. One lane's multiplications form a chain of
/// dependent steps, four lanes run side by side. A collision merely drops one more source.
fn vector_key(v: &[f32]) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01B3;
    let mut h = [0xcbf2_9ce4_8422_2325u64; 4];
    let mut it = v.chunks_exact(4);
    for c in &mut it {
        for (h, x) in h.iter_mut().zip(c) {
            *h = (*h ^ x.to_bits() as u64).wrapping_mul(PRIME);
        }
    }
    for (h, x) in h.iter_mut().zip(it.remainder()) {
        *h = (*h ^ x.to_bits() as u64).wrapping_mul(PRIME);
    }
    h.iter().fold(v.len() as u64, |a, &b| {
        (a ^ b).wrapping_mul(PRIME).rotate_left(29)
    })
}

#[inline]
fn dist2(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// One orientation's sources in one window.
struct Sources {
    positions: Vec<u32>,
    vectors: Vec<f32>,
    pca: Option<Pca>,
    tree: Option<Box<dyn Search>>,
}

type Fill = (usize, [f32; 4]);
/// A hole's fill order ((texel, orientation) pairs) and its stalled texels.
type Schedule = (Vec<(usize, u8)>, Vec<usize>);

fn synthesize_level(
    l: &Level,
    coarse: &[Level],
    i: usize,
    ch: usize,
    p: &Params,
) -> (Vec<Fill>, LevelStats) {
    let n = coarse.len() + 1 + i;
    let dim = dims(i, n, ch);
    let mut st = LevelStats {
        level: i,
        width: l.w,
        height: l.h,
        dims: dim,
        ..Default::default()
    };
    let comps = components(l);
    if comps.is_empty() {
        return (Vec::new(), st);
    }
    let dist = distances(l);
    let mut slot = vec![u32::MAX; l.w * l.h];
    for c in &comps {
        for (k, &t) in c.iter().enumerate() {
            slot[t] = k as u32;
        }
    }
    let margin = (p.margin >> i).max(8);
    let rects: Vec<Rect> = comps
        .iter()
        .map(|c| {
            let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
            for &t in c {
                let (x, y) = (t % l.w, t / l.w);
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
            Rect {
                x0: x0.saturating_sub(margin),
                y0: y0.saturating_sub(margin),
                x1: (x1 + margin).min(l.w),
                y1: (y1 + margin).min(l.h),
            }
        })
        .collect();
    // Merge holes whose windows overlap (sweep along x), so each window builds one set of
    // trees.
    let mut sets = UnionFind::new(comps.len());
    let mut by_x: Vec<usize> = (0..comps.len()).collect();
    by_x.sort_by_key(|&k| (rects[k].x0, k));
    for a in 0..by_x.len() {
        for b in a + 1..by_x.len() {
            let (ra, rb) = (&rects[by_x[a]], &rects[by_x[b]]);
            if rb.x0 >= ra.x1 {
                break;
            }
            if ra.overlaps(rb) {
                sets.union(by_x[a], by_x[b]);
            }
        }
    }
    let mut clusters: Vec<(Rect, Vec<usize>)> = Vec::new();
    let mut cid = vec![usize::MAX; comps.len()];
    for k in 0..comps.len() {
        let r = sets.find(k);
        if cid[r] == usize::MAX {
            cid[r] = clusters.len();
            clusters.push((rects[k], Vec::new()));
        }
        let c = &mut clusters[cid[r]];
        c.0 = c.0.union(&rects[k]);
        c.1.push(k);
    }
    // Windows can grow into one another after merging; that only means two sets of trees
    // share source texels, which is harmless.
    st.windows = clusters.len();
    // One task per cluster, hole and orientation (`with_max_len(1)`): their sizes differ by
    // orders of magnitude, and rayon's adaptive split would hand a core a run of them.
    let per_cluster: Vec<(Vec<Fill>, LevelStats)> = clusters
        .par_iter()
        .with_max_len(1)
        .enumerate()
        .map(|(ci, (rect, members))| {
            let scheds: Vec<Schedule> = members
                .par_iter()
                .with_max_len(1)
                .map(|&k| schedule(l, &comps[k], &dist, &slot))
                .collect();
            let mut used = [0usize; 8];
            for (order, _) in &scheds {
                for &(_, o) in order {
                    used[o as usize] += 1;
                }
            }
            let sources: Vec<Option<Sources>> = (0..8)
                .into_par_iter()
                .with_max_len(1)
                .map(|o| {
                    (used[o] > 0).then(|| {
                        let cap = source_cap(p.max_sources, used[o]);
                        let seed = (i * 131 + ci) as u64;
                        build_sources(l, coarse, rect, o, ch, dim, p, cap, seed)
                    })
                })
                .collect();
            let mut cs = LevelStats::default();
            for s in sources.iter().flatten() {
                cs.sources += s.positions.len() as u64;
                cs.reduced_dims += s.pca.as_ref().map_or(dim, |pc| pc.rows) as f64;
            }
            let fills: Vec<(Vec<Fill>, u64, u64, u64)> = members
                .par_iter()
                .zip(&scheds)
                .with_max_len(1)
                .map(|(&k, sched)| {
                    fill_hole(l, coarse, &comps[k], &slot, sched, &sources, rect, i, ch, p)
                })
                .collect();
            let mut out = Vec::new();
            for (f, coherent, stalled, searched) in fills {
                cs.texels += f.len() as u64 - stalled;
                cs.coherent += coherent;
                cs.searched += searched;
                cs.stalled += stalled;
                out.extend(f);
            }
            cs.windows = sources.iter().flatten().count();
            (out, cs)
        })
        .collect();
    let mut out = Vec::new();
    let mut trees = 0usize;
    for (f, cs) in per_cluster {
        out.extend(f);
        st.texels += cs.texels;
        st.coherent += cs.coherent;
        st.searched += cs.searched;
        st.stalled += cs.stalled;
        st.sources += cs.sources;
        st.reduced_dims += cs.reduced_dims;
        trees += cs.windows;
    }
    if trees > 0 {
        st.reduced_dims /= trees as f64;
    }
    (out, st)
}

/// Source texels drawn per tree: as many as the window offers up to `max` (0: no limit), but
/// no more than [`SOURCES_PER_QUERY`] per texel the tree serves (with a floor of
/// [`MIN_SOURCES`]): a tree that answers a few hundred queries at a coarse level or for a rare
/// kernel orientation does not need the sources of one that answers tens of thousands, and
/// building it dominated synthesis.
fn source_cap(max: usize, queries: usize) -> usize {
    if max == 0 {
        return 0;
    }
    (queries * SOURCES_PER_QUERY).clamp(MIN_SOURCES.min(max), max)
}

/// See [`source_cap`].
const SOURCES_PER_QUERY: usize = 8;

/// See [`source_cap`].
const MIN_SOURCES: usize = 4096;

/// How much better than the tree's descent-only match the coherent candidate must be (on top
/// of Hertzmann's factor) to be taken without the exact search. The descent's match is no
/// nearer in the reduced space than the exact search's, so without a margin every texel
/// whose exact match would have won by less than the gap between the two took the coherent
/// candidate instead. On the 54 OpenCV cases (`tests/it/restore_reference.rs`), mean PSNR
/// against searching every texel with the same seed: 1 lost 0.06 dB (two seeds), 2 lost 0.03
/// (eleven), 4 lost 0.01 (ten; between seeds the mean moves by 0.08 dB); synthesis of the
/// 4096² benchmark took 5.5, 7.1 and 7.9 s against 19.0 s (`docs/decisions.md`, "The exact
/// search only where it could win").
const DESCENT_MARGIN: f32 = 4.0;

#[allow(clippy::too_many_arguments)]
fn build_sources(
    l: &Level,
    coarse: &[Level],
    rect: &Rect,
    o: usize,
    ch: usize,
    dim: usize,
    p: &Params,
    max_sources: usize,
    salt: u64,
) -> Sources {
    let mut rng = SplitMix64::new(p.seed ^ salt.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ o as u64);
    let (rw, rh) = (rect.x1 - rect.x0, rect.y1 - rect.y0);
    let mut positions: Vec<u32> = Vec::new();
    // A window much larger than the sample: draw texels at random and keep the valid ones
    // (uniform over the valid texels, as the full scan below), instead of testing every
    // texel of a 4096x4096 window for each of eight orientations. Windows with few valid
    // texels (an atlas's sparse charts) fall back to the scan.
    if max_sources > 0 && rw * rh > 4 * max_sources {
        let mut taken = rustc_hash::FxHashSet::default();
        taken.reserve(max_sources);
        for _ in 0..8 * max_sources {
            if positions.len() == max_sources {
                break;
            }
            let r = rng.next_u64();
            let x = rect.x0 + (r % rw as u64) as usize;
            let y = rect.y0 + ((r >> 32) % rh as u64) as usize;
            let q = y * l.w + x;
            if valid_source(l, q, o) && taken.insert(q) {
                positions.push(q as u32);
            }
        }
        if positions.len() < max_sources {
            positions.clear();
        }
    }
    if positions.is_empty() {
        for y in rect.y0..rect.y1 {
            for x in rect.x0..rect.x1 {
                let q = y * l.w + x;
                if valid_source(l, q, o) {
                    positions.push(q as u32);
                }
            }
        }
        if max_sources > 0 && positions.len() > max_sources {
            for k in 0..max_sources {
                let j = k + (rng.next_u64() % (positions.len() - k) as u64) as usize;
                positions.swap(k, j);
            }
            positions.truncate(max_sources);
        }
    }
    positions.sort_unstable();
    let mut vectors = Vec::with_capacity(positions.len() * dim);
    let mut v = Vec::with_capacity(dim);
    // Flat regions give thousands of identical neighbourhoods, which make kd-tree queries
    // scan whole buckets of ties: keep one texel per distinct vector (the first in scan
    // order; coherence candidates still reach every texel).
    let mut seen = rustc_hash::FxHashSet::default();
    seen.reserve(positions.len());
    let mut kept = Vec::with_capacity(positions.len());
    for &q in &positions {
        source_vector(l, coarse, q as usize, o, ch, &mut v);
        if seen.insert(vector_key(&v)) {
            vectors.extend_from_slice(&v);
            kept.push(q);
        }
    }
    let positions = kept;
    if positions.is_empty() {
        return Sources {
            positions,
            vectors,
            pca: None,
            tree: None,
        };
    }
    let (pca, tree) = if p.exact {
        (None, build_tree(&vectors, dim))
    } else {
        let pca = Pca::fit(&vectors, dim, 0.95);
        let mut red = Vec::with_capacity(positions.len() * pca.rows);
        let mut r = Vec::new();
        for c in vectors.chunks(dim) {
            pca.project(c, &mut r);
            red.extend_from_slice(&r);
        }
        let t = build_tree(&red, pca.rows);
        (Some(pca), t)
    };
    Sources {
        positions,
        vectors,
        pca,
        tree: Some(tree),
    }
}

/// Fills one hole in its schedule's order. Returns the fills, how many came from coherence
/// candidates, how many stalled and how many ran the exact tree search.
#[allow(clippy::too_many_arguments)]
fn fill_hole(
    l: &Level,
    coarse: &[Level],
    comp: &[usize],
    slot: &[u32],
    sched: &Schedule,
    sources: &[Option<Sources>],
    rect: &Rect,
    i: usize,
    ch: usize,
    p: &Params,
) -> (Vec<Fill>, u64, u64, u64) {
    let (order, stalled) = sched;
    // Values and origins of the hole's texels as they are filled (indexed by `slot`).
    let mut vals = vec![[0f32; 4]; comp.len()];
    let mut origin = vec![u32::MAX; comp.len()];
    let mut done = vec![false; comp.len()];
    let dim = dims(i, coarse.len() + 1 + i, ch);
    let factor = 1.0 + p.coherence * 0.5f32.powi(i as i32);
    let mut query = Vec::with_capacity(dim);
    let mut cand = Vec::with_capacity(dim);
    let mut red = Vec::new();
    let mut hits = Vec::new();
    let mut coherent = 0u64;
    let mut searched = 0u64;
    let mut out = Vec::with_capacity(comp.len());
    for &(t, o) in order {
        let o = o as usize;
        query.clear();
        let kt = kernel(l, t, o).expect("scheduled kernels fit");
        for &j in &kt {
            if slot[j] != u32::MAX {
                query.extend_from_slice(&vals[slot[j] as usize][..ch]);
            } else {
                push_texel(&mut query, &l.data, j, ch);
            }
        }
        context(coarse, t % l.w, t / l.w, ch, &mut query);
        // Coherence (Ashikhmin): shift the origin of every synthesised neighbour back by its
        // offset.
        let mut best_coh: Option<(f32, u32)> = None;
        // Coherent neighbours usually propose the same texel: score each candidate once.
        let mut tried = [u32::MAX; 12];
        let mut ntried = 0;
        for (&j, &od) in kt.iter().zip(&KERNELS[o].0) {
            if slot[j] == u32::MAX || !done[slot[j] as usize] {
                continue;
            }
            let src = origin[slot[j] as usize];
            if src == u32::MAX {
                continue;
            }
            let Some(c) = offset(l, src as usize, (-od.0, -od.1)) else {
                continue;
            };
            let (cx, cy) = (c % l.w, c / l.w);
            if !rect.contains(cx, cy) || !valid_source(l, c, o) {
                continue;
            }
            if tried[..ntried].contains(&(c as u32)) {
                continue;
            }
            tried[ntried] = c as u32;
            ntried += 1;
            source_vector(l, coarse, c, o, ch, &mut cand);
            let dc = dist2(&query, &cand);
            if best_coh.is_none_or(|b| dc < b.0) {
                best_coh = Some((dc, c as u32));
            }
        }
        // Hertzmann's switch needs the exact match only where it could beat the coherent
        // candidate by the factor: the descent's match is no nearer than the exact one, so
        // when the coherent candidate wins against it by DESCENT_MARGIN as well, the exact
        // search is skipped (the paper's exact method searches every texel).
        let mut best: Option<(f32, u32, bool)> = None;
        let mut projected = false;
        let mut settled = false;
        if let (false, Some(bc), Some(s)) = (p.exact, best_coh, &sources[o]) {
            if let Some(tree) = &s.tree {
                let h = match &s.pca {
                    None => tree.descend(&query),
                    Some(pca) => {
                        pca.project(&query, &mut red);
                        projected = true;
                        tree.descend(&red)
                    }
                } as usize;
                let d = dist2(&query, &s.vectors[h * dim..(h + 1) * dim]);
                settled = bc.0 * DESCENT_MARGIN <= d * factor;
            }
        }
        if settled {
            // The coherent candidate is the pick.
        } else if let Some(s) = &sources[o] {
            searched += 1;
            if let Some(tree) = &s.tree {
                match &s.pca {
                    None => tree.nearest(&query, 1, &mut hits),
                    Some(pca) => {
                        if !projected {
                            pca.project(&query, &mut red);
                        }
                        tree.nearest(&red, p.rerank.min(s.positions.len()).max(1), &mut hits);
                    }
                }
                for &h in &hits {
                    let h = h as usize;
                    let d = dist2(&query, &s.vectors[h * dim..(h + 1) * dim]);
                    if best.is_none_or(|b| d < b.0) {
                        best = Some((d, s.positions[h], false));
                    }
                }
            }
        }
        let pick = match (best, best_coh) {
            (Some(a), Some(c)) if c.0 <= a.0 * factor => Some((c.1, true)),
            (Some(a), _) => Some((a.1, false)),
            (None, Some(c)) => Some((c.1, true)),
            (None, None) => None,
        };
        let mut v = [0f32; 4];
        let src = match pick {
            Some((q, coh)) => {
                coherent += coh as u64;
                let q = q as usize;
                v[..ch].copy_from_slice(&l.data[q * ch..q * ch + ch]);
                q as u32
            }
            // No source at all: no detail here (the low band alone).
            None => u32::MAX,
        };
        let k = slot[t] as usize;
        vals[k] = v;
        origin[k] = src;
        done[k] = true;
        out.push((t, v));
    }
    for &t in stalled {
        out.push((t, [0f32; 4]));
    }
    (out, coherent, stalled.len() as u64, searched)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_distinct_orientations() {
        let mut shapes: Vec<Vec<(i32, i32)>> = (0..8)
            .map(|o| {
                let mut s: Vec<_> = CAUSAL.iter().map(|&d| orient(o, d)).collect();
                s.sort();
                s
            })
            .collect();
        shapes.sort();
        shapes.dedup();
        assert_eq!(shapes.len(), 8);
    }

    #[test]
    fn dims_follow_the_paper() {
        // 5x5 causal (12) + 3x3 (9) + 1x1 per level above, per channel.
        assert_eq!(dims(0, 3, 3), 3 * (12 + 9 + 1));
        assert_eq!(dims(1, 3, 3), 3 * (12 + 9));
        assert_eq!(dims(2, 3, 3), 3 * 12);
        assert_eq!(dims(0, 4, 1), 12 + 9 + 2);
    }

    #[test]
    fn every_hole_texel_is_scheduled_once() {
        let (w, h) = (30, 20);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                (8..20).contains(&x) && (5..15).contains(&y) && !(x == 12 && y < 10)
            })
            .collect();
        let l = Level::new(w, h, vec![0.0; w * h], vec![true; w * h], mask);
        let comps = components(&l);
        assert_eq!(comps.len(), 1);
        let mut slot = vec![u32::MAX; w * h];
        for (k, &t) in comps[0].iter().enumerate() {
            slot[t] = k as u32;
        }
        let (order, stalled) = schedule(&l, &comps[0], &distances(&l), &slot);
        assert!(stalled.is_empty());
        let mut seen: Vec<usize> = order.iter().map(|x| x.0).collect();
        seen.sort();
        assert_eq!(seen, comps[0]);
        // Every kernel reads only known or earlier-filled texels.
        let mut filled = std::collections::HashSet::new();
        for &(t, o) in &order {
            for &d in &CAUSAL {
                let j = offset(&l, t, orient(o as usize, d)).unwrap();
                assert!(l.known(j) || filled.contains(&j));
            }
            filled.insert(t);
        }
    }

    #[test]
    fn coherence_settles_a_periodic_texture_without_the_tree() {
        // A random 7 x 5 tile repeated: every hole texel has an exact match, and once the
        // first ones are placed the coherent candidate matches exactly too, so the fast
        // search continues the pattern while running the tree on few texels; the paper's
        // exact method searches every one.
        let (w, h) = (96, 80);
        let mut rng = SplitMix64::new(7);
        let tile: Vec<f32> = (0..35)
            .map(|_| (rng.next_u64() % 1000) as f32 / 1000.0)
            .collect();
        let truth: Vec<f32> = (0..w * h)
            .map(|i| tile[(i / w % 5) * 7 + i % w % 7])
            .collect();
        let mask: Vec<bool> = (0..w * h)
            .map(|i| (30..60).contains(&(i % w)) && (25..55).contains(&(i / w)))
            .collect();
        let band: Vec<f32> = (0..w * h)
            .map(|i| if mask[i] { 0.0 } else { truth[i] })
            .collect();
        for exact in [false, true] {
            let p = Params {
                exact,
                coherence: 10.0,
                seed: 1,
                max_sources: if exact { 0 } else { 16384 },
                margin: 16,
                rerank: 8,
            };
            let mut levels = pyramid(band.clone(), w, h, 1, &mask, &vec![true; w * h], 1);
            let st = synthesize(&mut levels, 1, &p);
            assert_eq!(st[0].texels, 900);
            assert_eq!(levels[0].data, truth, "exact = {exact}");
            if exact {
                assert_eq!(st[0].searched, 900);
            } else {
                assert!(st[0].searched < 90, "{} of 900 searched", st[0].searched);
            }
        }
    }
}
