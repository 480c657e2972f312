//! Primitive meshes with known analytic properties, used by tests and benchmarks.

use std::collections::HashMap;

use crate::mesh::Mesh;

/// A geodesic icosphere of the given radius: the icosahedron subdivided `subdivisions` times
/// (each step splits every triangle in four) and projected onto the sphere.
/// It has `10·4^s + 2` vertices and is exactly symmetric, so its Laplace spectrum shows the
/// sphere's multiplicities `2l+1` sharply.
///
/// ```
/// let s = shapeforest::synth::icosphere(2, 1.0);
/// assert_eq!(s.n_vertices(), 162);
/// assert!((s.surface_area() - 4.0 * std::f64::consts::PI).abs() < 0.3);
/// ```
pub fn icosphere(subdivisions: u32, radius: f64) -> Mesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut faces: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let project = |p: [f64; 3]| {
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        [p[0] / n, p[1] / n, p[2] / n]
    };
    for v in vertices.iter_mut() {
        *v = project(*v);
    }
    for _ in 0..subdivisions {
        let mut midpoint: HashMap<(usize, usize), usize> = HashMap::new();
        let mut next = Vec::with_capacity(faces.len() * 4);
        let mut mid = |a: usize, b: usize, vertices: &mut Vec<[f64; 3]>| {
            let key = (a.min(b), a.max(b));
            *midpoint.entry(key).or_insert_with(|| {
                let (p, q) = (vertices[a], vertices[b]);
                vertices.push(project([(p[0] + q[0]) / 2.0, (p[1] + q[1]) / 2.0, (p[2] + q[2]) / 2.0]));
                vertices.len() - 1
            })
        };
        for &[a, b, c] in &faces {
            let ab = mid(a, b, &mut vertices);
            let bc = mid(b, c, &mut vertices);
            let ca = mid(c, a, &mut vertices);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        faces = next;
    }
    for v in vertices.iter_mut() {
        *v = [v[0] * radius, v[1] * radius, v[2] * radius];
    }
    Mesh { vertices, faces, face_multiplicity: Vec::new() }
}

/// A flat rectangular grid `[0, width] × [0, height]` in the z = 0 plane with `nx × ny`
/// vertices, each cell split into two triangles along alternating diagonals (so the
/// triangulation has no preferred direction). It has a boundary.
///
/// ```
/// let p = shapeforest::synth::grid_plane(11, 6, 2.0, 1.0);
/// assert_eq!(p.n_vertices(), 66);
/// assert!((p.surface_area() - 2.0).abs() < 1e-12);
/// ```
pub fn grid_plane(nx: usize, ny: usize, width: f64, height: f64) -> Mesh {
    assert!(nx >= 2 && ny >= 2, "grid_plane needs at least 2 × 2 vertices");
    let mut vertices = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            vertices.push([width * i as f64 / (nx - 1) as f64, height * j as f64 / (ny - 1) as f64, 0.0]);
        }
    }
    let mut faces = Vec::with_capacity(2 * (nx - 1) * (ny - 1));
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            let a = j * nx + i;
            let (b, c, d) = (a + 1, a + nx, a + nx + 1);
            if (i + j) % 2 == 0 {
                faces.push([a, b, d]);
                faces.push([a, d, c]);
            } else {
                faces.push([a, b, c]);
                faces.push([b, d, c]);
            }
        }
    }
    Mesh { vertices, faces, face_multiplicity: Vec::new() }
}

/// A torus with major radius `major`, minor radius `minor`, and `nu × nv` vertices
/// (around the axis × around the tube). Closed, genus one.
///
/// ```
/// let t = shapeforest::synth::torus(64, 32, 2.0, 0.5);
/// let exact = 4.0 * std::f64::consts::PI.powi(2) * 2.0 * 0.5;
/// assert!((t.surface_area() - exact).abs() / exact < 0.01);
/// ```
pub fn torus(nu: usize, nv: usize, major: f64, minor: f64) -> Mesh {
    assert!(nu >= 3 && nv >= 3, "torus needs at least 3 × 3 vertices");
    let tau = std::f64::consts::TAU;
    let mut vertices = Vec::with_capacity(nu * nv);
    for i in 0..nu {
        let u = tau * i as f64 / nu as f64;
        for j in 0..nv {
            let v = tau * j as f64 / nv as f64;
            let r = major + minor * v.cos();
            vertices.push([r * u.cos(), r * u.sin(), minor * v.sin()]);
        }
    }
    let id = |i: usize, j: usize| (i % nu) * nv + (j % nv);
    let mut faces = Vec::with_capacity(2 * nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Mesh { vertices, faces, face_multiplicity: Vec::new() }
}

/// The same surface with its vertices in another (seeded, random) order, as a shape
/// triangulated on its own has no index in common with another: returns the shuffled mesh and
/// `new_index[old vertex]`. Faces are remapped, so geometry and connectivity are unchanged.
///
/// ```
/// use shapeforest::synth::{icosphere, shuffle_vertices};
/// let m = icosphere(1, 1.0);
/// let (s, new_index) = shuffle_vertices(&m, 7).unwrap();
/// assert_eq!(s.vertices[new_index[5]], m.vertices[5]);
/// assert!((s.surface_area() - m.surface_area()).abs() < 1e-12);
/// ```
pub fn shuffle_vertices(mesh: &Mesh, seed: u64) -> Result<(Mesh, Vec<usize>), crate::mesh::MeshError> {
    use rand::{seq::SliceRandom, SeedableRng};
    let n = mesh.n_vertices();
    let mut new_index: Vec<usize> = (0..n).collect();
    new_index.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    let mut vertices = vec![[0.0; 3]; n];
    for (old, &new) in new_index.iter().enumerate() {
        vertices[new] = mesh.vertices[old];
    }
    let faces = mesh.faces.iter().map(|f| [new_index[f[0]], new_index[f[1]], new_index[f[2]]]).collect();
    Ok((Mesh::new(vertices, faces)?, new_index))
}
