//! Fuzzing the readers an attacker can feed (issue 16): mesh bytes, model files with their
//! checksum recomputed, label maps and pipeline files. Each must end in a value or an error —
//! no panic, no abort, and memory bounded by the limits, not by what the bytes claim.
//!
//! `#[ignore]`d: `.ci/run` runs them with `PROPTEST_CASES` set and the address space capped
//! (`ulimit -v`), so an allocation a forged size drives fails the run:
//! `PROPTEST_CASES=2000 cargo test --release --test fuzz -- --ignored`.

use std::sync::{Arc, OnceLock};

use proptest::prelude::*;
use shapeforest::{
    forest::{
        fnv1a64, labels_identity, read_label_map, read_per_label_map, read_per_label_rows, RandomForest,
        TrainingSet, TrainingShape,
    },
    limits::Limits,
    mesh::{parse_mesh, parse_tosca, write_mesh, MeshFormat},
    pipeline::PipelineSpec,
    spectral::{compute_spectrum, Spectrum, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

/// A small trained model, its file bytes, and the spectrum of its training shape.
struct Fixture {
    model: Vec<u8>,
    /// The same model in format version 2 (still read), whose MessagePack payload maps onto
    /// JSON values for the structured edits (version 3 holds the trees as byte strings).
    model_v2: Vec<u8>,
    spectrum: Arc<Spectrum>,
    meshes: Vec<(MeshFormat, Vec<u8>)>,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let fam = creature_family(&CreatureParams { target_vertices: 800, seed: 1, ..Default::default() }, 1)
            .unwrap();
        let mesh = &fam.shapes[0];
        let spectrum = Arc::new(compute_spectrum(mesh, &SpectrumParams::new(20)).unwrap());
        let n = mesh.n_vertices();
        let shape = TrainingShape::new("s", spectrum.clone(), labels_identity(n));
        let set = TrainingSet::new(vec![shape], n).unwrap();
        let forest = RandomForest::params().n_trees(2).max_depth(6).fit(&set).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut meshes = Vec::new();
        for (ext, format) in [("off", MeshFormat::Off), ("obj", MeshFormat::Obj), ("ply", MeshFormat::Ply)] {
            let p = dir.path().join(format!("m.{ext}"));
            write_mesh(&p, mesh).unwrap();
            meshes.push((format, std::fs::read(&p).unwrap()));
        }
        Fixture {
            model: forest.to_bytes().unwrap(),
            model_v2: forest.to_bytes_version(2).unwrap(),
            spectrum,
            meshes,
        }
    })
}

/// Nasty values for numbers in text and in decoded structures.
const NASTY: &[&str] = &[
    "0",
    "-1",
    "-2",
    "1",
    "65535",
    "268435456",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "1e308",
    "nan",
    "-inf",
    "3.5",
];

/// Applies edits to bytes: `(position, op, byte)`; ops overwrite, insert, delete, or insert a
/// nasty number.
fn mutate(base: &[u8], edits: &[(usize, u8, u8)]) -> Vec<u8> {
    let mut out = base.to_vec();
    for &(pos, op, byte) in edits {
        let at = if out.is_empty() { 0 } else { pos % (out.len() + 1) };
        match op % 4 {
            0 if at < out.len() => out[at] = byte,
            1 => out.insert(at, byte),
            2 if at < out.len() => {
                out.remove(at);
            }
            _ => {
                let s = NASTY[byte as usize % NASTY.len()];
                out.splice(at..at, s.bytes());
            }
        }
    }
    out
}

fn edits() -> impl Strategy<Value = Vec<(usize, u8, u8)>> {
    proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..12)
}

/// Re-frames a payload as a model file with a valid checksum (as an attacker would).
fn with_checksum(prefix: &[u8], payload: &[u8]) -> Vec<u8> {
    let mut out = prefix[..12].to_vec();
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&fnv1a64(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// Every numeric leaf of a decoded payload, as a path of array indices / keys.
fn numeric_paths(v: &serde_json::Value, path: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    if out.len() > 4000 {
        return;
    }
    match v {
        serde_json::Value::Number(_) => out.push(path.clone()),
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate().take(64) {
                path.push(i.to_string());
                numeric_paths(x, path, out);
                path.pop();
            }
        }
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                path.push(k.clone());
                numeric_paths(x, path, out);
                path.pop();
            }
        }
        _ => {}
    }
}

