//! Fast diffusion inpainting (Oliveira et al. 2001): masked pixels are repeatedly replaced by
//! a weighted mean of their eight neighbours (a = 0.073235 diagonally, b = 0.176765 along the
//! axes), known pixels never change.
//!
//! Plain repetition needs on the order of r^2 sweeps to carry colour into a hole of radius r.
//! We start each level from the solution one octave coarser (a pull-push cascade down to a few
//! pixels) and run the same sweeps there, so a 90-pixel disc converges in the same number of
//! sweeps as a scratch. Only pixels inside `domain` are read: chart gutter never bleeds in.

use rayon::prelude::*;

const A: f32 = 0.073235;
const B: f32 = 0.176765;

/// Fills the pixels of `fill` (within `domain`) of an interleaved image with `ch` channels.
/// `sweeps` Jacobi sweeps run at every level of the cascade.
pub(crate) fn inpaint(
    data: &mut [f32],
    w: usize,
    h: usize,
    ch: usize,
    fill: &[bool],
    domain: &[bool],
    sweeps: usize,
) {
    let fill: Vec<bool> = fill.iter().zip(domain).map(|(&f, &d)| f && d).collect();
    if !fill.iter().any(|&f| f) {
        return;
    }
    init_from_coarser(data, w, h, ch, &fill, domain, sweeps);
    smooth(data, w, h, ch, &fill, domain, sweeps);
}

/// Sets the fill pixels from a filled half-resolution copy (recursively).
fn init_from_coarser(
    data: &mut [f32],
    w: usize,
    h: usize,
    ch: usize,
    fill: &[bool],
    domain: &[bool],
    sweeps: usize,
) {
    if w <= 2 && h <= 2 {
        // Mean of what is known; zero if nothing is.
        let mut sum = vec![0f64; ch];
        let mut n = 0f64;
        for i in 0..w * h {
            if domain[i] && !fill[i] {
                for c in 0..ch {
                    sum[c] += data[i * ch + c] as f64;
                }
                n += 1.0;
            }
        }
        for i in 0..w * h {
            if fill[i] {
                for c in 0..ch {
                    data[i * ch + c] = if n > 0.0 { (sum[c] / n) as f32 } else { 0.0 };
                }
            }
        }
        return;
    }
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut cd = vec![0f32; w2 * h2 * ch];
    let mut cknown = vec![false; w2 * h2];
    let mut cdomain = vec![false; w2 * h2];
    // Every value is added to before it is written (`crate::io::touch_for_writing`).
    crate::io::touch_for_writing(&mut cd);
    crate::io::touch_for_writing(&mut cdomain);
    for y2 in 0..h2 {
        for x2 in 0..w2 {
            let j = y2 * w2 + x2;
            let mut n = 0f32;
            for y in 2 * y2..(2 * y2 + 2).min(h) {
                for x in 2 * x2..(2 * x2 + 2).min(w) {
                    let i = y * w + x;
                    cdomain[j] |= domain[i];
                    if domain[i] && !fill[i] {
                        for c in 0..ch {
                            cd[j * ch + c] += data[i * ch + c];
                        }
                        n += 1.0;
                    }
                }
            }
            if n > 0.0 {
                cknown[j] = true;
                for c in 0..ch {
                    cd[j * ch + c] /= n;
                }
            }
        }
    }
    let cfill: Vec<bool> = cknown
        .iter()
        .zip(&cdomain)
        .map(|(&k, &d)| d && !k)
        .collect();
    if cfill.iter().any(|&f| f) {
        init_from_coarser(&mut cd, w2, h2, ch, &cfill, &cdomain, sweeps);
        smooth(&mut cd, w2, h2, ch, &cfill, &cdomain, sweeps);
    }
    // Bilinear from the coarse grid (sample centres at 2j + 0.5).
    data.par_chunks_mut(w * ch)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..w {
                let i = y * w + x;
                if !fill[i] {
                    continue;
                }
                let fx = ((x as f32 - 0.5) / 2.0).clamp(0.0, (w2 - 1) as f32);
                let fy = ((y as f32 - 0.5) / 2.0).clamp(0.0, (h2 - 1) as f32);
                let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(w2 - 1), (y0 + 1).min(h2 - 1));
                let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                let mut acc = [0f32; 4];
                let mut wsum = 0f32;
                for (xx, yy, wt) in [
                    (x0, y0, (1.0 - tx) * (1.0 - ty)),
                    (x1, y0, tx * (1.0 - ty)),
                    (x0, y1, (1.0 - tx) * ty),
                    (x1, y1, tx * ty),
                ] {
                    let j = yy * w2 + xx;
                    if cdomain[j] && wt > 0.0 {
                        for c in 0..ch {
                            acc[c] += wt * cd[j * ch + c];
                        }
                        wsum += wt;
                    }
                }
                if wsum > 0.0 {
                    for c in 0..ch {
                        row[x * ch + c] = acc[c] / wsum;
                    }
                }
            }
        });
}

