//! `scantex texture`: the stages in order, with timings, peak memory and the outputs.
//!
//! mesh + photographs -> [`atlas::build`] beside [`bind::bind`] -> [`photometric::normalise`]
//! -> [`merge::merge`] (stage 3, [`crate::resample::resample`], inside) ->
//! [`restore::restore_atlas`] -> textured mesh. The [`atlas::Atlas`] is built once and borrowed
//! by every later stage.

use crate::atlas::{self, AtlasOptions, AtlasReport};
use crate::bind::{self, BindOptions, Rejections};
use crate::error::{Error, Result};
use crate::io::{self, EncodedTexture, Staged};
use crate::memory::{self, Estimate, MemoryLimit};
use crate::merge::{self, Masks, MergeOptions};
use crate::mesh::{order::MeshOrder, Mesh};
use crate::photometric::{self, GainModel, Gains, PhotometricOptions};
use crate::progress::Progress;
use crate::resample::{ResampleOptions, ResampleStats, Resampled};
use crate::restore::{self, RestoreOptions};
use crate::scene::Photo;
use crate::seams::{seam_visibility, SeamReport};
use crate::synth::{self, ExemplarSource, SynthOptions};
use image::{DynamicImage, Rgb32FImage};
use nalgebra::Vector3;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The important view direction V of the atlas's visual-importance weight.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum ViewWeight {
    /// The mean viewing direction of the photographs, when they agree enough to have one
    /// (the mean of their unit viewing directions has length at least 0.3; photographs all
    /// around an object have no preferred view and get no weight). Default.
    #[default]
    MeanPhotoDirection,
    /// A given direction (from the eye towards the object).
    Direction([f64; 3]),
    /// No view weight.
    Off,
}

/// Pixel format of the atlas file beside the OBJ.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum TextureFormat {
    /// 8-bit sRGB PNG. Default.
    #[default]
    Png,
    /// 16-bit PNG.
    Png16,
    /// 32-bit float OpenEXR (the GLB still embeds an 8-bit PNG: glTF has no EXR).
    Exr,
}

impl std::fmt::Display for TextureFormat {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            TextureFormat::Png => "png",
            TextureFormat::Png16 => "png16",
            TextureFormat::Exr => "exr",
        })
    }
}

impl std::str::FromStr for TextureFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "png" => Ok(TextureFormat::Png),
            "png16" => Ok(TextureFormat::Png16),
            "exr" => Ok(TextureFormat::Exr),
            _ => Err(format!(
                "unknown texture format '{s}' (expected png, png16 or exr)"
            )),
        }
    }
}

/// The atlas page's side when texturing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AtlasSize {
    /// From the photographs ([`atlas::density::auto_size`]): two texels per axis for every
    /// photograph pixel that covers the surface in its best view, rounded up to a power of
    /// two, at most [`TextureOptions::max_size`].
    #[default]
    Auto,
    /// This many texels per side.
    Fixed(u32),
}

impl std::fmt::Display for AtlasSize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AtlasSize::Auto => f.write_str("auto"),
            AtlasSize::Fixed(n) => write!(f, "{n}"),
        }
    }
}

impl std::str::FromStr for AtlasSize {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "auto" {
            return Ok(AtlasSize::Auto);
        }
        let (lo, hi) = (atlas::SIZE_RANGE.start(), atlas::SIZE_RANGE.end());
        match s.trim().parse::<i64>() {
            Ok(n) if (*lo as i64..=*hi as i64).contains(&n) => Ok(AtlasSize::Fixed(n as u32)),
            Ok(_) => Err(format!(
                "{s} is out of range: expected auto or a number from {lo} to {hi}"
            )),
            Err(_) => Err(format!(
                "'{s}' is not a valid number: expected auto or a number from {lo} to {hi}"
            )),
        }
    }
}

/// Stage 5 on the atlas.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Restoration {
    /// Leave the merge stage's vertex-colour interpolation in the unseen texels.
    Off,
    /// Diffusion of the low band plus synthesis of the high band from the chart's observed
    /// texels (§5), except the regions it hands to exemplar synthesis (stage 6): those deeper
    /// than `handing.min_depth` feature scales and atlas holes larger than `handing.max_hole`
    /// texels.
    Synthesis {
        /// The restoration itself.
        options: RestoreOptions,
        /// Which regions it leaves to stage 6. Default: [`restore::Handing::default`].
        handing: restore::Handing,
    },
}

impl Default for Restoration {
    fn default() -> Self {
        Restoration::Synthesis {
            options: RestoreOptions::default(),
            handing: restore::Handing::default(),
        }
    }
}

