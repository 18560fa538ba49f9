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
    /// Multiband merging: thread-seconds of that spent sampling texels (the rest is pyramids).
    pub cpu_seconds_sampling: f64,
    /// Multiband merging: seconds of the complement layers, the collapse of every chart and
    /// its copy into the atlas.
    pub seconds_collapse: f64,
    /// Chart-border levelling after a multiband merge, if it ran.
    pub seam_levelling: Option<crate::level::LevelStats>,
    /// The same run again on the restored atlas ([`crate::merge::relevel`]), if it ran.
    pub seam_levelling_after_restore: Option<crate::level::LevelStats>,
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
            let hue = (p as f32 * 0.618_034).fract() * 6.0;
            let f = hue.fract();
            let (a, b) = ((255.0 * (1.0 - f)) as u8, (255.0 * f) as u8);
            image::Rgb(match hue as u32 {
                0 => [255, b, 0],
                1 => [a, 255, 0],
                2 => [0, 255, b],
                3 => [0, a, 255],
                4 => [b, 0, 255],
                _ => [255, 0, a],
            })
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

/// Sorted photographs common to the three vertices of every face, compressed rows.
pub(crate) struct Common {
    offsets: Vec<u32>,
    photos: Vec<u32>,
    /// Per face: some photograph is valid at all three vertices (before any face check or
    /// limit), the paper's green test.
    all_three: Vec<bool>,
}

impl Common {
    /// Per face, the photographs valid at all three vertices (the paper's common photographs),
    /// or with `any_vertex` those valid at one vertex at least (per-texel occlusion then decides
    /// where on the face each one sees). With `face_check` (threshold), photographs whose face
    /// colour disagrees with the others' are left out of that face's list.
    fn new(
        mesh: &Mesh,
        b: &Binding,
        face_check: Option<f32>,
        any_vertex: bool,
        max_views: usize,
    ) -> Self {
        let lists: Vec<(Vec<u32>, bool)> = mesh
            .faces
            .par_iter()
            .map(|f| {
                let views = [f[0].idx(), f[1].idx(), f[2].idx()].map(|v| b.views(v));
                // Per photograph: colour sum, vertices seeing it, weight sum.
                let mut found: Vec<(u32, [f32; 3], u32, f32)> = Vec::new();
                for vs in &views {
                    for s in *vs {
                        match found.iter_mut().find(|e| e.0 == s.photo) {
                            Some(e) => {
                                (0..3).for_each(|k| e.1[k] += s.color[k]);
                                e.2 += 1;
                                e.3 += s.weight;
                            }
                            None => found.push((s.photo, s.color, 1, s.weight)),
                        }
                    }
                }
                let all_three = found.iter().any(|e| e.2 == 3);
                found.retain(|e| any_vertex || e.2 == 3);
                found.sort_unstable_by_key(|e| e.0);
                if let Some(t) = face_check {
                    let colors: Vec<[f32; 3]> =
                        found.iter().map(|e| e.1.map(|c| c / e.2 as f32)).collect();
                    let mut ok = consistent(&colors, t).into_iter();
                    found.retain(|_| ok.next().unwrap_or(true));
                }
                if max_views > 0 && found.len() > max_views {
                    // Heaviest first, ties by photograph index (deterministic), then back to
                    // photograph order for the binary searches.
                    found.sort_unstable_by(|a, b| b.3.total_cmp(&a.3).then(a.0.cmp(&b.0)));
                    found.truncate(max_views);
                    found.sort_unstable_by_key(|e| e.0);
                }
                (found.into_iter().map(|e| e.0).collect(), all_three)
            })
            .collect();
        let mut offsets = Vec::with_capacity(lists.len() + 1);
        offsets.push(0u32);
        let mut photos = Vec::new();
        let mut all_three = Vec::with_capacity(lists.len());
        for (l, a) in lists {
            photos.extend(l);
            offsets.push(photos.len() as u32);
            all_three.push(a);
        }
        Common {
            offsets,
            photos,
            all_three,
        }
    }

