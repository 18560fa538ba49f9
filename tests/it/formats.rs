//! VisualSFM `.nvm` and OpenMVS `.mvs` camera files (issue 25): a real VisualSFM solution's
//! points land on its own measurements through the cameras as scantex reads them; the
//! undistorted sample written in each format projects as its COLMAP model; malformed files
//! name what is wrong.

use crate::common;
use nalgebra::Point3;
use scantex::camera::colmap::{self, Reconstruction};
use scantex::camera::{nvm, openmvs};
use scantex::error::Result;
use std::path::Path;

/// The sizes of a COLMAP model's photographs by file name, standing in for the photographs
/// (the undistorted ones are made by `calib/undistorted/make.py`, not committed).
fn sizes_of(rec: &Reconstruction) -> impl Fn(&str) -> Result<(u32, u32)> + '_ {
    move |name: &str| {
        let img = rec.images.values().find(|i| i.name == name).unwrap();
        let cam = &rec.cameras[&img.camera_id];
        Ok((cam.width, cam.height))
    }
}

/// `calib/nvm/visualsfm_excerpt.nvm` is a real VisualSFM solution (22 cameras, 8 of its
/// points; `calib/nvm/README.md`) whose cameras carry radial distortions of -0.39 to 0.17.
/// Projected through the cameras as scantex reads them (the measurement distortion inverted
/// by FULL_OPENCV), every point lands on VisualSFM's own measurement of it (pixels from the
/// image centre) within the solution's residual; read without the distortion, the worst is
/// 23 px off.
#[test]
fn a_real_visualsfm_solution_reprojects_onto_its_measurements() {
    let path = common::root().join("calib/nvm/visualsfm_excerpt.nvm");
    let text = std::fs::read_to_string(&path).unwrap();
    // The file stores no size and measures from the centre: any size holding them will do.
    let (w, h) = (2000u32, 1500u32);
    let rec = nvm::parse(&path, &text, &|_| Ok((w, h))).unwrap();
    assert_eq!(rec.images.len(), 22);
    let lines: Vec<&str> = text.lines().collect();
    let npts: usize = lines[26].trim().parse().unwrap();
    let mut errors = Vec::new();
    for line in &lines[27..27 + npts] {
        let v: Vec<f64> = line
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let x = Point3::new(v[0], v[1], v[2]);
        for k in 0..v[6] as usize {
            let (c, mx, my) = (v[7 + 4 * k] as u32, v[9 + 4 * k], v[10 + 4 * k]);
            let img = &rec.images[&(c + 1)];
            let p = img.pose.transform(&x);
            assert!(p.z > 0.0, "point behind camera {c}");
            let px = rec.cameras[&img.camera_id].project(&p).unwrap();
            let (ux, uy) = (px.x - w as f64 / 2.0, px.y - h as f64 / 2.0);
            errors.push(((ux - mx).powi(2) + (uy - my).powi(2)).sqrt());
        }
    }
    errors.sort_by(f64::total_cmp);
    let (median, worst) = (errors[errors.len() / 2], errors[errors.len() - 1]);
    eprintln!(
        "VisualSFM excerpt: {} observations, median {median:.3} px, worst {worst:.3} px",
        errors.len()
    );
    assert!(errors.len() >= 100, "{} observations", errors.len());
    assert!(
        median < 1.5 && worst < 4.0,
        "median {median} px, worst {worst} px"
    );
}

