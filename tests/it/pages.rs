//! Atlas pages (issue 25): when the photographs support more texels than one page of
//! `--max-size` holds, charts go onto several pages written as UDIM tiles, and every reader
//! (ours, the Khronos validator, Blender) sees one material per page.

use crate::common;
use scantex::eval::{evaluate_scene, EvalOptions, ImageScore};
use scantex::mesh::TextureSource;
use scantex::pipeline::TextureOptions;
use scantex::scene::SceneSpec;
use std::path::Path;

fn held_out(model: &Path) -> ImageScore {
    evaluate_scene(
        model,
        &SceneSpec {
            dir: Some(common::root().join("samples/torus/heldout")),
            ..Default::default()
        },
        &EvalOptions { gain_fit: true },
    )
    .unwrap()
    .mean
    .unwrap()
}

/// The sample at a 1024 cap asks for about 1660 texels a side: several pages. Every face lies
/// on exactly one page, every page is written and coloured, both outputs read back as the
/// same UDIM texture, and the pages keep the detail one capped page loses.
#[test]
fn pages_hold_every_face_once_and_read_back_as_udim_tiles() {
    let dir = tempfile::tempdir().unwrap();
    let scene = common::root().join("samples/torus");
    let mut opts = TextureOptions {
        max_size: 1024,
        ..Default::default()
    };
    let paged = common::texture_into(&scene, &opts, &dir.path().join("paged"));
    let n = paged.pages.len();
    assert!(n >= 2, "{n} pages");
    assert_eq!(paged.report.atlas.pages as usize, n);
    assert_eq!(paged.report.pages.len(), n);
    assert!(paged.report.atlas.overlapping_texels == 0);
    // Each face's three UVs lie on one page, inside it; every page holds faces.
    let uv = paged.mesh.uv.as_ref().unwrap();
    let mut faces_on = vec![0usize; n];
    for t in &uv.faces {
        let u = t.map(|i| uv.coords[i as usize].x);
        let p = u[0].floor();
        assert!(u.iter().all(|&x| x >= p && x <= p + 1.0), "{u:?}");
        assert!((0.0..n as f32).contains(&p), "page {p} of {n}");
        faces_on[p as usize] += 1;
    }
    assert!(faces_on.iter().all(|&c| c > 0), "{faces_on:?}");
    // Every page: photographs coloured its charts, the tiles are on disk and the MTL names them.
    let mtl = std::fs::read_to_string(dir.path().join("paged/model.mtl")).unwrap();
    for (p, page) in paged.pages.iter().enumerate() {
        assert_eq!(page.tile, 1001 + p as u32);
        assert!(paged.report.pages[p].resample.texels_photos > 0);
        let tile = format!("model.{}.png", 1001 + p);
        let img = image::open(dir.path().join("paged").join(&tile)).unwrap();
        assert_eq!((img.width(), img.height()), (1024, 1024));
        assert!(mtl.contains(&format!("map_Kd {tile}")), "{mtl}");
    }
    assert!(!dir.path().join("paged/model.png").exists());
    // Both files read back as the UDIM texture, and render the same.
    for f in ["model.obj", "model.glb"] {
        let (m, _) = scantex::io::read_mesh(&dir.path().join("paged").join(f)).unwrap();
        match &m.texture {
            Some(TextureSource::Tiles(t)) => assert_eq!(t.len(), n, "{f}"),
            other => panic!("{f}: {other:?}"),
        }
    }
    let obj = held_out(&dir.path().join("paged/model.obj"));
    let glb = held_out(&dir.path().join("paged/model.glb"));
    // The OBJ keeps the positions' 64-bit values and the GLB rounds them to 32 bits, so a
    // pixel on a triangle's edge may render apart (1.5e-6 dB on one layout, 2026-12-05); a
    // wrong or missing tile costs whole decibels.
    assert!((obj.psnr - glb.psnr).abs() < 1e-4, "{obj:?} {glb:?}");
    // One page at the same cap has fewer texels and scores lower; a limit of two pages
    // gives two.
    opts.max_pages = Some(1);
    let one = common::texture_into(&scene, &opts, &dir.path().join("one"));
    assert_eq!(one.pages.len(), 1);
    assert!(dir.path().join("one/model.png").is_file());
    let one = held_out(&dir.path().join("one/model.obj"));
    // The extra texels show in the correlation; PSNR moves by a few hundredths of a dB with
    // the charts' layout either way (pages 34.76 against 34.70 dB on one layout, 34.734
    // against 34.747 on another, 2026-12-05), so it is only held within that.
    assert!(
        obj.one_minus_ncc < one.one_minus_ncc,
        "pages {obj:?} one page {one:?}"
    );
    assert!(obj.psnr > one.psnr - 0.05, "pages {obj:?} one page {one:?}");
    opts.max_pages = Some(2);
    let two = common::texture_into(&scene, &opts, &dir.path().join("two"));
    assert_eq!(two.pages.len(), 2);
    // The paged GLB passes the Khronos validator.
    let report = crate::mesh_io::khronos_validate(&dir.path().join("paged/model.glb"));
    assert_eq!(report["errors"], 0, "{report}");
    assert_eq!(report["warnings"], 0, "{report}");
    blender_imports(&dir.path().join("paged"), n);
}

