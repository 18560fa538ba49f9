//! A depth map of the mesh as one photograph sees it: triangles projected through the camera
//! model (distortion included, vertex by vertex) and rasterised with a z-buffer. Used by the
//! binding for occlusion, silhouettes and the background estimate, and by the resampling for
//! per-texel occlusion (`docs/decisions.md`, "Binding and resampling").

use crate::camera::PosedCamera;
use crate::memory::SpareBuffers;
use crate::mesh::Mesh;
use nalgebra::{Point2, Vector3};
use rayon::prelude::*;

/// Camera-frame depth (z) of the nearest surface per depth pixel; `f32::INFINITY` where the
/// mesh does not cover it. The map may be coarser than the photograph: `scale` depth pixels per
/// photo pixel.
#[derive(Debug, Clone)]
pub struct DepthMap {
    /// Width in depth pixels.
    pub width: u32,
    /// Height in depth pixels.
    pub height: u32,
    /// Depth pixels per photo pixel (at most 1).
    pub scale: f64,
    /// Row-major depths.
    pub z: Vec<f32>,
}

/// At most this many z-buffers are rasterised at once (one per part of the faces), then merged
/// by their minimum: bounded memory however many threads there are.
pub const MAX_PARTS: usize = 8;

impl DepthMap {
    /// Renders the depth of `mesh` seen by `view`, at most `max_side` pixels on the longer side.
    /// A triangle with a corner that cannot be imaged (behind the camera) is left out.
    pub fn render(mesh: &Mesh, view: &PosedCamera, max_side: u32) -> Self {
        Self::render_projected(mesh, view, &project_vertices(mesh, view), max_side)
    }

    /// [`DepthMap::render`] from the vertices already projected by [`project_vertices`].
    pub fn render_projected(
        mesh: &Mesh,
        view: &PosedCamera,
        projected: &[Option<[f64; 3]>],
        max_side: u32,
    ) -> Self {
        let mut none = SpareBuffers::new(0);
        Self::render_projected_reusing(mesh, view, projected, max_side, &mut none)
    }

    /// [`DepthMap::render_projected`] in buffers from `spare` where one has the map's size
    /// (the z-buffers of the faces' parts but the first go back to `spare`; so can the map's
    /// own, [`DepthMap::z`], once it is no longer needed). A loop over photographs that
    /// renders each one's map in fresh memory faults every page of it in again (151k of the
    /// 1.5M-face scene's 2.5M page faults were binding's maps); the same bytes either way.
    pub fn render_projected_reusing(
        mesh: &Mesh,
        view: &PosedCamera,
        projected: &[Option<[f64; 3]>],
        max_side: u32,
        spare: &mut SpareBuffers,
    ) -> Self {
        let (pw, ph) = (view.camera.width, view.camera.height);
        let scale = (max_side as f64 / pw.max(ph) as f64).min(1.0);
        let w = ((pw as f64 * scale).round() as u32).max(1);
        let h = ((ph as f64 * scale).round() as u32).max(1);
        let w_us = w as usize;
        // Projected corners in depth pixel coordinates (pixel centres at +0.5) and z, and
        // the rows the triangle covers, if it lands in the image.
        let corners = |f: usize| -> Option<([[f64; 3]; 3], usize, usize)> {
            let fv = mesh.faces[f];
            let at = |k: usize| projected[fv[k].idx()].map(|[x, y, z]| [x * scale, y * scale, z]);
            let (a, b, c) = (at(0)?, at(1)?, at(2)?);
            let (ylo, yhi) = (a[1].min(b[1]).min(c[1]), a[1].max(b[1]).max(c[1]));
            let (xlo, xhi) = (a[0].min(b[0]).min(c[0]), a[0].max(b[0]).max(c[0]));
            if yhi < 0.0 || xhi < 0.0 || ylo > h as f64 || xlo > w as f64 {
                return None;
            }
            let r0 = (ylo - 0.5).ceil().max(0.0) as usize;
            let r1 = ((yhi - 0.5).floor() as i64).min(h as i64 - 1);
            (r1 >= r0 as i64).then_some(([a, b, c], r0, r1 as usize))
        };
        // Each part of the faces (contiguous, so nearby on a scan's surface) into its own
        // z-buffer, then the buffers' minimum: the nearest depth per pixel is the same
        // whichever part a face fell in, so the map does not depend on the thread count.
        // One pass over the faces; binning them into row bands first cost more than the
        // rasterising itself on meshes whose faces are smaller than a depth pixel.
        let nf = mesh.num_faces();
        let parts = rayon::current_num_threads()
            .clamp(1, MAX_PARTS)
            .min(nf.max(1));
        let per = nf.div_ceil(parts).max(1);
        let len = w_us * h as usize;
        let given: Vec<Option<Vec<f32>>> = (0..parts).map(|_| spare.take(len)).collect();
        let mut buffers: Vec<Vec<f32>> = given
            .into_par_iter()
            .enumerate()
            .map(|(k, reused)| {
                let mut z = match reused {
                    Some(mut z) => {
                        z.fill(f32::INFINITY);
                        z
                    }
                    None => vec![f32::INFINITY; len],
                };
                for f in k * per..((k + 1) * per).min(nf) {
                    if let Some((t, r0, r1)) = corners(f) {
                        raster_depth(&t, r0, r1, w_us, |x, y, d| {
                            let cell = &mut z[y * w_us + x];
                            if d < *cell {
                                *cell = d;
                            }
                        });
                    }
                }
                z
            })
            .collect();
        let mut z = buffers.swap_remove(0);
        if !buffers.is_empty() {
            z.par_chunks_mut(w_us).enumerate().for_each(|(y, row)| {
                for other in &buffers {
                    for (cell, &d) in row.iter_mut().zip(&other[y * w_us..(y + 1) * w_us]) {
                        if d < *cell {
                            *cell = d;
                        }
                    }
                }
            });
        }
        spare.put(buffers);
        DepthMap {
            width: w,
            height: h,
            scale,
            z,
        }
    }

