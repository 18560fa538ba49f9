//! Stage 6: exemplar patch synthesis on the surface for the regions no photograph saw and
//! restoration left (`restore::Unrestored::regions`). Each region gets a smooth low band that
//! continues the colours at its rim from the colour photographed surface of the same shape
//! has (`prior`) and detail from an exemplar (a square of the surface the
//! photographs saw, flattened onto its tangent plane and chosen by orientation, colour and
//! place, or the user's image), pasted in
//! overlapping surface patches and blended so that the exemplar's histogram is kept
//! (`surface`, `plane`). The 2D core also runs on its own ([`plane::synthesize`],
//! `scantex synth`).

mod flat;
mod pick;
pub mod plane;
mod prior;
mod surface;

use crate::atlas::Atlas;
use crate::error::{Error, Result};
use crate::mesh::{FaceId, Mesh};
use crate::resample::Resampled;
use crate::restore::{Handover, Unrestored};
use crate::rng::SplitMix64;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;
use surface::{Layout, Source};

/// Where stage 6 takes its exemplars from.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ExemplarSource {
    /// No stage 6: the regions restoration left keep their vertex colours.
    Off,
    /// Per region, the square of the photographed surface most like the region's rim,
    /// flattened onto its tangent plane. Default.
    #[default]
    Auto,
    /// This image for every region, one pixel per atlas texel, its top towards "up".
    File(PathBuf),
}

impl std::fmt::Display for ExemplarSource {
    /// The text `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ExemplarSource::Off => f.write_str("off"),
            ExemplarSource::Auto => f.write_str("auto"),
            ExemplarSource::File(p) => write!(f, "{}", p.display()),
        }
    }
}

impl std::str::FromStr for ExemplarSource {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "off" => Ok(ExemplarSource::Off),
            "auto" => Ok(ExemplarSource::Auto),
            "" => Err("expected auto, off or an image file".into()),
            p => Ok(ExemplarSource::File(PathBuf::from(p))),
        }
    }
}

/// Options for [`synthesize`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SynthOptions {
    /// Where exemplars come from. Default: [`ExemplarSource::Auto`].
    pub exemplar: ExemplarSource,
    /// Patch radius, exemplar texels; 0 = eight feature scales of the observed texture,
    /// between 16 and 48. Default: 0.
    pub radius: f64,
    /// Exemplar offsets tried per patch; the one agreeing best with the patches already
    /// placed wins. Default: 16.
    pub candidates: usize,
    /// Random seed (patch order and offsets): the same seed gives the same bytes. Default:
    /// restoration's ([`crate::restore::RestoreOptions::default`]), as `--seed` sets both.
    pub seed: u64,
    /// Keep which patch won each texel ([`Synthesized::patches`]), for `--debug-dir`'s
    /// `synth.png` (8 bytes per texel written). Default: false.
    pub keep_patch_map: bool,
}

impl Default for SynthOptions {
    fn default() -> Self {
        SynthOptions {
            exemplar: ExemplarSource::Auto,
            radius: 0.0,
            candidates: 16,
            seed: crate::restore::RestoreOptions::default().seed,
            keep_patch_map: false,
        }
    }
}

/// The smallest exemplar image side stage 6 takes, pixels (a patch of the smallest radius
/// fits).
pub const MIN_EXEMPLAR_SIDE: u32 = 16;

/// Patch radii `radius` may take, texels (0 = automatic).
pub const RADIUS_RANGE: std::ops::RangeInclusive<f64> = 0.0..=512.0;

impl SynthOptions {
    /// Checks the values.
    pub fn validate(&self) -> Result<()> {
        if !RADIUS_RANGE.contains(&self.radius) || (self.radius > 0.0 && self.radius < 4.0) {
            return Err(Error::option(
                "synth_radius",
                format!(
                    "{} texels: expected 0 (automatic) or a radius from 4 to 512",
                    self.radius
                ),
            ));
        }
        if self.candidates == 0 {
            return Err(Error::option("synth_candidates", "must be at least 1"));
        }
        Ok(())
    }
}

