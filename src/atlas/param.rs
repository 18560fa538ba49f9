//! Per-chart flattening (issue 4, step 2): a flip-free starting map and Sander et al.'s
//! stretch measures; [`super::optimize`] then minimises the paper's stretch from it.
//!
//! The start, first that is one-to-one: orthogonal projection onto the chart's mean-normal
//! plane (isometric for planar charts); the least-squares conformal map (free boundary, good for
//! long or curved charts); Floater's mean-value embedding with the boundary on a circle by arc
//! length, one-to-one for any disk (positive weights, convex boundary: Floater 2003).

use crate::mesh::{FaceId, Mesh, VertexId};
use nalgebra::{Point3, Vector2, Vector3};
use rustc_hash::FxHashMap;

/// A flattened chart with its own vertex numbering.
#[derive(Debug, Clone, PartialEq)]
pub struct ChartMap {
    /// Global vertex of each local vertex.
    pub vertices: Vec<VertexId>,
    /// UV of each local vertex (chart units: 3D length for an isometric map).
    pub uv: Vec<Vector2<f64>>,
    /// Faces in local vertex indices, in the order of `face_ids`.
    pub faces: Vec<[u32; 3]>,
    /// The mesh face of each local face.
    pub face_ids: Vec<FaceId>,
}

/// Signed area of a UV triangle (positive when counter-clockwise).
pub fn uv_area(q: [Vector2<f64>; 3]) -> f64 {
    0.5 * (q[1] - q[0]).perp(&(q[2] - q[0]))
}

/// Smallest height/base ratio of a triangle of area `area` and squared edge lengths `e2`:
/// `2 A / (longest edge)^2`, 0 for a point. One square root of the largest instead of three
/// (the same value: the square root is monotone and correctly rounded); this runs for every
/// triangle at every step of the stretch minimisation.
fn height_base(area: f64, e2: [f64; 3]) -> f64 {
    let m = e2.iter().cloned().fold(0.0, f64::max).sqrt();
    if m > 0.0 {
        2.0 * area / (m * m)
    } else {
        0.0
    }
}

/// Smallest height/base ratio of a UV triangle (negative if it is flipped).
pub fn height_base_2d(q: [Vector2<f64>; 3]) -> f64 {
    height_base(
        uv_area(q),
        [
            (q[1] - q[0]).norm_squared(),
            (q[2] - q[1]).norm_squared(),
            (q[0] - q[2]).norm_squared(),
        ],
    )
}

/// Smallest height/base ratio of a 3D triangle.
pub fn height_base_3d(p: [Point3<f64>; 3]) -> f64 {
    let area = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
    height_base(
        area,
        [
            (p[1] - p[0]).norm_squared(),
            (p[2] - p[1]).norm_squared(),
            (p[0] - p[2]).norm_squared(),
        ],
    )
}

/// Stretch of one triangle (Sander et al. 2001), from its 3D and 2D corners.
/// Returns `(L2, L-infinity, signed 2D area)`; non-finite stretch for a flipped or degenerate
/// 2D triangle.
pub fn triangle_stretch(p: [Point3<f64>; 3], q: [Vector2<f64>; 3]) -> (f64, f64, f64) {
    let area2 = uv_area(q);
    if area2 <= 0.0 {
        return (f64::INFINITY, f64::INFINITY, area2);
    }
    let (s, t) = (q.map(|v| v.x), q.map(|v| v.y));
    let ss: Vector3<f64> =
        (p[0].coords * (t[1] - t[2]) + p[1].coords * (t[2] - t[0]) + p[2].coords * (t[0] - t[1]))
            / (2.0 * area2);
    let st: Vector3<f64> =
        (p[0].coords * (s[2] - s[1]) + p[1].coords * (s[0] - s[2]) + p[2].coords * (s[1] - s[0]))
            / (2.0 * area2);
    let (a, b, c) = (ss.dot(&ss), ss.dot(&st), st.dot(&st));
    let l2 = ((a + c) / 2.0).sqrt();
    let linf = (((a + c) + ((a - c).powi(2) + 4.0 * b * b).sqrt()) / 2.0).sqrt();
    (l2, linf, area2)
}

/// Stretch of a whole map, with Sander's normalisation: the 2D domain is scaled so its total
/// area equals the total 3D area, so an isometry scores exactly 1.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Stretch {
    /// `sqrt(sum L2(T)^2 A3(T) / sum A3(T))` after normalisation.
    pub l2: f64,
    /// Largest per-triangle L-infinity stretch after normalisation.
    pub linf: f64,
    /// UV triangles with negative signed area.
    pub flipped: usize,
    /// UV triangles with zero area.
    pub zero_area: usize,
}

