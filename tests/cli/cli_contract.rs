//! The command-line contract, for every command: one meaning per exit code (0 ok, 1 error with
//! one `umbra: error:` line naming the file or flag, 2 usage, 3 partial failure), nothing
//! written when a command fails (the working directory, hidden files included, is byte for byte
//! as before), negative numbers accepted by every numeric flag, and an interrupted bake leaves
//! neither temporary nor partial files. Also: the README's command and exit-code tables match
//! `umbra --help`.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn cloud() -> String {
    root().join("data/cloud.vdb").display().to_string()
}

fn level_set() -> Option<String> {
    let p = root().join("../shared/corpus/gen/sphere_levelset.vdb");
    p.exists().then(|| p.display().to_string())
}

fn run_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_umbra"))
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap()
}

/// Every file under `dir` (hidden ones too) with its bytes, and every directory.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                out.insert(p.clone(), None);
                todo.push(p);
            } else {
                out.insert(p.clone(), Some(std::fs::read(&p).unwrap()));
            }
        }
    }
    out
}

/// A working directory with an existing map, a text file, a valid job and a broken one.
fn workdir() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("existing.exr"), b"keep me").unwrap();
    std::fs::write(d.join(".hidden"), b"hidden").unwrap();
    std::fs::write(d.join("notes.txt"), b"not a vdb").unwrap();
    std::fs::write(d.join("bad.csv"), "a,b,c\n1,2,3\n").unwrap();
    std::fs::write(
        d.join("job.toml"),
        format!(
            "output = \"out/{{light}}.exr\"\n[[inputs]]\nfile = \"{}\"\n[[lights]]\nname = \"sun\"\ndir = [0, -1, 0]\n[bake]\nres = [8, 8]\n",
            cloud()
        ),
    )
    .unwrap();
    std::fs::write(d.join("broken.toml"), "output = [\n").unwrap();
    std::fs::write(
        d.join("badkey.toml"),
        "output = \"o.exr\"\n[[inputs]]\nfile = \"x.vdb\"\n[[lights]]\nname = \"a\"\ndir = [0, 0, 0]\n",
    )
    .unwrap();
    dir
}

