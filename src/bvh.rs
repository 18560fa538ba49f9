//! A bounding-volume hierarchy over boxes, geometry-agnostic: the caller supplies the leaf
//! test (house style: like parry's `Bvh::cast_ray(.., primitive_check)`). Used for ray casting
//! in the renderer and, later, occlusion tests in binding.

use nalgebra::{Point3, Vector3};

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Minimum corner.
    pub lo: Point3<f64>,
    /// Maximum corner.
    pub hi: Point3<f64>,
}

impl Aabb {
    /// The empty box (grows to anything it is joined with).
    pub fn empty() -> Self {
        Aabb {
            lo: Point3::from([f64::INFINITY; 3]),
            hi: Point3::from([f64::NEG_INFINITY; 3]),
        }
    }

    /// The smallest box holding `points`.
    pub fn of(points: &[Point3<f64>]) -> Self {
        let mut b = Self::empty();
        for p in points {
            b.grow(p);
        }
        b
    }

    /// Grows the box to hold `p`.
    pub fn grow(&mut self, p: &Point3<f64>) {
        self.lo = self.lo.inf(p);
        self.hi = self.hi.sup(p);
    }

    /// Grows the box to hold `o`.
    pub fn join(&mut self, o: &Aabb) {
        self.lo = self.lo.inf(&o.lo);
        self.hi = self.hi.sup(&o.hi);
    }

    fn centre(&self) -> Point3<f64> {
        nalgebra::center(&self.lo, &self.hi)
    }

    /// Entry distance of the ray into the box within `[0, t_max]`, if it enters.
    fn hit(&self, o: &Point3<f64>, inv_d: &Vector3<f64>, t_max: f64) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, t_max);
        for k in 0..3 {
            let a = (self.lo[k] - o[k]) * inv_d[k];
            let b = (self.hi[k] - o[k]) * inv_d[k];
            let (a, b) = if a <= b { (a, b) } else { (b, a) };
            // NaN (0 * inf) means the ray lies in the slab plane: keep the current interval.
            if a > t0 {
                t0 = a;
            }
            if b < t1 {
                t1 = b;
            }
            if t0 > t1 {
                return None;
            }
        }
        Some(t0)
    }
}

#[derive(Debug, Clone)]
struct Node {
    bounds: Aabb,
    /// Leaf: first index into `order`; inner: index of the left child (right = left + 1).
    first: u32,
    /// Leaf: number of primitives; inner: 0.
    count: u32,
}

/// The hierarchy: built once over primitive boxes, queried with caller-supplied leaf tests.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

const LEAF_SIZE: usize = 4;

impl Bvh {
    /// Builds over `boxes` (primitive i has box i) by median splits on the longest axis of the
    /// centroids: O(n log n), deterministic.
    pub fn build(boxes: &[Aabb]) -> Self {
        let mut order: Vec<u32> = (0..boxes.len() as u32).collect();
        let centres: Vec<Point3<f64>> = boxes.iter().map(Aabb::centre).collect();
        let mut nodes = vec![Node {
            bounds: Aabb::empty(),
            first: 0,
            count: 0,
        }];
        // (node index, start, end) still to split.
        let mut todo = vec![(0usize, 0usize, boxes.len())];
        while let Some((ni, start, end)) = todo.pop() {
            let mut bounds = Aabb::empty();
            let mut cb = Aabb::empty();
            for &i in &order[start..end] {
                bounds.join(&boxes[i as usize]);
                cb.grow(&centres[i as usize]);
            }
            nodes[ni].bounds = bounds;
            if end - start <= LEAF_SIZE {
                nodes[ni].first = start as u32;
                nodes[ni].count = (end - start) as u32;
                continue;
            }
            let ext = cb.hi - cb.lo;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = (start + end) / 2;
            order[start..end].select_nth_unstable_by(mid - start, |&a, &b| {
                centres[a as usize][axis]
                    .total_cmp(&centres[b as usize][axis])
                    .then(a.cmp(&b))
            });
            let left = nodes.len();
            nodes.push(Node {
                bounds: Aabb::empty(),
                first: 0,
                count: 0,
            });
            nodes.push(Node {
                bounds: Aabb::empty(),
                first: 0,
                count: 0,
            });
            nodes[ni].first = left as u32;
            todo.push((left, start, mid));
            todo.push((left + 1, mid, end));
        }
        Bvh { nodes, order }
    }

