//! Sampling one photograph into the atlas: the per-face work shared by every way of combining
//! photographs ([`Sampler`]), a photograph made ready to sample ([`PhotoSampler`]: projected
//! vertices, depth map, mip pyramid) and the per-texel sampling through per-face affine maps.

use super::*;
use crate::memory::SpareBuffers;

/// Clamps barycentrics to the triangle (texels just outside it, owned conservatively).
pub(super) fn clamp_bary(b: [f64; 3]) -> [f64; 3] {
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
pub(super) struct PhotoPyramid<'a> {
    pub(super) base: &'a PhotoPixels,
    pub(super) levels: MipLevels,
}

/// The levels below a photograph's base. With a mask, only object pixels are averaged: each
/// level holds colour times coverage (the share of object pixels under it) and the coverage,
/// and a sample divides the one by the other, so that the colour under the mask's black (a
/// backdrop, a turntable, whatever a background-removal tool left) never reaches a texel
/// through a coarse level or a tap beside the outline. The base needs no weights: a base
/// sample reading a background pixel is refused ([`mask_holds`]).
#[derive(Default)]
pub struct MipLevels {
    colour: Vec<Rgb32FImage>,
    /// Per level, the share of object pixels; empty without a mask.
    cover: Vec<Vec<f32>>,
}

/// Buffers of mip levels that a photograph no longer needs, for the next photograph's levels
/// of the same size. A level of a 12 MP photograph is tens of megabytes: allocated afresh
/// for each photograph, it came from new pages of memory each time (the allocator unmaps a
/// worker thread's block when it is freed), and their first writes were 1% of the 1.5M-face
/// scene's time. Every value of a reused buffer is written before it is read.
pub struct SpareLevels(std::sync::Mutex<(SpareBuffers, usize)>);

impl Default for SpareLevels {
    /// Keeps every photograph's levels that it is given (up to the cap).
    fn default() -> Self {
        SpareLevels(std::sync::Mutex::new((
            SpareBuffers::new(Self::KEEP),
            usize::MAX,
        )))
    }
}

impl SpareLevels {
    /// At most this many buffers are kept (two photographs' levels and coverage), the
    /// newest: photographs of several sizes leave buffers no later one may fit.
    const KEEP: usize = 32;

    /// For a loop over `photos` photographs that builds each one's levels while the one
    /// before it is sampled ([`crate::photos::for_each_photo_with`]): the levels of the
    /// photograph sampled `k`-th go to the one `k + 2`-th, so the last two photographs' are
    /// freed, not kept (they would only add to the loop's peak).
    pub fn for_loop(photos: usize) -> Self {
        SpareLevels(std::sync::Mutex::new((
            SpareBuffers::new(Self::KEEP),
            photos.saturating_sub(2),
        )))
    }

    /// A buffer of `len` values, reused if one of that length is spare (its old values
    /// still in it), zeroed otherwise.
    fn take(&self, len: usize) -> Vec<f32> {
        let mut spare = self.0.lock().unwrap_or_else(|e| e.into_inner());
        spare.0.take(len).unwrap_or_else(|| vec![0f32; len])
    }

    /// Keeps the mip levels of a photograph that has been sampled, if a later one can use
    /// them.
    pub fn give(&self, ph: PhotoSampler) {
        self.keep(ph.pyramid.levels);
    }

    /// Keeps `levels`' buffers, if a later photograph can use them.
    pub(super) fn keep(&self, levels: MipLevels) {
        let mut spare = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let (bufs, useful) = &mut *spare;
        if *useful == 0 {
            return;
        }
        *useful -= 1;
        bufs.put(
            levels
                .colour
                .into_iter()
                .map(Rgb32FImage::into_raw)
                .chain(levels.cover),
        );
    }
}

#[cfg(test)]
impl MipLevels {
    /// The colour levels and the coverage levels.
    pub(super) fn parts(&self) -> (&[Rgb32FImage], &[Vec<f32>]) {
        (&self.colour, &self.cover)
    }
}

