//! `umbra query STAGE --positions PRIM` and a batch job's `[[positions]]` entry toward a stage
//! light with extent (`--light-angle`, `--light-radius`; issue 60): each point's answer is
//! `umbra query STAGE --at P --ray-id i` with the same keys, bit for bit; the job writes the
//! same answers as the command; the outputs say how many points were sampled; a transmittance
//! volume toward a sun with an angle holds at a voxel what `query --at` answers at its centre.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use assert_cmd::Command;
use serde_json::Value;
use std::path::{Path, PathBuf};

const CLOUD: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data/cloud.vdb");

const POINTS: [[f64; 3]; 4] = [
    [1.9, -1.0, 0.3],
    [-2.0, 1.5, 0.3],
    [0.0, 0.0, 0.0],
    [9.0, 9.0, 9.0],
];

fn umbra(args: &[&str]) -> (i32, String, String) {
    let o = Command::cargo_bin("umbra")
        .unwrap()
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code().unwrap(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn json(args: &[&str]) -> Value {
    let (code, out, err) = umbra(args);
    assert_eq!(code, 0, "{args:?}: {err}");
    serde_json::from_str(out.trim()).unwrap()
}

/// The cloud, a points prim and a sun travelling along -Y, at time code 1001.
fn stage(dir: &Path) -> PathBuf {
    let pts: Vec<String> = POINTS
        .iter()
        .map(|p| format!("({}, {}, {})", p[0], p[1], p[2]))
        .collect();
    let text = format!(
        "#usda 1.0\n(\n    startTimeCode = 1001\n    endTimeCode = 1001\n)\n\n\
         def Volume \"cloud\"\n{{\n    rel field:density = </cloud/density>\n\n    \
         def OpenVDBAsset \"density\"\n    {{\n        asset filePath = @{CLOUD}@\n        \
         token fieldName = \"density\"\n    }}\n}}\n\n\
         def Points \"pts\"\n{{\n    point3f[] points = [{}]\n}}\n\n\
         def DistantLight \"sun\"\n{{\n    double3 xformOp:rotateXYZ = (-90, 0, 0)\n    \
         uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}}\n",
        pts.join(", ")
    );
    let p = dir.join("shot.usda");
    std::fs::write(&p, text).unwrap();
    p
}

const KEYS: [&str; 6] = [
    "--light-angle=8",
    "--light-samples=64",
    "--density-scale=4",
    "--estimator=ratio",
    "--samples=2",
    "--seed=5",
];

#[test]
fn positions_answer_query_at_each_point_and_the_job_writes_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let shot = stage(dir.path());
    let s = shot.to_str().unwrap();
    let mut args = vec!["query", s, "--positions", "/pts", "--json"];
    args.extend(KEYS);
    let doc = json(&args);
    assert_eq!(doc["light_samples"], 64, "{doc}");
    let f = &doc["frames"][0];
    // The far point's cone misses the cloud, and one near point's passes between its voxels:
    // both answered without sampling.
    assert_eq!(f["sampled"], 2, "{doc}");
    // At the points as the stage holds them (point3f: f32 positions).
    for (i, p) in f["positions"].as_array().unwrap().iter().enumerate() {
        let at = format!("--at={},{},{}", p[0], p[1], p[2]);
        let id = i.to_string();
        let mut args = vec!["query", s, at.as_str(), "--ray-id", id.as_str(), "--json"];
        args.extend(KEYS);
        let one = json(&args);
        assert_eq!(one["T"], f["T"][i], "point {i}: {one}");
        assert_eq!(one["std_err"], f["std_err"][i], "point {i}: {one}");
    }
    // The text summary says how many points were sampled and the worst error bar.
    let mut args = vec!["query", s, "--positions", "/pts"];
    args.extend(KEYS);
    let (code, out, err) = umbra(&args);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("2 of 4 points sampled"), "{out}");

    // A job's [[positions]] entry with the same keys: the same answers, and the layer.
    let job = dir.path().join("job.toml");
    let layer = dir.path().join("out/pts.usda");
    std::fs::write(
        &job,
        format!(
            "[[positions]]\nusd = \"{s}\"\nprim = \"/pts\"\nusd_out = \"{}\"\nlight_angle = 8\n\
             light_samples = 64\ndensity_scale = 4\nestimator = \"ratio\"\nsamples = 2\n\
             seed = 5\n",
            layer.display()
        ),
    )
    .unwrap();
    let (code, _, err) = umbra(&["batch", job.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let frame: Value = serde_json::from_str(
        &std::fs::read_to_string(dir.path().join("out/pts.points/1001.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(frame["T"], f["T"]);
    assert_eq!(frame["std_err"], f["std_err"]);
    assert_eq!(frame["light_samples"], 64);
    assert_eq!(frame["sampled"], 2);
    // The job's layer is the command's.
    let cmd_layer = dir.path().join("cmd.usda");
    let mut args = vec!["query", s, "--positions", "/pts", "--usd-out"];
    let l = cmd_layer.to_str().unwrap();
    args.push(l);
    args.extend(KEYS);
    let (code, _, err) = umbra(&args);
    assert_eq!(code, 0, "{err}");
    let text = std::fs::read_to_string(&layer).unwrap();
    assert_eq!(text, std::fs::read_to_string(&cmd_layer).unwrap());
    // The error bars beside the answers, one time sample per frame.
    assert!(
        text.contains("float[] primvars:umbra:transmittance:sun.timeSamples")
            && text.contains("float[] primvars:umbra:transmittance_std_err:sun.timeSamples"),
        "{text}"
    );
    // Toward the point light, the layer holds T only, as before.
    let (code, _, err) = umbra(&[
        "query",
        s,
        "--positions",
        "/pts",
        "--usd-out",
        l,
        "--force",
        "--light-angle=0",
    ]);
    assert_eq!(code, 0, "{err}");
    let hard = std::fs::read_to_string(&cmd_layer).unwrap();
    assert!(
        !hard.contains("std_err") && hard.contains("transmittance:sun"),
        "{hard}"
    );
}

#[test]
fn a_jobs_bad_extent_keys_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let shot = stage(dir.path());
    for (keys, name) in [
        ("light_angle = -1", "positions[0].light_angle"),
        ("light_angle = 180", "positions[0].light_angle"),
        (
            "light_angle = 2\nlight_radius = 1",
            "positions[0].light_radius",
        ),
        // The stage light is a sun: a radius does not apply.
        ("light_radius = 1", "positions[0].light_radius"),
        ("light_dir = [0, -1, 0]", "positions[0]"),
    ] {
        let job = dir.path().join("job.toml");
        std::fs::write(
            &job,
            format!(
                "[[positions]]\nusd = \"{}\"\nprim = \"/pts\"\nusd_out = \"o.usda\"\n{keys}\n",
                shot.display()
            ),
        )
        .unwrap();
        let (code, _, err) = umbra(&["batch", job.to_str().unwrap()]);
        assert_eq!(code, 1, "{keys}: {err}");
        assert!(err.contains(name), "{keys}: {err}");
    }
}

#[test]
fn a_transmittance_volume_toward_a_sun_with_an_angle() {
    let dir = tempfile::tempdir().unwrap();
    let hard = dir.path().join("hard.vdb");
    let zero = dir.path().join("zero.vdb");
    let soft = dir.path().join("soft.vdb");
    let base = ["bake", CLOUD, "--light-dir=0,-1,0", "--density-scale=4"];
    let run = |extra: &[&str], out: &Path| -> Value {
        let mut args = base.to_vec();
        args.extend_from_slice(extra);
        args.extend(["-o", out.to_str().unwrap(), "--json"]);
        json(&args)
    };
    let h = run(&[], &hard);
    assert!(h.get("light_samples").is_none(), "{h}");
    run(&["--light-angle=0", "--light-samples=64"], &zero);
    // Zero extent: today's bytes.
    assert_eq!(std::fs::read(&hard).unwrap(), std::fs::read(&zero).unwrap());
    let s = run(&["--light-angle=8", "--light-samples=64"], &soft);
    assert_eq!(s["light_samples"], 64, "{s}");
    assert_eq!(s["sampled_fraction"], 1.0, "{s}");
    assert!(s["std_err_max"].as_f64().unwrap() > 0.0, "{s}");
    assert_eq!(s["voxels"], h["voxels"]);
    // The light's extent in the metadata (names and string values are stored as they are).
    let has = |p: &Path, what: &str| {
        let bytes = std::fs::read(p).unwrap();
        bytes.windows(what.len()).any(|w| w == what.as_bytes())
    };
    assert!(has(&soft, "umbra:light_extent") && has(&soft, "Sun { angle: 8.0 }"));
    assert!(has(&soft, "umbra:light_samples") && !has(&hard, "umbra:light_extent"));
}

/// A batch job of transmittance volumes takes `[bake]`'s keys of a light with extent: its
/// file is `umbra bake`'s, byte for byte; a job of maps takes them too.
#[test]
fn a_batch_job_of_transmittance_volumes_takes_the_keys() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    let write = |output: &str| {
        std::fs::write(
            &job,
            format!(
                "output = \"{}/{output}\"\n[[inputs]]\nfile = \"{CLOUD}\"\n[bake]\n\
                 light_dir = [0, -1, 0]\nlight_angle = 8.0\nlight_samples = 64\n\
                 density_scale = 4.0\n",
                dir.path().display()
            ),
        )
        .unwrap();
    };
    write("{stem}.vdb");
    let (code, _, err) = umbra(&["batch", job.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let cli = dir.path().join("cli.vdb");
    let (code, _, err) = umbra(&[
        "bake",
        CLOUD,
        "--light-dir=0,-1,0",
        "--light-angle=8",
        "--light-samples=64",
        "--density-scale=4",
        "-o",
        cli.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    // The batch's file is the command's, but for the task's key it carries.
    assert!(crate::common::same_volume_but_key(
        &dir.path().join("cloud.vdb"),
        &cli
    ));
    // A job of maps takes them too (a soft map per input).
    write("{stem}.exr");
    let (code, _, err) = umbra(&["batch", job.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(dir.path().join("cloud.exr").exists());
}

/// Extreme lights on a transmittance volume: answered (T in [0, 1]), never a panic; a work
/// beyond the budget is refused up front by name.
#[test]
fn a_transmittance_volume_under_extreme_lights() {
    let dir = tempfile::tempdir().unwrap();
    // A 16^3-voxel box of constant density 0.2.
    let mut leaves = Vec::new();
    for i in [0, 8] {
        for j in [0, 8] {
            for k in [0, 8] {
                leaves.push(crate::vdb_writer::Leaf::filled([i, j, k], 0.2));
            }
        }
    }
    let boxed = dir.path().join("box.vdb");
    crate::vdb_writer::VdbFile::new(vec![crate::vdb_writer::Grid::fog("density", leaves)])
        .write(&boxed);
    let tiles = boxed.to_str().unwrap();
    let out = dir.path().join("t.vdb");
    for light in [
        [
            "--light-dir=0,-1,0",
            "--light-angle=179.9",
            "--light-samples=64",
        ],
        [
            "--light-pos=0,0,0",
            "--light-radius=1e300",
            "--light-samples=64",
        ],
        [
            "--light-pos=1e300,0,0",
            "--light-radius=1e299",
            "--light-samples=64",
        ],
    ] {
        let mut args = vec!["bake", tiles];
        args.extend(light);
        args.extend(["-o", out.to_str().unwrap(), "--force", "--json"]);
        let v = json(&args);
        let (lo, hi) = (v["T_min"].as_f64().unwrap(), v["T_max"].as_f64().unwrap());
        assert!(
            (0.0..=1.0).contains(&lo) && (0.0..=1.0).contains(&hi),
            "{light:?}: {v}"
        );
        assert!(v["std_err_max"].as_f64().unwrap().is_finite(), "{v}");
    }
    let (code, _, err) = umbra(&[
        "bake",
        CLOUD,
        "--light-dir=0,-1,0",
        "--light-angle=8",
        "--light-samples=1048576",
        "-o",
        out.to_str().unwrap(),
        "--force",
    ]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("'--light-samples'") && err.contains("budget"),
        "{err}"
    );
}
