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

/// Fills the pixels of `fill` (within `domain`) of an interleaved image with `ch` channels
/// (1 or 3: restoration's images are grey or RGB, checked by [`super::inpaint`]). `sweeps`
/// Jacobi sweeps run at every level of the cascade.
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
    // Each coarse texel reads its own 2 x 2 block: rows of the coarse grid in parallel.
    let src: &[f32] = data;
    cd.par_chunks_mut(w2 * ch)
        .zip(cknown.par_chunks_mut(w2))
        .zip(cdomain.par_chunks_mut(w2))
        .enumerate()
        .for_each(|(y2, ((cd, cknown), cdomain))| {
            for x2 in 0..w2 {
                let mut n = 0f32;
                for y in 2 * y2..(2 * y2 + 2).min(h) {
                    for x in 2 * x2..(2 * x2 + 2).min(w) {
                        let i = y * w + x;
                        cdomain[x2] |= domain[i];
                        if domain[i] && !fill[i] {
                            for c in 0..ch {
                                cd[x2 * ch + c] += src[i * ch + c];
                            }
                            n += 1.0;
                        }
                    }
                }
                if n > 0.0 {
                    cknown[x2] = true;
                    for c in 0..ch {
                        cd[x2 * ch + c] /= n;
                    }
                }
            }
        });
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
    match ch {
        1 => smooth_ch::<1>(data, w, h, fill, domain, sweeps),
        3 => smooth_ch::<3>(data, w, h, fill, domain, sweeps),
        _ => unreachable!("restoration works on grey or RGB images"),
    }
}

/// Fill pixels per parallel task of a sweep: one pixel per task cost more in rayon's
/// splitting than in the stencil.
const SWEEP_CHUNK: usize = 1024;

/// [`smooth`] for `CH` channels. Which of a pixel's eight neighbours lie in the image and in
/// the domain does not change between sweeps, so it is found once (a bit per neighbour, in
/// the stencil's order) with the weight sum, added in that same order: the sweeps then read
/// only the neighbours' values, and give the same bytes as testing every neighbour in every
/// sweep did.
fn smooth_ch<const CH: usize>(
    data: &mut [f32],
    w: usize,
    h: usize,
    fill: &[bool],
    domain: &[bool],
    sweeps: usize,
) {
    // The stencil's order: rows above, beside and below, left to right.
    const STENCIL: [(i64, i64); 8] = [
        (-1, -1),
        (0, -1),
        (1, -1),
        (-1, 0),
        (1, 0),
        (-1, 1),
        (0, 1),
        (1, 1),
    ];
    let idx: Vec<usize> = (0..w * h).filter(|&i| fill[i]).collect();
    if idx.is_empty() || sweeps == 0 {
        return;
    }
    let offsets: [isize; 8] = STENCIL.map(|(dx, dy)| dy as isize * w as isize + dx as isize);
    let weights: [f32; 8] = STENCIL.map(|(dx, dy)| if dx == 0 || dy == 0 { B } else { A });
    let (nbits, wsums): (Vec<u8>, Vec<f32>) = idx
        .par_iter()
        .map(|&i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let mut bits = 0u8;
            let mut wsum = 0f32;
            for (b, &(dx, dy)) in STENCIL.iter().enumerate() {
                let (xx, yy) = (x + dx, y + dy);
                if xx < 0 || yy < 0 || xx >= w as i64 || yy >= h as i64 {
                    continue;
                }
                if domain[yy as usize * w + xx as usize] {
                    bits |= 1 << b;
                    wsum += weights[b];
                }
            }
            (bits, wsum)
        })
        .unzip();
    let mut next = vec![[0f32; CH]; idx.len()];
    for _ in 0..sweeps {
        let src: &[f32] = data;
        next.par_chunks_mut(SWEEP_CHUNK)
            .zip(idx.par_chunks(SWEEP_CHUNK))
            .zip(nbits.par_chunks(SWEEP_CHUNK))
            .zip(wsums.par_chunks(SWEEP_CHUNK))
            .for_each(|(((out, is), bs), ws)| {
                for (((o, &i), &bits), &wsum) in out.iter_mut().zip(is).zip(bs).zip(ws) {
                    let mut acc = [0f32; CH];
                    for b in 0..8 {
                        if bits & (1 << b) != 0 {
                            let j = (i as isize + offsets[b]) as usize;
                            for c in 0..CH {
                                acc[c] += weights[b] * src[j * CH + c];
                            }
                        }
                    }
                    for c in 0..CH {
                        o[c] = if wsum > 0.0 {
                            acc[c] / wsum
                        } else {
                            src[i * CH + c]
                        };
                    }
                }
            });
        for (v, &i) in next.iter().zip(&idx) {
            let dst: &mut [f32; CH] = (&mut data[i * CH..i * CH + CH])
                .try_into()
                .expect("CH values");
            *dst = *v;
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

    /// The sweeps as first written: every neighbour tested for the image and the domain in
    /// every sweep.
    fn smooth_reference(
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
            for (out, &i) in next.chunks_mut(ch).zip(&idx) {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                let mut acc = [0f32; 4];
                let mut wsum = 0f32;
                for dy in -1i64..=1 {
                    for dx in -1i64..=1 {
                        let (xx, yy) = (x + dx, y + dy);
                        if (dx == 0 && dy == 0)
                            || xx < 0
                            || yy < 0
                            || xx >= w as i64
                            || yy >= h as i64
                        {
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
            }
            for (k, &i) in idx.iter().enumerate() {
                data[i * ch..i * ch + ch].copy_from_slice(&next[k * ch..k * ch + ch]);
            }
        }
    }

    #[test]
    fn sweeps_give_the_bytes_of_testing_every_neighbour() {
        // Random fill and domain up to the image's edges (fill pixels with no neighbour in
        // the domain too), odd sizes, one and three channels.
        let mut rng = crate::rng::SplitMix64::new(7);
        for &(w, h, ch) in &[(37, 23, 3), (64, 1, 1), (1, 9, 3), (50, 41, 1)] {
            let mut u = || rng.next_f64() as f32;
            let domain: Vec<bool> = (0..w * h).map(|_| u() < 0.8).collect();
            let fill: Vec<bool> = (0..w * h).map(|i| domain[i] && u() < 0.4).collect();
            let start: Vec<f32> = (0..w * h * ch).map(|_| u()).collect();
            let (mut a, mut b) = (start.clone(), start);
            smooth(&mut a, w, h, ch, &fill, &domain, 7);
            smooth_reference(&mut b, w, h, ch, &fill, &domain, 7);
            assert!(fill.iter().any(|&f| f));
            for (k, (x, y)) in a.iter().zip(&b).enumerate() {
                assert_eq!(x.to_bits(), y.to_bits(), "{w}x{h}x{ch}, value {k}");
            }
        }
    }

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
