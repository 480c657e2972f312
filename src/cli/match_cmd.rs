//! `shapeforest match`: dense correspondence of one mesh to a reference with a trained model,
//! or (with `--to`) between two scans through the label space.
//!
//! Forest prediction, then the regulariser against the reference. Labels are read through a
//! label → reference-vertex table: the one the model file stores for its reference (any
//! labelled training shape can be the reference; for a shared-indexing class any shape of the
//! class), or, for another reference mesh, the one built from its label map
//! (`--reference-labels`). A reference the model cannot place its labels on is refused, never
//! matched silently. With `--to B`, `B` is mapped onto the reference, and the scan onto `B`
//! through that map ([`shapeforest::regularizer::regularize_pair`]). Writes into `--out`:
//! - `SCAN.map.txt`: a header comment, then line `i` = the reference vertex (0-based) matched to
//!   scan vertex `i` (with `--to B`: `SCAN.to.B.map.txt`, line `i` = the vertex of `B`);
//! - `REF.colored.ply` and `SCAN.colored.ply`: the reference coloured by a smooth function of
//!   its coordinates, and the scan coloured through the map (matching parts share colours);
//! - `SCAN.report.json`: timings, number of sparse matches, orientation score, mean forest
//!   confidence (with `--to` and the refinement on, those of the scan's map onto the
//!   reference, whose composition with `B`'s starts the pair map: `quality_of` says which).

use std::{
    fmt::Write as _,
    path::{Path, PathBuf},
    sync::Arc,
    time::Instant,
};

use anyhow::{bail, Context, Result};
use clap::Args;
use rayon::prelude::*;
use shapeforest::{
    eval::protocol::DOUBT_VOTES,
    forest::{
        per_vertex_labels, read_label_map, read_per_label_rows, reference_table, Prediction, RandomForest,
    },
    mesh::{coordinate_colors, read_mesh, write_colored_ply, Mesh},
    regularizer::{
        poses_by_nearness, regularize, regularize_pair, reversed_area, through_labels, view_orientation,
        DenseMap, PairParams, PreparedShape, RegularizerParams, ScanPart, UNFLIP_THRESHOLD,
    },
    spectral::{spectrum_cached, Spectrum, SpectrumCache, SpectrumParams},
};

/// Arguments of `shapeforest match`.
#[derive(Debug, Args)]
pub struct MatchArgs {
    /// Model file written by `shapeforest train` (`RandomForest::save`).
    #[arg(long)]
    pub model: PathBuf,
    /// Reference mesh: the model's reference (`train` names it; a wrong one is refused with its
    /// name), any shape of a shared-indexing class, or another mesh with `--reference-labels`.
    #[arg(long)]
    pub reference: PathBuf,
    /// Label map of the reference, when it is not the model's own reference: `.vts` (line k =
    /// the 1-based vertex of label k) or per vertex (line v = the 0-based label of vertex v).
    #[arg(long, value_name = "FILE")]
    pub reference_labels: Option<PathBuf>,
    /// Map the scan to this other scan instead of the reference (through the label space).
    #[arg(long, value_name = "MESH")]
    pub to: Option<PathBuf>,
    /// Mesh to match.
    #[arg(long)]
    pub mesh: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "shapeforest-match")]
    pub out: PathBuf,
    /// Spectrum cache folder (none by default).
    #[arg(long)]
    pub cache: Option<PathBuf>,
    /// Refine the regularised map by ZoomOut (see README, "ZoomOut refinement"); on by default
    /// with --to.
    #[arg(long, conflicts_with = "no_zoomout")]
    pub zoomout: bool,
    /// No ZoomOut refinement, also with --to.
    #[arg(long)]
    pub no_zoomout: bool,
    /// Final basis size of the ZoomOut refinement (which starts at 100, at most half of it,
    /// then runs the extrinsic step and the choice by the posterior; README, "ZoomOut
    /// refinement"). More than the model's eigenpairs (100) computes every shape's spectrum
    /// again with this many for ZoomOut alone, at the cost of those spectra (FAUST pairs: 1.54
    /// mean error ×100 with the default 200; 1.80 with the refinement of before, 20 → 100).
    #[arg(long, default_value_t = 200, value_name = "K")]
    pub zoomout_k: usize,
    /// With the ZoomOut refinement: how far (× √area) its last, settling round may move an
    /// image, after the choice and after a relay's or a vote's map reaches the reference
    /// (`regularizer::settle_map`; README, "Settling"; 0: no settling round).
    #[arg(long, default_value_t = shapeforest::regularizer::SETTLE_REACH, value_name = "R", value_parser = super::eval::parse_reach)]
    pub settle_reach: f64,
    /// With the ZoomOut refinement: its last step re-places each image by the rigid fit of the
    /// images of its neighbours within this radius (× √area; `regularizer::local_rigid`;
    /// README, "Local rigid fit"; 0: off).
    #[arg(long, default_value_t = shapeforest::regularizer::LocalRigidParams::default().radius, value_name = "R", value_parser = super::eval::parse_reach)]
    pub rigid_radius: f64,
    /// A labelled training shape in another pose, with its label map (as --reference-labels);
    /// repeatable. The scan is regularised onto the one among them and the reference whose pose
    /// is nearest its own, and the map carried back to the reference through the labels
    /// (`regularizer::nearest_pose`; README, "Relays").
    #[arg(long, num_args = 2, value_names = ["MESH", "LABELS"], conflicts_with = "to")]
    pub relay: Vec<PathBuf>,
    /// With --relay: regularise onto this many of the nearest poses (the reference among the
    /// candidates) and vote per vertex among the maps carried to the reference
    /// (`regularizer::vote_maps`; README, "Relays"). Each vote costs a spectrum and a
    /// regularisation.
    #[arg(long, default_value_t = 1, value_name = "N", requires = "relay")]
    pub relay_votes: usize,
    /// With --relay and one vote: a map that reads as mirrored on more than this fraction of the
    /// scan's area (a mirrored limb; the report's `reversed_area`) is voted with the maps onto
    /// the next two nearest poses (0: never).
    #[arg(long, default_value_t = shapeforest::eval::protocol::DOUBT_REVERSED_AREA, value_name = "F", value_parser = super::eval::parse_share)]
    pub doubt_votes: f64,
    /// With --relay and one vote, on a single view: a map whose orientation score reads below
    /// this (the report's `view_orientation`) is doubted: the view is regularised onto the next
    /// nearest poses too, one after another until a map reads at least this (two at most), and
    /// the best oriented map kept (the report's `tried_poses`; README
    /// "Doubted views"; 0: never).
    #[arg(long, default_value_t = shapeforest::eval::protocol::DOUBT_VIEW_ORIENTATION, value_name = "S", value_parser = super::eval::parse_share)]
    pub doubt_view: f64,
}

