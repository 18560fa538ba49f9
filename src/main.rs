//! The `scantex` command: parses arguments, calls the library, reports errors. Most of its
//! length is the argument definitions with their help text (every option of every command);
//! the commands' work is in the library.

use clap::{Args, Parser, Subcommand};
use scantex::eval::EvalOptions;
use scantex::render::{Lighting, Shading};
use scantex::scene::{Scene, SceneSpec};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "scantex",
    version,
    about = "Texture atlases for 3D-scanned objects from calibrated photographs",
    after_help = "Exit status: 0 done; 1 bad input, or an option value only the input shows to \
                  be wrong (the message names the file, line, element or option), or a CPU this \
                  build cannot use; 2 usage error: an unknown option or a value out of its range; \
                  3 internal error (a bug: please report it); 128 + N stopped by signal N \
                  (nothing half-written is left)."
)]
struct Cli {
    /// Worker threads for the data-parallel work (0: one per core, or RAYON_NUM_THREADS when
    /// set). For several jobs on one machine; the output is the same bytes at any count.
    #[arg(
        long,
        global = true,
        default_value_t = 0,
        value_name = "N",
        value_parser = clap::value_parser!(u16).range(0..=MAX_THREADS)
    )]
    threads: u16,
    #[command(subcommand)]
    command: Command,
}

/// The most `--threads` takes: far more threads than cores only adds memory (per-thread
/// buffers) and switching.
const MAX_THREADS: i64 = 1024;

