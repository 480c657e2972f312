//! `shapeforest eval` on a class whose shapes do not share vertex indexing: ground truth from
//! per-label `.vts` tables and symmetry from `.sym.vts`, built here from the synthetic creature
//! family by shuffling each shape's vertices (no shared data needed).

mod common;

use std::path::Path;

use rand::{seq::SliceRandom, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shapeforest::{
    mesh::{write_mesh, Mesh},
    synth::{creature_family, CreatureParams},
};

use common::bin;

fn lines(v: impl Iterator<Item = usize>) -> String {
    v.map(|x| format!("{x}\n")).collect()
}

/// Writes `n` shuffled creatures as `creatureI.off.gz` with `corres/creatureI.vts` and
/// `.sym.vts` (1-based; `rows` labels), and returns the class folder.
fn shuffled_class(dir: &Path, n: usize, rows: usize) -> std::path::PathBuf {
    let params = CreatureParams { target_vertices: 1500, seed: 7, ..Default::default() };
    let family = creature_family(&params, n).unwrap();
    let class = dir.join("class");
    std::fs::create_dir_all(class.join("corres")).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let nv = family.shapes[0].n_vertices();
    let mut labelled: Vec<usize> = (0..nv).collect();
    labelled.shuffle(&mut rng);
    labelled.truncate(rows);
    for (i, shape) in family.shapes.iter().enumerate() {
        let mut perm: Vec<usize> = (0..nv).collect();
        perm.shuffle(&mut rng);
        let mut vertices = vec![[0.0; 3]; nv];
        for v in 0..nv {
            vertices[perm[v]] = shape.vertices[v];
        }
        let faces = shape.faces.iter().map(|f| f.map(|v| perm[v])).collect();
        let mesh = Mesh::new(vertices, faces).unwrap();
        write_mesh(class.join(format!("creature{i}.off.gz")), &mesh).unwrap();
        let corres = class.join("corres");
        std::fs::write(corres.join(format!("creature{i}.vts")), lines(labelled.iter().map(|&v| perm[v] + 1)))
            .unwrap();
        std::fs::write(
            corres.join(format!("creature{i}.sym.vts")),
            lines(labelled.iter().map(|&v| perm[family.symmetry[v]] + 1)),
        )
        .unwrap();
    }
    class
}

/// `shapeforest eval` of `class` (2 training shapes, 1 test) into `out`; its standard output.
fn eval_class(class: &Path, out: &Path, trees: usize, points: usize) -> String {
    let o = bin()
        .args(["eval", "--quiet", "--no-cache", "--prefix", "creature", "--train", "2", "--tests", "1"])
        .args(["--trees", &trees.to_string(), "--eval-points", &points.to_string(), "--class"])
        .arg(class)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(o.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&o.stderr));
    println!("{stdout}");
    stdout
}

#[test]
fn eval_reads_vts_ground_truth_and_sym_vts_symmetry() {
    let dir = tempfile::tempdir().unwrap();
    let class = shuffled_class(dir.path(), 3, 1200);
    let out = dir.path().join("out");
    let stdout = eval_class(&class, &out, 6, 400);
    assert!(stdout.contains("1200 ground-truth rows (.vts)"), "{stdout}");
    assert!(stdout.contains("symmetry from .sym.vts"), "{stdout}");
    assert!(
        stdout.contains("relays: ") && stdout.contains(" of 1 test shape(s) regularised onto"),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    // Every row names the training shape its test was regularised onto (the reference or a
    // relay), never the test shape itself, and no shape voted with (one vote by default).
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (onto_col, voted_col) = (column("regularised_onto"), column("voted_with"));
    for row in csv.lines().skip(1) {
        let cols: Vec<&str> = row.split(',').collect();
        assert_eq!(cols.len(), header.len(), "{row}");
        let onto = cols[onto_col];
        assert!(onto.starts_with("creature") && onto != cols[0], "{row}");
        assert!(cols[voted_col].is_empty(), "{row}");
    }
    let reg = csv.lines().find(|l| l.contains(",forest+reg,")).unwrap();
    // The numeric columns (n … sym_median); the perturbation columns follow.
    let cols: Vec<f64> = reg.split(',').skip(3).take(9).map(|c| c.parse().unwrap()).collect();
    // n, within_005, within_010, mean, median, sym_within_005, sym_within_010, ...
    assert_eq!(cols[0], 400.0);
    assert!(cols[2] > 0.5, "regularised forest reached only {} within 0.1: {reg}", cols[2]);
    assert!(cols[6] >= cols[2], "flips allowed cannot score lower than strict: {reg}");
    let pairs = std::fs::read_to_string(out.join("peer/pairs.json")).unwrap();
    assert!(pairs.contains("eval_reference_mirror_vertices") && pairs.contains(".off.gz"), "{pairs}");
}

#[test]
fn vts_mistakes_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let class = shuffled_class(dir.path(), 2, 50);
    let run = || {
        let o = bin()
            .args(["eval", "--quiet", "--no-cache", "--prefix", "creature", "--class"])
            .arg(&class)
            .output();
        String::from_utf8_lossy(&o.unwrap().stderr).to_string()
    };
    // A vertex beyond the mesh names the file, the line and the 1-based convention.
    let vts = class.join("corres/creature1.vts");
    let good = std::fs::read_to_string(&vts).unwrap();
    std::fs::write(&vts, format!("{good}999999\n")).unwrap();
    let err = run();
    assert!(err.contains("creature1.vts") && err.contains("line 51") && err.contains("1-based"), "{err}");
    // A 0 in a 1-based table is refused too.
    std::fs::write(&vts, format!("0\n{good}")).unwrap();
    let err = run();
    assert!(err.contains("creature1.vts") && err.contains("line 1"), "{err}");
    // A mesh without a table: the class mixes conventions, the missing one is named.
    std::fs::remove_file(&vts).unwrap();
    let err = run();
    assert!(err.contains("missing for: creature1"), "{err}");
}

