//! `shapeforest predict`: a model and a mesh → per-vertex labels and top-k candidates.

use std::{
    io::{BufWriter, Write},
    path::PathBuf,
    time::Instant,
};

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use shapeforest::forest::RandomForest;

use super::common::{load_mesh, spectra};

#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Format {
    /// One line per vertex: `vertex map_label label:prob …` (top-k), `-` for no label.
    Text,
    /// MessagePack: `{ n_labels, map: [label|null], top_k: [[[label, prob], …], …] }`.
    Msgpack,
}

#[derive(Debug, Args)]
pub struct PredictArgs {
    /// Model file written by `shapeforest train`.
    #[arg(short, long)]
    pub model: PathBuf,
    /// The mesh to label.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Candidates listed per vertex.
    #[arg(long, default_value_t = 5)]
    pub top_k: usize,
    /// Output file (default: standard output).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,
    /// Folder caching spectra between runs.
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

#[derive(serde::Serialize)]
struct Packed {
    n_labels: usize,
    map: Vec<Option<u32>>,
    top_k: Vec<Vec<(u32, f32)>>,
}

pub fn run(args: PredictArgs) -> Result<()> {
    let forest = RandomForest::load(&args.model)?;
    let mesh = load_mesh(&args.mesh)?;
    let t0 = Instant::now();
    let spectrum = spectra(&[&mesh], forest.k(), args.cache.as_deref(), "spectrum")?.remove(0);
    let t_spec = t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let prediction = forest.predict_mesh(&mesh, &spectrum)?;
    eprintln!(
        "{}: {} vertices; spectrum {:.2} s, prediction {:.2} s, mean support {:.1}",
        args.mesh.display(),
        mesh.n_vertices(),
        t_spec,
        t0.elapsed().as_secs_f64(),
        prediction.mean_support()
    );
    // A vertex no face uses has no surface around it: its spectrum values say nothing about
    // where it is, so it gets no label rather than a confident-looking one.
    let mut referenced = vec![false; mesh.n_vertices()];
    for f in &mesh.faces {
        for &v in f {
            referenced[v] = true;
        }
    }
    let unreferenced = referenced.iter().filter(|r| !**r).count();
    if unreferenced > 0 {
        eprintln!("{unreferenced} vertices are in no face: they get no label (`-`)");
    }
    let mut map = prediction.map_labels();
    for (v, l) in map.iter_mut().enumerate() {
        if !referenced[v] {
            *l = None;
        }
    }
    let top_k = |v: usize| if referenced[v] { prediction.top_k(v, args.top_k) } else { Vec::new() };
    let mut out: Box<dyn Write> = match &args.out {
        Some(p) => Box::new(BufWriter::new(
            std::fs::File::create(p).with_context(|| format!("cannot create {}", p.display()))?,
        )),
        None => Box::new(BufWriter::new(std::io::stdout().lock())),
    };
    match args.format {
        Format::Text => {
            writeln!(out, "# vertex map_label top-{} label:probability", args.top_k)?;
            for (v, label) in map.iter().enumerate() {
                match label {
                    Some(l) => write!(out, "{v} {l}")?,
                    None => write!(out, "{v} -")?,
                }
                for (l, p) in top_k(v) {
                    write!(out, " {l}:{p:.4}")?;
                }
                writeln!(out)?;
            }
        }
        Format::Msgpack => {
            let packed =
                Packed { n_labels: prediction.n_labels(), top_k: (0..map.len()).map(top_k).collect(), map };
            let bytes = rmp_serde::to_vec_named(&packed).context("encoding the prediction")?;
            out.write_all(&bytes)?;
        }
    }
    out.flush()?;
    Ok(())
}
