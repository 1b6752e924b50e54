//! NanoVDB `.nvdb` input (issue 49), against NanoVDB itself: corpus files converted by Debian's
//! `nanovdb_convert` (libnanovdb-tools) with every codec and quantisation, each compared with the
//! same grid converted back to `.vdb` by `nanovdb_convert` (what NanoVDB decodes): the trees
//! voxel by voxel, exact transmittance queries and a small baked map, to 1e-6 relative. Then
//! multi-grid and multi-segment files, and corrupt files that must end in one clean error.

use crate::common;
use std::path::{Path, PathBuf};
use umbra::bake::{bake, BakeSettings, Camera, Projection, Resolution, View};
use umbra::estimate::{estimate, Estimator, Options};
use umbra::{Ray, Volume};

/// Every codec and quantisation `nanovdb_convert` writes, by name.
pub const CASES: [(&str, &[&str]); 7] = [
    ("none", &[]),
    ("zip", &["-z"]),
    ("blosc", &["-b"]),
    ("fp16", &["--fp16"]),
    ("fp8", &["--fp8"]),
    ("fp4", &["--fp4"]),
    ("fpN", &["--fpN", "-a", "0.01"]),
];

use common::nanovdb_convert as convert;

fn corpus(rel: &str) -> Option<PathBuf> {
    Some(common::corpus_dir()?.join(rel))
}

/// `.vdb` -> `.nvdb` with `args`, and that `.nvdb` back to `.vdb` (what NanoVDB decodes).
fn pair(dir: &Path, src: &Path, case: &str, args: &[&str]) -> (PathBuf, PathBuf) {
    let stem = src.file_stem().unwrap().to_string_lossy();
    let nvdb = dir.join(format!("{stem}.{case}.nvdb"));
    let back = dir.join(format!("{stem}.{case}.back.vdb"));
    convert(args, src, &nvdb);
    convert(&[], &nvdb, &back);
    (nvdb, back)
}

fn rel(a: f64, b: f64) -> f64 {
    if a == b || (a.is_nan() && b.is_nan()) {
        0.0
    } else {
        (a - b).abs() / a.abs().max(b.abs()).max(1e-30)
    }
}

/// The largest relative difference between two grids' values over every voxel of either's
/// leaves and the active states there, which must agree; tiles and background likewise.
pub(crate) fn tree_diff(
    a: &umbra::internals::tree::Tree,
    b: &umbra::internals::tree::Tree,
    what: &str,
) -> f64 {
    let mut worst = rel(a.background().into(), b.background().into());
    for (t, o) in [(a, b), (b, a)] {
        for leaf in t.leaves() {
            for i in 0..512i32 {
                let ijk = [
                    leaf.origin[0] + (i >> 6),
                    leaf.origin[1] + ((i >> 3) & 7),
                    leaf.origin[2] + (i & 7),
                ];
                assert_eq!(
                    t.is_active(ijk),
                    o.is_active(ijk),
                    "{what}: active state at {ijk:?}"
                );
                worst = worst.max(rel(t.value(ijk).into(), o.value(ijk).into()));
            }
        }
    }
    let (sa, sb) = (a.stats(), b.stats());
    assert_eq!(sa.active_voxels, sb.active_voxels, "{what}: active voxels");
    assert_eq!(sa.index_bbox, sb.index_bbox, "{what}: index bbox");
    assert_eq!(
        (sa.root_tiles, sa.upper_tiles, sa.lower_tiles),
        (sb.root_tiles, sb.upper_tiles, sb.lower_tiles),
        "{what}: tiles"
    );
    worst
}

