//! The 2D core of stage 6: an exemplar prepared for histogram-preserving blending (Heitz and
//! Neyret 2018, the micro level of the three-level approach: decorrelate the colours, map each
//! channel to a standard Gaussian through its own histogram, blend overlapping patches with
//! weights normalised to keep the variance, map back), and synthesis of an image of any size
//! from overlapping patches at random offsets, each offset chosen among a few candidates to
//! agree with the patches already placed (content aligned locally).

use crate::error::{Error, Result};
use crate::rng::SplitMix64;
use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

/// Quantiles kept per channel for the inverse histogram transform.
const LUT: usize = 1024;

/// An exemplar ready for blending: its texels as Gaussian values in a decorrelated colour
/// basis, and per channel the quantiles that map them back.
#[derive(Debug, Clone)]
pub struct Exemplar {
    /// Width in texels.
    pub width: usize,
    /// Height in texels.
    pub height: usize,
    /// Gaussianised decorrelated values, three per texel, row-major.
    g: Vec<[f32; 3]>,
    /// Per channel: the sorted decorrelated values (forward transform) and `LUT` quantiles
    /// (inverse transform).
    sorted: [Vec<f32>; 3],
    lut: [Vec<f32>; 3],
    /// Mean colour.
    mean: [f32; 3],
    /// Rows: the decorrelating basis (eigenvectors of the colour covariance).
    basis: Matrix3<f32>,
}

/// Standard normal CDF (Abramowitz and Stegun 7.1.26 on erf: error below 1.5e-7).
fn phi(x: f32) -> f32 {
    let z = (x as f64).abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-z * z).exp();
    (0.5 * (1.0 + if x < 0.0 { -erf } else { erf })) as f32
}

