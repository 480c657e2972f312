//! Dense symmetry maps derived from sparse symmetric feature points, checked against the exact
//! mirror map of the synthetic creature.

mod common;

use std::sync::Arc;

use shapeforest::{
    eval::symmetry::{SymmetricFeatures, SymmetryParams, SymmetrySolver},
    geodesic::{farthest_point_sampling_euclidean, HeatMethodSolver, HeatParams},
    spectral::{compute_spectrum, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

#[test]
fn derived_symmetry_of_the_creature_matches_its_exact_mirror() {
    let params = CreatureParams { target_vertices: 2500, seed: 3, ..Default::default() };
    // A posed shape (not the template): its mirror map is only approximately an isometry.
    let family = creature_family(&params, 2).unwrap();
    let mesh = &family.shapes[1];
    let exact = &family.symmetry;
    let n = mesh.n_vertices();
    // A handful of sparse features: 6 mirrored pairs spread over the body, 2 plane points.
    let spread = farthest_point_sampling_euclidean(mesh, 40, None).unwrap();
    let mut features = SymmetricFeatures::default();
    for &v in &spread {
        if features.pairs.len() < 6 && exact[v] != v && mesh.vertices[v][0] > 0.05 {
            features.pairs.push((v, exact[v]));
        }
    }
    features.plane = (0..n).filter(|&v| exact[v] == v).step_by(97).take(2).collect();
    assert_eq!(features.pairs.len(), 6);

    let spectrum = Arc::new(compute_spectrum(mesh, &SpectrumParams::new(80)).unwrap());
    let solver = SymmetrySolver::new(mesh, spectrum, SymmetryParams::default()).unwrap();
    let derived = solver.derive(&features).unwrap();
    assert_eq!(derived.map.len(), n);

    // Geodesic error of the derived mirror against the exact one at 300 spread vertices.
    let probe = farthest_point_sampling_euclidean(mesh, 300, Some(0)).unwrap();
    let heat = HeatMethodSolver::new(mesh, HeatParams::default()).unwrap();
    let targets: Vec<usize> = probe.iter().map(|&v| exact[v]).collect();
    let fields = heat.distances_from_many(&targets).unwrap();
    let norm = 1.0 / mesh.surface_area().sqrt();
    let errors: Vec<f64> =
        probe.iter().enumerate().map(|(j, &v)| fields[(derived.map[v], j)] * norm).collect();
    let within = errors.iter().filter(|&&e| e <= 0.05).count() as f64 / errors.len() as f64;
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    println!("derived symmetry: {:.1} % within 0.05, mean {mean:.4}", 100.0 * within);
    assert!(within >= 0.9, "only {:.1} % of vertices within 0.05 of the exact mirror", 100.0 * within);

    // Cross-validation at the feature points reports the accuracy honestly.
    let v = solver.validate(&features, 3, &derived).unwrap();
    println!(
        "held out: {:.1} % within 0.05, mean {:.4}, max {:.4}; involution {:.1} %",
        100.0 * v.within_005,
        v.mean,
        v.max,
        100.0 * v.involution_within_005
    );
    assert_eq!(v.held_out.len(), 2 * features.pairs.len() + features.plane.len());
    assert!(v.within_005 >= 0.8);
    assert!(v.involution_within_005 >= 0.9);
}

/// The shared data folder, when its TOSCA set is there.
fn data_dir() -> Option<std::path::PathBuf> {
    common::shared_data("tosca").map(|_| common::data_root())
}

fn read_one_based(path: &std::path::Path) -> Vec<usize> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(|t| t.parse::<usize>().unwrap() - 1)
        .collect()
}

/// TOSCA wolf0 is the same mesh in the hi-res set and in the remeshed set, whose `.sym.vts`
/// gives its mirror map at 5000 points: a dense, independent check of the symmetry derived
/// from the 8 sparse feature pairs of `wolf.sym.info`.
#[test]
fn derived_symmetry_of_tosca_wolf_agrees_with_its_mirrored_ground_truth() {
    let Some(data) = data_dir() else { return };
    let Some(corres) = common::shared_data("tosca-r5k/TOSCA_Isometric/vtx_5k/corres/wolf0.sym.vts")
        .and_then(|p| p.parent().map(|d| d.to_path_buf()))
    else {
        return;
    };
    let mesh = shapeforest::mesh::read_mesh(data.join("tosca/wolf0.off")).unwrap();
    let pid: Vec<usize> = std::fs::read_to_string(data.join("tosca/wolf.pid"))
        .unwrap()
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(|t| t.parse().unwrap()))
        .collect();
    let mut features = SymmetricFeatures::default();
    for line in std::fs::read_to_string(data.join("tosca/wolf.sym.info")).unwrap().lines() {
        let ids: Vec<usize> = line.split_whitespace().map(|t| t.parse().unwrap()).collect();
        match ids.as_slice() {
            [a, b] => features.pairs.push((pid[*a], pid[*b])),
            [a] => features.plane.push(pid[*a]),
            _ => {}
        }
    }
    let spectrum = Arc::new(compute_spectrum(&mesh, &SpectrumParams::new(100)).unwrap());
    let solver = SymmetrySolver::new(&mesh, spectrum, SymmetryParams::default()).unwrap();
    let derived = solver.derive(&features).unwrap();

    let vts = read_one_based(&corres.join("wolf0.vts"));
    let sym = read_one_based(&corres.join("wolf0.sym.vts"));
    // Every 10th row: geodesic distance from the derived mirror to the listed one.
    let rows: Vec<usize> = (0..vts.len()).step_by(10).collect();
    let heat = HeatMethodSolver::new(&mesh, HeatParams::default()).unwrap();
    let fields = heat.distances_from_many(&rows.iter().map(|&k| sym[k]).collect::<Vec<_>>()).unwrap();
    let norm = 1.0 / mesh.surface_area().sqrt();
    let errors: Vec<f64> =
        rows.iter().enumerate().map(|(j, &k)| fields[(derived.map[vts[k]], j)] * norm).collect();
    let within = errors.iter().filter(|&&e| e <= 0.05).count() as f64 / errors.len() as f64;
    println!(
        "wolf0: derived symmetry within 0.05 of the .sym.vts mirror at {:.1} % of {} rows, mean {:.4}",
        100.0 * within,
        rows.len(),
        errors.iter().sum::<f64>() / errors.len() as f64
    );
    assert!(within >= 0.9, "only {:.1} % within 0.05", 100.0 * within);
}

