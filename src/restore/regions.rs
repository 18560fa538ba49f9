//! Which unseen regions are beyond restoration: boundary-driven restoration continues what
//! lies within a few feature sizes of a hole's rim; a region deeper than that (measured on
//! the surface, from its rim, against the texture's own feature scale) is handed to exemplar
//! synthesis (stage 6) as faces, with the reason.

use crate::atlas::Atlas;
use crate::mesh::topology::NO_FACE;
use crate::mesh::{FaceId, Mesh};
use crate::resample::TexelSource;
use rayon::prelude::*;
use serde::Serialize;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Why restoration handed a region to stage 6.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Handover {
    /// Deeper than the depth limit (feature scales from the rim).
    Deep,
    /// Part of an atlas hole larger than `max_hole` texels.
    TooLarge,
    /// In a chart no photograph saw: nothing in 2D to restore it from.
    Unreachable,
}

/// A connected set of faces no photograph saw, handed to stage 6.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct UnseenRegion {
    /// Faces, in index order.
    pub faces: Vec<u32>,
    /// Unseen texels of those faces.
    pub texels: u64,
    /// Largest distance on the surface from the region's rim, texels (infinite when no
    /// photograph saw any face around it).
    pub depth_texels: f64,
    /// Why it was handed over (the first reason that applies, in the order of [`Handover`]:
    /// the least).
    pub reason: Handover,
}

/// The texture's feature scale, texels: the smallest lag at which the autocorrelation of the
/// seen luma's detail (luma minus its running mean over 17 texels along the row) falls below
/// one half, over a sample of rows; 4 when the seen texels carry no detail. Between 1 and 16.
pub fn feature_scale(color: &image::Rgb32FImage, source: &[u8]) -> f64 {
    let n = color.width() as usize;
    const HALF: usize = 8;
    const MAX_LAG: usize = 16;
    let luma = |x: usize, y: usize| crate::planar::luma(&color.get_pixel(x as u32, y as u32).0);
    // Rows in parallel, each row's sums added in row order (deterministic).
    type Sums = [[f64; MAX_LAG + 1]; 3];
    let stride = (n / 512).max(1);
    let rows: Vec<Sums> = (0..n)
        .into_par_iter()
        .step_by(stride)
        .map(|y| {
            let [mut num, mut e0, mut e1] = [[0f64; MAX_LAG + 1]; 3];
            let row = &source[y * n..(y + 1) * n];
            // Runs of seen texels long enough to hold the window and the lags.
            let mut x = 0;
            while x < n {
                if row[x] != TexelSource::Photos as u8 {
                    x += 1;
                    continue;
                }
                let start = x;
                while x < n && row[x] == TexelSource::Photos as u8 {
                    x += 1;
                }
                let len = x - start;
                if len < 2 * HALF + MAX_LAG + 2 {
                    continue;
                }
                let l: Vec<f64> = (start..x).map(|xx| luma(xx, y)).collect();
                let mut pre = vec![0f64; len + 1];
                for i in 0..len {
                    pre[i + 1] = pre[i] + l[i];
                }
                let d: Vec<f64> = (HALF..len - HALF)
                    .map(|i| l[i] - (pre[i + HALF + 1] - pre[i - HALF]) / (2 * HALF + 1) as f64)
                    .collect();
                for lag in 0..=MAX_LAG {
                    for i in 0..d.len() - lag {
                        num[lag] += d[i] * d[i + lag];
                        e0[lag] += d[i] * d[i];
                        e1[lag] += d[i + lag] * d[i + lag];
                    }
                }
            }
            [num, e0, e1]
        })
        .collect();
    let [mut num, mut e0, mut e1] = [[0f64; MAX_LAG + 1]; 3];
    for [a, b, c] in &rows {
        for lag in 0..=MAX_LAG {
            num[lag] += a[lag];
            e0[lag] += b[lag];
            e1[lag] += c[lag];
        }
    }
    if e0[0] < 1e-9 {
        return 4.0;
    }
    for lag in 1..=MAX_LAG {
        let c = num[lag] / (e0[lag] * e1[lag]).sqrt().max(1e-300);
        if c < 0.5 {
            return lag as f64;
        }
    }
    MAX_LAG as f64
}

/// Per face: texels no photograph coloured and texels photographs coloured.
pub(super) fn face_counts(atlas: &Atlas, source: &[u8], faces: usize) -> (Vec<u32>, Vec<u32>) {
    use std::sync::atomic::{AtomicU32, Ordering::Relaxed};
    // Counted in parallel (integer counts: the same whatever the order).
    let count = || (0..faces).map(|_| AtomicU32::new(0)).collect::<Vec<_>>();
    let (hidden, seen) = (count(), count());
    source.par_iter().enumerate().for_each(|(i, &s)| {
        if let Some(f) = atlas.owner(i) {
            if s == TexelSource::Photos as u8 {
                seen[f as usize].fetch_add(1, Relaxed);
            } else if TexelSource::is_unseen(s) {
                hidden[f as usize].fetch_add(1, Relaxed);
            }
        }
    });
    let plain = |v: Vec<AtomicU32>| v.into_iter().map(AtomicU32::into_inner).collect();
    (plain(hidden), plain(seen))
}

