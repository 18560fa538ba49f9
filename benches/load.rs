//! Load-time benchmark: COLMAP models (text and binary) and meshes from `../shared/data`.
//! Prints a table of the median of 15 runs (after one warm-up). Run with:
//!
//!     cargo bench --bench load

use std::path::{Path, PathBuf};
use std::time::Instant;

fn median_ms(mut f: impl FnMut()) -> (f64, f64) {
    f();
    let mut t: Vec<f64> = (0..15)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[t.len() / 2], t[t.len() - 1])
}

fn main() {
    let data = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if !data.is_dir() {
        eprintln!("skipping: {} is missing", data.display());
        return;
    }
    let sol = data.join("colmap/statue_of_liberty/sparse/0");
    let mut rows: Vec<(String, String, f64, f64)> = Vec::new();
    let mut add = |name: &str, what: String, f: &mut dyn FnMut()| {
        let (med, max) = median_ms(f);
        rows.push((name.to_string(), what, med, max));
    };
    use scantex::camera::colmap::{read_format, Format};
    let r = read_format(&sol, Format::Text).unwrap();
    let size = format!("{} images, {} points", r.images.len(), r.points3d.len());
    add("statue_of_liberty COLMAP text", size.clone(), &mut || {
        read_format(&sol, Format::Text).unwrap();
    });
    add("statue_of_liberty COLMAP binary", size, &mut || {
        read_format(&sol, Format::Binary).unwrap();
    });
    add(
        "statue_of_liberty reprojection (all tracks)",
        "7,760 observations".into(),
        &mut || {
            std::hint::black_box(r.track_errors());
        },
    );
    let meshes: [(&str, &Path); 3] = [
        (
            "floor_patch meshed-poisson.ply",
            Path::new("colmap/floor_patch/dense/0/meshed-poisson.ply"),
        ),
        ("corset Corset.obj", Path::new("scans/corset/Corset.obj")),
        ("corset Corset.gltf", Path::new("scans/corset/Corset.gltf")),
    ];
    for (name, rel) in meshes {
        let p = data.join(rel);
        let (m, _) = scantex::io::read_mesh(&p).unwrap();
        add(
            name,
            format!("{} vertices, {} faces", m.num_vertices(), m.num_faces()),
            &mut || {
                scantex::io::read_mesh(&p).unwrap();
            },
        );
    }
    let (m, _) = scantex::io::read_mesh(&data.join(meshes[0].1)).unwrap();
    add(
        "floor_patch topology (components, loops)",
        format!("{} faces", m.num_faces()),
        &mut || {
            std::hint::black_box(m.topology());
        },
    );
    println!("| what | size | median (ms) | max of 15 (ms) |");
    println!("|---|---|---:|---:|");
    for (name, what, med, max) in rows {
        println!("| {name} | {what} | {med:.2} | {max:.2} |");
    }
}
