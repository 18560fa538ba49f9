//! `scantex info`: what a user runs first to check their data. Mesh topology, cameras,
//! photographs found and missing, and the reprojection error of the COLMAP model's 3D points
//! through our camera models (a wrong model interpretation shows up here at once).

use crate::scene::{PhotoStatus, Scene};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt;

/// Everything `scantex info` reports; serialised as-is by `--json`.
#[derive(Debug, Clone, Serialize)]
pub struct InfoReport {
    /// Where each part of the scene was found.
    pub paths: crate::scene::ScenePaths,
    /// Mesh facts, if the scene has a mesh.
    pub mesh: Option<MeshInfo>,
    /// COLMAP model facts, if the scene has one.
    pub colmap: Option<ColmapInfo>,
}

/// Mesh facts.
#[derive(Debug, Clone, Serialize)]
pub struct MeshInfo {
    /// Vertices.
    pub vertices: usize,
    /// Triangles kept.
    pub faces: usize,
    /// What loading dropped or triangulated.
    pub load: crate::mesh::LoadReport,
    /// Connectivity.
    pub topology: crate::mesh::Topology,
    /// Axis-aligned bounding box, minimum corner.
    pub bbox_min: [f64; 3],
    /// Axis-aligned bounding box, maximum corner.
    pub bbox_max: [f64; 3],
    /// Has per-corner texture coordinates.
    pub has_uv: bool,
    /// Has per-vertex normals.
    pub has_normals: bool,
    /// Has per-vertex colours.
    pub has_colors: bool,
}

/// COLMAP model facts.
#[derive(Debug, Clone, Serialize)]
pub struct ColmapInfo {
    /// Number of cameras.
    pub cameras: usize,
    /// Cameras per model name.
    pub cameras_by_model: BTreeMap<String, usize>,
    /// Registered images.
    pub images: usize,
    /// 3D points.
    pub points3d: usize,
    /// Track observations (2D points with a 3D point).
    pub observations: usize,
    /// Photographs present with the right size.
    pub photos_ok: usize,
    /// Photograph files missing (names, at most 20 listed).
    pub photos_missing: Vec<String>,
    /// Photograph files unreadable or of the wrong size, with the reason (at most 20 listed).
    pub photos_bad: Vec<(String, String)>,
    /// Number missing in all.
    pub photos_missing_count: usize,
    /// Number unreadable or wrong-sized in all.
    pub photos_bad_count: usize,
    /// Photographs with a mask file.
    pub masks: usize,
    /// Photographs whose file carries an alpha channel (read as a mask where it hides
    /// pixels; whether it does is only known once decoded).
    pub alpha: usize,
    /// Reprojection error over all observations, in pixels.
    pub reprojection: Option<ErrorStats>,
    /// Fraction of 3D points whose mean track error, recomputed here, matches COLMAP's stored
    /// ERROR to 1e-3 px: near 1.0 means we read the model exactly as COLMAP does.
    pub stored_error_agreement: Option<f64>,
}

/// Summary of a set of errors.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct ErrorStats {
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Maximum.
    pub max: f64,
}

impl ErrorStats {
    /// Mean, median and max of `v` (`None` if empty).
    pub fn of(v: &mut [f64]) -> Option<Self> {
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        Some(ErrorStats {
            mean: v.iter().sum::<f64>() / n as f64,
            median,
            max: v[n - 1],
        })
    }
}

const LIST_LIMIT: usize = 20;

/// Builds the report for a loaded scene (probes photo headers; decodes nothing).
pub fn info(scene: &Scene) -> InfoReport {
    let mesh = scene.mesh.as_ref().map(|(m, load)| {
        let (lo, hi) = m.bounding_box();
        MeshInfo {
            vertices: m.num_vertices(),
            faces: m.num_faces(),
            load: load.clone(),
            topology: m.topology(),
            bbox_min: lo.into(),
            bbox_max: hi.into(),
            has_uv: m.uv.is_some(),
            has_normals: m.normals.is_some(),
            has_colors: m.colors.is_some(),
        }
    });
    let colmap = scene.reconstruction.as_ref().map(|rec| {
        let mut by_model = BTreeMap::new();
        for c in rec.cameras.values() {
            *by_model.entry(c.model.name().to_string()).or_insert(0) += 1;
        }
        let statuses: Vec<(String, PhotoStatus, bool)> = {
            use rayon::prelude::*;
            scene
                .photos
                .par_iter()
                .map(|p| {
                    let st = p.status();
                    let alpha = matches!(st, PhotoStatus::Ok)
                        && crate::io::image::has_alpha(&p.path).unwrap_or(false);
                    (p.name.clone(), st, alpha)
                })
                .collect()
        };
        let mut missing = Vec::new();
        let mut bad = Vec::new();
        for (name, st, _) in &statuses {
            match st {
                PhotoStatus::Ok => {}
                PhotoStatus::Missing => missing.push(name.clone()),
                PhotoStatus::Unreadable(m) => bad.push((name.clone(), m.clone())),
                PhotoStatus::WrongSize { found, expected } => bad.push((
                    name.clone(),
                    format!(
                        "{}x{}, camera says {}x{}",
                        found.0, found.1, expected.0, expected.1
                    ),
                )),
            }
        }
        let tracks = rec.track_errors();
        let mut all: Vec<f64> = tracks.iter().flat_map(|(_, e)| e.iter().copied()).collect();
        let agree = tracks
            .iter()
            .filter(|(pid, e)| {
                !e.is_empty() && {
                    let mean = e.iter().sum::<f64>() / e.len() as f64;
                    (mean - rec.points3d[pid].error).abs() <= 1e-3
                }
            })
            .count();
        let (nm, nb) = (missing.len(), bad.len());
        missing.truncate(LIST_LIMIT);
        bad.truncate(LIST_LIMIT);
        ColmapInfo {
            cameras: rec.cameras.len(),
            cameras_by_model: by_model,
            images: rec.images.len(),
            points3d: rec.points3d.len(),
            observations: all.len(),
            photos_ok: statuses.len() - nm - nb,
            photos_missing: missing,
            photos_bad: bad,
            photos_missing_count: nm,
            photos_bad_count: nb,
            masks: scene.photos.iter().filter(|p| p.mask.is_some()).count(),
            alpha: statuses.iter().filter(|s| s.2).count(),
            reprojection: ErrorStats::of(&mut all),
            stored_error_agreement: (!tracks.is_empty())
                .then(|| agree as f64 / tracks.len() as f64),
        }
    });
    InfoReport {
        paths: scene.paths.clone(),
        mesh,
        colmap,
    }
}

