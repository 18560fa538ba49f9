//! COLMAP sparse models (`cameras`, `images`, `points3D`) in text and binary, read and written.
//! One file for one format: the text and binary readers and writers of the three files share
//! their records and checks, which is what makes it longer than 800 lines.
//!
//! Formats as COLMAP writes them (`src/colmap/scene/reconstruction_io.cc`): little-endian binary
//! with `u64` counts, NUL-terminated image names and `u64::MAX` for "no 3D point"; text with
//! `#` comments, two lines per image, `-1` for "no 3D point". Every error names the file and the
//! line (text) or byte offset (binary) at fault. Counts in binary headers are never trusted for
//! allocation, so a corrupt count cannot exhaust memory.

use super::{Camera, CameraModel, Pose};
use crate::error::{Error, Location, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// One image of a sparse model: its pose, camera and 2D observations.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// COLMAP's image id.
    pub id: u32,
    /// Id of the camera in [`Reconstruction::cameras`].
    pub camera_id: u32,
    /// File name relative to the images directory.
    pub name: String,
    /// World -> camera transform.
    pub pose: Pose,
    /// 2D keypoints with the 3D point each observes, if any.
    pub points2d: Vec<Point2D>,
}

/// A keypoint of an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point2D {
    /// Pixel position (COLMAP convention: pixel centres at +0.5).
    pub xy: [f64; 2],
    /// The 3D point this keypoint observes.
    pub point3d_id: Option<u64>,
}

/// A triangulated 3D point with its track.
#[derive(Debug, Clone, PartialEq)]
pub struct Point3D {
    /// World position.
    pub xyz: [f64; 3],
    /// Colour (8-bit sRGB).
    pub rgb: [u8; 3],
    /// COLMAP's stored mean reprojection error in pixels.
    pub error: f64,
    /// Observations as (image id, index into that image's `points2d`).
    pub track: Vec<(u32, u32)>,
}

/// A COLMAP sparse model. Maps are ordered by id so iteration is deterministic.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Reconstruction {
    /// Cameras by id.
    pub cameras: BTreeMap<u32, Camera>,
    /// Registered images by id.
    pub images: BTreeMap<u32, Image>,
    /// 3D points by id.
    pub points3d: BTreeMap<u64, Point3D>,
}

/// Which of COLMAP's two encodings a model directory holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `cameras.txt`, `images.txt`, `points3D.txt`.
    Text,
    /// `cameras.bin`, `images.bin`, `points3D.bin`.
    Binary,
}

impl Format {
    fn ext(self) -> &'static str {
        match self {
            Format::Text => "txt",
            Format::Binary => "bin",
        }
    }
}

/// The format of the model in `dir`: binary when `cameras.bin` exists (COLMAP's default output),
/// else text when `cameras.txt` does.
pub fn detect_format(dir: &Path) -> Option<Format> {
    if dir.join("cameras.bin").is_file() {
        Some(Format::Binary)
    } else if dir.join("cameras.txt").is_file() {
        Some(Format::Text)
    } else {
        None
    }
}

/// Reads the model in `dir`, in whichever format it holds (binary preferred).
pub fn read(dir: &Path) -> Result<Reconstruction> {
    match detect_format(dir) {
        Some(f) => read_format(dir, f),
        None => Err(Error::Directory {
            path: dir.to_path_buf(),
            msg: "no COLMAP model (cameras.bin or cameras.txt) found".into(),
        }),
    }
}

/// Reads the model in `dir` in the given format. `points3D` is optional (COLMAP's
/// undistorter sometimes omits it); cameras and images are required.
pub fn read_format(dir: &Path, format: Format) -> Result<Reconstruction> {
    let file = |stem: &str| dir.join(format!("{stem}.{}", format.ext()));
    let (cams, imgs, pts) = (file("cameras"), file("images"), file("points3D"));
    let mut rec = Reconstruction::default();
    match format {
        Format::Text => {
            rec.cameras = read_cameras_text(&cams)?;
            rec.images = read_images_text(&imgs)?;
            if pts.is_file() {
                rec.points3d = read_points_text(&pts)?;
            }
        }
        Format::Binary => {
            rec.cameras = read_cameras_binary(&cams)?;
            rec.images = read_images_binary(&imgs)?;
            if pts.is_file() {
                rec.points3d = read_points_binary(&pts)?;
            }
        }
    }
    rec.check_references(&imgs, &pts)?;
    Ok(rec)
}

