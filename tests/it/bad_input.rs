//! Bad input through the CLI: every case gets a clear error naming the file and the line,
//! record or element at fault, a non-zero exit, no panic, and no output written.

use crate::common;

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

/// Every file and directory under `dir` (directories too: a failed run must not leave an empty
/// output directory behind either).
fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.push(p.clone());
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
fn focal_lengths_that_are_not_positive_and_empty_images() {
    // A zero focal length images every point at the principal point, a negative one mirrors
    // the photograph: both once bound the mesh to wrong colours without a word.
    for (from, to, says) in [
        (
            " 50 50 ",
            " 0 50 ",
            "focal lengths 0 and 50 must be positive",
        ),
        (
            " 50 50 ",
            " -50 -50 ",
            "focal lengths -50 and -50 must be positive",
        ),
        (" 64 48 ", " 0 48 ", "image size 0 x 48 has no pixels"),
    ] {
        let d = setup();
        edit(&d.path().join("sparse/cameras.txt"), from, to);
        let err = fails(d.path(), &["."]);
        assert!(err.contains("cameras.txt:4") && err.contains(says), "{err}");
    }
    // The same check holds for the binary model's reader.
    let d = binary_scene();
    let p = d.path().join("sparse/cameras.bin");
    let mut b = std::fs::read(&p).unwrap();
    // After the count (8), id (4), model (4), width and height (8 each): fx as f64.
    b[32..40].copy_from_slice(&(-50f64).to_le_bytes());
    std::fs::write(&p, b).unwrap();
    let err = fails(d.path(), &["."]);
    assert!(
        err.contains("cameras.bin") && err.contains("focal lengths -50 and 50 must be positive"),
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
fn repeated_faces_are_left_out_with_a_warning() {
    // Every face twice, the copy turned over: each edge then has four faces, and every face
    // became a chart of its own (the sample took 93 s instead of 4).
    let d = setup();
    std::fs::write(
        d.path().join("mesh.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n\
         f 2 3 1\nf 4 2 1\nf 4 3 2\nf 3 4 1\n",
    )
    .unwrap();
    let info = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["info", "."])
        .current_dir(d.path())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(info.status.success(), "{text}");
    assert!(text.contains("repeated (skipped)   4"), "{text}");
    // Textured: the sample with its faces repeated, turned over.
    let t = tempfile::tempdir().unwrap();
    common::copy_dir(&common::root().join("samples/torus"), t.path());
    let (mut mesh, _) = scantex::io::read_mesh(&t.path().join("mesh.ply")).unwrap();
    let n = mesh.faces.len();
    let turned: Vec<_> = mesh.faces.iter().map(|f| [f[2], f[1], f[0]]).collect();
    mesh.faces.extend(turned);
    scantex::io::write_mesh(&t.path().join("mesh.ply"), &mesh, None).unwrap();
    let out = t.path().join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["texture", ".", "-q", "--size", "512", "-o"])
        .arg(&out)
        .current_dir(t.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{err}");
    let said = format!("left out {n} faces of the mesh that repeat an earlier face's vertices");
    assert!(err.contains(&said), "{err}");
    let obj = std::fs::read_to_string(out.join("model.obj")).unwrap();
    assert_eq!(obj.lines().filter(|l| l.starts_with("f ")).count(), n);
    let report = std::fs::read_to_string(out.join("report.json")).unwrap();
    assert!(report.contains(&said), "{report}");
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

/// A Draco-compressed glTF (its accessors have no data of their own) is refused for what it
/// is, with what to do.
#[test]
fn gltf_with_compressed_meshes_names_the_extension() {
    let d = setup();
    std::fs::remove_file(d.path().join("mesh.obj")).unwrap();
    std::fs::write(d.path().join("b.bin"), [0u8; 64]).unwrap();
    let draco = "KHR_draco_mesh_compression";
    let g = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "extensionsUsed": [draco], "extensionsRequired": [draco],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0},
            "extensions": {draco: {"bufferView": 0, "attributes": {"POSITION": 0}}}}]}],
        "buffers": [{"uri": "b.bin", "byteLength": 64}],
        "bufferViews": [{"buffer": 0, "byteLength": 64}],
        "accessors": [{"componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 1.0]}]
    });
    std::fs::write(d.path().join("mesh.gltf"), g.to_string()).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["mesh.gltf", draco, "without mesh compression"],
    );
}

