//! Stage 1, the atlas (issue 4, in progress). Built: chart segmentation into disks
//! ([`segment`]), a flip-free start per chart (projection, LSCM, or mean-value embedding) with
//! Sander's stretch measures ([`param`]), the paper's view-weighted L2 stretch minimisation with
//! the shape barrier ([`optimize`]), and [`flatten_all`], which splits charts whose stretch stays
//! too high. To come: packing into atlas pages, `scantex param`, keeping a whole disk-shaped
//! mesh as one chart when its stretch allows.

pub mod optimize;
pub mod param;
pub mod segment;

use crate::mesh::Mesh;
use param::ChartMap;
use segment::{is_disk, split, Adjacency, SegmentOptions};

/// Options for [`flatten_all`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlattenOptions {
    /// Segmentation options.
    pub segment: SegmentOptions,
    /// Stretch minimisation (view weight, shape barrier).
    pub stretch: optimize::StretchOptions,
    /// A chart whose own L2 stretch after minimisation exceeds this is split in two and both
    /// halves flattened again. Default: 1.25.
    pub max_chart_stretch: f64,
}

impl Default for FlattenOptions {
    fn default() -> Self {
        FlattenOptions {
            segment: SegmentOptions::default(),
            stretch: optimize::StretchOptions::default(),
            max_chart_stretch: 1.25,
        }
    }
}

/// Segments `mesh` and flattens every chart, splitting charts until each one's L2 stretch is
/// at most `max_chart_stretch` (a single triangle is always an isometry, so this ends).
/// Charts are processed in parallel; the result does not depend on the thread count.
pub fn flatten_all(mesh: &Mesh, opts: &FlattenOptions) -> Vec<ChartMap> {
    use rayon::prelude::*;
    let adj = Adjacency::new(mesh);
    let charts = segment::segment(mesh, &opts.segment).charts;
    let per_chart: Vec<Vec<ChartMap>> = charts
        .into_par_iter()
        .map(|chart| flatten_chart(mesh, &adj, chart, opts))
        .collect();
    per_chart.into_iter().flatten().collect()
}