/// Everything `scantex texture` can be told.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureOptions {
    /// Atlas (gutter, stretch). Default: [`AtlasOptions::default`] (gutter 4); its
    /// `pack.size` is set from `size` when texturing.
    pub atlas: AtlasOptions,
    /// The atlas page's side. Default: [`AtlasSize::Auto`], from the photographs.
    pub size: AtlasSize,
    /// The largest side [`AtlasSize::Auto`] may choose. Default: 8192.
    pub max_size: u32,
    /// Where the view weight's direction comes from. Default: mean photo direction.
    pub view_weight: ViewWeight,
    /// Binding (method, background, consistency, weights).
    pub bind: BindOptions,
    /// Per-photograph gains (exposure, white balance, shading). Default:
    /// [`PhotometricOptions::default`] (lighting model). [`TextureOptions::paper`] turns it off.
    pub photometric: PhotometricOptions,
    /// Resampling (gutter fill, views per face).
    pub resample: ResampleOptions,
    /// Merging the photographs. Default: [`MergeOptions::default`] (multiband, best-view
    /// masks); [`TextureOptions::paper`] uses the paper's masks.
    pub merge: MergeOptions,
    /// What fills the texels no photograph saw. Default:
    /// [`Restoration::Synthesis`] with [`RestoreOptions::default`] and
    /// [`restore::Handing::default`].
    pub restoration: Restoration,
    /// Exemplar synthesis (stage 6) of the regions restoration hands over; runs only when
    /// restoration does. Default: [`SynthOptions::default`] (exemplars from the atlas).
    pub synth: SynthOptions,
    /// Atlas file format. Default: PNG.
    pub format: TextureFormat,
    /// Keep the UVs the mesh arrived with (unwrapped by another tool) instead of making an
    /// atlas: the texture is resampled into that layout, page 0 only. Default: false.
    pub keep_uvs: bool,
    /// At most this many atlas pages. When the photographs support more texels than one page
    /// of `max_size` holds ([`AtlasSize::Auto`]), or a fixed texel density
    /// (`atlas.pack.texels_per_unit`) needs more, charts go onto several pages (UDIM tiles
    /// 1001, 1002, ...); with a limit the density is lowered until they fit (`Some(1)`: one
    /// page, as with a cap). Default: `None`, as many pages as the density needs.
    pub max_pages: Option<u32>,
    /// How much memory the run may use. With [`AtlasSize::Auto`] pages get a smaller side
    /// (and there are more of them) when a page of `max_size` would not fit; a fixed size
    /// that cannot fit, or a mesh and binding that alone exceed the limit, fail before any
    /// work with the estimate. Default: [`MemoryLimit::default`] (75% of the machine).
    pub memory_limit: MemoryLimit,
}

impl Default for TextureOptions {
    fn default() -> Self {
        TextureOptions {
            atlas: AtlasOptions::default(),
            size: AtlasSize::default(),
            max_size: 8192,
            view_weight: ViewWeight::default(),
            bind: BindOptions::default(),
            photometric: PhotometricOptions::default(),
            resample: ResampleOptions::default(),
            merge: MergeOptions::default(),
            restoration: Restoration::default(),
            synth: SynthOptions::default(),
            format: TextureFormat::default(),
            keep_uvs: false,
            max_pages: None,
            memory_limit: MemoryLimit::default(),
        }
    }
}

impl TextureOptions {
    /// The paper's method throughout: paper binding and resampling, no photometric gains.
    pub fn paper() -> TextureOptions {
        let mut o = TextureOptions::default();
        o.bind.method = bind::Method::Paper;
        o.photometric.model = GainModel::Off;
        o.photometric.delight = photometric::Delight::Off;
        o.merge.masks = Masks::Paper;
        o
    }

    /// The defaults of a binding method: [`TextureOptions::paper`] for the paper's,
    /// [`TextureOptions::default`] for the robust one.
    pub fn for_method(method: bind::Method) -> TextureOptions {
        match method {
            bind::Method::Paper => TextureOptions::paper(),
            bind::Method::Robust => TextureOptions::default(),
        }
    }

    /// Checks every stage's options.
    pub fn validate(&self) -> Result<()> {
        self.atlas.validate()?;
        self.bind.validate()?;
        self.photometric.validate()?;
        self.merge.validate()?;
        self.synth.validate()?;
        self.memory_limit.validate()?;
        let fixed = match self.size {
            AtlasSize::Fixed(n) => Some(("size", n)),
            AtlasSize::Auto => None,
        };
        for (name, n) in fixed.into_iter().chain([("max_size", self.max_size)]) {
            if !atlas::SIZE_RANGE.contains(&n) {
                return Err(Error::option(
                    name,
                    format!("{n} texels: expected a side in {:?}", atlas::SIZE_RANGE),
                ));
            }
        }
        if self.max_pages == Some(0) {
            return Err(Error::option(
                "pages",
                "at most 0 pages leaves nowhere to put a chart",
            ));
        }
        if self.keep_uvs && self.atlas.pack.texels_per_unit.is_some() {
            return Err(Error::option(
                "texel_density",
                "--keep-uvs keeps the mesh's own layout: a texel density cannot apply",
            ));
        }
        Ok(())
    }
}

/// Time and memory of one stage.
#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    /// Stage name.
    pub stage: &'static str,
    /// Wall time, seconds.
    pub seconds: f64,
    /// Peak resident memory of the process during the stage, MB (0 if unknown). Atlas and
    /// binding run side by side: both report the peak of the two together.
    pub peak_mb: f64,
    /// The atlas page (UDIM tile) the stage worked on, when there are several.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile: Option<u32>,
}

/// What the stages after gains did on one atlas page.
#[derive(Debug, Clone, Serialize)]
pub struct PageReport {
    /// UDIM tile number: 1001 for the first page.
    pub tile: u32,
    /// Triangles per class and texels per source.
    pub resample: ResampleStats,
    /// What the multiband merge and the chart-border levelling measured.
    pub merging: merge::MergeStats,
    /// Seam visibility of the page (1 = invisible): across view boundaries and chart borders.
    pub seams: SeamReport,
    /// Restoration of the texels no photograph saw (stage 5), if it ran.
    pub restore: Option<restore::RestoreReport>,
    /// Exemplar synthesis of the regions restoration handed over (stage 6), if it ran.
    pub synth: Option<synth::SynthReport>,
    /// Of the texels of green triangles (all three vertices seen by one photograph), the
    /// fraction coloured from photographs; the rest are hidden from every photograph at texel
    /// precision (robust) and take vertex colours.
    pub completeness_seen: f64,
}