#[test]
fn atlas_options_out_of_range_and_meshes_without_uvs() {
    let d = setup();
    for (args, what) in [
        (vec!["mesh.obj", "-o", "p.obj", "--k", "1"], "k = 1"),
        (vec!["mesh.obj", "-o", "p.obj", "--alpha", "0.6"], "alpha"),
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
        // A density no page can hold fails before any chart is rasterised at it (it aborted
        // on a failed allocation of 1.8e18 bytes).
        (
            vec!["mesh.obj", "-o", "p.obj", "--texel-density", "1e12"],
            "a chart is larger than a 4096-texel page",
        ),
    ] {
        let err = fails_cmd(d.path(), "param", &args);
        assert!(err.contains(what), "{args:?}: {err}");
    }
    let err = fails_cmd(d.path(), "uv-report", &["mesh.obj"]);
    assert!(err.contains("no texture coordinates"), "{err}");
    // The atlas size's range is clap's to check: a usage error.
    usage_fails(
        "param",
        &["mesh.obj", "-o", "p.obj", "--size", "8"],
        &["--size", "from 16 to 32768"],
    );
}

// ---------------------------------------------------------------------------------------------
// The texture command: bad photographs, poses and models, outputs, options.

/// `scantex texture . -o out` in `dir` must fail naming `what`, writing nothing (no `out`).
fn texture_fails(dir: &Path, extra: &[&str]) -> String {
    let mut args = vec![".", "-o", "out", "-q"];
    args.extend_from_slice(extra);
    let err = fails_cmd(dir, "texture", &args);
    assert!(!dir.join("out").exists(), "out/ was created: {err}");
    err
}

/// Asserts that `err` contains every one of `parts`.
fn names(err: &str, parts: &[&str]) {
    for p in parts {
        assert!(err.contains(p), "'{p}' not in: {err}");
    }
}

/// The first line of the file at `p` that starts with `prefix` (a record by its id).
fn line_starting(p: &Path, prefix: &str) -> String {
    let text = std::fs::read_to_string(p).unwrap();
    let line = text.lines().find(|l| l.starts_with(prefix));
    line.unwrap_or_else(|| panic!("no line starts with '{prefix}'"))
        .to_string()
}

/// The observation line (POINTS2D) of the image named `name` in images.txt at `p`.
fn observations_of(p: &Path, name: &str) -> String {
    let text = std::fs::read_to_string(p).unwrap();
    let mut lines = text.lines().skip_while(|l| !l.ends_with(name));
    lines.nth(1).unwrap().to_string()
}

/// A real JPEG photograph (the bundled sample's first view), for truncation cases.
fn sample_jpeg() -> Vec<u8> {
    std::fs::read(common::root().join("samples/torus/images/view_01.jpg")).unwrap()
}

#[test]
fn truncated_jpeg_photographs_are_errors_naming_the_file() {
    let d = setup();
    let jpg = sample_jpeg();
    let cams = d.path().join("sparse/cameras.txt");
    edit(&cams, "64 48", "640 480");
    edit(&d.path().join("sparse/images.txt"), "img1.png", "img1.jpg");
    std::fs::write(d.path().join("images/img1.jpg"), &jpg[..20_000]).unwrap();
    // img2 must be of the camera's size too, so that only img1 is at fault.
    image::RgbImage::new(640, 480)
        .save(d.path().join("images/img2.png"))
        .unwrap();
    let err = texture_fails(d.path(), &[]);
    names(
        &err,
        &["img1.jpg", "truncated", "byte 20000", "--skip-bad-images"],
    );
    // info says the same and exits non-zero.
    let err = fails(d.path(), &["."]);
    names(&err, &["img1.jpg", "truncated"]);
}

#[test]
fn truncated_and_corrupt_png_photographs_are_errors_naming_the_file() {
    let d = setup();
    let p = d.path().join("images/img2.png");
    let mut img = image::RgbImage::new(64, 48);
    for (x, y, px) in img.enumerate_pixels_mut() {
        *px = image::Rgb([(x * 4) as u8, (y * 5) as u8, ((x * y) % 251) as u8]);
    }
    img.save(&p).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() - 40]).unwrap();
    names(&texture_fails(d.path(), &[]), &["img2.png"]);
    // A flipped byte inside the compressed data: the checksum or the inflater objects.
    let mut bad = bytes.clone();
    let mid = bytes.len() / 2;
    bad[mid] ^= 0x5A;
    std::fs::write(&p, &bad).unwrap();
    names(&texture_fails(d.path(), &[]), &["img2.png"]);
}

