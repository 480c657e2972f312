//! `shapeforest demo`: everything built so far, on built-in synthetic data.

use anyhow::Result;
use clap::Args;
use shapeforest::{spectral::dense_spectrum, synth::icosphere};

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Icosphere subdivisions for the spectrum check.
    #[arg(long, default_value_t = 3)]
    pub subdivisions: u32,
}

pub fn run(args: DemoArgs) -> Result<()> {
    let sphere = icosphere(args.subdivisions, 1.0);
    let spectrum = dense_spectrum(&sphere, 16)?;
    println!(
        "unit sphere, {} vertices: first Laplace eigenvalues (mesh units) vs l(l+1)",
        sphere.n_vertices()
    );
    for (j, lambda) in spectrum.eigenvalues.iter().enumerate() {
        let l = (j as f64).sqrt().floor();
        println!("  λ_{j:<2} = {:8.4}   exact {:4}", lambda / spectrum.area, l * (l + 1.0));
    }
    Ok(())
}
