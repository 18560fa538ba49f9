//! Seam visibility of a texture atlas: how much sharper the colour changes where the source
//! photograph changes, or where two charts meet, than it does elsewhere. 1.0 means no visible
//! seam.
//!
//! - View boundaries: adjacent texel pairs (right and down neighbours) inside a chart, at least
//!   two texels from its border, both coloured from photographs. The ratio is the mean absolute
//!   luma difference over pairs whose best-weighted photographs differ, divided by the mean
//!   over the pairs flanking them on the same line (one texel before and after, each within
//!   one photograph's region): the same local control as for chart borders. The global variant
//!   (divided by the mean over all pairs whose best photographs agree) is reported too, but
//!   where view boundaries follow the content it measures the content, not a seam: on the
//!   corset photographed with identical exposure and light it is 16 for winner-take-all and
//!   3.1 for multiband, whose local ratios are 6.8 and 1.23 (docs/decisions.md).
//! - Chart borders: along every mesh edge where two charts meet (the same 3D edge with
//!   different texture coordinates on its two faces), one sample per texel of edge length.
//!   Each side is read (bilinear) half a texel inside its own face, so the two reads are one
//!   texel apart on the surface; the control pair is the same side's reads at half and one and
//!   a half texels inside. The ratio is the mean seam difference over the mean control
//!   difference.

use crate::atlas::texels::border_samples;
use crate::mesh::Mesh;
use crate::planar::BitMask;
use crate::resample::{TexelSource, NO_PHOTO};
use image::Rgb32FImage;
use nalgebra::Vector2;
use rayon::prelude::*;
use serde::Serialize;

/// Seam ratios of one atlas.
#[derive(Debug, Clone, Copy, Serialize, PartialEq)]
pub struct SeamReport {
    /// Mean luma step across view boundaries over the mean step of the pairs flanking it on
    /// the same line, one texel to either side (1 = invisible).
    pub view_boundary_ratio: f64,
    /// Mean luma step across view boundaries over the mean step of all pairs whose best
    /// photographs agree. Biased upwards wherever view boundaries follow the content (a
    /// photograph rejected on dark marks, silhouettes along creases): 16 for winner-take-all
    /// on the corset photographed with no gain or light differences at all.
    pub view_boundary_ratio_global: f64,
    /// Texel pairs across view boundaries.
    pub view_boundary_pairs: u64,
    /// Mean luma step across chart borders over the mean step one texel inside (1 =
    /// invisible).
    pub chart_border_ratio: f64,
    /// Samples along chart borders.
    pub chart_border_samples: u64,
}

fn luma(c: [f32; 3]) -> f64 {
    0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64
}