#[test]
fn skip_bad_images_leaves_a_bad_photograph_out_with_a_warning_and_a_report_entry() {
    let d = tempfile::tempdir().unwrap();
    common::copy_dir(&common::root().join("samples/torus"), d.path());
    let p = d.path().join("images/view_03.jpg");
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 3]).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args([
            "texture",
            ".",
            "-o",
            "out",
            "-q",
            "--size",
            "256",
            "--no-restore",
        ])
        .arg("--skip-bad-images")
        .current_dir(d.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    names(&err, &["warning", "view_03.jpg", "truncated"]);
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/report.json")).unwrap()).unwrap();
    assert_eq!(r["photos"], 15);
    assert_eq!(r["photos_bad"][0]["name"], "view_03.jpg");
    assert!(r["warnings"][0].as_str().unwrap().contains("view_03.jpg"));
}

#[test]
fn photographs_that_contribute_nothing_are_warned_about() {
    let d = tempfile::tempdir().unwrap();
    common::copy_dir(&common::root().join("samples/torus"), d.path());
    // Turn image 2 half round: it now looks away from the object.
    let images = d.path().join("sparse/0/images.txt");
    let text = std::fs::read_to_string(&images).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let i = lines
        .iter()
        .position(|l| l.ends_with("view_02.jpg"))
        .unwrap();
    let mut t: Vec<String> = lines[i].split_whitespace().map(str::to_string).collect();
    t[6] = "1000".into();
    lines[i] = t.join(" ");
    std::fs::write(&images, lines.join("\n") + "\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args([
            "texture",
            ".",
            "-o",
            "out",
            "-q",
            "--size",
            "256",
            "--no-restore",
        ])
        .current_dir(d.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    names(&err, &["warning", "view_02.jpg", "contributes nothing"]);
    let r: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.path().join("out/report.json")).unwrap()).unwrap();
    let w = r["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].as_str().unwrap().contains("view_02.jpg"));
}

#[test]
fn a_mask_of_the_wrong_size_names_the_mask() {
    let d = setup();
    std::fs::create_dir_all(d.path().join("masks")).unwrap();
    image::GrayImage::new(10, 10)
        .save(d.path().join("masks/img1.png"))
        .unwrap();
    image::GrayImage::new(64, 48)
        .save(d.path().join("masks/img2.png"))
        .unwrap();
    // The mask is read when the photograph is: texturing (binding) is where it fails.
    let err = texture_fails(d.path(), &["--size", "64", "--no-restore"]);
    names(&err, &["masks/img1.png", "10x10", "64x48"]);
}

