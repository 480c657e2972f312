//! Orientation-sensitive descriptors (after Ren, Poulenard, Guibas, Ovsjanikov, "Continuous and
//! orientation-preserving correspondences via functional maps", 2018).
//!
//! Intrinsic descriptors (WKS, HKS) are blind to left/right: a mirror symmetry `S` of a body
//! leaves them unchanged, `f ∘ S = f`. The scalar triple product of two descriptor gradients
//! with the surface normal, `h = ⟨n, ∇f × ∇g⟩`, changes sign under an orientation-reversing
//! map (a mirror image) and is kept by an orientation-preserving one. Its vector over several
//! descriptor pairs is therefore a correspondence-free cue that tells a match from its mirror
//! image, provided both meshes are consistently oriented (outward normals, as scanned bodies
//! and the synthetic families are).
//!
//! Conventions: functions are piecewise linear on faces; per-face values are averaged to
//! vertices with face-area weights; the mesh is taken at unit area (the result is scale-free).

use faer::{Mat, MatRef};

use super::wks_filter_sq;
use crate::{
    mesh::{cross, dot, sub, Mesh},
    spectral::Spectrum,
};

/// Log-energies of `count` band-pass functions spread over the low part of a spectrum (its
/// first ~30 nonzero eigenvalues), where the functions are smooth enough for stable gradients:
/// the inputs of [`orientation_descriptors`]. Choose them on one shape (a reference) and use
/// them on both shapes of a pair, so that the two sets of functions correspond.
///
/// ```
/// use shapeforest::{descriptor::orientation_band_energies, spectral::{compute_spectrum, SpectrumParams}, synth::icosphere};
/// let s = compute_spectrum(&icosphere(2, 1.0), &SpectrumParams::new(40)).unwrap();
/// let e = orientation_band_energies(&s, 5);
/// assert_eq!(e.len(), 5);
/// assert!(e.windows(2).all(|w| w[0] < w[1]));
/// ```
pub fn orientation_band_energies(spectrum: &Spectrum, count: usize) -> Vec<f64> {
    let lam = &spectrum.eigenvalues;
    let first = lam.iter().position(|&l| l > 1e-9 * lam.last().copied().unwrap_or(1.0)).unwrap_or(0);
    let last = (first + 30).min(lam.len().saturating_sub(1));
    let (lo, hi) = (lam[first].max(1e-12).ln(), lam[last].max(1e-12).ln());
    (0..count).map(|i| lo + (hi - lo) * (i as f64 + 0.5) / count as f64).collect()
}

/// Band-pass (WKS-like) functions `Σ_k f_e(λ_k)² φ_k²` of a spectrum at the given log-energies
/// (the filter width is their spacing), each normalised by its filter's total weight: an
/// `n × energies.len()` matrix of smooth, intrinsic functions.
///
/// ```
/// use shapeforest::{descriptor::{band_pass_functions, orientation_band_energies}, spectral::{compute_spectrum, SpectrumParams}, synth::icosphere};
/// let s = compute_spectrum(&icosphere(2, 1.0), &SpectrumParams::new(40)).unwrap();
/// let f = band_pass_functions(&s, &orientation_band_energies(&s, 5));
/// assert_eq!((f.nrows(), f.ncols()), (s.n_vertices, 5));
/// assert!((0..f.nrows()).all(|v| f[(v, 0)] >= 0.0));
/// ```
pub fn band_pass_functions(spectrum: &Spectrum, energies: &[f64]) -> Mat<f64> {
    let sigma = if energies.len() > 1 {
        ((energies[energies.len() - 1] - energies[0]) / (energies.len() - 1) as f64).max(1e-6)
    } else {
        1.0
    };
    let n = spectrum.n_vertices;
    let mut f = Mat::zeros(n, energies.len());
    for (c, &e) in energies.iter().enumerate() {
        let w: Vec<f64> = spectrum
            .eigenvalues
            .iter()
            .map(|&l| if l > 0.0 { wks_filter_sq(e, l, sigma) } else { 0.0 })
            .collect();
        let norm: f64 = w.iter().sum::<f64>().max(f64::MIN_POSITIVE);
        for (k, &wk) in w.iter().enumerate() {
            if wk > 1e-12 * norm {
                let phi = spectrum.phi(k);
                for v in 0..n {
                    f[(v, c)] += wk / norm * phi[v] * phi[v];
                }
            }
        }
    }
    f
}

