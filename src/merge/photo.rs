//! The layers of one chart: a photograph's (sampled through stage 3's sampler, holes filled,
//! split into bands under its mask) and the complement's (the vertex-colour texture where no
//! mask reaches).

use super::*;

/// Photograph `ph`'s layer on chart `ch`: sampled, holes filled, split into bands and added
/// under its mask.
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
pub(super) fn add_photo(
    prep: &Sampler,
    ph: &PhotoSampler,
    ch: &Chart,
    acc: &mut ChartAcc,
    ring: Option<&[Vec<u32>]>,
    face_ref: &[f32],
    face_full: &super::FaceLists,
    mopts: &MergeOptions,
    cpu_sampling: &AtomicU64,
) {
    let photo = ph.index() as u32;
    if !ch.faces.iter().any(|&f| ph.samples(f)) {
        return;
    }
    let t = std::time::Instant::now();
    // Only the part of the chart near what the photograph sees: its faces' rectangle, padded
    // by the coarsest level's reach (beyond it the mask is zero at every level) and aligned to
    // that level's grid.
    let (mut bx0, mut by0, mut bx1, mut by1) = (usize::MAX, usize::MAX, 0, 0);
    for &f in ch.faces {
        if ph.samples(f) {
            let ((r0, r1), (c0, c1)) = prep.face_rect(f as usize).expect("chart faces rasterise");
            (bx0, by0) = (bx0.min(c0 - ch.x0), by0.min(r0 - ch.y0));
            (bx1, by1) = (bx1.max(c1 + 1 - ch.x0), by1.max(r1 + 1 - ch.y0));
        }
    }
    let step = 1usize << ch.levels;
    let pad = 4 * step;
    let ox = bx0.saturating_sub(pad) / step * step;
    let oy = by0.saturating_sub(pad) / step * step;
    let (w, h) = ((bx1 + pad).min(ch.w) - ox, (by1 + pad).min(ch.h) - oy);
    let mut layer = Layer::new((ox, oy), (w, h), acc.sizes(), mopts.a);
    let winner_mode = mopts.masks == Masks::BestView;
    let fine_alone = mopts.fine_exponent == f32::INFINITY;
    // The level-0 texels that enter the finest band (chart x | y << 16, colour, mask), held
    // until the layer's coarser levels are built, in 12 bytes: with blended finest bands a
    // photograph keeps every texel it samples at full resolution, up to millions on one
    // chart. Colours in fixed point (`FINE_COLOUR_SCALE`).
    let mut fine: Vec<(u32, [u16; 3], f16)> = Vec::new();
    let fine_texel = |x: usize, y: usize, c: [f32; 3], m: f32| {
        // Charts are at most 32768 texels wide and high (the atlas's limit).
        let c = c.map(|v| (v * FINE_COLOUR_SCALE + 0.5).clamp(0.0, 65535.0) as u16);
        ((x | y << 16) as u32, c, f16::from_f32(m))
    };
    let mut any_mask = false;
    let n = prep.size();
    for &f in ch.faces {
        if !ph.samples(f) {
            continue;
        }
        let in_mask = match ring {
            Some(r) => prep.mesh().faces[f as usize]
                .iter()
                .all(|v| r[v.idx()].binary_search(&photo).is_ok()),
            None => true,
        };
        let reference = face_ref[f as usize];
        let mask_of = |wt: f32| match mopts.masks {
            Masks::Paper => f32::from(in_mask),
            _ if reference > 0.0 => (wt / reference).min(1.0),
            _ => 1.0,
        };
        let full = face_full.get(f as usize);
        if ch.levels > 0 && !full.is_empty() && full.binary_search(&photo).is_err() {
            // Coarse: one sample per 2 x 2 texels, for the coarser bands; these texels count
            // as seen (never in the finest band: theirs is not known).
            prep.sample_face(ph, f, 0, n, Some((ch.x0, ch.y0)), |x, y, c, wt| {
                let (x, y) = (x - ch.x0, y - ch.y0);
                for (bx, by) in [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)] {
                    // Texels of any face this photograph samples (a neighbour's texels
                    // whose own block anchor lies in this face); texels of other charts in
                    // the rectangle are never copied out, so marking them is harmless.
                    if bx >= ch.w || by >= ch.h {
                        continue;
                    }
                    match prep.owner((ch.y0 + by) * n + ch.x0 + bx) {
                        Some(g) if g == f || ph.samples(g) => {}
                        _ => continue,
                    }
                    let i = by * ch.w + bx;
                    acc.ready(0, i);
                    acc.views[i] = acc.views[i].saturating_add(1);
                    if acc.best_w[i] == f16::ZERO {
                        acc.best_w[i] = COARSE_SEEN;
                        acc.best[i] = photo as u16;
                    }
                }
                let m = mask_of(wt);
                layer.splat(x, y, c, m, 4.0);
                any_mask |= m > 0.0;
            });
            continue;
        }
        prep.sample_face(ph, f, 0, n, None, |x, y, c, wt| {
            let (x, y) = (x - ch.x0, y - ch.y0);
            let m = mask_of(wt);
            let i = y * ch.w + x;
            acc.ready(0, i);
            acc.views[i] = acc.views[i].saturating_add(1);
            // Photographs come in order, so ties keep the first: deterministic.
            let rel = relative_weight(wt, reference);
            let wins = rel > acc.best_w[i];
            if wins {
                acc.best_w[i] = rel;
                acc.best[i] = photo as u16;
            }
            if let Some(avg) = &mut acc.avg {
                for k in 0..3 {
                    avg[i][k] += wt * c[k];
                }
                avg[i][3] += wt;
            }
            layer.splat(x, y, c, m, 1.0);
            any_mask |= m > 0.0;
            if winner_mode {
                // Into the finest band's running mean, or with an infinite exponent in place
                // of it where this photograph wins.
                if fine_alone {
                    if wins {
                        fine.push(fine_texel(x, y, c, f32::INFINITY));
                    }
                } else {
                    let mf = fine_weight(wt, reference, mopts.fine_exponent);
                    fine.push(fine_texel(x, y, c, mf));
                }
            } else if m > 0.0 {
                fine.push(fine_texel(x, y, c, m));
            }
        });
    }
    cpu_sampling.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
    if !any_mask {
        return;
    }
    layer.reduce();
    let fine = fine.into_iter().map(|(xy, c, m)| {
        let (x, y) = ((xy & 0xffff) as usize, (xy >> 16) as usize);
        (x, y, c.map(|v| v as f32 / FINE_COLOUR_SCALE), m.to_f32())
    });
    layer.accumulate(acc, winner_mode, fine);
}

