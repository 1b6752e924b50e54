//! Deterministic mutation fuzzing of the loader: truncated copies and copies with flipped bytes
//! or extreme 4/8-byte values, spread over the header, the grid descriptors, the grid metadata
//! and transform, the topology and the leaf buffers of corpus files. Opening and loading every
//! grid of every mutant must return `Ok` or a typed `Err`: never panic, never hang, never
//! allocate gigabytes.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{corpus_dir, panic_message, peak_rss_bytes};
use rand::{Rng, SeedableRng};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use umbra::info::GridInfo;

const FILES: &[&str] = &[
    "gen/puff_blosc.vdb",
    "gen/puff_zip.vdb",
    "gen/cloud_fbm_half.vdb",
    "gen/tiles_mixed.vdb",
    "real/openvdb_smoke1_houdini_v222.vdb",
    "gen/puff_none.vdb",
    "gen/xform_affine_rotated.vdb",
    "gen/bool_mask.vdb",
    "real/blender_smoke_fluid_data_0050.vdb",
];
const SEED: u64 = 0x756d_6272_615f_6d75; // "umbra_mu"
/// Truncate at every offset below this.
const DENSE_TRUNCATION_BYTES: u64 = 300;
const RANDOM_TRUNCATIONS_PER_FILE: usize = 40;
const FLIPS_PER_FILE: usize = 140;
const OVERWRITES_PER_FILE: usize = 140;
const RSS_LIMIT: u64 = 2 << 30;
const SLOW_CASE: Duration = Duration::from_secs(10);

#[derive(Debug, Clone)]
enum Mutation {
    /// Keep only the first `n` bytes.
    Truncate(u64),
    /// XOR one byte.
    Flip { at: u64, xor: u8 },
    /// Overwrite bytes at `at` (4 or 8 little-endian bytes of an extreme value).
    Overwrite { at: u64, bytes: Vec<u8> },
}

impl std::fmt::Display for Mutation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Truncate(n) => write!(f, "truncate to {n} bytes"),
            Self::Flip { at, xor } => write!(f, "xor byte {at} with {xor:#04x}"),
            Self::Overwrite { at, bytes } => write!(f, "overwrite bytes {at}.. with {bytes:02x?}"),
        }
    }
}

#[derive(Debug, Clone)]
struct Case {
    file: usize,
    region: &'static str,
    mutation: Mutation,
}

