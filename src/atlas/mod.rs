//! Stage 1, the atlas: chart segmentation into disks ([`segment`]), a flip-free start per chart
//! (LSCM, projection or mean-value embedding) with Sander's stretch measures ([`param`]), the
//! paper's view-weighted L2 stretch minimisation with the shape barrier ([`optimize`]),
//! [`flatten_all`], which splits charts whose stretch stays too high, and packing of the charts
//! into atlas pages by rasterised footprints ([`pack`]). [`parameterize`] runs it all;
//! [`measure`] reports on any mesh's existing UVs.

pub mod density;
pub mod optimize;
pub mod pack;
pub mod param;
pub mod segment;
#[cfg(test)]
mod test_meshes;
pub(crate) mod texels;

use crate::error::MeshElement;
use crate::mesh::{Mesh, UnionFind};
use nalgebra::Vector2;
use param::ChartMap;
use rustc_hash::FxHashMap;
use segment::{is_disk, split, Adjacency, SegmentOptions};
use texels::TexelMap;

/// Options for [`flatten_all`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlattenOptions {
    /// Segmentation options.
    pub segment: SegmentOptions,
    /// Stretch minimisation (view weight, shape barrier).
    pub stretch: optimize::StretchOptions,
    /// A chart whose own L2 stretch after minimisation exceeds this is split in two and both
    /// halves flattened again. Default: 1.25.
    pub max_chart_stretch: f64,
    /// Without a view weight, a chart whose starting map already has L2 stretch at most this
    /// is kept as it is (the minimisation would gain less than the difference). Default: 1.001.
    pub skip_below: f64,
    /// A chart starting at most this stretched gets a short minimisation (60 L-BFGS
    /// iterations, 2 sweeps). Default: 1.01.
    pub light_below: f64,
    /// A chart (of more than one face) whose starting map has L2 stretch above this is split
    /// without minimising it: minimisation would not bring it within `max_chart_stretch`.
    /// Default: 10. Slivers give starts of 3-6 that minimise to about 1; splitting everything
    /// above 2.5 at once had made 6,846 charts of a sliver-rich 1.48M-face mesh, 2,776 now
    /// (`scantex param` at 8192; docs/decisions.md, "Charts split before minimising").
    pub split_above: f64,
}

impl Default for FlattenOptions {
    fn default() -> Self {
        FlattenOptions {
            segment: SegmentOptions::default(),
            stretch: optimize::StretchOptions::default(),
            max_chart_stretch: 1.25,
            skip_below: 1.001,
            light_below: 1.01,
            split_above: 10.0,
        }
    }
}

/// Segments `mesh` and flattens every chart, splitting charts until each one's L2 stretch is
/// at most `max_chart_stretch` (a single triangle is always an isometry, so this ends).
/// A connected component that is already a disk is first tried whole: if its minimised
/// stretch is within `max_chart_stretch` it stays one chart (no seams at all).
/// Components are processed in parallel; the result does not depend on the thread count.
pub fn flatten_all(mesh: &Mesh, opts: &FlattenOptions) -> Vec<ChartMap> {
    flatten_all_with(mesh, &Adjacency::new(mesh), opts)
}

/// [`flatten_all`] with the mesh's adjacency already built.
pub fn flatten_all_with(mesh: &Mesh, adj: &Adjacency, opts: &FlattenOptions) -> Vec<ChartMap> {
    flatten_all_reporting(mesh, adj, opts, &crate::progress::Silent)
}

/// [`flatten_all_with`], reporting the segmented charts flattened as `progress`'s "atlas"
/// stage.
fn flatten_all_reporting(
    mesh: &Mesh,
    adj: &Adjacency,
    opts: &FlattenOptions,
    progress: &dyn crate::progress::Progress,
) -> Vec<ChartMap> {
    use rayon::prelude::*;
    let charts = segment::segment_with(mesh, adj, &opts.segment).charts;
    progress.start("atlas", charts.len() as u64);
    // Group the charts by connected component (through crossable edges), in chart order.
    let comp = components(mesh, adj);
    let mut groups: Vec<(u32, Vec<Vec<crate::mesh::FaceId>>)> = Vec::new();
    let mut slot: FxHashMap<u32, usize> = FxHashMap::default();
    for c in charts {
        let k = comp[c[0].idx()];
        let i = *slot.entry(k).or_insert_with(|| {
            groups.push((k, Vec::new()));
            groups.len() - 1
        });
        groups[i].1.push(c);
    }
    // One task per group and per chart (`with_max_len(1)`): rayon's adaptive split hands
    // each core a run of items and cannot take back part of a run, so a run holding the
    // largest charts leaves the other core idle.
    let per_group: Vec<Vec<ChartMap>> = groups
        .into_par_iter()
        .with_max_len(1)
        .map(|(_, group)| {
            if group.len() > 1 {
                let whole: Vec<crate::mesh::FaceId> = group.iter().flatten().copied().collect();
                if is_disk(mesh, adj, &whole) {
                    let mut map = param::flatten(mesh, &whole);
                    optimize::optimize(mesh, &mut map, &opts.stretch);
                    let s = param::stretch(mesh, std::slice::from_ref(&map));
                    if s.l2 <= opts.max_chart_stretch && s.flipped == 0 && s.zero_area == 0 {
                        progress.advance(group.len() as u64);
                        return vec![map];
                    }
                }
            }
            // Charts of one component in parallel too: a scan is often one big component.
            group
                .into_par_iter()
                .with_max_len(1)
                .flat_map_iter(|c| {
                    let maps = flatten_chart(mesh, adj, c, opts);
                    progress.advance(1);
                    maps
                })
                .collect()
        })
        .collect();
    progress.finish();
    per_group.into_iter().flatten().collect()
}

/// Connected component of each face through crossable edges.
fn components(mesh: &Mesh, adj: &Adjacency) -> Vec<u32> {
    let mut comp = vec![u32::MAX; mesh.num_faces()];
    let mut next = 0;
    for seed in 0..mesh.num_faces() {
        if comp[seed] != u32::MAX {
            continue;
        }
        comp[seed] = next;
        let mut stack = vec![seed];
        while let Some(f) = stack.pop() {
            for g in adj.neighbours[f].iter().flatten() {
                if comp[*g as usize] == u32::MAX {
                    comp[*g as usize] = next;
                    stack.push(*g as usize);
                }
            }
        }
        next += 1;
    }
    comp
}

