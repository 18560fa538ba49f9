//! Stage 2b: photometric normalisation. In: the [`Binding`] (every vertex's colour in each of
//! its valid photographs) and vertex normals. Out: [`Gains`], one gain field per photograph
//! that maps its colours onto the consensus of all photographs.
//!
//! The paper assumes photographs agree in colour; under changing exposure, white balance and
//! light they do not, and each change of source photograph shows as a seam. We model photograph
//! `i`'s colour of a vertex with normal `n` and consensus colour `m` as `g_i(n) * m`, per
//! channel, where `g_i` is a real spherical-harmonic polynomial of the normal up to order 2
//! (9 terms): order 0 is exposure times white balance, orders 1-2 capture a distant light's
//! shading (order 2 holds 99% of a clamped cosine's energy; Ramamoorthi and Hanrahan 2001).
//! Gains and consensus are solved alternately by weighted least squares with Cauchy
//! reweighting, so occluder and highlight samples barely pull. The consensus keeps the mean
//! brightness of the photographs (the gauge: the weighted mean gain over all samples is 1).
//!
//! The consensus still holds the photographs' average lighting, a function of the normal.
//! With `delight` (default) that too is fitted (order 2, over the bound vertices) and divided
//! out, on the assumption that albedo does not correlate with the normal at so low an order;
//! on the corset scene this is worth +5.4 dB held-out PSNR (docs/benchmarks.md).

use crate::bind::Binding;
use nalgebra::{SMatrix, SVector, Vector3};
use rayon::prelude::*;
use serde::Serialize;
use std::str::FromStr;

/// Spherical-harmonic terms per channel.
pub const TERMS: usize = 9;

/// What per-photograph colour differences to model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GainModel {
    /// None: photographs are used as they are (the paper).
    Off,
    /// One gain per photograph and channel (exposure and white balance).
    Exposure,
    /// Exposure, white balance and low-frequency shading as a function of the surface normal
    /// (order-2 spherical harmonics per channel).
    #[default]
    Lighting,
}

impl std::fmt::Display for GainModel {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            GainModel::Off => "off",
            GainModel::Exposure => "exposure",
            GainModel::Lighting => "lighting",
        })
    }
}

impl FromStr for GainModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" | "none" => Ok(GainModel::Off),
            "exposure" => Ok(GainModel::Exposure),
            "lighting" => Ok(GainModel::Lighting),
            _ => Err(format!(
                "unknown gain model '{s}': expected off, exposure or lighting"
            )),
        }
    }
}

/// Options for [`solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotometricOptions {
    /// The gain model. Default: `Lighting`.
    pub model: GainModel,
    /// Alternations between gains and consensus. Default: 6.
    pub iterations: usize,
    /// Ridge weight pulling the normal-dependent terms to zero, relative to the data's energy;
    /// keeps the fit sane on photographs that see a narrow range of normals. Default: 0.05.
    pub ridge: f64,
    /// Scale of the Cauchy reweighting, as a log colour ratio: a sample off the model by this
    /// much counts half. Default: 0.15.
    pub outlier_scale: f64,
    /// Gains are clamped to [1 / max_gain, max_gain] when applied. Default: 4.
    pub max_gain: f32,
    /// Also divide out the shading common to all photographs (order-2 spherical harmonics
    /// of the normal fitted to the consensus, assuming albedo does not depend on the normal),
    /// leaving albedo, which is what glTF's base colour and any relit renderer expect. Lighting
    /// model only. Default: true.
    pub delight: bool,
}

impl Default for PhotometricOptions {
    fn default() -> Self {
        PhotometricOptions {
            model: GainModel::Lighting,
            iterations: 6,
            ridge: 0.05,
            outlier_scale: 0.15,
            max_gain: 4.0,
            delight: true,
        }
    }
}

impl PhotometricOptions {
    /// Checks ranges.
    pub fn validate(&self) -> crate::Result<()> {
        let bad = |o: &'static str, m: &str| Err(crate::Error::option(o, m));
        if self.iterations == 0 || self.iterations > 100 {
            return bad("iterations", "photometric iterations must be in 1..=100");
        }
        if !(self.ridge >= 0.0 && self.ridge.is_finite()) {
            return bad("ridge", "photometric ridge must be finite and >= 0");
        }
        if !(self.outlier_scale > 0.0 && self.outlier_scale.is_finite()) {
            return bad(
                "outlier_scale",
                "photometric outlier scale must be finite and > 0",
            );
        }
        if !(self.max_gain >= 1.0 && self.max_gain.is_finite()) {
            return bad("max_gain", "photometric max gain must be finite and >= 1");
        }
        Ok(())
    }
}

