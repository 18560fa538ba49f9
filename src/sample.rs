//! Generating scenes whose true colours we know: a procedural object (a dented torus: one
//! handle, a concavity that hides part of itself, an underside no camera sees) or any textured
//! mesh, photographed by virtual SIMPLE_RADIAL cameras with varied exposure, white balance and
//! light. Writes the scene layout `scantex` reads (mesh, `sparse/0`, `images/`, `masks/`), plus
//! held-out views (`heldout/`) and the truth (`truth/model.glb`, `truth/lighting.json`).

use crate::camera::colmap::{self, Image, Point2D, Point3D, Reconstruction};
use crate::camera::{Camera, CameraModel, Pose, PosedCamera};
use crate::error::{Error, Result};
use crate::io::{self, EncodedTexture};
use crate::mesh::{Mesh, UvMap, VertexId};
use crate::raycast::RayMesh;
use crate::render::{render, Lighting, RenderOptions, Shading, Texture};
use crate::rng::SplitMix64;
use image::{DynamicImage, Rgb32FImage, RgbImage};
use nalgebra::{Point3, Rotation3, UnitQuaternion, Vector2, Vector3};
use std::collections::BTreeMap;
use std::path::Path;

/// Options for [`generate`].
#[derive(Debug, Clone, PartialEq)]
pub struct SampleOptions {
    /// Photographs used for texturing. Default: 16.
    pub photos: usize,
    /// Held-out photographs, for evaluation only. Default: 4.
    pub heldout: usize,
    /// Image size in pixels. Default: 800 x 600.
    pub size: (u32, u32),
    /// World "up": cameras stay between `min_elevation` and `max_elevation` above the plane
    /// normal to it, so the underside is never seen. Default: +Z.
    pub up: Vector3<f64>,
    /// Lowest camera elevation, degrees. Default: 20.
    pub min_elevation: f64,
    /// Highest camera elevation, degrees. Default: 65.
    pub max_elevation: f64,
    /// Largest exposure and white-balance deviation, as a fraction. Default: 0.25 (+-25%).
    pub gain_range: f64,
    /// Light each photograph from its own random direction (30-80 degrees up); false lights
    /// all from one direction (55 degrees up), so photographs differ by gains only. Default:
    /// true.
    pub vary_light: bool,
    /// JPEG quality of the photographs. Default: 97.
    pub jpeg_quality: u8,
    /// A sector of azimuth, degrees, that no input photograph looks from (centred on the
    /// first horizontal axis); held-out views still go all around, and `heldout/unseen/`
    /// marks the pixels of each whose surface no input photograph saw. Default: 0.
    pub unseen_sector: f64,
    /// Random seed: same seed, same bytes. Default: 1.
    pub seed: u64,
    /// The procedural object photographed when no mesh is given. Default: the torus.
    pub object: SampleObject,
}

/// Procedural objects [`generate_to`] can photograph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SampleObject {
    /// A dented torus whose colours do not follow its orientation ([`dented_torus`]).
    #[default]
    Torus,
    /// A painted jar whose albedo follows its normal: a white top, saturated sides, a coloured
    /// foot ([`painted_jar`]). It provokes delighting, which reads such albedo as light.
    Jar,
}

impl std::fmt::Display for SampleObject {
    /// The name `from_str` reads.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SampleObject::Torus => "torus",
            SampleObject::Jar => "jar",
        })
    }
}

impl std::str::FromStr for SampleObject {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "torus" => Ok(SampleObject::Torus),
            "jar" => Ok(SampleObject::Jar),
            _ => Err(format!(
                "unknown sample object '{s}': expected torus or jar"
            )),
        }
    }
}

/// Sectors [`SampleOptions::unseen_sector`] may take, degrees.
pub const SECTOR_RANGE: std::ops::RangeInclusive<f64> = 0.0..=300.0;

