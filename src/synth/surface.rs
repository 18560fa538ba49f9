//! Stage 6 on the surface: a smooth low band over each region (harmonic on the mesh, fixed
//! at the rim to the colours around it), overlapping patches grown on the surface (lapped
//! textures: geodesic growth from random uncovered faces, each flattened onto its tangent
//! plane with "up" as its direction), exemplar detail pasted into each patch at the offset
//! agreeing best with the patches already placed, and the histogram-preserving blend of the
//! overlaps, evaluated at every texel's surface point: chart borders inside a region do not
//! show, because both sides of a border are the same points of the surface.

use super::plane::{blend, bump, bump_squared, choose_offset, Exemplar};
use super::prior::ShapePrior;
use super::BandSummary;
use crate::atlas::Atlas;
use crate::mesh::topology::NO_FACE;
use crate::mesh::{FaceId, Mesh};
use crate::resample::TexelSource;
use crate::rng::SplitMix64;
use nalgebra::{Matrix2, Point3, Vector2, Vector3};
use rayon::prelude::*;

/// Exemplar detail with its map from the surface: `m` takes a tangent offset (right, up) in
/// scene units to exemplar texels, so scale and orientation follow where it was taken from.
pub(super) struct Source {
    pub(super) ex: Exemplar,
    pub(super) m: Matrix2<f64>,
}

impl Source {
    /// An exemplar laid on the tangent plane upright: `tpu` texels per scene unit, columns
    /// along right, rows down (its top towards up).
    pub(super) fn upright(ex: Exemplar, tpu: f64) -> Source {
        Source {
            ex,
            m: Matrix2::new(tpu, 0.0, 0.0, -tpu),
        }
    }

    /// Exemplar texels per scene unit (geometric mean over both axes).
    pub(super) fn density(&self) -> f64 {
        self.m.determinant().abs().sqrt().max(1e-12)
    }
}

/// A patch: its tangent frame on the surface and where its content comes from.
#[derive(Debug, Clone)]
pub(super) struct Patch {
    origin: Point3<f64>,
    right: Vector3<f64>,
    up: Vector3<f64>,
    normal: Vector3<f64>,
    offset: [f64; 2],
    source: u32,
}

impl Patch {
    /// Tangent coordinates (right, up) of `p`, scene units.
    #[inline]
    fn coords(&self, p: &Point3<f64>) -> Vector2<f64> {
        let d = p - self.origin;
        Vector2::new(d.dot(&self.right), d.dot(&self.up))
    }
}

/// Face `f`'s centroid.
pub(super) fn centroid(mesh: &Mesh, f: u32) -> Point3<f64> {
    let t = mesh.triangle(FaceId(f));
    Point3::from((t[0].coords + t[1].coords + t[2].coords) / 3.0)
}

/// The tangent direction "up" takes at normal `n`: up projected onto the tangent plane, or a
/// fixed horizontal axis where the surface faces up or down.
pub(super) fn tangent_up(n: &Vector3<f64>, up: &Vector3<f64>) -> Vector3<f64> {
    let t = up - n * n.dot(up);
    if t.norm() > 0.2 {
        return t.normalize();
    }
    let side = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let s = side - up * side.dot(up);
    let t = s - n * n.dot(&s);
    if t.norm() > 1e-9 {
        t.normalize()
    } else {
        n.cross(&Vector3::new(0.3, 0.5, 0.8)).normalize()
    }
}

/// Faces meeting across an edge at a smaller cosine between their normals (more than 30
/// degrees apart, the sharp-edge angle modelling tools default to) meet at a crease: the low
/// band keeps a value on each side of it. Measured in `docs/decisions.md` ("Creases in the
/// low band").
pub(super) const CREASE_COS: f64 = 0.866_025_403_784_439;

/// The low band over the regions, per face corner: corners of a vertex on one side of a
/// crease share a value, so a vertex where a cut face meets a skin carries both colours.
pub(super) struct LowBand<'a> {
    /// Per vertex: the value of faces the regions do not touch (the vertex-colour fill).
    vertex: &'a [[f32; 3]],
    /// Face -> its index in `corners` (`u32::MAX`: not a region face or next to one).
    face: Vec<u32>,
    /// Per region face or face next to one: the band at its three corners.
    corners: Vec<[[f32; 3]; 3]>,
    /// Per such face: bit k set when corner k was fixed to the rim's colour.
    fixed: Vec<u8>,
    /// The band at the rims and inside the regions, averaged.
    pub(super) summary: BandSummary,
}

impl LowBand<'_> {
    /// The band in face `f` (corners `fv`) at barycentrics `b`.
    pub(super) fn at(&self, f: u32, fv: &[crate::mesh::VertexId; 3], b: &[f64; 3]) -> [f32; 3] {
        match self.face[f as usize] {
            u32::MAX => at_bary(self.vertex, fv, b),
            i => {
                let c = &self.corners[i as usize];
                std::array::from_fn(|k| {
                    c[0][k] * b[0] as f32 + c[1][k] * b[1] as f32 + c[2][k] * b[2] as f32
                })
            }
        }
    }

    /// The value at corner `k` of face `f` if it was fixed to the rim's colour.
    pub(super) fn fixed_corner(&self, f: u32, k: usize) -> Option<[f32; 3]> {
        match self.face[f as usize] {
            u32::MAX => None,
            i => (self.fixed[i as usize] >> k & 1 == 1).then(|| self.corners[i as usize][k]),
        }
    }
}

