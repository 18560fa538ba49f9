//! Stage 2, binding (paper section 4.1, `docs/method.md` section 2): for every vertex, the
//! photographs that may colour it, each with the vertex's colour in that photograph and a
//! weight. In: a mesh, its vertex normals, the registered photographs. Out: [`Binding`].
//!
//! A photograph is valid for a vertex when the vertex projects inside it (through the camera's
//! distortion), its normal faces the camera, nothing occludes it, it is not a silhouette vertex
//! (a fan triangle faces away), and it does not show background there (masks when the scene
//! has them; otherwise the paper's median-filtered, Gaussian-weighted comparison with the
//! background colour, estimated per photograph). [`Method::Robust`] adds a photo-consistency
//! check across the valid photographs of each vertex and weights that prefer close, frontal
//! views; [`Method::Paper`] is the paper as written.
//!
//! Photographs are decoded one at a time (the next one decodes while the current one is
//! processed), so memory does not grow with their number.

use crate::depth::{focal_px, project_vertices_into, DepthMap};
use crate::error::{Error, Result};
use crate::io::image::PhotoPixels;
use crate::mesh::{FaceId, Mesh};
use crate::photos::for_each_photo;
use crate::progress::Progress;
use crate::scene::Photo;
use nalgebra::{Point2, Vector3};
use rayon::prelude::*;
use serde::Serialize;

/// Which variant of binding and resampling runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The paper as written: per-vertex visibility (segment to the camera against a BVH), the
    /// mean of the common photographs weighted by `<N, V>`, bilinear photo samples.
    Paper,
    /// Per-texel occlusion from a depth map per photograph, weights by the texel's projected
    /// area in the photograph (closer and more frontal views count more), photo-consistency
    /// rejection of outlying views per vertex, mip-mapped photo samples. Default.
    #[default]
    Robust,
}

impl std::fmt::Display for Method {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Paper => "paper",
            Method::Robust => "robust",
        })
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "paper" => Ok(Method::Paper),
            "robust" => Ok(Method::Robust),
            _ => Err(format!("unknown method '{s}' (expected paper or robust)")),
        }
    }
}

/// How the background colour for the paper's background test is found.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Background {
    /// The median colour of the pixels the mesh does not cover, per photograph; the test is
    /// skipped for a photograph whose uncovered pixels are not uniform (their median distance
    /// from that colour exceeds [`BindOptions::background_max_spread`]). Default.
    #[default]
    Estimate,
    /// One colour (RGB in [0, 1]) for every photograph.
    Color([f32; 3]),
    /// No background test.
    Off,
}

impl std::fmt::Display for Background {
    /// The text `from_str` reads: `auto`, `off` or `r,g,b`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Background::Estimate => f.write_str("auto"),
            Background::Off => f.write_str("off"),
            Background::Color([r, g, b]) => write!(f, "{r},{g},{b}"),
        }
    }
}

impl std::str::FromStr for Background {
    type Err = String;
    /// `auto` (estimated per photograph), `off`, or a colour `r,g,b`.
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "auto" => return Ok(Background::Estimate),
            "off" => return Ok(Background::Off),
            _ => {}
        }
        let v: Vec<f32> = s
            .split(',')
            .map(|t| {
                t.trim().parse::<f32>().map_err(|_| {
                    format!(
                        "'{}' is not a number (background: auto, off or r,g,b)",
                        t.trim()
                    )
                })
            })
            .collect::<std::result::Result<_, _>>()?;
        // The range is checked by BindOptions::validate, which names the option.
        match v.as_slice() {
            [r, g, b] => Ok(Background::Color([*r, *g, *b])),
            _ => Err(format!(
                "background '{s}': expected auto, off or three numbers r,g,b"
            )),
        }
    }
}

/// Where the robust method's photo-consistency check applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Consistency {
    /// Per face: the face's colour in each candidate photograph (mean of its corners'
    /// samples) against the median over those photographs; an outlying photograph stops
    /// colouring that face only.
    Face,
    /// Per vertex: an outlying photograph is dropped from the vertex's valid set (and so from
    /// the gains solve, the vertex colours and every face around it). Default: measured best
    /// with and without passers-by (benches/passerby.py).
    #[default]
    Vertex,
    /// No check.
    Off,
}

impl std::fmt::Display for Consistency {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Consistency::Face => "face",
            Consistency::Vertex => "vertex",
            Consistency::Off => "off",
        })
    }
}

