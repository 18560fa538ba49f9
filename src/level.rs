//! Seam levelling (part of stage 4): a smooth additive colour correction per chart that makes
//! the two sides of every chart border agree.
//!
//! Per-chart pyramids blend each chart in its own image, so their coarse bands mix the
//! photographs differently on either side of a border, and the deeper the pyramid the larger
//! the step (docs/decisions.md). After the merge we therefore solve, as Lempitsky and Ivanov
//! (2007) and TexRecon's global levelling do, for one correction `g` per texture coordinate
//! (RGB), interpolated linearly over each triangle in the atlas, minimising
//!
//! ```text
//!   sum over border samples s   |g_1(s) - g_2(s) + c_1(s) - c_2(s)|^2
//! + smoothness * sum over triangle edges (u, v) inside charts   |g_u - g_v|^2
//! + smoothness * sum over u   (area around u / REACH^2) |g_u|^2
//! ```
//!
//! where `c_1(s)`, `c_2(s)` are the atlas colours half a texel inside either side of a border
//! sample, one sample per texel of edge length (the same reads as the chart-border seam measure
//! in [`crate::seams`]), plus a screening term `|g_u|^2` weighted by the chart area around `u`
//! over [`REACH`]^2, so that corrections fade over about [`REACH`] texels instead of shifting
//! whole charts. The correction is piecewise linear on the mesh, so it only moves colour at the
//! scale of triangles. Border samples are reweighted (Cauchy, [`ROBUST_SCALE`]) so that real
//! differences along a border do not pull. Solved by conjugate gradients with a Jacobi
//! preconditioner, matrix-free.

use crate::atlas::texels::{border_samples, texel_point};
use crate::mesh::Mesh;
use nalgebra::Vector2;
use rayon::prelude::*;
use serde::Serialize;

/// Weight of the smoothness term per triangle edge, relative to one border sample. Chosen on
/// the corset (docs/decisions.md): 0.1 reaches chart-border ratio 1.10; 1 gives 1.24 and 10
/// 1.63 for at most 0.15 dB of held-out PSNR.
pub const SMOOTHNESS: f64 = 0.1;

/// Texels over which a correction fades into its chart. On the corset at 2 levels
/// (docs/decisions.md) 16 gives chart-border ratio 1.074 and held-out 1 - NCC 0.2308; 256
/// (nearly whole-chart shifts) 1.099 and 0.2329; 4 1.080 and 0.2308.
pub const REACH: f64 = 16.0;

/// Scale of the Cauchy reweighting of border samples (RGB difference, 0-1): a sample whose
/// sides still differ by this after a solve counts half. On the corset 0.02 improves
/// held-out PSNR by 0.17 dB and the chart-border ratio from 1.127 to 1.101 over plain least
/// squares.
pub const ROBUST_SCALE: f64 = 0.02;

/// Relative residual at which a solve stops. On the corset 1e-3 takes 47 iterations where
/// 1e-5 took 263, and the levelled atlas differs by at most 2/255 (1% of values by 1); the
/// border step after levelling is the same to 1e-7 (docs/decisions.md).
const TOLERANCE: f64 = 1e-3;

/// Reweighted solves after the first.
const REWEIGHTS: usize = 3;