/// Flattens one chart, splitting it while its stretch is too high. The two halves of a split
/// are flattened side by side (a large chart that splits many times is otherwise one long
/// serial task at the end of the stage); the result lists the first half's charts before the
/// second's, a half that is not a disk as its second part's charts before its first's.
fn flatten_chart(
    mesh: &Mesh,
    adj: &Adjacency,
    chart: Vec<crate::mesh::FaceId>,
    opts: &FlattenOptions,
) -> Vec<ChartMap> {
    let mut map = param::flatten(mesh, &chart);
    let start = param::stretch(mesh, std::slice::from_ref(&map));
    // Charts that already flatten almost isometrically need no minimisation, and charts
    // far above the split threshold are split at once (docs/decisions.md).
    let hopeless = start.l2 > opts.split_above && chart.len() > 1;
    if !hopeless && (start.l2 > opts.skip_below || opts.stretch.view_dir.is_some()) {
        // Nearly isometric starts converge in a few dozen iterations; the full budget goes
        // to charts with real stretch to remove.
        let mut so = opts.stretch;
        if start.l2 <= opts.light_below {
            so.iterations = so.iterations.min(60);
            so.sweeps = so.sweeps.min(2);
        }
        optimize::optimize(mesh, &mut map, &so);
    }
    let s = param::stretch(mesh, std::slice::from_ref(&map));
    if !(chart.len() > 1 && (s.l2 > opts.max_chart_stretch || s.flipped > 0 || s.zero_area > 0)) {
        return vec![map];
    }
    drop(map);
    let (a, b) = split(adj, &chart);
    drop(chart);
    // Split halves can be non-disks: split again (second part first, as the serial stack
    // this replaces did, so that the charts and the atlas keep their order and bytes).
    let parts = |part: Vec<crate::mesh::FaceId>| -> Vec<Vec<crate::mesh::FaceId>> {
        if is_disk(mesh, adj, &part) {
            vec![part]
        } else {
            let (x, y) = split(adj, &part);
            vec![y, x]
        }
    };
    let run = |ps: Vec<Vec<crate::mesh::FaceId>>| -> Vec<ChartMap> {
        use rayon::prelude::*;
        ps.into_par_iter()
            .with_max_len(1)
            .flat_map_iter(|p| flatten_chart(mesh, adj, p, opts))
            .collect()
    };
    let (mut first, second) = rayon::join(|| run(parts(a)), || run(parts(b)));
    first.extend(second);
    first
}

/// One chart's place on the atlas page: its faces (those that own texels, by index) and the
/// bounding rectangle of their texels.
#[derive(Debug, Clone, PartialEq)]
pub struct ChartRect {
    /// Faces of the chart that rasterise on the page, in index order.
    pub faces: Vec<u32>,
    /// Left column of the rectangle.
    pub x0: usize,
    /// Top row of the rectangle.
    pub y0: usize,
    /// Width in texels.
    pub w: usize,
    /// Height in texels.
    pub h: usize,
}

/// The atlas as every stage after the first sees it: the page size, the charts, each face's
/// chart and the texel raster (which face owns each texel), built once from the mesh's UVs.
/// Charts are numbered in the order of their first face that owns texels; faces with no texel
/// on the page have no chart (`u32::MAX`).
pub struct Atlas {
    /// Page side in texels.
    pub size: u32,
    /// The charts on the page.
    pub charts: Vec<ChartRect>,
    /// Chart of each face (index into `charts`), `u32::MAX` for faces with no texel.
    pub face_chart: Vec<u32>,
    pub(crate) texels: TexelMap,
}

impl Atlas {
    /// The atlas of UVs a mesh arrived with (from any tool): charts are the UV islands, faces
    /// joined through shared texture-coordinate indices. Page 0 (u, v in [0, 1]) only.
    pub fn from_uvs(mesh: &Mesh, size: u32) -> crate::Result<Atlas> {
        let uv = mesh.uv.as_ref().ok_or_else(|| {
            crate::Error::mesh(MeshElement::Whole, "it has no texture coordinates")
        })?;
        let island = uv_islands(uv);
        Atlas::with_charts(mesh, size, &island)
    }

    /// The atlas of `mesh`'s UVs where `chart_of` gives each face's chart under any numbering
    /// (stage 1's, or UV islands).
    fn with_charts(mesh: &Mesh, size: u32, chart_of: &[u32]) -> crate::Result<Atlas> {
        Atlas::with_charts_where(mesh, size, chart_of, &|_| true)
    }

    /// [`Atlas::with_charts`] for the faces `on_page` accepts only (the others have no chart).
    fn with_charts_where(
        mesh: &Mesh,
        size: u32,
        chart_of: &[u32],
        on_page: &(dyn Fn(usize) -> bool + Sync),
    ) -> crate::Result<Atlas> {
        if !SIZE_RANGE.contains(&size) {
            return Err(crate::Error::option(
                "size",
                format!("atlas size {size} must lie in {SIZE_RANGE:?}"),
            ));
        }
        let texels = TexelMap::new(mesh, size, on_page)?;
        let mut index_of = FxHashMap::default();
        let mut charts: Vec<ChartRect> = Vec::new();
        let mut face_chart = vec![u32::MAX; mesh.num_faces()];
        for (f, slot) in face_chart.iter_mut().enumerate() {
            let Some(r) = &texels.faces[f] else {
                continue;
            };
            let ((r0, r1), (c0, c1)) = (r.rows, r.cols);
            let ci = *index_of.entry(chart_of[f]).or_insert_with(|| {
                charts.push(ChartRect {
                    faces: Vec::new(),
                    x0: c0,
                    y0: r0,
                    w: c1 + 1,
                    h: r1 + 1,
                });
                charts.len() as u32 - 1
            });
            *slot = ci;
            let ch = &mut charts[ci as usize];
            ch.faces.push(f as u32);
            // w and h hold the exclusive right and bottom edges until the end.
            ch.x0 = ch.x0.min(c0);
            ch.y0 = ch.y0.min(r0);
            ch.w = ch.w.max(c1 + 1);
            ch.h = ch.h.max(r1 + 1);
        }
        for ch in &mut charts {
            ch.w -= ch.x0;
            ch.h -= ch.y0;
        }
        Ok(Atlas {
            size,
            charts,
            face_chart,
            texels,
        })
    }

    /// Face owning texel `i` (row-major), if any.
    #[inline]
    pub fn owner(&self, i: usize) -> Option<u32> {
        let f = self.texels.owner[i];
        (f != texels::NO_FACE).then_some(f)
    }

    /// Barycentric coordinates of texel (x, y)'s centre in face `f`'s triangle (unclamped),
    /// if `f` lies on the page.
    pub fn barycentric(&self, f: usize, x: usize, y: usize) -> Option<[f64; 3]> {
        self.texels.faces[f].as_ref().map(|r| r.bary(x, y))
    }

