//! The triangle mesh every stage works on, its id types, and topology statistics.

use crate::error::{Error, Result};
use nalgebra::{Point3, Vector2, Vector3};
use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub mod order;
pub mod topology;
pub use topology::UnionFind;

/// Index of a vertex in [`Mesh::positions`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct VertexId(pub u32);

/// Index of a face in [`Mesh::faces`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub struct FaceId(pub u32);

impl VertexId {
    /// As a `usize` index.
    #[inline]
    pub fn idx(self) -> usize {
        self.0 as usize
    }
}

impl FaceId {
    /// As a `usize` index.
    #[inline]
    pub fn idx(self) -> usize {
        self.0 as usize
    }
}

/// Texture coordinates stored per face corner, so that a vertex on a chart seam can have a
/// different UV in each chart (as OBJ and PLY `texcoord` lists allow).
///
/// Convention: (0, 0) is the lower-left corner of the texture image and v points up, as in
/// OBJ and OpenGL; glTF's top-left origin is converted on read and write.
#[derive(Debug, Clone, PartialEq)]
pub struct UvMap {
    /// Distinct texture coordinates.
    pub coords: Vec<Vector2<f32>>,
    /// For each face, the index into `coords` of each corner.
    pub faces: Vec<[u32; 3]>,
}

impl UvMap {
    /// The UDIM page (0 for tile 1001) of face `f`: the integer part of its corners' mean u.
    pub fn face_page(&self, f: usize) -> u32 {
        let u: f32 = self.faces[f]
            .iter()
            .map(|&i| self.coords[i as usize].x)
            .sum::<f32>()
            / 3.0;
        u.floor().max(0.0) as u32
    }
}

/// Where a mesh's colour texture comes from, kept undecoded until someone needs the pixels.
#[derive(Debug, Clone, PartialEq)]
pub enum TextureSource {
    /// An image file (OBJ `map_Kd`, glTF image URI).
    File(PathBuf),
    /// Encoded image bytes embedded in the mesh file (GLB buffer view, data URI).
    Embedded(Vec<u8>),
    /// UDIM tiles: the images of pages 0, 1, ... (tiles 1001, 1002, ...); page `p` holds
    /// the faces whose u lies in `[p, p + 1]`.
    Tiles(Vec<TextureSource>),
}

/// A triangle mesh with optional per-vertex normals and colours, per-corner UVs and a texture.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Point3<f64>>,
    /// Triangles, counter-clockwise seen from outside.
    pub faces: Vec<[VertexId; 3]>,
    /// Per-vertex unit normals, if the file had them.
    pub normals: Option<Vec<Vector3<f32>>>,
    /// Per-vertex colours in [0, 1] (sRGB-encoded, as stored), if the file had them.
    pub colors: Option<Vec<[f32; 3]>>,
    /// Per-corner texture coordinates, if the file had them.
    pub uv: Option<UvMap>,
    /// The colour texture, if the file named one.
    pub texture: Option<TextureSource>,
}

/// What a reader dropped while loading a mesh, reported rather than fatal.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LoadReport {
    /// Faces removed because two corners share a vertex or the triangle has zero area.
    pub degenerate_faces: usize,
    /// Faces removed because an earlier face has the same three vertices (in either
    /// orientation): a second copy of a surface makes every edge non-manifold, so each face
    /// became a chart of its own.
    pub duplicate_faces: usize,
    /// Polygons with more than three corners, split into triangles.
    pub polygons_triangulated: usize,
}

impl LoadReport {
    /// One warning per kind of face left out: what a job writes has fewer faces than the
    /// file, which must be said, not silent.
    pub fn warnings(&self) -> Vec<String> {
        [
            (self.degenerate_faces, "with a repeated corner or zero area"),
            (
                self.duplicate_faces,
                "that repeat an earlier face's vertices",
            ),
        ]
        .into_iter()
        .filter(|&(n, _)| n > 0)
        .map(|(n, which)| format!("left out {n} faces of the mesh {which}"))
        .collect()
    }
}

impl Mesh {
    /// Number of vertices.
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn num_faces(&self) -> usize {
        self.faces.len()
    }

    /// The three corner positions of face `f`.
    pub fn triangle(&self, f: FaceId) -> [Point3<f64>; 3] {
        self.faces[f.idx()].map(|v| self.positions[v.idx()])
    }

    /// Unnormalised face normal (twice the area times the unit normal).
    pub fn face_normal_area(&self, f: FaceId) -> Vector3<f64> {
        let [a, b, c] = self.triangle(f);
        (b - a).cross(&(c - a))
    }

    /// Area of face `f`.
    pub fn face_area(&self, f: FaceId) -> f64 {
        0.5 * self.face_normal_area(f).norm()
    }

