//! Wavefront OBJ (+ MTL) through `tobj`, with our own line locator for its errors (tobj reports
//! what went wrong but not where) and fan triangulation so we can count polygons.

use super::{EncodedTexture, Staged};
use crate::error::{Error, Result};
use crate::mesh::{LoadReport, Mesh, TextureSource, UvMap, VertexId};
use nalgebra::{Point3, Vector2, Vector3};
use std::fmt::Write as _;
use std::path::Path;

/// Reads an OBJ file: all objects and groups merged, polygons fan-triangulated, normals
/// averaged per position, UVs kept per corner, the first material's `map_Kd` as texture.
pub fn read(path: &Path) -> Result<(Mesh, LoadReport)> {
    let opts = tobj::LoadOptions {
        triangulate: false,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, materials) = tobj::load_obj(path, &opts).map_err(|e| locate_error(path, e))?;
    let mut mesh = Mesh::default();
    let mut report = LoadReport::default();
    let mut uv = UvMap {
        coords: Vec::new(),
        faces: Vec::new(),
    };
    let mut normal_sum: Vec<Vector3<f64>> = Vec::new();
    let mut any_normals = false;
    let mut any_colors = false;
    let mut colors: Vec<[f32; 3]> = Vec::new();
    let mut all_have_uv = true;
    for model in &models {
        let m = &model.mesh;
        let v0 = mesh.positions.len() as u32;
        let t0 = uv.coords.len() as u32;
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|c| Point3::new(c[0], c[1], c[2])),
        );
        uv.coords.extend(
            m.texcoords
                .chunks_exact(2)
                .map(|c| Vector2::new(c[0] as f32, c[1] as f32)),
        );
        let nv = m.positions.len() / 3;
        if m.vertex_color.len() == m.positions.len() && !m.vertex_color.is_empty() {
            any_colors = true;
            colors.extend(
                m.vertex_color
                    .chunks_exact(3)
                    .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32]),
            );
        } else {
            colors.extend(std::iter::repeat_n([1.0f32; 3], nv));
        }
        normal_sum.extend(std::iter::repeat_n(Vector3::zeros(), nv));
        let has_uv = !m.texcoord_indices.is_empty();
        let has_n = !m.normal_indices.is_empty();
        all_have_uv &= has_uv || m.indices.is_empty();
        // Face arities are empty when every face is a triangle.
        let arities: Vec<usize> = if m.face_arities.is_empty() {
            vec![3; m.indices.len() / 3]
        } else {
            m.face_arities.iter().map(|&a| a as usize).collect()
        };
        let mut start = 0;
        for a in arities {
            let corners = start..start + a;
            start += a;
            if a < 3 {
                report.degenerate_faces += 1;
                continue;
            }
            if a > 3 {
                report.polygons_triangulated += 1;
            }
            let idx = &m.indices[corners.clone()];
            if has_n {
                for (k, &vi) in idx.iter().enumerate() {
                    let ni = m.normal_indices[corners.start + k] as usize;
                    if let Some(n) = m.normals.get(3 * ni..3 * ni + 3) {
                        normal_sum[(v0 + vi) as usize] += Vector3::new(n[0], n[1], n[2]);
                        any_normals = true;
                    }
                }
            }
            for k in 1..a - 1 {
                mesh.faces.push([
                    VertexId(v0 + idx[0]),
                    VertexId(v0 + idx[k]),
                    VertexId(v0 + idx[k + 1]),
                ]);
                if has_uv {
                    let t = &m.texcoord_indices[corners.clone()];
                    uv.faces.push([t0 + t[0], t0 + t[k], t0 + t[k + 1]]);
                }
            }
        }
    }
    if any_normals {
        mesh.normals = Some(
            normal_sum
                .iter()
                .map(|n| {
                    let l = n.norm();
                    if l > 0.0 {
                        (n / l).cast::<f32>()
                    } else {
                        Vector3::zeros()
                    }
                })
                .collect(),
        );
    }
    if any_colors {
        mesh.colors = Some(colors);
    }
    if all_have_uv && !uv.faces.is_empty() {
        mesh.uv = Some(uv);
    }
    if let Ok(mats) = materials {
        if let Some(tex) = mats.iter().find_map(|m| m.diffuse_texture.clone()) {
            let dir = path.parent().unwrap_or(Path::new("."));
            mesh.texture = Some(TextureSource::File(dir.join(tex.trim())));
        }
    }
    Ok((mesh, report))
}

