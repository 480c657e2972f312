//! A synthetic four-legged creature and families of its deformations with known ground truth.
//!
//! # The template
//! The body is a smooth union (polynomial smooth minimum, blend radius 0.12) of thirteen round
//! cones: torso, neck, head, two tail segments, and an upper and a lower segment for each of
//! four legs ([`PART_NAMES`]). Its zero set is polygonised by mirror-symmetric surface nets and
//! relaxed (Delaunay flips, tangential smoothing with projection back onto the surface), giving
//! a closed, connected, consistently oriented (outward normals, counter-clockwise faces) genus-0
//! triangle mesh with about `target_vertices` vertices.
//!
//! # Coordinates and symmetry
//! `x` points to the creature's right, `y` up and `z` forward (the head is at `+z`); the body is
//! about 3.8 units long, 2.2 tall and 1.0 wide, with the soles near `y = −1.26`. The template is
//! exactly mirror-symmetric about the plane `x = 0`: `symmetry[i]` is the vertex at the mirror
//! image of vertex `i` (bit-exact: `x` negated, `y` and `z` equal), `symmetry` is an involution,
//! and its fixed points are the vertices lying on the plane.
//!
//! # Deformations
//! Shapes are deformed by linear blend skinning of a 13-bone skeleton, one bone per part, each
//! rotating about a joint at the start of its part (hips and shoulders inside the torso, knees,
//! neck base, head, tail base and middle). Skinning weights are `exp(−(d_b − d_min)/τ)`,
//! normalised, with `d_b` the distance to part `b`'s round cone and `τ = 0.1`, so they blend
//! smoothly across joints. Every non-root joint turns by random angles up to
//! `pose_amplitude` times a per-joint limit (knees 0.5 rad, hips 0.35 rad, neck 0.35–0.4 rad,
//! tail 0.4–0.5 rad), which keeps the shapes near-isometric and free of gross self-intersections. With
//! `non_isometric = s > 0` each bone is also scaled by random factors in `[e^{−s}, e^{s}]`
//! along its axis (longer or shorter neck, legs, tail) and across it (fatter or thinner parts);
//! left and right bones share their factors. Vertex order never changes: vertex `i` of every
//! shape corresponds to vertex `i` of the template.
//!
//! # Determinism
//! The template depends only on `target_vertices`. Shape `k` of a family depends only on the
//! seed, `k` and the amplitudes (a `ChaCha8Rng` seeded with `seed` on stream `k`), not on how
//! many shapes are asked for.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::isosurface::polygonise_symmetric;
use super::sdf::{smooth_min, RoundCone};
use super::skinning::{deform, skin_weights, Bone, Deformation, SkinWeights};
use super::SynthError;
use crate::mesh::Mesh;

/// Names of the creature's parts (= skeleton bones), indexed as in [`Creature::vertex_part`].
pub const PART_NAMES: [&str; 13] = [
    "torso",
    "neck",
    "head",
    "tail_base",
    "tail_tip",
    "front_right_upper_leg",
    "front_right_lower_leg",
    "front_left_upper_leg",
    "front_left_lower_leg",
    "hind_right_upper_leg",
    "hind_right_lower_leg",
    "hind_left_upper_leg",
    "hind_left_lower_leg",
];

/// Smallest accepted `target_vertices`: below it the thin parts (tail tip, lower legs) are
/// thinner than the sampling grid.
pub const MIN_TARGET_VERTICES: usize = 800;
/// Largest accepted `target_vertices` (the sampling grid grows as `target^{3/2}`: about 30 M
/// samples, 0.4 GB, at this size).
pub const MAX_TARGET_VERTICES: usize = 200_000;

/// Blend radius of the smooth union of the body parts.
const BLEND: f64 = 0.12;
/// Relaxation rounds (each: one flip sweep and three smoothing steps). More rounds do not
/// help: on coarse meshes they let the projection pinch vertices together at thin tips.
const RELAX_ROUNDS: usize = 6;
/// Skinning blend length.
const SKIN_TAU: f64 = 0.1;

