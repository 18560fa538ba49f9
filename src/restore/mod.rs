//! Stage 5: restoration of texels no photograph saw (§5 of the paper). The image is split by
//! frequency with a DCT (`dct`); the low band is inpainted by diffusion (`diffuse`) and the
//! high band is synthesised from the rest of the image, coarse to fine (`synth`); the two are
//! summed. Works on any 2D image ([`inpaint`], `scantex inpaint`) and on the atlas after
//! merging ([`restore_atlas`]), where it reads chart texels only.

mod atlas;
mod dct;
mod diffuse;
mod regions;
mod synth;

pub use atlas::{picture, restore_atlas, Handing, Unrestored};
pub use regions::{feature_scale, Handover, UnseenRegion};
pub use synth::LevelStats;

use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::Serialize;
use std::time::Instant;

pub use crate::planar::Image;

/// How the high band's nearest neighbours are found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// As the paper: exact kd-tree search on the full 5x5-causal + 3x3 + 1x1 neighbourhood
    /// vectors (36 to 70 numbers for colour), over every known texel of the window.
    Paper,
    /// PCA of the neighbourhood vectors keeping 95% of the variance (at most 8 numbers), a
    /// kd-tree on the reduced vectors, exact re-ranking of the nearest few, over at most
    /// [`RestoreOptions::max_sources`] source texels per kernel orientation.
    #[default]
    Fast,
}

/// How many DCT subbands form the low band.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Kappa {
    /// The smallest kappa whose high band's autocorrelation has an element standard
    /// deviation below [`RestoreOptions::kappa_threshold`] (the paper's rule).
    #[default]
    Auto,
    /// This many subbands: 0 is pure synthesis, the image's longer side or more is pure
    /// diffusion inpainting.
    Fixed(usize),
}

impl std::fmt::Display for Method {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Paper => "paper",
            Method::Fast => "fast",
        })
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "paper" => Ok(Method::Paper),
            "fast" => Ok(Method::Fast),
            _ => Err(format!("unknown method '{s}' (expected paper or fast)")),
        }
    }
}

impl std::fmt::Display for Kappa {
    /// The text `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Kappa::Auto => f.write_str("auto"),
            Kappa::Fixed(k) => write!(f, "{k}"),
        }
    }
}

impl std::str::FromStr for Kappa {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "auto" {
            return Ok(Kappa::Auto);
        }
        s.parse::<usize>()
            .map(Kappa::Fixed)
            .map_err(|_| format!("kappa must be auto or a whole number of subbands, not '{s}'"))
    }
}

/// Options of the restoration stage and of `scantex inpaint`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RestoreOptions {
    /// Neighbour search. Default: [`Method::Fast`].
    pub method: Method,
    /// Low-band size. Default: [`Kappa::Auto`].
    pub kappa: Kappa,
    /// Threshold of the automatic kappa, on the element standard deviation of the per-pixel
    /// autocorrelation of intensities in [0, 1]. Default: 0.001 (the paper's).
    pub kappa_threshold: f64,
    /// Levels of the high-band pyramid (n + 1 in the paper), 1 to 8. Default: 3 (the paper
    /// found three or four best).
    pub levels: usize,
    /// Hertzmann's coherence parameter: a coherent candidate wins if its squared distance is
    /// within (1 + coherence * 2^-level) of the search's. Default: 10.
    pub coherence: f32,
    /// Seeds the choice of source texels when a window has more than `max_sources`.
    /// Default: 0.
    pub seed: u64,
    /// Fast method: source texels per kernel orientation and window, drawn at random with
    /// `seed`. Default: 16384.
    pub max_sources: usize,
    /// Margin of known texels around a hole that may serve as its source, in texels of the
    /// full-resolution level (halved per level, at least 8). Default: 64.
    pub margin: usize,
    /// Diffusion sweeps per level of the low band's coarse-to-fine cascade. Default: 20 (40
    /// gave the same figures on the 54 OpenCV comparison cases, within 0.004 dB, and took 0.8 s
    /// more on 4096x4096).
    pub sweeps: usize,
    /// Divide the high band by its local amplitude before synthesis and multiply the
    /// diffused amplitude back in the hole (not in the paper). Nearest-neighbour search
    /// favours low-contrast neighbourhoods, so under an intensity ramp the hole takes the
    /// dark side's faint detail; normalising removes that. Default: true.
    pub normalise_contrast: bool,
    /// How much of the synthesised band's local mean (three box passes of radius 1, sigma
    /// about 1.4 pixels) in the hole is replaced by the diffused local mean of the known side
    /// (not in the paper), 0 to 1. Synthesis copies texture, and with it a local mean
    /// unrelated to the truth's; 1 leaves synthesis only the finest detail (closest to the
    /// truth at coarse scales, flatter to the eye in large holes), 0 is the paper. Default: 0.6
    /// (the smallest that keeps every OpenCV comparison case within 1 dB of TELEA's
    /// low-frequency PSNR; `docs/decisions.md`).
    pub mean_from_diffusion: f32,
    /// Scale each hole's synthesised detail so that its fine-detail energy (the result minus
    /// its 7x7 blur) equals that of the known texels around it, by at most 2x either way (not
    /// in the paper). Pixel-wise synthesis joins pieces of different source texels, and every
    /// join adds an edge the surroundings do not have. Default: true.
    pub match_detail: bool,
}