/// The memory limit a run was held to and what it was estimated to need.
#[derive(Debug, Clone, Serialize)]
pub struct MemoryReport {
    /// The limit, bytes (`None`: no limit, or the machine's memory unknown).
    pub limit_bytes: Option<u64>,
    /// The estimate by part, bytes, with the binding's views counted.
    pub estimate: Estimate,
    /// Its total, bytes.
    pub estimate_bytes: u64,
    /// The largest page side `--size auto` could choose under the limit (`max_size`, or less
    /// when the limit lowered it).
    pub max_side: u32,
}

/// What `scantex texture` did (written as `report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct TextureReport {
    /// scantex version.
    pub version: &'static str,
    /// Binding and resampling method.
    pub method: bind::Method,
    /// How the photographs were merged.
    pub merge: MergeOptions,
    /// Mesh vertices (after welding) and faces.
    pub vertices: usize,
    /// See `vertices`.
    pub faces: usize,
    /// Photographs used.
    pub photos: usize,
    /// Registered images left out because their file is absent (`--skip-missing`).
    pub photos_skipped: Vec<String>,
    /// Registered images left out because their photograph is bad (`--skip-bad-images`).
    pub photos_bad: Vec<crate::scene::BadPhoto>,
    /// Everything the run warned about on standard error (photographs that contribute
    /// nothing, photographs left out).
    pub warnings: Vec<String>,
    /// The view direction the atlas weighted by, if any.
    pub view_dir: Option<[f64; 3]>,
    /// The side of an atlas page, texels.
    pub atlas_size: u32,
    /// How `--size auto` chose it, if it did.
    pub auto_size: Option<atlas::density::AutoSize>,
    /// The atlas stage's report.
    pub atlas: AtlasReport,
    /// Vertices with at least one valid photograph.
    pub vertices_bound: usize,
    /// Vertices with none.
    pub vertices_unbound: usize,
    /// Why vertex-photograph pairs were rejected.
    pub rejections: Rejections,
    /// Per photograph: vertices bound and background colour used.
    pub per_photo: Vec<bind::PhotoBinding>,
    /// Per-photograph gains and how far they brought the photographs together.
    pub gains: Gains,
    /// Per atlas page (one unless the charts needed several): resampling, merging,
    /// restoration, synthesis and seams.
    pub pages: Vec<PageReport>,
    /// Per-stage time and peak memory (atlas and bind run concurrently: their times overlap).
    pub stages: Vec<StageReport>,
    /// Wall time of the whole run (reading the inputs aside), seconds.
    pub seconds: f64,
    /// Worker threads of the pool the run's data-parallel work ran on (the output does not
    /// depend on it).
    pub threads: usize,
    /// The memory limit and the estimate the run was checked against.
    pub memory: MemoryReport,
    /// Peak resident memory of the process so far (reading the inputs included), MB (0 if
    /// unknown).
    pub peak_mb: f64,
}

/// One atlas page of [`Textured`].
#[derive(Debug, Clone)]
pub struct TexturedPage {
    /// UDIM tile number: 1001 for the first page.
    pub tile: u32,
    /// The resampled page and its per-texel bookkeeping.
    pub resampled: Resampled,
    /// The unseen texels restoration left (none restored when restoration is off).
    pub unrestored: Option<restore::Unrestored>,
    /// Stage 6's patch map ([`synth::Synthesized::patches`]; empty unless kept), if it ran.
    pub patch_map: Option<Vec<(u32, u32)>>,
    /// Stage 6's exemplars from the surface ([`synth::Synthesized::exemplars`]; empty unless
    /// kept).
    pub exemplars: Vec<image::RgbImage>,
}

/// The product of [`texture`].
#[derive(Debug, Clone)]
pub struct Textured {
    /// The mesh with its atlas UVs (page `p` at u in `[p, p + 1]`).
    pub mesh: Mesh,
    /// The atlas pages in tile order; one unless the charts needed several. Only the pages
    /// the sink kept ([`texture_with`]; [`texture`] keeps all).
    pub pages: Vec<TexturedPage>,
    /// What happened.
    pub report: TextureReport,
}

impl Textured {
    /// The first page (tile 1001), the whole atlas when there is one page.
    ///
    /// # Panics
    /// If the pages were handed to a sink that kept none ([`texture_with`]).
    pub fn page(&self) -> &TexturedPage {
        &self.pages[0]
    }
}

/// The stages' reports as they end, each with its wall time and the peak resident memory
/// while it ran.
struct StageLog {
    reports: Vec<StageReport>,
    watch: io::MemoryWatch,
    t: Instant,
}

impl StageLog {
    fn new() -> StageLog {
        StageLog {
            reports: Vec::new(),
            watch: io::MemoryWatch::start(),
            t: Instant::now(),
        }
    }

    /// Ends stage `name`, begun when the previous one ended, on page `tile`.
    fn end(&mut self, name: &'static str, tile: Option<u32>) {
        self.reports.push(StageReport {
            stage: name,
            seconds: self.t.elapsed().as_secs_f64(),
            peak_mb: self.watch.take() as f64 / 1e6,
            tile,
        });
        self.t = Instant::now();
    }