    /// Length on the surface of one texel of face `f`, scene units, if `f` lies on the page.
    pub fn texel_length(&self, f: usize) -> Option<f64> {
        self.texels.faces[f].as_ref().map(|r| r.texel_len)
    }

    /// Texels per unit of surface length on the page: the median over the faces on it (1 when
    /// none is).
    pub fn texels_per_unit(&self) -> f64 {
        let mut d: Vec<f64> = (0..self.face_chart.len())
            .filter_map(|f| self.texel_length(f))
            .map(|l| 1.0 / l)
            .filter(|v| v.is_finite() && *v > 0.0)
            .collect();
        if d.is_empty() {
            return 1.0;
        }
        let mid = d.len() / 2;
        *d.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// Corners of face `f` in texel coordinates (x right, y down), if `f` lies on the page.
    pub fn face_texels(&self, f: usize) -> Option<[nalgebra::Vector2<f64>; 3]> {
        self.texels.faces[f].as_ref().map(|r| r.t)
    }

    /// Texel rows and columns (inclusive) face `f` may own, if it lies on the page.
    pub fn face_rect(&self, f: usize) -> Option<((usize, usize), (usize, usize))> {
        self.texels.faces[f].as_ref().map(|r| (r.rows, r.cols))
    }

    /// The texels face `f` owns (row-major indices, in row order); none if it is not on the
    /// page.
    pub fn owned_texels(&self, f: usize) -> impl Iterator<Item = usize> + '_ {
        let n = self.size as usize;
        let rect = self.face_rect(f);
        rect.into_iter()
            .flat_map(move |((r0, r1), (c0, c1))| {
                (r0..=r1).flat_map(move |y| (c0..=c1).map(move |x| y * n + x))
            })
            .filter(move |&i| self.owner(i) == Some(f as u32))
    }
}

/// Options for [`parameterize`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AtlasOptions {
    /// Charts and stretch.
    pub flatten: FlattenOptions,
    /// Atlas size, gutter and texel density.
    pub pack: pack::PackOptions,
    /// Give charts texels by their weighted stretch energy ([`optimize::chart_scales`]) rather
    /// than one density for all. Default: true.
    pub budget_by_energy: bool,
}

impl Default for AtlasOptions {
    fn default() -> Self {
        AtlasOptions {
            flatten: FlattenOptions::default(),
            pack: pack::PackOptions::default(),
            budget_by_energy: true,
        }
    }
}

/// Atlas sizes (texels per side) [`AtlasOptions::validate`] accepts.
pub const SIZE_RANGE: std::ops::RangeInclusive<u32> = 16..=32768;

impl AtlasOptions {
    /// Checks the options' ranges; the error says which option is out of range.
    pub fn validate(&self) -> crate::Result<()> {
        let s = &self.flatten.stretch;
        let bad = |o: &'static str, what: String| Err(crate::Error::option(o, what));
        if !(s.k > 1.0 && s.k.is_finite()) {
            return bad(
                "k",
                format!("k = {} must exceed 1 (w = 1 / (<N, V> + k))", s.k),
            );
        }
        if !(0.0..0.5).contains(&s.alpha) {
            return bad("alpha", format!("alpha = {} must lie in [0, 0.5)", s.alpha));
        }
        if let Some(v) = s.view_dir {
            if !(v.iter().all(|x| x.is_finite()) && v.norm() > 0.0) {
                return bad(
                    "view_dir",
                    format!("view direction {v:?} must be a non-zero finite vector"),
                );
            }
        }
        if !SIZE_RANGE.contains(&self.pack.size) {
            return bad(
                "size",
                format!("atlas size {} must lie in {SIZE_RANGE:?}", self.pack.size),
            );
        }
        if 2 * self.pack.gutter + 1 >= self.pack.size {
            return bad(
                "gutter",
                format!(
                    "gutter {} leaves no room in a {}-texel atlas",
                    self.pack.gutter, self.pack.size
                ),
            );
        }
        if let Some(d) = self.pack.texels_per_unit {
            if !(d.is_finite() && d > 0.0) {
                return bad(
                    "texel_density",
                    format!("texel density {d} must be a positive number"),
                );
            }
        }
        if let Some(t) = self.pack.chart_texels {
            if !(t.is_finite() && t > 0.0) {
                return bad(
                    "chart_texels",
                    format!("chart texels {t} must be a positive number"),
                );
            }
        }
        if self.pack.max_pages == Some(0) {
            return bad(
                "pages",
                "at most 0 pages leaves nowhere to put a chart".into(),
            );
        }
        Ok(())
    }
}

/// What [`parameterize`] measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct AtlasReport {
    /// Number of charts.
    pub charts: usize,
    /// Stretch of the whole atlas (Sander's L2 and L-infinity, 2D area normalised to 3D area),
    /// with flipped and zero-area UV triangles.
    pub stretch: param::Stretch,
    /// Length of edges where two charts meet, over the length of all edges.
    pub seam_ratio: f64,
    /// Texels covered by charts over all texels (texel centres inside a UV triangle, all pages).
    pub utilisation: f64,
    /// Atlas pages (UDIM tiles 1001, 1002, ...).
    pub pages: u32,
    /// Texels covered by more than one chart (0 unless something is wrong).
    pub overlapping_texels: usize,
    /// Texels per unit of 3D length.
    pub texels_per_unit: f64,
    /// Seconds spent segmenting, flattening and minimising stretch.
    pub seconds_charts: f64,
    /// Seconds spent packing.
    pub seconds_pack: f64,
    /// Seconds spent measuring (rasterising the layout).
    pub seconds_measure: f64,
}

/// Stage 1: gives `mesh` texture coordinates in one atlas. The mesh is welded first (vertices
/// split along old UV seams are one surface again); its faces keep their order.
pub fn parameterize(mesh: &Mesh, opts: &AtlasOptions) -> crate::Result<(Mesh, AtlasReport)> {
    parameterize_reporting(mesh, opts, &crate::progress::Silent)
}

/// [`parameterize`], reporting the charts flattened to `progress`.
pub fn parameterize_reporting(
    mesh: &Mesh,
    opts: &AtlasOptions,
    progress: &dyn crate::progress::Progress,
) -> crate::Result<(Mesh, AtlasReport)> {
    let mut m = mesh.clone();
    m.uv = None;
    m.texture = None;
    m.weld();
    let (uv, _, report) = layout(&m, opts, progress)?;
    m.uv = Some(uv);
    Ok((m, report))
}

