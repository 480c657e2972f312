//! Seeded perturbations that turn a clean, closed mesh into what real scans look like: holes,
//! a single-view partial scan, a cropped part (missing limbs), vertex noise.
//!
//! Every perturbation keeps the ground truth: the result carries `kept[new] = old`, the vertex
//! of the input each output vertex is, so correspondences defined on the input (vertex indices
//! or `.vts` rows) can be read on the perturbed mesh, and points that the perturbation removed
//! are known. Faces are removed, never re-triangulated; vertices that no face uses any more are
//! dropped, so the output has no isolated vertex.
//!
//! Conventions: radii are fractions of `√area` of the input mesh (the unit every error of the
//! crate uses), noise is a fraction of the mean edge length; every random choice comes from a
//! `ChaCha8` generator seeded with the caller's seed and the perturbation's position in the
//! list, so a perturbation list with a seed is a reproducible experiment.

use std::fmt;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{cross, dot, sub, triangle_area, Mesh, MeshError};

/// One perturbation of a test shape.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Perturbation {
    /// `count` holes: the faces whose centroid lies within `radius · √area` (Euclidean) of one of
    /// `count` centres drawn uniformly on the surface.
    Holes {
        /// Number of holes.
        count: usize,
        /// Radius as a fraction of `√area`.
        radius: f64,
    },
    /// A single-view scan: the faces seen from a random direction (orthographic), i.e. facing
    /// it (normal · direction above `min_cos`) and not hidden behind other faces (depth
    /// buffer), as a range scanner sees the surface. Grazing faces are lost, as real scanners
    /// lose them, so the result is usually fragmented into several components.
    PartialView {
        /// Faces whose normal makes a larger angle with the view than `acos(min_cos)` are not
        /// captured (default 0.15, ~81°).
        min_cos: f64,
    },
    /// A cropped part: only the faces whose centroid lies within `radius · √area` of a random
    /// point of the surface are kept (a missing limb, a partial capture).
    Crop {
        /// Radius as a fraction of `√area`.
        radius: f64,
    },
    /// Gaussian noise of standard deviation `sigma · mean edge length` on every coordinate.
    Noise {
        /// Standard deviation as a fraction of the mean edge length.
        sigma: f64,
    },
    /// A point cloud: the faces are dropped and a seeded random `fraction` of the vertices is
    /// kept (in order), whose surface is rebuilt from local triangulations
    /// ([`super::point_cloud_mesh`]). Applied after every other perturbation of the list.
    PointCloud {
        /// Fraction of the vertices kept, in (0, 1].
        fraction: f64,
    },
}

impl Perturbation {
    /// The default single-view scan.
    pub const PARTIAL_VIEW: Perturbation = Perturbation::PartialView { min_cos: 0.15 };

    /// A short name for tables and file names, e.g. `holes5x0.015`, `partial-view`, `crop0.5`,
    /// `noise0.1`.
    ///
    /// ```
    /// use shapeforest::mesh::Perturbation;
    /// assert_eq!(Perturbation::Holes { count: 3, radius: 0.04 }.name(), "holes3x0.04");
    /// ```
    pub fn name(&self) -> String {
        self.to_string()
    }

    /// A training-set augmentation kind as written on the command line and in pipeline files:
    /// `partial-view`, `holes:N:R` or `crop:R`.
    ///
    /// ```
    /// use shapeforest::mesh::Perturbation;
    /// assert_eq!(Perturbation::parse_kind("holes:3:0.1"), Ok(Perturbation::Holes { count: 3, radius: 0.1 }));
    /// assert_eq!(Perturbation::parse_kind("partial-view"), Ok(Perturbation::PARTIAL_VIEW));
    /// assert!(Perturbation::parse_kind("holes:3").unwrap_err().contains("expected N:R"));
    /// ```
    pub fn parse_kind(text: &str) -> Result<Perturbation, String> {
        if text == "partial-view" {
            return Ok(Perturbation::PARTIAL_VIEW);
        }
        if let Some(rest) = text.strip_prefix("holes:") {
            return Self::parse_holes(rest);
        }
        if let Some(r) = text.strip_prefix("crop:") {
            let radius = r.parse().map_err(|_| format!("the crop radius {r:?} is not a number"))?;
            return Ok(Perturbation::Crop { radius });
        }
        Err(format!("expected partial-view, holes:N:R or crop:R, got {text:?}"))
    }