/// The first level below a masked base: colour times coverage, and coverage (object pixels
/// are those of mask value 128 and above).
fn half_size_masked<V: Values + ?Sized>(
    raw: &V,
    mask: &[u8],
    w: u32,
    h: u32,
    spare: &SpareLevels,
) -> (Rgb32FImage, Vec<f32>) {
    let (nw, nh) = (w / 2, h / 2);
    let mut buf = spare.take((nw * nh * 3) as usize);
    let mut cover = spare.take((nw * nh) as usize);
    let (w, stride) = (w as usize, 3 * w as usize);
    buf.par_chunks_mut((nw * 3) as usize)
        .zip(cover.par_chunks_mut(nw as usize))
        .enumerate()
        .for_each(|(y, (row, crow))| {
            let (m0, m1) = (2 * y * w, (2 * y + 1) * w);
            let (r0, r1) = (2 * y * stride, (2 * y + 1) * stride);
            for (x, (o, c)) in row.chunks_exact_mut(3).zip(crow.iter_mut()).enumerate() {
                let taps = [
                    (m0 + 2 * x, r0 + 6 * x),
                    (m0 + 2 * x + 1, r0 + 6 * x + 3),
                    (m1 + 2 * x, r1 + 6 * x),
                    (m1 + 2 * x + 1, r1 + 6 * x + 3),
                ];
                let mut n = 0u32;
                let mut sum = [0f32; 3];
                for (mi, ri) in taps {
                    if mask[mi] >= 128 {
                        n += 1;
                        for (k, v) in sum.iter_mut().enumerate() {
                            *v += raw.value(ri + k);
                        }
                    }
                }
                for (v, s) in o.iter_mut().zip(sum) {
                    *v = s * 0.25;
                }
                *c = 0.25 * n as f32;
            }
        });
    (
        Rgb32FImage::from_raw(nw, nh, buf).expect("sized nw*nh*3"),
        cover,
    )
}

/// One 2x2 box-filter reduction of the `w` x `h` values `raw` of `C` channels.
fn half_size_n<const C: usize, V: Values + ?Sized>(
    raw: &V,
    w: u32,
    h: u32,
    spare: &SpareLevels,
) -> Vec<f32> {
    let (nw, nh) = (w as usize / 2, h as usize / 2);
    let mut buf = spare.take(nw * nh * C);
    let stride = C * w as usize;
    buf.par_chunks_mut((nw * C).max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (r0, r1) = (2 * y * stride, (2 * y + 1) * stride);
            for (x, o) in row.chunks_exact_mut(C).enumerate() {
                let (a, b) = (r0 + 2 * C * x, r1 + 2 * C * x);
                for (k, v) in o.iter_mut().enumerate() {
                    *v = 0.25
                        * (raw.value(a + k)
                            + raw.value(a + C + k)
                            + raw.value(b + k)
                            + raw.value(b + C + k));
                }
            }
        });
    buf
}

/// One 2x2 box-filter reduction of the `w` x `h` RGB values `raw`.
pub(super) fn half_size<V: Values + ?Sized>(
    raw: &V,
    w: u32,
    h: u32,
    spare: &SpareLevels,
) -> Rgb32FImage {
    Rgb32FImage::from_raw(w / 2, h / 2, half_size_n::<3, V>(raw, w, h, spare))
        .expect("sized nw*nh*3")
}

/// Bilinear sample at pixel coordinate (`x`, `y`) (pixel units, centres at integers) of the
/// `w` x `h` values `raw` of `C` channels, clamped at the borders.
#[inline(always)]
fn bilinear_n<const C: usize, V: Values + ?Sized>(
    raw: &V,
    w: u32,
    h: u32,
    x: f64,
    y: f64,
) -> [f32; C] {
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
    let cl = |v: f64, n: u32| (v.max(0.0) as u32).min(n - 1);
    let (xa, xb, ya, yb) = (cl(x0, w), cl(x0 + 1.0, w), cl(y0, h), cl(y0 + 1.0, h));
    let at = |x: u32, y: u32| -> [f32; C] {
        let i = C * (y as usize * w as usize + x as usize);
        std::array::from_fn(|k| raw.value(i + k))
    };
    let (p00, p10) = (at(xa, ya), at(xb, ya));
    let (p01, p11) = (at(xa, yb), at(xb, yb));
    std::array::from_fn(|k| {
        let top = p00[k] + (p10[k] - p00[k]) * fx;
        let bot = p01[k] + (p11[k] - p01[k]) * fx;
        top + (bot - top) * fy
    })
}