/// Parameters of a creature family.
#[derive(Clone, Debug, PartialEq)]
pub struct CreatureParams {
    /// Approximate number of template vertices (the result is within a few percent);
    /// between [`MIN_TARGET_VERTICES`] and [`MAX_TARGET_VERTICES`].
    pub target_vertices: usize,
    /// Seed of the random poses and shape factors.
    pub seed: u64,
    /// Scale of the random joint angles: 0 gives the rest pose, 1 (default) the nominal joint
    /// limits; at most 2.
    pub pose_amplitude: f64,
    /// Strength `s` of the random per-bone scaling (factors in `[e^{−s}, e^{s}]`); 0 (default)
    /// keeps the shapes near-isometric; at most 1.
    pub non_isometric: f64,
}

impl Default for CreatureParams {
    fn default() -> Self {
        Self { target_vertices: 5000, seed: 0, pose_amplitude: 1.0, non_isometric: 0.0 }
    }
}

impl CreatureParams {
    /// Checks every parameter, naming the first one out of range.
    ///
    /// ```
    /// use shapeforest::synth::CreatureParams;
    /// assert!(CreatureParams::default().check().is_ok());
    /// let bad = CreatureParams { pose_amplitude: -1.0, ..Default::default() };
    /// assert!(bad.check().unwrap_err().to_string().contains("pose_amplitude"));
    /// ```
    pub fn check(&self) -> Result<(), SynthError> {
        if !(MIN_TARGET_VERTICES..=MAX_TARGET_VERTICES).contains(&self.target_vertices) {
            return Err(SynthError::InvalidParameter {
                name: "target_vertices",
                value: self.target_vertices.to_string(),
                expected: "an integer in 800..=200000",
            });
        }
        if !(self.pose_amplitude.is_finite() && (0.0..=2.0).contains(&self.pose_amplitude)) {
            return Err(SynthError::InvalidParameter {
                name: "pose_amplitude",
                value: self.pose_amplitude.to_string(),
                expected: "a number in [0, 2]",
            });
        }
        if !(self.non_isometric.is_finite() && (0.0..=1.0).contains(&self.non_isometric)) {
            return Err(SynthError::InvalidParameter {
                name: "non_isometric",
                value: self.non_isometric.to_string(),
                expected: "a number in [0, 1]",
            });
        }
        Ok(())
    }
}

/// The rest-pose creature: mesh, mirror symmetry, part labels and the skinning rig.
#[derive(Clone, Debug)]
pub struct Creature {
    /// The template mesh (rest pose).
    pub mesh: Mesh,
    /// `symmetry[i]` is the vertex at the mirror image (about `x = 0`) of vertex `i`.
    pub symmetry: Vec<usize>,
    /// The part (index into [`PART_NAMES`]) with the largest skinning weight at each vertex.
    pub vertex_part: Vec<usize>,
    bones: Vec<Bone>,
    skin: SkinWeights,
}

/// A family of shapes sharing the template's vertex indexing.
#[derive(Clone, Debug)]
pub struct ShapeFamily {
    /// The rest-pose template.
    pub template: Mesh,
    /// The shapes; `shapes[0]` is the template itself, the others are random deformations.
    pub shapes: Vec<Mesh>,
    /// Mirror symmetry of the template (approximately that of isometric poses too).
    pub symmetry: Vec<usize>,
    /// Part label of each vertex (index into [`PART_NAMES`]).
    pub vertex_part: Vec<usize>,
}