    /// Walks every leaf primitive whose box the ray `origin + t dir` enters with
    /// `t < t_max`, nearest boxes first. `test(prim, t_max)` returns a closer hit distance to
    /// shrink the search, or `None`. Returns the final `t_max`.
    pub fn cast(
        &self,
        origin: &Point3<f64>,
        dir: &Vector3<f64>,
        mut t_max: f64,
        mut test: impl FnMut(u32, f64) -> Option<f64>,
    ) -> f64 {
        if self.order.is_empty() {
            return t_max;
        }
        let inv = dir.map(|d| 1.0 / d);
        let mut stack: Vec<u32> = Vec::with_capacity(64);
        stack.push(0);
        while let Some(ni) = stack.pop() {
            let n = &self.nodes[ni as usize];
            if n.bounds.hit(origin, &inv, t_max).is_none() {
                continue;
            }
            if n.count > 0 {
                for &p in &self.order[n.first as usize..(n.first + n.count) as usize] {
                    if let Some(t) = test(p, t_max) {
                        if t < t_max {
                            t_max = t;
                        }
                    }
                }
                continue;
            }
            let (l, r) = (n.first, n.first + 1);
            let tl = self.nodes[l as usize].bounds.hit(origin, &inv, t_max);
            let tr = self.nodes[r as usize].bounds.hit(origin, &inv, t_max);
            // Push the farther child first so the nearer is searched first.
            match (tl, tr) {
                (Some(a), Some(b)) => {
                    if a <= b {
                        stack.push(r);
                        stack.push(l);
                    } else {
                        stack.push(l);
                        stack.push(r);
                    }
                }
                (Some(_), None) => stack.push(l),
                (None, Some(_)) => stack.push(r),
                (None, None) => {}
            }
        }
        t_max
    }
}

/// Ray-triangle intersection (Moller-Trumbore): `(t, b1, b2)` with the hit at
/// `(1 - b1 - b2) a + b1 b + b2 c`, both faces counted.
pub fn ray_triangle(
    o: &Point3<f64>,
    d: &Vector3<f64>,
    [a, b, c]: &[Point3<f64>; 3],
) -> Option<(f64, f64, f64)> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(&q) * inv;
    (t > 0.0).then_some((t, u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Nearest hit by the BVH equals the brute-force nearest hit on random triangles and rays.
    #[test]
    fn bvh_hit_equals_brute_force() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let tris: Vec<[Point3<f64>; 3]> = (0..500)
            .map(|_| {
                let c = Point3::new(rnd() * 10.0, rnd() * 10.0, rnd() * 10.0);
                [0, 1, 2].map(|_| c + Vector3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5))
            })
            .collect();
        let bvh = Bvh::build(&tris.iter().map(|t| Aabb::of(t)).collect::<Vec<_>>());
        for _ in 0..2000 {
            let o = Point3::new(rnd() * 12.0 - 1.0, rnd() * 12.0 - 1.0, -2.0);
            let d = Vector3::new(rnd() - 0.5, rnd() - 0.5, 1.0).normalize();
            let brute = tris
                .iter()
                .filter_map(|t| ray_triangle(&o, &d, t).map(|h| h.0))
                .fold(f64::INFINITY, f64::min);
            let fast = bvh.cast(&o, &d, f64::INFINITY, |p, _| {
                ray_triangle(&o, &d, &tris[p as usize]).map(|h| h.0)
            });
            assert_eq!(fast, brute);
        }
    }
}
