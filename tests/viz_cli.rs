//! Pictures beside results, through the binary: the PNG snapshot of `match` and of the batch
//! match pipeline (the daemon's sink), `shapeforest view` on both kinds of result folder, and
//! the evaluation's `index.html` with a snapshot and a view per test shape.

mod common;

use std::{path::Path, process::Command};

use common::bin;

fn run(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}

/// Decodes a PNG and counts, in each half, the pixels that differ from the top-left one (the
/// background).
fn drawn_halves(path: &Path) -> (usize, usize, usize) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let (w, h) = (info.width as usize, info.height as usize);
    let px = |x: usize, y: usize| &buf[3 * (y * w + x)..3 * (y * w + x) + 3];
    let bg = px(0, 0).to_vec();
    let count = |x0: usize, x1: usize| {
        (0..h).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| px(x, y) != bg.as_slice()).count()
    };
    (count(0, w / 2), count(w / 2, w), w * h / 2)
}

fn assert_both_drawn(path: &Path) {
    let (left, right, half) = drawn_halves(path);
    assert!(
        left * 20 > half && right * 20 > half,
        "{}: drawn pixels {left} / {right} of {half}",
        path.display()
    );
}

#[test]
fn match_results_get_a_snapshot_and_view_writes_a_page() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    common::creatures_data_folder(&data, 4);
    let root = env!("CARGO_MANIFEST_DIR");
    for p in ["train", "match"] {
        run(bin().arg("run").arg(format!("{root}/pipelines/{p}.toml")).arg("--data-dir").arg(&data));
    }
    // The pipeline's match sink (the daemon's) writes the snapshot beside the map.
    let result = data.join("matched/scan");
    assert_both_drawn(&result.join("scan.png"));
    let said = run(bin().arg("view").arg(&result));
    assert!(said.contains("view.html"), "{said}");
    let page = std::fs::read_to_string(result.join("view.html")).unwrap();
    assert!(page.contains("scan: scan") && page.contains("reference: c0"), "names in the page");
    assert!(!page.contains("data-mode=\"error\""), "no ground truth here: no heat-map button");

    // `shapeforest match` writes SCAN.png too, and its folder can be viewed.
    let out = dir.path().join("m");
    // `shapeforest match` of the folder's scan onto its reference c0 (and `extra` arguments).
    let match_scan = |out: &Path, extra: &[&std::ffi::OsStr]| {
        let mut cmd = bin();
        cmd.args(["match", "--model"]).arg(data.join("models/model-v000001.sfm"));
        cmd.arg("--reference").arg(data.join("labeled/c0.off"));
        cmd.arg("--mesh").arg(data.join("incoming/scan.off")).args(extra).arg("--out").arg(out);
        run(&mut cmd)
    };
    match_scan(&out, &[]);
    assert_both_drawn(&out.join("scan.png"));
    // With a SCAN.errors.csv beside the map the page gets the heat map and the curve.
    std::fs::write(out.join("scan.errors.csv"), "vertex,error\n0,0.01\n7,0.3\n").unwrap();
    run(bin().arg("view").arg(&out).arg("--out").arg(out.join("page.html")));
    let page = std::fs::read_to_string(out.join("page.html")).unwrap();
    assert!(page.contains("data-mode=\"error\"") && page.contains("50.0 % within 0.05"));

    // A scan-to-scan map (`match --to B`): the page shows the scan against B.
    let out2 = dir.path().join("m2");
    let b = data.join("labeled/c1.off");
    match_scan(&out2, &["--to".as_ref(), b.as_os_str()]);
    assert_both_drawn(&out2.join("scan.png"));
    run(bin().arg("view").arg(&out2));
    let page = std::fs::read_to_string(out2.join("view.html")).unwrap();
    assert!(page.contains("scan: scan") && page.contains("reference: c1"), "the page maps onto B");

    // Bad folders and bad files are named.
    let o = bin().arg("view").arg(data.join("incoming")).output().unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("no SCAN.map.txt in"));
    std::fs::write(out.join("scan.map.txt"), "# header\n1\nx\n").unwrap();
    let o = bin().arg("view").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("scan.map.txt line 3: not a vertex index"), "{err}");
}

#[test]
fn eval_writes_an_index_page_with_a_snapshot_and_a_view_per_test_shape() {
    let out = tempfile::tempdir().unwrap();
    let stdout = run(bin()
        .args(["eval", "--quiet", "--no-cache", "--synthetic", "--vertices", "1000", "--shapes", "4"])
        .args(["--train", "2", "--tests", "2", "--trees", "3", "--eval-points", "200", "--out"])
        .arg(out.path()));
    assert!(stdout.contains("index.html"), "{stdout}");
    let index = std::fs::read_to_string(out.path().join("index.html")).unwrap();
    assert!(index.contains("<svg"), "the curves are inlined");
    assert!(index.contains("forest+reg"), "the table is on the page");
    let shots: Vec<&str> = index.match_indices("<img src=\"shapes/").map(|(i, _)| &index[i + 10..]).collect();
    assert_eq!(shots.len(), 2, "one snapshot per test shape");
    for s in shots {
        let file = &s[..s.find('"').unwrap()];
        assert_both_drawn(&out.path().join(file));
        let stem = file.trim_end_matches(".png");
        assert_both_drawn(&out.path().join(format!("{stem}.errors.png")));
        let view = std::fs::read_to_string(out.path().join(format!("{stem}.view.html"))).unwrap();
        assert!(view.contains("error heat map") && view.contains("200 evaluated points"));
    }
}