    pub(crate) fn of(&self, f: usize) -> &[u32] {
        &self.photos[self.offsets[f] as usize..self.offsets[f + 1] as usize]
    }
}

/// Classifies every face (green, blue, red).
pub fn classify(mesh: &Mesh, b: &Binding) -> Vec<FaceClass> {
    let common = Common::new(mesh, b, None, false, 0);
    classes_from(mesh, b, &common)
}

fn classes_from(mesh: &Mesh, b: &Binding, common: &Common) -> Vec<FaceClass> {
    (0..mesh.num_faces())
        .map(|f| {
            if common.all_three[f] {
                FaceClass::Green
            } else if mesh.faces[f].iter().all(|v| !b.views(v.idx()).is_empty()) {
                FaceClass::Blue
            } else {
                FaceClass::Red
            }
        })
        .collect()
}

/// The paper's fill of unbound vertices: rounds at 80, 60, 40 and 20% of the one-ring
/// coloured, each repeated until nothing changes, then any coloured neighbour; a vertex takes
/// the mean of its coloured neighbours. Rounds update all qualifying vertices at once (the
/// result does not depend on vertex order). Vertices no fill reaches get the mean colour.
pub fn fill_vertex_colors(
    mesh: &Mesh,
    colors: &[Option<[f32; 3]>],
) -> (Vec<[f32; 3]>, [u64; 5], u64) {
    let nv = mesh.num_vertices();
    let nbr = crate::mesh::topology::one_rings(mesh);
    let mut col: Vec<Option<[f32; 3]>> = colors.to_vec();
    let mut per_round = [0u64; 5];
    for (round, p) in [0.8, 0.6, 0.4, 0.2, 0.0].into_iter().enumerate() {
        // Each round starts from every uncoloured vertex; after a pass only the neighbours of
        // what it coloured can have become eligible (a vertex's test reads its ring only).
        let mut candidates: Vec<u32> = (0..nv as u32)
            .filter(|&v| col[v as usize].is_none())
            .collect();
        loop {
            let updates: Vec<(usize, [f32; 3])> = candidates
                .par_iter()
                .map(|&v| v as usize)
                .filter(|&v| col[v].is_none() && !nbr[v].is_empty())
                .filter_map(|v| {
                    let coloured: Vec<[f32; 3]> =
                        nbr[v].iter().filter_map(|&u| col[u as usize]).collect();
                    let frac = coloured.len() as f64 / nbr[v].len() as f64;
                    if coloured.is_empty() || frac < p {
                        return None;
                    }
                    let n = coloured.len() as f32;
                    Some((
                        v,
                        std::array::from_fn(|k| coloured.iter().map(|c| c[k]).sum::<f32>() / n),
                    ))
                })
                .collect();
            if updates.is_empty() {
                break;
            }
            per_round[round] += updates.len() as u64;
            for &(v, c) in &updates {
                col[v] = Some(c);
            }
            candidates = updates
                .iter()
                .flat_map(|&(v, _)| nbr[v].iter().copied())
                .filter(|&u| col[u as usize].is_none())
                .collect();
            candidates.sort_unstable();
            candidates.dedup();
        }
    }
    let known: Vec<[f32; 3]> = col.iter().flatten().copied().collect();
    let mean = if known.is_empty() {
        [0.5; 3]
    } else {
        std::array::from_fn(|k| known.iter().map(|c| c[k]).sum::<f32>() / known.len() as f32)
    };
    let unreachable = col.iter().filter(|c| c.is_none()).count() as u64;
    (
        col.into_iter().map(|c| c.unwrap_or(mean)).collect(),
        per_round,
        unreachable,
    )
}

/// Clamps barycentrics to the triangle (texels just outside it, owned conservatively).
fn clamp_bary(b: [f64; 3]) -> [f64; 3] {
    let c = b.map(|v| v.max(0.0));
    let s: f64 = c.iter().sum();
    if s > 0.0 {
        c.map(|v| v / s)
    } else {
        [1.0 / 3.0; 3]
    }
}