/// Flattens one chart, splitting it while its stretch is too high.
fn flatten_chart(
    mesh: &Mesh,
    adj: &Adjacency,
    chart: Vec<crate::mesh::FaceId>,
    opts: &FlattenOptions,
) -> Vec<ChartMap> {
    let mut todo = vec![chart];
    let mut out = Vec::new();
    while let Some(chart) = todo.pop() {
        let mut map = param::flatten(mesh, &chart);
        let start = param::stretch(mesh, std::slice::from_ref(&map));
        // Charts that already flatten almost isometrically need no minimisation.
        if start.l2 > 1.001 || opts.stretch.view_dir.is_some() {
            optimize::optimize(mesh, &mut map, &opts.stretch);
        }
        let s = param::stretch(mesh, std::slice::from_ref(&map));
        if chart.len() > 1 && (s.l2 > opts.max_chart_stretch || s.flipped > 0 || s.zero_area > 0) {
            let (a, b) = split(adj, &chart);
            for part in [b, a] {
                if is_disk(mesh, adj, &part) {
                    todo.push(part);
                } else {
                    // Split halves can be non-disks: split again.
                    let (x, y) = split(adj, &part);
                    todo.push(x);
                    todo.push(y);
                }
            }
        } else {
            out.push(map);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flatten_all_bounds_every_charts_stretch_without_flips() {
        let (torus, _) = crate::sample::dented_torus(90, 36, (8, 8));
        let opts = FlattenOptions::default();
        let maps = flatten_all(&torus, &opts);
        let mut faces = vec![0; torus.num_faces()];
        for m in &maps {
            let s = param::stretch(&torus, std::slice::from_ref(m));
            assert!(
                s.l2 <= opts.max_chart_stretch || m.faces.len() == 1,
                "{s:?}"
            );
            assert_eq!((s.flipped, s.zero_area), (0, 0));
            for f in &m.face_ids {
                faces[f.idx()] += 1;
            }
        }
        assert!(
            faces.iter().all(|&n| n == 1),
            "every face in exactly one chart"
        );
        let total = param::stretch(&torus, &maps);
        assert!(total.l2 < 1.01, "{total:?}");
        // The torus is cut into few charts: LSCM starts and minimisation keep bands whole.
        assert!(maps.len() <= 16, "{} charts", maps.len());
        assert_eq!(flatten_all(&torus, &opts), maps, "deterministic");
    }
}

#[cfg(test)]
mod view_weight_tests {
    use super::*;
    use crate::mesh::FaceId;

    /// Looking down on a cap (V = -z), triangles near its top get more texture area per
    /// unit 3D area than triangles at the rim, and the barrier keeps every triangle's h/b at or
    /// above alpha where the 3D triangle allows it.
    #[test]
    fn view_weight_moves_texels_towards_the_important_view() {
        let (torus, _) = crate::sample::dented_torus(120, 48, (8, 8));
        // The top of the tube (phi around 90 degrees) over a quarter of the ring: a cap-like
        // disk whose normals run from +z (top) to sideways (rim).
        let faces: Vec<FaceId> = (0..torus.num_faces() as u32)
            .map(FaceId)
            .filter(|f| {
                let c: nalgebra::Vector3<f64> = torus
                    .triangle(*f)
                    .iter()
                    .map(|p| p.coords)
                    .sum::<nalgebra::Vector3<f64>>()
                    / 3.0;
                c.z > 0.15 && c.y < 0.0 && c.x < 0.0 && c.x < 0.3 * c.y && c.y < 0.3 * c.x
            })
            .collect();
        let area_ratio = |map: &param::ChartMap| {
            let (mut top, mut rim) = ((0.0, 0.0), (0.0, 0.0));
            for (t, f) in map.faces.iter().zip(&map.face_ids) {
                let q = t.map(|i| map.uv[i as usize]);
                let a2 = 0.5 * (q[1] - q[0]).perp(&(q[2] - q[0]));
                let n = torus.face_normal_area(*f);
                let a3 = 0.5 * n.norm();
                let nz = n.z / n.norm();
                if nz > 0.9 {
                    top = (top.0 + a2, top.1 + a3);
                } else if nz < 0.7 {
                    rim = (rim.0 + a2, rim.1 + a3);
                }
            }
            (top.0 / top.1) / (rim.0 / rim.1)
        };
        let mut plain = param::flatten(&torus, &faces);
        let mut weighted = plain.clone();
        optimize::optimize(&torus, &mut plain, &optimize::StretchOptions::default());
        let opts = optimize::StretchOptions {
            view_dir: Some(-nalgebra::Vector3::z()),
            k: 1.2,
            alpha: 0.1,
            ..Default::default()
        };
        optimize::optimize(&torus, &mut weighted, &opts);
        let (rp, rw) = (area_ratio(&plain), area_ratio(&weighted));
        assert!(
            rw > 1.5 * rp && rw > 1.3,
            "texel density top/rim: plain {rp:.3}, weighted {rw:.3}"
        );
        let s = param::stretch(&torus, std::slice::from_ref(&weighted));
        assert_eq!((s.flipped, s.zero_area), (0, 0));
        for (t, f) in weighted.faces.iter().zip(&weighted.face_ids) {
            let q = t.map(|i| weighted.uv[i as usize]);
            let a2 = 0.5 * (q[1] - q[0]).perp(&(q[2] - q[0]));
            let m = [
                (q[1] - q[0]).norm(),
                (q[2] - q[1]).norm(),
                (q[0] - q[2]).norm(),
            ]
            .into_iter()
            .fold(0.0, f64::max);
            let p = torus.triangle(*f);
            let m3 = [
                (p[1] - p[0]).norm(),
                (p[2] - p[1]).norm(),
                (p[0] - p[2]).norm(),
            ]
            .into_iter()
            .fold(0.0, f64::max);
            let hb3 = 2.0 * 0.5 * torus.face_normal_area(*f).norm() / (m3 * m3);
            assert!(
                2.0 * a2 / (m * m) >= 0.1f64.min(hb3) * 0.999 - 1e-12,
                "h/b below alpha"
            );
        }
    }
}
