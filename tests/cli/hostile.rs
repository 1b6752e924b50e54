//! Hostile files, numbers and paths against the real `umbra` binary. Every hostile `.vdb` is
//! generated here (by the test-only writer in `common/vdb_writer.rs`, whose output a round-trip
//! test checks against umbra, `vdb_print` and pyopenvdb) and every command runs under
//! `prlimit --as` (an address-space cap far above what a good file of that size needs) with a
//! wall-clock watchdog. A refused command must exit 1, print exactly one `umbra: error:` line
//! (after any `umbra: warning:` lines) naming the file (the flag, for a refused number; a usage
//! error may exit 2 instead), never panic or die of an allocation failure, finish quickly, and
//! leave its working directory as it was (names, sizes, mtimes: no output appears).
//!
//! The cases: self-pointing and looping grid descriptor chains with huge grid counts; sparse
//! 3 GB files with a far block offset or a 0xFFFFFFFF metadata length; instanced grids whose
//! parent has another value type or is the grid itself (and, as the control, a valid instance);
//! leaves at opposite corners of the i32 index range (bake time) and at the extreme corners
//! (optical depth equal to the same leaf at the origin); degenerate and ill-conditioned
//! transforms; names with terminal control bytes; work budgets far beyond any machine.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::vdb_writer;

use std::collections::BTreeMap;
use std::io::Read;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime};
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};
use vdb_writer::{Grid, Leaf, Map, RootTile, ValueType, VdbFile};

const MIB: u64 = 1 << 20;
const GIB: u64 = 1 << 30;
/// A command still running after this long is killed and the test fails.
const WATCHDOG: Duration = Duration::from_secs(20);
/// "Refused at once / quickly".
const QUICK: f64 = 5.0;
/// Size of the sparse files (no disk blocks behind the hole).
const SPARSE_LEN: u64 = 3_000_000_000;

// ---------------------------------------------------------------------------------------------
// Running the binary

/// One finished (or killed) run of `prlimit --as=LIMIT -- umbra ARGS`.
struct Run {
    what: String,
    code: Option<i32>,
    signal: Option<i32>,
    stdout: Vec<u8>,
    stderr: Vec<u8>,
    secs: f64,
    timed_out: bool,
    /// Largest `VmHWM` seen while polling (a lower bound of the peak RSS), bytes.
    sampled_rss: u64,
}

impl Run {
    fn err(&self) -> String {
        String::from_utf8_lossy(&self.stderr).into_owned()
    }

    fn out(&self) -> String {
        String::from_utf8_lossy(&self.stdout).into_owned()
    }

    /// Everything about the run, for failure messages.
    fn describe(&self) -> String {
        let clip = |s: String| {
            if s.len() > 1500 {
                let cut = (0..=1500)
                    .rev()
                    .find(|&i| s.is_char_boundary(i))
                    .unwrap_or(0);
                format!("{}... ({} bytes)", &s[..cut], s.len())
            } else {
                s
            }
        };
        format!(
            "`{}`: exit {:?}, signal {:?}, {:.2} s{}, sampled peak RSS {} MiB\n  stderr: {:?}\n  stdout: {:?}",
            self.what,
            self.code,
            self.signal,
            self.secs,
            if self.timed_out {
                " (KILLED by the watchdog)"
            } else {
                ""
            },
            self.sampled_rss / MIB,
            clip(self.err()),
            clip(self.out()),
        )
    }
}

fn vm_hwm(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmHWM:"))?.to_string();
            line.split_whitespace().nth(1)?.parse::<u64>().ok()
        })
        .map_or(0, |kb| kb * 1024)
}

/// Run `umbra ARGS` in `dir` under `prlimit --as=limit`, killing it after [`WATCHDOG`].
/// The environment caps malloc arenas and rayon's global pool so the address-space limit
/// measures umbra, not the machine's core count.
fn umbra(dir: &Path, limit: u64, args: &[&str]) -> Run {
    let what = format!("prlimit --as={limit} -- umbra {}", args.join(" "));
    let mut child = Command::new("prlimit")
        .arg(format!("--as={limit}"))
        .arg("--")
        .arg(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .current_dir(dir)
        .env("MALLOC_ARENA_MAX", "2")
        .env("RAYON_NUM_THREADS", "2")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn prlimit (util-linux)");
    let drain = |mut p: Box<dyn Read + Send>| {
        std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = p.read_to_end(&mut b);
            b
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    let start = Instant::now();
    let pid = child.id();
    let mut sampled_rss = 0;
    let mut timed_out = false;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        sampled_rss = sampled_rss.max(vm_hwm(pid));
        if start.elapsed() > WATCHDOG {
            timed_out = true;
            let _ = child.kill();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let secs = start.elapsed().as_secs_f64();
    let run = Run {
        what,
        code: status.code(),
        signal: status.signal(),
        stdout: out.join().unwrap(),
        stderr: err.join().unwrap(),
        secs,
        timed_out,
        sampled_rss,
    };
    // Shown with `--nocapture`: what every command did.
    eprintln!("{}", run.describe());
    run
}

/// Every path under `dir` (hidden ones too) with whether it is a directory, its size and mtime.
type Snapshot = BTreeMap<PathBuf, (bool, u64, SystemTime)>;

fn snapshot(dir: &Path) -> Snapshot {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            let m = std::fs::symlink_metadata(&p).unwrap();
            if m.is_dir() {
                todo.push(p.clone());
            }
            out.insert(p, (m.is_dir(), m.len(), m.modified().unwrap()));
        }
    }
    out
}

fn diff(before: &Snapshot, after: &Snapshot) -> Option<String> {
    if before == after {
        return None;
    }
    let mut d = Vec::new();
    for (p, v) in after {
        match before.get(p) {
            None => d.push(format!("new {}", p.display())),
            Some(b) if b != v => d.push(format!("changed {}", p.display())),
            Some(_) => {}
        }
    }
    for p in before.keys().filter(|p| !after.contains_key(*p)) {
        d.push(format!("removed {}", p.display()));
    }
    Some(d.join(", "))
}

/// A working directory with a file that must survive every command untouched.
fn workdir() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("existing.exr"), b"keep me").unwrap();
    std::fs::write(dir.path().join(".hidden"), b"hidden").unwrap();
    dir
}