/// Connected components (through shared edges) of the faces `member` marks, each with its
/// depth from the rim (faces next to a non-member), in surface units; components with no rim
/// get infinity. Faces `elsewhere` marks (on another atlas page: this page knows nothing of
/// their texels) are neither members nor rim. Deterministic: components in order of their
/// first face.
pub(super) fn components(
    mesh: &Mesh,
    adj: &[[u32; 3]],
    member: &[bool],
    elsewhere: &dyn Fn(u32) -> bool,
) -> Vec<(Vec<u32>, f64)> {
    let centroid = |f: u32| {
        let t = mesh.triangle(FaceId(f));
        (t[0].coords + t[1].coords + t[2].coords) / 3.0
    };
    let mut comp_of = vec![u32::MAX; member.len()];
    let mut dist = vec![f64::INFINITY; member.len()];
    let mut out = Vec::new();
    for s in 0..member.len() {
        if !member[s] || comp_of[s] != u32::MAX {
            continue;
        }
        let id = out.len() as u32;
        let mut faces = vec![s as u32];
        comp_of[s] = id;
        let mut k = 0;
        while k < faces.len() {
            let f = faces[k] as usize;
            k += 1;
            for &g in &adj[f] {
                if g != NO_FACE && member[g as usize] && comp_of[g as usize] == u32::MAX {
                    comp_of[g as usize] = id;
                    faces.push(g);
                }
            }
        }
        faces.sort_unstable();
        // Multi-source Dijkstra from the rim over face centroids.
        let mut heap = BinaryHeap::new();
        for &f in &faces {
            let rim = adj[f as usize]
                .iter()
                .any(|&g| g != NO_FACE && !member[g as usize] && !elsewhere(g));
            if rim {
                dist[f as usize] = 0.0;
                heap.push(Reverse((Ordered(0.0), f)));
            }
        }
        let mut depth = if heap.is_empty() { f64::INFINITY } else { 0.0 };
        while let Some(Reverse((d, f))) = heap.pop() {
            let d = d.0;
            if dist[f as usize] < d {
                continue;
            }
            depth = f64::max(depth, d);
            let c = centroid(f);
            for &g in &adj[f as usize] {
                if g == NO_FACE || !member[g as usize] {
                    continue;
                }
                let nd = d + (centroid(g) - c).norm();
                if nd < dist[g as usize] {
                    dist[g as usize] = nd;
                    heap.push(Reverse((Ordered(nd), g)));
                }
            }
        }
        out.push((faces, depth));
    }
    out
}

/// A total order on finite distances for the heap.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ordered(f64);
impl Eq for Ordered {}
impl PartialOrd for Ordered {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Ordered {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.0.total_cmp(&o.0)
    }
}

/// The regions of faces no photograph saw (per face: `hidden` and `seen` texels, from
/// [`face_counts`]) whose depth from the rim is at least `min_depth` feature scales (`scale`
/// texels each).
pub(super) fn deep_regions(
    mesh: &Mesh,
    atlas: &Atlas,
    adj: &[[u32; 3]],
    (hidden, seen): (&[u32], &[u32]),
    scale: f64,
    min_depth: f64,
) -> Vec<UnseenRegion> {
    let elsewhere = |f: u32| atlas.face_chart[f as usize] == u32::MAX;
    let member: Vec<bool> = (0..seen.len())
        .map(|f| seen[f] == 0 && !elsewhere(f as u32))
        .collect();
    let tpu = atlas.texels_per_unit();
    components(mesh, adj, &member, &elsewhere)
        .into_iter()
        .filter_map(|(faces, depth)| {
            let depth_texels = depth * tpu;
            (depth_texels >= min_depth * scale).then(|| UnseenRegion {
                texels: faces.iter().map(|&f| u64::from(hidden[f as usize])).sum(),
                faces,
                depth_texels,
                reason: Handover::Deep,
            })
        })
        .collect()
}

