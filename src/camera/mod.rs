//! Cameras: intrinsics with every COLMAP model ([`CameraModel`]), poses in COLMAP's
//! world-to-camera convention ([`Pose`]), and the COLMAP sparse-model format ([`colmap`]).

pub mod bundler;
pub mod colmap;
pub mod meshroom;
mod model;
pub mod nvm;
pub mod opencv;
pub mod openmvs;

pub use model::CameraModel;

use crate::error::{Error, Location, Result};
use nalgebra::{Point2, Point3, Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Whether `path` is a file whose extension is one of `exts` (any case).
pub(crate) fn is_file_with_extension(path: &Path, exts: &[&str]) -> bool {
    path.is_file()
        && path
            .extension()
            .is_some_and(|e| exts.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// The file name of a path stored by another program (split at `/` or `\`): camera files
/// store paths of the machine that made them, and the scene's images directory supplies the
/// folder.
pub(crate) fn file_name(stored: &str) -> String {
    stored
        .rsplit(['/', '\\'])
        .next()
        .unwrap_or(stored)
        .to_string()
}

/// The whitespace-separated words of a text camera file with the line each is on, so that
/// errors name the line.
pub(crate) struct Words<'a> {
    path: &'a Path,
    words: Box<dyn Iterator<Item = (usize, &'a str)> + 'a>,
    line: usize,
}

impl<'a> Words<'a> {
    /// The words of `text`, leaving out lines that start with `comment`.
    pub(crate) fn new(path: &'a Path, text: &'a str, comment: Option<char>) -> Self {
        let words = text
            .lines()
            .enumerate()
            .filter(move |(_, l)| comment.is_none_or(|c| !l.trim_start().starts_with(c)))
            .flat_map(|(i, l)| l.split_whitespace().map(move |t| (i + 1, t)));
        Words {
            path,
            words: Box::new(words),
            line: 1,
        }
    }

    /// The line of the last word read (1 before any).
    pub(crate) fn line(&self) -> usize {
        self.line
    }

    /// An error at the last word's line.
    pub(crate) fn error(&self, msg: impl Into<String>) -> Error {
        Error::parse(self.path, Location::Line(self.line), msg)
    }

    /// The next word, or an error saying what the file ends before.
    pub(crate) fn word(&mut self, what: &str) -> Result<&'a str> {
        let (line, t) = self
            .words
            .next()
            .ok_or_else(|| self.error(format!("ends before {what}")))?;
        self.line = line;
        Ok(t)
    }

    /// `word` (the last one read) as a finite number.
    pub(crate) fn as_number(&self, word: &str, what: &str) -> Result<f64> {
        word.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.error(format!("{what}: '{word}' is not a number")))
    }

    /// The next word as a finite number.
    pub(crate) fn number(&mut self, what: &str) -> Result<f64> {
        let w = self.word(what)?;
        self.as_number(w, what)
    }
}

/// The size of photograph `name` in `images`, for camera files that do not store it; the
/// error without `images` names `model` and says what to give.
pub(crate) fn photo_size(model: &Path, images: Option<&Path>, name: &str) -> Result<(u32, u32)> {
    let dir = images.ok_or_else(|| {
        Error::at_element(
            model,
            "images",
            format!("it stores no size for {name}: give the photographs (--images)"),
        )
    })?;
    let p = dir.join(name);
    image::image_dimensions(&p)
        .map_err(|e| Error::parse(&p, Location::File, format!("cannot read its size: {e}")))
}

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
    /// A camera, checking that `params` has the length `model` needs and is finite, that the
    /// focal lengths are positive and that the image has pixels (a zero or negative focal
    /// length projects every point to the principal point or mirrors the image: no
    /// calibration writes one, and it would bind the mesh to wrong colours silently).
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
        if model == CameraModel::Equirectangular {
            if !(params[0] > 0.0 && params[1] > 0.0) {
                return Err(format!(
                    "camera {id}: panorama size {} x {} must be positive",
                    params[0], params[1]
                ));
            }
        } else {
            let (fx, fy, _, _) = model.intrinsics(&params);
            if !(fx > 0.0 && fy > 0.0) {
                return Err(format!(
                    "camera {id}: focal lengths {fx} and {fy} must be positive"
                ));
            }
        }
        if width == 0 || height == 0 {
            return Err(format!(
                "camera {id}: image size {width} x {height} has no pixels"
            ));
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