    /// Mean length of the faces' edges (each interior edge counted twice); 0 without faces.
    pub fn mean_edge_length(&self) -> f64 {
        if self.faces.is_empty() {
            return 0.0;
        }
        let total: f64 = self
            .faces
            .iter()
            .map(|f| {
                let p = |k: usize| self.positions[f[k].idx()];
                (p(1) - p(0)).norm() + (p(2) - p(1)).norm() + (p(0) - p(2)).norm()
            })
            .sum();
        total / (3 * self.faces.len()) as f64
    }

    /// Checks what every reader must guarantee and drops degenerate and repeated faces: at
    /// least one face, finite positions, indices in range. `path` names the file in errors.
    pub fn validate(&mut self, path: &Path) -> Result<LoadReport> {
        let mut report = LoadReport::default();
        if let Some(i) = self
            .positions
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(Error::at_element(
                path,
                format!("vertex {i}"),
                format!(
                    "position {:?} is not finite",
                    self.positions[i].coords.as_slice()
                ),
            ));
        }
        let n = self.positions.len();
        for (f, face) in self.faces.iter().enumerate() {
            if let Some(v) = face.iter().find(|v| v.idx() >= n) {
                return Err(Error::at_element(
                    path,
                    format!("face {f}"),
                    format!(
                        "vertex index {} is out of range (the mesh has {n} vertices)",
                        v.0
                    ),
                ));
            }
        }
        if let Some(uv) = &self.uv {
            if uv.faces.len() != self.faces.len() {
                return Err(Error::at_element(
                    path,
                    "texture coordinates",
                    "some faces have texture coordinates and others do not",
                ));
            }
            let m = uv.coords.len();
            for (f, face) in uv.faces.iter().enumerate() {
                if face.iter().any(|&t| t as usize >= m) {
                    return Err(Error::at_element(
                        path,
                        format!("face {f}"),
                        format!("texture coordinate index out of range ({m} coordinates)"),
                    ));
                }
            }
            if let Some(i) = uv
                .coords
                .iter()
                .position(|t| !t.iter().all(|c| c.is_finite()))
            {
                return Err(Error::at_element(
                    path,
                    format!("texture coordinate {i}"),
                    "value is not finite",
                ));
            }
        }
        for (what, len) in [
            ("normals", self.normals.as_ref().map(Vec::len)),
            ("colours", self.colors.as_ref().map(Vec::len)),
        ] {
            if let Some(len) = len {
                if len != n {
                    return Err(Error::at_element(
                        path,
                        what,
                        format!("{len} {what} for {n} vertices"),
                    ));
                }
            }
        }
        // Drop degenerate faces (repeated corner or exactly zero area), keeping UVs aligned.
        let keep: Vec<bool> = (0..self.faces.len())
            .map(|f| {
                let [a, b, c] = self.faces[f];
                a != b && b != c && a != c && self.face_normal_area(FaceId(f as u32)).norm() > 0.0
            })
            .collect();
        report.degenerate_faces = self.retain_faces(&keep);
        if self.faces.is_empty() {
            return Err(Error::at_element(
                path,
                "faces",
                "the mesh has no (non-degenerate) triangles",
            ));
        }
        // Drop repeated faces (the same vertices, either orientation), keeping the first.
        let mut seen = rustc_hash::FxHashSet::default();
        seen.reserve(self.faces.len());
        let keep: Vec<bool> = self
            .faces
            .iter()
            .map(|f| {
                let mut k = f.map(|v| v.0);
                k.sort_unstable();
                seen.insert(k)
            })
            .collect();
        report.duplicate_faces = self.retain_faces(&keep);
        Ok(report)
    }

    /// Keeps the faces (and their texture coordinates) `keep` marks; returns how many went.
    fn retain_faces(&mut self, keep: &[bool]) -> usize {
        let dropped = keep.iter().filter(|k| !**k).count();
        if dropped > 0 {
            let mut it = keep.iter();
            self.faces.retain(|_| *it.next().unwrap());
            if let Some(uv) = &mut self.uv {
                let mut it = keep.iter();
                uv.faces.retain(|_| *it.next().unwrap());
            }
        }
        dropped
    }

    /// Axis-aligned bounding box `(min, max)`.
    pub fn bounding_box(&self) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Point3::from([f64::INFINITY; 3]);
        let mut hi = Point3::from([f64::NEG_INFINITY; 3]);
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    }

    /// Area-weighted vertex normals (for meshes whose file has none).
    pub fn vertex_normals(&self) -> Vec<Vector3<f64>> {
        let mut n = vec![Vector3::zeros(); self.positions.len()];
        for f in 0..self.faces.len() {
            let fnrm = self.face_normal_area(FaceId(f as u32));
            for v in self.faces[f] {
                n[v.idx()] += fnrm;
            }
        }
        for v in &mut n {
            let l = v.norm();
            if l > 0.0 {
                *v /= l;
            }
        }
        n
    }

    /// Merges vertices with bit-identical positions (a mesh exported with vertices split along
    /// its old UV seams becomes one surface again). Per-corner UVs are kept; per-vertex normals
    /// and colours are taken from the first of each merged group. Returns the number merged.
    pub fn weld(&mut self) -> usize {
        let mut first: HashMap<[u64; 3], u32> = HashMap::with_capacity(self.positions.len());
        let mut remap = Vec::with_capacity(self.positions.len());
        let mut kept = Vec::new();
        for (i, p) in self.positions.iter().enumerate() {
            let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
            let next = kept.len() as u32;
            let id = *first.entry(key).or_insert_with(|| {
                kept.push(i);
                next
            });
            remap.push(id);
        }
        let merged = self.positions.len() - kept.len();
        if merged == 0 {
            return 0;
        }
        self.positions = kept.iter().map(|&i| self.positions[i]).collect();
        if let Some(n) = &mut self.normals {
            *n = kept.iter().map(|&i| n[i]).collect();
        }
        if let Some(c) = &mut self.colors {
            *c = kept.iter().map(|&i| c[i]).collect();
        }
        for f in &mut self.faces {
            *f = f.map(|v| VertexId(remap[v.idx()]));
        }
        merged
    }

    /// Topology statistics: components, boundary loops, non-manifold edges.
    pub fn topology(&self) -> Topology {
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.faces.len() * 2);
        for f in &self.faces {
            for k in 0..3 {
                let (a, b) = (f[k].0, f[(k + 1) % 3].0);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        let mut uf = UnionFind::new(self.positions.len());
        for f in &self.faces {
            uf.union(f[0].idx(), f[1].idx());
            uf.union(f[1].idx(), f[2].idx());
        }
        let mut used = vec![false; self.positions.len()];
        for f in &self.faces {
            for v in f {
                used[v.idx()] = true;
            }
        }
        let components = (0..self.positions.len())
            .filter(|&v| used[v] && uf.find(v) == v)
            .count();
        // Boundary loops: connected components of the graph of boundary edges. Exact for
        // manifold boundaries; two loops touching at a vertex count once.
        let mut buf = UnionFind::new(self.positions.len());
        let mut on_boundary = vec![false; self.positions.len()];
        let mut boundary_edges = 0;
        let mut non_manifold_edges = 0;
        for (&(a, b), &count) in &edges {
            match count {
                1 => {
                    boundary_edges += 1;
                    buf.union(a as usize, b as usize);
                    on_boundary[a as usize] = true;
                    on_boundary[b as usize] = true;
                }
                2 => {}
                _ => non_manifold_edges += 1,
            }
        }
        let boundary_loops = (0..self.positions.len())
            .filter(|&v| on_boundary[v] && buf.find(v) == v)
            .count();
        let euler = used.iter().filter(|u| **u).count() as i64 - edges.len() as i64
            + self.faces.len() as i64;
        Topology {
            edges: edges.len(),
            boundary_edges,
            boundary_loops,
            non_manifold_edges,
            components,
            unreferenced_vertices: used.iter().filter(|u| !**u).count(),
            euler_characteristic: euler,
        }
    }
}