/// The real spherical-harmonic polynomials up to order 2 (unnormalised).
pub fn basis(n: &Vector3<f64>) -> [f64; TERMS] {
    let (x, y, z) = (n.x, n.y, n.z);
    [
        1.0,
        x,
        y,
        z,
        x * y,
        y * z,
        x * z,
        x * x - y * y,
        3.0 * z * z - 1.0,
    ]
}

/// One photograph's gain field: per channel, coefficients of [`basis`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PhotoGain {
    /// Coefficients per channel (R, G, B).
    pub coeffs: [[f32; TERMS]; 3],
}

impl PhotoGain {
    /// Gain 1 everywhere.
    pub const IDENTITY: PhotoGain = PhotoGain {
        coeffs: [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]; 3],
    };

    /// The gain per channel for surface normal `n`, unclamped.
    pub fn at(&self, n: &Vector3<f64>) -> [f32; 3] {
        let b = basis(n);
        std::array::from_fn(|k| {
            self.coeffs[k]
                .iter()
                .zip(b)
                .map(|(c, b)| c * b as f32)
                .sum()
        })
    }
}

/// The solved gains of every photograph.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Gains {
    /// Model used.
    pub model: GainModel,
    /// One per photograph, in the binding's photograph order.
    pub per_photo: Vec<PhotoGain>,
    /// Shading common to all photographs, divided out with `delight` (identity otherwise).
    pub common: PhotoGain,
    /// Weighted RMS of (sample - model) / model over samples of vertices seen twice or more,
    /// before normalisation (grey level, Cauchy-weighted samples included).
    pub rms_before: f64,
    /// The same after.
    pub rms_after: f64,
    /// Clamp applied by [`Gains::correct`].
    #[serde(skip)]
    pub max_gain: f32,
}

impl Gains {
    /// No correction for `photos` photographs.
    pub fn identity(photos: usize) -> Gains {
        Gains {
            model: GainModel::Off,
            per_photo: vec![PhotoGain::IDENTITY; photos],
            common: PhotoGain::IDENTITY,
            rms_before: 0.0,
            rms_after: 0.0,
            max_gain: 1.0,
        }
    }

    /// True when [`Gains::correct`] changes nothing.
    pub fn is_identity(&self) -> bool {
        self.common == PhotoGain::IDENTITY
            && self.per_photo.iter().all(|g| *g == PhotoGain::IDENTITY)
    }

    /// `color` as photograph `photo` saw it at a surface with normal `n`, mapped to the
    /// consensus.
    pub fn correct(&self, photo: usize, n: &Vector3<f64>, color: [f32; 3]) -> [f32; 3] {
        let f = self.factor(photo, n);
        std::array::from_fn(|k| color[k] * f[k])
    }

    /// The factor [`Gains::correct`] multiplies photograph `photo`'s colours by at normal `n`.
    pub fn factor(&self, photo: usize, n: &Vector3<f64>) -> [f32; 3] {
        let g = self.per_photo[photo].at(n);
        let c = self.common.at(n);
        let lo = 1.0 / self.max_gain;
        std::array::from_fn(|k| {
            1.0 / (g[k].clamp(lo, self.max_gain) * c[k].clamp(lo, self.max_gain))
        })
    }

    /// Corrects every sample of `binding` in place (`normals` per vertex).
    fn apply(&self, binding: &mut Binding, normals: &[Vector3<f64>]) {
        let offsets = &binding.offsets;
        for (v, n) in normals.iter().enumerate() {
            for s in &mut binding.samples[offsets[v] as usize..offsets[v + 1] as usize] {
                s.color = self.correct(s.photo as usize, n, s.color);
            }
        }
    }
}

/// Solves the gains of `binding`'s photographs ([`solve`]) and corrects its samples by them;
/// returns the corrected binding and the gains, which resampling applies to texels the same
/// way.
pub fn normalise(
    mut binding: Binding,
    normals: &[Vector3<f64>],
    opts: &PhotometricOptions,
) -> (Binding, Gains) {
    let gains = solve(&binding, normals, opts);
    if !gains.is_identity() {
        gains.apply(&mut binding, normals);
    }
    (binding, gains)
}

/// A sample's share in the fit.
#[derive(Clone, Copy)]
struct Obs {
    vertex: u32,
    color: [f32; 3],
    weight: f32,
}