    /// Ends stages that ran side by side, each timed by itself, with their common peak.
    fn end_together(&mut self, timed: &[(&'static str, f64)]) {
        let peak_mb = self.watch.take() as f64 / 1e6;
        for &(stage, seconds) in timed {
            self.reports.push(StageReport {
                stage,
                seconds,
                peak_mb,
                tile: None,
            });
        }
        self.t = Instant::now();
    }
}

/// The smallest page side the memory limit may lower `--size auto`'s pages to: smaller pages
/// would each re-read every photograph for little atlas.
pub const MIN_PAGE_UNDER_LIMIT: u32 = 1024;

/// The UDIM tile of page `p` of `count`, when there are several.
fn page_tile(count: u32, p: u32) -> Option<u32> {
    (count > 1).then_some(1001 + p)
}

/// The scene's "up" as the photographs suggest it: photographers hold cameras level, so up
/// is the direction most nearly perpendicular to every camera's image-horizontal axis (the
/// least eigenvector of the sum of their outer products), signed to agree with the cameras'
/// image-up directions. A mean of image-up vectors alone would tilt towards the side the
/// cameras stand on. Falls back to +Z without photographs.
pub fn mean_up(photos: &[Photo]) -> Vector3<f64> {
    let mut s = nalgebra::Matrix3::<f64>::zeros();
    let mut ups = Vector3::zeros();
    for p in photos {
        let inv = p.view.pose.rotation.inverse();
        let x = inv * Vector3::x();
        s += x * x.transpose();
        ups += inv * -Vector3::y();
    }
    if photos.is_empty() {
        return Vector3::z();
    }
    let eig = nalgebra::SymmetricEigen::new(s);
    let k = (0..3)
        .min_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))
        .unwrap_or(2);
    let up = eig.eigenvectors.column(k).into_owned().normalize();
    if up.dot(&ups) < 0.0 {
        -up
    } else {
        up
    }
}

/// Mean viewing direction of the photographs, if they agree enough to have one.
///
/// Rounded to 1e-9 per component: the stretch minimisation's path depends on its last
/// digits, and the same poses stored by another format (a quaternion against a matrix, a
/// centre against a translation) differ there; rounded, they give the same atlas
/// (`docs/decisions.md`, "OpenMVS scenes").
pub fn mean_view_dir(photos: &[Photo]) -> Option<Vector3<f64>> {
    let sum: Vector3<f64> = photos.iter().map(|p| p.view.pose.view_dir()).sum();
    let mean = sum / photos.len().max(1) as f64;
    (mean.norm() >= 0.3).then(|| mean.normalize().map(|c| (c * 1e9).round() / 1e9))
}

/// Runs every stage on `mesh` and `photos`; the product keeps every page.
pub fn texture(
    mesh: &Mesh,
    photos: &[Photo],
    opts: &TextureOptions,
    progress: &dyn Progress,
) -> Result<Textured> {
    texture_with(mesh, photos, opts, progress, &mut |_, _, page| {
        Ok(Some(page))
    })
}

/// What [`texture_with`] does with each page as it is finished: it gets the mesh with that
/// page's UVs at `[0, 1]`, the number of pages and the page, and returns the page to keep it
/// in [`Textured::pages`] or `None` once it has written it (so the next page does not hold
/// this one's images).
pub type PageSink<'a> = dyn FnMut(&Mesh, u32, TexturedPage) -> Result<Option<TexturedPage>> + 'a;

