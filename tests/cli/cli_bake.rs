//! `umbra bake` end to end: pixel rays rebuilt from the EXR header attributes alone give the
//! same T with `umbra query`; the `--json` camera object matches them; a real OpenEXR reader
//! (OpenImageIO's `iinfo` / `oiiotool`, Debian `openimageio-tools`) opens the map; thread count
//! does not change a byte; bad arguments give one-line errors and leave nothing behind.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use assert_cmd::Command;
use bake_support::read_exr;
use serde_json::Value;
use std::path::Path;

fn umbra() -> Command {
    Command::cargo_bin("umbra").unwrap()
}

fn bake(dir: &Path, name: &str, extra: &[&str]) -> Value {
    let out = dir.join(name);
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--grid",
            "density",
            "--json",
            "-o",
        ])
        .arg(&out)
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

fn v3(v: &Value) -> [f64; 3] {
    std::array::from_fn(|a| v[a].as_f64().unwrap())
}

fn csv(p: [f64; 3]) -> String {
    format!("{},{},{}", p[0], p[1], p[2])
}

#[test]
fn header_attributes_rebuild_rays_that_query_reproduces() {
    let dir = tempfile::tempdir().unwrap();
    let ratio = ["--estimator", "ratio", "--samples", "16", "--seed", "5"];
    let cases: [(&str, &[&str], &[&str]); 3] = [
        (
            "ortho.exr",
            &["--light-dir=-1,-1,0.3", "--res", "40x30"],
            &[],
        ),
        (
            "persp.exr",
            &["--light-pos", "5,4,3", "--res", "30x30"],
            &[],
        ),
        (
            "ratio.exr",
            &[
                "--light-dir",
                "0.2,-1,0.1",
                "--res",
                "20x16",
                "--order",
                "rays",
            ],
            &ratio,
        ),
    ];
    for (name, args, est) in cases {
        let common = ["--density-scale", "2", "--interp", "trilinear"];
        let summary = bake(dir.path(), name, &[args, &common[..], est].concat());
        let exr = read_exr(&dir.path().join(name));
        // Exact maps are traced in object order; the ratio map asks for ray order (`--order
        // rays`), where a pixel is what `query --ray-id` answers.
        let order = if name == "ortho.exr" || name == "persp.exr" {
            "sweep"
        } else {
            "rays"
        };
        assert_eq!(summary["order"], order, "{name}");
        // The JSON camera object is exactly the six keys, equal to the attributes.
        let cam = &summary["camera"];
        let mut keys: Vec<&String> = cam.as_object().unwrap().keys().collect();
        keys.sort();
        assert_eq!(
            keys,
            ["direction", "kind", "origin", "step_x", "step_y", "t_max"]
        );
        assert_eq!(cam["kind"].as_str().unwrap(), exr.text("camera_kind"));
        // (serde_json's default float parsing may be one ulp off.)
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(1.0);
        for k in ["origin", "step_x", "step_y", "direction"] {
            let (a, b) = (v3(&cam[k]), exr.v3d(&format!("camera_{k}")));
            assert!(
                (0..3).all(|c| near(a[c], b[c])),
                "{name} {k}: {a:?} vs {b:?}"
            );
        }
        assert!(near(
            cam["t_max"].as_f64().unwrap(),
            exr.f64("camera_t_max")
        ));
        assert_eq!(exr.f64("density_scale"), 2.0);
        assert_eq!(exr.text("grid"), "density");
        assert_eq!(exr.text("source_file"), "data/cloud.vdb");
        let (w, h) = (exr.w, exr.h);
        for (i, j) in [
            (0, 0),
            (w - 1, 0),
            (0, h - 1),
            (w / 2, h / 3),
            (w - 1, h - 1),
            (w / 3, h / 2),
        ] {
            let ray = exr.ray(i, j);
            let p = j * w + i;
            let o = umbra()
                .args(["query", "data/cloud.vdb", "--grid", "density", "--json"])
                .args(["--density-scale", "2", "--interp", "trilinear"])
                .arg(format!("--from={}", csv(ray.origin().to_array())))
                .arg(format!("--to={}", csv(ray.at(ray.t_max()).to_array())))
                .args(["--ray-id", &p.to_string()])
                .args(est)
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
            let q: Value = serde_json::from_slice(&o.stdout).unwrap();
            let t = q["T"].as_f64().unwrap();
            let got = f64::from(exr.ch["T"][p]);
            assert!(
                (t - got).abs() < 2e-6,
                "{name} ({i},{j}): query {t} vs map {got}"
            );
        }
    }
}

