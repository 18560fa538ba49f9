//! Renderer, held-out evaluation and the bundled sample: the sample's truth re-rendered
//! reproduces its photographs; eval ranks truth above grey and above a shifted texture;
//! distortion bends straight lines exactly as the camera model predicts.

use crate::common;

use image::GrayImage;
use nalgebra::{Point2, Point3, Vector2};
use scantex::camera::{Camera, CameraModel, Pose, PosedCamera};
use scantex::eval::{compare, evaluate, EvalOptions};
use scantex::mesh::{Mesh, VertexId};
use scantex::render::{load_textured, read_lighting, render, RayMesh, RenderOptions, Shading};
use scantex::scene::{Scene, SceneSpec};
use std::path::Path;

fn sample() -> std::path::PathBuf {
    common::root().join("samples/torus")
}

/// Renders `truth` through every photo of `scene_dir` with the scene's own lighting and returns
/// the PSNR inside each photo's mask.
fn reproduce(truth: &Path, scene_dir: &Path, lighting: &Path) -> Vec<(String, f64)> {
    let (mesh, tex) = load_textured(truth).unwrap();
    let rm = RayMesh::new(&mesh);
    let lights = read_lighting(lighting).unwrap();
    let scene = Scene::load(&SceneSpec {
        dir: Some(scene_dir.into()),
        ..Default::default()
    })
    .unwrap();
    assert!(!scene.photos.is_empty());
    scene
        .photos
        .iter()
        .map(|p| {
            let opts = RenderOptions {
                shading: Shading::Lambert,
                lighting: lights[&p.name],
                ..Default::default()
            };
            let r = render(&rm, tex.as_ref(), &p.view, &opts);
            let mask = p.load_mask().unwrap().expect("sample photos have masks");
            let s = compare(
                &p.name,
                &r.color,
                &p.load().unwrap(),
                &mask,
                &mask,
                &mask,
                &EvalOptions::default(),
            );
            (p.name.clone(), s.psnr)
        })
        .collect()
}

#[test]
fn sample_truth_rerendered_reproduces_the_photos() {
    let s = sample();
    for (name, psnr) in reproduce(
        &s.join("truth/model.glb"),
        &s,
        &s.join("truth/lighting.json"),
    ) {
        eprintln!("{name}: {psnr:.2} dB");
        assert!(psnr >= 40.0, "{name}: {psnr:.2} dB");
    }
}

#[test]
fn sample_matches_its_specification() {
    let s = sample();
    let scene = Scene::load(&SceneSpec {
        dir: Some(s.clone()),
        ..Default::default()
    })
    .unwrap();
    let (mesh, _) = scene.mesh.as_ref().unwrap();
    let topo = mesh.topology();
    assert!((20_000..=60_000).contains(&mesh.num_faces()));
    // Closed, one component, genus 1 (a handle): Euler characteristic 0.
    assert_eq!(
        (
            topo.boundary_loops,
            topo.components,
            topo.euler_characteristic
        ),
        (0, 1, 0)
    );
    assert!(mesh.uv.is_none(), "the input mesh is bare");
    assert!((12..=24).contains(&scene.photos.len()));
    for p in &scene.photos {
        assert_eq!((p.view.camera.width, p.view.camera.height), (800, 600));
        assert_eq!(p.view.camera.model, CameraModel::SimpleRadial);
        assert!(p.mask.is_some());
    }
    // Exposure and white balance vary by up to +-25%.
    let l = read_lighting(&s.join("truth/lighting.json")).unwrap();
    let ex: Vec<f32> = l.values().map(|v| v.exposure).collect();
    let spread =
        ex.iter().cloned().fold(f32::MIN, f32::max) - ex.iter().cloned().fold(f32::MAX, f32::min);
    assert!(
        spread > 0.25 && ex.iter().all(|e| (0.75..=1.25).contains(e)),
        "{ex:?}"
    );
    // A region no photograph sees: vertices whose normal points down are never front-facing.
    let normals = mesh.vertex_normals();
    let unseen = (0..mesh.num_vertices())
        .filter(|&v| {
            scene
                .photos
                .iter()
                .all(|p| (p.view.pose.center() - mesh.positions[v]).dot(&normals[v]) <= 0.0)
        })
        .count();
    assert!(
        unseen as f64 > 0.1 * mesh.num_vertices() as f64,
        "unseen vertices: {unseen}"
    );
    assert_eq!(
        Scene::load(&SceneSpec {
            dir: Some(s.join("heldout")),
            ..Default::default()
        })
        .unwrap()
        .photos
        .len(),
        4
    );
    // The whole sample stays under 6 MB.
    let size: u64 = walk(&s)
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .sum();
    assert!(size < 6_000_000, "{size} bytes");
}