/// A training shape the scan may be regularised onto instead of the reference.
struct Relay {
    path: PathBuf,
    mesh: Arc<Mesh>,
    /// Label → vertex of `mesh`.
    table: Vec<usize>,
}

/// A shape the scan is regularised onto (the reference or a relay): prepared, its label →
/// vertex table (`None`: labels are vertices) and its vertex map to the reference (`None`: it is
/// the reference).
struct OntoShape<'a> {
    prepared: PreparedShape,
    table: Option<&'a [usize]>,
    to_reference: Option<Vec<usize>>,
}

/// Fixes the signature of the closure that prepares a shape to regularise onto (a closure's
/// own annotation cannot tie the relay's lifetime to the result's).
fn onto_preparation<'a, F>(f: F) -> F
where
    F: Fn(Option<&'a Relay>) -> Result<(OntoShape<'a>, f64, f64)>,
{
    f
}

fn stem(p: &Path) -> String {
    shapeforest::pipeline::shape_stem(p)
}

/// The label → vertex table of `mesh` (read from `mesh_path`) from its label map at `path`:
/// `.vts` per-label rows, or one label per vertex; every one of the model's labels must be
/// placed.
fn table_from_labels(
    path: &Path,
    mesh: &Mesh,
    mesh_path: &Path,
    forest: &RandomForest,
) -> Result<Vec<usize>> {
    let n_labels = forest.n_labels();
    let file = std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let reader = std::io::BufReader::new(file);
    let is_vts = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("vts"));
    let (labels, rows) = if is_vts {
        let rows = read_per_label_rows(reader, true, mesh.n_vertices())
            .with_context(|| format!("bad label map {}", path.display()))?;
        (per_vertex_labels(&rows, mesh.n_vertices()), Some(rows))
    } else {
        let labels = read_label_map(reader, false, n_labels)
            .with_context(|| format!("bad label map {}", path.display()))?;
        if labels.len() != mesh.n_vertices() {
            bail!(
                "{} has {} lines but the mesh {} has {} vertices (one label per vertex expected)",
                path.display(),
                labels.len(),
                mesh_path.display(),
                mesh.n_vertices()
            );
        }
        (labels, None)
    };
    let t = reference_table(n_labels, mesh, &labels, rows.as_deref(), &[])
        .with_context(|| format!("{} cannot place the model's labels", path.display()))?;
    if t.unused > 0 {
        bail!(
            "the labels {} place {} of the model's {} labels; the other {} are not on {}, so points \
             predicted with them would be matched wrongly: use a shape that carries every label{}",
            path.display(),
            t.exact,
            n_labels,
            t.unused,
            mesh_path.display(),
            forest
                .reference()
                .map_or(String::new(), |r| format!(", or the model's own reference `{}`", r.name))
        );
    }
    Ok(t.table)
}

