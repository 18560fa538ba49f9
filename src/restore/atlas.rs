//! Stage 5 on the atlas: which texels to restore (unseen, in charts with seen texels, in
//! holes of at most `max_hole`), restored in independent crops in parallel, faded into the
//! vertex colours at chart borders; what is left goes on as [`Unrestored`].

use super::regions::{self, UnseenRegion};
use super::*;
use crate::planar::BitMask;

/// The unseen texels restoration did not fill, handed on for exemplar synthesis (stage 6) and
/// drawn by `--debug-dir` (`restore.png`). One bit per atlas texel, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Unrestored {
    /// Atlas side in texels.
    pub size: usize,
    /// Texels of unseen atlas holes larger than `max_hole`, left for stage 6 (they keep
    /// their vertex colours when it is off).
    pub too_large: BitMask,
    /// Unseen texels of charts no photograph saw at all: nothing in 2D to restore them from.
    pub unreachable: BitMask,
    /// Unseen texels of regions deeper than the depth limit, left for stage 6 before
    /// restoration ran.
    pub deep: BitMask,
    /// The texture's feature scale, texels ([`regions::feature_scale`]).
    pub feature_scale: f64,
    /// Every region handed to stage 6: deep, too large or unreachable, as faces.
    pub regions: Vec<UnseenRegion>,
    /// The mesh's face adjacency ([`crate::mesh::topology::face_adjacency`]) when there are
    /// regions (found with it), so that stage 6 need not build it again; empty otherwise.
    pub adjacency: Vec<[u32; 3]>,
}

/// What stage 5 did to each texel: grey where photographs coloured it, green where it was
/// restored, blue where it was left for lying deeper than the depth limit, magenta where it
/// was left for being part of a region larger than `max_hole`, orange where its chart had no
/// seen texel (or restoration did not run: `left` is `None`), black outside the charts.
pub fn picture(res: &crate::resample::Resampled, left: Option<&Unrestored>) -> image::RgbImage {
    use crate::resample::TexelSource as S;
    let (w, h) = res.color.dimensions();
    image::RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        let s = res.source[i];
        image::Rgb(if s == S::Photos as u8 {
            [110, 110, 110]
        } else if S::is_unseen(s) {
            match left {
                Some(l) if l.deep.get(i) => [60, 120, 230],
                Some(l) if l.too_large.get(i) => [220, 40, 200],
                Some(l) if !l.unreachable.get(i) => [40, 200, 60],
                _ => [240, 140, 20],
            }
        } else {
            [0, 0, 0]
        })
    })
}

/// Which unseen regions restoration leaves to exemplar synthesis (stage 6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Handing {
    /// Largest atlas hole restored, texels (0 = no limit). Default: 16384 (a 128 x 128
    /// region).
    pub max_hole: usize,
    /// Regions of faces no photograph saw whose depth from their rim on the surface is at
    /// least this many feature scales go to stage 6 before restoration (infinite = none).
    /// Default: 12.
    pub min_depth: f64,
}

impl Default for Handing {
    fn default() -> Self {
        Handing {
            max_hole: 16384,
            min_depth: 12.0,
        }
    }
}

