//! A scene: the mesh, the COLMAP model, the photographs and optional masks a user points at,
//! either as one directory (`mesh.*`, `sparse/` or `sparse/0/`, `images/`, `masks/`) or as
//! explicit paths. Photographs are only probed (header) here and decoded on demand, one at a
//! time, so a scene of 1,000 photos never holds them all in memory.

use crate::camera::colmap::{self, Reconstruction};
use crate::camera::PosedCamera;
use crate::camera::{bundler, meshroom, nvm, openmvs};
use crate::error::{Error, Result};
use crate::io::image::PhotoPixels;
use crate::io::{self, MeshFormat};
use crate::mesh::{LoadReport, Mesh};
use image::{GrayImage, Rgb32FImage};
use std::path::{Path, PathBuf};

/// What the user pointed at: a scene directory and/or explicit paths (explicit paths win).
#[derive(Debug, Clone, Default)]
pub struct SceneSpec {
    /// Scene directory holding a mesh file, `sparse/` (or `sparse/0/`), `images/`, `masks/`.
    pub dir: Option<PathBuf>,
    /// Mesh file (.obj, .ply, .gltf, .glb).
    pub mesh: Option<PathBuf>,
    /// COLMAP model directory (holding `cameras.bin|txt`), a folder with `sparse/`, or a
    /// Meshroom camera file (`cameras.sfm`).
    pub colmap: Option<PathBuf>,
    /// Directory of photographs, named as in the COLMAP model.
    pub images: Option<PathBuf>,
    /// Directory of object masks (white = object), named like the photos (optionally `.png`
    /// appended, as COLMAP does).
    pub masks: Option<PathBuf>,
    /// Leave out registered images whose photograph file is absent (held out, or deleted as
    /// bad) instead of failing on them. Default: false.
    pub skip_missing: bool,
    /// Leave out registered images whose photograph is unreadable, truncated, corrupt or of
    /// another size than its camera, with a warning, instead of failing on them. Default: false.
    pub skip_bad: bool,
}

/// The resolved locations of a scene's parts; `None` where the scene has no such part.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ScenePaths {
    /// Mesh file.
    pub mesh: Option<PathBuf>,
    /// COLMAP model directory.
    pub colmap: Option<PathBuf>,
    /// Photographs directory.
    pub images: Option<PathBuf>,
    /// Masks directory.
    pub masks: Option<PathBuf>,
}

impl SceneSpec {
    /// Finds each part: explicit paths first, then the conventional places in `dir`.
    pub fn resolve(&self) -> Result<ScenePaths> {
        if let Some(d) = &self.dir {
            if !d.is_dir() {
                return Err(Error::io(
                    d,
                    std::io::Error::new(std::io::ErrorKind::NotFound, "scene directory not found"),
                ));
            }
        }
        let mesh = match (&self.mesh, &self.dir) {
            (Some(m), _) => Some(m.clone()),
            (None, Some(d)) => find_mesh(d)?,
            (None, None) => None,
        };
        let colmap = match (&self.colmap, &self.dir) {
            // A Meshroom camera file stands where a COLMAP model would.
            (Some(c), _) if is_camera_file(c) => Some(c.clone()),
            (Some(c), _) => Some(if colmap::detect_format(c).is_some() {
                c.clone()
            } else {
                colmap::find_model_dir(c).ok_or_else(|| Error::Directory {
                    path: c.clone(),
                    msg: "no COLMAP model here (expected cameras.bin or cameras.txt, or \
                              sparse/0/)"
                        .into(),
                })?
            }),
            (None, Some(d)) => match colmap::find_model_dir(d)
                .or_else(|| Some(d.join("cameras.sfm")).filter(|p| meshroom::is_sfm_file(p)))
            {
                Some(m) => Some(m),
                None => find_camera_file(d)?,
            },
            (None, None) => None,
        };
        // Without a scene folder, a camera file's own folder may hold images/ (OpenMVS and
        // VisualSFM name the photographs relative to it).
        let camera_folder = colmap
            .as_deref()
            .filter(|c| is_camera_file(c))
            .and_then(Path::parent);
        let images = self.images.clone().or_else(|| {
            self.dir
                .as_deref()
                .or(camera_folder)
                .map(|d| d.join("images"))
                .filter(|p| p.is_dir())
        });
        let masks = self.masks.clone().or_else(|| {
            self.dir
                .as_ref()
                .map(|d| d.join("masks"))
                .filter(|p| p.is_dir())
        });
        for (what, p) in [("images", &images), ("masks", &masks)] {
            if let Some(p) = p {
                if !p.is_dir() {
                    return Err(Error::io(
                        p,
                        std::io::Error::new(
                            std::io::ErrorKind::NotFound,
                            format!("{what} directory not found"),
                        ),
                    ));
                }
            }
        }
        Ok(ScenePaths {
            mesh,
            colmap,
            images,
            masks,
        })
    }
}