#[derive(Subcommand)]
enum Command {
    /// Check a scene: mesh topology, cameras, photographs, reprojection error.
    Info {
        #[command(flatten)]
        scene: SceneArgs,
        /// Print the report as JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Render a textured mesh from every camera of a scene (one PNG per photograph, plus
    /// coverage masks in <out>/masks/).
    Render {
        /// Textured mesh to render (OBJ with MTL and texture, or GLB).
        #[arg(long = "mesh", value_name = "MESH")]
        textured: PathBuf,
        #[command(flatten)]
        scene: ViewArgs,
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        /// Lambert shading instead of flat albedo.
        #[arg(long)]
        lambert: bool,
        /// Ambient fraction for Lambert shading.
        #[arg(long, default_value_t = scantex::render::RenderOptions::default().ambient, allow_negative_numbers = true, value_parser = number_in(0.0f32..=1.0))]
        ambient: f32,
        /// Direction towards the light (world frame), for Lambert shading.
        #[arg(long, default_value_t = Vec3(scantex::render::Lighting::default().light_dir))]
        light: Vec3,
        /// Exposure gain for every image.
        #[arg(long, default_value_t = scantex::render::Lighting::default().exposure, allow_negative_numbers = true, value_parser = number_in(0.0f32..=1e6))]
        gain: f32,
        /// White-balance gains R,G,B for every image.
        #[arg(long, default_value_t = Vec3(scantex::render::Lighting::default().white_balance.map(f64::from)))]
        wb: Vec3,
        /// JSON file of per-image lighting ({"name": {"exposure", "white_balance", "light_dir"}}),
        /// overriding --gain, --wb and --light for the images it names.
        #[arg(long)]
        lighting: Option<PathBuf>,
    },
    /// Compare a textured mesh with held-out photographs (virtual rephotography).
    Eval {
        /// Textured mesh to evaluate (OBJ with MTL and texture, or GLB).
        #[arg(long = "mesh", value_name = "MESH")]
        textured: PathBuf,
        #[command(flatten)]
        scene: ViewArgs,
        /// Fit one gain per channel per image before PSNR and SSIM.
        #[arg(long)]
        gain_fit: bool,
        /// Also write the report as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// Texture a scanned mesh from its calibrated photographs: atlas, binding, gains,
    /// resampling, merging, restoration and synthesis of what no photograph saw. Writes
    /// <out>/model.obj (+ .mtl and the atlas), model.glb and report.json.
    Texture {
        #[command(flatten)]
        scene: SceneArgs,
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        /// Atlas side in texels, or auto: from the photographs (two texels per axis for each
        /// pixel that sees the surface in its best view, rounded up to a power of two).
        #[arg(long, default_value_t = scantex::pipeline::TextureOptions::default().size, allow_negative_numbers = true)]
        size: scantex::pipeline::AtlasSize,
        /// The largest side --size auto may choose: when the photographs support more
        /// texels than such a page holds, charts go onto several pages of this side (UDIM
        /// tiles model.1001.png, model.1002.png, ...).
        #[arg(long, default_value_t = scantex::pipeline::TextureOptions::default().max_size, allow_negative_numbers = true, value_parser = number_in(scantex::atlas::SIZE_RANGE))]
        max_size: u32,
        /// At most this many atlas pages: the texel density is lowered until the charts fit
        /// (1: one page, as older versions made). Default: as many as the density needs.
        #[arg(long, allow_negative_numbers = true, value_parser = number_in(1u32..=u32::MAX))]
        pages: Option<u32>,
        /// How much memory the run may use: a share of the machine (75%), a size (12G,
        /// 512M) or off. --size auto makes pages smaller when a page of --max-size would not
        /// fit; a run that cannot fit fails at once, saying what it would need.
        #[arg(long, default_value_t = scantex::pipeline::TextureOptions::default().memory_limit)]
        memory_limit: scantex::memory::MemoryLimit,
        /// Texels per unit of scene length instead of a density from the photographs; the
        /// charts fill as many pages (of --size, or of --max-size with --size auto) as they
        /// need.
        #[arg(long, allow_negative_numbers = true, value_parser = number_in(f64::MIN_POSITIVE..=f64::MAX))]
        texel_density: Option<f64>,
        #[command(flatten)]
        atlas: AtlasArgs,
        /// Keep the UVs the mesh arrived with (unwrapped by another tool: Blender, xatlas,
        /// Metashape) and texture into that layout, instead of making a new atlas; --size
        /// still sets the page. UVs must lie in [0, 1].
        #[arg(long)]
        keep_uvs: bool,
        /// paper: the paper's binding and resampling as written; robust: per-texel occlusion,
        /// projected-area weights, photo-consistency rejection.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().method)]
        method: scantex::bind::Method,
        /// Atlas file format beside the OBJ: png, png16 or exr (the GLB always embeds PNG).
        #[arg(long, default_value_t = scantex::pipeline::TextureFormat::default())]
        format: scantex::pipeline::TextureFormat,
        /// Important view direction V for the atlas (from the eye towards the object), x,y,z.
        /// Default: the photographs' mean viewing direction, when they have one.
        #[arg(long, value_parser = parse_vec3, conflicts_with = "no_view_weight")]
        view_dir: Option<[f64; 3]>,
        /// No visual-importance weight in the atlas.
        #[arg(long)]
        no_view_weight: bool,
        /// Background colour for the background test: auto (estimated per photograph), off,
        /// or r,g,b in [0, 1]. Masks, when the scene has them, decide instead.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().background)]
        background: scantex::bind::Background,
        /// RGB distance below which a vertex's sample counts as background.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().background_threshold, allow_negative_numbers = true, value_parser = number_in(0.0f32..=2.0))]
        background_threshold: f32,
        /// Robust method: photo-consistency check per vertex, per face, or off.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().consistency)]
        consistency: scantex::bind::Consistency,
        /// Robust method: views farther than this (RGB distance) from the median of a
        /// vertex's views, and than 3 robust deviations, are dropped.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().consistency_threshold, allow_negative_numbers = true, value_parser = number_in(0.0f32..=2.0))]
        consistency_threshold: f32,
        /// Robust method: exponent on the projected-area view weight.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().weight_power, allow_negative_numbers = true, value_parser = number_in(scantex::bind::WEIGHT_POWER_RANGE))]
        weight_power: f64,
        /// Per-photograph gains solved from overlaps: off, exposure (gain per channel),
        /// lighting (also smooth shading by surface normal), directional (also one distant
        /// light plus ambient: a lamp or the sun) or auto (whichever, with whichever
        /// --delight, best predicts each photograph from the others; report.json gives every
        /// candidate's score). Default: auto, off with --method paper.
        #[arg(long)]
        gains: Option<scantex::photometric::GainModel>,
        /// The shading all photographs share (their average light): off (kept in the
        /// texture), steps (fitted to brightness steps between nearby vertices), global
        /// (fitted to brightness over the normal; reads albedo that follows the normal as
        /// light) or auto (chosen as --gains auto chooses). Default: auto, off with
        /// --method paper.
        #[arg(long, conflicts_with = "no_delight")]
        delight: Option<scantex::photometric::Delight>,
        /// Same as --delight off.
        #[arg(long)]
        no_delight: bool,
        /// Solve no per-photograph exposure, white balance or shading (same as --gains off):
        /// blending alone removes the photographs' differences.
        #[arg(long, conflicts_with = "gains")]
        no_exposure_solve: bool,
        /// How the photographs seen at a texel combine: none (the best-weighted photograph
        /// alone), average (weighted mean) or multiband (multiresolution spline per chart).
        #[arg(long, default_value_t = scantex::merge::MergeOptions::default().merge)]
        merge: scantex::merge::Merge,
        /// Multiband masks: paper (triangles seen with three valid vertices minus the outer
        /// ring), weighted (view weights) or best-view (view weights, finest band from the
        /// best photograph). Default: best-view, paper with --method paper.
        #[arg(long)]
        merge_masks: Option<scantex::merge::Masks>,
        /// Multiband: most pyramid levels per chart (a chart gets log2(longer side) - 3).
        #[arg(long, default_value_t = scantex::merge::MergeOptions::default().levels, allow_negative_numbers = true, value_parser = number_in(scantex::merge::LEVELS_RANGE))]
        levels: u32,
        /// Multiband: centre weight a of the 5-tap pyramid kernel (0.4 as the paper; OpenCV
        /// uses 0.375).
        #[arg(long, default_value_t = scantex::merge::MergeOptions::default().a, allow_negative_numbers = true, value_parser = number_in(scantex::merge::KERNEL_A_RANGE))]
        kernel_a: f32,
        /// Multiband with best-view masks: per face, this many photographs of largest weight
        /// are sampled at every texel; the others at every other texel, for the coarser bands
        /// only (0 = all at every texel; slower, same finest band).
        #[arg(long, default_value_t = scantex::merge::MergeOptions::default().full_views, allow_negative_numbers = true, value_parser = number_in(0usize..=1 << 20))]
        full_views: usize,
        /// Multiband with best-view masks: the finest band blends the fully sampled
        /// photographs by their view weights to this power (0 = equally; larger favours the
        /// best view; inf = the best view alone, which leaves a step where it changes).
        #[arg(long, default_value_t = scantex::merge::MergeOptions::default().fine_exponent, allow_negative_numbers = true, value_parser = number_in(0.0f32..=f32::INFINITY))]
        fine_exponent: f32,
        /// Multiband: leave chart borders as blended, without the smooth per-chart correction
        /// that makes both sides of every border agree.
        #[arg(long)]
        no_seam_levelling: bool,
        /// Leave the texels no photograph saw with the merge's vertex-colour interpolation
        /// instead of restoring them (diffusion of the low band + synthesis of the detail).
        #[arg(long)]
        no_restore: bool,
        /// Restoration's neighbour search: fast (PCA-reduced kd-tree, re-ranked) or paper
        /// (exact kd-tree on full neighbourhoods; slower).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().method)]
        restore_method: scantex::restore::Method,
        /// Largest unseen atlas hole restored, texels; larger ones go to exemplar synthesis (0
        /// = no limit; a region of a million texels takes minutes).
        #[arg(long, default_value_t = scantex::restore::Handing::default().max_hole, allow_negative_numbers = true, value_parser = number_in(0usize..=usize::MAX))]
        max_hole: usize,
        /// Unseen regions at least this many feature scales deep (distance on the surface
        /// from their rim, against the texture's own detail size) go to exemplar synthesis
        /// instead of restoration (inf = none).
        #[arg(long, default_value_t = scantex::restore::Handing::default().min_depth, allow_negative_numbers = true, value_parser = number_in(0.0f64..=f64::INFINITY))]
        min_depth: f64,
        /// Exemplar synthesis of the regions restoration leaves (stage 6): auto (per region,
        /// the square of photographed surface most like its rim, flattened onto its tangent
        /// plane; --debug-dir shows them as exemplar0.png...), off (they keep their vertex
        /// colours), or an image file (one pixel per atlas texel, its top towards up).
        #[arg(long, default_value_t = scantex::synth::SynthOptions::default().exemplar)]
        exemplar: scantex::synth::ExemplarSource,
        /// Stage 6 patch radius, exemplar texels (0 = eight feature scales, 16 to 48).
        #[arg(long, default_value_t = scantex::synth::SynthOptions::default().radius, allow_negative_numbers = true, value_parser = number_in(scantex::synth::RADIUS_RANGE))]
        synth_radius: f64,
        /// Seed of restoration's and synthesis's random choices (the same seed gives the
        /// same bytes).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().seed, allow_negative_numbers = true, value_parser = number_in(0u64..=u64::MAX))]
        seed: u64,
        /// Longest side of the per-photograph depth map, pixels.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().depth_resolution, allow_negative_numbers = true, value_parser = number_in(scantex::bind::DEPTH_RESOLUTION_RANGE))]
        depth_resolution: u32,
        /// Robust method: most photographs sampled per face, the heaviest at its vertices; 0 =
        /// all.
        #[arg(long, default_value_t = scantex::resample::ResampleOptions::default().max_views, allow_negative_numbers = true, value_parser = number_in(0usize..=1 << 20))]
        max_views: usize,
        /// Most views binding keeps per vertex, the heaviest; 0 = all. Binding's memory is
        /// then flat in the number of photographs.
        #[arg(long, default_value_t = scantex::bind::BindOptions::default().max_views, allow_negative_numbers = true, value_parser = number_in(0usize..=1 << 20))]
        vertex_views: usize,
        /// Gutter texels filled by extending chart colours.
        #[arg(long, default_value_t = scantex::resample::ResampleOptions::default().gutter_fill, allow_negative_numbers = true, value_parser = number_in(0u32..=1024))]
        gutter_fill: u32,
        /// Write the stages' pictures here: triangle classes, coverage, masks, restoration
        /// (restore.png: restored, left for stage 6 and why), stage 6's patches (synth.png)
        /// and the atlas layout.
        #[arg(long)]
        debug_dir: Option<PathBuf>,
        /// No progress: neither bars (on a terminal) nor, when standard error goes to a log,
        /// the lines long stages print there (every 30 s, and when a stage of over 5 s
        /// ends). Warnings and errors still print.
        #[arg(short, long)]
        quiet: bool,
    },
    /// Fill the masked pixels of any image (stage 5 on its own): a DCT split, diffusion
    /// inpainting of the low band and multiresolution synthesis of the high band.
    Inpaint {
        /// Image to restore (PNG 8/16-bit, JPEG, EXR; grey or RGB, alpha is dropped).
        image: PathBuf,
        /// Mask of the same size: white = fill.
        #[arg(long)]
        mask: PathBuf,
        /// Output image (.png, .jpg or .exr; PNG keeps a 16-bit input's depth).
        #[arg(short, long)]
        out: PathBuf,
        /// DCT subbands in the low band: auto (the paper's autocorrelation rule) or a number
        /// (0 = pure synthesis, the longer side = pure diffusion).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().kappa)]
        kappa: scantex::restore::Kappa,
        /// Levels of the high-band pyramid (1 to 8).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().levels, allow_negative_numbers = true, value_parser = number_in(scantex::restore::LEVELS_RANGE))]
        levels: usize,
        /// Seed for the choice of source pixels (the same seed gives the same bytes).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().seed, allow_negative_numbers = true, value_parser = number_in(0u64..=u64::MAX))]
        seed: u64,
        /// Neighbour search: fast (PCA-reduced kd-tree with exact re-ranking) or paper (exact
        /// kd-tree on full neighbourhoods; slower).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().method)]
        method: scantex::restore::Method,
        /// Hertzmann's coherence parameter (0 = always take the search's match).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().coherence, allow_negative_numbers = true, value_parser = number_in(0.0f32..=1e6))]
        coherence: f32,
        /// Fast method: source pixels per kernel orientation and window.
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().max_sources, allow_negative_numbers = true, value_parser = number_in(1usize..=1 << 30))]
        max_sources: usize,
        /// Known pixels around a hole that may serve as its source, pixels.
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().margin, allow_negative_numbers = true, value_parser = number_in(1usize..=1 << 16))]
        margin: usize,
        /// Synthesise the high band as it is, without dividing out its local amplitude (the
        /// paper's way; detail fades under intensity ramps).
        #[arg(long)]
        no_contrast_normalisation: bool,
        /// How much of the hole's local mean comes from diffusion instead of synthesis, 0
        /// (the paper) to 1 (closest to the truth at coarse scales, flatter to the eye).
        #[arg(long, default_value_t = scantex::restore::RestoreOptions::default().mean_from_diffusion, allow_negative_numbers = true, value_parser = number_in(0.0f32..=1.0))]
        mean_from_diffusion: f32,
        /// Keep each hole's synthesised detail as it comes, without matching its energy to
        /// the surroundings' (the paper's way; joins between copied pieces add edges).
        #[arg(long)]
        no_detail_match: bool,
        /// Print the report (kappa, per-level counts, timings) as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Synthesise an image of any size from an exemplar (stage 6's 2D core): overlapping
    /// patches at random offsets, each chosen to agree with its neighbours, blended so the
    /// exemplar's colour histogram is kept.
    Synth {
        /// Exemplar image (PNG 8/16-bit, JPEG, EXR; grey or RGB, alpha is dropped).
        exemplar: PathBuf,
        /// Output image (.png, .jpg or .exr; PNG keeps a 16-bit input's depth).
        #[arg(short, long)]
        out: PathBuf,
        /// Output size, WIDTHxHEIGHT pixels.
        #[arg(long, value_parser = parse_size)]
        size: (usize, usize),
        /// Patch radius, pixels (capped so a patch fits in the exemplar).
        #[arg(long, default_value_t = scantex::synth::plane::PlaneOptions::default().radius, allow_negative_numbers = true, value_parser = number_in(2.0f64..=512.0))]
        radius: f64,
        /// Exemplar offsets tried per patch (1 = purely random).
        #[arg(long, default_value_t = scantex::synth::plane::PlaneOptions::default().candidates, allow_negative_numbers = true, value_parser = number_in(1usize..=4096))]
        candidates: usize,
        /// Random seed (the same seed gives the same bytes).
        #[arg(long, default_value_t = scantex::synth::plane::PlaneOptions::default().seed, allow_negative_numbers = true, value_parser = number_in(0u64..=u64::MAX))]
        seed: u64,
    },
    /// Give a mesh texture coordinates: charts, stretch minimisation, packing (stage 1).
    Param {
        /// Input mesh (.obj, .ply, .gltf, .glb); existing UVs are ignored.
        mesh: PathBuf,
        /// Output mesh with UVs (.obj, .ply or .glb); a layout picture is written beside it
        /// as <stem>_layout.png.
        #[arg(short, long)]
        out: PathBuf,
        /// Atlas size in texels.
        #[arg(long, default_value_t = scantex::atlas::AtlasOptions::default().pack.size, allow_negative_numbers = true, value_parser = number_in(scantex::atlas::SIZE_RANGE))]
        size: u32,
        #[command(flatten)]
        atlas: AtlasArgs,
        /// Viewing direction V of the important view (from the eye towards the object), x,y,z.
        #[arg(long, value_parser = parse_vec3)]
        view_dir: Option<[f64; 3]>,
        /// Write the report as JSON here.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Fixed texel density (texels per unit of 3D length): charts fill as many pages as
        /// they need (UDIM tiles: page p has u in [p, p+1]). Default: the largest density
        /// that fits one page.
        #[arg(long)]
        texel_density: Option<f64>,
        /// One texel density for every chart, instead of shares by weighted stretch energy.
        #[arg(long)]
        uniform_density: bool,
    },
    /// Measure the UV atlas a mesh already has (from scantex or any other unwrapper): UV
    /// islands, stretch, flips, seams, utilisation and overlapping texels; prints JSON.
    UvReport {
        /// Mesh with texture coordinates (.obj, .ply, .gltf, .glb).
        mesh: PathBuf,
        /// Texture size (texels per side, per UDIM page) for utilisation and overlaps.
        #[arg(long, default_value_t = scantex::atlas::AtlasOptions::default().pack.size, allow_negative_numbers = true, value_parser = number_in(scantex::atlas::SIZE_RANGE))]
        size: u32,
    },
    /// Generate a sample scene with known true colours.
    Sample {
        /// Output directory.
        #[arg(short, long)]
        out: PathBuf,
        /// Photograph this textured mesh instead of the procedural torus (its bare mesh
        /// becomes the scene's input).
        #[arg(long)]
        from_mesh: Option<PathBuf>,
        /// World up axis for camera placement: x, y or z.
        #[arg(long, default_value_t = Axis::of(scantex::sample::SampleOptions::default().up))]
        up: Axis,
        /// Number of photographs.
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().photos, allow_negative_numbers = true, value_parser = number_in(1usize..=100_000))]
        photos: usize,
        /// Random seed.
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().seed, allow_negative_numbers = true, value_parser = number_in(0u64..=u64::MAX))]
        seed: u64,
        /// Largest per-photograph exposure and white-balance deviation (0.25 = +-25%).
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().gain_range, allow_negative_numbers = true, value_parser = number_in(scantex::sample::GAIN_RANGE_LIMITS))]
        gain_range: f64,
        /// Light every photograph from the same direction (default: a random one each).
        #[arg(long)]
        fixed_light: bool,
        /// Leave this sector of azimuth, degrees, unphotographed (a side no input sees);
        /// held-out views still go all around and heldout/unseen/ marks their pixels whose
        /// surface no input saw (for `eval`'s unseen-region scores).
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().unseen_sector, allow_negative_numbers = true, value_parser = number_in(scantex::sample::SECTOR_RANGE))]
        unseen_sector: f64,
        /// Held-out photographs.
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().heldout, allow_negative_numbers = true, value_parser = number_in(0usize..=100_000))]
        heldout: usize,
        /// Procedural object without --from-mesh: torus (colours independent of orientation)
        /// or jar (white top, saturated sides: albedo that follows the normal).
        #[arg(long, default_value_t = scantex::sample::SampleOptions::default().object, conflicts_with = "from_mesh")]
        object: scantex::sample::SampleObject,
    },
}

