//! Motion blur on the command line (`--velocity`, `--shutter`, `--fps`, `--velocity-scale`,
//! `--time-samples`): a constant velocity is a translation, so a blurred map (and its slices,
//! the time-averaged visibility at given depths) equals the mean of exact maps of the volume
//! moved by `--xform` through the same camera; bad input ends in exit 1, one `umbra: error:`
//! line naming the flag or grid, and nothing written. The caches are written by OpenVDB
//! (`tests/motion/make_reference.py`, pyopenvdb).

use crate::bake_support::read_exr;
use crate::common;
use std::path::Path;
use std::process::Output;

fn umbra(args: &[&str]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) {
    let o = umbra(args);
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The caches of `make_reference.py` in `dir`, and its JSON; `None` without pyopenvdb.
fn caches(dir: &Path) -> Option<serde_json::Value> {
    if !common::oracle_available() {
        return None;
    }
    let script =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/motion/make_reference.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(script)
        .arg(dir)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(dir.join("reference.json")).unwrap();
    Some(serde_json::from_str(&text).unwrap())
}

#[test]
fn a_blurred_map_is_the_mean_of_translated_maps_through_one_camera() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(reference) = caches(d) else { return };
    let v: Vec<f64> = reference["constant"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    let file = d.join("constant.vdb");
    let file = file.to_str().unwrap();
    let blur = d.join("blur.exr");
    let (open, close, fps) = (-0.5, 1.0, 24.0);
    let common_args = ["--density-scale", "0.06", "--depths", "14,18,22", "--quiet"];
    let mut args = vec![
        "bake",
        file,
        "-o",
        blur.to_str().unwrap(),
        "--light-dir",
        "0.2,-0.3,-1",
        "--res",
        "40",
        "--velocity",
        "vel",
        "--shutter",
        "-0.5,1",
        "--fps",
        "24",
        "--estimator",
        "riemann",
        "--step",
        "0.25",
        "--time-samples",
        "64",
    ];
    args.extend_from_slice(&common_args);
    ok(&args);
    let blurred = read_exr(&blur);
    // The mean of exact maps of the volume moved by v t / F, 48 shutter midpoints.
    let n = 48;
    let mut mean: std::collections::HashMap<String, Vec<f64>> = Default::default();
    for j in 0..n {
        let t = open + (close - open) * (j as f64 + 0.5) / n as f64;
        let s = v.iter().map(|c| c * t / fps).collect::<Vec<_>>();
        let xform = format!("1,0,0,{},0,1,0,{},0,0,1,{},0,0,0,1", s[0], s[1], s[2]);
        let out = d.join(format!("still{j}.exr"));
        let mut a = vec![
            "bake",
            file,
            "-o",
            out.to_str().unwrap(),
            "--camera",
            blur.to_str().unwrap(),
            "--xform",
            &xform,
        ];
        a.extend_from_slice(&common_args);
        ok(&a);
        for (name, px) in read_exr(&out).ch {
            let m = mean.entry(name).or_insert_with(|| vec![0.0; px.len()]);
            for (m, p) in m.iter_mut().zip(px) {
                *m += f64::from(p) / n as f64;
            }
        }
    }
    let mut moved = 0.0f64;
    for (name, want) in &mean {
        let got = &blurred.ch[name];
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!(
                (f64::from(*g) - w).abs() < 3e-3,
                "{name} pixel {i}: blurred {g} vs mean of moved maps {w}"
            );
        }
    }
    // The blur is visible: the still map differs from the mean by much more.
    let still = d.join("still.exr");
    let mut a = vec![
        "bake",
        file,
        "-o",
        still.to_str().unwrap(),
        "--camera",
        blur.to_str().unwrap(),
    ];
    a.extend_from_slice(&common_args);
    ok(&a);
    let still = read_exr(&still);
    for (s, w) in still.ch["T"].iter().zip(&mean["T"]) {
        moved = moved.max((f64::from(*s) - w).abs());
    }
    assert!(moved > 0.05, "the test must blur: {moved}");
    assert_eq!(mean.len(), 4, "T and three slices: {:?}", mean.keys());
}

