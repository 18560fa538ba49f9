//! Any bytes as a `.glb` or `.gltf` file (no external buffers): must return Ok or Err, never
//! panic; a mesh that parses must also validate without panicking.
#![no_main]
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    // A directory that does not exist, so a URI never reads a real file.
    let p = Path::new("/nonexistent-fuzz-dir/fuzz.glb");
    if let Ok((mut mesh, _)) = scantex::io::gltf::parse(p, data) {
        if mesh.validate(p).is_ok() {
            let _ = mesh.topology();
        }
    }
});
