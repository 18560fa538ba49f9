//! Stage 3, resampling (paper section 4.1, `docs/method.md` section 3): photographs into the
//! atlas. In: the mesh with its atlas UVs, vertex normals, the [`Binding`], the photographs.
//! Out: [`Resampled`] (the atlas colour, where each texel's colour came from, the triangle
//! classes).
//!
//! Triangles are green (the three vertices share a valid photograph), blue (all bound, none in
//! common) or red (a vertex unbound). Green texels take the weighted mean of the common
//! photographs; blue and red texels interpolate vertex colours, red after the paper's
//! iterative fill of unbound vertices (80/60/40/20% of the one-ring coloured, then any
//! coloured neighbour). The robust method also tests every texel against each photograph's
//! depth map (a triangle half hidden in a photograph takes its colour only where it is seen);
//! a green texel no photograph sees falls back to vertex colours.
//!
//! The atlas is processed in bands of rows in parallel; photographs one at a time, so memory is
//! the atlas's accumulators plus two decoded photographs.

use crate::atlas::texels::BAND;
use crate::atlas::Atlas;
use crate::bind::{consistent, depth_tolerance, Binding, Consistency, Method};
use crate::camera::PosedCamera;
use crate::depth::{focal_px, DepthMap};
use crate::error::{Error, Result};
use crate::io::image::{PhotoPixels, Values};
use crate::mesh::Mesh;
use crate::photometric::Gains;
use crate::photos::for_each_photo_with;
use crate::progress::Progress;
use crate::scene::Photo;
use image::{GrayImage, Rgb32FImage, RgbImage};
use nalgebra::{Point2, Point3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

mod classify;
mod sampler;
use classify::*;
pub use classify::{classify, fill_vertex_colors};
pub(crate) use classify::{face_runs, FaceLists};
#[cfg(test)]
use sampler::*;
pub use sampler::{PhotoSampler, PhotoSetup, Sampler, SpareLevels};

/// The paper's triangle classes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FaceClass {
    /// The three vertices share at least one valid photograph.
    Green,
    /// Every vertex is bound, none in common.
    Blue,
    /// At least one vertex is unbound.
    Red,
}

/// Where a texel's colour came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum TexelSource {
    /// Outside every chart and beyond the gutter fill.
    Empty = 0,
    /// Weighted mean of photographs.
    Photos = 1,
    /// A green triangle's texel that no photograph saw (robust method's per-texel tests):
    /// vertex colours.
    GreenFallback = 2,
    /// A blue triangle: interpolated vertex colours.
    Blue = 3,
    /// A red triangle: interpolated vertex colours after the fill.
    Red = 4,
    /// Gutter, extended from the nearest chart texels.
    Gutter = 5,
}

impl TexelSource {
    /// Whether a texel of this source (as stored in [`Resampled::source`]) lies in a chart but
    /// took its colour from no photograph: green fallback, blue or red triangles.
    pub fn is_unseen(s: u8) -> bool {
        s == TexelSource::GreenFallback as u8
            || s == TexelSource::Blue as u8
            || s == TexelSource::Red as u8
    }
}

/// Options for [`resample`] beyond the binding's (method, weights, depth maps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResampleOptions {
    /// Texels of gutter around every chart filled by extending the chart's colours, so that
    /// bilinear filtering and mip-mapping never pull in empty texels. Default: 8.
    pub gutter_fill: u32,
    /// Robust method: at most this many photographs per face, those with the largest weight
    /// at its vertices (the rest add little and cost time in proportion); 0 = all.
    /// Default: 12.
    pub max_views: usize,
}

impl Default for ResampleOptions {
    fn default() -> Self {
        ResampleOptions {
            gutter_fill: 8,
            max_views: 12,
        }
    }
}

