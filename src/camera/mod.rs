//! Cameras: intrinsics with every COLMAP model ([`CameraModel`]), poses in COLMAP's
//! world-to-camera convention ([`Pose`]), and the COLMAP sparse-model format ([`colmap`]).

pub mod bundler;
pub mod colmap;
pub mod meshroom;
mod model;
pub mod opencv;

pub use model::CameraModel;

use nalgebra::{Point2, Point3, Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A calibrated camera: model, image size and COLMAP's parameter vector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// COLMAP's camera id.
    pub id: u32,
    /// Projection model.
    pub model: CameraModel,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Parameters in COLMAP's order for `model` (see [`CameraModel`]).
    pub params: Vec<f64>,
}

impl Camera {
    /// A camera, checking that `params` has the length `model` needs and is finite.
    pub fn new(
        id: u32,
        model: CameraModel,
        width: u32,
        height: u32,
        params: Vec<f64>,
    ) -> std::result::Result<Self, String> {
        if params.len() != model.num_params() {
            return Err(format!(
                "camera {id}: model {} takes {} parameters, found {}",
                model.name(),
                model.num_params(),
                params.len()
            ));
        }
        if let Some(i) = params.iter().position(|p| !p.is_finite()) {
            return Err(format!("camera {id}: parameter {i} is not finite"));
        }
        Ok(Camera {
            id,
            model,
            width,
            height,
            params,
        })
    }

    /// Pixel of the camera-frame point `p`, or `None` if it cannot be imaged. The pixel may lie
    /// outside the image; see [`Camera::contains`].
    pub fn project(&self, p: &Vector3<f64>) -> Option<Point2<f64>> {
        self.model
            .img_from_cam(&self.params, [p.x, p.y, p.z])
            .map(|[x, y]| Point2::new(x, y))
    }

    /// Unit camera-frame ray through pixel `px` (pixel centres at +0.5).
    pub fn ray(&self, px: &Point2<f64>) -> Option<Vector3<f64>> {
        self.model
            .ray_from_img(&self.params, [px.x, px.y])
            .map(Vector3::from)
    }

    /// True if `px` lies inside the image rectangle `[0, width] x [0, height]`.
    pub fn contains(&self, px: &Point2<f64>) -> bool {
        px.x >= 0.0 && px.y >= 0.0 && px.x <= self.width as f64 && px.y <= self.height as f64
    }
}

/// A rigid transform from world to camera coordinates, as COLMAP stores it:
/// `x_cam = R * x_world + t`, with R from the quaternion (QW, QX, QY, QZ).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Rotation world -> camera.
    pub rotation: UnitQuaternion<f64>,
    /// Translation world -> camera.
    pub translation: Vector3<f64>,
}

impl Pose {
    /// From COLMAP's `QW QX QY QZ` and `TX TY TZ`.
    ///
    /// A quaternion within 1e-4 of unit length is kept exactly as stored, as COLMAP 4.2 does:
    /// text models round it to 6 digits, and applying it unnormalised (the same formula as
    /// Eigen's) reproduces COLMAP's projections bit for bit; it also makes our writer -> reader
    /// round trip exact. A quaternion further from unit is normalised: it was not written by
    /// COLMAP's bundle adjuster, and only its direction can be meant.
    pub fn from_colmap(q: [f64; 4], t: [f64; 3]) -> Self {
        let q = Quaternion::new(q[0], q[1], q[2], q[3]);
        let rotation = if (q.norm() - 1.0).abs() <= 1e-4 {
            UnitQuaternion::new_unchecked(q)
        } else {
            UnitQuaternion::from_quaternion(q)
        };
        Pose {
            rotation,
            translation: Vector3::from(t),
        }
    }

    /// COLMAP's `[QW, QX, QY, QZ]`.
    pub fn quaternion_wxyz(&self) -> [f64; 4] {
        let q = self.rotation.quaternion();
        [q.w, q.i, q.j, q.k]
    }

    /// World point -> camera frame.
    pub fn transform(&self, p: &Point3<f64>) -> Vector3<f64> {
        self.rotation * p.coords + self.translation
    }

    /// Camera centre in world coordinates: `-R^T t`.
    pub fn center(&self) -> Point3<f64> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }

    /// Viewing direction (camera +Z) in world coordinates.
    pub fn view_dir(&self) -> Vector3<f64> {
        self.rotation.inverse() * Vector3::z()
    }
}

/// A camera with its pose: what a photograph was taken with.
#[derive(Debug, Clone, PartialEq)]
pub struct PosedCamera {
    /// Intrinsics.
    pub camera: Camera,
    /// Extrinsics.
    pub pose: Pose,
}

impl PosedCamera {
    /// Pixel of world point `p`, or `None` if it cannot be imaged.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        self.camera.project(&self.pose.transform(p))
    }

    /// Unit world-frame ray through pixel `px`.
    pub fn world_ray(&self, px: &Point2<f64>) -> Option<Vector3<f64>> {
        self.camera
            .ray(px)
            .map(|r| self.pose.rotation.inverse() * r)
    }
}
