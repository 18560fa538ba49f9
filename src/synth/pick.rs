//! Exemplars from what the photographs saw: squares of the photographed surface flattened
//! onto their tangent plane at the atlas's texel density ([`super::flat`]), described by how
//! their surface faces "up", their mean colour, detail and where they are; each region takes
//! the square most like its rim (orientation, colour, place).

use super::flat::{colour, seeds, square, Square};
use super::surface::{centroid, tangent_up};
use crate::atlas::Atlas;
use crate::camera::PosedCamera;
use crate::mesh::{FaceId, Mesh};
use crate::resample::{Resampled, TexelSource, NO_PHOTO};
use nalgebra::{Matrix2, Matrix2x3, Point3, Vector3};
use rayon::prelude::*;

/// Luma of texel `i` of a row-major RGB float buffer.
fn texel_luma(data: &[f32], i: usize) -> f64 {
    crate::planar::luma(&[data[i * 3], data[i * 3 + 1], data[i * 3 + 2]])
}

/// Most squares flattened as candidates: their centres are spread over the photographed
/// surface on a grid coarse enough to hold at most this many.
pub(super) const MAX_CANDIDATES: usize = 4096;

/// A square of the photographed surface that can serve as an exemplar.
#[derive(Debug, Clone)]
pub(super) struct Candidate {
    /// Where on the surface, flattened how.
    pub(super) square: Square,
    /// Mean colour.
    pub(super) mean: [f32; 3],
    /// Mean of the surface normal's component along up.
    pub(super) facing_up: f64,
    /// Mean surface point.
    pub(super) centre: Point3<f64>,
    /// Detail energy: mean squared difference between a texel's luma and the mean of its
    /// four neighbours `lag` texels away (the detail scale stage 6 pastes).
    pub(super) detail: f64,
    /// Largest distance between the mean colours of the square's four quadrants: a colour
    /// edge or gradient inside it, which would paste as blotches.
    pub(super) spread: f64,
    /// How sharply the photographs saw the square: the least, over its sampled texels, of
    /// the winning photograph's pixels per texel along the most foreshortened direction. Low
    /// where it was seen at a grazing angle or from afar: there a photograph pixel is
    /// stretched over several texels and its edges come out as stripes, which pasted
    /// elsewhere would repeat as a pattern the surface never had.
    pub(super) sharpness: f64,
}
/// A photograph as exemplar choice sees it: its pose and focal length in pixels.
pub(super) struct Eye<'a> {
    /// Camera and pose.
    pub(super) view: &'a PosedCamera,
    /// Focal length, pixels.
    pub(super) focal: f64,
}

/// Pixels per texel along the most foreshortened direction with which `eye` saw point `p`
/// of a face with unit normal `n` and `tpu` texels per scene unit (0 when it faces away).
fn pixels_per_texel(eye: &Eye, p: &Point3<f64>, n: &Vector3<f64>, tpu: f64) -> f64 {
    let cam = eye.view.pose.transform(p);
    let to_eye = eye.view.pose.center() - p;
    let cos = n.dot(&to_eye) / to_eye.norm().max(1e-300);
    if cam.z <= 0.0 || cos <= 0.0 || tpu <= 0.0 {
        return 0.0;
    }
    eye.focal * cos / (cam.z * tpu)
}

/// [`pixels_per_texel`] for a face at `mid` (unit normal `n`, `tpu` texels per scene unit)
/// as photograph `best` (an index of `eyes`, or [`NO_PHOTO`]: 0) saw it.
fn seen_sharpness(eyes: &[Eye], best: u16, mid: &Point3<f64>, n: &Vector3<f64>, tpu: f64) -> f64 {
    match eyes.get(best as usize) {
        Some(eye) if best != NO_PHOTO => pixels_per_texel(eye, mid, n, tpu),
        _ => 0.0,
    }
}

/// The map from face `f`'s tangent offsets (right, up) to texels.
pub(super) fn face_map(
    mesh: &Mesh,
    atlas: &Atlas,
    f: usize,
    up: &Vector3<f64>,
) -> Option<Matrix2<f64>> {
    let t = atlas.face_texels(f)?;
    let p = mesh.triangle(FaceId(f as u32));
    let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
    let n = e1.cross(&e2);
    if n.norm() < 1e-300 {
        return None;
    }
    let n = n.normalize();
    // J E = U with E the 3D edges and U the texel edges: J = U (E^T E)^-1 E^T.
    let g = Matrix2::new(e1.dot(&e1), e1.dot(&e2), e2.dot(&e1), e2.dot(&e2));
    let gi = g.try_inverse()?;
    let u = Matrix2::from_columns(&[t[1] - t[0], t[2] - t[0]]);
    let et = Matrix2x3::from_rows(&[e1.transpose(), e2.transpose()]);
    let j = u * gi * et;
    let tu = tangent_up(&n, up);
    let right = tu.cross(&n);
    Some(Matrix2::from_columns(&[j * right, j * tu]))
}

