//! Any bytes as a photograph or a mask (JPEG, PNG, TIFF, EXR, by content): the completeness
//! check and the decoder must return Ok or Err, never panic, and allocate at most 64 MB.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let p = Path::new("fuzz.img");
    if let Ok(img) = scantex::io::image::decode_checked(p, data, 64 << 20) {
        let (mask, w, h) = scantex::io::image::mask_of(&img);
        assert_eq!(mask.len(), w * h);
    }
});