/// Turns a tobj error into ours, pointing at the first line that explains it.
fn locate_error(path: &Path, e: tobj::LoadError) -> Error {
    if matches!(
        e,
        tobj::LoadError::OpenFileFailed | tobj::LoadError::ReadError
    ) {
        let io = std::fs::File::open(path)
            .err()
            .unwrap_or_else(|| std::io::Error::other(e.to_string()));
        return Error::io(path, io);
    }
    let Ok(text) = std::fs::read_to_string(path) else {
        return Error::parse(path, crate::error::Location::File, e.to_string());
    };
    let (mut nv, mut nt, mut nn) = (0usize, 0usize, 0usize);
    for (i, line) in text.lines().enumerate() {
        let mut toks = line.split_whitespace();
        let bad = |msg: String| Some(Error::at_line(path, i + 1, msg));
        let found = match toks.next() {
            Some(kind @ ("v" | "vt" | "vn")) => {
                let vals: Vec<&str> = toks.collect();
                let need = if kind == "vt" { 1 } else { 3 };
                let counter = match kind {
                    "v" => &mut nv,
                    "vt" => &mut nt,
                    _ => &mut nn,
                };
                *counter += 1;
                if vals.len() < need || vals.iter().any(|v| v.parse::<f64>().is_err()) {
                    bad(format!("'{}': {e}", line.trim()))
                } else {
                    None
                }
            }
            Some("f") => toks.find_map(|corner| {
                corner.split('/').zip([nv, nt, nn]).find_map(|(s, n)| {
                    if s.is_empty() {
                        return None;
                    }
                    match s.parse::<i64>() {
                        Ok(k)
                            if (k > 0 && k as usize <= n)
                                || (k < 0 && k.unsigned_abs() as usize <= n) =>
                        {
                            None
                        }
                        Ok(k) => bad(format!(
                            "face index {k} is out of range ({n} defined so far)"
                        )),
                        Err(_) => bad(format!("face corner '{corner}' is malformed")),
                    }
                })
            }),
            _ => None,
        };
        if let Some(err) = found {
            return err;
        }
    }
    Error::parse(path, crate::error::Location::File, e.to_string())
}

/// Writes `mesh` as OBJ; with a texture, also `<stem>.mtl` and `<stem>.<png|jpg>` beside it.
/// Positions use shortest round-trip formatting, so a re-read gives the same numbers.
pub fn write(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    texture: Option<&EncodedTexture>,
) -> Result<()> {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "model".into());
    let mut s = String::with_capacity(mesh.positions.len() * 40 + mesh.faces.len() * 30);
    s.push_str("# written by scantex\n");
    if texture.is_some() {
        let _ = writeln!(s, "mtllib {stem}.mtl\nusemtl material0");
    }
    for (i, p) in mesh.positions.iter().enumerate() {
        let _ = write!(s, "v {} {} {}", p.x, p.y, p.z);
        if let Some(c) = &mesh.colors {
            let _ = write!(s, " {} {} {}", c[i][0], c[i][1], c[i][2]);
        }
        s.push('\n');
    }
    if let Some(uv) = &mesh.uv {
        for t in &uv.coords {
            let _ = writeln!(s, "vt {} {}", t.x, t.y);
        }
    }
    if let Some(n) = &mesh.normals {
        for v in n {
            let _ = writeln!(s, "vn {} {} {}", v.x, v.y, v.z);
        }
    }
    let has_n = mesh.normals.is_some();
    for (f, face) in mesh.faces.iter().enumerate() {
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
    }
    staged.write(path, s.as_bytes())?;
    if let Some(tex) = texture {
        let tex_name = format!("{stem}.{}", tex.extension());
        let mtl = format!(
            "# written by scantex\nnewmtl material0\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nillum 1\nmap_Kd {tex_name}\n"
        );
        staged.write(&path.with_file_name(format!("{stem}.mtl")), mtl.as_bytes())?;
        staged.write(&path.with_file_name(tex_name), &tex.bytes)?;
    }
    Ok(())
}