/// Stage 1 on one page: `mesh` (welded, as [`Mesh::weld`] leaves it) gains its atlas UVs,
/// and the [`Atlas`] that later stages borrow is built from stage 1's own charts. Options that
/// spread charts over several pages are refused; [`build_pages`] takes them.
pub fn build(mesh: Mesh, opts: &AtlasOptions) -> crate::Result<(Mesh, Atlas, AtlasReport)> {
    let (mesh, pages, report) = build_pages(mesh, opts)?;
    if pages.count() > 1 {
        return Err(crate::Error::option(
            "texel_density",
            format!(
                "the charts need {} pages at this density: build makes one",
                pages.count()
            ),
        ));
    }
    let atlas = pages.atlas(&mesh, 0)?;
    Ok((mesh, atlas, report))
}

/// Stage 1 as texturing runs it: `mesh` (welded, as [`Mesh::weld`] leaves it) gains its atlas
/// UVs on one or more pages (UDIM tiles: page `p` at u in `[p, p + 1]`), and [`Pages`] builds
/// each page's [`Atlas`] from stage 1's own charts when its turn comes.
pub fn build_pages(mesh: Mesh, opts: &AtlasOptions) -> crate::Result<(Mesh, Pages, AtlasReport)> {
    build_pages_reporting(mesh, opts, &crate::progress::Silent)
}

/// [`build_pages`], reporting the charts flattened to `progress` (the packing that follows
/// has no steps to count).
pub fn build_pages_reporting(
    mut mesh: Mesh,
    opts: &AtlasOptions,
    progress: &dyn crate::progress::Progress,
) -> crate::Result<(Mesh, Pages, AtlasReport)> {
    let (uv, face_chart, report) = layout(&mesh, opts, progress)?;
    let face_page =
        (report.pages > 1).then(|| (0..uv.faces.len()).map(|f| uv.face_page(f)).collect());
    mesh.uv = Some(uv);
    let pages = Pages {
        size: opts.pack.size,
        count: report.pages.max(1),
        face_chart,
        face_page,
    };
    Ok((mesh, pages, report))
}

/// The pages of an atlas and what builds each page's [`Atlas`]: one page's texel raster is
/// the size of the page, so texturing builds them one at a time.
pub struct Pages {
    size: u32,
    count: u32,
    face_chart: Vec<u32>,
    /// Each face's page; `None` when there is one page.
    face_page: Option<Vec<u32>>,
}

impl Pages {
    /// Number of pages (UDIM tiles 1001, 1002, ...).
    pub fn count(&self) -> u32 {
        self.count
    }

    /// The [`Atlas`] of page `page`. `mesh` is the mesh [`build_pages`] returned with its UVs
    /// moved so that this page lies at u in `[0, 1]` ([`place_page`]): every later stage reads
    /// texel positions from the mesh's UVs on page 0.
    pub fn atlas(&self, mesh: &Mesh, page: u32) -> crate::Result<Atlas> {
        match &self.face_page {
            None => Atlas::with_charts(mesh, self.size, &self.face_chart),
            Some(fp) => {
                Atlas::with_charts_where(mesh, self.size, &self.face_chart, &|f| fp[f] == page)
            }
        }
    }
}

/// Sets `mesh`'s texture coordinates to `original` (the coordinates [`build_pages`] gave it)
/// moved by `page` whole pages towards page 0, so that page `page` lies at u in `[0, 1]`.
/// Always from `original`: moving a coordinate below zero rounds it in f32, so moves made one
/// after another would not come back to the same bits.
pub fn place_page(mesh: &mut Mesh, original: &[nalgebra::Vector2<f32>], page: u32) {
    if let Some(uv) = &mut mesh.uv {
        let d = page as f32;
        for (c, o) in uv.coords.iter_mut().zip(original) {
            *c = nalgebra::Vector2::new(o.x - d, o.y);
        }
    }
}

/// Stage 1 for a mesh that keeps the UVs it arrived with (`texture --keep-uvs`): no new
/// layout, the [`Pages`] of its UV islands on one `size` page and the report [`measure`] gives.
/// `mesh` is welded, as [`Mesh::weld`] leaves it (as for [`build`]).
/// Texturing writes one page: faces whose UVs lie outside [0, 1] are refused.
pub fn keep(mesh: Mesh, size: u32) -> crate::Result<(Mesh, Pages, AtlasReport)> {
    let Some(uv) = &mesh.uv else {
        return Err(crate::Error::mesh(
            MeshElement::Whole,
            "--keep-uvs: it has no texture coordinates to keep",
        ));
    };
    let centroid = |f: usize| {
        let c = uv.faces[f].map(|i| uv.coords[i as usize]);
        (c[0] + c[1] + c[2]) / 3.0
    };
    let off_page = |f: usize| {
        let c = centroid(f);
        !((0.0..=1.0).contains(&c.x) && (0.0..=1.0).contains(&c.y))
    };
    if let Some(f) = (0..uv.faces.len()).find(|&f| off_page(f)) {
        let c = centroid(f);
        return Err(crate::Error::mesh(
            MeshElement::Face(f),
            format!(
                "--keep-uvs: it lies at texture coordinates ({}, {}), outside [0, 1] (another \
             UDIM page, or a repeating texture); texturing writes one page",
                c.x, c.y
            ),
        ));
    }
    if !SIZE_RANGE.contains(&size) {
        return Err(crate::Error::option(
            "size",
            format!("atlas size {size} must lie in {SIZE_RANGE:?}"),
        ));
    }
    // One island map for the atlas and the report.
    let islands = uv_islands(uv);
    let report = measure_with(&mesh, &Adjacency::new(&mesh), uv, &islands, size);
    let pages = Pages {
        size,
        count: 1,
        face_chart: islands,
        face_page: None,
    };
    Ok((mesh, pages, report))
}

/// Charts, flattening, stretch budget and packing of a welded mesh: the UVs, each face's chart
/// and the report.
fn layout(
    m: &Mesh,
    opts: &AtlasOptions,
    progress: &dyn crate::progress::Progress,
) -> crate::Result<(crate::mesh::UvMap, Vec<u32>, AtlasReport)> {
    opts.validate()?;
    let t0 = std::time::Instant::now();
    let adj = Adjacency::new(m);
    let maps = flatten_all_reporting(m, &adj, &opts.flatten, progress);
    let t1 = std::time::Instant::now();
    let scales = if opts.budget_by_energy {
        optimize::chart_scales(m, &maps, &opts.flatten.stretch)
    } else {
        vec![1.0; maps.len()]
    };
    let packed = pack::pack(m, &maps, &scales, &opts.pack)?;
    let t2 = std::time::Instant::now();
    let mut report = measure_with(m, &adj, &packed.uv, &packed.face_chart, opts.pack.size);
    report.texels_per_unit = packed.texels_per_unit;
    report.seconds_charts = (t1 - t0).as_secs_f64();
    report.seconds_pack = (t2 - t1).as_secs_f64();
    report.seconds_measure = t2.elapsed().as_secs_f64();
    Ok((packed.uv, packed.face_chart, report))
}

