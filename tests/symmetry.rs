//! Dense symmetry maps derived from sparse symmetric feature points, checked against the exact
//! mirror map of the synthetic creature.

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
