//! Held-out evaluation ("virtual rephotography", Waechter et al. 2017): render a textured mesh
//! from a photograph's viewpoint and compare inside the mesh's footprint (and the photo's mask
//! where there is one). PSNR, SSIM, 1 - NCC over 7x7 patches (tolerates exposure differences)
//! and completeness (footprint pixels the texture actually covers).

use crate::error::Result;
use crate::planar::luma;
use crate::raycast::RayMesh;
use crate::render::{render, RenderOptions, Texture};
use crate::scene::Photo;
use image::{GrayImage, Rgb32FImage};
use serde::Serialize;

/// Options for [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EvalOptions {
    /// Fit one gain per channel per image (least squares) before PSNR and SSIM, so exposure
    /// and white-balance differences do not count. Default: off.
    pub gain_fit: bool,
}

/// Scores of one photograph.
#[derive(Debug, Clone, Serialize)]
pub struct ImageScore {
    /// Photograph name.
    pub name: String,
    /// Pixels compared (footprint, within the mask if any).
    pub pixels: usize,
    /// Peak signal-to-noise ratio in dB (peak 1.0), over RGB.
    pub psnr: f64,
    /// Mean SSIM of the luma (Gaussian window 11x11, sigma 1.5) over the compared pixels.
    pub ssim: f64,
    /// Mean of 1 - NCC over 7x7 luma patches lying wholly in the compared region.
    pub one_minus_ncc: f64,
    /// Fraction of footprint (and mask) pixels where the texture holds real colour.
    pub completeness: f64,
    /// Fitted per-channel gains (1 when not fitted).
    pub gains: [f64; 3],
    /// Scores over the pixels whose surface no input photograph saw, when the photograph
    /// has an unseen-surface mask ([`crate::scene::Photo::unseen`]).
    pub unseen: Option<UnseenScore>,
    /// With an unseen-surface mask, the same scores over the pixels whose surface the input
    /// photographs saw: what they give, the reference for [`ImageScore::unseen`]'s detail
    /// and Gram distance (its ΔE is about 0, the gains being fitted there; its rim is the
    /// same band as the unseen scores', so the same value in each photograph, though the
    /// means weigh the photographs by their seen pixels).
    pub seen: Option<UnseenScore>,
}

/// A rendered pixel whose channels (in [0, 1], after gains) sum to at most this is black.
pub const BLACK_SUM: f64 = 0.02;
/// A truth pixel whose channels sum to at most this is black too (JPEG noise included), so
/// that a black rendered pixel there is not a hole.
pub const BLACK_TRUTH_SUM: f64 = 0.06;

/// How a texture does where no input photograph saw the surface, against the truth (the
/// held-out photograph), after per-channel gains fitted on the seen pixels; as
/// [`ImageScore::seen`], the same over the seen pixels ("unseen" below then reads "seen").
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct UnseenScore {
    /// Unseen pixels (inside the object's footprint).
    pub pixels: usize,
    /// Fraction of them the texture covers with colour (rendered, and not black where the
    /// truth is not black within one pixel: [`BLACK_SUM`], [`BLACK_TRUTH_SUM`]).
    pub coverage: f64,
    /// RMS of the output's detail (luma minus its Gaussian blur, sigma 1.5) over the truth's,
    /// on the unseen pixels 2 pixels in from their border: 0 for a flat fill, 1 for detail of
    /// the truth's strength.
    pub detail_ratio: f64,
    /// CIE76 colour difference of the mean colours over the unseen pixels.
    pub delta_e: f64,
    /// Relative Frobenius distance between the Gram matrices of eight filter responses
    /// (luma derivatives and Laplacians at two scales, two chroma detail bands) of output and
    /// truth over the same pixels: 0 for equal texture statistics, 1 for a flat fill.
    pub gram_distance: f64,
    /// Mean gradient magnitude of the luma (blurred, sigma 1.5) within 3 pixels of the
    /// border between seen and unseen surface, output over truth: above 1 where the output
    /// shows an edge the truth does not have.
    pub rim_gradient_ratio: f64,
}

