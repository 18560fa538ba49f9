//! Packing alone, on the charts of an atlas that already exists: reads a mesh with UVs (the
//! OBJ `scantex param` or `scantex texture` writes), takes its UV islands as the charts (their
//! flattening kept, at the scale they have), and times `atlas::pack::pack` on them, as the
//! texturing run would call it (one page, the largest density that fits). Prints the charts,
//! the seconds, the utilisation and a hash of the packed UVs (to check that a change keeps the
//! bytes). Run with:
//!
//!     cargo bench --bench pack -- <mesh.obj> [size]...
//!
//! The 10.6M-face scale mesh's atlas: `scantex param <work>/mesh_s2_m3.ply -o p.obj` on the
//! mesh `benches/scale_curve.py <work> 10000000:50` writes, then this on `p.obj` at 8192.

use scantex::atlas::pack::{coverage_counts, pack, PackOptions};
use scantex::atlas::param::ChartMap;
use scantex::mesh::FaceId;
use std::collections::HashMap;
use std::hash::{Hash, Hasher};
use std::path::Path;
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    let Some(path) = args.first() else {
        eprintln!("usage: cargo bench --bench pack -- <mesh.obj> [size]...");
        std::process::exit(2);
    };
    let sizes: Vec<u32> = if args.len() > 1 {
        args[1..]
            .iter()
            .map(|s| s.parse().expect("a size in texels"))
            .collect()
    } else {
        vec![8192]
    };
    let t = Instant::now();
    let (mesh, _) = scantex::io::read_mesh(Path::new(path)).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1)
    });
    let Some(uv) = mesh.uv.clone() else {
        eprintln!("{path} has no texture coordinates");
        std::process::exit(1)
    };
    let island = scantex::atlas::uv_islands(&uv);
    let charts = island.iter().map(|&c| c as usize + 1).max().unwrap_or(0);
    let mut maps: Vec<ChartMap> = (0..charts)
        .map(|_| ChartMap {
            vertices: Vec::new(),
            uv: Vec::new(),
            faces: Vec::new(),
            face_ids: Vec::new(),
        })
        .collect();
    let mut local: Vec<HashMap<u32, u32>> = vec![HashMap::new(); charts];
    for (f, t) in uv.faces.iter().enumerate() {
        let c = island[f] as usize;
        let (map, loc) = (&mut maps[c], &mut local[c]);
        let mut tri = [0u32; 3];
        for k in 0..3 {
            let n = map.uv.len() as u32;
            tri[k] = *loc.entry(t[k]).or_insert_with(|| {
                // Atlas units: the density search rescales.
                let p = uv.coords[t[k] as usize].cast::<f64>();
                map.uv.push(p);
                map.vertices.push(mesh.faces[f][k]);
                n
            });
        }
        map.faces.push(tri);
        map.face_ids.push(FaceId(f as u32));
    }
    println!(
        "{path}: {} faces, {} charts, read in {:.1} s",
        mesh.num_faces(),
        maps.len(),
        t.elapsed().as_secs_f64()
    );
    let ones = vec![1.0; maps.len()];
    for size in sizes {
        let opts = PackOptions {
            size,
            ..PackOptions::default()
        };
        let t = Instant::now();
        let packed = pack(&mesh, &maps, &ones, &opts).unwrap_or_else(|e| {
            eprintln!("{e}");
            std::process::exit(1)
        });
        let secs = t.elapsed().as_secs_f64();
        let (covered, overlaps) =
            coverage_counts(&packed.uv, &packed.face_chart, size, packed.pages);
        let used = covered as f64 / (size as usize * size as usize * packed.pages as usize) as f64;
        let mut h = std::collections::hash_map::DefaultHasher::new();
        for c in &packed.uv.coords {
            c.x.to_bits().hash(&mut h);
            c.y.to_bits().hash(&mut h);
        }
        println!(
            "size {size}: pack {secs:.2} s, {} page(s), utilisation {used:.4}, overlapping \
             texels {overlaps}, uv hash {:016x}",
            packed.pages,
            h.finish()
        );
    }
}
