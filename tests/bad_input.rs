//! Bad input through the CLI: every case gets a clear error naming the file and the line,
//! record or element at fault, a non-zero exit, no panic, and no output written.

mod common;

use nalgebra::Point3;
use scantex::camera::colmap::{self, Image, Point2D, Point3D, Reconstruction};
use scantex::camera::{Camera, CameraModel, Pose};
use std::path::Path;
use std::process::Command;

/// A small valid scene: tetrahedron mesh, one PINHOLE camera, two photos, three points.
fn scene(dir: &Path) {
    std::fs::write(
        dir.join("mesh.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n",
    )
    .unwrap();
    let mut rec = Reconstruction::default();
    let cam = Camera::new(
        1,
        CameraModel::Pinhole,
        64,
        48,
        vec![50.0, 50.0, 32.0, 24.0],
    )
    .unwrap();
    rec.cameras.insert(1, cam.clone());
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for id in 1..=2u32 {
        let pose = Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.1 * id as f64, 0.0, 5.0]);
        let mut points2d = Vec::new();
        for (pid, p) in [
            (1u64, [0.0, 0.0, 0.0]),
            (2, [1.0, 0.0, 0.0]),
            (3, [0.0, 1.0, 0.0]),
        ] {
            let px = cam.project(&pose.transform(&Point3::from(p))).unwrap();
            points2d.push(Point2D {
                xy: [px.x, px.y],
                point3d_id: Some(pid),
            });
        }
        let name = format!("img{id}.png");
        image::RgbImage::new(64, 48)
            .save(dir.join("images").join(&name))
            .unwrap();
        rec.images.insert(
            id,
            Image {
                id,
                camera_id: 1,
                name,
                pose,
                points2d,
            },
        );
    }
    for (pid, p) in [
        (1u64, [0.0, 0.0, 0.0]),
        (2, [1.0, 0.0, 0.0]),
        (3, [0.0, 1.0, 0.0]),
    ] {
        let track = vec![(1, pid as u32 - 1), (2, pid as u32 - 1)];
        rec.points3d.insert(
            pid,
            Point3D {
                xyz: p,
                rgb: [1, 2, 3],
                error: 0.0,
                track,
            },
        );
    }
    colmap::write_text(&rec, &dir.join("sparse")).unwrap();
}

fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = walk(dir)
        .into_iter()
        .map(|p| p.strip_prefix(dir).unwrap().display().to_string())
        .collect();
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// Runs `scantex info <args>` in `dir` and returns stderr, asserting failure without panic
/// and that no file appeared.
fn fails(dir: &Path, args: &[&str]) -> String {
    fails_cmd(dir, "info", args)
}

/// As [`fails`], for any subcommand.
fn fails_cmd(dir: &Path, cmd: &str, args: &[&str]) -> String {
    let before = files(dir);
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .arg(cmd)
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        !out.status.success(),
        "expected failure for {args:?}; stderr: {err}"
    );
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    assert!(err.contains("scantex: error:"), "{err}");
    assert_eq!(files(dir), before, "files were written");
    err
}

fn setup() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    scene(d.path());
    d
}

/// The valid scene with its OBJ replaced by a PLY of the given content.
fn with_ply(content: &[u8]) -> tempfile::TempDir {
    let d = setup();
    std::fs::remove_file(d.path().join("mesh.obj")).unwrap();
    std::fs::write(d.path().join("mesh.ply"), content).unwrap();
    d
}

#[test]
fn the_valid_scene_passes() {
    let d = setup();
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["info", "--json"])
        .arg(d.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["mesh"]["faces"], 4);
    assert_eq!(r["mesh"]["topology"]["components"], 1);
    assert_eq!(r["colmap"]["photos_ok"], 2);
    assert!(r["colmap"]["reprojection"]["max"].as_f64().unwrap() < 1e-9);
}

fn binary_scene() -> tempfile::TempDir {
    let d = setup();
    let rec = colmap::read(&d.path().join("sparse")).unwrap();
    for f in ["cameras.txt", "images.txt", "points3D.txt"] {
        std::fs::remove_file(d.path().join("sparse").join(f)).unwrap();
    }
    colmap::write_binary(&rec, &d.path().join("sparse")).unwrap();
    d
}

#[test]
fn truncated_binary_colmap_files() {
    for f in ["cameras.bin", "images.bin", "points3D.bin"] {
        let d = binary_scene();
        let p = d.path().join("sparse").join(f);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 5]).unwrap();
        let err = fails(d.path(), &["."]);
        assert!(
            err.contains(f) && err.contains("byte") && err.contains("truncated"),
            "{err}"
        );
    }
}

#[test]
fn corrupt_binary_counts_fail_fast() {
    let d = binary_scene();
    let p = d.path().join("sparse").join("points3D.bin");
    let mut bytes = std::fs::read(&p).unwrap();
    bytes[..8].copy_from_slice(&(u64::MAX / 2).to_le_bytes());
    std::fs::write(&p, &bytes).unwrap();
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("points3D.bin (byte 0)") && err.contains("corrupt"),
        "{err}"
    );
}

fn edit(path: &Path, from: &str, to: &str) {
    let s = std::fs::read_to_string(path).unwrap();
    assert!(s.contains(from), "{from} not in {}", path.display());
    std::fs::write(path, s.replacen(from, to, 1)).unwrap();
}

#[test]
fn unknown_camera_model() {
    let d = setup();
    edit(
        &d.path().join("sparse/cameras.txt"),
        "PINHOLE",
        "PINHOLE_PLUS",
    );
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("cameras.txt:4") && err.contains("unknown camera model 'PINHOLE_PLUS'"),
        "{err}"
    );
}