#[test]
fn bad_motion_input_is_one_line_naming_the_flag_or_grid_and_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let file = file.to_str().unwrap();
    let out = d.join("m.exr");
    let out_s = out.to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["--velocity", "vel"], "--estimator"),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--shutter",
                "1,0",
            ],
            "--shutter",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--shutter",
                "nan,1",
            ],
            "--shutter",
        ),
        (
            &["--velocity", "vel", "--estimator", "ratio", "--fps", "0"],
            "--fps",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--velocity-scale",
                "inf",
            ],
            "--velocity-scale",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "riemann",
                "--time-samples",
                "0",
            ],
            "--time-samples",
        ),
        (&["--shutter", "0,1"], "--shutter"),
        (&["--time-samples", "4"], "--time-samples"),
        // Options blur cannot take are refused by name (issue 58).
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--time-samples",
                "4",
            ],
            "--time-samples",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--granularity",
                "lower",
            ],
            "--granularity",
        ),
        // A blurred march counts every shutter time in the work budget (issue 58).
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "jittered",
                "--samples",
                "4096",
                "--time-samples",
                "1024",
                "--step",
                "0.005",
            ],
            "shutter times",
        ),
        // Reaches from extreme numbers (issue 58): refused with the reach, never a panic or a
        // wrapped count.
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "riemann",
                "--velocity-scale",
                "1e30",
            ],
            "world units",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--shutter=0,1e20",
            ],
            "world units",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--fps",
                "1e-300",
            ],
            "world units",
        ),
        (
            &[
                "--velocity",
                "vel",
                "--estimator",
                "ratio",
                "--shutter=0,1e6",
            ],
            "voxels)",
        ),
        (&["--velocity", "density", "--estimator", "ratio"], "vec3"),
        (&["--velocity", "nope", "--estimator", "ratio"], "nope"),
    ];
    for (extra, named) in cases {
        for cmd in ["bake", "query"] {
            let mut a = vec![cmd, file];
            if cmd == "bake" {
                a.extend_from_slice(&["-o", out_s, "--light-dir", "0,0,-1", "--res", "8"]);
            } else {
                a.extend_from_slice(&["--from", "13,-20,10", "--to", "13,30,10"]);
            }
            a.extend_from_slice(extra);
            let o = umbra(&a);
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(1), "{a:?}: {err}");
            assert_eq!(err.lines().count(), 1, "{a:?}: {err}");
            assert!(
                err.starts_with("umbra: error:") && err.contains(named),
                "{a:?}: {err}"
            );
            assert!(!out.exists(), "{a:?} wrote {}", out.display());
            if err.contains("world units") {
                assert!(
                    err.contains("--shutter") && err.contains("16777216 blocks"),
                    "{err}"
                );
            }
        }
    }
}

#[test]
fn queries_blur_and_the_still_shutter_is_the_still_answer() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let file = file.to_str().unwrap();
    let t = |extra: &[&str]| {
        let mut a = vec![
            "query",
            file,
            "--json",
            "--density-scale",
            "0.06",
            "--from",
            "13.3,-20,10.7",
            "--to",
            "13.3,30,10.7",
            "--estimator",
            "ratio",
            "--spp",
            "64",
        ];
        a.extend_from_slice(extra);
        let o = umbra(&a);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["T"].as_f64().unwrap()
    };
    let still = t(&[]);
    assert_eq!(t(&["--velocity", "vel", "--shutter", "0,0"]), still);
    assert_eq!(t(&["--velocity", "vel", "--velocity-scale", "0"]), still);
    assert_ne!(t(&["--velocity", "vel", "--shutter", "-1,1"]), still);
}

