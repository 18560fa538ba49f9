//! glTF 2.0 input (`.gltf` + buffers, `.glb`) through the `gltf` crate, every triangle primitive
//! of the default scene with its node transforms applied; and binary glTF output with the
//! texture embedded, written so that the Khronos validator reports no errors or warnings.

use super::{EncodedTexture, Staged};
use crate::error::{Error, Result};
use crate::mesh::{LoadReport, Mesh, TextureSource, UvMap, VertexId};
use nalgebra::{Matrix3, Matrix4, Point3, Vector2, Vector3};
use serde_json::json;
use std::path::Path;

/// Reads a `.gltf` or `.glb` file. The `gltf` crate validates indices but may still panic
/// on byte ranges that run past a buffer in a corrupt file; such a panic is turned into an
/// error naming the file, so bad input never takes the process down.
pub fn read(path: &Path) -> Result<(Mesh, LoadReport)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let caught =
        quietly(|| std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| parse(path, &bytes))));
    match caught {
        Ok(r) => r,
        Err(_) => Err(Error::parse(
            path,
            crate::error::Location::File,
            "corrupt glTF: an accessor or buffer view runs past its buffer",
        )),
    }
}

thread_local! {
    /// Set while this thread runs code whose panics are caught and turned into errors.
    static QUIET: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with the panic message of this thread silenced: a panic that [`read`] catches and
/// reports as an error naming the file must not also print a backtrace. Every other panic, on
/// every thread, still goes to the hook that was installed before.
fn quietly<T>(f: impl FnOnce() -> T) -> T {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET.with(|q| q.get()) {
                previous(info);
            }
        }));
    });
    QUIET.with(|q| q.set(true));
    let out = f();
    QUIET.with(|q| q.set(false));
    out
}

/// Refuses a file that requires an extension this reader lacks, naming it: compressed meshes
/// (Draco, meshopt) would otherwise fail as a list of accessors without data.
fn check_required_extensions(path: &Path, json: &gltf::json::Root) -> Result<()> {
    let Some(e) = json
        .extensions_required
        .iter()
        .find(|e| !gltf::json::extensions::ENABLED_EXTENSIONS.contains(&e.as_str()))
    else {
        return Ok(());
    };
    let hint = if e.contains("draco") || e.contains("meshopt") {
        "; scantex reads uncompressed meshes: export the mesh again without mesh compression"
    } else {
        ""
    };
    Err(Error::parse(
        path,
        crate::error::Location::File,
        format!("the file requires the glTF extension {e}, which scantex does not read{hint}"),
    ))
}

/// Parses the bytes of a `.gltf` or `.glb` file; external buffers and textures are looked up
/// beside `path`, which also names the file in errors. Unlike [`read`], a panic inside the
/// `gltf` crate is not caught here (so fuzzing sees it).
pub fn parse(path: &Path, bytes: &[u8]) -> Result<(Mesh, LoadReport)> {
    let gltf_error = |e: gltf::Error| match e {
        gltf::Error::Io(io) => Error::io(path, io),
        other => Error::parse(path, crate::error::Location::File, other.to_string()),
    };
    check_glb_length(path, bytes)?;
    let raw = gltf::Gltf::from_slice_without_validation(bytes).map_err(gltf_error)?;
    check_required_extensions(path, raw.document.as_json())?;
    check_position_accessors(path, raw.document.as_json())?;
    let g = gltf::Gltf {
        document: gltf::Document::from_json(raw.document.into_json()).map_err(gltf_error)?,
        blob: raw.blob,
    };
    let base = path.parent().unwrap_or(Path::new("."));
    check_buffer_uris(path, &g.document)?;
    let buffers = gltf::import_buffers(&g.document, Some(base), g.blob.clone())
        .map_err(|e| buffer_error(path, base, &g.document, e))?;
    let mut out = Builder::default();
    let roots: Vec<gltf::Node> = match g
        .document
        .default_scene()
        .or_else(|| g.document.scenes().next())
    {
        Some(scene) => scene.nodes().collect(),
        None => Vec::new(),
    };
    if roots.is_empty() {
        // No scene: take every mesh untransformed rather than nothing.
        for mesh in g.document.meshes() {
            out.add_mesh(path, &mesh, &Matrix4::identity(), &buffers)?;
        }
    } else {
        for node in roots {
            out.add_node(path, &node, &Matrix4::identity(), &buffers, 0)?;
        }
    }
    let mut mesh = out.mesh;
    // Primitives with different base-colour images (one material per page, as scantex
    // writes several pages): each image becomes a UDIM page and its primitives' UVs move there.
    let mut images: Vec<usize> = Vec::new();
    for &(_, _, img) in &out.prim_images {
        if let Some(i) = img.filter(|i| !images.contains(i)) {
            images.push(i);
        }
    }
    let tiles = if images.len() > 1 && out.all_uv {
        for &(first, n, img) in &out.prim_images {
            let page = img
                .and_then(|i| images.iter().position(|&j| j == i))
                .unwrap_or(0);
            for t in &mut out.uv[first..first + n] {
                t.x += page as f32;
            }
        }
        images
            .iter()
            .map(|&i| texture_source(&g.document, base, i, &buffers))
            .collect::<Option<Vec<_>>>()
    } else {
        None
    };
    if out.all_uv && !mesh.faces.is_empty() {
        mesh.uv = Some(UvMap {
            coords: out.uv,
            faces: mesh.faces.iter().map(|f| f.map(|v| v.0)).collect(),
        });
    }
    if out.all_normals && !mesh.positions.is_empty() {
        mesh.normals = Some(out.normals);
    }
    if out.all_colors && !mesh.positions.is_empty() {
        mesh.colors = Some(out.colors);
    }
    // The first candidate that exists: some scans name a base-colour file they do not ship.
    mesh.texture = match tiles {
        Some(t) => Some(TextureSource::Tiles(t)),
        None => out
            .textures
            .iter()
            .filter_map(|&i| texture_source(&g.document, base, i, &buffers))
            .find(|t| match t {
                TextureSource::File(p) => p.is_file(),
                TextureSource::Embedded(_) | TextureSource::Tiles(_) => true,
            }),
    };
    Ok((mesh, out.report))
}