#[test]
fn bad_invocations_exit_with_their_code_say_one_line_and_write_nothing() {
    let c = cloud();
    let c = c.as_str();
    let seg = ["--from", "-2,0,0", "--to", "2,0,0"];
    let mut cases: Vec<(Vec<&str>, i32, &str)> = vec![
        // info
        (vec!["info", "missing.vdb"], 1, "missing.vdb"),
        (vec!["info"], 2, ""),
        (vec!["info", c, "--grid", "nope"], 1, "nope"),
        (vec!["info", "notes.txt"], 1, "notes.txt"),
        (vec!["info", "--frobnicate", c], 2, ""),
        (
            vec!["info", "../shared/corpus/bad/zero_bytes.vdb"],
            1,
            "zero_bytes",
        ),
        // query
        (vec!["query", c, "--from", "0,0,0"], 1, "--to"),
        (vec!["query", c, "--at", "0,0,0"], 1, "--light-dir"),
        (vec!["query", c, "--from", "0,0", "--to", "1,1,1"], 2, ""),
        (
            [&["query", c], &seg[..], &["--estimator", "magic"]].concat(),
            1,
            "unknown estimator",
        ),
        (
            [
                &["query", c],
                &seg[..],
                &["--estimator", "riemann", "--step", "0"],
            ]
            .concat(),
            1,
            "--step",
        ),
        (
            [
                &["query", c],
                &seg[..],
                &["--estimator", "riemann", "--step", "-1"],
            ]
            .concat(),
            1,
            "--step",
        ),
        (
            [&["query", c], &seg[..], &["--density-scale", "-5"]].concat(),
            1,
            "density-scale",
        ),
        (
            [
                &["query", c],
                &seg[..],
                &["--estimator", "ratio", "--samples", "0"],
            ]
            .concat(),
            1,
            "--samples",
        ),
        (
            [
                &["query", c],
                &seg[..],
                &["--estimator", "ratio", "--step", "1"],
            ]
            .concat(),
            1,
            "--step",
        ),
        (
            [&["query", "missing.vdb"], &seg[..]].concat(),
            1,
            "missing.vdb",
        ),
        (
            [&["query", c, "--grid", "nope"], &seg[..]].concat(),
            1,
            "nope",
        ),
        (vec!["query", c, "--rays", "missing.csv"], 1, "missing.csv"),
        (vec!["query", c, "--rays", "bad.csv"], 1, "bad.csv"),
        (
            [&["query", c], &seg[..], &["--light-dir", "1,0,0"]].concat(),
            1,
            "--at",
        ),
        // bake
        (
            vec!["bake", c, "--light-dir", "1,0,0", "-o", "out.png"],
            1,
            "--output",
        ),
        (
            vec!["bake", c, "--light-dir", "1,0,0", "-o", "-"],
            1,
            "standard output",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "/sys/a.exr",
                "--res",
                "2048x2048",
            ],
            1,
            "/sys",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--preview",
                "no/p.png",
            ],
            1,
            "no/p.png",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--preview",
                "p.jpg",
            ],
            1,
            "--preview",
        ),
        (
            vec!["bake", c, "--light-dir", "1,0,0", "-o", "existing.exr"],
            1,
            "existing.exr",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--res",
                "0x10",
            ],
            1,
            "res",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--res",
                "-5x100",
            ],
            2,
            "--res",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--res",
                "big",
            ],
            2,
            "--res",
        ),
        (vec!["bake", c, "-o", "o.exr"], 1, "--light-dir"),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--fov",
                "30",
            ],
            1,
            "--fov",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--slices",
                "0",
            ],
            1,
            "slices",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--depths",
                "3,1",
            ],
            1,
            "increasing",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--target-error",
                "-1",
            ],
            1,
            "target-error",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--spp",
                "0",
            ],
            1,
            "--samples",
        ),
        (
            vec![
                "bake",
                c,
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
                "--density-scale",
                "-5",
            ],
            1,
            "density-scale",
        ),
        (
            vec!["bake", c, "--light-dir", "0,0,0", "-o", "o.exr"],
            1,
            "light-dir",
        ),
        (vec!["bake", c, "--light-dir", "1,0,0"], 2, ""),
        // batch
        (vec!["batch", "missing.toml"], 1, "missing.toml"),
        (vec!["batch", "broken.toml"], 1, "broken.toml"),
        (vec!["batch", "badkey.toml"], 1, "lights[0].dir"),
        (
            vec!["batch", "job.toml", "--task", "99"],
            1,
            "invalid argument '--task': 99",
        ),
        (vec!["batch", "job.toml", "--shard", "3/2"], 2, ""),
        // compare
        (
            vec!["compare", c, "-o", "cmp", "--estimators", "magic"],
            1,
            "unknown estimator",
        ),
        (vec!["compare", c, "-o", "/sys/cmp"], 1, "/sys"),
        (vec!["compare", "-o", "cmp"], 1, "--stress"),
        (
            vec![
                "compare",
                c,
                "-o",
                "cmp",
                "--estimators",
                "ratio",
                "--step",
                "1",
            ],
            1,
            "--step",
        ),
        (vec!["compare", c], 2, ""),
        // estimators
        (vec!["estimators", "--frob"], 2, ""),
    ];
    let ls = level_set();
    if let Some(ls) = &ls {
        cases.push((
            vec![
                "bake",
                ls,
                "--grid",
                "ls_sphere",
                "--light-dir",
                "1,0,0",
                "-o",
                "o.exr",
            ],
            1,
            "level set",
        ));
        cases.push((
            [&["query", ls, "--grid", "ls_sphere"], &seg[..]].concat(),
            1,
            "level set",
        ));
        cases.push((
            vec!["compare", ls, "--grid", "ls_sphere", "-o", "cmp"],
            1,
            "level set",
        ));
    }
    assert!(cases.len() >= 40, "{} cases", cases.len());
    let dir = workdir();
    // `../shared/...` is relative to the checkout: run those from a symlinked view.
    let before = snapshot(dir.path());
    for (args, code, needle) in &cases {
        let cwd = if args.iter().any(|a| a.starts_with("../shared")) {
            root()
        } else {
            dir.path().to_path_buf()
        };
        let o = run_in(&cwd, args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(*code), "{args:?}: {err}");
        if *code == 1 {
            assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
            assert!(err.starts_with("umbra: error: "), "{args:?}: {err}");
            assert!(err.contains(needle), "{args:?}: '{needle}' not in {err}");
        }
        assert_eq!(
            snapshot(dir.path()),
            before,
            "{args:?} changed the working directory"
        );
    }
}