/// Measures the UV atlas a mesh already has (from any tool), as [`parameterize`] reports its
/// own: charts are the UV islands (faces joined through shared texture-coordinate indices),
/// stretch over the whole atlas, seams, and utilisation and overlaps at `size` texels per page
/// (UDIM pages from the integer part of u). Times are zero.
pub fn measure(mesh: &Mesh, size: u32) -> crate::Result<AtlasReport> {
    let Some(uv) = &mesh.uv else {
        return Err(crate::Error::mesh(
            MeshElement::Whole,
            "it has no texture coordinates",
        ));
    };
    if !(1..=32768).contains(&size) {
        return Err(crate::Error::option(
            "size",
            format!("atlas size {size} must lie in 1..=32768"),
        ));
    }
    let face_chart = uv_islands(uv);
    let mut m = mesh.clone();
    m.weld();
    let adj = Adjacency::new(&m);
    Ok(measure_with(&m, &adj, uv, &face_chart, size))
}

/// Each face's UV island (faces joined through shared texture-coordinate indices), numbered in
/// the order of their first face.
pub fn uv_islands(uv: &crate::mesh::UvMap) -> Vec<u32> {
    let mut sets = UnionFind::new(uv.coords.len());
    for t in &uv.faces {
        sets.union(t[0] as usize, t[1] as usize);
        sets.union(t[0] as usize, t[2] as usize);
    }
    let mut id: FxHashMap<usize, u32> = FxHashMap::default();
    uv.faces
        .iter()
        .map(|t| {
            let r = sets.find(t[0] as usize);
            let n = id.len() as u32;
            *id.entry(r).or_insert(n)
        })
        .collect()
}

fn measure_with(
    m: &Mesh,
    adj: &Adjacency,
    uv: &crate::mesh::UvMap,
    face_chart: &[u32],
    size: u32,
) -> AtlasReport {
    let mut stretch = param::stretch_uv(m, uv);
    // A mirrored island is not a fold: count as flipped the triangles whose orientation differs
    // from the majority (by area) of their island.
    let signed: Vec<f64> = uv
        .faces
        .iter()
        .map(|t| param::uv_area(t.map(|i| uv.coords[i as usize].cast::<f64>())))
        .collect();
    let mut island = vec![
        0.0;
        face_chart
            .iter()
            .map(|&c| c as usize + 1)
            .max()
            .unwrap_or(0)
    ];
    for (a, &c) in signed.iter().zip(face_chart) {
        island[c as usize] += a;
    }
    stretch.flipped = signed
        .iter()
        .zip(face_chart)
        .filter(|(a, &c)| **a != 0.0 && (**a > 0.0) != (island[c as usize] > 0.0))
        .count();
    let pages = (0..uv.faces.len())
        .map(|f| uv.face_page(f) + 1)
        .max()
        .unwrap_or(1);
    let (covered, overlapping) = pack::coverage_counts(uv, face_chart, size, pages);
    let (mut seam, mut total) = (0.0, 0.0);
    for (f, face) in m.faces.iter().enumerate() {
        for k in 0..3 {
            let len = (m.positions[face[(k + 1) % 3].idx()] - m.positions[face[k].idx()]).norm();
            match adj.neighbours[f][k] {
                // Interior edges are seen from both sides: count each once.
                Some(g) if (g as usize) > f => {
                    total += len;
                    if face_chart[g as usize] != face_chart[f] {
                        seam += len;
                    }
                }
                Some(_) => {}
                None => total += len,
            }
        }
    }
    AtlasReport {
        charts: face_chart
            .iter()
            .map(|&c| c as usize + 1)
            .max()
            .unwrap_or(0),
        stretch,
        seam_ratio: if total > 0.0 { seam / total } else { 0.0 },
        utilisation: covered as f64 / (size as usize * size as usize * pages as usize) as f64,
        pages,
        overlapping_texels: overlapping,
        texels_per_unit: 0.0,
        seconds_charts: 0.0,
        seconds_pack: 0.0,
        seconds_measure: 0.0,
    }
}

/// A picture of the layout: each UV triangle filled with its L2 stretch (green 1, yellow 1.5,
/// red 2 or more), on dark grey. `size` pixels square.
pub fn layout_picture(mesh: &Mesh, size: u32) -> image::RgbImage {
    let mut img = image::RgbImage::from_pixel(size, size, image::Rgb([40, 40, 40]));
    let Some(uv) = &mesh.uv else { return img };
    let n = size as f64;
    // Per-triangle stretch at the atlas's common scale, normalised over the whole atlas.
    let (mut a2, mut a3) = (0.0, 0.0);
    for (f, t) in uv.faces.iter().enumerate() {
        let q = t.map(|i| uv.coords[i as usize].cast::<f64>());
        a2 += param::uv_area(q).abs();
        a3 += mesh.face_area(crate::mesh::FaceId(f as u32));
    }
    let k = (a2 / a3.max(1e-300)).sqrt();
    for (f, t) in uv.faces.iter().enumerate() {
        let q = t.map(|i| uv.coords[i as usize].cast::<f64>());
        let (l2, _, _) = param::triangle_stretch(
            mesh.triangle(crate::mesh::FaceId(f as u32)),
            q.map(|v| v / k),
        );
        let x = ((l2 - 1.0) / 1.0).clamp(0.0, 1.0) as f32;
        let colour = image::Rgb([
            (255.0 * (2.0 * x).min(1.0)) as u8,
            (255.0 * (2.0 - 2.0 * x).min(1.0)) as u8,
            40,
        ]);
        let p = q.map(|v| Vector2::new(v.x * n, (1.0 - v.y) * n));
        pack::raster_triangle(p, size, size, |x, y| img.put_pixel(x, y, colour));
    }
    img
}

#[cfg(test)]
mod tests {
    use super::test_meshes::{
        faces_where, icosphere, polar_grid, texel_density, two_copies, with_fins, with_holes,
    };
    use super::*;
    use nalgebra::{Point3, Vector3};

    /// What a [`Recorder`] saw: (stage, total) per start, steps advanced, finishes.
    type Recorded = (Vec<(String, u64)>, u64, usize);

    /// Records what a stage reports.
    #[derive(Default)]
    struct Recorder(std::sync::Mutex<Recorded>);