impl Default for RestoreOptions {
    fn default() -> Self {
        RestoreOptions {
            method: Method::Fast,
            kappa: Kappa::Auto,
            kappa_threshold: 0.001,
            levels: 3,
            coherence: 10.0,
            seed: 0,
            max_sources: 16384,
            margin: 64,
            sweeps: 20,
            normalise_contrast: true,
            mean_from_diffusion: 0.6,
            match_detail: true,
        }
    }
}

/// High-band pyramid levels [`RestoreOptions`] accepts.
pub const LEVELS_RANGE: std::ops::RangeInclusive<usize> = 1..=8;

impl RestoreOptions {
    /// Checks ranges.
    pub fn validate(&self) -> Result<()> {
        if !LEVELS_RANGE.contains(&self.levels) {
            return Err(Error::option(
                "levels",
                format!("restoration levels must be 1 to 8, not {}", self.levels),
            ));
        }
        if !(self.coherence.is_finite() && self.coherence >= 0.0) {
            return Err(Error::option(
                "coherence",
                format!(
                    "the coherence parameter must be a finite number >= 0, not {}",
                    self.coherence
                ),
            ));
        }
        if !(self.kappa_threshold.is_finite() && self.kappa_threshold > 0.0) {
            return Err(Error::option(
                "kappa_threshold",
                format!(
                    "the kappa threshold must be > 0, not {}",
                    self.kappa_threshold
                ),
            ));
        }
        if !(0.0..=1.0).contains(&self.mean_from_diffusion) {
            return Err(Error::option(
                "mean_from_diffusion",
                format!(
                    "the weight of the diffused local mean must be 0 to 1, not {}",
                    self.mean_from_diffusion
                ),
            ));
        }
        if self.method == Method::Fast && self.max_sources == 0 {
            return Err(Error::option(
                "max_sources",
                "the fast method needs at least one source texel per tree",
            ));
        }
        Ok(())
    }
}

/// What restoration did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RestoreReport {
    /// Texels filled.
    pub texels: u64,
    /// Atlas: unseen texels in holes larger than the size limit, left for stage 6.
    pub texels_left_large: u64,
    /// Atlas: unseen texels in charts with no seen texel, left for stage 6.
    pub texels_left_unreachable: u64,
    /// Atlas: unseen texels of regions deeper than the depth limit, left for stage 6.
    pub texels_left_deep: u64,
    /// Atlas: the texture's feature scale, texels (0 for a plain image).
    pub feature_scale: f64,
    /// Subbands in the low band (atlas: the median over crops).
    pub kappa: usize,
    /// Atlas: crops restored separately (groups of nearby holes); 0 for a plain image.
    pub windows: usize,
    /// Whether kappa was chosen automatically.
    pub kappa_auto: bool,
    /// The automatic rule's curve: element standard deviation of the autocorrelation of the
    /// high band for kappa = 0, 1, ... (empty for a fixed kappa).
    pub autocorrelation_std: Vec<f64>,
    /// Neighbour search.
    pub method: Method,
    /// Per pyramid level, coarsest first.
    pub levels: Vec<LevelStats>,
    /// Seconds: frequency split (with kappa), low-band diffusion, high-band synthesis.
    pub seconds_split: f64,
    /// See `seconds_split`.
    pub seconds_diffusion: f64,
    /// See `seconds_split`.
    pub seconds_synthesis: f64,
    /// Texel-weighted mean of the holes' detail scales ([`RestoreOptions::match_detail`];
    /// 1 when off).
    pub detail_scale: f64,
    /// Wall-clock seconds in all.
    pub seconds: f64,
}

