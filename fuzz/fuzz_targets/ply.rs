//! Any bytes as a PLY file: must return Ok or Err, never panic; a mesh that parses must
//! also validate without panicking.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let p = Path::new("fuzz.ply");
    if let Ok((mut mesh, _)) = scantex::io::ply::parse(p, data) {
        if mesh.validate(p).is_ok() {
            let _ = mesh.topology();
        }
    }
});