/// The label → reference-vertex table for `reference` (`None`: labels are its vertex indices).
fn label_table(args: &MatchArgs, forest: &RandomForest, reference: &Mesh) -> Result<Option<Vec<usize>>> {
    let n_labels = forest.n_labels();
    if let Some(path) = &args.reference_labels {
        return table_from_labels(path, reference, &args.reference, forest).map(Some);
    }
    match forest.reference() {
        Some(r) => r.table_for(reference).map(Some).with_context(|| {
            format!(
                "the model {} maps onto its reference `{}` ({} vertices), and {} ({} vertices) is another \
                 mesh: pass that reference, or this mesh's label map with --reference-labels",
                args.model.display(),
                r.name,
                r.n_vertices,
                args.reference.display(),
                reference.n_vertices()
            )
        }),
        None if n_labels == reference.n_vertices() => Ok(None),
        None => bail!(
            "the model {} has {} labels but the reference {} has {} vertices, and the model stores no \
             reference table (it predates format version 2): give the reference's label map with \
             --reference-labels, or use a shape whose vertex indices are the model's labels",
            args.model.display(),
            n_labels,
            args.reference.display(),
            reference.n_vertices()
        ),
    }
}

/// The `votes` shapes in the poses nearest the scan's (`part`), nearest first: a relay, or
/// `None` for the reference; and the reference's label table.
fn relays_by_nearness<'a>(
    part: &Mesh,
    prediction: &Prediction,
    reference: &Mesh,
    table: Option<&[usize]>,
    relays: &'a [Relay],
) -> Result<(Vec<Option<&'a Relay>>, Vec<usize>)> {
    let ref_table: Vec<usize> =
        table.map_or_else(|| (0..reference.n_vertices()).collect(), <[usize]>::to_vec);
    if relays.is_empty() {
        return Ok((vec![None], ref_table));
    }
    let mut candidates: Vec<(&Mesh, &[usize])> = vec![(reference, &ref_table)];
    candidates.extend(relays.iter().map(|r| (&*r.mesh, r.table.as_slice())));
    let ranked = poses_by_nearness(part, prediction, &candidates)?;
    let chosen = ranked.into_iter().map(|c| c.checked_sub(1).map(|i| &relays[i])).collect();
    Ok((chosen, ref_table))
}

fn spectrum(
    mesh: &Mesh,
    params: &SpectrumParams,
    cache: Option<&SpectrumCache>,
    path: &Path,
) -> Result<Spectrum> {
    spectrum_cached(mesh, params, cache)
        .with_context(|| format!("cannot compute the spectrum of {}", path.display()))
}

fn write_colored(path: &Path, mesh: &Mesh, colors: &[[u8; 3]]) -> Result<()> {
    write_colored_ply(path, mesh, colors).with_context(|| format!("cannot write {}", path.display()))
}

/// `match` is one short-lived process: it keeps what it frees for its own later allocations.
/// By default glibc serves large blocks from mappings of their own, unmapped when freed, and
/// trims the heap, so each stage's buffers are fresh pages again, each zeroed by the kernel on
/// first touch (on this VM ~2.4 µs a page): a 60K-vertex match took ~570K page faults. With
/// every block on the heap and no trimming: ~273K (the first touches of its 1.1 GB peak);
/// three alternated pairs under `perf stat`: 12.0 / 10.7 / 11.0 → 10.2 / 10.6 / 10.3 CPU-s,
/// 7.5 / 6.8 / 7.0 → 6.4 / 6.6 / 6.4 s, the same map; peak RSS 1.08 → 1.10 GB. The daemon, which must give memory back between scans, keeps
/// its own settings (`run::long_running_allocator`).
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator tuning; 0 mappings, a trim threshold of
    // i32::MAX and a 64 MiB top pad are valid values.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_TOP_PAD, 64 << 20);
    }
}

