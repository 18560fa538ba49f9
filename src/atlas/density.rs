//! The atlas size the photographs support (`texture --size auto`): texels for every
//! photograph pixel that covers the surface in its best view, and no more. A 20 x 0.8 MP
//! scene has far fewer such pixels than a 4096² atlas has texels; texels beyond them cost time
//! in every later stage and add nothing the photographs saw.

use crate::camera::PosedCamera;
use crate::mesh::{FaceId, Mesh};
use nalgebra::Point3;
use rayon::prelude::*;
use serde::Serialize;

/// Texels per photograph pixel along each axis. At one texel per pixel (half this) the
/// corset scene lost 0.27 dB held-out against a fixed 4096 atlas; at two it lost none
/// (`docs/decisions.md`, "Atlas size from the photographs").
pub const OVERSAMPLING: f64 = 2.0;
/// The share of the page the packed charts are expected to cover (measured: 0.62-0.82).
pub const EXPECTED_UTILISATION: f64 = 0.7;
/// The smallest size chosen.
pub const MIN_SIZE: u32 = 256;
/// At most this many faces are visited (an even stride through the rest); the sum is scaled
/// to the whole surface's area. Each is projected into every photograph, so this bounds the
/// cost at 1,000 photographs to 50M projections.
const MAX_FACES: usize = 50_000;

/// What [`auto_size`] measured and chose.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AutoSize {
    /// Photograph pixels covering the surface in its best views: the sum over faces of the
    /// face's area times the largest pixel density (pixels per unit of surface area,
    /// `cos(angle) focal² / (depth² cos(ray angle))`) of a photograph that frames it and
    /// faces it.
    pub photo_pixels: f64,
    /// Fraction of the surface area that some photograph frames and faces (occlusion is not
    /// tested, so this is an upper bound).
    pub area_seen: f64,
    /// The side the pixels ask for: `OVERSAMPLING * sqrt(photo_pixels / EXPECTED_UTILISATION)`.
    pub needed: f64,
    /// The side chosen: the power of two at or above `needed`, at least [`MIN_SIZE`], at
    /// most the cap.
    pub size: u32,
    /// Whether the cap lowered it.
    pub capped: bool,
}

