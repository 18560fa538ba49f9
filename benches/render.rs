//! Render-time benchmark: the bundled sample (all 16 views, 800x600) and a 1M-triangle mesh at
//! 12 MP (4000x3000). Prints a table; run with:
//!
//!     cargo bench --bench render

use scantex::camera::{Camera, CameraModel, PosedCamera};
use scantex::render::{load_textured, render, RayMesh, RenderOptions, Texture};
use scantex::scene::{Scene, SceneSpec};
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let s = root.join("samples/torus");
    let (mesh, tex) = load_textured(&s.join("truth/model.glb")).unwrap();
    let scene = Scene::load(&SceneSpec {
        dir: Some(s),
        ..Default::default()
    })
    .unwrap();
    let t = Instant::now();
    let rm = RayMesh::new(&mesh);
    let bvh_sample = t.elapsed().as_secs_f64();
    let t = Instant::now();
    for p in &scene.photos {
        std::hint::black_box(render(
            &rm,
            tex.as_ref(),
            &p.view,
            &RenderOptions::default(),
        ));
    }
    let sample_all = t.elapsed().as_secs_f64();

    let (big, big_tex) = scantex::sample::dented_torus(1000, 500, (2048, 1024));
    let big_tex = Texture::new(&big_tex);
    let t = Instant::now();
    let rm_big = RayMesh::new(&big);
    let bvh_big = t.elapsed().as_secs_f64();
    let p0 = &scene.photos[0].view;
    // The sample's first viewpoint, scaled to 4000x3000 (same field of view).
    let s5 = 5.0;
    let prm = &p0.camera.params;
    let cam = Camera::new(
        1,
        CameraModel::SimpleRadial,
        4000,
        3000,
        vec![prm[0] * s5, prm[1] * s5, prm[2] * s5, prm[3]],
    )
    .unwrap();
    let view = PosedCamera {
        camera: cam,
        pose: p0.pose,
    };
    let t = Instant::now();
    let r = render(&rm_big, Some(&big_tex), &view, &RenderOptions::default());
    let big_time = t.elapsed().as_secs_f64();
    let covered = r.coverage.pixels().filter(|p| p[0] > 0).count();
    println!("| what | size | BVH build (s) | render (s) |");
    println!("|---|---|---:|---:|");
    println!(
        "| sample, all {} views | {} triangles, 800x600 each | {:.3} | {:.2} |",
        scene.photos.len(),
        mesh.num_faces(),
        bvh_sample,
        sample_all
    );
    println!("| dented torus, 1 view | {} triangles, 4000x3000 ({:.1}M pixels on the object) | {:.2} | {:.2} |", big.num_faces(), covered as f64 / 1e6, bvh_big, big_time);
    println!("threads: {}", rayon::current_num_threads());
}