#[derive(Default)]
struct Builder {
    mesh: Mesh,
    report: LoadReport,
    uv: Vec<Vector2<f32>>,
    normals: Vec<Vector3<f32>>,
    colors: Vec<[f32; 3]>,
    all_uv: bool,
    all_normals: bool,
    all_colors: bool,
    started: bool,
    /// Candidate colour images: base colour, then the spec-gloss diffuse (older scans).
    textures: Vec<usize>,
    /// Per primitive: its first vertex, vertex count and base-colour image, if any.
    prim_images: Vec<(usize, usize, Option<usize>)>,
}

impl Builder {
    fn add_node(
        &mut self,
        path: &Path,
        node: &gltf::Node,
        parent: &Matrix4<f64>,
        buffers: &[gltf::buffer::Data],
        depth: usize,
    ) -> Result<()> {
        if depth > 256 {
            return Err(Error::at_element(
                path,
                format!("node {}", node.index()),
                "node hierarchy deeper than 256 levels (a cycle?)",
            ));
        }
        let local = Matrix4::from_column_slice(
            &node
                .transform()
                .matrix()
                .iter()
                .flatten()
                .map(|&v| v as f64)
                .collect::<Vec<_>>(),
        );
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            self.add_mesh(path, &mesh, &world, buffers)?;
        }
        for child in node.children() {
            self.add_node(path, &child, &world, buffers, depth + 1)?;
        }
        Ok(())
    }

    fn add_mesh(
        &mut self,
        path: &Path,
        mesh: &gltf::Mesh,
        world: &Matrix4<f64>,
        buffers: &[gltf::buffer::Data],
    ) -> Result<()> {
        let lin: Matrix3<f64> = world.fixed_view::<3, 3>(0, 0).into();
        let normal_m = lin.try_inverse().map(|m| m.transpose()).unwrap_or(lin);
        let flip = lin.determinant() < 0.0;
        for prim in mesh.primitives() {
            use gltf::mesh::Mode;
            let elem = format!("mesh {} primitive {}", mesh.index(), prim.index());
            let mode = prim.mode();
            if !matches!(
                mode,
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
            ) {
                continue;
            }
            check_formats(path, &elem, &prim)?;
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else {
                return Err(Error::at_element(
                    path,
                    elem,
                    "primitive has no POSITION attribute",
                ));
            };
            let base = self.mesh.positions.len() as u32;
            let pos: Vec<[f32; 3]> = pos.collect();
            let n = pos.len();
            for p in &pos {
                let v = world.transform_point(&Point3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                self.mesh.positions.push(v);
            }
            let first = !self.started;
            self.started = true;
            let uv: Option<Vec<[f32; 2]>> =
                reader.read_tex_coords(0).map(|t| t.into_f32().collect());
            self.all_uv = (first || self.all_uv) && uv.as_ref().is_some_and(|u| u.len() == n);
            self.uv.extend(
                uv.unwrap_or_default()
                    .into_iter()
                    .map(|t| Vector2::new(t[0], 1.0 - t[1]))
                    .chain(std::iter::repeat(Vector2::zeros()))
                    .take(n),
            );
            let nrm: Option<Vec<[f32; 3]>> = reader.read_normals().map(|i| i.collect());
            self.all_normals =
                (first || self.all_normals) && nrm.as_ref().is_some_and(|v| v.len() == n);
            self.normals.extend(
                nrm.unwrap_or_default()
                    .into_iter()
                    .map(|v| {
                        let t = normal_m * Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                        let l = t.norm();
                        if l > 0.0 {
                            (t / l).cast()
                        } else {
                            Vector3::zeros()
                        }
                    })
                    .chain(std::iter::repeat(Vector3::zeros()))
                    .take(n),
            );
            let col: Option<Vec<[f32; 3]>> =
                reader.read_colors(0).map(|c| c.into_rgb_f32().collect());
            self.all_colors =
                (first || self.all_colors) && col.as_ref().is_some_and(|v| v.len() == n);
            self.colors.extend(
                col.unwrap_or_default()
                    .into_iter()
                    .chain(std::iter::repeat([1.0; 3]))
                    .take(n),
            );
            let idx: Vec<u32> = match reader.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..n as u32).collect(),
            };
            if let Some(&bad) = idx.iter().find(|&&i| i as usize >= n) {
                return Err(Error::at_element(
                    path,
                    elem,
                    format!("index {bad} is out of range ({n} vertices)"),
                ));
            }
            let tris: Vec<[u32; 3]> = match mode {
                Mode::Triangles => {
                    if !idx.len().is_multiple_of(3) {
                        self.report.degenerate_faces += 1;
                    }
                    idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
                }
                Mode::TriangleStrip => (2..idx.len())
                    .map(|i| {
                        if i % 2 == 0 {
                            [idx[i - 2], idx[i - 1], idx[i]]
                        } else {
                            [idx[i - 1], idx[i - 2], idx[i]]
                        }
                    })
                    .collect(),
                _ => (2..idx.len())
                    .map(|i| [idx[0], idx[i - 1], idx[i]])
                    .collect(),
            };
            for t in tris {
                let t = if flip { [t[0], t[2], t[1]] } else { t };
                self.mesh.faces.push(t.map(|i| VertexId(base + i)));
            }
            let image = prim
                .material()
                .pbr_metallic_roughness()
                .base_color_texture()
                .map(|t| t.texture().source().index());
            self.prim_images.push((base as usize, n, image));
            if self.textures.is_empty() {
                let mat = prim.material();
                let base = mat.pbr_metallic_roughness().base_color_texture();
                let diffuse = mat
                    .pbr_specular_glossiness()
                    .and_then(|s| s.diffuse_texture());
                self.textures = base
                    .into_iter()
                    .chain(diffuse)
                    .map(|t| t.texture().source().index())
                    .collect();
            }
        }
        Ok(())
    }
}

