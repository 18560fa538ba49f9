//! Stanford PLY: ASCII and binary (little and big endian), any scalar type for any property,
//! face lists of any size and index type, per-vertex normals, colours and texture coordinates,
//! and MeshLab's per-corner `texcoord` face lists. Elements other than `vertex` and `face` are
//! read past. Errors give the header line or the data line / byte offset at fault.

use super::Staged;
use crate::error::{Error, Location, Result};
use crate::mesh::{LoadReport, Mesh, UvMap, VertexId};
use nalgebra::{Point3, Vector2, Vector3};
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
    /// Divisor that maps an integer colour channel to [0, 1].
    fn colour_scale(self) -> f64 {
        match self {
            Scalar::U8 | Scalar::I8 => 255.0,
            Scalar::U16 | Scalar::I16 => 65535.0,
            Scalar::U32 | Scalar::I32 => u32::MAX as f64,
            Scalar::F32 | Scalar::F64 => 1.0,
        }
    }
}

#[derive(Debug, Clone)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    LittleEndian,
    BigEndian,
}

/// Reads a PLY file from disk.
pub fn read(path: &Path) -> Result<(Mesh, LoadReport)> {
    let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(path, &data)
}

/// Parses PLY bytes; `path` only names the file in errors. Never panics on any input.
pub fn parse(path: &Path, data: &[u8]) -> Result<(Mesh, LoadReport)> {
    let (encoding, elements, body_start, header_lines) = parse_header(path, data)?;
    let mut src = Source {
        path,
        data,
        pos: body_start,
        line: header_lines + 1,
        encoding,
        tokens: Vec::new(),
    };
    let mut mesh = Mesh::default();
    let mut report = LoadReport::default();
    let mut uv_coords: Vec<Vector2<f32>> = Vec::new();
    let mut uv_faces: Vec<[u32; 3]> = Vec::new();
    let mut vertex_uv = false;
    let mut corner_uv = false;
    for el in &elements {
        // Cap preallocation by what the rest of the file could hold, so a corrupt count in
        // the header cannot allocate gigabytes.
        let min_record: usize = el
            .props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum::<usize>()
            .max(1);
        let cap = el
            .count
            .min((data.len() - src.pos.min(data.len())) / min_record + 1);
        match el.name.as_str() {
            "vertex" => {
                read_vertices(&mut src, el, cap, &mut mesh, &mut uv_coords, &mut vertex_uv)?
            }
            "face" => read_faces(
                &mut src,
                el,
                cap,
                &mut mesh,
                &mut report,
                &mut uv_coords,
                &mut uv_faces,
                &mut corner_uv,
            )?,
            // An element without properties has no data (and a huge count must not spin).
            _ if el.props.is_empty() => {}
            _ => {
                for _ in 0..el.count {
                    src.begin_record()?;
                    for p in &el.props {
                        src.skip(p)?;
                    }
                }
            }
        }
    }
    if vertex_uv && !corner_uv {
        uv_faces = mesh.faces.iter().map(|f| f.map(|v| v.0)).collect();
    }
    if (vertex_uv || corner_uv) && uv_faces.len() == mesh.faces.len() {
        mesh.uv = Some(UvMap {
            coords: uv_coords,
            faces: uv_faces,
        });
    }
    Ok((mesh, report))
}