/// A photograph as a mip chain (2x2 box filter), for samples whose footprint spans several
/// pixels. The base stays as decoded (8-bit photographs a quarter of the memory of floats);
/// the levels below it are floats.
struct PhotoPyramid<'a> {
    base: &'a PhotoPixels,
    levels: Vec<Rgb32FImage>,
}

/// One 2x2 box-filter reduction of the `w` x `h` RGB values `raw`.
fn half_size<V: Values + ?Sized>(raw: &V, w: u32, h: u32) -> Rgb32FImage {
    let (nw, nh) = (w / 2, h / 2);
    let mut buf = vec![0f32; (nw * nh * 3) as usize];
    let stride = 3 * w as usize;
    buf.par_chunks_mut((nw * 3) as usize)
        .enumerate()
        .for_each(|(y, row)| {
            let (r0, r1) = (2 * y * stride, (2 * y + 1) * stride);
            for (x, o) in row.chunks_exact_mut(3).enumerate() {
                let (a, b) = (r0 + 6 * x, r1 + 6 * x);
                for (k, v) in o.iter_mut().enumerate() {
                    *v = 0.25
                        * (raw.value(a + k)
                            + raw.value(a + 3 + k)
                            + raw.value(b + k)
                            + raw.value(b + 3 + k));
                }
            }
        });
    Rgb32FImage::from_raw(nw, nh, buf).expect("sized nw*nh*3")
}

/// Bilinear sample at pixel coordinate (`x`, `y`) (pixel units, centres at integers) of the
/// `w` x `h` RGB values `raw`, clamped at the borders.
#[inline(always)]
fn bilinear_in<V: Values + ?Sized>(raw: &V, w: u32, h: u32, x: f64, y: f64) -> [f32; 3] {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let cl = |v: f64, n: u32| (v.max(0.0) as u32).min(n - 1);
    let (xa, xb, ya, yb) = (cl(x0, w), cl(x0 + 1.0, w), cl(y0, h), cl(y0 + 1.0, h));
    let at = |x: u32, y: u32| -> [f32; 3] {
        let i = 3 * (y as usize * w as usize + x as usize);
        [raw.value(i), raw.value(i + 1), raw.value(i + 2)]
    };
    let (p00, p10) = (at(xa, ya), at(xb, ya));
    let (p01, p11) = (at(xa, yb), at(xb, yb));
    std::array::from_fn(|k| {
        let top = p00[k] + (p10[k] - p00[k]) * fx;
        let bot = p01[k] + (p11[k] - p01[k]) * fx;
        top + (bot - top) * fy
    })
}

impl<'a> PhotoPyramid<'a> {
    /// The levels below `base`, at most `levels`.
    fn levels_of(base: &PhotoPixels, levels: usize) -> Vec<Rgb32FImage> {
        let mut out: Vec<Rgb32FImage> = Vec::new();
        for _ in 0..levels {
            let (w, h) = match out.last() {
                Some(prev) => prev.dimensions(),
                None => base.dimensions(),
            };
            if w < 2 || h < 2 {
                break;
            }
            let next = match (out.last(), base) {
                (Some(prev), _) => half_size(prev.as_raw().as_slice(), w, h),
                (None, PhotoPixels::Rgb8(img)) => half_size(img.as_raw().as_slice(), w, h),
                (None, PhotoPixels::Rgb32F(img)) => half_size(img.as_raw().as_slice(), w, h),
            };
            out.push(next);
        }
        out
    }

    /// Bilinear sample at photo pixel coordinate `px` (centres at +0.5) of level `l`.
    fn bilinear(&self, l: usize, px: &Point2<f64>) -> [f32; 3] {
        let l = l.min(self.levels.len());
        let f = (1u32 << l) as f64;
        let (x, y) = (px.x / f - 0.5, px.y / f - 0.5);
        if l > 0 {
            let img = &self.levels[l - 1];
            let (w, h) = img.dimensions();
            return bilinear_in(img.as_raw().as_slice(), w, h, x, y);
        }
        match self.base {
            PhotoPixels::Rgb8(img) => {
                bilinear_in(img.as_raw().as_slice(), img.width(), img.height(), x, y)
            }
            PhotoPixels::Rgb32F(img) => {
                bilinear_in(img.as_raw().as_slice(), img.width(), img.height(), x, y)
            }
        }
    }

