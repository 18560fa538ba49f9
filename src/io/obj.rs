//! Wavefront OBJ (+ MTL). Our own parser rather than `tobj`: tobj renumbers vertices in
//! first-use order (so a write -> read round trip would not keep vertex order, and per-vertex
//! data from elsewhere would no longer line up) and reports errors without line numbers.
//! Supported: `v` (with optional RGB colour), `vt`, `vn`, `f` with any corner count and
//! negative (relative) indices, `mtllib` and the first `map_Kd`. Other statements (`o`, `g`,
//! `s`, `usemtl`, `l`, `p`, ...) are ignored.

use super::{EncodedTexture, Staged};
use crate::error::{Error, Result};
use crate::mesh::{LoadReport, Mesh, TextureSource, UvMap, VertexId};
use nalgebra::{Point3, Vector2, Vector3};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// Reads an OBJ file: polygons fan-triangulated, normals averaged per vertex, UVs per corner,
/// vertex colours if every vertex has them, the MTL's first `map_Kd` as texture.
pub fn read(path: &Path) -> Result<(Mesh, LoadReport)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(path, &bytes)
}

/// Parses OBJ text; `path` names the file in errors and locates the MTL. Never panics.
pub fn parse(path: &Path, bytes: &[u8]) -> Result<(Mesh, LoadReport)> {
    let text = String::from_utf8_lossy(bytes);
    let mut mesh = Mesh::default();
    let mut report = LoadReport::default();
    let mut colors: Vec<[f32; 3]> = Vec::new();
    let mut texcoords: Vec<Vector2<f32>> = Vec::new();
    let mut normals: Vec<Vector3<f64>> = Vec::new();
    let mut normal_sum: Vec<Vector3<f64>> = Vec::new();
    let mut uv_faces: Vec<[u32; 3]> = Vec::new();
    let mut faces_without_uv = 0usize;
    let mut any_normal = false;
    let mut mtllib: Option<String> = None;
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let line = raw.split('#').next().unwrap_or("").trim();
        let mut toks = line.split_whitespace();
        let Some(kind) = toks.next() else { continue };
        let nums = |toks: std::str::SplitWhitespace, min: usize, what: &str| -> Result<Vec<f64>> {
            let v: Vec<f64> = toks
                .map(|t| t.parse::<f64>())
                .collect::<std::result::Result<_, _>>()
                .map_err(|_| {
                    Error::at_line(
                        path,
                        ln,
                        format!("{what}: '{line}' has a value that is not a number"),
                    )
                })?;
            if v.len() < min {
                return Err(Error::at_line(
                    path,
                    ln,
                    format!("{what}: expected at least {min} values, found {}", v.len()),
                ));
            }
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                let names: &[&str] = match what {
                    "vertex" => &["x", "y", "z", "r", "g", "b", "w"],
                    "texture coordinate" => &["u", "v", "w"],
                    _ => &["x", "y", "z"],
                };
                let field = names.get(k).copied().unwrap_or("value");
                let token = line.split_whitespace().nth(k + 1).unwrap_or("");
                return Err(Error::at_line(
                    path,
                    ln,
                    format!(
                        "{what} {field} (value {} on the line) is '{token}', which is not finite",
                        k + 1
                    ),
                ));
            }
            Ok(v)
        };
        match kind {
            "v" => {
                let v = nums(toks, 3, "vertex")?;
                mesh.positions.push(Point3::new(v[0], v[1], v[2]));
                normal_sum.push(Vector3::zeros());
                if v.len() >= 6 {
                    colors.push([v[3] as f32, v[4] as f32, v[5] as f32]);
                }
            }
            "vt" => {
                let v = nums(toks, 1, "texture coordinate")?;
                texcoords.push(Vector2::new(
                    v[0] as f32,
                    v.get(1).copied().unwrap_or(0.0) as f32,
                ));
            }
            "vn" => {
                let v = nums(toks, 3, "normal")?;
                normals.push(Vector3::new(v[0], v[1], v[2]));
            }
            "f" => {
                let mut corners: Vec<(u32, Option<u32>)> = Vec::new();
                for c in toks {
                    let mut parts = c.split('/');
                    let resolve = |s: Option<&str>, n: usize, what: &str| -> Result<Option<u32>> {
                        let Some(s) = s.filter(|s| !s.is_empty()) else {
                            return Ok(None);
                        };
                        let k: i64 = s.parse().map_err(|_| {
                            Error::at_line(path, ln, format!("face corner '{c}' is malformed"))
                        })?;
                        let idx = if k > 0 { k - 1 } else { n as i64 + k };
                        if k == 0 || idx < 0 || idx >= n as i64 {
                            return Err(Error::at_line(
                                path,
                                ln,
                                format!(
                                    "face {what} index {k} is out of range ({n} defined so far)"
                                ),
                            ));
                        }
                        Ok(Some(idx as u32))
                    };
                    let v = resolve(parts.next(), mesh.positions.len(), "vertex")?.ok_or_else(
                        || {
                            Error::at_line(
                                path,
                                ln,
                                format!("face corner '{c}' has no vertex index"),
                            )
                        },
                    )?;
                    let t = resolve(parts.next(), texcoords.len(), "texture coordinate")?;
                    if let Some(n) = resolve(parts.next(), normals.len(), "normal")? {
                        normal_sum[v as usize] += normals[n as usize];
                        any_normal = true;
                    }
                    corners.push((v, t));
                }
                if corners.len() < 3 {
                    report.degenerate_faces += 1;
                    continue;
                }
                if corners.len() > 3 {
                    report.polygons_triangulated += 1;
                }
                let with_uv = corners.iter().all(|c| c.1.is_some());
                for k in 1..corners.len() - 1 {
                    let tri = [corners[0], corners[k], corners[k + 1]];
                    mesh.faces.push(tri.map(|c| VertexId(c.0)));
                    if with_uv {
                        uv_faces.push(tri.map(|c| c.1.unwrap_or(0)));
                    } else {
                        faces_without_uv += 1;
                    }
                }
            }
            "mtllib" if mtllib.is_none() => {
                mtllib = Some(line["mtllib".len()..].trim().to_string());
            }
            _ => {}
        }
    }
    if any_normal {
        mesh.normals = Some(
            normal_sum
                .iter()
                .map(|n| {
                    let l = n.norm();
                    if l > 0.0 {
                        (n / l).cast()
                    } else {
                        Vector3::zeros()
                    }
                })
                .collect(),
        );
    }
    if !colors.is_empty() && colors.len() == mesh.positions.len() {
        mesh.colors = Some(colors);
    }
    // UVs only when every face has them: a half-textured OBJ is treated as untextured.
    if faces_without_uv == 0 && !uv_faces.is_empty() {
        mesh.uv = Some(UvMap {
            coords: texcoords,
            faces: uv_faces,
        });
    }
    if let Some(lib) = mtllib {
        let dir = path.parent().unwrap_or(Path::new("."));
        let maps = diffuse_maps(&dir.join(&lib));
        mesh.texture = match udim_tiles(dir, &maps) {
            Some(tiles) => Some(TextureSource::Tiles(
                tiles.into_iter().map(TextureSource::File).collect(),
            )),
            None => maps.first().map(|t| TextureSource::File(dir.join(t))),
        };
    }
    Ok((mesh, report))
}