/// Solves the gain of every photograph of `binding` (`normals` per vertex, unit length).
pub fn solve(binding: &Binding, normals: &[Vector3<f64>], opts: &PhotometricOptions) -> Gains {
    let photos = binding.photos;
    if opts.model == GainModel::Off {
        return Gains::identity(photos);
    }
    let terms = if opts.model == GainModel::Lighting {
        TERMS
    } else {
        1
    };
    let nv = binding.offsets.len() - 1;
    // Observations by photograph; only vertices seen twice or more carry information.
    let mut by_photo: Vec<Vec<Obs>> = vec![Vec::new(); photos];
    for v in 0..nv {
        let vs = binding.views(v);
        if vs.len() < 2 {
            continue;
        }
        for s in vs {
            by_photo[s.photo as usize].push(Obs {
                vertex: v as u32,
                color: s.color,
                weight: s.weight.max(1e-6),
            });
        }
    }
    let basis_of: Vec<[f64; TERMS]> = normals.iter().map(basis).collect();
    let mut gains = vec![PhotoGain::IDENTITY; photos];
    let mut consensus = vec![[0f32; 3]; nv];
    let mut robust_w: Vec<Vec<f32>> = by_photo.iter().map(|o| vec![1.0; o.len()]).collect();
    let clamp = |g: f32| g.clamp(1.0 / opts.max_gain, opts.max_gain);
    let mut rms_before = 0.0;
    let mut rms_after = 0.0;
    for it in 0..=opts.iterations {
        // Consensus: robust weighted mean of the corrected samples.
        let mut sum = vec![[0f64; 4]; nv];
        for (i, obs) in by_photo.iter().enumerate() {
            for (o, rw) in obs.iter().zip(&robust_w[i]) {
                let g = gains[i].at(&normals[o.vertex as usize]);
                let w = (o.weight * rw) as f64;
                let s = &mut sum[o.vertex as usize];
                for k in 0..3 {
                    s[k] += w * (o.color[k] / clamp(g[k])) as f64;
                }
                s[3] += w;
            }
        }
        for (c, s) in consensus.iter_mut().zip(&sum) {
            if s[3] > 0.0 {
                *c = std::array::from_fn(|k| (s[k] / s[3]) as f32);
            }
        }
        // Residuals in log grey: the reweighting and the reported fit.
        let mut e2 = 0.0;
        let mut ew = 0.0;
        for (i, obs) in by_photo.iter().enumerate() {
            for (o, rw) in obs.iter().zip(robust_w[i].iter_mut()) {
                let g = gains[i].at(&normals[o.vertex as usize]);
                let m = consensus[o.vertex as usize];
                let pred: f32 = (0..3).map(|k| clamp(g[k]) * m[k]).sum();
                let seen: f32 = o.color.iter().sum();
                let r = ((seen.max(1e-3) / pred.max(1e-3)) as f64).ln();
                e2 += o.weight as f64 * ((seen - pred) as f64).powi(2);
                ew += o.weight as f64 * (pred as f64).powi(2);
                *rw = (1.0 / (1.0 + (r / opts.outlier_scale).powi(2))) as f32;
            }
        }
        let rms = (e2 / ew.max(1e-300)).sqrt();
        if it == 0 {
            rms_before = rms;
        }
        rms_after = rms;
        if it == opts.iterations {
            break;
        }
        // Gains: per photograph and channel, weighted least squares of colour = g(n) * m.
        gains = by_photo
            .par_iter()
            .zip(&robust_w)
            .map(|(obs, rws)| fit_photo(obs, rws, &basis_of, &consensus, terms, opts.ridge))
            .collect();
        // Gauge: the weighted mean gain over all samples is 1 per channel.
        let mut mean = [0f64; 4];
        for (i, obs) in by_photo.iter().enumerate() {
            for o in obs {
                let g = gains[i].at(&normals[o.vertex as usize]);
                for k in 0..3 {
                    mean[k] += o.weight as f64 * g[k] as f64;
                }
                mean[3] += o.weight as f64;
            }
        }
        if mean[3] > 0.0 {
            for g in &mut gains {
                for k in 0..3 {
                    let s = (mean[3] / mean[k].max(1e-12)) as f32;
                    g.coeffs[k].iter_mut().for_each(|c| *c *= s);
                }
            }
        }
    }
    let common = if opts.delight && terms == TERMS {
        let used: Vec<bool> = (0..nv).map(|v| binding.views(v).len() >= 2).collect();
        PhotoGain {
            coeffs: shading_of_consensus(&consensus, &used, &basis_of, opts.ridge),
        }
    } else {
        PhotoGain::IDENTITY
    };
    Gains {
        model: opts.model,
        per_photo: gains,
        common,
        rms_before,
        rms_after,
        max_gain: opts.max_gain,
    }
}