/// Scores of every photograph and their means.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// Per photograph.
    pub images: Vec<ImageScore>,
    /// Mean over photographs with at least one compared pixel.
    pub mean: Option<ImageScore>,
}

/// With `opts.gain_fit`, per channel the least-squares gain taking `rendered` to `photo` over
/// `region` (255 = use); otherwise, or with no pixel to fit on, 1.
fn fit_gains(
    rendered: &Rgb32FImage,
    photo: &Rgb32FImage,
    region: &GrayImage,
    opts: &EvalOptions,
) -> [f64; 3] {
    let mut gains = [1.0f64; 3];
    if !opts.gain_fit {
        return gains;
    }
    for (k, g) in gains.iter_mut().enumerate() {
        let (mut num, mut den) = (0.0, 0.0);
        for (x, y, p) in photo.enumerate_pixels() {
            if region.get_pixel(x, y)[0] > 127 {
                let r = rendered.get_pixel(x, y)[k] as f64;
                num += p[k] as f64 * r;
                den += r * r;
            }
        }
        if den > 0.0 {
            *g = num / den;
        }
    }
    gains
}

/// Compares `rendered` to `photo` inside `region` (255 = compare). `covered` says where the
/// texture holds real colour; `footprint` is where the mesh or the mask says the object is.
pub fn compare(
    name: &str,
    rendered: &Rgb32FImage,
    photo: &Rgb32FImage,
    region: &GrayImage,
    covered: &GrayImage,
    footprint: &GrayImage,
    opts: &EvalOptions,
) -> ImageScore {
    let (w, h) = photo.dimensions();
    let inside = |x: u32, y: u32| region.get_pixel(x, y)[0] > 127;
    let pixels = region.pixels().filter(|p| p[0] > 127).count();
    let gains = fit_gains(rendered, photo, region, opts);
    // The rendering with gains applied, and the photo's own values outside the region, so
    // that windows straddling the region border compare only what is inside.
    let r = Rgb32FImage::from_fn(w, h, |x, y| {
        if inside(x, y) {
            let p = rendered.get_pixel(x, y);
            image::Rgb(std::array::from_fn(|k| (p[k] as f64 * gains[k]) as f32))
        } else {
            *photo.get_pixel(x, y)
        }
    });
    let mut se = 0.0;
    for (x, y, p) in photo.enumerate_pixels() {
        if inside(x, y) {
            let q = r.get_pixel(x, y);
            se += (0..3)
                .map(|k| (p[k] as f64 - q[k] as f64).powi(2))
                .sum::<f64>();
        }
    }
    let mse = se / (3 * pixels.max(1)) as f64;
    let psnr = if mse > 0.0 {
        10.0 * (1.0 / mse).log10()
    } else {
        f64::INFINITY
    };
    let ly: Vec<f64> = photo.pixels().map(|p| luma(&p.0)).collect();
    let lr: Vec<f64> = r.pixels().map(|p| luma(&p.0)).collect();
    let ssim = ssim_mean(&ly, &lr, w as usize, h as usize, region);
    let one_minus_ncc = ncc_mean(&ly, &lr, w as usize, h as usize, region);
    let fp = footprint.pixels().filter(|p| p[0] > 127).count();
    let cov = footprint
        .enumerate_pixels()
        .filter(|(x, y, p)| p[0] > 127 && covered.get_pixel(*x, *y)[0] > 127)
        .count();
    ImageScore {
        name: name.to_string(),
        pixels,
        psnr,
        ssim,
        one_minus_ncc,
        completeness: if fp > 0 { cov as f64 / fp as f64 } else { 0.0 },
        gains,
        unseen: None,
        seen: None,
    }
}

/// sRGB-encoded RGB in [0, 1] to CIELAB (D65).
fn lab(c: [f64; 3]) -> [f64; 3] {
    let lin = c.map(|v| {
        let v = v.clamp(0.0, 1.0);
        if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    });
    let x = (0.4124 * lin[0] + 0.3576 * lin[1] + 0.1805 * lin[2]) / 0.95047;
    let y = 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2];
    let z = (0.0193 * lin[0] + 0.1192 * lin[1] + 0.9505 * lin[2]) / 1.08883;
    let f = |t: f64| {
        if t > 0.008856 {
            t.cbrt()
        } else {
            7.787 * t + 16.0 / 116.0
        }
    };
    let (fx, fy, fz) = (f(x), f(y), f(z));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// Pixels of `m` at least `r` pixels (4-neighbour steps) inside it.