/// A value parser for numbers in `range` whose message gives the range, for negative
/// numbers too (clap would otherwise take `-5` for a flag). Ranges the library validates come
/// from the library's own constants.
fn number_in<T>(
    range: std::ops::RangeInclusive<T>,
) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: std::str::FromStr + PartialOrd + std::fmt::Display + Copy + Send + Sync + 'static,
{
    let (lo, hi) = (*range.start(), *range.end());
    move |s: &str| {
        let hi_text = hi.to_string();
        let range = if hi_text == "inf" || hi_text == u64::MAX.to_string() {
            format!("{lo} or more")
        } else {
            format!("from {lo} to {hi}")
        };
        match s.trim().parse::<T>() {
            Ok(v) if v >= lo && v <= hi => Ok(v),
            Ok(_) => Err(format!("{s} is out of range: expected a number {range}")),
            Err(_) => Err(format!(
                "'{s}' is not a valid number: expected a number {range}"
            )),
        }
    }
}

/// Three numbers `x,y,z` on the command line (shown as such in `--help` defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Vec3([f64; 3]);

impl std::fmt::Display for Vec3 {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.0;
        write!(f, "{x},{y},{z}")
    }
}

impl std::str::FromStr for Vec3 {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        parse_vec3(s).map(Vec3)
    }
}

