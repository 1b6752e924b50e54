//! The loader against the shared corpus's reference statistics (`../shared/corpus/manifest.json`,
//! computed with OpenVDB 10 / pyopenvdb): every readable file and grid must match, every
//! malformed file OpenVDB rejects must be rejected with a typed error, and the `umbra info` CLI
//! must report errors on one line and print the library's report as JSON.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::common;

use common::{corpus_dir, entry_path, manifest, manifest_files, must_read, panic_message};
use serde_json::Value;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::process::Command;
use umbra::info::{FileInfo, GridInfo};

// ---------------------------------------------------------------------------------------------
// Value helpers
// ---------------------------------------------------------------------------------------------

/// A manifest or umbra JSON value as a number: numbers, `"inf"`/`"-inf"`/`"nan"` strings,
/// booleans as 0/1 and vectors as their length (OpenVDB's vec3 backgrounds). `null` is `None`.
fn num(v: &Value) -> Option<f64> {
    match v {
        Value::Number(n) => n.as_f64(),
        Value::String(s) => match s.to_ascii_lowercase().as_str() {
            "inf" | "+inf" | "infinity" => Some(f64::INFINITY),
            "-inf" | "-infinity" => Some(f64::NEG_INFINITY),
            "nan" => Some(f64::NAN),
            other => other.parse().ok(),
        },
        Value::Bool(b) => Some(f64::from(u8::from(*b))),
        Value::Array(a) => {
            let c: Option<Vec<f64>> = a.iter().map(num).collect();
            c.map(|c| c.iter().map(|x| x * x).sum::<f64>().sqrt())
        }
        _ => None,
    }
}

fn show(v: Option<f64>) -> String {
    v.map_or("none".to_string(), |x| format!("{x:e}"))
}

/// Value precision umbra guarantees for a value type: float, half, bool and (small) int32 values
/// are exactly representable in umbra's f32; double and vector lengths are rounded to f32.
fn exact_type(value_type: &str) -> bool {
    matches!(value_type, "float" | "bool" | "int32")
}

/// Compare a reference value with umbra's: exactly in f32 (the manifest prints the f32 value as
/// f64, so rounding it back to f32 is exact even if JSON parsing is off by an f64 ulp), or to a
/// relative tolerance.
fn same_value(reference: Option<f64>, got: Option<f64>, exact: bool) -> bool {
    match (reference, got) {
        (None, None) => true,
        (Some(a), Some(b)) if a.is_nan() || b.is_nan() => a.is_nan() && b.is_nan(),
        (Some(a), Some(b)) if a.is_infinite() || b.is_infinite() => a == b,
        (Some(a), Some(b)) if exact => (a as f32).to_bits() == (b as f32).to_bits(),
        (Some(a), Some(b)) => (a - b).abs() <= 1e-6 * a.abs().max(b.abs()),
        _ => false,
    }
}

fn rel_close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs())
}

// ---------------------------------------------------------------------------------------------
// Grid comparison
// ---------------------------------------------------------------------------------------------

