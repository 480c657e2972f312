//! Local rigid fitting of a map's images: each image re-placed where its neighbourhood's images,
//! fitted by a rotation and a translation, put it.
//!
//! The spectral refinements leave every image a fraction of an edge to an edge or two off, and
//! neighbouring images do not err alike: started from the true map itself, ZoomOut 100 → 200
//! leaves a FAUST pair's mean error at 1.3–2.0 × 10⁻² √area where the true map's is 0.4–0.5
//! (`examples/zoomout_oracle.rs`). A small piece of a body moves nearly rigidly from one pose
//! (or one person) to another, so the images of a vertex's neighbours, fitted by the rotation
//! and translation that carry the neighbourhood onto them (weighted least squares, the
//! Kabsch/Procrustes solution), tell where the vertex itself goes with the noise of one image
//! averaged out over the neighbourhood. The vertex takes the reference vertex nearest that
//! point among those within a reach of the image it replaces (two mean edge lengths: the step
//! repairs jitter, it does not move parts).
//!
//! Two guards keep it from doing harm. A neighbourhood that does not move rigidly, because it spans
//! a seam between a right and a wrong part of the map or a bending joint, is not used: the fit's
//! root-mean-square residual over it must stay within 1.3 mean edge lengths, or the image stays
//! (without this guard, and with a reach of 0.03 √area, on hi-res TOSCA cats whose maps are mostly
//! vertex-exact, 99.6 % of the points within 0.05 fell to 98.1 %). And both neighbourhoods, the
//! test vertex's and the image's, are the vertices connected to it through mesh edges without
//! leaving a Euclidean ball around it: a hand resting on a thigh does not join the thigh's
//! neighbourhoods, and an image on the inside of one thigh does not jump to the other touching it
//! (with a plain Euclidean reach it did, onto the mirror-image part: FAUST pairs 1.43 → 1.52 mean
//! ×100 strictly while 1.39 → 1.34 with flips allowed).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::RegularizerError as Error;
use crate::{
    geodesic::mean_edge_length,
    mesh::{face_neighbour_lists, Mesh},
    spectral::vertex_lumped_mass,
};

/// Settings of [`local_rigid`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LocalRigidParams {
    /// Radius of a vertex's neighbourhood, × the test shape's `√area`. Default 0.05.
    pub radius: f64,
    /// Rounds, each from the previous round's images. Default 2.
    pub rounds: usize,
    /// How far an image may move, in mean edge lengths of the reference (Euclidean, through
    /// vertices connected to the image). Default 2.
    pub reach: f64,
    /// The largest root-mean-square residual of a neighbourhood's fit, in mean edge lengths of
    /// the reference, for which the vertex's image is re-placed. Default 1.3.
    pub fit: f64,
}

impl Default for LocalRigidParams {
    fn default() -> Self {
        Self { radius: 0.05, rounds: 2, reach: 2.0, fit: 1.3 }
    }
}

impl LocalRigidParams {
    /// Checks the settings, naming the broken rule.
    pub fn check(&self) -> Result<(), Error> {
        let bad = |reason: String| Err(Error::InvalidParameter { name: "local rigid", reason });
        if !(self.radius > 0.0 && self.radius.is_finite()) {
            return bad(format!("radius = {}: must be finite and > 0", self.radius));
        }
        if !(self.reach >= 0.0 && self.reach.is_finite()) {
            return bad(format!("reach = {}: must be finite and ≥ 0", self.reach));
        }
        if !(self.fit >= 0.0 && self.fit.is_finite()) {
            return bad(format!("fit = {}: must be finite and ≥ 0", self.fit));
        }
        Ok(())
    }
}

/// Fewer neighbours than this (the vertex included) leave the image as it is: three points fix
/// a rotation, and a few more keep one stray image from turning it.
const MIN_NEIGHBOURS: usize = 6;

/// Into `out`: the vertices connected to `centre` through mesh edges (`adjacency`: offsets and
/// neighbours, [`face_neighbour_lists`]) without leaving the ball of squared radius `r2` around
/// it, `centre` first. `seen` marks the vertices found with `stamp` (a value that it holds for
/// no vertex yet, e.g. the index of the vertex the ball is made for).
fn connected_ball(
    points: &[Vector3<f64>],
    (offsets, neighbours): (&[usize], &[usize]),
    centre: usize,
    r2: f64,
    (seen, stamp): (&mut [u32], u32),
    out: &mut Vec<usize>,
) {
    out.clear();
    out.push(centre);
    seen[centre] = stamp;
    let mut head = 0;
    while head < out.len() {
        let u = out[head];
        head += 1;
        for &w in &neighbours[offsets[u]..offsets[u + 1]] {
            if seen[w] != stamp && (points[w] - points[centre]).norm_squared() <= r2 {
                seen[w] = stamp;
                out.push(w);
            }
        }
    }
}