/// Stretch of `maps` taken together (one normalisation for all of them).
pub fn stretch(mesh: &Mesh, maps: &[ChartMap]) -> Stretch {
    stretch_of(
        maps.iter().flat_map(|m| {
            m.face_ids
                .iter()
                .zip(&m.faces)
                .map(|(f, lf)| (*f, lf.map(|i| m.uv[i as usize])))
        }),
        mesh,
    )
}

/// Stretch of a mesh's per-corner UVs (one normalisation for the whole atlas, all pages).
pub fn stretch_uv(mesh: &Mesh, uv: &crate::mesh::UvMap) -> Stretch {
    stretch_of(
        uv.faces.iter().enumerate().map(|(f, t)| {
            (
                FaceId(f as u32),
                t.map(|i| uv.coords[i as usize].cast::<f64>()),
            )
        }),
        mesh,
    )
}

fn stretch_of(faces: impl Iterator<Item = (FaceId, [Vector2<f64>; 3])>, mesh: &Mesh) -> Stretch {
    let (mut a3, mut a2) = (0.0, 0.0);
    let mut tris = Vec::new();
    let (mut flipped, mut zero_area) = (0, 0);
    for (f, q) in faces {
        let p = mesh.triangle(f);
        let area3 = mesh.face_area(f);
        let (_, _, area2) = triangle_stretch(p, q);
        if area2 < 0.0 {
            flipped += 1;
        } else if area2 == 0.0 {
            zero_area += 1;
        }
        a3 += area3;
        a2 += area2.abs();
        tris.push((p, q, area3));
    }
    // Scaling the domain by k divides stretch by k: normalise with k = sqrt(A2 / A3).
    let k = if a3 > 0.0 { (a2 / a3).sqrt() } else { 1.0 };
    let (mut num, mut linf) = (0.0, 0.0f64);
    // Zero-area UV triangles have no finite stretch: they are counted in `zero_area` and left
    // out of L2 and L-infinity (as their 3D area is).
    let mut a3_used = 0.0;
    for (p, q, area3) in tris {
        let (l2, li, a2) = triangle_stretch(p, q.map(|v| v / k));
        if a2 != 0.0 && l2.is_finite() {
            num += l2 * l2 * area3;
            a3_used += area3;
            linf = linf.max(li);
        }
    }
    Stretch {
        l2: if a3_used > 0.0 {
            (num / a3_used).sqrt()
        } else {
            f64::NAN
        },
        linf,
        flipped,
        zero_area,
    }
}

/// Flattens one disk-shaped chart (see the module docs). The chart must be a disk
/// ([`super::segment::is_disk`]).
pub fn flatten(mesh: &Mesh, faces: &[FaceId]) -> ChartMap {
    let mut local: FxHashMap<u32, u32> = FxHashMap::default();
    let mut vertices = Vec::new();
    let lf: Vec<[u32; 3]> = faces
        .iter()
        .map(|f| {
            mesh.faces[f.idx()].map(|v| {
                *local.entry(v.0).or_insert_with(|| {
                    vertices.push(v);
                    vertices.len() as u32 - 1
                })
            })
        })
        .collect();
    let pos: Vec<Point3<f64>> = vertices.iter().map(|v| mesh.positions[v.idx()]).collect();
    // Every chart is scaled so its 2D area equals its 3D area: packing decides the relative
    // scale of charts later, and stretch figures compare shapes, not units.
    let area3: f64 = faces.iter().map(|f| mesh.face_area(*f)).sum();
    let map = |uv: Vec<Vector2<f64>>| {
        let area2: f64 = lf.iter().map(|t| uv_area(t.map(|i| uv[i as usize]))).sum();
        let k = if area2 > 0.0 && area3 > 0.0 {
            (area3 / area2).sqrt()
        } else {
            1.0
        };
        ChartMap {
            vertices: vertices.clone(),
            uv: uv.into_iter().map(|v| v * k).collect(),
            faces: lf.clone(),
            face_ids: faces.to_vec(),
        }
    };
    // 1. Projection onto the mean-normal plane, if every triangle keeps its orientation and
    //    no triangle is squashed (area ratio above 0.5 of its 3D area).
    let n: Vector3<f64> = faces.iter().map(|f| mesh.face_normal_area(*f)).sum();
    if let Some(n) = n.try_normalize(1e-300) {
        let e1 = n
            .cross(&if n.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            })
            .normalize();
        let e2 = n.cross(&e1);
        let uv: Vec<Vector2<f64>> = pos
            .iter()
            .map(|p| Vector2::new(p.coords.dot(&e1), p.coords.dot(&e2)))
            .collect();
        let ok = lf.iter().zip(faces).all(|(t, f)| {
            let q = t.map(|i| uv[i as usize]);
            uv_area(q) > 0.5 * mesh.face_area(*f)
        });
        if ok && !boundary_self_intersects(&lf, &uv) {
            return map(uv);
        }
    }
    // 2. Least-squares conformal map (free boundary), if it is one-to-one: far better than a
    //    circle for long or branching charts, but not guaranteed flip-free.
    if let Some(uv) = lscm(&lf, &pos) {
        let ok = lf.iter().all(|t| {
            let q = t.map(|i| uv[i as usize]);
            uv_area(q) > 0.0
        });
        if ok && !boundary_self_intersects(&lf, &uv) {
            return map(uv);
        }
    }
    // 3. Mean-value embedding with the boundary on a circle: always one-to-one.
    map(mean_value_embedding(&lf, &pos))
}