/// Inverse standard normal CDF (Acklam's rational approximation: relative error 1.2e-9).
fn phi_inv(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p = p.clamp(1e-12, 1.0 - 1e-12);
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

impl Exemplar {
    /// Prepares `width x height` RGB texels (row-major) for blending.
    pub fn new(width: usize, height: usize, texels: &[[f32; 3]]) -> Result<Exemplar> {
        if width < 4 || height < 4 || texels.len() != width * height {
            return Err(Error::Invalid(format!(
                "an exemplar needs at least 4 x 4 texels (got {width} x {height})"
            )));
        }
        if texels.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::Invalid("the exemplar has non-finite values".into()));
        }
        let n = texels.len() as f64;
        let mut mean = [0f64; 3];
        for t in texels {
            for k in 0..3 {
                mean[k] += t[k] as f64 / n;
            }
        }
        let mut cov = Matrix3::<f64>::zeros();
        for t in texels {
            let d = Vector3::from_fn(|k, _| t[k] as f64 - mean[k]);
            cov += d * d.transpose() / n;
        }
        // Eigenvectors sorted by decreasing variance, signs fixed, so the basis (and the
        // bytes) do not depend on the solver's ordering.
        let eig = SymmetricEigen::new(cov);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
        let mut basis = Matrix3::<f32>::zeros();
        for (row, &c) in order.iter().enumerate() {
            let mut v = eig.eigenvectors.column(c).into_owned();
            let big = (0..3)
                .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
                .unwrap_or(0);
            if v[big] < 0.0 {
                v = -v;
            }
            for k in 0..3 {
                basis[(row, k)] = v[k] as f32;
            }
        }
        let mean = mean.map(|m| m as f32);
        let project = |t: &[f32; 3]| -> [f32; 3] {
            let d = Vector3::new(t[0] - mean[0], t[1] - mean[1], t[2] - mean[2]);
            let p = basis * d;
            [p[0], p[1], p[2]]
        };
        let dec: Vec<[f32; 3]> = texels.iter().map(project).collect();
        let mut g = vec![[0f32; 3]; dec.len()];
        let mut sorted: [Vec<f32>; 3] = Default::default();
        let mut lut: [Vec<f32>; 3] = Default::default();
        for c in 0..3 {
            let mut idx: Vec<u32> = (0..dec.len() as u32).collect();
            idx.sort_by(|&a, &b| {
                dec[a as usize][c]
                    .total_cmp(&dec[b as usize][c])
                    .then(a.cmp(&b))
            });
            for (rank, &i) in idx.iter().enumerate() {
                g[i as usize][c] = phi_inv((rank as f64 + 0.5) / n) as f32;
            }
            sorted[c] = idx.iter().map(|&i| dec[i as usize][c]).collect();
            lut[c] = (0..LUT)
                .map(|k| {
                    let pos = (k as f64 + 0.5) / LUT as f64 * n - 0.5;
                    let i0 = pos.floor().clamp(0.0, n - 1.0) as usize;
                    let i1 = (i0 + 1).min(dec.len() - 1);
                    let t = (pos - i0 as f64).clamp(0.0, 1.0) as f32;
                    sorted[c][i0] + t * (sorted[c][i1] - sorted[c][i0])
                })
                .collect();
        }
        Ok(Exemplar {
            width,
            height,
            g,
            sorted,
            lut,
            mean,
            basis,
        })
    }

    /// The exemplar of an RGB image.
    pub fn from_image(img: &image::Rgb32FImage) -> Result<Exemplar> {
        let texels: Vec<[f32; 3]> = img.pixels().map(|p| p.0).collect();
        Exemplar::new(img.width() as usize, img.height() as usize, &texels)
    }

    /// Mean colour of the exemplar.
    pub fn mean(&self) -> [f32; 3] {
        self.mean
    }

    /// The Gaussian values at (x, y), bilinear, clamped to the exemplar.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> [f32; 3] {
        let x = x.clamp(0.0, (self.width - 1) as f64);
        let y = y.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let at = |xx: usize, yy: usize| &self.g[yy * self.width + xx];
        let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
        std::array::from_fn(|k| {
            let top = a[k] + fx * (b[k] - a[k]);
            let bot = c[k] + fx * (d[k] - c[k]);
            top + fy * (bot - top)
        })
    }

    /// The Gaussian values of a colour (the forward transform; colours outside the
    /// exemplar's range map to its extreme ranks).
    pub fn gaussianise(&self, rgb: [f32; 3]) -> [f32; 3] {
        let d = Vector3::new(
            rgb[0] - self.mean[0],
            rgb[1] - self.mean[1],
            rgb[2] - self.mean[2],
        );
        let p = self.basis * d;
        std::array::from_fn(|c| {
            let s = &self.sorted[c];
            let rank = s.partition_point(|&v| v < p[c]);
            phi_inv((rank as f64 + 0.5) / (s.len() as f64 + 1.0)) as f32
        })
    }

    /// The colour of Gaussian values (the inverse transform).
    pub fn colour(&self, g: [f32; 3]) -> [f32; 3] {
        let v: [f32; 3] = std::array::from_fn(|c| {
            let pos = phi(g[c]) * LUT as f32 - 0.5;
            let i0 = pos.floor().clamp(0.0, (LUT - 1) as f32) as usize;
            let i1 = (i0 + 1).min(LUT - 1);
            let t = (pos - i0 as f32).clamp(0.0, 1.0);
            self.lut[c][i0] + t * (self.lut[c][i1] - self.lut[c][i0])
        });
        let back = self.basis.transpose() * Vector3::new(v[0], v[1], v[2]);
        std::array::from_fn(|k| back[k] + self.mean[k])
    }
}

/// Histogram-preserving blend of Gaussian values: the weighted sum normalised by the root of
/// the summed squared weights keeps unit variance where patches overlap (a plain weighted
/// mean would halve it and blur). `None` when the weights vanish.
#[inline]
pub fn blend(samples: impl Iterator<Item = (f32, [f32; 3])>) -> Option<[f32; 3]> {
    let (mut acc, mut w2) = ([0f32; 3], 0f32);
    for (w, g) in samples {
        for k in 0..3 {
            acc[k] += w * g[k];
        }
        w2 += w * w;
    }
    (w2 > 1e-12).then(|| acc.map(|a| a / w2.sqrt()))
}

/// A patch's weight at `r`, its distance from the centre over its radius: smooth, 1 at the
/// centre, 0 from the radius on.
#[inline]
pub fn bump(r: f64) -> f32 {
    bump_squared(r * r)
}

/// [`bump`] from the square of its argument (no root where the squared distance is at hand).
#[inline]
pub fn bump_squared(r2: f64) -> f32 {
    let s = 1.0 - r2;
    if s <= 0.0 {
        0.0
    } else {
        (s * s) as f32
    }
}

