//! Mesh readers and writers: round trips, PLY encodings and property types, glTF node
//! transforms, the real corset scan in both formats, and the Khronos validator on our GLB.

use crate::common;

use nalgebra::{Point3, Vector2};
use scantex::io::{self, EncodedTexture};
use scantex::mesh::{Mesh, TextureSource, UvMap, VertexId};
use std::path::Path;

/// A cube with a UV seam: 8 vertices, 12 triangles, 14 UVs (a cross layout).
fn cube() -> Mesh {
    let p = |x, y, z| Point3::new(x, y, z);
    let positions = vec![
        p(0.0, 0.0, 0.0),
        p(1.0, 0.0, 0.0),
        p(1.0, 1.0, 0.0),
        p(0.0, 1.0, 0.0),
        p(0.0, 0.0, 1.0),
        p(1.0, 0.0, 1.0),
        p(1.0, 1.0, 1.0),
        p(0.0, 1.0, 1.0 + 1e-13),
    ];
    let quads = [
        [0, 3, 2, 1],
        [4, 5, 6, 7],
        [0, 1, 5, 4],
        [2, 3, 7, 6],
        [1, 2, 6, 5],
        [0, 4, 7, 3],
    ];
    let mut faces = Vec::new();
    let mut uv_faces = Vec::new();
    let mut coords = Vec::new();
    for (q, quad) in quads.iter().enumerate() {
        let base = coords.len() as u32;
        let (u0, v0) = ((q % 3) as f32 / 3.0, (q / 3) as f32 / 2.0);
        for (du, dv) in [(0.0, 0.0), (0.3, 0.0), (0.3, 0.45), (0.0, 0.45)] {
            coords.push(Vector2::new(u0 + du, v0 + dv));
        }
        faces.push([quad[0], quad[1], quad[2]].map(VertexId));
        faces.push([quad[0], quad[2], quad[3]].map(VertexId));
        uv_faces.push([base, base + 1, base + 2]);
        uv_faces.push([base, base + 2, base + 3]);
    }
    Mesh {
        positions,
        faces,
        uv: Some(UvMap {
            coords,
            faces: uv_faces,
        }),
        ..Default::default()
    }
}

fn png_texture() -> EncodedTexture {
    let img = image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([x as u8 * 30, y as u8 * 30, 128]));
    io::image::encode_png(&image::DynamicImage::ImageRgb8(img)).unwrap()
}

/// Per-corner UVs of face `f` (so meshes that store UVs differently compare equal).
fn corner_uvs(m: &Mesh, f: usize) -> [Vector2<f32>; 3] {
    let uv = m.uv.as_ref().unwrap();
    uv.faces[f].map(|t| uv.coords[t as usize])
}

#[test]
fn obj_round_trip_keeps_positions_faces_uvs_and_texture() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let path = dir.path().join("cube.obj");
    io::write_mesh(&path, &m, Some(&png_texture())).unwrap();
    assert!(dir.path().join("cube.mtl").is_file() && dir.path().join("cube.png").is_file());
    let (r, report) = io::read_mesh(&path).unwrap();
    assert_eq!(report.degenerate_faces, 0);
    assert_eq!(r.positions, m.positions, "positions must be bit-exact");
    assert_eq!(r.faces, m.faces);
    for f in 0..m.faces.len() {
        assert_eq!(corner_uvs(&r, f), corner_uvs(&m, f));
    }
    assert_eq!(
        r.texture,
        Some(TextureSource::File(dir.path().join("cube.png")))
    );
    // No temporary files left behind.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.contains(".tmp")), "{names:?}");
}

#[test]
fn ply_round_trip_keeps_positions_faces_uvs_normals_colours() {
    let dir = tempfile::tempdir().unwrap();
    let mut m = cube();
    m.normals = Some(m.vertex_normals().iter().map(|n| n.cast()).collect());
    m.colors = Some((0..8).map(|i| [i as f32 / 7.0, 0.5, 1.0]).collect());
    let path = dir.path().join("cube.ply");
    io::write_mesh(&path, &m, None).unwrap();
    let (r, _) = io::read_mesh(&path).unwrap();
    assert_eq!(r.positions, m.positions);
    assert_eq!(r.faces, m.faces);
    for f in 0..m.faces.len() {
        assert_eq!(corner_uvs(&r, f), corner_uvs(&m, f));
    }
    let (rn, mn) = (r.normals.unwrap(), m.normals.unwrap());
    assert!(rn.iter().zip(&mn).all(|(a, b)| (a - b).norm() < 1e-6));
    let rc = r.colors.unwrap();
    assert!(rc
        .iter()
        .zip(m.colors.unwrap())
        .all(|(a, b)| (0..3).all(|k| (a[k] - b[k]).abs() <= 0.51 / 255.0)));
}

