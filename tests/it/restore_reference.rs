//! Restoration (stage 5) against OpenCV's cv2.inpaint (TELEA, radius 5) on the textures of
//! `../shared/data/textures`, with the masks and figures `calib/opencv/inpaint.py` committed.
//! The metrics are the script's: inside the mask, PSNR, PSNR of 9x9-Gaussian-blurred images,
//! and the detail ratio (std of image - 5x5 blur inside the hole / outside it).

use crate::common;

use scantex::restore::{inpaint, Image, RestoreOptions};
use std::path::Path;

/// P5 (binary 8-bit) PGM, the format of the Portilla-Simoncelli exemplars.
fn read_pgm(p: &Path) -> (Vec<f64>, usize, usize) {
    let b = std::fs::read(p).unwrap();
    let mut fields = Vec::new();
    let mut i = 0;
    while fields.len() < 4 {
        while b[i].is_ascii_whitespace() {
            i += 1;
        }
        if b[i] == b'#' {
            while b[i] != b'\n' {
                i += 1;
            }
            continue;
        }
        let s = i;
        while !b[i].is_ascii_whitespace() {
            i += 1;
        }
        fields.push(String::from_utf8_lossy(&b[s..i]).to_string());
    }
    assert_eq!(fields[0], "P5");
    let (w, h): (usize, usize) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
    let data = b[i + 1..i + 1 + w * h]
        .iter()
        .map(|&v| v as f64 / 255.0)
        .collect();
    (data, w, h)
}

fn read_grey(p: &Path) -> (Vec<f64>, usize, usize) {
    if p.extension().is_some_and(|e| e == "pgm") {
        return read_pgm(p);
    }
    let img = image::open(p).unwrap().to_luma8();
    let (w, h) = (img.width() as usize, img.height() as usize);
    (
        img.into_raw().iter().map(|&v| v as f64 / 255.0).collect(),
        w,
        h,
    )
}

/// OpenCV's GaussianBlur with sigma derived from the size (fixed [1 4 6 4 1]/16 for 5x5),
/// BORDER_REFLECT.
fn gauss(img: &[f64], w: usize, h: usize, k: usize) -> Vec<f64> {
    let kern: Vec<f64> = if k == 5 {
        vec![1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0]
    } else {
        let sigma = 0.3 * ((k as f64 - 1.0) * 0.5 - 1.0) + 0.8;
        let r = (k / 2) as i64;
        let v: Vec<f64> = (-r..=r)
            .map(|x| (-(x * x) as f64 / (2.0 * sigma * sigma)).exp())
            .collect();
        let s: f64 = v.iter().sum();
        v.iter().map(|x| x / s).collect()
    };
    let r = (k / 2) as i64;
    let refl = |i: i64, n: usize| -> usize {
        let n = n as i64;
        let mut i = i;
        if i < 0 {
            i = -i - 1;
        }
        if i >= n {
            i = 2 * n - i - 1;
        }
        i as usize
    };
    let mut tmp = vec![0f64; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = (0..k)
                .map(|t| kern[t] * img[y * w + refl(x as i64 + t as i64 - r, w)])
                .sum();
        }
    }
    let mut out = vec![0f64; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (0..k)
                .map(|t| kern[t] * tmp[refl(y as i64 + t as i64 - r, h) * w + x])
                .sum();
        }
    }
    out
}

fn psnr(a: &[f64], b: &[f64]) -> f64 {
    let mse = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64;
    10.0 * (1.0 / mse.max(1e-12)).log10()
}

fn std(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}

struct Metrics {
    psnr: f64,
    lowfreq: f64,
    detail: f64,
}

fn metrics(truth: &[f64], res: &[f64], mask: &[bool], w: usize, h: usize) -> Metrics {
    let pick = |v: &[f64], inside: bool| -> Vec<f64> {
        v.iter()
            .zip(mask)
            .filter(|(_, &m)| m == inside)
            .map(|(x, _)| *x)
            .collect()
    };
    let (lt, lr) = (gauss(truth, w, h, 9), gauss(res, w, h, 9));
    let g5 = gauss(res, w, h, 5);
    let hp: Vec<f64> = res.iter().zip(&g5).map(|(a, b)| a - b).collect();
    Metrics {
        psnr: psnr(&pick(truth, true), &pick(res, true)),
        lowfreq: psnr(&pick(&lt, true), &pick(&lr, true)),
        detail: std(&pick(&hp, true)) / std(&pick(&hp, false)),
    }
}