/// The complement of the photographs' masks, carrying the vertex-colour texture (the paper's
/// mask), or with paper masks stage 3's texture where photographs saw the texel.
pub(super) fn add_complement(
    prep: &Sampler,
    ch: &Chart,
    ci: u32,
    face_chart: &[u32],
    acc: &mut ChartAcc,
    a: f32,
    winner_mode: bool,
) {
    let n = prep.size();
    // No photograph's mask covers the texel (best-view masks are positive exactly where a
    // view weight is). Decided before the layer adds to the level-0 sums.
    let uncovered: Vec<bool> = if winner_mode {
        acc.best_w.iter().map(|&b| b == f16::ZERO).collect()
    } else {
        acc.den[0].iter().map(|&d| d <= 0.0).collect()
    };
    let avg = acc.avg.take();
    // The layer's colour at chart texel (x, y), if the chart owns it.
    let colour = |x: usize, y: usize| -> Option<[f32; 3]> {
        let f = prep.owner((ch.y0 + y) * n + ch.x0 + x)?;
        if face_chart[f as usize] != ci {
            return None;
        }
        let i = y * ch.w + x;
        Some(match &avg {
            Some(avg) if avg[i][3] > 0.0 => {
                let s = avg[i][3];
                [avg[i][0] / s, avg[i][1] / s, avg[i][2] / s]
            }
            _ => prep.vertex_color_at(f, ch.x0 + x, ch.y0 + y),
        })
    };
    // Only the part of the chart within the coarsest level's reach of an uncovered texel
    // matters (beyond it the mask is zero at every level), as for the photographs' layers.
    let owned = |x: usize, y: usize| {
        prep.owner((ch.y0 + y) * n + ch.x0 + x)
            .is_some_and(|f| face_chart[f as usize] == ci)
    };
    let rows: Vec<Option<(usize, usize)>> = (0..ch.h)
        .into_par_iter()
        .map(|y| {
            let mut xs = (0..ch.w).filter(|&x| uncovered[y * ch.w + x] && owned(x, y));
            let first = xs.next()?;
            Some((first, xs.next_back().unwrap_or(first) + 1))
        })
        .collect();
    let Some(by0) = rows.iter().position(Option::is_some) else {
        // No texel left for the complement.
        return;
    };
    let by1 = rows.iter().rposition(Option::is_some).expect("one found") + 1;
    let (bx0, bx1) = rows
        .iter()
        .flatten()
        .fold((usize::MAX, 0), |(a, b), &(x0, x1)| (a.min(x0), b.max(x1)));
    let step = 1usize << ch.levels;
    let pad = 4 * step;
    let ox = bx0.saturating_sub(pad) / step * step;
    let oy = by0.saturating_sub(pad) / step * step;
    let (ex, ey) = ((bx1 + pad).min(ch.w), (by1 + pad).min(ch.h));
    // Colours are computed in parallel a block of rows at a time (the largest chart of the
    // 8192 speed scene spans 16.5M texels, alone in its batch), and added in order.
    const ROWS: usize = 64;
    let block = |y0: usize, only_uncovered: bool| -> Vec<(usize, usize, [f32; 3])> {
        (y0..(y0 + ROWS).min(ey))
            .into_par_iter()
            .flat_map_iter(|y| {
                let colour = &colour;
                let uncovered = &uncovered;
                (ox..ex).filter_map(move |x| {
                    if only_uncovered && !uncovered[y * ch.w + x] {
                        return None;
                    }
                    colour(x, y).map(|c| (x, y, c))
                })
            })
            .collect()
    };
    let mut layer = Layer::new((ox, oy), (ex - ox, ey - oy), acc.sizes(), a);
    for y0 in (oy..ey).step_by(ROWS) {
        for (x, y, c) in block(y0, false) {
            let m = f32::from(uncovered[y * ch.w + x]);
            layer.splat(x, y, c, m, 1.0);
        }
    }
    layer.reduce();
    // The finest band again from the colours (recomputing them costs less than holding a
    // chart's worth).
    let fine = (oy..ey)
        .step_by(ROWS)
        .flat_map(|y0| block(y0, true))
        // With best-view masks it replaces the finest band: it enters only texels no
        // photograph did.
        .map(|(x, y, c)| (x, y, c, if winner_mode { f32::INFINITY } else { 1.0 }));
    layer.accumulate(acc, winner_mode, fine);
}
