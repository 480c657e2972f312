//! The refinements after the regulariser on the synthetic family (same triangulation, other
//! poses: the true map is the identity): ZoomOut's schedule, the extrinsic refinement and its
//! settling round.

use std::sync::Arc;

use rand::{Rng, SeedableRng};
use shapeforest::{
    eval::{geodesic_errors, ErrorSummary},
    geodesic::HeatParams,
    regularizer::{
        local_rigid, refine_extrinsic, refine_zoomout, sample_cells, select_by_posterior, settle_map,
        ExtrinsicParams, LocalRigidParams, MapSelection, PreparedShape, ZoomOutParams, SETTLE_REACH,
    },
    spectral::{compute_spectrum, SpectrumParams},
    synth::{creature_family, CreatureParams},
};

struct Pair {
    test: PreparedShape,
    reference: PreparedShape,
    n: usize,
}

fn pair() -> Pair {
    let fam = creature_family(&CreatureParams { target_vertices: 2500, seed: 11, ..Default::default() }, 2)
        .unwrap();
    let prepare = |i: usize| {
        let mesh = Arc::new(fam.shapes[i].clone());
        let spectrum = Arc::new(compute_spectrum(&mesh, &SpectrumParams::new(80)).unwrap());
        PreparedShape::new(mesh, spectrum, HeatParams::default()).unwrap()
    };
    let (test, reference) = (prepare(0), prepare(1));
    let n = test.mesh.n_vertices();
    Pair { test, reference, n }
}

/// Errors (÷ √area) of `map` against the identity at every third vertex.
fn summary(p: &Pair, map: &[usize]) -> ErrorSummary {
    let evaluated: Vec<usize> = (0..p.n).step_by(3).collect();
    let fields = p.reference.heat.distances_from_many(&evaluated).unwrap();
    let (strict, _) =
        geodesic_errors(map, &evaluated, fields.as_ref(), None, p.reference.mesh.surface_area()).unwrap();
    ErrorSummary::of(&strict)
}

/// The identity with every vertex moved to a random mesh neighbour.
fn off_by_a_ring(p: &Pair, seed: u64) -> Vec<usize> {
    let mut neighbours = vec![Vec::new(); p.n];
    for f in &p.test.mesh.faces {
        for (a, b) in [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])] {
            neighbours[a].push(b);
            neighbours[b].push(a);
        }
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..p.n).map(|v| neighbours[v][rng.random_range(0..neighbours[v].len())]).collect()
}

#[test]
fn zoomout_started_half_way_keeps_a_true_map_better_than_from_twenty() {
    let p = pair();
    let identity: Vec<usize> = (0..p.n).collect();
    let run = |k_start: usize| {
        let z = ZoomOutParams { k_start, k_final: 80, extrinsic: None, ..Default::default() };
        summary(&p, &refine_zoomout(&p.test, &p.reference, &identity, &z).unwrap().unwrap())
    };
    let (from_20, half_way) = (run(20), run(ZoomOutParams::default().k_start));
    eprintln!("from 20: {from_20:?}\nhalf way: {half_way:?}");
    assert!(half_way.mean <= from_20.mean, "half way {half_way:?} vs from 20 {from_20:?}");
    assert!(half_way.mean < 0.02, "{half_way:?}");
}

#[test]
fn the_extrinsic_refinement_sharpens_a_map_off_by_a_ring() {
    let p = pair();
    let start = off_by_a_ring(&p, 5);
    let before = summary(&p, &start);
    let zoomed = refine_zoomout(
        &p.test,
        &p.reference,
        &start,
        &ZoomOutParams { extrinsic: None, ..Default::default() },
    )
    .unwrap()
    .unwrap();
    let zoomout_only = summary(&p, &zoomed);
    let refined = refine_extrinsic(&p.test, &p.reference, &zoomed, &ExtrinsicParams::default()).unwrap();
    let after = summary(&p, &refined);
    eprintln!("start: {before:?}\nZoomOut: {zoomout_only:?}\n+ extrinsic: {after:?}");
    assert!(after.mean < before.mean, "{after:?} vs start {before:?}");
    assert!(after.mean <= zoomout_only.mean, "{after:?} vs ZoomOut alone {zoomout_only:?}");
    // Without the coordinates (weight 0) the rounds are ZoomOut's own fixed point again.
    let spectral = ExtrinsicParams { weight: 0.0, ..Default::default() };
    let plain = summary(&p, &refine_extrinsic(&p.test, &p.reference, &zoomed, &spectral).unwrap());
    assert!(after.mean <= plain.mean, "{after:?} vs no coordinates {plain:?}");
}