/// Replaces the pose fields (QW QX QY QZ TX TY TZ) of image `id` in images.txt.
fn set_pose(dir: &Path, id: u32, pose: &str) {
    let p = dir.join("sparse/images.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let out: Vec<String> = text
        .lines()
        .map(|l| {
            let t: Vec<&str> = l.split_whitespace().collect();
            if t.len() >= 10 && t[0] == id.to_string() && l.ends_with(".png") {
                format!("{} {pose} {} {}", t[0], t[8], t[9])
            } else {
                l.to_string()
            }
        })
        .collect();
    std::fs::write(&p, out.join("\n") + "\n").unwrap();
}

#[test]
fn bad_quaternions_and_translations_in_text() {
    for (pose, what) in [
        ("0 0 0 0 0.2 0 5", "norm 0.000000"),
        ("0.5 0 0 0 0.2 0 5", "norm 0.500000"),
        ("2 0 0 0 0.2 0 5", "norm 2.000000"),
        ("nan 0 0 0 0.2 0 5", "quaternion is not finite"),
        ("1 0 0 0 0.2 inf 5", "translation is not finite"),
    ] {
        let d = setup();
        set_pose(d.path(), 2, pose);
        let err = fails(d.path(), &["."]);
        names(&err, &["images.txt:", what]);
        if what.starts_with("norm") {
            names(&err, &["image 2", "not a rotation"]);
        }
        let err = texture_fails(d.path(), &[]);
        names(&err, &["images.txt:", what]);
    }
}

/// The byte offset of image `id`'s quaternion in an images.bin written by `write_binary`.
fn quaternion_offset(bytes: &[u8], id: u32) -> usize {
    // Images are written in id order; the first starts after the u64 count.
    let mut pos = 8;
    loop {
        let this = u32::from_le_bytes(bytes[pos..pos + 4].try_into().unwrap());
        if this == id {
            return pos + 4;
        }
        pos += 4 + 56 + 4;
        while bytes[pos] != 0 {
            pos += 1;
        }
        pos += 1;
        let n = u64::from_le_bytes(bytes[pos..pos + 8].try_into().unwrap()) as usize;
        pos += 8 + 24 * n;
    }
}

#[test]
fn bad_quaternions_in_binary_name_the_byte() {
    for (q, what) in [
        ([0.0f64, 0.0, 0.0, 0.0], "norm 0.000000"),
        ([0.9, 0.0, 0.0, 0.0], "norm 0.900000"),
        ([f64::NAN, 0.0, 0.0, 0.0], "quaternion is not finite"),
    ] {
        let d = binary_scene();
        let p = d.path().join("sparse/images.bin");
        let mut bytes = std::fs::read(&p).unwrap();
        let at = quaternion_offset(&bytes, 2);
        for (k, v) in q.iter().enumerate() {
            bytes[at + 8 * k..at + 8 * k + 8].copy_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&p, &bytes).unwrap();
        let err = fails(d.path(), &["."]);
        names(&err, &[&format!("images.bin (byte {at})"), what]);
    }
}

#[test]
fn non_finite_camera_parameters_and_point_values() {
    let d = setup();
    edit(
        &d.path().join("sparse/cameras.txt"),
        "50 50 32",
        "50 nan 32",
    );
    names(
        &fails(d.path(), &["."]),
        &["cameras.txt:4", "parameter 1 is not finite"],
    );
    let d = setup();
    edit(
        &d.path().join("sparse/points3D.txt"),
        "1 0 0 0 ",
        "1 0 inf 0 ",
    );
    names(
        &fails(d.path(), &["."]),
        &["points3D.txt:", "XYZ is not finite"],
    );
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let line = line_starting(&p, "2 ");
    let mut t: Vec<&str> = line.split_whitespace().collect();
    t[7] = "nan";
    edit(&p, &line, &t.join(" "));
    names(
        &fails(d.path(), &["."]),
        &["points3D.txt:", "ERROR is not finite"],
    );
}

#[test]
fn trailing_bytes_in_any_binary_file() {
    for (f, what) in [
        ("cameras.bin", "after the last camera"),
        ("images.bin", "after the last image"),
        ("points3D.bin", "after the last point"),
    ] {
        let d = binary_scene();
        let p = d.path().join("sparse").join(f);
        let mut bytes = std::fs::read(&p).unwrap();
        let at = bytes.len();
        bytes.extend_from_slice(&[7, 7, 7]);
        std::fs::write(&p, &bytes).unwrap();
        let err = fails(d.path(), &["."]);
        names(
            &err,
            &[&format!("{f} (byte {at})"), "3 unexpected bytes", what],
        );
    }
}

#[test]
fn points3d_text_truncated_at_a_field_boundary() {
    // The last point loses its last track element: the file still parses as numbers.
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let last = text
        .lines()
        .rfind(|l| l.starts_with("3 "))
        .unwrap()
        .to_string();
    let t: Vec<&str> = last.split_whitespace().collect();
    let cut = t[..t.len() - 2].join(" ");
    std::fs::write(&p, text.replace(&last, &cut).trim_end()).unwrap();
    let err = fails(d.path(), &["."]);
    names(
        &err,
        &[
            "images.txt",
            "image 2",
            "keypoint 2",
            "point3D 3",
            "disagree",
        ],
    );
    // Cut before the track: an empty track.
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let cut = t[..8].join(" ");
    std::fs::write(&p, text.replace(&last, &cut).trim_end()).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["points3D.txt (point3D 3)", "track is empty"],
    );
    // Whole lines lost: images observe points that are not there.
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    std::fs::write(&p, text.replace(&last, "")).unwrap();
    names(
        &fails(d.path(), &["."]),
        &[
            "images.txt (image 1 (img1.png) keypoint 2)",
            "point3D 3",
            "does not exist",
        ],
    );
}

