//! Models trained from per-label maps (`.vts`) on shapes that each have their own vertex order,
//! as remeshed datasets and real scans do: `match` must read labels through the reference's
//! label table (never assume label = vertex), refuse a reference it cannot place labels on, and
//! map between two scans with `--to`.

mod common;

use std::{path::Path, process::Command};

use common::labels::{shuffled_family, vts, write_shape, Shuffled};

use common::bin;

fn read_map(path: &Path) -> Vec<usize> {
    std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.trim().parse().unwrap())
        .collect()
}

fn accuracy(map: &[usize], from: &Shuffled, to: &Shuffled) -> f64 {
    common::labels::accuracy(map, from, to)
}

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn match_reads_labels_through_the_reference_table() {
    let shapes = shuffled_family(8);
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut train = bin();
    train.arg("train");
    for (i, s) in shapes.iter().enumerate().take(5) {
        write_shape(d, &format!("shape{i}"), s);
        train.arg("--shape").arg(d.join(format!("shape{i}.off")));
        train.arg("--labels").arg(d.join(format!("shape{i}.vts")));
    }
    for (i, s) in shapes.iter().enumerate().skip(5) {
        write_shape(d, &format!("scan{i}"), s);
    }
    let model = d.join("m.sfm");
    let text = run_ok(train.args(["--one-based", "--trees", "8", "-k", "50", "--out"]).arg(&model));
    assert!(text.contains("reference shape0"), "{text}");

    // The model's own reference: the map is right (before, labels were read as vertex indices
    // of the reference and the map was wrong without a word).
    let out = d.join("to-ref");
    let matched = |reference: &str, extra: &[&str], out: &Path| {
        let mut c = bin();
        c.args(["match", "--model"]).arg(&model);
        c.arg("--reference").arg(d.join(format!("{reference}.off")));
        c.arg("--mesh").arg(d.join("scan5.off")).arg("--out").arg(out).args(extra);
        c.output().unwrap()
    };
    let r = matched("shape0", &[], &out);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let acc = accuracy(&read_map(&out.join("scan5.map.txt")), &shapes[5], &shapes[0]);
    assert!(acc >= 0.85, "map to the model's reference: {:.1} % within 0.05", 100.0 * acc);

    // Another training shape without its label map: refused, naming the model's reference.
    let r = matched("shape1", &[], &d.join("refused"));
    assert!(!r.status.success(), "a reference the model cannot place its labels on must be refused");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("shape0") && err.contains("--reference-labels"), "{err}");

    // ... and with its label map: right again.
    let labels = d.join("shape1.vts");
    let out1 = d.join("to-shape1");
    let r = matched("shape1", &["--reference-labels", labels.to_str().unwrap()], &out1);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let acc = accuracy(&read_map(&out1.join("scan5.map.txt")), &shapes[5], &shapes[1]);
    assert!(acc >= 0.85, "map to shape1 through its labels: {:.1} % within 0.05", 100.0 * acc);

    // Scan to scan, neither a training shape.
    let pair = d.join("pair");
    let r = matched("shape0", &["--to", d.join("scan6.off").to_str().unwrap()], &pair);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let map = read_map(&pair.join("scan5.to.scan6.map.txt"));
    assert_eq!(map.len(), shapes[5].mesh.n_vertices());
    let acc = accuracy(&map, &shapes[5], &shapes[6]);
    assert!(acc >= 0.8, "map scan5 → scan6: {:.1} % within 0.05", 100.0 * acc);
}

#[test]
fn a_reference_label_map_that_lacks_labels_is_refused() {
    let shapes = shuffled_family(4);
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut train = bin();
    train.arg("train");
    for (i, s) in shapes.iter().enumerate().take(3) {
        write_shape(d, &format!("shape{i}"), s);
        train.arg("--shape").arg(d.join(format!("shape{i}.off")));
        train.arg("--labels").arg(d.join(format!("shape{i}.vts")));
    }
    let model = d.join("m.sfm");
    run_ok(train.args(["--one-based", "--trees", "3", "-k", "30", "--out"]).arg(&model));
    // A label map of shape 3 with the last half of its rows blank.
    write_shape(d, "other", &shapes[3]);
    let text = vts(&shapes[3].truth);
    let half: Vec<&str> = text.lines().collect();
    let cut = half.len() / 2;
    let partial: String =
        half.iter().enumerate().map(|(i, l)| if i < cut { format!("{l}\n") } else { "\n".into() }).collect();
    std::fs::write(d.join("other.vts"), partial).unwrap();
    let out = bin()
        .args(["match", "--model"])
        .arg(&model)
        .arg("--reference")
        .arg(d.join("other.off"))
        .arg("--reference-labels")
        .arg(d.join("other.vts"))
        .arg("--mesh")
        .arg(d.join("shape1.off"))
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("other.vts") && err.contains("shape0"), "{err}");
}