    /// Trilinear sample with a footprint of `texels` photo pixels.
    fn sample(&self, px: &Point2<f64>, footprint: f64) -> [f32; 3] {
        let lod = footprint.max(1.0).log2().min(self.levels.len() as f64);
        let l0 = lod.floor() as usize;
        let a = self.bilinear(l0, px);
        if lod == l0 as f64 {
            return a;
        }
        let b = self.bilinear(l0 + 1, px);
        let t = (lod - l0 as f64) as f32;
        std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
    }
}

/// Largest pixel extent of a triangle resampled through an affine texel -> pixel map.
const AFFINE_PX: f64 = 8.0;

/// Largest pixel extent of a triangle resampled through an affine map if it passes the
/// centroid test.
const AFFINE_MAX_PX: f64 = 64.0;

/// Largest error of an affine map at a triangle's test points, pixels.
const AFFINE_TOL: f64 = 0.02;

/// Whether texels of the triangle `pos` (projected to `q` by `view`) may map to pixels
/// affinely: always when it spans under [`AFFINE_PX`] pixels; up to [`AFFINE_MAX_PX`] where
/// the map's error (perspective and distortion) is under [`AFFINE_TOL`] pixels at the
/// centroid and the edge midpoints.
fn affine_fits(view: &PosedCamera, pos: &[Point3<f64>; 3], q: &[Point2<f64>; 3]) -> bool {
    let extent = (q[0] - q[1])
        .norm()
        .max((q[1] - q[2]).norm())
        .max((q[2] - q[0]).norm());
    if extent < AFFINE_PX {
        return true;
    }
    if extent >= AFFINE_MAX_PX {
        return false;
    }
    // The error of the affine map is near quadratic over a triangle this small: with it under
    // the tolerance at the edge midpoints it is under 4/3 of it everywhere; the centroid
    // catches an error that cancels at the midpoints.
    let at = |b: [f64; 3]| -> bool {
        let p = Point3::from(pos[0].coords * b[0] + pos[1].coords * b[1] + pos[2].coords * b[2]);
        let lin = q[0].coords * b[0] + q[1].coords * b[1] + q[2].coords * b[2];
        let cam = view.pose.transform(&p);
        cam.z > 0.0
            && view
                .camera
                .project(&cam)
                .is_some_and(|e| (e.coords - lin).norm() < AFFINE_TOL)
    };
    let t = 1.0 / 3.0;
    at([t, t, t]) && at([0.5, 0.5, 0.0]) && at([0.0, 0.5, 0.5]) && at([0.5, 0.0, 0.5])
}

/// The per-face work shared by every way of combining the photographs: which face owns each
/// texel, the triangle classes, the photographs sampled per face, the filled vertex colours.
pub(crate) struct Prepared<'a> {
    pub(crate) mesh: &'a Mesh,
    pub(crate) normals: &'a [Vector3<f64>],
    pub(crate) binding: &'a Binding,
    gains: &'a Gains,
    pub(crate) atlas: &'a Atlas,
    pub(crate) classes: Vec<FaceClass>,
    pub(crate) common: Common,
    pub(crate) vertex_colors: Vec<[f32; 3]>,
    filled_per_round: [u64; 5],
    vertices_unreachable: u64,
    mean_edge: f64,
    robust: bool,
    identity: bool,
}

/// What [`Prepared::photo_setup`] computes for a photograph.
pub(crate) struct PhotoSetup {
    depth: Option<DepthMap>,
    levels: Vec<Rgb32FImage>,
    projected: Vec<Option<[f64; 3]>>,
    sampled: Vec<u64>,
    /// Seconds it took.
    pub(crate) seconds: f64,
}