/// Stage 5 on the atlas: fills the texels the merge marked as seen by no photograph (green
/// fallback, blue and red triangles), reading chart texels only. The gutter keeps the merge's
/// fill (the DCT split reads it as its crops' padding) and the old colours: the caller fills
/// it again ([`crate::resample::refill_gutter`]) after the last step that changes chart
/// colours. Regions beyond restoration (`handing`) are left untouched and handed on. Returns
/// what it did and the unseen texels it left, with their regions.
pub fn restore_atlas(
    res: &mut crate::resample::Resampled,
    mesh: &crate::mesh::Mesh,
    atlas: &crate::atlas::Atlas,
    opts: &RestoreOptions,
    handing: &Handing,
    progress: &dyn crate::progress::Progress,
) -> Result<(RestoreReport, Unrestored)> {
    use crate::resample::TexelSource as S;
    let max_hole = handing.max_hole;
    let n = res.color.width() as usize;
    let unseen = S::is_unseen;
    let mut domain: Vec<bool> = res
        .source
        .par_iter()
        .map(|&s| s == S::Photos as u8 || unseen(s))
        .collect();
    let any_unseen = res.source.par_iter().any(|&s| unseen(s));
    let feature_scale = regions::feature_scale(&res.color, &res.source);
    // Face adjacency and per-face texel counts, for the regions (only with unseen texels).
    let topo = any_unseen.then(|| {
        (
            crate::mesh::topology::face_adjacency(mesh),
            regions::face_counts(atlas, &res.source, mesh.num_faces()),
        )
    });
    // Deep regions first: they leave the domain, so no hole reads their vertex colours.
    let deep = match &topo {
        Some((adj, (hidden, seen))) if handing.min_depth.is_finite() => regions::deep_regions(
            mesh,
            atlas,
            adj,
            (hidden, seen),
            feature_scale,
            handing.min_depth,
        ),
        _ => Vec::new(),
    };
    let deep_mask = if deep.is_empty() {
        BitMask::new(n * n)
    } else {
        let mut is_deep = vec![false; mesh.num_faces()];
        for r in &deep {
            for &f in &r.faces {
                is_deep[f as usize] = true;
            }
        }
        // The n^2 passes here run in parallel: each took a few tenths of a second at 8192.
        let m = BitMask::from_fn_par(n * n, |i| {
            unseen(res.source[i]) && atlas.owner(i).is_some_and(|f| is_deep[f as usize])
        });
        domain.par_iter_mut().enumerate().for_each(|(i, d)| {
            if m.get(i) {
                *d = false;
            }
        });
        m
    };
    // Charts no photograph saw at all have nothing to restore from in 2D: their vertex colours
    // (continuous across seams, from the 3D neighbourhood) stay. Charts are separate domain
    // components (gutter lies between them), so "reachable from a seen texel" is "in a chart
    // with seen texels".
    let reach = {
        let seen: Vec<bool> = res
            .source
            .par_iter()
            .map(|&s| s == S::Photos as u8)
            .collect();
        grid_distance(n, n, &domain, &seen, None)
    };
    let mut mask: Vec<bool> = (0..n * n)
        .into_par_iter()
        .map(|i| domain[i] && unseen(res.source[i]) && reach[i] != u8::MAX)
        .collect();
    let mut left = Unrestored {
        size: n,
        too_large: BitMask::new(n * n),
        unreachable: BitMask::from_fn_par(n * n, |i| {
            domain[i] && unseen(res.source[i]) && reach[i] == u8::MAX
        }),
        deep: deep_mask,
        feature_scale,
        regions: Vec::new(),
        adjacency: Vec::new(),
    };
    let texels_left_unreachable = left.unreachable.count() as u64;
    drop(reach);
    // Large unseen regions are exemplar synthesis's (stage 6): pixel-by-pixel synthesis of a
    // region of a million texels is one long sequential walk, and its 2D neighbourhood is the
    // atlas's, not the surface's. They are left here for stage 6.
    let mut left_large = 0u64;
    let mut comps = holes(n, n, &mask);
    if max_hole > 0 {
        comps.retain(|comp| {
            if comp.len() > max_hole {
                left_large += comp.len() as u64;
                for &i in comp {
                    mask[i] = false;
                    left.too_large.set(i);
                }
                false
            } else {
                true
            }
        });
    }
    // Distance to the chart border: restored values fade into the vertex colours there, so
    // that both sides of a seam still agree.
    let border: Vec<bool> = (0..n * n)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % n, i / n);
            domain[i]
                && (x == 0
                    || y == 0
                    || x + 1 == n
                    || y + 1 == n
                    || !domain[i - 1]
                    || !domain[i + 1]
                    || !domain[i - n]
                    || !domain[i + n])
        })
        .collect();
    let to_border = grid_distance(n, n, &domain, &border, Some(BORDER_TAPER as u8));
    drop(border);
    let mut data = std::mem::replace(&mut res.color, image::Rgb32FImage::new(0, 0)).into_raw();
    // Holes are restored in crops (a group of nearby holes' bounding boxes widened by the
    // source margin), so the cost follows the holes, not the atlas: the split, envelope and
    // pyramid of a whole 4096 atlas took 12 s for 2264 texels. Crops stay under
    // `MAX_CROP_AREA` (one crop of a whole 8192 atlas took 59 s and 10 GB); a crop restores
    // its own holes only and reads no other hole's texels, so crops are independent and run
    // in parallel on the atlas as it came from the merge.
    let crops = crops(n, &comps, opts.margin.max(16) + 8, MAX_CROP_AREA);
    let wall = Instant::now();
    // Progress in hole texels, a crop's all at once when it is done.
    let crop_texels = |c: &Crop| c.holes.iter().map(|&k| comps[k].len() as u64).sum::<u64>();
    progress.start("restore", crops.iter().map(crop_texels).sum());
    // Largest crops first, one task each: rayon's adaptive split would hand a core a run of
    // crops, and the largest crop started last left the other core idle. The results go back
    // to the crops' order.
    let mut order: Vec<usize> = (0..crops.len()).collect();
    order.sort_by_key(|&k| {
        let r = crops[k].rect;
        std::cmp::Reverse((r.2 - r.0) * (r.3 - r.1))
    });
    let mut results: Vec<(usize, (Vec<Fill>, RestoreReport))> = order
        .par_iter()
        .with_max_len(1)
        .map(|&k| {
            let crop = &crops[k];
            let r = crop.rect;
            let (cw, chh) = (r.2 - r.0, r.3 - r.1);
            let idx = |x: usize, y: usize| (r.1 + y) * n + r.0 + x;
            let mut cimg = Vec::with_capacity(cw * chh * 3);
            let mut cdom = Vec::with_capacity(cw * chh);
            for y in 0..chh {
                let row = idx(0, y)..idx(cw, y);
                // A row at a time: a call per texel spent about 0.9 CPU s in memmove at 8192.
                cimg.extend_from_slice(&data[row.start * 3..row.end * 3]);
                cdom.extend(row.map(|i| domain[i] && !mask[i]));
            }
            let mut cmask = vec![false; cw * chh];
            for &k in &crop.holes {
                for &i in &comps[k] {
                    let j = (i / n - r.1) * cw + i % n - r.0;
                    cmask[j] = true;
                    cdom[j] = true;
                }
            }
            let img = Image {
                width: cw,
                height: chh,
                channels: 3,
                data: cimg,
            };
            let (out, rep) = inpaint(&img, &cmask, Some(&cdom), opts)?;
            let fills = (0..cw * chh)
                .filter(|&j| cmask[j])
                .map(|j| {
                    let c = [out.data[j * 3], out.data[j * 3 + 1], out.data[j * 3 + 2]];
                    (idx(j % cw, j / cw), c)
                })
                .collect();
            progress.advance(crop_texels(crop));
            Ok((k, (fills, rep)))
        })
        .collect::<Result<_>>()?;
    results.sort_unstable_by_key(|r| r.0);
    let mut report = RestoreReport {
        method: opts.method,
        windows: crops.len(),
        ..Default::default()
    };
    let mut kappas = Vec::new();
    for (_, (fills, rep)) in results {
        for (i, c) in fills {
            let w = f32::from(to_border[i].min(BORDER_TAPER as u8)) / BORDER_TAPER as f32;
            for (k, &v) in c.iter().enumerate() {
                let before = data[i * 3 + k];
                data[i * 3 + k] = before + w * (v - before);
            }
        }
        report.texels += rep.texels;
        report.detail_scale += rep.detail_scale * rep.texels as f64;
        report.seconds_split += rep.seconds_split;
        report.seconds_diffusion += rep.seconds_diffusion;
        report.seconds_synthesis += rep.seconds_synthesis;
        kappas.push(rep.kappa);
        for l in rep.levels {
            match report.levels.iter_mut().find(|m| m.level == l.level) {
                Some(m) => {
                    m.texels += l.texels;
                    m.coherent += l.coherent;
                    m.stalled += l.stalled;
                    m.windows += l.windows;
                    m.sources += l.sources;
                    m.seconds += l.seconds;
                }
                None => report.levels.push(l),
            }
        }
    }
    report.detail_scale = if report.texels > 0 {
        report.detail_scale / report.texels as f64
    } else {
        1.0
    };
    kappas.sort_unstable();
    report.kappa = kappas.get(kappas.len() / 2).copied().unwrap_or(0);
    report.kappa_auto = opts.kappa == Kappa::Auto;
    report.seconds = wall.elapsed().as_secs_f64();
    report.texels_left_large = left_large;
    report.texels_left_unreachable = texels_left_unreachable;
    report.texels_left_deep = left.deep.count() as u64;
    report.feature_scale = feature_scale;
    // Texels left imply unseen texels, so the topology is there.
    if let Some((adj, (hidden, _))) =
        topo.filter(|_| left.deep.count() + left.too_large.count() + left.unreachable.count() > 0)
    {
        left.regions = regions::handed_over(
            mesh,
            atlas,
            &adj,
            &hidden,
            &deep,
            &left.too_large,
            &left.unreachable,
        );
        left.adjacency = adj;
    }
    res.color = image::Rgb32FImage::from_raw(n as u32, n as u32, data).expect("n * n * 3 values");
    Ok((report, left))
}

