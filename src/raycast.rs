//! A mesh prepared for ray casting: its triangles in a [`Bvh`], nearest hits with
//! barycentrics, interpolated normals. Binding (the paper's occlusion test), the renderer and
//! the scene generator cast rays through it.

use crate::bvh::{ray_triangle, Aabb, Bvh};
use crate::mesh::{FaceId, Mesh};
use nalgebra::{Point3, Vector2, Vector3};

/// A mesh prepared for ray casting.
pub struct RayMesh<'a> {
    pub(crate) mesh: &'a Mesh,
    bvh: Bvh,
    normals: Vec<Vector3<f64>>,
}

/// The nearest surface point along a ray.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    /// The face hit.
    pub face: FaceId,
    /// Distance along the (unit) ray.
    pub t: f64,
    /// Barycentric weights of the three corners.
    pub bary: [f64; 3],
}

impl<'a> RayMesh<'a> {
    /// Builds the BVH over the mesh's triangles.
    pub fn new(mesh: &'a Mesh) -> Self {
        let boxes: Vec<Aabb> = (0..mesh.num_faces())
            .map(|f| Aabb::of(&mesh.triangle(FaceId(f as u32))))
            .collect();
        let normals = match &mesh.normals {
            Some(n) => n.iter().map(|v| v.cast()).collect(),
            None => mesh.vertex_normals(),
        };
        RayMesh {
            mesh,
            bvh: Bvh::build(&boxes),
            normals,
        }
    }

    /// Nearest hit of the ray `o + t d` (d unit), if any.
    pub fn intersect(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        self.bvh.cast(o, d, f64::INFINITY, |p, t_max| {
            let (t, b1, b2) = ray_triangle(o, d, &self.mesh.triangle(FaceId(p)))?;
            // Ties broken by face id so the result does not depend on traversal order.
            let better = t < t_max || (t == t_max && best.is_some_and(|b| p < b.face.0));
            if better {
                best = Some(Hit {
                    face: FaceId(p),
                    t,
                    bary: [1.0 - b1 - b2, b1, b2],
                });
                Some(t)
            } else {
                None
            }
        });
        best
    }

    /// Interpolated unit normal at a hit.
    pub fn normal(&self, h: &Hit) -> Vector3<f64> {
        let f = self.mesh.faces[h.face.idx()];
        let n: Vector3<f64> = (0..3).map(|k| self.normals[f[k].idx()] * h.bary[k]).sum();
        let l = n.norm();
        if l > 0.0 {
            n / l
        } else {
            self.mesh.face_normal_area(h.face).normalize()
        }
    }

    /// Texture coordinate at a point given by barycentrics on face `f`.
    pub(crate) fn uv(&self, f: FaceId, bary: [f64; 3]) -> Option<Vector2<f64>> {
        let uv = self.mesh.uv.as_ref()?;
        let c = uv.faces[f.idx()];
        Some(
            (0..3)
                .map(|k| uv.coords[c[k] as usize].cast::<f64>() * bary[k])
                .sum(),
        )
    }

    /// Barycentrics of the point where the ray meets face `f`'s plane (may be outside the
    /// triangle): used for ray differentials.
    pub(crate) fn plane_bary(
        &self,
        f: FaceId,
        o: &Point3<f64>,
        d: &Vector3<f64>,
    ) -> Option<[f64; 3]> {
        let [a, b, c] = self.mesh.triangle(f);
        let n = (b - a).cross(&(c - a));
        let denom = n.dot(d);
        if denom.abs() < 1e-300 {
            return None;
        }
        let t = n.dot(&(a - o)) / denom;
        let p = o + d * t;
        let nn = n.norm_squared();
        let b1 = (p - a).cross(&(c - a)).dot(&n) / nn;
        let b2 = (b - a).cross(&(p - a)).dot(&n) / nn;
        Some([1.0 - b1 - b2, b1, b2])
    }
}