#[test]
fn restoration_keeps_detail_and_the_low_band_against_opencv_telea() {
    let Some(data) = common::shared_data("textures") else {
        return;
    };
    let reference = common::calib_json("opencv/inpaint.json");
    let cases = reference["results"].as_array().unwrap();
    assert_eq!(cases.len(), 54, "9 textures x 2 variants x 3 masks");
    let (mut detail_ok, mut lf_ok, mut ours_psnr, mut telea_psnr) = (0, 0, 0.0, 0.0);
    let mut report = String::new();
    for c in cases {
        let (tex, w, h) = read_grey(&data.join(c["path"].as_str().unwrap()));
        let truth: Vec<f64> = if c["ramp"].as_bool().unwrap() {
            tex.iter()
                .enumerate()
                .map(|(i, v)| v * (0.2 + 0.8 * (i % w) as f64 / (w - 1) as f64))
                .collect()
        } else {
            tex
        };
        let mpath = common::root()
            .join("calib/opencv/inpaint")
            .join(c["mask_file"].as_str().unwrap());
        let (mask, _, _) = scantex::io::image::read_mask(&mpath).unwrap();
        // Both tools see the same 8-bit input; the result is compared as 8-bit.
        let input = Image {
            width: w,
            height: h,
            channels: 1,
            data: truth
                .iter()
                .map(|v| ((v * 255.0).round() / 255.0) as f32)
                .collect(),
        };
        let (out, _) = inpaint(&input, &mask, None, &RestoreOptions::default()).unwrap();
        let res: Vec<f64> = out
            .data
            .iter()
            .map(|&v| (v.clamp(0.0, 1.0) as f64 * 255.0).round() / 255.0)
            .collect();
        let m = metrics(&truth, &res, &mask, w, h);
        let telea = &c["telea"];
        let t_lf = telea["lowfreq_psnr"].as_f64().unwrap();
        detail_ok += (0.8..=1.2).contains(&m.detail) as usize;
        lf_ok += (m.lowfreq >= t_lf - 1.0) as usize;
        ours_psnr += m.psnr;
        telea_psnr += telea["psnr"].as_f64().unwrap();
        report += &format!(
            "{} ramp={} {}: detail {:.2} (TELEA {:.2}), low-freq PSNR {:.2} (TELEA {:.2})\n",
            c["texture"],
            c["ramp"],
            c["mask"],
            m.detail,
            telea["detail_ratio"].as_f64().unwrap(),
            m.lowfreq,
            t_lf
        );
        // No case may be far off: a smooth fill (diffusion) has a detail ratio near 0.2.
        assert!(
            (0.7..=1.35).contains(&m.detail) && m.lowfreq >= t_lf - 1.6,
            "{report}"
        );
    }
    eprint!("{report}");
    eprintln!(
        "mean PSNR {:.4} dB (TELEA {:.4}); detail ratio within 0.8-1.2 in {detail_ok}/54, \
         low-frequency PSNR within 1 dB of TELEA's in {lf_ok}/54",
        ours_psnr / 54.0,
        telea_psnr / 54.0
    );
    // The targets, every case (measured 54/54 and 54/54, docs/benchmarks.md; the
    // closest cases are 0.02 and 0.2 dB inside).
    assert!(
        detail_ok == 54,
        "detail ratio within 0.8-1.2 in {detail_ok}/54\n{report}"
    );
    assert!(
        lf_ok == 54,
        "low-frequency PSNR within 1 dB of TELEA in {lf_ok}/54\n{report}"
    );
    assert!(
        ours_psnr > telea_psnr,
        "mean PSNR {:.2} vs TELEA {:.2}",
        ours_psnr / 54.0,
        telea_psnr / 54.0
    );
}

#[test]
fn restoration_is_deterministic_and_never_touches_known_pixels() {
    let Some(p) = common::shared_data("textures/brick.png") else {
        return;
    };
    let (tex, w, h) = read_grey(&p);
    let (mask, _, _) = scantex::io::image::read_mask(
        &common::root().join("calib/opencv/inpaint/blobs15_512x512.png"),
    )
    .unwrap();
    let img = Image {
        width: w,
        height: h,
        channels: 1,
        data: tex.iter().map(|&v| v as f32).collect(),
    };
    let o = RestoreOptions {
        seed: 7,
        ..Default::default()
    };
    let (a, ra) = inpaint(&img, &mask, None, &o).unwrap();
    let (b, _) = inpaint(&img, &mask, None, &o).unwrap();
    assert_eq!(a, b, "same seed, same output");
    for (i, (&m, (&x, &y))) in mask.iter().zip(a.data.iter().zip(&img.data)).enumerate() {
        if !m {
            assert_eq!(x, y, "known pixel {i} changed");
        }
    }
    assert_eq!(ra.texels as usize, mask.iter().filter(|&&m| m).count());
    assert!(ra.levels.iter().all(|l| l.stalled == 0), "{:?}", ra.levels);
}
