//! Meshroom / AliceVision camera files (`cameras.sfm`, the JSON form of an SfMData) read into
//! a [`Reconstruction`], so a scene reconstructed by Meshroom textures like a COLMAP one.
//!
//! What the format stores, from AliceVision's own reader and writer (`sfmDataIO/jsonIO.cpp`)
//! and its COLMAP exporter (`sfmDataIO/colmap.cpp`):
//! - numbers as JSON strings or numbers (both are accepted);
//! - a pose as `rotation` (the world-to-camera matrix, 9 values in Eigen's column-major
//!   order) and `center` (the camera centre in the world), so `t = -R C`;
//! - focal lengths in pixels before file version 1.2.2, then in millimetres with the sensor
//!   width (`fx = focalLength / sensorWidth * width`) and `pixelRatio` (a focal ratio
//!   `fx / fy` before 1.2.5, a pixel aspect ratio `fy / fx` from 1.2.5 on);
//! - the principal point from the image's top-left corner before 1.2.1, from its centre
//!   since; AliceVision's COLMAP exporter writes `w / 2 + offset` as COLMAP's `cx` with no
//!   half-pixel shift, and so does this reader;
//! - distortion `radial1` (k1), `radial3` (k1, k2, k3), `brown` (k1, k2, k3, t1, t2) and
//!   `fisheye4` (k1..k4) are COLMAP's FULL_OPENCV and OPENCV_FISHEYE, as AliceVision exports
//!   them; `pinhole` is PINHOLE.
//!
//! Views without a pose (not reconstructed) are left out, as COLMAP models leave out
//! unregistered images. Image names are the file names of the views' paths (Meshroom stores
//! absolute paths of the machine that ran it), looked up in the scene's images directory.

use super::colmap::{Image, Reconstruction};
use super::{Camera, CameraModel, Pose};
use crate::error::{Error, Result};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::Path;

/// Whether `path` names a Meshroom camera file (`.sfm`, or `.json` holding `views`).
pub fn is_sfm_file(path: &Path) -> bool {
    super::is_file_with_extension(path, &["sfm", "json"])
}

/// Reads a Meshroom `cameras.sfm` (or any SfMData JSON) into a [`Reconstruction`] with no 3D
/// points. Errors name the file and the element at fault.
pub fn read(path: &Path) -> Result<Reconstruction> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(path, &bytes)
}

