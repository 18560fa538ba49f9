//! Gaussian and Laplacian pyramids (Burt and Adelson 1983) on multi-channel float planes, with
//! OpenCV's conventions so that `reduce` with `a = 0.375` is `cv2.pyrDown` and `expand` is
//! `cv2.pyrUp` (tested against fixtures in `calib/opencv/`): a 5-tap generating kernel
//! `[1/4 - a/2, 1/4, a, 1/4, 1/4 - a/2]`, reflect-101 borders, a reduced size of `ceil(n / 2)`,
//! and expansion as zero insertion followed by the kernel times two (reflect-101 on the
//! doubled grid, cropped to the requested size).
//!
//! Also a push-pull hole filler built from the same operators (normalised convolution across
//! scales), used to give undefined texels smooth values before a pyramid is built.

use rayon::prelude::*;

/// A `w` x `h` image with `c` interleaved float channels, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    /// Width.
    pub w: usize,
    /// Height.
    pub h: usize,
    /// Channels.
    pub c: usize,
    /// `w * h * c` values.
    pub d: Vec<f32>,
}

impl Plane {
    /// A plane of zeros.
    pub fn zeros(w: usize, h: usize, c: usize) -> Plane {
        Plane {
            w,
            h,
            c,
            d: vec![0.0; w * h * c],
        }
    }

    /// Wraps `d` (`w * h * c` values); `None` if the length disagrees.
    pub fn from_vec(w: usize, h: usize, c: usize, d: Vec<f32>) -> Option<Plane> {
        (d.len() == w * h * c).then_some(Plane { w, h, c, d })
    }
}

/// Below this many values a plane is filtered on one thread (the merge already runs charts in
/// parallel; splitting small planes costs more than it gains).
const PAR_MIN: usize = 1 << 16;

/// The 5-tap generating kernel with centre weight `a` (0.4 in the paper, 0.375 in OpenCV).
pub fn kernel(a: f32) -> [f32; 5] {
    let e = 0.25 - 0.5 * a;
    [e, 0.25, a, 0.25, e]
}

/// Reflect-101 (`gfedcb|abcdefgh|gfedcba`): OpenCV's default border.
#[inline]
pub(crate) fn reflect101(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let n = n as isize;
    let mut i = i;
    loop {
        if i < 0 {
            i = -i;
        } else if i >= n {
            i = 2 * n - 2 - i;
        } else {
            return i as usize;
        }
    }
}

fn rows_mut(d: &mut [f32], row: usize, par: bool, f: impl Fn(usize, &mut [f32]) + Sync) {
    if par {
        d.par_chunks_mut(row).enumerate().for_each(|(y, r)| f(y, r));
    } else {
        d.chunks_mut(row).enumerate().for_each(|(y, r)| f(y, r));
    }
}

/// Source index `2x + t - 2` of a reduction, reflected.
#[inline]
fn down_tap(x: usize, t: usize, n: usize) -> usize {
    reflect101(2 * x as isize + t as isize - 2, n)
}

/// One level down: blur with the kernel, keep even samples; `ceil(w/2)` x `ceil(h/2)`.
pub fn reduce(src: &Plane, a: f32) -> Plane {
    let k = kernel(a);
    let (w, h, c) = (src.w, src.h, src.c);
    let (dw, dh) = (w.div_ceil(2), h.div_ceil(2));
    let par = w * h * c >= PAR_MIN;
    let mut tmp = vec![0f32; dw * h * c];
    rows_mut(&mut tmp, dw * c, par, |y, row| {
        let s = &src.d[y * w * c..(y + 1) * w * c];
        for x in 0..dw {
            let o = &mut row[x * c..(x + 1) * c];
            if x >= 1 && 2 * x + 2 < w {
                // Interior: no reflection.
                let b = (2 * x - 2) * c;
                for ch in 0..c {
                    o[ch] = k[0] * s[b + ch]
                        + k[1] * s[b + c + ch]
                        + k[2] * s[b + 2 * c + ch]
                        + k[3] * s[b + 3 * c + ch]
                        + k[4] * s[b + 4 * c + ch];
                }
            } else {
                for (t, kt) in k.iter().enumerate() {
                    let sx = down_tap(x, t, w);
                    for ch in 0..c {
                        o[ch] += kt * s[sx * c + ch];
                    }
                }
            }
        }
    });
    let mut out = vec![0f32; dw * dh * c];
    let rl = dw * c;
    rows_mut(&mut out, rl, par, |y, row| {
        let r: [&[f32]; 5] = std::array::from_fn(|t| {
            let sy = down_tap(y, t, h);
            &tmp[sy * rl..(sy + 1) * rl]
        });
        for (i, o) in row.iter_mut().enumerate() {
            *o = k[0] * r[0][i] + k[1] * r[1][i] + k[2] * r[2][i] + k[3] * r[3][i] + k[4] * r[4][i];
        }
    });
    Plane {
        w: dw,
        h: dh,
        c,
        d: out,
    }
}

