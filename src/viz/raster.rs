//! A small software rasteriser: both meshes of a pair side by side, a fixed camera,
//! per-vertex colours interpolated over each triangle, Lambert shading (two-sided), a z-buffer,
//! 2× supersampling. Written here rather than taken from a crate because the renderers in Rust
//! need a GPU or a window; this is ~150 lines and runs anywhere.

use super::{ViewPair, VizError};
use crate::mesh::Mesh;

/// An RGB image, rows top to bottom, 3 bytes per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width · height · 3` bytes.
    pub rgb: Vec<u8>,
}

impl Image {
    /// The pixel at `(x, y)`.
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }
}

/// Settings of a snapshot.
#[derive(Clone, Debug, PartialEq)]
pub struct SnapshotParams {
    /// Image width (both panels), default 800.
    pub width: usize,
    /// Image height, default 400.
    pub height: usize,
    /// Background colour, default light grey.
    pub background: [u8; 3],
    /// Camera azimuth about the y axis, degrees (default 25).
    pub azimuth_deg: f64,
    /// Camera elevation, degrees (default 15).
    pub elevation_deg: f64,
}

impl Default for SnapshotParams {
    fn default() -> Self {
        Self { width: 800, height: 400, background: [246, 246, 246], azimuth_deg: 25.0, elevation_deg: 15.0 }
    }
}

impl SnapshotParams {
    fn check(&self) -> Result<(), VizError> {
        if !(16..=8192).contains(&self.width) || !(16..=8192).contains(&self.height) {
            return Err(VizError::InvalidParameter {
                name: "width/height",
                reason: format!("must be in 16..=8192, got {}×{}", self.width, self.height),
            });
        }
        Ok(())
    }

    /// World → camera rotation: the viewer looks along −z of the camera frame, y up.
    fn rotation(&self) -> [[f64; 3]; 3] {
        let (a, e) = (self.azimuth_deg.to_radians(), self.elevation_deg.to_radians());
        let (ca, sa, ce, se) = (a.cos(), a.sin(), e.cos(), e.sin());
        // Rotate about y by −a, then about x by e.
        [[ca, 0.0, -sa], [se * sa, ce, se * ca], [ce * sa, -se, ce * ca]]
    }
}

const SUPERSAMPLE: usize = 2;

/// One panel: rasterise `mesh` into the region `x0..x0 + w` of the buffers.
#[allow(clippy::too_many_arguments)]
fn draw_mesh(
    mesh: &Mesh,
    colors: &[[u8; 3]],
    rot: &[[f64; 3]; 3],
    x0: usize,
    w: usize,
    h: usize,
    stride: usize,
    color: &mut [f32],
    depth: &mut [f64],
) {
    let cam: Vec<[f64; 3]> = mesh
        .vertices
        .iter()
        .map(|p| {
            let mut q = [0.0; 3];
            for (r, out) in rot.iter().zip(q.iter_mut()) {
                *out = r[0] * p[0] + r[1] * p[1] + r[2] * p[2];
            }
            q
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in &cam {
        for a in 0..2 {
            lo[a] = lo[a].min(q[a]);
            hi[a] = hi[a].max(q[a]);
        }
    }
    let ext = [(hi[0] - lo[0]).max(1e-12), (hi[1] - lo[1]).max(1e-12)];
    let scale = (0.9 * w as f64 / ext[0]).min(0.9 * h as f64 / ext[1]);
    let (mx, my) = ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0);
    let screen: Vec<[f64; 3]> = cam
        .iter()
        .map(|q| {
            [x0 as f64 + w as f64 / 2.0 + scale * (q[0] - mx), h as f64 / 2.0 - scale * (q[1] - my), q[2]]
        })
        .collect();
    let light = {
        let l: [f64; 3] = [0.35, 0.55, 1.0];
        let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        [l[0] / n, l[1] / n, l[2] / n]
    };
    for tri in &mesh.faces {
        let [a, b, c] = tri.map(|i| screen[i]);
        let [ca, cb, cc] = tri.map(|i| cam[i]);
        let u = [cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]];
        let v = [cc[0] - ca[0], cc[1] - ca[1], cc[2] - ca[2]];
        let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len == 0.0 {
            continue;
        }
        let shade = (0.3 + 0.7 * ((n[0] * light[0] + n[1] * light[1] + n[2] * light[2]) / len).abs()) as f32;
        let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        if area.abs() < 1e-12 {
            continue;
        }
        let xs = (a[0].min(b[0]).min(c[0]).floor().max(x0 as f64) as usize, a[0].max(b[0]).max(c[0]).ceil());
        let ys = (a[1].min(b[1]).min(c[1]).floor().max(0.0) as usize, a[1].max(b[1]).max(c[1]).ceil());
        let x_end = (xs.1.max(0.0) as usize).min(x0 + w - 1);
        let y_end = (ys.1.max(0.0) as usize).min(h - 1);
        let col = tri.map(|i| colors[i].map(f32::from));
        for y in ys.0..=y_end {
            let py = y as f64 + 0.5;
            for x in xs.0..=x_end {
                let px = x as f64 + 0.5;
                let w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) / area;
                let w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a[2] + w1 * b[2] + w2 * c[2];
                let k = y * stride + x;
                if z <= depth[k] {
                    continue;
                }
                depth[k] = z;
                let (w0, w1, w2) = (w0 as f32, w1 as f32, w2 as f32);
                for ch in 0..3 {
                    color[3 * k + ch] = shade * (w0 * col[0][ch] + w1 * col[1][ch] + w2 * col[2][ch]);
                }
            }
        }
    }
}