/// [`read`] on bytes already in memory; `path` names them in errors.
pub fn parse(path: &Path, bytes: &[u8]) -> Result<Reconstruction> {
    let doc: Value = serde_json::from_slice(bytes).map_err(|e| {
        Error::parse(
            path,
            crate::error::Location::Line(e.line()),
            format!("not valid JSON: {e}"),
        )
    })?;
    let bad = |elem: String, msg: String| Error::at_element(path, elem, msg);
    if !doc.get("views").is_some_and(Value::is_array) {
        return Err(bad(
            "views".into(),
            "not a camera file: expected a JSON object with a list of views (and intrinsics \
             and poses)"
                .into(),
        ));
    }
    let version = match doc.get("version") {
        Some(Value::Array(v)) if v.len() == 3 => {
            let n: Vec<u32> = v
                .iter()
                .map(|x| num(x).map(|f| f as u32))
                .collect::<Option<_>>()
                .ok_or_else(|| bad("version".into(), "expected three numbers".into()))?;
            (n[0], n[1], n[2])
        }
        // No version: AliceVision reads it as the oldest layout.
        _ => (1, 0, 0),
    };
    let list = |key: &str| -> Result<&[Value]> {
        match doc.get(key) {
            Some(Value::Array(a)) => Ok(a),
            // AliceVision writes an empty list as "".
            Some(Value::String(s)) if s.is_empty() => Ok(&[]),
            None => Ok(&[]),
            Some(_) => Err(bad(key.into(), "expected a list".into())),
        }
    };
    let mut cameras = BTreeMap::new();
    let mut camera_of: BTreeMap<String, u32> = BTreeMap::new();
    for (i, intr) in list("intrinsics")?.iter().enumerate() {
        let elem = format!("intrinsics[{i}]");
        let key =
            id_of(intr, "intrinsicId").ok_or_else(|| bad(elem.clone(), "no intrinsicId".into()))?;
        let id = cameras.len() as u32 + 1;
        let cam = intrinsic(intr, id, version).map_err(|m| bad(elem.clone(), m))?;
        cameras.insert(id, cam);
        camera_of.insert(key, id);
    }
    let mut poses: BTreeMap<String, Pose> = BTreeMap::new();
    for (i, p) in list("poses")?.iter().enumerate() {
        let elem = format!("poses[{i}]");
        let key = id_of(p, "poseId").ok_or_else(|| bad(elem.clone(), "no poseId".into()))?;
        let t = p
            .get("pose")
            .and_then(|p| p.get("transform"))
            .ok_or_else(|| bad(elem.clone(), "no pose.transform".into()))?;
        let pose = transform(t).map_err(|m| bad(elem.clone(), m))?;
        poses.insert(key, pose);
    }
    let mut images = BTreeMap::new();
    for (i, v) in list("views")?.iter().enumerate() {
        let elem = format!("views[{i}]");
        let Some(pose) = id_of(v, "poseId").and_then(|k| poses.get(&k)) else {
            continue; // not reconstructed
        };
        let intr =
            id_of(v, "intrinsicId").ok_or_else(|| bad(elem.clone(), "no intrinsicId".into()))?;
        let &camera_id = camera_of.get(&intr).ok_or_else(|| {
            bad(
                elem.clone(),
                format!("intrinsic {intr} is not in the file's intrinsics"),
            )
        })?;
        let path_str = v
            .get("path")
            .and_then(Value::as_str)
            .ok_or_else(|| bad(elem.clone(), "no path".into()))?;
        let name = super::file_name(path_str);
        // A view with no file (synthetic scenes) is named by its id.
        let name = if name.is_empty() {
            format!(
                "view{}",
                id_of(v, "viewId").unwrap_or_else(|| i.to_string())
            )
        } else {
            name
        };
        let id = images.len() as u32 + 1;
        images.insert(
            id,
            Image {
                id,
                camera_id,
                name,
                pose: *pose,
                points2d: Vec::new(),
            },
        );
    }
    Ok(Reconstruction {
        cameras,
        images,
        points3d: BTreeMap::new(),
    })
}

/// A number written as a JSON number or a string.
fn num(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => s.trim().parse().ok(),
        _ => None,
    }
}

/// An id written as a number or a string, as text.
fn id_of(v: &Value, key: &str) -> Option<String> {
    match v.get(key)? {
        Value::Number(n) => Some(n.to_string()),
        Value::String(s) => Some(s.trim().to_string()),
        _ => None,
    }
}

fn field(v: &Value, key: &str) -> std::result::Result<f64, String> {
    v.get(key)
        .and_then(num)
        .filter(|x| x.is_finite())
        .ok_or_else(|| format!("{key} is missing or not a finite number"))
}

fn numbers(v: &Value, key: &str) -> std::result::Result<Vec<f64>, String> {
    match v.get(key) {
        Some(Value::Array(a)) => a
            .iter()
            .map(|x| num(x).filter(|f| f.is_finite()))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| format!("{key} holds something that is not a number")),
        Some(Value::String(s)) if s.is_empty() => Ok(Vec::new()),
        None => Ok(Vec::new()),
        Some(_) => Err(format!("{key} is not a list of numbers")),
    }
}