/// Longest side on which kappa is chosen: kappa counts cycles across the image, so a
/// box-downsampled copy gives the same count at a fraction of the cost.
const KAPPA_ANALYSIS_SIDE: usize = 512;
/// Box radius of the contrast envelope (three passes: sigma about 6 pixels).
const ENVELOPE_RADIUS: usize = 12;
/// Known texels within this Chebyshev distance of a hole get the blurred known band as the
/// boundary of the local mean's diffusion (see [`RestoreOptions::mean_from_diffusion`]).
const MEAN_RING: usize = 4;
/// Largest kappa the automatic rule tries.
const KAPPA_MAX_AUTO: usize = 16;
/// Known texels at grid distance `DETAIL_RING.0..=DETAIL_RING.1` from a hole measure the
/// detail it should have (the nearest ones are skipped: their blur reaches into the hole).
const DETAIL_RING: (u32, u32) = (3, 16);
/// Bounds of the detail scale.
const DETAIL_SCALE: (f64, f64) = (0.5, 1.0);

/// Fills the texels of `mask` (true = fill) of `image`. With a `domain`, texels outside it
/// are neither read nor written (an atlas's gutter); the mask is clipped to the domain.
pub fn inpaint(
    image: &Image,
    mask: &[bool],
    domain: Option<&[bool]>,
    opts: &RestoreOptions,
) -> Result<(Image, RestoreReport)> {
    opts.validate()?;
    let (w, h, ch) = (image.width, image.height, image.channels);
    if !(ch == 1 || ch == 3) || image.data.len() != w * h * ch || w == 0 || h == 0 {
        return Err(Error::Invalid(format!(
            "inpaint: a {w}x{h} image with {ch} channels and {} values is not a grey or RGB image",
            image.data.len()
        )));
    }
    if mask.len() != w * h || domain.is_some_and(|d| d.len() != w * h) {
        return Err(Error::Invalid(format!(
            "inpaint: the mask must have one value per pixel of the {w}x{h} image"
        )));
    }
    let full;
    let domain = match domain {
        Some(d) => d,
        None => {
            full = vec![true; w * h];
            &full
        }
    };
    let fill: Vec<bool> = mask.iter().zip(domain).map(|(&m, &d)| m && d).collect();
    let texels = fill.iter().filter(|&&f| f).count() as u64;
    let dims = ch * (12 + 9 + opts.levels.saturating_sub(2));
    if dims > synth::MAX_DIMS {
        return Err(Error::option(
            "levels",
            format!(
                "inpaint: {} levels make {dims}-number neighbourhoods; at most {} are supported",
                opts.levels,
                synth::MAX_DIMS
            ),
        ));
    }
    let wall = Instant::now();
    let mut report = RestoreReport {
        texels,
        method: opts.method,
        ..Default::default()
    };
    if texels == 0 || !domain.iter().zip(&fill).any(|(&d, &f)| d && !f) {
        // Nothing to fill, or nothing known to fill from: the image as it is.
        report.seconds = wall.elapsed().as_secs_f64();
        return Ok((image.clone(), report));
    }

    // The hole's current content must not reach the low band (it may be the truth, or the
    // vertex colours): fill it smoothly first, so the DCT sees only what is known.
    let mut t = Instant::now();
    let mut pre = image.data.clone();
    diffuse::inpaint(&mut pre, w, h, ch, &fill, domain, opts.sweeps);
    let kappa = match opts.kappa {
        Kappa::Fixed(k) => k.min(w.max(h)),
        Kappa::Auto => {
            let (y, sw, sh) = luminance_small(&pre, w, h, ch);
            let (k, curve) = dct::auto_kappa(
                &y,
                sw,
                sh,
                opts.kappa_threshold,
                KAPPA_MAX_AUTO.min(sw.max(sh)),
            );
            report.kappa_auto = true;
            report.autocorrelation_std = curve;
            k
        }
    };
    report.kappa = kappa;
    let mut low = vec![0f32; w * h * ch];
    let mut high = vec![0f32; w * h * ch];

    for c in 0..ch {
        let plane: Vec<f32> = (0..w * h).map(|i| pre[i * ch + c]).collect();
        let (l, hb) = dct::split(&plane, w, h, kappa);
        for i in 0..w * h {
            low[i * ch + c] = l[i];
            high[i * ch + c] = hb[i];
        }
    }
    drop(pre);
    report.seconds_split = lap(&mut t);

    // With kappa 0 the low band is zero, and diffusing zeros leaves zeros.
    if kappa > 0 {
        diffuse::inpaint(&mut low, w, h, ch, &fill, domain, opts.sweeps);
    }
    report.seconds_diffusion = lap(&mut t);

    let env = opts
        .normalise_contrast
        .then(|| diffuse::envelope(&high, w, h, ch, &fill, domain, ENVELOPE_RADIUS, opts.sweeps));
    if let Some(e) = &env {
        for i in 0..w * h {
            for c in 0..ch {
                high[i * ch + c] /= e[i];
            }
        }
    }
    let mut levels = synth::pyramid(high, w, h, ch, &fill, domain, opts.levels);
    let params = synth::Params {
        exact: opts.method == Method::Paper,
        coherence: opts.coherence,
        seed: opts.seed,
        max_sources: if opts.method == Method::Paper {
            0
        } else {
            opts.max_sources
        },
        margin: opts.margin,
        rerank: 8,
    };
    report.levels = synth::synthesize(&mut levels, ch, &params);
    if opts.mean_from_diffusion > 0.0 {
        // Synthesis copies texture, and with it a local mean that is unrelated to the
        // truth's; diffusion gets the mean right and the detail wrong. Keep the synthesised
        // band's fine detail only and take its local mean from diffusion of the known side.
        // Both means are needed in the holes only; the known side's is blurred where the
        // diffusion reads it closely (within `MEAN_RING` of a hole) and left as it is farther
        // out, where only block averages of the pull-push cascade see it. Blurring whole crops
        // took 1.1 of the corset's 7 CPU seconds of restoration.
        let hb = &mut levels[0].data;
        let known: Vec<bool> = (0..w * h).map(|i| domain[i] && !fill[i]).collect();
        let mut mean_known = hb.clone();
        let mut ring = vec![false; w * h];
        for i in (0..w * h).filter(|&i| fill[i]) {
            let (x, y) = (i % w, i / w);
            for yy in y.saturating_sub(MEAN_RING)..(y + MEAN_RING + 1).min(h) {
                for xx in x.saturating_sub(MEAN_RING)..(x + MEAN_RING + 1).min(w) {
                    ring[yy * w + xx] |= known[yy * w + xx];
                }
            }
        }
        let ring: Vec<usize> = (0..w * h).filter(|&i| ring[i]).collect();
        let blurred: Vec<[f32; 3]> = ring
            .par_iter()
            .map(|&i| local_mean(hb, w, h, ch, &known, i))
            .collect();
        for (&i, m) in ring.iter().zip(&blurred) {
            mean_known[i * ch..i * ch + ch].copy_from_slice(&m[..ch]);
        }
        diffuse::inpaint(&mut mean_known, w, h, ch, &fill, domain, opts.sweeps);
        let holes: Vec<usize> = (0..w * h).filter(|&i| fill[i]).collect();
        let mean_synth: Vec<[f32; 3]> = holes
            .par_iter()
            .map(|&i| local_mean(hb, w, h, ch, domain, i))
            .collect();
        for (&i, ms) in holes.iter().zip(&mean_synth) {
            for c in 0..ch {
                hb[i * ch + c] += opts.mean_from_diffusion * (mean_known[i * ch + c] - ms[c]);
            }
        }
    }
    report.seconds_synthesis = lap(&mut t);

    let mut out = image.clone();
    let h0 = &levels[0].data;
    for i in 0..w * h {
        if fill[i] {
            for c in 0..ch {
                let amp = env.as_ref().map_or(1.0, |e| e[i]);
                out.data[i * ch + c] = low[i * ch + c] + amp * h0[i * ch + c];
            }
        }
    }
    report.detail_scale = 1.0;
    if opts.match_detail {
        report.detail_scale = match_detail(&mut out.data, w, h, ch, &fill, domain);
    }
    report.seconds = wall.elapsed().as_secs_f64();
    Ok((out, report))
}

