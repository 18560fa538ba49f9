//! The texels of an atlas page: which face owns each texel and each face's triangle in texel
//! coordinates, and the samples along chart borders. Built once per atlas ([`super::Atlas`])
//! and read by every stage that works on texels (resampling, merging, levelling, seams).

use crate::error::{Error, Result};
use crate::mesh::{FaceId, Mesh};
use nalgebra::Vector2;
use rayon::prelude::*;

/// Texture coordinate `corner` of `uv` in texel units of an `n`-texel page: x right, y down
/// from the page's top-left corner (UVs have v up from the lower left).
pub(crate) fn texel_point(uv: &crate::mesh::UvMap, corner: u32, n: usize) -> Vector2<f64> {
    let q = uv.coords[corner as usize];
    let s = n as f64;
    Vector2::new(q.x as f64 * s, (1.0 - q.y as f64) * s)
}

/// Rows of the atlas processed together by one thread.
pub(crate) const BAND: usize = 16;

/// A face's triangle in texel coordinates and what the per-texel work needs of it.
pub(crate) struct FaceRaster {
    /// Corners (x right, y down), texel centres at +0.5.
    pub(crate) t: [Vector2<f64>; 3],
    /// Twice the signed area.
    pub(crate) area2: f64,
    /// Texel rows spanned (inclusive), conservatively.
    pub(crate) rows: (usize, usize),
    /// Texel columns spanned (inclusive), conservatively.
    pub(crate) cols: (usize, usize),
    /// 3D length of one texel on this face.
    pub(crate) texel_len: f64,
}

impl FaceRaster {
    /// Barycentrics of the texel centre (x, y), unclamped.
    pub(crate) fn bary(&self, x: usize, y: usize) -> [f64; 3] {
        let p = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
        let [a, b, c] = &self.t;
        let cross = |u: Vector2<f64>, v: Vector2<f64>| u.x * v.y - u.y * v.x;
        let wa = cross(b - p, c - p) / self.area2;
        let wb = cross(c - p, a - p) / self.area2;
        [wa, wb, 1.0 - wa - wb]
    }

    /// Signed distances (texels) from the centre (x, y) to the three edge lines, positive
    /// inside.
    pub(crate) fn edge_distances(&self, x: usize, y: usize) -> [f64; 3] {
        let b = self.bary(x, y);
        let [a, bb, c] = &self.t;
        let len = [(c - bb).norm(), (a - c).norm(), (bb - a).norm()];
        std::array::from_fn(|k| b[k] * self.area2.abs() / len[k].max(1e-300))
    }
}

/// Which face owns each texel: the face containing the texel centre (the first by index on a
/// shared edge); texels a face merely touches (within 0.75 texel of it) go to the first such
/// face if no centre lies in them, so chart borders are coloured from their own triangles.
pub(crate) struct TexelMap {
    pub(crate) size: usize,
    pub(crate) faces: Vec<Option<FaceRaster>>,
    /// Faces overlapping each band, by index.
    pub(crate) bands: Vec<Vec<u32>>,
    pub(crate) owner: Vec<u32>,
}

pub(crate) const NO_FACE: u32 = u32::MAX;