    /// Holes written `N:R` (N holes of radius R·√area).
    pub fn parse_holes(text: &str) -> Result<Perturbation, String> {
        let (n, r) =
            text.split_once(':').ok_or_else(|| format!("expected N:R (e.g. 5:0.015), got {text:?}"))?;
        let count =
            n.trim().parse().map_err(|_| format!("the number of holes {n:?} is not a whole number"))?;
        let radius = r.trim().parse().map_err(|_| format!("the radius {r:?} is not a number"))?;
        Ok(Perturbation::Holes { count, radius })
    }

    fn check(&self) -> Result<(), MeshError> {
        let bad = |what: &str| Err(MeshError::InvalidPerturbation(format!("{self}: {what}")));
        match *self {
            Perturbation::Holes { count, radius } => {
                if count == 0 || count > 10_000 {
                    return bad("the number of holes must be in 1..=10000");
                }
                if !(radius.is_finite() && radius > 0.0 && radius <= 10.0) {
                    return bad("the radius must be a positive fraction of √area (at most 10)");
                }
            }
            Perturbation::PartialView { min_cos } => {
                if !(min_cos.is_finite() && (0.0..1.0).contains(&min_cos)) {
                    return bad("the minimum cosine must be in [0, 1)");
                }
            }
            Perturbation::Crop { radius } => {
                if !(radius.is_finite() && radius > 0.0 && radius <= 10.0) {
                    return bad("the radius must be a positive fraction of √area (at most 10)");
                }
            }
            Perturbation::Noise { sigma } => {
                if !(sigma.is_finite() && (0.0..=10.0).contains(&sigma)) {
                    return bad("the noise level must be in [0, 10] mean edge lengths");
                }
            }
            Perturbation::PointCloud { fraction } => {
                if !(fraction.is_finite() && fraction > 0.0 && fraction <= 1.0) {
                    return bad("the fraction of points kept must be in (0, 1]");
                }
            }
        }
        Ok(())
    }
}

impl fmt::Display for Perturbation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Perturbation::Holes { count, radius } => write!(f, "holes{count}x{radius}"),
            Perturbation::PartialView { min_cos: 0.15 } => write!(f, "partial-view"),
            Perturbation::PartialView { min_cos } => write!(f, "partial-view{min_cos}"),
            Perturbation::Crop { radius } => write!(f, "crop{radius}"),
            Perturbation::Noise { sigma } => write!(f, "noise{sigma}"),
            Perturbation::PointCloud { fraction: 1.0 } => write!(f, "point-cloud"),
            Perturbation::PointCloud { fraction } => write!(f, "point-cloud{fraction}"),
        }
    }
}

/// The names of a perturbation list joined by `+` (`"none"` for an empty list).
///
/// ```
/// use shapeforest::mesh::{perturbations_name, Perturbation};
/// let p = [Perturbation::Holes { count: 5, radius: 0.015 }, Perturbation::Noise { sigma: 0.1 }];
/// assert_eq!(perturbations_name(&p), "holes5x0.015+noise0.1");
/// assert_eq!(perturbations_name(&[]), "none");
/// ```
pub fn perturbations_name(list: &[Perturbation]) -> String {
    if list.is_empty() {
        return "none".into();
    }
    list.iter().map(|p| p.name()).collect::<Vec<_>>().join("+")
}

/// A perturbed mesh and where its vertices come from.
#[derive(Clone, Debug)]
pub struct Perturbed {
    /// The perturbed mesh.
    pub mesh: Mesh,
    /// `kept[v]`: the input vertex that output vertex `v` is (strictly increasing).
    pub kept: Vec<usize>,
}

impl Perturbed {
    /// `new_index[old]`: the output vertex of each input vertex (`None` where it was removed).
    pub fn new_index(&self, n_input: usize) -> Vec<Option<usize>> {
        let mut out = vec![None; n_input];
        for (new, &old) in self.kept.iter().enumerate() {
            out[old] = Some(new);
        }
        out
    }

    /// Fraction of the input's surface area still present.
    pub fn area_fraction(&self, input: &Mesh) -> f64 {
        self.mesh.surface_area() / input.surface_area().max(f64::MIN_POSITIVE)
    }
}

