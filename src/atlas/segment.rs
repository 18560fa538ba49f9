//! Chart segmentation: cuts any triangle mesh into charts that are topological disks, each
//! bounded in normal deviation so it flattens with low stretch (issue 4, step 1).
//!
//! Charts grow greedily from seeds across manifold, consistently oriented edges while the face
//! normal stays within `max_angle` of the chart's mean normal; the cheapest candidate (normal
//! deviation plus added boundary length) is taken first. A chart that is not a disk (Euler
//! characteristic other than 1, several boundary loops, or a pinched boundary vertex) is split
//! in two from its two mutually farthest faces, recursively; a single triangle is always a
//! disk, so this terminates. Non-manifold and inconsistently oriented edges are never crossed,
//! so they become chart borders and never cause a failure.

use crate::mesh::{FaceId, Mesh};
use nalgebra::Vector3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

/// Options for [`segment`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentOptions {
    /// Largest angle, in degrees, between a face normal and its chart's mean normal.
    /// Default: 65.
    pub max_angle: f64,
    /// Weight of the boundary-length term against the normal term when choosing the next face
    /// (higher gives rounder charts and shorter seams). Default: 0.5.
    pub compactness: f64,
    /// Charts with fewer faces are merged into the neighbour they share most edges with when
    /// the union is still a disk, whatever its normal deviation: slivers of noisy scans
    /// otherwise become hundreds of tiny charts, each a seam. Default: 24.
    pub min_faces: usize,
    /// Rounds of averaging face normals with their neighbours before the normal test.
    /// Default: 3.
    pub smoothing: usize,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions {
            max_angle: 65.0,
            compactness: 0.5,
            min_faces: 24,
            smoothing: 3,
        }
    }
}

/// The charts of a mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct Charts {
    /// For each face, its chart.
    pub face_chart: Vec<u32>,
    /// For each chart, its faces in growth order.
    pub charts: Vec<Vec<FaceId>>,
}

/// Face adjacency across manifold, consistently oriented edges.
pub struct Adjacency {
    /// `neighbours[f][k]`: the face across edge k (corners k, k+1) of face f, if crossable.
    pub neighbours: Vec<[Option<u32>; 3]>,
}

impl Adjacency {
    /// Builds the adjacency of `mesh`.
    pub fn new(mesh: &Mesh) -> Self {
        // An edge's corners lie side by side in the sorted edges, so one sweep pairs them
        // (binary searches for each half-edge and its twin took twice as long on 1.5M faces).
        let edges = crate::mesh::topology::sorted_edges(mesh);
        let mut neighbours = vec![[None; 3]; mesh.num_faces()];
        let forward = |f: u32, k: u8| {
            let face = &mesh.faces[f as usize];
            face[k as usize].0 < face[(k as usize + 1) % 3].0
        };
        for group in edges.chunk_by(|p, q| (p.0, p.1) == (q.0, q.1)) {
            match *group {
                // Manifold and consistently oriented: exactly this half-edge and one twin
                // running the other way.
                [(a, b, f, k), (_, _, g, l)] if a != b && forward(f, k) != forward(g, l) => {
                    neighbours[f as usize][k as usize] = Some(g);
                    neighbours[g as usize][l as usize] = Some(f);
                }
                // A degenerate edge (both ends the same vertex) is its own twin.
                [(a, b, f, k)] if a == b => neighbours[f as usize][k as usize] = Some(f),
                _ => {}
            }
        }
        Adjacency { neighbours }
    }
}

/// Cuts `mesh` into disk-shaped charts.
pub fn segment(mesh: &Mesh, opts: &SegmentOptions) -> Charts {
    segment_with(mesh, &Adjacency::new(mesh), opts)
}

