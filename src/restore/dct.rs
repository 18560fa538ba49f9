//! Frequency split of §5.2: an orthonormal 2D DCT-II (rustdct), the low band of the first
//! kappa subbands, and kappa chosen from the autocorrelation of the high band.

use rayon::prelude::*;
use rustdct::{DctNum, DctPlanner, TransformType2And3};
use std::sync::Arc;

/// An orthonormal separable 2D DCT-II of a `w` x `h` image (and its inverse, DCT-III).
pub(crate) struct Dct2<T: DctNum = f64> {
    w: usize,
    h: usize,
    row: Arc<dyn TransformType2And3<T>>,
    col: Arc<dyn TransformType2And3<T>>,
}

impl<T: DctNum> Dct2<T> {
    pub(crate) fn new(w: usize, h: usize) -> Dct2<T> {
        let mut p = DctPlanner::new();
        Dct2 {
            w,
            h,
            row: p.plan_dct2(w),
            col: p.plan_dct2(h),
        }
    }

    /// In place, row-major `h` rows of `w`.
    pub(crate) fn forward(&self, data: &mut [T]) {
        self.pass(data, true);
    }

    /// Exact inverse of [`Dct2::forward`].
    pub(crate) fn inverse(&self, data: &mut [T]) {
        self.pass(data, false);
    }

    fn pass(&self, data: &mut [T], forward: bool) {
        let (w, h) = (self.w, self.h);
        rows(data, w, &*self.row, forward);
        let mut t = transpose(data, w, h);
        rows(&mut t, h, &*self.col, forward);
        let back = transpose(&t, h, w);
        data.copy_from_slice(&back);
    }
}

/// Orthonormal 1D transforms of every row. rustdct does not normalise: DCT-II scaled by
/// sqrt(1/n) (k = 0) and sqrt(2/n) is orthonormal; the inverse undoes the scale and runs
/// DCT-III, which carries a factor 1/2 on the first coefficient.
fn rows<T: DctNum>(data: &mut [T], n: usize, t: &dyn TransformType2And3<T>, forward: bool) {
    let c = |v: f64| T::from_f64(v).expect("a float type");
    let s0 = c((1.0 / n as f64).sqrt());
    let s = c((2.0 / n as f64).sqrt());
    let two_s0 = c(2.0 * (1.0 / n as f64).sqrt());
    data.par_chunks_mut(n).for_each_init(
        || vec![T::zero(); t.get_scratch_len()],
        |scratch, row| {
            if forward {
                t.process_dct2_with_scratch(row, scratch);
                row[0] = row[0] * s0;
                for v in &mut row[1..] {
                    *v = *v * s;
                }
            } else {
                row[0] = row[0] * two_s0;
                for v in &mut row[1..] {
                    *v = *v * s;
                }
                t.process_dct3_with_scratch(row, scratch);
            }
        },
    );
}

fn transpose<T: DctNum>(data: &[T], w: usize, h: usize) -> Vec<T> {
    let mut out = vec![T::zero(); w * h];
    out.par_chunks_mut(h).enumerate().for_each(|(x, col)| {
        for (y, v) in col.iter_mut().enumerate() {
            *v = data[y * w + x];
        }
    });
    out
}

/// Whether DCT coefficient (u across, v down) of a `w` x `h` image lies in the first `kappa`
/// subbands. Subband k is the square ring max(u', v') = k of the coefficient plane scaled to
/// the image's longer side, u' = u * S / w, v' = v * S / h: the paper pads to a square, and on
/// the square this is max(u, v) < kappa. kappa = S keeps every coefficient.
pub(crate) fn in_low_band(u: usize, v: usize, w: usize, h: usize, kappa: usize) -> bool {
    let s = w.max(h);
    u * s < kappa * w && v * s < kappa * h
}

/// Splits one channel into (low, high) with low = inverse DCT of the first `kappa` subbands
/// and high = image - low.
pub(crate) fn split(channel: &[f32], w: usize, h: usize, kappa: usize) -> (Vec<f32>, Vec<f32>) {
    if kappa == 0 {
        // No subband is low: the transforms would give zeros (the inverse DCT of zeros) and
        // the image itself, exactly. The automatic rule picks 0 for most atlas crops.
        return (vec![0.0; channel.len()], channel.to_vec());
    }
    // The low band's coefficients form a U x V corner of the plane (u < kappa w / S).
    let (nu, nv) = (
        (kappa * w).div_ceil(w.max(h)).min(w),
        (kappa * h).div_ceil(w.max(h)).min(h),
    );
    let low = if nu + nv <= DIRECT_MAX {
        low_direct(channel, w, h, nu, nv)
    } else {
        low_by_transform(channel, w, h, kappa)
    };
    let high = channel.iter().zip(&low).map(|(a, b)| a - b).collect();
    (low, high)
}