fn erode(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let mut cur = m.to_vec();
    for _ in 0..r {
        let prev = cur.clone();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                if prev[i]
                    && (x == 0
                        || y == 0
                        || x + 1 == w
                        || y + 1 == h
                        || !prev[i - 1]
                        || !prev[i + 1]
                        || !prev[i - w]
                        || !prev[i + w])
                {
                    cur[i] = false;
                }
            }
        }
    }
    cur
}

/// Pixels within `r` pixels (4-neighbour steps) of `m`.
fn dilate(m: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let inv: Vec<bool> = m.iter().map(|v| !v).collect();
    erode(&inv, w, h, r).iter().map(|v| !v).collect()
}

/// The eight filter responses of [`UnseenScore::gram_distance`] at every pixel.
fn responses(img: &Rgb32FImage) -> Vec<[f64; 8]> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let l: Vec<f64> = img.pixels().map(|p| luma(&p.0)).collect();
    let rg: Vec<f64> = img.pixels().map(|p| p[0] as f64 - p[1] as f64).collect();
    let by: Vec<f64> = img
        .pixels()
        .map(|p| 0.5 * (p[0] as f64 + p[1] as f64) - p[2] as f64)
        .collect();
    let b1 = blur(&l, w, h);
    let b2 = blur(&b1, w, h);
    let (rgb, byb) = (blur(&rg, w, h), blur(&by, w, h));
    let at = |v: &[f64], x: i64, y: i64| {
        v[y.clamp(0, h as i64 - 1) as usize * w + x.clamp(0, w as i64 - 1) as usize]
    };
    (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as i64, (i / w) as i64);
            let d = |v: &[f64], s: i64| {
                (
                    (at(v, x + s, y) - at(v, x - s, y)) / 2.0,
                    (at(v, x, y + s) - at(v, x, y - s)) / 2.0,
                    at(v, x + s, y) + at(v, x - s, y) + at(v, x, y + s) + at(v, x, y - s)
                        - 4.0 * at(v, x, y),
                )
            };
            let (ax, ay, al) = d(&l, 1);
            let (bx, bb, bl) = d(&b2, 2);
            [ax, ay, al, bx, bb, bl, rg[i] - rgb[i], by[i] - byb[i]]
        })
        .collect()
}

/// [`UnseenScore`] of `rendered` (gains applied) against `photo` over `unseen` (footprint
/// pixels no input photograph saw), `seen` (the compared pixels that are not unseen) and
/// `covered` (where the rendering holds colour).
pub fn unseen_score(
    rendered: &Rgb32FImage,
    photo: &Rgb32FImage,
    unseen: &[bool],
    seen: &[bool],
    covered: &[bool],
) -> Option<UnseenScore> {
    region_score(&Filtered::new(rendered, photo), unseen, seen, covered)
}

/// What [`region_score`] reads of a rendering and its photograph, whichever region it scores:
/// both images, their luma and its blur, and their filter responses.
struct Filtered<'a> {
    rendered: &'a Rgb32FImage,
    photo: &'a Rgb32FImage,
    lo: Vec<f64>,
    lt: Vec<f64>,
    bo: Vec<f64>,
    bt: Vec<f64>,
    ro: Vec<[f64; 8]>,
    rt: Vec<[f64; 8]>,
}

impl<'a> Filtered<'a> {
    fn new(rendered: &'a Rgb32FImage, photo: &'a Rgb32FImage) -> Self {
        let (w, h) = (photo.width() as usize, photo.height() as usize);
        let lo: Vec<f64> = rendered.pixels().map(|p| luma(&p.0)).collect();
        let lt: Vec<f64> = photo.pixels().map(|p| luma(&p.0)).collect();
        let (bo, bt) = (blur(&lo, w, h), blur(&lt, w, h));
        Filtered {
            rendered,
            photo,
            lo,
            lt,
            bo,
            bt,
            ro: responses(rendered),
            rt: responses(photo),
        }
    }
}