/// Whether `path` is a camera file that stands where a COLMAP model directory would: a
/// Meshroom `cameras.sfm`, a Bundler `.out`, a VisualSFM `.nvm` or an OpenMVS `.mvs`.
pub fn is_camera_file(path: &Path) -> bool {
    meshroom::is_sfm_file(path)
        || bundler::is_bundle_file(path)
        || nvm::is_nvm_file(path)
        || openmvs::is_mvs_file(path)
}

/// What kind of camera model `path` is, as [`read_model`] reads it, for people.
pub fn camera_format(path: &Path) -> &'static str {
    if meshroom::is_sfm_file(path) {
        "Meshroom / AliceVision cameras.sfm"
    } else if bundler::is_bundle_file(path) {
        "Bundler file"
    } else if nvm::is_nvm_file(path) {
        "VisualSFM NVM file"
    } else if openmvs::is_mvs_file(path) {
        "OpenMVS interface archive"
    } else {
        "COLMAP model"
    }
}

/// The camera model at `path`: a COLMAP model directory or one of the camera files of
/// [`is_camera_file`] (Bundler and VisualSFM store no image size, and OpenMVS may not: it
/// comes from the photographs in `images`).
pub fn read_model(path: &Path, images: Option<&Path>) -> Result<Reconstruction> {
    if meshroom::is_sfm_file(path) {
        meshroom::read(path)
    } else if bundler::is_bundle_file(path) {
        bundler::read(path, images)
    } else if nvm::is_nvm_file(path) {
        nvm::read(path, images)
    } else if openmvs::is_mvs_file(path) {
        openmvs::read(path, images)
    } else {
        colmap::read(path)
    }
}

/// The single mesh file at the top of `dir`, if any; an error if there are several.
fn find_mesh(dir: &Path) -> Result<Option<PathBuf>> {
    find_one(dir, "mesh files", "--mesh", &|p| {
        p.is_file() && MeshFormat::from_path(p).is_some()
    })
}

/// The single VisualSFM `.nvm` or OpenMVS `.mvs` at the top of `dir`, if any (a scene folder
/// as those tools leave it); an error if there are several.
fn find_camera_file(dir: &Path) -> Result<Option<PathBuf>> {
    find_one(dir, "camera files", "--colmap", &|p| {
        nvm::is_nvm_file(p) || openmvs::is_mvs_file(p)
    })
}

/// The single file at the top of `dir` that `keep` accepts, if any; an error naming them and
/// `option` if there are several.
fn find_one(
    dir: &Path,
    what: &str,
    option: &str,
    keep: &dyn Fn(&Path) -> bool,
) -> Result<Option<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut found: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| keep(p))
        .collect();
    found.sort();
    match found.len() {
        0 => Ok(None),
        1 => Ok(found.pop()),
        _ => Err(Error::Directory {
            path: dir.to_path_buf(),
            msg: format!(
                "several {what} ({}); choose one with {option}",
                found
                    .iter()
                    .map(|p| p
                        .file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .into_owned())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }),
    }
}

/// One registered photograph: where its pixels are and how it was taken.
#[derive(Debug, Clone)]
pub struct Photo {
    /// COLMAP image id.
    pub image_id: u32,
    /// Name in the COLMAP model (relative path under the images directory).
    pub name: String,
    /// Full path of the photograph file.
    pub path: PathBuf,
    /// Full path of its mask, if the scene has one for it.
    pub mask: Option<PathBuf>,
    /// Full path of its unseen-surface mask (white = surface no input photograph saw), if
    /// the scene has one: `unseen/<stem>.png` beside the images directory, as `scantex
    /// sample --unseen-sector` writes for held-out views.
    pub unseen: Option<PathBuf>,
    /// Camera and pose.
    pub view: PosedCamera,
}

/// What probing a photograph's file found.
#[derive(Debug, Clone, PartialEq)]
pub enum PhotoStatus {
    /// Present, readable, and the size its camera says.
    Ok,
    /// No file at the path.
    Missing,
    /// The header could not be read.
    Unreadable(String),
    /// The file's size differs from its camera's.
    WrongSize {
        /// Size in the file.
        found: (u32, u32),
        /// Size the camera declares.
        expected: (u32, u32),
    },
}