#[test]
fn real_openexr_reader_opens_the_map() {
    let dir = tempfile::tempdir().unwrap();
    let s = bake(
        dir.path(),
        "m.exr",
        &[
            "--light-dir=-1,-1,0",
            "--res",
            "64x48",
            "--slices",
            "2",
            "--stderr",
        ],
    );
    let p = dir.path().join("m.exr");
    let Ok(o) = std::process::Command::new("iinfo")
        .arg("-v")
        .arg(&p)
        .output()
    else {
        assert!(
            std::env::var("UMBRA_SKIP_OIIO").as_deref() == Ok("1"),
            "iinfo (Debian openimageio-tools) is not installed; set UMBRA_SKIP_OIIO=1 to skip"
        );
        return;
    };
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    for want in [
        "4 channel, float openexr",
        "channel list: T, T.stderr, slice00.T, slice01.T",
        "worldToCamera:",
        "worldToNDC:",
        "umbra:camera_kind: \"ortho\"",
        "umbra:camera_origin:",
        "umbra:camera_t_max:",
        "umbra:estimator: \"regular\"",
        "umbra:light_dir: -1, -1, 0",
        "umbra:depth.01:",
    ] {
        assert!(text.contains(want), "iinfo -v lacks '{want}':\n{text}");
    }
    // oiiotool's own decoding of T (the first channel) has our mean.
    let o = std::process::Command::new("oiiotool")
        .arg("--stats")
        .arg(&p)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    let avg: f64 = text
        .lines()
        .find_map(|l| l.trim().strip_prefix("Stats Avg:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no Stats Avg in:\n{text}"));
    let mean = s["T_mean"].as_f64().unwrap();
    assert!((avg - mean).abs() < 1e-5, "oiiotool mean {avg} vs {mean}");
}

#[test]
fn one_and_two_threads_give_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "--light-dir",
        "1,-0.4,0.2",
        "--res",
        "48x40",
        "--estimator",
        "ratio",
        "--spp",
        "4",
        "--seed",
        "9",
        "--target-error",
        "0.05",
        "--slices",
        "3",
        "--stderr",
    ];
    let mut files = Vec::new();
    for t in ["1", "2"] {
        let name = format!("t{t}.exr");
        let s = bake(dir.path(), &name, &[&args[..], &["--threads", t]].concat());
        assert_eq!(s["threads"].as_u64().unwrap().to_string(), t);
        files.push(std::fs::read(dir.path().join(name)).unwrap());
    }
    assert_eq!(files[0], files[1]);
}