/// Counts of what [`resample`] did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ResampleStats {
    /// Triangles per class.
    pub green: u64,
    /// See [`FaceClass::Blue`].
    pub blue: u64,
    /// See [`FaceClass::Red`].
    pub red: u64,
    /// Texels coloured from photographs.
    pub texels_photos: u64,
    /// Green-triangle texels no photograph saw (vertex colours instead).
    pub texels_green_fallback: u64,
    /// Blue-triangle texels.
    pub texels_blue: u64,
    /// Red-triangle texels.
    pub texels_red: u64,
    /// Gutter texels filled.
    pub texels_gutter: u64,
    /// Unbound vertices coloured by the fill, per round (80, 60, 40, 20%, any neighbour).
    pub filled_per_round: [u64; 5],
    /// Vertices no fill could reach (components no photograph saw): the mean colour.
    pub vertices_unreachable: u64,
    /// Seconds spent per photograph on its depth map and mip pyramid, summed.
    pub seconds_photo_setup: f64,
    /// Seconds spent sampling texels from photographs (with multiband merging: also building
    /// and adding the bands), summed.
    pub seconds_texels: f64,
}

/// The resampled atlas.
#[derive(Debug, Clone)]
pub struct Resampled {
    /// Atlas colour, RGB in the photographs' values.
    pub color: Rgb32FImage,
    /// [`TexelSource`] per texel, row-major.
    pub source: Vec<u8>,
    /// Photographs that contributed to each texel (saturating at 255).
    pub views: Vec<u8>,
    /// Class of each face.
    pub classes: Vec<FaceClass>,
    /// The photograph with the largest weight at each texel ([`NO_PHOTO`] if none).
    pub best_photo: Vec<u16>,
    /// Vertex colours after the fill (one per vertex).
    pub vertex_colors: Vec<[f32; 3]>,
    /// Counts.
    pub stats: ResampleStats,
}

/// A saturated colour for index `k` (photograph, patch): hues spaced by the golden angle, 0
/// red, so neighbouring indices stand apart.
pub fn index_colour(k: u32) -> [u8; 3] {
    let hue = (k as f32 * 0.618_034).fract() * 6.0;
    let f = hue.fract();
    let (a, b) = ((255.0 * (1.0 - f)) as u8, (255.0 * f) as u8);
    match hue as u32 {
        0 => [255, b, 0],
        1 => [a, 255, 0],
        2 => [0, 255, b],
        3 => [0, a, 255],
        4 => [b, 0, 255],
        _ => [255, 0, a],
    }
}

impl Resampled {
    /// The paper's Fig. 7: texels coloured by their triangle's class (black outside charts).
    pub fn class_picture(&self) -> RgbImage {
        let (w, h) = self.color.dimensions();
        RgbImage::from_fn(w, h, |x, y| {
            let s = self.source[(y * w + x) as usize];
            image::Rgb(match s {
                1 | 2 => [40, 200, 60],
                3 => [50, 90, 230],
                4 => [230, 50, 40],
                5 => [40, 40, 40],
                _ => [0, 0, 0],
            })
        })
    }

    /// The merge's masks as one picture: each texel in the colour of its best photograph (the
    /// one whose mask wins it: hues spaced by the golden angle, photograph 0 red), black where
    /// no photograph saw it.
    pub fn best_photo_picture(&self) -> RgbImage {
        let (w, h) = self.color.dimensions();
        RgbImage::from_fn(w, h, |x, y| {
            let p = self.best_photo[(y * w + x) as usize];
            if p == NO_PHOTO {
                return image::Rgb([0, 0, 0]);
            }
            image::Rgb(index_colour(u32::from(p)))
        })
    }

    /// Coverage: grey by the number of photographs that coloured the texel (brighter = more,
    /// white at 8 or more), orange for chart texels no photograph saw, black outside charts.
    pub fn coverage_picture(&self) -> RgbImage {
        let (w, h) = self.color.dimensions();
        RgbImage::from_fn(w, h, |x, y| {
            let i = (y * w + x) as usize;
            match self.source[i] {
                1 => {
                    let g = (60 + 195 * self.views[i].min(8) as u32 / 8) as u8;
                    image::Rgb([g, g, g])
                }
                2..=4 => image::Rgb([240, 140, 20]),
                _ => image::Rgb([0, 0, 0]),
            }
        })
    }
}

/// No photograph (in [`Resampled::best_photo`]).
pub const NO_PHOTO: u16 = u16::MAX;

