//! One layer of the multiband merge (a photograph's, or the complement's) on part of a chart:
//! splatting its samples into a normalised-convolution pyramid, the pyramid's reduction and
//! expansion taps, and its bands added into a chart's accumulators.

use super::*;

/// Fixed-point scale of the colours a layer holds for its finest band: steps of 1.2e-4
/// (far below 8-bit output's 3.9e-3, and finer than half precision's 4.9e-4 near 1), up
/// to 8 (photographs' values are at most 1 before the gains scale them; a colour beyond 8
/// would be clipped in the finest band only).
pub(super) const FINE_COLOUR_SCALE: f32 = 8192.0;

/// Below this a sum of weights counts as nothing.
pub(super) const EPS: f32 = 1e-12;

/// The texels of the next coarser level a texel `x` of a level `n` texels wide reaches in a
/// reduction, with their kernel weights (reflect-101 at the chart's borders, as
/// [`pyramid::reduce`]): `(index, weight)` pairs, `count` of them used.
#[inline(always)]
pub(super) fn down_taps(x: usize, n: usize, k: &[f32; 5]) -> ([usize; 6], [f32; 6], usize) {
    let mut idx = [0usize; 6];
    let mut wt = [0f32; 6];
    let j = x / 2;
    if x >= 3 && x + 4 <= n {
        // Interior: source 2X + t - 2 = x.
        if x.is_multiple_of(2) {
            idx[..3].copy_from_slice(&[j - 1, j, j + 1]);
            wt[..3].copy_from_slice(&[k[4], k[2], k[0]]);
            return (idx, wt, 3);
        }
        idx[..2].copy_from_slice(&[j, j + 1]);
        wt[..2].copy_from_slice(&[k[3], k[1]]);
        return (idx, wt, 2);
    }
    // Near a border the reflected taps reach `x` too.
    let mut c = 0;
    for big in j.saturating_sub(3)..(j + 4).min(n.div_ceil(2)) {
        let s: f32 = (0..5)
            .filter(|&t| pyramid::reflect101(2 * big as isize + t as isize - 2, n) == x)
            .map(|t| k[t])
            .sum();
        if s > 0.0 && c < 6 {
            idx[c] = big;
            wt[c] = s;
            c += 1;
        }
    }
    (idx, wt, c)
}

/// The texels of level `n` texels wide an expansion reads for texel `x` of the next finer
/// level, with their weights (twice the kernel's; reflect-101 on the doubled grid, as
/// [`pyramid::expand`]).
#[inline]
pub(super) fn up_taps(x: usize, n: usize, k: &[f32; 5]) -> ([usize; 3], [f32; 3], usize) {
    let j = (x / 2) as isize;
    let u = |i: isize| pyramid::up_src(i, n);
    if x.is_multiple_of(2) {
        (
            [u(j - 1), u(j), u(j + 1)],
            [2.0 * k[0], 2.0 * k[2], 2.0 * k[4]],
            3,
        )
    } else {
        ([u(j), u(j + 1), 0], [2.0 * k[1], 2.0 * k[3], 0.0], 2)
    }
}

/// The taps `(idx, wt, n)` (level coordinates) that fall inside `[b, b + len)`, moved to
/// buffer coordinates, in their order.
#[inline(always)]
pub(super) fn clip_taps<const N: usize>(
    (idx, wt, n): ([usize; N], [f32; N], usize),
    b: usize,
    len: usize,
) -> ([usize; N], [f32; N], usize) {
    let mut out = ([0usize; N], [0f32; N], 0usize);
    for t in 0..n {
        if let Some(i) = idx[t].checked_sub(b).filter(|&v| v < len) {
            out.0[out.2] = i;
            out.1[out.2] = wt[t];
            out.2 += 1;
        }
    }
    out
}

/// Calls `f(index, weight)` for the products of the column taps and row taps (level
/// coordinates, [`clip_taps`]) that fall inside a `w` x `h` buffer whose origin is
/// (`bx`, `by`) on that level, rows outer.
#[inline(always)]
pub(super) fn for_taps_in<const NX: usize, const NY: usize>(
    cols: ([usize; NX], [f32; NX], usize),
    rows: ([usize; NY], [f32; NY], usize),
    (bx, by): (usize, usize),
    (w, h): (usize, usize),
    mut f: impl FnMut(usize, f32),
) {
    let (xi, xw, xn) = clip_taps(cols, bx, w);
    let (yi, yw, yn) = clip_taps(rows, by, h);
    for b in 0..yn {
        for a in 0..xn {
            f(yi[b] * w + xi[a], xw[a] * yw[b]);
        }
    }
}

