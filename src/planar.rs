//! The float image that restoration and `scantex inpaint` work on, read and written by
//! [`crate::io::image`]: a foundation type, so that reading images does not depend on a stage.

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
