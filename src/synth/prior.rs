//! Where the low band starts inside a region: the colour the photographed surface has where
//! its shape is alike, at the same height along "up", the same distance from the object's
//! axis and with the same facing against up. It is trusted only where the photographed
//! surface of that shape is of one colour (a jar's body, a mannequin's skin, a garment's
//! band) and not where its colour changes around the axis (a torus's hue sectors), nor where
//! no photographed surface is of that shape: there the vertex-colour fill stays. The vertex
//! fill alone carries whatever colour lies nearest along the mesh into a region: on the
//! one-sided jar, the lid's grey ran down its body (`docs/decisions.md`, "The low band starts
//! from surface of the same shape").

use crate::mesh::Mesh;
use crate::resample::{FaceClass, Resampled};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use std::num::NonZero;

/// Height along up and distance from the axis, in this fraction of the object's radius (half
/// its bounding box's diagonal), count as one unit of the shape's descriptor.
const PLACE_SCALE: f64 = 0.05;
/// A difference of this much in the cosine between the normal and up counts as one unit.
const FACING_SCALE: f64 = 0.3;
/// Photographed vertices the colour is taken from.
const NEIGHBOURS: usize = 64;
/// Trust halves (to e^-1/2) where the nearest photographed vertex of the same shape is one
/// unit of the descriptor away...
const REACH: f64 = 1.0;
/// ... or where the colours of the photographed vertices of that shape spread by this much
/// (standard deviation, summed over the channels' variances, colour values 0-1).
const SPREAD: f64 = 0.07;

/// The photographed vertices, by their shape's descriptor.
pub(super) struct ShapePrior {
    tree: ImmutableKdTree<f32, 3>,
    colours: Vec<[f32; 3]>,
    frame: Frame,
}

impl ShapePrior {
    /// The prior over the photographed vertices outside the regions (`member` per face):
    /// those of a face whose corners are all bound (not [`FaceClass::Red`]), with their
    /// binding colours.
    pub(super) fn photographed(
        mesh: &Mesh,
        normals: &[Vector3<f64>],
        up: &Vector3<f64>,
        res: &Resampled,
        member: &[bool],
    ) -> Option<ShapePrior> {
        let mut seen = vec![false; mesh.num_vertices()];
        for (f, fv) in mesh.faces.iter().enumerate() {
            if res.classes[f] != FaceClass::Red {
                for v in fv {
                    seen[v.idx()] = true;
                }
            }
        }
        for (f, fv) in mesh.faces.iter().enumerate() {
            if member[f] {
                for v in fv {
                    seen[v.idx()] = false;
                }
            }
        }
        ShapePrior::new(mesh, normals, up, |v| seen[v].then(|| res.vertex_colors[v]))
    }

    /// The prior over the vertices `seen` gives a colour for (the photographed ones outside
    /// the regions), with their unit `normals`; `None` when there are none.
    fn new(
        mesh: &Mesh,
        normals: &[Vector3<f64>],
        up: &Vector3<f64>,
        seen: impl Fn(usize) -> Option<[f32; 3]>,
    ) -> Option<ShapePrior> {
        let (lo, hi) = mesh.bounding_box();
        let frame = Frame {
            centre: nalgebra::center(&lo, &hi),
            unit: ((hi - lo).norm() / 2.0 * PLACE_SCALE).max(1e-300),
            up: *up,
        };
        let mut points = Vec::new();
        let mut colours = Vec::new();
        for (v, p) in mesh.positions.iter().enumerate() {
            if let Some(c) = seen(v) {
                points.push(frame.descriptor(p, &normals[v]));
                colours.push(c);
            }
        }
        if points.is_empty() {
            return None;
        }
        Some(ShapePrior {
            tree: ImmutableKdTree::new_from_slice(&points).ok()?,
            colours,
            frame,
        })
    }

    /// The colour at a point `p` with unit normal `n`: the photographed vertices' of that
    /// shape, blended with `fallback` by how far they lie and how much they disagree.
    pub(super) fn at(&self, p: &Point3<f64>, n: &Vector3<f64>, fallback: [f32; 3]) -> [f32; 3] {
        let k = NonZero::new(NEIGHBOURS.min(self.colours.len())).unwrap_or(NonZero::<usize>::MIN);
        let found = self
            .tree
            .query(&self.frame.descriptor(p, n))
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute();
        let Some(first) = found.first() else {
            return fallback;
        };
        let d0 = first.distance as f64;
        let (mut sum, mut sum2, mut total) = ([0f64; 3], [0f64; 3], 0.0);
        for it in found.iter() {
            // Nearer shapes count more (a Gaussian of unit width, relative to the nearest).
            let w = (-(it.distance as f64 - d0) / 2.0).exp();
            let c = self.colours[it.item as usize];
            for j in 0..3 {
                sum[j] += w * c[j] as f64;
                sum2[j] += w * (c[j] as f64).powi(2);
            }
            total += w;
        }
        let mean = sum.map(|s| s / total);
        let spread: f64 = (0..3)
            .map(|j| sum2[j] / total - mean[j] * mean[j])
            .sum::<f64>()
            .max(0.0);
        let trust = (-d0 / (2.0 * REACH * REACH) - spread / (2.0 * SPREAD * SPREAD)).exp() as f32;
        std::array::from_fn(|j| trust * mean[j] as f32 + (1.0 - trust) * fallback[j])
    }
}