/// A world axis: x, y or z.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    /// The axis `v` points along (z for anything else).
    fn of(v: nalgebra::Vector3<f64>) -> Axis {
        match (v.x != 0.0, v.y != 0.0) {
            (true, _) => Axis::X,
            (_, true) => Axis::Y,
            _ => Axis::Z,
        }
    }

    fn vector(self) -> nalgebra::Vector3<f64> {
        match self {
            Axis::X => nalgebra::Vector3::x(),
            Axis::Y => nalgebra::Vector3::y(),
            Axis::Z => nalgebra::Vector3::z(),
        }
    }
}

impl std::fmt::Display for Axis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Axis::X => "x",
            Axis::Y => "y",
            Axis::Z => "z",
        })
    }
}

/// WIDTHxHEIGHT, each from 1 to the largest side `scantex synth` writes.
fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let max = scantex::synth::plane::MAX_SIDE;
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT (for example 512x512)"))?;
    let side = |v: &str| match v.trim().parse::<usize>() {
        Ok(n) if (1..=max).contains(&n) => Ok(n),
        _ => Err(format!(
            "'{v}' in '{s}' is not a side from 1 to {max} pixels"
        )),
    };
    Ok((side(w)?, side(h)?))
}

fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|t| {
            t.trim()
                .parse::<f64>()
                .map_err(|_| format!("'{t}' is not a number"))
        })
        .collect::<Result<_, _>>()?;
    match v.as_slice() {
        [a, b, c] if v.iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => Err(format!("expected three numbers x,y,z, got '{s}'")),
    }
}

