//! Mesh ingest through the public API: round trips in every format, file-level errors that
//! name the file, robustness against arbitrary and damaged bytes, and real TOSCA data when
//! present (`$SHAPEFOREST_DATA`, else `../shared/data` beside the crate).

mod common;

use std::io::Write;

use proptest::prelude::*;
use shapeforest::mesh::{
    parse_mesh, parse_obj, parse_off, parse_ply, parse_tosca, parse_tri, parse_vert, read_mesh,
    read_mesh_from, read_mesh_with_report, write_mesh, write_obj, write_off, write_ply, write_tosca, Mesh,
    MeshError, MeshFormat, MeshWarning, PlyEncoding,
};
use shapeforest::synth::{icosphere, torus};

/// A mesh with awkward coordinates: values with long decimal expansions, tiny and huge
/// magnitudes, negative zero.
fn awkward_mesh() -> Mesh {
    let mut m = torus(7, 5, 2.0, 0.5);
    m.vertices[0] = [0.1 + 0.2, -0.0, 1e-300];
    m.vertices[1] = [1.0 / 3.0, 6.02214076e23, -5e-324];
    m.vertices[2] = [f64::MAX, f64::MIN_POSITIVE, std::f64::consts::PI];
    m
}

fn bits(m: &Mesh) -> Vec<[u64; 3]> {
    m.vertices.iter().map(|p| [p[0].to_bits(), p[1].to_bits(), p[2].to_bits()]).collect()
}

fn encode(m: &Mesh, format: &str) -> Vec<u8> {
    let mut out = Vec::new();
    match format {
        "off" => write_off(m, &mut out).unwrap(),
        "obj" => write_obj(m, &mut out).unwrap(),
        "ply-ascii" => write_ply(m, &mut out, PlyEncoding::Ascii, None).unwrap(),
        "ply-binary" => write_ply(m, &mut out, PlyEncoding::BinaryLittleEndian, None).unwrap(),
        _ => unreachable!(),
    }
    out
}

fn decode(bytes: &[u8], format: &str) -> Result<Mesh, MeshError> {
    let r = match format {
        "off" => parse_off(bytes),
        "obj" => parse_obj(bytes),
        _ => parse_ply(bytes),
    };
    r.map(|(m, _)| m)
}

const FORMATS: [&str; 4] = ["off", "obj", "ply-ascii", "ply-binary"];

#[test]
fn every_format_round_trips_bit_exactly() {
    let m = awkward_mesh();
    for format in FORMATS {
        let back = decode(&encode(&m, format), format).unwrap_or_else(|e| panic!("{format}: {e}"));
        assert_eq!(back.faces, m.faces, "{format}");
        assert_eq!(bits(&back), bits(&m), "{format}");
    }
    let (mut vert, mut tri) = (Vec::new(), Vec::new());
    write_tosca(&m, &mut vert, &mut tri).unwrap();
    let (back, _) = parse_tosca(&vert, &tri).unwrap();
    assert_eq!((bits(&back), back.faces), (bits(&m), m.faces));
}

#[test]
fn ply_with_colours_round_trips_and_rejects_a_wrong_colour_count() {
    let m = icosphere(1, 1.0);
    let colours: Vec<[u8; 3]> = (0..m.n_vertices()).map(|i| [i as u8, 255 - i as u8, 7]).collect();
    for encoding in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
        let mut out = Vec::new();
        write_ply(&m, &mut out, encoding, Some(&colours)).unwrap();
        assert_eq!(parse_ply(&out).unwrap().0, m);
    }
    let err = write_ply(&m, Vec::new(), PlyEncoding::Ascii, Some(&colours[..3])).unwrap_err();
    assert_eq!(err.to_string(), "3 vertex colours given for 42 vertices");
}

