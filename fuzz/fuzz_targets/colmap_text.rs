//! Any bytes as a COLMAP text model: the input is split at NUL bytes into cameras.txt,
//! images.txt and points3D.txt. Parsing and the cross-file checks must return Ok or Err, never
//! panic; a model that parses must project its points without panicking.
#![no_main]
use libfuzzer_sys::fuzz_target;
use scantex::camera::colmap;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let mut parts = data.splitn(3, |&b| b == 0).map(String::from_utf8_lossy);
    let cameras = parts.next().unwrap_or_default();
    let images = parts.next().unwrap_or_default();
    let points = parts.next().unwrap_or_default();
    if let Ok(rec) = colmap::parse_text(Path::new("fuzz"), &cameras, &images, &points) {
        let _ = rec.track_errors();
    }
});