fn texture_source(
    doc: &gltf::Document,
    base: &Path,
    image_index: usize,
    buffers: &[gltf::buffer::Data],
) -> Option<TextureSource> {
    let image = doc.images().nth(image_index)?;
    match image.source() {
        gltf::image::Source::View { view, .. } => {
            let buf = buffers.get(view.buffer().index())?;
            let bytes = buf.0.get(view.offset()..view.offset() + view.length())?;
            Some(TextureSource::Embedded(bytes.to_vec()))
        }
        // Textures inlined as data URIs are not kept (rare in scans; the mesh still loads).
        gltf::image::Source::Uri { uri, .. } if uri.starts_with("data:") => None,
        gltf::image::Source::Uri { uri, .. } => {
            Some(TextureSource::File(base.join(percent_decode(uri)?)))
        }
    }
}

/// Writes a binary glTF (`.glb`) with positions, normals, UVs (if any) and the texture
/// embedded. glTF stores attributes per vertex, so vertices on UV seams are split.
pub fn write_glb(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    texture: Option<&EncodedTexture>,
) -> Result<()> {
    write_glb_pages(
        staged,
        path,
        mesh,
        texture.map_or(&[][..], std::slice::from_ref),
    )
}

/// [`write_glb`] with one texture per atlas page: with two or more, the faces of page `p`
/// (u in `[p, p + 1]`) form primitive `p` with its own material and texture, and their UVs
/// are moved to `[0, 1]` (glTF has no UDIM tiles).
pub fn write_glb_pages(
    staged: &mut Staged,
    path: &Path,
    mesh: &Mesh,
    textures: &[EncodedTexture],
) -> Result<()> {
    let bytes = glb_bytes(path, mesh, textures)?;
    staged.write(path, &bytes)
}

