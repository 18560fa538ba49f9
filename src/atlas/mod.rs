//! Stage 1, the atlas (issue 4, in progress): chart segmentation is built
//! ([`segment::segment`]); per-chart parameterization with the paper's view-weighted L2
//! stretch and packing are to come.

pub mod segment;