/// Exposure and white-balance deviations [`SampleOptions::gain_range`] may take.
pub const GAIN_RANGE_LIMITS: std::ops::RangeInclusive<f64> = 0.0..=0.9;

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions {
            photos: 16,
            heldout: 4,
            size: (800, 600),
            up: Vector3::z(),
            min_elevation: 20.0,
            max_elevation: 65.0,
            gain_range: 0.25,
            vary_light: true,
            jpeg_quality: 97,
            unseen_sector: 0.0,
            seed: 1,
            object: SampleObject::Torus,
        }
    }
}

/// Hash-based value noise in [0, 1] on an integer lattice (fine texture for the torus).
fn lattice(i: i64, j: i64) -> f64 {
    let mut h =
        (i as u64).wrapping_mul(0x9E3779B97F4A7C15) ^ (j as u64).wrapping_mul(0xC2B2AE3D27D4EB4F);
    h ^= h >> 29;
    h = h.wrapping_mul(0xBF58476D1CE4E5B9);
    h ^= h >> 32;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// The torus's true colour at surface parameters (theta around the ring, phi around the tube):
/// six hue sectors with sharp borders (large structure), wavy fine stripes and value noise
/// (fine texture), and a checker band with hard edges over the top.
pub fn torus_colour(theta: f64, phi: f64) -> [f32; 3] {
    use std::f64::consts::TAU;
    const PALETTE: [[f64; 3]; 6] = [
        [0.80, 0.22, 0.18],
        [0.85, 0.62, 0.20],
        [0.30, 0.62, 0.28],
        [0.22, 0.38, 0.78],
        [0.55, 0.28, 0.62],
        [0.88, 0.84, 0.72],
    ];
    let t = theta.rem_euclid(TAU);
    let p = phi.rem_euclid(TAU);
    let sector = ((t / TAU * 6.0) as usize).min(5);
    let stripes = 0.5 + 0.5 * (40.0 * p + 3.0 * (25.0 * t).sin()).sin();
    let (ni, nj) = ((t / TAU * 512.0) as i64, (p / TAU * 256.0) as i64);
    let noise = lattice(ni, nj) - 0.5;
    let mut v = 0.78 + 0.16 * stripes + 0.10 * noise;
    // Checker over the top of the tube: 48 x 4 cells, hard edges.
    if (0.9..2.2).contains(&p) {
        let ci = (t / TAU * 48.0) as i64;
        let cj = ((p - 0.9) / 1.3 * 4.0) as i64;
        if (ci + cj) % 2 == 0 {
            v *= 0.55;
        }
    }
    PALETTE[sector].map(|c| (c * v).clamp(0.0, 1.0) as f32)
}

/// The procedural sample object with its true texture: a torus lying in the XY plane (z up)
/// with a deep dent in the top of its tube. `n_theta x n_phi` quads, two triangles each.
pub fn dented_torus(n_theta: usize, n_phi: usize, tex_size: (u32, u32)) -> (Mesh, DynamicImage) {
    use std::f64::consts::TAU;
    let (big_r, r0) = (1.0, 0.42);
    let pos = |theta: f64, phi: f64| {
        // Gaussian dent centred on the top of the tube at theta = 0.6.
        let dt = (theta - 0.6 + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0;
        let dp = phi - TAU / 4.0;
        let dent = 0.55 * (-(dt * dt / 0.08 + dp * dp / 0.35)).exp();
        let r = r0 * (1.0 - dent);
        Point3::new(
            (big_r + r * phi.cos()) * theta.cos(),
            (big_r + r * phi.cos()) * theta.sin(),
            r * phi.sin(),
        )
    };
    let mut positions = Vec::with_capacity(n_theta * n_phi);
    for i in 0..n_theta {
        for j in 0..n_phi {
            positions.push(pos(
                TAU * i as f64 / n_theta as f64,
                TAU * j as f64 / n_phi as f64,
            ));
        }
    }
    let vid = |i: usize, j: usize| VertexId(((i % n_theta) * n_phi + j % n_phi) as u32);
    grid_mesh(positions, n_theta, n_phi, &vid, tex_size, &|u, v| {
        torus_colour(TAU * u, TAU * v)
    })
}

/// A mesh over an `n_u x n_v` grid of parameters whose corner `(i, j)` is vertex `vid(i, j)`,
/// two triangles per cell (counter-clockwise seen from outside when d/du x d/dv points
/// outwards; triangles that a pole collapses are left out), with texture coordinates
/// `(i / n_u, j / n_v)` and a `tex_size` texture of `colour(u, v)`.
fn grid_mesh(
    positions: Vec<Point3<f64>>,
    n_u: usize,
    n_v: usize,
    vid: &dyn Fn(usize, usize) -> VertexId,
    tex_size: (u32, u32),
    colour: &dyn Fn(f64, f64) -> [f32; 3],
) -> (Mesh, DynamicImage) {
    let mut coords = Vec::with_capacity((n_u + 1) * (n_v + 1));
    for i in 0..=n_u {
        for j in 0..=n_v {
            coords.push(Vector2::new(i as f32 / n_u as f32, j as f32 / n_v as f32));
        }
    }
    let tid = |i: usize, j: usize| (i * (n_v + 1) + j) as u32;
    let mut faces = Vec::new();
    let mut uv_faces = Vec::new();
    for i in 0..n_u {
        for j in 0..n_v {
            for c in [[(0, 0), (1, 1), (0, 1)], [(0, 0), (1, 0), (1, 1)]] {
                let f = c.map(|(a, b)| vid(i + a, j + b));
                if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
                    faces.push(f);
                    uv_faces.push(c.map(|(a, b)| tid(i + a, j + b)));
                }
            }
        }
    }
    let mesh = Mesh {
        positions,
        faces,
        uv: Some(UvMap {
            coords,
            faces: uv_faces,
        }),
        ..Default::default()
    };
    let (tw, th) = tex_size;
    let tex = Rgb32FImage::from_fn(tw, th, |x, y| {
        let u = (x as f64 + 0.5) / tw as f64;
        let v = 1.0 - (y as f64 + 0.5) / th as f64;
        image::Rgb(colour(u, v))
    });
    (mesh, DynamicImage::ImageRgb8(crate::render::to_rgb8(&tex)))
}

/// The jar's profile, bottom pole to top pole, as (radius, height) corners: a flat base, a
/// vertical foot, a bulging body and a domed top.
fn jar_profile() -> Vec<(f64, f64)> {
    use std::f64::consts::PI;
    let mut p = vec![(0.0, 0.0), (0.55, 0.0), (0.55, 0.2)];
    for k in 1..=24 {
        let t = k as f64 / 24.0;
        p.push((0.55 + 0.2 * (PI * t).sin(), 0.2 + 0.9 * t));
    }
    for k in 1..=16 {
        let a = k as f64 / 16.0 * PI / 2.0;
        p.push((0.55 * a.cos(), 1.1 + 0.3 * a.sin()));
    }
    p
}

/// The jar's true colour at angle `theta` and profile position `s` (arclength fraction from
/// the bottom pole), with `foot` and `top` the fractions where the body starts and ends:
/// green base and foot, pink body with blue bands, white top; a little value noise on all.
fn jar_colour(theta: f64, s: f64, foot: f64, top: f64) -> [f32; 3] {
    use std::f64::consts::TAU;
    let t = theta.rem_euclid(TAU);
    let noise = lattice((t / TAU * 512.0) as i64, (s * 256.0) as i64) - 0.5;
    let base = if s < foot {
        [0.22, 0.52, 0.30]
    } else if s >= top {
        [0.80, 0.79, 0.76]
    } else {
        let b = (s - foot) / (top - foot);
        // Two blue bands with a wavy edge on the pink body.
        let w = 0.015 * (6.0 * t).sin();
        if (0.28..0.38).contains(&(b + w)) || (0.66..0.72).contains(&(b + w)) {
            [0.20, 0.34, 0.80]
        } else {
            [0.88, 0.34, 0.50]
        }
    };
    base.map(|c| (c * (1.0 + 0.12 * noise)).clamp(0.0, 1.0) as f32)
}

/// The painted jar with its true texture: a surface of revolution about +Z (closed, genus 0),
/// `n_theta` segments around and `n_s` along the profile. Its albedo follows its normal (the
/// top faces up and is white, the sides are saturated), the case where delighting mistakes
/// albedo for light.
pub fn painted_jar(n_theta: usize, n_s: usize, tex_size: (u32, u32)) -> (Mesh, DynamicImage) {
    use std::f64::consts::TAU;
    let corners = jar_profile();
    let mut arc = vec![0.0];
    for w in corners.windows(2) {
        let d = ((w[1].0 - w[0].0).powi(2) + (w[1].1 - w[0].1).powi(2)).sqrt();
        arc.push(arc.last().unwrap() + d);
    }
    let total = *arc.last().unwrap();
    // Body from the foot's top corner (index 2) to the dome's start (index 2 + 24).
    let (foot, top) = (arc[2] / total, arc[26] / total);
    let at = |s: f64| {
        let d = s * total;
        let k = arc.partition_point(|&a| a <= d).clamp(1, corners.len() - 1);
        let f = ((d - arc[k - 1]) / (arc[k] - arc[k - 1])).clamp(0.0, 1.0);
        let (a, b) = (corners[k - 1], corners[k]);
        (a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1))
    };
    // Rings j = 1..n_s - 1, poles at j = 0 (bottom) and j = n_s (top).
    let mut positions = vec![Point3::new(0.0, 0.0, 0.0)];
    for j in 1..n_s {
        let (r, z) = at(j as f64 / n_s as f64);
        for i in 0..n_theta {
            let th = TAU * i as f64 / n_theta as f64;
            positions.push(Point3::new(r * th.cos(), r * th.sin(), z));
        }
    }
    let top_pole = positions.len() as u32;
    positions.push(Point3::new(0.0, 0.0, at(1.0).1));
    let vid = |i: usize, j: usize| match j {
        0 => VertexId(0),
        j if j == n_s => VertexId(top_pole),
        j => VertexId((1 + (j - 1) * n_theta + i % n_theta) as u32),
    };
    grid_mesh(positions, n_theta, n_s, &vid, tex_size, &|u, v| {
        jar_colour(TAU * u, v, foot, top)
    })
}

