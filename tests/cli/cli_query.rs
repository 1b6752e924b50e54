//! `umbra query` modes: `--at` toward a directional or point light, `--rays` CSV batches (input
//! order, per-line errors, thread-count independence, stdin), and bad arguments.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use assert_cmd::Command;
use serde_json::Value;
use umbra::regular::optical_depth;
use umbra::{Interp, Ray, Volume};

fn umbra() -> Command {
    Command::cargo_bin("umbra").unwrap()
}

/// Run `umbra query FILE ARGS --json`; (exit code, one JSON value per stdout line, stderr).
fn query(file: &str, args: &[&str], stdin: Option<&str>) -> (i32, Vec<Value>, String) {
    let mut c = umbra();
    c.args(["query", file, "--json"]).args(args);
    if let Some(s) = stdin {
        c.write_stdin(s);
    }
    let o = c.output().unwrap();
    let lines = String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    (
        o.status.code().unwrap(),
        lines,
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn t(v: &Value) -> f64 {
    v["T"].as_f64().unwrap()
}

fn csv(p: [f64; 3]) -> String {
    format!("{},{},{}", p[0], p[1], p[2])
}

#[test]
fn at_light_dir_traces_to_the_volume_edge() {
    let at = [0.1, 1.4, -0.2];
    let d = [-1.0, -1.5, 0.5];
    let (code, a, _) = query(
        "data/cloud.vdb",
        &["--at", &csv(at), "--light-dir", &csv(d)],
        None,
    );
    assert_eq!(code, 0);
    let len = a[0]["length"].as_f64().unwrap();
    assert!(len > 0.5 && len < 10.0, "{len}");
    // The same segment written out, and a much longer one (zero background: nothing more).
    let n = (d.iter().map(|v| v * v).sum::<f64>()).sqrt();
    let end = |l: f64| std::array::from_fn(|k| at[k] - l * d[k] / n);
    for l in [len, 100.0] {
        let (_, b, _) = query(
            "data/cloud.vdb",
            &[
                &format!("--from={}", csv(at)),
                &format!("--to={}", csv(end(l))),
            ],
            None,
        );
        assert!(
            (t(&a[0]) - t(&b[0])).abs() < 1e-12,
            "{} vs {}",
            t(&a[0]),
            t(&b[0])
        );
    }
    assert!(t(&a[0]) < 0.99, "the point is inside the cloud");
    // A non-zero background: the ray still ends (finite tau), where the volume box ends.
    let (code, c, err) = query(
        "data/bg_multi.vdb",
        &[
            "--grid",
            "density",
            "--at",
            "0,2,0",
            "--light-dir",
            "1,0.2,0",
        ],
        None,
    );
    if code == 0 {
        let tau = c[0]["tau"].as_f64().unwrap();
        assert!(tau.is_finite() && tau > 0.0, "{tau}");
    } else {
        panic!("{err}");
    }
}

#[test]
fn at_light_pos_is_the_segment_to_the_light() {
    let (at, light) = ([0.3, 1.5, 0.1], [4.0, 5.0, -2.0]);
    let (code, a, _) = query(
        "data/cloud.vdb",
        &[
            "--at",
            &csv(at),
            "--light-pos",
            &csv(light),
            "--density-scale",
            "3",
        ],
        None,
    );
    assert_eq!(code, 0);
    let (_, b, _) = query(
        "data/cloud.vdb",
        &[
            &format!("--from={}", csv(at)),
            &format!("--to={}", csv(light)),
            "--density-scale",
            "3",
        ],
        None,
    );
    assert_eq!(t(&a[0]), t(&b[0]));
}

/// A CSV data row: its line number and segment, or `None` for a bad line.
type Row = Option<(usize, [f64; 6])>;

/// 150 segments through the cloud from a fixed LCG, with bad lines at known places.
fn batch() -> (String, Vec<Row>) {
    let mut s = 12345u64;
    let mut r = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut text = String::from("# a comment\nox, oy, oz, ex, ey, ez\n");
    let mut rows = Vec::new();
    for n in 0..150 {
        let line = text.lines().count() + 1;
        match n {
            7 => text.push_str("1,2,three,4,5,6\n"),
            40 => text.push_str("1,2,3,4,5\n"),
            41 => text.push('\n'),
            90 => text.push_str("nan,0,0,1,1,1\n"),
            _ => {
                let v: [f64; 6] = std::array::from_fn(|k| {
                    if k % 3 == 1 {
                        0.2 + 3.0 * r()
                    } else {
                        4.0 * r() - 2.0
                    }
                });
                text.push_str(&format!(
                    "{},{},{},{},{},{}\n",
                    v[0], v[1], v[2], v[3], v[4], v[5]
                ));
                rows.push(Some((line, v)));
                continue;
            }
        }
        if n != 41 {
            rows.push(None);
        }
    }
    (text, rows)
}

#[test]
fn rays_batch_answers_in_order_with_per_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (text, rows) = batch();
    let f = dir.path().join("rays.csv");
    std::fs::write(&f, &text).unwrap();
    let vol = Volume::load("data/cloud.vdb", "density", 1.0).unwrap();
    let mut outs = Vec::new();
    for threads in ["1", "2"] {
        let (code, out, err) = query(
            "data/cloud.vdb",
            &["--rays", f.to_str().unwrap(), "--threads", threads],
            None,
        );
        assert_eq!(code, 3, "{err}");
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(
            err.starts_with("umbra: error: 3 of 149 queries failed (first: line 10: oz = 'three'"),
            "{err}"
        );
        assert_eq!(out.len(), rows.len());
        for (o, row) in out.iter().zip(&rows) {
            match row {
                None => assert!(o["error"].is_string(), "{o}"),
                Some((line, v)) => {
                    assert_eq!(o["line"].as_u64().unwrap() as usize, *line);
                    let ray = Ray::between([v[0], v[1], v[2]], [v[3], v[4], v[5]]).unwrap();
                    let want = optical_depth(&vol, &ray, Interp::Trilinear).unwrap();
                    // Exact batches run on the f32 kernel (`regular::optical_depths`): the
                    // f64 walk's answer to `2e-6 tau + 1e-7`.
                    let tau = o["tau"].as_f64().unwrap();
                    assert!(
                        (tau - want.tau).abs() <= 2e-6 * want.tau + 1e-7,
                        "{tau} vs {}",
                        want.tau
                    );
                    for k in ["T", "std_err", "tau", "lookups", "estimator", "seconds"] {
                        assert!(!o[k].is_null() || k == "tau", "{k} missing in {o}");
                    }
                }
            }
        }
        outs.push(out);
    }
    // Exact answers do not depend on the thread count either (bit for bit).
    let taus =
        |out: &Vec<serde_json::Value>| out.iter().map(|o| o["tau"].clone()).collect::<Vec<_>>();
    assert_eq!(taus(&outs[0]), taus(&outs[1]));
    // Stochastic answers do not depend on the thread count, and row n is ray id n.
    let est = ["--estimator", "ratio", "--samples", "8", "--seed", "4"];
    let mut ts = Vec::new();
    for threads in ["1", "2"] {
        let (_, out, _) = query(
            "data/cloud.vdb",
            &[&["--rays", "-", "--threads", threads][..], &est[..]].concat(),
            Some(&text),
        );
        ts.push(out.iter().map(|o| o["T"].clone()).collect::<Vec<_>>());
    }
    assert_eq!(ts[0], ts[1]);
    let (n, (_, v)) = rows
        .iter()
        .enumerate()
        .filter_map(|(n, r)| r.map(|r| (n, r)))
        .nth(20)
        .unwrap();
    let (_, single, _) = query(
        "data/cloud.vdb",
        &[
            &[
                &format!("--from={},{},{}", v[0], v[1], v[2]) as &str,
                &format!("--to={},{},{}", v[3], v[4], v[5]),
                "--ray-id",
                &n.to_string(),
            ][..],
            &est[..],
        ]
        .concat(),
        None,
    );
    assert_eq!(single[0]["T"], ts[0][n]);
}

#[test]
fn plain_batch_output_names_lines() {
    let o = umbra()
        .args(["query", "data/cloud.vdb", "--rays", "-"])
        .write_stdin("ox,oy,oz,ex,ey,ez\n-3,1.5,0,3,1.5,0\nx\n")
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(o.status.code(), Some(3));
    assert!(lines[0].starts_with("line 2: T = "), "{out}");
    assert!(
        lines[1].starts_with("line 3: error: expected 6 fields"),
        "{out}"
    );
}

#[test]
fn bad_query_arguments_are_one_line_errors() {
    let cases: [(&[&str], Option<&str>, &str); 9] = [
        (&["--from", "0,0,0"], None, "go together"),
        (&["--at", "0,0,0"], None, "--at needs"),
        (
            &[
                "--at",
                "0,0,0",
                "--light-dir",
                "1,0,0",
                "--light-pos",
                "1,1,1",
            ],
            None,
            "not both",
        ),
        (&["--light-dir", "1,0,0"], None, "exactly one"),
        (
            &["--from", "0,0,0", "--to", "1,1,1", "--rays", "-"],
            Some("ox,oy,oz,ex,ey,ez\n"),
            "exactly one",
        ),
        (&[], None, "exactly one"),
        (
            &["--at", "0,0,0", "--light-dir", "0,0,0"],
            None,
            "has no length",
        ),
        (
            &["--rays", "-"],
            Some("a,b,c\n1,2,3\n"),
            "neither the header ox,oy,oz,ex,ey,ez nor six numbers",
        ),
        (&["--rays", "-"], Some("\n# nothing\n"), "no segments"),
    ];
    for (args, stdin, want) in cases {
        let mut c = umbra();
        c.args(["query", "data/cloud.vdb"]).args(args);
        if let Some(s) = stdin {
            c.write_stdin(s);
        }
        let o = c.output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with("umbra: error: ") && err.contains(want),
            "{args:?}: {err}"
        );
    }
    let o = umbra()
        .args(["query", "data/cloud.vdb", "--rays", "/no/such.csv"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
}

/// Far points (issue 68, item 3): a segment, a point light, a sun and a sphere light from
/// `x = 1e16` and `1e17` along `y = 0.5, z = 0` through the cloud answer what the same line
/// from `x = 3` answers (0.049315), within 1e-6: the walk starts next to the cloud, not
/// from 1e16 away (2 world units of f64 resolution there). An oblique line keeps its line
/// too; a finite 1e300-long segment has a finite length, in text and JSON.
#[test]
fn far_points_answer_what_near_points_answer() {
    let cloud = "data/cloud.vdb";
    let one = |args: &[&str]| {
        let (code, v, err) = query(cloud, args, None);
        assert_eq!(code, 0, "{args:?}: {err}");
        assert!(!err.contains("met no active voxel"), "{args:?}: {err}");
        t(&v[0])
    };
    let near = one(&["--from", "3,0.5,0", "--to=-3,0.5,0"]);
    assert!((near - 0.049315).abs() < 1e-6, "{near}");
    let soft_near = one(&[
        "--at",
        "3,0.5,0",
        "--light-pos=-3,0.5,0",
        "--light-radius",
        "1e-7",
    ]);
    assert!((soft_near - near).abs() < 1e-6, "{soft_near} {near}");
    for x in ["1e16", "1e17"] {
        let (a, b) = (format!("{x},0.5,0"), format!("-{x},0.5,0"));
        let cases: [(&str, Vec<&str>); 4] = [
            ("segment", vec!["--from", &a, "--to", &b]),
            ("point light", vec!["--at", &a, "--light-pos", &b]),
            ("sun", vec!["--at", &a, "--light-dir", "1,0,0"]),
            (
                "sphere light",
                vec!["--at", &a, "--light-pos", &b, "--light-radius", "1e-7"],
            ),
        ];
        for (what, args) in cases {
            let got = one(&args);
            assert!(
                (got - near).abs() < 1e-6,
                "{what} at {x}: {got}, near {near}"
            );
        }
    }
    // An oblique line, y = 3x in z = 0, from 1e16 away against the same line near.
    let near = one(&["--from", "2,6,0", "--to=-2,-6,0"]);
    let far = one(&["--from", "1e16,3e16,0", "--to=-1e16,-3e16,0"]);
    assert!((far - near).abs() < 1e-6, "oblique: {far}, near {near}");
    let far = one(&[
        "--at",
        "1e16,3e16,0",
        "--light-pos=-1e16,-3e16,0",
        "--light-radius",
        "1e-7",
    ]);
    assert!(
        (far - near).abs() < 1e-6,
        "oblique sphere light: {far}, near {near}"
    );
    // A segment 1e300 long: its length is finite (it printed inf, and null in JSON).
    let (code, v, _) = query(cloud, &["--from", "0,0,0", "--to", "1e300,0,0"], None);
    assert_eq!(code, 0);
    assert_eq!(v[0]["length"].as_f64(), Some(1e300), "{}", v[0]);
    let o = umbra()
        .args(["query", cloud, "--from", "0,0,0", "--to", "1e300,0,0"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("length 1e300") && !text.contains("inf"),
        "{text}"
    );
}

/// A perspective map from a light 1e16 away (issue 68, item 3, maps): its pinhole is too far
/// for the sweep's footprints and its rays' walks, which gave `T` up to 6.9; it is traced, each
/// ray moved next to the volume, and is the sun's map along the same axis to 2e-4.
#[test]
fn a_map_from_a_far_light_is_the_suns() {
    let dir = tempfile::tempdir().unwrap();
    let range = |args: &[&str]| -> (f64, f64) {
        let out = dir.path().join("m.exr");
        let o = umbra()
            .args(["bake", "data/cloud.vdb", "--res", "16", "--force", "-o"])
            .arg(&out)
            .args(args)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        assert!(
            o.status.success(),
            "{text}{}",
            String::from_utf8_lossy(&o.stderr)
        );
        let r = text
            .split("T in [")
            .nth(1)
            .unwrap()
            .split(']')
            .next()
            .unwrap();
        let (a, b) = r.split_once(", ").unwrap();
        (a.parse().unwrap(), b.parse().unwrap())
    };
    let sun = range(&["--light-dir", "1,0,0"]);
    let far = range(&["--light-pos=-1e16,0.5,0"]);
    assert!(far.1 <= 1.0, "far {far:?}");
    assert!(
        (far.0 - sun.0).abs() <= 2e-4 && (far.1 - sun.1).abs() <= 2e-4,
        "far {far:?}, sun {sun:?}"
    );
}

/// A deep map from a light 1e16 away (issue 68, item 3): its depths, distances from the light
/// in f32, cannot tell the cloud's layers apart, so it is refused naming `--deep` and why
/// (it failed with "the profile's depths and optical depths must not decrease"); from 100
/// units away it is baked.
#[test]
fn a_deep_map_from_a_far_light_is_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("d.exr");
    let bake = |pos: &str| {
        umbra()
            .args(["bake", "data/cloud.vdb", "--res", "8", "--deep", "--force"])
            .arg(format!("--light-pos={pos}"))
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap()
    };
    let o = bake("-1e16,0.5,0");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("umbra: error: ") && err.contains("'--deep'") && err.contains("32-bit"),
        "{err}"
    );
    assert!(!out.exists());
    let o = bake("-100,0.5,0");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.exists());
}