/// [`unseen_score`] over `unseen` with the images filtered once ([`Filtered`]), so that
/// [`evaluate`] scores both regions of a view from the same filtering.
fn region_score(
    f: &Filtered,
    unseen: &[bool],
    seen: &[bool],
    covered: &[bool],
) -> Option<UnseenScore> {
    let (rendered, photo) = (f.rendered, f.photo);
    let (w, h) = (photo.width() as usize, photo.height() as usize);
    let pixels = unseen.iter().filter(|&&u| u).count();
    if pixels == 0 {
        return None;
    }
    let colour = |img: &Rgb32FImage, i: usize| {
        let p = img.get_pixel((i % w) as u32, (i / w) as u32);
        [p[0] as f64, p[1] as f64, p[2] as f64]
    };
    // A black pixel is a hole (a peer's black fill, an untextured face) unless the truth is
    // black there too, or one pixel away: a scan's black trim or lacing, reproduced, is not
    // missing colour.
    let black = |img: &Rgb32FImage, i: usize, at: f64| colour(img, i).iter().sum::<f64>() <= at;
    let truth_black_near = |i: usize| {
        let (x, y) = ((i % w) as i64, (i / w) as i64);
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (u, v) = (x + dx, y + dy);
                u >= 0
                    && v >= 0
                    && (u as usize) < w
                    && (v as usize) < h
                    && black(photo, v as usize * w + u as usize, BLACK_TRUTH_SUM)
            })
        })
    };
    let cov = (0..w * h)
        .filter(|&i| {
            unseen[i] && covered[i] && (!black(rendered, i, BLACK_SUM) || truth_black_near(i))
        })
        .count();
    let inner = erode(unseen, w, h, 2);
    let inner_n = inner.iter().filter(|&&v| v).count().max(1);
    let (lo, lt, bo, bt) = (&f.lo, &f.lt, &f.bo, &f.bt);
    let (mut eo, mut et) = (0.0, 0.0);
    for i in (0..w * h).filter(|&i| inner[i]) {
        eo += (lo[i] - bo[i]).powi(2);
        et += (lt[i] - bt[i]).powi(2);
    }
    let (mut mo, mut mt) = ([0f64; 3], [0f64; 3]);
    for i in (0..w * h).filter(|&i| unseen[i]) {
        let (a, b) = (colour(rendered, i), colour(photo, i));
        for k in 0..3 {
            mo[k] += a[k] / pixels as f64;
            mt[k] += b[k] / pixels as f64;
        }
    }
    let (la, lb) = (lab(mo), lab(mt));
    let delta_e = (0..3).map(|k| (la[k] - lb[k]).powi(2)).sum::<f64>().sqrt();
    let gram = |r: &[[f64; 8]]| {
        let mut g = [[0f64; 8]; 8];
        for i in (0..w * h).filter(|&i| inner[i]) {
            for a in 0..8 {
                for b in 0..8 {
                    g[a][b] += r[i][a] * r[i][b] / inner_n as f64;
                }
            }
        }
        g
    };
    let (go, gt) = (gram(&f.ro), gram(&f.rt));
    let (mut num, mut den) = (0.0, 0.0);
    for a in 0..8 {
        for b in 0..8 {
            num += (go[a][b] - gt[a][b]).powi(2);
            den += gt[a][b].powi(2);
        }
    }
    // The rim: both sides of the border between seen and unseen surface.
    let near_seen = dilate(seen, w, h, 3);
    let near_unseen = dilate(unseen, w, h, 3);
    let grad = |b: &[f64], i: usize| {
        let (x, y) = (i % w, i / w);
        if x == 0 || y == 0 || x + 1 == w || y + 1 == h {
            return 0.0;
        }
        (((b[i + 1] - b[i - 1]) / 2.0).powi(2) + ((b[i + w] - b[i - w]) / 2.0).powi(2)).sqrt()
    };
    let (mut go_r, mut gt_r) = (0.0, 0.0);
    for i in 0..w * h {
        if (unseen[i] && near_seen[i]) || (seen[i] && near_unseen[i]) {
            go_r += grad(bo, i);
            gt_r += grad(bt, i);
        }
    }
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 0.0 };
    Some(UnseenScore {
        pixels,
        coverage: cov as f64 / pixels as f64,
        detail_ratio: ratio(eo, et).sqrt(),
        delta_e,
        gram_distance: ratio(num, den).sqrt(),
        rim_gradient_ratio: ratio(go_r, gt_r),
    })
}