/// A camera at `centre` looking at `target`, image "up" along `up`.
fn look_at(centre: Point3<f64>, target: Point3<f64>, up: &Vector3<f64>) -> Pose {
    let z = (target - centre).normalize();
    let y = -(up - z * up.dot(&z)).normalize();
    let x = y.cross(&z);
    let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_rows(&[
        x.transpose(),
        y.transpose(),
        z.transpose(),
    ]));
    let q = UnitQuaternion::from_rotation_matrix(&r);
    Pose {
        rotation: q,
        translation: -(q * centre.coords),
    }
}

/// What [`generate`] made.
#[derive(Debug, Clone)]
pub struct SampleReport {
    /// Lighting per photograph and held-out photograph name.
    pub lighting: BTreeMap<String, Lighting>,
    /// Total bytes written.
    pub bytes: u64,
}

/// Photographs `truth` (textured by `texture`) and writes a scene to `out`.
pub fn generate(
    truth: &Mesh,
    texture: &DynamicImage,
    opts: &SampleOptions,
    out: &Path,
) -> Result<SampleReport> {
    if !GAIN_RANGE_LIMITS.contains(&opts.gain_range) {
        return Err(Error::option(
            "gain_range",
            format!("gain range {} must lie in [0, 0.9]", opts.gain_range),
        ));
    }
    if !SECTOR_RANGE.contains(&opts.unseen_sector) {
        return Err(Error::option(
            "unseen_sector",
            format!(
                "{} degrees: expected a sector from 0 to 300",
                opts.unseen_sector
            ),
        ));
    }
    if truth.uv.is_none() {
        return Err(Error::mesh(
            crate::MeshElement::Whole,
            "the truth mesh needs texture coordinates",
        ));
    }
    let mut rng = SplitMix64::new(opts.seed);
    // The texture as stored (JPEG in the GLB) is what the photos show, so re-rendering the
    // truth reproduces them up to the photographs' own JPEG compression.
    let encoded = {
        let mut bytes = Vec::new();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 95);
        texture
            .to_rgb8()
            .write_with_encoder(enc)
            .map_err(|e| Error::Internal(format!("JPEG encoding of the texture in memory: {e}")))?;
        EncodedTexture {
            bytes,
            mime: "image/jpeg",
        }
    };
    let tex = Texture::new(&io::image::decode_bytes(
        &encoded.bytes,
        Path::new("texture"),
    )?);
    let ray_mesh = RayMesh::new(truth);
    let (lo, hi) = truth.bounding_box();
    let centre = nalgebra::center(&lo, &hi);
    let radius = truth
        .positions
        .iter()
        .map(|p| (p - centre).norm())
        .fold(0.0, f64::max);
    let up = opts.up.normalize();
    let side = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let (e1, e2) = {
        let a = (side - up * side.dot(&up)).normalize();
        (a, up.cross(&a))
    };
    let (w, h) = opts.size;
    let n = opts.photos + opts.heldout;
    let mut views: Vec<(String, PosedCamera, Lighting, bool)> = Vec::with_capacity(n);
    for k in 0..n {
        let heldout = k >= opts.photos;
        // Photos spread evenly in azimuth; held-out views halfway between them.
        let (count, idx, offset) = if heldout {
            (opts.heldout, k - opts.photos, 0.5)
        } else {
            (opts.photos, k, 0.0)
        };
        // Input photographs spread over the azimuths outside the unseen sector.
        let span = if heldout {
            std::f64::consts::TAU
        } else {
            std::f64::consts::TAU - opts.unseen_sector.to_radians()
        };
        let start = if heldout {
            0.0
        } else {
            opts.unseen_sector.to_radians() / 2.0
        };
        let az = start
            + span
                * (idx as f64
                    + offset
                    + 0.5 * f64::from(!heldout && opts.unseen_sector > 0.0)
                    + rng.range(-0.2, 0.2))
                / count as f64;
        let el = rng
            .range(opts.min_elevation, opts.max_elevation)
            .to_radians();
        let f = rng.range(0.85, 1.0) * w as f64;
        let half_fov = ((w.min(h) as f64 / 2.0) / f).atan();
        let dist = radius / half_fov.sin() * rng.range(1.02, 1.2);
        let dir = (e1 * az.cos() + e2 * az.sin()) * el.cos() + up * el.sin();
        let cam_centre = centre + dir * dist;
        let target = centre + (e1 * rng.range(-0.1, 0.1) + e2 * rng.range(-0.1, 0.1)) * radius;
        let k_dist = rng.range(-0.12, -0.04);
        let camera = Camera::new(
            k as u32 + 1,
            CameraModel::SimpleRadial,
            w,
            h,
            vec![f, w as f64 / 2.0, h as f64 / 2.0, k_dist],
        )
        .map_err(Error::Internal)?;
        let g = opts.gain_range;
        let lighting = Lighting {
            exposure: rng.range(1.0 - g, 1.0 + g) as f32,
            white_balance: [
                rng.range(1.0 - g, 1.0 + g) as f32,
                1.0,
                rng.range(1.0 - g, 1.0 + g) as f32,
            ],
            light_dir: {
                let (mut la, mut le) = (
                    rng.range(0.0, std::f64::consts::TAU),
                    rng.range(30.0f64, 80.0).to_radians(),
                );
                if !opts.vary_light {
                    (la, le) = (0.0, 55f64.to_radians());
                }
                ((e1 * la.cos() + e2 * la.sin()) * le.cos() + up * le.sin()).into()
            },
        };
        let name = if heldout {
            format!("heldout_{:02}.jpg", idx + 1)
        } else {
            format!("view_{:02}.jpg", idx + 1)
        };
        views.push((
            name,
            PosedCamera {
                camera,
                pose: look_at(cam_centre, target, &up),
            },
            lighting,
            heldout,
        ));
    }
    // 3D points: every 7th vertex, observed where it is the first surface its ray meets.
    let mut recs = [Reconstruction::default(), Reconstruction::default()];
    let mut tracks: BTreeMap<u64, Vec<(usize, u32, u32)>> = BTreeMap::new();
    for (k, (name, view, _, heldout)) in views.iter().enumerate() {
        let rec = &mut recs[*heldout as usize];
        rec.cameras.insert(view.camera.id, view.camera.clone());
        let mut points2d = Vec::new();
        for vi in (0..truth.num_vertices()).step_by(7) {
            let p = truth.positions[vi];
            let Some(px) = view.project(&p) else { continue };
            if !view.camera.contains(&px) {
                continue;
            }
            let c = view.pose.center();
            let d = (p - c).normalize();
            let visible = ray_mesh
                .intersect(&c, &d)
                .is_some_and(|hit| (hit.t - (p - c).norm()).abs() < 1e-6 * radius);
            if visible {
                tracks.entry(vi as u64 + 1).or_default().push((
                    k,
                    view.camera.id,
                    points2d.len() as u32,
                ));
                points2d.push(Point2D {
                    xy: [px.x, px.y],
                    point3d_id: Some(vi as u64 + 1),
                });
            }
        }
        rec.images.insert(
            view.camera.id,
            Image {
                id: view.camera.id,
                camera_id: view.camera.id,
                name: name.clone(),
                pose: view.pose,
                points2d,
            },
        );
    }
    for (pid, obs) in &tracks {
        let p = truth.positions[*pid as usize - 1];
        for half in [false, true] {
            let track: Vec<(u32, u32)> = obs
                .iter()
                .filter(|o| views[o.0].3 == half)
                .map(|o| (o.1, o.2))
                .collect();
            let rec = &mut recs[half as usize];
            if track.len() >= 2 {
                rec.points3d.insert(
                    *pid,
                    Point3D {
                        xyz: p.into(),
                        rgb: [128, 128, 128],
                        error: 0.0,
                        track,
                    },
                );
            } else {
                // A single observation is no 3D point: unlink it.
                for (iid, idx) in track {
                    rec.images.get_mut(&iid).unwrap().points2d[idx as usize].point3d_id = None;
                }
            }
        }
    }
    for (sub, rec) in [("", &recs[0]), ("heldout", &recs[1])] {
        let root = out.join(sub);
        colmap::write_text(rec, &root.join("sparse").join("0"))?;
        for d in ["images", "masks"] {
            std::fs::create_dir_all(root.join(d)).map_err(|e| Error::io(root.join(d), e))?;
        }
    }
    let mut lighting = BTreeMap::new();
    for (name, view, light, heldout) in &views {
        // Held-out views vary exposure and white balance but are lit evenly: they measure the
        // texture, and a per-channel gain (eval --gain-fit) is all that separates them from it.
        let shading = if *heldout {
            Shading::Flat
        } else {
            Shading::Lambert
        };
        let opts_r = RenderOptions {
            shading,
            lighting: *light,
            ..Default::default()
        };
        let r = render(&ray_mesh, Some(&tex), view, &opts_r);
        let bg = {
            let t = rng.range(0.0, 1.0) as f32;
            ([0.16 + 0.05 * t, 0.22, 0.26], [0.40, 0.42 + 0.05 * t, 0.44])
        };
        let photo = RgbImage::from_fn(w, h, |x, y| {
            let covered = r.coverage.get_pixel(x, y)[0] > 0;
            let c = if covered {
                r.color.get_pixel(x, y).0
            } else {
                let s = y as f32 / h as f32;
                std::array::from_fn(|k| bg.0[k] + (bg.1[k] - bg.0[k]) * s)
            };
            image::Rgb(c.map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8))
        });
        let root = if *heldout {
            out.join("heldout")
        } else {
            out.to_path_buf()
        };
        let mut bytes = Vec::new();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, opts.jpeg_quality);
        photo
            .write_with_encoder(enc)
            .map_err(|e| Error::Internal(format!("JPEG encoding in memory: {e}")))?;
        io::write_atomic(&root.join("images").join(name), &bytes)?;
        let mask_name = Path::new(name).with_extension("png");
        let png = io::image::encode_png(&DynamicImage::ImageLuma8(r.coverage))?;
        io::write_atomic(&root.join("masks").join(&mask_name), &png.bytes)?;
        if *heldout && opts.unseen_sector > 0.0 {
            let inputs: Vec<&PosedCamera> = views.iter().filter(|v| !v.3).map(|v| &v.1).collect();
            let unseen = unseen_mask(&ray_mesh, truth, view, &inputs, radius);
            let png = io::image::encode_png(&DynamicImage::ImageLuma8(unseen))?;
            let dir = root.join("unseen");
            std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
            io::write_atomic(&dir.join(&mask_name), &png.bytes)?;
        }
        lighting.insert(name.clone(), *light);
    }
    // The bare input mesh (no UVs, no texture) and the truth.
    let bare = Mesh {
        positions: truth.positions.clone(),
        faces: truth.faces.clone(),
        ..Default::default()
    };
    io::write_mesh(&out.join("mesh.ply"), &bare, None)?;
    std::fs::create_dir_all(out.join("truth")).map_err(|e| Error::io(out.join("truth"), e))?;
    let mut truth_out = truth.clone();
    truth_out.normals = None;
    truth_out.texture = None;
    io::write_mesh(
        &out.join("truth").join("model.glb"),
        &truth_out,
        Some(&encoded),
    )?;
    let json = serde_json::to_string_pretty(&lighting).expect("lighting serialises");
    io::write_atomic(&out.join("truth").join("lighting.json"), json.as_bytes())?;
    Ok(SampleReport {
        lighting,
        bytes: dir_size(out),
    })
}