/// Bilinear luma at texel coordinates (x right, y down, centres at +0.5), clamped.
fn bilinear(img: &Rgb32FImage, p: Vector2<f64>) -> f64 {
    let (w, h) = img.dimensions();
    let (x, y) = (p.x - 0.5, p.y - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let cl = |v: f64, n: u32| (v.max(0.0) as u32).min(n - 1);
    let g = |xx: f64, yy: f64| luma(img.get_pixel(cl(xx, w), cl(yy, h)).0);
    let top = g(x0, y0) * (1.0 - fx) + g(x0 + 1.0, y0) * fx;
    let bot = g(x0, y0 + 1.0) * (1.0 - fx) + g(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bot * fy
}

/// The texels that enter the view-boundary sums: coloured from photographs, with a best
/// photograph, and distance-2 interior (the 5 x 5 neighbourhood all chart texels). In two
/// parallel passes, columns of five then rows of five: testing the whole neighbourhood at
/// every look took most of the seam stage at 8192.
fn interior_photo_texels(source: &[u8], best: &[u16], w: usize, h: usize) -> BitMask {
    let chart = |s: u8| (1..=4).contains(&s);
    let inner = |v: usize, n: usize| v >= 2 && v + 2 < n;
    // Texels whose column of five (two rows up, two down) is all chart.
    let column = BitMask::from_fn_par(w * h, |i| {
        inner(i / w, h) && (i - 2 * w..=i + 2 * w).step_by(w).all(|j| chart(source[j]))
    });
    BitMask::from_fn_par(w * h, |i| {
        source[i] == TexelSource::Photos as u8
            && best[i] != NO_PHOTO
            && inner(i % w, w)
            && (i - 2..=i + 2).all(|j| column.get(j))
    })
}

/// Both ratios for `atlas` (page 0 of `mesh`'s UVs), with each texel's [`TexelSource`] and
/// best photograph as [`crate::resample::Resampled`] records them.
pub fn seam_visibility(
    mesh: &Mesh,
    atlas: &Rgb32FImage,
    source: &[u8],
    best: &[u16],
) -> SeamReport {
    let (w, h) = atlas.dimensions();
    let (w, h) = (w as usize, h as usize);
    let interior = interior_photo_texels(source, best, w, h);
    let ok = |i: usize| interior.get(i);
    let y_at = |i: usize| luma(atlas.get_pixel((i % w) as u32, (i / w) as u32).0);
    // Per row band: sums for the global ratio (across, within) and the local one (across
    // with both flanking pairs within, and those flanks).
    let sums = (2..h.saturating_sub(2))
        .into_par_iter()
        .map(|y| {
            let mut t = [0f64; 6];
            for x in 2..w.saturating_sub(2) {
                let i = y * w + x;
                if !ok(i) {
                    continue;
                }
                for step in [1, w] {
                    let j = i + step;
                    if !ok(j) {
                        continue;
                    }
                    let d = (y_at(i) - y_at(j)).abs();
                    if best[i] == best[j] {
                        t[2] += d;
                        t[3] += 1.0;
                        continue;
                    }
                    t[0] += d;
                    t[1] += 1.0;
                    // Interior texels have chart texels two steps away on every side.
                    let (p, q) = (i - step, j + step);
                    if ok(p) && ok(q) && best[p] == best[i] && best[q] == best[j] {
                        t[4] += d;
                        t[5] += 0.5 * ((y_at(p) - y_at(i)).abs() + (y_at(j) - y_at(q)).abs());
                    }
                }
            }
            t
        })
        .collect::<Vec<[f64; 6]>>()
        // Summed in row order: rayon's reduce groups rows by how work was stolen, and float
        // addition in another grouping moved the last digits of report.json under load.
        .iter()
        .fold([0f64; 6], |a, b| std::array::from_fn(|k| a[k] + b[k]));
    let [across, n_across, within, n_within, local, flank] = sums;
    let view_boundary_ratio_global = if n_across > 0.0 && within > 0.0 {
        (across / n_across) / (within / n_within)
    } else {
        1.0
    };
    let view_boundary_ratio = if n_across > 0.0 && flank > 0.0 {
        local / flank
    } else {
        1.0
    };
    let (seam, control, samples) = chart_borders(mesh, atlas);
    SeamReport {
        view_boundary_ratio,
        view_boundary_ratio_global,
        view_boundary_pairs: n_across as u64,
        chart_border_ratio: if samples > 0 && control > 0.0 {
            seam / control
        } else {
            1.0
        },
        chart_border_samples: samples,
    }
}

/// Sums of the seam and control differences along chart borders, and the sample count.
fn chart_borders(mesh: &Mesh, atlas: &Rgb32FImage) -> (f64, f64, u64) {
    let (mut seam, mut control) = (0f64, 0f64);
    let samples = border_samples(mesh, atlas.width() as usize);
    for b in &samples {
        let [p1, p2] = b.at;
        let [n1, n2] = b.inward;
        let y1 = bilinear(atlas, p1 + n1 * 0.5);
        let y2 = bilinear(atlas, p2 + n2 * 0.5);
        seam += (y1 - y2).abs();
        control += 0.5
            * ((y1 - bilinear(atlas, p1 + n1 * 1.5)).abs()
                + (y2 - bilinear(atlas, p2 + n2 * 1.5)).abs());
    }
    (seam, control, samples.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interior_bits_are_the_texels_whose_5x5_neighbourhood_is_chart() {
        let mut rng = crate::rng::SplitMix64::new(5);
        for (w, h) in [(3, 9), (5, 5), (70, 23), (130, 40)] {
            // Mostly chart texels with random holes, sources and missing best photographs.
            let source: Vec<u8> = (0..w * h)
                .map(|_| match rng.next_f64() {
                    r if r < 0.05 => TexelSource::Empty as u8,
                    r if r < 0.08 => TexelSource::Gutter as u8,
                    r if r < 0.15 => TexelSource::Red as u8,
                    _ => TexelSource::Photos as u8,
                })
                .collect();
            let best: Vec<u16> = (0..w * h)
                .map(|_| if rng.next_f64() < 0.05 { NO_PHOTO } else { 1 })
                .collect();
            let bits = interior_photo_texels(&source, &best, w, h);
            let chart = |s: u8| (1..=4).contains(&s);
            let mut ones = 0;
            for y in 0..h {
                for x in 0..w {
                    let i = y * w + x;
                    let interior = x >= 2
                        && y >= 2
                        && x + 2 < w
                        && y + 2 < h
                        && (y - 2..=y + 2)
                            .all(|yy| (x - 2..=x + 2).all(|xx| chart(source[yy * w + xx])));
                    let want =
                        interior && source[i] == TexelSource::Photos as u8 && best[i] != NO_PHOTO;
                    assert_eq!(bits.get(i), want, "{w}x{h} at ({x}, {y})");
                    ones += usize::from(want);
                }
            }
            if w >= 70 {
                assert!(ones > 0, "{w}x{h}: some interior texels");
            }
        }
    }

    #[test]
    fn a_step_between_photographs_shows_and_a_smooth_field_does_not() {
        // 40x40 chart texels in a 48x48 atlas, a horizontal ramp plus noise-free texture;
        // photo 0 on the left half, photo 1 on the right.
        let n = 48;
        let mut source = vec![0u8; n * n];
        let mut best = vec![NO_PHOTO; n * n];
        for y in 4..44 {
            for x in 4..44 {
                source[y * n + x] = TexelSource::Photos as u8;
                best[y * n + x] = u16::from(x >= 24);
            }
        }
        let tex = |step: f32| {
            Rgb32FImage::from_fn(n as u32, n as u32, |x, y| {
                let v = 0.3 + 0.01 * x as f32 + 0.02 * ((x + 2 * y) % 3) as f32;
                let v = if x >= 24 { v + step } else { v };
                image::Rgb([v, v, v])
            })
        };
        let mesh = Mesh::default();
        let smooth = seam_visibility(&mesh, &tex(0.0), &source, &best);
        let stepped = seam_visibility(&mesh, &tex(0.2), &source, &best);
        assert_eq!(smooth.view_boundary_pairs, 36);
        assert!((smooth.view_boundary_ratio - 1.0).abs() < 0.3, "{smooth:?}");
        assert!(stepped.view_boundary_ratio > 5.0, "{stepped:?}");
    }

    #[test]
    fn chart_borders_show_a_step_and_not_a_continuous_colour() {
        use crate::mesh::{UvMap, VertexId};
        use nalgebra::{Point3, Vector2 as V2};
        // A unit quad split along its diagonal 0-2 into two charts side by side in the atlas.
        let mut mesh = Mesh::default();
        for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
            mesh.positions.push(Point3::new(x, y, 0.0));
        }
        mesh.faces = vec![
            [VertexId(0), VertexId(1), VertexId(2)],
            [VertexId(0), VertexId(2), VertexId(3)],
        ];
        let place = |x: f32, y: f32, ox: f32| V2::new(0.05 + ox + 0.4 * x, 0.05 + 0.4 * y);
        let corners = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        let mut coords: Vec<V2<f32>> = corners.iter().map(|&(x, y)| place(x, y, 0.0)).collect();
        coords.extend(corners.iter().map(|&(x, y)| place(x, y, 0.5)));
        mesh.uv = Some(UvMap {
            coords,
            faces: vec![[0, 1, 2], [4, 6, 7]],
        });
        let n = 64u32;
        // Colour as a function of the 3D point, each chart's rectangle filled from its own map.
        let tex = |step: f32| {
            Rgb32FImage::from_fn(n, n, |x, y| {
                let u = (x as f32 + 0.5) / n as f32;
                let v = 1.0 - (y as f32 + 0.5) / n as f32;
                let (ox, add) = if u < 0.5 { (0.05, 0.0) } else { (0.55, step) };
                let (px, py) = ((u - ox) / 0.4, (v - 0.05) / 0.4);
                let c = 0.2 + 0.3 * px + 0.2 * py + add;
                image::Rgb([c, c, c])
            })
        };
        let none = vec![0u8; (n * n) as usize];
        let best = vec![NO_PHOTO; (n * n) as usize];
        let smooth = seam_visibility(&mesh, &tex(0.0), &none, &best);
        let stepped = seam_visibility(&mesh, &tex(0.15), &none, &best);
        assert!(smooth.chart_border_samples >= 25, "{smooth:?}");
        assert!(
            smooth.chart_border_ratio < 1.2,
            "continuous colour: {smooth:?}"
        );
        assert!(stepped.chart_border_ratio > 5.0, "step: {stepped:?}");
    }
}