/// Source index of an expansion's neighbour `j` (may be -1 or `n`): reflect-101 on the doubled
/// grid makes source -1 read 1 and source `n` read `n - 1`.
#[inline]
pub(crate) fn up_src(j: isize, n: usize) -> usize {
    if j < 0 {
        1.min(n - 1)
    } else if j as usize >= n {
        n - 1
    } else {
        j as usize
    }
}

/// One level up to `dw` x `dh` (each at most twice the source's): zero insertion, then the
/// kernel times two per axis, on the full doubled grid (a smaller size is its crop, as in
/// OpenCV).
pub fn expand(src: &Plane, dw: usize, dh: usize, a: f32) -> Plane {
    let k = kernel(a).map(|v| 2.0 * v);
    let (sw, sh, c) = (src.w, src.h, src.c);
    assert!(
        dw <= 2 * sw && dh <= 2 * sh && dw > 0 && dh > 0,
        "expand to at most twice the size"
    );
    let par = dw * dh * c >= PAR_MIN;
    // Horizontal: sw -> dw on every source row. Even outputs 2j read sources j-1, j, j+1
    // (weights k0, k2, k4); odd outputs 2j+1 read j, j+1 (k1, k3).
    let mut tmp = vec![0f32; dw * sh * c];
    rows_mut(&mut tmp, dw * c, par, |y, row| {
        expand_row(&src.d[y * sw * c..(y + 1) * sw * c], c, &k, row)
    });
    let mut out = vec![0f32; dw * dh * c];
    let rl = dw * c;
    rows_mut(&mut out, rl, par, |y, row| {
        expand_col(y, sh, &k, |sy| &tmp[sy * rl..(sy + 1) * rl], row)
    });
    Plane {
        w: dw,
        h: dh,
        c,
        d: out,
    }
}

/// [`expand`]'s horizontal pass: source row `s` (`c` channels) to `row` (as many texels as it
/// holds), with the doubled kernel `k`. Even outputs 2j read sources j-1, j, j+1 (weights
/// k0, k2, k4); odd outputs 2j+1 read j, j+1 (k1, k3).
#[inline]
pub(crate) fn expand_row(s: &[f32], c: usize, k: &[f32; 5], row: &mut [f32]) {
    let sw = s.len() / c;
    for (x, o) in row.chunks_exact_mut(c).enumerate() {
        let j = (x / 2) as isize;
        if x % 2 == 0 {
            let (a0, a1, a2) = (up_src(j - 1, sw), up_src(j, sw), up_src(j + 1, sw));
            for ch in 0..c {
                o[ch] = k[0] * s[a0 * c + ch] + k[2] * s[a1 * c + ch] + k[4] * s[a2 * c + ch];
            }
        } else {
            let (a1, a2) = (up_src(j, sw), up_src(j + 1, sw));
            for ch in 0..c {
                o[ch] = k[1] * s[a1 * c + ch] + k[3] * s[a2 * c + ch];
            }
        }
    }
}

/// [`expand`]'s vertical pass for output row `y` of a source `sh` rows high: `row` from the
/// horizontally expanded source rows `tmp(sy)`, with the doubled kernel `k`.
#[inline]
pub(crate) fn expand_col<'a>(
    y: usize,
    sh: usize,
    k: &[f32; 5],
    tmp: impl Fn(usize) -> &'a [f32],
    row: &mut [f32],
) {
    let j = (y / 2) as isize;
    let r = |jj: isize| tmp(up_src(jj, sh));
    if y.is_multiple_of(2) {
        let (r0, r1, r2) = (r(j - 1), r(j), r(j + 1));
        for (i, o) in row.iter_mut().enumerate() {
            *o = k[0] * r0[i] + k[2] * r1[i] + k[4] * r2[i];
        }
    } else {
        let (r1, r2) = (r(j), r(j + 1));
        for (i, o) in row.iter_mut().enumerate() {
            *o = k[1] * r1[i] + k[3] * r2[i];
        }
    }
}