#[test]
fn inconsistent_tracks_and_keypoints() {
    // A track element pointing at a keypoint that observes another point.
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let line = line_starting(&p, "1 ");
    let fixed = line.replacen(" 2 0", " 2 1", 1);
    assert_ne!(fixed, line);
    edit(&p, &line, &fixed);
    names(
        &fails(d.path(), &["."]),
        &[
            "points3D.txt (point3D 1)",
            "image 2 keypoint 1",
            "point3D 2",
        ],
    );
    // A track element past the image's keypoints.
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let line = line_starting(&p, "1 ");
    edit(&p, &line, &line.replacen(" 2 0", " 2 9", 1));
    names(
        &fails(d.path(), &["."]),
        &["point3D 1", "image 2 keypoint 9", "does not exist"],
    );
    // A keypoint far outside its image.
    let d = setup();
    let p = d.path().join("sparse/images.txt");
    let obs = observations_of(&p, "img2.png");
    let mut t: Vec<String> = obs.split_whitespace().map(str::to_string).collect();
    t[0] = "1e9".into();
    edit(&p, &obs, &t.join(" "));
    names(
        &fails(d.path(), &["."]),
        &[
            "images.txt (image 2 (img2.png) keypoint 0)",
            "far outside",
            "64x48",
        ],
    );
}

#[test]
fn observation_lines_that_do_not_hold_triples() {
    let d = setup();
    let p = d.path().join("sparse/images.txt");
    let obs = observations_of(&p, "img1.png");
    edit(&p, &obs, &format!("{obs} 5"));
    names(
        &fails(d.path(), &["."]),
        &["images.txt:", "not a multiple of 3"],
    );
}

#[test]
fn duplicate_ids() {
    let d = setup();
    let p = d.path().join("sparse/cameras.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let line = line_starting(&p, "1 ");
    std::fs::write(&p, format!("{text}{line}\n")).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["cameras.txt:", "camera 1 defined twice"],
    );
    let d = setup();
    let p = d.path().join("sparse/points3D.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let line = line_starting(&p, "1 ");
    std::fs::write(&p, format!("{text}{line}\n")).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["points3D.txt:", "point3D 1 defined twice"],
    );
}

/// Two images' poses and observations overwritten with random bytes, seed by seed: each
/// corrupt file is either refused naming images.bin, or gives back a model whose poses and
/// keypoints agree with the original (the bytes landed where they change nothing that
/// matters). A silently wrong pose is the failure.
#[test]
fn random_overwrites_of_a_real_images_bin_never_give_a_silently_wrong_pose() {
    let Some(src) = common::shared_data("colmap/statue_of_liberty/sparse/0") else {
        return;
    };
    let original = colmap::read(&src).unwrap();
    let bytes = std::fs::read(src.join("images.bin")).unwrap();
    let d = tempfile::tempdir().unwrap();
    for f in ["cameras.bin", "points3D.bin"] {
        std::fs::copy(src.join(f), d.path().join(f)).unwrap();
    }
    let mut refused = 0;
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for _seed in 0..30 {
        let mut b = bytes.clone();
        for _ in 0..200 {
            let i = (next() % b.len() as u64) as usize;
            b[i] = next() as u8;
        }
        std::fs::write(d.path().join("images.bin"), &b).unwrap();
        match colmap::read(d.path()) {
            Err(e) => {
                assert!(e.to_string().contains("images.bin"), "{e}");
                refused += 1;
            }
            Ok(rec) => {
                for (id, img) in &original.images {
                    let got = &rec.images[id];
                    let dq = got.pose.rotation.angle_to(&img.pose.rotation);
                    let dt = (got.pose.translation - img.pose.translation).norm();
                    assert!(dq < 1e-3 && dt < 1e-3, "image {id}: pose moved silently");
                    for (a, b) in got.points2d.iter().zip(&img.points2d) {
                        assert!((a.xy[0] - b.xy[0]).abs() < 1.0 && (a.xy[1] - b.xy[1]).abs() < 1.0);
                    }
                }
            }
        }
    }
    // 200 random bytes in 190 kB almost always hit something checkable.
    assert!(refused >= 25, "only {refused} of 30 corrupt files refused");
}