/// Compare one grid's report with its manifest entry; push a line per mismatching field.
fn compare_grid(file: &str, m: &Value, g: &GridInfo, out: &mut Vec<String>) {
    let name = &g.name;
    let mut bad = |field: &str, expected: String, got: String| {
        out.push(format!(
            "{file} :: {name}: {field}: expected {expected}, got {got}"
        ));
    };
    if let Some(e) = &g.error {
        bad("load", "Ok".into(), format!("error: {e}"));
        return;
    }
    let vt = m["value_type"].as_str().unwrap_or("?");
    if g.value_type != vt {
        bad("value_type", vt.into(), g.value_type.clone());
    }
    let exact = exact_type(vt);

    // Topology: exact.
    let av = m["active_voxels"].as_u64();
    if av != g.active_voxels {
        bad(
            "active_voxels",
            format!("{av:?}"),
            format!("{:?}", g.active_voxels),
        );
    }
    let bbox: Option<[[i32; 3]; 2]> = serde_json::from_value(m["index_bbox"].clone()).ok();
    if bbox != g.index_bbox {
        bad(
            "index_bbox",
            format!("{bbox:?}"),
            format!("{:?}", g.index_bbox),
        );
    }
    if let Some(leaves) = m.get("leaf_nodes").and_then(Value::as_u64) {
        if Some(leaves) != g.leaf_count {
            bad(
                "leaf_count",
                leaves.to_string(),
                format!("{:?}", g.leaf_count),
            );
        }
    }
    let tiles = &m["active_tiles"];
    for (mkey, ukey) in [
        ("root_level_4096^3", "root"),
        ("upper_internal_128^3", "upper"),
        ("lower_internal_8^3", "lower"),
    ] {
        let want = tiles[mkey].as_u64();
        let got = g.tiles.as_ref().and_then(|t| t[ukey].as_u64());
        if want != got {
            bad(
                &format!("active tiles ({ukey})"),
                format!("{want:?}"),
                format!("{got:?}"),
            );
        }
    }

    // Transform.
    let map = m["transform_map"].as_str();
    if map != g.map.as_deref() {
        bad("map", format!("{map:?}"), format!("{:?}", g.map));
    }
    if map != Some("NonlinearFrustumMap") {
        let want: Option<[f64; 3]> = serde_json::from_value(m["voxel_size"].clone()).ok();
        let ok = match (want, g.voxel_size) {
            (Some(w), Some(v)) => (0..3).all(|a| rel_close(w[a], v[a], 1e-9)),
            _ => false,
        };
        if !ok {
            bad(
                "voxel_size",
                format!("{want:?}"),
                format!("{:?}", g.voxel_size),
            );
        }
    }

    // Values.
    let bg_want = num(&m["background"]);
    let bg_got = g.background.as_ref().and_then(num);
    if !same_value(bg_want, bg_got, exact) {
        bad("background", show(bg_want), show(bg_got));
    }
    for (mkey, got) in [("min", &g.value_min), ("max", &g.value_max)] {
        let want = num(&m[mkey]);
        let got = got.as_ref().and_then(num);
        if !same_value(want, got, exact) {
            bad(mkey, show(want), show(got));
        }
    }
    let sum_want = m["sum_finite"].as_f64();
    let sum_ok = match (sum_want, g.value_sum) {
        (Some(a), Some(b)) => (a - b).abs() <= (1e-6 * a.abs()).max(1e-6),
        _ => false,
    };
    if !sum_ok {
        bad("sum_finite", show(sum_want), show(g.value_sum));
    }
    let nan = m["nan_voxels"].as_u64();
    if nan != g.nan_count {
        bad(
            "nan_count",
            format!("{nan:?}"),
            format!("{:?}", g.nan_count),
        );
    }
    let inf = m["pos_inf_voxels"]
        .as_u64()
        .zip(m["neg_inf_voxels"].as_u64())
        .map(|(p, n)| p + n);
    if inf != g.inf_count {
        bad(
            "inf_count (+/-)",
            format!("{inf:?}"),
            format!("{:?}", g.inf_count),
        );
    }
}

/// Manifest grids that carry reference statistics.
fn reference_grids(entry: &Value) -> Vec<&Value> {
    entry["grids"]
        .as_array()
        .map(|g| {
            g.iter()
                .filter(|g| g.get("active_voxels").is_some())
                .collect()
        })
        .unwrap_or_default()
}

/// Compare a whole file report with its manifest entry. Returns the number of grids compared.
fn compare_file(file: &str, entry: &Value, info: &FileInfo, out: &mut Vec<String>) -> usize {
    let want: Vec<&str> = entry["grids"]
        .as_array()
        .map(|g| g.iter().filter_map(|g| g["name"].as_str()).collect())
        .unwrap_or_default();
    let got: Vec<&str> = info.grids.iter().map(|g| g.name.as_str()).collect();
    if want != got {
        out.push(format!(
            "{file}: grid names/order: expected {want:?}, got {got:?}"
        ));
    }
    let mut used = vec![false; info.grids.len()];
    let mut compared = 0;
    for m in reference_grids(entry) {
        let name = m["name"].as_str().unwrap_or("?");
        let found = (0..info.grids.len()).find(|&i| !used[i] && info.grids[i].name == name);
        match found {
            Some(i) => {
                used[i] = true;
                compare_grid(file, m, &info.grids[i], out);
                compared += 1;
            }
            None => out.push(format!(
                "{file} :: {name}: grid missing from umbra's report"
            )),
        }
    }
    compared
}