/// Least-squares conformal map (Levy et al. 2002) with the two boundary vertices farthest
/// apart pinned, solved through the normal equations by sparse Cholesky. `None` if the system
/// is degenerate.
fn lscm(faces: &[[u32; 3]], pos: &[Point3<f64>]) -> Option<Vec<Vector2<f64>>> {
    let n = pos.len();
    let next = boundary_next(faces);
    let bverts: Vec<u32> = {
        let mut b: Vec<u32> = next.keys().copied().collect();
        b.sort();
        b
    };
    if bverts.len() < 2 {
        return None;
    }
    // Pins: an extreme boundary vertex and the boundary vertex farthest from it.
    let far = |from: u32| -> u32 {
        *bverts
            .iter()
            .max_by(|&&a, &&b| {
                (pos[a as usize] - pos[from as usize])
                    .norm()
                    .total_cmp(&(pos[b as usize] - pos[from as usize]).norm())
                    .then(b.cmp(&a))
            })
            .unwrap()
    };
    let p0 = far(bverts[0]);
    let p1 = far(p0);
    if p0 == p1 {
        return None;
    }
    let d = (pos[p1 as usize] - pos[p0 as usize]).norm();
    let mut pinned: FxHashMap<u32, Vector2<f64>> = FxHashMap::default();
    pinned.insert(p0, Vector2::zeros());
    pinned.insert(p1, Vector2::new(d, 0.0));
    // Unknown index of each free vertex (u and v interleaved).
    let mut idx = vec![usize::MAX; n];
    let mut m = 0;
    for (i, slot) in idx.iter_mut().enumerate() {
        if !pinned.contains_key(&(i as u32)) {
            *slot = m;
            m += 1;
        }
    }
    // Per triangle: coefficients (a_k, b_k) of the complex residual sum_k (a_k + i b_k) U_k.
    let coeffs: Vec<[(f64, f64); 3]> = faces
        .iter()
        .map(|t| {
            let p = t.map(|i| pos[i as usize]);
            let e1 = p[1] - p[0];
            let n3 = e1.cross(&(p[2] - p[0]));
            let area = 0.5 * n3.norm();
            let x = e1.normalize();
            let y = n3.normalize().cross(&x);
            let l = [
                Vector2::zeros(),
                Vector2::new(e1.norm(), 0.0),
                Vector2::new((p[2] - p[0]).dot(&x), (p[2] - p[0]).dot(&y)),
            ];
            let s = 1.0 / (2.0 * area.max(1e-300)).sqrt();
            std::array::from_fn(|k| {
                let w = l[(k + 2) % 3] - l[(k + 1) % 3];
                (w.x * s, w.y * s)
            })
        })
        .collect();
    // Residual rows: r1 = sum a u - b v, r2 = sum b u + a v.
    let apply = |x: &[f64], out: &mut Vec<f64>, fixed: bool| {
        out.clear();
        for (t, c) in faces.iter().zip(&coeffs) {
            let (mut r1, mut r2) = (0.0, 0.0);
            for k in 0..3 {
                let vi = t[k] as usize;
                let (u, v) = if idx[vi] == usize::MAX {
                    if !fixed {
                        continue;
                    }
                    let p = pinned[&t[k]];
                    (p.x, p.y)
                } else {
                    if fixed {
                        continue;
                    }
                    (x[2 * idx[vi]], x[2 * idx[vi] + 1])
                };
                let (a, b) = c[k];
                r1 += a * u - b * v;
                r2 += b * u + a * v;
            }
            out.push(r1);
            out.push(r2);
        }
    };
    let apply_t = |r: &[f64], out: &mut Vec<f64>| {
        out.clear();
        out.resize(2 * m, 0.0);
        for (fi, (t, c)) in faces.iter().zip(&coeffs).enumerate() {
            let (r1, r2) = (r[2 * fi], r[2 * fi + 1]);
            for k in 0..3 {
                let vi = t[k] as usize;
                if idx[vi] == usize::MAX {
                    continue;
                }
                let (a, b) = c[k];
                out[2 * idx[vi]] += a * r1 + b * r2;
                out[2 * idx[vi] + 1] += -b * r1 + a * r2;
            }
        }
    };
    // Normal equations A^T A x = -A^T (A_fixed p).
    let mut tmp = Vec::new();
    apply(&[], &mut tmp, true);
    let mut rhs = Vec::new();
    apply_t(&tmp, &mut rhs);
    for v in &mut rhs {
        *v = -*v;
    }
    // Assemble the lower triangle of A^T A: each triangle's two residual rows touch at most six
    // unknowns, so it adds a 6 x 6 block. Then a sparse Cholesky factorisation (faer, with a
    // fill-reducing ordering) solves it exactly, in time close to linear for surface meshes;
    // conjugate gradients needed thousands of iterations on charts of 10^5 vertices.
    use faer::linalg::solvers::Solve;
    let a = lscm_normal_matrix(faces, &coeffs, &idx, m)?;
    let llt = a.sp_cholesky(faer::Side::Lower).ok()?;
    let x = llt.solve(faer::Mat::<f64>::from_fn(2 * m, 1, |i, _| rhs[i]));
    let x: Vec<f64> = (0..2 * m).map(|i| x[(i, 0)]).collect();
    if x.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let uv: Vec<Vector2<f64>> = (0..n)
        .map(|i| match pinned.get(&(i as u32)) {
            Some(p) => *p,
            None => Vector2::new(x[2 * idx[i]], x[2 * idx[i] + 1]),
        })
        .collect();
    // LSCM may come out mirrored: flip v if most area is negative.
    let signed: f64 = faces
        .iter()
        .map(|t| uv_area(t.map(|i| uv[i as usize])))
        .sum();
    Some(if signed < 0.0 {
        uv.into_iter().map(|v| Vector2::new(v.x, -v.y)).collect()
    } else {
        uv
    })
}