/// 255 where `view` sees a surface point that no camera of `inputs` sees (in its image,
/// facing it, not occluded), 0 elsewhere (background included).
fn unseen_mask(
    mesh: &RayMesh,
    truth: &Mesh,
    view: &PosedCamera,
    inputs: &[&PosedCamera],
    radius: f64,
) -> image::GrayImage {
    use rayon::prelude::*;
    let (w, h) = (view.camera.width, view.camera.height);
    let centres: Vec<Point3<f64>> = inputs.iter().map(|c| c.pose.center()).collect();
    let rows: Vec<Vec<u8>> = (0..h)
        .into_par_iter()
        .map(|y| {
            (0..w)
                .map(|x| {
                    let px = nalgebra::Point2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let o = view.pose.center();
                    let Some(d) = view.world_ray(&px) else {
                        return 0;
                    };
                    let Some(hit) = mesh.intersect(&o, &d) else {
                        return 0;
                    };
                    let p = o + d * hit.t;
                    let n = truth.face_normal_area(hit.face).normalize();
                    let seen = inputs.iter().zip(&centres).any(|(cam, c)| {
                        let to = c - p;
                        if to.dot(&n) <= 0.0 {
                            return false;
                        }
                        let Some(q) = cam.project(&p) else {
                            return false;
                        };
                        if !cam.camera.contains(&q) {
                            return false;
                        }
                        let dist = to.norm();
                        let back = -to / dist;
                        mesh.intersect(c, &back)
                            .is_some_and(|h2| h2.t >= dist - 1e-4 * radius)
                    });
                    if seen {
                        0
                    } else {
                        255
                    }
                })
                .collect()
        })
        .collect();
    image::GrayImage::from_raw(w, h, rows.concat()).expect("w * h values")
}