/// Where one region's exemplar came from.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum ExemplarUsed {
    /// A square of the photographed surface flattened onto its tangent plane.
    Surface {
        /// The face it is centred on.
        face: u32,
        /// Its centre (the face's centroid), scene frame.
        centre: [f64; 3],
        /// Side, texels.
        size: usize,
    },
    /// The user's image.
    File,
    /// None fitted (no crop of seen texels large enough): the low band alone.
    None,
}

/// What stage 6 did for one region.
#[derive(Debug, Clone, Serialize)]
pub struct RegionReport {
    /// Faces.
    pub faces: usize,
    /// Unseen texels written.
    pub texels: u64,
    /// Largest distance from the rim on the surface, texels.
    pub depth_texels: f64,
    /// Why restoration handed it over.
    pub reason: Handover,
    /// Its exemplar.
    pub exemplar: ExemplarUsed,
    /// Patches grown over it.
    pub patches: usize,
}

/// The low band's start and end averaged over the regions' corner groups (linear colour, 0
/// where there are none): those fixed to their rim's texels, and the inner ones the harmonic
/// correction solves for. An inner mean far from the rim's says how much of the regions'
/// colour comes from the band's start (the vertex-colour fill and the shape prior) rather
/// than from their rims (docs/decisions.md, "The band's interior against its rim").
#[derive(Debug, Clone, Copy, Default, Serialize, PartialEq)]
pub struct BandSummary {
    /// Corner groups fixed to the colour of their rim.
    pub rim_groups: usize,
    /// Their mean start, before they were fixed.
    pub rim_start: [f32; 3],
    /// Their mean fixed colour.
    pub rim_fixed: [f32; 3],
    /// Corner groups inside the regions (solved for).
    pub inner_groups: usize,
    /// Their mean start.
    pub inner_start: [f32; 3],
    /// Their mean value after the correction.
    pub inner_end: [f32; 3],
}

/// What stage 6 did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SynthReport {
    /// Per region, in order of their first face.
    pub regions: Vec<RegionReport>,
    /// Texels written.
    pub texels: u64,
    /// Of those, texels no patch reached (low band only).
    pub texels_low_only: u64,
    /// Patches in all.
    pub patches: usize,
    /// Patch radius used, exemplar texels.
    pub radius: f64,
    /// The direction taken as up (the photographs' mean up), scene frame.
    pub up: [f64; 3],
    /// The low band at the regions' rims and inside them.
    pub low_band: BandSummary,
    /// Seconds: low band, exemplars, patches, baking, in all.
    pub seconds_low_band: f64,
    /// See `seconds_low_band`.
    pub seconds_exemplars: f64,
    /// See `seconds_low_band`.
    pub seconds_patches: f64,
    /// See `seconds_low_band`.
    pub seconds_bake: f64,
    /// See `seconds_low_band`.
    pub seconds: f64,
}

/// What [`synthesize`] made besides the atlas colours.
#[derive(Debug, Clone, Default)]
pub struct Synthesized {
    /// What it did.
    pub report: SynthReport,
    /// With [`SynthOptions::keep_patch_map`]: each texel written (row-major index) and its
    /// heaviest patch (`u32::MAX` where no patch reached it).
    pub patches: Vec<(u32, u32)>,
    /// With [`SynthOptions::keep_patch_map`]: the exemplars taken from the surface, as the
    /// photographs coloured them (before their detail is split off), in the order of
    /// [`RegionReport::exemplar`]'s first mention.
    pub exemplars: Vec<image::RgbImage>,
}