/// One photograph ready to be sampled: its projected vertices, depth map, mip pyramid and
/// the faces that sample it.
pub(crate) struct PhotoSampler<'a> {
    pub(crate) index: usize,
    view: &'a PosedCamera,
    depth: Option<DepthMap>,
    /// Every vertex projected: photo pixel and camera depth (shared with the depth map).
    projected: Vec<Option<[f64; 3]>>,
    /// Bit per face: whether the face samples this photograph ([`Prepared::samples`]).
    sampled: Vec<u64>,
    pyramid: PhotoPyramid<'a>,
    mask: Option<&'a GrayImage>,
    centre: Point3<f64>,
    focal: f64,
}

impl PhotoSampler<'_> {
    /// Whether face `f` samples this photograph.
    #[inline]
    pub(crate) fn samples(&self, f: u32) -> bool {
        self.sampled[f as usize / 64] >> (f % 64) & 1 == 1
    }
}

impl<'a> Prepared<'a> {
    /// Checks the inputs and does the per-face work for `atlas`.
    pub(crate) fn new(
        mesh: &'a Mesh,
        atlas: &'a Atlas,
        normals: &'a [Vector3<f64>],
        binding: &'a Binding,
        gains: &'a Gains,
        opts: &ResampleOptions,
    ) -> Result<Self> {
        if binding.offsets.len() != mesh.num_vertices() + 1
            || normals.len() != mesh.num_vertices()
            || atlas.face_chart.len() != mesh.num_faces()
        {
            return Err(Error::Invalid(
                "binding, normals and atlas must belong to the mesh being resampled".into(),
            ));
        }
        let bind_opts = &binding.options;
        let face_check = (bind_opts.method == Method::Robust
            && bind_opts.consistency == Consistency::Face)
            .then_some(bind_opts.consistency_threshold);
        let robust = bind_opts.method == Method::Robust;
        // The paper samples the common photographs of green faces only; robust tries every
        // photograph valid at any vertex and lets the per-texel depth test decide.
        let common = Common::new(
            mesh,
            binding,
            face_check,
            robust,
            if robust { opts.max_views } else { 0 },
        );
        let classes = classes_from(mesh, binding, &common);
        let (vertex_colors, filled_per_round, vertices_unreachable) =
            fill_vertex_colors(mesh, &binding.vertex_colors());
        Ok(Prepared {
            mesh,
            normals,
            binding,
            atlas,
            classes,
            common,
            vertex_colors,
            filled_per_round,
            vertices_unreachable,
            mean_edge: mesh.mean_edge_length(),
            robust,
            gains,
            identity: gains.is_identity(),
        })
    }

    /// Atlas side in texels.
    pub(crate) fn size(&self) -> usize {
        self.atlas.texels.size
    }

    /// Face owning texel `i` (row-major), if any.
    pub(crate) fn owner(&self, i: usize) -> Option<u32> {
        self.atlas.owner(i)
    }

    /// Whether face `f` samples photograph `photo`.
    pub(crate) fn samples(&self, f: usize, photo: u32) -> bool {
        self.common.of(f).binary_search(&photo).is_ok()
    }

    /// Texel rows and columns (inclusive) face `f` may own, if it lies on the page.
    pub(crate) fn face_rect(&self, f: usize) -> Option<((usize, usize), (usize, usize))> {
        self.atlas.face_rect(f)
    }

    /// The part of getting photograph `pi` (decoded as `rgb`) ready to sample that takes
    /// time: its projected vertices, depth map, mip levels and the faces that sample it,
    /// owned, so that it can run beside the work on the previous photograph.
    pub(crate) fn photo_setup(&self, photos: &[Photo], pi: usize, rgb: &PhotoPixels) -> PhotoSetup {
        let view = &photos[pi].view;
        let t = std::time::Instant::now();
        let projected = crate::depth::project_vertices(self.mesh, view);
        let depth = self.robust.then(|| {
            let res = self.binding.options.depth_resolution;
            DepthMap::render_projected(self.mesh, view, &projected, res).eroded(1)
        });
        let levels = PhotoPyramid::levels_of(rgb, if self.robust { 8 } else { 0 });
        // One test per face here instead of a search per face and chart in the loops.
        let photo = pi as u32;
        let sampled = (0..self.mesh.num_faces())
            .into_par_iter()
            .step_by(64)
            .map(|f0| {
                (f0..(f0 + 64).min(self.mesh.num_faces()))
                    .filter(|&f| self.samples(f, photo))
                    .fold(0u64, |w, f| w | 1 << (f - f0))
            })
            .collect();
        PhotoSetup {
            depth,
            levels,
            projected,
            sampled,
            seconds: t.elapsed().as_secs_f64(),
        }
    }