/// The atlas side `views` support for `mesh`, at most `max_size` (a power of two or not:
/// the cap is used as given).
pub fn auto_size(mesh: &Mesh, views: &[&PosedCamera], max_size: u32) -> AutoSize {
    let nf = mesh.num_faces();
    let stride = nf.div_ceil(MAX_FACES).max(1);
    let centres: Vec<Point3<f64>> = views.iter().map(|v| v.pose.center()).collect();
    let focals: Vec<f64> = views.iter().map(|v| crate::depth::focal_px(v)).collect();
    // Per chunk of faces in order, summed in order: the same bytes whatever the threads.
    let parts: Vec<[f64; 3]> = (0..nf)
        .step_by(stride)
        .collect::<Vec<_>>()
        .par_chunks(4096)
        .map(|chunk| {
            let mut acc = [0f64; 3]; // area, area seen, pixels
            for &f in chunk {
                let [a, b, c] = mesh.triangle(FaceId(f as u32));
                let cross = mesh.face_normal_area(FaceId(f as u32));
                let area = 0.5 * cross.norm();
                if area <= 0.0 || !area.is_finite() {
                    continue;
                }
                let n = cross / (2.0 * area);
                let centre = Point3::from((a.coords + b.coords + c.coords) / 3.0);
                let mut best = 0f64;
                for (k, view) in views.iter().enumerate() {
                    let to_cam = centres[k] - centre;
                    let dist = to_cam.norm();
                    let cos = n.dot(&to_cam) / dist.max(1e-300);
                    if cos <= 0.0 {
                        continue;
                    }
                    let cam = view.pose.transform(&centre);
                    if cam.z <= 0.0 {
                        continue;
                    }
                    match view.camera.project(&cam) {
                        Some(px) if view.camera.contains(&px) => {
                            // Image area per unit of surface: cos(angle) f² / (depth² cos(ray
                            // angle off the axis)), and cos(ray angle) = depth / distance.
                            let px = cos * focals[k] * focals[k] * dist / cam.z.powi(3);
                            best = best.max(px);
                        }
                        _ => {}
                    }
                }
                acc[0] += area;
                if best > 0.0 {
                    acc[1] += area;
                    acc[2] += area * best;
                }
            }
            acc
        })
        .collect();
    let total = parts
        .iter()
        .fold([0f64; 3], |s, p| [s[0] + p[0], s[1] + p[1], s[2] + p[2]]);
    // The visited faces stand for the whole surface: scale by its area over theirs.
    let surface: f64 = if stride == 1 {
        total[0]
    } else {
        (0..nf).map(|f| mesh.face_area(FaceId(f as u32))).sum()
    };
    let scale = if total[0] > 0.0 {
        surface / total[0]
    } else {
        0.0
    };
    let photo_pixels = total[2] * scale;
    let needed = OVERSAMPLING * (photo_pixels / EXPECTED_UTILISATION).sqrt();
    let pow2 = if needed.is_finite() && needed > MIN_SIZE as f64 {
        (needed.ceil() as u64)
            .next_power_of_two()
            .min(u32::MAX as u64 / 2) as u32
    } else {
        MIN_SIZE
    };
    let max_size = max_size.max(1);
    AutoSize {
        photo_pixels,
        area_seen: if total[0] > 0.0 {
            total[1] / total[0]
        } else {
            0.0
        },
        needed,
        size: pow2.min(max_size),
        capped: pow2 > max_size,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, CameraModel, Pose};
    use crate::mesh::VertexId;
    use nalgebra::{UnitQuaternion, Vector3};

    /// A unit square at z = 0 facing +z, seen head-on from distance `d` by a pinhole of focal
    /// `f`: it covers (f / d)² pixels.
    fn square_and_view(d: f64, f: f64) -> (Mesh, PosedCamera) {
        let m = Mesh {
            positions: vec![
                Point3::new(-0.5, -0.5, 0.0),
                Point3::new(0.5, -0.5, 0.0),
                Point3::new(0.5, 0.5, 0.0),
                Point3::new(-0.5, 0.5, 0.0),
            ],
            faces: vec![
                [VertexId(0), VertexId(1), VertexId(2)],
                [VertexId(0), VertexId(2), VertexId(3)],
            ],
            ..Default::default()
        };
        // Camera at (0, 0, d) looking down -z: camera +z is world -z (a turn about x).
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let pose = Pose {
            rotation,
            translation: -(rotation * Vector3::new(0.0, 0.0, d)),
        };
        let camera = Camera::new(
            1,
            CameraModel::SimplePinhole,
            2000,
            2000,
            vec![f, 1000.0, 1000.0],
        )
        .unwrap();
        (m, PosedCamera { camera, pose })
    }

    #[test]
    fn a_square_seen_head_on_asks_for_its_pixels_twice_over_per_axis() {
        let (m, v) = square_and_view(2.0, 1000.0);
        let a = auto_size(&m, &[&v], 8192);
        // (1000 / 2)² = 250,000 pixels.
        assert!((a.photo_pixels - 250_000.0).abs() < 1.0, "{a:?}");
        assert!((a.area_seen - 1.0).abs() < 1e-12);
        let needed = OVERSAMPLING * (250_000.0 / EXPECTED_UTILISATION).sqrt();
        assert!((a.needed - needed).abs() < 1e-6);
        assert_eq!(a.size, (needed.ceil() as u32).next_power_of_two());
        assert!(!a.capped);
        // Twice as far: a quarter of the pixels, half the side.
        let (m, v) = square_and_view(4.0, 1000.0);
        let b = auto_size(&m, &[&v], 8192);
        assert!((b.photo_pixels - 62_500.0).abs() < 1.0, "{b:?}");
        assert_eq!(b.size, a.size / 2);
        // The cap, and a camera behind the square sees nothing: the smallest size.
        assert_eq!(auto_size(&m, &[&v], 256).size, 256);
        assert!(auto_size(&m, &[&v], 256).capped);
        let (m, mut v) = square_and_view(2.0, 1000.0);
        v.pose.translation = -(v.pose.rotation * Vector3::new(0.0, 0.0, -2.0));
        let c = auto_size(&m, &[&v], 8192);
        assert_eq!((c.photo_pixels, c.area_seen, c.size), (0.0, 0.0, MIN_SIZE));
    }
}
