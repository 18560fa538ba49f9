//! Squares of the surface flattened onto their tangent plane: the exemplars stage 6 takes
//! from what the photographs saw. A square is centred on a face, oriented by "up" (as the
//! patches it will be pasted into are) and sampled at the atlas's texel density, so its
//! content depends on the surface and the photographs, not on how the atlas happens to lay
//! out and cut the charts: a square may span several charts.

use super::surface::{centroid, point_triangle, tangent_up};
use crate::atlas::Atlas;
use crate::mesh::topology::NO_FACE;
use crate::mesh::{FaceId, Mesh};
use crate::resample::TexelSource;
use nalgebra::{Point3, Vector2, Vector3};

/// Least cosine between a face under a square and the square's normal (about 37 degrees):
/// steeper faces would be squeezed by the flattening by more than a fifth.
pub(super) const FLAT_COS: f64 = 0.8;

/// Most faces under one square; a square over more is refused (the mesh is far finer than
/// the texels, and a few thousand squares would cost more than the rest of stage 6).
const MAX_FACES: usize = 1 << 16;

/// A square of the surface: its centre, tangent frame and size.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Square {
    /// The face it is centred on.
    pub(super) seed: u32,
    /// The seed face's centroid.
    pub(super) centre: Point3<f64>,
    /// Tangent direction of the square's columns.
    pub(super) right: Vector3<f64>,
    /// Tangent direction against its rows ("up" on the tangent plane).
    pub(super) up: Vector3<f64>,
    /// The plane's normal: the area-weighted mean normal of the faces under the square.
    pub(super) normal: Vector3<f64>,
    /// Side, texels.
    pub(super) size: usize,
    /// Texels per scene unit.
    pub(super) tpu: f64,
    /// The faces within reach of the centre (the square's circumradius), in the order met.
    faces: Vec<u32>,
}

/// What lies under one texel of a flattened square: the face, the point in atlas texel
/// coordinates (texel (x, y)'s centre at (x + 0.5, y + 0.5)) and its [`taps`].
#[derive(Debug, Clone, Copy)]
pub(super) struct Under {
    /// The face.
    pub(super) face: u32,
    /// Where in the atlas.
    pub(super) at: Vector2<f64>,
    /// The photographed texels its colour reads, with their weights.
    taps: [(usize, f64); 4],
}

/// Faces to centre squares on: per cell of a grid of side `cell` (scene units), the face
/// whose centroid lies nearest the cell's centre (the lowest index on ties) among those on
/// the page photographed at their centroid (as [`taps`] says); the cell doubles until at
/// most `most` cells hold one. In face order.
pub(super) fn seeds(mesh: &Mesh, atlas: &Atlas, source: &[u8], cell: f64, most: usize) -> Vec<u32> {
    let usable: Vec<(u32, Point3<f64>)> = (0..mesh.num_faces())
        .filter_map(|f| {
            let t = atlas.face_texels(f)?;
            let at = (t[0] + t[1] + t[2]) / 3.0;
            photographed(atlas, source, f as u32, &at).then_some(())?;
            Some((f as u32, centroid(mesh, f as u32)))
        })
        .collect();
    let mut cell = cell.max(1e-12);
    loop {
        let mut best: rustc_hash::FxHashMap<[i64; 3], (f64, u32)> = Default::default();
        for &(f, p) in &usable {
            let g = p.coords / cell;
            let key = [g.x.floor() as i64, g.y.floor() as i64, g.z.floor() as i64];
            let mid = Vector3::new(key[0] as f64, key[1] as f64, key[2] as f64).add_scalar(0.5);
            let d = (g - mid).norm_squared();
            let e = best.entry(key).or_insert((d, f));
            // Faces come in index order, so a tie keeps the lower index.
            if d < e.0 {
                *e = (d, f);
            }
        }
        if best.len() <= most || !cell.is_finite() {
            let mut s: Vec<u32> = best.into_values().map(|(_, f)| f).collect();
            s.sort_unstable();
            return s;
        }
        cell *= 2.0;
    }
}