    impl crate::progress::Progress for Recorder {
        fn start(&self, stage: &str, total: u64) {
            self.0.lock().unwrap().0.push((stage.to_string(), total));
        }
        fn advance(&self, n: u64) {
            self.0.lock().unwrap().1 += n;
        }
        fn finish(&self) {
            self.0.lock().unwrap().2 += 1;
        }
    }

    /// The atlas's bar counts the segmented charts and ends full, whether a component is
    /// kept whole (a disk folded at a right angle: two charts, one flat piece) or charted
    /// (the torus, with splits), and the layout is the one an unreported build makes.
    #[test]
    fn atlas_progress_reaches_its_total() {
        let folded = polar_grid(6, 24, |r, k| {
            let a = std::f64::consts::TAU * k as f64 / 24.0;
            let (x, y) = (r as f64 * a.cos(), r as f64 * a.sin());
            if x > 0.0 {
                Point3::new(0.0, y, x)
            } else {
                Point3::new(x, y, 0.0)
            }
        });
        let (torus, _) = crate::sample::dented_torus(60, 24, (8, 8));
        for mesh in [folded, torus] {
            let opts = AtlasOptions::default();
            let rec = Recorder::default();
            let (reported, _, _) = build_pages_reporting(mesh.clone(), &opts, &rec).unwrap();
            let (quiet, _, _) = build_pages(mesh, &opts).unwrap();
            assert!(reported.uv == quiet.uv);
            let (starts, advanced, finished) = rec.0.into_inner().unwrap();
            assert_eq!(starts.len(), 1, "{starts:?}");
            assert_eq!(starts[0].0, "atlas");
            assert!(starts[0].1 > 0);
            assert_eq!(advanced, starts[0].1);
            assert_eq!(finished, 1);
        }
    }

    /// A chart of 18 faces from a sliver-rich mesh (the corset after three sqrt(3) steps
    /// without smoothing: slivers along its boundary), whose flip-free start has L2 stretch
    /// 3.5. Minimised, it is one chart within the bound; split at once at starts above 2.5 (the
    /// old rule), it became three. Such charts multiplied a 1.48M-face mesh's charts by 2.5.
    #[test]
    fn sliver_charts_are_minimised_before_they_are_split() {
        let positions: Vec<Point3<f64>> = [
            [
                0.011478147469460964,
                0.010276311077177525,
                -0.00013822864275425673,
            ],
            [
                0.011383814737200737,
                0.010267363861203194,
                -0.0004126916464883834,
            ],
            [
                0.011626494117081165,
                0.010298081673681736,
                0.00016398286970797926,
            ],
            [
                0.011549483053386211,
                0.01029337290674448,
                -0.0001723236928228289,
            ],
            [
                0.011255905032157898,
                0.010272610001266003,
                -0.000586534442845732,
            ],
            [
                0.011367559432983398,
                0.010285794734954834,
                -0.000373915012460202,
            ],
            [
                0.01116575300693512,
                0.010309109464287758,
                -0.0006938521401025355,
            ],
            [
                0.011304480023682117,
                0.010351063683629036,
                -0.0003611674765124917,
            ],
            [
                0.011458777822554111,
                0.010271962732076645,
                -0.0002896642545238137,
            ],
            [
                0.011123813688755035,
                0.010232408531010151,
                -0.0009275226038880646,
            ],
            [
                0.01128815021365881,
                0.010258368216454983,
                -0.0006892586243338883,
            ],
            [
                0.011471141129732132,
                0.01028861477971077,
                -0.0005107342149131,
            ],
            [
                0.011715891771018505,
                0.01031841617077589,
                0.00007047851249808446,
            ],
            [
                0.011016339994966984,
                0.010264670476317406,
                -0.000972996698692441,
            ],
            [
                0.011672784574329853,
                0.010323147289454937,
                -0.0003919494047295302,
            ],
            [
                0.011288909241557121,
                0.01047211792320013,
                -0.00009998599853133783,
            ],
            [
                0.011460883542895317,
                0.010419445112347603,
                0.00014963769353926182,
            ],
            [
                0.011888734996318817,
                0.010363658890128136,
                0.0005085531738586724,
            ],
        ]
        .iter()
        .map(|p: &[f64; 3]| Point3::new(p[0], p[1], p[2]))
        .collect();
        let faces: Vec<[crate::mesh::VertexId; 3]> = [
            [0, 1, 2],
            [3, 2, 1],
            [0, 4, 1],
            [0, 5, 4],
            [6, 4, 5],
            [6, 5, 7],
            [8, 7, 5],
            [9, 1, 4],
            [9, 10, 1],
            [3, 1, 10],
            [3, 10, 11],
            [3, 11, 12],
            [9, 4, 13],
            [6, 13, 4],
            [14, 12, 11],
            [15, 7, 16],
            [8, 16, 7],
            [14, 17, 12],
        ]
        .iter()
        .map(|f: &[u32; 3]| f.map(crate::mesh::VertexId))
        .collect();
        let mesh = Mesh {
            positions,
            faces,
            ..Default::default()
        };
        let all: Vec<crate::mesh::FaceId> = (0..mesh.num_faces() as u32)
            .map(crate::mesh::FaceId)
            .collect();
        let start = param::stretch(&mesh, &[param::flatten(&mesh, &all)]);
        let opts = FlattenOptions::default();
        assert!(
            start.l2 > 2.0 * opts.max_chart_stretch && start.l2 < opts.split_above,
            "{start:?}"
        );
        let maps = flatten_all(&mesh, &opts);
        assert_eq!(maps.len(), 1);
        let s = param::stretch(&mesh, &maps);
        assert!(s.l2 <= opts.max_chart_stretch, "{s:?}");
        assert_eq!((s.flipped, s.zero_area), (0, 0));
        let eager = FlattenOptions {
            split_above: 2.0 * opts.max_chart_stretch,
            ..opts
        };
        assert!(flatten_all(&mesh, &eager).len() > 1);
    }

    #[test]
    fn flatten_all_bounds_every_charts_stretch_without_flips() {
        let (torus, _) = crate::sample::dented_torus(90, 36, (8, 8));
        let opts = FlattenOptions::default();
        let maps = flatten_all(&torus, &opts);
        let mut faces = vec![0; torus.num_faces()];
        for m in &maps {
            let s = param::stretch(&torus, std::slice::from_ref(m));
            assert!(
                s.l2 <= opts.max_chart_stretch || m.faces.len() == 1,
                "{s:?}"
            );
            assert_eq!((s.flipped, s.zero_area), (0, 0));
            for f in &m.face_ids {
                faces[f.idx()] += 1;
            }
        }
        assert!(
            faces.iter().all(|&n| n == 1),
            "every face in exactly one chart"
        );
        let total = param::stretch(&torus, &maps);
        assert!(total.l2 < 1.01, "{total:?}");
        // The torus is cut into few charts: LSCM starts and minimisation keep bands whole.
        assert!(maps.len() <= 16, "{} charts", maps.len());
        assert_eq!(flatten_all(&torus, &opts), maps, "deterministic");
    }