/// [`segment`] with the mesh's adjacency already built.
pub fn segment_with(mesh: &Mesh, adj: &Adjacency, opts: &SegmentOptions) -> Charts {
    let normals: Vec<Vector3<f64>> = (0..mesh.num_faces())
        .into_par_iter()
        .map(|f| mesh.face_normal_area(FaceId(f as u32)))
        .collect();
    // Scans are noisy: test the normal cone on face normals smoothed over a few rings of
    // neighbours (area weighted), so single noisy triangles do not start charts of their own.
    let mut smooth = normals.clone();
    for _ in 0..opts.smoothing {
        smooth = (0..mesh.num_faces())
            .into_par_iter()
            .map(|f| {
                smooth[f]
                    + adj.neighbours[f]
                        .iter()
                        .flatten()
                        .map(|g| smooth[*g as usize])
                        .sum::<Vector3<f64>>()
            })
            .collect();
    }
    let unit: Vec<Vector3<f64>> = smooth
        .iter()
        .map(|n| n.try_normalize(0.0).unwrap_or_else(Vector3::z))
        .collect();
    let edge_len = |f: usize, k: usize| {
        let face = mesh.faces[f];
        (mesh.positions[face[(k + 1) % 3].idx()] - mesh.positions[face[k].idx()]).norm()
    };
    let mean_edge = {
        let total: f64 = (0..mesh.num_faces())
            .map(|f| (0..3).map(|k| edge_len(f, k)).sum::<f64>())
            .sum();
        (total / (3 * mesh.num_faces().max(1)) as f64).max(1e-300)
    };
    let cos_max = opts.max_angle.to_radians().cos();
    let mut chart_of = vec![u32::MAX; mesh.num_faces()];
    let mut grown: Vec<Vec<FaceId>> = Vec::new();
    for seed in 0..mesh.num_faces() {
        if chart_of[seed] != u32::MAX {
            continue;
        }
        let id = grown.len() as u32;
        let mut faces = vec![FaceId(seed as u32)];
        chart_of[seed] = id;
        let mut sum_n = unit[seed] * normals[seed].norm();
        let mut heap: BinaryHeap<Reverse<(u64, u32)>> = BinaryHeap::new();
        let push = |heap: &mut BinaryHeap<Reverse<(u64, u32)>>,
                    chart_of: &[u32],
                    f: usize,
                    sum_n: &Vector3<f64>| {
            for nb in adj.neighbours[f].iter().flatten() {
                let g = *nb as usize;
                if chart_of[g] != u32::MAX {
                    continue;
                }
                let dir = sum_n.try_normalize(0.0).unwrap_or(unit[f]);
                let dev = 1.0 - unit[g].dot(&dir);
                // Boundary change if g joins: its edges already bordering the chart become
                // interior, the others become boundary.
                let (mut inner, mut outer) = (0.0, 0.0);
                for k in 0..3 {
                    match adj.neighbours[g][k] {
                        Some(h) if chart_of[h as usize] == chart_of[f] => inner += edge_len(g, k),
                        _ => outer += edge_len(g, k),
                    }
                }
                let cost = dev + opts.compactness * (outer - inner) / mean_edge * 0.1;
                // Costs are compared as ordered bits of a non-negative shifted value.
                let key = ((cost + 10.0).max(0.0)).to_bits();
                heap.push(Reverse((key, g as u32)));
            }
        };
        push(&mut heap, &chart_of, seed, &sum_n);
        while let Some(Reverse((_, g))) = heap.pop() {
            let g = g as usize;
            if chart_of[g] != u32::MAX {
                continue;
            }
            let dir = sum_n.try_normalize(0.0).unwrap_or(unit[seed]);
            if unit[g].dot(&dir) < cos_max {
                continue;
            }
            chart_of[g] = id;
            faces.push(FaceId(g as u32));
            sum_n += unit[g] * normals[g].norm();
            push(&mut heap, &chart_of, g, &sum_n);
        }
        grown.push(faces);
    }
    // Make every chart a disk: each grown chart's splits are its own, so the charts are cut
    // side by side and their pieces concatenated in the grown charts' order.
    let charts: Vec<Vec<FaceId>> = grown
        .into_par_iter()
        .with_max_len(1)
        .flat_map_iter(|c| {
            let mut pieces = Vec::new();
            let mut todo = vec![c];
            while let Some(c) = todo.pop() {
                if is_disk(mesh, adj, &c) {
                    pieces.push(c);
                } else {
                    let (a, b) = split(adj, &c);
                    todo.push(b);
                    todo.push(a);
                }
            }
            pieces
        })
        .collect();
    let charts = merge_small(mesh, adj, charts, opts.min_faces);
    let mut face_chart = vec![0u32; mesh.num_faces()];
    for (i, c) in charts.iter().enumerate() {
        for f in c {
            face_chart[f.idx()] = i as u32;
        }
    }
    Charts { face_chart, charts }
}