#[test]
fn every_product_and_a_batch_job_take_the_motion() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let f = file.to_str().unwrap();
    let out = |n: &str| d.join(n).to_str().unwrap().to_string();
    let motion = [
        "--velocity",
        "vel",
        "--shutter",
        "-1,1",
        "--estimator",
        "riemann",
        "--density-scale",
        "0.06",
        "--quiet",
    ];
    let bake = |o: &str, extra: &[&str], moving: bool| {
        let mut a = vec!["bake", f, "-o", o];
        a.extend_from_slice(extra);
        if moving {
            a.extend_from_slice(&motion);
        } else {
            a.extend_from_slice(&[
                "--estimator",
                "riemann",
                "--density-scale",
                "0.06",
                "--quiet",
            ]);
        }
        ok(&a);
    };
    // Maps blur wherever the camera looks from; deep and fixed-size deep maps and
    // transmittance volumes are made with the motion too.
    for (name, extra) in [
        ("ortho", vec!["--light-dir", "0.2,-0.3,-1", "--res", "24"]),
        ("persp", vec!["--light-pos", "13,9,40", "--res", "24"]),
        (
            "omni",
            vec!["--light-pos", "13,9,11", "--omni", "cube", "--res", "8"],
        ),
    ] {
        let (a, b) = (
            out(&format!("{name}_blur.exr")),
            out(&format!("{name}_still.exr")),
        );
        bake(&a, &extra, true);
        bake(&b, &extra, false);
        let (a, b) = (read_exr(Path::new(&a)), read_exr(Path::new(&b)));
        let diff = a.ch["T"]
            .iter()
            .zip(&b.ch["T"])
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(diff > 0.01, "{name}: the blurred map equals the still one");
    }
    for extra in [vec!["--deep"], vec!["--deep-format", "fourier:7"]] {
        let o = out("deep.exr");
        let mut a = vec!["--light-dir", "0.2,-0.3,-1", "--res", "12", "--force"];
        a.extend_from_slice(&extra);
        bake(&o, &a, true);
    }
    bake(&out("t.vdb"), &["--light-dir", "0.2,-0.3,-1"], true);
    // A job's [bake] keys: the same map as the command line's, bit for bit.
    let job = d.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "output = \"{}/job_{{stem}}.exr\"\n[[inputs]]\nfile = \"{f}\"\n[[lights]]\nname = \
             \"sun\"\ndir = [0.2, -0.3, -1.0]\n[bake]\nres = 24\nvelocity = \"vel\"\nshutter = \
             [-1.0, 1.0]\nestimator = \"riemann\"\ndensity_scale = 0.06\n",
            d.display()
        ),
    )
    .unwrap();
    ok(&["batch", job.to_str().unwrap(), "--quiet"]);
    let from_job = read_exr(&d.join("job_swirl.exr"));
    let direct = read_exr(&d.join("ortho_blur.exr"));
    assert_eq!(from_job.ch["T"], direct.ch["T"]);
    let schema = umbra(&["batch", "--schema"]);
    let schema = String::from_utf8_lossy(&schema.stdout);
    for key in [
        "velocity",
        "shutter",
        "fps",
        "velocity_scale",
        "time_samples",
    ] {
        assert!(schema.contains(&format!("\"{key}\"")), "schema lacks {key}");
    }
}

#[test]
fn a_job_with_an_extreme_reach_fails_its_task_by_name_not_by_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let f = d.join("swirl.vdb");
    let job = d.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "output = \"{}/job_{{stem}}.exr\"\n[[inputs]]\nfile = \"{}\"\n[[lights]]\nname = \
             \"sun\"\ndir = [0.2, -0.3, -1.0]\n[bake]\nres = 8\nvelocity = \"vel\"\n\
             velocity_scale = 1e30\nestimator = \"riemann\"\n",
            d.display(),
            f.display()
        ),
    )
    .unwrap();
    let o = umbra(&["batch", job.to_str().unwrap(), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        matches!(o.status.code(), Some(1 | 3)),
        "{:?}: {err}",
        o.status
    );
    assert!(
        err.contains("world units") && !err.contains("panicked"),
        "{err}"
    );
    assert!(!d.join("job_swirl.exr").exists());
}

#[test]
fn a_shutter_that_moves_the_cache_past_its_own_size_is_warned_about() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let file = file.to_str().unwrap();
    let q = |scale: &str| {
        umbra(&[
            "query",
            file,
            "--from",
            "13,-20,10",
            "--to",
            "13,30,10",
            "--velocity",
            "vel",
            "--estimator",
            "riemann",
            "--velocity-scale",
            scale,
        ])
    };
    let far = q("5");
    let err = String::from_utf8_lossy(&far.stderr);
    assert!(far.status.success(), "{err}");
    assert!(
        err.contains("farther than the cache's own size") && err.contains("voxels"),
        "{err}"
    );
    let near = q("1");
    assert!(!String::from_utf8_lossy(&near.stderr).contains("farther"));
}