    /// Looking down on a cap (V = -z), triangles near its top get more texture area per unit
    /// 3D area than triangles at the rim, and the barrier keeps every triangle's h/b at or above
    /// alpha where the 3D triangle allows it.
    #[test]
    fn view_weight_moves_texels_towards_the_important_view() {
        let (torus, _) = crate::sample::dented_torus(120, 48, (8, 8));
        // The top of the tube over a quarter of the ring, away from the dent: a cap-like disk
        // whose normals run from +z (top) to sideways (rim).
        let faces = faces_where(&torus, |c| {
            c.z > 0.15 && c.x < 0.3 * c.y && c.y < 0.3 * c.x && c.x < 0.0
        });
        let ratio = |map: &param::ChartMap| {
            texel_density(&torus, map, |nz| nz > 0.9) / texel_density(&torus, map, |nz| nz < 0.7)
        };
        let mut plain = param::flatten(&torus, &faces);
        let mut weighted = plain.clone();
        optimize::optimize(&torus, &mut plain, &optimize::StretchOptions::default());
        let opts = optimize::StretchOptions {
            view_dir: Some(-Vector3::z()),
            k: 1.2,
            alpha: 0.1,
            ..Default::default()
        };
        optimize::optimize(&torus, &mut weighted, &opts);
        let (rp, rw) = (ratio(&plain), ratio(&weighted));
        assert!(
            rw > 1.5 * rp && rw > 1.3,
            "texel density top/rim: plain {rp:.3}, weighted {rw:.3}"
        );
        let s = param::stretch(&torus, std::slice::from_ref(&weighted));
        assert_eq!((s.flipped, s.zero_area), (0, 0));
        for (t, f) in weighted.faces.iter().zip(&weighted.face_ids) {
            let hb2 = param::height_base_2d(t.map(|i| weighted.uv[i as usize]));
            let hb3 = param::height_base_3d(torus.triangle(*f));
            assert!(
                hb2 >= 0.1f64.min(hb3) * 0.999 - 1e-12,
                "h/b {hb2} below alpha"
            );
        }
    }

    /// The chart covering each texel centre (first found), by rasterising the UV triangles.
    fn texel_owner(uv: &crate::mesh::UvMap, face_chart: &[u32], size: u32) -> Vec<Option<u32>> {
        let mut owner = vec![None; (size * size) as usize];
        for (f, t) in uv.faces.iter().enumerate() {
            let q = t.map(|i| uv.coords[i as usize].cast::<f64>() * size as f64);
            pack::raster_triangle(q, size, size, |x, y| {
                owner[(y * size + x) as usize].get_or_insert(face_chart[f]);
            });
        }
        owner
    }

    /// Genus-1, two-component, holed and non-manifold meshes all get UVs in [0, 1] for every
    /// face, no texel is covered by two charts, charts keep the gutter apart, and the result is
    /// deterministic.
    #[test]
    fn packed_atlases_never_overlap_and_cover_every_face() {
        let (torus, _) = crate::sample::dented_torus(60, 24, (8, 8));
        let meshes = [
            two_copies(&torus, Vector3::new(4.0, 0.0, 0.0)),
            with_holes(&torus, 13),
            with_fins(&torus, 4, 101, 1.3),
            torus,
            icosphere(3),
        ];
        let opts = AtlasOptions {
            pack: pack::PackOptions {
                size: 512,
                gutter: 4,
                ..Default::default()
            },
            ..Default::default()
        };
        for mut mesh in meshes {
            mesh.weld();
            let (m, atlas, r) = build(mesh.clone(), &opts).unwrap();
            // Stage 1's charts are the UV islands later stages would find in its UVs.
            let islands = Atlas::from_uvs(&m, 512).unwrap();
            assert_eq!(atlas.charts, islands.charts);
            assert_eq!(atlas.face_chart, islands.face_chart);
            assert_eq!(atlas.charts.len(), r.charts);
            assert!(atlas.face_chart.iter().all(|&c| c != u32::MAX));
            assert_eq!(r.overlapping_texels, 0, "{r:?}");
            assert_eq!((r.stretch.flipped, r.stretch.zero_area), (0, 0));
            let uv = m.uv.as_ref().unwrap();
            assert_eq!(uv.faces.len(), m.num_faces());
            assert!(uv
                .coords
                .iter()
                .all(|c| (0.0..=1.0).contains(&c.x) && (0.0..=1.0).contains(&c.y)));
            // Gutter: no texel within 3 texels (Chebyshev) of a chart belongs to another chart.
            let owner = texel_owner(uv, &atlas.face_chart, 512);
            for y in 0..512i64 {
                for x in 0..512i64 {
                    let Some(a) = owner[(y * 512 + x) as usize] else {
                        continue;
                    };
                    for (dx, dy) in (-3..=3i64).flat_map(|dx| (-3..=3i64).map(move |dy| (dx, dy))) {
                        let (u, v) = (x + dx, y + dy);
                        if (0..512).contains(&u) && (0..512).contains(&v) {
                            let b = owner[(v * 512 + u) as usize];
                            assert!(
                                b.is_none() || b == Some(a),
                                "charts {a} and {b:?} closer than the gutter"
                            );
                        }
                    }
                }
            }
            assert!(r.utilisation > 0.1, "{r:?}");
            let (m2, _) = parameterize(&mesh, &opts).unwrap();
            assert!(m2.uv == m.uv, "deterministic");
        }
    }