/// Scales the fine detail (the texel minus its 7x7 blur) of the holes of `fill` so that its
/// energy matches that of the known texels of `domain` around them
/// ([`RestoreOptions::match_detail`]). Returns the texel-weighted mean scale.
fn match_detail(
    out: &mut [f32],
    w: usize,
    h: usize,
    ch: usize,
    fill: &[bool],
    domain: &[bool],
) -> f64 {
    let hole: Vec<usize> = (0..w * h).filter(|&i| fill[i]).collect();
    if hole.is_empty() {
        return 1.0;
    }
    let ring: Vec<usize> = {
        let d = grid_distance(w, h, domain, fill, Some(DETAIL_RING.1 as u8));
        (0..w * h)
            .filter(|&i| !fill[i] && d[i] >= DETAIL_RING.0 as u8 && d[i] != u8::MAX)
            .collect()
    };
    // The texel minus its local mean over the domain.
    let highpass = |data: &[f32], i: usize| -> [f32; 3] {
        let m = local_mean(data, w, h, ch, domain, i);
        std::array::from_fn(|c| if c < ch { data[i * ch + c] - m[c] } else { 0.0 })
    };
    // Mean squared high-pass; summed per fixed chunk, then in order, so the same bytes come
    // out whatever the threads do.
    let energy = |data: &[f32], texels: &[usize]| -> f64 {
        let parts: Vec<f64> = texels
            .par_chunks(4096)
            .map(|c| {
                c.iter()
                    .map(|&i| {
                        highpass(data, i)
                            .iter()
                            .map(|&d| f64::from(d * d))
                            .sum::<f64>()
                    })
                    .sum()
            })
            .collect();
        parts.iter().sum::<f64>() / texels.len().max(1) as f64
    };
    // What is scaled is the hole's high-pass as the energy sees it, so the hole keeps its
    // local mean (its shading) and a one-texel hole is not left out.
    let fine: Vec<[f32; 3]> = hole.par_iter().map(|&i| highpass(out, i)).collect();
    // One scale for all the holes: the energy of a hole's surroundings is a noisy estimate
    // of what the hole should hold when the texture's features are as large as the hole
    // (per-hole scales took sawtooth stripes down to 0.7 of their energy).
    let mut total = 1f64;
    // The ring is known texels, unchanged by the scaling: measured once. Too few texels
    // around (holes filling their chart) say nothing reliable.
    if ring.len() < 16 {
        return total;
    }
    let er = energy(out, &ring);
    // Two passes: the blur at a hole's edge mixes known and scaled texels, so one scale
    // undershoots a little.
    for _ in 0..2 {
        let ei = energy(out, &hole);
        if ei <= 0.0 {
            break;
        }
        let new = ((er / ei).sqrt() * total).clamp(DETAIL_SCALE.0, DETAIL_SCALE.1);
        let step = (new - total) as f32;
        total = new;
        for (&i, d) in hole.iter().zip(&fine) {
            for j in 0..ch {
                out[i * ch + j] += step * d[j];
            }
        }
    }
    total
}