/// One splat contribution of weight `wt`: colour sums and weight into `d`, mask sum into
/// `mask` (both splat paths share it, so that they add the same numbers).
#[inline(always)]
pub(super) fn add_splat(d: &mut [f32], mask: &mut f32, wt: f32, c: [f32; 3], m: f32) {
    d[0] += wt * c[0];
    d[1] += wt * c[1];
    d[2] += wt * c[2];
    d[3] += wt;
    if m > 0.0 {
        *mask += wt * m;
    }
}

/// [`Layer::splat`]'s sums for taps `xw` x `yw` from texel `(x0, y0)` of a level-1 buffer
/// `gw` wide (colour sums and weight in `g`, mask sums in `mask`).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub(super) fn splat_block<const NX: usize, const NY: usize>(
    g: &mut [f32],
    mask: &mut [f32],
    gw: usize,
    (x0, y0): (usize, usize),
    xw: [f32; NX],
    yw: [f32; NY],
    c: [f32; 3],
    m: f32,
    w: f32,
) {
    for (b, &wy) in yw.iter().enumerate() {
        let row = (y0 + b) * gw + x0;
        let d = &mut g[4 * row..4 * (row + NX)];
        let ms = &mut mask[row..row + NX];
        for (a, &wx) in xw.iter().enumerate() {
            add_splat(&mut d[4 * a..4 * a + 4], &mut ms[a], wx * wy * w, c, m);
        }
    }
}

/// One layer (a photograph's, or the complement's) on part of a chart, as its pyramid is
/// built. Level-0 texels are splatted straight into level 1 as they are sampled, so no
/// level-0 image is ever held: the photographs are sampled where they see the chart only, and
/// the transient memory is a quarter of the part's texels. The pyramid is a
/// normalised-convolution one: every level is the reduced colour sums over the reduced known
/// weight, every band a level minus the likewise normalised expansion of the next, so texels
/// the layer does not know never enter a band. Borders are reflect-101 at the chart's edges,
/// as [`pyramid::reduce`] and [`pyramid::expand`]; the part is padded beyond the reach of the
/// kernels, so elsewhere nothing lies outside it.
pub(super) struct Layer {
    /// Level-0 origin of the part in the chart, a multiple of `2^levels` so that every
    /// level's grid lines up with the chart's.
    pub(super) ox: usize,
    pub(super) oy: usize,
    /// The chart's size per level (`chart[0]` = level 0).
    pub(super) chart: Vec<(usize, usize)>,
    /// Levels 1..=levels: colour sums and known weight (4 channels).
    pub(super) g: Vec<Plane>,
    /// Levels 1..=levels: the reduced mask.
    pub(super) m: Vec<Vec<f32>>,
    pub(super) k: [f32; 5],
}

impl Layer {
    /// A layer on the `w` x `h` texels of the chart from (`ox`, `oy`); `chart` is the
    /// chart's size per level, `levels + 1` entries.
    pub(super) fn new(
        (ox, oy): (usize, usize),
        (w, h): (usize, usize),
        chart: Vec<(usize, usize)>,
        a: f32,
    ) -> Self {
        let (mut g, mut m) = (Vec::new(), Vec::new());
        if chart.len() > 1 {
            let (w1, h1) = (w.div_ceil(2), h.div_ceil(2));
            let (mut g1, mut m1) = (Plane::zeros(w1, h1, 4), vec![0f32; w1 * h1]);
            // Splats add into these (`crate::io::touch_for_writing`).
            crate::io::touch_for_writing(&mut g1.d);
            crate::io::touch_for_writing(&mut m1);
            g.push(g1);
            m.push(m1);
        }
        Layer {
            ox,
            oy,
            chart,
            g,
            m,
            k: pyramid::kernel(a),
        }
    }

    pub(super) fn levels(&self) -> usize {
        self.chart.len() - 1
    }

