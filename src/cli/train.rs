//! `shapeforest train`: labelled shapes → a forest model file.

use std::{fs::File, io::BufReader, path::PathBuf, sync::Arc, time::Instant};

use anyhow::{bail, Context, Result};
use clap::Args;
use shapeforest::{
    forest::{
        labels_identity, per_vertex_labels, read_label_map, read_per_label_rows, reference_table,
        ModelReference, RandomForest, TrainingSet, TrainingShape,
    },
    mesh::Mesh,
    regularizer::symmetry_from_pairs,
    synth::{creature_family, CreatureParams},
};

use super::common::{load_mesh, mesh_files, progress, shape_name, spectra};

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// A folder of shapes of one class sharing vertex indexing (e.g. TOSCA's cat0…cat10):
    /// label = vertex index of the reference (the first file, or --reference).
    #[arg(long, conflicts_with_all = ["shapes", "synthetic"])]
    pub class: Option<PathBuf>,
    /// With --class: only files whose name starts with this (e.g. "cat").
    #[arg(long, default_value = "")]
    pub prefix: String,
    /// With --class: at most this many shapes (in name order).
    #[arg(long)]
    pub max_shapes: Option<usize>,
    /// Explicit training shapes, each followed by its label map via --labels (same order).
    #[arg(long = "shape", value_name = "MESH")]
    pub shapes: Vec<PathBuf>,
    /// Label maps for --shape. Per-vertex files hold one label per vertex per line (blank, -1
    /// or "none" = unlabelled); per-label files (`.vts`, as in remeshed TOSCA/FAUST/SCAPE) hold,
    /// on line k, the vertex that carries label k.
    #[arg(long = "labels", value_name = "FILE")]
    pub labels: Vec<PathBuf>,
    /// Labels in per-vertex maps are 1-based; a 0 then means none. (Per-label `.vts` maps are
    /// always read 1-based, the format's convention, unless --zero-based-vts.)
    #[arg(long)]
    pub one_based: bool,
    /// Read per-label (`.vts`) maps as 0-based vertex indices.
    #[arg(long)]
    pub zero_based_vts: bool,
    /// Learn partiality from examples: add --augment-copies seeded perturbed copies of every
    /// training shape per kind: `partial-view`, `holes:N:R` or `crop:R` (repeatable). The
    /// copies are matched as scans are (largest component, the whole shape's area).
    #[arg(long, value_name = "KIND", value_parser = super::eval::parse_augment)]
    pub augment: Vec<shapeforest::mesh::Perturbation>,
    /// Perturbed copies per training shape and --augment kind.
    #[arg(long, default_value_t = 15)]
    pub augment_copies: usize,
    #[command(flatten)]
    pub local: super::common::LocalFlags,
    /// Leave out a shape that cannot be used (unreadable, wrong vertex count, a label map of
    /// the wrong length) with a warning, instead of failing.
    #[arg(long)]
    pub skip_bad: bool,
    /// How label maps are laid out (`auto`: per-label for `.vts` files, per-vertex otherwise).
    #[arg(long, value_enum, default_value_t = LabelLayout::Auto)]
    pub label_layout: LabelLayout,
    /// Size of the label set (default: the largest label + 1 over all maps).
    #[arg(long)]
    pub n_labels: Option<usize>,
    /// Train on the built-in synthetic creature family instead of files.
    #[arg(long)]
    pub synthetic: bool,
    /// With --synthetic: vertices per shape.
    #[arg(long, default_value_t = 5000)]
    pub vertices: usize,
    /// With --synthetic: number of training shapes.
    #[arg(long, default_value_t = 6)]
    pub n_synthetic: usize,
    /// Output model file.
    #[arg(short, long, default_value = "model.sfm")]
    pub out: PathBuf,
    /// Eigenpairs per shape (K).
    #[arg(short, long, default_value_t = 100)]
    pub k: usize,
    /// Number of trees: `auto` (default) 15 where the leaves are pure (complete shapes), 60
    /// where they hold several samples (with --augment copies; README "More trees for views"),
    /// or a number.
    #[arg(long, default_value = "auto", value_name = "N|auto", value_parser = super::eval::parse_trees)]
    pub trees: usize,
    /// Maximum tree depth.
    #[arg(long, default_value_t = 25)]
    pub depth: usize,
    /// Split candidates per node.
    #[arg(long, default_value_t = 20)]
    pub candidates: usize,
    /// Each child of a split keeps at least this many training samples: `auto` (default) an
    /// eighth of the training set's samples per label, at least 1 (pure leaves for six complete
    /// shapes; 3–5 with 15 single-view copies of each, README "Leaves sized by the training
    /// set"), or a number (1: pure leaves).
    #[arg(long, default_value = "auto", value_name = "N|auto", value_parser = super::eval::parse_min_leaf)]
    pub min_leaf: usize,
    /// Random seed (training is deterministic given the seed).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Folder caching spectra between runs (keyed by mesh content and K).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// The training shape (file stem) that `match` maps onto by default; its label → vertex
    /// table is stored in the model (default: the first shape).
    #[arg(long)]
    pub reference: Option<String>,
}

