//! Meshes and measures shared by the atlas stage's tests.

use super::param::{uv_area, ChartMap};
use crate::mesh::{FaceId, Mesh, VertexId};
use nalgebra::{Point3, Vector3};

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