/// Binary big-endian PLY with `float` coordinates, `uint8` list counts and `int32` indices,
/// an extra `confidence` property and a quad.
#[test]
fn big_endian_ply_with_mixed_types_reads() {
    let mut data = b"ply\nformat binary_big_endian 1.0\nelement vertex 4\nproperty float32 x\n\
property float32 y\nproperty float32 z\nproperty float confidence\nelement face 1\n\
property list uint8 int32 vertex_indices\nend_header\n"
        .to_vec();
    let verts = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.5]];
    for v in verts {
        for c in v {
            data.extend_from_slice(&c.to_be_bytes());
        }
        data.extend_from_slice(&0.25f32.to_be_bytes());
    }
    data.push(4);
    for i in [0i32, 1, 2, 3] {
        data.extend_from_slice(&i.to_be_bytes());
    }
    let (m, report) = parse_ply(&data).unwrap();
    assert_eq!(m.vertices[3], [0.0, 1.0, 0.5]);
    assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(report.warnings, vec![MeshWarning::PolygonsTriangulated { polygons: 1, triangles: 2 }]);

    // A face index out of range in binary data is located by element.
    let n = data.len();
    data[n - 4..].copy_from_slice(&9i32.to_be_bytes());
    let err = parse_ply(&data).unwrap_err();
    assert_eq!(err.to_string(), "face element 0: face 1 refers to vertex 9, but the mesh has 4 vertices");
}

#[test]
fn files_round_trip_through_every_extension_including_gzip() {
    let dir = tempfile::tempdir().unwrap();
    let m = awkward_mesh();
    for name in ["a.off", "a.obj", "a.ply", "b.off.gz", "b.OBJ.GZ", "b.ply.gz", "t.vert", "u.tri.gz"] {
        let path = dir.path().join(name);
        write_mesh(&path, &m).unwrap_or_else(|e| panic!("{e}"));
        let (back, report) = read_mesh_with_report(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((bits(&back), &back.faces), (bits(&m), &m.faces), "{name}");
        assert_eq!(report.format, MeshFormat::from_path(&path).unwrap());
    }
    // Either file of a TOSCA pair finds its sibling, compressed or not.
    assert_eq!(read_mesh(dir.path().join("t.tri")).unwrap(), m);
    assert_eq!(read_mesh(dir.path().join("u.vert.gz")).unwrap(), m);
    // Gzip data is recognised by content too.
    let gz = std::fs::read(dir.path().join("b.off.gz")).unwrap();
    std::fs::write(dir.path().join("plain-name.off"), &gz).unwrap();
    assert_eq!(read_mesh(dir.path().join("plain-name.off")).unwrap(), m);
    let (back, _) = read_mesh_from(&gz[..], MeshFormat::Off).unwrap();
    assert_eq!(back, m);
}

#[test]
fn file_errors_name_the_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let cat = dir.path().join("cat.off");
    let mut text = String::from("OFF\n20 1 0\n");
    for i in 0..14 {
        text.push_str(&format!("{i} 0 0\n"));
    }
    text.push_str("1 2\n"); // line 17
    std::fs::write(&cat, &text).unwrap();
    let err = read_mesh(&cat).unwrap_err();
    assert_eq!(err.to_string(), format!("{}: line 17: expected 3 coordinates, found 2", cat.display()));
    assert_eq!((err.path(), err.line()), (Some(cat.as_path()), Some(17)));

    let missing = dir.path().join("nope.ply");
    let err = read_mesh(&missing).unwrap_err();
    assert!(matches!(err.root(), MeshError::Io(_)), "{err}");
    assert!(err.to_string().starts_with(&format!("{}: I/O error", missing.display())), "{err}");

    let err = read_mesh(dir.path().join("scan.stl")).unwrap_err();
    assert!(err.to_string().ends_with(
        "scan.stl: unknown mesh file extension \"stl\": expected .off, .obj, .ply, .vert, .tri or .xyz, optionally followed by .gz"
    ), "{err}");

    std::fs::write(dir.path().join("lonely.vert"), "0 0 0\n").unwrap();
    let err = read_mesh(dir.path().join("lonely.vert")).unwrap_err();
    assert!(matches!(err.root(), MeshError::MissingSibling { .. }), "{err}");
    assert!(err.to_string().contains("lonely.tri does not exist"), "{err}");

    // In a TOSCA pair, face errors name the .tri file.
    std::fs::write(dir.path().join("pair.vert"), "0 0 0\n1 0 0\n0 1 0\n").unwrap();
    std::fs::write(dir.path().join("pair.tri"), "1 2 3\n1 2 4\n").unwrap();
    let err = read_mesh(dir.path().join("pair.vert")).unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}: line 2: face 1 refers to vertex 3, but the mesh has 3 vertices",
            dir.path().join("pair.tri").display()
        )
    );

    // Corrupt gzip.
    std::fs::write(dir.path().join("bad.off.gz"), [0x1f, 0x8b, 8, 0, 1, 2, 3]).unwrap();
    let err = read_mesh(dir.path().join("bad.off.gz")).unwrap_err();
    assert!(matches!(err.root(), MeshError::Decompress(_)), "{err}");
}