#[test]
fn ply_ascii_with_quads_uchar_colours_texcoords_and_extra_elements() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("quad.ply");
    std::fs::write(&path, "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nelement vertex 5\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nproperty uchar red\r\nproperty uchar green\r\nproperty uchar blue\r\nproperty float s\r\nproperty float t\r\nelement face 2\r\nproperty list uchar uint vertex_indices\r\nelement edge 1\r\nproperty int vertex1\r\nproperty int vertex2\r\nend_header\r\n0 0 0 255 0 0 0 0\r\n1 0 0 0 255 0 1 0\r\n1 1 0 0 0 255 1 1\r\n0 1 0 255 255 255 0 1\r\n0.5 0.5 1 0 0 0 0.5 0.5\r\n4 0 1 2 3\r\n3 0 1 4\r\n0 1\r\n").unwrap();
    let (m, report) = io::read_mesh(&path).unwrap();
    assert_eq!((m.num_vertices(), m.num_faces()), (5, 3));
    assert_eq!(report.polygons_triangulated, 1);
    assert_eq!(m.colors.as_ref().unwrap()[1], [0.0, 1.0, 0.0]);
    assert_eq!(corner_uvs(&m, 0)[2], Vector2::new(1.0, 1.0));
}

/// Encodes a small mesh as binary PLY in either byte order with the given scalar types.
fn binary_ply(big_endian: bool, pos_double: bool, count_ty: &str, index_ty: &str) -> Vec<u8> {
    let pt = if pos_double { "double" } else { "float" };
    let fmt = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut b = format!("ply\nformat {fmt} 1.0\nelement vertex 4\nproperty {pt} x\nproperty {pt} y\nproperty {pt} z\nproperty float nx\nproperty float ny\nproperty float nz\nelement face 1\nproperty list {count_ty} {index_ty} vertex_indices\nend_header\n").into_bytes();
    let put = |b: &mut Vec<u8>, le: Vec<u8>| {
        let mut v = le;
        if big_endian {
            v.reverse();
        }
        b.extend(v);
    };
    for (x, y) in [(0.0, 0.0), (2.0, 0.0), (2.0, 3.0), (0.0, 3.0)] {
        for c in [x, y, 0.25f64] {
            put(
                &mut b,
                if pos_double {
                    c.to_le_bytes().to_vec()
                } else {
                    (c as f32).to_le_bytes().to_vec()
                },
            );
        }
        for c in [0.0f32, 0.0, 1.0] {
            put(&mut b, c.to_le_bytes().to_vec());
        }
    }
    let int = |ty: &str, v: u32| -> Vec<u8> {
        match ty {
            "uchar" | "char" => vec![v as u8],
            "ushort" | "short" => (v as u16).to_le_bytes().to_vec(),
            _ => v.to_le_bytes().to_vec(),
        }
    };
    put(&mut b, int(count_ty, 4));
    for i in 0..4 {
        put(&mut b, int(index_ty, i));
    }
    b
}

#[test]
fn ply_binary_both_endians_all_index_types() {
    for be in [false, true] {
        for dbl in [false, true] {
            for (ct, it) in [
                ("uchar", "int"),
                ("uchar", "uint"),
                ("ushort", "ushort"),
                ("int", "int"),
                ("char", "uchar"),
                ("uint", "short"),
            ] {
                let data = binary_ply(be, dbl, ct, it);
                let (m, rep) = io::ply::parse(Path::new("t.ply"), &data)
                    .unwrap_or_else(|e| panic!("{be} {dbl} {ct} {it}: {e}"));
                assert_eq!(
                    m.positions[2],
                    Point3::new(2.0, 3.0, 0.25),
                    "{be} {dbl} {ct} {it}"
                );
                assert_eq!(m.faces.len(), 2);
                assert_eq!(rep.polygons_triangulated, 1);
                assert_eq!(m.normals.as_ref().unwrap()[3].z, 1.0);
            }
        }
    }
}

#[test]
fn glb_round_trip_and_embedded_texture() {
    let dir = tempfile::tempdir().unwrap();
    let m = cube();
    let tex = png_texture();
    let path = dir.path().join("cube.glb");
    io::write_mesh(&path, &m, Some(&tex)).unwrap();
    let (r, _) = io::read_mesh(&path).unwrap();
    assert_eq!(r.faces.len(), m.faces.len());
    // Seams split vertices: 24 (position, uv) pairs.
    assert_eq!(r.num_vertices(), 24);
    for f in 0..m.faces.len() {
        let a = m.triangle(scantex::mesh::FaceId(f as u32));
        let b = r.triangle(scantex::mesh::FaceId(f as u32));
        for k in 0..3 {
            assert!((a[k] - b[k]).norm() < 1e-6, "positions are stored as f32");
            assert!((corner_uvs(&r, f)[k] - corner_uvs(&m, f)[k]).norm() < 1e-6);
        }
    }
    assert_eq!(r.texture, Some(TextureSource::Embedded(tex.bytes)));
}