/// The lower triangle of LSCM's normal matrix `A^T A` in compressed columns, built directly:
/// free vertex `p` owns columns `2p` (u) and `2p + 1` (v), whose rows are its own 2 x 2
/// block's lower triangle and then, for each free neighbour `q > p` in order, rows `2q` and
/// `2q + 1`. Building it from one triplet per block entry (21 per triangle) spent about a
/// third of LSCM's time in the triplets' sort (`docs/decisions.md`, "LSCM's matrix built in
/// columns"). `coeffs` are each triangle's residual coefficients, `idx` each vertex's unknown
/// (`usize::MAX` if pinned). `None` if its entries do not fit `u32` indices.
fn lscm_normal_matrix(
    faces: &[[u32; 3]],
    coeffs: &[[(f64, f64); 3]],
    idx: &[usize],
    m: usize,
) -> Option<faer::sparse::SparseColMat<u32, f64>> {
    use faer::sparse::{SparseColMat, SymbolicSparseColMat};
    let free = |t: &[u32; 3]| t.map(|v| idx[v as usize]);
    // Neighbours q > p of each free vertex p: counted, filled, then sorted and deduplicated
    // in place (each list holds a vertex's few edges, so the sorts are short).
    let mut start = vec![0usize; m + 1];
    for t in faces {
        let f = free(t);
        for a in 0..3 {
            for b in 0..3 {
                if f[a] != usize::MAX && f[b] != usize::MAX && f[a] < f[b] {
                    start[f[a] + 1] += 1;
                }
            }
        }
    }
    for p in 0..m {
        start[p + 1] += start[p];
    }
    let mut nb = vec![0u32; start[m]];
    let mut fill = start.clone();
    for t in faces {
        let f = free(t);
        for a in 0..3 {
            for b in 0..3 {
                if f[a] != usize::MAX && f[b] != usize::MAX && f[a] < f[b] {
                    nb[fill[f[a]]] = f[b] as u32;
                    fill[f[a]] += 1;
                }
            }
        }
    }
    let mut deg = vec![0usize; m + 1];
    let mut out = 0;
    for p in 0..m {
        let list = &mut nb[start[p]..start[p + 1]];
        list.sort_unstable();
        let mut k = 0;
        for i in 0..list.len() {
            if i == 0 || list[i] != list[i - 1] {
                list[k] = list[i];
                k += 1;
            }
        }
        nb.copy_within(start[p]..start[p] + k, out);
        deg[p + 1] = deg[p] + k;
        out += k;
    }
    nb.truncate(out);
    if 3 * m + 4 * out >= u32::MAX as usize {
        return None;
    }
    // Each free vertex's two columns, u then v.
    let mut col_ptr = Vec::with_capacity(2 * m + 1);
    let mut row_idx = Vec::with_capacity(2 * m + 4 * out);
    col_ptr.push(0u32);
    for p in 0..m {
        let list = &nb[deg[p]..deg[p + 1]];
        for s in 0..2 {
            row_idx.extend((s..2).map(|r| (2 * p + r) as u32));
            for &q in list {
                row_idx.extend([2 * q, 2 * q + 1]);
            }
            col_ptr.push(row_idx.len() as u32);
        }
    }
    let mut val = vec![0f64; row_idx.len()];
    for (t, c) in faces.iter().zip(coeffs) {
        let f = free(t);
        for (ka, &p) in f.iter().enumerate() {
            if p == usize::MAX {
                continue;
            }
            for (kb, &q) in f.iter().enumerate() {
                if q == usize::MAX || q < p {
                    continue;
                }
                // Rows (q's u, q's v) against columns (p's u, p's v): the coefficients of
                // u and v in the residual rows r1 and r2 are (a, b) and (-b, a).
                let (a1, b1) = c[ka];
                let (a2, b2) = c[kb];
                let colp = [(a1, b1), (-b1, a1)];
                let rowq = [(a2, b2), (-b2, a2)];
                // The neighbour's place in p's list; None for p's own block.
                let k =
                    (q != p).then(|| nb[deg[p]..deg[p + 1]].partition_point(|&x| (x as usize) < q));
                for (sc, &(ci1, ci2)) in colp.iter().enumerate() {
                    let base = col_ptr[2 * p + sc] as usize;
                    for (sr, &(ri1, ri2)) in rowq.iter().enumerate() {
                        let at = match k {
                            // The own block's lower triangle only.
                            None if sr < sc => continue,
                            None => base + sr - sc,
                            Some(k) => base + (2 - sc) + 2 * k + sr,
                        };
                        val[at] += ri1 * ci1 + ri2 * ci2;
                    }
                }
            }
        }
    }
    let symbolic = SymbolicSparseColMat::new_checked(2 * m, 2 * m, col_ptr, None, row_idx);
    Some(SparseColMat::new(symbolic, val))
}