/// The low band over the regions: a start (the vertex-colour fill `init`, which carries
/// colour from the nearest photographed vertices, moved towards `prior`'s colour of surface
/// of the same shape where the prior is trusted) plus a harmonic correction (uniform weights, on the
/// regions' faces) that makes it meet, at every region corner, the per-channel median colour
/// of the texels around that corner's vertex on the same side of any crease
/// ([`CREASE_COS`]): those of the faces outside the regions (as restored or photographed)
/// and the photographed ones of the region faces (`source` says which). Corners of a vertex
/// joined through smooth edges share one value; a region with no rim keeps its start (a small
/// pull towards no correction keeps the system definite). `adj` is the face adjacency.
#[allow(clippy::too_many_arguments)]
pub(super) fn low_band<'a>(
    mesh: &Mesh,
    atlas: &Atlas,
    color: &image::Rgb32FImage,
    source: &[u8],
    member: &[bool],
    adj: &[[u32; 3]],
    init: &'a [[f32; 3]],
    prior: Option<&ShapePrior>,
) -> LowBand<'a> {
    let nv = mesh.num_vertices();
    let nf = mesh.num_faces();
    let mut in_region = vec![false; nv];
    for (f, fv) in mesh.faces.iter().enumerate() {
        if member[f] {
            for v in fv {
                in_region[v.idx()] = true;
            }
        }
    }
    // Faces involved: the regions' and those outside with a region vertex (the rim faces).
    let mut face = vec![u32::MAX; nf];
    let mut involved: Vec<u32> = Vec::new();
    for (f, fv) in mesh.faces.iter().enumerate() {
        if member[f] || fv.iter().any(|v| in_region[v.idx()]) {
            face[f] = involved.len() as u32;
            involved.push(f as u32);
        }
    }
    // Corners (3 per involved face) of one vertex joined across smooth edges.
    let normal = |f: u32| mesh.face_normal_area(FaceId(f)).try_normalize(1e-300);
    let mut sets = crate::mesh::topology::UnionFind::new(involved.len() * 3);
    for (i, &f) in involved.iter().enumerate() {
        let fv = mesh.faces[f as usize];
        for (k, &g) in adj[f as usize].iter().enumerate() {
            if g == NO_FACE || face[g as usize] == u32::MAX {
                continue;
            }
            let smooth = match (normal(f), normal(g)) {
                (Some(a), Some(b)) => a.dot(&b) >= CREASE_COS,
                _ => true,
            };
            if !smooth {
                continue;
            }
            let j = face[g as usize] as usize;
            let gv = mesh.faces[g as usize];
            for c in [k, (k + 1) % 3] {
                if let Some(d) = gv.iter().position(|v| *v == fv[c]) {
                    sets.union(3 * i + c, 3 * j + d);
                }
            }
        }
    }
    // Groups numbered in corner order (whichever corner the sets chose as root); each knows
    // its vertex.
    let corners_n = involved.len() * 3;
    let mut group = vec![u32::MAX; corners_n];
    let mut group_vertex: Vec<u32> = Vec::new();
    for c in 0..corners_n {
        let r = sets.find(c);
        if group[r] == u32::MAX {
            group[r] = group_vertex.len() as u32;
            group_vertex.push(mesh.faces[involved[c / 3] as usize][c % 3].0);
        }
        group[c] = group[r];
    }
    drop(sets);
    let ng = group_vertex.len();
    let mut group_in_region = vec![false; ng];
    for (i, &f) in involved.iter().enumerate() {
        if member[f as usize] {
            for k in 0..3 {
                group_in_region[group[3 * i + k] as usize] = true;
            }
        }
    }
    // Rim faces' texels (and region faces' photographed ones) fix the region groups they
    // touch, at their per-channel median: the rim often runs along a thin dark trim or seam
    // line, which a mean would carry into the whole region (see docs/decisions.md, "The
    // rim's median").
    let data: &[f32] = color.as_raw();
    let texels = corner_texels(atlas, data, source, &involved, member);
    let mut pairs: Vec<(u32, u32)> = Vec::new();
    for i in 0..involved.len() {
        if texels.0[i] == texels.0[i + 1] {
            continue;
        }
        for k in 0..3 {
            let g = group[3 * i + k];
            if group_in_region[g as usize] {
                pairs.push((g, i as u32));
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let runs: Vec<&[(u32, u32)]> = pairs.chunk_by(|a, b| a.0 == b.0).collect();
    let medians: Vec<(u32, [f32; 3])> = runs
        .par_iter()
        .map_init(Vec::new, |scratch: &mut Vec<[f32; 3]>, run| {
            scratch.clear();
            for &(_, i) in run.iter() {
                let (a, b) = (texels.0[i as usize], texels.0[i as usize + 1]);
                scratch.extend_from_slice(&texels.1[a as usize..b as usize]);
            }
            (run[0].0, median3(scratch))
        })
        .collect();
    drop(texels);
    let mut fixed = vec![false; ng];
    let mut init_g: Vec<[f32; 3]> = group_vertex.iter().map(|&v| init[v as usize]).collect();
    if let Some(prior) = prior {
        // Inside the regions the band starts from the colour of photographed surface of the
        // same shape where that is trusted, each side of a crease with its own facing.
        let mut facing = vec![Vector3::zeros(); ng];
        for (i, &f) in involved.iter().enumerate() {
            let n = mesh.face_normal_area(FaceId(f));
            for k in 0..3 {
                facing[group[3 * i + k] as usize] += n;
            }
        }
        init_g
            .par_iter_mut()
            .zip(facing.par_iter())
            .enumerate()
            .filter(|(g, _)| group_in_region[*g])
            .for_each(|(g, (value, n))| {
                let p = &mesh.positions[group_vertex[g] as usize];
                let n = n.try_normalize(1e-300).unwrap_or_else(Vector3::zeros);
                *value = prior.at(p, &n, *value);
            });
    }
    let mut out: Vec<[f32; 3]> = init_g.clone();
    for (g, m) in medians {
        fixed[g as usize] = true;
        out[g as usize] = m;
    }
    // Unknowns and their neighbours through region faces.
    let mut unknown = vec![u32::MAX; ng];
    let mut vars = Vec::new();
    for g in 0..ng {
        if group_in_region[g] && !fixed[g] {
            unknown[g] = vars.len() as u32;
            vars.push(g as u32);
        }
    }
    if !vars.is_empty() {
        let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); vars.len()];
        for (i, &f) in involved.iter().enumerate() {
            if !member[f as usize] {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (group[3 * i + k], group[3 * i + (k + 1) % 3]);
                if unknown[a as usize] != u32::MAX {
                    nbr[unknown[a as usize] as usize].push(b);
                }
                if unknown[b as usize] != u32::MAX {
                    nbr[unknown[b as usize] as usize].push(a);
                }
            }
        }
        for n in &mut nbr {
            n.sort_unstable();
            n.dedup();
        }
        solve_correction(&nbr, &unknown, &vars, &init_g, &mut out);
    }
    let summary = band_summary(&group_in_region, &fixed, &init_g, &out);
    let corners: Vec<[[f32; 3]; 3]> = (0..involved.len())
        .map(|i| std::array::from_fn(|k| out[group[3 * i + k] as usize]))
        .collect();
    let fixed_bits: Vec<u8> = (0..involved.len())
        .map(|i| {
            (0..3).fold(0u8, |m, k| {
                m | u8::from(fixed[group[3 * i + k] as usize]) << k
            })
        })
        .collect();
    LowBand {
        vertex: init,
        face,
        corners,
        fixed: fixed_bits,
        summary,
    }
}