#[test]
fn force_preview_and_overwrite() {
    let dir = tempfile::tempdir().unwrap();
    let args = ["--light-dir", "0,-1,0", "--res", "32x24", "--preview"];
    let png = dir.path().join("p.png");
    let s = bake(
        dir.path(),
        "a.exr",
        &[&args[..], &[png.to_str().unwrap()]].concat(),
    );
    assert_eq!(s["preview"].as_str().unwrap(), png.to_str().unwrap());
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let info = dec.read_info().unwrap();
    assert_eq!((info.info().width, info.info().height), (32, 24));
    let before = std::fs::read(dir.path().join("a.exr")).unwrap();
    // Without --force nothing is touched; with it both are rewritten.
    let o = umbra()
        .args(["bake", "data/cloud.vdb", "--light-dir", "1,0,0", "-o"])
        .arg(dir.path().join("a.exr"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(std::fs::read(dir.path().join("a.exr")).unwrap(), before);
    let all = [&args[..], &[png.to_str().unwrap(), "--force", "--spp", "2"]].concat();
    bake(dir.path(), "a.exr", &all);
}

#[test]
fn bad_arguments_give_one_line_errors_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let existing = dir.path().join("existing.exr");
    std::fs::write(&existing, b"keep me").unwrap();
    let out = dir.path().join("out.exr");
    let out = out.to_str().unwrap();
    let inside = "0,1.6,0";
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--light-dir", "0,0,0", "-o", out], "has no length"),
        (
            vec!["--light-dir", "1,0,0", "--res", "0x0", "-o", out],
            "no pixels",
        ),
        (
            vec!["--light-dir", "1,0,0", "--res", "100000x100000", "-o", out],
            "too large",
        ),
        (vec!["--light-pos", inside, "--ortho", "-o", out], "inside"),
        (vec!["--light-pos", inside, "-o", out], "--fov"),
        (
            vec!["--light-pos", "9,9,9", "--fov", "180", "-o", out],
            "(0, 180)",
        ),
        (
            vec!["--light-dir", "1,0,0", "--fov", "40", "-o", out],
            "perspective",
        ),
        (vec!["-o", out], "--light-dir"),
        (
            vec!["--light-dir", "1,0,0", "-o", existing.to_str().unwrap()],
            "--force",
        ),
        (
            vec!["--light-dir", "1,0,0", "-o", "/nonexistent-dir/x.exr"],
            "no directory",
        ),
        (
            vec![
                "--light-dir",
                "1,0,0",
                "-o",
                dir.path().to_str().unwrap(),
                "--force",
            ],
            "directory",
        ),
        (
            vec!["--light-dir", "1,0,0", "--slices", "0", "-o", out],
            "slices",
        ),
        (
            vec!["--light-dir", "1,0,0", "--depths", "3,1", "-o", out],
            "increasing",
        ),
        (
            vec![
                "--light-dir",
                "1,0,0",
                "--slices",
                "2",
                "--depths",
                "1",
                "-o",
                out,
            ],
            "not both",
        ),
        (
            vec!["--light-dir", "1,0,0", "--target-error=-1", "-o", out],
            "target-error",
        ),
        (
            vec!["--light-dir", "1,0,0", "--spp", "0", "-o", out],
            "samples",
        ),
        (
            vec!["--light-dir", "1,0,0", "--estimator", "magic", "-o", out],
            "unknown estimator",
        ),
    ];
    for (args, want) in cases {
        let o = umbra()
            .args(["bake", "data/cloud.vdb"])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with("umbra: error: ") && err.contains(want),
            "{args:?}: {err}"
        );
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["existing.exr"], "{args:?} left {names:?}");
    }
    assert_eq!(std::fs::read(&existing).unwrap(), b"keep me");
    // A value that is not a resolution at all is a usage error, as for every flag's value.
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--light-dir",
            "1,0,0",
            "--res",
            "big",
            "-o",
            out,
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("expected WxH"));
    assert!(!std::path::Path::new(out).exists());
    let o = umbra()
        .args(["bake", "no/such.vdb", "--light-dir", "1,0,0", "-o", out])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
}

/// An option a product does not honour is said by name: `--max-memory` on a colour map (which
/// loads whole) is a warning on stderr and in `--json` `warnings`, naming the flag. A level set
/// with background 0 baked as a solid (Blender's liquids write `phi` so) is warned about by
/// name, and its map has no T = 0 pixel where the field only touches 0.
#[test]
fn unhonoured_options_and_zero_backgrounds_are_warned_about_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--light-dir=0,-1,0",
            "--res",
            "32",
            "--sigma-t",
            "1,2,3",
            "--max-memory",
            "64M",
            "--json",
            "-o",
        ])
        .arg(dir.path().join("c.exr"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("warning") && err.contains("--max-memory"),
        "{err}"
    );
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let w = &v["warnings"][0];
    assert_eq!(w["kind"], "memory-budget-ignored", "{v}");
    assert!(w["message"].as_str().unwrap().contains("--max-memory"));
    // Blender's real smoke-and-liquid cache: `phi_inflow` is a level set of background 0.
    let file = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/real/blender_smoke_fluid_data_0050.vdb");
    if !file.exists() {
        assert!(std::env::var("UMBRA_SKIP_CORPUS").as_deref() == Ok("1"));
        return;
    }
    let o = umbra()
        .arg("bake")
        .arg(&file)
        .args([
            "--grid",
            "phi_inflow",
            "--levelset",
            "solid",
            "--light-dir=0,-1,0",
            "--res",
            "64",
            "--json",
            "-o",
        ])
        .arg(dir.path().join("phi.exr"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("level set 'phi_inflow' has background 0"),
        "{err}"
    );
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["warnings"][0]["kind"], "solid-background", "{v}");
}