/// Directed boundary edges of a disk's faces, as a map from start to end vertex.
fn boundary_next(faces: &[[u32; 3]]) -> FxHashMap<u32, u32> {
    let mut directed: FxHashMap<(u32, u32), u32> = FxHashMap::default();
    for t in faces {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    directed
        .keys()
        .filter(|(a, b)| !directed.contains_key(&(*b, *a)))
        .map(|&(a, b)| (a, b))
        .collect()
}

/// True if two boundary edges of the map cross (a projection can fold over itself at the
/// border even when every triangle keeps its orientation).
pub(crate) fn boundary_self_intersects(faces: &[[u32; 3]], uv: &[Vector2<f64>]) -> bool {
    edges_cross(&boundary_edges(faces), uv)
}

/// The directed boundary edges of a chart, sorted.
pub(crate) fn boundary_edges(faces: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut edges: Vec<(u32, u32)> = boundary_next(faces).into_iter().collect();
    edges.sort_unstable();
    edges
}

/// True if two of `edges` (sharing no vertex) cross.
pub(crate) fn edges_cross(edges: &[(u32, u32)], uv: &[Vector2<f64>]) -> bool {
    if edges.len() < 4 {
        return false;
    }
    // Bucket the edges in a uniform grid of about one edge per cell, then test only pairs that
    // share a cell: linear in the border length for the borders charts have.
    let lo = edges.iter().fold(Vector2::repeat(f64::INFINITY), |a, e| {
        a.inf(&uv[e.0 as usize])
    });
    let hi = edges
        .iter()
        .fold(Vector2::repeat(f64::NEG_INFINITY), |a, e| {
            a.sup(&uv[e.0 as usize])
        });
    let cells = (edges.len() as f64).sqrt().ceil().max(1.0);
    let ext = (hi - lo).max().max(1e-300);
    let cell = ext / cells;
    let dim = cells as usize + 1;
    let key = |p: Vector2<f64>| {
        let c = ((p - lo) / cell).map(|v| (v.max(0.0) as usize).min(dim - 1));
        (c.x, c.y)
    };
    // Cells as one flat array (counting sort): this runs at every line-search step of the
    // stretch minimisation, where a hash map per call cost more than the tests themselves.
    let cell_range = |&(a, b): &(u32, u32)| {
        let (ka, kb) = (key(uv[a as usize]), key(uv[b as usize]));
        (
            ka.0.min(kb.0)..=ka.0.max(kb.0),
            ka.1.min(kb.1)..=ka.1.max(kb.1),
        )
    };
    let mut start = vec![0u32; dim * dim + 1];
    for e in edges {
        let (xs, ys) = cell_range(e);
        for x in xs {
            for y in ys.clone() {
                start[x * dim + y + 1] += 1;
            }
        }
    }
    for c in 1..start.len() {
        start[c] += start[c - 1];
    }
    let mut fill = start.clone();
    let mut slots = vec![0u32; start[dim * dim] as usize];
    for (i, e) in edges.iter().enumerate() {
        let (xs, ys) = cell_range(e);
        for x in xs {
            for y in ys.clone() {
                let c = x * dim + y;
                slots[fill[c] as usize] = i as u32;
                fill[c] += 1;
            }
        }
    }
    let cross = |a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>| (b - a).perp(&(c - a));
    for c in 0..dim * dim {
        let list = &slots[start[c] as usize..start[c + 1] as usize];
        for (n, &i) in list.iter().enumerate() {
            let (a, b) = edges[i as usize];
            for &j in &list[n + 1..] {
                let (c, d) = edges[j as usize];
                if a == c || a == d || b == c || b == d {
                    continue;
                }
                let (pa, pb, pc, pd) = (
                    uv[a as usize],
                    uv[b as usize],
                    uv[c as usize],
                    uv[d as usize],
                );
                let (d1, d2) = (cross(pc, pd, pa), cross(pc, pd, pb));
                let (d3, d4) = (cross(pa, pb, pc), cross(pa, pb, pd));
                if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
                    return true;
                }
            }
        }
    }
    false
}