/// [`BandSummary`] of the groups in a region (`in_region`), fixed or not (`fixed`), from
/// their `start` and `end` values.
fn band_summary(
    in_region: &[bool],
    fixed: &[bool],
    start: &[[f32; 3]],
    end: &[[f32; 3]],
) -> BandSummary {
    // Sums over (rim, inner) x (start, end), in group order.
    let mut sums = [[[0f64; 3]; 2]; 2];
    let mut counts = [0usize; 2];
    for g in (0..in_region.len()).filter(|&g| in_region[g]) {
        let side = usize::from(!fixed[g]);
        counts[side] += 1;
        for c in 0..3 {
            sums[side][0][c] += start[g][c] as f64;
            sums[side][1][c] += end[g][c] as f64;
        }
    }
    let mean = |side: usize, which: usize| -> [f32; 3] {
        std::array::from_fn(|c| (sums[side][which][c] / counts[side].max(1) as f64) as f32)
    };
    BandSummary {
        rim_groups: counts[0],
        rim_start: mean(0, 0),
        rim_fixed: mean(0, 1),
        inner_groups: counts[1],
        inner_start: mean(1, 0),
        inner_end: mean(1, 1),
    }
}

/// The texels that describe the `involved` faces' colours, grouped by face in compressed
/// rows (offsets, colours): all of a rim face's (outside the regions: photographed or
/// restored), and the photographed ones of a region face. A region face of a coarse mesh is
/// often mostly photographed, its few unseen texels the ones stage 6 writes; without them
/// its corners took their colour from rim faces far across it (see docs/decisions.md, "A
/// region face's own photographed texels").
fn corner_texels(
    atlas: &Atlas,
    data: &[f32],
    source: &[u8],
    involved: &[u32],
    member: &[bool],
) -> (Vec<u32>, Vec<[f32; 3]>) {
    let per_face: Vec<Vec<[f32; 3]>> = involved
        .par_iter()
        .map(|&f| {
            let region = member[f as usize];
            atlas
                .owned_texels(f as usize)
                .filter(|&i| !region || source[i] == TexelSource::Photos as u8)
                .map(|i| [data[i * 3], data[i * 3 + 1], data[i * 3 + 2]])
                .collect()
        })
        .collect();
    let mut offsets = Vec::with_capacity(involved.len() + 1);
    offsets.push(0u32);
    for t in &per_face {
        offsets.push(offsets[offsets.len() - 1] + t.len() as u32);
    }
    (offsets, per_face.concat())
}

/// Per-channel median of `v` (upper median; reorders `v`).
fn median3(v: &mut [[f32; 3]]) -> [f32; 3] {
    let m = v.len() / 2;
    std::array::from_fn(|k| {
        v.select_nth_unstable_by(m, |a, b| a[k].total_cmp(&b[k]));
        v[m][k]
    })
}

/// The harmonic correction of the unknowns (`vars`, numbered by `unknown`) towards the fixed
/// values in `out` (`out - init` at fixed neighbours), written into `out`.
///
/// The three channels' systems share their matrix, so they are solved in lockstep: each
/// product with the matrix walks the neighbours once for all three, and the neighbours are
/// read from one flat list of unknown indices. Every channel still does its own conjugate
/// gradients, with its own step sizes and stopping test, the same operations in the same
/// order as one channel at a time (`correction_per_channel`, the unit test's
/// reference): the same bits. On the 1.5M-face scene the low band took 2.2-2.6 s with one
/// channel at a time and 1.35-1.41 s in lockstep (`docs/benchmarks.md`, "Stage 6's serial
/// work").
fn solve_correction(
    nbr: &[Vec<u32>],
    unknown: &[u32],
    vars: &[u32],
    init: &[[f32; 3]],
    out: &mut [[f32; 3]],
) {
    let x = correction(nbr, unknown, init, out);
    for (i, &v) in vars.iter().enumerate() {
        for c in 0..3 {
            out[v as usize][c] = init[v as usize][c] + x[i][c] as f32;
        }
    }
}

