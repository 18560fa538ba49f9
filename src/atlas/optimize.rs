//! Minimisation of the paper's extended L2 stretch over one chart (method.md §1):
//!
//! `L2(M) = sqrt( sum_T [L2(T)^2 w(T) A3(T) + s(T)] / sum_T w(T) A3(T) )`, with
//! `w(T) = 1 / (<N(T), V> + k)` and the shape barrier `s(T)` infinite when the smallest
//! height/base ratio of the UV triangle falls below alpha.
//!
//! Scale: L2 falls as the chart grows, so we minimise the scale-free product
//! `(sum L2(T)^2 w A3) * (sum A2)`, which is Sander's normalisation (2D area equal to 3D area)
//! applied inside the energy. Like Sander et al. 2001 we move one vertex at a time along a
//! descent direction with a line search, boundary vertices included; a move is refused if any
//! incident triangle flips, degenerates or breaks the barrier, or if a boundary edge would cross
//! another, so the map stays one-to-one throughout.

use super::param::{height_base_2d, height_base_3d, uv_area, ChartMap};
use crate::mesh::Mesh;
use nalgebra::{Point3, Vector2, Vector3};
use std::collections::HashMap;

/// Options for [`optimize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StretchOptions {
    /// The "important view" direction V: the direction the viewer looks in (from the eye towards
    /// the object), so triangles facing the viewer have <N, V> near -1 and the largest weight
    /// 1 / (k - 1); that is why k must exceed 1. `None` for no view weight (w = 1).
    /// Default: `None` (the texture stage passes the photographs' mean viewing direction).
    pub view_dir: Option<Vector3<f64>>,
    /// k in w(T) = 1 / (<N, V> + k); useful range 1.01..2. Default: 1.5.
    pub k: f64,
    /// Smallest allowed height/base ratio of a UV triangle (where the 3D triangle itself
    /// allows it). Default: 0.05.
    pub alpha: f64,
    /// Sweeps over all vertices. Default: 40.
    pub sweeps: usize,
}

impl Default for StretchOptions {
    fn default() -> Self {
        StretchOptions {
            view_dir: None,
            k: 1.5,
            alpha: 0.05,
            sweeps: 40,
        }
    }
}

/// The paper's visual importance of a triangle with (any-length) normal `n`:
/// `w = 1 / (<N, V> + k)`, or 1 without a view direction.
pub fn weight(n: Vector3<f64>, opts: &StretchOptions) -> f64 {
    match (opts.view_dir.and_then(|v| v.try_normalize(0.0)), n.try_normalize(0.0)) {
        (Some(v), Some(n)) => 1.0 / (n.dot(&v) + opts.k),
        // A degenerate triangle has no facing: it counts as seen edge-on.
        (Some(_), None) => 1.0 / opts.k,
        (None, _) => 1.0,
    }
}

/// Texel budget across charts (Sander et al. 2001, §4): scaling chart i by c_i divides its
/// weighted stretch energy E_i by c_i^2 and multiplies its area a_i by c_i^2; the minimum of
/// the total energy for a fixed total area is at c_i proportional to (E_i / a_i)^(1/4). So
/// charts the view weight marks as important, or that stretch more, get more texels.
/// Returns c_i with an area-weighted mean of c_i^2 equal to 1.
pub fn chart_scales(mesh: &Mesh, maps: &[ChartMap], opts: &StretchOptions) -> Vec<f64> {
    let raw: Vec<(f64, f64)> = maps
        .iter()
        .map(|m| {
            let (mut e, mut a) = (0.0, 0.0);
            for (t, f) in m.faces.iter().zip(&m.face_ids) {
                let q = t.map(|i| m.uv[i as usize]);
                let (l2, _, a2) = super::param::triangle_stretch(mesh.triangle(*f), q);
                let a3 = mesh.face_area(*f);
                if a2.is_finite() && a2 > 0.0 && l2.is_finite() {
                    e += weight(mesh.face_normal_area(*f), opts) * l2 * l2 * a3;
                    a += a2;
                }
            }
            (e, a)
        })
        .collect();
    let c: Vec<f64> = raw
        .iter()
        .map(|&(e, a)| if e > 0.0 && a > 0.0 { (e / a).powf(0.25) } else { 1.0 })
        .collect();
    let (num, den) = raw
        .iter()
        .zip(&c)
        .fold((0.0, 0.0), |(n, d), (&(_, a), &c)| (n + a * c * c, d + a));
    let norm = if num > 0.0 { (den / num).sqrt() } else { 1.0 };
    c.iter().map(|c| c * norm).collect()
}

