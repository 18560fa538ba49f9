//! Raster types of the foundation: the float image that restoration and `scantex inpaint` work
//! on (read and written by [`crate::io::image`], so that reading images does not depend on a
//! stage), and a bit per texel for the masks stages hand on.

/// An image of `channels` interleaved float channels (1 = grey, 3 = RGB), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// 1 or 3.
    pub channels: usize,
    /// `width * height * channels` values, nominally in [0, 1].
    pub data: Vec<f32>,
}

/// Rec. 601 luma of an RGB value (the weights held-out evaluation and stage 6 measure
/// detail with).
pub fn luma(p: &[f32; 3]) -> f64 {
    0.299 * p[0] as f64 + 0.587 * p[1] as f64 + 0.114 * p[2] as f64
}

/// One bit per element (texel), row-major: the masks stages hand forward.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BitMask {
    bits: Vec<u64>,
    len: usize,
}

impl BitMask {
    /// `len` clear bits.
    pub fn new(len: usize) -> Self {
        BitMask {
            bits: vec![0; len.div_ceil(64)],
            len,
        }
    }

    /// `len` elements, element `i` set where `f(i)`: 64 elements a word, the words in
    /// parallel (whole-atlas masks at 8192 are 67M elements).
    pub fn from_fn_par(len: usize, f: impl Fn(usize) -> bool + Sync) -> Self {
        use rayon::prelude::*;
        let mut bits = vec![0u64; len.div_ceil(64)];
        bits.par_iter_mut().enumerate().for_each(|(k, w)| {
            for i in 64 * k..(64 * k + 64).min(len) {
                if f(i) {
                    *w |= 1 << (i % 64);
                }
            }
        });
        BitMask { bits, len }
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Sets element `i`.
    pub fn set(&mut self, i: usize) {
        self.bits[i / 64] |= 1 << (i % 64);
    }

    /// Whether element `i` is set.
    #[inline]
    pub fn get(&self, i: usize) -> bool {
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    /// Number of set elements.
    pub fn count(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }
}