impl fmt::Display for InfoReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let show = |p: &Option<std::path::PathBuf>| {
            p.as_ref()
                .map_or("(none)".to_string(), |p| p.display().to_string())
        };
        writeln!(f, "scene")?;
        writeln!(f, "  mesh     {}", show(&self.paths.mesh))?;
        // The JSON keeps the key `colmap`; people read which format it is.
        let cameras = self
            .paths
            .colmap
            .as_deref()
            .map_or("(none)".to_string(), |p| {
                format!("{} ({})", p.display(), crate::scene::camera_format(p))
            });
        writeln!(f, "  cameras  {cameras}")?;
        writeln!(f, "  images   {}", show(&self.paths.images))?;
        writeln!(f, "  masks    {}", show(&self.paths.masks))?;
        if let Some(m) = &self.mesh {
            let t = &m.topology;
            writeln!(f, "mesh")?;
            writeln!(f, "  vertices             {}", m.vertices)?;
            writeln!(f, "  faces                {}", m.faces)?;
            if m.load.degenerate_faces > 0 {
                writeln!(f, "  degenerate (skipped) {}", m.load.degenerate_faces)?;
            }
            if m.load.duplicate_faces > 0 {
                writeln!(f, "  repeated (skipped)   {}", m.load.duplicate_faces)?;
            }
            if m.load.polygons_triangulated > 0 {
                writeln!(f, "  polygons split       {}", m.load.polygons_triangulated)?;
            }
            writeln!(f, "  components           {}", t.components)?;
            writeln!(f, "  boundary loops       {}", t.boundary_loops)?;
            writeln!(f, "  non-manifold edges   {}", t.non_manifold_edges)?;
            writeln!(f, "  euler characteristic {}", t.euler_characteristic)?;
            let [a, b, c] = m.bbox_min;
            let [x, y, z] = m.bbox_max;
            writeln!(
                f,
                "  bounding box         [{a:.4}, {b:.4}, {c:.4}] .. [{x:.4}, {y:.4}, {z:.4}]"
            )?;
            let yn = |b: bool| if b { "yes" } else { "no" };
            writeln!(
                f,
                "  uv / normals / colours  {} / {} / {}",
                yn(m.has_uv),
                yn(m.has_normals),
                yn(m.has_colors)
            )?;
        }
        if let Some(c) = &self.colmap {
            writeln!(f, "cameras")?;
            let models: Vec<String> = c
                .cameras_by_model
                .iter()
                .map(|(k, v)| format!("{v} {k}"))
                .collect();
            writeln!(f, "  cameras      {} ({})", c.cameras, models.join(", "))?;
            writeln!(f, "  images       {}", c.images)?;
            writeln!(
                f,
                "  points3D     {} ({} observations)",
                c.points3d, c.observations
            )?;
            writeln!(
                f,
                "  photographs  {} ok, {} missing, {} unreadable or wrong size",
                c.photos_ok, c.photos_missing_count, c.photos_bad_count
            )?;
            for n in &c.photos_missing {
                writeln!(f, "    missing: {n}")?;
            }
            for (n, why) in &c.photos_bad {
                writeln!(f, "    bad:     {n}: {why}")?;
            }
            writeln!(f, "  masks        {}", c.masks)?;
            if c.alpha > 0 {
                writeln!(
                    f,
                    "  alpha        {} (an alpha channel that hides pixels masks its photograph)",
                    c.alpha
                )?;
            }
            if let Some(r) = &c.reprojection {
                writeln!(
                    f,
                    "  reprojection error (px)  mean {:.4}  median {:.4}  max {:.4}",
                    r.mean, r.median, r.max
                )?;
            }
            if let Some(a) = c.stored_error_agreement {
                writeln!(
                    f,
                    "  points matching COLMAP's stored error to 1e-3 px: {:.2}%",
                    100.0 * a
                )?;
                if a < 0.99 {
                    writeln!(
                        f,
                        "    (expected below 100% for models from COLMAP's image_undistorter, which keeps\n     the errors of the distorted model, and for text models, which round poses to 6 digits)"
                    )?;
                }
            }
        }
        Ok(())
    }
}
