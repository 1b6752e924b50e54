//! `umbra query --at` toward a light with extent (`--light-angle`, `--light-radius`,
//! `--light-samples`; issue 60, first slice): zero extent prints today's bytes, the answer
//! is the same for `--threads 1` and 2, JSON reports the directions traced, and the products
//! that do not answer them yet (transmittance volumes, per-point answers) refuse the flags by
//! name. Maps: tests/cli/lights_maps.rs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use assert_cmd::Command;
use serde_json::Value;

const CLOUD: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data/cloud.vdb");

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

/// The JSON answer of a query, `seconds` aside.
fn answer(extra: &[&str]) -> Value {
    let mut args = vec![
        "query",
        CLOUD,
        "--at=1.9,-1.0,0.3",
        "--density-scale",
        "4",
        "--json",
    ];
    args.extend_from_slice(extra);
    let (code, out, err) = umbra(&args);
    assert_eq!(code, 0, "{err}");
    let mut v: Value = serde_json::from_str(out.trim()).unwrap();
    v.as_object_mut().unwrap().remove("seconds");
    v
}

#[test]
fn zero_extent_prints_the_point_lights_bytes() {
    let sun = ["--light-dir=0,-1,0"];
    let hard = answer(&sun);
    assert!(hard.get("light_samples").is_none());
    let zero = answer(&["--light-dir=0,-1,0", "--light-angle", "0"]);
    assert_eq!(hard.to_string(), zero.to_string());
    let lamp = answer(&["--light-pos=0.5,4,0"]);
    let zero = answer(&["--light-pos=0.5,4,0", "--light-radius", "0"]);
    assert_eq!(lamp.to_string(), zero.to_string());
}

#[test]
fn a_soft_answer_reports_its_directions_and_ignores_the_thread_count() {
    let soft = |threads: &str| {
        answer(&[
            "--light-dir=0,-1,0",
            "--light-angle",
            "8",
            "--light-samples",
            "100",
            "--estimator",
            "ratio",
            "--samples",
            "2",
            "--threads",
            threads,
        ])
    };
    let one = soft("1");
    assert_eq!(one.to_string(), soft("2").to_string());
    // 100 rounded up to 16 replicates of 7.
    assert_eq!(one["light_samples"], 112);
    assert!(one["std_err"].as_f64().unwrap() > 0.0);
    assert!(one["tau"].is_null());
    let hard = answer(&["--light-dir=0,-1,0"]);
    assert!((one["T"].as_f64().unwrap() - hard["T"].as_f64().unwrap()).abs() > 0.01);
    // The text answer says how many directions.
    let (code, out, _) = umbra(&[
        "query",
        CLOUD,
        "--at=1.9,-1.0,0.3",
        "--light-dir=0,-1,0",
        "--light-angle=8",
    ]);
    assert_eq!(code, 0);
    assert!(out.contains(" light directions"), "{out}");
}

#[test]
fn every_refusal_names_its_flag() {
    let dir = tempfile::tempdir().unwrap();
    let exr = dir.path().join("m.exr");
    let vdb = dir.path().join("t.vdb");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-angle=-1",
            ],
            "--light-angle",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-angle=180",
            ],
            "--light-angle",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-angle=nan",
            ],
            "--light-angle",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-pos=0,4,0",
                "--light-angle=2",
            ],
            "--light-angle",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-radius=1",
            ],
            "--light-radius",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-pos=0,4,0",
                "--light-radius=-2",
            ],
            "--light-radius",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-samples=64",
            ],
            "--light-samples",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-angle=1",
                "--light-samples=0",
            ],
            "--light-samples",
        ),
        (
            vec![
                "query",
                CLOUD,
                "--at=0,-1,0",
                "--light-dir=0,-1,0",
                "--light-angle=1",
                "--light-samples=4000000000",
            ],
            "--light-samples",
        ),
        (
            vec!["query", CLOUD, "--positions", "/pts", "--light-radius=-1"],
            "--light-radius",
        ),
        (
            vec![
                "bake",
                CLOUD,
                "--light-dir=0,-1,0",
                "--receiver-depth=2",
                "-o",
            ],
            "--receiver-depth",
        ),
        (
            vec![
                "bake",
                CLOUD,
                "--light-pos=0,4,0",
                "--light-radius=-1",
                "-o",
            ],
            "--light-radius",
        ),
    ];
    for (mut args, flag) in cases {
        // A map refuses a receiver depth without a light with extent; both products refuse
        // a bad size.
        let out = if flag == "--receiver-depth" {
            exr.to_str().unwrap()
        } else {
            vdb.to_str().unwrap()
        };
        if args[0] == "bake" {
            args.push(out);
        }
        let (code, _, err) = umbra(&args);
        assert_eq!(code, 1, "{args:?}: {err}");
        assert!(
            err.starts_with("umbra: error: ") && err.contains(&format!("'{flag}'")),
            "{args:?}: {err}"
        );
    }
    assert!(!exr.exists() && !vdb.exists());
    // A batch job of per-point answers too.
    let job = dir.path().join("job.toml");
    std::fs::write(
        &job,
        "[[positions]]\nusd = \"shot.usda\"\nprim = \"/pts\"\nusd_out = \"o.usda\"\n[bake]\n\
         light_dir = [0, -1, 0]\nlight_angle = 2.0\n",
    )
    .unwrap();
    let (code, _, err) = umbra(&["batch", job.to_str().unwrap()]);
    assert_eq!(code, 1, "{err}");
    assert!(
        err.contains("bake.light_angle") && err.contains("each entry"),
        "{err}"
    );
}

/// A sphere light 1e300 away (its squared distance overflows): answered, never an error about
/// a ray without direction. Toward `+x` the whole cone passes beside the cloud's voxels: `T =
/// 1` proven, without sampling; up and to `-x` it crosses the cloud: sampled, an error bar
/// that is not 0.
#[test]
fn a_sphere_light_at_1e300_is_answered() {
    let v = answer(&["--light-pos=1e300,0,0", "--light-radius", "1e299"]);
    assert_eq!(
        (&v["T"], &v["std_err"], &v["light_samples"]),
        (&Value::from(1.0), &Value::from(0.0), &Value::from(0)),
        "{v}"
    );
    let v = answer(&["--light-pos=-1e300,0.5e300,0", "--light-radius", "1e299"]);
    let t = v["T"].as_f64().unwrap();
    assert!(t > 0.0 && t < 1.0, "{v}");
    assert!(v["std_err"].as_f64().unwrap() > 0.0, "{v}");
}
