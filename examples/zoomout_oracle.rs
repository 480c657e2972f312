//! How precise can a refinement of a pair map be? Starts ZoomOut (and the extrinsic
//! refinement) from the ground-truth map of remeshed pairs and scores what comes out.
//!
//! `cargo run --release --example zoomout_oracle -- DIR K A:B ...` (DIR: a remeshed class folder
//! with `corres/NAME.vts`; K: ZoomOut's final basis): for each pair, the mean error ×100 and the
//! fraction within 0.05 of (1) the true map, each unlabelled vertex taking the image of its
//! nearest labelled vertex, (2) ZoomOut to K from it, (3) the extrinsic refinement after (2).

use std::{path::Path, sync::Arc};

use anyhow::{bail, Context, Result};
use shapeforest::{
    geodesic::{HeatMethodSolver, HeatParams},
    mesh::{extend_map_by_nearest, read_mesh},
    regularizer::{refine_extrinsic, refine_zoomout, ExtrinsicParams, PreparedShape, ZoomOutParams},
    spectral::{spectrum_cached, SpectrumCache, SpectrumParams},
};

fn vts(dir: &Path, name: &str) -> Result<Vec<usize>> {
    let p = dir.join("corres").join(format!("{name}.vts"));
    let t = std::fs::read_to_string(&p).with_context(|| format!("cannot read {}", p.display()))?;
    t.split_whitespace().map(|x| Ok(x.parse::<usize>()? - 1)).collect()
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [dir, k, pairs @ ..] = args.as_slice() else { bail!("usage: zoomout_oracle DIR K A:B ...") };
    let dir = Path::new(dir);
    let k: usize = k.parse()?;
    let cache = SpectrumCache::new(std::path::PathBuf::from("shapeforest-data/cache"))?;
    let prepare = |name: &str| -> Result<(PreparedShape, Vec<usize>)> {
        let mesh = Arc::new(read_mesh(dir.join(format!("{name}.off.gz")))?);
        let s100 = spectrum_cached(&mesh, &SpectrumParams::new(100), Some(&cache))?;
        let sk = spectrum_cached(&mesh, &SpectrumParams { k, ..SpectrumParams::new(100) }, Some(&cache))?;
        let p = PreparedShape::new(mesh, Arc::new(s100), HeatParams::default())?
            .with_zoomout_spectrum(Arc::new(sk))?;
        Ok((p, vts(dir, name)?))
    };
    for pair in pairs {
        let (a, b) = pair.split_once(':').context("pairs are A:B")?;
        let (pa, ta) = prepare(a)?;
        let (pb, tb) = prepare(b)?;
        // True map on the labelled vertices of A, extended by nearest labelled vertex.
        let mut seen = vec![false; pa.mesh.n_vertices()];
        let (mut kept, mut images) = (Vec::new(), Vec::new());
        for (i, &v) in ta.iter().enumerate() {
            if !seen[v] {
                seen[v] = true;
                kept.push(v);
                images.push(tb[i]);
            }
        }
        let truth = extend_map_by_nearest(&pa.mesh, &kept, &images);
        let ks: usize = std::env::var("KSTART").ok().and_then(|x| x.parse().ok()).unwrap_or(20);
        let z = ZoomOutParams { k_final: k, k_start: ks, ..ZoomOutParams::default() };
        let zoomed = refine_zoomout(&pa, &pb, &truth, &z)?.unwrap_or_else(|| truth.clone());
        let w: f64 = std::env::var("EXT_W").ok().and_then(|x| x.parse().ok()).unwrap_or(1.0);
        let r: usize = std::env::var("EXT_R").ok().and_then(|x| x.parse().ok()).unwrap_or(3);
        let e = ExtrinsicParams { deformation_k: k, weight: w, rounds: r, ..Default::default() };
        let ext = refine_extrinsic(&pa, &pb, &zoomed, &e)?;
        let ext_t = refine_extrinsic(&pa, &pb, &truth, &e)?;
        let heat = HeatMethodSolver::new(&pb.mesh, HeatParams::default())?;
        let norm = 1.0 / pb.mesh.surface_area().sqrt();
        let fields = heat.distances_from_many(&tb)?;
        let score = |map: &[usize]| {
            let e: Vec<f64> = (0..ta.len()).map(|i| fields[(map[ta[i]], i)] * norm).collect();
            let mean = e.iter().sum::<f64>() / e.len() as f64;
            (100.0 * mean, 100.0 * e.iter().filter(|&&x| x <= 0.05).count() as f64 / e.len() as f64)
        };
        if let Ok(d) = std::env::var("DUMP") {
            let mut out = String::from("k,truth,zoomout,extrinsic,extrinsic_truth\n");
            for i in 0..ta.len() {
                let e = |m: &[usize]| fields[(m[ta[i]], i)] * norm;
                out += &format!("{i},{:.5},{:.5},{:.5},{:.5}\n", e(&truth), e(&zoomed), e(&ext), e(&ext_t));
            }
            std::fs::write(format!("{d}/{a}_{b}.csv"), out)?;
        }
        let (t, zo, ex, et) = (score(&truth), score(&zoomed), score(&ext), score(&ext_t));
        println!(
            "{a} → {b}: truth {:.2} / {:.1} %, ZoomOut to {k} {:.2} / {:.1} %, + extrinsic {:.2} / {:.1} %, extrinsic from truth {:.2} / {:.1} %",
            t.0, t.1, zo.0, zo.1, ex.0, ex.1, et.0, et.1
        );
    }
    Ok(())
}