/// `map` (test vertex → reference vertex) with every image re-placed by the rigid fit of its
/// neighbourhood's images (see the module documentation).
pub fn local_rigid(
    test: &Mesh,
    reference: &Mesh,
    map: &[usize],
    params: &LocalRigidParams,
) -> Result<Vec<usize>, Error> {
    params.check()?;
    let (n, nr) = (test.n_vertices(), reference.n_vertices());
    if map.len() != n || map.iter().any(|&r| r >= nr) {
        return Err(Error::SizeMismatch(format!(
            "local rigid: a map of {} entries for a test shape of {n} vertices onto {nr}",
            map.len()
        )));
    }
    let unit = |mesh: &Mesh| -> Vec<Vector3<f64>> {
        let s = 1.0 / mesh.surface_area().max(f64::MIN_POSITIVE).sqrt();
        mesh.vertices.iter().map(|p| Vector3::new(p[0], p[1], p[2]) * s).collect()
    };
    let (xt, xr) = (unit(test), unit(reference));
    // Vertex areas (a third of each adjacent face's) weigh the fit, so that a densely
    // triangulated patch does not outweigh a coarse one.
    let weight = vertex_lumped_mass(test);
    let (offsets, neighbours) = face_neighbour_lists(&test.faces, n);
    let (r_offsets, r_neighbours) = face_neighbour_lists(&reference.faces, nr);
    // The reference's mean edge length, in the units of `xr`.
    let edge = mean_edge_length(reference) / reference.surface_area().max(f64::MIN_POSITIVE).sqrt();
    let r2 = params.radius * params.radius;
    let reach2 = (params.reach * edge).powi(2);
    let fit2 = (params.fit * edge).powi(2);
    // Every vertex's neighbourhood, the same in every round.
    let balls: Vec<Vec<u32>> = (0..n)
        .into_par_iter()
        .map_init(
            || (vec![u32::MAX; n], Vec::new()),
            |(seen, ball), v| {
                connected_ball(&xt, (&offsets, &neighbours), v, r2, (seen, v as u32), ball);
                ball.iter().map(|&u| u as u32).collect()
            },
        )
        .collect();
    let mut current = map.to_vec();
    for _ in 0..params.rounds {
        let next: Vec<usize> = (0..n)
            .into_par_iter()
            .map_init(
                || (vec![u32::MAX; nr], Vec::<usize>::new()),
                |(seen_r, near), v| {
                    let stamp = v as u32;
                    let ball = &balls[v];
                    let ball = || ball.iter().map(|&u| u as usize);
                    if ball().len() < MIN_NEIGHBOURS {
                        return current[v];
                    }
                    let total: f64 = ball().map(|u| weight[u]).sum();
                    if total <= 0.0 {
                        return current[v];
                    }
                    let mut mx = Vector3::zeros();
                    let mut my = Vector3::zeros();
                    for u in ball() {
                        mx += xt[u] * weight[u];
                        my += xr[current[u]] * weight[u];
                    }
                    mx /= total;
                    my /= total;
                    let mut h = Matrix3::zeros();
                    for u in ball() {
                        h += (xt[u] - mx) * (xr[current[u]] - my).transpose() * weight[u];
                    }
                    let svd = h.svd(true, true);
                    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else { return current[v] };
                    let mut d = Matrix3::identity();
                    d[(2, 2)] = (vt.transpose() * u.transpose()).determinant().signum();
                    let rotation = vt.transpose() * d * u.transpose();
                    // A neighbourhood that does not move rigidly (a seam between a right and
                    // a wrong part, a bending joint) tells nothing: the image stays.
                    let mut spread = 0.0;
                    for u in ball() {
                        spread += weight[u] * (rotation * (xt[u] - mx) + my - xr[current[u]]).norm_squared();
                    }
                    if spread > fit2 * total {
                        return current[v];
                    }
                    let p = rotation * (xt[v] - mx) + my;
                    if !p.iter().all(|x| x.is_finite()) {
                        return current[v];
                    }
                    // The reference vertex nearest that point among those connected to the
                    // image within the reach.
                    connected_ball(
                        &xr,
                        (&r_offsets, &r_neighbours),
                        current[v],
                        reach2,
                        (seen_r, stamp),
                        near,
                    );
                    let distance = |u: &usize| (xr[*u] - p).norm_squared();
                    near.iter()
                        .copied()
                        .min_by(|a, b| distance(a).total_cmp(&distance(b)))
                        .unwrap_or(current[v])
                },
            )
            .collect();
        let changed = next != current;
        current = next;
        if !changed {
            break;
        }
    }
    Ok(current)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid of `k × k` vertices, spacing 1.
    fn grid(k: usize) -> Mesh {
        let mut vertices = Vec::new();
        for i in 0..k {
            for j in 0..k {
                vertices.push([i as f64, j as f64, 0.0]);
            }
        }
        let mut faces = Vec::new();
        for i in 0..k - 1 {
            for j in 0..k - 1 {
                let a = i * k + j;
                faces.push([a, a + k, a + 1]);
                faces.push([a + 1, a + k, a + k + 1]);
            }
        }
        Mesh::new(vertices, faces).unwrap()
    }

    #[test]
    fn stray_images_return_to_their_neighbours_fit() {
        let mesh = grid(20);
        let n = mesh.n_vertices();
        // The identity with a few images one vertex off, away from the border.
        let mut map: Vec<usize> = (0..n).collect();
        let strays = [5 * 20 + 5, 9 * 20 + 12, 14 * 20 + 7];
        for &v in &strays {
            map[v] = v + 1;
        }
        let params = LocalRigidParams { radius: 3.5 / 19.0, reach: 3.0, ..Default::default() };
        let fixed = local_rigid(&mesh, &mesh, &map, &params).unwrap();
        assert_eq!(fixed, (0..n).collect::<Vec<_>>());
    }

    #[test]
    fn a_rigid_motion_of_the_reference_is_followed_and_the_reach_holds() {
        let mesh = grid(12);
        let n = mesh.n_vertices();
        // The reference: the same grid turned a quarter and moved; the true map is the identity.
        let turned =
            Mesh::new(mesh.vertices.iter().map(|p| [-p[1] + 50.0, p[0], 3.0]).collect(), mesh.faces.clone())
                .unwrap();
        let mut map: Vec<usize> = (0..n).collect();
        map[5 * 12 + 5] = 5 * 12 + 6;
        let params = LocalRigidParams { radius: 3.5 / 11.0, rounds: 1, reach: 3.0, ..Default::default() };
        assert_eq!(local_rigid(&mesh, &turned, &map, &params).unwrap()[5 * 12 + 5], 5 * 12 + 5);
        // A reach shorter than an edge keeps the stray image.
        let short = LocalRigidParams { reach: 0.4, ..params };
        assert_eq!(local_rigid(&mesh, &turned, &map, &short).unwrap()[5 * 12 + 5], 5 * 12 + 6);
        assert!(local_rigid(&mesh, &turned, &map, &LocalRigidParams { radius: f64::NAN, ..params }).is_err());
        assert!(local_rigid(&mesh, &turned, &map[1..], &params).is_err());
    }

    #[test]
    fn an_image_does_not_jump_to_a_part_that_only_touches_it() {
        // The reference: a sheet and a copy of it, not connected, a thousandth of an edge aside
        // (one thigh against the other); the test shape is the first sheet, mapped onto it with
        // one stray image. The fits land between the vertices, where a copy's vertex is as often
        // the nearest in space; the connected reach never offers one.
        let sheet = grid(10);
        let n = sheet.n_vertices();
        let mut vertices = sheet.vertices.clone();
        vertices.extend(sheet.vertices.iter().map(|p| [p[0], p[1] + 0.001, 0.0]));
        let mut faces = sheet.faces.clone();
        faces.extend(sheet.faces.iter().map(|f| [f[0] + n, f[1] + n, f[2] + n]));
        let reference = Mesh::new(vertices, faces).unwrap();
        let mut map: Vec<usize> = (0..n).collect();
        map[4 * 10 + 4] = 4 * 10 + 5;
        let params = LocalRigidParams { radius: 0.4, reach: 2.0, ..Default::default() };
        let fixed = local_rigid(&sheet, &reference, &map, &params).unwrap();
        assert!(fixed.iter().all(|&r| r < n), "an image crossed to the other sheet");
        assert_eq!(fixed[4 * 10 + 4], 4 * 10 + 4);
    }

    #[test]
    fn a_neighbourhood_that_does_not_move_rigidly_leaves_the_images() {
        // The left half mapped as it is, the right half mirrored onto itself: no rotation
        // fits a neighbourhood there or across the seam, and the fit must not average them.
        let mesh = grid(20);
        let map: Vec<usize> =
            (0..mesh.n_vertices()).map(|v| if v % 20 < 10 { v } else { v - v % 20 + 29 - v % 20 }).collect();
        let params = LocalRigidParams { radius: 3.5 / 19.0, reach: 3.0, ..Default::default() };
        assert_eq!(local_rigid(&mesh, &mesh, &map, &params).unwrap(), map);
        let ungated = LocalRigidParams { fit: 100.0, ..params };
        assert_ne!(local_rigid(&mesh, &mesh, &map, &ungated).unwrap(), map);
    }
}
