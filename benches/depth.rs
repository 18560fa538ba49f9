//! Depth maps alone: times `DepthMap::render_projected` (binding's occlusion map) and its
//! erosion (the merge's) for every photograph of a scene, as the texturing run makes them.
//! Prints the seconds per photograph and a hash of the maps (to check that a change keeps
//! them). Run with:
//!
//!     cargo bench --bench depth -- <scene> [max side, default 2048]
//!
//! The 1.5M-face scene: `python3 benches/scale_curve.py --exact <work> 1500000:50`, then this
//! on `<work>/scene1500000_50_exact`.

use scantex::depth::{project_vertices, DepthMap};
use scantex::scene::{Scene, SceneSpec};
use std::hash::{Hash, Hasher};
use std::path::PathBuf;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let Some(dir) = args.first() else {
        eprintln!("usage: cargo bench --bench depth -- <scene> [max side]");
        std::process::exit(2);
    };
    let side: u32 = args
        .get(1)
        .map_or(2048, |s| s.parse().expect("a side in pixels"));
    let scene = Scene::load(&SceneSpec {
        dir: Some(PathBuf::from(dir)),
        ..Default::default()
    })
    .unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    });
    let Some((mesh, _)) = &scene.mesh else {
        eprintln!("{dir} has no mesh");
        std::process::exit(1)
    };
    let (mut render, mut erode) = (0.0, 0.0);
    let mut hash = std::collections::hash_map::DefaultHasher::new();
    for p in &scene.photos {
        let projected = project_vertices(mesh, &p.view);
        let t = Instant::now();
        let d = DepthMap::render_projected(mesh, &p.view, &projected, side);
        render += t.elapsed().as_secs_f64();
        let t = Instant::now();
        let e = d.eroded(1);
        erode += t.elapsed().as_secs_f64();
        for m in [&d, &e] {
            m.z.iter().for_each(|v| v.to_bits().hash(&mut hash));
        }
    }
    let n = scene.photos.len().max(1) as f64;
    println!(
        "{} faces, {} photographs at {side}: render {:.1} ms, erode {:.1} ms per photograph, hash {:016x}",
        mesh.num_faces(),
        scene.photos.len(),
        1e3 * render / n,
        1e3 * erode / n,
        hash.finish()
    );
}