#[test]
fn settling_sharpens_a_map_and_moves_no_image_beyond_its_reach() {
    let p = pair();
    let start = off_by_a_ring(&p, 7);
    let e = ExtrinsicParams::default();
    let settled = settle_map(&p.test, &p.reference, &start, &e, SETTLE_REACH).unwrap();
    let (before, after) = (summary(&p, &start), summary(&p, &settled));
    eprintln!("off by a ring: {before:?}\nsettled: {after:?}");
    assert!(after.mean < before.mean, "{after:?} vs start {before:?}");
    let pos = &p.reference.mesh.vertices;
    let scale = p.reference.mesh.surface_area().sqrt();
    let moved =
        |a: usize, b: usize| (0..3).map(|k| (pos[a][k] - pos[b][k]).powi(2)).sum::<f64>().sqrt() / scale;
    assert!(start.iter().zip(&settled).all(|(&a, &b)| moved(a, b) <= SETTLE_REACH + 1e-12));
    // No reach: the map as it was; an unbounded one: one plain round of the extrinsic step.
    assert_eq!(settle_map(&p.test, &p.reference, &start, &e, 0.0).unwrap(), start);
    let round = refine_extrinsic(&p.test, &p.reference, &start, &ExtrinsicParams { rounds: 1, ..e }).unwrap();
    assert_eq!(settle_map(&p.test, &p.reference, &start, &e, 1e9).unwrap(), round);
    // A reach of half an edge: the images a ring away stay where they were.
    let edge =
        p.test.mesh.faces.iter().map(|f| moved(f[0], f[1])).sum::<f64>() / p.test.mesh.faces.len() as f64;
    let short = settle_map(&p.test, &p.reference, &start, &e, 0.5 * edge).unwrap();
    assert!(start.iter().zip(&short).all(|(&a, &b)| moved(a, b) <= 0.5 * edge + 1e-12));
    assert!(start.iter().zip(&round).any(|(&a, &b)| moved(a, b) > 0.5 * edge), "the round moved nothing far");
    assert_ne!(short, round);
    let err = settle_map(&p.test, &p.reference, &start, &e, f64::NAN).unwrap_err().to_string();
    assert!(err.contains("settle"), "{err}");
}

#[test]
fn the_local_rigid_fit_sharpens_a_jittered_map_and_leaves_a_right_one() {
    let p = pair();
    let start = off_by_a_ring(&p, 9);
    let params = LocalRigidParams::default();
    let fitted = local_rigid(&p.test.mesh, &p.reference.mesh, &start, &params).unwrap();
    let (before, after) = (summary(&p, &start), summary(&p, &fitted));
    eprintln!("off by a ring: {before:?}\nlocal rigid fit: {after:?}");
    assert!(after.mean < 0.5 * before.mean, "{after:?} vs start {before:?}");
    // No image moves farther than the reach (in mean edge lengths of the reference).
    let scale = 1.0 / p.reference.mesh.surface_area().sqrt();
    let pos = &p.reference.mesh.vertices;
    let dist =
        |a: usize, b: usize| (0..3).map(|k| (pos[a][k] - pos[b][k]).powi(2)).sum::<f64>().sqrt() * scale;
    let edge = p
        .reference
        .mesh
        .faces
        .iter()
        .map(|f| dist(f[0], f[1]) + dist(f[1], f[2]) + dist(f[2], f[0]))
        .sum::<f64>()
        / (3 * p.reference.mesh.faces.len()) as f64;
    assert!(start.iter().zip(&fitted).all(|(&a, &b)| dist(a, b) <= params.reach * edge + 1e-12));
    // The true map (the shapes share their vertices) is left nearly as it is.
    let identity: Vec<usize> = (0..p.n).collect();
    let kept = local_rigid(&p.test.mesh, &p.reference.mesh, &identity, &params).unwrap();
    let same = kept.iter().enumerate().filter(|&(v, &r)| v == r).count();
    assert!(same * 100 >= p.n * 98, "{same} of {} images kept", p.n);
    let err = local_rigid(&p.test.mesh, &p.reference.mesh, &start, &LocalRigidParams { fit: -1.0, ..params })
        .unwrap_err()
        .to_string();
    assert!(err.contains("fit"), "{err}");
}

#[test]
fn extrinsic_settings_are_checked() {
    let p = pair();
    let identity: Vec<usize> = (0..p.n).collect();
    for (bad, what) in [
        (ExtrinsicParams { deformation_k: 0, ..Default::default() }, "deformation_k"),
        (ExtrinsicParams { weight: f64::NAN, ..Default::default() }, "weight"),
        (ExtrinsicParams { samples: 0, ..Default::default() }, "samples"),
    ] {
        let err = refine_extrinsic(&p.test, &p.reference, &identity, &bad).unwrap_err().to_string();
        assert!(err.contains(what), "{err}");
    }
    let short = refine_extrinsic(&p.test, &p.reference, &identity[1..], &ExtrinsicParams::default());
    assert!(short.is_err());
}