/// Mean of texel `i`'s 7x7 neighbourhood over the texels of `weight`, weighted by three box
/// passes of radius 1 (the 7-tap kernel 1 3 6 7 6 3 1 per axis, sigma about 1.4 texels); zero
/// where no weighted texel is in reach. Channels past `ch` are zero.
fn local_mean(data: &[f32], w: usize, h: usize, ch: usize, weight: &[bool], i: usize) -> [f32; 3] {
    const K: [f32; 7] = [1.0, 3.0, 6.0, 7.0, 6.0, 3.0, 1.0];
    let (x, y) = (i % w, i / w);
    let mut acc = [0f32; 3];
    let mut wsum = 0f32;
    for (ky, yy) in K.iter().zip(y as isize - 3..) {
        if yy < 0 || yy >= h as isize {
            continue;
        }
        for (kx, xx) in K.iter().zip(x as isize - 3..) {
            if xx < 0 || xx >= w as isize {
                continue;
            }
            let j = yy as usize * w + xx as usize;
            if !weight[j] {
                continue;
            }
            let k = ky * kx;
            wsum += k;
            for c in 0..ch {
                acc[c] += k * data[j * ch + c];
            }
        }
    }
    if wsum > 0.0 {
        acc.map(|a| a / wsum)
    } else {
        [0.0; 3]
    }
}