/// The `map_Kd` files of an MTL file in order (options such as `-s 1 1 1` skipped); none if
/// the file is missing or has none: a mesh without its texture is still a mesh.
fn diffuse_maps(mtl: &Path) -> Vec<String> {
    let Ok(text) = std::fs::read_to_string(mtl) else {
        return Vec::new();
    };
    text.lines()
        .filter_map(|l| {
            let rest = l.trim().strip_prefix("map_Kd")?;
            // The file name is what follows the options: take the last token.
            rest.split_whitespace().last().map(|s| s.to_string())
        })
        .collect()
}

/// The pages of a UDIM texture, if the maps name one: either one map with the `<UDIM>` token
/// (Blender's convention, tiles found on disk from 1001 on) or maps `<stem>.1001.<ext>`,
/// `<stem>.1002.<ext>`, ... (what scantex writes). A missing tile in the sequence ends it.
fn udim_tiles(dir: &Path, maps: &[String]) -> Option<Vec<std::path::PathBuf>> {
    let first = maps.first()?;
    let pattern = if first.contains("<UDIM>") {
        first.clone()
    } else {
        let (head, ext) = first.rsplit_once('.')?;
        let stem = head.strip_suffix(".1001")?;
        format!("{stem}.<UDIM>.{ext}")
    };
    let tile = |t: u32| pattern.replace("<UDIM>", &t.to_string());
    let named: Vec<String> = (1001..1101)
        .map(tile)
        .take_while(|n| maps.contains(n) || (maps.len() == 1 && dir.join(n).is_file()))
        .collect();
    (named.len() > 1 || first.contains("<UDIM>"))
        .then(|| named.iter().map(|n| dir.join(n)).collect())
        .filter(|v: &Vec<_>| !v.is_empty())
}