#[test]
fn ply_whose_vertex_count_exceeds_the_data_says_so() {
    // A 40 x 40 grid with colours, one vertex more declared than written: the faces' bytes
    // are read out of step. The message must point at the file's structure, not at a
    // garbage index as if one face were wrong.
    let n = 40u32;
    let mut faces = Vec::new();
    for y in 0..n - 1 {
        for x in 0..n - 1 {
            let a = (y * n + x) as i32;
            faces.push([a + n as i32 + 1, a + 1, a]);
            faces.push([a + n as i32, a + n as i32 + 1, a]);
        }
    }
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        n * n + 1,
        faces.len()
    )
    .into_bytes();
    for y in 0..n {
        for x in 0..n {
            for c in [x as f32 * 0.1, y as f32 * 0.1, 0.0] {
                b.extend_from_slice(&c.to_le_bytes());
            }
            b.extend_from_slice(&[200, 100, 50]);
        }
    }
    for f in &faces {
        b.push(3);
        for i in f {
            b.extend_from_slice(&i.to_le_bytes());
        }
    }
    let d = with_ply(&b);
    let err = fails(d.path(), &["."]);
    names(&err, &["mesh.ply (byte", "truncated"]);
    // An index no count can explain, in a binary file: the message says the data is
    // misaligned against the header.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    for c in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
        b.extend_from_slice(&c.to_le_bytes());
    }
    b.push(3);
    for i in [0i32, 1, -83689472] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    let d = with_ply(&b);
    let err = fails(d.path(), &["."]);
    names(
        &err,
        &[
            "mesh.ply (byte",
            "face 0",
            "-83689472 is not a vertex number",
            "header",
        ],
    );
}

#[test]
fn obj_with_a_nan_vertex_names_the_coordinate_and_the_token() {
    let d = setup();
    edit(&d.path().join("mesh.obj"), "v 0 0 1", "v 0 0 NaN");
    names(
        &fails(d.path(), &["."]),
        &["mesh.obj:4", "vertex z", "'NaN'", "not finite"],
    );
}

/// A one-triangle glTF with its positions in `b.bin`.
fn gltf_scene(bin_len: usize, declared: usize) -> tempfile::TempDir {
    let d = setup();
    std::fs::remove_file(d.path().join("mesh.obj")).unwrap();
    let mut bin = Vec::new();
    for v in [[0f32, 0., 0.], [1., 0., 0.], [0., 1., 0.]] {
        for c in v {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    bin.truncate(bin_len);
    std::fs::write(d.path().join("b.bin"), &bin).unwrap();
    let g = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"uri": "b.bin", "byteLength": declared}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}]
    });
    std::fs::write(d.path().join("mesh.gltf"), g.to_string()).unwrap();
    d
}

#[test]
fn gltf_whose_bin_is_missing_or_short_names_the_bin() {
    let d = gltf_scene(36, 36);
    std::fs::remove_file(d.path().join("b.bin")).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["mesh.gltf (buffer 0 (b.bin))", "b.bin", "No such file"],
    );
    let d = gltf_scene(20, 36);
    names(
        &fails(d.path(), &["."]),
        &[
            "mesh.gltf (buffer 0 (b.bin))",
            "holds 20 bytes",
            "declares 36",
        ],
    );
}

#[test]
fn glb_that_is_not_a_glb() {
    let d = setup();
    std::fs::remove_file(d.path().join("mesh.obj")).unwrap();
    std::fs::write(d.path().join("mesh.glb"), b"glTF\x02\0\0\0garbage").unwrap();
    names(&fails(d.path(), &["."]), &["mesh.glb"]);
}

#[test]
fn several_meshes_in_one_scene_directory() {
    let d = setup();
    std::fs::copy(d.path().join("mesh.obj"), d.path().join("other.obj")).unwrap();
    names(
        &fails(d.path(), &["."]),
        &["several mesh files", "mesh.obj", "other.obj", "--mesh"],
    );
}

#[test]
fn a_mesh_no_photograph_sees() {
    let d = setup();
    for id in 1..=2 {
        set_pose(d.path(), id, "1 0 0 0 0 0 -50");
    }
    // Observations must still lie on the image: keep the points, they are not reprojected.
    let err = texture_fails(d.path(), &["--size", "64", "--no-restore"]);
    names(&err, &["no photograph sees any vertex"]);
}

#[test]
fn an_unwritable_output_fails_before_any_work() {
    let d = setup();
    std::fs::write(d.path().join("plain"), b"x").unwrap();
    // A broken mesh too: the output is checked first, so its fault is the one named.
    std::fs::write(d.path().join("mesh.obj"), "v 0 0 nan\n").unwrap();
    let err = fails_cmd(d.path(), "texture", &[".", "-o", "plain/out", "-q"]);
    names(&err, &["plain"]);
    assert!(!err.contains("mesh.obj"), "{err}");
    let err = fails_cmd(
        d.path(),
        "texture",
        &[".", "-o", "out", "--debug-dir", "plain/dbg", "-q"],
    );
    names(&err, &["plain"]);
    assert!(!d.path().join("out").exists());
    let err = fails_cmd(d.path(), "param", &["mesh.obj", "-o", "plain/p.obj"]);
    names(&err, &["plain"]);
    let err = fails_cmd(
        d.path(),
        "inpaint",
        &["mesh.obj", "--mask", "mesh.obj", "-o", "plain/x.png"],
    );
    names(&err, &["plain"]);
    let err = fails_cmd(
        d.path(),
        "inpaint",
        &["mesh.obj", "--mask", "mesh.obj", "-o", "x.webp"],
    );
    names(&err, &["x.webp", "output format"]);
}