#[test]
fn bad_symmetry_inputs_are_refused_with_a_reason() {
    let mesh = shapeforest::synth::icosphere(2, 1.0);
    let spectrum = Arc::new(compute_spectrum(&mesh, &SpectrumParams::new(30)).unwrap());
    let small = SymmetryParams { k_final: 30, zoomout_samples: 100, ..Default::default() };
    let solver = SymmetrySolver::new(&mesh, spectrum.clone(), small.clone()).unwrap();
    let err = |f: SymmetricFeatures| solver.fit(&f).unwrap_err().to_string();
    assert!(err(SymmetricFeatures::default()).contains("at least one mirrored feature pair"));
    let far = SymmetricFeatures { pairs: vec![(0, 100_000)], plane: vec![] };
    assert!(err(far).contains("100000"));
    // A spectrum of another mesh, and too few eigenpairs for the initial fit.
    let other = shapeforest::synth::icosphere(1, 1.0);
    let e = SymmetrySolver::new(&other, spectrum.clone(), small.clone()).err().unwrap().to_string();
    assert!(e.contains("vertices"), "{e}");
    let tiny = Arc::new(compute_spectrum(&mesh, &SpectrumParams::new(10)).unwrap());
    let e = SymmetrySolver::new(&mesh, tiny, small).err().unwrap().to_string();
    assert!(e.contains("eigenpairs"), "{e}");
}
