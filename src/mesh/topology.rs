//! Connectivity of a mesh, in one place: disjoint sets (components, UV islands, holes) and
//! vertex one-rings.

use super::Mesh;
use rayon::slice::ParallelSliceMut;

/// Each vertex's one-ring: the vertices it shares an edge with, sorted, without repeats.
pub fn one_rings(mesh: &Mesh) -> Vec<Vec<u32>> {
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); mesh.num_vertices()];
    for f in &mesh.faces {
        for k in 0..3 {
            let (a, b) = (f[k].0, f[(k + 1) % 3].0);
            nbr[a as usize].push(b);
            nbr[b as usize].push(a);
        }
    }
    for n in &mut nbr {
        n.sort_unstable();
        n.dedup();
    }
    nbr
}

/// No neighbour across this edge (a boundary, or a third face on a non-manifold edge).
pub const NO_FACE: u32 = u32::MAX;

/// Every face's edges (edge k joins corners k and k + 1) as (lower vertex, higher vertex,
/// face, k), sorted: the corners that share an edge lie side by side.
pub fn sorted_edges(mesh: &Mesh) -> Vec<(u32, u32, u32, u8)> {
    let mut edges: Vec<(u32, u32, u32, u8)> = Vec::with_capacity(mesh.faces.len() * 3);
    for (f, fv) in mesh.faces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (fv[k].0, fv[(k + 1) % 3].0);
            edges.push((a.min(b), a.max(b), f as u32, k as u8));
        }
    }
    // The tuples are distinct (one per face corner), so the parallel sort's order is the
    // serial one's whatever the thread count.
    edges.par_sort_unstable();
    edges
}

/// Each face's neighbours across its three edges (edge k joins corners k and k + 1), or
/// [`NO_FACE`]. On a non-manifold edge the faces pair up in index order.
pub fn face_adjacency(mesh: &Mesh) -> Vec<[u32; 3]> {
    let edges = sorted_edges(mesh);
    let mut adj = vec![[NO_FACE; 3]; mesh.faces.len()];
    let mut i = 0;
    while i + 1 < edges.len() {
        let (e, n) = (edges[i], edges[i + 1]);
        if (e.0, e.1) == (n.0, n.1) {
            adj[e.2 as usize][e.3 as usize] = n.2;
            adj[n.2 as usize][n.3 as usize] = e.2;
            i += 2;
        } else {
            i += 1;
        }
    }
    adj
}

/// Disjoint sets with path halving and union by size.
pub struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    /// `n` singleton sets.
    pub fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }

    /// The representative of `x`'s set.
    pub fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] as usize != x {
            let p = self.parent[x] as usize;
            self.parent[x] = self.parent[p];
            x = self.parent[x] as usize;
        }
        x
    }

    /// Joins the sets of `a` and `b`.
    pub fn union(&mut self, a: usize, b: usize) {
        let (mut a, mut b) = (self.find(a), self.find(b));
        if a == b {
            return;
        }
        if self.size[a] < self.size[b] {
            std::mem::swap(&mut a, &mut b);
        }
        self.parent[b] = a as u32;
        self.size[a] += self.size[b];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_rings_of_two_triangles() {
        let m = Mesh {
            positions: vec![nalgebra::Point3::origin(); 4],
            faces: [[0, 1, 2], [2, 1, 3]]
                .iter()
                .map(|f| f.map(crate::mesh::VertexId))
                .collect(),
            ..Default::default()
        };
        assert_eq!(
            one_rings(&m),
            vec![vec![1, 2], vec![0, 2, 3], vec![0, 1, 3], vec![1, 2]]
        );
        // The two faces meet across edge 1-2: edge 1 (corners 1, 2) of face 0, edge 0 of
        // face 1; every other edge is a boundary.
        assert_eq!(
            face_adjacency(&m),
            vec![[NO_FACE, 1, NO_FACE], [0, NO_FACE, NO_FACE]]
        );
        let mut u = UnionFind::new(4);
        u.union(0, 3);
        assert_eq!(u.find(3), u.find(0));
        assert_ne!(u.find(1), u.find(0));
    }
}