/// The exemplar offset, among `candidates` random ones, whose values agree best with
/// `constraints` (a point in patch coordinates and the Gaussian value wanted there); the
/// first candidate when there is no constraint. Offsets keep a patch of radius `radius`
/// inside the exemplar.
pub fn choose_offset(
    ex: &Exemplar,
    radius: f64,
    candidates: usize,
    rng: &mut SplitMix64,
    constraints: &[([f64; 2], [f32; 3])],
) -> [f64; 2] {
    let lo = radius + 1.0;
    let (hx, hy) = (ex.width as f64 - lo, ex.height as f64 - lo);
    let mut draw = || {
        [
            if hx > lo {
                rng.range(lo, hx)
            } else {
                ex.width as f64 / 2.0
            },
            if hy > lo {
                rng.range(lo, hy)
            } else {
                ex.height as f64 / 2.0
            },
        ]
    };
    let first = draw();
    if constraints.is_empty() {
        return first;
    }
    let cost = |o: [f64; 2]| -> f64 {
        constraints
            .iter()
            .map(|(p, g)| {
                let s = ex.sample(o[0] + p[0], o[1] + p[1]);
                (0..3).map(|k| ((s[k] - g[k]) as f64).powi(2)).sum::<f64>()
            })
            .sum()
    };
    let mut best = (cost(first), first);
    for _ in 1..candidates.max(1) {
        let o = draw();
        let c = cost(o);
        if c < best.0 {
            best = (c, o);
        }
    }
    best.1
}

/// Options for [`synthesize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneOptions {
    /// Patch radius, texels (capped so a patch fits in the exemplar). Default: 32.
    pub radius: f64,
    /// Random offsets tried per patch; the one agreeing best with the patches already placed
    /// wins (1 = purely random). Default: 16.
    pub candidates: usize,
    /// Random seed: the same seed gives the same bytes. Default: 1.
    pub seed: u64,
}

impl Default for PlaneOptions {
    fn default() -> Self {
        PlaneOptions {
            radius: 32.0,
            candidates: 16,
            seed: 1,
        }
    }
}

/// The largest patch radius an exemplar of this size holds.
pub fn max_radius(ex: &Exemplar) -> f64 {
    ((ex.width.min(ex.height) as f64 - 3.0) / 2.0).max(1.0)
}

/// A `width x height` image of `ex`'s texture: patches centred on a jittered grid (spacing
/// one radius, so every pixel lies within 0.8 radius of a centre), placed in raster order,
/// each at the candidate offset agreeing best with its placed neighbours, blended with the
/// histogram-preserving blend. Row-major RGB.
pub fn synthesize(
    ex: &Exemplar,
    width: usize,
    height: usize,
    opts: &PlaneOptions,
) -> Vec<[f32; 3]> {
    let r = opts.radius.clamp(2.0, max_radius(ex));
    let step = r;
    let (gw, gh) = (
        (width as f64 / step).ceil() as usize + 1,
        (height as f64 / step).ceil() as usize + 1,
    );
    let mut rng = SplitMix64::new(opts.seed);
    // (centre, offset) per grid cell, row-major.
    let mut patches: Vec<([f64; 2], [f64; 2])> = Vec::with_capacity(gw * gh);
    for gy in 0..gh {
        for gx in 0..gw {
            // Whole-pixel centres and offsets: every output pixel then reads exemplar
            // texels as they are (bilinear reads between texels would average independent
            // values and lower the variance the blend keeps).
            let c = [
                (gx as f64 * step + rng.range(-0.2, 0.2) * step).round(),
                (gy as f64 * step + rng.range(-0.2, 0.2) * step).round(),
            ];
            // Constraints: where this patch overlaps the placed left and upper neighbours,
            // what they show there.
            let mut cons = Vec::new();
            let neighbours = [
                (gx > 0).then(|| gy * gw + gx - 1),
                (gy > 0).then(|| (gy - 1) * gw + gx),
                (gy > 0 && gx > 0).then(|| (gy - 1) * gw + gx - 1),
                (gy > 0 && gx + 1 < gw).then(|| (gy - 1) * gw + gx + 1),
            ];
            for &(nc, no) in neighbours.iter().flatten().map(|&k| &patches[k]) {
                for s in 0..12 {
                    let a = s as f64 / 12.0 * std::f64::consts::TAU;
                    for rr in [0.35, 0.7] {
                        let p = [c[0] + rr * r * a.cos(), c[1] + rr * r * a.sin()];
                        let dn = ((p[0] - nc[0]).powi(2) + (p[1] - nc[1]).powi(2)).sqrt();
                        if dn < 0.8 * r {
                            let g = ex.sample(no[0] + p[0] - nc[0], no[1] + p[1] - nc[1]);
                            cons.push(([p[0] - c[0], p[1] - c[1]], g));
                        }
                    }
                }
            }
            let o = choose_offset(ex, r, opts.candidates, &mut rng, &cons).map(f64::round);
            patches.push((c, o));
        }
    }
    let mut out = vec![[0f32; 3]; width * height];
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let gy = (y as f64 / step).round() as i64;
        for (x, px) in row.iter_mut().enumerate() {
            let gx = (x as f64 / step).round() as i64;
            let mut near = Vec::with_capacity(9);
            for yy in (gy - 2).max(0)..=(gy + 2).min(gh as i64 - 1) {
                for xx in (gx - 2).max(0)..=(gx + 2).min(gw as i64 - 1) {
                    let (c, o) = patches[yy as usize * gw + xx as usize];
                    let (dx, dy) = (x as f64 - c[0], y as f64 - c[1]);
                    let w = bump((dx * dx + dy * dy).sqrt() / r);
                    if w > 0.0 {
                        near.push((w, ex.sample(o[0] + dx, o[1] + dy)));
                    }
                }
            }
            let g = blend(near.into_iter()).unwrap_or([0.0; 3]);
            *px = ex.colour(g);
        }
    });
    out
}

