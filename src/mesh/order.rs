//! A spatial order for meshes whose faces come in no spatial order. Every stage walks faces
//! and vertices in index order and reads their neighbours' data; on a mesh written in a
//! scattered order (the speed scene's, from trimesh) those reads land far apart in memory:
//! sorted, the 1.5M-face speed scene runs 4-5% faster (`docs/benchmarks.md`, "The mesh's
//! order" and "Scattered meshes sorted for the work"). The pipeline sorts such a mesh for its
//! own work and hands everything back in the input's order; a mesh already in a spatial
//! order (what the scans' meshers write) is left as it is.

use super::{Mesh, VertexId};
use nalgebra::Point3;
use rayon::prelude::*;

/// A mesh is scattered when the lowest vertex index of one face and of the next differ by
/// more than this, at the median over consecutive faces. Meshers write neighbouring faces
/// one after the other (a median of 1 on the corset and the sample torus, 6 on floor_patch's
/// COLMAP mesh); the speed scene's faces jump by 139,402 of 768,080 vertices.
pub const SCATTERED_JUMP: u32 = 1024;

/// A permutation of a mesh's faces and vertices.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshOrder {
    /// Face `i` of the sorted mesh is face `faces[i]` of the original.
    faces: Vec<u32>,
    /// Vertex `i` of the sorted mesh is vertex `vertices[i]` of the original.
    vertices: Vec<u32>,
    /// Original face `f` is face `face_at[f]` of the sorted mesh.
    face_at: Vec<u32>,
    /// Original vertex `v` is vertex `vertex_at[v]` of the sorted mesh.
    vertex_at: Vec<u32>,
}

/// The inverse of the permutation `p` (new index -> old).
fn inverse(p: &[u32]) -> Vec<u32> {
    let mut inv = vec![0u32; p.len()];
    for (new, &old) in p.iter().enumerate() {
        inv[old as usize] = new as u32;
    }
    inv
}