    /// A hemisphere (latitude-longitude grid, pole at +z) with V on its pole (looking down,
    /// V = -z) and k = 1.2 stays one chart without flips, and triangles near the pole get more
    /// texture area per unit 3D area than triangles at the rim: 1.226 measured, against 1.259
    /// for the exact optimum of the energy over radial maps (benches/hemisphere_optimum.py).
    /// The "at least twice" is beyond any one-chart map under this energy; across
    /// charts the texel budget does give about sqrt(w) (see
    /// `chart_budget_follows_the_view_weight`).
    #[test]
    fn hemisphere_with_view_on_its_pole_is_one_chart_with_texels_at_the_pole() {
        let (rings, sectors) = (16, 48);
        let mesh = polar_grid(rings, sectors, |i, j| {
            let lat = std::f64::consts::FRAC_PI_2 * i as f64 / rings as f64;
            let lon = std::f64::consts::TAU * j as f64 / sectors as f64;
            Point3::new(lat.sin() * lon.cos(), lat.sin() * lon.sin(), lat.cos())
        });
        let mut opts = FlattenOptions::default();
        opts.stretch.view_dir = Some(-Vector3::z());
        opts.stretch.k = 1.2;
        let maps = flatten_all(&mesh, &opts);
        assert_eq!(maps.len(), 1, "the hemisphere is one chart");
        let s = param::stretch(&mesh, &maps);
        assert_eq!((s.flipped, s.zero_area), (0, 0));
        let ratio = texel_density(&mesh, &maps[0], |nz| nz > 0.9)
            / texel_density(&mesh, &maps[0], |nz| nz < 0.2);
        assert!(
            ratio >= 1.18,
            "texture area per 3D area, pole / rim = {ratio:.3}"
        );
        // Without the view weight it stays one chart too.
        assert_eq!(flatten_all(&mesh, &FlattenOptions::default()).len(), 1);
    }

    /// Texture area per unit 3D area of the faces `pick` selects, in the packed atlas.
    fn packed_density(m: &Mesh, pick: impl Fn(usize) -> bool) -> f64 {
        let uv = m.uv.as_ref().unwrap();
        let (mut a2, mut a3) = (0.0, 0.0);
        for (f, t) in uv.faces.iter().enumerate().filter(|(f, _)| pick(*f)) {
            a2 += param::uv_area(t.map(|i| uv.coords[i as usize].cast::<f64>())).abs();
            a3 += m.face_area(crate::mesh::FaceId(f as u32));
        }
        a2 / a3
    }

    /// Two flat disks, one facing the important view (<N, V> = -1, w = 5 with k = 1.2) and one
    /// seen edge-on (w = 1/1.2): the packer gives the first sqrt(6) = 2.449 times the texture
    /// area per unit 3D area (Sander's budget, c^2 proportional to sqrt(w) for isometric
    /// charts); with `budget_by_energy` off, the same density.
    #[test]
    fn chart_budget_follows_the_view_weight() {
        let disk = polar_grid(6, 24, |r, k| {
            let a = std::f64::consts::TAU * k as f64 / 24.0;
            Point3::new(r as f64 * a.cos(), r as f64 * a.sin(), 0.0)
        });
        let up = disk.face_normal_area(crate::mesh::FaceId(0)).z.signum();
        let mut side = disk.clone();
        for p in side.positions.iter_mut() {
            *p = Point3::new(20.0, p.x, p.y);
        }
        let mesh = two_copies(&disk, Vector3::zeros());
        let mut mesh = mesh;
        let n = disk.num_vertices();
        mesh.positions[n..].copy_from_slice(&side.positions);
        let nf = disk.num_faces();
        let mut opts = AtlasOptions::default();
        opts.flatten.stretch.view_dir = Some(Vector3::new(0.0, 0.0, -up));
        opts.flatten.stretch.k = 1.2;
        opts.pack.size = 1024;
        let (m, r) = parameterize(&mesh, &opts).unwrap();
        assert_eq!((r.charts, r.overlapping_texels), (2, 0), "{r:?}");
        let ratio = packed_density(&m, |f| f < nf) / packed_density(&m, |f| f >= nf);
        assert!((ratio - 6f64.sqrt()).abs() < 0.02 * 6f64.sqrt(), "{ratio}");
        opts.budget_by_energy = false;
        let (m, _) = parameterize(&mesh, &opts).unwrap();
        let ratio = packed_density(&m, |f| f < nf) / packed_density(&m, |f| f >= nf);
        assert!((ratio - 1.0).abs() < 0.01, "{ratio}");
    }

    /// At a fixed texel density too high for one page, charts spread over UDIM pages: every
    /// face lies inside one page, no texel of any page is covered twice, and uv-report's
    /// measure of the result agrees with the packer's report.
    #[test]
    fn fixed_density_spreads_charts_over_pages() {
        let (torus, _) = crate::sample::dented_torus(60, 24, (8, 8));
        let mesh = two_copies(&torus, Vector3::new(4.0, 0.0, 0.0));
        let mut opts = AtlasOptions::default();
        opts.pack.size = 256;
        let (_, one) = parameterize(&mesh, &opts).unwrap();
        assert_eq!(one.pages, 1);
        opts.pack.texels_per_unit = Some(one.texels_per_unit * 1.5);
        let (m, r) = parameterize(&mesh, &opts).unwrap();
        assert!(r.pages >= 2, "{} pages", r.pages);
        assert_eq!(r.overlapping_texels, 0);
        assert_eq!((r.stretch.flipped, r.stretch.zero_area), (0, 0));
        let uv = m.uv.as_ref().unwrap();
        for (f, t) in uv.faces.iter().enumerate() {
            let p = uv.face_page(f) as f32;
            assert!(t
                .iter()
                .all(|&i| (p..=p + 1.0).contains(&uv.coords[i as usize].x)
                    && (0.0..=1.0).contains(&uv.coords[i as usize].y)));
        }
        let again = measure(&m, 256).unwrap();
        assert_eq!((again.charts, again.pages), (r.charts, r.pages));
        assert!((again.utilisation - r.utilisation).abs() < 1e-12);
        assert!((again.seam_ratio - r.seam_ratio).abs() < 1e-9);
        // A chart larger than a page at the requested density is an error, not a panic.
        opts.pack.texels_per_unit = Some(one.texels_per_unit * 100.0);
        assert!(parameterize(&mesh, &opts).is_err());
    }

    /// Out-of-range options are refused with a message naming the option.
    #[test]
    fn bad_options_are_errors() {
        let (torus, _) = crate::sample::dented_torus(30, 12, (4, 4));
        type Case = (fn(&mut AtlasOptions), &'static str);
        let cases: [Case; 5] = [
            (|o| o.flatten.stretch.k = 1.0, "k = 1"),
            (|o| o.flatten.stretch.alpha = 0.7, "alpha"),
            (
                |o| o.flatten.stretch.view_dir = Some(Vector3::zeros()),
                "view direction",
            ),
            (|o| o.pack.size = 8, "atlas size"),
            (|o| o.pack.texels_per_unit = Some(-1.0), "texel density"),
        ];
        for (set, what) in cases {
            let mut o = AtlasOptions::default();
            set(&mut o);
            let e = parameterize(&torus, &o).unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        }
    }
}