#[test]
fn a_second_run_into_the_same_output_is_refused() {
    let d = setup();
    // What a run in progress holds: its staging directory, locked.
    let tmp = d
        .path()
        .join("out")
        .join(scantex::io::staging::staging_name("texture"));
    std::fs::create_dir_all(&tmp).unwrap();
    let lock = std::fs::File::create(tmp.join("lock")).unwrap();
    lock.lock().unwrap();
    let before = files(d.path());
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["texture", ".", "-o", "out", "-q"])
        .current_dir(d.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    names(&err, &["out", "another scantex run"]);
    assert_eq!(files(d.path()), before);
    drop(lock);
}

#[test]
fn inpaint_inputs_that_do_not_fit() {
    let d = setup();
    image::RgbImage::new(8, 8)
        .save(d.path().join("a.png"))
        .unwrap();
    image::GrayImage::new(4, 8)
        .save(d.path().join("m.png"))
        .unwrap();
    names(
        &fails_cmd(
            d.path(),
            "inpaint",
            &["a.png", "--mask", "m.png", "-o", "o.png"],
        ),
        &["m.png", "4x8", "8x8"],
    );
    let jpg = sample_jpeg();
    std::fs::write(d.path().join("t.jpg"), &jpg[..jpg.len() / 2]).unwrap();
    names(
        &fails_cmd(
            d.path(),
            "inpaint",
            &["t.jpg", "--mask", "m.png", "-o", "o.png"],
        ),
        &["t.jpg", "truncated"],
    );
}

#[test]
fn mesh_outputs_of_an_unknown_kind() {
    let d = setup();
    names(
        &fails_cmd(d.path(), "param", &["mesh.obj", "-o", "p.gltf"]),
        &["p.gltf", "must be .obj, .ply or .glb"],
    );
}

#[test]
fn an_output_path_that_is_a_file_is_named() {
    let d = setup();
    std::fs::write(d.path().join("taken"), b"a file").unwrap();
    names(
        &fails_cmd(d.path(), "texture", &[".", "-o", "taken", "-q"]),
        &[
            "taken",
            "is a file, not a directory",
            "the output must be a directory",
        ],
    );
    names(
        &fails_cmd(d.path(), "texture", &[".", "-o", "taken/out", "-q"]),
        &["taken", "is a file", "cannot hold the output directory"],
    );
    assert_eq!(std::fs::read(d.path().join("taken")).unwrap(), b"a file");
}