/// The percentages a farm engine's lines carry, in order (`prefix N suffix` lines only).
fn percents(text: &str, prefix: &str, suffix: &str) -> Vec<u32> {
    text.lines()
        .filter_map(|l| l.strip_prefix(prefix)?.strip_suffix(suffix)?.parse().ok())
        .collect()
}

/// `--progress ENGINE` prints the engine's lines, rising from 0 to 100 at whole percents, on
/// the stream the engine reads (OpenJD on stderr, so `--json` stays one JSON document; ALF and
/// Deadline on stdout), even with `--quiet`; an OpenJD session's variable picks OpenJD's lines
/// by itself, and `--quiet` silences that. The map is the same bytes whatever is shown.
#[test]
fn farm_engines_read_the_progress_lines_they_expect() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, extra: &[&str], env: Option<&Path>| {
        let mut cmd = umbra();
        cmd.args([
            "bake",
            "data/cloud.vdb",
            "--light-dir=-1,-1,0.3",
            "--res",
            "64x48",
            "-o",
        ])
        .arg(dir.path().join(name))
        .args(extra)
        .env_remove("OPENJD_SESSION_WORKING_DIR");
        if let Some(d) = env {
            cmd.env("OPENJD_SESSION_WORKING_DIR", d);
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (
            String::from_utf8(o.stdout).unwrap(),
            String::from_utf8(o.stderr).unwrap(),
        )
    };
    let rising = |p: &[u32]| {
        p.first() == Some(&0) && p.last() == Some(&100) && p.windows(2).all(|w| w[0] < w[1])
    };
    let (out, err) = run(
        "openjd.exr",
        &["--progress", "openjd", "--json", "--quiet"],
        None,
    );
    assert!(rising(&percents(&err, "openjd_progress: ", "")), "{err}");
    assert!(serde_json::from_str::<Value>(&out).is_ok(), "{out}");
    let (out, err) = run("alf.exr", &["--progress", "alf", "--quiet"], None);
    assert!(rising(&percents(&out, "ALF_PROGRESS ", "%")), "{out}");
    assert!(!err.contains("ALF_PROGRESS"), "{err}");
    let (out, _) = run("deadline.exr", &["--progress", "deadline"], None);
    assert!(rising(&percents(&out, "Progress: ", "%")), "{out}");
    // The summary still follows the lines.
    assert!(out.lines().last().unwrap_or("").contains("rays/s"), "{out}");
    // Under an OpenJD session, `auto` prints OpenJD's lines; `--quiet` or `none` silence them.
    let (_, err) = run("auto.exr", &[], Some(dir.path()));
    assert!(rising(&percents(&err, "openjd_progress: ", "")), "{err}");
    let (_, err) = run("auto-quiet.exr", &["--quiet"], Some(dir.path()));
    assert!(!err.contains("openjd_progress"), "{err}");
    let (_, err) = run("none.exr", &["--progress", "none"], Some(dir.path()));
    assert!(!err.contains("openjd_progress"), "{err}");
    let (out, err) = run("plain.exr", &["--quiet"], None);
    assert!(out.is_empty() && err.is_empty(), "{out}{err}");
    let bytes = std::fs::read(dir.path().join("plain.exr")).unwrap();
    for name in [
        "openjd.exr",
        "alf.exr",
        "deadline.exr",
        "auto.exr",
        "none.exr",
    ] {
        assert_eq!(
            std::fs::read(dir.path().join(name)).unwrap(),
            bytes,
            "{name}"
        );
    }
    // A transmittance volume reports its voxels the same way.
    let vdb = dir.path().join("t.vdb");
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--light-dir=0,-1,0",
            "--progress",
            "alf",
            "-q",
            "-o",
        ])
        .arg(&vdb)
        .output()
        .unwrap();
    let out = String::from_utf8(o.stdout).unwrap();
    assert!(
        o.status.success() && rising(&percents(&out, "ALF_PROGRESS ", "%")),
        "{out}"
    );
}