/// Separable Gaussian blur (sigma 1.5, radius 5) with clamped borders.
fn blur(v: &[f64], w: usize, h: usize) -> Vec<f64> {
    let k: Vec<f64> = (-5i32..=5)
        .map(|i| (-(i * i) as f64 / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|x| x / s).collect();
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = (0..11)
                .map(|i| {
                    k[i] * v[y * w + (x as i64 + i as i64 - 5).clamp(0, w as i64 - 1) as usize]
                })
                .sum();
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (0..11)
                .map(|i| {
                    k[i] * tmp[(y as i64 + i as i64 - 5).clamp(0, h as i64 - 1) as usize * w + x]
                })
                .sum();
        }
    }
    out
}

/// Mean SSIM (Wang et al. 2004, C1 = 0.01^2, C2 = 0.03^2 for range 1) over region pixels.
fn ssim_mean(a: &[f64], b: &[f64], w: usize, h: usize, region: &GrayImage) -> f64 {
    let prod = |f: &dyn Fn(usize) -> f64| blur(&(0..w * h).map(f).collect::<Vec<_>>(), w, h);
    let (ma, mb) = (blur(a, w, h), blur(b, w, h));
    let saa = prod(&|i| a[i] * a[i]);
    let sbb = prod(&|i| b[i] * b[i]);
    let sab = prod(&|i| a[i] * b[i]);
    let (c1, c2) = (1e-4, 9e-4);
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, p) in region.pixels().enumerate() {
        if p[0] > 127 {
            let (va, vb, cab) = (
                saa[i] - ma[i] * ma[i],
                sbb[i] - mb[i] * mb[i],
                sab[i] - ma[i] * mb[i],
            );
            sum += ((2.0 * ma[i] * mb[i] + c1) * (2.0 * cab + c2))
                / ((ma[i] * ma[i] + mb[i] * mb[i] + c1) * (va + vb + c2));
            n += 1;
        }
    }
    if n > 0 {
        sum / n as f64
    } else {
        0.0
    }
}

/// Mean 1 - NCC over 7x7 patches wholly inside the region. Patches where the photograph is
/// flat (standard deviation below 1e-3) carry no structure to match and are skipped; a flat
/// rendering of a structured patch scores 1 (no correlation).
fn ncc_mean(a: &[f64], b: &[f64], w: usize, h: usize, region: &GrayImage) -> f64 {
    const R: usize = 3;
    let (mut sum, mut n) = (0.0, 0usize);
    if w <= 2 * R || h <= 2 * R {
        return 0.0;
    }
    for y in R..h - R {
        'px: for x in R..w - R {
            for dy in 0..=2 * R {
                for dx in 0..=2 * R {
                    if region.get_pixel((x + dx - R) as u32, (y + dy - R) as u32)[0] <= 127 {
                        continue 'px;
                    }
                }
            }
            let idx = |dx: usize, dy: usize| (y + dy - R) * w + x + dx - R;
            let m = ((2 * R + 1) * (2 * R + 1)) as f64;
            let (mut sa, mut sb) = (0.0, 0.0);
            for dy in 0..=2 * R {
                for dx in 0..=2 * R {
                    sa += a[idx(dx, dy)];
                    sb += b[idx(dx, dy)];
                }
            }
            let (ma, mb) = (sa / m, sb / m);
            let (mut vaa, mut vbb, mut vab) = (0.0, 0.0, 0.0);
            for dy in 0..=2 * R {
                for dx in 0..=2 * R {
                    let (p, q) = (a[idx(dx, dy)] - ma, b[idx(dx, dy)] - mb);
                    vaa += p * p;
                    vbb += q * q;
                    vab += p * q;
                }
            }
            if (vaa / m).sqrt() < 1e-3 {
                continue;
            }
            sum += if (vbb / m).sqrt() < 1e-3 {
                1.0
            } else {
                1.0 - vab / (vaa * vbb).sqrt()
            };
            n += 1;
        }
    }
    if n > 0 {
        sum / n as f64
    } else {
        0.0
    }
}

