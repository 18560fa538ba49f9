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
use rustc_hash::FxHashMap;

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
    /// Iterations of the global phase (L-BFGS on all vertices). Default: 300.
    pub iterations: usize,
    /// Sweeps of one-vertex-at-a-time descent after it. Default: 10.
    pub sweeps: usize,
}

impl Default for StretchOptions {
    fn default() -> Self {
        StretchOptions {
            view_dir: None,
            k: 1.5,
            alpha: 0.05,
            iterations: 300,
            sweeps: 10,
        }
    }
}

/// The paper's visual importance of a triangle with (any-length) normal `n`:
/// `w = 1 / (<N, V> + k)`, or 1 without a view direction.
pub fn weight(n: Vector3<f64>, opts: &StretchOptions) -> f64 {
    match (
        opts.view_dir.and_then(|v| v.try_normalize(0.0)),
        n.try_normalize(0.0),
    ) {
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
        .map(|&(e, a)| {
            if e > 0.0 && a > 0.0 {
                (e / a).powf(0.25)
            } else {
                1.0
            }
        })
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

/// A tentative move: the new energy, stretch sum and area sum (its per-face terms go into a
/// buffer the caller reuses: one allocation per try was a malloc per probe of every sweep).
type Move = (f64, f64, f64);

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

/// Boundary edges bucketed in a uniform grid (cells of twice the mean boundary edge length),
/// kept up to date as vertices move, so the test for a crossing looks at nearby edges only.
struct EdgeGrid {
    cell: f64,
    cells: FxHashMap<(i64, i64), Vec<u32>>,
}

impl EdgeGrid {
    fn new(edges: &[(usize, usize)], uv: &[Vector2<f64>]) -> EdgeGrid {
        let mean = edges
            .iter()
            .map(|&(a, b)| (uv[a] - uv[b]).norm())
            .sum::<f64>()
            / edges.len().max(1) as f64;
        let mut g = EdgeGrid {
            cell: (2.0 * mean).max(1e-300),
            cells: FxHashMap::default(),
        };
        for (i, &e) in edges.iter().enumerate() {
            g.insert(i, e, uv);
        }
        g
    }

    fn range(&self, a: Vector2<f64>, b: Vector2<f64>) -> impl Iterator<Item = (i64, i64)> {
        let c = |x: f64| (x / self.cell).floor() as i64;
        let (x0, x1) = (c(a.x.min(b.x)), c(a.x.max(b.x)));
        let (y0, y1) = (c(a.y.min(b.y)), c(a.y.max(b.y)));
        (x0..=x1).flat_map(move |x| (y0..=y1).map(move |y| (x, y)))
    }

    fn insert(&mut self, i: usize, (a, b): (usize, usize), uv: &[Vector2<f64>]) {
        let keys: Vec<(i64, i64)> = self.range(uv[a], uv[b]).collect();
        for k in keys {
            self.cells.entry(k).or_default().push(i as u32);
        }
    }

    fn remove(&mut self, i: usize, (a, b): (usize, usize), uv: &[Vector2<f64>]) {
        let keys: Vec<(i64, i64)> = self.range(uv[a], uv[b]).collect();
        for k in keys {
            if let Some(list) = self.cells.get_mut(&k) {
                list.retain(|&j| j != i as u32);
            }
        }
    }

    /// Edges in the cells the segment a-b passes over (possibly repeated).
    fn near(&self, a: Vector2<f64>, b: Vector2<f64>) -> impl Iterator<Item = u32> + '_ {
        self.range(a, b)
            .filter_map(|k| self.cells.get(&k))
            .flatten()
            .copied()
    }
}

/// Gradient of one face's stretch term `wa F / (8 A^2)` and of its area `A` with respect to
/// its three UV corners. With N_s = sum p_i (t_j - t_k), N_t = sum p_i (s_k - s_j) (cyclic),
/// F = |N_s|^2 + |N_t|^2 and signed area A, dA/dq_i = (t_j - t_k, s_k - s_j) / 2 and
/// dF/dq_i = 2 (N_t . (p_j - p_k), N_s . (p_k - p_j)).
fn face_gradient(f: &Face, q: [Vector2<f64>; 3]) -> [(Vector2<f64>, Vector2<f64>); 3] {
    let p = &f.p;
    let ns = p[0].coords * (q[1].y - q[2].y)
        + p[1].coords * (q[2].y - q[0].y)
        + p[2].coords * (q[0].y - q[1].y);
    let nt = p[0].coords * (q[2].x - q[1].x)
        + p[1].coords * (q[0].x - q[2].x)
        + p[2].coords * (q[1].x - q[0].x);
    let a = uv_area(q);
    let ff = ns.norm_squared() + nt.norm_squared();
    std::array::from_fn(|i| {
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        let da = Vector2::new(0.5 * (q[j].y - q[k].y), 0.5 * (q[k].x - q[j].x));
        let df = Vector2::new(2.0 * nt.dot(&(p[j] - p[k])), 2.0 * ns.dot(&(p[k] - p[j])));
        ((df - da * (2.0 * ff / a)) * (f.wa / (8.0 * a * a)), da)
    })
}

/// Exact gradient of E = SL * SA with respect to the UV of vertex `v` (its faces `incident`):
/// dE = dSL * SA + SL * dSA.
fn vertex_gradient(
    faces: &[Face],
    incident: &[usize],
    v: usize,
    uv: &[Vector2<f64>],
    sl: f64,
    sa: f64,
) -> Vector2<f64> {
    let mut g = Vector2::zeros();
    for &fi in incident {
        let f = &faces[fi];
        let i =
            f.v.iter()
                .position(|&u| u == v)
                .expect("v is a corner of its faces");
        let (dterm, da) = face_gradient(f, f.v.map(|u| uv[u]))[i];
        g += dterm * sa + da * sl;
    }
    g
}

/// SL and SA of the whole chart, or `None` if a triangle breaks the barrier (or flips).
fn energy_terms(faces: &[Face], uv: &[Vector2<f64>]) -> Option<(f64, f64)> {
    let (mut sl, mut sa) = (0.0, 0.0);
    for f in faces {
        let (l, a) = terms(f, f.v.map(|i| uv[i]))?;
        sl += l;
        sa += a;
    }
    Some((sl, sa))
}

/// The global phase stops after five iterations in a row that each lower the energy by less
/// than this fraction. On the 1.17M-face corset 1e-5 took 20,645 iterations over the 400
/// minimised charts against 37,723 for 1e-7 (5.6 against 9.0 CPU s), with the atlas's L2
/// 1.013581 against 1.013574 (docs/decisions.md, "Atlas"). It waited until stage 6's
/// exemplars stopped depending on the layout (2026-12-05).
const STALL: f64 = 1e-5;

/// Global phase: L-BFGS on all UVs at once, which moves the low-frequency modes (overall
/// area distribution) that one-vertex-at-a-time descent barely touches on large charts. The
/// line search never lets a triangle reach zero area (largest step from the quadratic of each
/// triangle's signed area, as Smith and Schaefer 2015), refuses steps that break the shape
/// barrier or make the boundary cross itself, and requires sufficient decrease. Returns the
/// iterations done.
fn lbfgs(faces: &[Face], local: &[[u32; 3]], uv: &mut [Vector2<f64>], iterations: usize) -> usize {
    const HISTORY: usize = 8;
    let n = uv.len();
    let border = super::param::boundary_edges(local);
    let flat = |uv: &[Vector2<f64>]| -> Vec<f64> { uv.iter().flat_map(|p| [p.x, p.y]).collect() };
    let grad = |uv: &[Vector2<f64>], sl: f64, sa: f64| -> Vec<f64> {
        let mut g = vec![0.0; 2 * n];
        for f in faces {
            let gs = face_gradient(f, f.v.map(|i| uv[i]));
            for (k, &(dterm, da)) in gs.iter().enumerate() {
                let d = dterm * sa + da * sl;
                g[2 * f.v[k]] += d.x;
                g[2 * f.v[k] + 1] += d.y;
            }
        }
        g
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let Some((sl, sa)) = energy_terms(faces, uv) else {
        return 0;
    };
    let mut e = sl * sa;
    let mut g = grad(uv, sl, sa);
    let mut hist: std::collections::VecDeque<(Vec<f64>, Vec<f64>, f64)> = Default::default();
    let mean_edge = faces
        .iter()
        .map(|f| (uv[f.v[1]] - uv[f.v[0]]).norm())
        .sum::<f64>()
        / faces.len().max(1) as f64;
    let mut stalls = 0;
    let mut done = 0;
    let mut trial = vec![Vector2::zeros(); n];
    for it in 0..iterations {
        done = it + 1;
        // Two-loop recursion.
        let mut d: Vec<f64> = g.iter().map(|x| -x).collect();
        let mut alphas = Vec::with_capacity(hist.len());
        for (s, y, rho) in hist.iter().rev() {
            let a = rho * dot(s, &d);
            for (di, yi) in d.iter_mut().zip(y) {
                *di -= a * yi;
            }
            alphas.push(a);
        }
        if let Some((s, y, _)) = hist.back() {
            let gamma = dot(s, y) / dot(y, y);
            for di in d.iter_mut() {
                *di *= gamma;
            }
        }
        for ((s, y, rho), a) in hist.iter().zip(alphas.iter().rev()) {
            let b = rho * dot(y, &d);
            for (di, si) in d.iter_mut().zip(s) {
                *di += (a - b) * si;
            }
        }
        let mut slope = dot(&g, &d);
        if slope.is_nan() || slope >= 0.0 {
            hist.clear();
            d = g.iter().map(|x| -x).collect();
            slope = -dot(&g, &g);
        }
        if slope == 0.0 {
            break;
        }
        // First step: move the fastest vertex a tenth of an edge; later, the quasi-Newton step.
        let dmax = d.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let mut step = if hist.is_empty() {
            0.1 * mean_edge / dmax.max(1e-300)
        } else {
            1.0
        };
        // Largest step before any triangle's signed area reaches zero.
        for f in faces {
            let q = f.v.map(|i| uv[i]);
            let dv = f.v.map(|i| Vector2::new(d[2 * i], d[2 * i + 1]));
            let (e1, e2) = (q[1] - q[0], q[2] - q[0]);
            let (f1, f2) = (dv[1] - dv[0], dv[2] - dv[0]);
            let (c0, c1, c2) = (e1.perp(&e2), e1.perp(&f2) + f1.perp(&e2), f1.perp(&f2));
            let root = if c2.abs() < 1e-300 {
                if c1 < 0.0 {
                    -c0 / c1
                } else {
                    f64::INFINITY
                }
            } else {
                let disc = c1 * c1 - 4.0 * c2 * c0;
                if disc < 0.0 {
                    f64::INFINITY
                } else {
                    let r = disc.sqrt();
                    let (t1, t2) = ((-c1 - r) / (2.0 * c2), (-c1 + r) / (2.0 * c2));
                    [t1, t2]
                        .into_iter()
                        .filter(|t| *t > 0.0)
                        .fold(f64::INFINITY, f64::min)
                }
            };
            step = step.min(0.8 * root);
        }
        let mut accepted = None;
        for _ in 0..40 {
            for (i, t) in trial.iter_mut().enumerate() {
                *t = uv[i] + Vector2::new(d[2 * i], d[2 * i + 1]) * step;
            }
            if let Some((nl, na)) = energy_terms(faces, &trial) {
                let ne = nl * na;
                if ne <= e + 1e-4 * step * slope && !super::param::edges_cross(&border, &trial) {
                    accepted = Some((nl, na, ne));
                    break;
                }
            }
            step *= 0.5;
        }
        let Some((nl, na, ne)) = accepted else { break };
        let old = flat(uv);
        uv.copy_from_slice(&trial);
        let ng = grad(uv, nl, na);
        let s: Vec<f64> = flat(uv).iter().zip(&old).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = ng.iter().zip(&g).map(|(a, b)| a - b).collect();
        let sy = dot(&s, &y);
        if sy > 1e-300 {
            if hist.len() == HISTORY {
                hist.pop_front();
            }
            hist.push_back((s, y, 1.0 / sy));
        }
        stalls = if e - ne < STALL * e { stalls + 1 } else { 0 };
        (e, g) = (ne, ng);
        if stalls >= 5 {
            break;
        }
    }
    done
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
    let mut directed: FxHashMap<(usize, usize), ()> = FxHashMap::default();
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
    if opts.iterations > 0 {
        lbfgs(&faces, &map.faces, uv, opts.iterations);
    }
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
    let mut grid = EdgeGrid::new(&boundary, uv);
    let crosses = |v: usize, p: Vector2<f64>, uv: &[Vector2<f64>], grid: &EdgeGrid| -> bool {
        let at = |u: usize| if u == v { p } else { uv[u] };
        for &ei in &on_boundary[v] {
            let (a, b) = boundary[ei];
            let (pa, pb) = (at(a), at(b));
            let hit = grid.near(pa, pb).any(|j| {
                let (c, d) = boundary[j as usize];
                j as usize != ei
                    && c != a
                    && c != b
                    && d != a
                    && d != b
                    && segments_cross(pa, pb, at(c), at(d))
            });
            if hit {
                return true;
            }
        }
        false
    };
    let try_move = |v: usize,
                    p: Vector2<f64>,
                    uv: &[Vector2<f64>],
                    term: &[(f64, f64)],
                    sl: f64,
                    sa: f64,
                    new_terms: &mut Vec<(f64, f64)>|
     -> Option<Move> {
        new_terms.clear();
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
        Some((nl * na, nl, na))
    };
    let mut nt: Vec<(f64, f64)> = Vec::new();
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
            let grad = vertex_gradient(&faces, &incident[v], v, uv, sl, sa);
            let ok = grad.iter().all(|g| g.is_finite());
            if !ok || grad.norm() == 0.0 {
                continue;
            }
            let dir = -grad.normalize();
            let mut step = 0.5 * scale;
            for _ in 0..10 {
                let probe = uv[v] + dir * step;
                if let Some((e, nl, na)) = try_move(v, probe, uv, &term, sl, sa, &mut nt) {
                    if e < energy && !crosses(v, probe, uv, &grid) {
                        for &ei in &on_boundary[v] {
                            grid.remove(ei, boundary[ei], uv);
                        }
                        uv[v] += dir * step;
                        for &ei in &on_boundary[v] {
                            grid.insert(ei, boundary[ei], uv);
                        }
                        for (&fi, &t) in incident[v].iter().zip(&nt) {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The analytic gradient equals central differences of E = SL * SA.
    #[test]
    fn vertex_gradient_matches_finite_differences() {
        let pts = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(1.0, 0.1, 0.2),
            Point3::new(0.2, 1.1, -0.3),
            Point3::new(-0.9, 0.4, 0.5),
        ];
        let uv = vec![
            Vector2::new(0.05, -0.02),
            Vector2::new(1.1, 0.0),
            Vector2::new(0.3, 0.9),
            Vector2::new(-0.8, 0.6),
        ];
        let tris = [[0usize, 1, 2], [0, 2, 3]];
        let faces: Vec<Face> = tris
            .iter()
            .zip([0.7, 1.9])
            .map(|(t, wa)| Face {
                v: *t,
                p: t.map(|i| pts[i]),
                wa,
                min_hb: 0.0,
            })
            .collect();
        let energy = |uv: &[Vector2<f64>]| {
            let (mut sl, mut sa) = (0.0, 0.0);
            for f in &faces {
                let (l, a) = terms(f, f.v.map(|i| uv[i])).unwrap();
                sl += l;
                sa += a;
            }
            (sl, sa)
        };
        let (sl, sa) = energy(&uv);
        let g = vertex_gradient(&faces, &[0, 1], 0, &uv, sl, sa);
        let h = 1e-6;
        for d in 0..2 {
            let (mut a, mut b) = (uv.clone(), uv.clone());
            a[0][d] += h;
            b[0][d] -= h;
            let (ea, eb) = (energy(&a), energy(&b));
            let fd = (ea.0 * ea.1 - eb.0 * eb.1) / (2.0 * h);
            assert!(
                (fd - g[d]).abs() < 1e-6 * fd.abs().max(1.0),
                "{d}: {fd} vs {}",
                g[d]
            );
        }
    }
}
