//! Whether a vertex map preserves orientation, read off the map itself.
//!
//! Intrinsic descriptors cannot tell a shape from its mirror image, so a map between two
//! left/right symmetric bodies can come out mirrored, wholly or on some limbs. Both surfaces
//! are oriented (outward normals), and a map that preserves orientation sends a test triangle
//! `(a, b, c)` to an image triangle `(T a, T b, T c)` whose normal points the way the
//! reference's surface does there; a mirrored map turns it inside out. This measure is
//! geometric, pose-independent and needs no descriptor: it is the sign of
//! `((p_{T b} − p_{T a}) × (p_{T c} − p_{T a})) · (n_{T a} + n_{T b} + n_{T c})` per test face,
//! weighted by the face's area; faces whose corners collapse onto fewer than three reference
//! vertices carry no vote.

use super::Error;
use crate::mesh::{cross, dot, norm, sub, vertex_normals, Mesh};

/// Orientation of a vertex map, see the module documentation.
#[derive(Clone, Debug, PartialEq)]
pub struct MapOrientation {
    /// Area-weighted mean sign over the test faces with a non-degenerate image, in [−1, 1]:
    /// near 1 for an orientation-preserving map, near −1 for a mirror image.
    pub score: f64,
    /// Per test vertex, the area-weighted mean sign of its faces (0 where none has a vote).
    pub per_vertex: Vec<f64>,
    /// Fraction of the test area whose faces have a non-degenerate image.
    pub voting_area: f64,
}

fn face_cross(mesh: &Mesh, a: usize, b: usize, c: usize) -> [f64; 3] {
    let (p, q, r) = (mesh.vertices[a], mesh.vertices[b], mesh.vertices[c]);
    let u = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
    let v = [r[0] - p[0], r[1] - p[1], r[2] - p[2]];
    [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
}

/// The orientation of `map` (test vertex → reference vertex), see the module documentation.
/// `map` must have one entry per test vertex, each a reference vertex (the caller's maps do).
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::map_orientation};
/// // A tetrahedron onto itself: the identity keeps orientation, swapping two vertices
/// // (a reflection) reverses it.
/// let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
/// let tet = Mesh::new(v, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).unwrap();
/// assert_eq!(map_orientation(&tet, &tet, &[0, 1, 2, 3]).score, 1.0);
/// assert_eq!(map_orientation(&tet, &tet, &[1, 0, 2, 3]).score, -1.0);
/// ```
pub fn map_orientation(test: &Mesh, reference: &Mesh, map: &[usize]) -> MapOrientation {
    let normals = vertex_normals(reference);
    let n = test.n_vertices();
    let mut num = vec![0.0; n];
    let mut den = vec![0.0; n];
    let (mut total, mut voting, mut signed) = (0.0, 0.0, 0.0);
    for f in &test.faces {
        let w = {
            let c = face_cross(test, f[0], f[1], f[2]);
            0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
        };
        total += w;
        let (a, b, c) = (map[f[0]], map[f[1]], map[f[2]]);
        if a == b || b == c || a == c {
            continue;
        }
        let img = face_cross(reference, a, b, c);
        let nr = [
            normals[a][0] + normals[b][0] + normals[c][0],
            normals[a][1] + normals[b][1] + normals[c][1],
            normals[a][2] + normals[b][2] + normals[c][2],
        ];
        let dot = img[0] * nr[0] + img[1] * nr[1] + img[2] * nr[2];
        let s = if dot > 0.0 {
            1.0
        } else if dot < 0.0 {
            -1.0
        } else {
            continue;
        };
        voting += w;
        signed += w * s;
        for &v in f {
            num[v] += w * s;
            den[v] += w;
        }
    }
    let per_vertex = num.iter().zip(&den).map(|(a, d)| if *d > 0.0 { a / d } else { 0.0 }).collect();
    MapOrientation {
        score: if voting > 0.0 { signed / voting } else { 0.0 },
        per_vertex,
        voting_area: if total > 0.0 { voting / total } else { 0.0 },
    }
}

/// The per-vertex orientation of `orientation` smoothed over the test mesh: `rounds` passes
/// of averaging each vertex with its face neighbours (a diffusion of about
/// `√rounds` edge lengths), so that a mirrored limb reads as one negative region and
/// isolated folds do not.
pub fn smoothed_orientation(test: &Mesh, orientation: &MapOrientation, rounds: usize) -> Vec<f64> {
    let (offsets, neighbours) = crate::mesh::face_neighbour_lists(&test.faces, test.n_vertices());
    diffuse(&offsets, &neighbours, orientation.per_vertex.clone(), rounds)
}