/// [`solve_correction`]'s corrections of the unknowns, in double precision (what the unit
/// test compares bit for bit: rounding to `f32` would hide a change of summation order).
fn correction(
    nbr: &[Vec<u32>],
    unknown: &[u32],
    init: &[[f32; 3]],
    out: &[[f32; 3]],
) -> Vec<[f64; 3]> {
    const EPS: f64 = 1e-3;
    const MAX_ITERATIONS: usize = 2000;
    let n = nbr.len();
    // (L + eps I) x = b per channel: L the graph Laplacian over unknowns, b the fixed
    // neighbours' corrections.
    let diag: Vec<f64> = nbr.iter().map(|n| n.len() as f64 + EPS).collect();
    let mut start = Vec::with_capacity(n + 1);
    let mut cols: Vec<u32> = Vec::new();
    start.push(0usize);
    for nb in nbr {
        cols.extend(
            nb.iter()
                .map(|&u| unknown[u as usize])
                .filter(|&j| j != u32::MAX),
        );
        start.push(cols.len());
    }
    let b: [Vec<f64>; 3] = std::array::from_fn(|c| {
        (0..n)
            .map(|i| {
                nbr[i]
                    .iter()
                    .filter(|&&u| unknown[u as usize] == u32::MAX)
                    .map(|&u| (out[u as usize][c] - init[u as usize][c]) as f64)
                    .sum::<f64>()
            })
            .collect()
    });
    // Dot products are summed in index order, one pass for the three channels, from the
    // value an empty `f64` sum starts at, as `Iterator::sum` does: the same bits as the
    // per-channel solve's, on any thread count. Element-wise updates run in parallel.
    let zero = std::iter::empty::<f64>().sum::<f64>();
    let dot3 = |a: &[[f64; 3]], b: &[[f64; 3]]| {
        a.iter().zip(b).fold([zero; 3], |mut s, (x, y)| {
            for c in 0..3 {
                s[c] += x[c] * y[c];
            }
            s
        })
    };
    let apply = |p: &[[f64; 3]], y: &mut [[f64; 3]]| {
        y.par_iter_mut().enumerate().for_each(|(i, yi)| {
            let d = diag[i];
            let mut s = [d * p[i][0], d * p[i][1], d * p[i][2]];
            for &j in &cols[start[i]..start[i + 1]] {
                let q = &p[j as usize];
                for c in 0..3 {
                    s[c] -= q[c];
                }
            }
            *yi = s;
        });
    };
    // The correction, from zero.
    let mut x = vec![[0f64; 3]; n];
    let mut ap = vec![[0f64; 3]; n];
    apply(&x, &mut ap);
    let mut r: Vec<[f64; 3]> = (0..n)
        .map(|i| std::array::from_fn(|c| b[c][i] - ap[i][c]))
        .collect();
    // Jacobi preconditioner.
    let mut z: Vec<[f64; 3]> = r.iter().zip(&diag).map(|(r, d)| r.map(|v| v / d)).collect();
    let mut p = z.clone();
    let mut rz = dot3(&r, &z);
    let b_norm: [f64; 3] =
        std::array::from_fn(|c| b[c].iter().fold(zero, |s, v| s + v * v).sqrt().max(1e-12));
    let mut rr = dot3(&r, &r);
    let mut active = [true; 3];
    const CHUNK: usize = 4096;
    for _ in 0..MAX_ITERATIONS {
        for c in 0..3 {
            active[c] &= rr[c].sqrt() >= 1e-6 * b_norm[c];
        }
        if !active.iter().any(|&a| a) {
            break;
        }
        apply(&p, &mut ap);
        let pap = dot3(&p, &ap);
        let alpha: [f64; 3] = std::array::from_fn(|c| rz[c] / pap[c].max(1e-300));
        x.par_chunks_mut(CHUNK)
            .zip(r.par_chunks_mut(CHUNK))
            .zip(z.par_chunks_mut(CHUNK))
            .enumerate()
            .for_each(|(k, ((xs, rs), zs))| {
                let o = k * CHUNK;
                for i in 0..xs.len() {
                    for c in (0..3).filter(|&c| active[c]) {
                        xs[i][c] += alpha[c] * p[o + i][c];
                        rs[i][c] -= alpha[c] * ap[o + i][c];
                        zs[i][c] = rs[i][c] / diag[o + i];
                    }
                }
            });
        let rz_new = dot3(&r, &z);
        rr = dot3(&r, &r);
        let beta: [f64; 3] = std::array::from_fn(|c| rz_new[c] / rz[c].max(1e-300));
        for c in (0..3).filter(|&c| active[c]) {
            rz[c] = rz_new[c];
        }
        p.par_iter_mut().zip(z.par_iter()).for_each(|(p, z)| {
            for c in (0..3).filter(|&c| active[c]) {
                p[c] = z[c] + beta[c] * p[c];
            }
        });
    }
    x
}

/// Options of the patch layout.
pub(super) struct Layout {
    /// Patch radius in exemplar texels.
    pub(super) radius: f64,
    /// Offsets tried per patch.
    pub(super) candidates: usize,
}

/// Distance from `p` to the triangle `t` (closest point by regions, Ericson 5.1.5).
pub(super) fn point_triangle(p: &Point3<f64>, t: &[Point3<f64>; 3]) -> f64 {
    let (a, b, c) = (t[0], t[1], t[2]);
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(&ap), ac.dot(&ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.norm();
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(&bp), ac.dot(&bp));
    if d3 >= 0.0 && d4 <= d3 {
        return bp.norm();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + ab * v)).norm();
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(&cp), ac.dot(&cp));
    if d6 >= 0.0 && d5 <= d6 {
        return cp.norm();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + ac * w)).norm();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + (c - b) * w)).norm();
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    (p - (a + ab * v + ac * w)).norm()
}