/// Renders `mesh` from every photo's viewpoint and compares. Photos are decoded one at a time.
pub fn evaluate(
    mesh: &RayMesh,
    texture: Option<&Texture>,
    photos: &[Photo],
    opts: &EvalOptions,
) -> Result<EvalReport> {
    let mut images = Vec::with_capacity(photos.len());
    for photo in photos {
        let (img, mask) = photo.load_with_mask(Vec::new())?;
        let img = img.into_rgb32f();
        let r = render(mesh, texture, &photo.view, &RenderOptions::default());
        let (w, h) = img.dimensions();
        let in_mask = |x: u32, y: u32| mask.as_ref().is_none_or(|m| m.get_pixel(x, y)[0] > 127);
        let region = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if r.coverage.get_pixel(x, y)[0] > 0 && in_mask(x, y) {
                255
            } else {
                0
            }])
        });
        // The object's footprint: the mask where there is one (so missing geometry counts as
        // incomplete), else the rendered coverage.
        let footprint = match &mask {
            Some(m) => m.clone(),
            None => r.coverage.clone(),
        };
        let covered = GrayImage::from_fn(w, h, |x, y| {
            let ok = r.coverage.get_pixel(x, y)[0] > 0 && r.texture_alpha.get_pixel(x, y)[0] > 0.5;
            image::Luma([if ok { 255 } else { 0 }])
        });
        let mut score = compare(
            &photo.name,
            &r.color,
            &img,
            &region,
            &covered,
            &footprint,
            opts,
        );
        // PSNR and the rest stay over every compared pixel; the pixels no input photograph
        // saw get their own scores, with gains (when fitted) from the seen pixels only.
        if let Some(u) = photo.load_unseen()? {
            let seen_region = GrayImage::from_fn(w, h, |x, y| {
                let keep = region.get_pixel(x, y)[0] > 127 && u.get_pixel(x, y)[0] <= 127;
                image::Luma([if keep { 255 } else { 0 }])
            });
            let g = fit_gains(&r.color, &img, &seen_region, opts);
            // Where the rendering shows no surface, the photograph's own pixels: the scores'
            // blurs and filters reach a few pixels past the object's outline, and there the
            // rendering's black background against the photograph's would count as a step at
            // every unseen region that meets the outline (the one-sided avocado's first two
            // views: rim 2.14 and 2.03 before, 1.56 and 0.67 after; Gram 2.06 and 6.14 before,
            // 0.31 and 0.71 after).
            let gained = Rgb32FImage::from_fn(w, h, |x, y| {
                if r.coverage.get_pixel(x, y)[0] == 0 {
                    return *img.get_pixel(x, y);
                }
                let p = r.color.get_pixel(x, y);
                image::Rgb(std::array::from_fn(|k| (p[k] as f64 * g[k]) as f32))
            });
            let n = (w * h) as usize;
            let at = |img: &GrayImage, i: usize| img.as_raw()[i] > 127;
            let unseen_px: Vec<bool> = (0..n).map(|i| at(&u, i) && at(&footprint, i)).collect();
            let seen_px: Vec<bool> = (0..n).map(|i| at(&seen_region, i)).collect();
            let cov_px: Vec<bool> = (0..n).map(|i| r.coverage.as_raw()[i] > 0).collect();
            let filtered = Filtered::new(&gained, &img);
            score.unseen = region_score(&filtered, &unseen_px, &seen_px, &cov_px);
            score.seen = region_score(&filtered, &seen_px, &unseen_px, &cov_px);
        }
        images.push(score);
    }
    let valid: Vec<&ImageScore> = images.iter().filter(|s| s.pixels > 0).collect();
    let mean = (!valid.is_empty()).then(|| {
        let n = valid.len() as f64;
        let avg = |f: &dyn Fn(&ImageScore) -> f64| valid.iter().map(|s| f(s)).sum::<f64>() / n;
        ImageScore {
            name: "mean".into(),
            pixels: valid.iter().map(|s| s.pixels).sum(),
            psnr: avg(&|s| s.psnr),
            ssim: avg(&|s| s.ssim),
            one_minus_ncc: avg(&|s| s.one_minus_ncc),
            completeness: avg(&|s| s.completeness),
            gains: std::array::from_fn(|k| avg(&|s| s.gains[k])),
            unseen: mean_region(&images, |s| s.unseen.as_ref()),
            seen: mean_region(&images, |s| s.seen.as_ref()),
        }
    });
    Ok(EvalReport { images, mean })
}