/// [`bilinear_n`] of RGB values.
#[inline(always)]
pub(super) fn bilinear_in<V: Values + ?Sized>(raw: &V, w: u32, h: u32, x: f64, y: f64) -> [f32; 3] {
    bilinear_n::<3, V>(raw, w, h, x, y)
}

impl<'a> PhotoPyramid<'a> {
    /// The levels below `base`, at most `levels`, weighted by `mask` if there is one, in
    /// `spare` buffers where there are some.
    pub(super) fn levels_of(
        base: &PhotoPixels,
        mask: Option<&GrayImage>,
        levels: usize,
        spare: &SpareLevels,
    ) -> MipLevels {
        let mask = mask.filter(|m| m.dimensions() == base.dimensions());
        let mut out = MipLevels::default();
        for _ in 0..levels {
            let (w, h) = match out.colour.last() {
                Some(prev) => prev.dimensions(),
                None => base.dimensions(),
            };
            if w < 2 || h < 2 {
                break;
            }
            let next = match out.colour.last() {
                Some(prev) => {
                    if let Some(c) = out.cover.last() {
                        let c = half_size_n::<1, [f32]>(c.as_slice(), w, h, spare);
                        out.cover.push(c);
                    }
                    half_size(prev.as_raw().as_slice(), w, h, spare)
                }
                None => match (base, mask) {
                    (PhotoPixels::Rgb8(img), Some(m)) => {
                        let (c, cover) = half_size_masked(img.as_raw().as_slice(), m, w, h, spare);
                        out.cover.push(cover);
                        c
                    }
                    (PhotoPixels::Rgb32F(img), Some(m)) => {
                        let (c, cover) = half_size_masked(img.as_raw().as_slice(), m, w, h, spare);
                        out.cover.push(cover);
                        c
                    }
                    (PhotoPixels::Rgb8(img), None) => {
                        half_size(img.as_raw().as_slice(), w, h, spare)
                    }
                    (PhotoPixels::Rgb32F(img), None) => {
                        half_size(img.as_raw().as_slice(), w, h, spare)
                    }
                },
            };
            out.colour.push(next);
        }
        out
    }