/// Applies `list` in order to `mesh` (see the module documentation). An empty list returns the
/// mesh unchanged with the identity vertex map.
///
/// Errors: a perturbation with out-of-range settings, or one that removes every face
/// ([`MeshError::InvalidPerturbation`]).
///
/// ```
/// use shapeforest::mesh::{perturb, Perturbation};
/// use shapeforest::synth::icosphere;
/// let sphere = icosphere(3, 1.0);
/// let holed = perturb(&sphere, &[Perturbation::Holes { count: 3, radius: 0.05 }], 7).unwrap();
/// assert!(holed.mesh.n_faces() < sphere.n_faces());
/// // Every kept vertex sits where it was.
/// for (v, &old) in holed.kept.iter().enumerate() {
///     assert_eq!(holed.mesh.vertices[v], sphere.vertices[old]);
/// }
/// ```
pub fn perturb(mesh: &Mesh, list: &[Perturbation], seed: u64) -> Result<Perturbed, MeshError> {
    for p in list {
        p.check()?;
    }
    let sqrt_area = mesh.surface_area().sqrt();
    let mut vertices = mesh.vertices.clone();
    let mut faces: Vec<[usize; 3]> = mesh.faces.clone();
    let mut cloud = None;
    for (i, p) in list.iter().enumerate() {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ (0x5f3a_9c21_d4e7_b861u64.wrapping_mul(i as u64 + 1)));
        match *p {
            Perturbation::Holes { count, radius } => {
                let r2 = (radius * sqrt_area).powi(2);
                let centres: Vec<[f64; 3]> =
                    (0..count).filter_map(|_| random_surface_point(&vertices, &faces, &mut rng)).collect();
                faces.retain(|f| {
                    let c = centroid(&vertices, f);
                    centres.iter().all(|q| dist2(c, *q) > r2)
                });
            }
            Perturbation::PartialView { min_cos } => {
                let dir = random_direction(&mut rng);
                faces = visible_faces(&vertices, &faces, dir, min_cos);
            }
            Perturbation::Crop { radius } => {
                let r2 = (radius * sqrt_area).powi(2);
                if let Some(q) = random_surface_point(&vertices, &faces, &mut rng) {
                    faces.retain(|f| dist2(centroid(&vertices, f), q) <= r2);
                }
            }
            Perturbation::Noise { sigma } => {
                let h = mean_edge_length(&vertices, &faces);
                let s = sigma * h;
                for v in vertices.iter_mut() {
                    for c in v.iter_mut() {
                        *c += s * standard_normal(&mut rng);
                    }
                }
            }
            Perturbation::PointCloud { fraction } => cloud = Some((fraction, rng.clone())),
        }
        if faces.is_empty() {
            return Err(MeshError::InvalidPerturbation(format!(
                "{p}: no face is left (the perturbations {} remove the whole surface)",
                perturbations_name(list)
            )));
        }
    }
    // Compact: keep the vertices that a face still uses, in input order.
    let mut used = vec![false; vertices.len()];
    for f in &faces {
        for &v in f {
            used[v] = true;
        }
    }
    let kept: Vec<usize> = (0..vertices.len()).filter(|&v| used[v]).collect();
    let mut new_index = vec![usize::MAX; vertices.len()];
    for (new, &old) in kept.iter().enumerate() {
        new_index[old] = new;
    }
    if let Some((fraction, mut rng)) = cloud {
        let sampled: Vec<usize> = kept.iter().copied().filter(|_| rng.random_bool(fraction)).collect();
        let points: Vec<[f64; 3]> = sampled.iter().map(|&v| vertices[v]).collect();
        let mesh = super::point_cloud_mesh(&points, super::DEFAULT_NEIGHBOURS).map_err(|e| {
            MeshError::InvalidPerturbation(format!(
                "{}: no point-cloud surface: {e}",
                perturbations_name(list)
            ))
        })?;
        return Ok(Perturbed { mesh, kept: sampled });
    }
    let out_vertices = kept.iter().map(|&v| vertices[v]).collect();
    let out_faces = faces.iter().map(|f| [new_index[f[0]], new_index[f[1]], new_index[f[2]]]).collect();
    Ok(Perturbed { mesh: Mesh::new(out_vertices, out_faces)?, kept })
}

