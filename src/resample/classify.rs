//! Triangle classes (green, blue, red), the photographs common to each face's vertices, and the
//! paper's fill of vertex colours for vertices no photograph saw.

use super::*;

/// A short list of photographs per face, in one buffer (`items[offsets[f]..offsets[f + 1]]`).
#[derive(Debug, Default)]
pub(crate) struct FaceLists {
    offsets: Vec<u32>,
    items: Vec<u32>,
}

impl FaceLists {
    /// Appends the next face's list, sorted.
    pub(crate) fn push(&mut self, list: &mut [u32]) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        list.sort_unstable();
        self.items.extend_from_slice(list);
        self.offsets.push(self.items.len() as u32);
    }

    /// Appends the faces of `other`, which follow this one's.
    pub(crate) fn append(&mut self, other: FaceLists) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        let base = *self.offsets.last().unwrap_or(&0);
        self.offsets
            .extend(other.offsets.iter().skip(1).map(|o| o + base));
        self.items.extend(other.items);
    }

    /// Face `f`'s list (empty: no limit).
    pub(crate) fn get(&self, f: usize) -> &[u32] {
        &self.items[self.offsets[f] as usize..self.offsets[f + 1] as usize]
    }
}

/// Faces per task when per-face lists are built.
const FACE_RUN: usize = 8192;

/// `0..nf` cut into runs of [`FACE_RUN`] faces: per-face lists are built a run per task, each
/// into its own [`FaceLists`] through one scratch list, then appended in order (a list per face
/// costs an allocation per face, and collected from a scratch list keeps its capacity).
pub(crate) fn face_runs(nf: usize) -> Vec<std::ops::Range<usize>> {
    (0..nf)
        .step_by(FACE_RUN)
        .map(|s| s..(s + FACE_RUN).min(nf))
        .collect()
}

/// Sorted photographs common to the three vertices of every face, compressed rows.
pub(crate) struct Common {
    lists: FaceLists,
    /// Per face: some photograph is valid at all three vertices (before any face check or
    /// limit), the paper's green test.
    pub(super) all_three: Vec<bool>,
}

impl Common {
    /// Per face, the photographs valid at all three vertices (the paper's common photographs),
    /// or with `any_vertex` those valid at one vertex at least (per-texel occlusion then decides
    /// where on the face each one sees). With `face_check` (threshold), photographs whose face
    /// colour disagrees with the others' are left out of that face's list.
    pub(super) fn new(
        mesh: &Mesh,
        b: &Binding,
        face_check: Option<f32>,
        any_vertex: bool,
        max_views: usize,
    ) -> Self {
        // In runs of faces: a list per face collected from the scratch list kept the
        // scratch's allocation (Rust's in-place collect), up to 1.5 KB per face with 1,000
        // photographs.
        let nf = mesh.num_faces();
        let parts: Vec<(FaceLists, Vec<bool>)> = face_runs(nf)
            .into_par_iter()
            .map(|run| {
                let mut lists = FaceLists::default();
                let mut all = Vec::with_capacity(run.len());
                // Per photograph: colour sum, vertices seeing it, weight sum.
                let mut found: Vec<(u32, [f32; 3], u32, f32)> = Vec::new();
                let mut ids: Vec<u32> = Vec::new();
                for f in &mesh.faces[run] {
                    let views = [f[0].idx(), f[1].idx(), f[2].idx()].map(|v| b.views(v));
                    found.clear();
                    for vs in &views {
                        for s in *vs {
                            match found.iter_mut().find(|e| e.0 == s.photo) {
                                Some(e) => {
                                    (0..3).for_each(|k| e.1[k] += s.color[k]);
                                    e.2 += 1;
                                    e.3 += s.weight;
                                }
                                None => found.push((s.photo, s.color, 1, s.weight)),
                            }
                        }
                    }
                    let all_three = found.iter().any(|e| e.2 == 3);
                    found.retain(|e| any_vertex || e.2 == 3);
                    found.sort_unstable_by_key(|e| e.0);
                    if let Some(t) = face_check {
                        let colors: Vec<[f32; 3]> =
                            found.iter().map(|e| e.1.map(|c| c / e.2 as f32)).collect();
                        let mut ok = consistent(&colors, t).into_iter();
                        found.retain(|_| ok.next().unwrap_or(true));
                    }
                    if max_views > 0 && found.len() > max_views {
                        // Heaviest first, ties by photograph index (deterministic), then back to
                        // photograph order for the binary searches.
                        found.sort_unstable_by(|a, b| b.3.total_cmp(&a.3).then(a.0.cmp(&b.0)));
                        found.truncate(max_views);
                        found.sort_unstable_by_key(|e| e.0);
                    }
                    ids.clear();
                    ids.extend(found.iter().map(|e| e.0));
                    lists.push(&mut ids);
                    all.push(all_three);
                }
                (lists, all)
            })
            .collect();
        let mut common = FaceLists::default();
        let mut all_three = Vec::with_capacity(nf);
        for (l, a) in parts {
            common.append(l);
            all_three.extend(a);
        }
        Common {
            lists: common,
            all_three,
        }
    }

