//! Meshes and measures shared by the atlas stage's tests.

use super::param::{uv_area, ChartMap};
use crate::mesh::{FaceId, Mesh, VertexId};
use nalgebra::{Point3, Vector3};
use std::collections::HashMap;

/// A disk-like grid around a centre vertex: `pos(0, 0)` is the centre, `pos(r, k)` vertex k of
/// ring r (1..=rings, `sectors` per ring). Fans around the centre, quads split between rings.
pub fn polar_grid(rings: usize, sectors: usize, pos: impl Fn(usize, usize) -> Point3<f64>) -> Mesh {
    let mut positions = vec![pos(0, 0)];
    for r in 1..=rings {
        positions.extend((0..sectors).map(|k| pos(r, k)));
    }
    let id = |r: usize, k: usize| {
        VertexId(if r == 0 {
            0
        } else {
            (1 + (r - 1) * sectors + k % sectors) as u32
        })
    };
    let mut faces: Vec<[VertexId; 3]> = (0..sectors)
        .map(|k| [id(0, 0), id(1, k), id(1, k + 1)])
        .collect();
    for r in 1..rings {
        for k in 0..sectors {
            faces.push([id(r, k), id(r + 1, k), id(r + 1, k + 1)]);
            faces.push([id(r, k), id(r + 1, k + 1), id(r, k + 1)]);
        }
    }
    Mesh {
        positions,
        faces,
        ..Default::default()
    }
}

/// `m` and a copy moved by `offset`: two components.
pub fn two_copies(m: &Mesh, offset: Vector3<f64>) -> Mesh {
    let mut two = m.clone();
    let n = m.num_vertices() as u32;
    two.positions.extend(m.positions.iter().map(|p| p + offset));
    two.faces
        .extend(m.faces.iter().map(|f| f.map(|v| VertexId(v.0 + n))));
    two
}

/// `m` without every `every`-th face: holes.
pub fn with_holes(m: &Mesh, every: usize) -> Mesh {
    let mut holed = m.clone();
    holed.faces = m
        .faces
        .iter()
        .enumerate()
        .filter(|(i, _)| i % every != 0)
        .map(|(_, f)| *f)
        .collect();
    holed
}

/// `m` with `count` fins (extra triangles on existing edges, every `stride`-th face), making
/// those edges non-manifold.
pub fn with_fins(m: &Mesh, count: usize, stride: usize, scale: f64) -> Mesh {
    let mut fins = m.clone();
    for e in 0..count {
        let f = fins.faces[e * stride];
        fins.positions.push(fins.positions[f[0].idx()] * scale);
        fins.faces
            .push([f[0], f[1], VertexId(fins.positions.len() as u32 - 1)]);
    }
    fins
}

/// Texture area per unit 3D area over the chart's faces whose unit normal's z satisfies `pick`.
pub fn texel_density(mesh: &Mesh, map: &ChartMap, pick: impl Fn(f64) -> bool) -> f64 {
    let (mut a2, mut a3) = (0.0, 0.0);
    for (t, f) in map.faces.iter().zip(&map.face_ids) {
        let n = mesh.face_normal_area(*f);
        if pick(n.z / n.norm()) {
            a2 += uv_area(t.map(|i| map.uv[i as usize]));
            a3 += mesh.face_area(*f);
        }
    }
    a2 / a3
}

/// Faces of `m` whose centroid satisfies `pick`.
pub fn faces_where(m: &Mesh, pick: impl Fn(Point3<f64>) -> bool) -> Vec<FaceId> {
    (0..m.num_faces() as u32)
        .map(FaceId)
        .filter(|f| {
            let [a, b, c] = m.triangle(*f);
            pick(Point3::from((a.coords + b.coords + c.coords) / 3.0))
        })
        .collect()
}

/// An icosahedron subdivided `levels` times, on the unit sphere.
pub fn icosphere(levels: usize) -> Mesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut p: Vec<Point3<f64>> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Point3::new(x, y, z))
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut nf = Vec::new();
        for tri in &f {
            let m: Vec<u32> = (0..3)
                .map(|k| {
                    let (a, b) = (tri[k].min(tri[(k + 1) % 3]), tri[k].max(tri[(k + 1) % 3]));
                    *mid.entry((a, b)).or_insert_with(|| {
                        p.push(nalgebra::center(&p[a as usize], &p[b as usize]));
                        p.len() as u32 - 1
                    })
                })
                .collect();
            nf.extend([
                [tri[0], m[0], m[2]],
                [tri[1], m[1], m[0]],
                [tri[2], m[2], m[1]],
                [m[0], m[1], m[2]],
            ]);
        }
        f = nf;
    }
    for q in &mut p {
        *q = Point3::from(q.coords.normalize());
    }
    Mesh {
        positions: p,
        faces: f.into_iter().map(|t| t.map(VertexId)).collect(),
        ..Default::default()
    }
}