impl std::str::FromStr for Consistency {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "face" => Ok(Consistency::Face),
            "vertex" => Ok(Consistency::Vertex),
            "off" => Ok(Consistency::Off),
            _ => Err(format!(
                "unknown consistency check '{s}' (expected face, vertex or off)"
            )),
        }
    }
}

/// Options for [`bind`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BindOptions {
    /// Paper or robust. Default: [`Method::Robust`].
    pub method: Method,
    /// Smallest cosine between a vertex normal and the direction to the camera for the vertex
    /// to face it. Default: 0.0 (the paper: facing at all).
    pub min_cos: f64,
    /// Background colour. Default: [`Background::Estimate`].
    pub background: Background,
    /// RGB distance (values in [0, 1]) below which a vertex's filtered sample counts as
    /// background. Default: 0.06.
    pub background_threshold: f32,
    /// Estimated backgrounds whose pixels spread more than this (median RGB distance from
    /// their median colour) are not uniform and are not used. Default: 0.05.
    pub background_max_spread: f32,
    /// Robust method only: the background test applies only within this many photo pixels of
    /// the mesh's outline in the photograph, where registration errors put background under
    /// the surface; elsewhere a dark object on a dark background would lose its vertices.
    /// Default: 8.
    pub background_reach: u32,
    /// Robust method only: where the photo-consistency check applies. Default: per vertex.
    pub consistency: Consistency,
    /// Robust method only: a view whose colour is farther than this (RGB distance) and than 3
    /// robust standard deviations from the median of the views is dropped (moving people,
    /// highlights). Needs at least 3 views. Default: 0.12.
    pub consistency_threshold: f32,
    /// Robust method only: exponent on the projected-area weight; higher favours the single
    /// best view (sharper, less blur from misregistration). Default: 1.0.
    pub weight_power: f64,
    /// Longest side of the per-photograph depth map, pixels. Default: 2048.
    pub depth_resolution: u32,
    /// The most views a vertex keeps, the heaviest (ties: the earlier photograph); 0 keeps
    /// every view. The binding then holds at most this many 20-byte views per vertex however
    /// many photographs there are (resampling uses at most 12 per face). Default: 32.
    pub max_views: usize,
}

impl Default for BindOptions {
    fn default() -> Self {
        BindOptions {
            method: Method::Robust,
            min_cos: 0.0,
            background: Background::Estimate,
            background_threshold: 0.06,
            background_max_spread: 0.05,
            background_reach: 8,
            consistency: Consistency::Vertex,
            consistency_threshold: 0.12,
            weight_power: 1.0,
            depth_resolution: 2048,
            max_views: 32,
        }
    }
}

/// View-weight exponents [`BindOptions::validate`] accepts.
pub const WEIGHT_POWER_RANGE: std::ops::RangeInclusive<f64> = 0.0..=8.0;
/// Depth-map sides (pixels) [`BindOptions::validate`] accepts.
pub const DEPTH_RESOLUTION_RANGE: std::ops::RangeInclusive<u32> = 64..=16384;

impl BindOptions {
    /// Checks ranges; the error names the option.
    pub fn validate(&self) -> Result<()> {
        let bad = |o: &'static str, m: String| Err(Error::option(o, m));
        if !(-1.0..1.0).contains(&self.min_cos) {
            return bad("min_cos", format!("{} must lie in [-1, 1)", self.min_cos));
        }
        if !(self.background_threshold >= 0.0 && self.background_threshold.is_finite()) {
            return bad(
                "background_threshold",
                format!(
                    "background threshold {} must be a non-negative number",
                    self.background_threshold
                ),
            );
        }
        if let Background::Color(c) = self.background {
            if !c.iter().all(|v| (0.0..=1.0).contains(v)) {
                return bad(
                    "background",
                    format!("background colour {c:?} must lie in [0, 1]"),
                );
            }
        }
        if !(self.consistency_threshold >= 0.0 && self.consistency_threshold.is_finite()) {
            return bad(
                "consistency_threshold",
                format!(
                    "consistency threshold {} must be a non-negative number",
                    self.consistency_threshold
                ),
            );
        }
        if !WEIGHT_POWER_RANGE.contains(&self.weight_power) {
            return bad(
                "weight_power",
                format!("weight power {} must lie in [0, 8]", self.weight_power),
            );
        }
        if !DEPTH_RESOLUTION_RANGE.contains(&self.depth_resolution) {
            return bad(
                "depth_resolution",
                format!(
                    "depth resolution {} must lie in 64..=16384",
                    self.depth_resolution
                ),
            );
        }
        Ok(())
    }
}