/// Issue 58: a blurred map's `T.stderr` channel holds as the query's does. A 48x48 `riemann`
/// map of the swirling cache at 32 time samples against the same map at 1024 (so only the time
/// sampling is judged): no pixel reports 0 where it is off, at most 1 % beyond 4 error bars.
/// One time sample writes NaN (unknown) error bars.
#[test]
fn a_blurred_maps_error_channel_holds() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let file = file.to_str().unwrap();
    let bake = |k: &str, name: &str| {
        let out = d.join(name);
        ok(&[
            "bake",
            file,
            "-o",
            out.to_str().unwrap(),
            "--light-dir",
            "0.2,-0.3,-1",
            "--res",
            "48",
            "--stderr",
            "--velocity",
            "vel",
            "--shutter",
            "-1,1",
            "--density-scale",
            "0.06",
            "--estimator",
            "riemann",
            "--step",
            "0.5",
            "--time-samples",
            k,
            "--quiet",
        ]);
        read_exr(&out)
    };
    let reference = bake("1024", "ref.exr");
    let map = bake("32", "k32.exr");
    let (t, err, want) = (&map.ch["T"], &map.ch["T.stderr"], &reference.ch["T"]);
    let (mut beyond4, mut wrong_zeros, mut blurred) = (0, 0, 0);
    for ((t, e), w) in t.iter().zip(err).zip(want) {
        let off = (t - w).abs();
        blurred += usize::from(*w < 0.999);
        if *e == 0.0 {
            wrong_zeros += usize::from(off > 1e-4);
        } else if off > 4.0 * e {
            beyond4 += 1;
        }
    }
    assert!(blurred > 200, "only {blurred} pixels see the cache");
    assert_eq!(wrong_zeros, 0);
    assert!(
        beyond4 * 100 <= t.len(),
        "{beyond4} of {} beyond 4",
        t.len()
    );
    let one = bake("1", "k1.exr");
    let nan = one.ch["T.stderr"].iter().filter(|e| e.is_nan()).count();
    assert!(
        nan >= blurred,
        "{nan} unknown error bars, {blurred} blurred pixels"
    );
}

/// `/usr/bin/time -f %M` of `umbra args`: the exit status, umbra's stderr, and the child's
/// peak resident set in KiB (time's last line).
fn peak_kib(args: &[&str]) -> (std::process::ExitStatus, String, u64) {
    let o = std::process::Command::new("/usr/bin/time")
        .args(["-f", "%M", env!("CARGO_BIN_EXE_umbra")])
        .args(args)
        .output()
        .expect("/usr/bin/time (Debian package time) measures the peak memory");
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    let (rest, last) = err
        .trim_end()
        .rsplit_once('\n')
        .unwrap_or(("", err.trim_end()));
    // time's own note of a failed command is not umbra's.
    let rest: Vec<&str> = rest
        .lines()
        .filter(|l| !l.starts_with("Command exited with non-zero status"))
        .collect();
    (o.status, rest.join("\n"), last.trim().parse().unwrap())
}