#[test]
fn negative_numbers_work_with_and_without_equals() {
    let dir = workdir();
    let c = cloud();
    for args in [
        vec!["query", &c, "--from", "-2,-0.5,0", "--to", "2,0.5,-0.25"],
        vec!["query", &c, "--from=-2,-0.5,0", "--to=2,0.5,-0.25"],
        vec!["query", &c, "--at", "0,1.5,0", "--light-dir", "-1,-1,0"],
        vec!["query", &c, "--at=0,1.5,0", "--light-dir=-1,-1,0"],
        vec!["query", &c, "--at", "-0.5,1,0", "--light-pos", "-3,4,-2"],
    ] {
        let o = run_in(dir.path(), &args);
        assert!(
            o.status.success(),
            "{args:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    // Negative numeric values reach the library's validation (exit 1), not clap (exit 2).
    for flag in ["--density-scale", "--step"] {
        for form in [
            vec![flag.to_string(), "-3".into()],
            vec![format!("{flag}=-3")],
        ] {
            let mut args = vec!["query", c.as_str(), "--from", "0,0,0", "--to", "1,0,0"];
            args.extend(["--estimator", "riemann"]);
            args.extend(form.iter().map(String::as_str));
            let o = run_in(dir.path(), &args);
            assert_eq!(o.status.code(), Some(1), "{args:?}");
        }
    }
}

#[test]
fn res_n_is_n_on_the_long_side() {
    let dir = workdir();
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &cloud(),
            "--light-dir=-1,-1,0",
            "--res",
            "100",
            "-o",
            "m.exr",
            "--json",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let (w, h) = (v["width"].as_u64().unwrap(), v["height"].as_u64().unwrap());
    assert_eq!(w.max(h), 100, "{w}x{h}");
    assert!(
        w.min(h) >= 1 && w != h,
        "{w}x{h}: the aspect of the framed box"
    );
}

#[test]
fn partial_failures_exit_3_and_answer_the_rest() {
    let dir = workdir();
    std::fs::write(
        dir.path().join("rays.csv"),
        "-2,0,0,2,0,0\n-2,0,0,nan,0,0\n-2,0.5,0,2,0.5,0\n",
    )
    .unwrap();
    let o = run_in(dir.path(), &["query", &cloud(), "--rays", "rays.csv"]);
    assert_eq!(o.status.code(), Some(3));
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        out.lines().filter(|l| l.contains("T = ")).count(),
        2,
        "{out}"
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.starts_with("umbra: error: 1 of 3"), "{err}");
    // info over several files, one of them unreadable: the others are still described.
    let o = run_in(dir.path(), &["info", &cloud(), "notes.txt"]);
    assert_eq!(o.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&o.stdout).contains("density"));
}

#[test]
fn tiny_transmittance_is_printed_with_its_digits() {
    let dir = workdir();
    let o = run_in(
        dir.path(),
        &[
            "query",
            &cloud(),
            "--from",
            "-2,1.5,0",
            "--to",
            "2,1.5,0",
            "--density-scale",
            "60",
        ],
    );
    assert!(o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    let t = out
        .split("T = ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap();
    let t = t.trim_end_matches(',');
    let v: f64 = t.parse().unwrap();
    assert!(v > 0.0 && v < 1e-4, "{out}");
    assert!(t.contains('e'), "scientific notation: {out}");
}

#[test]
fn an_almost_empty_map_warns_and_suggests_a_density_scale() {
    let dir = workdir();
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &cloud(),
            "--light-dir=-1,-1,0",
            "--res",
            "16",
            "-o",
            "m.exr",
            "--density-scale",
            "0.001",
            "-q",
        ],
    );
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("almost empty") && err.contains("--density-scale"),
        "{err}"
    );
    let boxes = root().join("data/box_tiles.vdb").display().to_string();
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &boxes,
            "--light-dir=0,-1,0",
            "--res",
            "16",
            "-o",
            "k.exr",
            "--density-scale",
            "1e4",
            "-q",
        ],
    );
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("almost black"), "{err}");
}