/// Per-vertex orientation descriptors: for every pair `(i, j)`, `i < j`, of the columns of
/// `functions` (`n × q`), the area-weighted vertex average of `⟨n, ∇f_i × ∇f_j⟩`. Returns a
/// row-major `n × q(q−1)/2` array. Columns are divided by their root mean square so that all
/// pairs weigh alike.
///
/// ```
/// use shapeforest::descriptor::orientation_descriptors;
/// use shapeforest::synth::grid_plane;
/// let plane = grid_plane(5, 5, 1.0, 1.0);
/// // f = x, g = y on the plane z = 0 (normal +z): ∇f × ∇g = +z everywhere.
/// let f = faer::Mat::from_fn(25, 2, |v, j| plane.vertices[v][j]);
/// let h = orientation_descriptors(&plane, f.as_ref());
/// assert!(h.iter().all(|&x| (x - 1.0).abs() < 1e-9));
/// // Mirroring the plane (x → −x, faces reversed to keep the normal) flips the sign.
/// ```
pub fn orientation_descriptors(mesh: &Mesh, functions: MatRef<'_, f64>) -> Vec<f64> {
    let n = mesh.n_vertices();
    let q = functions.ncols();
    let pairs: Vec<(usize, usize)> = (0..q).flat_map(|i| (i + 1..q).map(move |j| (i, j))).collect();
    let np = pairs.len();
    let mut out = vec![0.0; n * np];
    if np == 0 || functions.nrows() != n {
        return out;
    }
    let mut weight = vec![0.0; n];
    let scale = 1.0 / mesh.surface_area().max(f64::MIN_POSITIVE).sqrt();
    let mut grads = vec![[0.0; 3]; q];
    for f in &mesh.faces {
        let p: Vec<[f64; 3]> = f.iter().map(|&v| mesh.vertices[v].map(|c| c * scale)).collect();
        let normal = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let twice_area = dot(normal, normal).sqrt();
        if twice_area <= 0.0 || !twice_area.is_finite() {
            continue;
        }
        let nrm = normal.map(|c| c / twice_area);
        // ∇f = Σ_v f_v (n × e_v) / (2A), e_v the edge opposite v, counter-clockwise.
        let e = [sub(p[2], p[1]), sub(p[0], p[2]), sub(p[1], p[0])];
        let rot: Vec<[f64; 3]> = e.iter().map(|&ev| cross(nrm, ev).map(|c| c / twice_area)).collect();
        for (c, g) in grads.iter_mut().enumerate() {
            *g = [0.0; 3];
            for k in 0..3 {
                let fv = functions[(f[k], c)];
                for d in 0..3 {
                    g[d] += fv * rot[k][d];
                }
            }
        }
        let area = 0.5 * twice_area;
        for &v in f {
            weight[v] += area;
        }
        for (k, &(i, j)) in pairs.iter().enumerate() {
            let h = dot(nrm, cross(grads[i], grads[j])) * area;
            for &v in f {
                out[v * np + k] += h;
            }
        }
    }
    for v in 0..n {
        if weight[v] > 0.0 {
            for k in 0..np {
                out[v * np + k] /= weight[v];
            }
        }
    }
    for k in 0..np {
        let rms = ((0..n).map(|v| out[v * np + k].powi(2)).sum::<f64>() / n as f64).sqrt();
        if rms > 0.0 {
            for v in 0..n {
                out[v * np + k] /= rms;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::grid_plane;

    #[test]
    fn mirror_image_flips_the_sign() {
        let plane = grid_plane(7, 5, 2.0, 1.0);
        let f = |p: [f64; 3]| [p[0] * p[0] + p[1], (p[0] * 3.0).sin() + p[1] * p[1]];
        let fa = faer::Mat::from_fn(plane.n_vertices(), 2, |v, j| f(plane.vertices[v])[j]);
        let h = orientation_descriptors(&plane, fa.as_ref());
        // Mirror x → −x and reverse the faces so the normal still points up; same functions
        // evaluated at the pre-image (f ∘ S).
        let mirrored = Mesh {
            vertices: plane.vertices.iter().map(|p| [-p[0], p[1], p[2]]).collect(),
            faces: plane.faces.iter().map(|f| [f[0], f[2], f[1]]).collect(),
            face_multiplicity: Vec::new(),
        };
        let hm = orientation_descriptors(&mirrored, fa.as_ref());
        for v in 0..plane.n_vertices() {
            assert!((h[v] + hm[v]).abs() < 1e-9 * (1.0 + h[v].abs()), "vertex {v}: {} vs {}", h[v], hm[v]);
        }
    }
}