/// `rounds` passes of averaging each vertex's value with those of its face neighbours
/// (`offsets`, `neighbours`: [`crate::mesh::face_neighbour_lists`]).
pub(super) fn diffuse(offsets: &[usize], neighbours: &[usize], mut cur: Vec<f64>, rounds: usize) -> Vec<f64> {
    use rayon::prelude::*;
    // Each pass reads the last one only: its vertices in blocks side by side.
    const BLOCK: usize = 2048;
    let mut next = vec![0.0; cur.len()];
    for _ in 0..rounds {
        next.par_chunks_mut(BLOCK).enumerate().for_each(|(b, block)| {
            for (i, out) in block.iter_mut().enumerate() {
                let v = b * BLOCK + i;
                let nb = &neighbours[offsets[v]..offsets[v + 1]];
                let sum: f64 = nb.iter().map(|&u| cur[u]).sum();
                *out = (cur[v] + sum) / (1 + nb.len()) as f64;
            }
        });
        std::mem::swap(&mut cur, &mut next);
    }
    cur
}

/// The default threshold of [`unflip`] (and of [`reversed_area`]'s reading of a map): a smoothed
/// orientation below −0.2 reads as mirrored.
pub const UNFLIP_THRESHOLD: f64 = 0.2;

/// Smoothing passes for [`unflip`] on a mesh of `n` vertices: a diffusion radius of about
/// 0.05·√area (`(0.05·√area / h)²` passes for an edge length `h` of a regular mesh).
pub fn unflip_rounds(n: usize) -> usize {
    (n / 400).clamp(4, 400)
}

/// Fraction of the test's area (lumped vertex areas) where `map` reads as mirrored: its
/// smoothed orientation ([`smoothed_orientation`] with [`unflip_rounds`] passes, as [`unflip`]
/// reads it) is below `-threshold`. Near 0 for a map that keeps orientation; a mirrored limb
/// shows as the limb's share of the area. `map` must have one entry per test vertex, each a
/// reference vertex.
pub fn reversed_area(test: &Mesh, reference: &Mesh, map: &[usize], threshold: f64) -> f64 {
    let orientation = map_orientation(test, reference, map);
    let smooth = smoothed_orientation(test, &orientation, unflip_rounds(test.n_vertices()));
    let mass = crate::spectral::vertex_lumped_mass(test);
    let total = mass.iter().fold(0.0, |a, m| a + m);
    let reversed = smooth.iter().zip(&mass).filter(|(s, _)| **s < -threshold).fold(0.0, |a, (_, m)| a + m);
    if total > 0.0 {
        reversed / total
    } else {
        0.0
    }
}

/// What [`unflip`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct Unflip {
    /// The repaired map.
    pub map: Vec<usize>,
    /// Orientation score before and after.
    pub score_before: f64,
    /// See `score_before`.
    pub score_after: f64,
    /// Fraction of the test vertices whose image was replaced by its mirror.
    pub changed: f64,
}

/// Repairs the mirrored parts of `map` (test → reference): where the smoothed per-vertex
/// orientation ([`smoothed_orientation`]) is below `-threshold`, the image is replaced by its
/// mirror under `symmetry` (a self-map of the reference: `symmetry[r]` is the vertex at the
/// mirror image of `r`). Returns `None` when no vertex is reversed or when the repaired map
/// is not better oriented than the input.
pub fn unflip(
    test: &Mesh,
    reference: &Mesh,
    map: &[usize],
    symmetry: &[usize],
    threshold: f64,
) -> Option<Unflip> {
    if symmetry.len() != reference.n_vertices() || map.len() != test.n_vertices() {
        return None;
    }
    let before = map_orientation(test, reference, map);
    let smooth = smoothed_orientation(test, &before, unflip_rounds(test.n_vertices()));
    let mut out = map.to_vec();
    let mut changed = 0usize;
    for (v, &s) in smooth.iter().enumerate() {
        if s < -threshold {
            out[v] = symmetry[map[v]];
            changed += 1;
        }
    }
    if changed == 0 {
        return None;
    }
    let after = map_orientation(test, reference, &out);
    (after.score > before.score).then(|| Unflip {
        map: out,
        score_before: before.score,
        score_after: after.score,
        changed: changed as f64 / map.len().max(1) as f64,
    })
}