    /// Adds level-0 texel (`x`, `y`) (chart coordinates) of colour `c`, known with weight
    /// `w` (the texels it stands for), under mask `m`, to level 1.
    #[inline(always)]
    pub(super) fn splat(&mut self, x: usize, y: usize, c: [f32; 3], m: f32, w: f32) {
        let Some(g) = self.g.first_mut() else {
            return;
        };
        let (nw, nh) = self.chart[0];
        let mask = &mut self.m[0];
        let (gw, gh) = (g.w, g.h);
        let (bx, by) = (self.ox / 2, self.oy / 2);
        // Away from the chart's border the taps are the kernel's, by parity alone, and (the
        // part being padded) inside the part: the same sums without the general tap lists.
        if x >= 3 && x + 4 <= nw && y >= 3 && y + 4 <= nh {
            let k = &self.k;
            let first = |v: usize| {
                if v.is_multiple_of(2) {
                    v / 2 - 1
                } else {
                    v / 2
                }
            };
            let (x0, y0) = (first(x), first(y));
            if x0 >= bx && x0 + 3 <= bx + gw && y0 >= by && y0 + 3 <= by + gh {
                let at = (x0 - bx, y0 - by);
                let (even, odd) = ([k[4], k[2], k[0]], [k[3], k[1]]);
                let (g, m_) = (&mut g.d[..], &mut mask[..]);
                match (x.is_multiple_of(2), y.is_multiple_of(2)) {
                    (true, true) => splat_block(g, m_, gw, at, even, even, c, m, w),
                    (false, true) => splat_block(g, m_, gw, at, odd, even, c, m, w),
                    (true, false) => splat_block(g, m_, gw, at, even, odd, c, m, w),
                    (false, false) => splat_block(g, m_, gw, at, odd, odd, c, m, w),
                }
                return;
            }
        }
        for_taps_in(
            down_taps(x, nw, &self.k),
            down_taps(y, nh, &self.k),
            (self.ox / 2, self.oy / 2),
            (gw, gh),
            |i, kw| add_splat(&mut g.d[4 * i..4 * i + 4], &mut mask[i], kw * w, c, m),
        );
    }

    /// Builds levels 2 and up from level 1 (separable, reflect-101 at the chart's edges, zero
    /// beyond the part elsewhere).
    pub(super) fn reduce(&mut self) {
        for l in 1..self.levels() {
            let (src, (nw, nh)) = (&self.g[l - 1], self.chart[l]);
            let (ox, oy) = (self.ox >> l, self.oy >> l);
            let g = reduce_part(src, (ox, oy), (nw, nh), &self.k);
            let ms = Plane::from_vec(src.w, src.h, 1, std::mem::take(&mut self.m[l - 1]))
                .expect("sized");
            let m = reduce_part(&ms, (ox, oy), (nw, nh), &self.k);
            self.m[l - 1] = ms.d;
            self.g.push(g);
            self.m.push(m.d);
        }
    }

    /// The expansion taps of level `l + 1` for every column and row of level `l` this layer
    /// covers (layer coordinates, the taps inside the layer's level `l + 1`): [`up_taps`]
    /// clipped by [`clip_taps`] once per column and row instead of once per texel, as
    /// [`for_taps_in`] would for each texel.
    pub(super) fn up_grid(&self, l: usize) -> UpGrid {
        let g = &self.g[l];
        let (nw, nh) = self.chart[l + 1];
        let (bx, by) = (self.ox >> (l + 1), self.oy >> (l + 1));
        let (ox, oy) = (self.ox >> l, self.oy >> l);
        // The level-`l` extent of the layer: twice the next level's, which covers it.
        let (w, h) = (2 * g.w, 2 * g.h);
        UpGrid {
            cols: (0..w)
                .map(|x| clip_taps(up_taps(ox + x, nw, &self.k), bx, g.w))
                .collect(),
            rows: (0..h)
                .map(|y| clip_taps(up_taps(oy + y, nh, &self.k), by, g.h))
                .collect(),
            origin: (ox, oy),
        }
    }