/// [`texture`], handing each finished page to `on_page`.
pub fn texture_with(
    mesh: &Mesh,
    photos: &[Photo],
    opts: &TextureOptions,
    progress: &dyn Progress,
    on_page: &mut PageSink,
) -> Result<Textured> {
    opts.validate()?;
    if photos.is_empty() {
        return Err(Error::Invalid(
            "the scene has no registered photographs to texture from".into(),
        ));
    }
    // The user's exemplar is read before any work, so a bad file stops the run at once.
    let user = match &opts.synth.exemplar {
        ExemplarSource::File(p) => {
            let img = io::image::read_rgb32f(p)?;
            let min = synth::MIN_EXEMPLAR_SIDE;
            if img.width() < min || img.height() < min {
                return Err(Error::parse(
                    p,
                    crate::Location::File,
                    format!(
                        "the exemplar is {}x{} pixels: stage 6 needs at least {min}x{min}",
                        img.width(),
                        img.height()
                    ),
                ));
            }
            Some(img)
        }
        _ => None,
    };
    let mut log = StageLog::new();
    let wall = Instant::now();
    let mut atlas_opts = opts.atlas;
    let view_dir = match opts.view_weight {
        ViewWeight::MeanPhotoDirection => mean_view_dir(photos),
        ViewWeight::Direction(d) => Some(Vector3::from(d)),
        ViewWeight::Off => None,
    };
    atlas_opts.flatten.stretch.view_dir = view_dir;
    // The atlas only adds UVs to the welded mesh, and binding needs no UVs: the two run side
    // by side, so binding's photo decoding fills the cores the packer leaves idle.
    let mut welded = mesh.clone();
    welded.texture = None;
    if !opts.keep_uvs {
        welded.uv = None;
    }
    welded.weld();
    // A mesh whose faces come in no spatial order is worked on in one (5% of the 1.5M-face
    // speed scene's time, docs/decisions.md) and handed back in its own order: the pages'
    // per-face and per-vertex products, the mesh each page sink gets and the result's.
    let order = welded.scattered_order();
    if let Some(o) = &order {
        welded = welded.reordered(o);
    }
    let normals = welded.vertex_normals();
    // The memory limit first: it may lower the page side that `--size auto` can choose.
    let limit = opts.memory_limit.bytes();
    let photo_pixels = photos
        .iter()
        .map(|p| u64::from(p.view.camera.width) * u64::from(p.view.camera.height))
        .max()
        .unwrap_or(0);
    let mut per_vertex = memory::ASSUMED_VIEWS.min(photos.len() as u64);
    if opts.bind.max_views > 0 {
        per_vertex = per_vertex.min(opts.bind.max_views as u64);
    }
    let assumed_views = welded.num_vertices() as u64 * per_vertex;
    let mut estimate = Estimate::new(welded.num_faces() as u64, assumed_views, photo_pixels, 0);
    let mut max_size = opts.max_size;
    let mut warnings = Vec::new();
    if let (Some(limit), AtlasSize::Auto, false) = (limit, opts.size, opts.keep_uvs) {
        let floor = MIN_PAGE_UNDER_LIMIT.min(max_size);
        let Some(side) = memory::fitting_side(&estimate, max_size, floor, limit) else {
            return Err(memory::over_limit(
                &estimate,
                floor,
                &opts.memory_limit,
                &format!(
                    "not even pages of {floor} texels fit beside the mesh and the \
                     photographs; raise --memory-limit, or texture a decimated mesh"
                ),
            ));
        };
        if side < max_size {
            let w = format!(
                "pages of at most {side} texels instead of {max_size}, to stay within the \
                 memory limit of {}",
                memory::human(limit)
            );
            progress.warn(&w);
            warnings.push(w);
            max_size = side;
        }
    }
    let auto_size = match opts.size {
        AtlasSize::Fixed(n) => {
            atlas_opts.pack.size = n;
            None
        }
        AtlasSize::Auto => {
            let views: Vec<_> = photos.iter().map(|p| &p.view).collect();
            let a = atlas::density::auto_size(&welded, &views, max_size);
            atlas_opts.pack.size = a.size;
            // More texels than a capped page holds: pages of the cap, with the texels the
            // photographs support (the side's rounding to a power of two does not apply).
            let spread = a.capped && opts.max_pages != Some(1) && !opts.keep_uvs;
            if spread && atlas_opts.pack.texels_per_unit.is_none() {
                let k = atlas::density::OVERSAMPLING;
                atlas_opts.pack.chart_texels = Some(k * k * a.photo_pixels);
            }
            Some(a)
        }
    };
    if opts.size == AtlasSize::Auto && atlas_opts.pack.texels_per_unit.is_some() {
        atlas_opts.pack.size = max_size;
    }
    let side = atlas_opts.pack.size;
    if let Some(l) = limit {
        if estimate.with_side(side).total() > l {
            return Err(memory::over_limit(
                &estimate,
                side,
                &opts.memory_limit,
                "use --size auto (pages of a side that fits), a smaller --size, or raise \
                 --memory-limit",
            ));
        }
    }
    atlas_opts.pack.max_pages = opts.max_pages;
    // The atlas reports its charts on a bar of its own, below binding's.
    let atlas_progress = progress.beside();
    let (atlas_done, bind_done) = rayon::join(
        || {
            let t = Instant::now();
            let built = if opts.keep_uvs {
                atlas::keep(welded.clone(), atlas_opts.pack.size)
            } else {
                atlas::build_pages_reporting(welded.clone(), &atlas_opts, atlas_progress.as_ref())
            };
            built.map(|r| (r, t.elapsed().as_secs_f64()))
        },
        || {
            let t = Instant::now();
            bind::bind(&welded, &normals, photos, &opts.bind, progress)
                .map(|b| (b, t.elapsed().as_secs_f64()))
        },
    );
    let ((mut m, pages, atlas_report), atlas_stage) = atlas_done?;
    let (binding, bind_stage) = bind_done?;
    drop(welded);
    log.end_together(&[("atlas", atlas_stage), ("bind", bind_stage)]);
    // Binding has counted its views: the estimate with them, before the pages' work.
    estimate = Estimate::new(
        m.num_faces() as u64,
        binding.samples.len() as u64,
        photo_pixels,
        side,
    );
    if let Some(l) = limit {
        if estimate.total() > l {
            return Err(memory::over_limit(
                &estimate,
                side,
                &opts.memory_limit,
                &format!(
                    "binding keeps {} views of {} vertices; raise --memory-limit, or use \
                     fewer photographs or a smaller --max-size",
                    binding.samples.len(),
                    binding.offsets.len().saturating_sub(1)
                ),
            ));
        }
    }
    if binding.bound_vertices() == 0 {
        let r = &binding.rejections;
        return Err(Error::Invalid(format!(
            "no photograph sees any vertex of the mesh (vertex-photograph pairs rejected: \
             {} outside the image, {} facing away, {} silhouette, {} occluded, {} masked out, \
             {} background); check that the mesh and the COLMAP model share one frame",
            r.outside, r.facing, r.silhouette, r.occluded, r.mask, r.background
        )));
    }
    if opts.keep_uvs && atlas_report.overlapping_texels > 0 {
        let w = format!(
            "the mesh's own UVs overlap ({} texels covered by more than one chart): the \
             overlapping parts of the surface share those texels' colours",
            atlas_report.overlapping_texels
        );
        progress.warn(&w);
        warnings.push(w);
    }
    for b in binding.per_photo.iter().filter(|b| b.vertices == 0) {
        let w = format!(
            "photograph {} sees no vertex of the mesh and contributes nothing (check its pose \
             and that it shows the object)",
            b.name
        );
        progress.warn(&w);
        warnings.push(w);
    }
    progress.start("gains", 1);
    let (binding, gains) = photometric::normalise(binding, &m, &normals, &opts.photometric);
    progress.finish();
    log.end("gains", None);
    // One page at a time: each page's texel raster, layers and restoration are the size of a
    // page, and are dropped before the next page begins. Later stages read texel positions
    // from the mesh's UVs on page 0, so each page in turn is moved there.
    let count = pages.count();
    let up = mean_up(photos);
    let mut done = Vec::with_capacity(count as usize);
    let mut page_reports = Vec::with_capacity(count as usize);
    let original = (count > 1)
        .then(|| m.uv.as_ref().map(|uv| uv.coords.clone()))
        .flatten();
    for p in 0..count {
        if let Some(o) = &original {
            atlas::place_page(&mut m, o, p);
        }
        let ctx = PageContext {
            mesh: &m,
            normals: &normals,
            binding: &binding,
            gains: &gains,
            photos,
            user: user.as_ref(),
            up,
            opts,
            progress,
            tile: page_tile(count, p),
        };
        let atlas = pages.atlas(&m, p)?;
        let (mut page, mut report) = texture_page(&ctx, &atlas, 1001 + p, &mut log)?;
        drop(atlas);
        let in_order;
        let sink_mesh = match &order {
            Some(o) => {
                to_original_order(&mut page, &mut report, o);
                in_order = m.in_original_order(o);
                &in_order
            }
            None => &m,
        };
        done.extend(on_page(sink_mesh, count, page)?);
        log.end("output", page_tile(count, p));
        page_reports.push(report);
    }
    if let (Some(o), Some(uv)) = (original, &mut m.uv) {
        uv.coords = o;
    }
    let stages = log.reports;
    // The kernel's high-water mark covers the reading before the stages; the watch's samples
    // can be ahead of it (its counters are synchronised lazily).
    let peak_mb = stages
        .iter()
        .map(|s| s.peak_mb)
        .fold(io::peak_memory().unwrap_or(0) as f64 / 1e6, f64::max);
    let report = TextureReport {
        version: env!("CARGO_PKG_VERSION"),
        method: opts.bind.method,
        merge: opts.merge,
        vertices: m.num_vertices(),
        faces: m.num_faces(),
        photos: photos.len(),
        photos_skipped: Vec::new(),
        photos_bad: Vec::new(),
        warnings,
        view_dir: view_dir.map(|v| [v.x, v.y, v.z]),
        atlas_size: atlas_opts.pack.size,
        auto_size,
        atlas: atlas_report,
        vertices_bound: binding.bound_vertices(),
        vertices_unbound: m.num_vertices() - binding.bound_vertices(),
        rejections: binding.rejections,
        per_photo: binding.per_photo.clone(),
        gains,
        pages: page_reports,
        stages,
        seconds: wall.elapsed().as_secs_f64(),
        threads: rayon::current_num_threads(),
        memory: MemoryReport {
            limit_bytes: limit,
            estimate,
            estimate_bytes: estimate.total(),
            max_side: max_size,
        },
        peak_mb,
    };
    Ok(Textured {
        mesh: match &order {
            Some(o) => m.in_original_order(o),
            None => m,
        },
        pages: done,
        report,
    })
}