/// The square of side `size` texels (at `tpu` texels per scene unit) centred on face
/// `seed`, its columns along "up"'s tangent direction turned right; `None` when the faces
/// within its reach (found across `adj`, the face adjacency) are too many.
pub(super) fn square(
    mesh: &Mesh,
    adj: &[[u32; 3]],
    seed: u32,
    size: usize,
    tpu: f64,
    up: &Vector3<f64>,
) -> Option<Square> {
    let centre = centroid(mesh, seed);
    let reach = size as f64 / tpu * std::f64::consts::FRAC_1_SQRT_2;
    let mut faces = vec![seed];
    let mut seen = rustc_hash::FxHashSet::default();
    seen.insert(seed);
    let mut k = 0;
    while k < faces.len() {
        for g in adj[faces[k] as usize] {
            if g != NO_FACE
                && !seen.contains(&g)
                && point_triangle(&centre, &mesh.triangle(FaceId(g))) <= reach
            {
                seen.insert(g);
                faces.push(g);
                if faces.len() > MAX_FACES {
                    return None;
                }
            }
        }
        k += 1;
    }
    let sum: Vector3<f64> = faces
        .iter()
        .map(|&f| mesh.face_normal_area(FaceId(f)))
        .sum();
    let normal = sum.try_normalize(1e-300)?;
    let up_t = tangent_up(&normal, up);
    Some(Square {
        seed,
        centre,
        right: up_t.cross(&normal),
        up: up_t,
        normal,
        size,
        tpu,
        faces,
    })
}

impl Square {
    /// A square of side `size` at `centre` facing +z, over no face (for tests of what uses
    /// squares).
    #[cfg(test)]
    pub(super) fn bare(centre: Point3<f64>, size: usize) -> Square {
        Square {
            seed: 0,
            centre,
            right: Vector3::x(),
            up: Vector3::y(),
            normal: Vector3::z(),
            size,
            tpu: 1.0,
            faces: Vec::new(),
        }
    }

    /// Square texel coordinates of point `p` (columns right, rows down) and its height over
    /// the plane, scene units.
    fn project(&self, p: &Point3<f64>) -> (Vector2<f64>, f64) {
        let d = p - self.centre;
        let h = self.size as f64 / 2.0;
        (
            Vector2::new(
                h + d.dot(&self.right) * self.tpu,
                h - d.dot(&self.up) * self.tpu,
            ),
            d.dot(&self.normal),
        )
    }

    /// What lies under each of the square's texels (row-major), the surface nearest the plane
    /// where several layers do; `None` unless every texel lies on a face of the page turned
    /// no more than [`FLAT_COS`] from the plane, at a point the photographs saw (as [`taps`]
    /// says).
    pub(super) fn flatten(&self, mesh: &Mesh, atlas: &Atlas, source: &[u8]) -> Option<Vec<Under>> {
        let laid = self.lay(mesh, atlas, source)?;
        (0..self.size * self.size)
            .map(|i| laid.under(i % self.size, i / self.size))
            .collect()
    }