/// Open a file and report on every grid, catching panics.
fn report(path: &Path) -> Result<umbra::Result<FileInfo>, String> {
    catch_unwind(AssertUnwindSafe(|| {
        umbra::internals::vdb::open(path).map(|a| FileInfo::from_archive(&a))
    }))
    .map_err(|p| panic_message(p.as_ref()))
}

fn vdb_files_under(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(Result::ok)
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".vdb"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

// ---------------------------------------------------------------------------------------------
// Tests
// ---------------------------------------------------------------------------------------------

#[test]
fn every_readable_corpus_grid_matches_the_reference_statistics() {
    let Some(dir) = corpus_dir() else { return };
    let m = manifest(&dir);
    let files = manifest_files(&m);
    let mut mismatches = Vec::new();

    // Every .vdb on disk must be described by the manifest, so nothing is skipped silently.
    for sub in ["gen", "real", "bad"] {
        for name in vdb_files_under(&dir.join(sub)) {
            let rel = format!("{sub}/{name}");
            if !files.iter().any(|f| entry_path(f) == rel) {
                mismatches.push(format!("{rel}: on disk but not in manifest.json"));
            }
        }
    }

    let readable: Vec<&Value> = files.iter().filter(|f| must_read(entry_path(f))).collect();
    let expected_grids: usize = readable.iter().map(|f| reference_grids(f).len()).sum();
    let (mut files_checked, mut grids_checked) = (0usize, 0usize);
    for entry in &readable {
        let file = entry_path(entry);
        match report(&dir.join(file)) {
            Err(panic) => mismatches.push(format!("{file}: PANIC: {panic}")),
            Ok(Err(e)) => mismatches.push(format!("{file}: open failed: {e}")),
            Ok(Ok(info)) => {
                files_checked += 1;
                grids_checked += compare_file(file, entry, &info, &mut mismatches);
            }
        }
    }
    eprintln!(
        "corpus manifest: {files_checked}/{} readable files and {grids_checked}/{expected_grids} \
         reference grids checked, {} mismatches",
        readable.len(),
        mismatches.len()
    );
    assert!(
        mismatches.is_empty(),
        "{} mismatches against the corpus manifest:\n{}",
        mismatches.len(),
        mismatches.join("\n")
    );
    assert!(
        readable.len() >= 10,
        "manifest lists only {} readable files",
        readable.len()
    );
    assert!(
        expected_grids >= readable.len(),
        "too few reference grids: {expected_grids}"
    );
    assert_eq!(
        files_checked,
        readable.len(),
        "not every readable file was checked"
    );
    assert_eq!(
        grids_checked, expected_grids,
        "not every reference grid was checked"
    );
}

/// Bad files OpenVDB itself rejects (vdb_print error) or whose header the manifest's raw parser
/// cannot read: umbra must return an error for them. The others (`corrupt_leaf_payload`, whose
/// scrambled leaf values are still well-formed floats, and `flipped_header_bytes`, which
/// OpenVDB reads after warning about the version) umbra may read; if it does, it must agree with
/// the manifest.
fn must_reject(entry: &Value) -> bool {
    entry.get("openvdb_error").is_some()
        || entry["header"].get("error").is_some()
        || entry["header"]["magic_ok"] == Value::Bool(false)
}

#[test]
fn malformed_files_give_typed_errors_not_panics() {
    let Some(dir) = corpus_dir() else { return };
    let m = manifest(&dir);
    let mut failures = Vec::new();
    let mut outcomes = Vec::new();
    let bad: Vec<&Value> = manifest_files(&m)
        .iter()
        .filter(|f| entry_path(f).starts_with("bad/"))
        .collect();
    let mut rejected = 0;
    for entry in &bad {
        let file = entry_path(entry);
        let path = dir.join(file);
        let base = path.file_name().unwrap().to_string_lossy().into_owned();
        // open + load of every grid, separately from FileInfo (which swallows grid errors).
        let res = catch_unwind(AssertUnwindSafe(|| -> umbra::Result<usize> {
            let archive = umbra::internals::vdb::open(&path)?;
            for gd in &archive.grids {
                archive.load(gd)?;
            }
            Ok(archive.grids.len())
        }));
        match res {
            Err(p) => failures.push(format!("{file}: PANIC: {}", panic_message(p.as_ref()))),
            Ok(Err(e)) => {
                rejected += 1;
                let msg = e.to_string();
                outcomes.push(format!("{file}: Err({msg})"));
                if !msg.contains(&base) {
                    failures.push(format!(
                        "{file}: error message does not name the file: {msg}"
                    ));
                }
                if file == "bad/corrupt_leaf_payload.vdb" {
                    failures.push(format!("{file}: OpenVDB reads it but umbra fails: {msg}"));
                }
            }
            Ok(Ok(n)) => {
                outcomes.push(format!("{file}: Ok ({n} grids)"));
                if must_reject(entry) {
                    failures.push(format!(
                        "{file}: OpenVDB rejects it ({}) but umbra loaded {n} grid(s) without error",
                        entry
                            .get("openvdb_error")
                            .or_else(|| entry["header"].get("error"))
                            .map_or_else(|| "bad magic".to_string(), ToString::to_string)
                    ));
                } else if let Ok(Ok(info)) = report(&path) {
                    compare_file(file, entry, &info, &mut failures);
                }
            }
        }
    }
    eprintln!(
        "malformed files ({} in bad/, {rejected} rejected):\n  {}",
        bad.len(),
        outcomes.join("\n  ")
    );
    assert!(
        bad.len() >= 10,
        "manifest lists only {} bad files",
        bad.len()
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

fn umbra_cmd(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .expect("run the umbra binary")
}

/// `umbra` must exit 1 with exactly one stderr line `umbra: error: ...` containing every
/// `needles` string, and print nothing on stdout.
fn expect_cli_error(args: &[&str], needles: &[&str], failures: &mut Vec<String>) {
    let out = umbra_cmd(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let line = stderr.trim_end_matches('\n');
    let mut problems = Vec::new();
    if out.status.code() != Some(1) {
        problems.push(format!("exit status {:?}, expected 1", out.status.code()));
    }
    if line.lines().count() != 1 {
        problems.push(format!("{} stderr lines, expected 1", line.lines().count()));
    }
    if !line.starts_with("umbra: error: ") {
        problems.push("stderr does not start with `umbra: error: `".into());
    }
    for n in needles {
        if !line.contains(n) {
            problems.push(format!("stderr does not mention `{n}`"));
        }
    }
    if !out.stdout.is_empty() {
        problems.push(format!("{} bytes on stdout", out.stdout.len()));
    }
    if !problems.is_empty() {
        failures.push(format!(
            "umbra {}: {} (stderr: {line:?})",
            args.join(" "),
            problems.join("; ")
        ));
    }
}

#[test]
fn cli_reports_each_error_on_one_line() {
    let Some(dir) = corpus_dir() else { return };
    let m = manifest(&dir);
    let mut failures = Vec::new();
    let mut cases = 0;
    for entry in manifest_files(&m)
        .iter()
        .filter(|f| entry_path(f).starts_with("bad/"))
    {
        let file = entry_path(entry);
        let path = dir.join(file);
        let p = path.to_str().unwrap();
        let base = path.file_name().unwrap().to_str().unwrap();
        let lib_open_ok = umbra::internals::vdb::open(&path).is_ok();
        if must_reject(entry) || !lib_open_ok {
            for json in [true, false] {
                let args: &[&str] = if json {
                    &["info", p, "--json"]
                } else {
                    &["info", p]
                };
                expect_cli_error(args, &[base], &mut failures);
                cases += 1;
            }
        }
    }
    let tmp = tempfile::tempdir().unwrap();
    let tdir = tmp.path().to_str().unwrap();
    expect_cli_error(
        &["info", tdir, "--json"],
        &[tdir, "directory"],
        &mut failures,
    );
    let missing = tmp.path().join("no_such_file.vdb");
    let missing = missing.to_str().unwrap();
    expect_cli_error(
        &["info", missing, "--json"],
        &["no_such_file.vdb"],
        &mut failures,
    );
    let text = tmp.path().join("notes.vdb");
    std::fs::write(
        &text,
        "This is not a VDB file, just some text.\n".repeat(20),
    )
    .unwrap();
    expect_cli_error(
        &["info", text.to_str().unwrap(), "--json"],
        &["notes.vdb"],
        &mut failures,
    );
    let multi = dir.join("gen/multigrid_smoke.vdb");
    let multi = multi.to_str().unwrap();
    expect_cli_error(
        &["info", multi, "--grid", "nope"],
        &[
            "multigrid_smoke.vdb",
            "nope",
            "density",
            "temperature",
            "velocity",
        ],
        &mut failures,
    );
    expect_cli_error(
        &["info", multi, "--json", "--grid", "nope"],
        &[
            "multigrid_smoke.vdb",
            "nope",
            "density",
            "temperature",
            "velocity",
        ],
        &mut failures,
    );
    cases += 5;
    eprintln!("CLI error cases: {cases}");
    assert!(cases >= 20, "too few CLI error cases: {cases}");
    assert!(
        failures.is_empty(),
        "{} CLI failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn cli_json_equals_the_library_report() {
    let Some(dir) = corpus_dir() else { return };
    let mut failures = Vec::new();
    for file in [
        "gen/multigrid_smoke.vdb",
        "gen/extreme_nan_inf.vdb",
        "gen/tiles_root_level.vdb",
        "gen/empty_grid.vdb",
        "gen/xform_frustum.vdb",
        "real/blender_smoke_fluid_data_0050.vdb",
        "real/houdini20_no_grids.vdb",
    ] {
        let path = dir.join(file);
        let p = path.to_str().unwrap();
        let lib = FileInfo::from_archive(&umbra::internals::vdb::open(&path).unwrap());
        // Both sides go through JSON text and the same parser, so float parsing cannot differ.
        let lib_json: Value = serde_json::from_str(&serde_json::to_string(&lib).unwrap()).unwrap();
        let out = umbra_cmd(&["info", p, "--json"]);
        if out.status.code() != Some(0) {
            failures.push(format!(
                "{file}: `umbra info --json` exit {:?}: {}",
                out.status.code(),
                String::from_utf8_lossy(&out.stderr)
            ));
            continue;
        }
        match serde_json::from_slice::<Value>(&out.stdout) {
            Err(e) => failures.push(format!("{file}: `umbra info --json` is not JSON: {e}")),
            Ok(cli) if cli != lib_json => {
                failures.push(format!(
                    "{file}: CLI JSON differs from the library:\n{cli}\nvs\n{lib_json}"
                ));
            }
            Ok(_) => {}
        }
        let text = umbra_cmd(&["info", p]);
        if text.status.code() != Some(0) || text.stdout.is_empty() {
            failures.push(format!(
                "{file}: `umbra info` (text) exit {:?}",
                text.status.code()
            ));
        }
    }
    // --grid keeps exactly the grid asked for, with the library's values.
    let path = dir.join("gen/multigrid_smoke.vdb");
    let lib = FileInfo::from_archive(&umbra::internals::vdb::open(&path).unwrap());
    let want: Value = serde_json::from_str(
        &serde_json::to_string(lib.grids.iter().find(|g| g.name == "temperature").unwrap())
            .unwrap(),
    )
    .unwrap();
    let out = umbra_cmd(&[
        "info",
        path.to_str().unwrap(),
        "--json",
        "--grid",
        "temperature",
    ]);
    let cli: Value = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
    let grids = cli["grids"].as_array().cloned().unwrap_or_default();
    if out.status.code() != Some(0) || grids.len() != 1 || grids[0] != want {
        failures.push(format!(
            "--grid temperature: exit {:?}, grids {grids:?}",
            out.status.code()
        ));
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