/// Largest side `scantex synth` writes, pixels.
pub const MAX_SIDE: usize = 16384;

/// [`synthesize`] on a planar image (grey or RGB, as `scantex synth` reads it): the output
/// has the input's channels.
pub fn synthesize_image(
    img: &crate::planar::Image,
    width: usize,
    height: usize,
    opts: &PlaneOptions,
) -> Result<crate::planar::Image> {
    if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
        return Err(Error::option(
            "size",
            format!("{width}x{height}: each side must lie in 1..={MAX_SIDE}"),
        ));
    }
    if opts.candidates == 0 || !(opts.radius >= 2.0 && opts.radius <= 512.0) {
        return Err(Error::option(
            "radius",
            format!(
                "radius {} and {} candidates: expected a radius from 2 to 512 and at least one candidate",
                opts.radius, opts.candidates
            ),
        ));
    }
    let ch = img.channels;
    if !(ch == 1 || ch == 3) || img.data.len() != img.width * img.height * ch {
        return Err(Error::Invalid(format!(
            "the exemplar must be a grey or RGB image (got {} channels)",
            ch
        )));
    }
    let texels: Vec<[f32; 3]> = img
        .data
        .chunks(ch)
        .map(|p| {
            if ch == 1 {
                [p[0]; 3]
            } else {
                [p[0], p[1], p[2]]
            }
        })
        .collect();
    let ex = Exemplar::new(img.width, img.height, &texels)?;
    let out = synthesize(&ex, width, height, opts);
    let data = if ch == 1 {
        out.iter().map(|p| p[0]).collect()
    } else {
        out.iter().flatten().copied().collect()
    };
    Ok(crate::planar::Image {
        width,
        height,
        channels: ch,
        data,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise_exemplar(w: usize, h: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = SplitMix64::new(seed);
        (0..w * h)
            .map(|_| {
                let a = rng.next_f64() as f32;
                [0.2 + 0.5 * a, 0.3 + 0.2 * a, 0.6 * rng.next_f64() as f32]
            })
            .collect()
    }

    /// The normal CDF and its inverse agree (round trip) over the range used.
    #[test]
    fn phi_and_its_inverse_round_trip() {
        for k in 1..200 {
            let p = k as f64 / 200.0;
            let x = phi_inv(p);
            assert!((phi(x as f32) as f64 - p).abs() < 2e-6, "{p} -> {x}");
        }
        assert!((phi_inv(0.975) - 1.959_964).abs() < 1e-5);
    }

    /// Gaussianising an exemplar texel and mapping it back gives the texel (the transforms
    /// are inverse up to the quantile table's resolution).
    #[test]
    fn transforms_round_trip() {
        let t = noise_exemplar(64, 64, 3);
        let ex = Exemplar::new(64, 64, &t).unwrap();
        let mut worst = 0f32;
        for (i, c) in t.iter().enumerate().step_by(7) {
            let back = ex.colour(ex.g[i]);
            for k in 0..3 {
                worst = worst.max((back[k] - c[k]).abs());
            }
        }
        assert!(worst < 0.01, "worst round-trip error {worst}");
    }

    /// The synthesised image keeps the exemplar's per-channel histogram: mean, deviation and
    /// the 10th and 90th percentiles within a small tolerance, on independent noise where a
    /// plain blend would halve the deviation at every overlap.
    #[test]
    fn synthesis_preserves_the_histogram() {
        let t = noise_exemplar(96, 96, 5);
        let ex = Exemplar::new(96, 96, &t).unwrap();
        let out = synthesize(&ex, 200, 150, &PlaneOptions::default());
        let stats = |v: &[[f32; 3]], k: usize| {
            let mut c: Vec<f32> = v.iter().map(|p| p[k]).collect();
            c.sort_by(f32::total_cmp);
            let n = c.len() as f64;
            let m = c.iter().map(|&x| x as f64).sum::<f64>() / n;
            let sd = (c.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / n).sqrt();
            (m, sd, c[c.len() / 10] as f64, c[c.len() * 9 / 10] as f64)
        };
        for k in 0..3 {
            let (a, b) = (stats(&t, k), stats(&out, k));
            assert!((a.0 - b.0).abs() < 0.01, "channel {k} mean {a:?} vs {b:?}");
            assert!(
                (a.1 - b.1).abs() < 0.1 * a.1,
                "channel {k} deviation {a:?} vs {b:?}"
            );
            assert!(
                (a.2 - b.2).abs() < 0.03 && (a.3 - b.3).abs() < 0.03,
                "{a:?} vs {b:?}"
            );
        }
    }

    /// The same seed gives the same values; another seed other values.
    #[test]
    fn synthesis_is_deterministic() {
        let t = noise_exemplar(64, 64, 9);
        let ex = Exemplar::new(64, 64, &t).unwrap();
        let o = PlaneOptions::default();
        let a = synthesize(&ex, 80, 60, &o);
        assert_eq!(a, synthesize(&ex, 80, 60, &o));
        assert_ne!(a, synthesize(&ex, 80, 60, &PlaneOptions { seed: 2, ..o }));
    }

    /// Offsets are chosen by their agreement: given constraints copied from one offset, the
    /// search over many candidates lands closer to it than a random draw does on average.
    #[test]
    fn choose_offset_follows_the_constraints() {
        // A smooth ramp exemplar: values identify positions.
        let t: Vec<[f32; 3]> = (0..128 * 128)
            .map(|i| {
                let (x, y) = ((i % 128) as f32, (i / 128) as f32);
                [x / 128.0, y / 128.0, (x + y) / 256.0]
            })
            .collect();
        let ex = Exemplar::new(128, 128, &t).unwrap();
        let target = [60.0, 70.0];
        let cons: Vec<_> = [[-5.0, 0.0], [5.0, 3.0], [0.0, -6.0]]
            .iter()
            .map(|p| (*p, ex.sample(target[0] + p[0], target[1] + p[1])))
            .collect();
        let mut rng = SplitMix64::new(1);
        let o = choose_offset(&ex, 20.0, 400, &mut rng, &cons);
        let d = ((o[0] - target[0]).powi(2) + (o[1] - target[1]).powi(2)).sqrt();
        assert!(d < 6.0, "chosen {o:?}, wanted {target:?}");
    }

    #[test]
    fn tiny_or_bad_exemplars_are_refused() {
        assert!(Exemplar::new(3, 3, &[[0.0; 3]; 9]).is_err());
        let mut t = vec![[0.5f32; 3]; 16];
        t[3][1] = f32::NAN;
        assert!(Exemplar::new(4, 4, &t).is_err());
    }
}