/// The shading common to all photographs: the order-2 fit of the consensus grey level over the
/// normal, divided by its mean (so that mean brightness is kept); the same for every channel.
fn shading_of_consensus(
    consensus: &[[f32; 3]],
    used: &[bool],
    basis_of: &[[f64; TERMS]],
    ridge: f64,
) -> [[f32; TERMS]; 3] {
    let mut identity = [0f32; TERMS];
    identity[0] = 1.0;
    let mut a = SMatrix::<f64, TERMS, TERMS>::zeros();
    let mut b = SVector::<f64, TERMS>::zeros();
    let mut mean = 0.0;
    let mut count = 0.0;
    for ((c, u), y) in consensus.iter().zip(used).zip(basis_of) {
        if !u {
            continue;
        }
        // Every bound vertex counts once: the prior is over the surface, not the views. Grey,
        // as for the per-photograph fields.
        let g: f64 = c.iter().map(|&v| v as f64).sum();
        let row = SVector::<f64, TERMS>::from_row_slice(y);
        a += row * row.transpose();
        b += g * row;
        mean += g;
        count += 1.0;
    }
    if count < 4.0 * TERMS as f64 || mean <= 1e-9 {
        return [identity; 3];
    }
    // As for the per-photograph fits: a narrow range of normals leaves the shading flat.
    for j in 1..TERMS {
        a[(j, j)] += ridge * count;
    }
    match a.cholesky() {
        Some(ch) => {
            let x = ch.solve(&b) * (count / mean);
            [std::array::from_fn(|j| x[j] as f32); 3]
        }
        None => [identity; 3],
    }
}