/// Interrupt bakes (with and without a preview and slices) with SIGINT and SIGTERM at many
/// moments: afterwards there is no temporary file and either no output at all or every output,
/// complete and readable, and the message names what is on disk.
#[test]
fn interrupted_bakes_leave_no_temporary_or_partial_files() {
    let c = cloud();
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    let variants: [&[&str]; 4] = [
        &[],
        &["--preview", "p.png"],
        &["--slices", "3"],
        &["--preview", "p.png", "--slices", "2", "--stderr"],
    ];
    let base = [
        "bake",
        c.as_str(),
        "--light-dir=-1,-1,0.3",
        "--res",
        "900",
        "--estimator",
        "ratio",
        "--spp",
        "6",
        "-o",
        "m.exr",
        "-q",
    ];
    // The signals land across the bake's own duration on this machine (measured once, the
    // shortest variant uninterrupted), so most interrupt it whatever the machine's speed (a
    // few, near the end, may find it finished or committing).
    let full_ms = {
        let dir = tempfile::tempdir().unwrap();
        let t0 = std::time::Instant::now();
        let ok = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .current_dir(dir.path())
            .args(base)
            .status()
            .unwrap();
        assert!(ok.success());
        (t0.elapsed().as_millis() as u64).max(100)
    };
    let mut interrupted = 0;
    for k in 0..16 {
        let dir = tempfile::tempdir().unwrap();
        let extra = variants[k % variants.len()];
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        let child = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .current_dir(dir.path())
            .args(&args)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let wait_ms = 30 + rand() % full_ms;
        std::thread::sleep(std::time::Duration::from_millis(wait_ms));
        let sig = if k % 2 == 0 { "-INT" } else { "-TERM" };
        // The shell's built-in kill: no procps needed on a fresh machine.
        let _ = Command::new("sh")
            .args(["-c", &format!("kill {sig} {}", child.id())])
            .status();
        let out = child.wait_with_output().unwrap();
        let files: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            files.iter().all(|f| !f.ends_with(".tmp")),
            "{args:?} after {wait_ms} ms ({sig}): {files:?}"
        );
        match out.status.code() {
            Some(0) => {
                // Finished first: every output there and readable.
                let exr = bake_support::read_exr(&dir.path().join("m.exr"));
                assert!(exr.ch.contains_key("T"));
                if extra.contains(&"--preview") {
                    assert!(files.contains(&"p.png".to_string()), "{files:?}");
                }
            }
            code => {
                interrupted += 1;
                assert!(
                    matches!(code, Some(130 | 143) | None),
                    "{args:?}: exit {code:?}: {}",
                    String::from_utf8_lossy(&out.stderr)
                );
                // Outputs all or nothing: an interrupted commit finishes before the exit.
                let want: Vec<&str> = if extra.contains(&"--preview") {
                    vec!["m.exr", "p.png"]
                } else {
                    vec!["m.exr"]
                };
                let have: Vec<&str> = want
                    .iter()
                    .copied()
                    .filter(|f| files.contains(&(*f).to_string()))
                    .collect();
                assert!(
                    have.is_empty() || have == want,
                    "{args:?} after {wait_ms} ms: {files:?}"
                );
                assert!(files.len() == have.len(), "{files:?}");
                // The message says what is on disk: the outputs that were complete before the
                // signal, or that nothing was written.
                let err = String::from_utf8_lossy(&out.stderr);
                if code.is_some() {
                    if have.is_empty() {
                        assert!(err.contains("no output was written"), "{err}");
                    } else {
                        assert!(err.contains("complete before the interrupt"), "{err}");
                        for f in &have {
                            assert!(err.contains(f), "{f} not named: {err}");
                        }
                    }
                }
            }
        }
    }
    eprintln!("{interrupted} of 16 bakes interrupted (an uninterrupted one took {full_ms} ms)");
    assert!(
        interrupted >= 8,
        "only {interrupted} of 16 bakes were interrupted"
    );
}

#[test]
fn readme_tables_match_help() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let help = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .arg("--help")
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    // Commands: README's table rows `| \`umbra NAME ...` against the help's command list.
    let table = readme.split("## Commands").nth(1).unwrap();
    let mut documented: Vec<&str> = table
        .lines()
        .take_while(|l| !l.starts_with("##"))
        .filter_map(|l| l.strip_prefix("| `umbra "))
        .filter_map(|l| l.split([' ', '`']).next())
        .collect();
    documented.sort_unstable();
    let commands = help.split("Commands:").nth(1).unwrap();
    let mut listed: Vec<&str> = commands
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .collect();
    listed.sort_unstable();
    assert_eq!(documented, listed);
    // Exit codes: every `| N | meaning |` row of the README's table is in the help text.
    let codes = readme.split("## Exit codes").nth(1).unwrap();
    let rows: Vec<(String, String)> = codes
        .lines()
        .take_while(|l| !l.starts_with("##"))
        .filter_map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells.len() >= 3
                && cells[1].chars().all(|c| c.is_ascii_digit())
                && !cells[1].is_empty())
            .then(|| (cells[1].to_string(), cells[2].to_string()))
        })
        .collect();
    assert!(rows.len() >= 5, "{rows:?}");
    for (code, meaning) in rows {
        let first_word = meaning.split([' ', ':']).next().unwrap().to_lowercase();
        assert!(
            help.lines().any(|l| {
                let t = l.trim_start();
                t.starts_with(&code) && t[code.len()..].to_lowercase().contains(&first_word)
            }),
            "exit code {code} ({meaning}) is not in --help:\n{help}"
        );
    }
}

