//! Whether a map keeps the handedness of the surface or mirrors it, from the extrinsic
//! geometry of both meshes: a small triangle of test points and the triangle of their images
//! wind the same way about each surface's normal under a map that preserves orientation, the
//! opposite way under a mirror image. On a partial scan the intrinsic orientation descriptors
//! ([`super::Orientation`]) are computed from the part's own spectrum and often agree with a
//! mirrored map; this check needs only both meshes' face winding (outward normals, as scans and
//! the shared data have them) and is unchanged by rigid motion and by a near-isometric
//! deformation of small triangles.

use super::RegularizerError as Error;
use crate::{geodesic::farthest_point_sampling_euclidean, mesh::Mesh};

/// Area-weighted vertex normals (unnormalised) from the faces' winding.
fn vertex_normals(mesh: &Mesh) -> Vec<[f64; 3]> {
    let mut n = vec![[0.0; 3]; mesh.n_vertices()];
    for f in &mesh.faces {
        let [a, b, c] = [mesh.vertices[f[0]], mesh.vertices[f[1]], mesh.vertices[f[2]]];
        let cr = cross(sub(b, a), sub(c, a));
        for &v in f {
            for d in 0..3 {
                n[v][d] += cr[d];
            }
        }
    }
    n
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The handedness of `map` (test vertex → reference vertex), in `[−1, 1]`: over `samples`
/// farthest-point samples `p` of the test shape, each with its two nearest other samples `q`,
/// `r`, the mean of `sign(det(q − p, r − p, n(p))) · sign(det(T(q) − T(p), T(r) − T(p), n(T(p))))`
/// (triangles that degenerate on either side are skipped). Near 1: the map keeps the surface's
/// orientation; near −1: it is a mirror image; 0 when no triangle could be judged.
pub fn handedness(test: &Mesh, reference: &Mesh, map: &[usize], samples: usize) -> Result<f64, Error> {
    if map.len() != test.n_vertices() {
        return Err(Error::SizeMismatch(format!(
            "a map of {} vertices for a test shape of {}",
            map.len(),
            test.n_vertices()
        )));
    }
    if let Some(&r) = map.iter().find(|&&r| r >= reference.n_vertices()) {
        return Err(Error::SizeMismatch(format!(
            "the map names reference vertex {r}, the reference has {}",
            reference.n_vertices()
        )));
    }
    let n = samples.min(test.n_vertices());
    if n < 3 {
        return Ok(0.0);
    }
    let s = farthest_point_sampling_euclidean(test, n, None)?;
    let (nt, nr) = (vertex_normals(test), vertex_normals(reference));
    let (pt, pr) = (&test.vertices, &reference.vertices);
    let (mut votes, mut judged) = (0.0, 0usize);
    for (i, &p) in s.iter().enumerate() {
        // The two nearest other samples.
        let mut near: Vec<(f64, usize)> = s
            .iter()
            .enumerate()
            .filter(|&(j, _)| j != i)
            .map(|(_, &q)| (dot(sub(pt[q], pt[p]), sub(pt[q], pt[p])), q))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (q, r) = (near[0].1, near[1].1);
        let side = |pos: &[[f64; 3]], normals: &[[f64; 3]], a: usize, b: usize, c: usize| {
            let e = cross(sub(pos[b], pos[a]), sub(pos[c], pos[a]));
            let scale = dot(e, e).sqrt() * dot(normals[a], normals[a]).sqrt();
            let d = dot(e, normals[a]);
            // Skip a triangle nearly edge-on to the normal or collapsed.
            (scale > 0.0 && d.abs() > 0.2 * scale).then_some(d.signum())
        };
        let (tp, tq, tr) = (map[p], map[q], map[r]);
        if tp == tq || tp == tr || tq == tr {
            continue;
        }
        if let (Some(a), Some(b)) = (side(pt, &nt, p, q, r), side(pr, &nr, tp, tq, tr)) {
            votes += a * b;
            judged += 1;
        }
    }
    Ok(if judged > 0 { votes / judged as f64 } else { 0.0 })
}

/// `symmetry ∘ map` when it keeps the surface's orientation better than `map` does by
/// [`handedness`] on `samples` samples, and `map` is judged mirrored (negative handedness);
/// `None` otherwise. `symmetry` is a left/right self-map of the reference's vertices.
pub fn unmirrored(
    test: &Mesh,
    reference: &Mesh,
    map: &[usize],
    symmetry: &[usize],
    samples: usize,
) -> Result<Option<Vec<usize>>, Error> {
    if symmetry.len() != reference.n_vertices() || symmetry.iter().any(|&r| r >= reference.n_vertices()) {
        return Err(Error::SizeMismatch(format!(
            "a symmetry of {} entries for a reference of {} vertices",
            symmetry.len(),
            reference.n_vertices()
        )));
    }
    let before = handedness(test, reference, map, samples)?;
    if before >= 0.0 {
        return Ok(None);
    }
    let mirrored: Vec<usize> = map.iter().map(|&r| symmetry[r]).collect();
    let after = handedness(test, reference, &mirrored, samples)?;
    Ok((after > before).then_some(mirrored))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    /// An ellipsoid, its vertex mirror map across the plane x = 0 (an icosphere is symmetric
    /// in x), and a copy of it bent a little.
    fn ellipsoid() -> (Mesh, Vec<usize>) {
        let mut mesh = icosphere(3, 1.0);
        for v in &mut mesh.vertices {
            v[1] *= 1.3;
            v[2] *= 1.7;
        }
        let pos = mesh.vertices.clone();
        let mirror = pos
            .iter()
            .map(|p| {
                let m = [-p[0], p[1], p[2]];
                (0..pos.len())
                    .min_by(|&a, &b| {
                        dot(sub(pos[a], m), sub(pos[a], m)).total_cmp(&dot(sub(pos[b], m), sub(pos[b], m)))
                    })
                    .unwrap()
            })
            .collect();
        (mesh, mirror)
    }

    #[test]
    fn the_identity_keeps_handedness_and_its_mirror_image_reverses_it() {
        let (mesh, mirror) = ellipsoid();
        let mut moved = mesh.clone();
        // A rigid motion and a gentle bend of the test shape change nothing.
        for v in &mut moved.vertices {
            let (x, y, z) = (v[0], v[1], v[2]);
            *v = [y + 3.0, -x + 0.1 * z * z, z - 1.0];
        }
        let identity: Vec<usize> = (0..mesh.n_vertices()).collect();
        let h = handedness(&moved, &mesh, &identity, 100).unwrap();
        assert!(h > 0.9, "identity: {h}");
        let h = handedness(&moved, &mesh, &mirror, 100).unwrap();
        assert!(h < -0.9, "mirror image: {h}");
        // The mirrored map is put right by the symmetry; the right one is left alone.
        let fixed = unmirrored(&moved, &mesh, &mirror, &mirror, 100).unwrap().expect("put right");
        let right = fixed.iter().enumerate().filter(|&(v, &r)| v == r).count();
        assert!(right * 10 >= mesh.n_vertices() * 9, "{right}");
        assert!(unmirrored(&moved, &mesh, &identity, &mirror, 100).unwrap().is_none());
    }
}