/// The undistorted sample (`calib/undistorted/torus`, COLMAP's own undistortion) written as
/// NVM and as OpenMVS archives of versions 0 (normalised intrinsics, no header), 1 and 7 (a
/// camera offset and rotated on its platform): every photograph projects the mesh's
/// vertices where the COLMAP model does.
#[test]
fn the_undistorted_sample_in_each_format_projects_as_its_colmap_model() {
    let root = common::root();
    let reference = colmap::read(&root.join("calib/undistorted/torus")).unwrap();
    let sizes = sizes_of(&reference);
    let nvm_path = root.join("calib/nvm/torus.nvm");
    let text = std::fs::read_to_string(&nvm_path).unwrap();
    let mut converted = vec![(
        "torus.nvm".to_string(),
        nvm::parse(&nvm_path, &text, &sizes).unwrap(),
    )];
    for f in ["torus_v0.mvs", "torus_v1.mvs", "torus_v7_rig.mvs"] {
        let p = root.join("calib/openmvs").join(f);
        let bytes = std::fs::read(&p).unwrap();
        converted.push((f.to_string(), openmvs::parse(&p, &bytes, &sizes).unwrap()));
    }
    for (name, rec) in &converted {
        let (worst, compared) = common::projection_difference(rec, &reference);
        eprintln!("{name}: {compared} projections, worst {worst:.2e} px");
        assert!(compared > 1000, "{name}: {compared}");
        assert!(worst < 1e-6, "{name}: {worst} px");
    }
    // Versions 1 and 7 store the resolution: no photograph is needed.
    let v1 = openmvs::read(&root.join("calib/openmvs/torus_v1.mvs"), None).unwrap();
    assert_eq!(v1.images.len(), 16);
    // Version 0 does not, and says what to give.
    let e = openmvs::read(&root.join("calib/openmvs/torus_v0.mvs"), None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--images"), "{e}");
}

/// Truncated files, bad numbers and headers, and ids or rotations that do not hold are
/// errors naming the file and the place.
#[test]
fn malformed_nvm_files_name_what_is_wrong() {
    let path = common::root().join("calib/nvm/visualsfm_excerpt.nvm");
    let good = std::fs::read_to_string(&path).unwrap();
    let size = |_: &str| Ok((2000, 1500));
    let cases = [
        (good[..300].to_string(), "ends before"),
        (good.replacen("2685.98071289", "x", 1), ":4:"),
        (good.replacen("NVM_V3", "NVM_V2", 1), "NVM_V3"),
        (
            good.replacen("0.754515574599", "3.0", 1),
            "camera 0 (PIC_0001.JPG)",
        ),
        (good.replacen("2685.98071289", "-5", 1), "not positive"),
    ];
    for (text, want) in cases {
        let e = nvm::parse(&path, &text, &size).unwrap_err().to_string();
        assert!(
            e.contains("visualsfm_excerpt.nvm") && e.contains(want),
            "{want}: {e}"
        );
    }
    let e = nvm::read(&path, None).unwrap_err().to_string();
    assert!(e.contains("--images"), "{e}");
}

/// The same for OpenMVS archives: truncation at every length, a newer version, OpenMVS's
/// full (boost) scene files, a corrupt count and an image pointing at no platform.
#[test]
fn malformed_openmvs_files_name_what_is_wrong() {
    let path = common::root().join("calib/openmvs/torus_v7_rig.mvs");
    let good = std::fs::read(&path).unwrap();
    let size = |_: &str| Ok((800, 600));
    let err = |bytes: &[u8]| {
        openmvs::parse(Path::new("x.mvs"), bytes, &size)
            .unwrap_err()
            .to_string()
    };
    // Every cut inside the platforms and images is an error, never a panic or a partial
    // scene (the points after the images are not read).
    let images_end = good.len() - 6 * 8 - 16 * 8 - 15 * 8;
    for cut in (0..images_end).step_by(7) {
        let e = err(&good[..cut]);
        assert!(e.contains("x.mvs"), "cut at {cut}: {e}");
    }
    let mut newer = good.clone();
    newer[4] = 8;
    assert!(err(&newer).contains("version 8"), "{}", err(&newer));
    let mut boost = b"\x16\x00\x00\x00\x00\x00\x00\x00serialization::archive".to_vec();
    boost.extend_from_slice(&[0; 32]);
    assert!(err(&boost).contains("InterfaceCOLMAP"), "{}", err(&boost));
    let mut huge = good.clone();
    huge[12..20].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(err(&huge).contains("do not fit"), "{}", err(&huge));
    // The first image's platform id (after its u64-counted name) set past the platforms.
    let needle = b"images/view_01.jpg";
    let at = good
        .windows(needle.len())
        .position(|w| w == needle)
        .unwrap()
        + needle.len();
    let mut bad_id = good.clone();
    bad_id[at + 8..at + 12].copy_from_slice(&99u32.to_le_bytes());
    let e = err(&bad_id);
    assert!(
        e.contains("image 0 (view_01.jpg)") && e.contains("platform 99"),
        "{e}"
    );
}