fn parse_header(path: &Path, data: &[u8]) -> Result<(Encoding, Vec<Element>, usize, usize)> {
    const END: &[u8] = b"end_header";
    let end = data
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| Error::at_line(path, 1, "not a PLY file: no 'end_header' found"))?;
    let mut body = end + END.len();
    // The header ends at the newline after end_header (LF or CRLF).
    if data.get(body) == Some(&b'\r') {
        body += 1;
    }
    if data.get(body) == Some(&b'\n') {
        body += 1;
    }
    let header = std::str::from_utf8(&data[..end])
        .map_err(|_| Error::at_line(path, 1, "PLY header is not ASCII text"))?;
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut nlines = 0;
    for (i, line) in header.lines().enumerate() {
        let ln = i + 1;
        nlines = ln;
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            None => {}
            Some("ply") if ln == 1 => {}
            _ if ln == 1 => {
                return Err(Error::at_line(
                    path,
                    1,
                    "not a PLY file: first line is not 'ply'",
                ))
            }
            Some("comment" | "obj_info") => {}
            Some("format") => {
                encoding = Some(match t.get(1).copied() {
                    Some("ascii") => Encoding::Ascii,
                    Some("binary_little_endian") => Encoding::LittleEndian,
                    Some("binary_big_endian") => Encoding::BigEndian,
                    other => {
                        return Err(Error::at_line(
                            path,
                            ln,
                            format!("unknown PLY format '{}'", other.unwrap_or("")),
                        ))
                    }
                })
            }
            Some("element") => {
                if t.len() != 3 {
                    return Err(Error::at_line(
                        path,
                        ln,
                        "expected 'element <name> <count>'",
                    ));
                }
                let count = t[2].parse::<usize>().map_err(|_| {
                    Error::at_line(
                        path,
                        ln,
                        format!("element count '{}' is not a number", t[2]),
                    )
                })?;
                elements.push(Element {
                    name: t[1].to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| Error::at_line(path, ln, "property before any element"))?;
                let unsupported = |ty: &str| {
                    Error::at_line(
                        path,
                        ln,
                        format!(
                            "unsupported PLY property type '{ty}' (element '{}'): expected char, uchar, short, ushort, int, uint, float or double",
                            el.name
                        ),
                    )
                };
                let kind = if t.get(1) == Some(&"list") {
                    if t.len() != 5 {
                        return Err(Error::at_line(
                            path,
                            ln,
                            "expected 'property list <count type> <item type> <name>'",
                        ));
                    }
                    let count = Scalar::parse(t[2]).ok_or_else(|| unsupported(t[2]))?;
                    if matches!(count, Scalar::F32 | Scalar::F64) {
                        return Err(Error::at_line(
                            path,
                            ln,
                            "list count type must be an integer",
                        ));
                    }
                    let item = Scalar::parse(t[3]).ok_or_else(|| unsupported(t[3]))?;
                    Kind::List { count, item }
                } else {
                    if t.len() != 3 {
                        return Err(Error::at_line(
                            path,
                            ln,
                            "expected 'property <type> <name>'",
                        ));
                    }
                    Kind::Scalar(Scalar::parse(t[1]).ok_or_else(|| unsupported(t[1]))?)
                };
                let name = t.last().unwrap().to_string();
                el.props.push(Property { name, kind });
            }
            Some(other) => {
                return Err(Error::at_line(
                    path,
                    ln,
                    format!("unknown PLY header keyword '{other}'"),
                ))
            }
        }
    }
    let encoding =
        encoding.ok_or_else(|| Error::at_line(path, 2, "PLY header has no 'format' line"))?;
    Ok((encoding, elements, body, nlines + 1))
}

/// The data section, read value by value in either encoding.
struct Source<'a> {
    path: &'a Path,
    data: &'a [u8],
    pos: usize,
    /// Current line (ASCII) for error messages.
    line: usize,
    encoding: Encoding,
    /// Remaining tokens of the current ASCII line.
    tokens: Vec<&'a str>,
}

impl<'a> Source<'a> {
    fn loc(&self) -> Location {
        match self.encoding {
            Encoding::Ascii => Location::Line(self.line.saturating_sub(1).max(1)),
            _ => Location::Byte(self.pos as u64),
        }
    }

    fn err(&self, msg: impl Into<String>) -> Error {
        Error::parse(self.path, self.loc(), msg)
    }

    /// ASCII records are one per line: load the next non-empty line's tokens.
    fn begin_record(&mut self) -> Result<()> {
        if self.encoding != Encoding::Ascii {
            return Ok(());
        }
        loop {
            if self.pos >= self.data.len() {
                self.line += 1;
                return Err(self.err("file ends before all elements were read: truncated"));
            }
            let rest = &self.data[self.pos..];
            let n = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
            let line = std::str::from_utf8(&rest[..n])
                .map_err(|_| self.err("data line is not ASCII text"))?;
            self.pos += (n + 1).min(rest.len());
            self.line += 1;
            let toks: Vec<&'a str> = line.split_whitespace().rev().collect();
            if !toks.is_empty() {
                self.tokens = toks;
                return Ok(());
            }
        }
    }

    fn value(&mut self, s: Scalar) -> Result<f64> {
        match self.encoding {
            Encoding::Ascii => {
                let tok = self
                    .tokens
                    .pop()
                    .ok_or_else(|| self.err("line has fewer values than the header declares"))?;
                let v = match s {
                    Scalar::F32 | Scalar::F64 => tok.parse::<f64>().ok(),
                    _ => tok.parse::<i64>().ok().map(|v| v as f64),
                };
                v.ok_or_else(|| self.err(format!("'{tok}' is not a valid {s:?} value")))
            }
            enc => {
                let n = s.size();
                if self.data.len() - self.pos < n {
                    return Err(self.err("file ends before all elements were read: truncated"));
                }
                let b = &self.data[self.pos..self.pos + n];
                self.pos += n;
                let mut a = [0u8; 8];
                a[..n].copy_from_slice(b);
                if enc == Encoding::BigEndian {
                    a[..n].reverse();
                }
                Ok(match s {
                    Scalar::I8 => a[0] as i8 as f64,
                    Scalar::U8 => a[0] as f64,
                    Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
                    Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
                    Scalar::F64 => f64::from_le_bytes(a),
                })
            }
        }
    }