impl TexelMap {
    /// The raster of the faces `on_page` accepts whose triangles reach the page.
    pub(crate) fn new(
        mesh: &Mesh,
        size: u32,
        on_page: &(dyn Fn(usize) -> bool + Sync),
    ) -> Result<Self> {
        let uv = mesh
            .uv
            .as_ref()
            .ok_or_else(|| Error::Internal("the texel raster needs a mesh with an atlas".into()))?;
        let s = size as f64;
        let n = size as usize;
        let faces: Vec<Option<FaceRaster>> = (0..mesh.num_faces())
            .into_par_iter()
            .map(|f| {
                if !on_page(f) {
                    return None;
                }
                let c = uv.faces[f];
                let t: [Vector2<f64>; 3] = c.map(|k| texel_point(uv, k, n));
                let cross = |u: Vector2<f64>, v: Vector2<f64>| u.x * v.y - u.y * v.x;
                let area2 = cross(t[1] - t[0], t[2] - t[0]);
                if area2.abs() < 1e-12 || t.iter().any(|p| !p.x.is_finite() || !p.y.is_finite()) {
                    return None;
                }
                let lo = t[0].inf(&t[1]).inf(&t[2]);
                let hi = t[0].sup(&t[1]).sup(&t[2]);
                if hi.x < 0.0 || hi.y < 0.0 || lo.x > s || lo.y > s {
                    return None; // another page
                }
                let clamp = |v: f64| v.clamp(0.0, s - 1.0) as usize;
                let a3 = mesh.face_area(FaceId(f as u32));
                Some(FaceRaster {
                    t,
                    area2,
                    rows: (clamp(lo.y - 1.0), clamp(hi.y + 1.0)),
                    cols: (clamp(lo.x - 1.0), clamp(hi.x + 1.0)),
                    texel_len: (a3 / (0.5 * area2.abs())).sqrt(),
                })
            })
            .collect();
        let mut bands: Vec<Vec<u32>> = vec![Vec::new(); n.div_ceil(BAND)];
        for (f, r) in faces.iter().enumerate() {
            if let Some(r) = r {
                for band in bands
                    .iter_mut()
                    .take(r.rows.1 / BAND + 1)
                    .skip(r.rows.0 / BAND)
                {
                    band.push(f as u32);
                }
            }
        }
        let mut owner = vec![NO_FACE; n * n];
        owner
            .par_chunks_mut(BAND * n)
            .zip(bands.par_iter())
            .enumerate()
            .for_each(|(bi, (rows, list))| {
                let y0 = bi * BAND;
                let y1 = y0 + rows.len() / n;
                for conservative in [false, true] {
                    for &f in list {
                        let r = faces[f as usize].as_ref().expect("listed faces rasterise");
                        for y in r.rows.0.max(y0)..=r.rows.1.min(y1 - 1) {
                            for x in r.cols.0..=r.cols.1 {
                                let o = &mut rows[(y - y0) * n + x];
                                if *o != NO_FACE {
                                    continue;
                                }
                                let inside = if conservative {
                                    r.edge_distances(x, y).iter().all(|&d| d >= -0.75)
                                } else {
                                    r.bary(x, y).iter().all(|&b| b >= 0.0)
                                };
                                if inside {
                                    *o = f;
                                }
                            }
                        }
                    }
                }
            });
        Ok(TexelMap {
            size: n,
            faces,
            bands,
            owner,
        })
    }
}

/// One sample along a chart border: the shared 3D edge `a`-`b` read on both of its faces.
pub(crate) struct BorderSample {
    /// The two faces.
    pub faces: [usize; 2],
    /// Per side, the texture-coordinate indices of `a` and `b`.
    pub uv: [[u32; 2]; 2],
    /// Position along the edge from `a` (0) to `b` (1).
    pub t: f64,
    /// Per side, the point on the edge (texel coordinates: x right, y down).
    pub at: [Vector2<f64>; 2],
    /// Per side, the unit step into its face, perpendicular to the edge.
    pub inward: [Vector2<f64>; 2],
}

