//! Bundler camera files (`bundle.out`, v0.3, with the image list beside it) read into a
//! [`Reconstruction`].
//!
//! Bundler's conventions (its documentation, "Output format"): a camera is `f k1 k2`, the
//! world-to-camera rotation `R` (three rows) and `t`, so `P = R X + t`; the camera looks down
//! its -z axis, `p = -P / P.z`, `p' = f (1 + k1 |p|^2 + k2 |p|^4) p`, in pixels from the image
//! centre with y up. In COLMAP's frame (y down, z forward) that is `diag(1, -1, -1)` applied
//! to `R` and `t`, a RADIAL camera `(f, w / 2, h / 2, k1, k2)`: the same projection, exactly.
//! A camera of all zeros was not reconstructed and is left out. The file stores no image
//! size: it is read from each photograph's header.

use super::colmap::{Image, Reconstruction};
use super::{Camera, CameraModel, Pose};
use crate::error::{Error, Location, Result};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use std::path::{Path, PathBuf};

/// Whether `path` names a Bundler file (`*.out`).
pub fn is_bundle_file(path: &Path) -> bool {
    super::is_file_with_extension(path, &["out"])
}

/// The image list that goes with `bundle`: `<bundle>.list.txt` (as COLMAP exports it), else
/// `list.txt` beside it (as Bundler writes it).
pub fn list_of(bundle: &Path) -> Option<PathBuf> {
    let mut named = bundle.as_os_str().to_owned();
    named.push(".list.txt");
    [PathBuf::from(named), bundle.with_file_name("list.txt")]
        .into_iter()
        .find(|p| p.is_file())
}

/// Reads `bundle` with its image list; photographs are looked up by file name in `images`
/// for their size.
pub fn read(bundle: &Path, images: Option<&Path>) -> Result<Reconstruction> {
    let list = list_of(bundle).ok_or_else(|| {
        Error::at_element(
            bundle,
            "image list",
            "no image list beside it (expected <file>.list.txt or list.txt)",
        )
    })?;
    let text = std::fs::read_to_string(bundle).map_err(|e| Error::io(bundle, e))?;
    let list_text = std::fs::read_to_string(&list).map_err(|e| Error::io(&list, e))?;
    let names: Vec<String> = list_text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| super::file_name(l.split_whitespace().next().unwrap_or("")))
        .collect();
    let size_of = |name: &str| super::photo_size(bundle, images, name);
    parse(bundle, &text, &names, &size_of)
}

/// [`read`] on the file's text, the list's file names and a source of image sizes.
pub fn parse(
    path: &Path,
    text: &str,
    names: &[String],
    size_of: &dyn Fn(&str) -> Result<(u32, u32)>,
) -> Result<Reconstruction> {
    let mut words = super::Words::new(path, text, Some('#'));
    let ncam = words.number("the number of cameras")?;
    let _npts = words.number("the number of points")?;
    if !(ncam >= 0.0 && ncam.fract() == 0.0 && ncam <= 1e7) {
        return Err(Error::parse(
            path,
            Location::Line(1),
            format!("{ncam} cameras is not a count"),
        ));
    }
    let ncam = ncam as usize;
    if names.len() != ncam {
        return Err(Error::at_element(
            path,
            "image list",
            format!(
                "the file has {ncam} cameras but its image list names {} images",
                names.len()
            ),
        ));
    }
    let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let mut rec = Reconstruction::default();
    for (i, name) in names.iter().enumerate() {
        let what = |k: &str| format!("camera {i}'s {k}");
        let (f, k1, k2) = (
            words.number(&what("f"))?,
            words.number(&what("k1"))?,
            words.number(&what("k2"))?,
        );
        let mut r = Matrix3::zeros();
        for row in 0..3 {
            for col in 0..3 {
                r[(row, col)] = words.number(&what("rotation"))?;
            }
        }
        let t = Vector3::new(
            words.number(&what("translation"))?,
            words.number(&what("translation"))?,
            words.number(&what("translation"))?,
        );
        if f == 0.0 {
            continue; // not reconstructed
        }
        let err = (r * r.transpose() - Matrix3::identity()).abs().max();
        if f < 0.0 || err > 1e-5 || r.determinant() < 0.0 {
            return Err(Error::parse(
                path,
                Location::Line(words.line()),
                format!("camera {i}: f = {f}, rotation off by {err:.2e}: not a camera"),
            ));
        }
        let (w, h) = size_of(name)?;
        let id = rec.cameras.len() as u32 + 1;
        let cam = Camera::new(
            id,
            CameraModel::Radial,
            w,
            h,
            vec![f, w as f64 / 2.0, h as f64 / 2.0, k1, k2],
        )
        .map_err(|m| Error::at_element(path, format!("camera {i}"), m))?;
        let rotation =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(flip * r));
        rec.cameras.insert(id, cam);
        rec.images.insert(
            id,
            Image {
                id,
                camera_id: id,
                name: name.clone(),
                pose: Pose {
                    rotation,
                    translation: flip * t,
                },
                points2d: Vec::new(),
            },
        );
    }
    Ok(rec)
}