/// Writes `mesh` as OBJ; with a texture, also `<stem>.mtl` and `<stem>.<png|jpg>` beside it.
/// Positions use shortest round-trip formatting, so a re-read gives the same numbers.
pub fn write(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    texture: Option<&EncodedTexture>,
) -> Result<()> {
    write_pages(
        staged,
        path,
        mesh,
        texture.map_or(&[][..], std::slice::from_ref),
    )
}

/// `n` lines formatted by `line(i, out)`, in chunks in parallel, joined in order.
fn par_lines(n: usize, line: impl Fn(usize, &mut String) + Sync) -> String {
    const CHUNK: usize = 1 << 14;
    let parts: Vec<String> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut s = String::with_capacity(CHUNK * 40);
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                line(i, &mut s);
            }
            s
        })
        .collect();
    parts.concat()
}

/// [`write`] with one texture per atlas page: with two or more, the faces of page `p` (u in
/// `[p, p + 1]`) use material `page<1001 + p>`, whose map is `<stem>.<1001 + p>.<ext>` (UDIM
/// tiles). The UVs keep their UDIM values: a UDIM workflow reads the tiles as one texture, and
/// a viewer that repeats textures reads each page's material at the same place.
pub fn write_pages(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    textures: &[EncodedTexture],
) -> Result<()> {
    encode_pages(path, mesh, textures).write(staged)
}

/// The files [`write_pages`] writes, encoded: the textures, the material and the OBJ, in the
/// order they are written (and moved into place).
pub struct ObjFiles<'t> {
    files: Vec<(std::path::PathBuf, std::borrow::Cow<'t, [u8]>)>,
}

impl ObjFiles<'_> {
    /// Writes the files in their order.
    pub fn write(&self, staged: &mut Staged) -> Result<()> {
        for (path, bytes) in &self.files {
            staged.write(path, bytes)?;
        }
        Ok(())
    }
}

