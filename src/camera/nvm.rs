//! VisualSFM `.nvm` files (`NVM_V3`) read into a [`Reconstruction`].
//!
//! The format, from VisualSFM's documentation and its reader in Changchang Wu's
//! Multicore Bundle Adjustment (`util.h`, `LoadNVM`), which OpenMVS's `InterfaceVisualSFM`
//! uses as is:
//! - a header `NVM_V3`, optionally followed by `FixedK fx cx fy cy r` (one calibration for
//!   every camera; its principal point is taken in COLMAP's convention, pixel centres at
//!   +0.5, as no reference says otherwise); `NVM_V3_R9T` stores rotations as 9 numbers and translations instead of
//!   quaternions and camera centres;
//! - a camera per line: `name f qw qx qy qz cx cy cz r 0`: the world-to-camera rotation as a
//!   quaternion, the camera centre `C` (so `t = -R C`), one focal length in pixels and the
//!   principal point at the image centre (COLMAP's `w / 2, h / 2`);
//! - `r` is a *measurement* distortion on normalised coordinates: the ideal pinhole point is
//!   `u = d (1 + r |d|^2)` of the measured point `d`, the inverse of COLMAP's direction. It
//!   becomes COLMAP's FULL_OPENCV with the [3/3] Padé approximant of that inverse
//!   ([`inverse_measurement_distortion`]), checked per camera on reading to agree within
//!   0.01 px out to the image's corners (1e-5 px for |r| up to 0.17);
//! - then the points (`x y z r g b n` and `n` measurements), which are not needed here;
//! - several models may follow one another; the first (VisualSFM writes the largest first)
//!   is read.
//!
//! Image names are the file names of the stored paths (VisualSFM stores them relative to
//! where it ran), looked up in the scene's images directory; their sizes come from the
//! photographs' headers, as the file stores none.

use super::colmap::{Image, Reconstruction};
use super::{Camera, CameraModel, Pose};
use crate::error::{Error, Location, Result};
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use std::path::Path;

/// Whether `path` names a VisualSFM file (`*.nvm`).
pub fn is_nvm_file(path: &Path) -> bool {
    super::is_file_with_extension(path, &["nvm"])
}

/// Reads `path`; photographs are looked up by file name in `images` for their size.
pub fn read(path: &Path, images: Option<&Path>) -> Result<Reconstruction> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let size_of = |name: &str| super::photo_size(path, images, name);
    parse(path, &text, &size_of)
}

/// Largest error, in pixels, accepted between the FULL_OPENCV camera and the file's
/// measurement distortion over the image; beyond it the camera is refused rather than
/// bent silently.
const MAX_DISTORTION_ERROR_PX: f64 = 0.01;

/// [`read`] on the file's text and a source of image sizes (by file name).
pub fn parse(
    path: &Path,
    text: &str,
    size_of: &dyn Fn(&str) -> Result<(u32, u32)>,
) -> Result<Reconstruction> {
    let mut words = super::Words::new(path, text, None);
    let header = words.word("the NVM_V3 header")?;
    if !header.starts_with("NVM_V3") {
        return Err(words.error(format!(
            "not a VisualSFM file: starts with '{header}', expected NVM_V3"
        )));
    }
    let r9t = header.contains("R9T");
    let mut first = words.word("the number of cameras")?;
    // FixedK fx cx fy cy r: principal point in pixels and a shared distortion.
    let mut fixed: Option<[f64; 5]> = None;
    if first == "FixedK" {
        let mut k = [0.0; 5];
        for (v, what) in k.iter_mut().zip(["fx", "cx", "fy", "cy", "r"]) {
            *v = words.number(&format!("FixedK {what}"))?;
        }
        fixed = Some(k);
        first = words.word("the number of cameras")?;
    }
    let ncam = words.as_number(first, "the number of cameras")?;
    if !(ncam >= 0.0 && ncam.fract() == 0.0 && ncam <= 1e7) {
        return Err(words.error(format!("{ncam} cameras is not a count")));
    }
    let mut rec = Reconstruction::default();
    for i in 0..ncam as usize {
        let what = |k: &str| format!("camera {i}'s {k}");
        let name = super::file_name(words.word(&what("file name"))?);
        let line = words.line();
        let f = words.number(&what("focal length"))?;
        let mut rot = [0.0; 9];
        let nrot = if r9t { 9 } else { 4 };
        for v in rot.iter_mut().take(nrot) {
            *v = words.number(&what("rotation"))?;
        }
        let mut c = [0.0; 3];
        for v in c.iter_mut() {
            *v = words.number(&what("centre"))?;
        }
        let r = words.number(&what("distortion"))?;
        let _zero = words.number(&what("final 0"))?;
        let rotation = if r9t {
            let m = Matrix3::from_row_slice(&rot);
            let err = (m * m.transpose() - Matrix3::identity()).abs().max();
            if err > 1e-5 || m.determinant() < 0.0 {
                return Err(Error::parse(
                    path,
                    Location::Line(line),
                    format!("camera {i} ({name}): rotation off by {err:.2e}: not a rotation"),
                ));
            }
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
        } else {
            let q = Quaternion::new(rot[0], rot[1], rot[2], rot[3]);
            if (q.norm() - 1.0).abs() > 1e-3 {
                return Err(Error::parse(
                    path,
                    Location::Line(line),
                    format!(
                        "camera {i} ({name}): quaternion of length {:.4}: not a rotation",
                        q.norm()
                    ),
                ));
            }
            UnitQuaternion::from_quaternion(q)
        };
        // R9T stores the translation itself; the quaternion form stores the centre.
        let c = Vector3::from(c);
        let translation = if r9t { c } else { -(rotation * c) };
        if f <= 0.0 {
            return Err(Error::parse(
                path,
                Location::Line(line),
                format!("camera {i} ({name}): focal length {f} is not positive"),
            ));
        }
        let (w, h) = size_of(&name)?;
        let (fx, fy, cx, cy, r) = match fixed {
            // As Multicore Bundle Adjustment reads it: the shared distortion unless it is 0.
            Some([fx, cx, fy, cy, k]) => (fx, fy, cx, cy, if k != 0.0 { k } else { r }),
            None => (f, f, w as f64 / 2.0, h as f64 / 2.0, r),
        };
        let (model, params) = if r == 0.0 {
            (CameraModel::Pinhole, vec![fx, fy, cx, cy])
        } else {
            let ext = inverse_measurement_distortion(r);
            let mut p = vec![fx, fy, cx, cy];
            p.extend_from_slice(&ext);
            (CameraModel::FullOpencv, p)
        };
        let id = rec.cameras.len() as u32 + 1;
        let cam = Camera::new(id, model, w, h, params)
            .map_err(|m| Error::at_element(path, format!("camera {i}"), m))?;
        if r != 0.0 {
            let err = distortion_error_px(&cam, r);
            if err.is_nan() || err > MAX_DISTORTION_ERROR_PX {
                return Err(Error::parse(
                    path,
                    Location::Line(line),
                    format!(
                        "camera {i} ({name}): radial distortion {r} is too strong to hold \
                         (the nearest camera scantex can use is {err:.3} px off at the image \
                         corners); undistort the photographs and set it to 0"
                    ),
                ));
            }
        }
        rec.cameras.insert(id, cam);
        rec.images.insert(
            id,
            Image {
                id,
                camera_id: id,
                name,
                pose: Pose {
                    rotation,
                    translation,
                },
                points2d: Vec::new(),
            },
        );
    }
    Ok(rec)
}