struct Face {
    v: [usize; 3],
    p: [Point3<f64>; 3],
    /// w(T) A3(T).
    wa: f64,
    /// Barrier threshold for this triangle.
    min_hb: f64,
}

/// A tentative move: the new energy, stretch sum, area sum and per-face terms.
type Move = (f64, f64, f64, Vec<(f64, f64)>);

/// The stretch term `L2(T)^2 w A3` and the UV area of a face, or `None` if the barrier is hit.
fn terms(f: &Face, q: [Vector2<f64>; 3]) -> Option<(f64, f64)> {
    let a2 = uv_area(q);
    if a2 <= 0.0 || !a2.is_finite() {
        return None;
    }
    if height_base_2d(q) < f.min_hb {
        return None;
    }
    let (s, t) = (q.map(|v| v.x), q.map(|v| v.y));
    let p = &f.p;
    let ss =
        (p[0].coords * (t[1] - t[2]) + p[1].coords * (t[2] - t[0]) + p[2].coords * (t[0] - t[1]))
            / (2.0 * a2);
    let st =
        (p[0].coords * (s[2] - s[1]) + p[1].coords * (s[0] - s[2]) + p[2].coords * (s[1] - s[0]))
            / (2.0 * a2);
    let l2sq = (ss.dot(&ss) + st.dot(&st)) / 2.0;
    Some((l2sq * f.wa, a2))
}