/// Parses a text model from the three files' contents, with every check [`read`] makes;
/// `dir` is only used to name the files in errors.
pub fn parse_text(dir: &Path, cameras: &str, images: &str, points: &str) -> Result<Reconstruction> {
    let (imgs, pts) = (dir.join("images.txt"), dir.join("points3D.txt"));
    let rec = Reconstruction {
        cameras: parse_cameras_text(&dir.join("cameras.txt"), cameras)?,
        images: parse_images_text(&imgs, images)?,
        points3d: parse_points_text(&pts, points)?,
    };
    rec.check_references(&imgs, &pts)?;
    Ok(rec)
}

/// "images.bin and points3D.bin", for messages about the two files disagreeing.
fn both(images: &Path, points: &Path) -> String {
    let name = |p: &Path| {
        p.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    format!("{} and {}", name(images), name(points))
}

impl Reconstruction {
    /// Checks that every image names an existing camera and every track element an existing
    /// image and keypoint.
    fn check_references(&self, images_path: &Path, points_path: &Path) -> Result<()> {
        for img in self.images.values() {
            if !self.cameras.contains_key(&img.camera_id) {
                return Err(Error::at_element(
                    images_path,
                    format!("image {} ({})", img.id, img.name),
                    format!("references camera {}, which does not exist", img.camera_id),
                ));
            }
        }
        for (pid, p) in &self.points3d {
            if p.track.is_empty() {
                return Err(Error::at_element(
                    points_path,
                    format!("point3D {pid}"),
                    "track is empty: truncated or corrupt file",
                ));
            }
            for &(iid, idx) in &p.track {
                let back = self
                    .images
                    .get(&iid)
                    .and_then(|i| i.points2d.get(idx as usize))
                    .map(|k| k.point3d_id);
                match back {
                    None => {
                        return Err(Error::at_element(
                            points_path,
                            format!("point3D {pid}"),
                            format!(
                                "track references image {iid} keypoint {idx}, which does not exist"
                            ),
                        ))
                    }
                    Some(Some(b)) if b == *pid => {}
                    Some(other) => {
                        return Err(Error::at_element(
                            points_path,
                            format!("point3D {pid}"),
                            format!(
                                "track holds image {iid} keypoint {idx}, but that keypoint \
                                 observes {}: {} disagree (truncated or corrupt)",
                                other.map_or("no point".to_string(), |b| format!("point3D {b}")),
                                both(images_path, points_path)
                            ),
                        ))
                    }
                }
            }
        }
        // The other way: what images say they observe must exist and list them back. The
        // undistorter may omit points3D; then there is nothing to check against.
        if self.points3d.is_empty() {
            return Ok(());
        }
        for img in self.images.values() {
            let cam = &self.cameras[&img.camera_id];
            let (w, h) = (cam.width as f64, cam.height as f64);
            // Real keypoints stray a little outside the image (undistorted or rescaled
            // models: 816 px in an 800 px wide image of statue_of_liberty); corrupt bytes in a
            // double land orders of magnitude away. The slack is one image size.
            let slack = w.max(h);
            for (k, p2) in img.points2d.iter().enumerate() {
                let [x, y] = p2.xy;
                if !(-slack..=w + slack).contains(&x) || !(-slack..=h + slack).contains(&y) {
                    return Err(Error::at_element(
                        images_path,
                        format!("image {} ({}) keypoint {k}", img.id, img.name),
                        format!(
                            "position ({x}, {y}) lies far outside the {}x{} image of camera {}: \
                             corrupt file",
                            cam.width, cam.height, cam.id
                        ),
                    ));
                }
                let Some(pid) = p2.point3d_id else { continue };
                let listed = self
                    .points3d
                    .get(&pid)
                    .is_some_and(|p| p.track.contains(&(img.id, k as u32)));
                if !listed {
                    return Err(Error::at_element(
                        images_path,
                        format!("image {} ({}) keypoint {k}", img.id, img.name),
                        format!(
                            "observes point3D {pid}, which {}: {} disagree (truncated or \
                             corrupt)",
                            if self.points3d.contains_key(&pid) {
                                "does not list it in its track"
                            } else {
                                "does not exist"
                            },
                            both(images_path, points_path)
                        ),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Reprojection error in pixels of every track observation, grouped per 3D point:
    /// `(point id, errors)`. Points behind a camera count as infinite error.
    pub fn track_errors(&self) -> Vec<(u64, Vec<f64>)> {
        self.points3d
            .iter()
            .map(|(&pid, p)| {
                let world = nalgebra::Point3::from(p.xyz);
                let errs = p
                    .track
                    .iter()
                    .map(|&(iid, idx)| {
                        let img = &self.images[&iid];
                        let cam = &self.cameras[&img.camera_id];
                        let obs = img.points2d[idx as usize].xy;
                        match cam.project(&img.pose.transform(&world)) {
                            Some(px) => ((px.x - obs[0]).powi(2) + (px.y - obs[1]).powi(2)).sqrt(),
                            None => f64::INFINITY,
                        }
                    })
                    .collect();
                (pid, errs)
            })
            .collect()
    }
}

/// How far a stored quaternion's norm may be from 1: COLMAP writes unit quaternions to full
/// precision, and six printed decimals stay within 1e-5. Anything farther is not a rotation
/// but a corrupt or hand-broken file, which would otherwise be normalised into a wrong pose.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

fn check_quaternion(q: [f64; 4], image: u32) -> std::result::Result<(), String> {
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!(
            "image {image}: quaternion {q:?} has norm {norm:.6}, not 1: not a rotation \
             (corrupt or wrongly written pose)"
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Text

fn read_text(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|e| Error::io(path, e))
}

/// Trimmed lines with their 1-based numbers.
fn text_lines(text: &str) -> Vec<(usize, String)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim().to_string()))
        .collect()
}

fn is_data(line: &str) -> bool {
    !line.is_empty() && !line.starts_with('#')
}

fn parse_num<T: std::str::FromStr>(path: &Path, line: usize, tok: &str, what: &str) -> Result<T> {
    tok.parse()
        .map_err(|_| Error::at_line(path, line, format!("{what}: '{tok}' is not a valid number")))
}

fn parse_finite(path: &Path, line: usize, tok: &str, what: &str) -> Result<f64> {
    let v: f64 = parse_num(path, line, tok, what)?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Error::at_line(path, line, format!("{what} is not finite")))
    }
}

fn need<'a>(path: &Path, line: usize, toks: &'a [&'a str], n: usize, what: &str) -> Result<()> {
    if toks.len() < n {
        return Err(Error::at_line(
            path,
            line,
            format!("{what}: expected at least {n} fields, found {}", toks.len()),
        ));
    }
    Ok(())
}

fn read_cameras_text(path: &Path) -> Result<BTreeMap<u32, Camera>> {
    parse_cameras_text(path, &read_text(path)?)
}

/// Parses the text of a `cameras.txt`; `path` is only used in errors.
pub fn parse_cameras_text(path: &Path, text: &str) -> Result<BTreeMap<u32, Camera>> {
    let mut out = BTreeMap::new();
    for (ln, line) in text_lines(text) {
        if !is_data(&line) {
            continue;
        }
        let t: Vec<&str> = line.split_whitespace().collect();
        need(path, ln, &t, 4, "camera")?;
        let id: u32 = parse_num(path, ln, t[0], "CAMERA_ID")?;
        let model = CameraModel::from_name(t[1])
            .ok_or_else(|| Error::at_line(path, ln, format!("unknown camera model '{}'", t[1])))?;
        let width: u32 = parse_num(path, ln, t[2], "WIDTH")?;
        let height: u32 = parse_num(path, ln, t[3], "HEIGHT")?;
        let params = t[4..]
            .iter()
            .map(|s| parse_num::<f64>(path, ln, s, "PARAMS"))
            .collect::<Result<Vec<_>>>()?;
        let cam = Camera::new(id, model, width, height, params)
            .map_err(|m| Error::at_line(path, ln, m))?;
        if out.insert(id, cam).is_some() {
            return Err(Error::at_line(
                path,
                ln,
                format!("camera {id} defined twice"),
            ));
        }
    }
    Ok(out)
}

fn read_images_text(path: &Path) -> Result<BTreeMap<u32, Image>> {
    parse_images_text(path, &read_text(path)?)
}

/// Parses the text of a `images.txt`; `path` is only used in errors.
pub fn parse_images_text(path: &Path, text: &str) -> Result<BTreeMap<u32, Image>> {
    let lines = text_lines(text);
    let mut out = BTreeMap::new();
    let mut i = 0;
    while i < lines.len() {
        let (ln, line) = &lines[i];
        i += 1;
        if !is_data(line) {
            continue;
        }
        let ln = *ln;
        let t: Vec<&str> = line.split_whitespace().collect();
        need(path, ln, &t, 10, "image")?;
        let id: u32 = parse_num(path, ln, t[0], "IMAGE_ID")?;
        let mut q = [0.0; 4];
        for (k, v) in q.iter_mut().enumerate() {
            *v = parse_finite(path, ln, t[1 + k], "quaternion")?;
        }
        check_quaternion(q, id).map_err(|m| Error::at_line(path, ln, m))?;
        let mut tr = [0.0; 3];
        for (k, v) in tr.iter_mut().enumerate() {
            *v = parse_finite(path, ln, t[5 + k], "translation")?;
        }
        let camera_id: u32 = parse_num(path, ln, t[8], "CAMERA_ID")?;
        // Names may contain spaces: everything after CAMERA_ID.
        let name = line
            .splitn(10, char::is_whitespace)
            .nth(9)
            .unwrap_or("")
            .trim()
            .to_string();
        // As COLMAP: the observation line follows unconditionally (it may be empty).
        let mut points2d = Vec::new();
        if i < lines.len() {
            let (pln, pline) = &lines[i];
            i += 1;
            let p: Vec<&str> = pline.split_whitespace().collect();
            if !p.len().is_multiple_of(3) {
                return Err(Error::at_line(
                    path,
                    *pln,
                    format!(
                        "POINTS2D of image {id}: {} fields is not a multiple of 3",
                        p.len()
                    ),
                ));
            }
            for c in p.chunks(3) {
                let x = parse_finite(path, *pln, c[0], "POINTS2D x")?;
                let y = parse_finite(path, *pln, c[1], "POINTS2D y")?;
                let pid: i64 = parse_num(path, *pln, c[2], "POINT3D_ID")?;
                points2d.push(Point2D {
                    xy: [x, y],
                    point3d_id: (pid >= 0).then_some(pid as u64),
                });
            }
        }
        let img = Image {
            id,
            camera_id,
            name,
            pose: Pose::from_colmap(q, tr),
            points2d,
        };
        if out.insert(id, img).is_some() {
            return Err(Error::at_line(
                path,
                ln,
                format!("image {id} defined twice"),
            ));
        }
    }
    Ok(out)
}

fn read_points_text(path: &Path) -> Result<BTreeMap<u64, Point3D>> {
    parse_points_text(path, &read_text(path)?)
}

/// Parses the text of a `points3D.txt`; `path` is only used in errors.
pub fn parse_points_text(path: &Path, text: &str) -> Result<BTreeMap<u64, Point3D>> {
    let mut out = BTreeMap::new();
    for (ln, line) in text_lines(text) {
        if !is_data(&line) {
            continue;
        }
        let t: Vec<&str> = line.split_whitespace().collect();
        need(path, ln, &t, 8, "point3D")?;
        let id: u64 = parse_num(path, ln, t[0], "POINT3D_ID")?;
        let mut xyz = [0.0; 3];
        for (k, v) in xyz.iter_mut().enumerate() {
            *v = parse_finite(path, ln, t[1 + k], "XYZ")?;
        }
        let mut rgb = [0u8; 3];
        for (k, v) in rgb.iter_mut().enumerate() {
            *v = parse_num(path, ln, t[4 + k], "RGB")?;
        }
        let error = parse_finite(path, ln, t[7], "ERROR")?;
        let rest = &t[8..];
        if !rest.len().is_multiple_of(2) {
            return Err(Error::at_line(
                path,
                ln,
                "TRACK must hold (IMAGE_ID, POINT2D_IDX) pairs",
            ));
        }
        let track = rest
            .chunks(2)
            .map(|c| {
                Ok((
                    parse_num(path, ln, c[0], "IMAGE_ID")?,
                    parse_num(path, ln, c[1], "POINT2D_IDX")?,
                ))
            })
            .collect::<Result<Vec<_>>>()?;
        let p = Point3D {
            xyz,
            rgb,
            error,
            track,
        };
        if out.insert(id, p).is_some() {
            return Err(Error::at_line(
                path,
                ln,
                format!("point3D {id} defined twice"),
            ));
        }
    }
    Ok(out)
}

/// Writes the model as COLMAP text into `dir` (created if needed). Numbers are written with
/// Rust's shortest round-trip formatting, so reading the files back is lossless. Each file is
/// written to a temporary name and renamed.
pub fn write_text(rec: &Reconstruction, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut s = String::new();
    s.push_str("# Camera list with one line of data per camera:\n");
    s.push_str("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    let _ = writeln!(s, "# Number of cameras: {}", rec.cameras.len());
    for c in rec.cameras.values() {
        let _ = write!(s, "{} {} {} {}", c.id, c.model.name(), c.width, c.height);
        for p in &c.params {
            let _ = write!(s, " {p}");
        }
        s.push('\n');
    }
    crate::io::write_atomic(&dir.join("cameras.txt"), s.as_bytes())?;

    let mut s = String::new();
    s.push_str("# Image list with two lines of data per image:\n");
    s.push_str("#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n");
    s.push_str("#   POINTS2D[] as (X, Y, POINT3D_ID)\n");
    let _ = writeln!(s, "# Number of images: {}", rec.images.len());
    for im in rec.images.values() {
        let [qw, qx, qy, qz] = im.pose.quaternion_wxyz();
        let t = im.pose.translation;
        let _ = writeln!(
            s,
            "{} {qw} {qx} {qy} {qz} {} {} {} {} {}",
            im.id, t.x, t.y, t.z, im.camera_id, im.name
        );
        let obs: Vec<String> = im
            .points2d
            .iter()
            .map(|p| {
                let pid = p.point3d_id.map_or(-1i128, |v| v as i128);
                format!("{} {} {pid}", p.xy[0], p.xy[1])
            })
            .collect();
        s.push_str(&obs.join(" "));
        s.push('\n');
    }
    crate::io::write_atomic(&dir.join("images.txt"), s.as_bytes())?;

    let mut s = String::new();
    s.push_str("# 3D point list with one line of data per point:\n");
    s.push_str("#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n");
    let _ = writeln!(s, "# Number of points: {}", rec.points3d.len());
    for (id, p) in &rec.points3d {
        let _ = write!(
            s,
            "{id} {} {} {} {} {} {} {}",
            p.xyz[0], p.xyz[1], p.xyz[2], p.rgb[0], p.rgb[1], p.rgb[2], p.error
        );
        for (i, k) in &p.track {
            let _ = write!(s, " {i} {k}");
        }
        s.push('\n');
    }
    crate::io::write_atomic(&dir.join("points3D.txt"), s.as_bytes())
}

// ---------------------------------------------------------------------------------------------
// Binary

/// A bounds-checked little-endian reader that reports the byte offset of any failure.
struct Cursor<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if self.data.len() - self.pos < n {
            return Err(Error::parse(
                self.path,
                Location::Byte(self.pos as u64),
                format!(
                    "file ends while reading {what} ({n} bytes needed, {} left): truncated or corrupt",
                    self.data.len() - self.pos
                ),
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn finite(&mut self, what: &str) -> Result<f64> {
        let at = self.pos;
        let v = self.f64(what)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.err_at(at, format!("{what} is not finite")))
        }
    }
    /// A count of records each at least `min_size` bytes long, refused if the rest of the file
    /// cannot hold that many (so a corrupt count fails fast instead of allocating).
    fn count(&mut self, min_size: usize, what: &str) -> Result<usize> {
        let at = self.pos;
        let n = self.u64(what)?;
        let left = (self.data.len() - self.pos) as u64;
        if n.checked_mul(min_size as u64).is_none_or(|b| b > left) {
            return Err(self.err_at(
                at,
                format!(
                    "{what} = {n} does not fit in the {left} bytes left: truncated or corrupt file"
                ),
            ));
        }
        Ok(n as usize)
    }
    fn err_at(&self, at: usize, msg: String) -> Error {
        Error::parse(self.path, Location::Byte(at as u64), msg)
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

fn read_cameras_binary(path: &Path) -> Result<BTreeMap<u32, Camera>> {
    let data = read_bytes(path)?;
    parse_cameras_binary(path, &data)
}

/// Parses the bytes of a `cameras.bin`; `path` is only used in errors.
pub fn parse_cameras_binary(path: &Path, data: &[u8]) -> Result<BTreeMap<u32, Camera>> {
    let mut c = Cursor { path, data, pos: 0 };
    let n = c.count(24, "number of cameras")?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let at = c.pos;
        let id = c.u32("CAMERA_ID")?;
        let model_id = c.i32("MODEL_ID")?;
        let model = CameraModel::from_id(model_id).ok_or_else(|| {
            c.err_at(
                at + 4,
                format!("camera {id}: unknown camera model id {model_id}"),
            )
        })?;
        let width = c.u64("WIDTH")?;
        let height = c.u64("HEIGHT")?;
        let (width, height) = match (u32::try_from(width), u32::try_from(height)) {
            (Ok(w), Ok(h)) => (w, h),
            _ => {
                return Err(c.err_at(
                    at,
                    format!("camera {id}: image size {width}x{height} is out of range"),
                ))
            }
        };
        let params = (0..model.num_params())
            .map(|_| c.f64("PARAMS"))
            .collect::<Result<Vec<_>>>()?;
        let cam = Camera::new(id, model, width, height, params).map_err(|m| c.err_at(at, m))?;
        if out.insert(id, cam).is_some() {
            return Err(c.err_at(at, format!("camera {id} defined twice")));
        }
    }
    if c.pos != data.len() {
        return Err(c.err_at(
            c.pos,
            format!(
                "{} unexpected bytes after the last camera",
                data.len() - c.pos
            ),
        ));
    }
    Ok(out)
}

fn read_images_binary(path: &Path) -> Result<BTreeMap<u32, Image>> {
    let data = read_bytes(path)?;
    parse_images_binary(path, &data)
}

/// Parses the bytes of an `images.bin`; `path` is only used in errors.
pub fn parse_images_binary(path: &Path, data: &[u8]) -> Result<BTreeMap<u32, Image>> {
    let mut c = Cursor { path, data, pos: 0 };
    let n = c.count(4 + 56 + 4 + 1 + 8, "number of images")?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let at = c.pos;
        let id = c.u32("IMAGE_ID")?;
        let mut q = [0.0; 4];
        let q_at = c.pos;
        for v in &mut q {
            *v = c.finite("quaternion")?;
        }
        check_quaternion(q, id).map_err(|m| c.err_at(q_at, m))?;
        let mut t = [0.0; 3];
        for v in &mut t {
            *v = c.finite("translation")?;
        }
        let camera_id = c.u32("CAMERA_ID")?;
        let name_at = c.pos;
        let end = data[c.pos..]
            .iter()
            .position(|&b| b == 0)
            .ok_or_else(|| c.err_at(name_at, format!("image {id}: name is not NUL-terminated")))?;
        let name = std::str::from_utf8(&data[c.pos..c.pos + end])
            .map_err(|_| c.err_at(name_at, format!("image {id}: name is not UTF-8")))?
            .to_string();
        c.pos += end + 1;
        let np = c.count(24, "number of 2D points")?;
        let mut points2d = Vec::with_capacity(np);
        for _ in 0..np {
            let x = c.finite("POINTS2D x")?;
            let y = c.finite("POINTS2D y")?;
            let pid = c.u64("POINT3D_ID")?;
            points2d.push(Point2D {
                xy: [x, y],
                point3d_id: (pid != u64::MAX).then_some(pid),
            });
        }
        let img = Image {
            id,
            camera_id,
            name,
            pose: Pose::from_colmap(q, t),
            points2d,
        };
        if out.insert(id, img).is_some() {
            return Err(c.err_at(at, format!("image {id} defined twice")));
        }
    }
    if c.pos != data.len() {
        return Err(c.err_at(
            c.pos,
            format!(
                "{} unexpected bytes after the last image",
                data.len() - c.pos
            ),
        ));
    }
    Ok(out)
}

fn read_points_binary(path: &Path) -> Result<BTreeMap<u64, Point3D>> {
    let data = read_bytes(path)?;
    parse_points_binary(path, &data)
}

/// Parses the bytes of a `points3D.bin`; `path` is only used in errors.
pub fn parse_points_binary(path: &Path, data: &[u8]) -> Result<BTreeMap<u64, Point3D>> {
    let mut c = Cursor { path, data, pos: 0 };
    let n = c.count(8 + 24 + 3 + 8 + 8, "number of points")?;
    let mut out = BTreeMap::new();
    for _ in 0..n {
        let at = c.pos;
        let id = c.u64("POINT3D_ID")?;
        let mut xyz = [0.0; 3];
        for v in &mut xyz {
            *v = c.finite("XYZ")?;
        }
        let rgb = [c.u8("R")?, c.u8("G")?, c.u8("B")?];
        let error = c.finite("ERROR")?;
        let nt = c.count(8, "track length")?;
        let mut track = Vec::with_capacity(nt);
        for _ in 0..nt {
            track.push((c.u32("IMAGE_ID")?, c.u32("POINT2D_IDX")?));
        }
        let p = Point3D {
            xyz,
            rgb,
            error,
            track,
        };
        if out.insert(id, p).is_some() {
            return Err(c.err_at(at, format!("point3D {id} defined twice")));
        }
    }
    if c.pos != data.len() {
        return Err(c.err_at(
            c.pos,
            format!(
                "{} unexpected bytes after the last point",
                data.len() - c.pos
            ),
        ));
    }
    Ok(out)
}

/// Writes the model as COLMAP binary into `dir` (created if needed), atomically per file.
pub fn write_binary(rec: &Reconstruction, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut b = Vec::new();
    b.extend((rec.cameras.len() as u64).to_le_bytes());
    for c in rec.cameras.values() {
        b.extend(c.id.to_le_bytes());
        b.extend(c.model.id().to_le_bytes());
        b.extend((c.width as u64).to_le_bytes());
        b.extend((c.height as u64).to_le_bytes());
        for p in &c.params {
            b.extend(p.to_le_bytes());
        }
    }
    crate::io::write_atomic(&dir.join("cameras.bin"), &b)?;

    let mut b = Vec::new();
    b.extend((rec.images.len() as u64).to_le_bytes());
    for im in rec.images.values() {
        b.extend(im.id.to_le_bytes());
        for v in im.pose.quaternion_wxyz() {
            b.extend(v.to_le_bytes());
        }
        for v in im.pose.translation.iter() {
            b.extend(v.to_le_bytes());
        }
        b.extend(im.camera_id.to_le_bytes());
        b.extend(im.name.as_bytes());
        b.push(0);
        b.extend((im.points2d.len() as u64).to_le_bytes());
        for p in &im.points2d {
            b.extend(p.xy[0].to_le_bytes());
            b.extend(p.xy[1].to_le_bytes());
            b.extend(p.point3d_id.unwrap_or(u64::MAX).to_le_bytes());
        }
    }
    crate::io::write_atomic(&dir.join("images.bin"), &b)?;

    let mut b = Vec::new();
    b.extend((rec.points3d.len() as u64).to_le_bytes());
    for (id, p) in &rec.points3d {
        b.extend(id.to_le_bytes());
        for v in p.xyz {
            b.extend(v.to_le_bytes());
        }
        b.extend(p.rgb);
        b.extend(p.error.to_le_bytes());
        b.extend((p.track.len() as u64).to_le_bytes());
        for (i, k) in &p.track {
            b.extend(i.to_le_bytes());
            b.extend(k.to_le_bytes());
        }
    }
    crate::io::write_atomic(&dir.join("points3D.bin"), &b)
}

/// The sparse-model directory under a scene root: `sparse/0/` if it holds a model, else
/// `sparse/`.
pub fn find_model_dir(root: &Path) -> Option<PathBuf> {
    [root.join("sparse").join("0"), root.join("sparse")]
        .into_iter()
        .find(|d| detect_format(d).is_some())
}