    /// Band `l` at texel (`x`, `y`) of level `l` (chart coordinates) whose level value is
    /// `v`: `v` minus the normalised expansion of the next level (taps `up`, from
    /// [`Self::up_grid`]), `v` itself at the top (`up` = `None`).
    #[inline]
    fn band(&self, l: usize, up: Option<&UpGrid>, x: usize, y: usize, mut v: [f32; 3]) -> [f32; 3] {
        let Some(up) = up else {
            return v;
        };
        let g = &self.g[l];
        let (xi, xw, xn) = up.cols[x - up.origin.0];
        let (yi, yw, yn) = up.rows[y - up.origin.1];
        // The sums of `for_taps_in`, in its order.
        let mut s = [0f32; 4];
        for b in 0..yn {
            for a in 0..xn {
                let i = yi[b] * g.w + xi[a];
                let wt = xw[a] * yw[b];
                for (sk, v) in s.iter_mut().zip(&g.d[4 * i..4 * i + 4]) {
                    *sk += wt * v;
                }
            }
        }
        if s[3] > EPS {
            for k in 0..3 {
                v[k] -= s[k] / s[3];
            }
        }
        v
    }

    /// Adds the layer's bands under its mask to `acc`: levels 1 and up from the reduced
    /// planes, level 0 from `fine`, the level-0 texels (chart coordinates, colour, mask) that
    /// enter it (with best-view masks, into the running mean `finest`, which a mask of
    /// infinity replaces).
    pub(super) fn accumulate(
        &self,
        acc: &mut ChartAcc,
        winner_mode: bool,
        fine: impl Iterator<Item = (usize, usize, [f32; 3], f32)>,
    ) {
        let ups: Vec<UpGrid> = (0..self.levels()).map(|l| self.up_grid(l)).collect();
        for l in 1..=self.levels() {
            let up = ups.get(l);
            let (g, m) = (&self.g[l - 1], &self.m[l - 1]);
            let (ox, oy) = (self.ox >> l, self.oy >> l);
            let cw = acc.num[l].w;
            for y in 0..g.h {
                for x in 0..g.w {
                    let i = y * g.w + x;
                    let (mw, wg) = (m[i], g.d[4 * i + 3]);
                    if mw <= 0.0 || wg <= EPS {
                        continue;
                    }
                    let v = std::array::from_fn(|k| g.d[4 * i + k] / wg);
                    let band = self.band(l, up, ox + x, oy + y, v);
                    let gi = (oy + y) * cw + ox + x;
                    acc.ready(l, gi);
                    let (num, den) = (&mut acc.num[l].d, &mut acc.den[l]);
                    den[gi] += mw;
                    for k in 0..3 {
                        num[3 * gi + k] += mw * band[k];
                    }
                }
            }
        }
        let cw = acc.num[0].w;
        for (x, y, c, mw) in fine {
            let band = self.band(0, ups.first(), x, y, c);
            let gi = y * cw + x;
            acc.ready(0, gi);
            if winner_mode {
                let mean = &mut acc.finest[3 * gi..3 * gi + 3];
                if mw == f32::INFINITY {
                    for (m, b) in mean.iter_mut().zip(band) {
                        *m = f16::from_f32(b);
                    }
                    // The weights may be gone already (`multiband` frees them after the
                    // photographs, before the complement).
                    if let Some(sum) = acc.finest_w.get_mut(gi) {
                        *sum = f16::ONE;
                    }
                } else if mw > 0.0 {
                    // Weights stay within half precision's range (`fine_weight`).
                    let sum = &mut acc.finest_w[gi];
                    let total = sum.to_f32() + mw;
                    let share = mw / total;
                    for (m, b) in mean.iter_mut().zip(band) {
                        let v = m.to_f32();
                        *m = f16::from_f32(v + share * (b - v));
                    }
                    *sum = f16::from_f32(total.min(FINE_WEIGHT_MAX));
                }
            } else if mw > 0.0 {
                acc.den[0][gi] += mw;
                for (v, b) in acc.num[0].d[3 * gi..3 * gi + 3].iter_mut().zip(band) {
                    *v += mw * b;
                }
            }
        }
    }
}

/// Per column and per row of one level of a layer, the taps of the next level's expansion
/// ([`Layer::up_grid`]): indices into that level's planes, weights, count.
pub(super) struct UpGrid {
    pub(super) cols: Vec<([usize; 3], [f32; 3], usize)>,
    pub(super) rows: Vec<([usize; 3], [f32; 3], usize)>,
    /// Chart coordinates of the first column and row.
    pub(super) origin: (usize, usize),
}