/// A left/right self-map of `mesh` (`map[v]`: the vertex at the mirror image of `v`) from
/// known mirror pairs `(v, mirror of v)`, e.g. the rows of a `.sym.vts` file beside its
/// `.vts`. A vertex in no pair takes the mirror of its nearest paired vertex (Euclidean); the
/// first pair of a vertex counts. Out-of-range vertices and an empty list are refused.
///
/// ```
/// use shapeforest::{mesh::Mesh, regularizer::symmetry_from_pairs};
/// let v = vec![[-1.0, 0.0, 0.0], [-0.9, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
/// let mesh = Mesh::new(v, vec![[0, 2, 3], [0, 1, 3]]).unwrap();
/// let map = symmetry_from_pairs(&mesh, &[(0, 2), (2, 0), (3, 3)]).unwrap();
/// assert_eq!(map, vec![2, 2, 0, 3]); // vertex 1 takes the mirror of its nearest, vertex 0
/// ```
pub fn symmetry_from_pairs(mesh: &Mesh, pairs: &[(usize, usize)]) -> Result<Vec<usize>, Error> {
    let n = mesh.n_vertices();
    if pairs.is_empty() {
        return Err(Error::InvalidInput("a symmetry needs at least one mirror pair".into()));
    }
    if let Some(&(a, b)) = pairs.iter().find(|&&(a, b)| a >= n || b >= n) {
        return Err(Error::InvalidInput(format!(
            "mirror pair ({a}, {b}) names a vertex outside the shape's {n}"
        )));
    }
    let mut mirror = vec![usize::MAX; n];
    for &(a, b) in pairs {
        if mirror[a] == usize::MAX {
            mirror[a] = b;
        }
    }
    let kept: Vec<usize> = (0..n).filter(|&v| mirror[v] != usize::MAX).collect();
    let part_map: Vec<usize> = kept.iter().map(|&v| mirror[v]).collect();
    Ok(crate::mesh::extend_map_by_nearest(mesh, &kept, &part_map))
}