/// The atlas options `texture` and `param` share.
#[derive(Args)]
struct AtlasArgs {
    /// Gutter between charts, in texels.
    #[arg(long, default_value_t = scantex::atlas::AtlasOptions::default().pack.gutter, allow_negative_numbers = true, value_parser = number_in(0u32..=16384))]
    gutter: u32,
    /// k in the visual importance w = 1 / (<N, V> + k); more than 1.
    #[arg(long, default_value_t = scantex::atlas::AtlasOptions::default().flatten.stretch.k, allow_negative_numbers = true)]
    k: f64,
    /// Smallest height/base ratio of a UV triangle (shape barrier), in [0, 0.5).
    #[arg(long, default_value_t = scantex::atlas::AtlasOptions::default().flatten.stretch.alpha, allow_negative_numbers = true)]
    alpha: f64,
}

impl AtlasArgs {
    fn apply(&self, opts: &mut scantex::atlas::AtlasOptions) {
        opts.pack.gutter = self.gutter;
        opts.flatten.stretch.k = self.k;
        opts.flatten.stretch.alpha = self.alpha;
    }
}

/// How every command is pointed at a scene: a directory, explicit paths, or both.
#[derive(Args)]
struct SceneArgs {
    #[command(flatten)]
    views: ViewArgs,
    /// Mesh file (.obj, .ply, .gltf, .glb); overrides the scene directory's.
    #[arg(long)]
    mesh: Option<PathBuf>,
}

impl SceneArgs {
    fn spec(self) -> SceneSpec {
        SceneSpec {
            mesh: self.mesh,
            ..self.views.spec()
        }
    }
}

/// The cameras and photographs of a scene (for render and eval, whose --mesh is the mesh under
/// test rather than the scene's).
#[derive(Args)]
struct ViewArgs {
    /// Scene directory holding a mesh file, sparse/ (or sparse/0/), images/ and optionally masks/.
    scene: Option<PathBuf>,
    /// COLMAP model directory (text or binary), a Meshroom cameras.sfm, a Bundler .out (its
    /// image list beside it as <file>.list.txt or list.txt), a VisualSFM .nvm or an OpenMVS
    /// interface .mvs (Bundler and VisualSFM store no image size: it comes from the
    /// photographs); overrides the scene directory's (sparse/, sparse/0/, cameras.sfm, or its
    /// one .nvm or .mvs).
    #[arg(long)]
    colmap: Option<PathBuf>,
    /// Photographs directory; overrides the scene directory's images/ (or, for a camera
    /// file given alone with --colmap, the images/ beside it).
    #[arg(long)]
    images: Option<PathBuf>,
    /// Object masks directory (white = object); overrides the scene directory's masks/.
    /// Photographs with an alpha channel that hides some pixels are masked by it as well.
    #[arg(long)]
    masks: Option<PathBuf>,
    /// Leave out registered images whose photograph file is absent instead of failing.
    #[arg(long)]
    skip_missing: bool,
    /// Leave out registered images whose photograph is unreadable, truncated, corrupt or of
    /// another size than its camera, with a warning (listed in report.json), instead of failing.
    #[arg(long)]
    skip_bad_images: bool,
}