/// The bytes [`write_glb_pages`] writes to `path` (named in errors), so that they can be
/// built beside other work.
pub fn glb_bytes(path: &Path, mesh: &Mesh, textures: &[EncodedTexture]) -> Result<Vec<u8>> {
    for t in textures {
        if t.mime != "image/png" && t.mime != "image/jpeg" {
            return Err(Error::at_element(
                path,
                "texture",
                format!("glTF embeds PNG or JPEG textures only, not {}", t.mime),
            ));
        }
    }
    let pages = match &mesh.uv {
        Some(_) => textures.len().max(1),
        None => 1,
    };
    let page_of = |f: usize| match &mesh.uv {
        Some(uv) if pages > 1 => (uv.face_page(f) as usize).min(pages - 1),
        _ => 0,
    };
    // One output vertex per distinct (position, uv) pair; indices per page. A UV belongs to
    // one chart, so to one page: the page it is moved from.
    // FxHash rather than SipHash, a cheaper hash for millions of corners: the map is only
    // looked up (ids follow first use), so the hash changes nothing in the file.
    let mut remap: rustc_hash::FxHashMap<(u32, u32), u32> = Default::default();
    remap.reserve(
        mesh.uv
            .as_ref()
            .map_or(mesh.positions.len(), |uv| uv.coords.len()),
    );
    let mut src: Vec<(u32, u32)> = Vec::new();
    let mut src_page: Vec<u32> = Vec::new();
    let mut indices: Vec<Vec<u32>> = vec![Vec::new(); pages];
    for (f, face) in mesh.faces.iter().enumerate() {
        let p = page_of(f);
        for (k, vid) in face.iter().enumerate() {
            let key = (vid.0, mesh.uv.as_ref().map_or(0, |uv| uv.faces[f][k]));
            let next = src.len() as u32;
            let id = *remap.entry(key).or_insert_with(|| {
                src.push(key);
                src_page.push(p as u32);
                next
            });
            indices[p].push(id);
        }
    }
    let normals: Vec<Vector3<f32>> = match &mesh.normals {
        Some(n) => n.clone(),
        None => mesh.vertex_normals().iter().map(|n| n.cast()).collect(),
    };
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, bytes: &[u8], target: Option<u32>| -> usize {
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        bin.extend_from_slice(bytes);
        views.push(v);
        views.len() - 1
    };
    const ARRAY_BUFFER: u32 = 34962;
    const ELEMENT_ARRAY_BUFFER: u32 = 34963;

    // Positions (f32, with the min/max glTF requires).
    let pos: Vec<[f32; 3]> = src
        .iter()
        .map(|&(v, _)| mesh.positions[v as usize].coords.cast::<f32>().into())
        .collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &pos {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let view = push_view(
        &mut bin,
        &f32_bytes(pos.iter().flatten()),
        Some(ARRAY_BUFFER),
    );
    accessors.push(
        json!({"bufferView": view, "componentType": 5126, "count": pos.len(),
        "type": "VEC3", "min": lo, "max": hi}),
    );
    let mut attributes = json!({"POSITION": 0});

    // Normals must be unit length; a vertex with no defined normal gets +Z.
    let nrm: Vec<[f32; 3]> = src
        .iter()
        .map(|&(v, _)| {
            let n = normals[v as usize];
            let l = n.norm();
            if l > 0.5 {
                (n / l).into()
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect();
    let view = push_view(
        &mut bin,
        &f32_bytes(nrm.iter().flatten()),
        Some(ARRAY_BUFFER),
    );
    accessors.push(
        json!({"bufferView": view, "componentType": 5126, "count": nrm.len(), "type": "VEC3"}),
    );
    attributes["NORMAL"] = json!(accessors.len() - 1);

    if let Some(uv) = &mesh.uv {
        // glTF's texture origin is the top-left corner: flip v.
        let t: Vec<[f32; 2]> = src
            .iter()
            .zip(&src_page)
            .map(|(&(_, t), &p)| {
                let c = uv.coords[t as usize];
                [c.x - p as f32, 1.0 - c.y]
            })
            .collect();
        let view = push_view(&mut bin, &f32_bytes(t.iter().flatten()), Some(ARRAY_BUFFER));
        accessors.push(
            json!({"bufferView": view, "componentType": 5126, "count": t.len(), "type": "VEC2"}),
        );
        attributes["TEXCOORD_0"] = json!(accessors.len() - 1);
    }
    let mut primitives = Vec::new();
    for list in &indices {
        if list.is_empty() && pages > 1 {
            continue; // a page with no face (glTF accessors need at least one element)
        }
        let idx_bytes: Vec<u8> = list.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = push_view(&mut bin, &idx_bytes, Some(ELEMENT_ARRAY_BUFFER));
        accessors.push(json!({"bufferView": view, "componentType": 5125, "count": list.len(), "type": "SCALAR"}));
        primitives.push(
            json!({"attributes": attributes.clone(), "indices": accessors.len() - 1, "mode": 4}),
        );
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": concat!("scantex ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
    });
    if let (false, Some(_)) = (textures.is_empty(), &mesh.uv) {
        let (mut images, mut texs, mut materials) = (Vec::new(), Vec::new(), Vec::new());
        let mut k = 0;
        for (p, tex) in textures.iter().enumerate().take(pages) {
            if indices[p].is_empty() && pages > 1 {
                continue;
            }
            let view = push_view(&mut bin, &tex.bytes, None);
            images.push(json!({"bufferView": view, "mimeType": tex.mime}));
            texs.push(json!({"sampler": 0, "source": k}));
            materials.push(json!({
                "pbrMetallicRoughness": {"baseColorTexture": {"index": k}, "metallicFactor": 0.0, "roughnessFactor": 1.0},
                "doubleSided": false
            }));
            primitives[k]["material"] = json!(k);
            k += 1;
        }
        doc["images"] = json!(images);
        // Linear filtering with mipmaps, clamped: charts must not wrap around the atlas.
        doc["samplers"] =
            json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}]);
        doc["textures"] = json!(texs);
        doc["materials"] = json!(materials);
    }
    doc["meshes"] = json!([{"primitives": primitives}]);
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    doc["buffers"] = json!([{"byteLength": bin.len()}]);
    doc["bufferViews"] = json!(views);
    doc["accessors"] = json!(accessors);

    let mut js = serde_json::to_vec(&doc).expect("JSON of plain values always serialises");
    while !js.len().is_multiple_of(4) {
        js.push(b' ');
    }
    let total = 12 + 8 + js.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((js.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&js);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&bin);
    Ok(out)
}