/// The skeleton, parents before children; each bone owns one round cone of the body.
fn skeleton() -> Vec<Bone> {
    let cone = |a: [f64; 3], r1: f64, b: [f64; 3], r2: f64| RoundCone { a, b, r1, r2 };
    let mut bones = vec![
        Bone {
            name: PART_NAMES[0],
            parent: None,
            joint: [0.0, 0.0, 0.0],
            cone: cone([0.0, 0.0, -0.7], 0.40, [0.0, 0.03, 0.7], 0.44),
            limits: [0.0; 3],
            mirror: 0,
        },
        Bone {
            name: PART_NAMES[1],
            parent: Some(0),
            joint: [0.0, 0.15, 0.85],
            cone: cone([0.0, 0.15, 0.85], 0.24, [0.0, 0.62, 1.25], 0.19),
            limits: [0.35, 0.4, 0.1],
            mirror: 1,
        },
        Bone {
            name: PART_NAMES[2],
            parent: Some(1),
            joint: [0.0, 0.62, 1.25],
            cone: cone([0.0, 0.70, 1.28], 0.27, [0.0, 0.60, 1.65], 0.15),
            limits: [0.3, 0.35, 0.15],
            mirror: 2,
        },
        Bone {
            name: PART_NAMES[3],
            parent: Some(0),
            joint: [0.0, 0.1, -0.9],
            cone: cone([0.0, 0.1, -0.9], 0.15, [0.0, 0.32, -1.4], 0.13),
            limits: [0.4, 0.5, 0.0],
            mirror: 3,
        },
        Bone {
            name: PART_NAMES[4],
            parent: Some(3),
            joint: [0.0, 0.32, -1.4],
            cone: cone([0.0, 0.32, -1.4], 0.13, [0.0, 0.38, -1.9], 0.115),
            limits: [0.5, 0.5, 0.0],
            mirror: 4,
        },
    ];
    // Legs: (upper joint, knee, foot, radii), right side; left side mirrored.
    let legs = [
        ([0.30, -0.12, 0.60], [0.32, -0.62, 0.66], [0.32, -1.12, 0.62], 0.19),
        ([0.30, -0.10, -0.55], [0.32, -0.60, -0.64], [0.32, -1.12, -0.56], 0.20),
    ];
    for (l, &(hip, knee, foot, r_top)) in legs.iter().enumerate() {
        for side in [1.0, -1.0] {
            let m = |p: [f64; 3]| [side * p[0], p[1], p[2]];
            let upper = bones.len();
            // Names: 5.. front right upper/lower, front left upper/lower, hind right, hind left.
            let mirror_upper = if side > 0.0 { upper + 2 } else { upper - 2 };
            bones.push(Bone {
                name: PART_NAMES[upper],
                parent: Some(0),
                joint: m(hip),
                cone: cone(m(hip), r_top, m(knee), 0.16),
                limits: [0.35, 0.08, 0.1],
                mirror: mirror_upper,
            });
            bones.push(Bone {
                name: PART_NAMES[upper + 1],
                parent: Some(upper),
                joint: m(knee),
                cone: cone(m(knee), 0.16, m(foot), 0.14),
                limits: [0.5, 0.0, 0.06],
                mirror: mirror_upper + 1,
            });
        }
        debug_assert!(l < 2);
    }
    bones
}

/// The creature's signed distance function (negative inside), on the right half `x ≥ 0`
/// (the polygoniser folds `x`): a smooth union of the mid-plane and right-side cones, each with
/// a bounding sphere so that cones too far to change the union are skipped.
struct BodySdf {
    /// `(cone, bounding-sphere centre, bounding-sphere radius)`, torso first.
    cones: Vec<(RoundCone, [f64; 3], f64)>,
}

impl BodySdf {
    fn new(bones: &[Bone]) -> Self {
        let cones = bones
            .iter()
            .enumerate()
            .filter(|(b, bone)| bone.mirror >= *b)
            .map(|(_, bone)| {
                let c = bone.cone;
                let centre = [0.5 * (c.a[0] + c.b[0]), 0.5 * (c.a[1] + c.b[1]), 0.5 * (c.a[2] + c.b[2])];
                let radius = 0.5 * crate::mesh::norm(crate::mesh::sub(c.b, c.a)) + c.r1.max(c.r2);
                (c, centre, radius)
            })
            .collect();
        Self { cones }
    }

    fn distance(&self, p: [f64; 3]) -> f64 {
        let mut acc = f64::INFINITY;
        for (cone, centre, radius) in &self.cones {
            // Lower bound of the cone's distance: if it exceeds acc + BLEND the smooth minimum
            // is unchanged.
            let lower = crate::mesh::norm(crate::mesh::sub(p, *centre)) - radius;
            if lower >= acc + BLEND {
                continue;
            }
            let d = cone.distance(p);
            acc = if acc.is_finite() { smooth_min(acc, d, BLEND) } else { d };
        }
        acc
    }
}