/// Floater's mean-value embedding: boundary on a circle (by arc length, counter-clockwise),
/// each interior vertex the mean-value-weighted average of its neighbours. Solved by sparse
/// LU ([`solve_direct`]), or by BiCGSTAB with a Jacobi preconditioner where that fails.
fn mean_value_embedding(faces: &[[u32; 3]], pos: &[Point3<f64>]) -> Vec<Vector2<f64>> {
    let n = pos.len();
    let next = boundary_next(faces);
    let mut uv = vec![Vector2::zeros(); n];
    let mut fixed = vec![false; n];
    // Walk the loop; a disk has exactly one.
    let start = *next.keys().min().expect("a disk has a boundary");
    let mut lp = vec![start];
    let mut v = next[&start];
    while v != start && lp.len() <= next.len() {
        lp.push(v);
        v = next[&v];
    }
    let len: Vec<f64> = (0..lp.len())
        .map(|i| (pos[lp[(i + 1) % lp.len()] as usize] - pos[lp[i] as usize]).norm())
        .collect();
    let total: f64 = len.iter().sum();
    let radius = total / std::f64::consts::TAU;
    let mut acc = 0.0;
    for (i, &b) in lp.iter().enumerate() {
        let a = std::f64::consts::TAU * acc / total;
        uv[b as usize] = Vector2::new(a.cos(), a.sin()) * radius;
        fixed[b as usize] = true;
        acc += len[i];
    }
    // Mean-value weights: w_ij = (tan(a/2) + tan(b/2)) / |p_i - p_j|, angles at i.
    let mut w: FxHashMap<(u32, u32), f64> = FxHashMap::default();
    for t in faces {
        for k in 0..3 {
            let (i, j, l) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (pi, pj, pl) = (pos[i as usize], pos[j as usize], pos[l as usize]);
            let (eij, eil) = (pj - pi, pl - pi);
            let angle = eij.angle(&eil);
            let th = (angle / 2.0).tan();
            let (dij, dil) = (eij.norm().max(1e-300), eil.norm().max(1e-300));
            *w.entry((i, j)).or_insert(0.0) += th / dij;
            *w.entry((i, l)).or_insert(0.0) += th / dil;
        }
    }
    let interior: Vec<u32> = (0..n as u32).filter(|&i| !fixed[i as usize]).collect();
    if interior.is_empty() {
        return uv;
    }
    let index: FxHashMap<u32, usize> = interior.iter().enumerate().map(|(k, &i)| (i, k)).collect();
    // Rows: diag * x_i - sum_j w_ij x_j = sum_{j fixed} w_ij u_j.
    let m = interior.len();
    let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m];
    let mut diag = vec![0.0; m];
    let mut rhs = vec![Vector2::zeros(); m];
    let mut keys: Vec<&(u32, u32)> = w.keys().collect();
    keys.sort();
    for &(i, j) in keys {
        let wij = w[&(i, j)];
        let Some(&r) = index.get(&i) else { continue };
        diag[r] += wij;
        match index.get(&j) {
            Some(&c) => rows[r].push((c, wij)),
            None => rhs[r] += uv[j as usize] * wij,
        }
    }
    let x = solve_direct(&rows, &diag, &rhs).unwrap_or_else(|| {
        let per_dim: [Vec<f64>; 2] = std::array::from_fn(|dim| {
            let b: Vec<f64> = rhs.iter().map(|v| v[dim]).collect();
            bicgstab(&rows, &diag, &b)
        });
        (0..m)
            .map(|k| Vector2::new(per_dim[0][k], per_dim[1][k]))
            .collect()
    });
    for (k, &i) in interior.iter().enumerate() {
        uv[i as usize] = x[k];
    }
    uv
}