/// The largest relative difference of exact transmittances along rays across the volume, and
/// of a 16x16 baked map.
fn answers_diff(a: &Volume, b: &Volume, what: &str) -> f64 {
    let corners = a.box_corners().unwrap();
    let (lo, hi) = corners.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), c| {
            (
                [0, 1, 2].map(|k| lo[k].min(c[k])),
                [0, 1, 2].map(|k| hi[k].max(c[k])),
            )
        },
    );
    let at = |f: [f64; 3]| [0, 1, 2].map(|k| lo[k] + f[k] * (hi[k] - lo[k]));
    let opts = Options::default();
    let mut worst = 0f64;
    for s in 0..24 {
        let t = f64::from(s) / 24.0;
        let ray = Ray::between(at([-0.1, t, 0.3 + 0.4 * t]), at([1.1, 1.0 - t, 0.5])).unwrap();
        let ea = estimate(a, &ray, 0, &Estimator::REGULAR, &opts)
            .unwrap()
            .value;
        let eb = estimate(b, &ray, 0, &Estimator::REGULAR, &opts)
            .unwrap()
            .value;
        worst = worst.max(rel(ea, eb));
    }
    let view = View {
        projection: Projection::Ortho,
        light_dir: Some([-1.0, -0.7, 0.3]),
        light_pos: None,
        fov_deg: None,
        res: Some(Resolution::Exact(16, 16)),
        ..View::default()
    };
    let camera = Camera::frame(&view, &a.box_corners().unwrap()).unwrap();
    let settings = BakeSettings::new(Estimator::REGULAR, Options::default());
    let ma = bake(a, &camera, &settings, &|_| {}).unwrap();
    let mb = bake(b, &camera, &settings, &|_| {}).unwrap();
    for (x, y) in ma.t.iter().zip(&mb.t) {
        worst = worst.max(rel(f64::from(*x), f64::from(*y)));
    }
    assert!(
        worst <= 1e-6,
        "{what}: answers differ by {worst:e} relative"
    );
    worst
}

/// Small corpus files, fog and level set, affine maps, tiles at every level, a double grid.
const FILES: [&str; 6] = [
    "gen/xform_affine_rotated.vdb",
    "gen/tiles_mixed.vdb",
    "gen/tiles_root_level.vdb",
    "gen/fog_nonzero_background.vdb",
    "gen/negative_coords.vdb",
    "real/double_density_dense_128x64x64.vdb",
];

#[test]
fn every_codec_and_quantisation_decodes_as_nanovdb_does() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut report = Vec::new();
    for file in FILES {
        let src = dir.join(file);
        for (case, args) in CASES {
            let (nvdb, back) = pair(tmp.path(), &src, case, args);
            let what = format!("{file} {case}");
            let ga = umbra::input::load_grid(&nvdb, "density").unwrap();
            let gb = umbra::input::load_grid(&back, "density").unwrap();
            let tree = tree_diff(&ga.tree, &gb.tree, &what);
            assert!(tree <= 1e-6, "{what}: values differ by {tree:e} relative");
            assert_eq!(ga.value_type, gb.value_type, "{what}");
            // The map: NanoVDB's (`world = M ijk + t`, `Map::applyMap`) is the source's.
            // nanovdb_convert 10.0.1 writes the 3x3 part transposed when converting back to
            // .vdb, so the round trip's transform is not the reference: the source's is.
            let source = umbra::input::load_grid(&src, "density").unwrap();
            let (wa, ws) = (
                ga.transform.world_from_index,
                source.transform.world_from_index,
            );
            for (ra, rs) in wa.iter().zip(&ws) {
                for (x, y) in ra.iter().zip(rs) {
                    assert!(
                        (x - y).abs() <= 1e-12 * (1.0 + y.abs()),
                        "{what}: {wa:?} vs {ws:?}"
                    );
                }
            }
            let va = Volume::load(&nvdb, "density", 1.0).unwrap();
            let mut gb = gb;
            gb.transform = source.transform.clone();
            let vb = Volume::new(gb, 1.0, &back).unwrap();
            let answers = answers_diff(&va, &vb, &what);
            info_agrees(&nvdb, &back, case, &what);
            report.push(format!("{what}: values {tree:e}, answers {answers:e}"));
        }
    }
    eprintln!("{}", report.join("\n"));
}

#[test]
fn quantised_grids_are_close_to_the_source() {
    // Not NanoVDB's own decoding, but a check that the quantisation was applied and read: Fp16
    // is within 2^-16 of the leaf's range, Fp4 within 2^-4, of the source values.
    let Some(src) = corpus("gen/negative_coords.vdb") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let exact = umbra::input::load_grid(&src, "density").unwrap();
    let range = exact.tree.bounds();
    let span = f64::from(range.max - range.min);
    for (case, args, tol) in [
        ("fp16", &["--fp16"][..], 1.0 / 65535.0),
        ("fp4", &["--fp4"], 1.0 / 15.0),
    ] {
        let nvdb = tmp.path().join(format!("q.{case}.nvdb"));
        convert(args, &src, &nvdb);
        let q = umbra::input::load_grid(&nvdb, "density").unwrap();
        let mut worst = 0f64;
        let mut changed = false;
        for (i, leaf) in exact.tree.leaves().iter().enumerate() {
            let ours = q.tree.leaf_values(
                q.tree
                    .leaves()
                    .iter()
                    .position(|l| l.origin == leaf.origin)
                    .unwrap() as u32,
            );
            for (a, b) in exact.tree.leaf_values(i as u32).iter().zip(ours) {
                worst = worst.max(f64::from((a - b).abs()));
                changed |= a != b;
            }
        }
        assert!(changed, "{case}: quantised values equal the source exactly");
        assert!(
            worst <= tol * span * 0.5 + 1e-6,
            "{case}: {worst} vs span {span}"
        );
    }
}