/// Merges charts under `min_faces` faces into the neighbouring chart they share most edges
/// with, when the union is a disk. Deterministic: smallest charts first, ties by index.
fn merge_small(
    mesh: &Mesh,
    adj: &Adjacency,
    mut charts: Vec<Vec<FaceId>>,
    min_faces: usize,
) -> Vec<Vec<FaceId>> {
    let mut sets = StampedSets::new(mesh.num_faces(), mesh.num_vertices());
    let mut owner = vec![0usize; mesh.num_faces()];
    for (i, c) in charts.iter().enumerate() {
        for f in c {
            owner[f.idx()] = i;
        }
    }
    loop {
        let mut order: Vec<usize> = (0..charts.len())
            .filter(|&i| !charts[i].is_empty() && charts[i].len() < min_faces)
            .collect();
        order.sort_by_key(|&i| (charts[i].len(), i));
        let mut changed = false;
        for i in order {
            if charts[i].is_empty() || charts[i].len() >= min_faces {
                continue;
            }
            let mut shared: FxHashMap<usize, usize> = FxHashMap::default();
            for f in &charts[i] {
                for g in adj.neighbours[f.idx()].iter().flatten() {
                    let o = owner[*g as usize];
                    if o != i {
                        *shared.entry(o).or_insert(0) += 1;
                    }
                }
            }
            let mut cands: Vec<(usize, usize)> = shared.into_iter().collect();
            cands.sort_by_key(|&(o, n)| (Reverse(n), o));
            for (o, _) in cands {
                let union: Vec<FaceId> = charts[o].iter().chain(&charts[i]).copied().collect();
                if disk_test(mesh, adj, &union, &mut sets) {
                    for f in &charts[i] {
                        owner[f.idx()] = o;
                    }
                    charts[o] = union;
                    charts[i].clear();
                    changed = true;
                    break;
                }
            }
        }
        if !changed {
            break;
        }
    }
    charts.retain(|c| !c.is_empty());
    charts
}

/// True if the faces form a topological disk: connected through crossable edges, Euler
/// characteristic 1, one boundary loop, and every boundary vertex on exactly two boundary edges
/// (no pinch).
pub fn is_disk(mesh: &Mesh, adj: &Adjacency, faces: &[FaceId]) -> bool {
    disk_test(mesh, adj, faces, &mut HashedSets::default())
}

/// The sets one disk test keeps: faces in the chart and reached, vertices with their
/// boundary degree, and each boundary edge's end by its start.
trait DiskSets {
    /// Empties every set.
    fn clear(&mut self);
    fn add_member(&mut self, f: u32);
    fn is_member(&self, f: u32) -> bool;
    /// Marks `f` reached; true the first time.
    fn reach(&mut self, f: u32) -> bool;
    fn reached(&self) -> usize;
    fn add_vertex(&mut self, v: u32);
    fn vertices(&self) -> usize;
    /// Adds one to a vertex's boundary degree (the vertex was added).
    fn bump(&mut self, v: u32);
    /// True if some vertex has a boundary degree other than 0 and 2.
    fn bad_degree(&self) -> bool;
    /// Records the boundary edge `a -> b`; false if `a` already starts one.
    fn set_next(&mut self, a: u32, b: u32) -> bool;
    fn next(&self, a: u32) -> Option<u32>;
}