#[test]
fn tiny_point_clouds_are_refused_in_every_format() {
    let cloud_off = b"OFF\n2 0 0\n0 0 0\n1 1 1\n".as_slice();
    let cloud_obj = b"v 0 0 0\nv 1 1 1\n".as_slice();
    let cloud_ply = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
property float z\nend_header\n0 0 0\n1 1 1\n"
        .as_slice();
    for (bytes, format) in
        [(cloud_off, MeshFormat::Off), (cloud_obj, MeshFormat::Obj), (cloud_ply, MeshFormat::Ply)]
    {
        let err = parse_mesh(bytes, format).unwrap_err();
        assert_eq!(err.to_string(), "a point cloud needs at least 4 points, this one has 2", "{format}");
    }
}

#[test]
fn warnings_report_defects_without_changing_the_mesh() {
    // Vertices 4 and 5 unused; faces 0 and 2 duplicate each other (so edges (0,1) and (1,2)
    // have three faces); face 3 is degenerate (collinear).
    let text = "OFF\n6 4 0\n0 0 0\n1 0 0\n0 1 0\n2 0 0\n7 7 7\n3 0 0\n\
3 0 1 2\n3 1 3 2\n3 2 1 0\n3 0 1 3\n";
    let (m, report) = parse_off(text.as_bytes()).unwrap();
    assert_eq!(m.n_vertices(), 6);
    assert_eq!(
        report.warnings,
        vec![
            MeshWarning::ZeroAreaFaces { count: 1, first: 3 },
            MeshWarning::NonManifoldEdges { count: 2 },
            MeshWarning::UnreferencedVertices { count: 2, first: 4 },
            MeshWarning::DuplicateFaces { count: 1, first: 2 },
        ]
    );
    let shown = report.to_string();
    assert!(shown.contains("warning: 1 duplicate face(s), the first is face 2"), "{shown}");
}

#[test]
fn huge_declared_counts_do_not_allocate() {
    let e = parse_off(b"OFF\n999999999999 1 0").unwrap_err();
    assert!(matches!(e, MeshError::Truncated { .. }), "{e}");
    let ply = b"ply\nformat ascii 1.0\nelement vertex 999999999999\nproperty float x\nproperty float y\n\
property float z\nelement face 999999999999\nproperty list uint uint vertex_indices\nend_header\n0 0 0\n";
    let e = parse_ply(ply).unwrap_err();
    assert!(matches!(e, MeshError::Truncated { .. }), "{e}");
    // A list length of 4 billion in a binary face.
    let mut ply =
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty uchar x\nproperty uchar y\n\
property uchar z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n"
            .to_vec();
    ply.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 1, 0]);
    ply.extend_from_slice(&u32::MAX.to_le_bytes());
    ply.extend_from_slice(&[0; 8]);
    let e = parse_ply(&ply).unwrap_err();
    assert!(matches!(e.root(), MeshError::Truncated { .. }), "{e}");
}