fn dir_size(p: &Path) -> u64 {
    std::fs::read_dir(p)
        .map(|rd| {
            rd.filter_map(|e| e.ok())
                .map(|e| {
                    let path = e.path();
                    if path.is_dir() {
                        dir_size(&path)
                    } else {
                        e.metadata().map(|m| m.len()).unwrap_or(0)
                    }
                })
                .sum()
        })
        .unwrap_or(0)
}

/// Generates the procedural torus sample (`from_mesh = None`) or photographs the textured mesh
/// at `from_mesh`, into `out`.
pub fn generate_to(
    from_mesh: Option<&Path>,
    opts: &SampleOptions,
    out: &Path,
) -> Result<SampleReport> {
    match from_mesh {
        None => {
            let (mesh, tex) = match opts.object {
                SampleObject::Torus => dented_torus(170, 72, (1024, 512)),
                SampleObject::Jar => painted_jar(160, 96, (1024, 512)),
            };
            generate(&mesh, &tex, opts, out)
        }
        Some(p) => {
            let (mut mesh, _) = io::read_mesh(p)?;
            let src = mesh.texture.clone().ok_or_else(|| {
                Error::at_element(p, "texture", "the mesh has no texture to photograph")
            })?;
            let img = match &src {
                crate::mesh::TextureSource::File(f) => io::image::read(f)?,
                crate::mesh::TextureSource::Embedded(b) => io::image::decode_bytes(b, p)?,
                crate::mesh::TextureSource::Tiles(_) => {
                    return Err(Error::at_element(
                        p,
                        "texture",
                        "a texture of several UDIM tiles cannot be photographed yet: give a \
                         mesh with one texture",
                    ))
                }
            };
            mesh.normals = None;
            generate(&mesh, &img, opts, out)
        }
    }
}