/// The orientation of a sparse match set read extrinsically: over every triplet of pairs
/// `(test vertex, reference vertex)`, whether the triangle turns the same way about the surface
/// normals on both shapes (+1) or the other way (−1), weighted by how far from degenerate both
/// triangles are; in [−1, 1] (0 without a usable triplet), negative for a mirror image. Unlike
/// the spectral orientation descriptors it needs no spectrum of the whole body, so it reads a
/// single view too.
pub(crate) fn matches_orientation(test: &Mesh, reference: &Mesh, pairs: &[(usize, usize)]) -> f64 {
    let (nt, nr) = (vertex_normals(test), vertex_normals(reference));
    // Signed sine of the triangle (a, b, c) about the mean normal at its corners.
    let turn = |mesh: &Mesh, normals: &[[f64; 3]], a: usize, b: usize, c: usize| {
        let p = mesh.vertices[a];
        let (u, v) = (sub(mesh.vertices[b], p), sub(mesh.vertices[c], p));
        let n: [f64; 3] = std::array::from_fn(|d| normals[a][d] + normals[b][d] + normals[c][d]);
        let scale = norm(u) * norm(v) * norm(n);
        if scale > 0.0 {
            dot(cross(u, v), n) / scale
        } else {
            0.0
        }
    };
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..pairs.len() {
        for j in i + 1..pairs.len() {
            for k in j + 1..pairs.len() {
                let st = turn(test, &nt, pairs[i].0, pairs[j].0, pairs[k].0);
                let sr = turn(reference, &nr, pairs[i].1, pairs[j].1, pairs[k].1);
                let w = st.abs().min(sr.abs());
                num += w * (st * sr).signum();
                den += w;
            }
        }
    }
    if den > 0.0 {
        num / den
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::icosphere;

    /// An ellipsoid symmetric about x = 0, and its mirror self-map (nearest vertex of each
    /// vertex's reflection).
    fn ellipsoid_and_mirror() -> (Mesh, Vec<usize>) {
        let mut mesh = icosphere(4, 1.0);
        for v in &mut mesh.vertices {
            v[1] *= 1.3;
            v[2] *= 1.7;
        }
        let mirror = (0..mesh.n_vertices())
            .map(|v| {
                let p = mesh.vertices[v];
                let q = [-p[0], p[1], p[2]];
                (0..mesh.n_vertices())
                    .min_by(|&a, &b| {
                        let d = |u: usize| {
                            let r = mesh.vertices[u];
                            (r[0] - q[0]).powi(2) + (r[1] - q[1]).powi(2) + (r[2] - q[2]).powi(2)
                        };
                        d(a).total_cmp(&d(b))
                    })
                    .unwrap()
            })
            .collect();
        (mesh, mirror)
    }

    #[test]
    fn a_sparse_match_set_on_a_single_view_reads_as_kept_or_mirrored() {
        use crate::mesh::{perturb, Perturbation};
        let fam = crate::synth::creature_family(
            &crate::synth::CreatureParams { target_vertices: 2000, seed: 3, ..Default::default() },
            2,
        )
        .unwrap();
        let (reference, posed) = (&fam.shapes[0], &fam.shapes[1]);
        // A single view of the other pose; ten of its vertices matched to their truth, and to
        // their truth's mirror image.
        let view = perturb(posed, &[Perturbation::PARTIAL_VIEW], 5).unwrap();
        let step = view.kept.len() / 10;
        let picked: Vec<usize> = (0..10).map(|i| i * step).collect();
        let kept: Vec<(usize, usize)> = picked.iter().map(|&v| (v, view.kept[v])).collect();
        let mirrored: Vec<(usize, usize)> = kept.iter().map(|&(v, r)| (v, fam.symmetry[r])).collect();
        let (k, m) = (
            matches_orientation(&view.mesh, reference, &kept),
            matches_orientation(&view.mesh, reference, &mirrored),
        );
        assert!(k > 0.5 && m < -0.5, "kept {k}, mirrored {m}");
        assert_eq!(matches_orientation(&view.mesh, reference, &kept[..2]), 0.0, "no triplet, no reading");
    }

    #[test]
    fn a_mirror_map_reads_as_reversed_and_the_identity_as_kept() {
        let (mesh, mirror) = ellipsoid_and_mirror();
        let identity: Vec<usize> = (0..mesh.n_vertices()).collect();
        let kept = map_orientation(&mesh, &mesh, &identity);
        assert_eq!(kept.score, 1.0);
        assert!(kept.voting_area > 0.99);
        let mirrored = map_orientation(&mesh, &mesh, &mirror);
        assert!(mirrored.score < -0.95, "a mirror image scores {}", mirrored.score);
    }

    #[test]
    fn a_mirrored_half_is_repaired_and_a_whole_mirror_image_too() {
        let (mesh, mirror) = ellipsoid_and_mirror();
        let n = mesh.n_vertices();
        let right =
            |map: &[usize]| map.iter().enumerate().filter(|(v, &r)| *v == r).count() as f64 / n as f64;
        // The upper half (z > 0.3) mapped through the mirror: a "limb" the wrong way round.
        let half: Vec<usize> =
            (0..n).map(|v| if mesh.vertices[v][2] > 0.3 { mirror[v] } else { v }).collect();
        assert!(right(&half) < 0.7);
        let u = unflip(&mesh, &mesh, &half, &mirror, 0.2).expect("the mirrored half is found");
        assert!(u.score_after > u.score_before);
        assert!(right(&u.map) > 0.97, "{:.3} of the vertices right after the repair", right(&u.map));
        // A whole mirror image becomes the identity (up to the mirror's own rounding).
        let whole = unflip(&mesh, &mesh, &mirror, &mirror, 0.2).expect("the mirror image is found");
        assert!(right(&whole.map) > 0.97);
        // An orientation-preserving map is left alone.
        let identity: Vec<usize> = (0..n).collect();
        assert!(unflip(&mesh, &mesh, &identity, &mirror, 0.2).is_none());
    }

    #[test]
    fn reversed_area_is_the_mirrored_share_of_the_surface() {
        let (mesh, mirror) = ellipsoid_and_mirror();
        let n = mesh.n_vertices();
        let identity: Vec<usize> = (0..n).collect();
        assert_eq!(reversed_area(&mesh, &mesh, &identity, 0.2), 0.0);
        assert!(reversed_area(&mesh, &mesh, &mirror, 0.2) > 0.98);
        // The cap z > 0.9 of an ellipsoid with semi-axis 1.7 is a small share of its area.
        let cap: Vec<usize> = (0..n).map(|v| if mesh.vertices[v][2] > 0.9 { mirror[v] } else { v }).collect();
        let share = reversed_area(&mesh, &mesh, &cap, 0.2);
        assert!(share > 0.05 && share < 0.3, "a mirrored cap reads as {share:.3} of the area");
    }

    #[test]
    fn symmetry_from_pairs_refuses_bad_pairs() {
        let (mesh, _) = ellipsoid_and_mirror();
        assert!(symmetry_from_pairs(&mesh, &[]).is_err());
        let n = mesh.n_vertices();
        let err = symmetry_from_pairs(&mesh, &[(0, n)]).unwrap_err().to_string();
        assert!(err.contains("outside"), "{err}");
    }
}
