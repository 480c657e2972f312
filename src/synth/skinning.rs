//! Skeleton, skinning weights and posing of the synthetic creature (linear blend skinning).
//!
//! Every bone owns one round cone of the body. A vertex's weight for bone `b` is
//! `exp(−(d_b − d_min)/τ)` normalised, where `d_b` is the signed distance to bone `b`'s cone,
//! so weights change smoothly across joints (over a zone of a few `τ`); only the four largest
//! weights are kept.
//!
//! A bone `b` with parent `q` and joint `j_b` (a point at the end of `q`) maps a rest point `p`
//! to `W_b(p) = W_q(j_b) + R_b·S_b·(p − j_b)`, where `R_b = R_q·(local rotation of b)` is the
//! accumulated joint rotation and `S_b` a local shape map: `α_b` along the bone axis and `ρ_b`
//! across it (both 1 for a pure pose; ≠ 1 for the non-isometric variant: longer neck, fatter
//! legs). The posed vertex is `Σ_b w_b W_b(p)`.

use super::sdf::RoundCone;

type Mat3 = [[f64; 3]; 3];

const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn mat_vec(a: &Mat3, v: [f64; 3]) -> [f64; 3] {
    [
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    ]
}

/// Rotation `Rx(θx)·Ry(θy)·Rz(θz)` (right-handed, radians).
pub(crate) fn rotation_xyz(t: [f64; 3]) -> Mat3 {
    let (sx, cx) = t[0].sin_cos();
    let (sy, cy) = t[1].sin_cos();
    let (sz, cz) = t[2].sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]];
    let ry = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
    let rz = [[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]];
    mat_mul(&mat_mul(&rx, &ry), &rz)
}

/// One bone of the skeleton.
#[derive(Clone, Debug)]
pub(crate) struct Bone {
    pub name: &'static str,
    /// Index of the parent bone; `None` for the root.
    pub parent: Option<usize>,
    /// Rest-pose joint (rotation centre).
    pub joint: [f64; 3],
    /// The body part this bone moves.
    pub cone: RoundCone,
    /// Largest joint angles about x, y, z (radians) at pose amplitude 1.
    pub limits: [f64; 3],
    /// Index of the mirror-image bone (itself for bones on the mid-plane).
    pub mirror: usize,
}

impl Bone {
    fn axis(&self) -> [f64; 3] {
        let d = crate::mesh::sub(self.cone.b, self.cone.a);
        let l = crate::mesh::norm(d);
        [d[0] / l, d[1] / l, d[2] / l]
    }
}

/// Skinning weights of a mesh: up to four `(bone, weight)` pairs per vertex, weights summing
/// to one.
#[derive(Clone, Debug)]
pub(crate) struct SkinWeights {
    pub weights: Vec<[(u16, f64); 4]>,
}

/// Computes smooth skinning weights (see the module documentation) with blend length `tau`.
pub(crate) fn skin_weights(bones: &[Bone], vertices: &[[f64; 3]], tau: f64) -> SkinWeights {
    use rayon::prelude::*;
    let weights = vertices
        .par_iter()
        .map(|&p| {
            let mut d: Vec<(f64, u16)> =
                bones.iter().enumerate().map(|(b, bone)| (bone.cone.distance(p), b as u16)).collect();
            d.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
            let d_min = d[0].0;
            let mut w = [(0u16, 0.0f64); 4];
            let mut total = 0.0;
            for (slot, &(db, b)) in d.iter().take(4).enumerate() {
                let x = (-(db - d_min) / tau).exp();
                w[slot] = (b, x);
                total += x;
            }
            for slot in w.iter_mut() {
                slot.1 /= total;
            }
            w
        })
        .collect();
    SkinWeights { weights }
}

/// Joint rotations and per-bone shape factors of one deformation.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Deformation {
    /// Local rotation angles (x, y, z) of each bone; the root's is ignored.
    pub angles: Vec<[f64; 3]>,
    /// Scale along each bone's axis.
    pub axial: Vec<f64>,
    /// Scale across each bone's axis.
    pub radial: Vec<f64>,
}

/// Applies `deformation` to the rest-pose `vertices` by linear blend skinning. Bones must be
/// listed parents first.
pub(crate) fn deform(
    bones: &[Bone],
    skin: &SkinWeights,
    vertices: &[[f64; 3]],
    deformation: &Deformation,
) -> Vec<[f64; 3]> {
    use rayon::prelude::*;
    let n = bones.len();
    // Affine maps W_b(p) = R_b S_b p + t_b, assembled parents first.
    let mut rot: Vec<Mat3> = vec![IDENTITY; n];
    let mut lin: Vec<Mat3> = vec![IDENTITY; n];
    let mut trans: Vec<[f64; 3]> = vec![[0.0; 3]; n];
    for (b, bone) in bones.iter().enumerate() {
        let d = bone.axis();
        let (alpha, rho) = (deformation.axial[b], deformation.radial[b]);
        let mut s = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                let along = d[i] * d[j];
                s[i][j] = alpha * along + rho * ((i == j) as u8 as f64 - along);
            }
        }
        let (r, anchor) = match bone.parent {
            None => (IDENTITY, bone.joint),
            Some(q) => {
                let r = mat_mul(&rot[q], &rotation_xyz(deformation.angles[b]));
                let jq = mat_vec(&lin[q], bone.joint);
                (r, [jq[0] + trans[q][0], jq[1] + trans[q][1], jq[2] + trans[q][2]])
            }
        };
        let l = mat_mul(&r, &s);
        let lj = mat_vec(&l, bone.joint);
        rot[b] = r;
        lin[b] = l;
        trans[b] = [anchor[0] - lj[0], anchor[1] - lj[1], anchor[2] - lj[2]];
    }
    vertices
        .par_iter()
        .zip(skin.weights.par_iter())
        .map(|(&p, w)| {
            let mut q = [0.0; 3];
            for &(b, wb) in w {
                if wb == 0.0 {
                    continue;
                }
                let b = b as usize;
                let x = mat_vec(&lin[b], p);
                for d in 0..3 {
                    q[d] += wb * (x[d] + trans[b][d]);
                }
            }
            q
        })
        .collect()
}
