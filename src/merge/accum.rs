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
    /// The pages of the arrays above written so far ([`ChartAcc::ready`]).
    written: Written,
}

/// Which 4 KB pages of a zeroed array have been written. Zeroed memory fresh from the system
/// is mapped on first touch; the merge's first touch of a texel is a `+=`, whose read maps the
/// kernel's shared zero page, and the write right after faults again and flushes every core's
/// TLB (an interrupt to the other cores per page: 3-4% of the merge's CPU time). A page's
/// first access is made a write instead ([`crate::io::touch_for_writing`]); pages no texel is
/// written in (other charts' texels and gutter in the chart's rectangle) stay unmapped.
#[derive(Default)]
struct Pages(Vec<u64>);

impl Pages {
    fn of<T>(v: &[T]) -> Pages {
        let pages = std::mem::size_of_val(v) / crate::io::PAGE + 2;
        Pages(vec![0; pages.div_ceil(64)])
    }

    /// Makes elements `a..b` (not empty) of `v`, the array these pages cover, writable.
    #[inline]
    fn ready<T>(&mut self, v: &mut [T], a: usize, b: usize) {
        let base = v.as_ptr() as usize;
        for i in [a, b - 1] {
            let page =
                (base + i * std::mem::size_of::<T>()) / crate::io::PAGE - base / crate::io::PAGE;
            let (w, bit) = (page / 64, page % 64);
            if self.0[w] >> bit & 1 == 0 {
                crate::io::touch_for_writing(&mut v[i..=i]);
                self.0[w] |= 1 << bit;
            }
        }
    }
}

/// [`Pages`] for each array of a [`ChartAcc`].
#[derive(Default)]
struct Written {
    num: Vec<Pages>,
    den: Vec<Pages>,
    finest: Pages,
    finest_w: Pages,
    best_w: Pages,
    views: Pages,
    avg: Pages,
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
            written: Written::default(),
        };
        acc.written = Written {
            num: acc.num.iter().map(|p| Pages::of(&p.d)).collect(),
            den: acc.den.iter().map(|d| Pages::of(d)).collect(),
            finest: Pages::of(&acc.finest),
            finest_w: Pages::of(&acc.finest_w),
            best_w: Pages::of(&acc.best_w),
            views: Pages::of(&acc.views),
            avg: acc.avg.as_deref().map_or_else(Pages::default, Pages::of),
        };
        acc
    }

    /// Makes texel `i` of level `l` writable in every array ([`Pages`]); call before the
    /// first write of a texel.
    #[inline]
    pub(super) fn ready(&mut self, l: usize, i: usize) {
        let w = &mut self.written;
        if !self.den[l].is_empty() {
            w.den[l].ready(&mut self.den[l], i, i + 1);
            w.num[l].ready(&mut self.num[l].d, 3 * i, 3 * i + 3);
        }
        if l > 0 {
            return;
        }
        w.views.ready(&mut self.views, i, i + 1);
        w.best_w.ready(&mut self.best_w, i, i + 1);
        if !self.finest.is_empty() {
            w.finest.ready(&mut self.finest, 3 * i, 3 * i + 3);
        }
        if !self.finest_w.is_empty() {
            w.finest_w.ready(&mut self.finest_w, i, i + 1);
        }
        if let Some(avg) = &mut self.avg {
            w.avg.ready(avg, i, i + 1);
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
