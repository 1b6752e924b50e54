//! NanoVDB 32.5 to 32.8 grids (issue 58) in the file forms their writers use, built here from a
//! grid Debian's `nanovdb_convert` (32.4) wrote: the grid buffer's layout did not change from
//! 32.4 to 32.8, only its magic number ("NanoVDB1" from 32.7, "NanoVDB0" with "NanoVDB1" in
//! `mData2` in 32.6), its version and its checksum. Each form must decode to the very tree the
//! 32.4 file gives:
//!
//! - Warp's `save_to_nvdb`: a 32.3.3 file header, metadata with only the sizes, type, class,
//!   world bbox, voxel size, name and codec (counts, index bbox and name key zero), a ZIP blob
//!   whose u64 byte count is not in the file size, the tree header's tile counts set to its node
//!   counts (Warp's builder does so); no checksum. (`python/tests/test_nvdb_warp.py` checks files
//!   Warp itself writes against Warp's own lookups.)
//! - NanoVDB 32.7+ (`nanovdb_convert` of OpenVDB 12, fVDB): the "NanoVDB2" segment header, full
//!   or partial checksums of the 32.7 kind (head: the grid and tree headers; tail: the blocked
//!   CRC-32 of the rest); and a 32.6 grid with its own checksum kind.
//!
//! The checksums are computed here from `GridChecksum.h`'s description (no NanoVDB of 32.7 or
//! later is installable here to write them: Warp leaves them out). A version umbra does not read
//! is refused by name; hostile bytes in the new forms end in one clean error.

use crate::common;
use crate::nvdb::tree_diff;
use std::path::{Path, PathBuf};

const MAGIC_OLD: &[u8; 8] = b"NanoVDB0";
const MAGIC_GRID: &[u8; 8] = b"NanoVDB1";
const MAGIC_FILE: &[u8; 8] = b"NanoVDB2";

fn version(major: u32, minor: u32, patch: u32) -> u32 {
    major << 21 | minor << 10 | patch
}

fn crc32(b: &[u8]) -> u32 {
    let mut c = flate2::Crc::new();
    c.update(b);
    c.sum()
}