fn centroid(v: &[[f64; 3]], f: &[usize; 3]) -> [f64; 3] {
    let (a, b, c) = (v[f[0]], v[f[1]], v[f[2]]);
    [(a[0] + b[0] + c[0]) / 3.0, (a[1] + b[1] + c[1]) / 3.0, (a[2] + b[2] + c[2]) / 3.0]
}

fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

fn mean_edge_length(v: &[[f64; 3]], faces: &[[usize; 3]]) -> f64 {
    let mut sum = 0.0;
    for f in faces {
        for e in 0..3 {
            sum += dist2(v[f[e]], v[f[(e + 1) % 3]]).sqrt();
        }
    }
    sum / (3 * faces.len()).max(1) as f64
}

/// A point drawn uniformly on the surface (a face by area, then uniform barycentric
/// coordinates); `None` for a surface of zero area.
fn random_surface_point(v: &[[f64; 3]], faces: &[[usize; 3]], rng: &mut ChaCha8Rng) -> Option<[f64; 3]> {
    let areas: Vec<f64> = faces.iter().map(|f| triangle_area(v[f[0]], v[f[1]], v[f[2]])).collect();
    let total: f64 = areas.iter().sum();
    if total.is_nan() || total <= 0.0 {
        return None;
    }
    let mut t = rng.random::<f64>() * total;
    let mut face = faces.len() - 1;
    for (i, a) in areas.iter().enumerate() {
        if t < *a {
            face = i;
            break;
        }
        t -= a;
    }
    let (mut r1, mut r2) = (rng.random::<f64>(), rng.random::<f64>());
    if r1 + r2 > 1.0 {
        (r1, r2) = (1.0 - r1, 1.0 - r2);
    }
    let f = faces[face];
    let (a, b, c) = (v[f[0]], v[f[1]], v[f[2]]);
    Some(std::array::from_fn(|d| a[d] + r1 * (b[d] - a[d]) + r2 * (c[d] - a[d])))
}

fn random_direction(rng: &mut ChaCha8Rng) -> [f64; 3] {
    loop {
        let d = [standard_normal(rng), standard_normal(rng), standard_normal(rng)];
        let n = dot(d, d).sqrt();
        if n > 1e-6 {
            return [d[0] / n, d[1] / n, d[2] / n];
        }
    }
}

