//! `shapeforest info`: what a mesh file holds, and what the readers warned about.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use shapeforest::mesh::read_mesh_with_report;

#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Mesh files (OFF, OBJ, PLY, TOSCA .vert/.tri; optionally .gz).
    #[arg(required = true)]
    pub meshes: Vec<PathBuf>,
}

pub fn run(args: InfoArgs) -> Result<()> {
    let mut failed = 0;
    for path in &args.meshes {
        match read_mesh_with_report(path) {
            Ok((_, report)) => println!("{}\n{report}", path.display()),
            Err(e) => {
                eprintln!("error: {e}");
                failed += 1;
            }
        }
    }
    if failed > 0 {
        anyhow::bail!("{failed} of {} files could not be read", args.meshes.len());
    }
    Ok(())
}