/// One intrinsic as a COLMAP camera.
fn intrinsic(v: &Value, id: u32, version: (u32, u32, u32)) -> std::result::Result<Camera, String> {
    let w = field(v, "width")?;
    let h = field(v, "height")?;
    if !(w >= 1.0 && h >= 1.0 && w <= u32::MAX as f64 && h <= u32::MAX as f64) {
        return Err(format!("image size {w} x {h} is not a size"));
    }
    let pp = numbers(v, "principalPoint")?;
    // Version 1.0-1.1 wrote the principal point as an object {x, y} in some releases.
    let (mut cx, mut cy) = match (pp.as_slice(), v.get("principalPoint")) {
        ([x, y], _) => (*x, *y),
        (_, Some(o @ Value::Object(_))) => (field(o, "x")?, field(o, "y")?),
        _ => return Err("principalPoint needs two numbers".into()),
    };
    if version >= (1, 2, 1) {
        cx += w / 2.0;
        cy += h / 2.0;
    }
    let (fx, fy) = if version < (1, 2, 0) {
        let f = field(v, "pxFocalLength")?;
        (f, f)
    } else if version < (1, 2, 2) {
        // Two values (fx, fy) in these versions; one number is read as both.
        match v.get("pxFocalLength") {
            Some(Value::Array(_)) => match numbers(v, "pxFocalLength")?.as_slice() {
                [fx, fy] => (*fx, *fy),
                _ => return Err("pxFocalLength needs two numbers".into()),
            },
            _ => {
                let f = field(v, "pxFocalLength")?;
                (f, f)
            }
        }
    } else {
        let sensor = v.get("sensorWidth").and_then(num).unwrap_or(36.0);
        let fx = field(v, "focalLength")? / sensor * w;
        let ratio = v.get("pixelRatio").and_then(num).unwrap_or(1.0);
        // Before 1.2.5 the field held fx / fy; since, the pixel aspect ratio fy / fx.
        let fy = if version < (1, 2, 5) {
            fx / ratio
        } else {
            fx * ratio
        };
        (fx, fy)
    };
    if !(fx > 0.0 && fy > 0.0 && fx.is_finite() && fy.is_finite()) {
        return Err(format!(
            "focal length {fx} x {fy} pixels is not positive (an uncalibrated camera?)"
        ));
    }
    let d = numbers(v, "distortionParams")?;
    let k = |i: usize| d.get(i).copied().unwrap_or(0.0);
    let ty = v.get("type").and_then(Value::as_str).unwrap_or("pinhole");
    let (model, params) = match ty {
        "pinhole" => (CameraModel::Pinhole, vec![fx, fy, cx, cy]),
        "radial1" => (
            CameraModel::FullOpencv,
            vec![fx, fy, cx, cy, k(0), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ),
        "radial3" => (
            CameraModel::FullOpencv,
            vec![fx, fy, cx, cy, k(0), k(1), 0.0, 0.0, k(2), 0.0, 0.0, 0.0],
        ),
        "brown" => (
            CameraModel::FullOpencv,
            vec![fx, fy, cx, cy, k(0), k(1), k(3), k(4), k(2), 0.0, 0.0, 0.0],
        ),
        "fisheye4" => (
            CameraModel::OpencvFisheye,
            vec![fx, fy, cx, cy, k(0), k(1), k(2), k(3)],
        ),
        other => {
            return Err(format!(
                "camera type '{other}' is not supported (pinhole, radial1, radial3, brown, \
                 fisheye4)"
            ))
        }
    };
    Camera::new(id, model, w as u32, h as u32, params)
}

/// A pose's `transform` (`rotation` column-major world-to-camera, `center`) as COLMAP's pose.
fn transform(t: &Value) -> std::result::Result<Pose, String> {
    let r = numbers(t, "rotation")?;
    let c = numbers(t, "center")?;
    if r.len() != 9 || c.len() != 3 {
        return Err(format!(
            "a transform needs 9 rotation and 3 centre values, found {} and {}",
            r.len(),
            c.len()
        ));
    }
    let m = Matrix3::from_column_slice(&r);
    // A rotation: orthonormal to the precision files are written with, and proper.
    let err = (m * m.transpose() - Matrix3::identity()).abs().max();
    if err > 1e-5 || m.determinant() < 0.0 {
        return Err(format!(
            "rotation is not a rotation (|R R^T - I| = {err:.2e}, det {:.4})",
            m.determinant()
        ));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    let centre = Vector3::new(c[0], c[1], c[2]);
    Ok(Pose {
        translation: -(rotation * centre),
        rotation,
    })
}