    pub(crate) fn of(&self, f: usize) -> &[u32] {
        self.lists.get(f)
    }
}

/// Classifies every face (green, blue, red).
pub fn classify(mesh: &Mesh, b: &Binding) -> Vec<FaceClass> {
    let common = Common::new(mesh, b, None, false, 0);
    classes_from(mesh, b, &common)
}

pub(super) fn classes_from(mesh: &Mesh, b: &Binding, common: &Common) -> Vec<FaceClass> {
    (0..mesh.num_faces())
        .map(|f| {
            if common.all_three[f] {
                FaceClass::Green
            } else if mesh.faces[f].iter().all(|v| !b.views(v.idx()).is_empty()) {
                FaceClass::Blue
            } else {
                FaceClass::Red
            }
        })
        .collect()
}

/// The paper's fill of unbound vertices: rounds at 80, 60, 40 and 20% of the one-ring
/// coloured, each repeated until nothing changes, then any coloured neighbour; a vertex takes
/// the mean of its coloured neighbours. Rounds update all qualifying vertices at once (the
/// result does not depend on vertex order). Vertices no fill reaches get the mean colour.
pub fn fill_vertex_colors(
    mesh: &Mesh,
    colors: &[Option<[f32; 3]>],
) -> (Vec<[f32; 3]>, [u64; 5], u64) {
    let nv = mesh.num_vertices();
    let nbr = crate::mesh::topology::one_rings(mesh);
    let mut col: Vec<Option<[f32; 3]>> = colors.to_vec();
    let mut per_round = [0u64; 5];
    for (round, p) in [0.8, 0.6, 0.4, 0.2, 0.0].into_iter().enumerate() {
        // Each round starts from every uncoloured vertex; after a pass only the neighbours of
        // what it coloured can have become eligible (a vertex's test reads its ring only).
        let mut candidates: Vec<u32> = (0..nv as u32)
            .filter(|&v| col[v as usize].is_none())
            .collect();
        loop {
            let updates: Vec<(usize, [f32; 3])> = candidates
                .par_iter()
                .map(|&v| v as usize)
                .filter(|&v| col[v].is_none() && !nbr[v].is_empty())
                .filter_map(|v| {
                    let coloured: Vec<[f32; 3]> =
                        nbr[v].iter().filter_map(|&u| col[u as usize]).collect();
                    let frac = coloured.len() as f64 / nbr[v].len() as f64;
                    if coloured.is_empty() || frac < p {
                        return None;
                    }
                    let n = coloured.len() as f32;
                    Some((
                        v,
                        std::array::from_fn(|k| coloured.iter().map(|c| c[k]).sum::<f32>() / n),
                    ))
                })
                .collect();
            if updates.is_empty() {
                break;
            }
            per_round[round] += updates.len() as u64;
            for &(v, c) in &updates {
                col[v] = Some(c);
            }
            candidates = updates
                .iter()
                .flat_map(|&(v, _)| nbr[v].iter().copied())
                .filter(|&u| col[u as usize].is_none())
                .collect();
            candidates.sort_unstable();
            candidates.dedup();
        }
    }
    let known: Vec<[f32; 3]> = col.iter().flatten().copied().collect();
    let mean = if known.is_empty() {
        [0.5; 3]
    } else {
        std::array::from_fn(|k| known.iter().map(|c| c[k]).sum::<f32>() / known.len() as f32)
    };
    let unreachable = col.iter().filter(|c| c.is_none()).count() as u64;
    (
        col.into_iter().map(|c| c.unwrap_or(mean)).collect(),
        per_round,
        unreachable,
    )
}