/// Runs `shapeforest match`.
pub fn run(args: MatchArgs) -> Result<()> {
    keep_freed_memory();
    let t_all = Instant::now();
    let t0 = Instant::now();
    if !args.model.is_file() {
        bail!("model file {} does not exist", args.model.display());
    }
    let forest = RandomForest::load(&args.model)
        .with_context(|| format!("cannot load the model {}", args.model.display()))?;
    let reference = read_mesh(&args.reference)
        .with_context(|| format!("cannot read mesh {}", args.reference.display()))?;
    let scan = read_mesh(&args.mesh).with_context(|| format!("cannot read mesh {}", args.mesh.display()))?;
    let target = match &args.to {
        Some(p) => Some(read_mesh(p).with_context(|| format!("cannot read mesh {}", p.display()))?),
        None => None,
    };
    let table = label_table(&args, &forest, &reference)?;
    let relays = args
        .relay
        .chunks(2)
        .map(|pair| {
            let [mesh_path, labels] = pair else { bail!("--relay takes a mesh and its label map") };
            let mesh =
                read_mesh(mesh_path).with_context(|| format!("cannot read mesh {}", mesh_path.display()))?;
            let table = table_from_labels(labels, &mesh, mesh_path, &forest)?;
            Ok(Relay { path: mesh_path.clone(), mesh: Arc::new(mesh), table })
        })
        .collect::<Result<Vec<_>>>()?;
    let load_s = t0.elapsed().as_secs_f64();
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let cache = match &args.cache {
        Some(d) => {
            Some(SpectrumCache::new(d.clone()).with_context(|| format!("cannot use cache {}", d.display()))?)
        }
        None => None,
    };
    let reg = RegularizerParams {
        zoomout: (args.zoomout || (args.to.is_some() && !args.no_zoomout)).then(|| {
            shapeforest::regularizer::ZoomOutParams {
                k_final: args.zoomout_k,
                settle: (args.settle_reach > 0.0).then_some(args.settle_reach),
                rigid: super::eval::rigid_params(args.rigid_radius),
                ..Default::default()
            }
        }),
        ..Default::default()
    };
    let k = forest.k().max(reg.fmap.k_test).max(reg.fmap.k_ref);
    let sp_params = SpectrumParams::new(k);
    // ZoomOut beyond the descriptors' eigenpairs: larger spectra for ZoomOut alone.
    let zoomout_params = reg.zoomout.filter(|z| z.k_final > k).map(|z| SpectrumParams::new(z.k_final));
    // A scan in pieces is matched on its largest component, an open partial scan normalised by
    // the reference's area (`ScanPart`); without --to only.
    let scan = Arc::new(scan);
    let part = if args.to.is_none() {
        ScanPart::of(&scan)
    } else {
        ScanPart { mesh: scan.clone(), kept: None, components: 1 }
    };
    if let Some(kept) = &part.kept {
        tracing::warn!(
            "{}: {} connected components; matching the largest ({} of {} vertices), the other pieces take \
             the match of their nearest matched vertex",
            args.mesh.display(),
            part.components,
            kept.len(),
            scan.n_vertices()
        );
    }
    // As in `eval`: small holes closed for the spectrum, read back on the part's vertices.
    let ref_area = reference.surface_area();
    let spectrum_mesh = match args.to {
        None => part.spectrum_mesh(ref_area).0,
        Some(_) => part.mesh.clone(),
    };
    // One eigensolve per shape: with ZoomOut's larger basis, the descriptors' K eigenpairs are
    // its leading ones.
    let solve = |mesh: &Mesh, path: &Path| -> Result<(Spectrum, Option<Spectrum>)> {
        match &zoomout_params {
            Some(zp) => {
                let large = spectrum(mesh, zp, cache.as_ref(), path)?;
                Ok((large.leading(k), Some(large)))
            }
            None => Ok((spectrum(mesh, &sp_params, cache.as_ref(), path)?, None)),
        }
    };
    let t0 = Instant::now();
    let (scan_spectrum, scan_zoomout) = solve(&spectrum_mesh, &args.mesh)?;
    let spectrum_scan_s = t0.elapsed().as_secs_f64();
    let (scan_spectrum, scale_ratio) = if args.to.is_none() {
        let (sp, r) = part.spectrum_for_matching(&spectrum_mesh, scan_spectrum, ref_area);
        (Arc::new(sp), r)
    } else {
        (Arc::new(scan_spectrum), 1.0)
    };

    let t0 = Instant::now();
    let prediction = forest.predict_mesh(&part.mesh, &scan_spectrum).context("forest prediction failed")?;
    let predict_s = t0.elapsed().as_secs_f64();
    let reference = Arc::new(reference);
    // The shapes the scan is regularised onto: the relay in the nearest pose, or the reference
    // (whose spectrum is then the only one solved besides the scan's), and with --relay-votes
    // the next nearest.
    let (ranked, ref_table) =
        relays_by_nearness(&part.mesh, &prediction, &reference, table.as_deref(), &relays)?;
    let mut ontos: Vec<Option<&Relay>> = ranked.iter().take(args.relay_votes.max(1)).copied().collect();
    // The reference's left/right symmetry, when the model stores it (trained with `.sym.vts`),
    // lets the regulariser repair mirrored maps; a relay gets it through the labels.
    let symmetry = forest.reference().filter(|r| r.is_mesh(&reference)).and_then(|r| r.symmetry_map());
    let has_symmetry = symmetry.is_some();
    let t0 = Instant::now();
    let mut test = PreparedShape::new(part.mesh.clone(), scan_spectrum, reg.heat)?;
    if let Some(sp) = scan_zoomout {
        let sp =
            if args.to.is_none() { part.spectrum_for_matching(&spectrum_mesh, sp, ref_area).0 } else { sp };
        test = test.with_zoomout_spectrum(Arc::new(sp))?;
    }
    let mut prepare_s = t0.elapsed().as_secs_f64();
    let mut spectrum_ref_s = 0.0;
    // A shape to regularise onto, prepared (its spectra and ZoomOut basis), and the seconds of
    // its spectra and of the preparation.
    let prepare_onto = |mesh: Arc<Mesh>, path: &Path| -> Result<(PreparedShape, f64, f64)> {
        let t0 = Instant::now();
        let (spectrum, zoomout) = solve(&mesh, path)?;
        let spectrum_s = t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let mut prepared = PreparedShape::new(mesh, Arc::new(spectrum), reg.heat)?;
        if let Some(z) = zoomout {
            prepared = prepared.with_zoomout_spectrum(Arc::new(z))?;
        }
        Ok((prepared, spectrum_s, t0.elapsed().as_secs_f64()))
    };
    // A shape to regularise onto (a relay, or the reference itself) prepared, with its label
    // table and its vertex map to the reference; the seconds of its spectra and preparation.
    let prepare_onto_shape = onto_preparation(|onto| {
        let t0 = Instant::now();
        let (onto_mesh, onto_path, onto_symmetry, to_reference) = match onto {
            None => (reference.clone(), args.reference.as_path(), symmetry.clone(), None),
            Some(relay) => {
                let to_reference = through_labels(&relay.mesh, &relay.table, &reference, &ref_table)?;
                let relay_symmetry = match &symmetry {
                    Some(sym) => {
                        let from_reference =
                            through_labels(&reference, &ref_table, &relay.mesh, &relay.table)?;
                        Some(to_reference.iter().map(|&r| from_reference[sym[r]]).collect())
                    }
                    None => None,
                };
                (relay.mesh.clone(), relay.path.as_path(), relay_symmetry, Some(to_reference))
            }
        };
        // The label maps count with the shape's spectrum.
        let labels_s = t0.elapsed().as_secs_f64();
        let (mut prepared, spectrum_s, preparation_s) = prepare_onto(onto_mesh, onto_path)?;
        let t0 = Instant::now();
        if let Some(s) = onto_symmetry {
            prepared = prepared.with_symmetry(s.into())?;
        }
        let onto_table = match onto {
            Some(relay) => Some(relay.table.as_slice()),
            None => table.as_deref(),
        };
        let shape = OntoShape { prepared, table: onto_table, to_reference };
        Ok((shape, labels_s + spectrum_s, preparation_s + t0.elapsed().as_secs_f64()))
    });
    let mut onto_shapes: Vec<OntoShape<'_>> = Vec::new();
    for &onto in &ontos {
        let (shape, spectrum_s, preparation_s) = prepare_onto_shape(onto)?;
        spectrum_ref_s += spectrum_s;
        prepare_s += preparation_s;
        onto_shapes.push(shape);
    }
    // With relays and one vote: a map that reads as mirrored on more than this share of the
    // scan's area is voted with the maps onto the next nearest poses.
    let one_vote_of_several = args.relay_votes <= 1 && ranked.len() > 1;
    let doubt = (one_vote_of_several && args.doubt_votes > 0.0).then_some(args.doubt_votes);
    // ... and a single view's map that reads poorly oriented is regularised onto them too, the
    // best oriented map kept.
    let doubt_view = (one_vote_of_several && args.doubt_view > 0.0).then_some(args.doubt_view);
    // A map carried from a relay or voted is settled onto the reference (`DenseMap::settled`),
    // which needs the reference prepared when it is not among the shapes regularised onto.
    let settles = args.to.is_none()
        && (ontos.len() > 1 || ontos[0].is_some() || doubt.is_some() || doubt_view.is_some())
        && reg.zoomout.is_some_and(|z| z.settles() || z.rigid.is_some());
    // (Prepared as a shape to regularise onto, so that a doubted map whose voters include the
    // reference takes it instead of preparing it again.)
    let mut settle_reference = if settles && ontos.iter().all(Option::is_some) {
        let (shape, spectrum_s, preparation_s) = prepare_onto_shape(None)?;
        spectrum_ref_s += spectrum_s;
        prepare_s += preparation_s;
        Some(shape)
    } else {
        None
    };
    let (mut reversed, mut view_score, mut doubt_prepare_s) = (None, None, 0.0);
    // A doubted view: the index in `ontos` of the pose whose map was kept (the best oriented).
    let mut chosen: Option<(usize, f64)> = None;
    let t0 = Instant::now();
    // With --to: the target scan's spectrum, prediction and preparation count in this stage.
    // `dense`: the regularisation the report's quality fields describe; `map`: the map written.
    let (dense, map, quality_of, target) = match (target, &args.to) {
        (Some(target), Some(target_path)) => {
            let (target_spectrum, target_zoomout) = solve(&target, target_path)?;
            let target_spectrum = Arc::new(target_spectrum);
            let target_prediction =
                forest.predict_mesh(&target, &target_spectrum).context("forest prediction failed")?;
            let target = Arc::new(target);
            let mut targetp = PreparedShape::new(target.clone(), target_spectrum, reg.heat)?;
            if let Some(sp) = target_zoomout {
                targetp = targetp.with_zoomout_spectrum(Arc::new(sp))?;
            }
            let pair = regularize_pair(
                &test,
                &targetp,
                &onto_shapes[0].prepared,
                &prediction,
                &target_prediction,
                table.as_deref(),
                &reg,
                &PairParams::default(),
            )?;
            match pair.regularised {
                Some(d) => (d, pair.map, "the pair map", Some((target, target_path))),
                None => (
                    pair.a_to_reference,
                    pair.map,
                    "the scan's map onto the reference (the pair map is its composition with the target's, refined)",
                    Some((target, target_path)),
                ),
            }
        }
        _ => {
            // Onto each shape, carried to the reference; the first voted with the others.
            // With `read`: the share of the scan's area where the map onto the shape (before it
            // is carried to the reference) reads as mirrored.
            // A map onto a relay is carried and then settled onto the reference (as `eval`
            // does): not settled onto the relay first. A voter (a map voted with others, then
            // settled) gets the voters' settings.
            let onto_map =
                |onto: &OntoShape<'_>, read: bool, voter: bool| -> Result<(DenseMap, Option<f64>)> {
                    // (Without a settling afterwards, every map is refined in full.)
                    let onto_reg = reg.for_map(settles && onto.to_reference.is_some(), settles && voter);
                    let dense = regularize(&test, &onto.prepared, &prediction, onto.table, &onto_reg)?;
                    let share = read.then(|| {
                        reversed_area(&test.mesh, &onto.prepared.mesh, &dense.map, UNFLIP_THRESHOLD)
                    });
                    let dense = match &onto.to_reference {
                        Some(t) => dense.carried(t)?,
                        None => dense,
                    };
                    Ok((dense, share))
                };
            // A carried or voted map, settled onto the reference (among `shapes`, or `spare`).
            let settle = |dense: DenseMap,
                          shapes: &[OntoShape<'_>],
                          spare: Option<&OntoShape<'_>>,
                          carried_or_voted: bool|
             -> Result<DenseMap> {
                let onto_reference = shapes.iter().chain(spare).find(|o| o.to_reference.is_none());
                match onto_reference {
                    Some(r) if settles && carried_or_voted => Ok(dense.settled(&test, &r.prepared, &reg)?),
                    _ => Ok(dense),
                }
            };
            let vote = |first: DenseMap, shapes: &[OntoShape<'_>], spare: Option<&OntoShape<'_>>| {
                // Independent regularisations, side by side.
                let others = shapes[1..]
                    .par_iter()
                    .map(|o| onto_map(o, false, true).map(|(d, _)| d))
                    .collect::<Result<Vec<_>>>()?;
                settle(first.voted(&others, &reference)?, shapes, spare, true)
            };
            let one_vote = onto_shapes.len() == 1;
            let (first, share) = onto_map(&onto_shapes[0], one_vote, !one_vote)?;
            reversed = share;
            let mirrored = doubt.is_some_and(|limit| share.is_some_and(|r| r > limit));
            // A single view's map onto the reference that reads poorly oriented: the view
            // regularised onto the next nearest poses too, the best oriented map kept.
            let mut poorly_oriented = false;
            let dense = if !one_vote {
                vote(first, &onto_shapes, settle_reference.as_ref())?
            } else if !mirrored {
                let carried = onto_shapes[0].to_reference.is_some();
                let dense = settle(first, &onto_shapes, settle_reference.as_ref(), carried)?;
                view_score = view_orientation(&test.mesh, &reference, &dense.map);
                poorly_oriented = doubt_view.is_some_and(|limit| view_score.is_some_and(|s| s < limit));
                dense
            } else {
                first
            };
            let dense = if one_vote && (mirrored || poorly_oriented) {
                // A map that reads as mirrored in part: voted with the next nearest poses'.
                ontos = ranked.iter().take(DOUBT_VOTES).copied().collect();
                // A mirrored part: voted with every pose's map. A poorly oriented view: the next
                // poses in order of nearness until a map reads oriented enough, the best kept.
                let limit = doubt_view.unwrap_or(f64::NEG_INFINITY);
                let mut best = (view_score.unwrap_or(f64::NEG_INFINITY), dense, 0);
                while onto_shapes.len() < ontos.len() && (mirrored || best.0 < limit) {
                    let t1 = Instant::now();
                    let shape = match ontos[onto_shapes.len()] {
                        None if settle_reference.is_some() => settle_reference.take().expect("checked"),
                        onto => {
                            let (shape, spectrum_s, preparation_s) = prepare_onto_shape(onto)?;
                            spectrum_ref_s += spectrum_s;
                            prepare_s += preparation_s;
                            shape
                        }
                    };
                    onto_shapes.push(shape);
                    doubt_prepare_s += t1.elapsed().as_secs_f64();
                    if mirrored {
                        continue;
                    }
                    let onto = &onto_shapes[onto_shapes.len() - 1];
                    let (map, _) = onto_map(onto, false, false)?;
                    let map =
                        settle(map, &onto_shapes, settle_reference.as_ref(), onto.to_reference.is_some())?;
                    let s = view_orientation(&test.mesh, &reference, &map.map);
                    if let Some(s) = s.filter(|&s| s > best.0) {
                        best = (s, map, onto_shapes.len() - 1);
                    }
                }
                if mirrored {
                    vote(best.1, &onto_shapes, settle_reference.as_ref())?
                } else {
                    ontos.truncate(onto_shapes.len());
                    chosen = Some((best.2, best.0));
                    best.1
                }
            } else {
                dense
            };
            let map = part.extend(&scan, dense.map.clone());
            (dense, map, "the map onto the reference", None)
        }
    };
    let name_of = |o: &Option<&Relay>| {
        o.map_or_else(|| args.reference.display().to_string(), |r| r.path.display().to_string())
    };
    let kept = chosen.map_or(0, |c| c.0);
    let onto_relay = ontos[kept].map(|r| r.path.display().to_string());
    // A doubted view's other poses were tried, not voted with.
    let others: Vec<String> =
        ontos.iter().enumerate().filter(|&(i, _)| i != kept).map(|(_, o)| name_of(o)).collect();
    let (voted_with, tried): (Vec<String>, Vec<String>) =
        if chosen.is_some() { (Vec::new(), others) } else { (others, Vec::new()) };
    // The relays a doubted map brought in count with the spectra and preparation.
    let regularize_s = t0.elapsed().as_secs_f64() - doubt_prepare_s;

    let t0 = Instant::now();
    let scan_name = stem(&args.mesh);
    let (onto, onto_path) = match &target {
        Some((t, p)) => (t.clone(), p.as_path()),
        None => (reference.clone(), args.reference.as_path()),
    };
    let onto_name = stem(onto_path);
    let mut text = format!(
        "# shapeforest match: line i (after this header) = vertex of {:?} (0-based) matched to vertex i of {:?}\n",
        onto_path.display().to_string(),
        args.mesh.display().to_string()
    );
    for &r in &map {
        let _ = writeln!(text, "{r}");
    }
    let map_name = match &target {
        Some(_) => format!("{scan_name}.to.{onto_name}.map.txt"),
        None => format!("{scan_name}.map.txt"),
    };
    let map_path = args.out.join(map_name);
    std::fs::write(&map_path, text).with_context(|| format!("cannot write {}", map_path.display()))?;
    let onto_colors = coordinate_colors(&onto);
    let scan_colors: Vec<[u8; 3]> = map.iter().map(|&r| onto_colors[r]).collect();
    write_colored(&args.out.join(format!("{onto_name}.colored.ply")), &onto, &onto_colors)?;
    write_colored(&args.out.join(format!("{scan_name}.colored.ply")), &scan, &scan_colors)?;
    super::visual::write_snapshot(&args.out, &scan_name, &scan, &onto, &map)?;
    let write_s = t0.elapsed().as_secs_f64();

    let confidence = prediction.mean_confidence();
    let tm = &dense.timings;
    let details = serde_json::json!({
        "mesh": args.mesh.display().to_string(),
        "reference": args.reference.display().to_string(),
        "to": args.to.as_ref().map(|p| p.display().to_string()),
        "regularised_onto_relay": onto_relay,
        "voted_with": voted_with,
        // the share of the scan's area where the map onto the nearest pose reads as mirrored
        // (one vote); above `--doubt-votes`, the map was voted with the next nearest poses'
        "reversed_area": reversed,
        "doubted": reversed.is_some() && (!voted_with.is_empty() || !tried.is_empty()),
        // on a single view, the orientation score of the map from the nearest pose onto the
        // reference (one vote, not voted on a mirrored part);
        // below `--doubt-view`, the view was regularised onto the next nearest poses too and the
        // best oriented map kept (`regularised_onto_relay`; the others in `tried_poses`)
        "view_orientation": view_score,
        "tried_poses": tried,
        "components": part.components,
        "matched_part_vertices": part.mesh.n_vertices(),
        "normalising_area_ratio": scale_ratio,
        "reference_symmetry": has_symmetry,
        "label_table": match (&args.reference_labels, forest.reference()) {
            (Some(p), _) => format!("from {}", p.display()),
            (None, Some(r)) => format!("stored in the model (reference `{}`)", r.name),
            (None, None) => "labels are reference vertices".to_string(),
        },
        "model": args.model.display().to_string(),
        "mesh_vertices": scan.n_vertices(),
        "reference_vertices": reference.n_vertices(),
        "to_vertices": target.as_ref().map(|t| t.0.n_vertices()),
        "n_matches": dense.matches.len(),
        "quality_of": quality_of,
        // heat-method sources solved and served from the prepared shapes' kept columns
        "heat_columns": {
            "scan": { "solved": test.column_counts().0, "reused": test.column_counts().1 },
            "reference": { "solved": onto_shapes[0].prepared.column_counts().0, "reused": onto_shapes[0].prepared.column_counts().1 },
        },
        "timings_s": {
            "load": load_s,
            "spectrum_mesh": spectrum_scan_s,
            "spectrum_reference": spectrum_ref_s,
            "predict": predict_s,
            "prepare": prepare_s,
            "regularize": regularize_s,
            "regularize_sampling": tm.sampling_s,
            "regularize_distances": tm.distances_s,
            "regularize_matching": tm.matching_s,
            "regularize_fmap": tm.fmap_s,
            "regularize_point_map": tm.point_map_s,
            "regularize_growth": tm.growth_s,
            "regularize_zoomout": tm.zoomout_s,
            "write": write_s,
            "total": t_all.elapsed().as_secs_f64(),
        },
    });
    let json = shapeforest::pipeline::MatchReport::new(&dense, &prediction, details).to_json()?;
    let report_path = args.out.join(format!("{scan_name}.report.json"));
    std::fs::write(&report_path, json).with_context(|| format!("cannot write {}", report_path.display()))?;
    println!(
        "{} → {}{}{}: {} vertices matched, {} sparse matches, orientation {:.3}, mean confidence {:.3}; \
         predict {predict_s:.2} s, regularise {regularize_s:.2} s; wrote {}",
        args.mesh.display(),
        onto_path.display(),
        onto_relay.as_ref().map_or(String::new(), |r| match chosen {
            None => format!(" (regularised onto {r}, the nearest pose)"),
            Some(_) => format!(" (regularised onto {r})"),
        }),
        match (voted_with.is_empty(), reversed) {
            (true, _) if !tried.is_empty() => format!(
                " (its map, the best oriented of the view's maps onto {} poses: {:.3} against {:.3} onto the nearest)",
                tried.len() + 1,
                chosen.map_or(f64::NAN, |c| c.1),
                view_score.unwrap_or(f64::NAN)
            ),
            (true, _) => String::new(),
            (false, Some(share)) => format!(
                " (voted with {}: {:.1} % of the area read as mirrored)",
                voted_with.join(" and "),
                100.0 * share
            ),
            (false, None) => format!(" (voted with {})", voted_with.join(" and ")),
        },
        map.len(),
        dense.matches.len(),
        dense.orientation_score,
        confidence,
        args.out.display()
    );
    Ok(())
}