/// Patches covering `faces` (one region, all of whose patches take `source`): sample points
/// over the faces (corners, centroids, and a grid on faces larger than the patch core) are
/// visited in a seeded random order, and each one no patch core covers yet seeds a patch,
/// grown through neighbouring faces within reach of it that face the same way. Appends to
/// `patches` (numbered from its length) and to each face's patch list in `face_patches`,
/// the region's own run of lists (a face's at its slot less the region's first slot).
#[allow(clippy::too_many_arguments)]
pub(super) fn grow_patches(
    mesh: &Mesh,
    adj: &[[u32; 3]],
    faces: &[u32],
    slot: &[u32],
    src: &Source,
    source_id: u32,
    up: &Vector3<f64>,
    layout: &Layout,
    rng: &mut SplitMix64,
    rim: &[(Point3<f64>, [f32; 3])],
    patches: &mut Vec<Patch>,
    face_patches: &mut [Vec<u32>],
) -> usize {
    let r_world = layout.radius / src.density();
    // The photographed detail around the region, bucketed by position: patches near the rim
    // choose their offset to continue it.
    let cell = r_world.max(1e-12);
    let key = |p: &Point3<f64>| {
        [
            (p.x / cell).floor() as i64,
            (p.y / cell).floor() as i64,
            (p.z / cell).floor() as i64,
        ]
    };
    let mut buckets: rustc_hash::FxHashMap<[i64; 3], Vec<u32>> = Default::default();
    for (i, (p, _)) in rim.iter().enumerate() {
        buckets.entry(key(p)).or_default().push(i as u32);
    }
    let reach = 1.2 * r_world;
    // Seeds at most 0.7 radius from every point: each texel blends about six patches, and
    // none has less than a quarter of the centre weight (bump(0.7) = 0.26).
    let core = 0.7 * r_world;
    let normal = |f: u32| mesh.face_normal_area(FaceId(f));
    // A region's faces hold consecutive slots: `local` indexes this region's scratch.
    let base = faces.first().map_or(0, |&f| slot[f as usize]);
    let inside = |g: u32| {
        g != NO_FACE && {
            let s = slot[g as usize];
            s != u32::MAX && s >= base && ((s - base) as usize) < faces.len()
        }
    };
    let local = |f: u32| (slot[f as usize] - base) as usize;
    // Sample points per face, spaced at most half the core apart.
    let mut points: Vec<(Point3<f64>, u32)> = Vec::new();
    let mut first = Vec::with_capacity(faces.len() + 1);
    for &f in faces {
        first.push(points.len());
        let t = mesh.triangle(FaceId(f));
        let longest = (t[1] - t[0])
            .norm()
            .max((t[2] - t[1]).norm())
            .max((t[0] - t[2]).norm());
        let k = ((longest / (0.5 * core)).ceil() as usize).clamp(1, 64);
        for i in 0..=k {
            for j in 0..=k - i {
                let (u, v) = (i as f64 / k as f64, j as f64 / k as f64);
                let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
                points.push((p, f));
            }
        }
        points.push((centroid(mesh, f), f));
    }
    first.push(points.len());
    let mut order: Vec<u32> = (0..points.len() as u32).collect();
    for i in (1..order.len()).rev() {
        let j = (rng.next_u64() % (i as u64 + 1)) as usize;
        order.swap(i, j);
    }
    let mut covered = vec![false; points.len()];
    let mut visited = vec![u32::MAX; faces.len()];
    let before = patches.len();
    for &pi in &order {
        if covered[pi as usize] {
            continue;
        }
        let (origin, seed) = points[pi as usize];
        let id = patches.len() as u32;
        let n_seed = normal(seed).normalize();
        // Faces within reach of the seed point, connected through faces within reach that
        // face within 78 degrees of the seed's, so the patch stays a height field over its
        // plane.
        let mut members = vec![seed];
        visited[local(seed)] = id;
        let mut k = 0;
        while k < members.len() {
            let f = members[k];
            k += 1;
            for &g in &adj[f as usize] {
                if !inside(g) || visited[local(g)] == id {
                    continue;
                }
                visited[local(g)] = id;
                if normal(g).normalize().dot(&n_seed) > 0.2
                    && point_triangle(&origin, &mesh.triangle(FaceId(g))) <= reach
                {
                    members.push(g);
                }
            }
        }
        members.sort_unstable();
        let mut n = Vector3::zeros();
        for &f in &members {
            if point_triangle(&origin, &mesh.triangle(FaceId(f))) <= core {
                n += normal(f);
            }
        }
        let n = if n.norm() > 0.0 {
            n.normalize()
        } else {
            n_seed
        };
        let t = tangent_up(&n, up);
        let b = t.cross(&n);
        let mut patch = Patch {
            origin,
            right: b,
            up: t,
            normal: n,
            offset: [0.0; 2],
            source: source_id,
        };
        // What the patches already placed show where this one overlaps them.
        let mut cons = Vec::new();
        let step = (members.len() / 48).max(1);
        for &f in members.iter().step_by(step) {
            let list = &face_patches[local(f)];
            if list.is_empty() {
                continue;
            }
            let p = centroid(mesh, f);
            let here = src.m * patch.coords(&p);
            if here.norm() > 0.8 * layout.radius {
                continue;
            }
            let best = list
                .iter()
                .map(|&k| {
                    let q = &patches[k as usize];
                    let off = src.m * q.coords(&p);
                    (bump(off.norm() / layout.radius), q, off)
                })
                .max_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((w, q, off)) = best {
                if w > 0.25 {
                    let g = src.ex.sample(q.offset[0] + off.x, q.offset[1] + off.y);
                    cons.push(([here.x, here.y], g));
                }
            }
        }
        let k0 = key(&origin);
        let mut near_rim = Vec::new();
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(b) = buckets.get(&[k0[0] + dx, k0[1] + dy, k0[2] + dz]) {
                        near_rim.extend(b.iter().copied());
                    }
                }
            }
        }
        near_rim.sort_unstable();
        let step = (near_rim.len() / 48).max(1);
        for &i in near_rim.iter().step_by(step) {
            let (p, g) = &rim[i as usize];
            let here = src.m * patch.coords(p);
            if here.norm() <= 0.8 * layout.radius && (p - origin).dot(&n).abs() < 0.5 * r_world {
                cons.push(([here.x, here.y], *g));
            }
        }
        patch.offset = choose_offset(&src.ex, layout.radius, layout.candidates, rng, &cons);
        patches.push(patch);
        for &f in &members {
            let l = local(f);
            face_patches[l].push(id);
            for q in first[l]..first[l + 1] {
                if (points[q].0 - origin).norm() <= core {
                    covered[q] = true;
                }
            }
        }
        covered[pi as usize] = true;
    }
    patches.len() - before
}

/// Barycentrics of texel (x, y) in face `f`, clamped to the triangle (a texel a face owns may
/// have its centre just outside it).
fn texel_barycentric(atlas: &Atlas, f: u32, x: usize, y: usize) -> Option<[f64; 3]> {
    let b = atlas.barycentric(f as usize, x, y)?;
    let b = b.map(|v| v.clamp(0.0, 1.0));
    let sum = b[0] + b[1] + b[2];
    Some(b.map(|v| v / sum.max(1e-12)))
}

/// The surface point of texel (x, y) in face `f`: [`texel_barycentric`] and the point they
/// give.
pub(super) fn texel_point(
    mesh: &Mesh,
    atlas: &Atlas,
    f: u32,
    x: usize,
    y: usize,
) -> Option<([f64; 3], Point3<f64>)> {
    let b = texel_barycentric(atlas, f, x, y)?;
    let tri = mesh.triangle(FaceId(f));
    let p = Point3::from(tri[0].coords * b[0] + tri[1].coords * b[1] + tri[2].coords * b[2]);
    Some((b, p))
}

/// Per-vertex colours `v` interpolated at barycentrics `b` of the face with corners `fv`.
pub(super) fn at_bary(v: &[[f32; 3]], fv: &[crate::mesh::VertexId; 3], b: &[f64; 3]) -> [f32; 3] {
    std::array::from_fn(|k| {
        v[fv[0].idx()][k] * b[0] as f32
            + v[fv[1].idx()][k] * b[1] as f32
            + v[fv[2].idx()][k] * b[2] as f32
    })
}