/// The low band of the first `kappa` subbands through the whole plane's transform and back.
fn low_by_transform<T: DctNum>(channel: &[T], w: usize, h: usize, kappa: usize) -> Vec<T> {
    let dct = Dct2::<T>::new(w, h);
    let mut c = channel.to_vec();
    dct.forward(&mut c);
    for v in 0..h {
        for u in 0..w {
            if !in_low_band(u, v, w, h, kappa) {
                c[v * w + u] = T::zero();
            }
        }
    }
    dct.inverse(&mut c);
    c
}

/// Up to this many low-band coefficients along both axes together, [`split`] projects onto
/// them directly (w h (U + V) products each way) instead of transforming the whole plane: the
/// automatic kappa is at most a few subbands, and two full transforms of every crop were half
/// of restoration's split time on the corset scene (`docs/benchmarks.md`).
const DIRECT_MAX: usize = 32;

/// The orthonormal DCT-II basis functions 0..n_k on n samples, row-major (k, x).
fn basis(n: usize, n_k: usize) -> Vec<f64> {
    let mut b = vec![0f64; n_k * n];
    for k in 0..n_k {
        let a = if k == 0 {
            (1.0 / n as f64).sqrt()
        } else {
            (2.0 / n as f64).sqrt()
        };
        for x in 0..n {
            b[k * n + x] =
                a * (std::f64::consts::PI * (2 * x + 1) as f64 * k as f64 / (2 * n) as f64).cos();
        }
    }
    b
}

/// The inverse transform of the first `nu` x `nv` coefficients of `channel`'s orthonormal
/// 2D DCT-II (the others zero): the projection onto those basis images, separably.
fn low_direct(channel: &[f32], w: usize, h: usize, nu: usize, nv: usize) -> Vec<f32> {
    let (bx, by) = (basis(w, nu), basis(h, nv));
    // Along the rows: r(y, u) = sum_x X(y, x) phi_u(x).
    let r: Vec<f64> = channel
        .par_chunks(w)
        .flat_map_iter(|row| {
            (0..nu).map(|u| {
                let b = &bx[u * w..u * w + w];
                row.iter().zip(b).map(|(&a, &p)| a as f64 * p).sum::<f64>()
            })
        })
        .collect();
    // Down the columns, and back: s(y, u) = sum_v phi_v(y) sum_y' phi_v(y') r(y', u).
    let mut c = vec![0f64; nv * nu];
    for v in 0..nv {
        for y in 0..h {
            let p = by[v * h + y];
            for u in 0..nu {
                c[v * nu + u] += p * r[y * nu + u];
            }
        }
    }
    let mut out = vec![0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let s: Vec<f64> = (0..nu)
            .map(|u| (0..nv).map(|v| by[v * h + y] * c[v * nu + u]).sum())
            .collect();
        for (x, o) in row.iter_mut().enumerate() {
            *o = (0..nu).map(|u| s[u] * bx[u * w + x]).sum::<f64>() as f32;
        }
    });
    out
}