/// `umbra info` on the `.nvdb` says what it says on the round trip, plus the NanoVDB keys.
fn info_agrees(nvdb: &Path, back: &Path, case: &str, what: &str) {
    use umbra::info::FileInfo;
    let a = FileInfo::read(nvdb, None).unwrap();
    let b = FileInfo::read(back, None).unwrap();
    assert_eq!((a.format, b.format), ("nvdb", "vdb"), "{what}");
    assert_eq!(a.grids.len(), b.grids.len(), "{what}");
    for (x, y) in a.grids.iter().zip(&b.grids) {
        assert!(
            x.error.is_none() && x.note.is_none(),
            "{what}: {:?}",
            x.error
        );
        assert_eq!(
            (
                &x.name,
                &x.value_type,
                &x.class,
                &x.index_bbox,
                x.active_voxels,
                x.leaf_count
            ),
            (
                &y.name,
                &y.value_type,
                &y.class,
                &y.index_bbox,
                y.active_voxels,
                y.leaf_count
            ),
            "{what}"
        );
        assert_eq!(
            (&x.tiles, &x.background, x.nan_count, x.inf_count),
            (&y.tiles, &y.background, y.nan_count, y.inf_count),
            "{what}"
        );
        assert_eq!(
            (&x.value_min, &x.value_max),
            (&y.value_min, &y.value_max),
            "{what}"
        );
        assert!(
            rel(x.value_sum.unwrap(), y.value_sum.unwrap()) <= 1e-9,
            "{what}: sums"
        );
        // nanovdb_convert's default checksum is partial (the head alone).
        assert_eq!(x.checksum.as_deref(), Some("partial"), "{what}");
        let codec = match case {
            "zip" => "ZIP",
            "blosc" => "BLOSC",
            _ => "NONE",
        };
        assert_eq!(x.codec.as_deref(), Some(codec), "{what}");
        let q = x.quantisation.as_deref().unwrap();
        // nanovdb_convert quantises float grids only.
        let want = if x.value_type == "float" && case.starts_with("fp") {
            case
        } else {
            "none"
        };
        assert_eq!(q, want, "{what}");
        assert!(
            y.codec.is_none() && y.checksum.is_none(),
            "{what}: .vdb grids have no NanoVDB keys"
        );
    }
}

#[test]
fn multi_grid_files_and_segments_give_every_grid_by_name() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let src = dir.join("gen/multigrid_smoke.vdb");
    let (zip, back) = pair(tmp.path(), &src, "zip", &["-z"]);
    for grid in ["density", "temperature", "velocity"] {
        let a = umbra::input::load_grid(&zip, grid).unwrap();
        let b = umbra::input::load_grid(&back, grid).unwrap();
        assert_eq!(a.name, grid);
        assert!(tree_diff(&a.tree, &b.tree, grid) <= 1e-6, "{grid}");
    }
    // A velocity grid is kept as its length, as the .vdb reader keeps a vec3s grid.
    let v = umbra::input::load_grid(&zip, "velocity").unwrap();
    assert_eq!(v.value_type, umbra::internals::vdb::ValueKind::Vec3s);
    let original = umbra::input::load_grid(&src, "velocity").unwrap();
    assert!(tree_diff(&v.tree, &original.tree, "velocity vs source") <= 1e-6);
    // Two segments back to back (another codec each): one file of every grid, in order.
    let blosc = tmp.path().join("one.blosc.nvdb");
    convert(&["-b"], &dir.join("gen/negative_coords.vdb"), &blosc);
    let both = tmp.path().join("both.nvdb");
    let mut bytes = std::fs::read(&zip).unwrap();
    bytes.extend(std::fs::read(&blosc).unwrap());
    std::fs::write(&both, bytes).unwrap();
    let file = umbra::input::GridFile::open(&both).unwrap();
    let missing = file.check_grid("nope").unwrap_err().to_string();
    assert!(
        missing.contains("density[0], temperature, velocity, density[1]"),
        "{missing}"
    );
    let second = file.load("density[1]").unwrap();
    let alone = umbra::input::load_grid(&blosc, "density").unwrap();
    assert_eq!(
        second.tree.stats().active_voxels,
        alone.tree.stats().active_voxels
    );
    assert!(tree_diff(&second.tree, &alone.tree, "second segment") == 0.0);
    assert!(
        file.lazy("density[1]").unwrap().is_none(),
        "no partial reads of a .nvdb grid"
    );
    let extent = file.extent("temperature").unwrap();
    let vol = Volume::load(&both, "temperature", 1.0).unwrap();
    assert_eq!(extent.value_box, vol.value_box());
}