/// Checks that `n` photographs fit: texels record their best photograph in 16 bits.
pub fn check_photo_count(n: usize) -> Result<()> {
    if n >= NO_PHOTO as usize {
        return Err(Error::Invalid(format!(
            "{n} photographs: at most {} can be combined in one atlas",
            NO_PHOTO - 1
        )));
    }
    Ok(())
}

/// Stage 3: resamples the bound photographs into `atlas` (page 0 of the mesh's UVs), each
/// texel the weighted mean of the photographs that see it (`winner` false) or the colour of
/// the one with the largest weight (`winner` true), corrected by `gains`. `normals` are unit
/// vertex normals of `mesh`.
#[allow(clippy::too_many_arguments)]
pub fn resample(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    atlas: &Atlas,
    binding: &Binding,
    gains: &Gains,
    photos: &[Photo],
    opts: &ResampleOptions,
    winner: bool,
    progress: &dyn Progress,
) -> Result<Resampled> {
    let prep = Sampler::new(mesh, atlas, normals, binding, gains, opts)?;
    resample_with(&prep, photos, opts, winner, progress)
}

/// [`resample`] with the sampler built: the weighted mean of the samples at each texel
/// (`winner` false) or the heaviest one (`winner` true).
pub fn resample_with(
    prep: &Sampler,
    photos: &[Photo],
    opts: &ResampleOptions,
    winner: bool,
    progress: &dyn Progress,
) -> Result<Resampled> {
    check_photo_count(photos.len())?;
    let n = prep.size();
    // Accumulators: weighted colour sum and weight (or the best colour and its weight),
    // photographs counted, best photograph.
    let mut acc = vec![[0f32; 4]; n * n];
    let mut views = vec![0u8; n * n];
    let mut best = vec![NO_PHOTO; n * n];
    let (mut seconds_photo_setup, mut seconds_texels) = (0.0, 0.0);
    progress.start("resampling", photos.len() as u64);
    // The next photograph's depth map and mip levels are built while this one is sampled.
    let wanted = prep.photos_on_page(photos.len());
    let spare = SpareLevels::for_loop(wanted.iter().filter(|&&w| w).count());
    let setup = |pi: usize, rgb: &PhotoPixels, mask: Option<&GrayImage>| {
        prep.photo_setup(photos, pi, rgb, mask, &spare)
    };
    for_each_photo_with(
        photos,
        Some(&wanted),
        progress,
        setup,
        |pi, rgb, _mask, setup| {
            seconds_photo_setup += setup.seconds;
            let ph = prep.photo_with(photos, pi, rgb, setup);
            let photo = pi as u32;
            let texels = std::time::Instant::now();
            acc.par_chunks_mut(BAND * n)
                .zip(views.par_chunks_mut(BAND * n))
                .zip(best.par_chunks_mut(BAND * n))
                .zip(prep.atlas.texels.bands.par_iter())
                .enumerate()
                .for_each(|(bi, (((acc, views), best), list))| {
                    let y0 = bi * BAND;
                    let y1 = y0 + acc.len() / n;
                    for &f in list {
                        if !ph.samples(f) {
                            continue;
                        }
                        prep.sample_face(&ph, f, y0, y1, None, |x, y, c, w| {
                            let i = (y - y0) * n + x;
                            let a = &mut acc[i];
                            // Photographs come in order, so ties keep the first: deterministic.
                            if w > a[3] {
                                best[i] = photo as u16;
                                if winner {
                                    *a = [c[0], c[1], c[2], w];
                                }
                            }
                            if !winner {
                                for k in 0..3 {
                                    a[k] += w * c[k];
                                }
                                a[3] += w;
                            }
                            views[i] = views[i].saturating_add(1);
                        });
                    }
                });
            seconds_texels += texels.elapsed().as_secs_f64();
            spare.give(ph);
            Ok(())
        },
    )?;
    progress.finish();
    // Resolve every chart texel: photographs, else vertex colours.
    let mut color = vec![0f32; n * n * 3];
    let mut source = vec![TexelSource::Empty as u8; n * n];
    color
        .par_chunks_mut(3 * n)
        .zip(source.par_chunks_mut(n))
        .enumerate()
        .for_each(|(y, (crow, srow))| {
            for x in 0..n {
                let Some(f) = prep.owner(y * n + x) else {
                    continue;
                };
                let a = acc[y * n + x];
                let out = &mut crow[3 * x..3 * x + 3];
                if a[3] > 0.0 {
                    let s = if winner { 1.0 } else { a[3] };
                    for k in 0..3 {
                        out[k] = a[k] / s;
                    }
                    srow[x] = TexelSource::Photos as u8;
                } else {
                    out.copy_from_slice(&prep.vertex_color_at(f, x, y));
                    srow[x] = prep.fallback_source(f) as u8;
                }
            }
        });
    drop(acc);
    Ok(prep.finish(
        color,
        source,
        views,
        best,
        opts,
        (seconds_photo_setup, seconds_texels),
    ))
}