/// Jacobi sweeps of the diffusion kernel over the fill pixels.
fn smooth(
    data: &mut [f32],
    w: usize,
    h: usize,
    ch: usize,
    fill: &[bool],
    domain: &[bool],
    sweeps: usize,
) {
    let idx: Vec<usize> = (0..w * h).filter(|&i| fill[i]).collect();
    let mut next = vec![0f32; idx.len() * ch];
    for _ in 0..sweeps {
        next.par_chunks_mut(ch).zip(&idx).for_each(|(out, &i)| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let mut acc = [0f32; 4];
            let mut wsum = 0f32;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let (xx, yy) = (x + dx, y + dy);
                    if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                        continue;
                    }
                    let j = yy as usize * w + xx as usize;
                    if !domain[j] {
                        continue;
                    }
                    let k = if dx == 0 || dy == 0 { B } else { A };
                    for c in 0..ch {
                        acc[c] += k * data[j * ch + c];
                    }
                    wsum += k;
                }
            }
            for c in 0..ch {
                out[c] = if wsum > 0.0 {
                    acc[c] / wsum
                } else {
                    data[i * ch + c]
                };
            }
        });
        for (k, &i) in idx.iter().enumerate() {
            data[i * ch..i * ch + ch].copy_from_slice(&next[k * ch..k * ch + ch]);
        }
    }
}

#[allow(clippy::too_many_arguments)]
/// Local amplitude of a zero-mean band: the square root of the mean over channels of the
/// band squared, averaged over known pixels with three passes of a box filter of radius `r`
/// (close to a Gaussian of sigma 0.9 r), then diffused into the fill pixels like the low band.
/// Floored at a small fraction of its median so that flat regions do not divide by zero.
pub(crate) fn envelope(
    band: &[f32],
    w: usize,
    h: usize,
    ch: usize,
    fill: &[bool],
    domain: &[bool],
    r: usize,
    sweeps: usize,
) -> Vec<f32> {
    let known: Vec<f32> = (0..w * h)
        .map(|i| (domain[i] && !fill[i]) as u8 as f32)
        .collect();
    let mut e2: Vec<f32> = (0..w * h)
        .map(|i| {
            known[i] * band[i * ch..i * ch + ch].iter().map(|v| v * v).sum::<f32>() / ch as f32
        })
        .collect();
    let mut wt = known.clone();
    for _ in 0..3 {
        box_blur(&mut e2, w, h, r);
        box_blur(&mut wt, w, h, r);
    }
    let mut env: Vec<f32> = e2
        .iter()
        .zip(&wt)
        .map(|(&a, &b)| {
            if b > 1e-6 {
                (a / b).max(0.0).sqrt()
            } else {
                0.0
            }
        })
        .collect();
    // Texels with no known neighbour within reach get the diffused value.
    let far: Vec<bool> = (0..w * h).map(|i| fill[i] || wt[i] <= 1e-6).collect();
    inpaint(&mut env, w, h, 1, &far, domain, sweeps);
    let mut sorted: Vec<f32> = (0..w * h)
        .filter(|&i| domain[i] && !fill[i])
        .map(|i| env[i])
        .collect();
    let floor = if sorted.is_empty() {
        1e-3
    } else {
        let mid = sorted.len() / 2;
        let (_, m, _) = sorted.select_nth_unstable_by(mid, f32::total_cmp);
        (0.05 * *m).max(1e-4)
    };
    for v in &mut env {
        *v = v.max(floor);
    }
    env
}

