//! Held-out evaluation ("virtual rephotography", Waechter et al. 2017): render a textured mesh
//! from a photograph's viewpoint and compare inside the mesh's footprint (and the photo's mask
//! where there is one). PSNR, SSIM, 1 - NCC over 7x7 patches (tolerates exposure differences)
//! and completeness (footprint pixels the texture actually covers).

use crate::error::Result;
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
}

/// Scores of every photograph and their means.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    /// Per photograph.
    pub images: Vec<ImageScore>,
    /// Mean over photographs with at least one compared pixel.
    pub mean: Option<ImageScore>,
}

/// Rec. 601 luma of an RGB pixel.
fn luma(p: &[f32; 3]) -> f64 {
    0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
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
    let mut gains = [1.0f64; 3];
    if opts.gain_fit && pixels > 0 {
        for (k, g) in gains.iter_mut().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for (x, y, p) in photo.enumerate_pixels() {
                if inside(x, y) {
                    let r = rendered.get_pixel(x, y)[k] as f64;
                    num += p[k] as f64 * r;
                    den += r * r;
                }
            }
            if den > 0.0 {
                *g = num / den;
            }
        }
    }
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
    }
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
        let img = photo.load()?;
        let mask = photo.load_mask()?;
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
        images.push(compare(
            &photo.name,
            &r.color,
            &img,
            &region,
            &covered,
            &footprint,
            opts,
        ));
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
        }
    });
    Ok(EvalReport { images, mean })
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
