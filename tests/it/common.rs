//! Helpers shared by the integration tests.

use std::path::{Path, PathBuf};

/// The project root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A path under `../shared/data`. When it is missing: panics under CI (`CI=true`), so the
/// real-data checks cannot silently vanish there; elsewhere prints why and returns `None`.
pub fn shared_data(rel: &str) -> Option<PathBuf> {
    let p = root().join("..").join("shared").join("data").join(rel);
    if p.exists() {
        return Some(p);
    }
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!(
            "real data {} is missing and CI=true: the check cannot be skipped",
            p.display()
        );
    }
    eprintln!("skipping: real data {} is missing", p.display());
    None
}

/// Reads a committed JSON reference file under `calib/`.
pub fn calib_json(rel: &str) -> serde_json::Value {
    let p = root().join("calib").join(rel);
    let s = std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_str(&s).unwrap()
}

/// `v` as a vector of f64 (a JSON array of numbers).
pub fn f64s(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

/// `v` as rows of f64 (a JSON array of arrays).
pub fn rows(v: &serde_json::Value) -> Vec<Vec<f64>> {
    v.as_array().unwrap().iter().map(f64s).collect()
}

/// Copies `src` into `dst`, subdirectories included.
pub fn copy_dir(src: &Path, dst: &Path) {
    std::fs::create_dir_all(dst).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        if e.path().is_file() {
            std::fs::copy(e.path(), dst.join(e.file_name())).unwrap();
        } else if e.path().is_dir() {
            copy_dir(&e.path(), &dst.join(e.file_name()));
        }
    }
}

/// Textures the scene directory `scene` with `opts` and writes the outputs (PNG) into `out`.
pub fn texture_into(
    scene: &Path,
    opts: &scantex::pipeline::TextureOptions,
    out: &Path,
) -> scantex::pipeline::Textured {
    let s = scantex::scene::Scene::load(&scantex::scene::SceneSpec {
        dir: Some(scene.into()),
        ..Default::default()
    })
    .unwrap();
    let (mesh, _) = s.mesh.as_ref().unwrap();
    let r = scantex::pipeline::texture(mesh, &s.photos, opts, &scantex::progress::Silent).unwrap();
    scantex::pipeline::write_outputs(out, &r, scantex::pipeline::TextureFormat::Png, None).unwrap();
    r
}

/// `mesh`'s positions and faces (nothing else) with its faces and vertices in the order of two
/// permutations drawn from `seed` (new index -> old), and the permutations.
pub fn shuffled(
    mesh: &scantex::mesh::Mesh,
    seed: u64,
) -> (scantex::mesh::Mesh, Vec<usize>, Vec<usize>) {
    let mut rng = scantex::rng::SplitMix64::new(seed);
    let mut perm = |len: usize| {
        let mut p: Vec<usize> = (0..len).collect();
        for i in (1..len).rev() {
            p.swap(i, (rng.next_u64() % (i as u64 + 1)) as usize);
        }
        p
    };
    let (pv, pf) = (perm(mesh.num_vertices()), perm(mesh.num_faces()));
    let mut at = vec![0u32; pv.len()];
    for (new, &old) in pv.iter().enumerate() {
        at[old] = new as u32;
    }
    let out = scantex::mesh::Mesh {
        positions: pv.iter().map(|&v| mesh.positions[v]).collect(),
        faces: pf
            .iter()
            .map(|&f| mesh.faces[f].map(|v| scantex::mesh::VertexId(at[v.idx()])))
            .collect(),
        ..Default::default()
    };
    (out, pv, pf)
}

/// The largest distance, in pixels, between where two camera models of the same photographs
/// (paired in image-id order, same names and sizes) put the sample's mesh vertices (every 97th,
/// where the second model sees them), and how many projections were compared.
pub fn projection_difference(
    a: &scantex::camera::colmap::Reconstruction,
    b: &scantex::camera::colmap::Reconstruction,
) -> (f64, usize) {
    let (mesh, _) = scantex::io::read_mesh(&root().join("samples/torus/mesh.ply")).unwrap();
    assert_eq!(a.images.len(), b.images.len());
    let (mut worst, mut compared) = (0f64, 0);
    for (x, y) in a.images.values().zip(b.images.values()) {
        assert_eq!(x.name, y.name);
        let (cx, cy) = (&a.cameras[&x.camera_id], &b.cameras[&y.camera_id]);
        assert_eq!((cx.width, cx.height), (cy.width, cy.height));
        for p in mesh.positions.iter().step_by(97) {
            let (pa, pb) = (x.pose.transform(p), y.pose.transform(p));
            if pb.z <= 0.0 {
                continue;
            }
            if let (Some(u), Some(v)) = (cx.project(&pa), cy.project(&pb)) {
                if cy.contains(&v) {
                    worst = worst.max((u - v).norm());
                    compared += 1;
                }
            }
        }
    }
    (worst, compared)
}
