//! Stage 1, the atlas (issue 4, in progress). Built: chart segmentation into disks
//! ([`segment`]), a flip-free flattening per chart with Sander's stretch measures ([`param`]),
//! and [`flatten_all`], which splits charts whose flattening stretches too much. To come: the
//! paper's view-weighted stretch minimisation with the shape barrier, and packing.

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
    /// A chart whose own L2 stretch exceeds this is split in two and both halves flattened
    /// again. Default: 1.25.
    pub max_chart_stretch: f64,
}

impl Default for FlattenOptions {
    fn default() -> Self {
        FlattenOptions {
            segment: SegmentOptions::default(),
            max_chart_stretch: 1.25,
        }
    }
}

/// Segments `mesh` and flattens every chart, splitting charts until each one's L2 stretch is
/// at most `max_chart_stretch` (a single triangle is always an isometry, so this ends).
pub fn flatten_all(mesh: &Mesh, opts: &FlattenOptions) -> Vec<ChartMap> {
    let adj = Adjacency::new(mesh);
    let mut todo: Vec<Vec<crate::mesh::FaceId>> = segment::segment(mesh, &opts.segment).charts;
    todo.reverse();
    let mut out = Vec::new();
    while let Some(chart) = todo.pop() {
        let map = param::flatten(mesh, &chart);
        let s = param::stretch(mesh, std::slice::from_ref(&map));
        if chart.len() > 1 && (s.l2 > opts.max_chart_stretch || s.flipped > 0 || s.zero_area > 0) {
            let (a, b) = split(&adj, &chart);
            for part in [b, a] {
                debug_assert!(is_disk(mesh, &adj, &part) || part.len() > 1);
                if is_disk(mesh, &adj, &part) {
                    todo.push(part);
                } else {
                    // Split halves can be non-disks: re-segment them into disks.
                    let (x, y) = split(&adj, &part);
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
        assert!(total.l2 < 1.05, "{total:?}");
        assert_eq!(flatten_all(&torus, &opts), maps, "deterministic");
    }
}