/// FULL_OPENCV's `k1, k2, p1, p2, k3, k4, k5, k6` for the inverse of NVM's measurement
/// distortion `u = d (1 + r |d|^2)`: the radial factor `|d| / |u|` as a function of
/// `t = r |u|^2` is the series `1 - t + 3 t^2 - 12 t^3 + 55 t^4 - ...` (coefficients
/// `(-1)^n C(3n, n) / (2n + 1)`, the inverse of `x + x^3`); its [3/3] Padé approximant
/// `(1 + 113/13 t + 243/13 t^2 + 85/13 t^3) / (1 + 126/13 t + 330/13 t^2 + 193/13 t^3)`
/// matches it to t^6 and is FULL_OPENCV's rational radial term.
pub fn inverse_measurement_distortion(r: f64) -> [f64; 8] {
    let (r2, r3) = (r * r, r * r * r);
    [
        113.0 / 13.0 * r,
        243.0 / 13.0 * r2,
        0.0,
        0.0,
        85.0 / 13.0 * r3,
        126.0 / 13.0 * r,
        330.0 / 13.0 * r2,
        193.0 / 13.0 * r3,
    ]
}

/// Largest distance, in pixels, between where `cam` images a ray and where NVM's model
/// (`u = d (1 + r |d|^2)`) does, over radii up to the image's farthest corner.
fn distortion_error_px(cam: &Camera, r: f64) -> f64 {
    let p = &cam.params;
    let (fx, cx, cy) = (p[0], p[2], p[3]);
    let corner = [(0.0, 0.0), (cam.width as f64, cam.height as f64)]
        .iter()
        .map(|&(x, y)| ((x - cx).powi(2) + (y - cy).powi(2)).sqrt())
        .fold(0.0f64, f64::max)
        / fx;
    const STEPS: usize = 64;
    let mut worst = 0.0f64;
    for s in 1..=STEPS {
        // A measured radius, its ideal point, and where the camera puts that ray.
        let d = corner * s as f64 / STEPS as f64;
        let u = d * (1.0 + r * d * d);
        if u <= 0.0 {
            return f64::INFINITY; // the model folds over inside the image
        }
        match cam.project(&Vector3::new(u, 0.0, 1.0)) {
            Some(px) => worst = worst.max(((px.x - cx) - d * fx).abs()),
            None => return f64::INFINITY,
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Padé radial term inverts NVM's distortion: pushing a measured point to its ideal
    /// point and back through FULL_OPENCV returns it, for distortions of both signs as
    /// strong as real VisualSFM files hold (-0.39 to 0.17), on a camera whose corners are
    /// half a focal length from the centre: within 1e-5 px up to |r| = 0.17, and within the
    /// reader's bound at -0.39.
    #[test]
    fn the_full_opencv_term_inverts_the_measurement_distortion() {
        for (r, bound) in [
            (-0.39, MAX_DISTORTION_ERROR_PX),
            (-0.1, 1e-5),
            (-0.01, 1e-5),
            (0.01, 1e-5),
            (0.1, 1e-5),
            (0.17, 1e-5),
        ] {
            let cam = Camera::new(1, CameraModel::FullOpencv, 2000, 1500, {
                let mut p = vec![2500.0, 2500.0, 1000.0, 750.0];
                p.extend_from_slice(&inverse_measurement_distortion(r));
                p
            })
            .unwrap();
            let err = distortion_error_px(&cam, r);
            assert!(err < bound, "r = {r}: {err} px");
        }
    }

    /// A camera whose distortion folds the image over is refused, naming it.
    #[test]
    fn a_distortion_too_strong_to_hold_is_refused() {
        let text = "NVM_V3\n1\na.jpg 500 1 0 0 0 0 0 0 -2.0 0\n0\n";
        let e = parse(Path::new("x.nvm"), text, &|_| Ok((2000, 1500)))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("camera 0 (a.jpg)") && e.contains("too strong"),
            "{e}"
        );
    }
}