#[test]
fn the_map_the_posterior_supports_is_chosen_region_by_region() {
    let p = pair();
    let identity: Vec<usize> = (0..p.n).collect();
    // A map whose upper half (by height on the test shape) is sent to the lowest vertex: a
    // patch in the wrong place; the posterior's candidates are each vertex and its neighbours.
    let (lo, hi) =
        p.test.mesh.vertices.iter().fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v[1]), b.max(v[1])));
    let lowest =
        (0..p.n).min_by(|&a, &b| p.test.mesh.vertices[a][1].total_cmp(&p.test.mesh.vertices[b][1])).unwrap();
    let upper = |v: usize| p.test.mesh.vertices[v][1] > 0.5 * (lo + hi);
    let patched: Vec<usize> = (0..p.n).map(|v| if upper(v) { lowest } else { v }).collect();
    let rounds = shapeforest::regularizer::unflip_rounds(p.n);
    // Either order: the identity wins where the maps differ, and where they agree nothing changes.
    for maps in [[&patched[..], &identity[..]], [&identity[..], &patched[..]]] {
        for margin in [1.0, 1.5] {
            let chosen = select_by_posterior(
                &p.test.mesh,
                &p.reference.mesh,
                identity.as_slice(),
                &maps,
                0.02,
                margin,
                rounds,
            );
            let right = chosen.iter().enumerate().filter(|&(v, &r)| v == r).count();
            assert!(
                right * 100 >= p.n * 98,
                "{right} of {} vertices chose the supported map ({margin})",
                p.n
            );
        }
    }
}

#[test]
fn a_map_only_slightly_better_supported_does_not_displace_the_first() {
    let p = pair();
    let identity: Vec<usize> = (0..p.n).collect();
    // One ring off everywhere: at a kernel of 0.1 √area (several edges) its images score a few
    // per cent below the identity's, a near-tie at the posterior's resolution.
    let ring = off_by_a_ring(&p, 5);
    let rounds = shapeforest::regularizer::unflip_rounds(p.n);
    let maps = [&ring[..], &identity[..]];
    let choose = |margin: f64| {
        select_by_posterior(&p.test.mesh, &p.reference.mesh, identity.as_slice(), &maps, 0.1, margin, rounds)
    };
    let count = |chosen: &[usize], of: &[usize]| chosen.iter().zip(of).filter(|(a, b)| a == b).count();
    // The plain maximum takes the identity, which scores higher everywhere.
    assert_eq!(count(&choose(1.0), &identity), p.n);
    // With the margin the first map is kept: no region is clearly better supported elsewhere.
    assert_eq!(count(&choose(1.5), &ring), p.n);
}

#[test]
fn a_shapes_sample_cells_are_made_once_per_count_and_are_the_plain_ones() {
    let p = pair();
    let first = p.test.sample_cells(500).unwrap();
    assert!(Arc::ptr_eq(&first, &p.test.sample_cells(500).unwrap()), "made once, then reused");
    assert_eq!(*first, sample_cells(&p.test.mesh, 500).unwrap());
    assert_eq!(p.test.sample_cells(300).unwrap().samples.len(), 300);
    assert!(Arc::ptr_eq(&first, &p.test.sample_cells(500).unwrap()), "another count does not evict");
}

#[test]
fn map_selection_settings_are_checked_and_old_files_get_the_defaults() {
    assert!(MapSelection::default().check().is_ok());
    for (bad, what) in [
        (MapSelection { margin: 0.5, ..Default::default() }, "margin"),
        (MapSelection { margin: f64::INFINITY, ..Default::default() }, "margin"),
        (MapSelection { sigma: 0.0, ..Default::default() }, "sigma"),
        (MapSelection { coarse: (30, 20), ..Default::default() }, "coarse"),
        (MapSelection { reach: -1.0, ..Default::default() }, "reach"),
    ] {
        let err = bad.check().unwrap_err();
        assert!(err.contains(what), "{err}");
    }
    // A setting written before the third map and the margin existed reads with their defaults.
    let old: MapSelection = serde_json::from_str(r#"{"coarse": [20, 100], "sigma": 0.03}"#).unwrap();
    assert_eq!(old, MapSelection { sigma: 0.03, ..Default::default() });
}

#[test]
fn the_command_line_refuses_a_reach_or_radius_that_is_not_a_distance() {
    for (command, flag, reach) in [
        ("eval", "--settle-reach", "-1"),
        ("match", "--settle-reach", "nan"),
        ("eval", "--settle-reach", "inf"),
        ("eval", "--rigid-radius", "-0.05"),
        ("match", "--rigid-radius", "nan"),
    ] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_shapeforest"))
            .args([command, &format!("{flag}={reach}")])
            .output()
            .unwrap();
        assert!(!o.status.success(), "{command} {flag} {reach} was accepted");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(flag) && err.contains("finite number ≥ 0"), "{err}");
    }
}