    /// Photograph `pi` (decoded as `rgb`, with its mask) ready to sample, from its `setup`.
    pub(crate) fn photo_with(
        &self,
        photos: &'a [Photo],
        pi: usize,
        rgb: &'a PhotoPixels,
        mask: Option<&'a GrayImage>,
        setup: PhotoSetup,
    ) -> PhotoSampler<'a> {
        let view = &photos[pi].view;
        PhotoSampler {
            index: pi,
            view,
            depth: setup.depth,
            projected: setup.projected,
            sampled: setup.sampled,
            pyramid: PhotoPyramid {
                base: rgb,
                levels: setup.levels,
            },
            mask,
            centre: view.pose.center(),
            focal: focal_px(view),
        }
    }

    /// Samples photograph `ph` at every texel face `f` owns in rows `y0..y1`, calling
    /// `emit(x, y, colour, weight)` for each texel the photograph sees (gain-corrected colour;
    /// weight `<N, V>` for the paper, projected area for robust).
    /// With `coarse` = Some((x, y)), only the texels at even offsets from (x, y) are sampled,
    /// each over twice the footprint (standing for the 2 x 2 texels from it).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn sample_face(
        &self,
        ph: &PhotoSampler,
        f: u32,
        y0: usize,
        y1: usize,
        coarse: Option<(usize, usize)>,
        mut emit: impl FnMut(usize, usize, [f32; 3], f32),
    ) {
        let n = self.atlas.texels.size;
        let Some(r) = self.atlas.texels.faces[f as usize].as_ref() else {
            return;
        };
        let (mesh, view, pi) = (self.mesh, ph.view, ph.index);
        let bind_opts = &self.binding.options;
        let fv = mesh.faces[f as usize];
        let pos: [Point3<f64>; 3] = std::array::from_fn(|k| mesh.positions[fv[k].idx()]);
        let nrm: [Vector3<f64>; 3] = std::array::from_fn(|k| self.normals[fv[k].idx()]);
        // Per face, from the photograph's projected vertices: an affine map texel -> pixel
        // where `affine_fits` finds its error far below a pixel; per-texel projection
        // otherwise.
        let proj = fv.map(|v| ph.projected[v.idx()]);
        let affine = match proj {
            [Some(a), Some(b), Some(c)] => {
                let q = [a, b, c].map(|p| Point2::new(p[0], p[1]));
                let fits = affine_fits(view, &pos, &q);
                fits.then(|| {
                    let cos: [f64; 3] = std::array::from_fn(|k| {
                        let to_cam = ph.centre - pos[k];
                        nrm[k].dot(&to_cam) / to_cam.norm().max(1e-300)
                    });
                    (q, [a[2], b[2], c[2]], cos)
                })
            }
            _ => None,
        };
        // Gain corrections at the vertices, interpolated (the fields are smooth).
        let gain: [[f32; 3]; 3] = if self.identity {
            [[1.0; 3]; 3]
        } else {
            nrm.map(|nv| self.gains.factor(pi, &nv))
        };
        let (step, (gx, gy)) = match coarse {
            Some(g) => (2, g),
            None => (1, (0, 0)),
        };
        let (ya, xa) = (r.rows.0.max(y0), r.cols.0);
        // The first row and column on the grid.
        let (ya, xa) = (ya + ((ya ^ gy) & (step - 1)), xa + ((xa ^ gx) & (step - 1)));
        for y in (ya..=r.rows.1.min(y1 - 1)).step_by(step) {
            for x in (xa..=r.cols.1).step_by(step) {
                if self.atlas.texels.owner[y * n + x] != f {
                    continue;
                }
                let b = clamp_bary(r.bary(x, y));
                let (px, z, cos) = match &affine {
                    Some((q, zs, cv)) => (
                        Point2::from(q[0].coords * b[0] + q[1].coords * b[1] + q[2].coords * b[2]),
                        zs[0] * b[0] + zs[1] * b[1] + zs[2] * b[2],
                        cv[0] * b[0] + cv[1] * b[1] + cv[2] * b[2],
                    ),
                    None => {
                        let p = Point3::from(
                            pos[0].coords * b[0] + pos[1].coords * b[1] + pos[2].coords * b[2],
                        );
                        let nn = (nrm[0] * b[0] + nrm[1] * b[1] + nrm[2] * b[2])
                            .try_normalize(1e-12)
                            .unwrap_or(nrm[0]);
                        let to_cam = ph.centre - p;
                        let cos = nn.dot(&to_cam) / to_cam.norm().max(1e-300);
                        let cam = view.pose.transform(&p);
                        if cam.z <= 0.0 {
                            continue;
                        }
                        let Some(px) = view.camera.project(&cam) else {
                            continue;
                        };
                        (px, cam.z, cos)
                    }
                };
                let (c, w) = if let Some(d) = &ph.depth {
                    if cos <= 0.0 || !view.camera.contains(&px) {
                        continue;
                    }
                    // Masks decide per texel too: a face seen at one vertex may leave the
                    // object's outline elsewhere.
                    if let Some(m) = ph.mask {
                        let (mx, my) = (px.x as u32, px.y as u32);
                        if mx >= m.width() || my >= m.height() || m.get_pixel(mx, my)[0] < 128 {
                            continue;
                        }
                    }
                    let tol = depth_tolerance(self.mean_edge, z, ph.focal * d.scale, cos);
                    if z > d.at(&px) as f64 + tol {
                        continue;
                    }
                    let footprint = step as f64 * r.texel_len * ph.focal / z;
                    let area = cos * (ph.focal * self.mean_edge / z).powi(2);
                    let w = if bind_opts.weight_power == 1.0 {
                        area
                    } else {
                        area.powf(bind_opts.weight_power)
                    };
                    (ph.pyramid.sample(&px, footprint), w)
                } else {
                    // The paper: every common photograph, weight <N, V>.
                    (ph.pyramid.bilinear(0, &px), cos.max(0.0))
                };
                let c: [f32; 3] = if self.identity {
                    c
                } else {
                    let bf = b.map(|v| v as f32);
                    std::array::from_fn(|k| {
                        c[k] * (gain[0][k] * bf[0] + gain[1][k] * bf[1] + gain[2][k] * bf[2])
                    })
                };
                emit(x, y, c, w as f32);
            }
        }
    }

    /// Face `f`'s vertex colours interpolated at texel (x, y).
    pub(crate) fn vertex_color_at(&self, f: u32, x: usize, y: usize) -> [f32; 3] {
        let r = self.atlas.texels.faces[f as usize]
            .as_ref()
            .expect("owners rasterise");
        let b = clamp_bary(r.bary(x, y));
        let fv = self.mesh.faces[f as usize];
        std::array::from_fn(|k| {
            (0..3)
                .map(|j| self.vertex_colors[fv[j].idx()][k] * b[j] as f32)
                .sum()
        })
    }

    /// Source of a chart texel of face `f` no photograph coloured.
    pub(crate) fn fallback_source(&self, f: u32) -> TexelSource {
        match self.classes[f as usize] {
            FaceClass::Green => TexelSource::GreenFallback,
            FaceClass::Blue => TexelSource::Blue,
            FaceClass::Red => TexelSource::Red,
        }
    }

    /// Fills the gutter and counts: the last step of every merge.
    pub(crate) fn finish(
        &self,
        mut color: Vec<f32>,
        mut source: Vec<u8>,
        views: Vec<u8>,
        best: Vec<u16>,
        opts: &ResampleOptions,
        seconds: (f64, f64),
    ) -> Resampled {
        let n = self.atlas.texels.size;
        let gutter = extend_into_gutter(&mut color, &mut source, n, opts.gutter_fill);
        let count = |s: TexelSource| source.par_iter().filter(|&&v| v == s as u8).count() as u64;
        let classes = self.classes.clone();
        let stats = ResampleStats {
            green: classes.iter().filter(|c| **c == FaceClass::Green).count() as u64,
            blue: classes.iter().filter(|c| **c == FaceClass::Blue).count() as u64,
            red: classes.iter().filter(|c| **c == FaceClass::Red).count() as u64,
            texels_photos: count(TexelSource::Photos),
            texels_green_fallback: count(TexelSource::GreenFallback),
            texels_blue: count(TexelSource::Blue),
            texels_red: count(TexelSource::Red),
            texels_gutter: gutter,
            filled_per_round: self.filled_per_round,
            vertices_unreachable: self.vertices_unreachable,
            seconds_photo_setup: seconds.0,
            seconds_texels: seconds.1,
            cpu_seconds_sampling: 0.0,
            seconds_collapse: 0.0,
            seam_levelling: None,
            seam_levelling_after_restore: None,
        };
        Resampled {
            color: Rgb32FImage::from_raw(n as u32, n as u32, color).expect("sized n*n*3"),
            source,
            views,
            best_photo: best,
            classes,
            vertex_colors: self.vertex_colors.clone(),
            stats,
        }
    }
}

