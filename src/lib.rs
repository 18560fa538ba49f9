//! scantex: colour for 3D-scanned objects. A registered mesh and calibrated photographs go in;
//! one seamless, hole-free texture atlas comes out.
//!
//! # The pipeline on one page
//!
//! Each stage is a function of plain typed data; `docs/architecture.md` has the full picture.
//! Stages marked *(planned)* are not built yet; their signatures are the design.
//!
//! | stage | function | in -> out |
//! |---|---|---|
//! | 0. load | [`scene::Scene::load`] | [`scene::SceneSpec`] -> [`mesh::Mesh`], [`camera::colmap::Reconstruction`], [`scene::Photo`]s (lazily decoded) |
//! | 1. atlas | [`atlas::build`] ([`atlas::keep`] for the mesh's own UVs; [`atlas::parameterize`] alone) | welded [`mesh::Mesh`] + view direction -> mesh with per-corner UVs, [`atlas::Atlas`] (charts, face -> chart, texel -> face, built once), [`atlas::AtlasReport`] |
//! | 2. bind | [`bind::bind`] | [`mesh::Mesh`] + normals + [`scene::Photo`]s -> [`bind::Binding`] (valid views per vertex) |
//! | 2b. gains | [`photometric::normalise`] | [`bind::Binding`] + [`mesh::Mesh`] + normals -> the binding with per-photograph gain fields applied, and the [`photometric::Gains`] (exposure, white balance, shading, common shading; with `auto`, every candidate's score) |
//! | 3. resample | [`resample::resample`] | [`mesh::Mesh`] + [`atlas::Atlas`] + [`bind::Binding`] + [`photometric::Gains`] + photos -> [`resample::Resampled`] (atlas colour, texel sources, triangle classes); stage 4 calls it per photograph and chart |
//! | 4. merge | [`merge::merge`] | mesh + [`atlas::Atlas`] + [`bind::Binding`] + [`photometric::Gains`] + photos -> [`resample::Resampled`] (photographs resampled and combined by a chart-aware multiresolution spline; texels no photograph's mask covers marked) |
//! | 5. restore | [`restore::restore_atlas`] ([`restore::inpaint`] for any image) | [`resample::Resampled`] + mesh + [`atlas::Atlas`] + [`restore::RestoreOptions`] + [`restore::Handing`] -> the atlas with unseen texels restored (DCT split, diffusion of the low band, synthesis of the high band), [`restore::RestoreReport`], and what it left as [`restore::Unrestored`] (texel masks and [`restore::UnseenRegion`]s of faces) |
//! | 6. synthesize | [`synth::synthesize`] ([`synth::plane::synthesize`] for a plain image) | [`resample::Resampled`] + mesh + normals + [`atlas::Atlas`] + [`restore::Unrestored`] + up + [`synth::SynthOptions`] -> the atlas with the handed-over regions filled (harmonic low band, exemplar detail in blended surface patches), [`synth::SynthReport`] |
//! | eval | [`eval::evaluate`] | textured [`mesh::Mesh`] + held-out [`scene::Photo`]s -> [`eval::EvalReport`] (PSNR, SSIM, 1-NCC, completeness) |
//! | all | [`pipeline::texture`] | stages 1-6 with one [`pipeline::TextureOptions`] -> [`pipeline::Textured`] + [`pipeline::TextureReport`] |
//! | out | [`io::write_mesh`] | [`mesh::Mesh`] + [`io::EncodedTexture`] -> OBJ/MTL/PNG, PLY, GLB |
//!
//! Conventions: COLMAP's camera conventions throughout ([`camera`]); texture coordinates with
//! origin at the lower-left ([`mesh::UvMap`]); every error is an [`Error`] naming the file and
//! the line, byte or element at fault.

pub mod atlas;
pub mod bind;
pub mod bvh;
pub mod camera;
pub mod depth;
pub mod error;
pub mod eval;
pub mod info;
pub mod io;
pub mod level;
pub mod memory;
pub mod merge;
pub mod mesh;
pub mod photometric;
pub mod photos;
pub mod pipeline;
pub mod planar;
pub mod progress;
pub mod pyramid;
pub mod raycast;
pub mod render;
pub mod resample;
pub mod restore;
pub mod rng;
pub mod sample;
pub mod scene;
pub mod seams;
pub mod synth;

pub use error::{Error, Location, MeshElement, Result};

#[cfg(test)]
mod tests {
    /// Every choice the pipeline makes comes from its options structs, never from environment
    /// variables: a switch read from the environment is a default written twice and a result
    /// no report names (one left from an experiment shipped in the photograph fit, read per
    /// sample). Reads every source file under `src/`.
    #[test]
    fn nothing_reads_the_environment() {
        fn walk(dir: &std::path::Path, found: &mut Vec<String>, files: &mut usize) {
            for entry in std::fs::read_dir(dir).unwrap() {
                let path = entry.unwrap().path();
                if path.is_dir() {
                    walk(&path, found, files);
                } else if path.extension().is_some_and(|e| e == "rs") {
                    *files += 1;
                    let text = std::fs::read_to_string(&path).unwrap();
                    for (i, line) in text.lines().enumerate() {
                        // Spelled in two parts so that this file does not match itself.
                        if [concat!("env::", "var"), concat!("var_", "os(")]
                            .iter()
                            .any(|p| line.contains(p))
                        {
                            found.push(format!("{}:{}: {}", path.display(), i + 1, line.trim()));
                        }
                    }
                }
            }
        }
        let (mut found, mut files) = (Vec::new(), 0);
        let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        walk(&src, &mut found, &mut files);
        assert!(
            files > 50,
            "read only {files} files under {}",
            src.display()
        );
        assert!(
            found.is_empty(),
            "environment read in:\n{}",
            found.join("\n")
        );
    }
}
