//! Fixtures shared by the integration tests: the binary, the shared data folder, labelled
//! synthetic shapes (`labels`) and the daemon driver (`daemon`).
#![allow(dead_code)]

pub mod daemon;
pub mod labels;

use std::{
    path::{Path, PathBuf},
    process::Command,
};

/// The `shapeforest` binary built for the tests.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_shapeforest"))
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