impl Photo {
    /// Probes the file header (no pixel decoding).
    pub fn status(&self) -> PhotoStatus {
        if !self.path.is_file() {
            return PhotoStatus::Missing;
        }
        match io::image::check_complete(&self.path).and_then(|()| io::image::dimensions(&self.path))
        {
            Err(e) => PhotoStatus::Unreadable(e.to_string()),
            Ok(found) => {
                let expected = (self.view.camera.width, self.view.camera.height);
                if found == expected {
                    PhotoStatus::Ok
                } else {
                    PhotoStatus::WrongSize { found, expected }
                }
            }
        }
    }

    /// Probes the file and turns any problem into an error naming it.
    pub fn check(&self) -> Result<()> {
        match self.status() {
            s @ (PhotoStatus::Ok | PhotoStatus::Missing) => self.verdict(s, ""),
            s => self.verdict(s, " (--skip-bad-images leaves such photographs out)"),
        }
    }

    /// A probe's status as a result: an error naming the file for any problem, `hint`
    /// appended to a bad photograph's message.
    fn verdict(&self, status: PhotoStatus, hint: &str) -> Result<()> {
        match status {
            PhotoStatus::Ok => Ok(()),
            PhotoStatus::Missing => Err(Error::io(
                &self.path,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    format!(
                        "photograph of image {} not found (--skip-missing leaves such images out)",
                        self.image_id
                    ),
                ),
            )),
            PhotoStatus::Unreadable(msg) => Err(Error::Photo {
                image_id: self.image_id,
                msg: format!("{msg}{hint}"),
            }),
            PhotoStatus::WrongSize { found, expected } => Err(Error::at_element(
                &self.path,
                format!("image {}", self.image_id),
                format!(
                    "photograph is {}x{} but camera {} is {}x{}{hint}",
                    found.0, found.1, self.view.camera.id, expected.0, expected.1
                ),
            )),
        }
    }

    /// Decodes the photograph as RGB floats in [0, 1], checking its size against the camera.
    pub fn load(&self) -> Result<Rgb32FImage> {
        Ok(self.load_pixels(Vec::new())?.into_rgb32f())
    }

    /// Decodes the photograph as stored (8-bit files stay 8-bit, in `spare`'s memory: a
    /// previous photograph's buffer), checking its size against the camera.
    pub fn load_pixels(&self, spare: Vec<u8>) -> Result<PhotoPixels> {
        Ok(self.load_pixels_and_alpha(spare)?.0)
    }

    /// [`Photo::load_pixels`], and the photograph's alpha channel when it hides some pixels
    /// ([`io::image::read_photo_and_alpha`]).
    fn load_pixels_and_alpha(&self, spare: Vec<u8>) -> Result<(PhotoPixels, Option<GrayImage>)> {
        let (img, alpha) = io::image::read_photo_and_alpha(&self.path, spare)?;
        let expected = (self.view.camera.width, self.view.camera.height);
        if img.dimensions() != expected {
            return Err(Error::at_element(
                &self.path,
                format!("image {}", self.image_id),
                format!(
                    "photograph is {}x{} but its camera is {}x{}",
                    img.width(),
                    img.height(),
                    expected.0,
                    expected.1
                ),
            ));
        }
        Ok((img, alpha))
    }

    /// Decodes the mask (white = object) if there is one, checking its size.
    pub fn load_mask(&self) -> Result<Option<GrayImage>> {
        self.load_gray(self.mask.as_deref(), "mask")
    }

    /// The photograph ([`Photo::load_pixels`]) and its object mask: the mask file's, the
    /// alpha channel's where it hides some pixels, or where both exist the pixels both keep
    /// (masks read 128 and above as object, so the smaller value of the two).
    pub fn load_with_mask(&self, spare: Vec<u8>) -> Result<(PhotoPixels, Option<GrayImage>)> {
        let (rgb, alpha) = self.load_pixels_and_alpha(spare)?;
        let mask = match (self.load_mask()?, alpha) {
            (Some(mut m), Some(a)) => {
                for (v, &b) in m.iter_mut().zip(a.iter()) {
                    *v = (*v).min(b);
                }
                Some(m)
            }
            (m, a) => m.or(a),
        };
        Ok((rgb, mask))
    }

    /// Decodes the unseen-surface mask if there is one, checking its size.
    pub fn load_unseen(&self) -> Result<Option<GrayImage>> {
        self.load_gray(self.unseen.as_deref(), "unseen mask")
    }

    fn load_gray(&self, p: Option<&Path>, what: &str) -> Result<Option<GrayImage>> {
        let Some(p) = p else { return Ok(None) };
        let m = io::image::read(p)?.into_luma8();
        let expected = (self.view.camera.width, self.view.camera.height);
        if m.dimensions() != expected {
            return Err(Error::at_element(
                p,
                format!("{what} of image {}", self.image_id),
                format!(
                    "{what} is {}x{} but its camera is {}x{}",
                    m.width(),
                    m.height(),
                    expected.0,
                    expected.1
                ),
            ));
        }
        Ok(Some(m))
    }
}