/// Builds the rest-pose creature template with about `params.target_vertices` vertices.
///
/// ```
/// use shapeforest::synth::{creature_template, CreatureParams};
/// let c = creature_template(&CreatureParams { target_vertices: 1000, ..Default::default() }).unwrap();
/// let n = c.mesh.n_vertices();
/// assert!((750..=1250).contains(&n));
/// assert!((0..n).all(|i| c.symmetry[c.symmetry[i]] == i));
/// ```
pub fn creature_template(params: &CreatureParams) -> Result<Creature, SynthError> {
    params.check()?;
    let bones = skeleton();
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for bone in &bones {
        for (c, r) in [(bone.cone.a, bone.cone.r1), (bone.cone.b, bone.cone.r2)] {
            for d in 0..3 {
                lo[d] = lo[d].min(c[d] - r - BLEND);
                hi[d] = hi[d].max(c[d] + r + BLEND);
            }
        }
    }
    let body = BodySdf::new(&bones);
    let sdf = |p: [f64; 3]| body.distance(p);
    let surface = polygonise_symmetric(&sdf, lo, hi, params.target_vertices, RELAX_ROUNDS)?;
    let skin = skin_weights(&bones, &surface.vertices, SKIN_TAU);
    let vertex_part = skin.weights.iter().map(|w| w[0].0 as usize).collect();
    let mesh = Mesh::new(surface.vertices, surface.faces)?;
    Ok(Creature { mesh, symmetry: surface.symmetry, vertex_part, bones, skin })
}

impl Creature {
    /// Number of parts (= skeleton bones).
    pub fn n_parts(&self) -> usize {
        self.bones.len()
    }

    /// Name of part `part` (see [`PART_NAMES`]).
    pub fn part_name(&self, part: usize) -> Option<&'static str> {
        self.bones.get(part).map(|b| b.name)
    }

    /// The `index`-th random deformation for `seed`: joint angles scaled by `pose_amplitude`
    /// and, when `non_isometric > 0`, per-bone axial and radial scale factors in
    /// `[e^{−s}, e^{s}]`. Same arguments give bit-identical meshes.
    pub fn random_shape(
        &self,
        seed: u64,
        index: u64,
        pose_amplitude: f64,
        non_isometric: f64,
    ) -> Result<Mesh, SynthError> {
        let check =
            CreatureParams { target_vertices: MIN_TARGET_VERTICES, seed, pose_amplitude, non_isometric };
        check.check()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(index);
        let n = self.bones.len();
        let mut angles = vec![[0.0; 3]; n];
        for (b, bone) in self.bones.iter().enumerate() {
            for (angle, limit) in angles[b].iter_mut().zip(bone.limits) {
                let u: f64 = rng.random_range(-1.0..=1.0);
                *angle = pose_amplitude * limit * u;
            }
        }
        let mut axial = vec![1.0; n];
        let mut radial = vec![1.0; n];
        for (b, bone) in self.bones.iter().enumerate() {
            let u: f64 = rng.random_range(-1.0..=1.0);
            let v: f64 = rng.random_range(-1.0..=1.0);
            if bone.mirror >= b {
                axial[b] = (non_isometric * u).exp();
                radial[b] = (non_isometric * v).exp();
                axial[bone.mirror] = axial[b];
                radial[bone.mirror] = radial[b];
            }
        }
        let deformation = Deformation { angles, axial, radial };
        let vertices = deform(&self.bones, &self.skin, &self.mesh.vertices, &deformation);
        Ok(Mesh::new(vertices, self.mesh.faces.clone())?)
    }
}

/// A family of `n_shapes` shapes sharing one template's vertex indexing: shape 0 is the rest
/// pose, shapes `1..n_shapes` random deformations (see [`Creature::random_shape`]).
///
/// ```
/// use shapeforest::synth::{creature_family, CreatureParams};
/// let fam = creature_family(&CreatureParams { target_vertices: 1000, ..Default::default() }, 3).unwrap();
/// assert_eq!(fam.shapes.len(), 3);
/// assert_eq!(fam.shapes[0], fam.template);
/// assert_eq!(fam.shapes[2].faces, fam.template.faces);
/// ```
pub fn creature_family(params: &CreatureParams, n_shapes: usize) -> Result<ShapeFamily, SynthError> {
    if n_shapes == 0 {
        return Err(SynthError::InvalidParameter {
            name: "n_shapes",
            value: "0".to_string(),
            expected: "at least 1",
        });
    }
    let creature = creature_template(params)?;
    let mut shapes = Vec::with_capacity(n_shapes);
    shapes.push(creature.mesh.clone());
    for k in 1..n_shapes {
        shapes.push(creature.random_shape(
            params.seed,
            k as u64,
            params.pose_amplitude,
            params.non_isometric,
        )?);
    }
    Ok(ShapeFamily {
        template: creature.mesh,
        shapes,
        symmetry: creature.symmetry,
        vertex_part: creature.vertex_part,
    })
}