#[test]
fn wrong_parameter_count() {
    let d = setup();
    edit(&d.path().join("sparse/cameras.txt"), " 32 24", " 32");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("cameras.txt:4") && err.contains("takes 4 parameters, found 3"),
        "{err}"
    );
}

#[test]
fn image_references_missing_camera() {
    let d = setup();
    edit(
        &d.path().join("sparse/images.txt"),
        " 1 img2.png",
        " 7 img2.png",
    );
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("images.txt (image 2 (img2.png))") && err.contains("camera 7"),
        "{err}"
    );
}

#[test]
fn photo_missing_unreadable_or_wrong_size() {
    let d = setup();
    std::fs::remove_file(d.path().join("images/img2.png")).unwrap();
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("img2.png") && err.contains("not found"),
        "{err}"
    );

    let d = setup();
    std::fs::write(d.path().join("images/img2.png"), b"this is not a PNG").unwrap();
    let err = fails(d.path(), &["."]);
    assert!(err.contains("img2.png") && err.contains("decode"), "{err}");

    let d = setup();
    image::RgbImage::new(60, 48)
        .save(d.path().join("images/img1.png"))
        .unwrap();
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("img1.png") && err.contains("60x48") && err.contains("64x48"),
        "{err}"
    );
}

#[test]
fn non_finite_vertex() {
    let d = setup();
    edit(&d.path().join("mesh.obj"), "v 1 0 0", "v 1 nan 0");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.obj:2") && err.contains("not finite"),
        "{err}"
    );
    let d = setup();
    edit(&d.path().join("mesh.obj"), "v 1 0 0", "v 1 inf 0");
    assert!(fails(d.path(), &["."]).contains("mesh.obj:2"));
}

#[test]
fn face_index_out_of_range() {
    let d = setup();
    edit(&d.path().join("mesh.obj"), "f 2 3 4", "f 2 3 9");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.obj:7") && err.contains("index 9 is out of range"),
        "{err}"
    );
    // PLY: the face element is named.
    let d = with_ply(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.ply (face 0)") && err.contains("out of range"),
        "{err}"
    );
}

#[test]
fn empty_mesh() {
    let d = setup();
    std::fs::write(d.path().join("mesh.obj"), "# nothing here\n").unwrap();
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.obj") && err.contains("no (non-degenerate) triangles"),
        "{err}"
    );
}

#[test]
fn unsupported_ply_property_type() {
    let d = with_ply(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty int64 z\nend_header\n");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.ply:6") && err.contains("unsupported PLY property type 'int64'"),
        "{err}"
    );
}

#[test]
fn truncated_ply() {
    let d = with_ply(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0");
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("mesh.ply (byte") && err.contains("truncated"),
        "{err}"
    );
}

#[test]
fn degenerate_faces_are_reported_and_skipped() {
    let d = setup();
    edit(
        &d.path().join("mesh.obj"),
        "f 1 3 2",
        "f 1 3 2\nf 1 1 2\nf 1 2",
    );
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["info", "--json"])
        .arg(d.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["mesh"]["faces"], 4);
    assert_eq!(r["mesh"]["load"]["degenerate_faces"], 2);
}

#[test]
fn missing_scene_parts_and_unknown_formats() {
    let d = setup();
    let err = fails(d.path(), &["no_such_dir"]);
    assert!(
        err.contains("no_such_dir") && err.contains("not found"),
        "{err}"
    );
    std::fs::write(d.path().join("mesh.stl"), "solid x").unwrap();
    let err = fails(d.path(), &["--mesh", "mesh.stl"]);
    assert!(
        err.contains("mesh.stl") && err.contains("unknown mesh format"),
        "{err}"
    );
    let err = fails(d.path(), &["--colmap", "images"]);
    assert!(err.contains("no COLMAP model"), "{err}");
}

#[test]
fn gltf_accessor_past_the_buffer() {
    let d = setup();
    std::fs::remove_file(d.path().join("mesh.obj")).unwrap();
    std::fs::write(d.path().join("b.bin"), [0u8; 12]).unwrap();
    let g = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"uri": "b.bin", "byteLength": 12}],
        "bufferViews": [{"buffer": 0, "byteLength": 360}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 30, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}]
    });
    std::fs::write(d.path().join("mesh.gltf"), g.to_string()).unwrap();
    let err = fails(d.path(), &["."]);
    assert!(err.contains("mesh.gltf"), "{err}");
}

#[test]
fn atlas_options_out_of_range_and_meshes_without_uvs() {
    let d = setup();
    for (args, what) in [
        (vec!["mesh.obj", "-o", "p.obj", "--k", "1"], "k = 1"),
        (vec!["mesh.obj", "-o", "p.obj", "--alpha", "0.6"], "alpha"),
        (vec!["mesh.obj", "-o", "p.obj", "--size", "8"], "atlas size"),
        (
            vec![
                "mesh.obj", "-o", "p.obj", "--gutter", "600", "--size", "1024",
            ],
            "gutter",
        ),
        (
            vec!["mesh.obj", "-o", "p.obj", "--view-dir", "0,0,0"],
            "view direction",
        ),
        (
            vec!["mesh.obj", "-o", "p.obj", "--texel-density", "0"],
            "texel density",
        ),
    ] {
        let err = fails_cmd(d.path(), "param", &args);
        assert!(err.contains(what), "{args:?}: {err}");
    }
    let err = fails_cmd(d.path(), "uv-report", &["mesh.obj"]);
    assert!(err.contains("no texture coordinates"), "{err}");
}
