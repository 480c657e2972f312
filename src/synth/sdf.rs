//! Signed distance functions for the synthetic creature: exact round cones (capsules whose
//! radius varies linearly along the axis) joined by a polynomial smooth minimum.
//!
//! Sign convention: negative inside, positive outside, zero on the surface.

use crate::mesh::{dot, sub};

/// A round cone: the convex hull of the sphere of radius `r1` at `a` and the sphere of radius
/// `r2` at `b`. `|r1 - r2|` must be smaller than `|b - a|`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoundCone {
    /// Centre of the first end sphere.
    pub a: [f64; 3],
    /// Centre of the second end sphere.
    pub b: [f64; 3],
    /// Radius at `a`.
    pub r1: f64,
    /// Radius at `b`.
    pub r2: f64,
}

impl RoundCone {
    /// Exact signed distance from `p` to the round cone.
    ///
    /// ```
    /// use shapeforest::synth::sdf::RoundCone;
    /// let c = RoundCone { a: [0.0; 3], b: [0.0, 0.0, 2.0], r1: 0.5, r2: 0.5 };
    /// assert!((c.distance([1.0, 0.0, 1.0]) - 0.5).abs() < 1e-12); // side of the capsule
    /// assert!((c.distance([0.0, 0.0, 3.0]) - 0.5).abs() < 1e-12); // beyond the far cap
    /// assert!((c.distance([0.0, 0.0, 1.0]) + 0.5).abs() < 1e-12); // inside
    /// ```
    pub fn distance(&self, p: [f64; 3]) -> f64 {
        let ba = sub(self.b, self.a);
        let l2 = dot(ba, ba);
        let rr = self.r1 - self.r2;
        let a2 = l2 - rr * rr;
        let il2 = 1.0 / l2;
        let pa = sub(p, self.a);
        let y = dot(pa, ba);
        let z = y - l2;
        let q = [pa[0] * l2 - ba[0] * y, pa[1] * l2 - ba[1] * y, pa[2] * l2 - ba[2] * y];
        let x2 = dot(q, q);
        let y2 = y * y * l2;
        let z2 = z * z * l2;
        let k = sign(rr) * rr * rr * x2;
        if sign(z) * a2 * z2 > k {
            return (x2 + z2).sqrt() * il2 - self.r2;
        }
        if sign(y) * a2 * y2 < k {
            return (x2 + y2).sqrt() * il2 - self.r1;
        }
        ((x2 * a2 * il2).sqrt() + y * rr) * il2 - self.r1
    }
}

/// `sign` as in GLSL: −1, 0 or +1.
#[inline]
fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}

/// Polynomial smooth minimum of `a` and `b` with blend radius `k > 0`: equal to `min(a, b)`
/// when `|a − b| ≥ k`, and smoothly below it otherwise (by at most `k/4`).
///
/// ```
/// use shapeforest::synth::sdf::smooth_min;
/// assert_eq!(smooth_min(0.0, 1.0, 0.1), 0.0);
/// assert!((smooth_min(0.0, 0.0, 0.1) + 0.025).abs() < 1e-15);
/// ```
#[inline]
pub fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}