fn walk(d: &Path) -> Vec<std::path::PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(d).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            v.extend(walk(&p))
        } else {
            v.push(p)
        }
    }
    v
}

#[test]
fn eval_ranks_truth_above_grey_and_above_a_shifted_texture() {
    let s = sample();
    let held = Scene::load(&SceneSpec {
        dir: Some(s.join("heldout")),
        ..Default::default()
    })
    .unwrap();
    let (mesh, tex) = load_textured(&s.join("truth/model.glb")).unwrap();
    let fit = EvalOptions { gain_fit: true };
    let truth = evaluate(&RayMesh::new(&mesh), tex.as_ref(), &held.photos, &fit)
        .unwrap()
        .mean
        .unwrap();
    assert!(truth.psnr > 30.0, "truth PSNR {:.2}", truth.psnr);
    assert!(truth.completeness > 0.99);
    // Uniform grey: no texture.
    let mut grey = mesh.clone();
    grey.uv = None;
    let g = evaluate(&RayMesh::new(&grey), None, &held.photos, &fit)
        .unwrap()
        .mean
        .unwrap();
    assert!(
        g.one_minus_ncc > 10.0 * truth.one_minus_ncc,
        "grey {:.4} vs truth {:.4}",
        g.one_minus_ncc,
        truth.one_minus_ncc
    );
    assert!(g.completeness < 0.01);
    // The texture shifted by 2 texels (the truth texture is 1024 wide).
    let mut shifted = mesh.clone();
    for c in &mut shifted.uv.as_mut().unwrap().coords {
        *c += Vector2::new(2.0 / 1024.0, 0.0);
    }
    let sh = evaluate(&RayMesh::new(&shifted), tex.as_ref(), &held.photos, &fit)
        .unwrap()
        .mean
        .unwrap();
    eprintln!("truth {truth:?}\nshifted {sh:?}\ngrey {g:?}");
    assert!(
        sh.psnr < truth.psnr - 3.0,
        "shifted {:.2} vs truth {:.2}",
        sh.psnr,
        truth.psnr
    );
    assert!(sh.one_minus_ncc > 1.5 * truth.one_minus_ncc);
}

#[test]
fn distortion_bends_straight_lines_as_the_model_predicts() {
    // A thin horizontal rod in front of a camera with strong barrel distortion.
    let cam = Camera::new(
        1,
        CameraModel::Opencv,
        640,
        480,
        vec![400.0, 400.0, 320.0, 240.0, -0.35, 0.08, 0.0, 0.0],
    )
    .unwrap();
    let view = PosedCamera {
        camera: cam.clone(),
        pose: Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
    };
    let (y0, z, half) = (1.6, 4.0, 0.01);
    let rod = Mesh {
        positions: vec![
            Point3::new(-6.0, y0 - half, z),
            Point3::new(6.0, y0 - half, z),
            Point3::new(6.0, y0 + half, z),
            Point3::new(-6.0, y0 + half, z),
        ],
        faces: vec![[0, 1, 2].map(VertexId), [0, 2, 3].map(VertexId)],
        ..Default::default()
    };
    let r = render(&RayMesh::new(&rod), None, &view, &RenderOptions::default());
    let mut checked = 0;
    let mut bend = (f64::MAX, f64::MIN);
    for i in 0..=40 {
        let x = -3.0 + 6.0 * i as f64 / 40.0;
        let px = view.project(&Point3::new(x, y0, z)).unwrap();
        let col = px.x.floor() as u32;
        if !(2..638).contains(&col) {
            continue;
        }
        // Coverage centroid of the rod in this column.
        let rows: Vec<u32> = (0..480)
            .filter(|&y| r.coverage.get_pixel(col, y)[0] > 0)
            .collect();
        assert!(!rows.is_empty(), "rod not rendered in column {col}");
        let centroid = rows.iter().map(|&y| y as f64 + 0.5).sum::<f64>() / rows.len() as f64;
        // The model's prediction for the rod's centre line in that column.
        let pred = view.project(&Point3::new(x, y0, z)).unwrap().y;
        assert!(
            (centroid - pred).abs() < 1.0,
            "column {col}: rendered {centroid:.2}, model {pred:.2}"
        );
        bend = (bend.0.min(pred), bend.1.max(pred));
        checked += 1;
    }
    assert!(checked > 20);
    // The pinhole image of the rod is a straight row (y = 240 + 400 * 0.4 = 400); the
    // distorted one curves by tens of pixels.
    assert!(
        bend.1 - bend.0 > 20.0,
        "curvature {:.1} px",
        bend.1 - bend.0
    );
    let _ = Point2::new(0.0, 0.0);
}