    fn list_len(&mut self, count: Scalar, item: Scalar) -> Result<usize> {
        let at = self.loc();
        let n = self.value(count)?;
        if n < 0.0 || n.fract() != 0.0 {
            return Err(Error::parse(
                self.path,
                at,
                format!("list length {n} is invalid"),
            ));
        }
        let n = n as usize;
        // A list longer than the rest of the file is corrupt; refuse before reading it.
        if self.encoding != Encoding::Ascii
            && n.saturating_mul(item.size()) > self.data.len() - self.pos
        {
            return Err(Error::parse(
                self.path,
                at,
                format!("list length {n} runs past the end of the file: truncated or corrupt"),
            ));
        }
        Ok(n)
    }

    fn skip(&mut self, p: &Property) -> Result<()> {
        match p.kind {
            Kind::Scalar(s) => {
                self.value(s)?;
            }
            Kind::List { count, item } => {
                let n = self.list_len(count, item)?;
                for _ in 0..n {
                    self.value(item)?;
                }
            }
        }
        Ok(())
    }
}

/// Which vertex slot a property fills.
#[derive(Clone, Copy)]
enum Slot {
    Pos(usize),
    Normal(usize),
    Color(usize, f64),
    Uv(usize),
    Other,
}

fn read_vertices(
    src: &mut Source,
    el: &Element,
    cap: usize,
    mesh: &mut Mesh,
    uv_coords: &mut Vec<Vector2<f32>>,
    has_uv: &mut bool,
) -> Result<()> {
    let slots: Vec<Slot> = el
        .props
        .iter()
        .map(|p| {
            let scalar = match p.kind {
                Kind::Scalar(s) => s,
                Kind::List { .. } => return Slot::Other,
            };
            match p.name.as_str() {
                "x" => Slot::Pos(0),
                "y" => Slot::Pos(1),
                "z" => Slot::Pos(2),
                "nx" => Slot::Normal(0),
                "ny" => Slot::Normal(1),
                "nz" => Slot::Normal(2),
                "red" | "r" | "diffuse_red" => Slot::Color(0, scalar.colour_scale()),
                "green" | "g" | "diffuse_green" => Slot::Color(1, scalar.colour_scale()),
                "blue" | "b" | "diffuse_blue" => Slot::Color(2, scalar.colour_scale()),
                "s" | "u" | "texture_u" | "texture_s" => Slot::Uv(0),
                "t" | "v" | "texture_v" | "texture_t" => Slot::Uv(1),
                _ => Slot::Other,
            }
        })
        .collect();
    let has = |f: fn(&Slot) -> bool| slots.iter().filter(|s| f(s)).count();
    if has(|s| matches!(s, Slot::Pos(_))) != 3 {
        return Err(Error::at_element(
            src.path,
            "element vertex",
            "vertices need scalar properties x, y and z",
        ));
    }
    let with_normals = has(|s| matches!(s, Slot::Normal(_))) == 3;
    let with_colors = has(|s| matches!(s, Slot::Color(..))) == 3;
    *has_uv = has(|s| matches!(s, Slot::Uv(_))) == 2;
    mesh.positions.reserve(cap);
    let mut normals = Vec::new();
    let mut colors = Vec::new();
    for _ in 0..el.count {
        src.begin_record()?;
        let (mut p, mut n, mut c, mut t) = ([0.0; 3], [0.0; 3], [0.0f32; 3], [0.0; 2]);
        for (prop, slot) in el.props.iter().zip(&slots) {
            match (*slot, &prop.kind) {
                (Slot::Pos(k), Kind::Scalar(s)) => p[k] = src.value(*s)?,
                (Slot::Normal(k), Kind::Scalar(s)) => n[k] = src.value(*s)?,
                (Slot::Color(k, scale), Kind::Scalar(s)) => c[k] = (src.value(*s)? / scale) as f32,
                (Slot::Uv(k), Kind::Scalar(s)) => t[k] = src.value(*s)?,
                _ => src.skip(prop)?,
            }
        }
        mesh.positions.push(Point3::from(p));
        if with_normals {
            let v = Vector3::from(n);
            let l = v.norm();
            normals.push(if l > 0.0 {
                (v / l).cast()
            } else {
                Vector3::zeros()
            });
        }
        if with_colors {
            colors.push(c);
        }
        if *has_uv {
            uv_coords.push(Vector2::new(t[0] as f32, t[1] as f32));
        }
    }
    mesh.normals = with_normals.then_some(normals);
    mesh.colors = with_colors.then_some(colors);
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn read_faces(
    src: &mut Source,
    el: &Element,
    cap: usize,
    mesh: &mut Mesh,
    report: &mut LoadReport,
    uv_coords: &mut Vec<Vector2<f32>>,
    uv_faces: &mut Vec<[u32; 3]>,
    corner_uv: &mut bool,
) -> Result<()> {
    let index_prop = el
        .props
        .iter()
        .position(|p| {
            matches!(p.kind, Kind::List { .. })
                && (p.name == "vertex_indices" || p.name == "vertex_index")
        })
        .ok_or_else(|| {
            Error::at_element(
                src.path,
                "element face",
                "faces need a list property 'vertex_indices' (or 'vertex_index')",
            )
        })?;
    let uv_prop = el
        .props
        .iter()
        .position(|p| matches!(p.kind, Kind::List { .. }) && p.name == "texcoord");
    *corner_uv = uv_prop.is_some();
    if *corner_uv {
        // Per-corner UVs replace any per-vertex ones.
        uv_coords.clear();
    }
    mesh.faces.reserve(cap);
    let mut idx: Vec<f64> = Vec::new();
    let mut tex: Vec<f64> = Vec::new();
    for f in 0..el.count {
        src.begin_record()?;
        let record_loc = src.loc();
        idx.clear();
        tex.clear();
        for (k, prop) in el.props.iter().enumerate() {
            match prop.kind {
                Kind::List { count, item } if k == index_prop || Some(k) == uv_prop => {
                    let n = src.list_len(count, item)?;
                    let out = if k == index_prop { &mut idx } else { &mut tex };
                    for _ in 0..n {
                        out.push(src.value(item)?);
                    }
                }
                _ => src.skip(prop)?,
            }
        }
        if idx.len() < 3 {
            report.degenerate_faces += 1;
            continue;
        }
        if idx.len() > 3 {
            report.polygons_triangulated += 1;
        }
        let mut ids = Vec::with_capacity(idx.len());
        for &v in &idx {
            if v < 0.0 || v >= u32::MAX as f64 || v.fract() != 0.0 {
                // A header that declares more vertices than the data holds makes faces' bytes
                // read as vertices, and then the faces' own fields garbage: say so.
                let why = if src.encoding == Encoding::Ascii {
                    ""
                } else {
                    "; the faces' bytes are misaligned, so the header's element counts or \
                     property types do not match the data (truncated or corrupt file?)"
                };
                return Err(Error::parse(
                    src.path,
                    record_loc,
                    format!("face {f}: vertex index {v} is not a vertex number{why}"),
                ));
            }
            ids.push(v as u32);
        }
        let base = uv_coords.len() as u32;
        if uv_prop.is_some() {
            if tex.len() != 2 * idx.len() {
                return Err(Error::at_element(
                    src.path,
                    format!("face {f}"),
                    format!(
                        "texcoord list has {} values for {} corners",
                        tex.len(),
                        idx.len()
                    ),
                ));
            }
            uv_coords.extend(
                tex.chunks_exact(2)
                    .map(|c| Vector2::new(c[0] as f32, c[1] as f32)),
            );
        }
        for k in 1..ids.len() - 1 {
            mesh.faces
                .push([VertexId(ids[0]), VertexId(ids[k]), VertexId(ids[k + 1])]);
            if uv_prop.is_some() {
                uv_faces.push([base, base + k as u32, base + k as u32 + 1]);
            }
        }
    }
    Ok(())
}

/// Writes binary little-endian PLY: `double` positions (lossless), `float` normals, `uchar`
/// colours, and per-corner UVs as MeshLab's `texcoord` face list.
pub fn write(staged: &mut Staged, path: &Path, mesh: &Mesh) -> Result<()> {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\ncomment written by scantex\n");
    h += &format!("element vertex {}\n", mesh.positions.len());
    h += "property double x\nproperty double y\nproperty double z\n";
    if mesh.normals.is_some() {
        h += "property float nx\nproperty float ny\nproperty float nz\n";
    }
    if mesh.colors.is_some() {
        h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
    }
    h += &format!("element face {}\n", mesh.faces.len());
    h += "property list uchar int vertex_indices\n";
    if mesh.uv.is_some() {
        h += "property list uchar float texcoord\n";
    }
    h += "end_header\n";
    let mut b = h.into_bytes();
    for (i, p) in mesh.positions.iter().enumerate() {
        for c in p.iter() {
            b.extend(c.to_le_bytes());
        }
        if let Some(n) = &mesh.normals {
            for c in n[i].iter() {
                b.extend(c.to_le_bytes());
            }
        }
        if let Some(col) = &mesh.colors {
            b.extend(col[i].map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8));
        }
    }
    for (f, face) in mesh.faces.iter().enumerate() {
        b.push(3);
        for v in face {
            b.extend((v.0 as i32).to_le_bytes());
        }
        if let Some(uv) = &mesh.uv {
            b.push(6);
            for &t in &uv.faces[f] {
                let c = uv.coords[t as usize];
                b.extend(c.x.to_le_bytes());
                b.extend(c.y.to_le_bytes());
            }
        }
    }
    staged.write(path, &b)
}
