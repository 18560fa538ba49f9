//! OpenMVS interface archives (`scene.mvs`, as `InterfaceCOLMAP`, `InterfaceVisualSFM` and
//! the other OpenMVS importers write them) read into a [`Reconstruction`].
//!
//! The layout is OpenMVS's `libs/MVS/Interface.h`, versions 0 to 7: an optional header
//! (`MVSI`, a `u32` version, a reserved `u32`; a file without it is version 0), then
//! little-endian values: `u64`-counted strings and vectors, `u32` ids, `f64` matrices in
//! row-major order. What is read:
//! - platforms, each with cameras (`name`, `bandName` from v4, `width height` from v1, `K`,
//!   `R`, `C` relative to the platform) and poses (`R` world-to-platform, `C` its centre);
//! - images (`name`, `maskName` from v5, platform, camera and pose ids, an id from v3, depth
//!   range and view scores from v7); an image whose pose id is `NO_ID` was not
//!   reconstructed and is left out, as COLMAP leaves out unregistered images.
//!
//! The points after the images are not needed and not read.
//!
//! Conventions (`Interface.h`): a camera's pose is `R = R_cam R_pose`,
//! `C = R_pose^T C_cam + C_pose`, in COLMAP's frame (x right, y down, z forward). `K` is
//! taken as COLMAP's intrinsics as they are, as OpenMVS's own `InterfaceCOLMAP` writes and
//! reads them both ways (no half-pixel shift, although `Interface.h` calls integer
//! coordinates pixel centres; `docs/decisions.md`, "OpenMVS scenes"). A camera with no
//! resolution stored (`width = height = 0`) has `K` divided by `max(width, height)` of its
//! images, whose size then comes from the photographs. The interface has no distortion:
//! OpenMVS works on undistorted photographs, and so the camera is PINHOLE.
//!
//! OpenMVS's own full scene files (written by `DensifyPointCloud` and the later tools with
//! boost serialization) are a different format; they are recognised and refused with what to
//! do instead.

use super::colmap::{Image, Reconstruction};
use super::{Camera, CameraModel, Pose};
use crate::error::{Error, Location, Result};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use std::path::Path;

/// Newest interface version this reader knows.
pub const MAX_VERSION: u32 = 7;

/// Whether `path` names an OpenMVS scene (`*.mvs`).
pub fn is_mvs_file(path: &Path) -> bool {
    super::is_file_with_extension(path, &["mvs"])
}

/// Reads `path`; photographs (looked up by file name in `images`) are opened only for
/// cameras that store no resolution.
pub fn read(path: &Path, images: Option<&Path>) -> Result<Reconstruction> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let size_of = |name: &str| super::photo_size(path, images, name);
    parse(path, &bytes, &size_of)
}

/// Little-endian cursor over the archive; errors give the byte offset.
struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if self.bytes.len() - self.at < n {
            return Err(Error::parse(
                self.path,
                Location::Byte(self.at as u64),
                format!("ends inside {what} (truncated, or not an OpenMVS interface archive)"),
            ));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn f64s<const N: usize>(&mut self, what: &str) -> Result<[f64; N]> {
        let at = self.at;
        let b = self.take(8 * N, what)?;
        let mut out = [0.0; N];
        for (o, c) in out.iter_mut().zip(b.chunks_exact(8)) {
            *o = f64::from_le_bytes(c.try_into().unwrap());
        }
        if out.iter().any(|v| !v.is_finite()) {
            return Err(Error::parse(
                self.path,
                Location::Byte(at as u64),
                format!("{what} holds a value that is not finite"),
            ));
        }
        Ok(out)
    }
    /// A vector's length, checked against the bytes left (each element takes at least
    /// `min_size`), so that a corrupt count cannot ask for terabytes.
    fn count(&mut self, min_size: usize, what: &str) -> Result<usize> {
        let at = self.at;
        let n = u64::from_le_bytes(self.take(8, what)?.try_into().unwrap());
        let left = (self.bytes.len() - self.at) as u64;
        if n.saturating_mul(min_size.max(1) as u64) > left {
            return Err(Error::parse(
                self.path,
                Location::Byte(at as u64),
                format!("{what}: {n} entries do not fit in the {left} bytes left"),
            ));
        }
        Ok(n as usize)
    }
    fn string(&mut self, what: &str) -> Result<String> {
        let n = self.count(1, what)?;
        let at = self.at;
        let b = self.take(n, what)?;
        String::from_utf8(b.to_vec()).map_err(|_| {
            Error::parse(
                self.path,
                Location::Byte(at as u64),
                format!("{what} is not UTF-8 text"),
            )
        })
    }
}

/// A camera on a platform: resolution (0 if normalised), `K`, and its pose on the platform.
struct MvsCamera {
    width: u32,
    height: u32,
    k: Matrix3<f64>,
    r: Matrix3<f64>,
    c: Vector3<f64>,
}

/// One platform's cameras and poses (`R`, `C`).
struct Platform {
    cameras: Vec<MvsCamera>,
    poses: Vec<(Matrix3<f64>, Vector3<f64>)>,
}