/// Why OBJ is parsed here and not by `tobj`: `tobj` renumbers vertices in order of first use
/// and drops unused ones, which would break correspondence by vertex index.
#[test]
fn tobj_would_renumber_vertices_and_our_reader_does_not() {
    let text = "v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 4 2 3\n";
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ..Default::default() };
    let (models, _) =
        tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| Err(tobj::LoadError::OpenFileFailed)).unwrap();
    let theirs = &models[0].mesh;
    assert_eq!(theirs.positions.len(), 9, "tobj keeps only the 3 used vertices");
    assert_eq!(theirs.indices, vec![0, 1, 2], "tobj renumbers them");
    let (ours, _) = parse_obj(text.as_bytes()).unwrap();
    assert_eq!(ours.n_vertices(), 4);
    assert_eq!(ours.faces, vec![[3, 1, 2]]);
}

// ---------------------------------------------------------------- robustness against any input

/// Valid files of every format, to be damaged.
fn valid_samples() -> Vec<(Vec<u8>, &'static str)> {
    let m = icosphere(0, 1.0);
    let mut samples: Vec<(Vec<u8>, &'static str)> = FORMATS.iter().map(|f| (encode(&m, f), *f)).collect();
    let (mut vert, mut tri) = (Vec::new(), Vec::new());
    write_tosca(&m, &mut vert, &mut tri).unwrap();
    samples.push((vert, "vert"));
    samples.push((tri, "tri"));
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    gz.write_all(&samples[0].0).unwrap();
    samples.push((gz.finish().unwrap(), "off"));
    samples
}

/// Feeds `bytes` to every reader; each must return (Ok or Err), never panic.
fn feed_all(bytes: &[u8]) {
    let _ = parse_off(bytes);
    let _ = parse_obj(bytes);
    let _ = parse_ply(bytes);
    let _ = parse_vert(bytes);
    let _ = parse_tri(bytes, 12);
    let _ = parse_tosca(bytes, bytes);
}

fn fuzz_cases() -> u32 {
    std::env::var("PROPTEST_CASES").ok().and_then(|c| c.parse().ok()).unwrap_or(512)
}

fn damaged_sample() -> impl Strategy<Value = Vec<u8>> {
    let samples = valid_samples();
    (0..samples.len(), any::<u64>(), prop::collection::vec((any::<u16>(), any::<u8>(), 0u8..4), 0..6))
        .prop_map(move |(which, cut, edits)| {
            let mut bytes = samples[which].0.clone();
            for (pos, byte, kind) in edits {
                if bytes.is_empty() {
                    break;
                }
                let at = pos as usize % bytes.len();
                match kind {
                    0 => bytes[at] = byte,
                    1 => bytes.insert(at, byte),
                    2 => {
                        bytes.remove(at);
                    }
                    // Swap in a digit or separator: keeps text files "almost valid".
                    _ => bytes[at] = b"0123456789 -\n.e"[byte as usize % 15],
                }
            }
            let keep = (cut as usize) % (bytes.len() + 1);
            if cut % 3 == 0 {
                bytes.truncate(keep);
            }
            bytes
        })
}

proptest! {
    // `PROPTEST_CASES=100000 cargo test --release --test mesh_io` for a longer fuzzing run.
    #![proptest_config(ProptestConfig { cases: fuzz_cases(), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        feed_all(&bytes);
    }

    #[test]
    fn random_bytes_after_a_valid_header_never_panic(
        header in prop::sample::select(vec![
            &b"OFF\n"[..], b"COFF 3 1 0\n", b"v 0 0 0\nf ",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
            b"ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\nproperty double z\nelement face 2\nproperty list int uint vertex_index\nend_header\n",
            &[0x1f, 0x8b][..],
        ]),
        tail in prop::collection::vec(any::<u8>(), 0..256),
    ) {
        let mut bytes = header.to_vec();
        bytes.extend_from_slice(&tail);
        feed_all(&bytes);
    }

    #[test]
    fn damaged_valid_files_never_panic(bytes in damaged_sample()) {
        feed_all(&bytes);
    }

    #[test]
    fn a_cut_file_with_counts_is_an_error_or_has_the_declared_counts(cut in 0usize..4096, which in 0usize..3) {
        // OBJ has no counts: a cut after a whole line is a valid smaller mesh, so it is not here.
        let m = icosphere(0, 1.0);
        let format = ["off", "ply-ascii", "ply-binary"][which];
        let full = encode(&m, format);
        let cut = cut % (full.len() + 1);
        // A cut inside the last number of a text file can still leave a valid number.
        if let Ok(back) = decode(&full[..cut], format) {
            prop_assert_eq!((back.n_vertices(), back.n_faces()), (m.n_vertices(), m.n_faces()));
            prop_assert!(cut + 4 >= full.len(), "cut at {} of {} bytes was accepted", cut, full.len());
        }
    }
}