/// Stage 6's picture: each texel it wrote in the colour of its heaviest patch (white where no
/// patch reached it: low band only), photographed texels grey, other chart texels (restored)
/// dark grey, black outside the charts.
pub fn picture(res: &Resampled, patches: &[(u32, u32)]) -> image::RgbImage {
    use crate::resample::TexelSource as S;
    let (w, h) = res.color.dimensions();
    let mut img = image::RgbImage::from_fn(w, h, |x, y| {
        let s = res.source[(y * w + x) as usize];
        image::Rgb(if s == S::Photos as u8 {
            [110, 110, 110]
        } else if s == S::Empty as u8 || s == S::Gutter as u8 {
            [0, 0, 0]
        } else {
            [50, 50, 50]
        })
    });
    for &(i, k) in patches {
        let c = if k == u32::MAX {
            [255, 255, 255]
        } else {
            crate::resample::index_colour(k)
        };
        img.put_pixel(i % w, i / w, image::Rgb(c));
    }
    img
}

/// Most photographed samples around one region that constrain its patches.
const RIM_SAMPLES: usize = 20_000;

/// The faces outside a region (`member` marks every region's faces) sharing an edge with it,
/// in index order.
fn rim_faces(adj: &[[u32; 3]], member: &[bool], faces: &[u32]) -> Vec<u32> {
    let mut rim: Vec<u32> = faces
        .iter()
        .flat_map(|&f| adj[f as usize])
        .filter(|&g| g != crate::mesh::topology::NO_FACE && !member[g as usize])
        .collect();
    rim.sort_unstable();
    rim.dedup();
    rim
}

/// The photographed detail just outside a region: of its rim faces' photographed `texels`
/// (from [`pick::photographed_texels`]; at most [`RIM_SAMPLES`], evenly strided), the surface
/// point and the colour minus the low band there, in `src`'s Gaussian values.
fn rim_detail(
    mesh: &Mesh,
    atlas: &Atlas,
    res: &Resampled,
    texels: &[(usize, u32)],
    low: &surface::LowBand<'_>,
    src: &Source,
) -> Vec<(nalgebra::Point3<f64>, [f32; 3])> {
    let n = atlas.size as usize;
    let data: &[f32] = res.color.as_raw();
    let step = texels.len().div_ceil(RIM_SAMPLES).max(1);
    texels
        .iter()
        .step_by(step)
        .filter_map(|&(i, f)| {
            let (b, p) = surface::texel_point(mesh, atlas, f, i % n, i / n)?;
            let l = low.at(f, &mesh.faces[f as usize], &b);
            let obs: [f32; 3] = std::array::from_fn(|k| data[i * 3 + k] - l[k]);
            Some((p, src.ex.gaussianise(obs)))
        })
        .collect()
}

/// A square crop's detail: the crop minus its Gaussian blur (sigma `sigma`), so it carries
/// texture, not shading or colour gradients (the low band brings those).
fn detail(texels: &[[f32; 3]], w: usize, h: usize, sigma: f64) -> Vec<[f32; 3]> {
    let r = (3.0 * sigma).ceil() as i64;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let ks: f32 = k.iter().sum();
    let pass = |src: &[[f32; 3]], horizontal: bool| -> Vec<[f32; 3]> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as i64, (i / w) as i64);
                let mut acc = [0f32; 3];
                for (j, kv) in k.iter().enumerate() {
                    let d = j as i64 - r;
                    let (xx, yy) = if horizontal {
                        ((x + d).clamp(0, w as i64 - 1), y)
                    } else {
                        (x, (y + d).clamp(0, h as i64 - 1))
                    };
                    let s = src[yy as usize * w + xx as usize];
                    for c in 0..3 {
                        acc[c] += kv * s[c];
                    }
                }
                acc.map(|a| a / ks)
            })
            .collect()
    };
    let blurred = pass(&pass(texels, true), false);
    texels
        .iter()
        .zip(&blurred)
        .map(|(t, b)| std::array::from_fn(|c| t[c] - b[c]))
        .collect()
}