/// Every region for stage 6: the deep regions and the faces owning texels restoration left
/// (`left`), joined where they touch; the reason is the deep one if any face was deep.
/// `hidden`: unseen texels per face ([`face_counts`]).
pub(super) fn handed_over(
    mesh: &Mesh,
    atlas: &Atlas,
    adj: &[[u32; 3]],
    hidden: &[u32],
    deep: &[UnseenRegion],
    left_too_large: &crate::planar::BitMask,
    left_unreachable: &crate::planar::BitMask,
) -> Vec<UnseenRegion> {
    let nf = mesh.num_faces();
    let mut why: Vec<Option<Handover>> = vec![None; nf];
    for r in deep {
        for &f in &r.faces {
            why[f as usize] = Some(Handover::Deep);
        }
    }
    for i in 0..left_too_large.len() {
        let reason = if left_too_large.get(i) {
            Handover::TooLarge
        } else if left_unreachable.get(i) {
            Handover::Unreachable
        } else {
            continue;
        };
        if let Some(f) = atlas.owner(i) {
            let w = &mut why[f as usize];
            *w = Some(w.map_or(reason, |old| old.min(reason)));
        }
    }
    let member: Vec<bool> = why.iter().map(|w| w.is_some()).collect();
    let tpu = atlas.texels_per_unit();
    components(mesh, adj, &member, &|f| {
        atlas.face_chart[f as usize] == u32::MAX
    })
    .into_iter()
    .map(|(faces, depth)| UnseenRegion {
        texels: faces.iter().map(|&f| u64::from(hidden[f as usize])).sum(),
        reason: faces
            .iter()
            .filter_map(|&f| why[f as usize])
            .min()
            .unwrap_or(Handover::Deep),
        depth_texels: depth * tpu,
        faces,
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::topology::face_adjacency;

    /// Sinusoidal stripes of period 24 along the rows: the detail's autocorrelation is
    /// cos(2 pi d / 24), below one half from d = 5 on; a flat atlas has no detail (4).
    #[test]
    fn feature_scale_of_stripes_is_their_correlation_length() {
        let n = 256u32;
        let img = image::Rgb32FImage::from_fn(n, n, |x, _| {
            let v = 0.5 + 0.3 * (std::f32::consts::TAU * x as f32 / 24.0).sin();
            image::Rgb([v, v, v])
        });
        let source = vec![TexelSource::Photos as u8; (n * n) as usize];
        let l = feature_scale(&img, &source);
        assert!((4.0..=5.0).contains(&l), "{l}");
        let flat = image::Rgb32FImage::from_pixel(n, n, image::Rgb([0.4, 0.4, 0.4]));
        assert_eq!(feature_scale(&flat, &source), 4.0);
        // Unseen texels are not read.
        let none = vec![TexelSource::Red as u8; (n * n) as usize];
        assert_eq!(feature_scale(&img, &none), 4.0);
    }

    /// A strip of unit squares: the depth from the rim grows by one square per step in.
    #[test]
    fn components_measure_depth_from_the_rim() {
        let k = 10;
        let mut positions = Vec::new();
        for i in 0..=k {
            positions.push(nalgebra::Point3::new(i as f64, 0.0, 0.0));
            positions.push(nalgebra::Point3::new(i as f64, 1.0, 0.0));
        }
        let v = |i: u32| crate::mesh::VertexId(i);
        let mut faces = Vec::new();
        for i in 0..k as u32 {
            faces.push([v(2 * i), v(2 * i + 2), v(2 * i + 1)]);
            faces.push([v(2 * i + 1), v(2 * i + 2), v(2 * i + 3)]);
        }
        let m = Mesh {
            positions,
            faces,
            ..Default::default()
        };
        let adj = face_adjacency(&m);
        // The first two squares are seen; the rest is one region, eight squares deep.
        let member: Vec<bool> = (0..2 * k).map(|f| f >= 4).collect();
        let c = components(&m, &adj, &member, &|_| false);
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].0, (4..2 * k as u32).collect::<Vec<_>>());
        // From the first region face's centroid to the last one's: 7.3 in a straight line;
        // the path through triangle centroids zigzags across the strip, up to a quarter
        // longer.
        assert!((7.0..=9.5).contains(&c[0].1), "{}", c[0].1);
        // With nothing seen there is no rim: infinitely deep.
        let all = vec![true; 2 * k];
        assert!(components(&m, &adj, &all, &|_| false)[0].1.is_infinite());
        // Faces on another atlas page are no rim: with the first two squares there, the
        // region has no rim on this page; with the last two there, it is measured from the
        // first squares alone, as before.
        let elsewhere_first = |f: u32| f < 4;
        let c = components(&m, &adj, &member, &elsewhere_first);
        assert!(c[0].1.is_infinite(), "{}", c[0].1);
        let member_cut: Vec<bool> = (0..2 * k).map(|f| (4..2 * k - 4).contains(&f)).collect();
        let elsewhere_last = |f: u32| f >= 2 * k as u32 - 4;
        let c = components(&m, &adj, &member_cut, &elsewhere_last);
        assert!((5.0..=7.5).contains(&c[0].1), "{}", c[0].1);
    }
}