/// Fills `res`'s gutter again from its current chart colours (after a stage changed them),
/// `width` texels deep.
pub fn refill_gutter(res: &mut Resampled, width: u32) {
    let n = res.color.width() as usize;
    for s in res.source.iter_mut() {
        if *s == TexelSource::Gutter as u8 {
            *s = TexelSource::Empty as u8;
        }
    }
    let color: &mut [f32] = &mut res.color;
    extend_into_gutter(color, &mut res.source, n, width);
}

/// Calls `f(j)` for the 8-neighbours `j` of texel `i` of an `n` x `n` grid inside it, rows
/// above first, each row left to right (the order the gutter's sums are taken in).
#[inline(always)]
fn for_neighbours(i: usize, n: usize, mut f: impl FnMut(usize)) {
    let (x, y) = (i % n, i / n);
    let (x0, x1) = (x.saturating_sub(1), (x + 1).min(n - 1));
    for yy in y.saturating_sub(1)..=(y + 1).min(n - 1) {
        for xx in x0..=x1 {
            if (xx, yy) != (x, y) {
                f(yy * n + xx);
            }
        }
    }
}

/// Extends chart colours `width` texels into the empty texels around them, ring by ring (each
/// new texel the mean of its already-coloured 8-neighbours). Returns the texels filled.
pub fn extend_into_gutter(color: &mut [f32], source: &mut [u8], n: usize, width: u32) -> u64 {
    let empty = TexelSource::Empty as u8;
    if n == 0 || width == 0 {
        return 0;
    }
    // The first ring, a row at a time: the empty texels with a coloured neighbour.
    let src: &[u8] = source;
    let mut frontier: Vec<usize> = (0..n)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut row = Vec::new();
            for x in 0..n {
                let i = y * n + x;
                if src[i] != empty {
                    continue;
                }
                let mut any = false;
                for_neighbours(i, n, |j| any |= src[j] != empty);
                if any {
                    row.push(i);
                }
            }
            row
        })
        .collect();
    // Texels already in the next ring carry this mark instead of a sort and dedup of the
    // ring (the sorts took about 0.8 CPU s of a run at 8192); no mark outlives the call.
    const QUEUED: u8 = u8::MAX;
    let mut filled = 0u64;
    for _ in 0..width {
        if frontier.is_empty() {
            break;
        }
        let (src, col): (&[u8], &[f32]) = (source, color);
        let new: Vec<[f32; 3]> = frontier
            .par_iter()
            .map(|&i| {
                let mut c = [0f32; 3];
                let mut m = 0f32;
                for_neighbours(i, n, |j| {
                    if src[j] != empty && src[j] != QUEUED {
                        for k in 0..3 {
                            c[k] += col[3 * j + k];
                        }
                        m += 1.0;
                    }
                });
                c.map(|v| v / m.max(1.0))
            })
            .collect();
        for (&i, c) in frontier.iter().zip(&new) {
            color[3 * i..3 * i + 3].copy_from_slice(c);
            source[i] = TexelSource::Gutter as u8;
        }
        filled += new.len() as u64;
        let mut next: Vec<usize> = Vec::with_capacity(2 * frontier.len());
        for &i in &frontier {
            for_neighbours(i, n, |j| {
                if source[j] == empty {
                    source[j] = QUEUED;
                    next.push(j);
                }
            });
        }
        frontier = next;
    }
    for &i in &frontier {
        if source[i] == QUEUED {
            source[i] = empty;
        }
    }
    filled
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bind::ViewSample;
    use crate::mesh::VertexId;

    /// A sample reads the mask where its bilinear taps do: one background pixel among the
    /// four taps rejects it, even when the pixel it falls in is the object's.
    #[test]
    fn a_sample_holds_only_if_all_its_taps_are_object() {
        // Object on columns 0..5, background from column 5; 8 x 4 pixels.
        let m = image::GrayImage::from_fn(8, 4, |x, _| image::Luma([if x < 5 { 255 } else { 0 }]));
        let taps = sampler::tap_mask(&m);
        let at = |x: f64, y: f64| sampler::mask_holds(&taps, &nalgebra::Point2::new(x, y));
        // Pixel 4's left half reads pixels 3 and 4; its right half reads pixel 5 too (the
        // old test, the pixel the sample falls in, kept it).
        assert!(at(4.4, 2.0));
        assert!(!at(4.6, 2.0));
        assert!(at(0.2, 0.2), "edge pixels clamp");
        assert!(!at(-0.1, 1.0) && !at(1.0, 4.0), "outside the image");
    }

    /// With a mask, every mip level and every tap beside the outline gives the object's
    /// colour, whatever the background's; without one, the levels average both (the box
    /// filter as before).
    #[test]
    fn masked_mip_levels_average_object_pixels_only() {
        // Object (grey 0.4) on columns 0..21, background (magenta or green) from 21; odd
        // sides, so that levels drop a row and a column.
        let (w, h) = (37u32, 19u32);
        let photo = |bg: [u8; 3]| {
            PhotoPixels::Rgb8(image::RgbImage::from_fn(w, h, |x, _| {
                image::Rgb(if x < 21 { [102; 3] } else { bg })
            }))
        };
        let mask =
            image::GrayImage::from_fn(w, h, |x, _| image::Luma([if x < 21 { 255 } else { 0 }]));
        let (a, b) = (photo([255, 0, 255]), photo([0, 255, 0]));
        let (la, lb) = (
            sampler::PhotoPyramid::levels_of(&a, Some(&mask), 8, &Default::default()),
            sampler::PhotoPyramid::levels_of(&b, Some(&mask), 8, &Default::default()),
        );
        let (pa, pb) = (
            sampler::PhotoPyramid {
                base: &a,
                levels: la,
            },
            sampler::PhotoPyramid {
                base: &b,
                levels: lb,
            },
        );
        let grey = 102.0 / 255.0;
        for l in 1..=4 {
            for i in 0..=40 {
                // Across the outline, inside the object's part of each level's grid.
                let x = 19.0 + 0.05 * i as f64;
                let px = nalgebra::Point2::new(x, 9.5);
                let (ca, cb) = (pa.bilinear(l, &px), pb.bilinear(l, &px));
                for k in 0..3 {
                    assert!((ca[k] - grey).abs() < 1e-5, "level {l} at {x}: {ca:?}");
                    assert!((cb[k] - grey).abs() < 1e-5, "level {l} at {x}: {cb:?}");
                }
                let t = pa.sample(&px, 5.3);
                assert!(t.iter().all(|v| (v - grey).abs() < 1e-5), "{t:?}");
            }
        }
        // Without the mask the first level beside the outline mixes in the background.
        let plain = sampler::PhotoPyramid {
            base: &a,
            levels: sampler::PhotoPyramid::levels_of(&a, None, 8, &Default::default()),
        };
        let c = plain.bilinear(1, &nalgebra::Point2::new(21.0, 9.5));
        assert!(c[0] > grey + 0.1 && c[1] < grey - 0.1, "{c:?}");
    }

    /// Levels built in the buffers another photograph's levels left behind are the same bits
    /// as levels built in fresh ones, with a mask and without.
    #[test]
    fn mip_levels_in_spare_buffers_are_the_same_as_fresh_ones() {
        let (w, h) = (45u32, 30u32);
        let photo = |seed: u32| {
            PhotoPixels::Rgb8(image::RgbImage::from_fn(w, h, |x, y| {
                let v = (x * 7 + y * 13 + seed * 31) % 251;
                image::Rgb([v as u8, (v * 3 % 256) as u8, (255 - v) as u8])
            }))
        };
        let mask = image::GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if (x + 2 * y) % 5 < 3 { 255 } else { 0 }])
        });
        let (a, b) = (photo(1), photo(2));
        for m in [Some(&mask), None] {
            let fresh = sampler::PhotoPyramid::levels_of(&a, m, 8, &Default::default());
            let spare = SpareLevels::default();
            spare.keep(sampler::PhotoPyramid::levels_of(
                &b,
                m,
                8,
                &Default::default(),
            ));
            let reused = sampler::PhotoPyramid::levels_of(&a, m, 8, &spare);
            let bits = |l: &sampler::MipLevels| -> Vec<Vec<u32>> {
                let (colour, cover) = l.parts();
                colour
                    .iter()
                    .map(|c| c.as_raw().iter().map(|v| v.to_bits()).collect())
                    .chain(
                        cover
                            .iter()
                            .map(|c| c.iter().map(|v| v.to_bits()).collect()),
                    )
                    .collect()
            };
            assert_eq!(bits(&fresh).len(), if m.is_some() { 8 } else { 4 });
            assert_eq!(bits(&fresh), bits(&reused));
            assert_ne!(
                bits(&fresh),
                bits(&sampler::PhotoPyramid::levels_of(&b, m, 8, &spare))
            );
        }
    }

    /// A strip of 2n triangles over vertices 0..2n+2 (two rows).
    fn strip(n: u32) -> Mesh {
        let mut m = Mesh::default();
        for i in 0..=n {
            m.positions.push(Point3::new(i as f64, 0.0, 0.0));
            m.positions.push(Point3::new(i as f64, 1.0, 0.0));
        }
        for i in 0..n {
            let (a, b, c, d) = (2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1);
            m.faces.push([VertexId(a), VertexId(b), VertexId(c)]);
            m.faces.push([VertexId(a), VertexId(c), VertexId(d)]);
        }
        m
    }

    fn sample(photo: u32, c: f32) -> ViewSample {
        ViewSample {
            photo,
            color: [c; 3],
            weight: 1.0,
        }
    }

    /// The gutter fill as first written (iterator neighbours, a sorted and deduplicated
    /// next ring), the reference for the faster one.
    fn gutter_reference(color: &mut [f32], source: &mut [u8], n: usize, width: u32) -> u64 {
        let empty = TexelSource::Empty as u8;
        let nbrs = |i: usize| {
            let (x, y) = ((i % n) as i64, (i / n) as i64);
            (-1i64..=1)
                .flat_map(move |dy| (-1i64..=1).map(move |dx| (x + dx, y + dy)))
                .filter(move |&(xx, yy)| {
                    (xx, yy) != (x, y) && xx >= 0 && yy >= 0 && xx < n as i64 && yy < n as i64
                })
                .map(move |(xx, yy)| yy as usize * n + xx as usize)
        };
        let mut frontier: Vec<usize> = (0..n * n)
            .filter(|&i| source[i] == empty && nbrs(i).any(|j| source[j] != empty))
            .collect();
        let mut filled = 0u64;
        for _ in 0..width {
            if frontier.is_empty() {
                break;
            }
            let new: Vec<(usize, [f32; 3])> = frontier
                .iter()
                .map(|&i| {
                    let mut c = [0f32; 3];
                    let mut m = 0f32;
                    for j in nbrs(i) {
                        if source[j] != empty {
                            for k in 0..3 {
                                c[k] += color[3 * j + k];
                            }
                            m += 1.0;
                        }
                    }
                    (i, c.map(|v| v / m.max(1.0)))
                })
                .collect();
            for (i, c) in &new {
                color[3 * i..3 * i + 3].copy_from_slice(c);
                source[*i] = TexelSource::Gutter as u8;
            }
            filled += new.len() as u64;
            let mut next: Vec<usize> = new
                .iter()
                .flat_map(|(i, _)| nbrs(*i))
                .filter(|&j| source[j] == empty)
                .collect();
            next.sort_unstable();
            next.dedup();
            frontier = next;
        }
        filled
    }

    #[test]
    fn gutter_fill_matches_the_reference_bit_for_bit() {
        let mut rng = crate::rng::SplitMix64::new(7);
        for (n, density, width) in [
            (1, 0.5, 3),
            (2, 0.3, 2),
            (37, 0.02, 8),
            (64, 0.2, 4),
            (50, 0.0, 8),
        ] {
            // Random blobs of chart texels (a few seeds grown a little) with random colours.
            let mut source = vec![TexelSource::Empty as u8; n * n];
            let mut color = vec![0f32; 3 * n * n];
            for i in 0..n * n {
                if rng.next_f64() < density {
                    for j in [i, i.saturating_sub(1), (i + n).min(n * n - 1)] {
                        source[j] = TexelSource::Photos as u8;
                    }
                }
            }
            for c in color.iter_mut() {
                *c = rng.next_f64() as f32;
            }
            let (mut c1, mut s1) = (color.clone(), source.clone());
            let (mut c2, mut s2) = (color, source);
            let f1 = extend_into_gutter(&mut c1, &mut s1, n, width);
            let f2 = gutter_reference(&mut c2, &mut s2, n, width);
            assert_eq!(f1, f2, "n {n}");
            assert_eq!(s1, s2, "n {n}");
            let (b1, b2): (Vec<u32>, Vec<u32>) = (
                c1.iter().map(|v| v.to_bits()).collect(),
                c2.iter().map(|v| v.to_bits()).collect(),
            );
            assert_eq!(b1, b2, "n {n}");
            if density > 0.0 && n > 10 {
                assert!(f1 > 0, "n {n}: something filled");
            }
        }
    }

    #[test]
    fn classes_follow_common_photographs() {
        let m = strip(3); // vertices 0..8, faces 0..6
                          // Photo 0 sees vertices 0-3, photo 1 sees 2-5; vertices 6, 7 unseen.
        let mut rows: Vec<Vec<ViewSample>> = vec![Vec::new(); 8];
        for r in &mut rows[0..4] {
            r.push(sample(0, 0.5));
        }
        for r in &mut rows[2..6] {
            r.push(sample(1, 0.5));
        }
        // Vertex 4 seen only by photo 1, vertex 5 too; faces (2,4,5),(2,5,3) have common
        // photo 1; faces (4,6,7),(4,7,5) touch unseen vertices.
        let mut offsets = vec![0u32];
        let mut samples = Vec::new();
        for r in &rows {
            samples.extend(r);
            offsets.push(samples.len() as u32);
        }
        let b = Binding::from_samples(offsets, samples, 2);
        let c = classify(&m, &b);
        assert_eq!(c[0], FaceClass::Green);
        assert_eq!(c[2], FaceClass::Green);
        assert_eq!(c[4], FaceClass::Red);
        assert_eq!(c[5], FaceClass::Red);
        // All three vertices seen, but by different photographs: blue.
        let mut rows2 = rows.clone();
        rows2[0] = vec![sample(1, 0.5)];
        rows2[1] = vec![sample(1, 0.5)];
        rows2[2] = vec![sample(0, 0.5)];
        let mut offsets = vec![0u32];
        let mut samples = Vec::new();
        for r in &rows2 {
            samples.extend(r);
            offsets.push(samples.len() as u32);
        }
        let c = classify(&m, &Binding::from_samples(offsets, samples, 2));
        assert_eq!(c[0], FaceClass::Blue);
    }

    #[test]
    fn affine_maps_are_used_only_where_they_land_within_tolerance() {
        use crate::camera::{Camera, CameraModel, Pose};
        // 4000 x 3000, f = 3000, strong barrel distortion.
        let camera = Camera::new(
            1,
            CameraModel::Opencv,
            4000,
            3000,
            vec![3000.0, 3000.0, 2000.0, 1500.0, -0.25, 0.08, 0.0, 0.0],
        )
        .unwrap();
        let view = PosedCamera {
            camera,
            pose: Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0; 3]),
        };
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut large_affine, mut large_rejected, mut worst) = (0, 0, 0f64);
        for _ in 0..4000 {
            // A triangle 0.3-3 units from the camera, anywhere in the image, of any size
            // and slant.
            let z = 0.3 + 2.7 * next();
            let c = Vector3::new((next() - 0.5) * 1.2 * z, (next() - 0.5) * 0.9 * z, z);
            let size = (2.0 + 70.0 * next()) * z / 3000.0;
            let pos: [Point3<f64>; 3] = std::array::from_fn(|_| {
                let d = Vector3::new(next() - 0.5, next() - 0.5, (next() - 0.5) * 2.0);
                Point3::from(c + d * size)
            });
            let proj: Option<Vec<Point2<f64>>> = pos
                .iter()
                .map(|p| {
                    (p.z > 0.0)
                        .then(|| view.camera.project(&p.coords))
                        .flatten()
                })
                .collect();
            let Some(q) = proj else { continue };
            let q = [q[0], q[1], q[2]];
            let extent = (q[0] - q[1])
                .norm()
                .max((q[1] - q[2]).norm())
                .max((q[2] - q[0]).norm());
            let fits = affine_fits(&view, &pos, &q);
            if extent >= AFFINE_PX {
                if fits {
                    large_affine += 1;
                } else {
                    large_rejected += 1;
                }
            }
            if !fits || extent < AFFINE_PX {
                continue;
            }
            for i in 0..=8 {
                for j in 0..=8 - i {
                    let b = [i as f64 / 8.0, j as f64 / 8.0, (8 - i - j) as f64 / 8.0];
                    let p = pos[0].coords * b[0] + pos[1].coords * b[1] + pos[2].coords * b[2];
                    let lin = q[0].coords * b[0] + q[1].coords * b[1] + q[2].coords * b[2];
                    let exact = view.camera.project(&p).unwrap();
                    worst = worst.max((exact.coords - lin).norm());
                }
            }
        }
        // Both outcomes happen, and accepted maps are within 4/3 of the tolerance everywhere
        // (a little more for the non-quadratic part).
        assert!(
            large_affine > 300 && large_rejected > 300,
            "{large_affine} {large_rejected}"
        );
        assert!(worst < 1.5 * AFFINE_TOL, "worst error {worst} px");
    }

    #[test]
    fn fill_reaches_every_connected_vertex_from_its_coloured_neighbours() {
        let m = strip(6); // 14 vertices
        let mut colors: Vec<Option<[f32; 3]>> = vec![None; 14];
        colors[0] = Some([1.0, 0.0, 0.0]);
        colors[1] = Some([1.0, 0.0, 0.0]);
        colors[12] = Some([0.0, 0.0, 1.0]);
        colors[13] = Some([0.0, 0.0, 1.0]);
        let (filled, per_round, unreachable) = fill_vertex_colors(&m, &colors);
        assert_eq!(unreachable, 0);
        assert_eq!(per_round.iter().sum::<u64>(), 10);
        // Known colours stay; near the red end red dominates, near the blue end blue.
        assert_eq!(filled[0], [1.0, 0.0, 0.0]);
        assert!(filled[2][0] > filled[2][2] && filled[11][2] > filled[11][0]);
        assert!(filled.iter().all(|c| c.iter().all(|v| v.is_finite())));
        // A vertex in no face is unreachable and takes the mean colour.
        let mut m2 = m.clone();
        m2.positions.push(Point3::new(9.0, 9.0, 9.0));
        let mut c2 = colors.clone();
        c2.push(None);
        let (f2, _, unreachable) = fill_vertex_colors(&m2, &c2);
        assert_eq!(unreachable, 1);
        assert!((f2[14][0] - 0.5).abs() < 1e-6 && (f2[14][2] - 0.5).abs() < 1e-6);
    }
}