/// Layout of a label-map file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LabelLayout {
    /// Per-label for files ending in `.vts`, per-vertex otherwise.
    Auto,
    /// Line v holds the label of vertex v.
    PerVertex,
    /// Line k holds the vertex carrying label k (`.vts`).
    PerLabel,
}

/// Reads the rows of a per-label (`.vts`-style) map (see [`read_per_label_rows`]).
fn read_per_label(path: &std::path::Path, one_based: bool, n_vertices: usize) -> Result<Vec<Option<u32>>> {
    let file = std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    read_per_label_rows(std::io::BufReader::new(file), one_based, n_vertices)
        .with_context(|| format!("bad label map {}", path.display()))
}

/// Named meshes with their labels (and the per-label rows they came from, if any).
struct Labelled {
    name: String,
    mesh: Mesh,
    labels: Vec<Option<u32>>,
    rows: Option<Vec<Option<u32>>>,
    /// Rows of the `.sym.vts` beside a `.vts` (row `k`: the vertex at the mirror image of row
    /// `k`'s), when there is one.
    mirror_rows: Option<Vec<Option<u32>>>,
}

fn gather(args: &TrainArgs) -> Result<(Vec<Labelled>, usize)> {
    if args.synthetic {
        let fam = creature_family(
            &CreatureParams { target_vertices: args.vertices, seed: args.seed, ..Default::default() },
            args.n_synthetic,
        )?;
        let n = fam.template.n_vertices();
        let shapes = fam
            .shapes
            .into_iter()
            .enumerate()
            .map(|(i, mesh)| Labelled {
                name: format!("creature{i}"),
                mesh,
                labels: labels_identity(n),
                rows: None,
                mirror_rows: None,
            })
            .collect();
        return Ok((shapes, n));
    }
    if let Some(dir) = &args.class {
        let mut files = mesh_files(dir, &args.prefix)?;
        if let Some(m) = args.max_shapes {
            files.truncate(m);
        }
        let mut shapes = Vec::new();
        let mut n_labels = None;
        for path in files {
            let mesh = match load_mesh(&path) {
                Ok(m) => m,
                Err(e) if args.skip_bad => {
                    eprintln!("skipping {}: {e:#}", path.display());
                    continue;
                }
                Err(e) => return Err(e.context("pass --skip-bad to leave unusable shapes out")),
            };
            let n = *n_labels.get_or_insert(mesh.n_vertices());
            if mesh.n_vertices() != n {
                let why = format!(
                    "{}: {} vertices, but the reference has {n}; a class folder needs shared vertex indexing (use --shape/--labels for other shapes)",
                    path.display(),
                    mesh.n_vertices()
                );
                if !args.skip_bad {
                    bail!("{why} (pass --skip-bad to leave it out)");
                }
                eprintln!("skipping {why}");
                continue;
            }
            shapes.push(Labelled {
                name: shape_name(&path),
                mesh,
                labels: labels_identity(n),
                rows: None,
                mirror_rows: None,
            });
        }
        let n = n_labels.context("no readable shapes in the class folder")?;
        return Ok((shapes, n));
    }
    if args.shapes.is_empty() {
        bail!("nothing to train on: give --class DIR, --shape MESH --labels FILE (repeated), or --synthetic");
    }
    if args.shapes.len() != args.labels.len() {
        bail!(
            "{} --shape but {} --labels: give one label map per shape",
            args.shapes.len(),
            args.labels.len()
        );
    }
    let bound = args.n_labels.unwrap_or(u32::MAX as usize);
    let mut shapes = Vec::new();
    for (mesh_path, label_path) in args.shapes.iter().zip(&args.labels) {
        let mesh = load_mesh(mesh_path)?;
        let is_vts =
            label_path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("vts"));
        let per_label = match args.label_layout {
            LabelLayout::Auto => is_vts,
            LabelLayout::PerVertex => false,
            LabelLayout::PerLabel => true,
        };
        let mut mirror_rows = None;
        let (labels, rows) = if per_label {
            let rows = read_per_label(label_path, !args.zero_based_vts, mesh.n_vertices())?;
            // `NAME.sym.vts` beside `NAME.vts`: the mirror image of every row (remeshed TOSCA,
            // FAUST), which gives the reference its left/right symmetry.
            let sym_path = label_path.with_extension("sym.vts");
            if is_vts && sym_path.is_file() {
                let m = read_per_label(&sym_path, !args.zero_based_vts, mesh.n_vertices())?;
                if m.len() != rows.len() {
                    bail!(
                        "{} has {} rows but {} has {}: a .sym.vts lists the mirror of every row",
                        sym_path.display(),
                        m.len(),
                        label_path.display(),
                        rows.len()
                    );
                }
                mirror_rows = Some(m);
            }
            (per_vertex_labels(&rows, mesh.n_vertices()), Some(rows))
        } else {
            let file =
                File::open(label_path).with_context(|| format!("cannot open {}", label_path.display()))?;
            let labels = read_label_map(BufReader::new(file), args.one_based, bound)
                .with_context(|| format!("in label map {}", label_path.display()))?;
            (labels, None)
        };
        shapes.push(Labelled { name: shape_name(mesh_path), mesh, labels, rows, mirror_rows });
    }
    let n = match args.n_labels {
        Some(n) => n,
        None => shapes
            .iter()
            .map(|s| {
                let per_vertex = s.labels.iter().flatten().map(|&l| l as usize + 1).max().unwrap_or(0);
                per_vertex.max(s.rows.as_ref().map_or(0, Vec::len))
            })
            .max()
            .unwrap_or(0),
    };
    Ok((shapes, n))
}