/// Texels over which restored atlas values fade into the vertex colours at a chart border.
pub(super) const BORDER_TAPER: u32 = 8;

/// A restored atlas texel: its index and colour.
pub(super) type Fill = (usize, [f32; 3]);

/// Largest crop built by merging holes' windows, texels (a single hole's window may exceed
/// it).
pub(super) const MAX_CROP_AREA: usize = 1 << 20;

/// A rectangle of the atlas (x0, y0, x1, y1) and the holes (indices) it restores.
pub(super) struct Crop {
    pub(super) rect: (usize, usize, usize, usize),
    pub(super) holes: Vec<usize>,
}

/// Crops covering every hole of `comps` widened by `margin`; overlapping crops are merged
/// while the merged one stays within `max_area` and is no larger than the two apart. The
/// crop-wide steps (the split, the diffusions, the envelope, the pyramid) cost in proportion
/// to a crop's area: two windows touching at a corner used to become their bounding box,
/// which on the corset at 4096 made 34 crops of 16.9M texels for 391k restored, against 66
/// crops of 13.1M now (`docs/decisions.md`, "Crops merged only where it saves area").
pub(super) fn crops(n: usize, comps: &[Vec<usize>], margin: usize, max_area: usize) -> Vec<Crop> {
    let mut crops: Vec<Crop> = comps
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let (mut x0, mut y0, mut x1, mut y1) = (n, n, 0, 0);
            for &i in c {
                let (x, y) = (i % n, i / n);
                x0 = x0.min(x);
                y0 = y0.min(y);
                x1 = x1.max(x + 1);
                y1 = y1.max(y + 1);
            }
            Crop {
                rect: (
                    x0.saturating_sub(margin),
                    y0.saturating_sub(margin),
                    (x1 + margin).min(n),
                    (y1 + margin).min(n),
                ),
                holes: vec![k],
            }
        })
        .collect();
    crops.sort_unstable_by_key(|c| (c.rect.1, c.rect.0, c.holes[0]));
    let area = |r: (usize, usize, usize, usize)| (r.2 - r.0) * (r.3 - r.1);
    // Merge until no merge is possible (quadratic passes over few crops are cheap).
    loop {
        let mut merged = false;
        let mut out: Vec<Crop> = Vec::with_capacity(crops.len());
        for c in crops {
            let r = c.rect;
            let target = out.iter_mut().find(|o| {
                let u = (
                    o.rect.0.min(r.0),
                    o.rect.1.min(r.1),
                    o.rect.2.max(r.2),
                    o.rect.3.max(r.3),
                );
                r.0 < o.rect.2
                    && o.rect.0 < r.2
                    && r.1 < o.rect.3
                    && o.rect.1 < r.3
                    && area(u) <= max_area
                    && area(u) <= area(o.rect) + area(r)
            });
            match target {
                Some(o) => {
                    o.rect = (
                        o.rect.0.min(r.0),
                        o.rect.1.min(r.1),
                        o.rect.2.max(r.2),
                        o.rect.3.max(r.3),
                    );
                    o.holes.extend(c.holes);
                    merged = true;
                }
                None => out.push(c),
            }
        }
        crops = out;
        if !merged {
            break;
        }
    }
    for c in &mut crops {
        c.holes.sort_unstable();
        // Sides with only small prime factors: the crop's DCTs run on rustdct's fast
        // mixed-radix plans instead of Bluestein's (a 1105 x 948 crop, 948 = 4 * 3 * 79).
        let (x0, x1) = smooth_span(c.rect.0, c.rect.2, n);
        let (y0, y1) = smooth_span(c.rect.1, c.rect.3, n);
        c.rect = (x0, y0, x1, y1);
    }
    crops
}