    /// Bilinear sample at photo pixel coordinate `px` (centres at +0.5) of level `l`.
    pub(super) fn bilinear(&self, l: usize, px: &Point2<f64>) -> [f32; 3] {
        let l = l.min(self.levels.colour.len());
        let f = (1u32 << l) as f64;
        let (x, y) = (px.x / f - 0.5, px.y / f - 0.5);
        if l > 0 {
            let img = &self.levels.colour[l - 1];
            let (w, h) = img.dimensions();
            let c = bilinear_in(img.as_raw().as_slice(), w, h, x, y);
            let Some(cover) = self.levels.cover.get(l - 1) else {
                return c;
            };
            let [a] = bilinear_n::<1, [f32]>(cover.as_slice(), w, h, x, y);
            // No object pixel under the taps (only where the level's grid leaves the base's
            // last row or column): the base sample, which the mask test passed.
            if a < 1e-6 {
                return self.bilinear(0, px);
            }
            return c.map(|v| v / a);
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
    pub(super) fn sample(&self, px: &Point2<f64>, footprint: f64) -> [f32; 3] {
        // Most texels are finer than a pixel (the atlas oversamples the photographs): level 0,
        // as the logarithm below would say (NaN included), without computing it for each.
        if footprint.is_nan() || footprint <= 1.0 {
            return self.bilinear(0, px);
        }
        let lod = footprint.log2().min(self.levels.colour.len() as f64);
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

/// The object mask as the bilinear sample sees it: a pixel is object (255) where it and its
/// right, lower and lower-right neighbours (clamped at the image's edge) all are, i.e. where a
/// sample whose first tap it is reads no background. A sample that reads one background
/// pixel carries background colour, which at a grazing angle, where a pixel spans several
/// texels, shows as bright streaks along the object's outline. Built once per photograph so
/// that the texel loop looks up one byte.
pub(super) fn tap_mask(m: &GrayImage) -> GrayImage {
    let (w, h) = (m.width() as usize, m.height() as usize);
    let src = m.as_raw();
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let (a, b) = (
                &src[y * w..(y + 1) * w],
                &src[(y + 1).min(h - 1) * w..][..w],
            );
            for x in 0..w {
                let x1 = (x + 1).min(w - 1);
                let object = a[x] >= 128 && a[x1] >= 128 && b[x] >= 128 && b[x1] >= 128;
                row[x] = if object { 255 } else { 0 };
            }
        });
    GrayImage::from_raw(m.width(), m.height(), out).expect("sized w*h")
}

/// Whether the bilinear sample at `px` (pixel centres at +0.5) reads object pixels only,
/// given the photograph's [`tap_mask`] `taps`. (At the image's left and top edge, where the
/// first tap is clamped, it reads one pixel more than the sample: conservative.)
pub(super) fn mask_holds(taps: &GrayImage, px: &Point2<f64>) -> bool {
    let (w, h) = (taps.width() as f64, taps.height() as f64);
    if !(px.x >= 0.0 && px.y >= 0.0 && px.x < w && px.y < h) {
        return false;
    }
    let x0 = (px.x - 0.5).floor().max(0.0) as usize;
    let y0 = (px.y - 0.5).floor().max(0.0) as usize;
    taps.as_raw()[y0 * taps.width() as usize + x0] >= 128
}

/// Largest pixel extent of a triangle resampled through an affine texel -> pixel map.
pub(super) const AFFINE_PX: f64 = 8.0;

/// Largest pixel extent of a triangle resampled through an affine map if it passes the
/// centroid test.
pub(super) const AFFINE_MAX_PX: f64 = 64.0;

/// Largest error of an affine map at a triangle's test points, pixels.
pub(super) const AFFINE_TOL: f64 = 0.02;

/// Whether texels of the triangle `pos` (projected to `q` by `view`) may map to pixels
/// affinely: always when it spans under [`AFFINE_PX`] pixels; up to [`AFFINE_MAX_PX`] where
/// the map's error (perspective and distortion) is under [`AFFINE_TOL`] pixels at the
/// centroid and the edge midpoints.
pub(super) fn affine_fits(
    view: &PosedCamera,
    pos: &[Point3<f64>; 3],
    q: &[Point2<f64>; 3],
) -> bool {
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

/// Stage 3's photograph sampling, the interface every way of combining photographs uses
/// (`--merge none|average` in [`super::resample`], multiband in [`crate::merge`]): the per-face
/// work done once (triangle classes, the photographs each face samples, filled vertex colours),
/// then per photograph a [`PhotoSampler`] and, per face, [`Sampler::sample_face`]: texel
/// samples (gain-corrected colour) and their weights.
pub struct Sampler<'a> {
    pub(super) mesh: &'a Mesh,
    pub(super) normals: &'a [Vector3<f64>],
    pub(super) binding: &'a Binding,
    pub(super) gains: &'a Gains,
    pub(super) atlas: &'a Atlas,
    pub(super) classes: Vec<FaceClass>,
    pub(super) common: Common,
    pub(super) vertex_colors: Vec<[f32; 3]>,
    pub(super) filled_per_round: [u64; 5],
    pub(super) vertices_unreachable: u64,
    pub(super) mean_edge: f64,
    pub(super) robust: bool,
    pub(super) identity: bool,
}

/// What [`Sampler::photo_setup`] computes for a photograph (owned, so that it can be built
/// beside the work on the previous photograph).
pub struct PhotoSetup {
    pub(super) depth: Option<DepthMap>,
    pub(super) levels: MipLevels,
    pub(super) taps: Option<GrayImage>,
    pub(super) projected: Vec<Option<[f64; 3]>>,
    pub(super) sampled: Vec<u64>,
    /// Seconds it took.
    pub seconds: f64,
}

/// One photograph ready to be sampled: its projected vertices, depth map, mip pyramid and
/// the faces that sample it.
pub struct PhotoSampler<'a> {
    pub(super) index: usize,
    pub(super) view: &'a PosedCamera,
    pub(super) depth: Option<DepthMap>,
    /// Every vertex projected: photo pixel and camera depth (shared with the depth map).
    pub(super) projected: Vec<Option<[f64; 3]>>,
    /// Bit per face: whether the face samples this photograph ([`Sampler::samples`]).
    pub(super) sampled: Vec<u64>,
    pub(super) pyramid: PhotoPyramid<'a>,
    /// The object mask's [`tap_mask`], if the photograph has a mask.
    pub(super) taps: Option<GrayImage>,
    pub(super) centre: Point3<f64>,
    pub(super) focal: f64,
}

impl PhotoSampler<'_> {
    /// The photograph's index in the photo list.
    pub fn index(&self) -> usize {
        self.index
    }