/// Whether every shape's labels are its vertex indices (a `--class` folder, the synthetic family).
fn is_shared_indexing(shapes: &[Labelled], n_labels: usize) -> bool {
    shapes.iter().all(|s| {
        s.rows.is_none()
            && s.mesh.n_vertices() == n_labels
            && s.labels.iter().enumerate().all(|(v, l)| *l == Some(v as u32))
    })
}

/// The reference table stored in the model: the chosen (or first) shape's labels, with labels it
/// lacks placed through the other shapes (see [`reference_table`]).
fn model_reference(shapes: &[Labelled], n_labels: usize, name: Option<&str>) -> Result<ModelReference> {
    let index = match name {
        Some(n) => shapes.iter().position(|s| s.name == n).with_context(|| {
            let names: Vec<&str> = shapes.iter().map(|s| s.name.as_str()).collect();
            format!("--reference {n} is not a training shape (they are: {})", names.join(", "))
        })?,
        None => 0,
    };
    let r = &shapes[index];
    if is_shared_indexing(shapes, n_labels) {
        return Ok(ModelReference::shared_indexing(&r.name, &r.mesh));
    }
    let donors: Vec<(&Mesh, &[Option<u32>])> = shapes
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != index)
        .map(|(_, s)| (&s.mesh, &s.labels[..]))
        .collect();
    let table = reference_table(n_labels, &r.mesh, &r.labels, r.rows.as_deref(), &donors)
        .with_context(|| format!("cannot use {} as the reference", r.name))?;
    if table.filled > 0 || table.unused > 0 {
        eprintln!(
            "reference {}: {} labels on its own vertices, {} placed through other shapes, {} carried by no shape",
            r.name, table.exact, table.filled, table.unused
        );
    }
    let reference = ModelReference::new(&r.name, &r.mesh, &table);
    match (&r.rows, &r.mirror_rows) {
        (Some(rows), Some(mirror)) => {
            let pairs: Vec<(usize, usize)> =
                rows.iter().zip(mirror).filter_map(|(a, b)| Some(((*a)? as usize, (*b)? as usize))).collect();
            let symmetry = symmetry_from_pairs(&r.mesh, &pairs)
                .with_context(|| format!("cannot read the symmetry of {}", r.name))?;
            eprintln!(
                "reference {}: left/right symmetry from its .sym.vts ({} mirror pairs)",
                r.name,
                pairs.len()
            );
            Ok(reference.with_symmetry(&symmetry)?)
        }
        _ => Ok(reference),
    }
}

/// Serve every allocation of 1 MiB or more from its own mapping, returned to the system when
/// freed. glibc's default raises this threshold as large blocks are freed, so the spectra's
/// 40–100 MB work buffers end up on the heap arenas and stay resident after each solve; with
/// it fixed, `train` on 6 × 52K vertices peaks at ~0.78 GB instead of ~0.92 GB (and grows
/// its trees in ~0.4 GB instead of ~0.5 GB), with the same model. Only `train` sets it.
fn release_large_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator tuning; any value is valid for M_MMAP_THRESHOLD
    // up to 32 MiB on 64-bit glibc.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