/// A page's products indexed by the faces and vertices of the mesh as the pipeline sorted it
/// ([`crate::mesh::order`]), indexed by the input's instead.
fn to_original_order(page: &mut TexturedPage, report: &mut PageReport, o: &MeshOrder) {
    let res = &mut page.resampled;
    res.classes = o.faces_to_original(&res.classes);
    res.vertex_colors = o.vertices_to_original(&res.vertex_colors);
    let face = |f: u32| {
        if f == crate::mesh::topology::NO_FACE {
            f
        } else {
            o.original_face(f)
        }
    };
    if let Some(left) = &mut page.unrestored {
        for r in &mut left.regions {
            for f in &mut r.faces {
                *f = face(*f);
            }
        }
        if !left.adjacency.is_empty() {
            left.adjacency = o
                .faces_to_original(&left.adjacency)
                .into_iter()
                .map(|a| a.map(face))
                .collect();
        }
    }
    if let Some(synth) = &mut report.synth {
        for r in &mut synth.regions {
            if let synth::ExemplarUsed::Surface { face: f, .. } = &mut r.exemplar {
                *f = face(*f);
            }
        }
    }
}

/// What every page's stages read: the whole mesh (its UVs with this page at `[0, 1]`), its
/// binding and gains, and the options.
struct PageContext<'a> {
    mesh: &'a Mesh,
    normals: &'a [Vector3<f64>],
    binding: &'a bind::Binding,
    gains: &'a Gains,
    photos: &'a [Photo],
    user: Option<&'a Rgb32FImage>,
    up: Vector3<f64>,
    opts: &'a TextureOptions,
    progress: &'a dyn Progress,
    /// The tile stage reports name, when there are several pages.
    tile: Option<u32>,
}