/// [`DiskSets`] in hash maps: for a single test, which touches only the chart's faces.
#[derive(Default)]
struct HashedSets {
    member: FxHashMap<u32, ()>,
    reached: FxHashMap<u32, ()>,
    degree: FxHashMap<u32, u32>,
    next: FxHashMap<u32, u32>,
}

impl DiskSets for HashedSets {
    fn clear(&mut self) {
        self.member.clear();
        self.reached.clear();
        self.degree.clear();
        self.next.clear();
    }
    fn add_member(&mut self, f: u32) {
        self.member.insert(f, ());
    }
    fn is_member(&self, f: u32) -> bool {
        self.member.contains_key(&f)
    }
    fn reach(&mut self, f: u32) -> bool {
        self.reached.insert(f, ()).is_none()
    }
    fn reached(&self) -> usize {
        self.reached.len()
    }
    fn add_vertex(&mut self, v: u32) {
        self.degree.entry(v).or_insert(0);
    }
    fn vertices(&self) -> usize {
        self.degree.len()
    }
    fn bump(&mut self, v: u32) {
        *self
            .degree
            .get_mut(&v)
            .expect("boundary vertices are the faces'") += 1;
    }
    fn bad_degree(&self) -> bool {
        self.degree.values().any(|&d| d != 0 && d != 2)
    }
    fn set_next(&mut self, a: u32, b: u32) -> bool {
        self.next.insert(a, b).is_none()
    }
    fn next(&self, a: u32) -> Option<u32> {
        self.next.get(&a).copied()
    }
}

/// [`DiskSets`] in arrays over the whole mesh, marked with a stamp per test: for many tests in
/// a row, where most of the time went into hashing a large chart's faces again for every small
/// chart merged into it (`merge_small`: 2.0 CPU s of the 1.5M-face scene's atlas, on one
/// core).
struct StampedSets {
    stamp: u32,
    member: Vec<u32>,
    reached: Vec<u32>,
    n_reached: usize,
    vertex: Vec<u32>,
    degree: Vec<u32>,
    touched: Vec<u32>,
    next_stamp: Vec<u32>,
    next: Vec<u32>,
}

impl StampedSets {
    fn new(faces: usize, vertices: usize) -> StampedSets {
        StampedSets {
            stamp: 0,
            member: vec![0; faces],
            reached: vec![0; faces],
            n_reached: 0,
            vertex: vec![0; vertices],
            degree: vec![0; vertices],
            touched: Vec::new(),
            next_stamp: vec![0; vertices],
            next: vec![0; vertices],
        }
    }
}

impl DiskSets for StampedSets {
    fn clear(&mut self) {
        if self.stamp == u32::MAX {
            for v in [
                &mut self.member,
                &mut self.reached,
                &mut self.vertex,
                &mut self.next_stamp,
            ] {
                v.fill(0);
            }
            self.stamp = 0;
        }
        self.stamp += 1;
        self.n_reached = 0;
        self.touched.clear();
    }
    fn add_member(&mut self, f: u32) {
        self.member[f as usize] = self.stamp;
    }
    fn is_member(&self, f: u32) -> bool {
        self.member[f as usize] == self.stamp
    }
    fn reach(&mut self, f: u32) -> bool {
        let first = self.reached[f as usize] != self.stamp;
        self.reached[f as usize] = self.stamp;
        self.n_reached += usize::from(first);
        first
    }
    fn reached(&self) -> usize {
        self.n_reached
    }
    fn add_vertex(&mut self, v: u32) {
        if self.vertex[v as usize] != self.stamp {
            self.vertex[v as usize] = self.stamp;
            self.degree[v as usize] = 0;
            self.touched.push(v);
        }
    }
    fn vertices(&self) -> usize {
        self.touched.len()
    }
    fn bump(&mut self, v: u32) {
        debug_assert_eq!(self.vertex[v as usize], self.stamp);
        self.degree[v as usize] += 1;
    }
    fn bad_degree(&self) -> bool {
        self.touched.iter().any(|&v| {
            let d = self.degree[v as usize];
            d != 0 && d != 2
        })
    }
    fn set_next(&mut self, a: u32, b: u32) -> bool {
        let fresh = self.next_stamp[a as usize] != self.stamp;
        self.next_stamp[a as usize] = self.stamp;
        self.next[a as usize] = b;
        fresh
    }
    fn next(&self, a: u32) -> Option<u32> {
        (self.next_stamp[a as usize] == self.stamp).then(|| self.next[a as usize])
    }
}

