//! Integration tests of the synthetic creature generator through the public API.
//!
//! Bounds asserted (all measured with margin, see the report in the `synth` branch log):
//! - template: closed, consistently oriented, connected 2-manifold, Euler characteristic 2,
//!   no face with area below 1e-6 of the mean, smallest triangle angle above [`MIN_ANGLE_DEG`];
//! - vertex count within 10 % of the target at 1K, 5K and 20K;
//! - default poses: mean relative edge-length change below 5 % and area change below 5 %,
//!   while vertices move by more than 1 % of the bounding-box diagonal on average and more
//!   than 5 % at the extremities.

use std::collections::HashMap;

use shapeforest::mesh::Mesh;
use shapeforest::synth::{creature_family, creature_template, CreatureParams, SynthError};

/// Smallest triangle angle (degrees) every template must exceed.
const MIN_ANGLE_DEG: f64 = 10.0;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn len(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

fn params(target: usize) -> CreatureParams {
    CreatureParams { target_vertices: target, ..Default::default() }
}

/// Smallest interior angle over all triangles, in degrees.
fn min_angle_deg(m: &Mesh) -> f64 {
    let mut worst = 180.0f64;
    for f in &m.faces {
        for e in 0..3 {
            let a = m.vertices[f[e]];
            let u = sub(m.vertices[f[(e + 1) % 3]], a);
            let v = sub(m.vertices[f[(e + 2) % 3]], a);
            let c = (dot(u, v) / (len(u) * len(v))).clamp(-1.0, 1.0);
            worst = worst.min(c.acos().to_degrees());
        }
    }
    worst
}

/// Undirected edges with their two faces; panics with a message if the surface is not closed
/// and consistently oriented.
fn assert_closed_oriented(m: &Mesh) -> Vec<(usize, usize)> {
    let mut directed: HashMap<(usize, usize), usize> = HashMap::new();
    for f in &m.faces {
        for e in 0..3 {
            *directed.entry((f[e], f[(e + 1) % 3])).or_default() += 1;
        }
    }
    let mut edges = Vec::new();
    for (&(a, b), &count) in &directed {
        assert_eq!(count, 1, "directed edge {a}->{b} used {count} times");
        assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}-{b} is not shared by exactly two faces");
        if a < b {
            edges.push((a, b));
        }
    }
    edges.sort_unstable();
    edges
}

fn n_components(n: usize, edges: &[(usize, usize)]) -> usize {
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for &(a, b) in edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        parent[ra] = rb;
    }
    (0..n).filter(|&v| find(&mut parent, v) == v).count()
}