/// A loaded scene. Only what the spec pointed at is present.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Where each part came from.
    pub paths: ScenePaths,
    /// The mesh with what loading dropped, if the scene has one.
    pub mesh: Option<(Mesh, LoadReport)>,
    /// The COLMAP model, if the scene has one.
    pub reconstruction: Option<Reconstruction>,
    /// Registered photographs, in image-id order (empty without a COLMAP model).
    pub photos: Vec<Photo>,
    /// Names of registered images left out because their file is absent
    /// ([`SceneSpec::skip_missing`]).
    pub skipped: Vec<String>,
    /// Registered images left out because their photograph is bad ([`SceneSpec::skip_bad`]).
    pub bad: Vec<BadPhoto>,
}

/// A photograph left out by [`SceneSpec::skip_bad`], and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BadPhoto {
    /// Name in the COLMAP model.
    pub name: String,
    /// What is wrong with it, naming the file.
    pub reason: String,
}

impl Scene {
    /// Loads the mesh and the COLMAP model and lists the photographs (not decoded).
    pub fn load(spec: &SceneSpec) -> Result<Scene> {
        let paths = spec.resolve()?;
        if paths.mesh.is_none() && paths.colmap.is_none() {
            return Err(Error::Invalid(
                "nothing to load: give a scene directory, or --mesh and/or --colmap".into(),
            ));
        }
        let mesh = paths.mesh.as_deref().map(io::read_mesh).transpose()?;
        let reconstruction = paths
            .colmap
            .as_deref()
            .map(|p| read_model(p, paths.images.as_deref()))
            .transpose()?;
        let mut photos = match &reconstruction {
            Some(rec) => photos_of(rec, &paths),
            None => Vec::new(),
        };
        let mut skipped = Vec::new();
        let mut bad = Vec::new();
        if spec.skip_missing || spec.skip_bad {
            use rayon::prelude::*;
            let statuses: Vec<PhotoStatus> = photos.par_iter().map(Photo::status).collect();
            let mut keep = Vec::with_capacity(photos.len());
            for (p, status) in photos.into_iter().zip(statuses) {
                match status {
                    PhotoStatus::Missing if spec.skip_missing => skipped.push(p.name.clone()),
                    // Left for check_photos to report.
                    PhotoStatus::Ok | PhotoStatus::Missing => keep.push(p),
                    bad_status if spec.skip_bad => {
                        let reason = p.verdict(bad_status, "").err().map(|e| e.to_string());
                        bad.push(BadPhoto {
                            name: p.name.clone(),
                            reason: reason.unwrap_or_default(),
                        });
                    }
                    _ => keep.push(p),
                }
            }
            photos = keep;
        }
        Ok(Scene {
            paths,
            mesh,
            reconstruction,
            photos,
            skipped,
            bad,
        })
    }

    /// Checks every photograph's file (header only); the first problem is the error.
    pub fn check_photos(&self) -> Result<()> {
        self.photos.iter().try_for_each(Photo::check)
    }
}

fn photos_of(rec: &Reconstruction, paths: &ScenePaths) -> Vec<Photo> {
    let images_dir = paths
        .images
        .clone()
        .unwrap_or_else(|| PathBuf::from("images"));
    rec.images
        .values()
        .map(|img| {
            let mask = paths.masks.as_ref().and_then(|m| {
                let stem = Path::new(&img.name).with_extension("png");
                [
                    m.join(&img.name),
                    m.join(format!("{}.png", img.name)),
                    m.join(stem),
                ]
                .into_iter()
                .find(|p| p.is_file())
            });
            let unseen = images_dir.parent().and_then(|d| {
                let p = d
                    .join("unseen")
                    .join(Path::new(&img.name).with_extension("png"));
                p.is_file().then_some(p)
            });
            Photo {
                image_id: img.id,
                name: img.name.clone(),
                path: images_dir.join(&img.name),
                mask,
                unseen,
                view: PosedCamera {
                    camera: rec.cameras[&img.camera_id].clone(),
                    pose: img.pose,
                },
            }
        })
        .collect()
}
