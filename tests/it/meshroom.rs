//! Meshroom / AliceVision camera files (issue 25): AliceVision's own synthetic cube scene
//! against the generator that made it, the bundled sample converted from COLMAP against its
//! COLMAP model, and malformed files.

use crate::common;
use nalgebra::{Matrix3, Rotation3, Vector3};
use scantex::camera::meshroom;
use scantex::camera::{colmap, CameraModel};
use std::path::Path;

/// `calib/meshroom/alicevision_cube_v1.2.6_excerpt.sfm` holds views, intrinsics and five
/// poses of AliceVision's compatibility scene, which `generateCubeScene` (AliceVision,
/// sfmDataIO/sceneSample.cpp) made: fx 1000, fy 2000 pixels, principal point offset (-26, 16)
/// from the centre of a 4092 x 2048 image, radial3 (0.1, 0.05, -0.001); pose (x, y, z) in
/// {-1, 0, 1}^3 has its centre at (x, y, z) and the world-to-camera rotation of angle-axis
/// (x, y, z). The file stores focal lengths in millimetres with a pixel aspect ratio and the
/// rotation column-major: reading it back to the generator's numbers checks every convention.
#[test]
fn alicevision_cube_scene_reads_back_to_its_generator() {
    let path = common::root().join("calib/meshroom/alicevision_cube_v1.2.6_excerpt.sfm");
    let rec = meshroom::read(&path).unwrap();
    assert_eq!(rec.cameras.len(), 2);
    assert_eq!(rec.images.len(), 10);
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9);
    let pinhole = &rec.cameras[&1];
    assert_eq!(pinhole.model, CameraModel::Pinhole);
    assert!(
        close(&pinhole.params, &[1000.0, 2000.0, 2020.0, 1040.0]),
        "{pinhole:?}"
    );
    let radial = &rec.cameras[&2];
    assert_eq!(radial.model, CameraModel::FullOpencv);
    let want = [
        1000.0, 2000.0, 2020.0, 1040.0, 0.1, 0.05, 0.0, 0.0, -0.001, 0.0, 0.0, 0.0,
    ];
    assert!(close(&radial.params, &want), "{radial:?}");
    assert_eq!((radial.width, radial.height), (4092, 2048));
    for img in rec.images.values() {
        // Views 2p and 2p + 1 share pose p; the excerpt's names are "view<id>".
        let view: i32 = img.name.trim_start_matches("view").parse().unwrap();
        let p = view / 2;
        let xyz = Vector3::new(
            (p / 9 - 1) as f64,
            ((p / 3) % 3 - 1) as f64,
            (p % 3 - 1) as f64,
        );
        let r: Matrix3<f64> = Rotation3::from_scaled_axis(xyz).into_inner();
        let got: Matrix3<f64> = img.pose.rotation.to_rotation_matrix().into_inner();
        assert!(
            (got - r).abs().max() < 1e-12,
            "view {view}: {got} against {r}"
        );
        let c = img.pose.center();
        assert!((c.coords - xyz).norm() < 1e-12, "view {view}: centre {c}");
        assert_eq!(img.camera_id, 1 + (view % 2) as u32);
    }
}

/// `calib/meshroom/torus_cameras.sfm` is the bundled sample's COLMAP model written by
/// `calib/meshroom/colmap_to_sfm.py` as Meshroom 2023 writes cameras.sfm (millimetre focal
/// lengths, centred principal point, column-major rotations, Windows paths): every photograph
/// projects the mesh's vertices where the COLMAP model does.
#[test]
fn the_sample_converted_to_cameras_sfm_projects_as_its_colmap_model() {
    let root = common::root();
    let sfm = meshroom::read(&root.join("calib/meshroom/torus_cameras.sfm")).unwrap();
    let col = colmap::read(&root.join("samples/torus/sparse/0")).unwrap();
    let (worst, compared) = common::projection_difference(&sfm, &col);
    assert!(compared > 1000, "{compared} projections compared");
    assert!(worst < 1e-6, "largest difference {worst} px");
}

/// A scene directory with `cameras.sfm` and no `sparse/` loads through it, and `--colmap`
/// accepts the file.
#[test]
fn scene_directories_find_cameras_sfm() {
    let dir = tempfile::tempdir().unwrap();
    let root = common::root();
    std::fs::copy(
        root.join("calib/meshroom/torus_cameras.sfm"),
        dir.path().join("cameras.sfm"),
    )
    .unwrap();
    std::fs::copy(
        root.join("samples/torus/mesh.ply"),
        dir.path().join("mesh.ply"),
    )
    .unwrap();
    common::copy_dir(
        &root.join("samples/torus/images"),
        &dir.path().join("images"),
    );
    let s = scantex::scene::Scene::load(&scantex::scene::SceneSpec {
        dir: Some(dir.path().into()),
        ..Default::default()
    })
    .unwrap();
    assert_eq!(s.photos.len(), 16);
    s.check_photos().unwrap();
}

/// Malformed files fail with the file and the element named, never a panic.
#[test]
fn malformed_cameras_sfm_names_what_is_wrong() {
    let good = std::fs::read_to_string(
        common::root().join("calib/meshroom/alicevision_cube_v1.2.6_excerpt.sfm"),
    )
    .unwrap();
    let p = Path::new("cameras.sfm");
    let cases: Vec<(String, &str)> = vec![
        (good[..good.len() / 2].to_string(), "line"),
        (
            good.replacen(
                "\"1\",\n                        \"0\"",
                "\"2\",\n                        \"0\"",
                1,
            ),
            "poses[3]",
        ),
        (
            good.replacen("\"type\": \"radial3\"", "\"type\": \"equirectangular\"", 1),
            "intrinsics[1]",
        ),
        (
            good.replacen(
                "\"focalLength\": \"8.7976539589442808\"",
                "\"focalLength\": \"-1\"",
                1,
            ),
            "intrinsics[0]",
        ),
        (
            good.replacen(
                "\"intrinsicId\": \"1\",\n            \"path\"",
                "\"intrinsicId\": \"7\",\n            \"path\"",
                1,
            ),
            "views[1]",
        ),
        ("[1, 2, 3]".to_string(), "views"),
    ];
    for (text, want) in cases {
        assert_ne!(text, good, "the case {want} changed nothing");
        let e = meshroom::parse(p, text.as_bytes()).unwrap_err().to_string();
        assert!(e.contains("cameras.sfm") && e.contains(want), "{want}: {e}");
    }
}