/// The 4-neighbours of texel `i` of a `w` x `h` grid.
fn neighbours4(i: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < w).then(|| i + 1),
        (y > 0).then(|| i - w),
        (y + 1 < h).then(|| i + w),
    ]
    .into_iter()
    .flatten()
}

/// 4-connected components of the `w` x `h` mask.
fn holes(w: usize, h: usize, mask: &[bool]) -> Vec<Vec<usize>> {
    let mut seen = vec![false; w * h];
    let mut out = Vec::new();
    for s in 0..w * h {
        if !mask[s] || seen[s] {
            continue;
        }
        let mut comp = vec![s];
        seen[s] = true;
        let mut k = 0;
        while k < comp.len() {
            let i = comp[k];
            k += 1;
            for j in neighbours4(i, w, h) {
                if mask[j] && !seen[j] {
                    seen[j] = true;
                    comp.push(j);
                }
            }
        }
        out.push(comp);
    }
    out
}

/// 4-connected grid distance on a `w` x `h` grid within `domain` from the `from` texels,
/// stopping at `limit` (texels farther away, or unreachable, keep `u8::MAX`); without a limit
/// every reachable texel is reached, distances saturating at 254. One byte per texel: at 8192
/// the atlas has 67M.
fn grid_distance(w: usize, h: usize, domain: &[bool], from: &[bool], limit: Option<u8>) -> Vec<u8> {
    let mut d = vec![u8::MAX; w * h];
    let start = |i: usize| from[i] && domain[i];
    // Every start texel is at 0, but only those with a neighbour to reach are queued: an
    // atlas's seen texels are tens of millions, and nearly all lie among other seen texels.
    let mut front: Vec<usize> = (0..w * h)
        .into_par_iter()
        .filter(|&i| start(i) && neighbours4(i, w, h).any(|j| domain[j] && !start(j)))
        .collect();
    d.par_iter_mut().enumerate().for_each(|(i, v)| {
        if start(i) {
            *v = 0;
        }
    });
    let mut step = 0u32;
    let mut next = Vec::new();
    while !front.is_empty() && limit.is_none_or(|l| step < u32::from(l)) {
        step += 1;
        next.clear();
        let v = step.min(u32::from(u8::MAX) - 1) as u8;
        for &i in &front {
            for j in neighbours4(i, w, h) {
                if domain[j] && d[j] == u8::MAX {
                    d[j] = v;
                    next.push(j);
                }
            }
        }
        std::mem::swap(&mut front, &mut next);
    }
    d
}

fn lap(t: &mut Instant) -> f64 {
    let s = t.elapsed().as_secs_f64();
    *t = Instant::now();
    s
}