/// Blender (Debian's package; `.ci/run` installs it) imports the paged OBJ and GLB with one
/// material per page, each reading its own 1024 x 1024 tile. Without Blender the check is
/// skipped with a printed reason, except under CI.
fn blender_imports(out: &Path, pages: usize) {
    let present = std::process::Command::new("blender")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !present {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "blender is missing and CI=true: .ci/run installs it"
        );
        eprintln!("skipping the Blender import: blender is not installed");
        return;
    }
    let script = common::root().join("tests/blender/import_pages.py");
    for f in ["model.obj", "model.glb"] {
        let o = std::process::Command::new("blender")
            .args(["--background", "--factory-startup", "--python"])
            .arg(&script)
            .arg("--")
            .arg(out.join(f))
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&o.stdout);
        let line = text
            .lines()
            .find_map(|l| l.strip_prefix("SCANTEX_JSON "))
            .unwrap_or_else(|| {
                panic!(
                    "{f}: Blender printed no result:\n{text}\n{}",
                    String::from_utf8_lossy(&o.stderr)
                )
            });
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(v["faces"], 24480, "{f}: {v}");
        let mats = v["materials"].as_object().unwrap();
        assert_eq!(mats.len(), pages, "{f}: {v}");
        for (name, images) in mats {
            let images = images.as_array().unwrap();
            assert_eq!(images.len(), 1, "{f} {name}: {v}");
            assert_eq!(images[0][1], 1024, "{f} {name}: not loaded: {v}");
            assert_eq!(images[0][2], 1024, "{f} {name}: not loaded: {v}");
        }
    }
}

/// `--memory-limit` on the command line (a process of its own, so that its peak is the
/// run's): a limit under what one 2048 page needs turns the sample's page into pages of
/// 1024, the same files as `--max-size 1024` gives, and the measured peak stays under it.
#[test]
fn a_memory_limit_makes_smaller_pages_and_the_run_stays_within_it() {
    let dir = tempfile::tempdir().unwrap();
    let scene = common::root().join("samples/torus");
    let run = |out: &str, extra: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_scantex"))
            .arg("texture")
            .arg(&scene)
            .arg("-o")
            .arg(dir.path().join(out))
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report = std::fs::read(dir.path().join(out).join("report.json")).unwrap();
        let report: serde_json::Value = serde_json::from_slice(&report).unwrap();
        (report, String::from_utf8_lossy(&o.stderr).into_owned())
    };
    let limit = 256u64 << 20;
    let (limited, stderr) = run("limited", &["--memory-limit", "256M"]);
    assert!(
        stderr.contains("pages of at most 1024 texels instead of 8192"),
        "{stderr}"
    );
    assert_eq!(limited["memory"]["limit_bytes"], limit);
    assert_eq!(limited["memory"]["max_side"], 1024);
    let pages = limited["pages"].as_array().unwrap().len();
    assert!(pages >= 2, "{pages} pages");
    let estimate = limited["memory"]["estimate_bytes"].as_u64().unwrap();
    assert!(estimate <= limit, "estimate {estimate}");
    let peak = limited["peak_mb"].as_f64().unwrap() * 1e6;
    assert!(peak > 0.0 && peak <= limit as f64, "peak {peak} bytes");
    // Each stage's own peak is measured (the run's is their largest by construction).
    for s in limited["stages"].as_array().unwrap() {
        assert!(s["peak_mb"].as_f64().unwrap() > 0.0, "{s}");
    }
    // The limit only chose the page side: the same pages as asking for that side.
    let (capped, _) = run("capped", &["--max-size", "1024", "--memory-limit", "off"]);
    assert_eq!(capped["memory"]["limit_bytes"], serde_json::Value::Null);
    assert_eq!(capped["pages"].as_array().unwrap().len(), pages);
    for f in ["model.obj", "model.1001.png", "model.1002.png"] {
        let a = std::fs::read(dir.path().join("limited").join(f)).unwrap();
        let b = std::fs::read(dir.path().join("capped").join(f)).unwrap();
        assert!(a == b, "{f} differs");
    }
}