    /// Depth pixel holding photo pixel coordinate `px`, if inside.
    fn cell(&self, px: &Point2<f64>) -> Option<(u32, u32)> {
        let (x, y) = (px.x * self.scale, px.y * self.scale);
        if x < 0.0 || y < 0.0 {
            return None;
        }
        let (x, y) = (x as u32, y as u32);
        (x < self.width && y < self.height).then_some((x, y))
    }

    /// Depth at photo pixel coordinate `px` (nearest depth pixel); infinity outside the map.
    pub fn at(&self, px: &Point2<f64>) -> f32 {
        self.cell(px).map_or(f32::INFINITY, |(x, y)| {
            self.z[(y * self.width + x) as usize]
        })
    }

    /// The map min-filtered over `(2r+1)^2` pixels: at each pixel the nearest surface any
    /// nearby photo pixel might mix in (antialiasing, registration error), one lookup for
    /// callers that test many points.
    pub fn eroded(&self, r: u32) -> DepthMap {
        let (w, h) = (self.width as usize, self.height as usize);
        let r = r as usize;
        // Separable: rows, then columns.
        let mut rows = vec![f32::INFINITY; w * h];
        rows.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
            let src = &self.z[y * w..(y + 1) * w];
            if r == 1 && w >= 3 {
                // The merge's radius: three taps without a slice per pixel (about half the
                // time at 2048).
                out[0] = src[0].min(src[1]);
                for (o, t) in out[1..w - 1].iter_mut().zip(src.windows(3)) {
                    *o = t[0].min(t[1]).min(t[2]);
                }
                out[w - 1] = src[w - 2].min(src[w - 1]);
                return;
            }
            for (x, o) in out.iter_mut().enumerate() {
                *o = src[x.saturating_sub(r)..=(x + r).min(w - 1)]
                    .iter()
                    .fold(f32::INFINITY, |m, &d| m.min(d));
            }
        });
        let mut z = vec![f32::INFINITY; w * h];
        z.par_chunks_mut(w).enumerate().for_each(|(y, out)| {
            for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                for (o, &d) in out.iter_mut().zip(&rows[yy * w..(yy + 1) * w]) {
                    *o = o.min(d);
                }
            }
        });
        DepthMap {
            width: self.width,
            height: self.height,
            scale: self.scale,
            z,
        }
    }

    /// True if some depth pixel within `r` of `px` is not covered by the mesh: `px` lies near
    /// the mesh's outline in this photograph.
    pub fn near_outline(&self, px: &Point2<f64>, r: u32) -> bool {
        let Some((x, y)) = self.cell(px) else {
            return true;
        };
        if x < r || y < r || x + r >= self.width || y + r >= self.height {
            return false;
        }
        (y - r..=y + r).any(|yy| {
            (x - r..=x + r).any(|xx| self.z[(yy * self.width + xx) as usize].is_infinite())
        })
    }

    /// Photo pixel coordinates (centres) of uncovered depth pixels, every `step`-th one in
    /// each direction: where the background shows.
    pub fn uncovered(&self, step: u32) -> Vec<Point2<f64>> {
        let mut out = Vec::new();
        for y in (0..self.height).step_by(step.max(1) as usize) {
            for x in (0..self.width).step_by(step.max(1) as usize) {
                if self.z[(y * self.width + x) as usize].is_infinite() {
                    out.push(Point2::new(
                        (x as f64 + 0.5) / self.scale,
                        (y as f64 + 0.5) / self.scale,
                    ));
                }
            }
        }
        out
    }
}