/// Run `args` in `dir` and check the refusal contract: exit 1 within `max_secs`, stderr is
/// `umbra: warning:` lines then exactly one `umbra: error: ` line that names `file` and
/// contains every word of `words` (case-insensitive) and none of `forbidden`; no panic or
/// allocation failure; `dir` unchanged. Returns the error line, or every problem found.
fn refused(
    dir: &Path,
    limit: u64,
    args: &[&str],
    file: &str,
    words: &[&str],
    forbidden: &[&str],
    max_secs: f64,
) -> Result<String, String> {
    let before = snapshot(dir);
    let r = umbra(dir, limit, args);
    let after = snapshot(dir);
    let mut problems = Vec::new();
    if let Some(d) = diff(&before, &after) {
        problems.push(format!("the working directory changed: {d}"));
    }
    if r.timed_out {
        problems.push(format!("still running after {WATCHDOG:?}"));
    }
    if r.code != Some(1) {
        problems.push(format!(
            "exit code {:?} (signal {:?}), not 1",
            r.code, r.signal
        ));
    }
    if r.secs >= max_secs {
        problems.push(format!("took {:.2} s (limit {max_secs} s)", r.secs));
    }
    let err = r.err();
    for bad in [
        "panicked",
        "RUST_BACKTRACE",
        "memory allocation of",
        "out of memory",
        "Cannot allocate",
        "capacity overflow",
    ] {
        if err.contains(bad) {
            problems.push(format!("stderr contains {bad:?}"));
        }
    }
    let lines: Vec<&str> = err.lines().collect();
    let errors: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.starts_with("umbra: error: "))
        .collect();
    let mut line = String::new();
    if errors.len() == 1 && lines.last() == errors.first() {
        line = errors[0].to_string();
        if let Some(other) = lines[..lines.len() - 1]
            .iter()
            .find(|l| !l.starts_with("umbra: warning:"))
        {
            problems.push(format!(
                "stderr line {other:?} is neither a warning nor the error"
            ));
        }
        if !line.contains(file) {
            problems.push(format!("the error line does not name the file {file:?}"));
        }
        let lower = line.to_lowercase();
        for w in words {
            if !lower.contains(&w.to_lowercase()) {
                problems.push(format!("the error line does not contain {w:?}"));
            }
        }
        for w in forbidden {
            if lower.contains(&w.to_lowercase()) {
                problems.push(format!("the error line contains {w:?}"));
            }
        }
    } else {
        problems.push(format!(
            "stderr has {} `umbra: error: ` lines (must be exactly one, the last line)",
            errors.len()
        ));
    }
    if problems.is_empty() {
        Ok(line)
    } else {
        Err(format!("{}\n  -> {}", r.describe(), problems.join("; ")))
    }
}

/// Fail with every problem found, if any.
fn assert_no_problems(problems: &[String]) {
    assert!(
        problems.is_empty(),
        "{} command(s) broke the contract:\n{}",
        problems.len(),
        problems.join("\n")
    );
}

/// `query FILE --grid GRID --from A --to B` (world coordinates).
fn query_args(file: &str, grid: &str, from: [f64; 3], to: [f64; 3]) -> Vec<String> {
    let v = |p: [f64; 3]| format!("{:e},{:e},{:e}", p[0], p[1], p[2]);
    vec![
        "query".into(),
        file.into(),
        "--grid".into(),
        grid.into(),
        format!("--from={}", v(from)),
        format!("--to={}", v(to)),
    ]
}