/// Samples along every mesh edge where two charts meet (the same 3D edge with different
/// texture coordinates on its two faces, both on an `n`-texel page), one per texel of edge
/// length.
pub(crate) fn border_samples(mesh: &Mesh, n: usize) -> Vec<BorderSample> {
    let Some(uv) = &mesh.uv else {
        return Vec::new();
    };
    let s = n as f64;
    let texel = |c: u32| texel_point(uv, c, n);
    let on_page = |p: Vector2<f64>| p.x >= 0.0 && p.y >= 0.0 && p.x <= s && p.y <= s;
    let inward = |a: Vector2<f64>, b: Vector2<f64>, o: Vector2<f64>| {
        let e = (b - a).try_normalize(1e-12)?;
        let nrm = Vector2::new(-e.y, e.x);
        Some(if nrm.dot(&(o - a)) >= 0.0 { nrm } else { -nrm })
    };
    // Each half-edge (face, corner) paired with the first half-edge of the same undirected
    // edge, in face order (the lowest face and corner): sorted, not hashed, so that it runs
    // in parallel; a half-edge that is its edge's first has no pair.
    let nf = mesh.faces.len();
    let mut halves: Vec<(u64, u32)> = (0..3 * nf)
        .into_par_iter()
        .map(|h| {
            let fv = mesh.faces[h / 3];
            let (a, b) = (fv[h % 3].0, fv[(h % 3 + 1) % 3].0);
            ((u64::from(a.min(b)) << 32) | u64::from(a.max(b)), h as u32)
        })
        .collect();
    halves.par_sort_unstable();
    let mut first_of = vec![u32::MAX; 3 * nf];
    for group in halves.chunk_by(|x, y| x.0 == y.0) {
        for &(_, h) in &group[1..] {
            first_of[h as usize] = group[0].1;
        }
    }
    drop(halves);
    let samples_of = |h: usize| -> Vec<BorderSample> {
        let Some(g3) = (first_of[h] != u32::MAX).then_some(first_of[h] as usize) else {
            return Vec::new();
        };
        let (f, k) = (h / 3, h % 3);
        let (g, gk) = (g3 / 3, g3 % 3);
        let fv = mesh.faces[f];
        let a = fv[k].0;
        // Texture coordinates of a then b on a face, and its third corner.
        let side = |face: usize, corner: usize| {
            let c = uv.faces[face];
            let (ca, cb) = (c[corner], c[(corner + 1) % 3]);
            let ab = if mesh.faces[face][corner].0 == a {
                [ca, cb]
            } else {
                [cb, ca]
            };
            (ab, c[(corner + 2) % 3])
        };
        let (i1, o1) = side(f, k);
        let (i2, o2) = side(g, gk);
        if i1 == i2 {
            return Vec::new(); // not a border: the same texture coordinates on both faces
        }
        let (a1, b1, a2, b2) = (texel(i1[0]), texel(i1[1]), texel(i2[0]), texel(i2[1]));
        let (p1, p2) = (texel(o1), texel(o2));
        if ![a1, b1, p1, a2, b2, p2].into_iter().all(on_page) {
            return Vec::new();
        }
        let (Some(n1), Some(n2)) = (inward(a1, b1, p1), inward(a2, b2, p2)) else {
            return Vec::new();
        };
        let m = ((b1 - a1).norm().max((b2 - a2).norm()).ceil() as usize).max(1);
        (0..m)
            .map(|j| {
                let t = (j as f64 + 0.5) / m as f64;
                BorderSample {
                    faces: [f, g],
                    uv: [i1, i2],
                    t,
                    at: [a1 + (b1 - a1) * t, a2 + (b2 - a2) * t],
                    inward: [n1, n2],
                }
            })
            .collect()
    };
    // In half-edge order, as a walk over the faces would emit them.
    (0..3 * nf)
        .into_par_iter()
        .flat_map_iter(samples_of)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The samples a walk over the faces gives, remembering each edge's first half-edge in a
    /// map (what [`border_samples`] did before it sorted): the same samples in the same order.
    #[test]
    fn border_samples_match_a_walk_over_the_faces() {
        let (torus, _) = crate::sample::dented_torus(40, 16, (6, 6));
        let opts = crate::atlas::AtlasOptions {
            pack: crate::atlas::pack::PackOptions {
                size: 512,
                ..Default::default()
            },
            ..Default::default()
        };
        let (mut mesh, _) = crate::atlas::parameterize(&torus, &opts).unwrap();
        // A third face on one edge (non-manifold), and a face with a repeated corner.
        let f0 = mesh.faces[0];
        mesh.faces.push([f0[1], f0[0], f0[2]]);
        mesh.faces.push([f0[0], f0[0], f0[1]]);
        // The third face has texture coordinates of its own, so its edges are borders with
        // both faces it meets.
        let uv = mesh.uv.as_mut().unwrap();
        let c0 = uv.faces[0];
        let base = uv.coords.len() as u32;
        for &c in &[c0[1], c0[0], c0[2]] {
            let p = uv.coords[c as usize];
            uv.coords
                .push(p * 0.999 + nalgebra::Vector2::repeat(0.0004));
        }
        uv.faces.push([base, base + 1, base + 2]);
        uv.faces.push([c0[0], c0[0], c0[1]]);
        let n = 512;
        let got = border_samples(&mesh, n);
        let uv = mesh.uv.as_ref().unwrap();
        let mut first: std::collections::HashMap<(u32, u32), (usize, usize)> = Default::default();
        let mut want = Vec::new();
        for (f, fv) in mesh.faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (fv[k].0, fv[(k + 1) % 3].0);
                let Some(&(g, gk)) = first.get(&(a.min(b), a.max(b))) else {
                    first.insert((a.min(b), a.max(b)), (f, k));
                    continue;
                };
                let side = |face: usize, corner: usize| {
                    let c = uv.faces[face];
                    let (ca, cb) = (c[corner], c[(corner + 1) % 3]);
                    if mesh.faces[face][corner].0 == a {
                        [ca, cb]
                    } else {
                        [cb, ca]
                    }
                };
                let (i1, i2) = (side(f, k), side(g, gk));
                if i1 != i2 {
                    want.push(([f, g], [i1, i2]));
                }
            }
        }
        // Every border edge of the walk, in its order (each sampled at least once; edges off
        // the page or degenerate are dropped by both).
        let mut edges: Vec<([usize; 2], [[u32; 2]; 2])> =
            got.iter().map(|b| (b.faces, b.uv)).collect();
        edges.dedup();
        let kept: Vec<_> = want.iter().filter(|e| edges.contains(e)).cloned().collect();
        assert_eq!(edges, kept);
        assert!(
            edges.len() > 50 && edges.len() + 2 >= want.len(),
            "{} of {}",
            edges.len(),
            want.len()
        );
        for b in &got {
            assert!(b.t > 0.0 && b.t < 1.0);
            assert!(
                (b.inward[0].norm() - 1.0).abs() < 1e-9 && (b.inward[1].norm() - 1.0).abs() < 1e-9
            );
        }
    }
}
