//! The order synthesis fills a level in: holes as groups of masked texels whose kernels cannot
//! touch, their distances to known texels, and each hole's schedule (texel and kernel
//! orientation, stalled texels last).

use super::*;

#[derive(Clone, Copy)]
pub(super) struct Rect {
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) x1: usize,
    pub(super) y1: usize,
}

impl Rect {
    pub(super) fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }
    pub(super) fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
    pub(super) fn union(&self, o: &Rect) -> Rect {
        Rect {
            x0: self.x0.min(o.x0),
            y0: self.y0.min(o.y0),
            x1: self.x1.max(o.x1),
            y1: self.y1.max(o.y1),
        }
    }
}

/// Masked texels grouped into holes whose kernels cannot touch one another.
pub(super) fn components(l: &Level) -> Vec<Vec<usize>> {
    let masked: Vec<usize> = (0..l.w * l.h).filter(|&i| l.mask[i]).collect();
    let mut slot = vec![u32::MAX; l.w * l.h];
    for (k, &i) in masked.iter().enumerate() {
        slot[i] = k as u32;
    }
    let mut sets = UnionFind::new(masked.len());
    for (k, &i) in masked.iter().enumerate() {
        // Earlier texels within Chebyshev distance 2 (the kernel's reach).
        for &d in &CAUSAL {
            if let Some(j) = offset(l, i, d) {
                if slot[j] != u32::MAX {
                    sets.union(k, slot[j] as usize);
                }
            }
        }
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut gid = vec![u32::MAX; masked.len()];
    for (k, &i) in masked.iter().enumerate() {
        let r = sets.find(k);
        if gid[r] == u32::MAX {
            gid[r] = groups.len() as u32;
            groups.push(Vec::new());
        }
        groups[gid[r] as usize].push(i);
    }
    groups
}

/// Manhattan distance of every masked texel to the nearest known texel (within the domain).
pub(super) fn distances(l: &Level) -> Vec<u32> {
    let mut d = vec![u32::MAX; l.w * l.h];
    let mut front: Vec<usize> = Vec::new();
    for i in 0..l.w * l.h {
        if l.known(i) {
            d[i] = 0;
            front.push(i);
        }
    }
    let mut next = Vec::new();
    let mut step = 0;
    while !front.is_empty() {
        step += 1;
        next.clear();
        for &i in &front {
            for dd in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
                if let Some(j) = offset(l, i, dd) {
                    if l.mask[j] && d[j] == u32::MAX {
                        d[j] = step;
                        next.push(j);
                    }
                }
            }
        }
        std::mem::swap(&mut front, &mut next);
    }
    d
}

/// A hole's fill order: (texel, orientation) in the order texels become fillable, and the
/// texels that never do. Texels are taken nearest to the known texels first (then in scanline
/// order); one whose kernel fits in no orientation yet waits until a texel within its reach
/// is filled, and comes back behind the front. Waiting texels left when nothing more can be
/// filled are stalled.
pub(super) fn schedule(l: &Level, comp: &[usize], dist: &[u32], slot: &[u32]) -> Schedule {
    // Masked texels within a kernel's reach belong to the same hole (components are built
    // with that reach), so `slot` indexes this hole's own flags.
    let mut avail = vec![false; comp.len()];
    // The priority a waiting texel failed at (u32::MAX: not waiting).
    let mut waiting = vec![u32::MAX; comp.len()];
    let mut heap: BinaryHeap<Reverse<(u32, usize, usize)>> = BinaryHeap::new();
    let mut stalled = Vec::new();
    for &i in comp {
        if dist[i] == u32::MAX {
            stalled.push(i);
        } else {
            heap.push(Reverse((dist[i], i / l.w, i % l.w)));
        }
    }
    let is_avail =
        |j: usize, avail: &[bool]| l.known(j) || (slot[j] != u32::MAX && avail[slot[j] as usize]);
    let mut order = Vec::with_capacity(comp.len());
    // Retrying a texel at every step of the front (the earlier scheme) popped the corset's
    // texels 13 times each, 56 in its largest hole.
    while let Some(Reverse((d, y, x))) = heap.pop() {
        let i = y * l.w + x;
        let fit = (0..8).find(|&o| {
            kernel(l, i, o).is_some_and(|k| k.iter().all(|&j| l.domain[j] && is_avail(j, &avail)))
        });
        let Some(o) = fit else {
            waiting[slot[i] as usize] = d;
            continue;
        };
        order.push((i, o as u8));
        avail[slot[i] as usize] = true;
        // Only a texel within Chebyshev distance 2 (a kernel's reach) can fit now where it
        // did not before.
        for dy in -2..=2 {
            for dx in -2..=2 {
                let Some(j) = offset(l, i, (dx, dy)) else {
                    continue;
                };
                if slot[j] == u32::MAX {
                    continue;
                }
                let w = &mut waiting[slot[j] as usize];
                if *w != u32::MAX {
                    heap.push(Reverse(((*w + 1).max(d), j / l.w, j % l.w)));
                    *w = u32::MAX;
                }
            }
        }
    }
    stalled.extend(
        comp.iter()
            .filter(|&&i| waiting[slot[i] as usize] != u32::MAX),
    );
    stalled.sort_unstable();
    (order, stalled)
}