/// Solves `(D - W) x = b` for both coordinates at once by sparse LU (faer, with a
/// fill-reducing ordering): close to linear time on surface meshes, where the iterative
/// solver below needed tens of thousands of iterations on the largest charts of a 10M-face
/// scan (the mean-value weights are not symmetric, so there is no Cholesky). `None` if the
/// factorisation fails or gives a non-finite value.
fn solve_direct(
    rows: &[Vec<(usize, f64)>],
    diag: &[f64],
    rhs: &[Vector2<f64>],
) -> Option<Vec<Vector2<f64>>> {
    use faer::linalg::solvers::Solve;
    use faer::sparse::{SparseColMat, Triplet};
    let m = diag.len();
    let mut trip: Vec<Triplet<u32, u32, f64>> =
        Vec::with_capacity(m + rows.iter().map(Vec::len).sum::<usize>());
    for (r, row) in rows.iter().enumerate() {
        trip.push(Triplet::new(r as u32, r as u32, diag[r]));
        for &(c, w) in row {
            trip.push(Triplet::new(r as u32, c as u32, -w));
        }
    }
    let a = SparseColMat::<u32, f64>::try_new_from_triplets(m, m, &trip).ok()?;
    drop(trip);
    let lu = a.sp_lu().ok()?;
    let x = lu.solve(faer::Mat::<f64>::from_fn(m, 2, |i, d| rhs[i][d]));
    let out: Vec<Vector2<f64>> = (0..m).map(|i| Vector2::new(x[(i, 0)], x[(i, 1)])).collect();
    out.iter()
        .all(|v| v.x.is_finite() && v.y.is_finite())
        .then_some(out)
}

