//! Any bytes as an OBJ file: must return Ok or Err, never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let p = Path::new("fuzz.obj");
    if let Ok((mut mesh, _)) = scantex::io::obj::parse(p, data) {
        if mesh.validate(p).is_ok() {
            let _ = mesh.topology();
        }
    }
});
