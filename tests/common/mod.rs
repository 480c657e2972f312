//! Fixtures shared by the integration tests: the binary, the shared data folder, labelled
//! synthetic shapes (`labels`), the bumpy-sphere family (`bumpy`, shared with the benches), a
//! data folder with labelled creatures and a scan, the daemon driver (`daemon`) and a real
//! `nats-server` for the scale-out tests (`nats`).
#![allow(dead_code)]

pub mod bumpy;
pub mod daemon;
pub mod labels;
pub mod nats;

use std::{
    path::{Path, PathBuf},
    process::Command,
};

/// The binary under test: the one built for the tests, or `$SHAPEFOREST_TEST_BIN` (to run the
/// suite against another build, e.g. to check that a test fails without a fix).
pub fn bin_path() -> PathBuf {
    std::env::var_os("SHAPEFOREST_TEST_BIN")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_BIN_EXE_shapeforest")))
}

/// A command running the binary under test.
pub fn bin() -> Command {
    Command::new(bin_path())
}

/// The shared data folder: `$SHAPEFOREST_DATA`, else `../shared/data` beside the crate.
pub fn data_root() -> PathBuf {
    match std::env::var_os("SHAPEFOREST_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
    }
}

/// `relative` inside the shared data folder, if it is there. When it is not, the test says
/// `SKIPPED` and why, and returns `None` — unless `SHAPEFOREST_REQUIRE_DATA=1` (CI, where the
/// data is present), where a missing file fails the test.
pub fn shared_data(relative: &str) -> Option<PathBuf> {
    let path = data_root().join(relative);
    if path.exists() {
        return Some(path);
    }
    let why = format!(
        "{} is absent (set SHAPEFOREST_DATA to the shared data folder, or put it at ../shared/data)",
        path.display()
    );
    if std::env::var("SHAPEFOREST_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("SHAPEFOREST_REQUIRE_DATA=1 but {why}");
    }
    println!("SKIPPED: {why}");
    None
}

/// A data folder for `pipelines/train.toml` and `match.toml`: three labelled creatures of
/// ~1200 vertices (identity labels) in `labeled/` and a fourth pose as `incoming/scan.off`.
/// Returns the vertices per shape.
pub fn creatures_data_folder(data: &Path, seed: u64) -> usize {
    let fam = shapeforest::synth::creature_family(
        &shapeforest::synth::CreatureParams { target_vertices: 1200, seed, ..Default::default() },
        4,
    )
    .unwrap();
    let n = fam.template.n_vertices();
    let labels: String = (0..n).map(|v| format!("{v}\n")).collect();
    std::fs::create_dir_all(data.join("labeled")).unwrap();
    std::fs::create_dir_all(data.join("incoming")).unwrap();
    for i in 0..3 {
        shapeforest::mesh::write_mesh(data.join(format!("labeled/c{i}.off")), &fam.shapes[i]).unwrap();
        std::fs::write(data.join(format!("labeled/c{i}.labels")), &labels).unwrap();
    }
    shapeforest::mesh::write_mesh(data.join("incoming/scan.off"), &fam.shapes[3]).unwrap();
    n
}

/// A model trained on `shapes` (one shared vertex indexing: labels = vertex indices; 60
/// eigenpairs, `trees` trees, the default seed) and saved at `path`.
pub fn save_shared_indexing_model(shapes: &[&shapeforest::mesh::Mesh], trees: usize, path: &Path) {
    use shapeforest::{
        forest::{RandomForest, TrainingSet},
        spectral::{compute_spectrum, SpectrumParams},
    };
    use std::sync::Arc;
    let spectra = shapes.iter().enumerate().map(|(i, m)| {
        (format!("s{i}"), Arc::new(compute_spectrum(m, &SpectrumParams::new(60)).expect("spectrum")))
    });
    let set = TrainingSet::same_indexing(spectra).expect("training set");
    let forest =
        RandomForest::params().n_trees(trees).check().expect("forest params").fit(&set).expect("forest");
    forest.save(path).expect("model file");
}

/// The family's shapes for the evaluation protocol (`s0`, `s1`, …), each its own ground truth
/// (shared vertex indexing).
pub fn protocol_shapes(
    fam: &shapeforest::synth::ShapeFamily,
) -> Vec<shapeforest::eval::protocol::ProtocolShape> {
    fam.shapes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            shapeforest::eval::protocol::ProtocolShape::identity(
                format!("s{i}"),
                std::sync::Arc::new(m.clone()),
            )
        })
        .collect()
}