/// One valid photograph of one vertex.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ViewSample {
    /// Index into the photograph list given to [`bind`].
    pub photo: u32,
    /// The vertex's colour in that photograph (3x3 Gaussian-weighted sample), RGB in [0, 1].
    pub color: [f32; 3],
    /// The view's weight for this vertex (`<N, V>` for the paper; projected area for robust).
    pub weight: f32,
}

/// Why vertex-photograph pairs were rejected, counted over all pairs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Rejections {
    /// Projects outside the image or behind the camera.
    pub outside: u64,
    /// Normal faces away from the camera.
    pub facing: u64,
    /// A fan triangle faces away (silhouette vertex).
    pub silhouette: u64,
    /// Something nearer hides it.
    pub occluded: u64,
    /// The mask says background.
    pub mask: u64,
    /// The filtered colour matches the background colour.
    pub background: u64,
    /// Disagrees with the vertex's other views (robust only).
    pub inconsistent: u64,
    /// Valid, but lighter than the vertex's [`BindOptions::max_views`] heaviest views.
    pub lighter: u64,
    /// Valid pairs kept.
    pub kept: u64,
}

impl Rejections {
    fn add(&mut self, o: &Rejections) {
        self.outside += o.outside;
        self.facing += o.facing;
        self.silhouette += o.silhouette;
        self.occluded += o.occluded;
        self.mask += o.mask;
        self.background += o.background;
        self.inconsistent += o.inconsistent;
        self.lighter += o.lighter;
        self.kept += o.kept;
    }
}

/// What each photograph contributed to the binding.
#[derive(Debug, Clone, Serialize)]
pub struct PhotoBinding {
    /// Photograph name.
    pub name: String,
    /// Vertices it is valid for.
    pub vertices: u64,
    /// Background colour used for it, if any.
    pub background: Option<[f32; 3]>,
    /// Whether an object mask (a mask file, or the photograph's alpha channel where it hides
    /// pixels) decided where it shows the object.
    pub masked: bool,
}

/// The valid photographs of every vertex, in compressed rows (`samples[offsets[v]..offsets[v +
/// 1]]`, in photograph order).
#[derive(Debug, Clone)]
pub struct Binding {
    /// Row starts, one per vertex plus one.
    pub offsets: Vec<u32>,
    /// Valid views, grouped by vertex.
    pub samples: Vec<ViewSample>,
    /// Number of photographs bound against.
    pub photos: usize,
    /// Rejection counts.
    pub rejections: Rejections,
    /// Per-photograph summary.
    pub per_photo: Vec<PhotoBinding>,
    /// The options the binding was made with (resampling follows the same method, depth
    /// resolution and consistency rule).
    pub options: BindOptions,
}

impl Binding {
    /// A binding from compressed rows (`offsets` one per vertex plus one) over `photos`
    /// photographs, with default options and no rejections recorded.
    pub fn from_samples(offsets: Vec<u32>, samples: Vec<ViewSample>, photos: usize) -> Binding {
        Binding {
            offsets,
            samples,
            photos,
            rejections: Rejections::default(),
            per_photo: Vec::new(),
            options: BindOptions::default(),
        }
    }