/// A class sharing vertex indexing with sparse feature files `creature.pid` and
/// `creature.sym.info` (pairs from the exact mirror map, or deliberately wrong ones).
fn feature_class(dir: &Path, wrong_pairs: bool) -> std::path::PathBuf {
    let params = CreatureParams { target_vertices: 900, seed: 5, ..Default::default() };
    let family = creature_family(&params, 3).unwrap();
    let class = dir.join("features");
    std::fs::create_dir_all(&class).unwrap();
    for (i, shape) in family.shapes.iter().enumerate() {
        write_mesh(class.join(format!("creature{i}.off")), shape).unwrap();
    }
    let t = &family.template;
    // Feature vertices spread over the right side (x > 0), with their mirror images.
    let mut right: Vec<usize> = (0..t.n_vertices()).filter(|&v| t.vertices[v][0] > 0.1).collect();
    right.shuffle(&mut ChaCha8Rng::seed_from_u64(2));
    right.truncate(8);
    let plane: Vec<usize> =
        (0..t.n_vertices()).filter(|&v| family.symmetry[v] == v).step_by(50).take(3).collect();
    let mut pid = String::new();
    let mut info = String::new();
    for (k, &v) in right.iter().enumerate() {
        // Wrong pairs: each feature "mirrors" the next one's mirror image.
        let m = if wrong_pairs { family.symmetry[right[(k + 1) % right.len()]] } else { family.symmetry[v] };
        pid.push_str(&format!("{v} 0 0 0\n{m} 0 0 0\n"));
        info.push_str(&format!("{} {}\n", 2 * k, 2 * k + 1));
    }
    info.push('\n');
    for (k, &v) in plane.iter().enumerate() {
        pid.push_str(&format!("{v} 0 0 0\n"));
        info.push_str(&format!("{}\n", 2 * right.len() + k));
    }
    std::fs::write(class.join("creature.pid"), pid).unwrap();
    std::fs::write(class.join("creature.sym.info"), info).unwrap();
    class
}

#[test]
fn eval_derives_a_symmetry_from_feature_points_and_refuses_a_wrong_one() {
    let dir = tempfile::tempdir().unwrap();
    for wrong in [false, true] {
        let class = feature_class(dir.path(), wrong);
        let out = dir.path().join(format!("out{wrong}"));
        let stdout = eval_class(&class, &out, 3, 200);
        assert!(stdout.contains("symmetry from creature.sym.info (8 pairs, "), "{stdout}");
        assert!(out.join("symmetry.csv").is_file());
        let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
        let reg = csv.lines().find(|l| l.contains(",forest+reg,")).unwrap();
        let sym_col = reg.split(',').nth(8).unwrap();
        if wrong {
            assert!(stdout.contains("not accurate enough"), "{stdout}");
            assert!(sym_col.is_empty(), "a refused symmetry must give strict figures only: {reg}");
        } else {
            assert!(!stdout.contains("not accurate enough"), "{stdout}");
            assert!(sym_col.parse::<f64>().unwrap() > 0.5, "{reg}");
        }
    }
}