/// Gaussian pyramid: `levels + 1` planes, the first `img`.
pub fn gaussian(img: Plane, levels: usize, a: f32) -> Vec<Plane> {
    let mut out = vec![img];
    for _ in 0..levels {
        let next = reduce(out.last().expect("non-empty"), a);
        out.push(next);
    }
    out
}

/// Laplacian pyramid from a Gaussian one: band `l` is `G_l - expand(G_{l+1})`; the last
/// plane stays the coarsest Gaussian level. Collapsing with [`collapse`] gives `G_0` back.
pub fn laplacian(mut g: Vec<Plane>, a: f32) -> Vec<Plane> {
    for l in 0..g.len().saturating_sub(1) {
        let up = expand(&g[l + 1], g[l].w, g[l].h, a);
        for (v, u) in g[l].d.iter_mut().zip(&up.d) {
            *v -= u;
        }
    }
    g
}

/// Sums a Laplacian pyramid back into an image.
pub fn collapse(mut bands: Vec<Plane>, a: f32) -> Plane {
    let mut acc = bands.pop().expect("at least one level");
    while let Some(mut band) = bands.pop() {
        let up = expand(&acc, band.w, band.h, a);
        for (v, u) in band.d.iter_mut().zip(&up.d) {
            *v += u;
        }
        acc = band;
    }
    acc
}

/// Burt and Adelson's multiresolution spline of `images` (same size and channels) under
/// `masks` (one weight per pixel each): every Laplacian band is the mask-weighted mean of the
/// images' bands, each mask reduced to that band's level; `levels` reductions. Where no mask
/// reaches at a level the band is zero (the coarsest level: the plain mean of the images).
pub fn blend(images: &[Plane], masks: &[Vec<f32>], levels: usize, a: f32) -> Plane {
    assert!(!images.is_empty() && images.len() == masks.len());
    let (w, h, c) = (images[0].w, images[0].h, images[0].c);
    let mut num: Vec<Plane> = Vec::new();
    let mut den: Vec<Vec<f32>> = Vec::new();
    for (img, m) in images.iter().zip(masks) {
        assert!(img.w == w && img.h == h && img.c == c && m.len() == w * h);
        let bands = laplacian(gaussian(img.clone(), levels, a), a);
        let mg = gaussian(
            Plane::from_vec(w, h, 1, m.clone()).expect("sized"),
            levels,
            a,
        );
        if num.is_empty() {
            num = bands.iter().map(|b| Plane::zeros(b.w, b.h, c)).collect();
            den = bands.iter().map(|b| vec![0f32; b.w * b.h]).collect();
        }
        for l in 0..bands.len() {
            for (i, &mw) in mg[l].d.iter().enumerate() {
                den[l][i] += mw;
                for ch in 0..c {
                    num[l].d[i * c + ch] += mw * bands[l].d[i * c + ch];
                }
            }
        }
    }
    let top = num.len() - 1;
    for (l, (n, d)) in num.iter_mut().zip(&den).enumerate() {
        for (i, &dw) in d.iter().enumerate() {
            for ch in 0..c {
                let v = &mut n.d[i * c + ch];
                *v = if dw > 1e-5 {
                    *v / dw
                } else if l == top {
                    images.iter().map(|im| im.d[i * c + ch]).sum::<f32>() / images.len() as f32
                } else {
                    0.0
                };
            }
        }
    }
    collapse(num, a)
}

/// Gives every value whose `weight` is zero a smooth value from the weighted ones around it
/// (push-pull: weighted means reduced level by level until every level is covered, then
/// expanded back into the holes). Values with positive weight are kept exactly. Returns
/// false, leaving `img` unchanged, if no weight is positive.
pub fn fill_holes(img: &mut Plane, weight: &[f32], a: f32) -> bool {
    assert_eq!(weight.len(), img.w * img.h, "one weight per pixel");
    if !weight.iter().any(|&w| w > 0.0) {
        return false;
    }
    if weight.iter().all(|&w| w > 0.0) {
        return true;
    }
    let c = img.c;
    // Premultiplied colour with the weight as an extra channel.
    let mut pm = Plane::zeros(img.w, img.h, c + 1);
    for (i, &w) in weight.iter().enumerate() {
        let w = w.max(0.0);
        for ch in 0..c {
            pm.d[i * (c + 1) + ch] = img.d[i * c + ch] * w;
        }
        pm.d[i * (c + 1) + c] = w;
    }
    let filled = fill_level(pm, a);
    for (i, &w) in weight.iter().enumerate() {
        if w <= 0.0 {
            img.d[i * c..(i + 1) * c].copy_from_slice(&filled[i * c..(i + 1) * c]);
        }
    }
    true
}