    /// Whether face `f` samples this photograph.
    #[inline]
    pub fn samples(&self, f: u32) -> bool {
        self.sampled[f as usize / 64] >> (f % 64) & 1 == 1
    }
}

impl<'a> Sampler<'a> {
    /// Checks the inputs and does the per-face work for `atlas`.
    pub fn new(
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
            return Err(Error::Internal(
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
        Ok(Sampler {
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

    /// The mesh being sampled.
    pub fn mesh(&self) -> &'a Mesh {
        self.mesh
    }

    /// The binding the samples follow.
    pub fn binding(&self) -> &'a Binding {
        self.binding
    }

    /// The atlas being filled.
    pub fn atlas(&self) -> &'a Atlas {
        self.atlas
    }

    /// Atlas side in texels.
    pub fn size(&self) -> usize {
        self.atlas.texels.size
    }

    /// Face owning texel `i` (row-major), if any.
    pub fn owner(&self, i: usize) -> Option<u32> {
        self.atlas.owner(i)
    }

    /// The photographs face `f` samples, ascending.
    pub fn photos_of(&self, f: usize) -> &[u32] {
        self.common.of(f)
    }

    /// Whether face `f` samples photograph `photo`.
    pub fn samples(&self, f: usize, photo: u32) -> bool {
        self.common.of(f).binary_search(&photo).is_ok()
    }

    /// Which of `n` photographs some face on this page samples: the others have nothing to
    /// give the page and need not be decoded for it.
    pub fn photos_on_page(&self, n: usize) -> Vec<bool> {
        (0..self.mesh.num_faces())
            .into_par_iter()
            .filter(|&f| self.atlas.face_rect(f).is_some())
            .fold(
                || vec![false; n],
                |mut w, f| {
                    for &p in self.common.of(f) {
                        w[p as usize] = true;
                    }
                    w
                },
            )
            .reduce(
                || vec![false; n],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x |= y);
                    a
                },
            )
    }

    /// Texel rows and columns (inclusive) face `f` may own, if it lies on the page.
    pub fn face_rect(&self, f: usize) -> Option<((usize, usize), (usize, usize))> {
        self.atlas.face_rect(f)
    }

    /// The part of getting photograph `pi` (decoded as `rgb`, with its `mask`) ready to
    /// sample that takes time: its projected vertices, depth map, mip levels, mask taps and
    /// the faces that sample it, owned, so that it can run beside the work on the previous
    /// photograph. The mip levels reuse `spare` buffers of photographs already sampled.
    pub fn photo_setup(
        &self,
        photos: &[Photo],
        pi: usize,
        rgb: &PhotoPixels,
        mask: Option<&GrayImage>,
        spare: &SpareLevels,
    ) -> PhotoSetup {
        let view = &photos[pi].view;
        let t = std::time::Instant::now();
        let projected = crate::depth::project_vertices(self.mesh, view);
        let depth = self.robust.then(|| {
            let res = self.binding.options.depth_resolution;
            DepthMap::render_projected(self.mesh, view, &projected, res).eroded(1)
        });
        let levels = PhotoPyramid::levels_of(rgb, mask, if self.robust { 8 } else { 0 }, spare);
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
            taps: mask.map(tap_mask),
            projected,
            sampled,
            seconds: t.elapsed().as_secs_f64(),
        }
    }

    /// Photograph `pi` (decoded as `rgb`) ready to sample, from its `setup`.
    pub fn photo_with(
        &self,
        photos: &'a [Photo],
        pi: usize,
        rgb: &'a PhotoPixels,
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
            taps: setup.taps,
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
    pub fn sample_face(
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
                    if let Some(m) = &ph.taps {
                        if !mask_holds(m, &px) {
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
    pub fn vertex_color_at(&self, f: u32, x: usize, y: usize) -> [f32; 3] {
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
    pub fn fallback_source(&self, f: u32) -> TexelSource {
        match self.classes[f as usize] {
            FaceClass::Green => TexelSource::GreenFallback,
            FaceClass::Blue => TexelSource::Blue,
            FaceClass::Red => TexelSource::Red,
        }
    }

    /// Fills the gutter and counts: the last step of every merge.
    pub fn finish(
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