fn at_path<'a>(v: &'a mut serde_json::Value, path: &[String]) -> Option<&'a mut serde_json::Value> {
    let mut cur = v;
    for p in path {
        cur = match cur {
            serde_json::Value::Array(a) => a.get_mut(p.parse::<usize>().ok()?)?,
            serde_json::Value::Object(m) => m.get_mut(p)?,
            _ => return None,
        };
    }
    Some(cur)
}

/// Loads model bytes as the daemon does: decode, check against the limits, and use it.
fn load_and_use(bytes: &[u8]) {
    let Ok(forest) = RandomForest::from_bytes(bytes) else { return };
    if Limits::default().check_model(&forest).is_err() {
        return;
    }
    let _ = forest.predict(&fixture().spectrum);
}

fn peak_rss() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmHWM:"))?.to_string();
            line.split_whitespace().nth(1)?.parse::<u64>().ok()
        })
        .map_or(0, |kb| kb * 1024)
}

proptest! {
    #[test]
    #[ignore]
    fn mesh_bytes_never_panic(which in 0usize..3, e in edits(), raw in proptest::collection::vec(any::<u8>(), 0..512)) {
        let (format, base) = &fixture().meshes[which];
        let bytes = mutate(base, &e);
        let _ = parse_mesh(&bytes, *format);
        let _ = parse_mesh(&raw, *format);
        let _ = parse_tosca(&raw, &bytes);
        prop_assert!(peak_rss() < 3 << 30);
    }

    #[test]
    #[ignore]
    fn model_bytes_with_recomputed_checksums_never_panic(
        e in edits(),
        leaf in any::<usize>(),
        value in 0usize..NASTY.len(),
        mirror in any::<bool>(),
    ) {
        let f = fixture();
        let (prefix, payload) = f.model.split_at(28);
        // Raw edits of the payload.
        load_and_use(&with_checksum(prefix, &mutate(payload, &e)));
        // A structured edit: one number of the decoded payload set to a nasty value, mirrored
        // into the forest's copy of a header field when asked (header and forest must agree),
        // on the version-2 encoding.
        let (prefix, payload) = f.model_v2.split_at(28);
        let mut v: serde_json::Value = rmp_serde::from_slice(payload).unwrap();
        let mut paths = Vec::new();
        numeric_paths(&v, &mut Vec::new(), &mut paths);
        // Header fields (params, label count, K, energy grid) are few: pick among them half the
        // time, mirrored into the forest's copy, as a forger who keeps both consistent would.
        let header: Vec<Vec<String>> = paths.iter().filter(|p| p.first().is_some_and(|f| f == "0")).cloned().collect();
        let path = if mirror && !header.is_empty() { header[leaf % header.len()].clone() } else { paths[leaf % paths.len()].clone() };
        let nasty: serde_json::Value = match NASTY[value].parse::<u64>() {
            Ok(u) => u.into(),
            Err(_) => NASTY[value].parse::<i64>().map(Into::into)
                .unwrap_or_else(|_| NASTY[value].parse::<f64>().ok().and_then(serde_json::Number::from_f64).map_or(0.into(), Into::into)),
        };
        if let Some(x) = at_path(&mut v, &path) {
            *x = nasty.clone();
        }
        if mirror && path.first().is_some_and(|p| p == "0") {
            let mut other = path.clone();
            other[0] = "1".into();
            if let Some(x) = at_path(&mut v, &other) {
                *x = nasty;
            }
        }
        if let Ok(bytes) = rmp_serde::to_vec(&v) {
            load_and_use(&with_checksum(prefix, &bytes));
        }
        prop_assert!(peak_rss() < 3 << 30);
    }

    #[test]
    #[ignore]
    fn label_maps_never_panic(e in edits(), n in 0usize..600, one_based in any::<bool>()) {
        let base = (0..400).map(|v| format!("{v}\n")).collect::<String>();
        let bytes = mutate(base.as_bytes(), &e);
        let _ = read_label_map(bytes.as_slice(), one_based, Limits::default().max_labels);
        let _ = read_per_label_map(bytes.as_slice(), one_based, n);
        let _ = read_per_label_rows(bytes.as_slice(), one_based, n);
        prop_assert!(peak_rss() < 3 << 30);
    }

    #[test]
    #[ignore]
    fn pipeline_files_never_panic(e in edits()) {
        let base = include_str!("../pipelines/watch.toml");
        let bytes = mutate(base.as_bytes(), &e);
        let text = String::from_utf8_lossy(&bytes);
        let _ = PipelineSpec::from_toml(&text, "fuzz.toml");
    }
}