#[test]
fn csv_with_a_byte_order_mark_and_control_characters_in_names() {
    let dir = workdir();
    std::fs::write(
        dir.path().join("bom.csv"),
        "\u{feff}ox,oy,oz,ex,ey,ez\n-2,1.5,0,2,1.5,0\n",
    )
    .unwrap();
    let o = run_in(dir.path(), &["query", &cloud(), "--rays", "bom.csv"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // A file name with ESC and BEL is printed escaped by info.
    let weird = dir.path().join("a\u{1b}[2J\u{7}.vdb");
    std::fs::copy(root().join("data/cloud.vdb"), &weird).unwrap();
    let o = run_in(dir.path(), &["info", weird.to_str().unwrap()]);
    assert!(o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(!out.contains('\u{1b}') && !out.contains('\u{7}'), "{out:?}");
    assert!(out.contains("\\x1b[2J\\x07"), "{out}");
}

#[test]
fn extreme_numbers_get_sensible_answers_and_messages() {
    let dir = workdir();
    let c = cloud();
    // A light direction of 1e308 has a direction; a light at 1e300 is not "at the centre".
    let o = run_in(
        dir.path(),
        &[
            "query",
            &c,
            "--at",
            "0,1.5,0",
            "--light-dir=-1e308,-1e308,0",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = String::from_utf8_lossy(&o.stdout).to_string();
    let o = run_in(
        dir.path(),
        &["query", &c, "--at", "0,1.5,0", "--light-dir=-1,-1,0"],
    );
    assert_eq!(
        a,
        String::from_utf8_lossy(&o.stdout),
        "same direction, same answer"
    );
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &c,
            "--light-pos=1e300,1e300,0",
            "--ortho",
            "--res",
            "8",
            "-o",
            "far.exr",
            "-q",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("centre"), "{err}");
    // --fov 1e308: a short number in the message, not 309 digits.
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &c,
            "--light-pos=3,3,3",
            "--fov",
            "1e308",
            "-o",
            "f.exr",
        ],
    );
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("1e308") && err.len() < 200, "{err}");
    // --threads beyond any machine: refused at once with the limit.
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &c,
            "--light-dir=1,0,0",
            "--threads",
            "100000",
            "-o",
            "t.exr",
        ],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("at most 1024"));
    // A 100 kB CSV field is not echoed in full.
    let long = "9".repeat(100_000);
    std::fs::write(dir.path().join("long.csv"), format!("0,0,0,1,1,x{long}\n")).unwrap();
    let o = run_in(dir.path(), &["query", &c, "--rays", "long.csv"]);
    assert!(
        o.stdout.len() + o.stderr.len() < 2_000,
        "echoed {} bytes",
        o.stdout.len()
    );
    // JSON tau: "inf" through an opaque voxel is not the null of an estimator without tau.
    let o = run_in(
        dir.path(),
        &[
            "query",
            &c,
            "--from",
            "-2,1.5,0",
            "--to",
            "2,1.5,0",
            "--json",
            "--estimator",
            "ratio",
        ],
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["tau"].is_null());
}

#[test]
fn stale_temporaries_of_killed_runs_are_removed_and_log_dirs_are_not_invented() {
    let dir = workdir();
    // What a SIGKILLed run leaves: its pid (beyond any pid_max) no longer runs.
    let stale = dir.path().join(".m.exr.umbra-999999999-0.tmp");
    std::fs::write(&stale, b"half a map").unwrap();
    let o = run_in(
        dir.path(),
        &[
            "bake",
            &cloud(),
            "--light-dir=1,0,0",
            "--res",
            "8",
            "-o",
            "m.exr",
            "-q",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!stale.exists(), "the stale temporary is still there");
    let o = run_in(
        dir.path(),
        &[
            "batch",
            "job.toml",
            "--log",
            "/nonexistent-umbra/dir/x.jsonl",
        ],
    );
    assert_eq!(o.status.code(), Some(1));
    assert!(!Path::new("/nonexistent-umbra").exists());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--log"));
}

/// A reader that stops early (`umbra info --json ... | head`) closes the pipe: umbra stops
/// quietly with status 0, as on a terminal, in text and in JSON (whose writer reports the
/// closed pipe through serde_json's error, not an io::Error).
#[test]
fn a_closed_pipe_is_not_an_error() {
    let files = vec![cloud(); 200];
    for json in [false, true] {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_umbra"));
        cmd.arg("info");
        if json {
            cmd.arg("--json");
        }
        let mut child = cmd
            .args(&files)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // Close the read end before umbra writes: every write meets a closed pipe.
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        assert!(
            out.status.success() && out.stderr.is_empty(),
            "json {json}: {:?} {}",
            out.status,
            String::from_utf8_lossy(&out.stderr)
        );
    }
}