/// Stages 3-6 and the seam measure on one atlas page.
fn texture_page(
    ctx: &PageContext,
    atlas: &atlas::Atlas,
    tile: u32,
    log: &mut StageLog,
) -> Result<(TexturedPage, PageReport)> {
    let (m, opts, progress) = (ctx.mesh, ctx.opts, ctx.progress);
    let mut stage = |name: &'static str| log.end(name, ctx.tile);
    // With restoration, chart borders are levelled once, after it (`merge::relevel` below):
    // levelling the merged atlas as well cost 2.4 s on a 1.5M-face scene and changed no
    // held-out score (docs/decisions.md, "Chart borders levelled once").
    let restoring = !matches!(opts.restoration, Restoration::Off);
    // Stage 6 runs when restoration left regions to it.
    let synth_follows = |left: &restore::Unrestored| {
        opts.synth.exemplar != ExemplarSource::Off && !left.regions.is_empty()
    };
    let merge_opts = merge::MergeOptions {
        level_seams: opts.merge.level_seams && !restoring,
        ..opts.merge
    };
    let (mut resampled, mut merging) = merge::merge(
        m,
        ctx.normals,
        atlas,
        ctx.binding,
        ctx.gains,
        ctx.photos,
        &opts.resample,
        &merge_opts,
        progress,
    )?;
    stage("resample+merge");
    let (restore, unrestored) = match opts.restoration {
        Restoration::Off => (None, None),
        Restoration::Synthesis { options, handing } => {
            // Neither restoration nor the levelling fills the gutter again: it is filled once,
            // after the last step that changes chart colours (a fill of an 8192 atlas takes
            // about half a second). Restoration's DCT split reads the merge's fill as its
            // crops' padding; the levelling and stage 6 read chart texels only.
            let (r, left) =
                restore::restore_atlas(&mut resampled, m, atlas, &options, &handing, progress)?;
            // Restored texels meet at chart borders without having seen each other, and the
            // merge left the borders to this one levelling.
            if opts.merge.merge == merge::Merge::Multiband && opts.merge.level_seams {
                let st = merge::relevel(m, atlas, &mut resampled)?;
                merging.seam_levelling_after_restore = Some(st);
            }
            if !synth_follows(&left) {
                crate::resample::refill_gutter(&mut resampled, opts.resample.gutter_fill);
            }
            progress.finish();
            stage("restore");
            (Some(r), Some(left))
        }
    };
    let synth = match &unrestored {
        Some(left) if synth_follows(left) => {
            let r = synth::synthesize(
                m,
                ctx.normals,
                atlas,
                &mut resampled,
                left,
                ctx.photos,
                ctx.up,
                ctx.user,
                &opts.synth,
                opts.resample.gutter_fill,
                progress,
            )?;
            progress.finish();
            stage("synth");
            Some(r)
        }
        _ => None,
    };
    let (synth, patch_map, exemplars) = match synth {
        Some(made) => (Some(made.report), Some(made.patches), made.exemplars),
        None => (None, None, Vec::new()),
    };
    let seams = seam_visibility(
        m,
        &resampled.color,
        &resampled.source,
        &resampled.best_photo,
    );
    stage("seams");
    let s = &resampled.stats;
    let seen = s.texels_photos + s.texels_green_fallback;
    let report = PageReport {
        tile,
        resample: resampled.stats.clone(),
        merging,
        seams,
        restore,
        synth,
        completeness_seen: if seen > 0 {
            s.texels_photos as f64 / seen as f64
        } else {
            1.0
        },
    };
    let page = TexturedPage {
        tile,
        resampled,
        unrestored,
        patch_map,
        exemplars,
    };
    Ok((page, report))
}

fn to_png8(img: &Rgb32FImage) -> Result<EncodedTexture> {
    io::image::encode_png(&DynamicImage::ImageRgb8(crate::render::to_rgb8(img)))
}

/// Writes `<dir>/model.obj` (+ `model.mtl`, `model.png|exr`), `model.glb`, `report.json`, and
/// with `debug` the pictures `classes.png`, `coverage.png`, `masks.png` (the photograph whose
/// mask wins each texel), `restore.png` (texels restored and left), `synth.png` (stage 6's
/// patches, when it ran and kept its patch map), `exemplar0.png`... (its exemplars from the
/// surface) and `layout.png` into that
/// directory. Every file appears at once or none does.
pub fn write_outputs(
    dir: &Path,
    result: &Textured,
    format: TextureFormat,
    debug: Option<&Path>,
) -> Result<()> {
    let staged = begin_outputs(dir, debug)?;
    write_staged(staged, dir, result, format, debug)
}

/// Prepares the output directories of `scantex texture` before any work: creates them, checks
/// that they can be written and that no other run is writing them, and removes what a killed
/// run left (see [`io::staging`]).
pub fn begin_outputs(dir: &Path, debug: Option<&Path>) -> Result<Staged> {
    let mut dirs = vec![dir];
    dirs.extend(debug);
    Staged::begin("texture", &dirs)
}

/// Writes a textured result's files page by page: each page's textures are encoded (and its
/// debug pictures written) as it comes, so only encoded bytes outlive a page; the meshes and
/// `report.json` follow at the end.
struct PageWriter<'a> {
    format: TextureFormat,
    debug: Option<&'a Path>,
    mains: Vec<EncodedTexture>,
    png8s: Vec<EncodedTexture>,
}

impl<'a> PageWriter<'a> {
    fn new(format: TextureFormat, debug: Option<&'a Path>) -> Self {
        PageWriter {
            format,
            debug,
            mains: Vec::new(),
            png8s: Vec::new(),
        }
    }

    /// One page of `count`; `at_page` is the mesh with this page's UVs at `[0, 1]`.
    fn page(
        &mut self,
        staged: &mut Staged,
        at_page: &Mesh,
        count: u32,
        page: &TexturedPage,
    ) -> Result<()> {
        let r = &page.resampled;
        let img = &r.color;
        let png8 = to_png8(img)?;
        self.mains.push(match self.format {
            TextureFormat::Png => png8.clone(),
            TextureFormat::Png16 => {
                io::image::encode_png(&DynamicImage::ImageRgb32F(img.clone()).into_rgb16().into())?
            }
            TextureFormat::Exr => io::image::encode_exr(img)?,
        });
        self.png8s.push(png8);
        let Some(d) = self.debug else {
            return Ok(());
        };
        // With several pages every picture names its tile: classes.1001.png, ...
        let name = |base: &str| match count > 1 {
            true => format!("{base}.{}.png", page.tile),
            false => format!("{base}.png"),
        };
        for (base, pic) in [
            ("classes", r.class_picture()),
            ("coverage", r.coverage_picture()),
            ("masks", r.best_photo_picture()),
            ("restore", restore::picture(r, page.unrestored.as_ref())),
            (
                "layout",
                atlas::layout_picture(at_page, img.width().min(4096)),
            ),
        ]
        .into_iter()
        .chain(
            page.patch_map
                .as_ref()
                .map(|m| ("synth", synth::picture(r, m))),
        ) {
            let enc = io::image::encode_png(&DynamicImage::ImageRgb8(pic))?;
            staged.write(&d.join(name(base)), &enc.bytes)?;
        }
        for (k, pic) in page.exemplars.iter().enumerate() {
            let enc = io::image::encode_png(&DynamicImage::ImageRgb8(pic.clone()))?;
            staged.write(&d.join(name(&format!("exemplar{k}"))), &enc.bytes)?;
        }
        Ok(())
    }