    /// [`Square::flatten`] without its [`taps`], which [`Laid::under`] finds for the texels
    /// asked for: choosing an exemplar reads a sixteenth of each candidate's texels, and
    /// holding every texel's taps (88 bytes a texel, 0.46 MB per candidate) took more time
    /// than finding them again (the sample's exemplars: 0.54-0.55 s against 0.62-0.66 s).
    pub(super) fn lay<'a>(
        &self,
        mesh: &Mesh,
        atlas: &'a Atlas,
        source: &'a [u8],
    ) -> Option<Laid<'a>> {
        let s = self.size;
        let mut under = vec![(f64::INFINITY, NO_FACE, Vector2::zeros(), false); s * s];
        let cross = |u: Vector2<f64>, v: Vector2<f64>| u.x * v.y - u.y * v.x;
        for &f in &self.faces {
            let na = mesh.face_normal_area(FaceId(f));
            // Faces turned away lie on another layer (a thin shell's far side).
            if na.dot(&self.normal) <= 0.0 {
                continue;
            }
            let Some(t) = atlas.face_texels(f as usize) else {
                continue;
            };
            let steep = na.dot(&self.normal) < FLAT_COS * na.norm();
            let p = mesh.triangle(FaceId(f));
            let q: [(Vector2<f64>, f64); 3] = std::array::from_fn(|k| self.project(&p[k]));
            let area = cross(q[1].0 - q[0].0, q[2].0 - q[0].0);
            if area.abs() < 1e-300 {
                continue;
            }
            let lo = q
                .iter()
                .fold(Vector2::repeat(f64::INFINITY), |a, v| a.inf(&v.0));
            let hi = q
                .iter()
                .fold(Vector2::repeat(f64::NEG_INFINITY), |a, v| a.sup(&v.0));
            let span = |a: f64, b: f64| {
                let a = (a - 0.5).ceil().max(0.0);
                let b = (b - 0.5).floor().min(s as f64 - 1.0);
                (a <= b).then_some((a as usize, b as usize))
            };
            let (Some((x0, x1)), Some((y0, y1))) = (span(lo.x, hi.x), span(lo.y, hi.y)) else {
                continue;
            };
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let c = Vector2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let wa = cross(q[1].0 - c, q[2].0 - c) / area;
                    let wb = cross(q[2].0 - c, q[0].0 - c) / area;
                    let wc = 1.0 - wa - wb;
                    if wa < -1e-9 || wb < -1e-9 || wc < -1e-9 {
                        continue;
                    }
                    let h = (wa * q[0].1 + wb * q[1].1 + wc * q[2].1).abs();
                    let u = &mut under[y * s + x];
                    if h < u.0 {
                        *u = (h, f, t[0] * wa + t[1] * wb + t[2] * wc, steep);
                    }
                }
            }
        }
        let under = under
            .into_iter()
            .map(|(_, f, at, steep)| {
                (f != NO_FACE && !steep && photographed(atlas, source, f, &at)).then_some((f, at))
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Laid {
            atlas,
            source,
            size: s,
            under,
        })
    }
}

/// A square [`Square::lay`] accepted: the face and atlas point under each texel.
pub(super) struct Laid<'a> {
    atlas: &'a Atlas,
    source: &'a [u8],
    size: usize,
    under: Vec<(u32, Vector2<f64>)>,
}

impl Laid<'_> {
    /// What lies under texel (`x`, `y`); `None` never happens ([`Square::lay`] found the
    /// taps of every texel in the same atlas).
    pub(super) fn under(&self, x: usize, y: usize) -> Option<Under> {
        let (face, at) = self.under[y * self.size + x];
        Some(Under {
            face,
            at,
            taps: taps(self.atlas, self.source, face, &at)?,
        })
    }
}

/// The four texels bilinear sampling at atlas point `at` of face `f` reads (texel (x, y)'s
/// centre at (x + 0.5, y + 0.5)) with their weights, those of `f`'s chart that photographs
/// coloured; `None` when there is none or when one of the four is a texel of a chart no
/// photograph saw (the point lies on or next to unseen surface). Texels beyond the chart (the
/// gutter, or another chart across it) are left out, so a point by a chart border counts as
/// photographed whichever way the atlas cut the surface there.
pub(super) fn taps(
    atlas: &Atlas,
    source: &[u8],
    f: u32,
    at: &Vector2<f64>,
) -> Option<[(usize, f64); 4]> {
    let quad = quad(atlas, source, at)?;
    let chart = atlas.face_chart[f as usize];
    let mut out = [(0usize, 0f64); 4];
    let mut any = false;
    for (k, &(i, w)) in quad.iter().enumerate() {
        if let Some(i) = i.filter(|&i| ours(atlas, source, chart, i)) {
            out[k] = (i, w);
            any |= w > 0.0;
        }
    }
    any.then_some(out)
}

/// Whether [`taps`] finds taps at `at` for face `f`, with fewer lookups: the charts of the
/// texels after the first of `f`'s chart with a weight are not needed.
fn photographed(atlas: &Atlas, source: &[u8], f: u32, at: &Vector2<f64>) -> bool {
    let Some(quad) = quad(atlas, source, at) else {
        return false;
    };
    let chart = atlas.face_chart[f as usize];
    quad.iter()
        .any(|&(i, w)| w > 0.0 && i.is_some_and(|i| ours(atlas, source, chart, i)))
}