/// The object's axis (along up through its bounding box's centre) and the descriptor's unit.
struct Frame {
    centre: Point3<f64>,
    unit: f64,
    up: Vector3<f64>,
}

impl Frame {
    /// Height along up and distance from the axis in units, facing in [`FACING_SCALE`]s.
    fn descriptor(&self, p: &Point3<f64>, n: &Vector3<f64>) -> [f32; 3] {
        let q = p - self.centre;
        let h = q.dot(&self.up);
        let r = (q - self.up * h).norm();
        [
            (h / self.unit) as f32,
            (r / self.unit) as f32,
            (n.dot(&self.up) / FACING_SCALE) as f32,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{PI, TAU};

    /// A closed tube of radius 1 along z from -1 to 1 (48 around, 24 rings) with flat caps.
    fn can() -> Mesh {
        Mesh::tube(48, 24, true)
    }

    /// The prior over the can's vertices whose angle lies outside the sector `hidden`
    /// (radians from angle 0), each coloured by `paint(angle, z)`.
    fn prior_of(mesh: &Mesh, hidden: f64, paint: impl Fn(f64, f64) -> [f32; 3]) -> ShapePrior {
        let normals = mesh.vertex_normals();
        ShapePrior::new(mesh, &normals, &Vector3::z(), |v| {
            let p = mesh.positions[v];
            let a = p.y.atan2(p.x).rem_euclid(TAU);
            (p.x.hypot(p.y) > 0.5 && a > hidden).then(|| paint(a, p.z))
        })
        .unwrap()
    }

    /// A point on the can's side at angle `a` and height `z`, and its normal.
    fn side(a: f64, z: f64) -> (Point3<f64>, Vector3<f64>) {
        (
            Point3::new(a.cos(), a.sin(), z),
            Vector3::new(a.cos(), a.sin(), 0.0),
        )
    }

    #[test]
    fn bands_around_the_axis_carry_into_the_unseen_side() {
        // Grey above z = 0.5, pink below: a jar's lid on its body. Half the can is hidden;
        // in its middle, far from any photographed vertex, the prior gives each band's colour
        // where the vertex fill would give whatever lies nearest.
        let grey = [0.6, 0.7, 0.65];
        let pink = [0.8, 0.3, 0.45];
        let mesh = can();
        let prior = prior_of(&mesh, PI, |_, z| if z > 0.5 { grey } else { pink });
        let far = [0.0; 3];
        // On rings of vertices (every 1/12), away from the border.
        for (z, want) in [(0.75, grey), (0.25, pink), (-0.75, pink)] {
            let (p, n) = side(PI / 2.0, z);
            let got = prior.at(&p, &n, far);
            for j in 0..3 {
                assert!(
                    (got[j] - want[j]).abs() < 0.01,
                    "z {z}: {got:?} against {want:?}"
                );
            }
        }
    }

    #[test]
    fn colours_that_change_around_the_axis_keep_the_fallback() {
        // Hue sectors, as on the sample's torus: the surface of one shape has several colours,
        // so the prior does not decide and the fill's colour stays.
        let mesh = can();
        let prior = prior_of(&mesh, PI, |a, _| {
            let s = (a / (PI / 3.0)) as usize;
            [[0.9, 0.2, 0.2], [0.2, 0.8, 0.2], [0.2, 0.3, 0.9]][s % 3]
        });
        let fill = [0.5, 0.4, 0.3];
        let (p, n) = side(PI / 2.0, 0.0);
        let got = prior.at(&p, &n, fill);
        for j in 0..3 {
            assert!((got[j] - fill[j]).abs() < 0.02, "{got:?} against {fill:?}");
        }
    }

    #[test]
    fn shapes_no_photograph_saw_keep_the_fallback() {
        // Only the side was photographed: the caps face along the axis, a facing no
        // photographed vertex has, so the prior does not reach them.
        let mesh = can();
        let normals = mesh.vertex_normals();
        let prior = ShapePrior::new(&mesh, &normals, &Vector3::z(), |v| {
            let p = mesh.positions[v];
            (p.z.abs() < 0.9).then_some([0.8, 0.3, 0.45])
        })
        .unwrap();
        let fill = [0.2, 0.2, 0.2];
        let got = prior.at(&Point3::new(0.2, 0.1, 1.0), &Vector3::z(), fill);
        for j in 0..3 {
            assert!((got[j] - fill[j]).abs() < 0.02, "{got:?} against {fill:?}");
        }
        assert!(ShapePrior::new(&mesh, &normals, &Vector3::z(), |_| None).is_none());
    }
}