/// A blurred map under `--max-memory` is baked in parts: the same EXR bytes as the whole bake,
/// at a lower peak memory; a budget below the least part is exit 1, one line naming the flag,
/// nothing written. The cache is the sample cloud tiled 5 x 5 x 5 with a swirling velocity
/// (`tests/motion/make_moving_cloud.py`, pyopenvdb).
#[test]
fn a_blurred_bake_under_max_memory_is_the_same_map_at_a_lower_peak() {
    if !common::oracle_available() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("moving.vdb");
    let script = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/motion/make_moving_cloud.py");
    let o = std::process::Command::new("/usr/bin/python3")
        .arg(script)
        .arg(&cache)
        .args(["--copies", "5", "5", "5"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let cache = cache.to_str().unwrap();
    let bake = |out: &Path, budget: Option<&str>| {
        let mut a = vec![
            cache,
            "--velocity",
            "vel",
            // The ray path both ways (a whole blurred riemann map is swept by default, equal to
            // the rays up to the order of its sums; parts go by rays).
            "--estimator",
            "riemann",
            "--order",
            "rays",
            "--res",
            "48x40",
            "--light-dir",
            "0.3,-1,0.2",
            "-o",
            out.to_str().unwrap(),
        ];
        if let Some(b) = budget {
            a.extend(["--max-memory", b]);
        }
        let mut args = vec!["bake"];
        args.extend(a);
        peak_kib(&args)
    };
    let whole_exr = dir.path().join("whole.exr");
    let (s, err, whole) = bake(&whole_exr, None);
    assert!(s.success(), "{err}");
    let parts_exr = dir.path().join("parts.exr");
    let (s, err, parts) = bake(&parts_exr, Some("96M"));
    assert!(s.success(), "{err}");
    assert!(
        std::fs::read(&whole_exr).unwrap() == std::fs::read(&parts_exr).unwrap(),
        "the EXR files differ"
    );
    assert!(
        parts * 4 < whole * 3,
        "peak {parts} KiB in parts against {whole} KiB whole"
    );
    // Left to choose its order, the same bake in parts goes by rays and says so (issue 67).
    let o = umbra(&[
        "bake",
        cache,
        "--velocity",
        "vel",
        "--estimator",
        "riemann",
        "--res",
        "48x40",
        "--light-dir",
        "0.3,-1,0.2",
        "--max-memory",
        "96M",
        "--json",
        "-o",
        dir.path().join("auto.exr").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("ray by ray") && err.contains("in parts under --max-memory"),
        "{err}"
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["order"], "rays", "{v}");
    assert!(
        v["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w["kind"] == "sweep-declined"),
        "{v}"
    );
    let small = dir.path().join("small.exr");
    let (s, err, _) = bake(&small, Some("8M"));
    assert_eq!(s.code(), Some(1), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("umbra: error: invalid argument '--max-memory'"),
        "{err}"
    );
    assert!(!small.exists());
}

/// Issue 67: a blurred `riemann` map the object-order sweep declines goes ray by ray and says
/// why, in stderr and in `--json` `warnings` (kind `sweep-declined`); a map it takes says
/// nothing and reports `"order": "sweep"`; `--order rays`, asked for, is not warned about.
/// (A map in parts under `--max-memory`: `a_blurred_bake_under_max_memory_is_the_same_map_at_a_lower_peak`.)
#[test]
fn a_blurred_map_the_sweep_declines_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let Some(_) = caches(d) else { return };
    let file = d.join("swirl.vdb");
    let file = file.to_str().unwrap();
    let out = d.join("m.exr");
    let bake = |extra: &[&str]| -> (String, serde_json::Value) {
        let mut a = vec![
            "bake",
            file,
            "--velocity",
            "vel",
            "--estimator",
            "riemann",
            "--res",
            "24",
            "--light-dir",
            "0.3,-1,0.2",
            "--json",
            "--force",
            "-o",
            out.to_str().unwrap(),
        ];
        a.extend(extra);
        let o = umbra(&a);
        let err = String::from_utf8_lossy(&o.stderr).to_string();
        assert!(o.status.success(), "{extra:?}: {err}");
        (err, serde_json::from_slice(&o.stdout).unwrap())
    };
    let declined = |v: &serde_json::Value| -> Vec<String> {
        v["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|w| w["kind"] == "sweep-declined")
            .map(|w| w["reason"].as_str().unwrap().to_string())
            .collect()
    };
    let (err, v) = bake(&[]);
    assert_eq!(v["order"], "sweep", "{v}");
    assert!(
        declined(&v).is_empty() && !err.contains("ray by ray"),
        "{err}"
    );
    let (err, v) = bake(&["--order", "rays"]);
    assert_eq!(v["order"], "rays", "{v}");
    assert!(
        declined(&v).is_empty() && !err.contains("ray by ray"),
        "{err}"
    );
    for (extra, why) in [
        (&["--interp", "nearest"][..], "--interp nearest"),
        (&["--global-majorant"][..], "--global-majorant"),
        (&["--target-error", "0.01"][..], "--target-error"),
        (&["--depths", "10,20"][..], "--depths"),
    ] {
        let (err, v) = bake(extra);
        assert_eq!(v["order"], "rays", "{extra:?}: {v}");
        let reasons = declined(&v);
        assert_eq!(reasons.len(), 1, "{extra:?}: {v}");
        assert!(reasons[0].contains(why), "{extra:?}: {reasons:?}");
        assert!(
            err.contains("warning") && err.contains("ray by ray") && err.contains(why),
            "{extra:?}: {err}"
        );
    }
}