/// NanoVDB's blocked CRC-32: the CRC-32 of the u32 CRC-32s of 4096-byte blocks, the last block
/// taking the remainder.
fn blocked(b: &[u8]) -> u32 {
    let n = b.len() / 4096;
    let mut crcs = Vec::new();
    for i in 0..n {
        let end = if i + 1 == n { b.len() } else { (i + 1) * 4096 };
        crcs.extend(crc32(&b[i * 4096..end]).to_le_bytes());
    }
    crc32(&crcs)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// A one-grid, uncompressed, unchecked `.nvdb` of `nanovdb_convert`: metadata, name, grid.
struct Source {
    meta: Vec<u8>,
    name: Vec<u8>,
    grid: Vec<u8>,
}

fn source(dir: &Path, rel: &str) -> (Source, PathBuf) {
    let src = common::corpus_dir().unwrap().join(rel);
    let stem = src.file_stem().unwrap().to_string_lossy().to_string();
    let nvdb = dir.join(format!("{stem}.32_4.nvdb"));
    common::nanovdb_convert(&["-c", "none"], &src, &nvdb);
    let b = std::fs::read(&nvdb).unwrap();
    let name_size = u32::from_le_bytes(b[16 + 136..16 + 140].try_into().unwrap()) as usize;
    let at = 16 + 176 + name_size;
    let s = Source {
        meta: b[16..16 + 176].to_vec(),
        name: b[16 + 176..at].to_vec(),
        grid: b[at..].to_vec(),
    };
    assert_eq!(s.grid.len() as u64, u64_at(&s.meta, 0), "one grid");
    (s, nvdb)
}

/// The grid as NanoVDB `minor` writes it: its magic number and version; 32.6 keeps "NanoVDB0"
/// and puts "NanoVDB1" in `mData2` (byte 664).
fn grid_of(s: &Source, minor: u32) -> Vec<u8> {
    let mut g = s.grid.clone();
    if minor >= 7 {
        g[..8].copy_from_slice(MAGIC_GRID);
    } else {
        g[664..672].copy_from_slice(MAGIC_GRID);
    }
    g[16..20].copy_from_slice(&version(32, minor, 0).to_le_bytes());
    g
}

/// Set the checksum as NanoVDB of the grid's version computes it (`full`: the tail too).
fn checksum(g: &mut [u8], full: bool) {
    let minor = (u32::from_le_bytes(g[16..20].try_into().unwrap()) >> 10) & 0x7ff;
    // 32.7 on: the grid and tree headers; 32.6: up to the first upper node.
    let mid = if minor >= 7 {
        672 + 64
    } else {
        672 + u64_at(g, 672 + 16) as usize
    };
    let head = crc32(&g[16..mid]);
    let tail = if full { blocked(&g[mid..]) } else { u32::MAX };
    let sum = u64::from(head) | u64::from(tail) << 32;
    g[8..16].copy_from_slice(&sum.to_le_bytes());
}

/// A file as Warp's `save_to_nvdb` writes one grid `g` named `name` with `codec` (0 NONE, 1 ZIP).
fn warp_file(g: &[u8], name: &[u8], codec: u16) -> Vec<u8> {
    let blob = match codec {
        0 => g.to_vec(),
        _ => {
            use std::io::Write;
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            z.write_all(g).unwrap();
            z.finish().unwrap()
        }
    };
    let v = version(32, 3, 3);
    let mut f = Vec::new();
    f.extend(MAGIC_OLD);
    f.extend(v.to_le_bytes());
    f.extend(1u16.to_le_bytes());
    f.extend(codec.to_le_bytes());
    let mut m = vec![0u8; 176];
    m[0..8].copy_from_slice(&(g.len() as u64).to_le_bytes());
    m[8..16].copy_from_slice(&(blob.len() as u64).to_le_bytes());
    m[32..36].copy_from_slice(&g[636..640]);
    m[36..40].copy_from_slice(&g[632..636]);
    m[40..88].copy_from_slice(&g[560..608]); // world bbox
    m[112..136].copy_from_slice(&g[608..632]); // voxel size
    m[136..140].copy_from_slice(&(name.len() as u32 + 1).to_le_bytes());
    m[168..170].copy_from_slice(&codec.to_le_bytes());
    m[172..176].copy_from_slice(&v.to_le_bytes());
    f.extend(m);
    f.extend(name);
    f.push(0);
    if codec != 0 {
        f.extend((blob.len() as u64).to_le_bytes());
    }
    f.extend(blob);
    f
}

/// Warp's grid: the tree header's tile counts are its node counts.
fn warp_grid(s: &Source) -> Vec<u8> {
    let mut g = grid_of(s, 8);
    let counts = g[672 + 32..672 + 44].to_vec();
    g[672 + 44..672 + 56].copy_from_slice(&counts);
    g
}

/// A file as NanoVDB `minor` writes it: header magic `magic`, its metadata version `minor`.
fn nanovdb_file(s: &Source, g: &[u8], magic: &[u8; 8], minor: u32) -> Vec<u8> {
    let v = version(32, minor, 0);
    let mut f = Vec::new();
    f.extend(magic);
    f.extend(v.to_le_bytes());
    f.extend(1u16.to_le_bytes());
    f.extend(0u16.to_le_bytes());
    let mut m = s.meta.clone();
    m[172..176].copy_from_slice(&v.to_le_bytes());
    f.extend(m);
    f.extend(&s.name);
    f.extend(g);
    f
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

fn checksum_of(p: &Path) -> String {
    let info = umbra::info::FileInfo::read(p, None).unwrap();
    let g = &info.grids[0];
    assert!(g.error.is_none(), "{}: {:?}", p.display(), g.error);
    g.checksum.clone().unwrap()
}

#[test]
fn newer_grids_in_every_writers_form_decode_as_the_32_4_grid() {
    if common::corpus_dir().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    // Affine rotated map; tiles at every level; a double grid.
    for rel in [
        "gen/xform_affine_rotated.vdb",
        "gen/tiles_mixed.vdb",
        "real/double_density_dense_128x64x64.vdb",
    ] {
        let (s, old) = source(d, rel);
        let name = String::from_utf8_lossy(&s.name[..s.name.len() - 1]).to_string();
        let want = umbra::input::load_grid(&old, &name).unwrap();
        let mut full_28 = grid_of(&s, 8);
        checksum(&mut full_28, true);
        let mut partial_27 = grid_of(&s, 7);
        checksum(&mut partial_27, false);
        let mut full_26 = grid_of(&s, 6);
        checksum(&mut full_26, true);
        let warp = warp_grid(&s);
        let named = &s.name[..s.name.len() - 1];
        let files = [
            ("warp none", warp_file(&warp, named, 0), "absent"),
            ("warp zip", warp_file(&warp, named, 1), "absent"),
            (
                "32.8 full",
                nanovdb_file(&s, &full_28, MAGIC_FILE, 8),
                "full",
            ),
            (
                "32.7 partial",
                nanovdb_file(&s, &partial_27, MAGIC_OLD, 7),
                "partial",
            ),
            (
                "32.6 full",
                nanovdb_file(&s, &full_26, MAGIC_OLD, 6),
                "full",
            ),
        ];
        for (what, bytes, kind) in files {
            let what = format!("{rel} {what}");
            let p = write(d, "new.nvdb", &bytes);
            let got = umbra::input::load_grid(&p, &name).unwrap_or_else(|e| panic!("{what}: {e}"));
            assert_eq!(
                got.tree.stats().active_voxels,
                want.tree.stats().active_voxels
            );
            assert_eq!(tree_diff(&got.tree, &want.tree, &what), 0.0, "{what}");
            assert_eq!(
                got.transform.world_from_index, want.transform.world_from_index,
                "{what}"
            );
            assert_eq!(checksum_of(&p), kind, "{what}");
            let info = umbra::info::FileInfo::read(&p, None).unwrap();
            assert_eq!(
                info.grids[0].nanovdb_version.as_deref(),
                Some(if what.contains("32.7") {
                    "32.7.0"
                } else if what.contains("32.6") {
                    "32.6.0"
                } else {
                    "32.8.0"
                }),
                "{what}"
            );
        }
    }
}

#[test]
fn unnamed_warp_grids_are_reachable_as_their_index() {
    if common::corpus_dir().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let (s, old) = source(tmp.path(), "gen/negative_coords.vdb");
    let mut g = warp_grid(&s);
    g[40..296].fill(0); // no name
    let p = write(tmp.path(), "unnamed.nvdb", &warp_file(&g, b"", 1));
    let got = umbra::input::load_grid(&p, "[0]").unwrap();
    assert_eq!(got.name, "[0]");
    let want = umbra::input::load_grid(&old, "density").unwrap();
    assert_eq!(tree_diff(&got.tree, &want.tree, "unnamed"), 0.0);
    let e = umbra::input::load_grid(&p, "density")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("no grid named 'density' (available: [0])"),
        "{e}"
    );
}

#[test]
fn versions_umbra_does_not_read_are_refused_by_name() {
    if common::corpus_dir().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (s, _) = source(d, "gen/negative_coords.vdb");
    for (major, minor) in [(33u32, 0u32), (32, 9)] {
        let v = version(major, minor, 0);
        // In the grid (Warp's header says 32.3.3 whatever the grid).
        let mut g = warp_grid(&s);
        g[16..20].copy_from_slice(&v.to_le_bytes());
        let p = write(d, "v.nvdb", &warp_file(&g, b"density", 0));
        let e = umbra::input::load_grid(&p, "density").unwrap_err();
        assert!(matches!(e, umbra::Error::Unsupported { .. }), "{e}");
        let want = format!("NanoVDB {major}.{minor}.0 grid 'density': not supported");
        assert!(e.to_string().contains(&want), "{e}");
        let info = umbra::info::FileInfo::read(&p, None).unwrap();
        let err = info.grids[0].error.clone().unwrap();
        assert!(err.contains(&want) && !err.contains("corrupt"), "{err}");
        // In the file header.
        let mut f = nanovdb_file(&s, &grid_of(&s, 8), MAGIC_FILE, 8);
        f[8..12].copy_from_slice(&v.to_le_bytes());
        let p = write(d, "h.nvdb", &f);
        let e = umbra::input::GridFile::open(&p).unwrap_err();
        assert!(matches!(e, umbra::Error::Unsupported { .. }), "{e}");
        assert!(
            e.to_string()
                .contains(&format!("NanoVDB {major}.{minor}.0 file header")),
            "{e}"
        );
    }
}

#[test]
fn newer_checksums_catch_what_they_cover() {
    if common::corpus_dir().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (s, _) = source(d, "gen/negative_coords.vdb");
    let flip = |full: bool, at: usize| {
        let mut g = grid_of(&s, 8);
        checksum(&mut g, full);
        let n = g.len();
        g[at.min(n - 1)] ^= 1;
        nanovdb_file(&s, &g, MAGIC_FILE, 8)
    };
    let n = s.grid.len();
    // The map's f32 matrix (umbra reads the f64 one): the head tells.
    let p = write(d, "head.nvdb", &flip(false, 300));
    let e = umbra::input::load_grid(&p, "density").unwrap_err();
    assert!(matches!(e, umbra::Error::InvalidNanoVdb { .. }), "{e}");
    let e = e.to_string();
    assert!(
        e.contains("corrupt NanoVDB file") && e.contains("checksum mismatch") && e.contains("head"),
        "{e}"
    );
    // The last leaf's values: a full checksum's tail tells; a partial one does not cover them.
    let p = write(d, "tail.nvdb", &flip(true, n - 100));
    let e = umbra::input::load_grid(&p, "density")
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch") && e.contains("tail"), "{e}");
    let p = write(d, "partial.nvdb", &flip(false, n - 100));
    assert!(umbra::input::load_grid(&p, "density").is_ok());
    assert_eq!(checksum_of(&p), "partial");
    // The root (its minimum, which umbra does not read): in the head before 32.7, in the tail
    // from 32.7 on.
    let root = 672 + u64_at(&s.grid, 672 + 24) as usize;
    let p = write(d, "root.nvdb", &flip(true, root + 33));
    let e = umbra::input::load_grid(&p, "density")
        .unwrap_err()
        .to_string();
    assert!(e.contains("checksum mismatch") && e.contains("tail"), "{e}");
}

#[test]
fn hostile_bytes_in_the_new_forms_end_in_one_clean_error() {
    if common::corpus_dir().is_none() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (s, _) = source(d, "gen/negative_coords.vdb");
    let mut full = grid_of(&s, 8);
    checksum(&mut full, true);
    let warp = warp_grid(&s);
    for (what, bytes) in [
        ("warp zip", warp_file(&warp, b"density", 1)),
        ("warp none", warp_file(&warp, b"density", 0)),
        ("32.8", nanovdb_file(&s, &full, MAGIC_FILE, 8)),
    ] {
        let n = bytes.len();
        let load = |b: &[u8]| -> Result<(), String> {
            let p = write(d, "x.nvdb", b);
            let f = umbra::input::GridFile::open(&p).map_err(|e| e.to_string())?;
            f.load("density").map(|_| ()).map_err(|e| e.to_string())
        };
        load(&bytes).unwrap();
        let cuts = (0..300.min(n)).chain((1..32).map(|k| k * n / 32));
        for cut in cuts {
            let e = load(&bytes[..cut]).expect_err(&format!("{what}: cut at {cut} loads"));
            assert!(!e.contains('\n') && e.contains("x.nvdb"), "{what}: {e}");
        }
        // Every header byte (file header, metadata, grid, tree) flipped, then bytes anywhere.
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let picks = (0..1000.min(n)).chain((0..300).map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % n as u64) as usize
        }));
        for at in picks.collect::<Vec<_>>() {
            let mut b = bytes.clone();
            b[at] ^= 0x81;
            if let Err(e) = load(&b) {
                assert!(
                    !e.contains('\n') && e.contains("x.nvdb"),
                    "{what} at {at}: {e}"
                );
            }
        }
    }
}