    /// The meshes (naming every page's texture) and `report.json`, moved into place last: once
    /// it is new, so is everything else.
    fn finish(
        self,
        mut staged: Staged,
        dir: &Path,
        mesh: &Mesh,
        report: &TextureReport,
    ) -> Result<()> {
        // The two meshes are encoded side by side (each in one pass over the faces, the OBJ's
        // in parallel chunks), then written in their order.
        let (obj_path, glb_path) = (dir.join("model.obj"), dir.join("model.glb"));
        let (obj, glb) = rayon::join(
            || io::obj::encode_pages(&obj_path, mesh, &self.mains),
            || io::gltf::glb_bytes(&glb_path, mesh, &self.png8s),
        );
        obj.write(&mut staged)?;
        staged.write(&glb_path, &glb?)?;
        let json = serde_json::to_vec_pretty(report)
            .map_err(|e| Error::Internal(format!("cannot serialise the report: {e}")))?;
        staged.write(&dir.join("report.json"), &json)?;
        staged.commit()
    }
}

/// [`write_outputs`] into staging prepared by [`begin_outputs`].
fn write_staged(
    mut staged: Staged,
    dir: &Path,
    result: &Textured,
    format: TextureFormat,
    debug: Option<&Path>,
) -> Result<()> {
    let mut w = PageWriter::new(format, debug);
    let count = result.pages.len() as u32;
    let mut at_page = result.mesh.clone();
    let original = result.mesh.uv.as_ref().map(|uv| uv.coords.clone());
    for page in &result.pages {
        if let Some(o) = &original {
            atlas::place_page(&mut at_page, o, page.tile - 1001);
        }
        w.page(&mut staged, &at_page, count, page)?;
    }
    w.finish(staged, dir, &result.mesh, &result.report)
}

/// The whole `scantex texture` job: loads the scene (mesh and COLMAP model required; every
/// photograph checked before any work), textures it, writes the outputs into `out`.
pub fn texture_scene(
    spec: &crate::scene::SceneSpec,
    opts: &TextureOptions,
    out: &Path,
    debug: Option<&Path>,
    progress: &dyn Progress,
) -> Result<Textured> {
    opts.validate()?;
    let staged = begin_outputs(out, debug)?;
    let scene = crate::scene::Scene::load(spec)?;
    let Some((mesh, load)) = &scene.mesh else {
        return Err(Error::Invalid(
            "texturing needs a mesh: give a scene directory with mesh.(ply|obj|glb) or --mesh"
                .into(),
        ));
    };
    if scene.reconstruction.is_none() {
        return Err(Error::Invalid(
            "texturing needs a COLMAP model: give a scene directory with sparse/ or --colmap"
                .into(),
        ));
    }
    let mut warnings = Vec::new();
    for w in load.warnings() {
        progress.warn(&w);
        warnings.push(w);
    }
    for b in &scene.bad {
        let w = format!("left out photograph {}: {}", b.name, b.reason);
        progress.warn(&w);
        warnings.push(w);
    }
    scene.check_photos()?;
    let mut opts = opts.clone();
    opts.synth.keep_patch_map = debug.is_some();
    // Each page is encoded into staging as it is finished and its images dropped: the run
    // holds one page's images at a time.
    let mut staged = staged;
    let mut writer = PageWriter::new(opts.format, debug);
    let mut result = texture_with(
        mesh,
        &scene.photos,
        &opts,
        progress,
        &mut |at_page, count, page| {
            writer.page(&mut staged, at_page, count, &page)?;
            Ok(None)
        },
    )?;
    result.report.photos_skipped = scene.skipped.clone();
    result.report.photos_bad = scene.bad.clone();
    warnings.append(&mut result.report.warnings);
    result.report.warnings = warnings;
    writer.finish(staged, out, &result.mesh, &result.report)?;
    Ok(result)
}

/// The whole `scantex param` job: reads `mesh`, gives it an atlas (stage 1 alone) and writes
/// the mesh with UVs to `out` (OBJ, PLY or GLB by extension), a layout picture beside it as
/// `<stem>_layout.png` (at most 2048 pixels) and, if asked, the report as JSON to `report`.
/// Every file appears at once or none does. Returns the report.
pub fn param_file(
    mesh: &Path,
    out: &Path,
    report: Option<&Path>,
    opts: &AtlasOptions,
    progress: &dyn Progress,
) -> Result<AtlasReport> {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let layout = out.with_file_name(format!("{stem}_layout.png"));
    let mut dirs = vec![io::staging::dir_of(out)];
    dirs.extend(report.map(io::staging::dir_of));
    let mut staged = Staged::begin(&io::staging::label_of(out), &dirs)?;
    let (input, load) = io::read_mesh(mesh)?;
    for w in load.warnings() {
        progress.warn(&w);
    }
    let (out_mesh, rep) = atlas::parameterize_reporting(&input, opts, progress)?;
    let picture = atlas::layout_picture(&out_mesh, opts.pack.size.min(2048));
    let png = io::image::encode_png(&DynamicImage::ImageRgb8(picture))?;
    io::stage_mesh(&mut staged, out, &out_mesh, None)?;
    staged.write(&layout, &png.bytes)?;
    if let Some(p) = report {
        let json = serde_json::to_vec_pretty(&rep)
            .map_err(|e| Error::Internal(format!("cannot serialise the report: {e}")))?;
        staged.write(p, &json)?;
    }
    staged.commit()?;
    Ok(rep)
}
