//! Model file size and load time by format version (issue 14): reads a model (any version),
//! writes it as versions 2 and 3, checks that both decode to the same forest, and reports bytes
//! and decode times.
//!
//! `cargo run --release --example model_size -- MODEL.sfm`

use std::time::Instant;

use shapeforest::forest::RandomForest;

fn main() -> anyhow::Result<()> {
    let path = std::env::args().nth(1).ok_or_else(|| anyhow::anyhow!("usage: model_size MODEL.sfm"))?;
    let forest = RandomForest::load(&path)?;
    let nodes = forest.n_nodes();
    let leaves = (nodes + forest.n_trees()) / 2; // full binary trees: leaves = (nodes + 1) / 2 each
    println!(
        "{path}: {} trees, {nodes} nodes ({leaves} leaves), mean leaf support {:.3}, {} labels",
        forest.n_trees(),
        forest.mean_leaf_support(),
        forest.n_labels()
    );
    let mut sizes = Vec::new();
    for version in [2u32, 3] {
        let t0 = Instant::now();
        let bytes = forest.to_bytes_version(version)?;
        let encode_s = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let back = RandomForest::from_bytes(&bytes)?;
        let decode_s = t0.elapsed().as_secs_f64();
        anyhow::ensure!(back == forest, "version {version} did not decode to the same forest");
        println!(
            "  version {version}: {:.1} MiB ({:.1} bytes per node), encode {encode_s:.2} s, decode {decode_s:.2} s",
            bytes.len() as f64 / (1 << 20) as f64,
            bytes.len() as f64 / nodes as f64
        );
        sizes.push(bytes.len());
    }
    println!("  version 3 / version 2: {:.3}", sizes[1] as f64 / sizes[0] as f64);
    Ok(())
}
