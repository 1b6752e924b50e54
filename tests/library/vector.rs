//! Vector grids decoded as their three components (`GridFile::load_vector`), against OpenVDB
//! itself: `tests/vector/make_grids.py` (pyopenvdb) writes a vec3s grid with a non-zero
//! background, a sheared and translated map, twelve full leaves, sparse leaves holding every
//! kind of inactive values OpenVDB stores (background, -background, one or two others, all),
//! active and inactive 8^3 tiles and a 128^3 tile, once plain (blosc + active mask, with an
//! instance of it and a float grid beside it), once saved as half, once of class staggered
//! with `vector_type` and `is_local_space`; then reads each file back and records what OpenVDB
//! decodes at every probe voxel. Each component tree must hold exactly those components and
//! active states, so must the files `vdb_tool` rewrites with codecs none, zip and active mask
//! only, and the `.nvdb` of `nanovdb_convert` (codecs none, zip, blosc); the
//! length decoding (`GridFile::load`) stays the length. Needs Debian's `python3-openvdb`
//! (`UMBRA_SKIP_ORACLE=1` skips without it) and `libnanovdb-tools`.

use crate::common;
use std::path::{Path, PathBuf};
use umbra::input::{GridFile, VectorFacts, VectorGrid};
use umbra::internals::vdb::ValueKind;
use umbra::Error;

/// What OpenVDB read back from one file: background, class, vector type, and per probe voxel
/// its components and active state.
struct Expect {
    background: [f32; 3],
    class: String,
    vector_type: String,
    probes: Vec<([i32; 3], [f32; 3], bool)>,
}

/// Write the grids into `dir` and read what OpenVDB decodes of each file; `None` when
/// pyopenvdb is missing and `UMBRA_SKIP_ORACLE=1`.
fn generated(dir: &Path) -> Option<std::collections::BTreeMap<String, Expect>> {
    if !common::oracle_available() {
        return None;
    }
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/vector/make_grids.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(script)
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "make_grids.py: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = std::fs::read_to_string(dir.join("expect.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let f = |v: &serde_json::Value| v.as_f64().unwrap() as f32;
    let mut out = std::collections::BTreeMap::new();
    for (name, e) in json.as_object().unwrap() {
        let bg = e["background"].as_array().unwrap();
        let probes = e["probes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| {
                let p = p.as_array().unwrap();
                let i = |k: usize| p[k].as_i64().unwrap() as i32;
                (
                    [i(0), i(1), i(2)],
                    [f(&p[3]), f(&p[4]), f(&p[5])],
                    p[6].as_bool().unwrap(),
                )
            })
            .collect();
        out.insert(
            name.clone(),
            Expect {
                background: [f(&bg[0]), f(&bg[1]), f(&bg[2])],
                class: e["class"].as_str().unwrap().to_string(),
                vector_type: e["vector_type"].as_str().unwrap().to_string(),
                probes,
            },
        );
    }
    Some(out)
}

/// Every component tree holds OpenVDB's components and active states at every probe, and the
/// background's components.
fn check_components(v: &VectorGrid, e: &Expect, what: &str) {
    assert_eq!(v.value_type, ValueKind::Vec3s, "{what}");
    for (k, tree) in v.components.iter().enumerate() {
        assert_eq!(
            tree.background().to_bits(),
            e.background[k].to_bits(),
            "{what}: background component {k}"
        );
    }
    assert!(e.probes.len() > 9000, "{what}: {} probes", e.probes.len());
    let mut tiles = 0;
    for &(ijk, want, active) in &e.probes {
        for (k, tree) in v.components.iter().enumerate() {
            assert_eq!(
                tree.value(ijk).to_bits(),
                want[k].to_bits(),
                "{what}: component {k} at {ijk:?}: {} vs OpenVDB's {}",
                tree.value(ijk),
                want[k]
            );
            assert_eq!(tree.is_active(ijk), active, "{what}: active at {ijk:?}");
        }
        if ijk[0] >= 64 && ijk[0] < 4096 {
            tiles += 1;
        }
    }
    assert!(tiles >= 10, "{what}: {tiles} tile and background probes");
    // The tile values themselves, as written.
    let at = |ijk: [i32; 3]| v.components.each_ref().map(|t| t.value(ijk));
    assert_eq!(at([66, 3, 5]), [7.0, -8.0, 9.0], "{what}: active 8^3 tile");
    assert_eq!(
        at([75, 1, 2]),
        [-1.5, 2.5, -3.5],
        "{what}: inactive 8^3 tile"
    );
    assert_eq!(at([200, 150, 255]), [-1.0, 2.0, -3.0], "{what}: 128^3 tile");
    assert_eq!(at([-1000, 5, 5]), [0.5, -0.25, 1.5], "{what}: background");
    // Bounds are computed: each component's stats see its values.
    for tree in &v.components {
        let s = tree.stats();
        assert!(s.active_voxels > 0, "{what}");
    }
}

