//! The `scantex` command: parses arguments, calls the library, reports errors.

use clap::{Args, Parser, Subcommand};
use scantex::scene::{Scene, SceneSpec};
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "scantex",
    version,
    about = "Texture atlases for 3D-scanned objects from calibrated photographs"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check a scene: mesh topology, cameras, photographs, reprojection error.
    Info {
        #[command(flatten)]
        scene: SceneArgs,
        /// Print the report as JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

/// How every command is pointed at a scene: a directory, explicit paths, or both.
#[derive(Args)]
struct SceneArgs {
    /// Scene directory holding a mesh file, sparse/ (or sparse/0/), images/ and optionally masks/.
    scene: Option<PathBuf>,
    /// Mesh file (.obj, .ply, .gltf, .glb); overrides the scene directory's.
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// COLMAP model directory (text or binary); overrides the scene directory's.
    #[arg(long)]
    colmap: Option<PathBuf>,
    /// Photographs directory; overrides the scene directory's images/.
    #[arg(long)]
    images: Option<PathBuf>,
    /// Object masks directory (white = object); overrides the scene directory's masks/.
    #[arg(long)]
    masks: Option<PathBuf>,
}

impl SceneArgs {
    fn spec(self) -> SceneSpec {
        SceneSpec {
            dir: self.scene,
            mesh: self.mesh,
            colmap: self.colmap,
            images: self.images,
            masks: self.masks,
        }
    }
}

fn run(cli: Cli) -> scantex::Result<ExitCode> {
    match cli.command {
        Command::Info { scene, json } => {
            let scene = Scene::load(&scene.spec())?;
            let report = scantex::info::info(&scene);
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&report).expect("report serialises")
                );
            } else {
                print!("{report}");
            }
            // Missing or broken photographs make the scene unusable for texturing: say so in
            // the exit code so batch jobs stop here.
            match scene.check_photos() {
                Ok(()) => Ok(ExitCode::SUCCESS),
                Err(e) => {
                    eprintln!("scantex: error: {e}");
                    Ok(ExitCode::FAILURE)
                }
            }
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("scantex: error: {e}");
            ExitCode::FAILURE
        }
    }
}