/// `bake FILE --grid GRID --light-dir=0,-1,0 -o OUT --res 32 -q --threads 2`.
fn bake_args(file: &str, grid: &str, out: &str) -> Vec<String> {
    [
        "bake",
        file,
        "--grid",
        grid,
        "--light-dir=0,-1,0",
        "-o",
        out,
        "--res",
        "32",
        "-q",
        "--threads",
        "2",
    ]
    .map(String::from)
    .to_vec()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// The three commands every hostile file goes through: info, a segment query, a bake.
fn info_query_bake(file: &str, grid: &str) -> Vec<Vec<String>> {
    vec![
        vec!["info".into(), file.into()],
        query_args(file, grid, [-2.0, 3.5, 4.5], [10.0, 4.5, 3.5]),
        bake_args(file, grid, "out.exr"),
    ]
}

/// Every problem of the commands `cmds` against the contract of [`refused`].
fn refuse_all(
    dir: &Path,
    limit: u64,
    cmds: &[Vec<String>],
    file: &str,
    words: &[&str],
    forbidden: &[&str],
    max_secs: f64,
) -> Vec<String> {
    cmds.iter()
        .filter_map(|c| refused(dir, limit, &strs(c), file, words, forbidden, max_secs).err())
        .collect()
}

/// One fog leaf of varied values at `origin`.
fn varied_leaf(origin: [i32; 3]) -> Leaf {
    Leaf::from_fn(origin, |[i, j, k]| {
        0.2 + 0.05 * i as f64 + 0.031 * j as f64 + 0.017 * ((i * k + j) % 5) as f64
    })
}

/// A valid file with one float fog grid `density` holding one leaf at the origin.
fn one_leaf(map: Map) -> VdbFile {
    VdbFile::new(vec![
        Grid::fog("density", vec![varied_leaf([0, 0, 0])]).with_map(map)
    ])
}

// ---------------------------------------------------------------------------------------------
// The writer itself

const PROBE_PY: &str = r#"
import json, sys, pyopenvdb as vdb
path = sys.argv[1]
out = {}
for g in vdb.readAllGridMetadata(path):
    grid = vdb.read(path, g.name)
    acc = grid.getConstAccessor()
    probes = json.loads(sys.argv[2])
    out[g.name] = {
        "type": grid.valueTypeName,
        "leaves": grid.leafCount(),
        "active": grid.activeVoxelCount(),
        "background": grid.background,
        "values": [acc.getValue(tuple(p)) for p in probes],
        "world": list(grid.transform.indexToWorld((2, 4, 1))),
    }
print(json.dumps(out))
"#;

#[test]
fn the_writer_round_trips_through_umbra_vdb_print_and_pyopenvdb() {
    let dir = workdir();
    let path = dir.path().join("roundtrip.vdb");
    let leaves = vec![
        varied_leaf([0, 0, 0]),
        Leaf::filled([-8, 16, 120], 0.5),
        varied_leaf([4096, -4096, 8]),
    ];
    let mut density = Grid::fog("density", leaves.clone()).with_map(Map::ScaleTranslate {
        scale: [0.5, 0.25, 2.0],
        translate: [1.0, 2.0, 3.0],
    });
    density.tiles.push(RootTile {
        origin: [8192, 0, 0],
        value: 0.25,
        active: true,
    });
    let vel = Grid::fog("vel", vec![Leaf::filled([0, 0, 0], 2.0)])
        .with_type(ValueType::Vec3s)
        .with_map(Map::UniformScale(0.1));
    let layout = VdbFile::new(vec![density, vel]).write(&path);
    assert_eq!(layout.grids.len(), 2);
    assert_eq!(layout.grids[0].leaf_count, 3);

    // Probes: voxels of each leaf, the root tile, and the background.
    let mut probes: Vec<[i32; 3]> = Vec::new();
    let mut want: Vec<f64> = Vec::new();
    for leaf in &leaves {
        for ijk in [[0, 0, 0], [7, 7, 7], [3, 5, 1], [6, 2, 4]] {
            probes.push(std::array::from_fn(|a| leaf.origin[a] + ijk[a] as i32));
            want.push(leaf.value(ijk));
        }
    }
    probes.push([8192 + 100, 4000, 5]);
    want.push(0.25);
    probes.push([-5000, 0, 0]);
    want.push(0.0);

    // umbra's decoder.
    let g = umbra::internals::vdb::load_grid(&path, "density").unwrap();
    assert_eq!(g.tree.leaves().len(), 3);
    assert_eq!(g.class.as_deref(), Some("fog volume"));
    for (p, w) in probes.iter().zip(&want) {
        assert_eq!(f64::from(g.tree.value(*p)), f64::from(*w as f32), "{p:?}");
    }
    assert!(g.tree.is_active([8192 + 100, 4000, 5]));
    assert_eq!(g.transform.index_to_world([2.0, 4.0, 1.0]), [2.0, 3.0, 5.0]);
    let v = umbra::internals::vdb::load_grid(&path, "vel").unwrap();
    assert_eq!(v.tree.leaves().len(), 1);
    assert_eq!(v.tree.value([3, 4, 5]), 2.0);
    assert!((v.transform.voxel_size()[0] - 0.1).abs() < 1e-15);

    // OpenVDB's own tools.
    let vp = Command::new("vdb_print")
        .args(["-l", path.to_str().unwrap()])
        .output()
        .expect("vdb_print (Debian libopenvdb-tools) is installed");
    let text = String::from_utf8_lossy(&vp.stdout);
    assert!(
        vp.status.success(),
        "vdb_print: {}",
        String::from_utf8_lossy(&vp.stderr)
    );
    assert!(
        text.contains("Leaf(3 x 8^3)") && text.contains("Leaf(1 x 8^3)"),
        "{text}"
    );
    assert!(text.contains("Tree_vec3s_5_4_3"), "{text}");
    let py = Command::new("/usr/bin/python3")
        .args(["-c", PROBE_PY, path.to_str().unwrap()])
        .arg(serde_json::to_string(&probes).unwrap())
        .output()
        .expect("/usr/bin/python3 runs");
    assert!(
        py.status.success(),
        "pyopenvdb (Debian python3-openvdb): {}",
        String::from_utf8_lossy(&py.stderr)
    );
    let j: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    let d = &j["density"];
    assert_eq!(d["type"], "float");
    assert_eq!(d["leaves"], 3);
    assert_eq!(d["active"], 3 * 512 + 4096u64.pow(3));
    for (i, w) in want.iter().enumerate() {
        let got = d["values"][i].as_f64().unwrap();
        assert_eq!(got, f64::from(*w as f32), "pyopenvdb at {:?}", probes[i]);
    }
    assert_eq!(d["world"], serde_json::json!([2.0, 3.0, 5.0]));
    assert_eq!(j["vel"]["type"], "vec3s");
    assert_eq!(j["vel"]["values"][0], serde_json::json!([2.0, 0.0, 0.0]));

    // The CLI reads it under the limits the hostile cases use.
    let file = "roundtrip.vdb";
    for (limit, args) in [
        (512 * MIB, vec!["info".to_string(), file.to_string()]),
        (
            512 * MIB,
            query_args(file, "density", [1.0, 2.5, 3.5], [5.0, 3.0, 3.5]),
        ),
        (512 * MIB, bake_args(file, "density", "ok.exr")),
    ] {
        let r = umbra(dir.path(), limit, &strs(&args));
        assert_eq!(r.code, Some(0), "{}", r.describe());
    }
    assert!(dir.path().join("ok.exr").is_file());
}

// ---------------------------------------------------------------------------------------------
// 1, 2: descriptor chains

#[test]
fn a_descriptor_pointing_at_itself_with_count_2_pow_31_is_refused_in_bounded_memory() {
    let dir = workdir();
    let (mut bytes, layout) = one_leaf(Map::UniformScale(1.0)).to_bytes();
    let g = &layout.grids[0];
    // Keep the header and the descriptor only; all three offsets point at the descriptor.
    bytes.truncate(usize::try_from(g.offset_fields[2] + 8).unwrap());
    assert_eq!(bytes.len(), 124);
    layout.set_offsets(&mut bytes, 0, g.descriptor, g.descriptor, g.descriptor);
    layout.set_grid_count(&mut bytes, i32::MAX);
    std::fs::write(dir.path().join("self_loop.vdb"), &bytes).unwrap();
    assert_no_problems(&refuse_all(
        dir.path(),
        512 * MIB,
        &info_query_bake("self_loop.vdb", "density"),
        "self_loop.vdb",
        &[],
        &[],
        QUICK,
    ));
}

#[test]
fn a_descriptor_chain_looping_back_with_count_10_pow_6_is_refused_quickly() {
    let dir = workdir();
    let file = VdbFile::new(vec![
        Grid::fog("density", vec![varied_leaf([0, 0, 0])]),
        Grid::fog("temperature", vec![varied_leaf([8, 0, 0])]),
    ]);
    let (mut bytes, layout) = file.to_bytes();
    // Grid 1 ends (and starts) where grid 0's descriptor starts: 0 -> 1 -> 0 -> 1 ...
    let d0 = layout.grids[0].descriptor;
    layout.set_offsets(&mut bytes, 1, d0, d0, d0);
    layout.set_grid_count(&mut bytes, 1_000_000);
    std::fs::write(dir.path().join("loop.vdb"), &bytes).unwrap();
    assert_no_problems(&refuse_all(
        dir.path(),
        GIB,
        &info_query_bake("loop.vdb", "density"),
        "loop.vdb",
        &[],
        &[],
        QUICK,
    ));
}

// ---------------------------------------------------------------------------------------------
// 3: sparse 3 GB files

/// `file` at the start of a sparse `SPARSE_LEN`-byte file, after `patch`.
fn sparse_file(path: &Path, file: &VdbFile, patch: impl FnOnce(&mut Vec<u8>, &vdb_writer::Layout)) {
    let (mut bytes, layout) = file.to_bytes();
    patch(&mut bytes, &layout);
    std::fs::write(path, &bytes).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(path).unwrap();
    f.set_len(SPARSE_LEN).unwrap();
}

/// A valid one-leaf grid with one more metadata entry, in the grid or in the file.
fn with_comment(in_grid: bool) -> VdbFile {
    let mut file = one_leaf(Map::UniformScale(1.0));
    let entry = (
        "comment".into(),
        "string".into(),
        b"a hostile length".to_vec(),
    );
    if in_grid {
        file.grids[0].metadata.push(entry);
    } else {
        file.metadata.push(entry);
    }
    file
}

#[test]
fn a_sparse_3_gb_file_with_the_block_offset_near_its_end_is_refused_without_reading_it() {
    let dir = workdir();
    let file = one_leaf(Map::UniformScale(1.0));
    sparse_file(&dir.path().join("far_block.vdb"), &file, |b, l| {
        let g = &l.grids[0];
        l.set_offsets(b, 0, g.grid_pos, SPARSE_LEN - 16, SPARSE_LEN);
    });
    assert_no_problems(&refuse_all(
        dir.path(),
        GIB,
        &info_query_bake("far_block.vdb", "density"),
        "far_block.vdb",
        &[],
        &[],
        QUICK,
    ));
}

#[test]
fn a_sparse_3_gb_file_with_a_grid_metadata_length_of_0xffffffff_is_refused_without_reading_it() {
    let dir = workdir();
    // The grid's offsets as written, and with the grid (so the metadata's region) reaching
    // the end of the file.
    for (name, far) in [("meta_len.vdb", false), ("meta_len_far_block.vdb", true)] {
        sparse_file(&dir.path().join(name), &with_comment(true), |b, l| {
            let g = &l.grids[0];
            vdb_writer::patch_u32(b, *g.metadata_size_fields.last().unwrap(), u32::MAX);
            if far {
                l.set_offsets(b, 0, g.grid_pos, SPARSE_LEN - 16, SPARSE_LEN);
            }
        });
    }
    let mut problems = Vec::new();
    for name in ["meta_len.vdb", "meta_len_far_block.vdb"] {
        problems.extend(refuse_all(
            dir.path(),
            GIB,
            &info_query_bake(name, "density"),
            name,
            &[],
            &[],
            QUICK,
        ));
    }
    assert_no_problems(&problems);
}

#[test]
fn a_sparse_3_gb_file_with_a_file_metadata_length_of_0xffffffff_is_refused_without_reading_it() {
    let dir = workdir();
    sparse_file(
        &dir.path().join("file_meta_len.vdb"),
        &with_comment(false),
        |b, l| {
            vdb_writer::patch_u32(b, l.file_metadata_size_fields[0], u32::MAX);
        },
    );
    assert_no_problems(&refuse_all(
        dir.path(),
        GIB,
        &info_query_bake("file_meta_len.vdb", "density"),
        "file_meta_len.vdb",
        &[],
        &[],
        QUICK,
    ));
}

// ---------------------------------------------------------------------------------------------
// 4, 5: instancing

/// Both block offsets an instance may carry: OpenVDB's 0, and the grid's end (empty block).
const INSTANCE_LAYOUTS: [(bool, &str); 2] = [(false, "block 0"), (true, "block at end")];

#[test]
fn a_valid_instanced_grid_answers_like_its_parent() {
    // The control for the two refusals below: same layout, matching types.
    let mut problems = Vec::new();
    for (at_end, label) in INSTANCE_LAYOUTS {
        let dir = workdir();
        let mut inst = Grid::instance("density", ValueType::Float, "parent");
        inst.instance_block_at_end = at_end;
        let file = VdbFile::new(vec![
            Grid::fog("parent", vec![varied_leaf([0, 0, 0])]),
            inst,
        ]);
        file.write(&dir.path().join("inst.vdb"));
        let path = dir.path().join("inst.vdb");
        let vp = Command::new("vdb_print")
            .arg(&path)
            .output()
            .expect("vdb_print runs");
        assert!(
            vp.status.success(),
            "{label}: vdb_print: {}",
            String::from_utf8_lossy(&vp.stderr)
        );
        let mut t = Vec::new();
        for grid in ["parent", "density"] {
            let args = query_args("inst.vdb", grid, [-2.0, 3.5, 4.5], [10.0, 4.5, 3.5]);
            let mut args = strs(&args);
            args.push("--json");
            let r = umbra(dir.path(), GIB, &args);
            let tau = serde_json::from_str::<serde_json::Value>(r.out().trim())
                .ok()
                .and_then(|v| v["tau"].as_f64());
            match (r.code, tau) {
                (Some(0), Some(tau)) => t.push(tau),
                _ => problems.push(format!(
                    "{label}: {}\n  -> must exit 0 with a tau",
                    r.describe()
                )),
            }
        }
        if t.len() == 2 && !(t[0] > 0.1 && t[0] == t[1]) {
            problems.push(format!(
                "{label}: tau of the parent and its instance {t:?} must be equal and positive"
            ));
        }
    }
    assert_no_problems(&problems);
}

#[test]
fn an_instance_of_a_parent_with_another_value_type_is_refused_naming_the_types() {
    let mut problems = Vec::new();
    for parent_type in [ValueType::Vec3s, ValueType::Int32] {
        for (at_end, label) in INSTANCE_LAYOUTS {
            let dir = workdir();
            let mut inst = Grid::instance("density", ValueType::Float, "parent");
            inst.instance_block_at_end = at_end;
            let file = VdbFile::new(vec![
                Grid::fog("parent", vec![Leaf::filled([0, 0, 0], 3.0)]).with_type(parent_type),
                inst,
            ]);
            file.write(&dir.path().join("mixed.vdb"));
            let cmds = &info_query_bake("mixed.vdb", "density")[1..];
            let parent_name = &parent_type.tree_type()[5..10]; // "vec3s" / "int32"
            for p in refuse_all(
                dir.path(),
                GIB,
                cmds,
                "mixed.vdb",
                &["instance", "type", "float", parent_name],
                &[],
                QUICK,
            ) {
                problems.push(format!("parent {parent_name}, {label}: {p}"));
            }
        }
    }
    assert_no_problems(&problems);
}

#[test]
fn a_grid_that_is_an_instance_of_itself_is_refused() {
    let mut problems = Vec::new();
    for (at_end, label) in INSTANCE_LAYOUTS {
        let dir = workdir();
        let mut me = Grid::instance("density", ValueType::Float, "density");
        me.instance_block_at_end = at_end;
        VdbFile::new(vec![me]).write(&dir.path().join("narcissus.vdb"));
        let cmds = &info_query_bake("narcissus.vdb", "density")[1..];
        for p in refuse_all(
            dir.path(),
            GIB,
            cmds,
            "narcissus.vdb",
            &["instance of itself"],
            &[],
            QUICK,
        ) {
            problems.push(format!("{label}: {p}"));
        }
    }
    assert_no_problems(&problems);
}

// ---------------------------------------------------------------------------------------------
// 6, 8: the corners of the index range

const MIN: i32 = i32::MIN;
const MAX_LEAF: i32 = i32::MAX - 7;

#[test]
fn leaves_at_opposite_corners_of_the_index_range_bake_about_as_fast_as_neighbours() {
    let dir = workdir();
    let write = |name: &str, a: [i32; 3], b: [i32; 3]| {
        VdbFile::new(vec![Grid::fog(
            "density",
            vec![varied_leaf(a), varied_leaf(b)],
        )])
        .write(&dir.path().join(name));
    };
    write("near.vdb", [0, 0, 0], [8, 8, 8]);
    write("far.vdb", [MIN; 3], [MAX_LEAF; 3]);
    let mut secs = Vec::new();
    for name in ["near", "far"] {
        let (vdb, exr) = (format!("{name}.vdb"), format!("{name}.exr"));
        let mut args = bake_args(&vdb, "density", &exr);
        args[4] = "--light-dir=-1,-1,-1".into();
        let r = umbra(dir.path(), GIB, &strs(&args));
        assert!(
            r.code == Some(0) && !r.timed_out,
            "{name}: {}",
            r.describe()
        );
        assert!(dir.path().join(&exr).is_file(), "{name}: no {exr}");
        secs.push(r.secs);
    }
    let (near, far) = (secs[0], secs[1]);
    assert!(far < 10.0, "far leaves: {far:.2} s (near: {near:.2} s)");
    assert!(
        far <= 5.0 * near + 0.5,
        "far leaves: {far:.2} s, not within a small factor of near leaves' {near:.2} s"
    );
    // The 32x32 map's pixels all miss the two 8^3 leaves (a pixel is 2^27 voxels wide), so a
    // quick bake alone would not show the leaves are still there: the ray along the whole
    // diagonal must cross both, each as the same ray crosses one such leaf at the origin.
    VdbFile::new(vec![Grid::fog("density", vec![varied_leaf([0; 3])])])
        .write(&dir.path().join("single.vdb"));
    let tau = |file: &str, from: f64, to: f64| {
        let args = query_args(file, "density", [from; 3], [to; 3]);
        let mut args = strs(&args);
        args.push("--json");
        let r = umbra(dir.path(), GIB, &args);
        let tau = serde_json::from_str::<serde_json::Value>(r.out().trim())
            .ok()
            .and_then(|v| v["tau"].as_f64());
        assert!(
            r.code == Some(0) && r.secs < 10.0 && tau.is_some(),
            "{}",
            r.describe()
        );
        tau.unwrap()
    };
    let one = tau("single.vdb", -2.5, 10.5);
    let both = tau("far.vdb", f64::from(MIN) - 2.5, f64::from(MAX_LEAF) + 10.5);
    assert!(one > 1.0, "the diagonal misses the leaf: tau {one}");
    let rel = (both - 2.0 * one).abs() / (2.0 * one);
    assert!(
        rel < 1e-5,
        "tau along the whole diagonal {both}, twice one leaf's {} (relative {rel:.2e})",
        2.0 * one
    );
}

#[test]
fn optical_depth_through_a_leaf_at_the_extreme_corners_equals_the_same_leaf_at_the_origin() {
    let dir = tempfile::tempdir().unwrap();
    // Offsets from the leaf origin, exactly representable at |coordinate| ~ 2^31 (multiples of
    // 2^-3), so both segments are the same segment in their leaf's frame.
    let segments: [([f64; 3], [f64; 3]); 4] = [
        ([-2.0, 3.25, 4.125], [10.0, 4.75, 2.875]), // enters and leaves through faces
        ([0.5, 0.5, 0.5], [7.25, 6.5, 1.0]),        // inside
        ([-3.0, 2.0, 5.0], [11.0, 2.0, 5.0]),       // along x, through the whole range
        ([9.5, -1.5, 8.25], [-1.25, 9.0, -0.5]),    // the other way, past every corner face
    ];
    let load = |origin: [i32; 3]| {
        let path = dir.path().join(format!("leaf_{}.vdb", origin[0]));
        VdbFile::new(vec![Grid::fog("density", vec![varied_leaf(origin)])]).write(&path);
        Volume::load(&path, "density", 1.0).unwrap()
    };
    let reference = load([0; 3]);
    let mut failures = Vec::new();
    for corner in [[MIN; 3], [MAX_LEAF; 3], [MIN, MAX_LEAF, MIN]] {
        let vol = load(corner);
        let o = corner.map(f64::from);
        for (a, b) in segments {
            let shifted = |p: [f64; 3]| std::array::from_fn(|k| o[k] + p[k]);
            for interp in [Interp::Trilinear, Interp::Nearest] {
                let want = optical_depth(&reference, &Ray::between(a, b).unwrap(), interp)
                    .unwrap()
                    .tau;
                let ray = Ray::between(shifted(a), shifted(b)).unwrap();
                let got = optical_depth(&vol, &ray, interp).unwrap().tau;
                assert!(want > 0.1, "the segment {a:?} -> {b:?} misses the leaf");
                let rel = (got - want).abs() / want;
                // Near |coordinate| 2^31 consecutive doubles are 2^-21 voxels apart, so the ray's
                // cell crossings carry relative errors of ~2^-31 each: 1e-7 is f64, 0.06 (7.5
                // instead of 8, the bug this guards against) is not.
                if rel.is_nan() || rel >= 1e-7 {
                    failures.push(format!(
                        "leaf at {corner:?}, {interp:?}, {a:?} -> {b:?}: tau {got} vs {want} at \
                         the origin (relative {rel:.3e})"
                    ));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

// ---------------------------------------------------------------------------------------------
// 7: transforms

#[test]
fn degenerate_and_ill_conditioned_transforms_are_refused_for_tracing_but_described() {
    let cases: [(&str, Map, &[&str], &[&str]); 3] = [
        ("subnormal.vdb", Map::Scale([5e-324; 3]), &[], &[]),
        (
            "tiny.vdb",
            Map::Scale([1e-150; 3]),
            &["voxel size"],
            &["determinant 0"],
        ),
        (
            "far_away.vdb",
            Map::ScaleTranslate {
                scale: [1.0; 3],
                translate: [1e17; 3],
            },
            &["voxel"],
            &[],
        ),
    ];
    let mut problems = Vec::new();
    for (name, map, words, forbidden) in cases {
        let dir = workdir();
        let file = one_leaf(map.clone());
        file.write(&dir.path().join(name));
        // A segment through the leaf, in world coordinates.
        let world = |p: [f64; 3]| -> [f64; 3] {
            match &map {
                Map::Scale(s) => std::array::from_fn(|k| s[k] * p[k]),
                Map::ScaleTranslate { scale, translate } => {
                    std::array::from_fn(|k| scale[k] * p[k] + translate[k])
                }
                _ => unreachable!(),
            }
        };
        let cmds = [
            query_args(
                name,
                "density",
                world([-2.0, 3.5, 4.5]),
                world([10.0, 4.5, 3.5]),
            ),
            bake_args(name, "density", "out.exr"),
        ];
        for c in &cmds {
            if let Err(p) = refused(dir.path(), GIB, &strs(c), name, words, forbidden, QUICK) {
                problems.push(p);
            }
        }
        let r = umbra(dir.path(), GIB, &["info", name]);
        if r.code != Some(0) || !r.out().contains("density") {
            problems.push(format!(
                "{}\n  -> info must exit 0 and describe the grid",
                r.describe()
            ));
        }
    }
    assert_no_problems(&problems);
}

// ---------------------------------------------------------------------------------------------
// 9: names with terminal control bytes

#[test]
fn grid_names_and_paths_with_escape_and_bell_bytes_are_printed_escaped() {
    let dir = workdir();
    let mut g = Grid::fog("x", vec![varied_leaf([0, 0, 0])]);
    g.name = b"d\x1b[31m\x07".to_vec();
    let file = VdbFile::new(vec![g]);
    file.write(&dir.path().join("names.vdb"));
    // The same file under a hostile path.
    let hostile_path = "p\x1b[31m\x07.vdb";
    file.write(&dir.path().join(hostile_path));
    let escaped_path = "p\\x1b[31m\\x07.vdb";
    let raw = |b: &[u8]| b.iter().any(|&c| c == 0x1b || c == 0x07);
    let escaped = |s: &str| {
        let l = s.to_lowercase();
        l.contains("\\x1b") && l.contains("\\x07")
    };
    let mut problems = Vec::new();
    for args in [
        vec!["info", "names.vdb"],
        vec!["info", "-v", "names.vdb"],
        vec!["info", hostile_path],
    ] {
        let r = umbra(dir.path(), GIB, &args);
        if r.code != Some(0) || raw(&r.stdout) || raw(&r.stderr) || !escaped(&r.out()) {
            problems.push(format!(
                "{}\n  -> must exit 0 and print names with \\x1b and \\x07 escaped, never raw",
                r.describe()
            ));
        }
    }
    // Errors that list the available names, echo a requested name, or name a hostile path.
    for (args, file) in [
        (
            query_args("names.vdb", "nope", [0.0; 3], [1.0; 3]),
            "names.vdb",
        ),
        (bake_args("names.vdb", "nope", "out.exr"), "names.vdb"),
        (
            ["info", "names.vdb", "--grid", "nope"]
                .map(String::from)
                .to_vec(),
            "names.vdb",
        ),
        (
            query_args("names.vdb", "n\x1bope\x07", [0.0; 3], [1.0; 3]),
            "names.vdb",
        ),
        (
            query_args(hostile_path, "nope", [0.0; 3], [1.0; 3]),
            escaped_path,
        ),
        (
            query_args("missing\x1b\x07.vdb", "density", [0.0; 3], [1.0; 3]),
            "missing\\x1b\\x07.vdb",
        ),
    ] {
        let before = snapshot(dir.path());
        let r = umbra(dir.path(), GIB, &strs(&args));
        let changed = diff(&before, &snapshot(dir.path()));
        let err = r.err();
        let errors: Vec<&str> = err
            .lines()
            .filter(|l| l.starts_with("umbra: error: "))
            .collect();
        if r.code != Some(1)
            || raw(&r.stdout)
            || raw(&r.stderr)
            || errors.len() != 1
            || !(escaped(errors[0]) && errors[0].contains(file))
            || changed.is_some()
        {
            problems.push(format!(
                "{}\n  -> must exit 1 with one error line naming {file:?} and the names with \
                 \\x1b and \\x07 escaped, never raw; directory changes: {changed:?}",
                r.describe()
            ));
        }
    }
    assert_no_problems(&problems);
}

// ---------------------------------------------------------------------------------------------
// 10: work budgets

#[test]
fn work_budgets_beyond_any_machine_are_refused_at_once() {
    let dir = workdir();
    let block: Vec<Leaf> = (0..8)
        .map(|n| Leaf::filled([8 * (n & 1), 8 * (n >> 1 & 1), 8 * (n >> 2)], 0.5))
        .collect();
    VdbFile::new(vec![Grid::fog("density", block)]).write(&dir.path().join("block.vdb"));
    let f = "block.vdb";
    let q = |extra: &[&str]| {
        let mut a = query_args(f, "density", [-4.0, 8.5, 7.5], [20.0, 8.5, 8.5]);
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let b = |extra: &[&str]| {
        let mut a = bake_args(f, "density", "out.exr");
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let cases = [
        q(&["--estimator", "ratio", "--samples", "4294967295"]),
        b(&[
            "--estimator",
            "ratio",
            "--max-spp",
            "4294967295",
            "--target-error",
            "1e-6",
        ]),
        {
            let mut a = b(&[]);
            a[8] = "1000000".into(); // --res
            a
        },
        q(&["--estimator", "riemann", "--step", "1e-9"]),
        b(&["--estimator", "riemann", "--step", "1e-9"]),
    ];
    let mut problems = Vec::new();
    for args in &cases {
        let before = snapshot(dir.path());
        let r = umbra(dir.path(), GIB, &strs(args));
        let changed = diff(&before, &snapshot(dir.path()));
        let mut p = Vec::new();
        if let Some(d) = changed {
            p.push(format!("the working directory changed: {d}"));
        }
        match r.code {
            Some(1) => {
                if let Err(e) = refused_lines(&r) {
                    p.push(e);
                }
            }
            Some(2) => {}
            other => p.push(format!("exit code {other:?}, not 1 or 2")),
        }
        if r.timed_out || r.secs >= QUICK {
            p.push(format!("took {:.2} s (limit {QUICK} s)", r.secs));
        }
        // Counts name their largest accepted value; a step too fine names its range (the
        // smallest accepted step).
        if !(r.err().contains("at most") || r.err().contains("[0.001, ")) {
            p.push("stderr does not name the accepted limit (\"at most\" or the range)".into());
        }
        if r.err().contains("panicked") {
            p.push("panic".into());
        }
        if !p.is_empty() {
            problems.push(format!("{}\n  -> {}", r.describe(), p.join("; ")));
        }
    }
    assert_no_problems(&problems);
}

/// The stderr shape of an exit-1 run: warnings, then one error line (which names the flag
/// rather than the file when the fault is a flag).
fn refused_lines(r: &Run) -> Result<(), String> {
    let err = r.err();
    let lines: Vec<&str> = err.lines().collect();
    let n = lines
        .iter()
        .filter(|l| l.starts_with("umbra: error: "))
        .count();
    let ok = n == 1
        && lines
            .last()
            .is_some_and(|l| l.starts_with("umbra: error: "))
        && lines[..lines.len() - 1]
            .iter()
            .all(|l| l.starts_with("umbra: warning:"));
    if ok {
        Ok(())
    } else {
        Err(format!(
            "stderr is not warnings then exactly one `umbra: error: ` line ({n} error lines)"
        ))
    }
}