#[cfg(test)]
mod tests {
    /// The volume a closed mesh encloses, positive when its faces point outwards.
    fn signed_volume(m: &crate::mesh::Mesh) -> f64 {
        (0..m.num_faces() as u32)
            .map(|f| {
                let [a, b, c] = m.triangle(crate::mesh::FaceId(f));
                a.coords.dot(&b.coords.cross(&c.coords)) / 6.0
            })
            .sum()
    }

    /// The torus is oriented outwards (positive signed volume), as the renderer, binding and
    /// atlas assume.
    #[test]
    fn dented_torus_faces_outwards() {
        let (m, _) = super::dented_torus(40, 16, (4, 4));
        let vol = signed_volume(&m);
        assert!(vol > 0.0, "signed volume {vol}");
    }

    /// The jar is closed (every edge shared by two faces, Euler characteristic 2) and
    /// oriented outwards.
    #[test]
    fn painted_jar_is_closed_and_faces_outwards() {
        let (m, _) = super::painted_jar(24, 12, (4, 4));
        let vol = signed_volume(&m);
        assert!(vol > 0.0, "signed volume {vol}");
        let mut edges = std::collections::HashMap::new();
        for f in &m.faces {
            for k in 0..3 {
                let (a, b) = (f[k].0, f[(k + 1) % 3].0);
                *edges.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        assert!(edges.values().all(|&c| c == 2));
        let chi = m.num_vertices() as i64 - edges.len() as i64 + m.num_faces() as i64;
        assert_eq!(chi, 2);
    }
}