/// No photograph (in [`Resampled::best_photo`]).
pub const NO_PHOTO: u16 = u16::MAX;

/// Texels record their best photograph in 16 bits.
pub(crate) fn check_photo_count(n: usize) -> Result<()> {
    if n >= NO_PHOTO as usize {
        return Err(Error::Invalid(format!(
            "{n} photographs: at most {} can be combined in one atlas",
            NO_PHOTO - 1
        )));
    }
    Ok(())
}

/// Stage 3: resamples the bound photographs into `atlas` (page 0 of the mesh's UVs), each texel the weighted mean of the photographs that see it (`winner` false) or the
/// colour of the one with the largest weight (`winner` true). `normals` are unit vertex
/// normals of `mesh`.
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
    let prep = Prepared::new(mesh, atlas, normals, binding, gains, opts)?;
    resample_with(&prep, photos, opts, winner, progress)
}

/// [`resample`] with the per-face work done.
pub(crate) fn resample_with(
    prep: &Prepared,
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
    let setup = |pi: usize, rgb: &PhotoPixels| prep.photo_setup(photos, pi, rgb);
    for_each_photo_with(photos, progress, setup, |pi, rgb, mask, setup| {
        seconds_photo_setup += setup.seconds;
        let ph = prep.photo_with(photos, pi, rgb, mask, setup);
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
        Ok(())
    })?;
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
pub(crate) fn refill_gutter(res: &mut Resampled, width: u32) {
    let n = res.color.width() as usize;
    for s in res.source.iter_mut() {
        if *s == TexelSource::Gutter as u8 {
            *s = TexelSource::Empty as u8;
        }
    }
    let color: &mut [f32] = &mut res.color;
    extend_into_gutter(color, &mut res.source, n, width);
}

/// Extends chart colours `width` texels into the empty texels around them, ring by ring (each
/// new texel the mean of its already-coloured 8-neighbours). Returns the texels filled.
pub(crate) fn extend_into_gutter(
    color: &mut [f32],
    source: &mut [u8],
    n: usize,
    width: u32,
) -> u64 {
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
        .into_par_iter()
        .filter(|&i| source[i] == empty && nbrs(i).any(|j| source[j] != empty))
        .collect();
    let mut filled = 0u64;
    for _ in 0..width {
        if frontier.is_empty() {
            break;
        }
        let new: Vec<(usize, [f32; 3])> = frontier
            .par_iter()
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bind::ViewSample;
    use crate::mesh::VertexId;

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