/// Every vertex of `mesh` projected into `view`: photo pixel coordinates (centres at +0.5) and
/// camera-frame depth, `None` behind the camera or outside the model's domain.
pub fn project_vertices(mesh: &Mesh, view: &PosedCamera) -> Vec<Option<[f64; 3]>> {
    let mut out = Vec::new();
    project_vertices_into(mesh, view, &mut out);
    out
}

/// [`project_vertices`] into `out`, reusing its memory: at ten million vertices a fresh
/// buffer per photograph is 300 MB of page faults.
pub fn project_vertices_into(mesh: &Mesh, view: &PosedCamera, out: &mut Vec<Option<[f64; 3]>>) {
    out.resize(mesh.positions.len(), None);
    out.par_iter_mut()
        .zip(mesh.positions.par_iter())
        .for_each(|(o, p)| {
            let c = view.pose.transform(p);
            *o = if c.z <= 0.0 {
                None
            } else {
                view.camera.project(&c).map(|px| [px.x, px.y, c.z])
            };
        });
}

/// Calls `put(x, y, depth)` for every pixel centre of rows `r0..=r1` inside the projected
/// triangle `t` (x, y, z per corner), depth interpolated as 1/z (perspective-correct for a
/// pinhole, a close approximation through mild distortion on small triangles).
fn raster_depth(
    t: &[[f64; 3]; 3],
    r0: usize,
    r1: usize,
    width: usize,
    mut put: impl FnMut(usize, usize, f32),
) {
    let [a, b, c] = t;
    // The columns first: many faces of a dense mesh cover no pixel centre, and for them the
    // four divisions below are wasted.
    let xlo = a[0].min(b[0]).min(c[0]);
    let xhi = a[0].max(b[0]).max(c[0]);
    let x0 = (xlo - 0.5).ceil().max(0.0) as usize;
    let x1 = ((xhi - 0.5).floor() as i64).min(width as i64 - 1);
    if x1 < x0 as i64 || r0 > r1 {
        return;
    }
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if area.abs() < 1e-12 {
        return;
    }
    let inv = 1.0 / area;
    let (iza, izb, izc) = (1.0 / a[2], 1.0 / b[2], 1.0 / c[2]);
    for y in r0..=r1 {
        let py = y as f64 + 0.5;
        for x in x0..=x1 as usize {
            let px = x as f64 + 0.5;
            let wa = ((b[0] - px) * (c[1] - py) - (c[0] - px) * (b[1] - py)) * inv;
            let wb = ((c[0] - px) * (a[1] - py) - (a[0] - px) * (c[1] - py)) * inv;
            let wc = 1.0 - wa - wb;
            if wa < 0.0 || wb < 0.0 || wc < 0.0 {
                continue;
            }
            let iz = wa * iza + wb * izb + wc * izc;
            put(x, y, (1.0 / iz) as f32);
        }
    }
}