#[test]
fn gltf_node_transforms_are_applied() {
    let dir = tempfile::tempdir().unwrap();
    // One triangle under a parent node (translate +10 x) and a child (scale 2, rotate 90 deg
    // about z): (1,0,0) -> scaled (2,0,0) -> rotated (0,2,0) -> translated (10,2,0).
    let mut bin = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend(v.to_le_bytes());
    }
    std::fs::write(dir.path().join("tri.bin"), &bin).unwrap();
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let gltf = serde_json::json!({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"translation": [10.0, 0.0, 0.0], "children": [1]},
                  {"mesh": 0, "scale": [2.0, 2.0, 2.0], "rotation": [0.0, 0.0, s, s]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "buffers": [{"uri": "tri.bin", "byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]}]
    });
    let path = dir.path().join("tri.gltf");
    std::fs::write(&path, serde_json::to_string(&gltf).unwrap()).unwrap();
    let (m, _) = io::read_mesh(&path).unwrap();
    let want = [
        Point3::new(10.0, 0.0, 0.0),
        Point3::new(10.0, 2.0, 0.0),
        Point3::new(8.0, 0.0, 0.0),
    ];
    for (p, w) in m.positions.iter().zip(want) {
        assert!((p - w).norm() < 1e-6, "{p} vs {w}");
    }
}

#[test]
fn corset_gltf_and_obj_describe_the_same_scan() {
    let Some(dir) = common::shared_data("scans/corset") else {
        return;
    };
    let (g, _) = io::read_mesh(&dir.join("Corset.gltf")).unwrap();
    let (o, _) = io::read_mesh(&dir.join("Corset.obj")).unwrap();
    assert_eq!((g.num_vertices(), g.num_faces()), (11505, 18324));
    assert_eq!(o.num_faces(), 18324);
    // The glTF node rotates 180 deg about y; the OBJ was exported with it applied, so reading
    // the glTF with its node transform must give the OBJ's positions.
    for f in (0..g.num_faces()).step_by(97) {
        let (tg, to) = (
            g.triangle(scantex::mesh::FaceId(f as u32)),
            o.triangle(scantex::mesh::FaceId(f as u32)),
        );
        for k in 0..3 {
            assert!(
                (tg[k] - to[k]).norm() < 1e-6,
                "face {f}: {} vs {}",
                tg[k],
                to[k]
            );
            // v is flipped in the OBJ; both read into the same (OBJ) convention.
            assert!(
                (corner_uvs(&g, f)[k] - corner_uvs(&o, f)[k]).norm() < 1e-5,
                "face {f} uv"
            );
        }
    }
    // The colour texture: base colour is named but not shipped, the spec-gloss diffuse is.
    assert_eq!(
        g.texture,
        Some(TextureSource::File(dir.join("Corset_diffuse.png")))
    );
    assert_eq!(
        o.texture,
        Some(TextureSource::File(dir.join("Corset_diffuse.png")))
    );
}

/// Runs the Khronos glTF validator (npm `gltf-validator`, pinned) on `glb`; installs it under
/// `target/npm` on first use, as the README says. npm's registry is reachable on every machine
/// of this project, so a failed install is a failed test, with npm's own words: the check never
/// passes by skipping.
pub(crate) fn khronos_validate(glb: &Path) -> serde_json::Value {
    let root = common::root();
    let prefix = root.join("target").join("npm");
    if !prefix.join("node_modules/gltf-validator").is_dir() {
        let out = std::process::Command::new("npm")
            .args(["install", "--no-audit", "--no-fund", "--prefix"])
            .arg(&prefix)
            .arg("gltf-validator@2.0.0-dev.3.10")
            .output()
            .unwrap_or_else(|e| panic!("cannot run npm to install gltf-validator: {e}"));
        assert!(
            out.status.success(),
            "npm install gltf-validator failed: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let out = std::process::Command::new("node")
        .arg(root.join("tests/gltf_validate.js"))
        .arg(glb)
        .env("NODE_PATH", prefix.join("node_modules"))
        .output()
        .unwrap_or_else(|e| panic!("cannot run node for the glTF validator: {e}"));
    assert!(
        out.status.success(),
        "validator failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn glb_passes_the_khronos_validator() {
    let dir = tempfile::tempdir().unwrap();
    let mut meshes = vec![("cube", cube(), Some(png_texture()))];
    let mut untextured = cube();
    untextured.uv = None;
    meshes.push(("untextured", untextured, None));
    if let Some(d) = common::shared_data("scans/corset") {
        let (m, _) = io::read_mesh(&d.join("Corset.obj")).unwrap();
        let tex = EncodedTexture {
            bytes: std::fs::read(d.join("Corset_diffuse.png")).unwrap(),
            mime: "image/png",
        };
        meshes.push(("corset", m, Some(tex)));
    }
    for (name, m, tex) in meshes {
        let path = dir.path().join(format!("{name}.glb"));
        io::write_mesh(&path, &m, tex.as_ref()).unwrap();
        let report = khronos_validate(&path);
        assert_eq!(report["errors"], 0, "{name}: {report}");
        assert_eq!(report["warnings"], 0, "{name}: {report}");
    }
}

/// Found by fuzzing: an element with no properties and a huge count spun for ever.
#[test]
fn fuzz_ply_zero_property_element_with_huge_count() {
    let data = b"ply\nformat binary_little_endian 1.0\nelement junk 1000000000000000000\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
    let started = std::time::Instant::now();
    let r = io::ply::parse(Path::new("hang.ply"), data);
    assert!(r.is_ok_and(|(m, _)| m.positions.is_empty()));
    // Not a timing target: a regression back to the loop would take years, not seconds.
    assert!(started.elapsed().as_secs() < 60);
}

/// Found by fuzzing (fuzz/run.sh gltf): a primitive whose POSITION names an accessor the file
/// does not have made the gltf crate's own validation index out of bounds (a panic, caught,
/// but printed with a backtrace and reported as a buffer overrun). It is an error naming the
/// primitive, with no panic.
#[test]
fn fuzz_gltf_dangling_position_accessor() {
    let doc = br#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}]}"#;
    let err = io::gltf::parse(Path::new("dangling.gltf"), doc)
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("dangling.gltf (mesh 0 primitive 0)") && err.contains("accessor 0"),
        "{err}"
    );
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("dangling.gltf");
    std::fs::write(&p, doc).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["info", "--mesh"])
        .arg(&p)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Found by fuzzing (fuzz/run.sh gltf, second run): a GLB header whose length field is below
/// the header's own 12 bytes made the gltf crate subtract with overflow (a panic in builds
/// with overflow checks, such as the tests'). It is an error naming the byte.
#[test]
fn fuzz_glb_length_shorter_than_its_header() {
    let mut glb = b"glTF".to_vec();
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&4u32.to_le_bytes());
    glb.extend_from_slice(b"\x10\0\0\0JSON{}              ");
    let err = io::gltf::parse(Path::new("short.glb"), &glb)
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("short.glb (byte 8)") && err.contains("declares 4 bytes"),
        "{err}"
    );
}

/// Found by fuzzing (fuzz/run.sh gltf, third run): a NORMAL accessor of VEC2 was read as VEC3
/// (the gltf crate only debug-asserts the size). Every attribute the reader takes must have
/// the format glTF requires, or the file is refused naming the primitive.
#[test]
fn fuzz_gltf_normals_of_the_wrong_type() {
    let doc = br#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0,"NORMAL":1}}]}],
        "buffers":[{"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAAAACAPwAAAAAAAAAAAAAAAAAAgD8AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA","byteLength":60}],
        "bufferViews":[{"buffer":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":24}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
                     {"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}]}"#;
    let err = io::gltf::parse(Path::new("normals.gltf"), doc)
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("normals.gltf (mesh 0 primitive 0)")
            && err.contains("Normals accessor 1")
            && err.contains("VEC3 of F32"),
        "{err}"
    );
}

/// Found by fuzzing (fuzz/run.sh gltf, fourth run): an accessor with count 0 made the gltf
/// crate compute `count - 1` with overflow. glTF requires at least one element.
#[test]
fn fuzz_gltf_accessor_with_no_elements() {
    let doc = br#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
        "buffers":[{"uri":"data:application/octet-stream;base64,AAAAAAAAAAAAAAAA","byteLength":12}],
        "bufferViews":[{"buffer":0,"byteLength":12}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":0,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}]}"#;
    let err = io::gltf::parse(Path::new("empty.gltf"), doc)
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("empty.gltf (mesh 0 primitive 0)") && err.contains("at least one element"),
        "{err}"
    );
}

/// Fifth gltf fuzz finding: a relative buffer URI whose percent escape (`%AA`) is not UTF-8 made
/// the `gltf` crate panic while decoding it.
#[test]
fn fuzz_gltf_buffer_uri_that_is_not_utf8() {
    let doc = std::fs::read("fuzz/regressions/gltf/crash-de1c8c1206803213be414bac76dca1359d5e0d9c")
        .expect("regression input is committed");
    let err = io::gltf::parse(Path::new("escape.gltf"), &doc)
        .expect_err("refused")
        .to_string();
    assert!(
        err.contains("escape.gltf (buffer 0)") && err.contains("not UTF-8"),
        "{err}"
    );
}