/// What levelling did.
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct LevelStats {
    /// Border samples (one per texel of chart-border length).
    pub samples: u64,
    /// Unknown corrections (texture coordinates on the page).
    pub unknowns: u64,
    /// Conjugate-gradient iterations.
    pub iterations: u32,
    /// Mean absolute colour difference across the border samples (RGB mean, 0-1), before.
    pub border_step_before: f64,
    /// The same after the correction.
    pub border_step_after: f64,
    /// Largest correction applied to any channel.
    pub max_correction: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// One border sample: the two sides' texture-coordinate pairs and position along the edge,
/// and the colour difference side 1 minus side 2.
struct Sample {
    u: [u32; 4],
    t: f64,
    d: [f64; 3],
}

impl Sample {
    /// Coefficients of the residual on `u`: side 1 positive, side 2 negative.
    fn coef(&self) -> [f64; 4] {
        [1.0 - self.t, self.t, -(1.0 - self.t), -self.t]
    }
}

type V3 = [f64; 3];

/// Levels the chart borders of `color` (an `n` x `n` RGB atlas of `mesh`'s page 0, `owner`
/// giving each texel's face and `face_chart` each face's chart) in place.
pub fn level_seams(
    mesh: &Mesh,
    n: usize,
    owner: &(dyn Fn(usize) -> Option<u32> + Sync),
    face_chart: &[u32],
    color: &mut [f32],
    smoothness: f64,
) -> LevelStats {
    let t = std::time::Instant::now();
    let Some(uv) = &mesh.uv else {
        return LevelStats::default();
    };
    let s = n as f64;
    let texel = |c: u32| texel_point(uv, c, n);
    // Bilinear colour at texel coordinates from the texels of `chart` only, so that gutter and
    // neighbouring charts never enter a read.
    let read = |p: Vector2<f64>, chart: u32| -> Option<V3> {
        let (x, y) = (p.x - 0.5, p.y - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (mut acc, mut wsum) = ([0f64; 3], 0f64);
        for (dx, dy, w) in [
            (0.0, 0.0, (1.0 - fx) * (1.0 - fy)),
            (1.0, 0.0, fx * (1.0 - fy)),
            (0.0, 1.0, (1.0 - fx) * fy),
            (1.0, 1.0, fx * fy),
        ] {
            let (xx, yy) = (x0 + dx, y0 + dy);
            if w <= 0.0 || xx < 0.0 || yy < 0.0 || xx >= s || yy >= s {
                continue;
            }
            let i = yy as usize * n + xx as usize;
            match owner(i) {
                Some(f) if face_chart[f as usize] == chart => {}
                _ => continue,
            }
            for k in 0..3 {
                acc[k] += w * color[3 * i + k] as f64;
            }
            wsum += w;
        }
        (wsum > 1e-6).then(|| acc.map(|v| v / wsum))
    };

    // Border samples, where both faces belong to charts on the page.
    let mut samples: Vec<Sample> = border_samples(mesh, n)
        .into_par_iter()
        .filter_map(|b| {
            let (c1, c2) = (face_chart[b.faces[0]], face_chart[b.faces[1]]);
            if c1 == u32::MAX || c2 == u32::MAX {
                return None;
            }
            let x1 = read(b.at[0] + b.inward[0] * 0.5, c1)?;
            let x2 = read(b.at[1] + b.inward[1] * 0.5, c2)?;
            Some(Sample {
                u: [b.uv[0][0], b.uv[0][1], b.uv[1][0], b.uv[1][1]],
                t: b.t,
                d: std::array::from_fn(|c| x1[c] - x2[c]),
            })
        })
        .collect();
    if samples.is_empty() {
        return LevelStats::default();
    }

    // Unknowns: texture coordinates of on-page faces, renumbered densely.
    let mut index = vec![u32::MAX; uv.coords.len()];
    let mut count = 0u32;
    let mut edges: Vec<(u32, u32)> = Vec::new();
    for (f, c) in uv.faces.iter().enumerate() {
        if face_chart[f] == u32::MAX {
            continue;
        }
        for &ci in c {
            if index[ci as usize] == u32::MAX {
                index[ci as usize] = count;
                count += 1;
            }
        }
        for k in 0..3 {
            let (x, y) = (index[c[k] as usize], index[c[(k + 1) % 3] as usize]);
            edges.push((x.min(y), x.max(y)));
        }
    }
    // Sorting pairs of integers: the parallel sort gives the same order.
    edges.par_sort_unstable();
    edges.dedup();
    let nu = count as usize;
    for smp in &mut samples {
        smp.u = smp.u.map(|u| index[u as usize]);
    }

    // Normal equations A g = rhs, applied matrix-free, with per-sample weights; reweighted
    // (Cauchy) so that border samples whose sides truly differ (an occlusion error, a
    // highlight, an edge of the content along the border) do not drag whole charts.
    // Screening: each unknown is pulled to zero by its share of chart area over REACH^2, so
    // a correction fades over about REACH texels from the border instead of shifting whole
    // charts, and the system stays well conditioned whatever the mesh size.
    let mut screen = vec![0f64; nu];
    for (f, c) in uv.faces.iter().enumerate() {
        if face_chart[f] == u32::MAX {
            continue;
        }
        let t = c.map(texel);
        let area = 0.5 * ((t[1] - t[0]).perp(&(t[2] - t[0]))).abs();
        for &ci in c {
            screen[index[ci as usize] as usize] += smoothness * area / (3.0 * REACH * REACH);
        }
    }
    let screen = &screen;
    // Per unknown, its neighbours and the border samples it enters (as CSR lists), so that
    // the operator is applied by gathering, in parallel.
    let csr = |pairs: &mut Vec<(u32, u32)>| -> (Vec<usize>, Vec<u32>) {
        pairs.par_sort_unstable();
        let mut start = vec![0usize; nu + 1];
        for &(u, _) in pairs.iter() {
            start[u as usize + 1] += 1;
        }
        for i in 0..nu {
            start[i + 1] += start[i];
        }
        (start, pairs.iter().map(|p| p.1).collect())
    };
    let (nbr_start, nbr) = csr(&mut edges.iter().flat_map(|&(u, v)| [(u, v), (v, u)]).collect());
    let (touch_start, touch) = csr(&mut samples
        .iter()
        .enumerate()
        .flat_map(|(si, smp)| (0..4).map(move |j| (smp.u[j], (4 * si + j) as u32)))
        .collect());
    // Each entry's sample and coefficient side by side, so that the gather below reads one
    // list and the samples' residuals instead of the samples themselves (48 bytes each, in
    // no order near the unknown's: on the 1.5M-face scene about half of the solve's time).
    let touch: Vec<(u32, f64)> = touch
        .iter()
        .map(|&t| {
            let (si, j) = (t as usize / 4, t as usize % 4);
            (si as u32, samples[si].coef()[j])
        })
        .collect();
    let solve = |wt: &[f64], x0: Vec<V3>| {
        // The samples' weighted residuals, written anew by every application.
        let mut r = vec![[0f64; 3]; samples.len()];
        let apply = |x: &[V3], out: &mut [V3]| {
            r.par_iter_mut()
                .zip(&samples)
                .zip(wt)
                .for_each(|((r, smp), &w)| {
                    let a = smp.coef();
                    *r = [0f64; 3];
                    for (j, &u) in smp.u.iter().enumerate() {
                        for c in 0..3 {
                            r[c] += w * a[j] * x[u as usize][c];
                        }
                    }
                });
            let r = &r;
            out.par_iter_mut().enumerate().for_each(|(u, o)| {
                let xu = x[u];
                let mut v = xu.map(|e| screen[u] * e);
                for &q in &nbr[nbr_start[u]..nbr_start[u + 1]] {
                    for c in 0..3 {
                        v[c] += smoothness * (xu[c] - x[q as usize][c]);
                    }
                }
                for &(si, a) in &touch[touch_start[u]..touch_start[u + 1]] {
                    for c in 0..3 {
                        v[c] += a * r[si as usize][c];
                    }
                }
                *o = v;
            });
        };
        let mut diag = screen.clone();
        let mut rhs = vec![[0f64; 3]; nu];
        for (smp, &w) in samples.iter().zip(wt) {
            let a = smp.coef();
            for (j, &u) in smp.u.iter().enumerate() {
                diag[u as usize] += w * a[j] * a[j];
                for (r, d) in rhs[u as usize].iter_mut().zip(smp.d) {
                    *r -= w * a[j] * d;
                }
            }
        }
        for &(u, v) in &edges {
            diag[u as usize] += smoothness;
            diag[v as usize] += smoothness;
        }
        conjugate_gradient(apply, &diag, &rhs, x0, TOLERANCE, 5000)
    };
    let residual = |smp: &Sample, g: &[V3]| -> f64 {
        let a = smp.coef();
        (0..3)
            .map(|c| {
                let corr: f64 = (0..4).map(|j| a[j] * g[smp.u[j] as usize][c]).sum();
                (smp.d[c] + corr).abs()
            })
            .sum::<f64>()
            / 3.0
    };
    let mut wt = vec![1f64; samples.len()];
    let (mut g, mut iterations) = solve(&wt, vec![[0f64; 3]; nu]);
    for _ in 0..REWEIGHTS {
        for (w, smp) in wt.iter_mut().zip(&samples) {
            let r = residual(smp, &g) / ROBUST_SCALE;
            *w = 1.0 / (1.0 + r * r);
        }
        // Warm start: reweighting moves the solution little.
        let (g2, it) = solve(&wt, g);
        g = g2;
        iterations += it;
    }

    // Step before and after, at the samples.
    let zero = vec![[0f64; 3]; nu];
    let step =
        |g: &[V3]| samples.iter().map(|s| residual(s, g)).sum::<f64>() / samples.len() as f64;
    let (border_step_before, border_step_after) = (step(&zero), step(&g));

    // Apply: each chart texel gets its face's interpolated correction.
    color
        .par_chunks_mut(3 * n)
        .enumerate()
        .for_each(|(y, row)| {
            for x in 0..n {
                let Some(f) = owner(y * n + x) else {
                    continue;
                };
                let f = f as usize;
                if face_chart[f] == u32::MAX {
                    continue;
                }
                let c = uv.faces[f];
                let t = c.map(texel);
                let b = barycentric(&t, Vector2::new(x as f64 + 0.5, y as f64 + 0.5));
                for k in 0..3 {
                    let corr: f64 = (0..3)
                        .map(|j| b[j] * g[index[c[j] as usize] as usize][k])
                        .sum();
                    row[3 * x + k] += corr as f32;
                }
            }
        });
    let max_correction = g
        .iter()
        .flat_map(|v| v.iter())
        .fold(0f64, |m, v| m.max(v.abs()));
    LevelStats {
        samples: samples.len() as u64,
        unknowns: nu as u64,
        iterations,
        border_step_before,
        border_step_after,
        max_correction,
        seconds: t.elapsed().as_secs_f64(),
    }
}

/// Barycentric coordinates of `p` in triangle `t`, clamped onto the triangle (texels owned
/// conservatively lie just outside their face).
fn barycentric(t: &[Vector2<f64>; 3], p: Vector2<f64>) -> [f64; 3] {
    let cross = |u: Vector2<f64>, v: Vector2<f64>| u.x * v.y - u.y * v.x;
    let area = cross(t[1] - t[0], t[2] - t[0]);
    if area.abs() < 1e-300 {
        return [1.0 / 3.0; 3];
    }
    let b1 = cross(p - t[0], t[2] - t[0]) / area;
    let b2 = cross(t[1] - t[0], p - t[0]) / area;
    let b = [1.0 - b1 - b2, b1, b2].map(|v| v.max(0.0));
    let s: f64 = b.iter().sum();
    if s > 0.0 {
        b.map(|v| v / s)
    } else {
        [1.0 / 3.0; 3]
    }
}

/// Preconditioned conjugate gradients for a symmetric positive-definite operator on RGB
/// vectors (three right-hand sides sharing the operator, each channel converging on its own
/// step sizes). Stops when every channel's residual is below `tol` times its right-hand side.
fn conjugate_gradient(
    mut apply: impl FnMut(&[V3], &mut [V3]),
    diag: &[f64],
    rhs: &[V3],
    x0: Vec<V3>,
    tol: f64,
    max_iter: u32,
) -> (Vec<V3>, u32) {
    let nu = rhs.len();
    // Sums over fixed chunks, added in order: parallel and still the same bits every run.
    const CHUNK: usize = 4096;
    let dot = |a: &[V3], b: &[V3]| -> V3 {
        let parts: Vec<V3> = a
            .par_chunks(CHUNK)
            .zip(b.par_chunks(CHUNK))
            .map(|(a, b)| {
                let mut s = [0f64; 3];
                for (x, y) in a.iter().zip(b) {
                    for c in 0..3 {
                        s[c] += x[c] * y[c];
                    }
                }
                s
            })
            .collect();
        parts
            .iter()
            .fold([0f64; 3], |s, p| std::array::from_fn(|c| s[c] + p[c]))
    };
    // r = rhs - A x0.
    let mut x = x0;
    let mut r = vec![[0f64; 3]; nu];
    apply(&x, &mut r);
    for (ri, bi) in r.iter_mut().zip(rhs) {
        *ri = std::array::from_fn(|c| bi[c] - ri[c]);
    }
    let precondition = |r: &[V3]| -> Vec<V3> {
        r.par_iter()
            .zip(diag)
            .map(|(v, &d)| v.map(|e| e / d))
            .collect()
    };
    let mut z = precondition(&r);
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let b2 = dot(rhs, rhs);
    let mut ap = vec![[0f64; 3]; nu];
    let mut it = 0;
    while it < max_iter {
        let r2 = dot(&r, &r);
        if (0..3).all(|c| r2[c] <= tol * tol * b2[c].max(1e-300)) {
            break;
        }
        apply(&p, &mut ap);
        let pap = dot(&p, &ap);
        let alpha: V3 = std::array::from_fn(|c| if pap[c] > 0.0 { rz[c] / pap[c] } else { 0.0 });
        x.par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(p.par_iter().zip(&ap))
            .for_each(|((xi, ri), (pi, api))| {
                for c in 0..3 {
                    xi[c] += alpha[c] * pi[c];
                    ri[c] -= alpha[c] * api[c];
                }
            });
        z = precondition(&r);
        let rz_new = dot(&r, &z);
        let beta: V3 = std::array::from_fn(|c| if rz[c] > 0.0 { rz_new[c] / rz[c] } else { 0.0 });
        p.par_iter_mut().zip(&z).for_each(|(pi, zi)| {
            for c in 0..3 {
                pi[c] = zi[c] + beta[c] * pi[c];
            }
        });
        rz = rz_new;
        it += 1;
    }
    (x, it)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{UvMap, VertexId};
    use nalgebra::Point3;

    /// A unit square of two triangles whose halves are separate charts, side by side in the
    /// atlas with a gutter between, coloured 0.2 and 0.6: levelling meets in the middle at
    /// the border and fades into each chart.
    #[test]
    fn two_charts_meet_in_the_middle() {
        let p = |x: f64, y: f64| Point3::new(x, y, 0.0);
        let uvp = |x: f32, y: f32| Vector2::new(x, y);
        let mesh = Mesh {
            positions: vec![p(0.0, 0.0), p(1.0, 0.0), p(1.0, 1.0), p(0.0, 1.0)],
            faces: vec![
                [VertexId(0), VertexId(1), VertexId(2)],
                [VertexId(0), VertexId(2), VertexId(3)],
            ],
            normals: None,
            colors: None,
            uv: Some(UvMap {
                coords: vec![
                    uvp(0.05, 0.1),
                    uvp(0.45, 0.1),
                    uvp(0.45, 0.9),
                    uvp(0.55, 0.1),
                    uvp(0.95, 0.9),
                    uvp(0.55, 0.9),
                ],
                faces: vec![[0, 1, 2], [3, 4, 5]],
            }),
            texture: None,
        };
        let n = 64;
        let uv = mesh.uv.as_ref().unwrap();
        let tri = |f: usize| -> [Vector2<f64>; 3] { uv.faces[f].map(|c| texel_point(uv, c, n)) };
        // Owner: the face whose triangle holds the texel centre, grown by one texel.
        let owner_map: Vec<Option<u32>> = (0..n * n)
            .map(|i| {
                let c = Vector2::new((i % n) as f64 + 0.5, (i / n) as f64 + 0.5);
                (0..2u32).find(|&f| {
                    let t = tri(f as usize);
                    (0..3).all(|k| {
                        let (a, b) = (t[k], t[(k + 1) % 3]);
                        let e = b - a;
                        let o = t[(k + 2) % 3] - a;
                        let side = |q: Vector2<f64>| e.x * q.y - e.y * q.x;
                        side(c - a) * side(o).signum() / e.norm() >= -1.0
                    })
                })
            })
            .collect();
        let owner = |i: usize| owner_map[i];
        let mut color = vec![0f32; n * n * 3];
        for (i, o) in owner_map.iter().enumerate() {
            if let Some(f) = o {
                let v = if *f == 0 { 0.2 } else { 0.6 };
                color[3 * i..3 * i + 3].fill(v);
            }
        }
        let st = level_seams(&mesh, n, &owner, &[0, 1], &mut color, SMOOTHNESS);
        assert!(st.samples > 20, "{st:?}");
        assert!((st.border_step_before - 0.4).abs() < 1e-6, "{st:?}");
        assert!(st.border_step_after < 0.02, "{st:?}");
        // Each chart moves towards the other, most at the border, never past the middle.
        let mut mean = [0f64; 2];
        let mut count = [0f64; 2];
        for (i, o) in owner_map.iter().enumerate() {
            if let Some(f) = o {
                let v = color[3 * i];
                assert!((0.2 - 1e-4..=0.6 + 1e-4).contains(&v), "{v}");
                mean[*f as usize] += v as f64;
                count[*f as usize] += 1.0;
            }
        }
        assert!(
            mean[0] / count[0] > 0.25 && mean[1] / count[1] < 0.55,
            "{mean:?}"
        );
    }

    #[test]
    fn conjugate_gradient_solves_a_small_system() {
        // Tridiagonal SPD matrix [2 -1; -1 2 -1; -1 2], x = (1, 2, 3) per channel scaled.
        let apply = |x: &[V3], out: &mut [V3]| {
            for i in 0..3 {
                for c in 0..3 {
                    let mut v = 2.0 * x[i][c];
                    if i > 0 {
                        v -= x[i - 1][c];
                    }
                    if i < 2 {
                        v -= x[i + 1][c];
                    }
                    out[i][c] = v;
                }
            }
        };
        let truth = [[1.0, 10.0, -1.0], [2.0, 20.0, -2.0], [3.0, 30.0, -3.0]];
        let mut rhs = vec![[0f64; 3]; 3];
        apply(&truth, &mut rhs);
        let (x, it) = conjugate_gradient(apply, &[2.0; 3], &rhs, vec![[0.0; 3]; 3], 1e-12, 100);
        assert!(it <= 4, "{it} iterations");
        for i in 0..3 {
            for c in 0..3 {
                assert!((x[i][c] - truth[i][c]).abs() < 1e-9, "{x:?}");
            }
        }
    }
}