impl ViewArgs {
    fn spec(self) -> SceneSpec {
        SceneSpec {
            dir: self.scene,
            mesh: None,
            colmap: self.colmap,
            images: self.images,
            masks: self.masks,
            skip_missing: self.skip_missing,
            skip_bad: self.skip_bad_images,
        }
    }
}

fn run(cli: Cli) -> scantex::Result<ExitCode> {
    match cli.command {
        Command::Render {
            textured,
            scene,
            out,
            lambert,
            ambient,
            light,
            gain,
            wb,
            lighting,
        } => {
            let opts = scantex::render::RenderOptions {
                shading: if lambert {
                    Shading::Lambert
                } else {
                    Shading::Flat
                },
                ambient,
                lighting: Lighting {
                    exposure: gain,
                    white_balance: wb.0.map(|v| v as f32),
                    light_dir: light.0,
                },
                ..Default::default()
            };
            let per_image = lighting
                .as_deref()
                .map(scantex::render::read_lighting)
                .transpose()?;
            let n = scantex::render::render_scene(
                &textured,
                &scene.spec(),
                &out,
                &opts,
                per_image.as_ref(),
            )?;
            eprintln!("rendered {n} views into {}", out.display());
            Ok(ExitCode::SUCCESS)
        }
        Command::Eval {
            textured,
            scene,
            gain_fit,
            json,
        } => {
            let staged = json
                .as_deref()
                .map(|p| {
                    let label = scantex::io::staging::label_of(p);
                    scantex::io::Staged::begin(&label, &[scantex::io::staging::dir_of(p)])
                })
                .transpose()?;
            let report =
                scantex::eval::evaluate_scene(&textured, &scene.spec(), &EvalOptions { gain_fit })?;
            print_out(&report.to_string());
            if let (Some(p), Some(mut staged)) = (json, staged) {
                let s = serde_json::to_string_pretty(&report).expect("report serialises");
                staged.write(&p, s.as_bytes())?;
                staged.commit()?;
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Texture {
            scene,
            out,
            size,
            max_size,
            pages,
            memory_limit,
            texel_density,
            atlas,
            keep_uvs,
            method,
            format,
            view_dir,
            no_view_weight,
            background,
            background_threshold,
            consistency,
            consistency_threshold,
            weight_power,
            gains,
            no_delight,
            delight,
            no_exposure_solve,
            merge,
            merge_masks,
            levels,
            kernel_a,
            full_views,
            fine_exponent,
            no_seam_levelling,
            no_restore,
            restore_method,
            max_hole,
            min_depth,
            exemplar,
            synth_radius,
            seed,
            depth_resolution,
            max_views,
            vertex_views,
            gutter_fill,
            debug_dir,
            quiet,
        } => {
            use scantex::pipeline::{TextureOptions, ViewWeight};
            let mut opts = TextureOptions::for_method(method);
            atlas.apply(&mut opts.atlas);
            opts.size = size;
            opts.max_size = max_size;
            opts.max_pages = pages;
            opts.memory_limit = memory_limit;
            opts.atlas.pack.texels_per_unit = texel_density;
            opts.keep_uvs = keep_uvs;
            opts.view_weight = match (view_dir, no_view_weight) {
                (_, true) => ViewWeight::Off,
                (Some(d), false) => ViewWeight::Direction(d),
                (None, false) => ViewWeight::MeanPhotoDirection,
            };
            if let Some(g) = gains {
                opts.photometric.model = g;
            }
            if no_exposure_solve {
                opts.photometric.model = scantex::photometric::GainModel::Off;
            }
            if let Some(d) = delight {
                opts.photometric.delight = d;
            }
            if no_delight {
                opts.photometric.delight = scantex::photometric::Delight::Off;
            }
            opts.merge.merge = merge;
            if let Some(m) = merge_masks {
                opts.merge.masks = m;
            }
            opts.merge.levels = levels;
            opts.merge.a = kernel_a;
            opts.merge.full_views = full_views;
            opts.merge.fine_exponent = fine_exponent;
            opts.merge.level_seams = !no_seam_levelling;
            opts.restoration = if no_restore {
                scantex::pipeline::Restoration::Off
            } else {
                scantex::pipeline::Restoration::Synthesis {
                    options: scantex::restore::RestoreOptions {
                        method: restore_method,
                        seed,
                        ..Default::default()
                    },
                    handing: scantex::restore::Handing {
                        max_hole,
                        min_depth,
                    },
                }
            };
            opts.synth = scantex::synth::SynthOptions {
                exemplar,
                radius: synth_radius,
                seed,
                ..Default::default()
            };
            opts.bind.background = background;
            opts.bind.background_threshold = background_threshold;
            opts.bind.consistency = consistency;
            opts.bind.consistency_threshold = consistency_threshold;
            opts.bind.weight_power = weight_power;
            opts.bind.depth_resolution = depth_resolution;
            opts.resample.gutter_fill = gutter_fill;
            opts.resample.max_views = max_views;
            opts.bind.max_views = vertex_views;
            opts.format = format;
            let progress: Box<dyn scantex::progress::Progress> = if quiet {
                Box::new(scantex::progress::Silent)
            } else {
                scantex::progress::for_stderr()
            };
            let result = scantex::pipeline::texture_scene(
                &scene.spec(),
                &opts,
                &out,
                debug_dir.as_deref(),
                progress.as_ref(),
            )?;
            let r = &result.report;
            let total = r.seconds;
            // Triangle classes are counted over the whole mesh, the same on every page.
            let c = &r.pages[0].resample;
            let pages = match r.pages.len() {
                1 => String::new(),
                n => format!("{n} pages of "),
            };
            eprintln!(
                "textured {} faces from {} photographs into {pages}a {}{} atlas in {:.1} s: {} \
                 of {} vertices bound; triangles {} green, {} blue, {} red; wrote {}",
                r.faces,
                r.photos,
                r.atlas_size,
                if r.auto_size.is_some() { " (auto)" } else { "" },
                total,
                r.vertices_bound,
                r.vertices,
                c.green,
                c.blue,
                c.red,
                out.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Param {
            mesh,
            out,
            size,
            atlas,
            view_dir,
            report,
            texel_density,
            uniform_density,
        } => {
            let mut opts = scantex::atlas::AtlasOptions::default();
            opts.pack.size = size;
            atlas.apply(&mut opts);
            opts.flatten.stretch.view_dir = view_dir.map(nalgebra::Vector3::from);
            opts.pack.texels_per_unit = texel_density;
            opts.budget_by_energy = !uniform_density;
            let rep = scantex::pipeline::param_file(
                &mesh,
                &out,
                report.as_deref(),
                &opts,
                scantex::progress::for_stderr().as_ref(),
            )?;
            let json = serde_json::to_string_pretty(&rep).expect("report serialises");
            print_out(&format!("{json}\n"));
            Ok(ExitCode::SUCCESS)
        }
        Command::UvReport { mesh, size } => {
            let (input, _) = scantex::io::read_mesh(&mesh)?;
            let rep = scantex::atlas::measure(&input, size)?;
            let json = serde_json::to_string_pretty(&rep).expect("report serialises");
            print_out(&format!("{json}\n"));
            Ok(ExitCode::SUCCESS)
        }
        Command::Sample {
            out,
            from_mesh,
            up,
            photos,
            seed,
            gain_range,
            fixed_light,
            unseen_sector,
            heldout,
            object,
        } => {
            let opts = scantex::sample::SampleOptions {
                up: up.vector(),
                photos,
                heldout,
                seed,
                gain_range,
                vary_light: !fixed_light,
                unseen_sector,
                object,
                ..Default::default()
            };
            let report = scantex::sample::generate_to(from_mesh.as_deref(), &opts, &out)?;
            eprintln!(
                "wrote {} ({:.2} MB)",
                out.display(),
                report.bytes as f64 / 1e6
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Inpaint {
            image,
            mask,
            out,
            kappa,
            levels,
            seed,
            method,
            coherence,
            max_sources,
            margin,
            no_contrast_normalisation,
            mean_from_diffusion,
            no_detail_match,
            json,
        } => {
            let opts = scantex::restore::RestoreOptions {
                method,
                kappa,
                levels,
                seed,
                coherence,
                max_sources,
                margin,
                normalise_contrast: !no_contrast_normalisation,
                mean_from_diffusion,
                match_detail: !no_detail_match,
                ..Default::default()
            };
            let label = scantex::io::staging::label_of(&out);
            scantex::io::image::planar_output_format(&out)?;
            let staged = scantex::io::Staged::begin(&label, &[scantex::io::staging::dir_of(&out)])?;
            let (img, depth) = scantex::io::image::read_planar(&image)?;
            let (m, mw, mh) = scantex::io::image::read_mask(&mask)?;
            if (mw, mh) != (img.width, img.height) {
                return Err(scantex::Error::parse(
                    &mask,
                    scantex::Location::File,
                    format!(
                        "the mask is {mw}x{mh} but the image {} is {}x{}",
                        image.display(),
                        img.width,
                        img.height
                    ),
                ));
            }
            let (restored, report) = scantex::restore::inpaint(&img, &m, None, &opts)?;
            scantex::io::image::stage_planar(staged, &out, &restored, depth)?;
            if json {
                print_out(&format!(
                    "{}\n",
                    serde_json::to_string_pretty(&report).expect("report serialises")
                ));
            } else {
                eprintln!(
                    "filled {} pixels (kappa {}{}) in {:.2} s; wrote {}",
                    report.texels,
                    report.kappa,
                    if report.kappa_auto { ", automatic" } else { "" },
                    report.seconds,
                    out.display()
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Synth {
            exemplar,
            out,
            size,
            radius,
            candidates,
            seed,
        } => {
            let opts = scantex::synth::plane::PlaneOptions {
                radius,
                candidates,
                seed,
            };
            let label = scantex::io::staging::label_of(&out);
            scantex::io::image::planar_output_format(&out)?;
            let staged = scantex::io::Staged::begin(&label, &[scantex::io::staging::dir_of(&out)])?;
            let (img, depth) = scantex::io::image::read_planar(&exemplar)?;
            let t = std::time::Instant::now();
            let made = scantex::synth::plane::synthesize_image(&img, size.0, size.1, &opts)?;
            let secs = t.elapsed().as_secs_f64();
            scantex::io::image::stage_planar(staged, &out, &made, depth)?;
            eprintln!(
                "synthesised {}x{} from a {}x{} exemplar in {:.2} s; wrote {}",
                size.0,
                size.1,
                img.width,
                img.height,
                secs,
                out.display()
            );
            Ok(ExitCode::SUCCESS)
        }
        Command::Info { scene, json } => {
            let scene = Scene::load(&scene.spec())?;
            let report = scantex::info::info(&scene);
            if json {
                print_out(&format!(
                    "{}\n",
                    serde_json::to_string_pretty(&report).expect("report serialises")
                ));
            } else {
                print_out(&report.to_string());
            }
            // Missing or broken photographs make the scene unusable for texturing: say so in
            // the exit code so batch jobs stop here. The report already probed every photo;
            // probe again only to name the first bad one.
            let bad = report
                .colmap
                .as_ref()
                .is_some_and(|c| c.photos_missing_count + c.photos_bad_count > 0);
            match if bad { scene.check_photos() } else { Ok(()) } {
                Ok(()) => Ok(ExitCode::SUCCESS),
                Err(e) => {
                    eprintln!("scantex: error: {e}");
                    Ok(ExitCode::FAILURE)
                }
            }
        }
    }
}

/// On SIGINT, SIGTERM or SIGHUP (a user's Ctrl-C, a batch scheduler's time-out, a closed
/// terminal): removes the run's staged outputs, so nothing half-written stays behind, and ends
/// the process with the shell's status for that signal (128 + its number).
fn remove_outputs_on_signals() {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        match signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) {
            Ok(mut signals) => {
                std::thread::spawn(move || {
                    if let Some(sig) = signals.forever().next() {
                        scantex::io::staging::abort_all();
                        eprintln!("scantex: stopped by signal {sig}; no output was written");
                        std::process::exit(128 + sig);
                    }
                });
            }
            Err(e) => eprintln!("scantex: warning: cannot watch for signals ({e})"),
        }
    }
}

/// Exit status for bad input or option values (the library's errors other than internal ones).
const EXIT_INPUT: u8 = 1;
/// Exit status for a failed internal check: a bug in scantex, not in the input.
const EXIT_INTERNAL: u8 = 3;

/// Writes `text` to standard output. A closed pipe (`scantex info --json | head -1`) ends the
/// program quietly with success: the reader has what it wanted.
fn print_out(text: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("scantex: error: cannot write to standard output: {e}");
        std::process::exit(EXIT_INPUT.into());
    }
}

fn main() -> ExitCode {
    if !cpu_supports_build() {
        // A static message: on such a CPU even copying a string may use what it lacks.
        eprintln!("scantex: error: {CPU_MESSAGE}");
        return ExitCode::from(EXIT_INPUT);
    }
    let cli = Cli::parse();
    if cli.threads > 0 {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(cli.threads.into())
            .build_global();
        if let Err(e) = pool {
            eprintln!(
                "scantex: error: cannot start {} worker threads: {e}",
                cli.threads
            );
            return ExitCode::from(EXIT_INPUT);
        }
    }
    remove_outputs_on_signals();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("scantex: error: {e}");
            ExitCode::from(match e {
                scantex::Error::Internal(_) => EXIT_INTERNAL,
                _ => EXIT_INPUT,
            })
        }
    }
}

/// Whether this CPU has the instructions the build was allowed to use: an x86-64 build for
/// x86-64-v3 (`.cargo/config.toml`) would otherwise stop on an illegal instruction somewhere
/// in the work, with no word of why. Checked first thing in `main` (the standard library's
/// start-up code is built for any x86-64). The CPUID bits are read directly:
/// `is_x86_feature_detected!` answers `true` without asking the CPU for every feature the
/// build enables.
#[allow(unused_unsafe)]
fn cpu_supports_build() -> bool {
    #[cfg(all(target_arch = "x86_64", target_feature = "avx2"))]
    {
        use std::arch::x86_64::{__cpuid, __cpuid_count, _xgetbv};
        let bit = |r: u32, b: u32| r >> b & 1 == 1;
        // SAFETY: CPUID exists on every x86-64 CPU; XGETBV is executed only where CPUID says
        // the OS enabled it (OSXSAVE).
        unsafe {
            let l1 = __cpuid(1);
            let l7 = __cpuid_count(7, 0);
            let ext = __cpuid(0x8000_0001);
            let osxsave = bit(l1.ecx, 27);
            // The OS saves the SSE and AVX registers on a context switch.
            let ymm = osxsave && _xgetbv(0) & 0b110 == 0b110;
            ymm && bit(l1.ecx, 28) // AVX
                && bit(l1.ecx, 12) // FMA
                && bit(l1.ecx, 22) // MOVBE
                && bit(l1.ecx, 29) // F16C
                && bit(l7.ebx, 5) // AVX2
                && bit(l7.ebx, 3) // BMI1
                && bit(l7.ebx, 8) // BMI2
                && bit(ext.ecx, 5) // LZCNT
        }
    }
    #[cfg(not(all(target_arch = "x86_64", target_feature = "avx2")))]
    true
}

/// What `main` says when [`cpu_supports_build`] refuses the CPU.
const CPU_MESSAGE: &str = "this build of scantex needs an x86-64-v3 CPU (AVX2, FMA, F16C, \
    BMI1/2, LZCNT, MOVBE: Intel Haswell, AMD Excavator or later); build one for this CPU with \
    RUSTFLAGS=\"-C target-cpu=x86-64\" cargo build --release --locked";

#[cfg(test)]
mod tests {
    /// The machines the tests run on have what the build uses: the check reads the CPU
    /// itself and accepts it.
    #[test]
    fn this_cpu_runs_this_build() {
        assert!(super::cpu_supports_build());
    }

    /// clap's own consistency checks (duplicate flags and the like) on every subcommand.
    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