fn f32_bytes<'a>(v: impl Iterator<Item = &'a f32>) -> Vec<u8> {
    v.flat_map(|f| f.to_le_bytes()).collect()
}

/// The accessor formats the reader is asked for: the `gltf` crate reads an attribute as the
/// type its semantic implies and only debug-asserts that the accessor holds it (found by
/// fuzzing: `fuzz_gltf_normals_of_the_wrong_type`), so a VEC2 normal would be read out of step.
fn check_formats(path: &Path, elem: &str, prim: &gltf::Primitive) -> Result<()> {
    use gltf::accessor::{DataType as D, Dimensions as N};
    use gltf::Semantic as S;
    let wrong = |what: &str, a: &gltf::Accessor, want: &str| {
        Err(Error::at_element(
            path,
            elem,
            format!(
                "{what} accessor {} holds {} {:?} of {:?}; glTF requires {want}",
                a.index(),
                a.count(),
                a.dimensions(),
                a.data_type()
            ),
        ))
    };
    for (semantic, a) in prim.attributes() {
        // glTF requires count >= 1; the crate computes `count - 1` unchecked (found by
        // fuzzing: `fuzz_gltf_accessor_with_no_elements`).
        if a.count() == 0 {
            return wrong(&format!("{semantic:?}"), &a, "at least one element");
        }
        let (d, t) = (a.dimensions(), a.data_type());
        match semantic {
            S::Positions | S::Normals if !(d == N::Vec3 && t == D::F32) => {
                return wrong(&format!("{semantic:?}"), &a, "VEC3 of F32");
            }
            S::TexCoords(_) if !(d == N::Vec2 && matches!(t, D::F32 | D::U8 | D::U16)) => {
                return wrong("TEXCOORD", &a, "VEC2 of F32, U8 or U16");
            }
            S::Colors(_)
                if !(matches!(d, N::Vec3 | N::Vec4) && matches!(t, D::F32 | D::U8 | D::U16)) =>
            {
                return wrong("COLOR", &a, "VEC3 or VEC4 of F32, U8 or U16");
            }
            _ => {}
        }
    }
    if let Some(a) = prim.indices() {
        if a.count() == 0
            || !(a.dimensions() == N::Scalar && matches!(a.data_type(), D::U8 | D::U16 | D::U32))
        {
            return wrong("indices", &a, "SCALAR of U8, U16 or U32");
        }
    }
    Ok(())
}