#[test]
fn generator_photographs_any_textured_mesh() {
    let Some(corset) = common::shared_data("scans/corset/Corset.gltf") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let opts = scantex::sample::SampleOptions {
        photos: 6,
        heldout: 2,
        up: nalgebra::Vector3::y(),
        ..Default::default()
    };
    scantex::sample::generate_to(Some(&corset), &opts, dir.path()).unwrap();
    let scene = Scene::load(&SceneSpec {
        dir: Some(dir.path().into()),
        ..Default::default()
    })
    .unwrap();
    let (bare, _) = scene.mesh.as_ref().unwrap();
    assert_eq!(bare.num_faces(), 18324);
    assert!(bare.uv.is_none() && bare.texture.is_none());
    scene.check_photos().unwrap();
    let psnr = reproduce(
        &dir.path().join("truth/model.glb"),
        dir.path(),
        &dir.path().join("truth/lighting.json"),
    );
    assert_eq!(psnr.len(), 6);
    for (name, p) in psnr {
        assert!(p >= 38.0, "{name}: {p:.2} dB");
    }
    // Same seed, same bytes.
    let again = tempfile::tempdir().unwrap();
    scantex::sample::generate_to(Some(&corset), &opts, again.path()).unwrap();
    for f in [
        "images/view_01.jpg",
        "sparse/0/images.txt",
        "truth/model.glb",
        "mesh.ply",
    ] {
        assert!(
            std::fs::read(dir.path().join(f)).unwrap()
                == std::fs::read(again.path().join(f)).unwrap(),
            "{f} differs"
        );
    }
}

#[test]
fn coverage_mask_marks_exactly_the_object() {
    let s = sample();
    let scene = Scene::load(&SceneSpec {
        dir: Some(s.clone()),
        ..Default::default()
    })
    .unwrap();
    let (mesh, tex) = load_textured(&s.join("truth/model.glb")).unwrap();
    let p = &scene.photos[0];
    let r = render(
        &RayMesh::new(&mesh),
        tex.as_ref(),
        &p.view,
        &RenderOptions::default(),
    );
    let mask: GrayImage = p.load_mask().unwrap().unwrap();
    let differ = r
        .coverage
        .pixels()
        .zip(mask.pixels())
        .filter(|(a, b)| a[0] != b[0])
        .count();
    assert_eq!(differ, 0);
}

#[test]
fn cli_render_and_eval_write_what_they_promise() {
    let s = sample();
    let out = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_scantex"))
            .args(args)
            .output()
            .unwrap()
    };
    let o = run(&[
        "render",
        "--mesh",
        s.join("truth/model.glb").to_str().unwrap(),
        s.join("heldout").to_str().unwrap(),
        "-o",
        out.path().to_str().unwrap(),
        "--lambert",
        "--light",
        "0,0,1",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for i in 1..=4 {
        let name = format!("heldout_{i:02}.png");
        let img = image::open(out.path().join(&name)).unwrap();
        assert_eq!((img.width(), img.height()), (800, 600));
        assert!(out.path().join("masks").join(&name).is_file());
    }
    let json = out.path().join("eval.json");
    let o = run(&[
        "eval",
        "--mesh",
        s.join("truth/model.glb").to_str().unwrap(),
        s.join("heldout").to_str().unwrap(),
        "--gain-fit",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let table = String::from_utf8_lossy(&o.stdout);
    assert_eq!(table.lines().count(), 6, "{table}");
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(r["images"].as_array().unwrap().len(), 4);
    assert!(r["mean"]["psnr"].as_f64().unwrap() > 40.0);
    // A bad argument is an error, not a panic, and writes nothing.
    let empty = tempfile::tempdir().unwrap();
    let o = run(&[
        "render",
        "--mesh",
        "nope.glb",
        s.to_str().unwrap(),
        "-o",
        empty.path().join("x").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope.glb"));
    assert!(!empty.path().join("x").exists());
    let o = run(&[
        "render",
        "--mesh",
        "a.glb",
        s.to_str().unwrap(),
        "-o",
        "x",
        "--light",
        "1,2",
    ]);
    assert!(!o.status.success() && String::from_utf8_lossy(&o.stderr).contains("three numbers"));
}

/// `sample --gain-range` outside [0, 0.9] is refused with a message naming it, and writes
/// nothing.
#[test]
fn sample_refuses_a_bad_gain_range() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_scantex"))
        .args(["sample", "--gain-range", "1.5", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    // A usage error (exit 2) that gives the valid range.
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--gain-range") && err.contains("1.5") && err.contains("from 0 to 0.9"),
        "{err}"
    );
    assert!(!out.join("images").exists());
}