/// The random numbers of region `k`'s patches: its own stream, drawn from a seed that mixes
/// the option's seed with `k`, so that regions can grow side by side.
fn region_rng(seed: u64, k: usize) -> SplitMix64 {
    SplitMix64::new(SplitMix64::new(seed.wrapping_add(k as u64)).next_u64())
}

/// Stage 6: fills the unseen texels of every region in `left` (low band plus exemplar
/// detail), then extends the charts into the gutter again. `photos` are the registered
/// photographs, indexed as `res.best_photo` (how sharply each crop was seen decides which can
/// serve as exemplars); `up` orients the patches (the photographs' mean up); `user` is the
/// user's exemplar image when [`ExemplarSource::File`] is chosen (read by the caller).
#[allow(clippy::too_many_arguments)]
pub fn synthesize(
    mesh: &Mesh,
    normals: &[Vector3<f64>],
    atlas: &Atlas,
    res: &mut Resampled,
    left: &Unrestored,
    photos: &[crate::scene::Photo],
    up: Vector3<f64>,
    user: Option<&image::Rgb32FImage>,
    opts: &SynthOptions,
    gutter_fill: u32,
    progress: &dyn crate::progress::Progress,
) -> Result<Synthesized> {
    opts.validate()?;
    let wall = Instant::now();
    let up = if up.norm() > 1e-12 {
        up.normalize()
    } else {
        Vector3::z()
    };
    let radius = if opts.radius > 0.0 {
        opts.radius
    } else {
        (8.0 * left.feature_scale).clamp(16.0, 48.0)
    };
    let mut report = SynthReport {
        radius,
        up: up.into(),
        ..Default::default()
    };
    if opts.exemplar == ExemplarSource::Off || left.regions.is_empty() {
        return Ok(Synthesized {
            report,
            ..Default::default()
        });
    }
    if matches!(opts.exemplar, ExemplarSource::File(_)) != user.is_some() {
        return Err(Error::Internal(
            "stage 6 needs the exemplar image exactly when an exemplar file is chosen".into(),
        ));
    }
    if mesh.num_faces() != atlas.face_chart.len() || normals.len() != mesh.num_vertices() {
        return Err(Error::Internal(
            "stage 6 was given an atlas or normals of another mesh".into(),
        ));
    }
    let nf = mesh.num_faces();
    let mut member = vec![false; nf];
    let mut slot = vec![u32::MAX; nf];
    let mut count = 0u32;
    for r in &left.regions {
        for &f in &r.faces {
            member[f as usize] = true;
            slot[f as usize] = count;
            count += 1;
        }
    }
    let mut t = Instant::now();
    // Restoration found the regions with the face adjacency and hands it over with them.
    let built;
    let adj: &[[u32; 3]] = if left.adjacency.len() == nf {
        &left.adjacency
    } else {
        built = crate::mesh::topology::face_adjacency(mesh);
        &built
    };
    let prior = prior::ShapePrior::photographed(mesh, normals, &up, res, &member);
    let low = surface::low_band(
        mesh,
        atlas,
        &res.color,
        &res.source,
        &member,
        adj,
        &res.vertex_colors,
        prior.as_ref(),
    );
    drop(prior);
    report.low_band = low.summary;
    report.seconds_low_band = t.elapsed().as_secs_f64();
    t = Instant::now();
    // Exemplars: the user's, or per region the surface square most like its rim.
    let tpu = atlas.texels_per_unit();
    let (lo, hi) = mesh.bounding_box();
    let object_radius = (hi - lo).norm() / 2.0;
    let sigma = radius / 4.0;
    let mut sources: Vec<Source> = Vec::new();
    let mut used: Vec<(ExemplarUsed, Option<u32>)> = Vec::with_capacity(left.regions.len());
    let mut exemplars = Vec::new();
    // Each region's photographed texels around its rim: its exemplar's look and constraints.
    let eyes: Vec<pick::Eye> = photos
        .iter()
        .map(|p| pick::Eye {
            view: &p.view,
            focal: crate::depth::focal_px(&p.view),
        })
        .collect();
    // Candidate crops (for the automatic choice) and the least sharpness the rims' texels
    // need to describe the surface: texels seen at a grazing angle carry stripes, not its
    // texture.
    let side = (((2.0 * radius + 8.0) / 8.0).ceil() * 8.0) as usize;
    let lag = (sigma.round() as usize).max(1);
    let (cands, floor) = if user.is_none() {
        let mut cands = pick::candidates(mesh, adj, atlas, res, &eyes, &up, side, lag);
        if cands.is_empty() {
            cands = pick::candidates(mesh, adj, atlas, res, &eyes, &up, side / 2, lag);
        }
        pick::sharp_only(cands)
    } else {
        (Vec::new(), 0.0)
    };
    let rims: Vec<Vec<(usize, u32)>> = left
        .regions
        .iter()
        .map(|r| {
            let all =
                pick::photographed_texels(atlas, &res.source, &rim_faces(adj, &member, &r.faces));
            pick::sharp_texels(mesh, atlas, res, &eyes, &up, all, floor)
        })
        .collect();
    if let Some(img) = user {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let texels: Vec<[f32; 3]> = img.pixels().map(|p| p.0).collect();
        let ex = plane::Exemplar::new(w, h, &detail(&texels, w, h, sigma))?;
        sources.push(Source::upright(ex, tpu));
        used.extend(left.regions.iter().map(|_| (ExemplarUsed::File, Some(0))));
    } else {
        let mut chosen: Vec<u32> = Vec::new();
        for (r, rim) in left.regions.iter().zip(&rims) {
            let (mut colour, mut cnt) = ([0f64; 3], 0.0f64);
            let mut centre = Vector3::zeros();
            let (mut facing, mut area) = (0.0, 0.0);
            for &f in &r.faces {
                let na = mesh.face_normal_area(FaceId(f));
                facing += na.dot(&up);
                area += na.norm();
                for (k, v) in mesh.faces[f as usize].iter().enumerate() {
                    if let Some(c) = low.fixed_corner(f, k) {
                        for j in 0..3 {
                            colour[j] += c[j] as f64;
                        }
                        centre += mesh.positions[v.idx()].coords;
                        cnt += 1.0;
                    }
                }
            }
            if cnt == 0.0 {
                // No rim: the region's own place and the fill's colours.
                for &f in &r.faces {
                    let tri = mesh.triangle(FaceId(f));
                    centre += (tri[0].coords + tri[1].coords + tri[2].coords) / 3.0;
                    let third = [1.0 / 3.0; 3];
                    let c = low.at(f, &mesh.faces[f as usize], &third);
                    for k in 0..3 {
                        colour[k] += c[k] as f64;
                    }
                    cnt += 1.0;
                }
            }
            let look = pick::RimLook {
                detail: pick::texels_detail(atlas, &res.color, &res.source, rim, lag),
                colour: colour.map(|c| (c / cnt.max(1.0)) as f32),
                facing_up: facing / area.max(1e-300),
                centre: nalgebra::Point3::from(centre / cnt.max(1.0)),
            };
            match pick::choose(&cands, &look, object_radius) {
                Some(c) => {
                    let key = c.square.seed;
                    let id = match chosen.iter().position(|k| *k == key) {
                        Some(i) => i,
                        None => {
                            let size = c.square.size;
                            let texels = pick::texels(mesh, atlas, res, c).ok_or_else(|| {
                                Error::Internal(format!(
                                    "stage 6's exemplar at face {} no longer flattens",
                                    c.square.seed
                                ))
                            })?;
                            if opts.keep_patch_map {
                                let img = image::Rgb32FImage::from_fn(
                                    size as u32,
                                    size as u32,
                                    |x, y| image::Rgb(texels[y as usize * size + x as usize]),
                                );
                                exemplars.push(crate::render::to_rgb8(&img));
                            }
                            let ex = plane::Exemplar::new(
                                size,
                                size,
                                &detail(&texels, size, size, sigma),
                            )?;
                            sources.push(Source::upright(ex, c.square.tpu));
                            chosen.push(key);
                            chosen.len() - 1
                        }
                    };
                    used.push((
                        ExemplarUsed::Surface {
                            face: c.square.seed,
                            centre: c.square.centre.into(),
                            size: c.square.size,
                        },
                        Some(id as u32),
                    ));
                }
                None => used.push((ExemplarUsed::None, None)),
            }
        }
    }
    report.seconds_exemplars = t.elapsed().as_secs_f64();
    t = Instant::now();
    // One radius for growing and baking: the largest every exemplar holds.
    let radius = sources
        .iter()
        .map(|s| plane::max_radius(&s.ex))
        .fold(radius, f64::min);
    report.radius = radius;
    // Regions grow their patches side by side, each from its own seed (the option's mixed
    // with the region's number), so the layout is the same on any thread count. A region's
    // faces hold consecutive slots, so each region owns one run of `face_patches`, and its
    // patches are numbered from 0 until they are joined below.
    let mut face_patches: Vec<Vec<u32>> = vec![Vec::new(); count as usize];
    let mut runs: Vec<&mut [Vec<u32>]> = Vec::with_capacity(left.regions.len());
    let mut rest = &mut face_patches[..];
    for r in &left.regions {
        let (run, tail) = rest.split_at_mut(r.faces.len());
        runs.push(run);
        rest = tail;
    }
    let grown: Vec<Vec<surface::Patch>> = {
        let res: &Resampled = res;
        let layout = Layout {
            radius,
            candidates: opts.candidates,
        };
        left.regions
            .par_iter()
            .zip(&used)
            .zip(&rims)
            .zip(runs.par_iter_mut())
            .enumerate()
            .with_max_len(1)
            .map(|(k, (((r, (_, src)), rim), run))| {
                let Some(id) = src else {
                    return Vec::new();
                };
                let s = &sources[*id as usize];
                let rim = rim_detail(mesh, atlas, res, rim, &low, s);
                let mut rng = region_rng(opts.seed, k);
                let mut grown = Vec::new();
                surface::grow_patches(
                    mesh, adj, &r.faces, &slot, s, *id, &up, &layout, &mut rng, &rim, &mut grown,
                    run,
                );
                grown
            })
            .collect()
    };
    // Patch numbers become the page's: a region's follow those of the regions before it.
    let mut patches = Vec::new();
    let mut per_region = Vec::with_capacity(grown.len());
    for (run, g) in runs.into_iter().zip(grown) {
        let offset = patches.len() as u32;
        for k in run.iter_mut().flatten() {
            *k += offset;
        }
        per_region.push(g.len());
        patches.extend(g);
    }
    report.seconds_patches = t.elapsed().as_secs_f64();
    t = Instant::now();
    let (written, bare, patch_map) = surface::bake(
        mesh,
        normals,
        atlas,
        &mut res.color,
        &res.source,
        &slot,
        &low,
        &patches,
        &face_patches,
        &sources,
        radius,
        opts.keep_patch_map,
        progress,
    );
    crate::resample::refill_gutter(res, gutter_fill);
    report.seconds_bake = t.elapsed().as_secs_f64();
    report.texels = written;
    report.texels_low_only = bare;
    report.patches = patches.len();
    report.regions = left
        .regions
        .iter()
        .zip(used)
        .zip(per_region)
        .map(|((r, (ex, _)), p)| RegionReport {
            faces: r.faces.len(),
            texels: r.texels,
            depth_texels: r.depth_texels,
            reason: r.reason,
            exemplar: ex,
            patches: p,
        })
        .collect();
    report.seconds = wall.elapsed().as_secs_f64();
    Ok(Synthesized {
        report,
        patches: patch_map,
        exemplars,
    })
}