/// CIE Y (Rec. 709 primaries, on the stored values) box-downsampled so that the longer side
/// is at most [`KAPPA_ANALYSIS_SIDE`].
fn luminance_small(data: &[f32], w: usize, h: usize, ch: usize) -> (Vec<f64>, usize, usize) {
    let f = w.max(h).div_ceil(KAPPA_ANALYSIS_SIDE).max(1);
    let (sw, sh) = (w.div_ceil(f), h.div_ceil(f));
    let mut y = vec![0f64; sw * sh];
    let mut n = vec![0f64; sw * sh];
    for yy in 0..h {
        for xx in 0..w {
            let i = yy * w + xx;
            let v = if ch == 3 {
                0.2126 * data[i * 3] as f64
                    + 0.7152 * data[i * 3 + 1] as f64
                    + 0.0722 * data[i * 3 + 2] as f64
            } else {
                data[i] as f64
            };
            let j = (yy / f) * sw + xx / f;
            y[j] += v;
            n[j] += 1.0;
        }
    }
    for (a, b) in y.iter_mut().zip(&n) {
        *a /= b.max(1.0);
    }
    (y, sw, sh)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize, ramp: bool) -> Image {
        // Blurred white noise: a homogeneous, non-periodic texture.
        let mut s = 99u64;
        let noise: Vec<f32> = (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 40) as f32 / (1u64 << 24) as f32 - 0.5
            })
            .collect();
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let mut a = 0.0;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    a += noise[((y + dy) % h) * w + (x + dx) % w];
                }
                let t = 0.5 + 0.2 * a;
                if ramp {
                    t * (0.2 + 0.8 * x as f32 / w as f32)
                } else {
                    t
                }
            })
            .collect();
        Image {
            width: w,
            height: h,
            channels: 1,
            data,
        }
    }

    fn disc(w: usize, h: usize, r: f32) -> Vec<bool> {
        (0..w * h)
            .map(|i| {
                let (x, y) = (
                    (i % w) as f32 - w as f32 / 2.0,
                    (i / w) as f32 - h as f32 / 2.0,
                );
                x * x + y * y < r * r
            })
            .collect()
    }

    /// Fine-detail energy (value minus its 3x3 mean) inside and outside the mask, per texel.
    fn detail_energy(d: &[f32], w: usize, h: usize, mask: &[bool]) -> (f64, f64) {
        let (mut e, mut n) = ([0f64; 2], [0f64; 2]);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut m = 0.0;
                for yy in y - 1..=y + 1 {
                    for xx in x - 1..=x + 1 {
                        m += d[yy * w + xx] / 9.0;
                    }
                }
                let k = mask[y * w + x] as usize;
                e[k] += f64::from((d[y * w + x] - m).powi(2));
                n[k] += 1.0;
            }
        }
        (e[1] / n[1], e[0] / n[0])
    }

    #[test]
    fn detail_matching_lowers_excess_energy_and_never_raises_it() {
        let (w, h) = (96, 80);
        let img = texture(w, h, false);
        let mask = disc(w, h, 14.0);
        let domain = vec![true; w * h];
        for (gain, expect_scale) in [(2.0f32, 0.5f64), (0.5, 1.0)] {
            // The hole holds the same texture at `gain` times its contrast.
            let mut out: Vec<f32> = (0..w * h)
                .map(|i| {
                    let v = img.data[i];
                    if mask[i] {
                        0.5 + gain * (v - 0.5)
                    } else {
                        v
                    }
                })
                .collect();
            let before = out.clone();
            let (before_in, before_out) = detail_energy(&out, w, h, &mask);
            let s = match_detail(&mut out, w, h, 1, &mask, &domain);
            let (after_in, after_out) = detail_energy(&out, w, h, &mask);
            for i in (0..w * h).filter(|&i| !mask[i]) {
                assert_eq!(out[i], before[i], "known texel {i} changed");
            }
            if expect_scale < 1.0 {
                assert!((s - expect_scale).abs() < 0.12, "scale {s}");
                let r = (after_in / after_out).sqrt();
                assert!(
                    (0.85..=1.15).contains(&r),
                    "detail ratio {r} (was {:.2})",
                    (before_in / before_out).sqrt()
                );
            } else {
                assert_eq!(s, 1.0, "faint detail is not amplified");
                assert_eq!(out, before);
                assert_eq!(after_in, before_in);
            }
        }
    }

    #[test]
    fn kappa_zero_is_pure_synthesis_and_kappa_max_pure_inpainting() {
        let img = texture(64, 48, true);
        let mask = disc(64, 48, 9.0);
        // Without contrast normalisation, which rescales copied values by the envelope.
        let mut o = RestoreOptions {
            kappa: Kappa::Fixed(0),
            normalise_contrast: false,
            mean_from_diffusion: 0.0,
            ..Default::default()
        };
        let (syn, r) = inpaint(&img, &mask, None, &o).unwrap();
        assert_eq!(r.kappa, 0);
        // Every filled value is a copy of a known pixel: nothing came from diffusion.
        let known: Vec<u32> = (0..64 * 48)
            .filter(|&i| !mask[i])
            .map(|i| img.data[i].to_bits())
            .collect();
        for i in (0..64 * 48).filter(|&i| mask[i]) {
            let v = syn.data[i];
            assert!(
                known.iter().any(|&k| (f32::from_bits(k) - v).abs() < 1e-6),
                "texel {i}: {v} is not a known value"
            );
        }
        // kappa = longer side: all low band, the result is the diffusion fill exactly.
        o.kappa = Kappa::Fixed(64);
        let (inp, _) = inpaint(&img, &mask, None, &o).unwrap();
        let mut diff = img.data.clone();
        diffuse::inpaint(&mut diff, 64, 48, 1, &mask, &vec![true; 64 * 48], o.sweeps);
        let (_, _) = (&inp, &diff);
        for i in (0..64 * 48).filter(|&i| mask[i]) {
            assert!(
                (inp.data[i] - diff[i]).abs() < 1e-4,
                "texel {i}: {} vs {}",
                inp.data[i],
                diff[i]
            );
        }
        // Known pixels never change.
        for i in (0..64 * 48).filter(|&i| !mask[i]) {
            assert_eq!(syn.data[i], img.data[i]);
            assert_eq!(inp.data[i], img.data[i]);
        }
    }

    #[test]
    fn automatic_kappa_lies_between_and_grows_with_a_ramp() {
        let o = RestoreOptions::default();
        let mask = disc(96, 96, 12.0);
        let (_, flat) = inpaint(&texture(96, 96, false), &mask, None, &o).unwrap();
        let (_, ramp) = inpaint(&texture(96, 96, true), &mask, None, &o).unwrap();
        assert!(
            ramp.kappa > flat.kappa,
            "flat {} ramp {}",
            flat.kappa,
            ramp.kappa
        );
        assert!(
            ramp.kappa > 0 && ramp.kappa < 96,
            "ramp kappa {}",
            ramp.kappa
        );
    }

    #[test]
    fn same_seed_same_bytes_and_detail_in_the_hole() {
        let img = texture(80, 60, false);
        let mask = disc(80, 60, 10.0);
        let o = RestoreOptions::default();
        let (a, _) = inpaint(&img, &mask, None, &o).unwrap();
        let (b, _) = inpaint(&img, &mask, None, &o).unwrap();
        assert_eq!(a, b);
        // The hole is not smooth: its high-pass energy is comparable to the surroundings'.
        let hp = |im: &Image, i: usize| {
            let (x, y) = (i % 80, i / 80);
            im.data[i]
                - 0.25
                    * (im.data[y * 80 + x - 1]
                        + im.data[y * 80 + x + 1]
                        + im.data[(y - 1) * 80 + x]
                        + im.data[(y + 1) * 80 + x])
        };
        let inside: Vec<usize> = (0..80 * 60).filter(|&i| disc(80, 60, 8.0)[i]).collect();
        let outside: Vec<usize> = (0..80 * 60)
            .filter(|&i| !mask[i] && i % 80 > 0 && i % 80 < 79 && i / 80 > 0 && i / 80 < 59)
            .collect();
        let e = |im: &Image, s: &[usize]| {
            (s.iter().map(|&i| hp(im, i).powi(2)).sum::<f32>() / s.len() as f32).sqrt()
        };
        let ratio = e(&a, &inside) / e(&img, &outside);
        assert!(ratio > 0.6 && ratio < 1.5, "detail ratio {ratio}");
    }

    #[test]
    fn bad_options_and_sizes_are_errors() {
        let img = texture(16, 16, false);
        let o = RestoreOptions {
            levels: 0,
            ..Default::default()
        };
        assert!(inpaint(&img, &[false; 256], None, &o).is_err());
        assert!(inpaint(&img, &[false; 10], None, &RestoreOptions::default()).is_err());
    }
}