/// A standard normal deviate (Box–Muller; two uniforms per call, simple and exact enough for
/// noise, so no extra dependency).
fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(f64::MIN_POSITIVE);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// The faces an orthographic range scanner looking along `-dir` (standing at `+∞ · dir`)
/// captures: front-facing with `cos > min_cos`, and the nearest surface at their centroid
/// (depth buffer at a resolution of about half the mean edge length, at most 2048²).
fn visible_faces(v: &[[f64; 3]], faces: &[[usize; 3]], dir: [f64; 3], min_cos: f64) -> Vec<[usize; 3]> {
    // Orthonormal frame (u, w, dir).
    let helper = if dir[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = normalize(cross(dir, helper));
    let w = cross(dir, u);
    let proj: Vec<[f64; 3]> = v.iter().map(|&p| [dot(p, u), dot(p, w), dot(p, dir)]).collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &proj {
        for d in 0..2 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let h = mean_edge_length(v, faces).max(f64::MIN_POSITIVE);
    let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(f64::MIN_POSITIVE);
    let res = ((extent / (0.5 * h)).ceil() as usize).clamp(64, 2048);
    let cell = extent / res as f64;
    let mut depth = vec![f64::NEG_INFINITY; res * res];
    let pixel = |x: f64, lo: f64| (((x - lo) / cell).floor().max(0.0) as usize).min(res - 1);
    // Rasterise every face (both orientations occlude).
    for f in faces {
        let (a, b, c) = (proj[f[0]], proj[f[1]], proj[f[2]]);
        let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        let (x0, x1) = (pixel(a[0].min(b[0]).min(c[0]), lo[0]), pixel(a[0].max(b[0]).max(c[0]), lo[0]));
        let (y0, y1) = (pixel(a[1].min(b[1]).min(c[1]), lo[1]), pixel(a[1].max(b[1]).max(c[1]), lo[1]));
        for py in y0..=y1 {
            for px in x0..=x1 {
                let (x, y) = (lo[0] + (px as f64 + 0.5) * cell, lo[1] + (py as f64 + 0.5) * cell);
                let z = if det.abs() < 1e-300 {
                    // Seen edge-on: it covers the pixels its corners fall in, at their depth.
                    a[2].max(b[2]).max(c[2])
                } else {
                    let l1 = ((x - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (y - a[1])) / det;
                    let l2 = ((b[0] - a[0]) * (y - a[1]) - (x - a[0]) * (b[1] - a[1])) / det;
                    if l1 < -1e-9 || l2 < -1e-9 || l1 + l2 > 1.0 + 1e-9 {
                        continue;
                    }
                    a[2] + l1 * (b[2] - a[2]) + l2 * (c[2] - a[2])
                };
                let slot = &mut depth[py * res + px];
                if z > *slot {
                    *slot = z;
                }
            }
        }
    }
    // A face is seen when its own plane, at the centre of the pixel holding its centroid, is
    // the nearest surface there (the depth buffer holds plane depths at pixel centres, so a
    // visible face compares equal to itself, whatever its slope).
    let tol = 0.05 * h;
    faces
        .iter()
        .filter(|f| {
            let (a, b, c) = (v[f[0]], v[f[1]], v[f[2]]);
            let n = cross(sub(b, a), sub(c, a));
            let len = dot(n, n).sqrt();
            if len.is_nan() || len <= 0.0 || dot(n, dir) / len <= min_cos {
                return false;
            }
            let (pa, pb, pc) = (proj[f[0]], proj[f[1]], proj[f[2]]);
            let (px, py) =
                (pixel((pa[0] + pb[0] + pc[0]) / 3.0, lo[0]), pixel((pa[1] + pb[1] + pc[1]) / 3.0, lo[1]));
            let (x, y) = (lo[0] + (px as f64 + 0.5) * cell, lo[1] + (py as f64 + 0.5) * cell);
            let det = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pc[0] - pa[0]) * (pb[1] - pa[1]);
            let z = if det.abs() < 1e-300 {
                (pa[2] + pb[2] + pc[2]) / 3.0
            } else {
                let l1 = ((x - pa[0]) * (pc[1] - pa[1]) - (pc[0] - pa[0]) * (y - pa[1])) / det;
                let l2 = ((pb[0] - pa[0]) * (y - pa[1]) - (x - pa[0]) * (pb[1] - pa[1])) / det;
                pa[2] + l1 * (pb[2] - pa[2]) + l2 * (pc[2] - pa[2])
            };
            z >= depth[py * res + px] - tol
        })
        .copied()
        .collect()
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt().max(f64::MIN_POSITIVE);
    [a[0] / n, a[1] / n, a[2] / n]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    #[test]
    fn holes_remove_about_the_expected_area_and_keep_positions() {
        let sphere = icosphere(5, 1.0);
        // One hole of radius 0.1·√area: on a sphere of area 4π, a cap of chord radius ρ has
        // area πρ², so ~π·0.01·4π/(4π) = 3.1 % of the surface.
        let p = perturb(&sphere, &[Perturbation::Holes { count: 1, radius: 0.1 }], 1).unwrap();
        let lost = 1.0 - p.area_fraction(&sphere);
        assert!((lost - 0.0314).abs() < 0.01, "removed {lost}");
        for (v, &old) in p.kept.iter().enumerate() {
            assert_eq!(p.mesh.vertices[v], sphere.vertices[old]);
        }
        assert!(p.kept.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn partial_view_of_a_sphere_keeps_the_facing_hemisphere() {
        let sphere = icosphere(5, 1.0);
        let p = perturb(&sphere, &[Perturbation::PARTIAL_VIEW], 3).unwrap();
        // Facing half minus the grazing band (cos ≤ 0.15): 0.5 · 0.85 of the area.
        let kept = p.area_fraction(&sphere);
        assert!((kept - 0.425).abs() < 0.03, "kept {kept}");
    }

    #[test]
    fn partial_view_hides_occluded_surfaces() {
        // Two parallel unit squares, one behind the other along z: seen from +z, the back one is
        // hidden. Build both, facing +z.
        let mut vertices = Vec::new();
        let mut faces = Vec::new();
        for z in [0.0, 1.0] {
            let o = vertices.len();
            let n = 20;
            for j in 0..=n {
                for i in 0..=n {
                    vertices.push([i as f64 / n as f64, j as f64 / n as f64, z]);
                }
            }
            for j in 0..n {
                for i in 0..n {
                    let a = o + j * (n + 1) + i;
                    faces.push([a, a + 1, a + n + 2]);
                    faces.push([a, a + n + 2, a + n + 1]);
                }
            }
        }
        let mesh = Mesh::new(vertices, faces).unwrap();
        let seen = visible_faces(&mesh.vertices, &mesh.faces, [0.0, 0.0, 1.0], 0.15);
        assert_eq!(seen.len(), 800);
        assert!(seen.iter().all(|f| mesh.vertices[f[0]][2] == 1.0));
    }

    #[test]
    fn crop_keeps_a_ball_and_noise_moves_vertices_by_the_requested_amount() {
        let sphere = icosphere(4, 1.0);
        let c = perturb(&sphere, &[Perturbation::Crop { radius: 0.2 }], 5).unwrap();
        let frac = c.area_fraction(&sphere);
        assert!(frac > 0.05 && frac < 0.25, "kept {frac}");
        let h = mean_edge_length(&sphere.vertices, &sphere.faces);
        let n = perturb(&sphere, &[Perturbation::Noise { sigma: 0.1 }], 5).unwrap();
        assert_eq!(n.mesh.n_vertices(), sphere.n_vertices());
        let rms = (n.mesh.vertices.iter().zip(&sphere.vertices).map(|(a, b)| dist2(*a, *b)).sum::<f64>()
            / (3 * sphere.n_vertices()) as f64)
            .sqrt();
        assert!((rms / (0.1 * h) - 1.0).abs() < 0.1, "rms {rms} vs {}", 0.1 * h);
    }

    #[test]
    fn perturbations_are_reproducible_and_checked() {
        let sphere = icosphere(3, 1.0);
        let list = [Perturbation::Holes { count: 4, radius: 0.05 }, Perturbation::Noise { sigma: 0.2 }];
        let a = perturb(&sphere, &list, 9).unwrap();
        let b = perturb(&sphere, &list, 9).unwrap();
        assert_eq!(a.mesh, b.mesh);
        let c = perturb(&sphere, &list, 10).unwrap();
        assert_ne!(a.mesh, c.mesh);
        let e = perturb(&sphere, &[Perturbation::Holes { count: 0, radius: 0.1 }], 0).unwrap_err();
        assert!(e.to_string().contains("number of holes"), "{e}");
        let e = perturb(&sphere, &[Perturbation::Crop { radius: 1e-9 }], 0).unwrap_err();
        assert!(e.to_string().contains("no face is left"), "{e}");
    }

    #[test]
    fn point_cloud_keeps_a_seeded_fraction_of_the_points() {
        let sphere = icosphere(3, 1.0);
        let all = perturb(&sphere, &[Perturbation::PointCloud { fraction: 1.0 }], 3).unwrap();
        assert_eq!(all.kept, (0..sphere.n_vertices()).collect::<Vec<_>>());
        assert_eq!(all.mesh.vertices, sphere.vertices);
        assert!(all.mesh.point_cloud_multiplicity().is_some());
        assert!((all.area_fraction(&sphere) - 1.0).abs() < 0.05);
        let half = perturb(&sphere, &[Perturbation::PointCloud { fraction: 0.5 }], 3).unwrap();
        let n = half.kept.len() as f64 / sphere.n_vertices() as f64;
        assert!((0.4..0.6).contains(&n), "{n}");
        assert!(half.kept.windows(2).all(|w| w[0] < w[1]));
        for (v, &old) in half.kept.iter().enumerate() {
            assert_eq!(half.mesh.vertices[v], sphere.vertices[old]);
        }
        assert_eq!(
            perturb(&sphere, &[Perturbation::PointCloud { fraction: 0.5 }], 3).unwrap().kept,
            half.kept
        );
        // after holes, the cloud samples what the holes left
        let list =
            [Perturbation::PointCloud { fraction: 1.0 }, Perturbation::Holes { count: 2, radius: 0.1 }];
        let holed = perturb(&sphere, &list, 4).unwrap();
        assert!(holed.kept.len() < sphere.n_vertices());
        assert_eq!(perturbations_name(&list), "point-cloud+holes2x0.1");
        let e = perturb(&sphere, &[Perturbation::PointCloud { fraction: 0.0 }], 3).unwrap_err();
        assert!(e.to_string().contains("(0, 1]"), "{e}");
    }
}