/// [`is_disk`] with its sets in `sets`.
fn disk_test(mesh: &Mesh, adj: &Adjacency, faces: &[FaceId], sets: &mut impl DiskSets) -> bool {
    if faces.is_empty() {
        return false;
    }
    sets.clear();
    for f in faces {
        sets.add_member(f.0);
    }
    // Connected through crossable edges inside the chart.
    let mut queue = VecDeque::from([faces[0].0]);
    sets.reach(faces[0].0);
    while let Some(f) = queue.pop_front() {
        for g in adj.neighbours[f as usize].iter().flatten() {
            if sets.is_member(*g) && sets.reach(*g) {
                queue.push_back(*g);
            }
        }
    }
    if sets.reached() != faces.len() {
        return false;
    }
    // Edges: interior if crossable to a member, else boundary.
    let (mut interior2, mut boundary) = (0usize, Vec::new());
    for f in faces {
        let face = mesh.faces[f.idx()];
        for k in 0..3 {
            sets.add_vertex(face[k].0);
            match adj.neighbours[f.idx()][k] {
                Some(g) if sets.is_member(g) => interior2 += 1,
                _ => boundary.push((face[k].0, face[(k + 1) % 3].0)),
            }
        }
    }
    let edges = interior2 / 2 + boundary.len();
    let euler = sets.vertices() as i64 - edges as i64 + faces.len() as i64;
    if euler != 1 || boundary.is_empty() {
        return false;
    }
    for &(a, b) in &boundary {
        sets.bump(a);
        sets.bump(b);
    }
    if sets.bad_degree() {
        return false;
    }
    // One loop: walk it from the first boundary edge.
    for &(a, b) in &boundary {
        if !sets.set_next(a, b) {
            return false;
        }
    }
    let start = boundary[0].0;
    let (mut v, mut steps) = (start, 0);
    loop {
        match sets.next(v) {
            Some(w) => {
                v = w;
                steps += 1;
            }
            None => return false,
        }
        if v == start || steps > boundary.len() {
            break;
        }
    }
    v == start && steps == boundary.len()
}