/// The four texels around atlas point `at` with their bilinear weights (`None` off the page);
/// `None` if one of them is a texel no photograph saw.
#[inline]
fn quad(atlas: &Atlas, source: &[u8], at: &Vector2<f64>) -> Option<[(Option<usize>, f64); 4]> {
    let n = atlas.size as i64;
    let (sx, sy) = (at.x - 0.5, at.y - 0.5);
    let (x0, y0) = (sx.floor(), sy.floor());
    let (fx, fy) = (sx - x0, sy - y0);
    let quad = [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ]
    .map(|(dx, dy, w)| {
        let (x, y) = (x0 as i64 + dx, y0 as i64 + dy);
        let inside = x >= 0 && y >= 0 && x < n && y < n;
        (inside.then(|| (y * n + x) as usize), w)
    });
    quad.iter()
        .all(|&(i, _)| i.is_none_or(|i| !TexelSource::is_unseen(source[i])))
        .then_some(quad)
}

/// Whether texel `i` is a photographed texel of chart `chart`.
#[inline]
fn ours(atlas: &Atlas, source: &[u8], chart: u32, i: usize) -> bool {
    source[i] == TexelSource::Photos as u8
        && atlas
            .owner(i)
            .is_some_and(|g| atlas.face_chart[g as usize] == chart)
}