/// Focal length in pixels near the image centre, measured through the camera model (works for
/// every model, fisheyes included).
pub fn focal_px(view: &PosedCamera) -> f64 {
    let d = 1e-3;
    match (
        view.camera.project(&Vector3::new(0.0, 0.0, 1.0)),
        view.camera.project(&Vector3::new(d, d, 1.0)),
    ) {
        (Some(a), Some(b)) => (b - a).norm() / (d * std::f64::consts::SQRT_2),
        _ => view.camera.width.max(view.camera.height) as f64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Camera, CameraModel, Pose};
    use crate::mesh::VertexId;
    use nalgebra::Point3;

    fn pinhole(w: u32, h: u32, f: f64) -> PosedCamera {
        PosedCamera {
            camera: Camera::new(
                1,
                CameraModel::Pinhole,
                w,
                h,
                vec![f, f, w as f64 / 2.0, h as f64 / 2.0],
            )
            .unwrap(),
            pose: Pose::from_colmap([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        }
    }

    /// Two squares facing the camera at z = 2 and z = 4, the near one covering the left half:
    /// depths are exact (planes parallel to the image), the nearer wins, the rest is empty.
    #[test]
    fn nearest_surface_wins_and_depth_is_exact() {
        let mut m = Mesh::default();
        let quad = |m: &mut Mesh, x0: f64, x1: f64, z: f64| {
            let b = m.positions.len() as u32;
            for (x, y) in [(x0, -1.0), (x1, -1.0), (x1, 1.0), (x0, 1.0)] {
                m.positions.push(Point3::new(x, y, z));
            }
            m.faces
                .push([VertexId(b), VertexId(b + 1), VertexId(b + 2)]);
            m.faces
                .push([VertexId(b), VertexId(b + 2), VertexId(b + 3)]);
        };
        quad(&mut m, -1.0, 0.0, 2.0);
        quad(&mut m, -1.0, 1.0, 4.0);
        let view = pinhole(200, 100, 50.0);
        let d = DepthMap::render(&m, &view, 1000);
        assert_eq!((d.width, d.height, d.scale), (200, 100, 1.0));
        // Left of centre: near square (covers x in [-25, 0] px from the centre at z = 2).
        assert_eq!(d.at(&Point2::new(90.5, 50.5)), 2.0);
        // Right of centre: far square only (x up to +12.5 px at z = 4).
        assert_eq!(d.at(&Point2::new(105.5, 50.5)), 4.0);
        assert!(d.at(&Point2::new(150.5, 50.5)).is_infinite());
        assert!(d.near_outline(&Point2::new(111.5, 50.5), 2));
        assert!(!d.near_outline(&Point2::new(100.5, 50.5), 2));
        // The eroded map is the minimum over each 5x5 window, everywhere.
        assert_eq!(d.eroded(2).at(&Point2::new(101.5, 50.5)), 2.0);
        assert_window_minimum(&d, 2);
        assert!((focal_px(&view) - 50.0).abs() < 1e-6);
        // Rendered in buffers holding another map's depths (and one of another size), the
        // map is the same; the parts' buffers but the first go back.
        let mut spare = SpareBuffers::new(8);
        spare.put([
            vec![0.5f32; 200 * 100],
            vec![0.25f32; 7],
            vec![1.5f32; 200 * 100],
        ]);
        let r = DepthMap::render_projected_reusing(
            &m,
            &view,
            &project_vertices(&m, &view),
            1000,
            &mut spare,
        );
        assert_eq!(r.z, d.z);
        let parts = rayon::current_num_threads()
            .clamp(1, MAX_PARTS)
            .min(m.num_faces());
        assert_eq!(spare.len(), 3 - parts.min(2) + (parts - 1));
    }

    /// `d.eroded(r)` against the minimum over each (2r+1)^2 window, brute force.
    fn assert_window_minimum(d: &DepthMap, r: u32) {
        let e = d.eroded(r);
        let (w, h, r) = (d.width as i64, d.height as i64, r as i64);
        for y in 0..h {
            for x in 0..w {
                let mut m = f32::INFINITY;
                for yy in (y - r).max(0)..=(y + r).min(h - 1) {
                    for xx in (x - r).max(0)..=(x + r).min(w - 1) {
                        m = m.min(d.z[(yy * w + xx) as usize]);
                    }
                }
                assert_eq!(e.z[(y * w + x) as usize], m, "radius {r} at {x},{y}");
            }
        }
    }

    /// Erosion is the window minimum at every pixel, borders included, for the merge's
    /// radius 1 (a path of its own) and others, on maps with random depths and holes.
    #[test]
    fn erosion_is_the_window_minimum_at_every_pixel() {
        let mut rng = crate::rng::SplitMix64::new(3);
        for (w, h) in [(1, 1), (2, 5), (3, 3), (17, 9)] {
            let z = (0..w * h)
                .map(|_| {
                    let v = rng.range(1.0, 9.0) as f32;
                    if v > 8.0 {
                        f32::INFINITY
                    } else {
                        v
                    }
                })
                .collect();
            let d = DepthMap {
                width: w as u32,
                height: h as u32,
                scale: 1.0,
                z,
            };
            for r in 0..=3 {
                assert_window_minimum(&d, r);
            }
        }
    }
}