/// Runs a command that clap must refuse: usage errors exit with 2 and name the option and its
/// valid range.
fn usage_fails(cmd: &str, args: &[&str], parts: &[&str]) {
    let d = setup();
    let before = files(d.path());
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .arg(cmd)
        .args(args)
        .current_dir(d.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(
        !err.contains("tip: to pass"),
        "clap took a number for a flag: {err}"
    );
    names(&err, parts);
    assert_eq!(files(d.path()), before);
}

#[test]
fn options_out_of_range_name_the_valid_range() {
    let t = |opt: &str, v: &str, range: &str| {
        usage_fails("texture", &[".", "-o", "out", opt, v], &[opt, v, range]);
    };
    t("--size", "-5", "from 16 to 32768");
    t("--size", "99999", "from 16 to 32768");
    t("--levels", "0", "from 1 to 12");
    t("--levels", "-1", "from 1 to 12");
    t("--kernel-a", "0.9", "from 0.2 to 0.5");
    t("--fine-exponent", "-1", "0 or more");
    t("--max-views", "-3", "from 0 to");
    t("--depth-resolution", "10", "from 64 to 16384");
    t("--seed", "-1", "0 or more");
    t("--weight-power", "9", "from 0 to 8");
    t("--background-threshold", "-0.1", "from 0 to 2");
    t("--gutter-fill", "-1", "from 0 to 1024");
    t("--gutter", "-4", "from 0 to 16384");
    t("--size", "big", "not a valid number");
    usage_fails(
        "texture",
        &[".", "-o", "out", "--method", "magic"],
        &["--method", "magic"],
    );
    usage_fails(
        "inpaint",
        &["a.png", "--mask", "m.png", "-o", "o.png", "--levels", "0"],
        &["--levels", "from 1 to 8"],
    );
    usage_fails(
        "uv-report",
        &["mesh.obj", "--size", "-1"],
        &["--size", "from 16 to 32768"],
    );
    usage_fails(
        "sample",
        &["-o", "s", "--photos", "0"],
        &["--photos", "from 1 to"],
    );
}

#[test]
fn option_values_the_library_refuses_name_the_option() {
    let d = setup();
    names(
        &texture_fails(d.path(), &["--background", "2,0,0"]),
        &["background colour", "[0, 1]"],
    );
    names(
        &texture_fails(d.path(), &["--texel-density", "1e12"]),
        &["--texel-density", "a chart is larger than"],
    );
    names(
        &texture_fails(d.path(), &["--keep-uvs", "--texel-density", "3"]),
        &["--texel-density", "--keep-uvs"],
    );
    // A fixed page the limit cannot hold fails before any work, with the estimate.
    names(
        &texture_fails(d.path(), &["--size", "8192", "--memory-limit", "1G"]),
        &[
            "--memory-limit",
            "would need about",
            "a 8192 page",
            "limit of 1.0 GiB",
        ],
    );
    names(
        &texture_fails(d.path(), &["--memory-limit", "20M"]),
        &["--memory-limit", "not even pages of 1024 texels fit"],
    );
    for (bad, says) in [
        ("0", "a positive size"),
        ("150%", "(0%, 100%]"),
        ("lots", "'lots' is not a memory limit"),
    ] {
        usage_fails(
            "texture",
            &[".", "-o", "out", "--memory-limit", bad],
            &["--memory-limit", says],
        );
    }
    usage_fails(
        "texture",
        &[".", "-o", "out", "--pages", "0"],
        &["--pages", "from 1 to"],
    );
    usage_fails(
        "texture",
        &[".", "-o", "out", "--background", "red"],
        &["'red' is not a number"],
    );
    usage_fails(
        "texture",
        &[".", "-o", "out", "--format", "webp"],
        &["--format", "unknown texture format 'webp'"],
    );
}

/// A reader that closes the pipe early (`scantex info --json | head -1`) ends the command
/// quietly with success, not with a panic about a broken pipe.
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["info", "--json", "samples/torus"])
        .current_dir(common::root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Closed before the scene is loaded, so the report's first write meets a closed pipe.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.code(), Some(0), "{err}");
}

/// `--help` shows the library's defaults (the command line takes them from the options'
/// `Default`, not from literals of its own), and the exit codes.
#[test]
fn help_shows_the_library_defaults_and_exit_codes() {
    let out = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["texture", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    let b = scantex::bind::BindOptions::default();
    let m = scantex::merge::MergeOptions::default();
    let r = scantex::resample::ResampleOptions::default();
    for (flag, value) in [
        (
            "--size",
            scantex::pipeline::TextureOptions::default()
                .size
                .to_string(),
        ),
        (
            "--max-size",
            scantex::pipeline::TextureOptions::default()
                .max_size
                .to_string(),
        ),
        ("--method", b.method.to_string()),
        ("--background", b.background.to_string()),
        (
            "--consistency-threshold",
            b.consistency_threshold.to_string(),
        ),
        ("--merge", m.merge.to_string()),
        ("--levels", m.levels.to_string()),
        ("--max-views", r.max_views.to_string()),
        (
            "--max-hole",
            scantex::restore::Handing::default().max_hole.to_string(),
        ),
    ] {
        let at = help
            .find(&format!("{flag} "))
            .unwrap_or_else(|| panic!("{flag} in {help}"));
        let rest = &help[at..];
        let entry = &rest[..rest[2..].find("\n      --").map_or(rest.len(), |e| e + 2)];
        assert!(
            entry.contains(&format!("[default: {value}]")),
            "{flag}: {entry}"
        );
    }
    let top = Command::new(env!("CARGO_BIN_EXE_scantex"))
        .arg("--help")
        .output()
        .unwrap();
    let top = String::from_utf8_lossy(&top.stdout);
    assert!(
        top.contains("Exit status") && top.contains("3 internal error"),
        "{top}"
    );
}