/// Writes stage 6's colour into every unseen texel of a region face: the low band
/// interpolated from the vertices plus the blended patch detail at the texel's surface point.
/// Returns (texels written, texels with no patch weight: low band only) and, with
/// `record`, the heaviest patch of each texel written (in texel order; `u32::MAX` for none).
///
/// Face by face: a texel's exemplar offset in a patch and the patch's facing there are affine
/// in the texel's barycentrics (the surface point is), so each face maps its three corners
/// into each of its patches once and its texels only interpolate (on the 1.17M-face scene the
/// per-texel projections were most of this stage's time).
#[allow(clippy::too_many_arguments)]
pub(super) fn bake(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    atlas: &Atlas,
    color: &mut image::Rgb32FImage,
    source: &[u8],
    slot: &[u32],
    low: &LowBand<'_>,
    patches: &[Patch],
    face_patches: &[Vec<u32>],
    sources: &[Source],
    radius: f64,
    record: bool,
    progress: &dyn crate::progress::Progress,
) -> (u64, u64, Vec<(u32, u32)>) {
    let n = atlas.size as usize;
    let inv_r2 = 1.0 / (radius * radius);
    // One patch as seen from one face: the exemplar offsets and normal dots at its corners.
    struct Corner {
        off: [Vector2<f64>; 3],
        dot: [f64; 3],
        offset: [f64; 2],
        source: u32,
        patch: u32,
    }
    let faces: Vec<u32> = (0..mesh.num_faces() as u32)
        .filter(|&f| slot[f as usize] != u32::MAX && atlas.face_rect(f as usize).is_some())
        .collect();
    // (texel, colour, heaviest patch, low band only) per texel written, a batch of faces at a
    // time so that the colours held stay small.
    type Out = (u32, [f32; 3], u32, bool);
    let bake_faces = |group: &[u32]| -> Vec<Out> {
        let mut out = Vec::new();
        let mut near: Vec<(f32, [f32; 3])> = Vec::new();
        let mut corners: Vec<Corner> = Vec::new();
        for &f in group {
            let fv = mesh.faces[f as usize];
            let tri = mesh.triangle(FaceId(f));
            let nrm = fv.map(|v| normals[v.idx()]);
            corners.clear();
            for &k in &face_patches[slot[f as usize] as usize] {
                let q = &patches[k as usize];
                let s = &sources[q.source as usize];
                corners.push(Corner {
                    off: std::array::from_fn(|c| s.m * q.coords(&tri[c])),
                    dot: std::array::from_fn(|c| nrm[c].dot(&q.normal)),
                    offset: q.offset,
                    source: q.source,
                    patch: k,
                });
            }
            for i in atlas.owned_texels(f as usize) {
                if !TexelSource::is_unseen(source[i]) {
                    continue;
                }
                let Some(b) = texel_barycentric(atlas, f, i % n, i / n) else {
                    continue;
                };
                let len = (nrm[0] * b[0] + nrm[1] * b[1] + nrm[2] * b[2]).norm();
                let base = low.at(f, &fv, &b);
                near.clear();
                let mut src_id = u32::MAX;
                let mut heaviest = (0f32, u32::MAX);
                for c in &corners {
                    let off = c.off[0] * b[0] + c.off[1] * b[1] + c.off[2] * b[2];
                    // Weight falls with distance in the exemplar and with the angle between
                    // the surface and the patch plane (both continuous over the surface).
                    let near_centre = bump_squared(off.norm_squared() * inv_r2);
                    if near_centre == 0.0 {
                        continue;
                    }
                    let cos = (c.dot[0] * b[0] + c.dot[1] * b[1] + c.dot[2] * b[2]) / len;
                    let facing = ((cos - 0.2) / 0.5).clamp(0.0, 1.0) as f32;
                    let w = near_centre * facing;
                    if w > 0.0 {
                        let s = &sources[c.source as usize];
                        near.push((w, s.ex.sample(c.offset[0] + off.x, c.offset[1] + off.y)));
                        src_id = c.source;
                        if w > heaviest.0 {
                            heaviest = (w, c.patch);
                        }
                    }
                }
                let (detail, bare) = match (blend(near.iter().copied()), src_id) {
                    (Some(g), id) if id != u32::MAX => (sources[id as usize].ex.colour(g), false),
                    _ => ([0.0; 3], true),
                };
                let c = std::array::from_fn(|k| base[k] + detail[k]);
                out.push((i as u32, c, heaviest.1, bare));
            }
        }
        out
    };
    let data: &mut [f32] = color.as_mut();
    let (mut written, mut bare) = (0u64, 0u64);
    let mut winners = Vec::new();
    const BATCH: usize = 16384;
    // The bake is most of stage 6's time: its faces are the stage's steps.
    progress.start("synth", faces.len() as u64);
    for batch in faces.chunks(BATCH) {
        let parts: Vec<Vec<Out>> = batch.par_chunks(64).map(bake_faces).collect();
        progress.advance(batch.len() as u64);
        for (i, c, heaviest, b) in parts.into_iter().flatten() {
            data[3 * i as usize..3 * i as usize + 3].copy_from_slice(&c);
            written += 1;
            bare += u64::from(b);
            if record {
                winners.push((i, heaviest));
            }
        }
    }
    winners.sort_unstable();
    (written, bare, winners)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::{build, AtlasOptions};
    use crate::mesh::VertexId;

    /// A strip folded along x = 0 by `angle` degrees: a flat part (z = 0, x from -2 to 0) and
    /// a part turned down from the fold, both two units of squares wide in y.
    fn folded(angle: f64) -> Mesh {
        let (s, c) = angle.to_radians().sin_cos();
        let mut m = Mesh::default();
        // Columns of two vertices (y = 0, 1): x = -2, -1, 0, then one and two units down
        // the turned part.
        for t in [-2.0, -1.0, 0.0, 1.0, 2.0] {
            for y in [0.0, 1.0] {
                let p = if t <= 0.0 {
                    Point3::new(t, y, 0.0)
                } else {
                    Point3::new(t * c, y, -t * s)
                };
                m.positions.push(p);
            }
        }
        for col in 0..4u32 {
            let (a, b, cc, d) = (2 * col, 2 * col + 2, 2 * col + 3, 2 * col + 1);
            m.faces.push([VertexId(a), VertexId(b), VertexId(cc)]);
            m.faces.push([VertexId(a), VertexId(cc), VertexId(d)]);
        }
        m
    }

    /// One channel at a time: the solve as it was before the channels went in lockstep,
    /// the reference [`correction`] must equal bit for bit.
    fn correction_per_channel(
        nbr: &[Vec<u32>],
        unknown: &[u32],
        vars: &[u32],
        init: &[[f32; 3]],
        out: &[[f32; 3]],
    ) -> Vec<[f64; 3]> {
        const EPS: f64 = 1e-3;
        let mut corr = vec![[0f64; 3]; vars.len()];
        for c in 0..3 {
            let diag: Vec<f64> = nbr.iter().map(|n| n.len() as f64 + EPS).collect();
            let b: Vec<f64> = (0..vars.len())
                .map(|i| {
                    nbr[i]
                        .iter()
                        .filter(|&&u| unknown[u as usize] == u32::MAX)
                        .map(|&u| (out[u as usize][c] - init[u as usize][c]) as f64)
                        .sum()
                })
                .collect();
            let apply = |x: &[f64], y: &mut [f64]| {
                for (i, yi) in y.iter_mut().enumerate() {
                    let mut s = diag[i] * x[i];
                    for &u in &nbr[i] {
                        let j = unknown[u as usize];
                        if j != u32::MAX {
                            s -= x[j as usize];
                        }
                    }
                    *yi = s;
                }
            };
            let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
            let mut x: Vec<f64> = vec![0.0; vars.len()];
            let mut ax = vec![0.0; x.len()];
            apply(&x, &mut ax);
            let mut r: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
            let mut z: Vec<f64> = r.iter().zip(&diag).map(|(r, d)| r / d).collect();
            let mut p = z.clone();
            let mut rz = dot(&r, &z);
            let b_norm = dot(&b, &b).sqrt().max(1e-12);
            let mut ap = vec![0.0; x.len()];
            for _ in 0..2000 {
                if dot(&r, &r).sqrt() < 1e-6 * b_norm {
                    break;
                }
                apply(&p, &mut ap);
                let alpha = rz / dot(&p, &ap).max(1e-300);
                for i in 0..x.len() {
                    x[i] += alpha * p[i];
                    r[i] -= alpha * ap[i];
                }
                for i in 0..x.len() {
                    z[i] = r[i] / diag[i];
                }
                let rz_new = dot(&r, &z);
                let beta = rz_new / rz.max(1e-300);
                rz = rz_new;
                for i in 0..x.len() {
                    p[i] = z[i] + beta * p[i];
                }
            }
            for (i, v) in x.into_iter().enumerate() {
                corr[i][c] = v;
            }
        }
        corr
    }

    #[test]
    fn channels_in_lockstep_are_the_per_channel_solve_bit_for_bit() {
        // A grid graph of 40 x 30 groups, its left and right columns fixed, plus a few
        // fixed groups inside; channel 1's fixed values all equal their start (its
        // right-hand side is zero, so it stops at once) and channel 2's span a wide range,
        // so the channels stop after different numbers of iterations.
        let (w, h) = (40usize, 30usize);
        let ng = w * h;
        let mut rng = crate::rng::SplitMix64::new(7);
        let mut uniform = || (rng.next_u64() >> 11) as f32 / (1u64 << 53) as f32;
        let fixed = |g: usize| g.is_multiple_of(w) || g % w == w - 1 || g % 97 == 13;
        let init: Vec<[f32; 3]> = (0..ng).map(|_| [uniform(), uniform(), uniform()]).collect();
        let mut out = init.clone();
        for g in (0..ng).filter(|&g| fixed(g)) {
            out[g] = [uniform(), init[g][1], 40.0 * uniform() - 20.0];
        }
        let mut unknown = vec![u32::MAX; ng];
        let mut vars = Vec::new();
        for g in (0..ng).filter(|&g| !fixed(g)) {
            unknown[g] = vars.len() as u32;
            vars.push(g as u32);
        }
        let nbr: Vec<Vec<u32>> = vars
            .iter()
            .map(|&g| {
                let (x, y) = (g as usize % w, g as usize / w);
                let mut n = Vec::new();
                if y > 0 {
                    n.push((g as usize - w) as u32);
                }
                if x > 0 {
                    n.push(g - 1);
                }
                if x + 1 < w {
                    n.push(g + 1);
                }
                if y + 1 < h {
                    n.push((g as usize + w) as u32);
                }
                n
            })
            .collect();
        let reference = correction_per_channel(&nbr, &unknown, &vars, &init, &out);
        let lockstep = correction(&nbr, &unknown, &init, &out);
        for (i, (a, b)) in lockstep.iter().zip(&reference).enumerate() {
            for c in 0..3 {
                assert_eq!(a[c].to_bits(), b[c].to_bits(), "unknown {i}, channel {c}");
            }
        }
        assert!(
            reference.iter().all(|r| r[1] == 0.0),
            "channel 1 has nothing to correct"
        );
        solve_correction(&nbr, &unknown, &vars, &init, &mut out);
        // The solve did something: the unknowns moved towards their fixed neighbours.
        let moved = vars
            .iter()
            .filter(|&&v| out[v as usize][2] != init[v as usize][2]);
        assert!(moved.count() > vars.len() / 2);
    }

    /// Options for one 256-texel page with a 4-texel gutter.
    fn page_256() -> AtlasOptions {
        AtlasOptions {
            pack: crate::atlas::pack::PackOptions {
                size: 256,
                gutter: 4,
                ..Default::default()
            },
            ..Default::default()
        }
    }

    /// Texel sources: the regions' faces unseen (red), the others photographed.
    fn sources(atlas: &Atlas, member: &[bool]) -> Vec<u8> {
        let n = atlas.size as usize;
        (0..n * n)
            .map(|i| match atlas.owner(i) {
                Some(f) if member[f as usize] => TexelSource::Red as u8,
                Some(_) => TexelSource::Photos as u8,
                None => TexelSource::Empty as u8,
            })
            .collect()
    }

    /// A flat 10 x 10 grid whose middle 6 x 6 squares are the region, the rest photographed
    /// in one colour, the band starting grey everywhere: the summary finds the rim's groups
    /// fixed to that colour and the harmonic correction carrying it to the inner groups.
    #[test]
    fn the_summary_follows_the_band_from_rim_to_centre() {
        let m = 10u32;
        let mut mesh = Mesh::default();
        for y in 0..=m {
            for x in 0..=m {
                mesh.positions
                    .push(Point3::new(x as f64 * 0.1, y as f64 * 0.1, 0.0));
            }
        }
        let id = |x: u32, y: u32| VertexId(y * (m + 1) + x);
        for y in 0..m {
            for x in 0..m {
                mesh.faces.push([id(x, y), id(x + 1, y), id(x + 1, y + 1)]);
                mesh.faces.push([id(x, y), id(x + 1, y + 1), id(x, y + 1)]);
            }
        }
        let (mesh, atlas, _) = build(mesh, &page_256()).unwrap();
        let member: Vec<bool> = (0..mesh.num_faces())
            .map(|f| {
                let c = centroid(&mesh, f as u32);
                (0.2..0.8).contains(&c.x) && (0.2..0.8).contains(&c.y)
            })
            .collect();
        let n = atlas.size;
        let color = image::Rgb32FImage::from_pixel(n, n, image::Rgb([0.8; 3]));
        let adj = crate::mesh::topology::face_adjacency(&mesh);
        let init = vec![[0.5f32; 3]; mesh.num_vertices()];
        let source = sources(&atlas, &member);
        let s = low_band(&mesh, &atlas, &color, &source, &member, &adj, &init, None).summary;
        // The region's 7 x 7 vertices: its boundary's 24 on the rim, 25 inside.
        assert_eq!((s.rim_groups, s.inner_groups), (24, 25));
        assert_eq!((s.rim_start, s.rim_fixed), ([0.5; 3], [0.8; 3]));
        assert_eq!(s.inner_start, [0.5; 3]);
        for c in s.inner_end {
            assert!((c - 0.8).abs() < 0.01, "{:?}", s.inner_end);
        }
    }

    /// The region as below, folded at 20 degrees, every rim face white but for thin black
    /// lines: the rim corners are fixed to white.
    #[test]
    fn thin_dark_lines_on_the_rim_do_not_darken_the_band() {
        let (mesh, atlas, _) = build(folded(20.0), &page_256()).unwrap();
        let centre = |f: usize| centroid(&mesh, f as u32);
        let member: Vec<bool> = (0..mesh.num_faces())
            .map(|f| centre(f).z.abs() < 1e-9 && centre(f).x < 0.0 && centre(f).x > -1.0)
            .collect();
        // White with every eighth texel column black: a mean of 0.875 around each corner.
        let n = atlas.size;
        let color =
            image::Rgb32FImage::from_fn(n, n, |x, _| image::Rgb([(x % 8 != 0) as u8 as f32; 3]));
        let adj = crate::mesh::topology::face_adjacency(&mesh);
        let init = vec![[0.5f32; 3]; mesh.num_vertices()];
        let source = sources(&atlas, &member);
        let low = low_band(&mesh, &atlas, &color, &source, &member, &adj, &init, None);
        let mut fixed = 0;
        for f in (0..mesh.num_faces()).filter(|&f| member[f]) {
            for k in 0..3 {
                if let Some(c) = low.fixed_corner(f as u32, k) {
                    assert_eq!(c, [1.0; 3], "face {f} corner {k}");
                    fixed += 1;
                }
            }
        }
        assert!(fixed > 0);
    }

    /// Every face is in the region, so there is no rim: with the faces photographed white but
    /// for a few unseen texels (a coarse mesh's faces), every corner is fixed to white; with
    /// all of their texels unseen, nothing is fixed and the band keeps the fill's grey.
    #[test]
    fn a_region_faces_photographed_texels_fix_its_corners() {
        let (mesh, atlas, _) = build(folded(20.0), &page_256()).unwrap();
        let member = vec![true; mesh.num_faces()];
        let n = atlas.size as usize;
        let adj = crate::mesh::topology::face_adjacency(&mesh);
        let init = vec![[0.5f32; 3]; mesh.num_vertices()];
        let unseen = sources(&atlas, &member);
        // Photographed: every texel of the faces but every tenth they own.
        let mut owned = 0;
        let photographed: Vec<u8> = unseen
            .iter()
            .map(|&s| {
                if s != TexelSource::Red as u8 {
                    return s;
                }
                owned += 1;
                if owned % 10 == 0 {
                    s
                } else {
                    TexelSource::Photos as u8
                }
            })
            .collect();
        let color = image::Rgb32FImage::from_fn(n as u32, n as u32, |x, y| {
            let i = y as usize * n + x as usize;
            image::Rgb(
                [if photographed[i] == TexelSource::Photos as u8 {
                    1.0
                } else {
                    0.0
                }; 3],
            )
        });
        for (source, want) in [(&photographed, Some(1.0)), (&unseen, None)] {
            let low = low_band(&mesh, &atlas, &color, source, &member, &adj, &init, None);
            for (f, fv) in mesh.faces.iter().enumerate() {
                for k in 0..3 {
                    assert_eq!(low.fixed_corner(f as u32, k).map(|c| c[0]), want);
                    let mut b = [0.0; 3];
                    b[k] = 1.0;
                    assert_eq!(low.at(f as u32, fv, &b)[0], want.unwrap_or(0.5));
                }
            }
        }
    }

    /// The flat part's two squares nearest the fold are the region; the other flat square
    /// is photographed white, the turned part black, the fill grey. Folded at 90 degrees
    /// the region's corners on the fold belong with the flat side and come out white (the
    /// black across the crease stays on its side); folded at 20 degrees (no crease) they
    /// are fixed to the median of the faces around the vertex, black ones included.
    #[test]
    fn a_crease_keeps_each_sides_colour() {
        for (angle, crease) in [(90.0, true), (20.0, false)] {
            let (mesh, atlas, _) = build(folded(angle), &page_256()).unwrap();
            let centre = |f: usize| centroid(&mesh, f as u32);
            let flat = |f: usize| centre(f).z.abs() < 1e-9 && centre(f).x < 0.0;
            let member: Vec<bool> = (0..mesh.num_faces())
                .map(|f| flat(f) && centre(f).x > -1.0)
                .collect();
            assert_eq!(member.iter().filter(|&&m| m).count(), 2);
            let n = atlas.size as usize;
            let color = image::Rgb32FImage::from_fn(n as u32, n as u32, |x, y| {
                let v = match atlas.owner(y as usize * n + x as usize) {
                    Some(f) if flat(f as usize) => 1.0,
                    _ => 0.0,
                };
                image::Rgb([v; 3])
            });
            let adj = crate::mesh::topology::face_adjacency(&mesh);
            let init = vec![[0.5f32; 3]; mesh.num_vertices()];
            let source = sources(&atlas, &member);
            let low = low_band(&mesh, &atlas, &color, &source, &member, &adj, &init, None);
            for f in (0..mesh.num_faces()).filter(|&f| member[f]) {
                let fv = mesh.faces[f];
                for (k, v) in fv.iter().enumerate() {
                    if mesh.positions[v.idx()].x.abs() > 1e-9 {
                        continue;
                    }
                    let mut b = [0.0; 3];
                    b[k] = 1.0;
                    let at = low.at(f as u32, &fv, &b)[0];
                    if crease {
                        assert!(at > 0.95, "{angle} degrees: {at}");
                        assert!(low.fixed_corner(f as u32, k).is_none());
                    } else {
                        assert!(at < 0.75, "{angle} degrees: {at}");
                        assert!(low.fixed_corner(f as u32, k).is_some());
                    }
                }
            }
        }
    }
}