/// Pixel-weighted means of the region scores (`of`: the unseen or the seen ones) of images
/// with at least 500 pixels in the region (smaller slivers are mostly border).
fn mean_region(
    images: &[ImageScore],
    of: impl Fn(&ImageScore) -> Option<&UnseenScore>,
) -> Option<UnseenScore> {
    let u: Vec<&UnseenScore> = images
        .iter()
        .filter_map(of)
        .filter(|u| u.pixels >= 500)
        .collect();
    let total: usize = u.iter().map(|s| s.pixels).sum();
    if total == 0 {
        return None;
    }
    let avg = |f: &dyn Fn(&UnseenScore) -> f64| {
        u.iter().map(|s| f(s) * s.pixels as f64).sum::<f64>() / total as f64
    };
    Some(UnseenScore {
        pixels: total,
        coverage: avg(&|s| s.coverage),
        detail_ratio: avg(&|s| s.detail_ratio),
        delta_e: avg(&|s| s.delta_e),
        gram_distance: avg(&|s| s.gram_distance),
        rim_gradient_ratio: avg(&|s| s.rim_gradient_ratio),
    })
}

impl EvalReport {
    /// The rows of one region's table: each image, then the mean, that has scores there
    /// (`of`: the unseen or the seen ones).
    fn region_rows(
        &self,
        of: impl Fn(&ImageScore) -> Option<&UnseenScore>,
    ) -> Vec<(&str, &UnseenScore)> {
        self.images
            .iter()
            .chain(self.mean.iter())
            .filter_map(|s| of(s).map(|u| (s.name.as_str(), u)))
            .collect()
    }
}

impl std::fmt::Display for EvalReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:<32} {:>9} {:>8} {:>7} {:>9} {:>8}",
            "image", "pixels", "PSNR", "SSIM", "1-NCC", "complete"
        )?;
        for s in self.images.iter().chain(self.mean.iter()) {
            writeln!(
                f,
                "{:<32} {:>9} {:>8.2} {:>7.4} {:>9.4} {:>8.4}",
                s.name, s.pixels, s.psnr, s.ssim, s.one_minus_ncc, s.completeness
            )?;
        }
        let with_unseen = self.region_rows(|s| s.unseen.as_ref());
        if !with_unseen.is_empty() {
            writeln!(
                f,
                "\nwhere no input photograph saw the surface:\n{:<32} {:>9} {:>8} {:>7} {:>7} {:>7} {:>7}",
                "image", "pixels", "coverage", "detail", "dE", "Gram", "rim"
            )?;
            for (name, u) in with_unseen {
                writeln!(
                    f,
                    "{:<32} {:>9} {:>8.4} {:>7.3} {:>7.2} {:>7.3} {:>7.3}",
                    name,
                    u.pixels,
                    u.coverage,
                    u.detail_ratio,
                    u.delta_e,
                    u.gram_distance,
                    u.rim_gradient_ratio
                )?;
            }
        }
        let with_seen = self.region_rows(|s| s.seen.as_ref());
        if !with_seen.is_empty() {
            writeln!(
                f,
                "\nthe same where the input photographs saw it (what they give):\n{:<32} {:>9} {:>8} {:>7} {:>7} {:>7}",
                "image", "pixels", "coverage", "detail", "dE", "Gram"
            )?;
            for (name, u) in with_seen {
                writeln!(
                    f,
                    "{:<32} {:>9} {:>8.4} {:>7.3} {:>7.2} {:>7.3}",
                    name, u.pixels, u.coverage, u.detail_ratio, u.delta_e, u.gram_distance
                )?;
            }
        }
        Ok(())
    }
}