/// [`write_pages`]' files, encoded but not written, so that the OBJ can be formatted beside
/// other work.
pub fn encode_pages<'t>(path: &Path, mesh: &Mesh, textures: &'t [EncodedTexture]) -> ObjFiles<'t> {
    use std::borrow::Cow;
    let mut files = Vec::new();
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into());
    let paged = textures.len() > 1 && mesh.uv.is_some();
    let mut s = String::with_capacity(mesh.positions.len() * 40 + mesh.faces.len() * 30);
    s.push_str("# written by scantex\n");
    if !textures.is_empty() {
        let _ = writeln!(s, "mtllib {stem}.mtl");
        if !paged {
            s.push_str("usemtl material0\n");
        }
    }
    // Lines are formatted in parallel, a chunk each, and joined in order (the same bytes):
    // formatting floats took a second for a million vertices on one core.
    s.push_str(&par_lines(mesh.positions.len(), |i, s| {
        let p = &mesh.positions[i];
        let _ = write!(s, "v {} {} {}", p.x, p.y, p.z);
        if let Some(c) = &mesh.colors {
            let _ = write!(s, " {} {} {}", c[i][0], c[i][1], c[i][2]);
        }
        s.push('\n');
    }));
    if let Some(uv) = &mesh.uv {
        s.push_str(&par_lines(uv.coords.len(), |i, s| {
            let t = &uv.coords[i];
            let _ = writeln!(s, "vt {} {}", t.x, t.y);
        }));
    }
    if let Some(n) = &mesh.normals {
        s.push_str(&par_lines(n.len(), |i, s| {
            let v = &n[i];
            let _ = writeln!(s, "vn {} {} {}", v.x, v.y, v.z);
        }));
    }
    let has_n = mesh.normals.is_some();
    // Faces in their order, grouped by page when there are several (stable within a page).
    let order: Vec<usize> = match (&mesh.uv, paged) {
        (Some(uv), true) => {
            let mut o: Vec<usize> = (0..mesh.faces.len()).collect();
            o.sort_by_key(|&f| uv.face_page(f).min(textures.len() as u32 - 1));
            o
        }
        _ => (0..mesh.faces.len()).collect(),
    };
    let face_line = |f: usize, s: &mut String| {
        let face = &mesh.faces[f];
        s.push('f');
        for (k, vid) in face.iter().enumerate() {
            let v = vid.0 + 1;
            match (&mesh.uv, has_n) {
                (Some(uv), true) => write!(s, " {v}/{}/{v}", uv.faces[f][k] + 1),
                (Some(uv), false) => write!(s, " {v}/{}", uv.faces[f][k] + 1),
                (None, true) => write!(s, " {v}//{v}"),
                (None, false) => write!(s, " {v}"),
            }
            .expect("writing to a String cannot fail");
        }
        s.push('\n');
    };
    // One run of faces per page (one run in all with a single page).
    let mut rest = &order[..];
    while !rest.is_empty() {
        let run = match (&mesh.uv, paged) {
            (Some(uv), true) => {
                let page = |f: usize| uv.face_page(f).min(textures.len() as u32 - 1);
                let p = page(rest[0]);
                let _ = writeln!(s, "usemtl page{}", 1001 + p);
                rest.iter().take_while(|&&f| page(f) == p).count()
            }
            _ => rest.len(),
        };
        let (now, later) = rest.split_at(run);
        s.push_str(&par_lines(now.len(), |i, s| face_line(now[i], s)));
        rest = later;
    }
    // Textures, then material, then the OBJ that names them: the order they are moved into
    // place, so the file a reader opens first is the last to change.
    if !textures.is_empty() {
        let mut mtl = String::from("# written by scantex\n");
        for (p, tex) in textures.iter().enumerate() {
            let (name, tex_name) = if paged {
                (
                    format!("page{}", 1001 + p),
                    format!("{stem}.{}.{}", 1001 + p, tex.extension()),
                )
            } else {
                ("material0".into(), format!("{stem}.{}", tex.extension()))
            };
            let _ = write!(
                mtl,
                "newmtl {name}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {tex_name}\n"
            );
            files.push((
                path.with_file_name(&tex_name),
                Cow::Borrowed(&tex.bytes[..]),
            ));
            if !paged {
                break;
            }
        }
        files.push((
            path.with_file_name(format!("{stem}.mtl")),
            Cow::Owned(mtl.into_bytes()),
        ));
    }
    files.push((path.to_path_buf(), Cow::Owned(s.into_bytes())));
    ObjFiles { files }
}