    /// Valid views of vertex `v`.
    pub fn views(&self, v: usize) -> &[ViewSample] {
        &self.samples[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }

    /// Vertices with at least one valid view.
    pub fn bound_vertices(&self) -> usize {
        self.offsets.windows(2).filter(|w| w[1] > w[0]).count()
    }

    /// Weighted mean colour of each vertex over its valid views (`None` when unbound).
    pub fn vertex_colors(&self) -> Vec<Option<[f32; 3]>> {
        (0..self.offsets.len() - 1)
            .map(|v| {
                let vs = self.views(v);
                let w: f32 = vs.iter().map(|s| s.weight).sum();
                if vs.is_empty() {
                    None
                } else if w > 0.0 {
                    Some(std::array::from_fn(|k| {
                        vs.iter().map(|s| s.color[k] * s.weight).sum::<f32>() / w
                    }))
                } else {
                    Some(std::array::from_fn(|k| {
                        vs.iter().map(|s| s.color[k]).sum::<f32>() / vs.len() as f32
                    }))
                }
            })
            .collect()
    }
}

/// Faces around each vertex, compressed rows.
pub(crate) struct VertexFaces {
    offsets: Vec<u32>,
    faces: Vec<u32>,
}

impl VertexFaces {
    pub(crate) fn new(mesh: &Mesh) -> Self {
        let nv = mesh.num_vertices();
        let mut offsets = vec![0u32; nv + 1];
        for f in &mesh.faces {
            for v in f {
                offsets[v.idx() + 1] += 1;
            }
        }
        for i in 0..nv {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut faces = vec![0u32; offsets[nv] as usize];
        for (fi, f) in mesh.faces.iter().enumerate() {
            for v in f {
                faces[fill[v.idx()] as usize] = fi as u32;
                fill[v.idx()] += 1;
            }
        }
        VertexFaces { offsets, faces }
    }

    pub(crate) fn of(&self, v: usize) -> &[u32] {
        &self.faces[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }
}

/// 3x3 Gaussian weights (1 2 1 / 2 4 2 / 1 2 1) / 16.
const GAUSS3: [f32; 9] = [1.0, 2.0, 1.0, 2.0, 4.0, 2.0, 1.0, 2.0, 1.0];

fn pixel(img: &PhotoPixels, x: i64, y: i64) -> [f32; 3] {
    let x = x.clamp(0, img.width() as i64 - 1) as u32;
    let y = y.clamp(0, img.height() as i64 - 1) as u32;
    img.get(x, y)
}

/// 3x3 Gaussian-weighted colour around the pixel holding `px`.
pub(crate) fn gauss_sample(img: &PhotoPixels, px: &Point2<f64>) -> [f32; 3] {
    let (cx, cy) = (px.x.floor() as i64, px.y.floor() as i64);
    let mut acc = [0.0f32; 3];
    for (i, w) in GAUSS3.iter().enumerate() {
        let p = pixel(img, cx + (i % 3) as i64 - 1, cy + (i / 3) as i64 - 1);
        for k in 0..3 {
            acc[k] += p[k] * w / 16.0;
        }
    }
    acc
}

/// The paper's background sample: the photograph median-filtered (3x3, per channel), then
/// sampled with the 3x3 Gaussian around `px`.
fn median_gauss_sample(img: &PhotoPixels, px: &Point2<f64>) -> [f32; 3] {
    let (cx, cy) = (px.x.floor() as i64, px.y.floor() as i64);
    let mut acc = [0.0f32; 3];
    for (i, w) in GAUSS3.iter().enumerate() {
        let (x, y) = (cx + (i % 3) as i64 - 1, cy + (i / 3) as i64 - 1);
        for (k, a) in acc.iter_mut().enumerate() {
            let mut v: [f32; 9] = std::array::from_fn(|j| {
                pixel(img, x + (j % 3) as i64 - 1, y + (j / 3) as i64 - 1)[k]
            });
            v.sort_unstable_by(f32::total_cmp);
            *a += v[4] * w / 16.0;
        }
    }
    acc
}

pub(crate) fn dist(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

pub(crate) fn median(v: &mut [f32]) -> f32 {
    v.sort_unstable_by(f32::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median colour of the uncovered pixels and their spread, if there are enough of them.
fn estimate_background(img: &PhotoPixels, depth: &DepthMap) -> Option<([f32; 3], f32)> {
    let step = (depth.width.max(depth.height) / 256).clamp(1, 8);
    let pts = depth.uncovered(step);
    // Fewer than 1% of the sampled grid: the mesh fills the frame, no background to learn.
    let grid = (depth.width / step).max(1) as usize * (depth.height / step).max(1) as usize;
    if pts.len() * 100 < grid {
        return None;
    }
    let cols: Vec<[f32; 3]> = pts.iter().map(|p| gauss_sample(img, p)).collect();
    let med: [f32; 3] = std::array::from_fn(|k| {
        let mut c: Vec<f32> = cols.iter().map(|c| c[k]).collect();
        median(&mut c)
    });
    let mut d: Vec<f32> = cols.iter().map(|c| dist(c, &med)).collect();
    Some((med, median(&mut d)))
}

/// Stage 2: binds every vertex of `mesh` to its valid photographs. `normals` are unit vertex
/// normals (same length as the vertices); photographs are decoded one at a time.
pub fn bind(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    photos: &[Photo],
    opts: &BindOptions,
    progress: &dyn Progress,
) -> Result<Binding> {
    opts.validate()?;
    if photos.len() > u32::MAX as usize {
        return Err(Error::Invalid("too many photographs".into()));
    }
    let nv = mesh.num_vertices();
    let vf = VertexFaces::new(mesh);
    let face_n: Vec<Vector3<f64>> = (0..mesh.num_faces())
        .into_par_iter()
        .map(|f| mesh.face_normal_area(FaceId(f as u32)))
        .collect();
    let mean_edge = mesh.mean_edge_length();
    // The paper's segment test needs a BVH; the robust method reads its depth maps instead.
    let rays = (opts.method == Method::Paper).then(|| crate::raycast::RayMesh::new(mesh));
    let mut slots = ViewSlots::new(nv, opts.max_views, photos.len())?;
    let mut rejections = Rejections::default();
    let mut per_photo = Vec::with_capacity(photos.len());
    // Each photograph's projected vertices, for its depth map and its vertex tests.
    let mut projected = Vec::new();
    // The depth maps' buffers, from one photograph to the next (a render takes at most
    // MAX_PARTS).
    let mut spare_depth = crate::memory::SpareBuffers::new(crate::depth::MAX_PARTS);
    progress.start("binding", photos.len() as u64);
    for_each_photo(photos, progress, |pi, rgb, mask| {
        let view = &photos[pi].view;
        project_vertices_into(mesh, view, &mut projected);
        let depth = DepthMap::render_projected_reusing(
            mesh,
            view,
            &projected,
            opts.depth_resolution,
            &mut spare_depth,
        );
        let background = match (mask, opts.background) {
            (Some(_), _) | (None, Background::Off) => None,
            (None, Background::Color(c)) => Some(c),
            (None, Background::Estimate) => estimate_background(rgb, &depth)
                .filter(|(_, spread)| *spread <= opts.background_max_spread)
                .map(|(c, _)| c),
        };
        let centre = view.pose.center();
        let focal = focal_px(view);
        let reach = (opts.background_reach as f64 * depth.scale).ceil().max(1.0) as u32;
        // The tests of one vertex against this photograph, in order; the first that fails
        // is counted.
        let test = |v: usize, rej: &mut Rejections| -> Option<ViewSample> {
            let p = mesh.positions[v];
            let px = projected[v]
                .map(|[x, y, z]| (Point2::new(x, y), z))
                .filter(|(px, _)| view.camera.contains(px));
            let Some((px, cam_z)) = px else {
                rej.outside += 1;
                return None;
            };
            let to_cam = centre - p;
            let dist_cam = to_cam.norm();
            let dir = to_cam / dist_cam.max(1e-300);
            let cos = normals[v].dot(&dir);
            if cos.is_nan() || cos <= opts.min_cos {
                rej.facing += 1;
                return None;
            }
            if vf
                .of(v)
                .iter()
                .any(|&f| face_n[f as usize].dot(&to_cam) <= 0.0)
            {
                rej.silhouette += 1;
                return None;
            }
            let eps = 1e-3 * mean_edge + 1e-9 * dist_cam;
            let occluded = match &rays {
                Some(r) => r
                    .intersect(&centre, &(-dir))
                    .is_some_and(|h| h.t < dist_cam - eps),
                None => {
                    let z = depth.at(&px) as f64;
                    cam_z > z + depth_tolerance(mean_edge, cam_z, focal * depth.scale, cos)
                }
            };
            if occluded {
                rej.occluded += 1;
                return None;
            }
            if let Some(m) = mask {
                let (x, y) = (px.x.floor() as i64, px.y.floor() as i64);
                let object = (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| {
                        let xx = (x + dx).clamp(0, m.width() as i64 - 1) as u32;
                        let yy = (y + dy).clamp(0, m.height() as i64 - 1) as u32;
                        m.get_pixel(xx, yy).0[0] >= 128
                    })
                });
                if !object {
                    rej.mask += 1;
                    return None;
                }
            } else if let Some(bg) = background {
                let test = opts.method == Method::Paper || depth.near_outline(&px, reach);
                if test && dist(&median_gauss_sample(rgb, &px), &bg) < opts.background_threshold {
                    rej.background += 1;
                    return None;
                }
            }
            let weight = match opts.method {
                Method::Paper => cos,
                // Projected area of a mean-edge square in pixels, times the cosine.
                Method::Robust => {
                    (cos * (focal * mean_edge / cam_z).powi(2)).powf(opts.weight_power)
                }
            };
            Some(ViewSample {
                photo: pi as u32,
                color: gauss_sample(rgb, &px),
                weight: weight as f32,
            })
        };
        let (rej, evicted) = slots
            .rows_mut()
            .enumerate()
            .fold(
                || (Rejections::default(), Vec::new()),
                |(mut rej, mut evicted), (v, (row, count))| {
                    if let Some(s) = test(v, &mut rej) {
                        match offer(row, count, s) {
                            Offer::Added => rej.kept += 1,
                            Offer::Replaced(p) => {
                                rej.kept += 1;
                                rej.lighter += 1;
                                if evicted.is_empty() {
                                    evicted = vec![0u64; photos.len()];
                                }
                                evicted[p as usize] += 1;
                            }
                            Offer::Lighter => rej.lighter += 1,
                        }
                    }
                    (rej, evicted)
                },
            )
            .reduce(
                || (Rejections::default(), Vec::new()),
                |(mut ra, mut a), (rb, b)| {
                    ra.add(&rb);
                    if a.is_empty() {
                        a = b;
                    } else {
                        a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    }
                    (ra, a)
                },
            );
        // The views this photograph gave that are still kept; those it pushed out of
        // earlier photographs' counts.
        let evicted_total: u64 = evicted.iter().sum();
        per_photo.push(PhotoBinding {
            name: photos[pi].name.clone(),
            vertices: rej.kept,
            background,
            masked: mask.is_some(),
        });
        for (p, e) in per_photo.iter_mut().zip(&evicted) {
            p.vertices -= e;
        }
        rejections.add(&rej);
        rejections.kept -= evicted_total;
        spare_depth.put([depth.z]);
        Ok(())
    })?;
    progress.finish();
    let (offsets, samples) = slots.into_rows();
    let mut binding = Binding {
        offsets,
        samples,
        photos: photos.len(),
        rejections,
        per_photo,
        options: *opts,
    };
    if opts.method == Method::Robust && opts.consistency == Consistency::Vertex {
        drop_inconsistent(&mut binding, opts.consistency_threshold);
    }
    Ok(binding)
}

/// Depth slack for "the same surface": half a mean edge (rasterised depth is linear across a
/// triangle, the surface point is not exactly on it) plus the depth change across two depth
/// pixels on a surface seen at `cos` (grazing views change depth fast).
pub(crate) fn depth_tolerance(mean_edge: f64, z: f64, focal_depth_px: f64, cos: f64) -> f64 {
    0.5 * mean_edge + 2.0 * z / focal_depth_px / cos.max(0.1)
}

/// Which of `colors` (one per view) agree with the others: all of them with fewer than 3.
/// Exposure, white balance and shading differ between photographs by a factor, which is not
/// disagreement: each colour is first scaled to the median brightness, then compared with the
/// per-channel median; a view is out when that distance exceeds both `threshold` and 3 robust
/// standard deviations (1.4826 x median distance), or when its brightness is more than
/// [`BRIGHTNESS_RATIO`] times off the median's.
pub(crate) fn consistent(colors: &[[f32; 3]], threshold: f32) -> Vec<bool> {
    if colors.len() < 3 {
        return vec![true; colors.len()];
    }
    let lum: Vec<f32> = colors
        .iter()
        .map(|c| (c[0] + c[1] + c[2]) / 3.0 + 1e-3)
        .collect();
    let mut l = lum.clone();
    let lmed = median(&mut l);
    let scaled: Vec<[f32; 3]> = colors
        .iter()
        .zip(&lum)
        .map(|(c, l)| c.map(|v| v * lmed / l))
        .collect();
    let med: [f32; 3] = std::array::from_fn(|k| {
        let mut c: Vec<f32> = scaled.iter().map(|c| c[k]).collect();
        median(&mut c)
    });
    let d: Vec<f32> = scaled.iter().map(|c| dist(c, &med)).collect();
    let mut dd = d.clone();
    let limit = (3.0 * 1.4826 * median(&mut dd)).max(threshold);
    d.iter()
        .zip(&lum)
        .map(|(&x, &l)| x <= limit && (l / lmed).ln().abs() <= BRIGHTNESS_RATIO.ln())
        .collect()
}

/// Brightness factor between a view and the median of the views beyond which the view is an
/// outlier (a highlight, a shadow cast by a passer-by): wider than exposure and shading
/// differences between photographs usually are.
const BRIGHTNESS_RATIO: f32 = 2.5;

/// The views binding keeps while the photographs come: `stride` slots per vertex holding its
/// heaviest views so far, so that memory is fixed before the first photograph whatever their
/// number (a list of pairs cut now and then peaked at four times the kept views).
struct ViewSlots {
    stride: usize,
    counts: Vec<u32>,
    slots: Vec<ViewSample>,
}

impl ViewSlots {
    /// Slots for `nv` vertices keeping at most `max_views` each (0: every view) of `photos`.
    fn new(nv: usize, max_views: usize, photos: usize) -> Result<ViewSlots> {
        let stride = match max_views {
            0 => photos,
            k => k.min(photos),
        }
        .max(1);
        let total = nv
            .checked_mul(stride)
            .filter(|&t| t <= u32::MAX as usize)
            .ok_or_else(|| {
                Error::option(
                    "vertex_views",
                    format!(
                        "{nv} vertices x {stride} views per vertex is more than the binding's \
                         2^32 views; lower --vertex-views"
                    ),
                )
            })?;
        Ok(ViewSlots {
            stride,
            counts: vec![0; nv],
            slots: vec![ViewSample::default(); total],
        })
    }

    /// Each vertex's slots and count, for one photograph's parallel pass.
    fn rows_mut(
        &mut self,
    ) -> impl IndexedParallelIterator<Item = (&mut [ViewSample], &mut u32)> + '_ {
        self.slots
            .par_chunks_mut(self.stride)
            .zip(self.counts.par_iter_mut())
    }

    /// Compressed rows (offsets, views), each row in photograph order.
    fn into_rows(self) -> (Vec<u32>, Vec<ViewSample>) {
        let ViewSlots {
            stride,
            counts,
            mut slots,
        } = self;
        slots
            .par_chunks_mut(stride)
            .zip(&counts)
            .for_each(|(row, &c)| row[..c as usize].sort_unstable_by_key(|s| s.photo));
        let mut offsets = Vec::with_capacity(counts.len() + 1);
        let mut end = 0u32;
        offsets.push(end);
        for (v, &c) in counts.iter().enumerate() {
            // Rows only move down (end <= v * stride), so in place.
            slots.copy_within(v * stride..v * stride + c as usize, end as usize);
            end += c;
            offsets.push(end);
        }
        slots.truncate(end as usize);
        slots.shrink_to_fit();
        (offsets, slots)
    }
}

/// What [`offer`] did with a view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Offer {
    /// A free slot took it.
    Added,
    /// It took the slot of the lightest view, from this photograph.
    Replaced(u32),
    /// It is not heavier than any kept view.
    Lighter,
}

/// Offers vertex's view `s` (from a photograph after all those kept) to its `row` of slots,
/// `count` of them used: kept while there is room, else in place of the lightest view if
/// heavier (ties: the earlier photograph stays). Exact: the heaviest k of a set are the
/// heaviest k of the heaviest k of a part and the rest.
fn offer(row: &mut [ViewSample], count: &mut u32, s: ViewSample) -> Offer {
    let n = *count as usize;
    if n < row.len() {
        row[n] = s;
        *count += 1;
        return Offer::Added;
    }
    // The lightest kept; among equal weights the latest photograph.
    let (i, lightest) = row
        .iter()
        .enumerate()
        .min_by(|(_, a), (_, b)| a.weight.total_cmp(&b.weight).then(b.photo.cmp(&a.photo)))
        .expect("a full row has slots");
    if s.weight.total_cmp(&lightest.weight) == std::cmp::Ordering::Greater {
        let p = lightest.photo;
        row[i] = s;
        Offer::Replaced(p)
    } else {
        Offer::Lighter
    }
}

/// Drops, per vertex, the views [`consistent`] rejects.
fn drop_inconsistent(b: &mut Binding, threshold: f32) {
    let nv = b.offsets.len() - 1;
    let keep: Vec<Vec<bool>> = (0..nv)
        .into_par_iter()
        .map(|v| {
            let c: Vec<[f32; 3]> = b.views(v).iter().map(|s| s.color).collect();
            consistent(&c, threshold)
        })
        .collect();
    let mut offsets = vec![0u32; nv + 1];
    let mut samples = Vec::with_capacity(b.samples.len());
    let mut dropped = 0u64;
    let mut lost = vec![0u64; b.per_photo.len()];
    for v in 0..nv {
        for (s, k) in b.views(v).iter().zip(&keep[v]) {
            if *k {
                samples.push(*s);
            } else {
                dropped += 1;
                lost[s.photo as usize] += 1;
            }
        }
        offsets[v + 1] = samples.len() as u32;
    }
    for (p, l) in b.per_photo.iter_mut().zip(lost) {
        p.vertices -= l;
    }
    b.offsets = offsets;
    b.samples = samples;
    b.rejections.inconsistent = dropped;
    b.rejections.kept -= dropped;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Views of `nv` vertices from `photos` photographs, by photograph, with pseudo-random
    /// weights (some equal, to exercise the tie rule) and some vertices unseen by some.
    fn views(nv: u32, photos: u32) -> Vec<(u32, ViewSample)> {
        let mut out = Vec::new();
        let mut x = 12345u64;
        for p in 0..photos {
            for v in 0..nv {
                x = x
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                if (x >> 60) < 3 {
                    continue;
                }
                let weight = ((x >> 40) % 7) as f32;
                out.push((
                    v,
                    ViewSample {
                        photo: p,
                        color: [0.5; 3],
                        weight,
                    },
                ));
            }
        }
        out
    }

    #[test]
    fn slots_keep_the_heaviest_views_in_photo_order() {
        for (nv, photos, k) in [(50u32, 40u32, 6usize), (30, 5, 6), (20, 12, 0)] {
            let all = views(nv, photos);
            // As binding offers them: photograph by photograph.
            let mut slots = ViewSlots::new(nv as usize, k, photos as usize).unwrap();
            let (mut kept, mut lighter) = (0u64, 0u64);
            let mut per = vec![0i64; photos as usize];
            for (v, s) in &all {
                let (row, count) = {
                    let st = slots.stride;
                    let v = *v as usize;
                    (&mut slots.slots[v * st..(v + 1) * st], &mut slots.counts[v])
                };
                match offer(row, count, *s) {
                    Offer::Added => {
                        kept += 1;
                        per[s.photo as usize] += 1;
                    }
                    Offer::Replaced(p) => {
                        lighter += 1;
                        per[s.photo as usize] += 1;
                        per[p as usize] -= 1;
                    }
                    Offer::Lighter => lighter += 1,
                }
            }
            let (off, got) = slots.into_rows();
            assert_eq!(off.len(), nv as usize + 1);
            // Against a direct reading of the rule, vertex by vertex.
            for v in 0..nv {
                let mut row: Vec<ViewSample> =
                    all.iter().filter(|p| p.0 == v).map(|p| p.1).collect();
                row.sort_by(|a, b| b.weight.total_cmp(&a.weight).then(a.photo.cmp(&b.photo)));
                if k > 0 {
                    row.truncate(k);
                }
                row.sort_by_key(|s| s.photo);
                let v = v as usize;
                assert_eq!(
                    &got[off[v] as usize..off[v + 1] as usize],
                    &row[..],
                    "vertex {v}"
                );
            }
            assert_eq!(kept, got.len() as u64);
            assert_eq!(kept + lighter, all.len() as u64);
            for (p, n) in per.iter().enumerate() {
                let n_got = got.iter().filter(|s| s.photo as usize == p).count() as i64;
                assert_eq!(*n, n_got, "photograph {p}");
            }
            if k == 0 {
                assert_eq!(lighter, 0);
            }
        }
    }

    #[test]
    fn consistency_tolerates_gain_and_drops_an_outlier() {
        let grey = [0.4f32, 0.35, 0.3];
        // The same surface under five exposures, and once behind a red passer-by.
        let mut views: Vec<[f32; 3]> = [0.7f32, 0.85, 1.0, 1.2, 1.45]
            .iter()
            .map(|g| grey.map(|c| c * g))
            .collect();
        views.push([0.6, 0.08, 0.1]);
        let ok = consistent(&views, 0.12);
        assert_eq!(ok, vec![true, true, true, true, true, false]);
        // Two views cannot outvote each other.
        assert_eq!(consistent(&views[4..], 0.12), vec![true, true]);
        // Far too dark is out even at the same hue.
        let mut dark = views[..5].to_vec();
        dark.push(grey.map(|c| c * 0.1));
        assert!(!consistent(&dark, 0.12)[5]);
    }

    #[test]
    fn options_are_validated_and_parsed() {
        assert!(BindOptions::default().validate().is_ok());
        let bad = BindOptions {
            depth_resolution: 0,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
        assert_eq!(
            "vertex".parse::<Consistency>().ok(),
            Some(Consistency::Vertex)
        );
        assert_eq!("paper".parse::<Method>().ok(), Some(Method::Paper));
        assert!("sometimes".parse::<Consistency>().is_err());
    }
}