fn segments_cross(a: Vector2<f64>, b: Vector2<f64>, c: Vector2<f64>, d: Vector2<f64>) -> bool {
    let cr = |o: Vector2<f64>, p: Vector2<f64>, q: Vector2<f64>| (p - o).perp(&(q - o));
    let (d1, d2, d3, d4) = (cr(c, d, a), cr(c, d, b), cr(a, b, c), cr(a, b, d));
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

/// Minimises the extended L2 stretch of `map` in place. Deterministic. Returns the final
/// normalised L2 stretch of the chart (with weights).
pub fn optimize(mesh: &Mesh, map: &mut ChartMap, opts: &StretchOptions) -> f64 {
    let nv = map.uv.len();
    let faces: Vec<Face> = map
        .faces
        .iter()
        .zip(&map.face_ids)
        .map(|(t, f)| {
            let p = mesh.triangle(*f);
            let n = mesh.face_normal_area(*f);
            let a3 = 0.5 * n.norm();
            let w = weight(n, opts);
            let hb3 = height_base_3d(p);
            let q = t.map(|i| map.uv[i as usize]);
            // Demand alpha where the 3D triangle allows it; never demand more than the start
            // already has, so the start is feasible.
            let min_hb = opts.alpha.min(hb3).min(height_base_2d(q)) * (1.0 - 1e-9);
            Face {
                v: t.map(|i| i as usize),
                p,
                wa: (w * a3).max(1e-300),
                min_hb,
            }
        })
        .collect();
    let mut incident: Vec<Vec<usize>> = vec![Vec::new(); nv];
    for (i, f) in faces.iter().enumerate() {
        for &v in &f.v {
            incident[v].push(i);
        }
    }
    // Boundary edges (directed, each once) and, per vertex, the boundary edges it is on.
    let mut directed: HashMap<(usize, usize), ()> = HashMap::new();
    for f in &faces {
        for k in 0..3 {
            directed.insert((f.v[k], f.v[(k + 1) % 3]), ());
        }
    }
    let mut boundary: Vec<(usize, usize)> = directed
        .keys()
        .filter(|(a, b)| !directed.contains_key(&(*b, *a)))
        .copied()
        .collect();
    boundary.sort();
    let mut on_boundary: Vec<Vec<usize>> = vec![Vec::new(); nv];
    for (i, &(a, b)) in boundary.iter().enumerate() {
        on_boundary[a].push(i);
        on_boundary[b].push(i);
    }
    let uv = &mut map.uv;
    let mut term: Vec<(f64, f64)> = faces
        .iter()
        .map(|f| terms(f, f.v.map(|i| uv[i])).unwrap_or((f64::INFINITY, 0.0)))
        .collect();
    if term.iter().any(|t| !t.0.is_finite()) {
        // The start violates its own barrier (cannot happen for a flip-free start); leave it.
        return f64::INFINITY;
    }
    let mut sl: f64 = term.iter().map(|t| t.0).sum();
    let mut sa: f64 = term.iter().map(|t| t.1).sum();
    let swa: f64 = faces.iter().map(|f| f.wa).sum();
    // Candidate energy after moving vertex v to `p`, with the new per-face terms.
    // Whether moving v to p makes one of v's boundary edges cross another boundary edge.
    // Checked only for moves about to be accepted: it is the costly test (linear in the
    // boundary length), and the gradient probes move too little to matter.
    let crosses = |v: usize, p: Vector2<f64>, uv: &[Vector2<f64>]| -> bool {
        for &ei in &on_boundary[v] {
            let (a, b) = boundary[ei];
            let (pa, pb) = (
                if a == v { p } else { uv[a] },
                if b == v { p } else { uv[b] },
            );
            for (j, &(c, d)) in boundary.iter().enumerate() {
                if j == ei || c == a || c == b || d == a || d == b {
                    continue;
                }
                let (pc, pd) = (
                    if c == v { p } else { uv[c] },
                    if d == v { p } else { uv[d] },
                );
                if segments_cross(pa, pb, pc, pd) {
                    return true;
                }
            }
        }
        false
    };
    let try_move = |v: usize,
                    p: Vector2<f64>,
                    uv: &[Vector2<f64>],
                    term: &[(f64, f64)],
                    sl: f64,
                    sa: f64|
     -> Option<Move> {
        let mut new_terms = Vec::with_capacity(incident[v].len());
        let (mut dl, mut da) = (0.0, 0.0);
        for &fi in &incident[v] {
            let f = &faces[fi];
            let q = f.v.map(|i| if i == v { p } else { uv[i] });
            let t = terms(f, q)?;
            dl += t.0 - term[fi].0;
            da += t.1 - term[fi].1;
            new_terms.push(t);
        }
        let (nl, na) = (sl + dl, sa + da);
        Some((nl * na, nl, na, new_terms))
    };
    let mut energy = sl * sa;
    for _ in 0..opts.sweeps {
        let start_energy = energy;
        for v in 0..nv {
            if incident[v].is_empty() {
                continue;
            }
            let scale = incident[v]
                .iter()
                .flat_map(|&fi| {
                    faces[fi]
                        .v
                        .iter()
                        .filter(|&&u| u != v)
                        .map(|&u| (uv[u] - uv[v]).norm())
                })
                .fold(f64::INFINITY, f64::min);
            if !(scale.is_finite() && scale > 0.0) {
                continue;
            }
            // Central-difference gradient of the energy at v.
            let h = 1e-4 * scale;
            let mut grad = Vector2::zeros();
            let mut ok = true;
            for d in 0..2 {
                let mut e = Vector2::zeros();
                e[d] = h;
                match (
                    try_move(v, uv[v] + e, uv, &term, sl, sa),
                    try_move(v, uv[v] - e, uv, &term, sl, sa),
                ) {
                    (Some(a), Some(b)) => grad[d] = (a.0 - b.0) / (2.0 * h),
                    _ => ok = false,
                }
            }
            if !ok || grad.norm() == 0.0 {
                continue;
            }
            let dir = -grad.normalize();
            let mut step = 0.5 * scale;
            for _ in 0..10 {
                if let Some((e, nl, na, nt)) = try_move(v, uv[v] + dir * step, uv, &term, sl, sa) {
                    if e < energy && !crosses(v, uv[v] + dir * step, uv) {
                        uv[v] += dir * step;
                        for (&fi, t) in incident[v].iter().zip(nt) {
                            term[fi] = t;
                        }
                        (sl, sa, energy) = (nl, na, e);
                        break;
                    }
                }
                step *= 0.5;
            }
        }
        // Re-sum to keep rounding drift out of the running totals.
        sl = term.iter().map(|t| t.0).sum();
        sa = term.iter().map(|t| t.1).sum();
        energy = sl * sa;
        if start_energy - energy < 1e-5 * start_energy {
            break;
        }
    }
    // Rescale so the chart's 2D area equals its 3D area; the weighted L2 at that scale is
    // sqrt(sum L2^2 w A3 / sum w A3) = sqrt(sl * sa / (swa * A3)).
    let total_a3: f64 = map.face_ids.iter().map(|f| mesh.face_area(*f)).sum();
    let k = (total_a3 / sa).sqrt();
    for p in uv.iter_mut() {
        *p *= k;
    }
    (sl * sa / (swa * total_a3)).sqrt()
}