/// A GLB whose header declares fewer bytes than the header itself: the `gltf` crate subtracts
/// the header's size from that length unchecked (gltf 1.4.1, `Glb::from_slice`), which panics
/// where overflow is checked (found by fuzzing: `fuzz_glb_length_shorter_than_its_header`).
fn check_glb_length(path: &Path, bytes: &[u8]) -> Result<()> {
    if bytes.len() >= 12 && bytes.starts_with(b"glTF") {
        let declared = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
        if declared < 12 {
            return Err(Error::parse(
                path,
                crate::error::Location::Byte(8),
                format!("GLB header declares {declared} bytes, fewer than its own 12"),
            ));
        }
    }
    Ok(())
}

/// The `gltf` crate's validation indexes the accessor of every primitive's POSITION before it
/// checks that the accessor exists (gltf-json 1.4.1, `primitive_validate_hook`), and panics on
/// a dangling index (found by fuzzing: `fuzz_gltf_dangling_position_accessor`). Checked here
/// first, so the error names the primitive.
fn check_position_accessors(path: &Path, root: &gltf::json::Root) -> Result<()> {
    use gltf::json::validation::Checked;
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let pos = prim
                .attributes
                .get(&Checked::Valid(gltf::json::mesh::Semantic::Positions));
            if let Some(i) = pos {
                if i.value() >= root.accessors.len() {
                    return Err(Error::at_element(
                        path,
                        format!("mesh {m} primitive {p}"),
                        format!(
                            "POSITION names accessor {}, but the file has {} accessors",
                            i.value(),
                            root.accessors.len()
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The file a relative buffer URI names, or `None` when the URI has a scheme (`data:`, `file:`)
/// or its escapes do not decode to UTF-8.
fn relative_uri_path(uri: &str) -> Option<String> {
    if uri.contains(':') {
        return None;
    }
    percent_decode(uri)
}

/// Percent escapes decoded (`my%20texture.png`) as the `gltf` crate does; `None` when the result
/// is not UTF-8.
fn percent_decode(uri: &str) -> Option<String> {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (
            b[i],
            b.get(i + 1).copied().and_then(hex),
            b.get(i + 2).copied().and_then(hex),
        ) {
            (b'%', Some(hi), Some(lo)) => {
                out.push((hi * 16 + lo) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

/// Relative buffer URIs whose percent escapes are not UTF-8 are refused here: the `gltf` crate
/// unwraps that decoding and would panic (found by fuzzing).
fn check_buffer_uris(path: &Path, doc: &gltf::Document) -> Result<()> {
    for b in doc.buffers() {
        if let gltf::buffer::Source::Uri(uri) = b.source() {
            if !uri.contains(':') && relative_uri_path(uri).is_none() {
                return Err(Error::at_element(
                    path,
                    format!("buffer {}", b.index()),
                    format!("URI {uri:?} has percent escapes that are not UTF-8"),
                ));
            }
        }
    }
    Ok(())
}

/// A buffer that could not be loaded, named by its index and, for an external file, its path:
/// the crate's own error gives only the operating system's words.
fn buffer_error(path: &Path, base: &Path, doc: &gltf::Document, e: gltf::Error) -> Error {
    for b in doc.buffers() {
        if let gltf::buffer::Source::Uri(uri) = b.source() {
            if uri.starts_with("data:") {
                continue;
            }
            let Some(name) = relative_uri_path(uri) else {
                continue;
            };
            let file = base.join(name);
            match std::fs::metadata(&file) {
                Err(io) => {
                    return Error::at_element(
                        path,
                        format!("buffer {} ({uri})", b.index()),
                        format!("cannot read {}: {io}", file.display()),
                    )
                }
                Ok(m) if (m.len() as usize) < b.length() => {
                    return Error::at_element(
                        path,
                        format!("buffer {} ({uri})", b.index()),
                        format!(
                            "{} holds {} bytes but the buffer declares {}: truncated",
                            file.display(),
                            m.len(),
                            b.length()
                        ),
                    )
                }
                Ok(_) => {}
            }
        }
    }
    Error::at_element(path, "buffers", e.to_string())
}