/// The atlas colour at `u` (a texel [`Square::flatten`] accepted): bilinear over its
/// photographed [`taps`].
pub(super) fn colour(data: &[f32], u: &Under) -> [f32; 3] {
    let (mut acc, mut wsum) = ([0f64; 3], 0f64);
    for (i, w) in u.taps {
        if w > 0.0 {
            for k in 0..3 {
                acc[k] += w * data[i * 3 + k] as f64;
            }
            wsum += w;
        }
    }
    acc.map(|a| (a / wsum.max(1e-300)) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::{build, AtlasOptions};
    use std::f64::consts::TAU;

    /// An open tube of radius 1 along z from -1 to 1 (64 segments around, 8 rings): not a
    /// disk, so the atlas has to cut it.
    fn tube() -> Mesh {
        Mesh::tube(64, 8, false)
    }

    /// The tube's colour at angle `a` and height `z`: red waves along the arc (twelve around),
    /// green along z (half a unit long).
    fn paint(a: f64, z: f64) -> [f32; 3] {
        let w = |phase: f64| (0.5 + 0.3 * phase.sin()) as f32;
        [w(12.0 * a), w(TAU * z / 0.5), 0.5]
    }

    /// [`tube`] and its atlas on a page of `size` texels with gutters of `gutter`.
    fn tube_atlas(size: u32, gutter: u32) -> (Mesh, Atlas) {
        let opts = AtlasOptions {
            pack: crate::atlas::pack::PackOptions {
                size,
                gutter,
                ..Default::default()
            },
            ..Default::default()
        };
        let (mesh, atlas, _) = build(tube(), &opts).unwrap();
        (mesh, atlas)
    }

    #[test]
    fn the_quick_check_agrees_with_the_taps_everywhere() {
        // A tube's atlas with a band of unseen texels, others photographed or empty: at
        // points all over the page (texel centres, edges and corners, off the page), for the
        // face owning the texel and for a face of another chart, `photographed` says what
        // `taps` finds.
        let (_, atlas) = tube_atlas(128, 2);
        let n = atlas.size as usize;
        let source: Vec<u8> = (0..n * n)
            .map(|i| match (atlas.owner(i), i % 7) {
                (None, _) => TexelSource::Empty as u8,
                (Some(_), _) if (i / n) % 40 < 3 => TexelSource::Red as u8,
                (Some(_), 0) => TexelSource::Empty as u8,
                _ => TexelSource::Photos as u8,
            })
            .collect();
        let other = |f: u32| {
            (0..atlas.face_chart.len() as u32)
                .find(|&g| atlas.face_chart[g as usize] != atlas.face_chart[f as usize])
                .unwrap()
        };
        let (mut yes, mut no) = (0, 0);
        for i in 0..n * n {
            let Some(f) = atlas.owner(i) else { continue };
            let (x, y) = ((i % n) as f64, (i / n) as f64);
            for (dx, dy) in [(0.5, 0.5), (0.0, 0.0), (0.25, 0.9), (1.0, 0.5), (-0.7, 0.2)] {
                let at = Vector2::new(x + dx, y + dy);
                for g in [f, other(f)] {
                    let quick = photographed(&atlas, &source, g, &at);
                    assert_eq!(
                        quick,
                        taps(&atlas, &source, g, &at).is_some(),
                        "{g} at {at}"
                    );
                    if quick {
                        yes += 1;
                    } else {
                        no += 1;
                    }
                }
            }
        }
        assert!(yes > 1000 && no > 1000, "{yes} accepted, {no} refused");
    }

    /// Every square the seeds give on a painted tube shows the paint where the surface under
    /// each of its texels lies (columns along the arc, rows down z, at the atlas's density),
    /// whether or not it spans a chart border; squares reaching past the tube's ends are
    /// refused.
    #[test]
    fn squares_show_the_surface_under_them_across_chart_borders() {
        let (mesh, atlas) = tube_atlas(256, 4);
        let n = atlas.size as usize;
        let mut source = vec![TexelSource::Empty as u8; n * n];
        let mut data = vec![0f32; n * n * 3];
        for i in 0..n * n {
            if let Some(f) = atlas.owner(i) {
                let b = atlas.barycentric(f as usize, i % n, i / n).unwrap();
                let t = mesh.triangle(FaceId(f));
                let p = t[0].coords * b[0] + t[1].coords * b[1] + t[2].coords * b[2];
                data[i * 3..i * 3 + 3].copy_from_slice(&paint(p.y.atan2(p.x), p.z));
                source[i] = TexelSource::Photos as u8;
            }
        }
        let charts: std::collections::HashSet<u32> = atlas.face_chart.iter().copied().collect();
        assert!(charts.len() > 1, "the tube is one chart");
        let adj = crate::mesh::topology::face_adjacency(&mesh);
        let tpu = atlas.texels_per_unit();
        let size = 16;
        let up = Vector3::z();
        let seeds = seeds(&mesh, &atlas, &source, size as f64 / 2.0 / tpu, 4096);
        let (mut accepted, mut refused, mut spanning) = (0, 0, 0);
        let reach = size as f64 / tpu * std::f64::consts::FRAC_1_SQRT_2;
        for &seed in &seeds {
            let sq = square(&mesh, &adj, seed, size, tpu, &up).unwrap();
            let Some(under) = sq.flatten(&mesh, &atlas, &source) else {
                // Only squares reaching past an end of the tube may be refused.
                assert!(
                    sq.centre.z.abs() + reach > 1.0,
                    "seed {seed} at {}",
                    sq.centre
                );
                refused += 1;
                continue;
            };
            accepted += 1;
            let cs: std::collections::HashSet<u32> = under
                .iter()
                .map(|u| atlas.face_chart[u.face as usize])
                .collect();
            spanning += usize::from(cs.len() > 1);
            let (a0, r0) = (sq.centre.y.atan2(sq.centre.x), sq.centre.coords.xy().norm());
            for (k, u) in under.iter().enumerate() {
                let (x, y) = ((k % size) as f64 + 0.5, (k / size) as f64 + 0.5);
                let right = (x - size as f64 / 2.0) / tpu;
                let down = (y - size as f64 / 2.0) / tpu;
                // The point under the texel, along the square's normal (radial here).
                let want = paint(a0 + (right / r0).asin(), sq.centre.z - down);
                let got = colour(&data, u);
                for c in 0..3 {
                    assert!(
                        (got[c] - want[c]).abs() < 0.03,
                        "seed {seed} texel {k}: {got:?} against {want:?}"
                    );
                }
            }
        }
        assert!(
            accepted > 50 && refused > 0,
            "{accepted} accepted, {refused} refused"
        );
        assert!(spanning > 0, "no square spans a chart border");
    }
}
