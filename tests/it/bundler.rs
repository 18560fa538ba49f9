//! Bundler files (issue 25): a real Bundler solution's points land on its own measurements
//! through the cameras as scantex reads them, and malformed files name what is wrong.

use crate::common;
use nalgebra::Point3;
use scantex::camera::bundler;

/// A point's (camera, x, y) measurements.
type Observations = Vec<(usize, f64, f64)>;

/// Points of a Bundler v0.3 file: position and (camera, x, y) observations in Bundler's
/// image frame (pixels from the centre, y up).
fn points(text: &str, cameras: usize) -> Vec<(Point3<f64>, Observations)> {
    let body: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    let npts: usize = body[0].split_whitespace().nth(1).unwrap().parse().unwrap();
    let mut out = Vec::new();
    let mut line = 1 + 5 * cameras;
    for _ in 0..npts {
        let x: Vec<f64> = body[line]
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let v: Vec<f64> = body[line + 2]
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let obs = (0..v[0] as usize)
            .map(|k| (v[1 + 4 * k] as usize, v[3 + 4 * k], v[4 + 4 * k]))
            .collect();
        out.push((Point3::new(x[0], x[1], x[2]), obs));
        line += 3;
    }
    out
}

/// `calib/bundler/lightbender_excerpt.out` is a real Bundler solution (10 cameras, 12 of its
/// points; `calib/bundler/README.md`). Projected through the cameras as scantex reads them
/// (COLMAP's frame, RADIAL, principal point at the image centre), every point lands on
/// Bundler's own measurement of it within Bundler's residual.
#[test]
fn a_real_bundler_solution_reprojects_onto_its_measurements() {
    let path = common::root().join("calib/bundler/lightbender_excerpt.out");
    let text = std::fs::read_to_string(&path).unwrap();
    let names: Vec<String> = (0..10).map(|i| format!("view{i}.jpg")).collect();
    // The file stores no size and its measurements are from the centre: any size will do.
    let (w, h) = (1000u32, 750u32);
    let rec = bundler::parse(&path, &text, &names, &|_| Ok((w, h))).unwrap();
    assert_eq!(rec.images.len(), 10);
    let mut errors = Vec::new();
    for (x, obs) in points(&text, 10) {
        for (c, bx, by) in obs {
            let img = &rec.images[&(c as u32 + 1)];
            let cam = &rec.cameras[&img.camera_id];
            let p = img.pose.transform(&x);
            assert!(p.z > 0.0, "point behind camera {c}");
            let px = cam.project(&p).unwrap();
            let (ux, uy) = (px.x - w as f64 / 2.0, h as f64 / 2.0 - px.y);
            errors.push(((ux - bx).powi(2) + (uy - by).powi(2)).sqrt());
        }
    }
    errors.sort_by(f64::total_cmp);
    let median = errors[errors.len() / 2];
    let worst = errors[errors.len() - 1];
    eprintln!(
        "Bundler excerpt: {} observations, median {median:.3} px, worst {worst:.3} px",
        errors.len()
    );
    assert!(errors.len() >= 60, "{} observations", errors.len());
    assert!(
        median < 1.0 && worst < 4.0,
        "median {median} px, worst {worst} px"
    );
}

/// Truncated files, bad numbers, a list of the wrong length and a camera that is no rotation
/// are errors naming the file and the place.
#[test]
fn malformed_bundler_files_name_what_is_wrong() {
    let path = common::root().join("calib/bundler/lightbender_excerpt.out");
    let good = std::fs::read_to_string(&path).unwrap();
    let names: Vec<String> = (0..10).map(|i| format!("view{i}.jpg")).collect();
    let size = |_: &str| Ok((1000, 750));
    let cases = [
        (good[..600].to_string(), names.clone(), "ends before"),
        (
            good.replacen("9.9150539147e-01", "x", 1),
            names.clone(),
            ":4:",
        ),
        (
            good.replacen("9.9150539147e-01", "3.0", 1),
            names.clone(),
            "camera 0",
        ),
        (good.clone(), names[..9].to_vec(), "image list"),
    ];
    for (text, list, want) in cases {
        let e = bundler::parse(&path, &text, &list, &size)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("lightbender_excerpt.out") && e.contains(want),
            "{want}: {e}"
        );
    }
    // Without the photographs there is no image size to give the cameras.
    let e = bundler::read(&path, None).unwrap_err().to_string();
    assert!(e.contains("--images"), "{e}");
}

/// `calib/bundler/torus.out` is the bundled sample's COLMAP model written by
/// `calib/bundler/colmap_to_bundler.py`: read back with the sample's photographs for their
/// sizes, every photograph projects the mesh's vertices where the COLMAP model does.
#[test]
fn the_sample_converted_to_bundler_projects_as_its_colmap_model() {
    let root = common::root();
    let images = root.join("samples/torus/images");
    let b = bundler::read(&root.join("calib/bundler/torus.out"), Some(&images)).unwrap();
    let c = scantex::camera::colmap::read(&root.join("samples/torus/sparse/0")).unwrap();
    let (worst, compared) = common::projection_difference(&b, &c);
    assert!(compared > 1000, "{compared} projections compared");
    assert!(worst < 1e-6, "largest difference {worst} px");
}