/// The standard deviation of the elements of the autocorrelation of the high band, for each
/// kappa in `0..=max_kappa`, and the smallest kappa whose value is below `threshold`
/// (`max_kappa` if none is).
///
/// Normalisation (the paper's footnote leaves it open): orthonormal transforms, intensities in
/// [0, 1], and A divided by the side S of the padded square, which makes A(tau) the mean over
/// pixels of H(x) H(x + tau): a per-pixel autocorrelation whose values do not grow with the
/// image size. Its element standard deviation is then about 1e-4 for a homogeneous texture and
/// 1e-2 for one under a strong intensity ramp, and the paper's 0.001 falls between.
pub(crate) fn auto_kappa(
    y: &[f64],
    w: usize,
    h: usize,
    threshold: f64,
    max_kappa: usize,
) -> (usize, Vec<f64>) {
    let s = w.max(h);
    let dct = Dct2::<f64>::new(w, h);
    let sq = Dct2::<f64>::new(s, s);
    let mut c = y.to_vec();
    dct.forward(&mut c);
    let mut curve = Vec::new();
    let mut chosen = None;
    for kappa in 0..=max_kappa {
        let mut hk = c.clone();
        for v in 0..h {
            for u in 0..w {
                if in_low_band(u, v, w, h, kappa) {
                    hk[v * w + u] = 0.0;
                }
            }
        }
        // DCT(H) on the zero-padded square: for a square image that is hk itself.
        let mut d = if w == h {
            hk
        } else {
            dct.inverse(&mut hk);
            let mut pad = vec![0f64; s * s];
            for yy in 0..h {
                pad[yy * s..yy * s + w].copy_from_slice(&hk[yy * w..yy * w + w]);
            }
            sq.forward(&mut pad);
            pad
        };
        for v in &mut d {
            *v *= *v;
        }
        sq.inverse(&mut d);
        let n = (w * h) as f64;
        let (mut sum, mut sum2) = (0f64, 0f64);
        for yy in 0..h {
            for xx in 0..w {
                let a = d[yy * s + xx] / s as f64;
                sum += a;
                sum2 += a * a;
            }
        }
        let mean = sum / n;
        let sd = (sum2 / n - mean * mean).max(0.0).sqrt();
        curve.push(sd);
        if sd < threshold {
            chosen = Some(kappa);
            break;
        }
    }
    (chosen.unwrap_or(max_kappa), curve)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dct_round_trip_and_orthonormality() {
        let (w, h) = (12, 7);
        let img: Vec<f64> = (0..w * h).map(|i| ((i * 37 % 11) as f64).sin()).collect();
        let mut c = img.clone();
        let d = Dct2::<f64>::new(w, h);
        d.forward(&mut c);
        let e0: f64 = img.iter().map(|v| v * v).sum();
        let e1: f64 = c.iter().map(|v| v * v).sum();
        assert!((e0 - e1).abs() < 1e-9 * e0, "Parseval: {e0} vs {e1}");
        d.inverse(&mut c);
        for (a, b) in img.iter().zip(&c) {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn split_extremes() {
        let (w, h) = (16, 10);
        let img: Vec<f32> = (0..w * h).map(|i| (i % 7) as f32 * 0.1).collect();
        let (l0, h0) = split(&img, w, h, 0);
        assert!(l0.iter().all(|v| v.abs() < 1e-6));
        assert!(h0.iter().zip(&img).all(|(a, b)| (a - b).abs() < 1e-6));
        let (lm, hm) = split(&img, w, h, w.max(h));
        assert!(hm.iter().all(|v| v.abs() < 1e-5));
        assert!(lm.iter().zip(&img).all(|(a, b)| (a - b).abs() < 1e-5));
        // kappa = 1 keeps exactly the mean.
        let (l1, _) = split(&img, w, h, 1);
        let mean = img.iter().sum::<f32>() / img.len() as f32;
        assert!(l1.iter().all(|v| (v - mean).abs() < 1e-5));
    }

    #[test]
    fn the_direct_projection_is_the_transforms_low_band() {
        // Non-square crops, as restoration cuts them: the low band projected directly must be
        // the whole transform's with the other coefficients zeroed.
        let mut s = 11u64;
        for (w, h) in [(97, 61), (40, 128), (64, 64)] {
            let img: Vec<f32> = (0..w * h)
                .map(|i| {
                    s = s
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    (s >> 40) as f32 / (1u64 << 24) as f32 + 0.002 * (i % w) as f32
                })
                .collect();
            for kappa in [1, 2, 3, 5, 9] {
                let (low, high) = split(&img, w, h, kappa);
                let wide: Vec<f64> = img.iter().map(|&v| v as f64).collect();
                let c = low_by_transform(&wide, w, h, kappa);
                for i in 0..w * h {
                    assert!(
                        (low[i] as f64 - c[i]).abs() < 1e-5,
                        "{w}x{h} kappa {kappa} at {i}: {} against {}",
                        low[i],
                        c[i]
                    );
                    assert!((low[i] + high[i] - img[i]).abs() < 1e-6);
                }
            }
        }
    }

    #[test]
    fn ramp_needs_a_larger_kappa_than_flat_noise() {
        let (w, h) = (64, 48);
        let mut s = 7u64;
        let noise: Vec<f64> = (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                0.5 + 0.1 * (((s >> 33) as f64 / (1u64 << 31) as f64) - 0.5)
            })
            .collect();
        let (k_flat, _) = auto_kappa(&noise, w, h, 0.001, 32);
        let ramp: Vec<f64> = noise
            .iter()
            .enumerate()
            .map(|(i, v)| v * (0.2 + 0.8 * (i % w) as f64 / w as f64))
            .collect();
        let (k_ramp, curve) = auto_kappa(&ramp, w, h, 0.001, 32);
        assert!(k_flat <= 1, "flat noise: kappa {k_flat}");
        assert!(
            k_ramp > k_flat && k_ramp < 32,
            "ramp: kappa {k_ramp}, curve {curve:?}"
        );
    }
}