/// Splits a chart in two by growing from its two mutually farthest faces (breadth first over
/// crossable edges, alternating), so both parts are connected and non-empty.
pub fn split(adj: &Adjacency, faces: &[FaceId]) -> (Vec<FaceId>, Vec<FaceId>) {
    let member: FxHashMap<u32, usize> = faces.iter().enumerate().map(|(i, f)| (f.0, i)).collect();
    let farthest = |from: u32| -> u32 {
        let mut dist: FxHashMap<u32, u32> = FxHashMap::from_iter([(from, 0)]);
        let mut queue = VecDeque::from([from]);
        let mut last = from;
        while let Some(f) = queue.pop_front() {
            last = f;
            for g in adj.neighbours[f as usize].iter().flatten() {
                if member.contains_key(g) && !dist.contains_key(g) {
                    dist.insert(*g, dist[&f] + 1);
                    queue.push_back(*g);
                }
            }
        }
        last
    };
    let a = farthest(faces[0].0);
    let mut b = farthest(a);
    if b == a {
        // Disconnected (through crossable edges): take any other face as the second seed.
        b = faces
            .iter()
            .map(|f| f.0)
            .find(|&f| f != a)
            .expect("a chart to split has two faces");
    }
    let mut owner: FxHashMap<u32, u8> = FxHashMap::from_iter([(a, 0), (b, 1)]);
    let mut queues = [VecDeque::from([a]), VecDeque::from([b])];
    while !queues[0].is_empty() || !queues[1].is_empty() {
        for (side, queue) in queues.iter_mut().enumerate() {
            if let Some(f) = queue.pop_front() {
                for g in adj.neighbours[f as usize].iter().flatten() {
                    if member.contains_key(g) && !owner.contains_key(g) {
                        owner.insert(*g, side as u8);
                        queue.push_back(*g);
                    }
                }
            }
        }
    }
    let (mut pa, mut pb) = (Vec::new(), Vec::new());
    for f in faces {
        match owner.get(&f.0) {
            Some(0) => pa.push(*f),
            Some(_) => pb.push(*f),
            // Unreached (another crossable component): its own chart later, via `b`'s side.
            None => pb.push(*f),
        }
    }
    (pa, pb)
}

#[cfg(test)]
mod tests {
    use super::super::test_meshes::icosphere;
    use super::*;
    use crate::atlas::test_meshes::{two_copies, with_fins, with_holes};

    /// The adjacency by its definition: for each half-edge, the one face with the reverse
    /// half-edge, if this half-edge and its reverse each occur once.
    fn adjacency_by_search(mesh: &Mesh) -> Vec<[Option<u32>; 3]> {
        let mut half: Vec<(u32, u32, u32)> = Vec::new();
        for (f, face) in mesh.faces.iter().enumerate() {
            for k in 0..3 {
                half.push((face[k].0, face[(k + 1) % 3].0, f as u32));
            }
        }
        half.sort_unstable();
        let count = |a: u32, b: u32| {
            let lo = half.partition_point(|h| (h.0, h.1) < (a, b));
            let hi = half.partition_point(|h| (h.0, h.1) <= (a, b));
            (hi - lo, (hi > lo).then(|| half[lo].2))
        };
        mesh.faces
            .iter()
            .map(|face| {
                std::array::from_fn(|k| {
                    let (a, b) = (face[k].0, face[(k + 1) % 3].0);
                    match (count(a, b).0, count(b, a)) {
                        (1, (1, Some(g))) => Some(g),
                        _ => None,
                    }
                })
            })
            .collect()
    }

    #[test]
    fn adjacency_pairs_each_manifold_edge_with_its_twin_only() {
        let mut m = with_fins(&icosphere(2), 5, 7, 1.2);
        // A flipped face, a degenerate face and a duplicated face, besides the fins'
        // non-manifold edges.
        m.faces[3].swap(0, 1);
        let (a, b) = (m.faces[7][0], m.faces[7][1]);
        m.faces.push([a, a, b]);
        let dup = m.faces[11];
        m.faces.push(dup);
        let adj = Adjacency::new(&m);
        assert_eq!(adj.neighbours, adjacency_by_search(&m));
        let crossable = adj.neighbours.iter().flatten().flatten().count();
        assert!(crossable > 3 * 300, "{crossable} crossable edges");
    }

    fn check(mesh: &Mesh) -> Charts {
        let c = segment(mesh, &SegmentOptions::default());
        let adj = Adjacency::new(mesh);
        let mut count = vec![0; mesh.num_faces()];
        for (i, chart) in c.charts.iter().enumerate() {
            assert!(is_disk(mesh, &adj, chart), "chart {i} is not a disk");
            for f in chart {
                count[f.idx()] += 1;
                assert_eq!(c.face_chart[f.idx()], i as u32);
            }
        }
        assert!(
            count.iter().all(|&n| n == 1),
            "every face in exactly one chart"
        );
        c
    }