/// Connectivity facts about a mesh, as `scantex info` reports them.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Topology {
    /// Distinct undirected edges.
    pub edges: usize,
    /// Edges with exactly one incident face.
    pub boundary_edges: usize,
    /// Closed chains of boundary edges (holes and open borders).
    pub boundary_loops: usize,
    /// Edges with three or more incident faces.
    pub non_manifold_edges: usize,
    /// Connected components (through shared vertices).
    pub components: usize,
    /// Vertices no face uses.
    pub unreferenced_vertices: usize,
    /// V - E + F over referenced vertices.
    pub euler_characteristic: i64,
}

#[cfg(test)]
impl Mesh {
    /// A tube of radius 1 along z from -1 to 1, `around` vertices per ring and `rings` rings
    /// of faces; with `caps`, closed by a fan at each end. Vertex `r * around + k` lies at
    /// angle k / around turns on ring r.
    pub(crate) fn tube(around: u32, rings: u32, caps: bool) -> Mesh {
        let mut m = Mesh::default();
        for r in 0..=rings {
            let z = -1.0 + 2.0 * r as f64 / rings as f64;
            for k in 0..around {
                let a = std::f64::consts::TAU * k as f64 / around as f64;
                m.positions.push(Point3::new(a.cos(), a.sin(), z));
            }
        }
        let v = |r: u32, k: u32| VertexId(r * around + k % around);
        for r in 0..rings {
            for k in 0..around {
                m.faces.push([v(r, k), v(r, k + 1), v(r + 1, k + 1)]);
                m.faces.push([v(r, k), v(r + 1, k + 1), v(r + 1, k)]);
            }
        }
        if caps {
            for (ring, z) in [(0, -1.0), (rings, 1.0)] {
                let c = VertexId(m.positions.len() as u32);
                m.positions.push(Point3::new(0.0, 0.0, z));
                for k in 0..around {
                    let (a, b) = (v(ring, k), v(ring, k + 1));
                    m.faces.push(if z > 0.0 { [a, b, c] } else { [b, a, c] });
                }
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(i: u32) -> VertexId {
        VertexId(i)
    }

    /// A closed tetrahedron: one component, no boundary, Euler characteristic 2.
    fn tetra() -> Mesh {
        Mesh {
            positions: vec![
                Point3::new(0.0, 0.0, 0.0),
                Point3::new(1.0, 0.0, 0.0),
                Point3::new(0.0, 1.0, 0.0),
                Point3::new(0.0, 0.0, 1.0),
            ],
            faces: vec![
                [v(0), v(2), v(1)],
                [v(0), v(1), v(3)],
                [v(1), v(2), v(3)],
                [v(0), v(3), v(2)],
            ],
            ..Default::default()
        }
    }

    #[test]
    fn weld_merges_seam_duplicates() {
        let mut m = tetra();
        // Split vertex 0 for the last face, as a UV-seam export would.
        m.positions.push(m.positions[0]);
        m.faces[3][0] = v(4);
        assert_eq!(m.topology().boundary_loops, 1);
        assert_eq!(m.weld(), 1);
        assert_eq!(m.num_vertices(), 4);
        assert_eq!(m.topology().euler_characteristic, 2);
    }

    #[test]
    fn closed_tetrahedron_topology() {
        let t = tetra().topology();
        assert_eq!(t.components, 1);
        assert_eq!(t.boundary_loops, 0);
        assert_eq!(t.non_manifold_edges, 0);
        assert_eq!(t.euler_characteristic, 2);
        assert_eq!(t.edges, 6);
    }

    #[test]
    fn open_and_non_manifold_topology() {
        let mut m = tetra();
        m.faces.pop(); // opens one hole
        let t = m.topology();
        assert_eq!((t.boundary_loops, t.boundary_edges), (1, 3));
        // A fin on edge (0,1) makes it non-manifold.
        m.positions.push(Point3::new(0.5, -1.0, 0.0));
        m.faces.push([v(0), v(1), v(4)]);
        assert_eq!(m.topology().non_manifold_edges, 1);
    }

    #[test]
    fn validate_drops_degenerate_faces_and_rejects_bad_ones() {
        let mut m = tetra();
        m.faces.push([v(0), v(0), v(1)]);
        let r = m.validate(Path::new("t.obj")).unwrap();
        assert_eq!(r.degenerate_faces, 1);
        assert_eq!(m.faces.len(), 4);

        // A face repeated, once as it is and once turned over: both copies go, the first
        // stays, and texture coordinates stay aligned with their faces.
        let mut m = tetra();
        let f1 = m.faces[1];
        m.faces.push(f1);
        m.faces.push([f1[2], f1[1], f1[0]]);
        let faces = m.faces.clone();
        m.uv = Some(UvMap {
            coords: vec![Vector2::new(0.0, 0.0); 3],
            faces: (0..faces.len() as u32).map(|k| [k % 3, 0, 0]).collect(),
        });
        let r = m.validate(Path::new("t.obj")).unwrap();
        assert_eq!((r.degenerate_faces, r.duplicate_faces), (0, 2));
        assert_eq!(m.faces, faces[..4]);
        let uv = m.uv.as_ref().unwrap();
        assert_eq!(
            uv.faces,
            (0..4u32).map(|k| [k % 3, 0, 0]).collect::<Vec<_>>()
        );

        let mut m = tetra();
        m.faces.push([v(0), v(1), v(9)]);
        let e = m.validate(Path::new("t.obj")).unwrap_err().to_string();
        assert!(
            e.contains("t.obj") && e.contains("face 4") && e.contains("out of range"),
            "{e}"
        );

        let mut m = tetra();
        m.positions[2].y = f64::NAN;
        let e = m.validate(Path::new("t.obj")).unwrap_err().to_string();
        assert!(e.contains("vertex 2") && e.contains("not finite"), "{e}");
    }
}