/// The smallest span around `[a, b)` inside `[0, n)` whose length is 5-smooth (2^i 3^j 5^k),
/// grown to the right first; `n` is a power of two, so the span always exists.
fn smooth_span(a: usize, b: usize, n: usize) -> (usize, usize) {
    let smooth = |mut v: usize| {
        for p in [2, 3, 5] {
            while v.is_multiple_of(p) {
                v /= p;
            }
        }
        v == 1
    };
    let len = (b - a..=n).find(|&l| smooth(l)).unwrap_or(n);
    let b2 = (a + len).min(n);
    (b2 - len, b2)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square hole of side `s` with its top-left texel at (x, y) on an `n` x `n` atlas.
    fn square(n: usize, x: usize, y: usize, s: usize) -> Vec<usize> {
        (y..y + s)
            .flat_map(|yy| (x..x + s).map(move |xx| yy * n + xx))
            .collect()
    }

    #[test]
    fn crops_merge_only_where_it_saves_area() {
        let n = 1024;
        let margin = 20;
        let comps = vec![
            // Two holes whose windows mostly overlap: one crop.
            square(n, 100, 100, 10),
            square(n, 115, 104, 10),
            // Two holes whose windows meet at a corner only: their bounding box would be
            // larger than both windows apart, so they stay two crops.
            square(n, 500, 500, 30),
            square(n, 565, 565, 30),
        ];
        let crops = crops(n, &comps, margin, MAX_CROP_AREA);
        let mut holes: Vec<Vec<usize>> = crops.iter().map(|c| c.holes.clone()).collect();
        holes.sort();
        assert_eq!(holes, vec![vec![0, 1], vec![2], vec![3]]);
        // Every crop holds its holes' windows.
        for c in &crops {
            let (x0, y0, x1, y1) = c.rect;
            for &k in &c.holes {
                for &i in &comps[k] {
                    let (x, y) = (i % n, i / n);
                    assert!(
                        x >= x0 + margin && x + margin < x1,
                        "hole {k} x {x} in {x0}..{x1}"
                    );
                    assert!(
                        y >= y0 + margin && y + margin < y1,
                        "hole {k} y {y} in {y0}..{y1}"
                    );
                }
            }
        }
        // The two corner-touching windows overlap, so the old rule (any overlap, within the
        // area cap) merged them.
        let w = |k: usize| {
            let (x, y) = (comps[k][0] % n, comps[k][0] / n);
            (x - margin, y - margin, x + 30 + margin, y + 30 + margin)
        };
        let (a, b) = (w(2), w(3));
        assert!(a.0 < b.2 && b.0 < a.2 && a.1 < b.3 && b.1 < a.3);
    }
}