pub fn run(args: TrainArgs) -> Result<()> {
    release_large_blocks();
    let params = RandomForest::params()
        .n_trees(args.trees)
        .max_depth(args.depth)
        .candidates_per_node(args.candidates)
        .min_samples_leaf(args.min_leaf)
        .seed(args.seed)
        .local_share(args.local.local_share)
        .check()?;
    let local = args.local.params()?;
    let (shapes, n_labels) = gather(&args)?;
    if shapes.is_empty() {
        bail!("no usable training shape");
    }
    let reference = model_reference(&shapes, n_labels, args.reference.as_deref())?;
    let t0 = Instant::now();
    let meshes: Vec<&Mesh> = shapes.iter().map(|s| &s.mesh).collect();
    let spectra = spectra(&meshes, args.k, args.cache.as_deref(), "spectra")?;
    eprintln!("spectra of {} shapes in {:.1} s", shapes.len(), t0.elapsed().as_secs_f64());
    let mut augmented = Vec::new();
    if !args.augment.is_empty() {
        let t0 = Instant::now();
        let cache = match args.cache.as_deref() {
            Some(d) => Some(shapeforest::spectral::SpectrumCache::new(d.to_path_buf())?),
            None => None,
        };
        let sp = shapeforest::spectral::SpectrumParams::new(args.k);
        // Small holes closed as a scan's are when it is matched.
        let kinds: Vec<Vec<shapeforest::mesh::Perturbation>> =
            args.augment.iter().map(|&p| vec![p]).collect();
        let augmentation = shapeforest::forest::Augmentation {
            kinds: &kinds,
            copies: args.augment_copies,
            fill_perimeter: Some(shapeforest::regularizer::ScanPart::FILL_PERIMETER),
            spectrum: &sp,
            cache: cache.as_ref(),
            local: local.as_ref(),
        };
        for (i, s) in shapes.iter().enumerate() {
            let copies = shapeforest::forest::augmented_copies(
                &s.name,
                &s.mesh,
                &s.labels,
                &augmentation,
                args.seed,
                i as u64,
            );
            for copy in copies {
                augmented.push(copy.with_context(|| format!("cannot make a perturbed copy of {}", s.name))?);
            }
        }
        eprintln!("{} perturbed copies in {:.1} s", augmented.len(), t0.elapsed().as_secs_f64());
    }
    let mut training: Vec<TrainingShape> = shapes
        .into_iter()
        .zip(spectra)
        .map(|(s, spectrum)| {
            TrainingShape::new(s.name.clone(), spectrum, s.labels)
                .with_local(&s.mesh, local.as_ref())
                .with_context(|| format!("local histograms of {}", s.name))
        })
        .collect::<Result<_>>()?;
    training.extend(augmented);
    let set = TrainingSet::new(training, n_labels)?;
    for (name, why) in set.rejected() {
        eprintln!("rejected {name}: {why}");
    }
    if !set.rejected().is_empty() && !args.skip_bad {
        bail!(
            "{} of {} training shapes cannot be used (above); fix them, or pass --skip-bad to train without them",
            set.rejected().len(),
            set.rejected().len() + set.shapes().len()
        );
    }
    let t0 = Instant::now();
    let params = params.resolved_for(&set);
    let bar = Arc::new(progress(params.n_trees() as u64, "trees"));
    let b = bar.clone();
    let (n_shapes, n_samples) = (set.shapes().len(), set.n_samples());
    // By value: the training spectra are freed once the trees' descriptor tables are built.
    let forest = params.fit_owned(set, &move |_| b.inc(1))?;
    bar.finish_and_clear();
    let forest = forest.with_reference(reference)?;
    eprintln!(
        "{} trees{} on {} shapes ({} samples, {} labels) in {:.1} s; leaves of at least {} sample(s){}, mean \
         leaf support {:.2}{}",
        forest.n_trees(),
        if args.trees == 0 { " (auto)" } else { "" },
        n_shapes,
        n_samples,
        n_labels,
        t0.elapsed().as_secs_f64(),
        forest.min_samples_leaf(),
        if args.min_leaf == 0 { " (auto)" } else { "" },
        forest.mean_leaf_support(),
        forest.local().map_or(String::new(), |l| format!(
            "; splits on local histograms (radius {}·√area, {} bins)",
            l.radius,
            l.dim()
        ))
    );
    forest.save(&args.out)?;
    let size = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "model written to {} ({:.1} MiB; reference {})",
        args.out.display(),
        size as f64 / (1u64 << 20) as f64,
        forest.reference().map_or("none", |r| r.name.as_str())
    );
    Ok(())
}