/// Normalised colour of a premultiplied plane with holes filled from coarser levels.
fn fill_level(pm: Plane, a: f32) -> Vec<f32> {
    let c = pm.c - 1;
    let n = pm.w * pm.h;
    let norm = |p: &Plane, i: usize| -> Option<f32> {
        let w = p.d[i * (c + 1) + c];
        (w > 1e-6).then_some(w)
    };
    let mut out = vec![0f32; n * c];
    let mut holes = false;
    for i in 0..n {
        match norm(&pm, i) {
            Some(w) => {
                for ch in 0..c {
                    out[i * c + ch] = pm.d[i * (c + 1) + ch] / w;
                }
            }
            None => holes = true,
        }
    }
    if !holes || (pm.w == 1 && pm.h == 1) {
        return out;
    }
    let coarse = reduce(&pm, a);
    let (cw, ch_) = (coarse.w, coarse.h);
    let coarse_filled = fill_level(coarse, a);
    let up = expand(
        &Plane {
            w: cw,
            h: ch_,
            c,
            d: coarse_filled,
        },
        pm.w,
        pm.h,
        a,
    );
    for i in 0..n {
        if norm(&pm, i).is_none() {
            out[i * c..(i + 1) * c].copy_from_slice(&up.d[i * c..(i + 1) * c]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Plane {
        let d = (0..w * h)
            .flat_map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                [0.1 * x + 0.05 * y, (0.3 * x).sin() + (0.2 * y).cos()]
            })
            .collect();
        Plane::from_vec(w, h, 2, d).unwrap()
    }

    #[test]
    fn laplacian_collapse_round_trips_on_odd_sizes() {
        for (w, h) in [(37, 23), (16, 16), (5, 1), (1, 9)] {
            let img = ramp(w, h);
            let back = collapse(laplacian(gaussian(img.clone(), 4, 0.4), 0.4), 0.4);
            assert_eq!((back.w, back.h), (w, h));
            let err = img
                .d
                .iter()
                .zip(&back.d)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            assert!(err < 1e-5, "{w}x{h}: {err}");
        }
    }

    #[test]
    fn kernel_preserves_constants() {
        let c = Plane::from_vec(9, 7, 1, vec![0.7; 63]).unwrap();
        let r = reduce(&c, 0.4);
        assert!(r.d.iter().all(|v| (v - 0.7).abs() < 1e-6));
        let e = expand(&r, 9, 7, 0.4);
        assert!(e.d.iter().all(|v| (v - 0.7).abs() < 1e-6));
    }

    #[test]
    fn holes_take_smooth_values_and_known_values_stay() {
        let mut img = ramp(40, 30);
        let truth = img.clone();
        let mut weight = vec![1f32; 40 * 30];
        for y in 10..20 {
            for x in 12..30 {
                weight[y * 40 + x] = 0.0;
                img.d[(y * 40 + x) * 2] = 1e6; // garbage that must not survive
                img.d[(y * 40 + x) * 2 + 1] = -1e6;
            }
        }
        assert!(fill_holes(&mut img, &weight, 0.4));
        let lo = truth.d.iter().cloned().fold(f32::MAX, f32::min);
        let hi = truth.d.iter().cloned().fold(f32::MIN, f32::max);
        for (i, w) in weight.iter().enumerate() {
            for ch in 0..2 {
                let v = img.d[i * 2 + ch];
                if *w > 0.0 {
                    assert_eq!(v, truth.d[i * 2 + ch]);
                } else {
                    assert!(v >= lo - 1e-3 && v <= hi + 1e-3, "{v}");
                }
            }
        }
        // Nothing to fill from: unchanged.
        let mut z = ramp(4, 4);
        assert!(!fill_holes(&mut z, &[0.0; 16], 0.4));
        assert_eq!(z, ramp(4, 4));
    }
}
