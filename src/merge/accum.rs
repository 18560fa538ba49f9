//! A chart's band accumulators: the sums the photographs' layers add their bands into, and
//! their collapse into the chart's colours.

use super::*;

/// A chart's band accumulators.
pub(super) struct ChartAcc {
    /// Per level: mask-weighted band sums (3 channels); for [`Masks::BestView`] level 0 is
    /// empty (see `finest`).
    pub(super) num: Vec<Plane>,
    /// Per level: mask sums (level 0 empty for [`Masks::BestView`]).
    pub(super) den: Vec<Vec<f32>>,
    /// [`Masks::BestView`]: the finest band's running weighted mean, in half precision (an
    /// error under 5e-4 for bands within +-1, below half a step of 8-bit output), 0 where
    /// no layer has entered it. At 8192 this and its weights in place of full-precision
    /// level-0 sums save 8 bytes per chart texel, about 0.4 GB.
    pub(super) finest: Vec<f16>,
    /// [`Masks::BestView`]: the weights summed into `finest` (1 once some layer entered it,
    /// with the best view alone, which replaces rather than averages). Freed after the
    /// photographs on charts with coarser levels (`multiband`), before the peak.
    pub(super) finest_w: Vec<f16>,
    /// Largest view weight so far (relative to the face's best view, `relative_weight`) and
    /// its photograph, photographs seen, per texel.
    pub(super) best_w: Vec<f16>,
    pub(super) best: Vec<u16>,
    pub(super) views: Vec<u8>,
    /// [`Masks::Paper`]: the weighted mean of the photographs (stage 3's texture), which the
    /// complement of the masks carries.
    pub(super) avg: Option<Vec<[f32; 4]>>,
    /// Per level, one bit per block of [`BLOCK`] texels: set once the block's memory in
    /// every array above has been made writable ([`ChartAcc::ready`]).
    written: Vec<Vec<u64>>,
}

/// Texels per block of [`ChartAcc::ready`]: small, so that a block's memory in any array
/// (at most 192 bytes) seldom reaches onto a page no texel is written in.
const BLOCK: usize = 16;

impl ChartAcc {
    pub(super) fn new(ch: &Chart, paper: bool, winner_mode: bool) -> Self {
        let mut num = Vec::new();
        let mut den = Vec::new();
        let (mut w, mut h) = (ch.w, ch.h);
        for l in 0..=ch.levels {
            if l == 0 && winner_mode {
                num.push(Plane {
                    w,
                    h,
                    c: 3,
                    d: Vec::new(),
                });
                den.push(Vec::new());
            } else {
                num.push(Plane::zeros(w, h, 3));
                den.push(vec![0f32; w * h]);
            }
            (w, h) = (w.div_ceil(2), h.div_ceil(2));
        }
        let n = ch.w * ch.h;
        let mut acc = ChartAcc {
            num,
            den,
            finest: if winner_mode {
                zeros_f16(3 * n)
            } else {
                Vec::new()
            },
            finest_w: if winner_mode {
                zeros_f16(n)
            } else {
                Vec::new()
            },
            best_w: zeros_f16(n),
            best: vec![NO_PHOTO; n],
            views: vec![0; n],
            avg: paper.then(|| vec![[0.0; 4]; n]),
            written: Vec::new(),
        };
        acc.written = acc
            .num
            .iter()
            .map(|p| vec![0; (p.w * p.h).div_ceil(BLOCK).div_ceil(64)])
            .collect();
        acc
    }

    /// Makes texel `i` of level `l` writable in every array; call before the first write of
    /// a texel. Zeroed memory fresh from the system is mapped on first touch; the merge's
    /// first touch of a texel is a `+=`, whose read maps the kernel's shared zero page, and the
    /// write right after faults again and flushes every core's TLB (an interrupt to the other
    /// cores per page: 3-4% of the merge's CPU time). The first access to the memory of the
    /// texel's block is made a write instead ([`crate::io::touch_for_writing`]); pages far
    /// from any texel written (other charts' texels and gutter in the chart's rectangle) stay
    /// unmapped.
    #[inline]
    pub(super) fn ready(&mut self, l: usize, i: usize) {
        let b = i / BLOCK;
        let (word, bit) = (b / 64, b % 64);
        if self.written[l][word] >> bit & 1 == 1 {
            return;
        }
        self.written[l][word] |= 1 << bit;
        self.ready_block(l, b * BLOCK);
    }

    /// The work of [`ChartAcc::ready`] for the block from texel `a` of level `l`.
    #[cold]
    fn ready_block(&mut self, l: usize, a: usize) {
        use crate::io::touch_for_writing as touch;
        let b = (a + BLOCK).min(self.num[l].w * self.num[l].h);
        if !self.den[l].is_empty() {
            touch(&mut self.den[l][a..b]);
            touch(&mut self.num[l].d[3 * a..3 * b]);
        }
        if l > 0 {
            return;
        }
        touch(&mut self.views[a..b]);
        touch(&mut self.best_w[a..b]);
        if !self.finest.is_empty() {
            touch(&mut self.finest[3 * a..3 * b]);
        }
        if !self.finest_w.is_empty() {
            touch(&mut self.finest_w[a..b]);
        }
        if let Some(avg) = &mut self.avg {
            touch(&mut avg[a..b]);
        }
    }

    /// The chart's size per level.
    pub(super) fn sizes(&self) -> Vec<(usize, usize)> {
        self.num.iter().map(|p| (p.w, p.h)).collect()
    }

    /// The blended chart image, or with best-view masks on a chart with coarser levels its
    /// level 1 (the finest band stays in `finest`, for [`write_chart`]); the band sums are
    /// freed, the per-texel bookkeeping stays.
    pub(super) fn collapse(&mut self, a: f32, winner_mode: bool) -> Plane {
        let top = self.num.len() - 1;
        for l in 0..=top {
            if l == 0 && winner_mode {
                continue;
            }
            let (num, den) = (&mut self.num[l], &self.den[l]);
            for (i, &d) in den.iter().enumerate() {
                for k in 0..3 {
                    let v = &mut num.d[3 * i + k];
                    *v = if d > 1e-6 { *v / d } else { 0.0 };
                }
            }
        }
        if winner_mode && top == 0 {
            // A chart too small for a pyramid: its one level is the blended colours, known
            // where some layer entered.
            let (w, h) = (self.num[0].w, self.num[0].h);
            let finest = std::mem::take(&mut self.finest);
            let weights = std::mem::take(&mut self.finest_w);
            self.den[0] = weights.iter().map(|&b| f32::from(b > f16::ZERO)).collect();
            let d: Vec<f32> = finest.iter().map(|v| v.to_f32()).collect();
            self.num[0] = Plane::from_vec(w, h, 3, d).expect("sized");
        }
        // The coarsest level is a colour, not a band: where no mask reaches it, extend the
        // colours around rather than expand zeros into the chart's border.
        let weights: Vec<f32> = self.den[top].iter().map(|&d| f32::from(d > 1e-6)).collect();
        pyramid::fill_holes(&mut self.num[top], &weights, a);
        self.den = Vec::new();
        if winner_mode && top > 0 {
            // The coarser levels collapsed; `write_chart` expands them a stripe at a time
            // and adds the half-precision finest band (no chart-sized full-precision image:
            // 12 bytes per texel less at the peak).
            let coarse = pyramid::collapse(self.num.split_off(1), a);
            self.num = Vec::new();
            return coarse;
        }
        pyramid::collapse(std::mem::take(&mut self.num), a)
    }
}