/// In-place box filter of radius `r` (zero outside the image), rows then columns.
fn box_blur(v: &mut [f32], w: usize, h: usize, r: usize) {
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w)
        .zip(v.par_chunks(w))
        .for_each(|(o, s)| {
            let mut acc: f32 = s[..r.min(w)].iter().sum();
            for x in 0..w {
                if x + r < w {
                    acc += s[x + r];
                }
                o[x] = acc;
                if x >= r {
                    acc -= s[x - r];
                }
            }
        });
    // Columns: running sums over rows, one accumulator per column, strips of columns in
    // parallel (row-major reads, no transpose).
    const STRIP: usize = 256;
    let strips: Vec<(usize, Vec<f32>)> = (0..w.div_ceil(STRIP))
        .into_par_iter()
        .map(|k| {
            let (x0, x1) = (k * STRIP, ((k + 1) * STRIP).min(w));
            let sw = x1 - x0;
            let mut acc = vec![0f32; sw];
            for y in 0..r.min(h) {
                for (a, &t) in acc.iter_mut().zip(&tmp[y * w + x0..y * w + x1]) {
                    *a += t;
                }
            }
            let mut out = vec![0f32; sw * h];
            for y in 0..h {
                if y + r < h {
                    let row = &tmp[(y + r) * w + x0..(y + r) * w + x1];
                    for (a, &t) in acc.iter_mut().zip(row) {
                        *a += t;
                    }
                }
                out[y * sw..(y + 1) * sw].copy_from_slice(&acc);
                if y >= r {
                    let row = &tmp[(y - r) * w + x0..(y - r) * w + x1];
                    for (a, &t) in acc.iter_mut().zip(row) {
                        *a -= t;
                    }
                }
            }
            (x0, out)
        })
        .collect();
    for (x0, out) in strips {
        let sw = out.len() / h;
        for y in 0..h {
            v[y * w + x0..y * w + x0 + sw].copy_from_slice(&out[y * sw..(y + 1) * sw]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fills_a_large_hole_in_a_linear_ramp_with_the_ramp() {
        // A harmonic function is the fixed point of diffusion: a ramp must come back.
        let (w, h) = (96, 80);
        let truth: Vec<f32> = (0..w * h)
            .map(|i| 0.2 + 0.6 * (i % w) as f32 / w as f32)
            .collect();
        let fill: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 - 48.0, (i / w) as f32 - 40.0);
                x * x + y * y < 30.0 * 30.0
            })
            .collect();
        let mut img: Vec<f32> = truth
            .iter()
            .zip(&fill)
            .map(|(&v, &f)| if f { 0.0 } else { v })
            .collect();
        inpaint(&mut img, w, h, 1, &fill, &vec![true; w * h], 40);
        let worst = img
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(worst < 0.01, "worst error {worst}");
    }

    #[test]
    fn never_reads_outside_the_domain() {
        let (w, h) = (20, 10);
        // Left half is domain at 0.5 with a hole; right half (outside) holds 100.
        let domain: Vec<bool> = (0..w * h).map(|i| i % w < 10).collect();
        let fill: Vec<bool> = (0..w * h)
            .map(|i| (4..9).contains(&(i % w)) && (3..7).contains(&(i / w)))
            .collect();
        let mut img: Vec<f32> = (0..w * h)
            .map(|i| if domain[i] { 0.5 } else { 100.0 })
            .collect();
        inpaint(&mut img, w, h, 1, &fill, &domain, 20);
        for i in 0..w * h {
            if fill[i] {
                assert!((img[i] - 0.5).abs() < 1e-4, "texel {i}: {}", img[i]);
            }
            if !domain[i] {
                assert_eq!(img[i], 100.0);
            }
        }
    }
}