/// One reduction of `src`, which covers the texels from (`ox`, `oy`) (even) of a level
/// `nw` x `nh` texels: reflect-101 at that level's edges, zero beyond `src` elsewhere. The
/// result covers the next level from (`ox / 2`, `oy / 2`).
pub(super) fn reduce_part(
    src: &Plane,
    (ox, oy): (usize, usize),
    (nw, nh): (usize, usize),
    k: &[f32; 5],
) -> Plane {
    let (w, h, c) = (src.w, src.h, src.c);
    let (dw, dh) = (w.div_ceil(2), h.div_ceil(2));
    // Source offsets (within `src`) and weights of output column/row `d`.
    let taps = |d: usize, o: usize, n: usize, len: usize| -> ([usize; 5], [f32; 5], usize) {
        let mut idx = [0usize; 5];
        let mut wt = [0f32; 5];
        let mut cnt = 0;
        let centre = 2 * (o / 2 + d) as isize;
        for (t, &kt) in k.iter().enumerate() {
            let s = pyramid::reflect101(centre + t as isize - 2, n) as isize - o as isize;
            if s >= 0 && (s as usize) < len {
                idx[cnt] = s as usize;
                wt[cnt] = kt;
                cnt += 1;
            }
        }
        (idx, wt, cnt)
    };
    let cols: Vec<_> = (0..dw).map(|x| taps(x, ox, nw, w)).collect();
    let mut tmp = vec![0f32; dw * h * c];
    // The channel count as a constant, so that the tap loops unroll (a layer's colour sums
    // have 4, its mask 1).
    match c {
        4 => reduce_rows::<4>(&src.d, w, &cols, &mut tmp),
        1 => reduce_rows::<1>(&src.d, w, &cols, &mut tmp),
        _ => reduce_rows_any(&src.d, w, c, &cols, &mut tmp),
    }
    let mut out = vec![0f32; dw * dh * c];
    // Every row is added to (`crate::io::touch_for_writing`).
    crate::io::touch_for_writing(&mut out);
    let rl = dw * c;
    for y in 0..dh {
        let (idx, wt, n) = taps(y, oy, nh, h);
        let row = &mut out[y * rl..(y + 1) * rl];
        for t in 0..n {
            let r = &tmp[idx[t] * rl..(idx[t] + 1) * rl];
            for (o, v) in row.iter_mut().zip(r) {
                *o += wt[t] * v;
            }
        }
    }
    Plane::from_vec(dw, dh, c, out).expect("sized")
}

/// Column taps of one output texel of a reduction: source indices, weights, count.
pub(super) type Taps = ([usize; 5], [f32; 5], usize);

/// The horizontal pass of [`reduce_part`] for `C` channels: each row of `src` (`w` texels)
/// into `tmp` through the column taps `cols`; all-zero rows are skipped (most of a layer).
pub(super) fn reduce_rows<const C: usize>(src: &[f32], w: usize, cols: &[Taps], tmp: &mut [f32]) {
    let dw = cols.len();
    for (s, row) in src.chunks_exact(w * C).zip(tmp.chunks_exact_mut(dw * C)) {
        if s.iter().all(|&v| v == 0.0) {
            continue;
        }
        for ((idx, wt, n), o) in cols.iter().zip(row.chunks_exact_mut(C)) {
            let mut acc = [0f32; C];
            for t in 0..*n {
                let v = &s[idx[t] * C..idx[t] * C + C];
                for ch in 0..C {
                    acc[ch] += wt[t] * v[ch];
                }
            }
            o.copy_from_slice(&acc);
        }
    }
}

/// [`reduce_rows`] for any channel count.
pub(super) fn reduce_rows_any(src: &[f32], w: usize, c: usize, cols: &[Taps], tmp: &mut [f32]) {
    let dw = cols.len();
    for (s, row) in src.chunks_exact(w * c).zip(tmp.chunks_exact_mut(dw * c)) {
        if s.iter().all(|&v| v == 0.0) {
            continue;
        }
        for ((idx, wt, n), o) in cols.iter().zip(row.chunks_exact_mut(c)) {
            for t in 0..*n {
                for ch in 0..c {
                    o[ch] += wt[t] * s[idx[t] * c + ch];
                }
            }
        }
    }
}

/// `n` half-precision zeros, from zeroed memory: pages the merge never writes (parts of
/// chart rectangles that are other charts' texels or gutter) are never made resident.
pub(super) fn zeros_f16(n: usize) -> Vec<f16> {
    use half::vec::HalfBitsVecExt;
    vec![0u16; n].reinterpret_into()
}