/// Loads the textured mesh and the scene's photographs and runs [`evaluate`].
pub fn evaluate_scene(
    textured: &std::path::Path,
    spec: &crate::scene::SceneSpec,
    opts: &EvalOptions,
) -> Result<EvalReport> {
    let (mesh, texture) = crate::render::load_textured(textured)?;
    let scene = crate::scene::Scene::load(&crate::scene::SceneSpec {
        mesh: None,
        ..spec.clone()
    })?;
    if scene.photos.is_empty() {
        return Err(crate::Error::Invalid(
            "the scene has no photographs to compare with".into(),
        ));
    }
    scene.check_photos()?;
    evaluate(&RayMesh::new(&mesh), texture.as_ref(), &scene.photos, opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn textured(w: u32, h: u32) -> Rgb32FImage {
        let mut rng = crate::rng::SplitMix64::new(5);
        Rgb32FImage::from_fn(w, h, |_, _| {
            let t = rng.next_f64() as f32;
            image::Rgb([0.3 + 0.4 * t, 0.5, 0.6 - 0.3 * t])
        })
    }

    /// The truth against itself scores perfectly; a flat fill of the right mean has no
    /// detail and the largest Gram distance.
    #[test]
    fn unseen_scores_of_the_truth_and_of_a_flat_fill() {
        let (w, h) = (64u32, 48u32);
        let truth = textured(w, h);
        let n = (w * h) as usize;
        let unseen: Vec<bool> = (0..n).map(|i| i % w as usize >= 32).collect();
        let seen: Vec<bool> = unseen.iter().map(|u| !u).collect();
        let covered = vec![true; n];
        let s = unseen_score(&truth, &truth, &unseen, &seen, &covered).unwrap();
        assert_eq!(s.pixels, n / 2);
        assert_eq!(s.coverage, 1.0);
        assert!(
            (s.detail_ratio - 1.0).abs() < 1e-9 && s.gram_distance < 1e-9,
            "{s:?}"
        );
        assert!(s.delta_e < 1e-9 && (s.rim_gradient_ratio - 1.0).abs() < 1e-9);
        let mean = [0.5f32, 0.5, 0.45];
        let flat = Rgb32FImage::from_fn(w, h, |x, y| {
            if x >= 32 {
                image::Rgb(mean)
            } else {
                *truth.get_pixel(x, y)
            }
        });
        let f = unseen_score(&flat, &truth, &unseen, &seen, &covered).unwrap();
        // (The blur reaches 5 pixels across the border, so a trace of the seen half's
        // detail remains 2 pixels in.)
        assert!(
            f.detail_ratio < 0.02 && (f.gram_distance - 1.0).abs() < 1e-3,
            "{f:?}"
        );
        assert!(f.delta_e < 2.0, "{f:?}");
        // Black or uncovered pixels do not count as covered.
        let black = Rgb32FImage::new(w, h);
        let b = unseen_score(&black, &truth, &unseen, &seen, &covered).unwrap();
        assert_eq!(b.coverage, 0.0);
        // Black where the truth is black too is covered: the unseen half's top rows made
        // black in the truth, then rendered black.
        let dark = Rgb32FImage::from_fn(w, h, |x, y| {
            if x >= 32 && y < 12 {
                image::Rgb([0.01, 0.01, 0.01])
            } else {
                *truth.get_pixel(x, y)
            }
        });
        let d = unseen_score(&black, &dark, &unseen, &seen, &covered).unwrap();
        // (Row 12, one pixel from the black, counts too.)
        assert!((d.coverage - 13.0 / 48.0).abs() < 1e-12, "{d:?}");
        assert!(unseen_score(&truth, &truth, &vec![false; n], &seen, &covered).is_none());
    }
}