/// The interface version of `bytes` and where its body starts, or an error for files that
/// are not interface archives.
fn header(path: &Path, bytes: &[u8]) -> Result<(u32, usize)> {
    if bytes.starts_with(b"MVSI") {
        let v = bytes
            .get(4..8)
            .map(|b| u32::from_le_bytes(b.try_into().unwrap()))
            .ok_or_else(|| Error::parse(path, Location::Byte(4), "ends inside its header"))?;
        if v > MAX_VERSION {
            return Err(Error::parse(
                path,
                Location::Byte(4),
                format!(
                    "interface version {v} is newer than this reader knows ({MAX_VERSION}); \
                     convert it with an OpenMVS of that version to COLMAP (InterfaceCOLMAP)"
                ),
            ));
        }
        return Ok((v, 12));
    }
    let head = &bytes[..bytes.len().min(64)];
    if head.windows(22).any(|w| w == b"serialization::archive") {
        return Err(Error::parse(
            path,
            Location::Byte(0),
            "an OpenMVS full scene (boost serialization), not the interface archive scantex \
             reads: export it with `InterfaceCOLMAP -i scene.mvs -o colmap/` and give that \
             model, or give the scene.mvs the importer wrote",
        ));
    }
    Ok((0, 0))
}

/// [`read`] on the archive's bytes and a source of image sizes (by file name).
pub fn parse(
    path: &Path,
    bytes: &[u8],
    size_of: &dyn Fn(&str) -> Result<(u32, u32)>,
) -> Result<Reconstruction> {
    let (version, start) = header(path, bytes)?;
    let mut rd = Reader {
        path,
        bytes,
        at: start,
    };
    let m33 = |a: [f64; 9]| Matrix3::from_row_slice(&a);
    // A platform takes at least its name's and two vectors' counts.
    let nplat = rd.count(24, "the platforms")?;
    let mut platforms = Vec::with_capacity(nplat);
    for p in 0..nplat {
        let what = |k: &str| format!("platform {p}'s {k}");
        rd.string(&what("name"))?;
        let ncam = rd.count(8 + 9 * 8 * 2 + 24, &what("cameras"))?;
        let mut cameras = Vec::with_capacity(ncam);
        for c in 0..ncam {
            let what = |k: &str| format!("platform {p} camera {c}'s {k}");
            rd.string(&what("name"))?;
            if version > 3 {
                rd.string(&what("band name"))?;
            }
            let (width, height) = if version > 0 {
                (rd.u32(&what("width"))?, rd.u32(&what("height"))?)
            } else {
                (0, 0)
            };
            let k = m33(rd.f64s::<9>(&what("K"))?);
            let r = m33(rd.f64s::<9>(&what("R"))?);
            let c = Vector3::from(rd.f64s::<3>(&what("C"))?);
            cameras.push(MvsCamera {
                width,
                height,
                k,
                r,
                c,
            });
        }
        let npose = rd.count(12 * 8, &what("poses"))?;
        let mut poses = Vec::with_capacity(npose);
        for q in 0..npose {
            let what = format!("platform {p} pose {q}");
            let r = m33(rd.f64s::<9>(&what)?);
            let c = Vector3::from(rd.f64s::<3>(&what)?);
            poses.push((r, c));
        }
        platforms.push(Platform { cameras, poses });
    }
    let nimg = rd.count(8 + 12, "the images")?;
    let mut rec = Reconstruction::default();
    for i in 0..nimg {
        let at = rd.at as u64;
        let what = |k: &str| format!("image {i}'s {k}");
        let stored = rd.string(&what("name"))?;
        if version > 4 {
            rd.string(&what("mask name"))?;
        }
        let (pid, cid, qid) = (
            rd.u32(&what("platform"))?,
            rd.u32(&what("camera"))?,
            rd.u32(&what("pose"))?,
        );
        if version > 2 {
            rd.u32(&what("id"))?;
        }
        if version > 6 {
            rd.take(12, &what("depth range"))?;
            let n = rd.count(24, &what("view scores"))?;
            rd.take(24 * n, &what("view scores"))?;
        }
        if qid == u32::MAX {
            continue; // not reconstructed
        }
        let name = super::file_name(&stored);
        let bad = |msg: String| {
            Error::parse(
                path,
                Location::Byte(at),
                format!("image {i} ({name}): {msg}"),
            )
        };
        let plat = platforms
            .get(pid as usize)
            .ok_or_else(|| bad(format!("platform {pid} does not exist ({nplat} platforms)")))?;
        let cam = plat.cameras.get(cid as usize).ok_or_else(|| {
            bad(format!(
                "camera {cid} of platform {pid} does not exist ({} cameras)",
                plat.cameras.len()
            ))
        })?;
        let (pr, pc) = plat.poses.get(qid as usize).ok_or_else(|| {
            bad(format!(
                "pose {qid} of platform {pid} does not exist ({} poses)",
                plat.poses.len()
            ))
        })?;
        let r = cam.r * pr;
        let c = pr.transpose() * cam.c + pc;
        let err = (r * r.transpose() - Matrix3::identity()).abs().max();
        if err > 1e-5 || r.determinant() < 0.0 {
            return Err(bad(format!(
                "its rotation is off by {err:.2e}: not a rotation"
            )));
        }
        let (w, h, scale) = if cam.width > 0 && cam.height > 0 {
            (cam.width, cam.height, 1.0)
        } else {
            let (w, h) = size_of(&name)?;
            (w, h, w.max(h) as f64)
        };
        let k = cam.k * scale;
        if k[(0, 1)].abs() > 1e-9 * k[(0, 0)].abs() {
            return Err(bad(format!(
                "its camera has skew {} (no camera model scantex reads has skew)",
                k[(0, 1)]
            )));
        }
        let id = rec.cameras.len() as u32 + 1;
        let camera = Camera::new(
            id,
            CameraModel::Pinhole,
            w,
            h,
            vec![k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)]],
        )
        .map_err(bad)?;
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
        rec.cameras.insert(id, camera);
        rec.images.insert(
            id,
            Image {
                id,
                camera_id: id,
                name,
                pose: Pose {
                    rotation,
                    translation: -(r * c),
                },
                points2d: Vec::new(),
            },
        );
    }
    Ok(rec)
}
