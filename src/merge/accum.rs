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
}

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
        ChartAcc {
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