/// Renders the pair: the scan coloured through the map on the left, the reference coloured by
/// its coordinates on the right, each fitted to its half. `scan_colors` overrides the scan's
/// colours (e.g. an error heat map), one per scan vertex.
///
/// ```
/// use shapeforest::{synth::icosphere, viz::{render_snapshot, SnapshotParams, ViewPair}};
/// let s = icosphere(2, 1.0);
/// let map: Vec<usize> = (0..s.n_vertices()).collect();
/// let pair = ViewPair::new(&s, "a", &s, "b", &map);
/// let img = render_snapshot(&pair, None, &SnapshotParams::default()).unwrap();
/// assert_eq!((img.width, img.height), (800, 400));
/// assert_ne!(img.pixel(200, 200), [246, 246, 246]); // the scan is drawn in the left half
/// ```
pub fn render_snapshot(
    pair: &ViewPair<'_>,
    scan_colors: Option<&[[u8; 3]]>,
    params: &SnapshotParams,
) -> Result<Image, VizError> {
    pair.check()?;
    params.check()?;
    let (ref_colors, mapped) = pair.map_colors();
    let scan_colors = match scan_colors {
        Some(c) if c.len() != pair.scan.n_vertices() => {
            return Err(VizError::SizeMismatch(format!(
                "{} colours for a scan of {} vertices",
                c.len(),
                pair.scan.n_vertices()
            )))
        }
        Some(c) => c,
        None => &mapped,
    };
    let (w, h) = (params.width * SUPERSAMPLE, params.height * SUPERSAMPLE);
    let bg = params.background.map(f32::from);
    let mut color: Vec<f32> = bg.iter().copied().cycle().take(w * h * 3).collect();
    let mut depth = vec![f64::NEG_INFINITY; w * h];
    let rot = params.rotation();
    let half = w / 2;
    draw_mesh(pair.scan, scan_colors, &rot, 0, half, h, w, &mut color, &mut depth);
    draw_mesh(pair.reference, &ref_colors, &rot, half, w - half, h, w, &mut color, &mut depth);
    let mut rgb = Vec::with_capacity(params.width * params.height * 3);
    let norm = 1.0 / (SUPERSAMPLE * SUPERSAMPLE) as f32;
    for y in 0..params.height {
        for x in 0..params.width {
            for ch in 0..3 {
                let mut s = 0.0;
                for dy in 0..SUPERSAMPLE {
                    for dx in 0..SUPERSAMPLE {
                        s += color[3 * ((y * SUPERSAMPLE + dy) * w + x * SUPERSAMPLE + dx) + ch];
                    }
                }
                rgb.push((s * norm).round().clamp(0.0, 255.0) as u8);
            }
        }
    }
    Ok(Image { width: params.width, height: params.height, rgb })
}

/// [`render_snapshot`] encoded as a PNG file's bytes.
pub fn snapshot_png(
    pair: &ViewPair<'_>,
    scan_colors: Option<&[[u8; 3]]>,
    params: &SnapshotParams,
) -> Result<Vec<u8>, VizError> {
    let img = render_snapshot(pair, scan_colors, params)?;
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, img.width as u32, img.height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(|e| VizError::Png(e.to_string()))?;
        writer.write_image_data(&img.rgb).map_err(|e| VizError::Png(e.to_string()))?;
        writer.finish().map_err(|e| VizError::Png(e.to_string()))?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::{icosphere, torus};

    #[test]
    fn both_panels_are_drawn_with_the_mapped_colours_and_shading() {
        let s = icosphere(3, 1.0);
        let t = torus(40, 20, 1.0, 0.3);
        // Every torus vertex mapped to the sphere's north-most vertex: the scan is one colour.
        let top = (0..s.n_vertices()).max_by(|&a, &b| s.vertices[a][1].total_cmp(&s.vertices[b][1])).unwrap();
        let map = vec![top; t.n_vertices()];
        let pair = ViewPair::new(&t, "t", &s, "s", &map);
        let p = SnapshotParams::default();
        let img = render_snapshot(&pair, None, &p).unwrap();
        let drawn = |x0: usize, x1: usize| {
            (0..img.height)
                .flat_map(|y| (x0..x1).map(move |x| (x, y)))
                .filter(|&(x, y)| img.pixel(x, y) != p.background)
                .count()
        };
        let (left, right) = (drawn(0, 400), drawn(400, 800));
        assert!(left > 20_000 && right > 40_000, "drawn pixels: {left} left, {right} right");
        // The scan's pixels are shades of one colour: the same hue, different brightness.
        let (ref_colors, _) = pair.map_colors();
        let c = ref_colors[top].map(f64::from);
        let mut shades = Vec::new();
        for y in 0..img.height {
            for x in 0..400 {
                let q = img.pixel(x, y);
                if q != p.background && (0..400).contains(&x) {
                    let q = q.map(f64::from);
                    let f = (q[0] + q[1] + q[2]) / (c[0] + c[1] + c[2]);
                    shades.push(f);
                }
            }
        }
        let (lo, hi) = shades.iter().fold((f64::MAX, 0.0f64), |(a, b), &f| (a.min(f), b.max(f)));
        assert!(hi - lo > 0.3, "shading varies: {lo}..{hi}");
        let png = snapshot_png(&pair, None, &p).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn bad_sizes_are_errors() {
        let s = icosphere(1, 1.0);
        let map = vec![0; 3];
        let pair = ViewPair::new(&s, "a", &s, "b", &map);
        let e = render_snapshot(&pair, None, &SnapshotParams::default()).unwrap_err().to_string();
        assert!(e.contains("the map has 3 entries but the scan `a` has 42 vertices"), "{e}");
        let map: Vec<usize> = (0..42).collect();
        let pair = ViewPair { map: &map, ..pair };
        let p = SnapshotParams { width: 0, ..Default::default() };
        assert!(render_snapshot(&pair, None, &p).unwrap_err().to_string().contains("width"));
    }
}