#[test]
fn grid_types_umbra_does_not_decode_are_described_and_refused_cleanly() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let nvdb = tmp.path().join("flags.nvdb");
    convert(&[], &dir.join("gen/int32_flags.vdb"), &nvdb);
    let info = umbra::info::FileInfo::read(&nvdb, None).unwrap();
    let g = &info.grids[0];
    assert!(g.error.is_none(), "{:?}", g.error);
    assert!(g.note.as_deref().unwrap().contains("int32"), "{:?}", g.note);
    assert!(g.active_voxels.unwrap() > 0 && g.voxel_size.is_some());
    let e = umbra::input::load_grid(&nvdb, "flags").unwrap_err();
    assert!(matches!(e, umbra::Error::Unsupported { .. }), "{e}");
}

/// Load every grid of `path` through the input layer: `Err` or `Ok`, never a panic.
fn load_any(path: &Path) -> Result<(), String> {
    let file = umbra::input::GridFile::open(path).map_err(|e| e.to_string())?;
    for g in ["density", "temperature", "velocity"] {
        if file.check_grid(g).is_ok() {
            file.load(g).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}

#[test]
fn corrupt_files_end_in_one_clean_error() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let src = dir.join("gen/negative_coords.vdb");
    let mk = |name: &str, bytes: &[u8]| {
        let p = tmp.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let empty = mk("empty.nvdb", b"");
    let text = mk("text.nvdb", b"not a NanoVDB file at all, just some text\n");
    for (p, want) in [(&empty, "empty file"), (&text, "bad magic number")] {
        let e = umbra::input::GridFile::open(p).unwrap_err();
        assert!(matches!(e, umbra::Error::NotVdb { .. }), "{e}");
        assert!(
            e.to_string()
                .contains(&format!("not a NanoVDB file ({want})")),
            "{e}"
        );
    }
    for (case, args) in [
        ("none", &["-c", "full"][..]),
        ("zip", &["-z"]),
        ("blosc", &["-b"]),
        ("fpN", &["--fpN", "-a", "0.01", "-c", "full"]),
        // No checksum: flipped bytes reach the tree decoder itself.
        ("unchecked", &["--fp4", "-c", "none"]),
    ] {
        let good = tmp.path().join(format!("good.{case}.nvdb"));
        convert(args, &src, &good);
        let bytes = std::fs::read(&good).unwrap();
        load_any(&good).unwrap();
        // Truncated anywhere: the first 400 bytes one by one, then every 1/64 of the file.
        let n = bytes.len();
        let cuts = (0..400.min(n)).chain((1..64).map(|k| k * n / 64));
        for cut in cuts {
            let p = mk("cut.nvdb", &bytes[..cut]);
            let e = load_any(&p).expect_err(&format!("{case}: cut at {cut} loads"));
            assert!(!e.contains('\n') && e.contains("cut.nvdb"), "{e}");
        }
        // Without a checksum, every byte of the headers (segment, metadata, grid, tree, root
        // and its first tiles) flipped in turn; then bytes anywhere: a clean error or (where no checksum covers
        // the byte) a load.
        let sweep = if case == "unchecked" { 1200.min(n) } else { 0 };
        for at in 0..sweep {
            let mut b = bytes.clone();
            b[at] ^= 0x81;
            let p = mk("head.nvdb", &b);
            if let Err(e) = load_any(&p) {
                assert!(!e.contains('\n') && e.contains("head.nvdb"), "{e}");
            }
        }
        let mut x = 0x2545_f491_4f6c_dd1du64;
        // UMBRA_NVDB_FLIPS=N for a longer run.
        let flips: usize = std::env::var("UMBRA_NVDB_FLIPS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(300);
        for _ in 0..flips {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let mut b = bytes.clone();
            let at = (x % n as u64) as usize;
            b[at] ^= 1 << (x >> 61);
            let p = mk("flip.nvdb", &b);
            if let Err(e) = load_any(&p) {
                assert!(!e.contains('\n') && e.contains("flip.nvdb"), "{e}");
            }
        }
    }
    // Checksums: a flipped byte in the grid header (covered by the head CRC) or in a node
    // (covered by the full checksum's tail) is a mismatch; with no checksum it is not checked.
    let full = tmp.path().join("good.none.nvdb");
    let info = umbra::info::FileInfo::read(&full, None).unwrap();
    assert_eq!(info.grids[0].checksum.as_deref(), Some("full"));
    let mut b = std::fs::read(&full).unwrap();
    let grid = 16 + 176 + 8; // segment header, metadata, "density\0"
    b[grid + 300] ^= 4; // the map's f32 matrix, which umbra does not read
    let e = umbra::input::load_grid(mk("head.nvdb", &b), "density")
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch") && e.contains("head"), "{e}");
    let info = umbra::info::FileInfo::read(&tmp.path().join("head.nvdb"), None).unwrap();
    assert_eq!(info.grids[0].checksum.as_deref(), Some("mismatch"));
    let mut b = std::fs::read(&full).unwrap();
    let n = b.len();
    b[n - 100] ^= 1; // the last leaf's values
    let e = umbra::input::load_grid(mk("tail.nvdb", &b), "density")
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch") && e.contains("tail"), "{e}");
    let none = tmp.path().join("nocheck.nvdb");
    convert(&["-c", "none"], &src, &none);
    let info = umbra::info::FileInfo::read(&none, None).unwrap();
    assert_eq!(info.grids[0].checksum.as_deref(), Some("absent"));
    // Lying metadata: voxel count, leaf count, grid size, codec.
    let good = std::fs::read(&full).unwrap();
    for (at, what) in [
        (16 + 24, "voxel count"),
        (16 + 140, "node counts"),
        (16, "grid size"),
        (16 + 168, "codec"),
    ] {
        let mut b = good.clone();
        b[at] ^= 1;
        let e = umbra::input::load_grid(mk("lie.nvdb", &b), "density")
            .unwrap_err()
            .to_string();
        assert!(e.contains(what) && e.contains("lie.nvdb"), "{what}: {e}");
    }
}

/// The leaves of a `.nvdb` are decoded on every core (issue 61): the tree one worker decodes
/// is the tree two and four decode, bit for bit (every leaf's origin, masks and 512 values, in
/// the same order), for every codec and quantisation, and a larger real cache in many chunks.
#[test]
fn nvdb_decoded_in_parallel_is_the_serial_decode_bit_for_bit() {
    let Some(dir) = common::corpus_dir() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let decode = |path: &Path, threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| umbra::input::load_grid(path, "density").unwrap())
    };
    let mut files: Vec<PathBuf> = FILES.iter().map(|f| dir.join(f)).collect();
    files.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb"));
    for src in &files {
        for (case, args) in CASES {
            let (nvdb, _) = pair(tmp.path(), src, case, args);
            let serial = decode(&nvdb, 1);
            for threads in [2, 4] {
                let par = decode(&nvdb, threads);
                let (a, b) = (&serial.tree, &par.tree);
                let what = format!("{} {case}, {threads} threads", src.display());
                assert_eq!(a.leaves().len(), b.leaves().len(), "{what}");
                assert!(!a.leaves().is_empty(), "{what}: no leaves");
                for (i, (la, lb)) in a.leaves().iter().zip(b.leaves()).enumerate() {
                    assert_eq!(la.origin, lb.origin, "{what}: leaf {i}");
                    assert_eq!(la.value_mask, lb.value_mask, "{what}: leaf {i}");
                    let (va, vb) = (a.leaf_values(i as u32), b.leaf_values(i as u32));
                    assert!(
                        va.iter().zip(vb).all(|(x, y)| x.to_bits() == y.to_bits()),
                        "{what}: leaf {i}'s values"
                    );
                }
                assert_eq!(a.background().to_bits(), b.background().to_bits(), "{what}");
                assert_eq!(a.stats().active_voxels, b.stats().active_voxels, "{what}");
            }
        }
    }
}
