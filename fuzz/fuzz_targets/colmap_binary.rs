//! Any bytes as cameras.bin, images.bin and points3D.bin: must return Ok or Err, never panic
//! or allocate without bound.
#![no_main]
use libfuzzer_sys::fuzz_target;
use scantex::camera::colmap;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let p = Path::new("fuzz.bin");
    let _ = colmap::parse_cameras_binary(p, data);
    let _ = colmap::parse_images_binary(p, data);
    let _ = colmap::parse_points_binary(p, data);
});
