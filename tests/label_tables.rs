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

/// A `.sym.vts` beside the reference's `.vts` (row k: the vertex at the mirror image of row k's,
/// as remeshed TOSCA and FAUST ship them) gives the model its reference's left/right symmetry,
/// which `match` uses to repair mirrored maps; one with the wrong number of rows is refused,
/// naming the file.
#[test]
fn a_sym_vts_beside_the_reference_labels_is_stored_and_used() {
    let shapes = shuffled_family(7);
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (i, s) in shapes.iter().enumerate() {
        write_shape(d, &format!("shape{i}"), s);
    }
    // The mirror rows: each row's vertex reflected through the plane x = mean x, snapped to the
    // nearest vertex.
    let m = &shapes[0].mesh;
    let cx = m.vertices.iter().map(|p| p[0]).sum::<f64>() / m.n_vertices() as f64;
    let mirror_of = |v: usize| {
        let p = m.vertices[v];
        let q = [2.0 * cx - p[0], p[1], p[2]];
        (0..m.n_vertices())
            .min_by(|&a, &b| {
                let d = |u: usize| (0..3).map(|c| (m.vertices[u][c] - q[c]).powi(2)).sum::<f64>();
                d(a).total_cmp(&d(b))
            })
            .unwrap()
    };
    let mirrored: Vec<usize> = shapes[0].truth.iter().map(|&v| mirror_of(v)).collect();
    let train = |out: &Path| {
        let mut c = bin();
        c.arg("train");
        for i in 0..5 {
            c.arg("--shape").arg(d.join(format!("shape{i}.off")));
            c.arg("--labels").arg(d.join(format!("shape{i}.vts")));
        }
        c.args(["--trees", "8", "-k", "50", "--out"]).arg(out);
        c.output().unwrap()
    };
    // Too few rows: refused, naming the file.
    std::fs::write(d.join("shape0.sym.vts"), vts(&mirrored[..10])).unwrap();
    let r = train(&d.join("bad.sfm"));
    assert!(!r.status.success(), "a .sym.vts with the wrong row count must be refused");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.contains("shape0.sym.vts") && err.contains("rows"), "{err}");

    std::fs::write(d.join("shape0.sym.vts"), vts(&mirrored)).unwrap();
    let model = d.join("m.sfm");
    let r = train(&model);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stderr).contains("symmetry from its .sym.vts"));
    let out = d.join("out");
    let mut c = bin();
    c.args(["match", "--model"]).arg(&model).arg("--reference").arg(d.join("shape0.off"));
    c.arg("--mesh").arg(d.join("shape5.off")).arg("--out").arg(&out);
    run_ok(&mut c);
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("shape5.report.json")).unwrap()).unwrap();
    assert_eq!(report["reference_symmetry"], serde_json::Value::Bool(true), "{report}");
    let acc = accuracy(&read_map(&out.join("shape5.map.txt")), &shapes[5], &shapes[0]);
    assert!(acc >= 0.85, "map with the symmetry repair on: {:.1} % within 0.05", 100.0 * acc);
}