/// Every square of side `size` texels (at the atlas's texel density, `tpu`) centred on one
/// of [`seeds`]' faces (a grid of its side, coarsened to [`MAX_CANDIDATES`]) that
/// [`Square::flatten`] accepts: photographed throughout, nearly flat; detail measured at
/// `lag` texels, sharpness from `eyes` (indexed as `res.best_photo`). In seed order.
#[allow(clippy::too_many_arguments)]
pub(super) fn candidates(
    mesh: &Mesh,
    adj: &[[u32; 3]],
    atlas: &Atlas,
    res: &Resampled,
    eyes: &[Eye],
    up: &Vector3<f64>,
    size: usize,
    lag: usize,
) -> Vec<Candidate> {
    let (color, source) = (&res.color, &res.source[..]);
    let n = atlas.size as usize;
    let tpu = atlas.texels_per_unit();
    if size < 8 || size > n {
        return Vec::new();
    }
    // The square's side, rounded down to a power of two scene units: atlases that differ a
    // little in density (another packing) seed the same faces. Half the side flattened
    // about four times as many squares for no better choice (docs/decisions.md, "Exemplars
    // flattened from the surface": the sample's exemplars 0.42 s against 0.14 s).
    let cell = (size as f64 / tpu).log2().floor().exp2();
    let data: &[f32] = color.as_raw();
    seeds(mesh, atlas, source, cell, MAX_CANDIDATES)
        .par_iter()
        .filter_map(|&seed| {
            let sq = square(mesh, adj, seed, size, tpu, up)?;
            let laid = sq.lay(mesh, atlas, source)?;
            let at = |x: usize, y: usize| laid.under(x, y).map(|u| colour(data, &u));
            let luma = |x: usize, y: usize| at(x, y).map(|c| crate::planar::luma(&c));
            let (mut mean, mut facing, mut centre, mut count) =
                ([0f64; 3], 0.0, Vector3::zeros(), 0usize);
            let mut detail = 0.0;
            let mut quad = [[0f64; 4]; 4];
            let mut sharpness = f64::INFINITY;
            // One sharpness per face and photograph: the face's centroid stands for its texels.
            let mut memo: Option<(u32, u16, f64)> = None;
            for y in (0..size).step_by(4) {
                for x in (0..size).step_by(4) {
                    let u = laid.under(x, y)?;
                    let f = FaceId(u.face);
                    let nrm = mesh.face_normal_area(f).normalize();
                    let mid = centroid(mesh, u.face);
                    let c = colour(data, &u);
                    for k in 0..3 {
                        mean[k] += c[k] as f64;
                    }
                    facing += nrm.dot(up);
                    centre += mid.coords;
                    // The texel under the point (its taps lie on the page, so clamping
                    // only matters half a texel from the page's edge).
                    let texel = |v: f64| (v.floor().max(0.0) as usize).min(n - 1);
                    let i = texel(u.at.y) * n + texel(u.at.x);
                    let best = res.best_photo[i];
                    let px = match memo {
                        Some((mf, mb, px)) if mf == u.face && mb == best => px,
                        _ => {
                            let px = seen_sharpness(eyes, best, &mid, &nrm, tpu);
                            memo = Some((u.face, best, px));
                            px
                        }
                    };
                    sharpness = sharpness.min(px);
                    let (xa, xb) = (x.max(lag) - lag, (x + lag).min(size - 1));
                    let (ya, yb) = (y.max(lag) - lag, (y + lag).min(size - 1));
                    let around = (luma(xa, y)? + luma(xb, y)? + luma(x, ya)? + luma(x, yb)?) / 4.0;
                    detail += (crate::planar::luma(&c) - around).powi(2);
                    let q = &mut quad[usize::from(x >= size / 2) + 2 * usize::from(y >= size / 2)];
                    for k in 0..3 {
                        q[k] += c[k] as f64;
                    }
                    q[3] += 1.0;
                    count += 1;
                }
            }
            let c = count as f64;
            let qm: Vec<[f64; 3]> = quad
                .iter()
                .map(|q| std::array::from_fn(|k| q[k] / q[3].max(1.0)))
                .collect();
            let mut spread = 0f64;
            for a in &qm {
                for b in &qm {
                    spread = spread.max((0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt());
                }
            }
            Some(Candidate {
                square: sq,
                spread,
                mean: mean.map(|v| (v / c) as f32),
                facing_up: facing / c,
                centre: Point3::from(centre / c),
                detail: detail / c,
                sharpness,
            })
        })
        .collect()
}

/// The colours of `c`'s square, row-major: the exemplar it gives.
/// `None` only if `res` changed since [`candidates`] flattened it.
pub(super) fn texels(
    mesh: &Mesh,
    atlas: &Atlas,
    res: &Resampled,
    c: &Candidate,
) -> Option<Vec<[f32; 3]>> {
    let data: &[f32] = res.color.as_raw();
    let under = c.square.flatten(mesh, atlas, &res.source)?;
    Some(under.iter().map(|u| colour(data, u)).collect())
}

/// Share of the sharpest candidates' sharpness (their 90th percentile) a candidate needs to be
/// kept: below half of it, a photograph pixel spans more than twice the texels it does where
/// the photographs saw best.
pub(super) const SHARP_SHARE: f64 = 0.5;

/// The candidates seen sharply enough ([`SHARP_SHARE`] of the 90th percentile of
/// sharpness), in their order, and that least sharpness; all of them and 0 when none is.
pub(super) fn sharp_only(cands: Vec<Candidate>) -> (Vec<Candidate>, f64) {
    if cands.is_empty() {
        return (cands, 0.0);
    }
    let mut s: Vec<f64> = cands.iter().map(|c| c.sharpness).collect();
    let k = (s.len() * 9 / 10).min(s.len() - 1);
    let top = *s.select_nth_unstable_by(k, f64::total_cmp).1;
    let floor = SHARP_SHARE * top;
    if cands.iter().any(|c| c.sharpness >= floor) {
        let kept = cands.into_iter().filter(|c| c.sharpness >= floor).collect();
        (kept, floor)
    } else {
        (cands, 0.0)
    }
}

/// The texels of `texels` (from [`photographed_texels`]) that their winning photograph saw
/// with at least `floor` pixels per texel (as [`Candidate::sharpness`]); all of them when
/// fewer than 64 are.
pub(super) fn sharp_texels(
    mesh: &Mesh,
    atlas: &Atlas,
    res: &Resampled,
    eyes: &[Eye],
    up: &Vector3<f64>,
    texels: Vec<(usize, u32)>,
    floor: f64,
) -> Vec<(usize, u32)> {
    if floor <= 0.0 {
        return texels;
    }
    // One figure per face and photograph: the face's centroid stands for its texels.
    let mut memo: Option<(u32, u16, f64)> = None;
    let kept: Vec<(usize, u32)> = texels
        .iter()
        .copied()
        .filter(|&(i, f)| {
            let best = res.best_photo[i];
            let px = match memo {
                Some((mf, mb, px)) if mf == f && mb == best => px,
                _ => {
                    let mid = centroid(mesh, f);
                    let n = mesh.face_normal_area(FaceId(f)).normalize();
                    let px = face_map(mesh, atlas, f as usize, up).map_or(0.0, |fm| {
                        seen_sharpness(eyes, best, &mid, &n, fm.determinant().abs().sqrt())
                    });
                    memo = Some((f, best, px));
                    px
                }
            };
            px >= floor
        })
        .collect();
    if kept.len() >= 64 {
        kept
    } else {
        texels
    }
}

/// What a region's rim looks like, for choosing its exemplar.
#[derive(Debug, Clone)]
pub(super) struct RimLook {
    /// Mean colour around the rim.
    pub(super) colour: [f32; 3],
    /// Area-weighted mean of the region's normals along up.
    pub(super) facing_up: f64,
    /// Mean position of the rim.
    pub(super) centre: Point3<f64>,
    /// Detail energy of the photographed texels around the rim, measured as
    /// [`Candidate::detail`]; `None` when there are none.
    pub(super) detail: Option<f64>,
}

/// The photographed texels each of `faces` owns (texel index, face), face by face in row
/// order.
pub(super) fn photographed_texels(
    atlas: &Atlas,
    source: &[u8],
    faces: &[u32],
) -> Vec<(usize, u32)> {
    faces
        .iter()
        .flat_map(|&f| atlas.owned_texels(f as usize).map(move |i| (i, f)))
        .filter(|&(i, _)| source[i] == TexelSource::Photos as u8)
        .collect()
}

/// Detail energy (as [`Candidate::detail`]) of `texels` (from [`photographed_texels`]).
pub(super) fn texels_detail(
    atlas: &Atlas,
    color: &image::Rgb32FImage,
    source: &[u8],
    texels: &[(usize, u32)],
    lag: usize,
) -> Option<f64> {
    let n = atlas.size as usize;
    let data: &[f32] = color.as_raw();
    let luma = |i: usize| texel_luma(data, i);
    let seen = |i: usize| source[i] == TexelSource::Photos as u8;
    let inside = |v: usize| v >= lag && v + lag < n;
    let (mut sum, mut count) = (0.0, 0usize);
    for &(i, _) in texels {
        if !inside(i % n) || !inside(i / n) {
            continue;
        }
        let nb = [i - lag, i + lag, i - lag * n, i + lag * n];
        if nb.iter().all(|&j| seen(j)) {
            let around = nb.iter().map(|&j| luma(j)).sum::<f64>() / 4.0;
            sum += (luma(i) - around).powi(2);
            count += 1;
        }
    }
    (count >= 64).then(|| sum / count as f64)
}

/// The candidate most like `rim`: orientation against up (0.6 apart costs 1), mean colour
/// (0.3 apart costs 1), distance (half the object's radius costs 1), a colour change inside
/// the crop (quadrant means 0.05 apart cost 1), and detail: twice the log of the ratio to the
/// rim's detail or the candidates' median, whichever is larger (the rim is often seen at
/// grazing angles, blurred; the surface it continues is not). The first on ties.
pub(super) fn choose<'a>(
    cands: &'a [Candidate],
    rim: &RimLook,
    radius: f64,
) -> Option<&'a Candidate> {
    let typical = {
        let mut d: Vec<f64> = cands.iter().map(|c| c.detail).collect();
        if d.is_empty() {
            return None;
        }
        let k = d.len() / 2;
        *d.select_nth_unstable_by(k, f64::total_cmp).1
    };
    let cost = |c: &Candidate| {
        let want = rim.detail.unwrap_or(typical).max(typical);
        let short = (want.max(1e-12) / c.detail.max(1e-12)).ln().abs();
        let dc = (0..3)
            .map(|k| ((c.mean[k] - rim.colour[k]) as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        (c.facing_up - rim.facing_up).abs() / 0.6
            + dc / 0.3
            + (c.centre - rim.centre).norm() / (0.5 * radius).max(1e-12)
            + c.spread / 0.05
            + 2.0 * short
    };
    cands
        .iter()
        .map(|c| (cost(c), c))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, c)| c)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, CameraModel, Pose};

    fn eye(view: &PosedCamera) -> Eye<'_> {
        Eye {
            view,
            focal: crate::depth::focal_px(view),
        }
    }

    /// A camera at the origin looking down +z (focal 1000 px): a point 2 units away on a face
    /// turned towards it gets 1000 / 2 / tpu pixels per texel; turned by 60 degrees, half that
    /// (the foreshortened direction); turned away or behind the camera, none.
    #[test]
    fn pixels_per_texel_follow_distance_and_foreshortening() {
        let view = PosedCamera {
            camera: Camera::new(
                1,
                CameraModel::Pinhole,
                800,
                600,
                vec![1000.0, 1000.0, 400.0, 300.0],
            )
            .unwrap(),
            pose: Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        };
        let e = eye(&view);
        let p = Point3::new(0.0, 0.0, 2.0);
        let tpu = 250.0;
        let frontal = pixels_per_texel(&e, &p, &Vector3::new(0.0, 0.0, -1.0), tpu);
        assert!((frontal - 2.0).abs() < 1e-9, "{frontal}");
        let a = 60f64.to_radians();
        let tilted = pixels_per_texel(&e, &p, &Vector3::new(a.sin(), 0.0, -a.cos()), tpu);
        assert!((tilted - 1.0).abs() < 1e-9, "{tilted}");
        assert_eq!(
            pixels_per_texel(&e, &p, &Vector3::new(0.0, 0.0, 1.0), tpu),
            0.0
        );
        let behind = Point3::new(0.0, 0.0, -2.0);
        assert_eq!(
            pixels_per_texel(&e, &behind, &Vector3::new(0.0, 0.0, 1.0), tpu),
            0.0
        );
    }

    fn cand(sharpness: f64) -> Candidate {
        Candidate {
            square: Square::bare(Point3::origin(), 16),
            mean: [0.5; 3],
            facing_up: 0.0,
            centre: Point3::origin(),
            detail: 1.0,
            spread: 0.0,
            sharpness,
        }
    }

    /// Of twenty crops seen at 1..20 pixels per texel the 90th percentile is 19: those under
    /// half of it go, the rest keep their order; crops all unseen (0) are all kept.
    #[test]
    fn only_sharply_seen_crops_serve_as_exemplars() {
        let (kept, floor) = sharp_only((1..=20).map(|s| cand(s as f64)).collect());
        assert_eq!(floor, SHARP_SHARE * 19.0);
        let s: Vec<f64> = kept.iter().map(|c| c.sharpness).collect();
        assert_eq!(s, (10..=20).map(|v| v as f64).collect::<Vec<_>>());
        let (kept, floor) = sharp_only(vec![cand(0.0), cand(0.0)]);
        assert_eq!((kept.len(), floor), (2, 0.0));
        assert!(sharp_only(Vec::new()).0.is_empty());
    }
}