/// `GridFile::load`'s length tree is the length of the components everywhere, the inactive
/// voxels OpenVDB stores implicitly as "minus the background" (a `.vdb` with active-mask
/// compression, node metadata 1 and 3) included: `|-bg| = |bg|`, as a `.nvdb`, which stores
/// the vector itself, gives. (Until issue 50 the `.vdb` decoder read them as `-|bg|`.)
fn check_length(file: &GridFile, grid: &str, e: &Expect, half: bool, what: &str) {
    let g = file.load(grid).unwrap();
    let len = |c: [f32; 3]| {
        if half {
            (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
        } else {
            let d = c.map(f64::from);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() as f32
        }
    };
    for &(ijk, want, _) in &e.probes {
        let (got, want) = (g.tree.value(ijk), len(want));
        assert!(
            (got - want).abs() <= 1e-6 * want.abs(),
            "{what}: length at {ijk:?}: {got} vs {want}"
        );
    }
}

#[test]
fn vector_grids_decode_to_openvdbs_components() {
    let dir = tempfile::tempdir().unwrap();
    let Some(expect) = generated(dir.path()) else {
        return;
    };
    for (name, e) in &expect {
        let path = dir.path().join(name);
        let file = GridFile::open(&path).unwrap();
        let v = file.load_vector("vel").unwrap();
        check_components(&v, e, name);
        assert_eq!(v.name, "vel");
        let g = file.load("vel").unwrap();
        assert_eq!(v.transform.world_from_index, g.transform.world_from_index);
        assert_eq!(v.metadata, g.metadata);
        // The sheared, translated map as written (OpenVDB's row-vector matrix, transposed).
        let m = v.transform.world_from_index;
        assert_eq!(
            (m[0][0], m[1][0], m[0][2]),
            (0.5, 0.1, 0.05),
            "{name}: {m:?}"
        );
        assert_eq!(
            (m[0][3], m[1][3], m[2][3]),
            (1.0, -2.0, 3.0),
            "{name}: {m:?}"
        );
        let staggered = name == "staggered.vdb";
        assert_eq!(v.is_staggered(), staggered, "{name}");
        assert_eq!(v.is_staggered(), e.class == "staggered", "{name}");
        assert_eq!(v.is_local_space(), staggered, "{name}");
        // OpenVDB writes `vector_type` only when set, and reads its absence as `invariant`.
        assert_eq!(
            v.vector_type().unwrap_or("invariant"),
            e.vector_type,
            "{name}"
        );
        assert_eq!(v.vector_type().is_some(), staggered, "{name}");
        check_length(&file, "vel", e, name == "half.vdb", name);
    }
    let stag = GridFile::open(dir.path().join("staggered.vdb"))
        .unwrap()
        .load_vector("vel")
        .unwrap();
    assert_eq!(stag.class.as_deref(), Some("staggered"));
    assert_eq!(stag.vector_type(), Some("contravariant relative"));
    // The instance shares the grid's tree in the file and decodes to the same components.
    let plain = dir.path().join("plain.vdb");
    let archive = umbra::internals::vdb::open(&plain).unwrap();
    let gd = archive.find_grid("vel_instance").unwrap();
    assert_eq!(gd.instance_parent, "vel", "pyopenvdb wrote no instance");
    let file = GridFile::open(&plain).unwrap();
    let inst = file.load_vector("vel_instance").unwrap();
    assert_eq!(inst.name, "vel_instance");
    check_components(&inst, &expect["plain.vdb"], "vel_instance");
    // Half values really are halves: some component differs from the plain file's.
    let differs = expect["half.vdb"]
        .probes
        .iter()
        .zip(&expect["plain.vdb"].probes)
        .any(|(h, p)| h.1 != p.1);
    assert!(differs, "the half file holds full-precision values");
}

/// The plain and half files rewritten by `vdb_tool` (Debian libopenvdb-tools) with codecs
/// none, zip and active mask only: the same components (the rewrite is lossless).
#[test]
fn every_vdb_codec_decodes_to_the_same_components() {
    let dir = tempfile::tempdir().unwrap();
    let Some(expect) = generated(dir.path()) else {
        return;
    };
    for src in ["plain.vdb", "half.vdb"] {
        for (codec, zip, active_mask) in [
            ("none", false, false),
            ("zip", true, true),
            ("active", false, true),
        ] {
            let out = dir.path().join(format!("{src}.{codec}.vdb"));
            let o = std::process::Command::new("vdb_tool")
                .arg("-read")
                .arg(dir.path().join(src))
                .arg("-write")
                .arg(format!("codec={codec}"))
                .arg(&out)
                .output();
            let o = match o {
                Ok(o) => o,
                Err(e) => {
                    assert!(
                        std::env::var("UMBRA_SKIP_ORACLE").as_deref() == Ok("1"),
                        "vdb_tool could not be run ({e}): apt-get install libopenvdb-tools"
                    );
                    return;
                }
            };
            assert!(
                o.status.success() && out.is_file(),
                "vdb_tool: {}",
                String::from_utf8_lossy(&o.stderr)
            );
            let what = format!("{src} as {codec}");
            let file = GridFile::open(&out).unwrap();
            let g = file.load("vel").unwrap();
            let c = g.compression;
            assert_eq!(
                (c.zip, c.blosc, c.active_mask),
                (zip, false, active_mask),
                "{what}"
            );
            assert_eq!(g.saved_as_half, src == "half.vdb", "{what}");
            let v = file.load_vector("vel").unwrap();
            check_components(&v, &expect[src], &what);
            // Without active-mask compression every value is stored: no implicit `-bg`.
            let half = src == "half.vdb";
            check_length(&file, "vel", &expect[src], half, &what);
        }
    }
}

#[test]
fn nanovdb_vector_grids_decode_to_the_same_components() {
    let dir = tempfile::tempdir().unwrap();
    let Some(expect) = generated(dir.path()) else {
        return;
    };
    for src in ["plain.vdb", "staggered.vdb"] {
        let e = &expect[src];
        for (case, args) in [
            ("none", &[][..]),
            ("zip", &["-z"][..]),
            ("blosc", &["-b"][..]),
        ] {
            let nvdb = dir.path().join(format!("{src}.{case}.nvdb"));
            common::nanovdb_convert(args, &dir.path().join(src), &nvdb);
            let file = GridFile::open(&nvdb).unwrap();
            let what = format!("{src} as {case} .nvdb");
            let v = file.load_vector("vel").unwrap();
            check_components(&v, e, &what);
            assert_eq!(v.is_staggered(), src == "staggered.vdb", "{what}");
            let vdb = GridFile::open(dir.path().join(src))
                .unwrap()
                .load_vector("vel")
                .unwrap();
            let (a, b) = (v.transform.world_from_index, vdb.transform.world_from_index);
            for r in 0..3 {
                for c in 0..4 {
                    assert!((a[r][c] - b[r][c]).abs() < 1e-6, "{what}: {a:?} vs {b:?}");
                }
            }
            check_length(&file, "vel", e, false, &what);
            if src == "plain.vdb" {
                let err = file.load_vector("density").unwrap_err();
                not_a_vector(&err, &nvdb);
            }
        }
    }
}

/// The error of a float grid asked for as a vector grid: unsupported, naming file and grid.
fn not_a_vector(err: &Error, path: &Path) {
    match err {
        Error::Unsupported { path: p, what } => {
            assert_eq!(p, path);
            assert_eq!(
                what,
                "grid 'density' is a float grid; a velocity must be a vec3 grid (vec3s, vec3d, \
                 vec3i)"
            );
        }
        other => panic!("{other:?}"),
    }
    let shown = err.to_string();
    assert!(shown.contains(&path.display().to_string()), "{shown}");
}

#[test]
fn a_float_grid_is_no_vector_grid() {
    // umbra's own float grid, and the sample cloud: no tool needed.
    let cloud = common::data("cloud.vdb");
    let err = GridFile::open(&cloud)
        .unwrap()
        .load_vector("density")
        .unwrap_err();
    not_a_vector(&err, &cloud);
    let missing = GridFile::open(&cloud)
        .unwrap()
        .load_vector("no such grid")
        .unwrap_err();
    assert!(matches!(missing, Error::GridNotFound { .. }), "{missing}");
    let dir = tempfile::tempdir().unwrap();
    if generated(dir.path()).is_none() {
        return;
    }
    let plain = dir.path().join("plain.vdb");
    let err = GridFile::open(&plain)
        .unwrap()
        .load_vector("density")
        .unwrap_err();
    not_a_vector(&err, &plain);
}