/// Least-squares gain field of one photograph: a grey shading field over the normal (light is
/// taken as colourless: a per-channel field would read the hue of albedo that happens to vary
/// with the normal as lighting), times one white-balance factor per channel. Photographs with
/// too few observations keep gain 1.
fn fit_photo(
    obs: &[Obs],
    robust_w: &[f32],
    basis_of: &[[f64; TERMS]],
    consensus: &[[f32; 3]],
    terms: usize,
    ridge: f64,
) -> PhotoGain {
    if obs.len() < 4 * terms {
        return PhotoGain::IDENTITY;
    }
    let grey = |c: &[f32; 3]| c.iter().map(|&v| v as f64).sum::<f64>();
    let mut a = SMatrix::<f64, TERMS, TERMS>::zeros();
    let mut b = SVector::<f64, TERMS>::zeros();
    let mut energy = 0.0;
    for (o, rw) in obs.iter().zip(robust_w) {
        let m = grey(&consensus[o.vertex as usize]);
        let w = (o.weight * rw) as f64;
        let row = SVector::<f64, TERMS>::from_fn(|j, _| {
            if j < terms {
                basis_of[o.vertex as usize][j] * m
            } else {
                0.0
            }
        });
        a += w * row * row.transpose();
        b += w * grey(&o.color) * row;
        energy += w * m * m;
    }
    if energy <= 1e-12 {
        return PhotoGain::IDENTITY;
    }
    // Ridge on the normal-dependent terms only; unused terms pinned to zero.
    for j in 1..TERMS {
        a[(j, j)] += if j < terms { ridge * energy } else { 1.0 };
    }
    let Some(ch) = a.cholesky() else {
        return PhotoGain::IDENTITY;
    };
    let shade = ch.solve(&b);
    let at = |v: usize| {
        basis_of[v]
            .iter()
            .zip(shade.iter())
            .map(|(y, c)| y * c)
            .sum::<f64>()
    };
    // White balance: per channel, the least-squares factor on top of the grey field.
    let mut num = [0f64; 3];
    let mut den = [0f64; 3];
    for (o, rw) in obs.iter().zip(robust_w) {
        let w = (o.weight * rw) as f64;
        let s = at(o.vertex as usize);
        let m = consensus[o.vertex as usize];
        for k in 0..3 {
            let p = s * m[k] as f64;
            num[k] += w * o.color[k] as f64 * p;
            den[k] += w * p * p;
        }
    }
    PhotoGain {
        coeffs: std::array::from_fn(|k| {
            let wb = if den[k] > 1e-12 { num[k] / den[k] } else { 1.0 };
            std::array::from_fn(|j| (shade[j] * wb) as f32)
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bind::{Binding, ViewSample};

    /// Vertices on a sphere, each seen by every photograph under its own exposure, white
    /// balance and Lambert light: the solve must bring the photographs into agreement.
    #[test]
    fn removes_exposure_and_directional_light() {
        let n = 400;
        let normals: Vec<Vector3<f64>> = (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let phi = i as f64 * 2.399963;
                let r = (1.0 - z * z).sqrt();
                Vector3::new(r * phi.cos(), r * phi.sin(), z)
            })
            .collect();
        let albedo = |v: usize| {
            let t = (v * 7919 % 101) as f32 / 100.0;
            [0.2 + 0.6 * t, 0.5 - 0.3 * t, 0.3 + 0.2 * t]
        };
        let lights = [
            (1.2, [1.1, 1.0, 0.8], Vector3::new(0.0, 0.0, 1.0)),
            (
                0.8,
                [0.9, 1.0, 1.2],
                Vector3::new(1.0, 0.0, 0.2).normalize(),
            ),
            (
                1.0,
                [1.0, 1.0, 1.0],
                Vector3::new(-0.5, 0.7, 0.5).normalize(),
            ),
            (
                0.9,
                [1.2, 1.0, 0.9],
                Vector3::new(0.0, -1.0, 0.3).normalize(),
            ),
        ];
        let mut offsets = vec![0u32];
        let mut samples = Vec::new();
        for (v, nv) in normals.iter().enumerate() {
            for (p, (e, wb, l)) in lights.iter().enumerate() {
                let shade = 0.35 + 0.65 * nv.dot(l).max(0.0) as f32;
                let a = albedo(v);
                samples.push(ViewSample {
                    photo: p as u32,
                    color: std::array::from_fn(|k| a[k] * e * wb[k] * shade),
                    weight: 1.0,
                });
            }
            offsets.push(samples.len() as u32);
        }
        let binding = Binding::from_samples(offsets, samples, lights.len());
        let spread = |b: &Binding| {
            // Mean over vertices of the max/min ratio of grey across photographs.
            (0..n)
                .map(|v| {
                    let g: Vec<f32> = b.views(v).iter().map(|s| s.color.iter().sum()).collect();
                    let (lo, hi) = g
                        .iter()
                        .fold((f32::MAX, 0f32), |(lo, hi), &x| (lo.min(x), hi.max(x)));
                    (hi / lo) as f64
                })
                .sum::<f64>()
                / n as f64
        };
        let before = spread(&binding);
        let (exp, _) = normalise(
            binding.clone(),
            &normals,
            &PhotometricOptions {
                model: GainModel::Exposure,
                ..Default::default()
            },
        );
        let (lit, g) = normalise(binding.clone(), &normals, &PhotometricOptions::default());
        assert!(g.rms_after < 0.25 * g.rms_before, "{g:?}");
        let (e, l) = (spread(&exp), spread(&lit));
        assert!(before > 2.0, "the test scene must disagree: {before}");
        assert!(e < before, "exposure gains help: {e} vs {before}");
        assert!(before > 2.0, "the test scene must disagree: {before}");
        assert!(e < before, "exposure gains help: {e} vs {before}");
        assert!(
            l < 1.25 && l < 0.6 * e,
            "lighting gains bring the views together: {l} vs {e}"
        );
        // Delighting: the corrected colour over the true albedo is nearly constant over the
        // sphere, where without it the average light's shading remains.
        let (kept, _) = normalise(
            binding.clone(),
            &normals,
            &PhotometricOptions {
                delight: false,
                ..Default::default()
            },
        );
        let cv = |b: &Binding| {
            let r: Vec<f64> = (0..n)
                .map(|v| {
                    let c: f32 = b.views(v).iter().map(|s| s.color.iter().sum::<f32>()).sum();
                    (c / b.views(v).len() as f32 / albedo(v).iter().sum::<f32>()) as f64
                })
                .collect();
            let m = r.iter().sum::<f64>() / n as f64;
            (r.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64).sqrt() / m
        };
        let (cv_kept, cv_delit) = (cv(&kept), cv(&lit));
        assert!(
            cv_delit < 0.5 * cv_kept,
            "delighting flattens the shading: {cv_delit} vs {cv_kept}"
        );
        // Off changes nothing.
        let off = solve(
            &binding,
            &normals,
            &PhotometricOptions {
                model: GainModel::Off,
                ..Default::default()
            },
        );
        assert!(off.is_identity());
    }

    #[test]
    fn model_parses() {
        assert_eq!("lighting".parse::<GainModel>(), Ok(GainModel::Lighting));
        assert_eq!("off".parse::<GainModel>(), Ok(GainModel::Off));
        assert!("sometimes".parse::<GainModel>().is_err());
    }
}
