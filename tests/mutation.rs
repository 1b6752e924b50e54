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

/// Source files and how many byte-level mutations (half flips, half overwrites) each gets:
/// fewer for the files that take longest to load, to keep the test fast.
const SOURCES: &[(&str, usize)] = &[
    ("gen/puff_blosc.vdb", 200),
    ("gen/puff_zip.vdb", 160),
    ("gen/cloud_fbm_half.vdb", 60),
    ("gen/tiles_mixed.vdb", 60),
    ("real/openvdb_smoke1_houdini_v222.vdb", 120),
    ("gen/puff_none.vdb", 120),
    ("gen/xform_affine_rotated.vdb", 100),
    ("gen/bool_mask.vdb", 120),
    ("real/blender_smoke_fluid_data_0050.vdb", 100),
];
const SEED: u64 = 0x756d_6272_615f_6d75; // "umbra_mu"
/// Truncate at every offset below this.
const DENSE_TRUNCATION_BYTES: u64 = 300;
const RANDOM_TRUNCATIONS_PER_FILE: usize = 40;
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

impl Mutation {
    /// The mutated copy of `orig`.
    fn apply(&self, orig: &[u8]) -> Vec<u8> {
        match self {
            Self::Truncate(n) => orig[..*n as usize].to_vec(),
            Self::Flip { at, xor } => {
                let mut v = orig.to_vec();
                v[*at as usize] ^= xor;
                v
            }
            Self::Overwrite { at, bytes } => {
                let mut v = orig.to_vec();
                v[*at as usize..*at as usize + bytes.len()].copy_from_slice(bytes);
                v
            }
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
    "grid metadata",
    "transform",
    "topology",
    "buffers",
];

/// Where a grid's metadata and transform end: after the u32 compression flags come the
/// metadata map (u32 count; per entry name, type name and a u32-sized value) and the transform
/// (map type name, then the map's f64 parameters).
fn grid_sections(file: &[u8], grid_pos: u64) -> (u64, u64) {
    let mut at = grid_pos as usize + 4;
    let u32_at = |at: &mut usize| {
        let v = u32::from_le_bytes(file[*at..*at + 4].try_into().unwrap()) as usize;
        *at += 4;
        v
    };
    let count = u32_at(&mut at);
    for _ in 0..count {
        for _ in 0..3 {
            let n = u32_at(&mut at);
            at += n;
        }
    }
    let meta_end = at;
    let n = u32_at(&mut at);
    let map = std::str::from_utf8(&file[at..at + n]).unwrap();
    at += n;
    at += match map {
        "UniformScaleMap" | "ScaleMap" => 5 * 24,
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => 6 * 24,
        "TranslationMap" => 24,
        "AffineMap" | "UnitaryMap" => 16 * 8,
        other => panic!("mutation source with an unexpected map {other}"),
    };
    (meta_end as u64, at as u64)
}

fn layout(path: &Path) -> Layout {
    let a = umbra::vdb::open(path).unwrap();
    let file = std::fs::read(path).unwrap();
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
        let (meta_end, xform_end) = grid_sections(&file, g.grid_pos);
        regions.push(("grid metadata", g.grid_pos, meta_end));
        regions.push(("transform", meta_end, xform_end));
        regions.push(("topology", xform_end, g.block_pos));
        regions.push(("buffers", g.block_pos, g.end_pos));
        for b in [
            desc_start,
            g.grid_pos,
            meta_end,
            xform_end,
            g.block_pos,
            g.end_pos,
        ] {
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
        let byte_mutations = SOURCES[file].1;
        for i in 0..byte_mutations {
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
            let mutation = if i < byte_mutations / 2 {
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

thread_local! {
    /// Set on fuzz worker threads, whose expected-to-be-caught panics are recorded quietly.
    static IN_FUZZ: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Record every panic's message and location; print it as usual unless it happened on a fuzz
/// worker (where it is caught and reported as a failed case).
fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let site = info
                .location()
                .map_or("?".into(), |l| format!("{}:{}", l.file(), l.line()));
            let msg = panic_message(info.payload());
            PANIC_SITES
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .push(format!("{msg} (at {site})"));
            if !IN_FUZZ.with(std::cell::Cell::get) {
                default_hook(info);
            }
        }));
    });
}

#[test]
fn mutated_corpus_files_never_panic() {
    let Some(dir) = corpus_dir() else { return };
    let started = Instant::now();
    let sources: Vec<PathBuf> = SOURCES.iter().map(|f| dir.join(f.0)).collect();
    let originals: Vec<Vec<u8>> = sources.iter().map(|p| std::fs::read(p).unwrap()).collect();
    let layouts: Vec<Layout> = sources.iter().map(|p| layout(p)).collect();
    let cases = make_cases(&layouts);
    let tmp = tempfile::tempdir().unwrap();

    install_panic_hook();

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
                IN_FUZZ.with(|f| f.set(true));
                // One working copy per source file, patched in place and restored after each case.
                let work: Vec<PathBuf> = (0..SOURCES.len())
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
    // Per region: (cases, errors).
    let mut by_region = std::collections::BTreeMap::<&str, (usize, usize)>::new();
    let mut time_per_file = vec![Duration::ZERO; SOURCES.len()];
    for (i, (case, (outcome, took))) in cases.iter().zip(&results).enumerate() {
        let what = format!(
            "{} [{}] {}",
            SOURCES[case.file].0, case.region, case.mutation
        );
        time_per_file[case.file] += *took;
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
        let tally = by_region.entry(case.region).or_default();
        tally.0 += 1;
        tally.1 += usize::from(first_kind.is_some());
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
        SOURCES.len(),
        slowest.0,
        SOURCES[cases[slowest.1].file].0,
        cases[slowest.1].region,
        cases[slowest.1].mutation,
        rss.map_or("?".into(), |b| (b >> 20).to_string()),
    );
    eprintln!("  per region (cases, errors): {by_region:?}");
    let per_file: Vec<String> = SOURCES
        .iter()
        .map(|s| s.0)
        .zip(&time_per_file)
        .map(|(f, t)| format!("{f} {:.1}s", t.as_secs_f64()))
        .collect();
    eprintln!("  time per file: {}", per_file.join(", "));
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

/// The CLI on a sample of the same mutants: `umbra info --json` must exit 0 (valid JSON), 2
/// (valid JSON, some grid has an `error`) or 1 (one `umbra: error:` line), never crash.
#[test]
fn cli_survives_mutated_files() {
    let Some(dir) = corpus_dir() else { return };
    install_panic_hook();
    let originals: Vec<Vec<u8>> = SOURCES
        .iter()
        .map(|f| std::fs::read(dir.join(f.0)).unwrap())
        .collect();
    let layouts: Vec<Layout> = SOURCES.iter().map(|f| layout(&dir.join(f.0))).collect();
    let cases = make_cases(&layouts);
    // Every 15th byte-level mutation, plus every 100th truncation.
    let sample: Vec<&Case> = cases
        .iter()
        .filter(|c| !matches!(c.mutation, Mutation::Truncate(_)))
        .step_by(15)
        .chain(
            cases
                .iter()
                .filter(|c| matches!(c.mutation, Mutation::Truncate(_)))
                .step_by(100),
        )
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("mutant.vdb");
    let mut failures = Vec::new();
    let mut codes = std::collections::BTreeMap::<i32, usize>::new();
    for case in &sample {
        std::fs::write(&path, case.mutation.apply(&originals[case.file])).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(["info", path.to_str().unwrap(), "--json"])
            .output()
            .unwrap();
        let what = format!(
            "{} [{}] {}",
            SOURCES[case.file].0, case.region, case.mutation
        );
        let stderr = String::from_utf8_lossy(&out.stderr);
        let code = out.status.code().unwrap_or(-1);
        *codes.entry(code).or_default() += 1;
        let json = serde_json::from_slice::<serde_json::Value>(&out.stdout).ok();
        let grids = json
            .as_ref()
            .and_then(|j| j["grids"].as_array())
            .map(|g| (g.len(), g.iter().filter(|g| !g["error"].is_null()).count()));
        let one_line = stderr.lines().count() == 1
            && stderr.starts_with("umbra: error: ")
            && stderr.contains("mutant.vdb");
        // 0: everything read; 3: some grids failed, the others described; 1: nothing
        // readable (no report, or a report whose every grid failed).
        let ok = match code {
            0 => grids.is_some_and(|(_, bad)| bad == 0),
            3 => one_line && grids.is_some_and(|(n, bad)| bad > 0 && bad < n),
            1 => one_line && (out.stdout.is_empty() || grids.is_some_and(|(n, bad)| bad == n)),
            _ => false,
        };
        if !ok || stderr.contains("panicked") {
            failures.push(format!("{what}: exit {code}, stderr {stderr:?}"));
        }
    }
    eprintln!("CLI on {} mutants: exit codes {codes:?}", sample.len());
    assert!(sample.len() >= 50, "only {} CLI mutants", sample.len());
    assert!(
        failures.is_empty(),
        "{} CLI failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