// ---------------------------------------------------------------- real data, when present

#[test]
fn real_tosca_wolf_reads_with_known_counts_and_topology() {
    let Some(path) = common::shared_data("tosca/wolf0.off") else { return };
    let (m, report) = read_mesh_with_report(&path).unwrap();
    assert_eq!((m.n_vertices(), m.n_faces()), (4344, 8684));
    let s = &report.summary;
    // The header's edge count, a closed connected surface of genus 0.
    assert_eq!(s.n_edges, 13026);
    assert_eq!((s.euler_characteristic, s.n_components(), s.n_boundary_loops), (2, 1, 0));
    assert!(s.is_closed());
    println!("{report}");
}

#[test]
fn real_tosca_r5k_gz_reads_with_known_counts() {
    let Some(path) = common::shared_data("tosca-r5k/TOSCA_Isometric/vtx_5k/cat0.off.gz") else { return };
    let (m, report) = read_mesh_with_report(&path).unwrap();
    assert_eq!((m.n_vertices(), m.n_faces()), (5000, 9996));
    assert_eq!((report.summary.n_edges, report.summary.euler_characteristic), (14994, 2));
    // Writing and reading back through every format keeps it exactly.
    for format in FORMATS {
        assert_eq!(decode(&encode(&m, format), format).unwrap(), m, "{format}");
    }
}

#[test]
fn every_real_tosca_r5k_mesh_reads_and_its_ground_truth_indices_fit() {
    let Some(shapes) = common::shared_data("tosca-r5k/TOSCA_Isometric/vtx_5k") else { return };
    let entries = std::fs::read_dir(&shapes).expect("the tosca-r5k folder lists");
    let mut n_read = 0;
    for entry in entries {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let Some(stem) = name.strip_suffix(".off.gz") else { continue };
        let mesh = read_mesh(&path).unwrap_or_else(|e| panic!("{e}"));
        let vts = shapes.join("corres").join(format!("{stem}.vts"));
        if let Ok(text) = std::fs::read_to_string(&vts) {
            for (k, line) in text.lines().enumerate() {
                let i: usize =
                    line.trim().parse().unwrap_or_else(|_| panic!("{}: line {}", vts.display(), k + 1));
                assert!((1..=mesh.n_vertices()).contains(&i), "{}: line {}: {i}", vts.display(), k + 1);
            }
        }
        n_read += 1;
    }
    assert!(n_read > 0, "no .off.gz files in {}", shapes.display());
}

#[test]
fn errors_and_reports_can_cross_threads() {
    fn assert_send_sync<T: Send + Sync + 'static>() {}
    assert_send_sync::<MeshError>();
    assert_send_sync::<shapeforest::mesh::MeshReport>();
    assert_send_sync::<shapeforest::mesh::MeshSummary>();
    // And convert into the crate error.
    let e: shapeforest::Error = parse_off(b"").unwrap_err().into();
    assert!(e.to_string().contains("expected an OFF header"));
}