    #[test]
    fn stamped_and_hashed_disk_tests_agree() {
        // Random face sets grown from seeds (disks, annuli, pinches, several pieces), some
        // with a duplicated face, on closed, holed and non-manifold meshes; one set of
        // stamped arrays serves every test in turn, as in `merge_small`. Its stamp starts
        // near the top, so the wrap-around is crossed too.
        let sphere = icosphere(3);
        let mut nm = with_fins(&sphere, 3, 50, 1.5);
        nm.faces[7] = [nm.faces[7][0], nm.faces[7][2], nm.faces[7][1]];
        let meshes = [sphere.clone(), with_holes(&sphere, 17), nm];
        let mut rng = crate::rng::SplitMix64::new(11);
        let (mut disks, mut others) = (0, 0);
        for mesh in &meshes {
            let adj = Adjacency::new(mesh);
            let mut stamped = StampedSets::new(mesh.num_faces(), mesh.num_vertices());
            stamped.stamp = u32::MAX - 20;
            for t in 0..200 {
                let n = mesh.num_faces();
                let want = 1 + (rng.next_u64() % 60) as usize;
                let mut faces: Vec<FaceId> = Vec::new();
                let mut queue = VecDeque::new();
                for _ in 0..1 + t % 3 {
                    queue.push_back((rng.next_u64() % n as u64) as u32);
                }
                let mut taken = vec![false; n];
                while let Some(f) = queue.pop_front() {
                    if faces.len() >= want || taken[f as usize] {
                        continue;
                    }
                    taken[f as usize] = true;
                    faces.push(FaceId(f));
                    for g in adj.neighbours[f as usize].iter().flatten() {
                        if !rng.next_u64().is_multiple_of(4) {
                            queue.push_back(*g);
                        }
                    }
                }
                if t % 17 == 0 {
                    faces.push(faces[0]);
                }
                let hashed = is_disk(mesh, &adj, &faces);
                assert_eq!(
                    disk_test(mesh, &adj, &faces, &mut stamped),
                    hashed,
                    "set {t}"
                );
                if hashed {
                    disks += 1;
                } else {
                    others += 1;
                }
            }
        }
        assert!(disks > 50 && others > 50, "{disks} disks, {others} others");
    }

    #[test]
    fn sphere_torus_components_holes_and_non_manifold_all_give_disks() {
        let sphere = icosphere(3);
        let c = check(&sphere);
        assert!(
            c.charts.len() >= 2 && c.charts.len() <= 40,
            "{} charts",
            c.charts.len()
        );

        let (torus, _) = crate::sample::dented_torus(60, 24, (8, 8));
        check(&torus);

        // Two components.
        let two = two_copies(&sphere, Vector3::new(3.0, 0.0, 0.0));
        let c = check(&two);
        let first = |f: &FaceId| f.idx() < sphere.num_faces();
        assert!(c
            .charts
            .iter()
            .all(|ch| ch.iter().all(|f| first(f) == first(&ch[0]))));

        // Holes.
        check(&with_holes(&sphere, 17));

        // Non-manifold: fins on three edges, and one face flipped.
        let mut nm = with_fins(&sphere, 3, 50, 1.5);
        nm.faces[7] = [nm.faces[7][0], nm.faces[7][2], nm.faces[7][1]];
        check(&nm);
    }

    #[test]
    fn a_flat_disk_stays_one_chart_and_segmentation_is_deterministic() {
        let mut m = icosphere(2);
        // Flatten the upper cap onto a plane: keep faces with all vertices above y = 0.5.
        m.faces
            .retain(|f| f.iter().all(|v| m.positions[v.idx()].y > 0.5));
        for p in &mut m.positions {
            p.y = 1.0;
        }
        let c = check(&m);
        assert_eq!(c.charts.len(), 1);
        let sphere = icosphere(3);
        assert_eq!(
            segment(&sphere, &SegmentOptions::default()),
            segment(&sphere, &SegmentOptions::default())
        );
    }
}