/// Solves `(D - W) x = b` (D diagonal, W the off-diagonal weights) by Jacobi-preconditioned
/// BiCGSTAB to a relative residual of 1e-12.
fn bicgstab(rows: &[Vec<(usize, f64)>], diag: &[f64], b: &[f64]) -> Vec<f64> {
    let n = b.len();
    let apply = |x: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|i| diag[i] * x[i] - rows[i].iter().map(|&(j, w)| w * x[j]).sum::<f64>())
            .collect()
    };
    let precond = |r: &[f64]| -> Vec<f64> { (0..n).map(|i| r[i] / diag[i]).collect() };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut x = precond(b);
    let ax = apply(&x);
    let mut r: Vec<f64> = (0..n).map(|i| b[i] - ax[i]).collect();
    let r0 = r.clone();
    let bnorm = dot(b, b).sqrt().max(1e-300);
    let (mut rho, mut alpha, mut omega) = (1.0, 1.0, 1.0);
    let mut v = vec![0.0; n];
    let mut p = vec![0.0; n];
    for _ in 0..10 * n + 100 {
        if dot(&r, &r).sqrt() / bnorm < 1e-12 {
            break;
        }
        let rho1 = dot(&r0, &r);
        if rho1.abs() < 1e-300 {
            break;
        }
        let beta = (rho1 / rho) * (alpha / omega);
        rho = rho1;
        for i in 0..n {
            p[i] = r[i] + beta * (p[i] - omega * v[i]);
        }
        let ph = precond(&p);
        v = apply(&ph);
        alpha = rho / dot(&r0, &v);
        let s: Vec<f64> = (0..n).map(|i| r[i] - alpha * v[i]).collect();
        let sh = precond(&s);
        let t = apply(&sh);
        let tt = dot(&t, &t);
        omega = if tt > 0.0 { dot(&t, &s) / tt } else { 0.0 };
        for i in 0..n {
            x[i] += alpha * ph[i] + omega * sh[i];
            r[i] = s[i] - omega * t[i];
        }
        if omega == 0.0 {
            break;
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::segment::{segment, SegmentOptions};

    /// LSCM's matrix built in columns holds the entries that faer builds from one triplet per
    /// block entry (the old assembly), with the same values up to the order of the sums, on
    /// a polar grid with unknowns numbered out of vertex order, two pinned vertices and a
    /// degenerate triangle that repeats a vertex.
    #[test]
    fn lscm_matrix_in_columns_matches_triplets() {
        use faer::sparse::{SparseColMat, Triplet};
        let mesh = crate::atlas::test_meshes::polar_grid(5, 16, |r, k| {
            Point3::new(r as f64, k as f64, 0.0)
        });
        let mut faces: Vec<[u32; 3]> = mesh.faces.iter().map(|f| f.map(|v| v.0)).collect();
        faces.push([3, 7, 3]);
        let n = mesh.positions.len();
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut unit = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        let coeffs: Vec<[(f64, f64); 3]> = faces
            .iter()
            .map(|_| std::array::from_fn(|_| (unit(), unit())))
            .collect();
        // Unknowns in reverse vertex order, vertices 0 and 5 pinned.
        let mut idx = vec![usize::MAX; n];
        let mut m = 0;
        for v in (0..n).rev() {
            if v != 0 && v != 5 {
                idx[v] = m;
                m += 1;
            }
        }
        let mut trip = Vec::new();
        for (t, c) in faces.iter().zip(&coeffs) {
            let mut cols: Vec<(u32, f64, f64)> = Vec::new();
            for k in 0..3 {
                let vi = t[k] as usize;
                if idx[vi] != usize::MAX {
                    let (a, b) = c[k];
                    cols.push((2 * idx[vi] as u32, a, b));
                    cols.push((2 * idx[vi] as u32 + 1, -b, a));
                }
            }
            for &(i, ri1, ri2) in &cols {
                for &(j, rj1, rj2) in &cols {
                    if i >= j {
                        trip.push(Triplet::new(i, j, ri1 * rj1 + ri2 * rj2));
                    }
                }
            }
        }
        let want = SparseColMat::<u32, f64>::try_new_from_triplets(2 * m, 2 * m, &trip).unwrap();
        let got = lscm_normal_matrix(&faces, &coeffs, &idx, m).unwrap();
        assert_eq!(got.symbolic().col_ptr(), want.symbolic().col_ptr());
        assert_eq!(got.symbolic().row_idx(), want.symbolic().row_idx());
        for (g, w) in got.val().iter().zip(want.val()) {
            assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "{g} against {w}");
        }
    }

    /// A planar disk (a triangulated polygon in a tilted plane) maps isometrically.
    #[test]
    fn planar_disk_maps_isometrically() {
        let mesh = crate::atlas::test_meshes::polar_grid(6, 24, |r, k| {
            let a = std::f64::consts::TAU * k as f64 / 24.0;
            let (x, y) = (r as f64 * a.cos(), r as f64 * a.sin());
            // Plane tilted about the x axis, with a little jitter inside the plane.
            let j = 0.1 * ((k * 7 + r * 3) % 5) as f64 / 5.0;
            Point3::new(x + j, (y - j) * 0.6, (y - j) * 0.8)
        });
        let all: Vec<FaceId> = (0..mesh.num_faces() as u32).map(FaceId).collect();
        let s = stretch(&mesh, &[flatten(&mesh, &all)]);
        assert!(
            (s.l2 - 1.0).abs() < 1e-3 && (s.linf - 1.0).abs() < 1e-3,
            "{s:?}"
        );
        assert_eq!((s.flipped, s.zero_area), (0, 0));
    }

    /// Every chart of curved meshes flattens without a flipped or zero-area triangle.
    #[test]
    fn charts_of_curved_meshes_flatten_without_flips() {
        let (torus, _) = crate::sample::dented_torus(80, 30, (8, 8));
        let c = segment(&torus, &SegmentOptions::default());
        let maps: Vec<ChartMap> = c.charts.iter().map(|ch| flatten(&torus, ch)).collect();
        let s = stretch(&torus, &maps);
        assert_eq!((s.flipped, s.zero_area), (0, 0), "{s:?}");
        assert!(s.l2.is_finite() && s.l2 >= 1.0);
        // A single chart that cannot be projected (a hemisphere-like cap) uses the mean-value
        // embedding, still without flips.
        let cap: Vec<FaceId> = c.charts.iter().max_by_key(|ch| ch.len()).unwrap().clone();
        let m = mean_value_embedding(
            &flatten(&torus, &cap).faces,
            &flatten(&torus, &cap)
                .vertices
                .iter()
                .map(|v| torus.positions[v.idx()])
                .collect::<Vec<_>>(),
        );
        let map = ChartMap {
            uv: m,
            ..flatten(&torus, &cap)
        };
        let s = stretch(&torus, &[map]);
        assert_eq!(s.flipped, 0, "{s:?}");
    }

    /// The direct solve of the mean-value system agrees with the iterative one (relative
    /// residual 1e-12) on a non-symmetric system of a grid's interior.
    #[test]
    fn direct_and_iterative_mean_value_solves_agree() {
        let k = 30;
        let id = |x: usize, y: usize| y * k + x;
        let (mut rows, mut diag, mut rhs) = (vec![Vec::new(); k * k], vec![0.0; k * k], vec![]);
        for y in 0..k {
            for x in 0..k {
                let i = id(x, y);
                // Unequal weights per direction make the matrix non-symmetric.
                for (dx, dy, w) in [(1i64, 0i64, 1.0), (-1, 0, 2.0), (0, 1, 0.5), (0, -1, 1.5)] {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    diag[i] += w;
                    if (0..k as i64).contains(&nx) && (0..k as i64).contains(&ny) {
                        rows[i].push((id(nx as usize, ny as usize), w));
                    }
                }
                rhs.push(Vector2::new((x as f64).sin(), y as f64 * 0.1));
            }
        }
        let direct = solve_direct(&rows, &diag, &rhs).expect("the system is regular");
        for dim in 0..2 {
            let b: Vec<f64> = rhs.iter().map(|v| v[dim]).collect();
            let it = bicgstab(&rows, &diag, &b);
            let scale = it.iter().fold(0f64, |m, v| m.max(v.abs()));
            for (d, i) in direct.iter().zip(&it) {
                assert!((d[dim] - i).abs() <= 1e-8 * scale, "{} vs {i}", d[dim]);
            }
        }
    }
}