/// Signed volume enclosed (positive for outward-oriented faces).
fn signed_volume(m: &Mesh) -> f64 {
    m.faces
        .iter()
        .map(|f| {
            let (a, b, c) = (m.vertices[f[0]], m.vertices[f[1]], m.vertices[f[2]]);
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum()
}

/// Relative edge-length changes `|ℓ' − ℓ| / ℓ` between two meshes with the same faces.
fn edge_distortion(a: &Mesh, b: &Mesh, edges: &[(usize, usize)]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut max = 0.0f64;
    for &(i, j) in edges {
        let la = len(sub(a.vertices[i], a.vertices[j]));
        let lb = len(sub(b.vertices[i], b.vertices[j]));
        let r = (lb - la).abs() / la;
        sum += r;
        max = max.max(r);
    }
    (sum / edges.len() as f64, max)
}

fn bbox_diagonal(m: &Mesh) -> f64 {
    let (lo, hi) = m.bounding_box();
    len(sub(hi, lo))
}

#[test]
fn template_is_a_closed_connected_sphere_with_good_triangles() {
    let c = creature_template(&params(5000)).expect("template");
    let m = &c.mesh;
    let edges = assert_closed_oriented(m);
    assert_eq!(n_components(m.n_vertices(), &edges), 1, "template is not connected");
    let euler = m.n_vertices() as i64 - edges.len() as i64 + m.n_faces() as i64;
    assert_eq!(euler, 2, "Euler characteristic");
    assert!(signed_volume(m) > 0.0, "faces must be oriented outwards");
    let areas = m.face_areas();
    let mean = areas.iter().sum::<f64>() / areas.len() as f64;
    let smallest = areas.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(smallest > 1e-6 * mean, "degenerate face: area {smallest} vs mean {mean}");
    let angle = min_angle_deg(m);
    assert!(angle > MIN_ANGLE_DEG, "smallest triangle angle {angle:.2}° ≤ {MIN_ANGLE_DEG}°");
    // Every vertex is used.
    let mut used = vec![false; m.n_vertices()];
    m.faces.iter().flatten().for_each(|&v| used[v] = true);
    assert!(used.iter().all(|&u| u), "unreferenced vertex");
}

#[test]
fn vertex_count_follows_the_target() {
    for target in [1000, 5000, 20000] {
        let c = creature_template(&params(target)).expect("template");
        let n = c.mesh.n_vertices() as f64;
        let ratio = n / target as f64;
        println!("target {target}: {n} vertices, min angle {:.1}°", min_angle_deg(&c.mesh));
        assert!((0.9..=1.1).contains(&ratio), "target {target}: got {n} vertices");
        assert_closed_oriented(&c.mesh);
        assert!(min_angle_deg(&c.mesh) > MIN_ANGLE_DEG);
    }
}

#[test]
fn symmetry_is_an_involution_mapping_to_mirror_positions() {
    let c = creature_template(&params(3000)).expect("template");
    let (m, s) = (&c.mesh, &c.symmetry);
    assert_eq!(s.len(), m.n_vertices());
    let mut fixed = 0;
    for i in 0..m.n_vertices() {
        assert_eq!(s[s[i]], i, "symmetry is not an involution at {i}");
        let (p, q) = (m.vertices[i], m.vertices[s[i]]);
        assert_eq!([p[0], p[1], p[2]], [-q[0], q[1], q[2]], "vertex {i} and its image are not mirrored");
        if s[i] == i {
            fixed += 1;
            assert_eq!(p[0], 0.0);
        }
    }
    // The mid-plane crosses torso, neck, head and tail: a profile curve of fixed points, but
    // most vertices are paired.
    assert!(fixed > 20 && fixed < m.n_vertices() / 10, "{fixed} fixed points");
    // Left and right legs are swapped by the symmetry.
    let names = shapeforest::synth::PART_NAMES;
    for i in 0..m.n_vertices() {
        let (a, b) = (names[c.vertex_part[i]], names[c.vertex_part[s[i]]]);
        assert_eq!(a.replace("left", "right"), b.replace("left", "right"), "vertex {i}: {a} vs {b}");
    }
}

#[test]
fn poses_are_near_isometric_but_move_the_vertices() {
    let fam = creature_family(&params(3000), 6).expect("family");
    let edges = assert_closed_oriented(&fam.template);
    let diag = bbox_diagonal(&fam.template);
    let mut worst_mean = 0.0f64;
    for (k, shape) in fam.shapes.iter().enumerate().skip(1) {
        assert_eq!(shape.faces, fam.template.faces);
        let (mean, max) = edge_distortion(&fam.template, shape, &edges);
        let moves: Vec<f64> =
            fam.template.vertices.iter().zip(&shape.vertices).map(|(&p, &q)| len(sub(p, q))).collect();
        let disp = moves.iter().sum::<f64>() / moves.len() as f64;
        let max_disp = moves.iter().cloned().fold(0.0, f64::max);
        let area_change = (shape.surface_area() / fam.template.surface_area() - 1.0).abs();
        println!(
            "pose {k}: edge change mean {:.2}% max {:.1}%, displacement mean {:.1}% max {:.1}% of diag, area change {:.2}%",
            100.0 * mean,
            100.0 * max,
            100.0 * disp / diag,
            100.0 * max_disp / diag,
            100.0 * area_change
        );
        assert!(mean < 0.05, "pose {k}: mean edge-length change {mean}");
        assert!(area_change < 0.05, "pose {k}: area change {area_change}");
        assert!(disp > 0.01 * diag, "pose {k}: mean displacement {disp} too small");
        assert!(max_disp > 0.05 * diag, "pose {k}: largest displacement {max_disp} too small");
        worst_mean = worst_mean.max(mean);
    }
    assert!(worst_mean > 0.0);
}

#[test]
fn non_isometric_variant_changes_lengths_and_area() {
    let p = CreatureParams { target_vertices: 2000, pose_amplitude: 0.0, non_isometric: 0.3, seed: 3 };
    let fam = creature_family(&p, 4).expect("family");
    let edges = assert_closed_oriented(&fam.template);
    for shape in &fam.shapes[1..] {
        let (mean, _) = edge_distortion(&fam.template, shape, &edges);
        let area_change = (shape.surface_area() / fam.template.surface_area() - 1.0).abs();
        println!(
            "non-isometric: edge change mean {:.1}%, area change {:.1}%",
            100.0 * mean,
            100.0 * area_change
        );
        assert!(mean > 0.05, "non-isometric edge change only {mean}");
        assert!(area_change > 0.02, "non-isometric area change only {area_change}");
    }
}

#[test]
fn same_seed_same_shapes_different_seed_different_poses() {
    let p = params(1500);
    let a = creature_family(&p, 3).expect("family");
    let b = creature_family(&p, 3).expect("family");
    for (x, y) in a.shapes.iter().zip(&b.shapes) {
        assert_eq!(x.content_hash(), y.content_hash());
    }
    assert_eq!(a.symmetry, b.symmetry);
    let c = creature_family(&CreatureParams { seed: 1, ..p }, 3).expect("family");
    assert_eq!(a.template, c.template, "the template does not depend on the seed");
    assert_ne!(a.shapes[1], c.shapes[1]);
    assert_ne!(a.shapes[1], a.shapes[2]);
    // Shape k does not depend on the family size.
    let d = creature_family(&p, 2).expect("family");
    assert_eq!(d.shapes[1], a.shapes[1]);
}

#[test]
fn bad_parameters_are_rejected_with_their_name() {
    let cases = [
        (CreatureParams { target_vertices: 10, ..Default::default() }, "target_vertices"),
        (CreatureParams { pose_amplitude: f64::NAN, ..Default::default() }, "pose_amplitude"),
        (CreatureParams { non_isometric: 2.0, ..Default::default() }, "non_isometric"),
    ];
    for (p, name) in cases {
        let err = creature_template(&p).unwrap_err();
        assert!(matches!(err, SynthError::InvalidParameter { .. }));
        assert!(err.to_string().contains(name), "{err}");
    }
    assert!(creature_family(&params(1000), 0).unwrap_err().to_string().contains("n_shapes"));
}

#[test]
#[ignore = "timing report; run with --ignored --nocapture"]
fn report_sizes_and_times() {
    for target in [1000, 5000, 20000, 50000] {
        let t = std::time::Instant::now();
        let c = creature_template(&params(target)).expect("template");
        let dt = t.elapsed().as_secs_f64();
        let edges = assert_closed_oriented(&c.mesh);
        let t2 = std::time::Instant::now();
        let poses: Vec<Mesh> = (1..=5).map(|k| c.random_shape(0, k, 1.0, 0.0).expect("pose")).collect();
        let dt2 = t2.elapsed().as_secs_f64() / 5.0;
        let (mut mean, mut max) = (0.0, 0.0f64);
        let mut all: Vec<f64> = Vec::new();
        for pose in &poses {
            let (m, x) = edge_distortion(&c.mesh, pose, &edges);
            mean += m / 5.0;
            max = max.max(x);
            all.extend(edges.iter().map(|&(i, j)| {
                let la = len(sub(c.mesh.vertices[i], c.mesh.vertices[j]));
                (len(sub(pose.vertices[i], pose.vertices[j])) - la).abs() / la
            }));
        }
        all.sort_by(f64::total_cmp);
        let p99 = all[all.len() * 99 / 100];
        println!(
            "target {target}: {} vertices, {} faces, template {dt:.3} s, pose {dt2:.4} s, min angle {:.1}°, \
             5 poses: edge change mean {:.2}% p99 {:.1}% max {:.1}%",
            c.mesh.n_vertices(),
            c.mesh.n_faces(),
            min_angle_deg(&c.mesh),
            100.0 * mean,
            100.0 * p99,
            100.0 * max
        );
    }
}

/// The point of near-isometric poses: the Laplace spectrum (what WKS is built from) barely
/// moves under a pose, but moves clearly under the non-isometric variant.
#[test]
fn low_spectrum_is_stable_under_poses_not_under_rescaling() {
    use shapeforest::spectral::dense_spectrum;
    let p = params(1000);
    let creature = creature_template(&p).expect("template");
    let pose = creature.random_shape(5, 1, 1.0, 0.0).expect("pose");
    let fat = creature.random_shape(5, 1, 0.0, 0.3).expect("non-isometric");
    let k = 9;
    let s0 = dense_spectrum(&creature.mesh, k).expect("spectrum");
    let s1 = dense_spectrum(&pose, k).expect("spectrum");
    let s2 = dense_spectrum(&fat, k).expect("spectrum");
    assert!(s0.eigenvalues[0].abs() < 1e-8 && s0.eigenvalues[1] > 1e-3, "one connected component");
    let rel = |a: &[f64], b: &[f64]| (1..k).map(|i| (a[i] - b[i]).abs() / a[i]).sum::<f64>() / (k - 1) as f64;
    let d_pose = rel(&s0.eigenvalues, &s1.eigenvalues);
    let d_fat = rel(&s0.eigenvalues, &s2.eigenvalues);
    println!(
        "mean relative change of λ1..λ8: pose {:.2}%, non-isometric {:.2}%",
        100.0 * d_pose,
        100.0 * d_fat
    );
    assert!(d_pose < 0.05, "pose changed the spectrum by {d_pose}");
    assert!(d_fat > 2.0 * d_pose, "non-isometric change {d_fat} not larger than pose change {d_pose}");
}