/// Byte ranges of one source file, from umbra's own reading of the unmutated file.
struct Layout {
    len: u64,
    /// (region name, start, end) half-open ranges, possibly several per name (one per grid).
    regions: Vec<(&'static str, u64, u64)>,
    /// Structure boundaries worth truncating at.
    boundaries: Vec<u64>,
}

const REGIONS: &[&str] = &[
    "header",
    "descriptor",
    "grid metadata+transform",
    "topology",
    "buffers",
];

fn layout(path: &Path) -> Layout {
    let a = umbra::vdb::open(path).unwrap();
    let len = a.file_len;
    let mut regions = Vec::new();
    let mut boundaries = Vec::new();
    assert!(
        !a.grids.is_empty(),
        "{}: mutation sources need grids",
        path.display()
    );
    let mut desc_start = {
        // Descriptor: name, type (with _HalfFloat), parent strings with u32 lengths, 3 x i64.
        let g = &a.grids[0];
        let half = if g.saved_as_half {
            "_HalfFloat".len()
        } else {
            0
        };
        let n = 12 + g.stored_name.len() + g.tree_type.len() + half + g.instance_parent.len() + 24;
        g.grid_pos - n as u64
    };
    regions.push(("header", 0, desc_start));
    for g in &a.grids {
        regions.push(("descriptor", desc_start, g.grid_pos));
        regions.push((
            "grid metadata+transform",
            g.grid_pos,
            (g.grid_pos + 1024).min(g.block_pos),
        ));
        regions.push(("topology", g.grid_pos, g.block_pos));
        regions.push(("buffers", g.block_pos, g.end_pos));
        for b in [desc_start, g.grid_pos, g.block_pos, g.end_pos] {
            boundaries.extend([b.saturating_sub(1), b, b + 1]);
        }
        desc_start = g.end_pos;
    }
    boundaries.retain(|&b| b < len);
    regions.retain(|r| r.1 < r.2);
    Layout {
        len,
        regions,
        boundaries,
    }
}

fn extreme_bytes(rng: &mut rand_pcg::Pcg64) -> Vec<u8> {
    const V32: [u32; 7] = [
        0xFFFF_FFFF,
        0x7FFF_FFFF,
        0x8000_0000,
        0,
        1,
        0x7F80_0000,
        0xFFFF_FFFE,
    ];
    const V64: [u64; 6] = [
        u64::MAX,
        0x7FFF_FFFF_FFFF_FFFF,
        0x8000_0000_0000_0000,
        0,
        0x7FFF_FFFF,
        0x7FF0_0000_0000_0000, // +inf as f64
    ];
    match rng.gen_range(0..5) {
        0 | 1 => V32[rng.gen_range(0..V32.len())].to_le_bytes().to_vec(),
        2 | 3 => V64[rng.gen_range(0..V64.len())].to_le_bytes().to_vec(),
        _ => rng.gen::<u64>().to_le_bytes().to_vec(),
    }
}

fn make_cases(layouts: &[Layout]) -> Vec<Case> {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(SEED);
    let mut cases = Vec::new();
    for (file, l) in layouts.iter().enumerate() {
        let mut push = |region, mutation| {
            cases.push(Case {
                file,
                region,
                mutation,
            });
        };
        for n in 0..DENSE_TRUNCATION_BYTES.min(l.len) {
            push("truncation (dense)", Mutation::Truncate(n));
        }
        for &b in &l.boundaries {
            push("truncation (boundary)", Mutation::Truncate(b));
        }
        for _ in 0..RANDOM_TRUNCATIONS_PER_FILE {
            push(
                "truncation (random)",
                Mutation::Truncate(rng.gen_range(DENSE_TRUNCATION_BYTES..l.len)),
            );
        }
        for i in 0..FLIPS_PER_FILE + OVERWRITES_PER_FILE {
            // Round-robin over the regions so small ones (header, descriptors) get their share.
            let region = REGIONS[i % REGIONS.len()];
            let spans: Vec<(u64, u64)> = l
                .regions
                .iter()
                .filter(|r| r.0 == region)
                .map(|r| (r.1, r.2))
                .collect();
            let (lo, hi) = spans[rng.gen_range(0..spans.len())];
            let at = rng.gen_range(lo..hi);
            let mutation = if i < FLIPS_PER_FILE {
                let xor = if rng.gen_bool(0.5) {
                    1u8 << rng.gen_range(0..8)
                } else {
                    rng.gen_range(1..=255)
                };
                Mutation::Flip { at, xor }
            } else {
                let mut bytes = extreme_bytes(&mut rng);
                bytes.truncate((l.len - at) as usize);
                Mutation::Overwrite { at, bytes }
            };
            push(region, mutation);
        }
    }
    cases
}

#[derive(Debug, Clone)]
enum Outcome {
    OpenErr(&'static str),
    /// Opened; (grids loaded Ok, grids that failed, kind of the first error).
    Loaded(usize, usize, Option<&'static str>),
    Panic(String),
}

fn kind(e: &umbra::Error) -> &'static str {
    match e {
        umbra::Error::Io { .. } => "Io",
        umbra::Error::NotVdb { .. } => "NotVdb",
        umbra::Error::Invalid { .. } => "Invalid",
        umbra::Error::Unsupported { .. } => "Unsupported",
        umbra::Error::GridNotFound { .. } => "GridNotFound",
        umbra::Error::InvalidArgument { .. } => "InvalidArgument",
        _ => "other",
    }
}

/// Open `path` and load every grid (and report on it as `umbra info` does), catching panics.
fn try_load(path: &Path) -> Outcome {
    let r = catch_unwind(AssertUnwindSafe(|| {
        let a = match umbra::vdb::open(path) {
            Ok(a) => a,
            Err(e) => return Outcome::OpenErr(kind(&e)),
        };
        let (mut ok, mut failed, mut first) = (0, 0, None);
        for gd in &a.grids {
            match a.load(gd) {
                Ok(g) => {
                    std::hint::black_box(GridInfo::from_grid(&g, &gd.tree_type));
                    ok += 1;
                }
                Err(e) => {
                    failed += 1;
                    first.get_or_insert(kind(&e));
                }
            }
        }
        Outcome::Loaded(ok, failed, first)
    }));
    r.unwrap_or_else(|p| Outcome::Panic(panic_message(p.as_ref())))
}

/// Panic locations seen by the hook (the payload carries only the message).
static PANIC_SITES: Mutex<Vec<String>> = Mutex::new(Vec::new());

#[test]
fn mutated_corpus_files_never_panic() {
    let Some(dir) = corpus_dir() else { return };
    let started = Instant::now();
    let sources: Vec<PathBuf> = FILES.iter().map(|f| dir.join(f)).collect();
    let originals: Vec<Vec<u8>> = sources.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let layouts: Vec<Layout> = sources.iter().map(|p| layout(p)).collect();
    let cases = make_cases(&layouts);
    let tmp = tempfile::tempdir().unwrap();

    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|info| {
        let site = info
            .location()
            .map_or("?".into(), |l| format!("{}:{}", l.file(), l.line()));
        let msg = panic_message(info.payload());
        PANIC_SITES
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(format!("{msg} (at {site})"));
    }));

    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(4);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<(Outcome, Duration)>>> = Mutex::new(vec![None; cases.len()]);
    std::thread::scope(|s| {
        for t in 0..threads {
            let (cases, originals, next, results, tmp) =
                (&cases, &originals, &next, &results, tmp.path());
            s.spawn(move || {
                // One working copy per source file, patched in place and restored after each case.
                let work: Vec<PathBuf> = (0..FILES.len())
                    .map(|f| tmp.join(format!("w{t}_{f}.vdb")))
                    .collect();
                for (w, o) in work.iter().zip(originals) {
                    std::fs::write(w, o).unwrap();
                }
                let trunc = tmp.join(format!("t{t}.vdb"));
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(case) = cases.get(i) else { break };
                    let orig = &originals[case.file];
                    let t0 = Instant::now();
                    let outcome = match &case.mutation {
                        Mutation::Truncate(n) => {
                            std::fs::write(&trunc, &orig[..*n as usize]).unwrap();
                            try_load(&trunc)
                        }
                        Mutation::Flip { at, xor } => {
                            let f = File::options().write(true).open(&work[case.file]).unwrap();
                            f.write_all_at(&[orig[*at as usize] ^ xor], *at).unwrap();
                            let o = try_load(&work[case.file]);
                            f.write_all_at(&orig[*at as usize..=*at as usize], *at)
                                .unwrap();
                            o
                        }
                        Mutation::Overwrite { at, bytes } => {
                            let f = File::options().write(true).open(&work[case.file]).unwrap();
                            f.write_all_at(bytes, *at).unwrap();
                            let o = try_load(&work[case.file]);
                            let a = *at as usize;
                            f.write_all_at(&orig[a..a + bytes.len()], *at).unwrap();
                            o
                        }
                    };
                    results.lock().unwrap()[i] = Some((outcome, t0.elapsed()));
                }
            });
        }
    });
    std::panic::set_hook(default_hook);

    let results: Vec<(Outcome, Duration)> = results
        .into_inner()
        .unwrap()
        .into_iter()
        .map(Option::unwrap)
        .collect();
    let mut failures = Vec::new();
    let (mut open_err, mut load_err, mut ok, mut partial) = (0, 0, 0, 0);
    let mut kinds = std::collections::BTreeMap::<&str, usize>::new();
    let mut slowest = (Duration::ZERO, 0);
    for (i, (case, (outcome, took))) in cases.iter().zip(&results).enumerate() {
        let what = format!("{} [{}] {}", FILES[case.file], case.region, case.mutation);
        if *took > slowest.0 {
            slowest = (*took, i);
        }
        if *took > SLOW_CASE {
            failures.push(format!("{what}: took {took:?}"));
        }
        let first_kind = match outcome {
            Outcome::Panic(msg) => {
                failures.push(format!("{what}: PANIC: {msg}"));
                None
            }
            Outcome::OpenErr(k) => {
                open_err += 1;
                Some(*k)
            }
            Outcome::Loaded(_, 0, _) => {
                ok += 1;
                None
            }
            Outcome::Loaded(n_ok, _, k) => {
                load_err += 1;
                if *n_ok > 0 {
                    partial += 1;
                }
                *k
            }
        };
        if let Some(k) = first_kind {
            *kinds.entry(k).or_default() += 1;
            // A regular, readable file can only be not-a-VDB, corrupt or unsupported.
            if !matches!(k, "NotVdb" | "Invalid" | "Unsupported") {
                failures.push(format!("{what}: unexpected error kind {k}"));
            }
        }
        // Every truncation is shorter than the file, so the last grid's end offset is past EOF.
        if matches!(case.mutation, Mutation::Truncate(_))
            && matches!(outcome, Outcome::Loaded(_, 0, _))
        {
            failures.push(format!("{what}: truncated file loaded without error"));
        }
    }
    let rss = peak_rss_bytes();
    let elapsed = started.elapsed();
    eprintln!(
        "mutation fuzz: {} cases over {} files in {elapsed:.1?} on {threads} threads: {open_err} failed \
         to open, {load_err} opened but a grid failed ({partial} with other grids loaded), {ok} loaded \
         Ok; error kinds {kinds:?}; slowest case {:?} ({} [{}] {}); peak RSS {} MiB",
        cases.len(),
        FILES.len(),
        slowest.0,
        FILES[cases[slowest.1].file],
        cases[slowest.1].region,
        cases[slowest.1].mutation,
        rss.map_or("?".into(), |b| (b >> 20).to_string()),
    );
    if !failures.is_empty() {
        let mut sites = PANIC_SITES.lock().unwrap().clone();
        sites.sort();
        sites.dedup();
        panic!(
            "{} of {} mutation cases failed:\n{}\npanic sites:\n{}",
            failures.len(),
            cases.len(),
            failures.join("\n"),
            sites.join("\n")
        );
    }
    assert!(cases.len() >= 3000, "only {} mutation cases", cases.len());
    assert!(
        ok > 0 && open_err + load_err > 0,
        "mutations should both pass and fail sometimes"
    );
    if let Some(rss) = rss {
        assert!(
            rss < RSS_LIMIT,
            "peak RSS {} MiB exceeds {} MiB",
            rss >> 20,
            RSS_LIMIT >> 20
        );
    }
}