/// Spreads the low 21 bits of `x` to every third bit.
fn spread(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

/// Indices sorted by the Morton code (21 bits per axis over the box `lo`-`hi`) of their
/// points, ties by index: the same order on every run and thread count.
fn morton_order(points: &[Point3<f64>], lo: &Point3<f64>, hi: &Point3<f64>) -> Vec<u32> {
    let extent = (hi - lo).max().max(1e-300);
    let scale = ((1u64 << 21) - 1) as f64 / extent;
    let mut keyed: Vec<(u64, u32)> = points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let q = |k: usize| {
                let v = ((p[k] - lo[k]) * scale).clamp(0.0, ((1u64 << 21) - 1) as f64);
                // NaN (a non-finite position) sorts with 0.
                spread(if v.is_nan() { 0 } else { v as u64 })
            };
            (q(0) | q(1) << 1 | q(2) << 2, i as u32)
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

impl Mesh {
    /// The median jump of the lowest vertex index from one face to the next (0 for fewer than
    /// two faces): 1 or so where faces come in a spatial order.
    pub fn median_face_jump(&self) -> u32 {
        let mut jumps: Vec<u32> = self
            .faces
            .windows(2)
            .map(|w| {
                let a = w[0].iter().map(|v| v.0).min().unwrap_or(0);
                let b = w[1].iter().map(|v| v.0).min().unwrap_or(0);
                a.abs_diff(b)
            })
            .collect();
        if jumps.is_empty() {
            return 0;
        }
        let k = jumps.len() / 2;
        *jumps.select_nth_unstable(k).1
    }

    /// The spatial order the pipeline works in when [`Mesh::median_face_jump`] exceeds
    /// [`SCATTERED_JUMP`]; `None` for a mesh already in a spatial order. Vertices sorted by
    /// the Morton code of their position, faces by that of their centroid.
    pub fn scattered_order(&self) -> Option<MeshOrder> {
        if self.median_face_jump() <= SCATTERED_JUMP {
            return None;
        }
        let (lo, hi) = self.bounding_box();
        let vertices = morton_order(&self.positions, &lo, &hi);
        let centroids: Vec<Point3<f64>> = self
            .faces
            .par_iter()
            .map(|f| {
                let [a, b, c] = f.map(|v| self.positions[v.idx()].coords);
                Point3::from((a + b + c) / 3.0)
            })
            .collect();
        let faces = morton_order(&centroids, &lo, &hi);
        Some(MeshOrder {
            face_at: inverse(&faces),
            vertex_at: inverse(&vertices),
            faces,
            vertices,
        })
    }

    /// This mesh with its faces and vertices in `order` (from [`Mesh::scattered_order`] of
    /// this mesh). Per-corner UVs follow their faces; the texture is kept.
    pub fn reordered(&self, order: &MeshOrder) -> Mesh {
        self.permuted(&order.vertices, &order.faces, &order.vertex_at)
    }

    /// The inverse of [`Mesh::reordered`]: a mesh worked on in `order`, with its faces and
    /// vertices back in the original order.
    pub fn in_original_order(&self, order: &MeshOrder) -> Mesh {
        self.permuted(&order.vertex_at, &order.face_at, &order.vertices)
    }

    /// Vertex `i` of the result is vertex `vertices[i]` of this mesh, face `i` is face
    /// `faces[i]` with its corners renamed by `rename` (this mesh's vertex -> the result's).
    fn permuted(&self, vertices: &[u32], faces: &[u32], rename: &[u32]) -> Mesh {
        Mesh {
            positions: pick(&self.positions, vertices),
            faces: faces
                .iter()
                .map(|&f| self.faces[f as usize].map(|v| VertexId(rename[v.idx()])))
                .collect(),
            normals: self.normals.as_ref().map(|n| pick(n, vertices)),
            colors: self.colors.as_ref().map(|c| pick(c, vertices)),
            uv: self.uv.as_ref().map(|uv| super::UvMap {
                coords: uv.coords.clone(),
                faces: pick(&uv.faces, faces),
            }),
            texture: self.texture.clone(),
        }
    }
}

/// `values[at[i]]` for every `i`.
fn pick<T: Clone>(values: &[T], at: &[u32]) -> Vec<T> {
    at.iter().map(|&i| values[i as usize].clone()).collect()
}

impl MeshOrder {
    /// Original index of face `f` of the sorted mesh.
    pub fn original_face(&self, f: u32) -> u32 {
        self.faces[f as usize]
    }

    /// Per-face values of the sorted mesh in the original faces' order.
    pub fn faces_to_original<T: Clone>(&self, per_face: &[T]) -> Vec<T> {
        pick(per_face, &self.face_at)
    }

    /// Per-vertex values of the sorted mesh in the original vertices' order.
    pub fn vertices_to_original<T: Clone>(&self, per_vertex: &[T]) -> Vec<T> {
        pick(per_vertex, &self.vertex_at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::UvMap;
    use crate::rng::SplitMix64;
    use nalgebra::{Vector2, Vector3};

    /// A grid of `n` x `n` quads (two triangles each, row by row, as meshers write them)
    /// with UVs, colours and normals.
    fn grid(n: u32) -> Mesh {
        let mut m = Mesh::default();
        for y in 0..=n {
            for x in 0..=n {
                m.positions
                    .push(Point3::new(x as f64, y as f64, (x * y % 7) as f64 * 0.1));
            }
        }
        let id = |x: u32, y: u32| VertexId(y * (n + 1) + x);
        for y in 0..n {
            for x in 0..n {
                m.faces.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                m.faces.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        let (nv, nf) = (m.positions.len(), m.faces.len() as u32);
        m.normals = Some((0..nv).map(|i| Vector3::new(0.0, 0.0, i as f32)).collect());
        m.colors = Some((0..nv).map(|i| [i as f32, 0.0, 1.0]).collect());
        m.uv = Some(UvMap {
            coords: (0..3 * nf).map(|i| Vector2::new(i as f32, 0.5)).collect(),
            faces: (0..nf).map(|f| [3 * f, 3 * f + 1, 3 * f + 2]).collect(),
        });
        m
    }

    /// `m` with its faces and vertices shuffled (seed 7).
    fn shuffled(m: &Mesh) -> Mesh {
        let mut rng = SplitMix64::new(7);
        let mut perm = |len: usize| {
            let mut p: Vec<u32> = (0..len as u32).collect();
            for i in (1..len).rev() {
                let j = (rng.next_u64() % (i as u64 + 1)) as usize;
                p.swap(i, j);
            }
            p
        };
        let (vertices, faces) = (perm(m.positions.len()), perm(m.faces.len()));
        let order = MeshOrder {
            face_at: inverse(&faces),
            vertex_at: inverse(&vertices),
            faces,
            vertices,
        };
        m.reordered(&order)
    }

    /// A shuffled grid is scattered; sorted, its faces follow each other in space, every face
    /// is the same triangle with the same UVs, and the way back gives the input exactly.
    #[test]
    fn a_scattered_mesh_sorts_and_comes_back_unchanged() {
        let m = shuffled(&grid(120));
        assert!(
            m.median_face_jump() > SCATTERED_JUMP,
            "{}",
            m.median_face_jump()
        );
        let order = m.scattered_order().expect("scattered");
        let sorted = m.reordered(&order);
        assert!(
            sorted.median_face_jump() < 64,
            "{}",
            sorted.median_face_jump()
        );
        assert!(sorted.scattered_order().is_none());
        for (f, t) in sorted.faces.iter().enumerate() {
            let old = order.original_face(f as u32) as usize;
            assert_eq!(
                sorted.triangle(crate::mesh::FaceId(f as u32)),
                m.triangle(crate::mesh::FaceId(old as u32))
            );
            let uv = |mesh: &Mesh, g: usize| mesh.uv.as_ref().unwrap().faces[g];
            assert_eq!(uv(&sorted, f), uv(&m, old));
            for (k, v) in t.iter().enumerate() {
                let ov = m.faces[old][k].idx();
                assert_eq!(
                    sorted.normals.as_ref().unwrap()[v.idx()],
                    m.normals.as_ref().unwrap()[ov]
                );
                assert_eq!(
                    sorted.colors.as_ref().unwrap()[v.idx()],
                    m.colors.as_ref().unwrap()[ov]
                );
            }
        }
        assert_eq!(sorted.in_original_order(&order), m);
        let per_face: Vec<u32> = order.faces.clone();
        assert_eq!(
            order.faces_to_original(&per_face),
            (0..m.faces.len() as u32).collect::<Vec<_>>()
        );
        let per_vertex: Vec<u32> = order.vertices.clone();
        assert_eq!(
            order.vertices_to_original(&per_vertex),
            (0..m.positions.len() as u32).collect::<Vec<_>>()
        );
    }

    /// Faces written row by row, as meshers write them, are left alone.
    #[test]
    fn a_mesh_in_spatial_order_is_left_as_it_is() {
        let m = grid(40);
        assert!(m.median_face_jump() <= 2, "{}", m.median_face_jump());
        assert!(m.scattered_order().is_none());
    }
}
