//! `umbra batch`: sequences x lights, failures, resume, shards, plan.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;
// Only `corpus_dir` is used here.
#[allow(unused_imports)]
use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

/// A 3-frame sequence (copies of data/cloud.vdb) and a two-light job in `dir`.
fn setup(dir: &Path, extra: &str) -> PathBuf {
    for f in 1..=3 {
        std::fs::copy(data("cloud.vdb"), dir.join(format!("cloud.{f:04}.vdb"))).unwrap();
    }
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        format!(
            r#"grid = "density"
output = "out/shadow_{{light}}.{{frame:04}}.exr"
{extra}
[[inputs]]
pattern = "cloud.$F4.vdb"
frames = [1, 3]

[[lights]]
name = "sun"
dir = [0.3, -1.0, 0.2]

[[lights]]
name = "lamp"
pos = [0.0, 4.0, 3.0]

[bake]
res = [32, 32]
estimator = "ratio"
spp = 4
seed = 7
density_scale = 2.0
"#
        ),
    )
    .unwrap();
    job
}

fn umbra(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap()
}

/// `umbra batch JOB EXTRA...` (no `--quiet`: the summary line is what several tests read; a
/// progress bar never shows on a pipe).
fn batch(job: &Path, extra: &[&str]) -> Output {
    let mut a = vec!["batch", job.to_str().unwrap()];
    a.extend_from_slice(extra);
    umbra(&a)
}

fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    if !dir.join("out").exists() {
        return Vec::new();
    }
    let mut v: Vec<_> = std::fs::read_dir(dir.join("out"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn log_records(dir: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(dir.join("out/umbra_batch.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

fn names(dir: &Path) -> Vec<String> {
    outputs(dir).into_iter().map(|(n, _)| n).collect()
}

const ALL: [&str; 6] = [
    "shadow_lamp.0001.exr",
    "shadow_lamp.0002.exr",
    "shadow_lamp.0003.exr",
    "shadow_sun.0001.exr",
    "shadow_sun.0002.exr",
    "shadow_sun.0003.exr",
];

/// `--progress ENGINE` prints the run's progress as the engine's lines (each task a share of
/// the run, rising 0 to 100), even with `--quiet`, on the stream the engine reads; a failing
/// task still ends the run at 100 and its failure goes to stderr.
#[test]
fn a_batch_run_prints_a_farm_engines_progress_lines() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let percents = |text: &str, prefix: &str, suffix: &str| -> Vec<u32> {
        text.lines()
            .filter_map(|l| l.strip_prefix(prefix)?.strip_suffix(suffix)?.parse().ok())
            .collect()
    };
    let rising = |p: &[u32]| {
        p.first() == Some(&0) && p.last() == Some(&100) && p.windows(2).all(|w| w[0] < w[1])
    };
    let o = batch(&job, &["--quiet", "--progress", "deadline", "--jobs", "2"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(rising(&percents(&out, "Progress: ", "%")), "{out}");
    assert_eq!(
        out.lines().count(),
        percents(&out, "Progress: ", "%").len(),
        "{out}"
    );
    std::fs::write(dir.path().join("cloud.0002.vdb"), b"not a vdb").unwrap();
    let o = batch(&job, &["--quiet", "--force", "--progress", "openjd"]);
    assert_eq!(o.status.code(), Some(3));
    assert!(o.stdout.is_empty());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(rising(&percents(&err, "openjd_progress: ", "")), "{err}");
    assert!(err.contains("cloud.0002.vdb"), "{err}");
}

/// `--quiet` prints nothing on stdout (the log has every task), and still exits 3 with the
/// failures on stderr.
#[test]
fn quiet_runs_print_no_summary() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let o = batch(&job, &["--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        o.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    assert_eq!(log_records(dir.path()).len(), 6);
    std::fs::write(dir.path().join("cloud.0002.vdb"), b"not a vdb").unwrap();
    let o = batch(&job, &["--quiet", "--force"]);
    assert_eq!(o.status.code(), Some(3));
    assert!(o.stdout.is_empty());
    assert!(String::from_utf8_lossy(&o.stderr).contains("cloud.0002.vdb"));
}

#[test]
fn sequence_two_lights_writes_every_output_then_rerun_skips_all() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let out = batch(&job, &[]);
    assert!(out.status.success(), "{out:?}");
    assert_eq!(names(dir.path()), ALL);
    let recs = log_records(dir.path());
    assert_eq!(recs.len(), 6);
    assert!(recs.iter().all(|r| r["status"] == "ok"), "{recs:?}");
    let first = outputs(dir.path());
    let out = batch(&job, &[]);
    assert!(out.status.success());
    let recs = log_records(dir.path());
    assert_eq!(recs.len(), 12);
    assert!(recs[6..].iter().all(|r| r["status"] == "skipped"));
    assert!(String::from_utf8_lossy(&out.stdout).contains("0 baked, 6 skipped"));
    assert_eq!(outputs(dir.path()), first);
}

#[test]
fn corrupt_frame_fails_alone_with_exit_code_3() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let bad = dir.path().join("cloud.0002.vdb");
    let bytes = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 3]).unwrap();
    let out = batch(&job, &[]);
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    assert_eq!(
        names(dir.path()),
        [
            "shadow_lamp.0001.exr",
            "shadow_lamp.0003.exr",
            "shadow_sun.0001.exr",
            "shadow_sun.0003.exr"
        ]
    );
    let recs = log_records(dir.path());
    let failed: Vec<_> = recs.iter().filter(|r| r["status"] == "failed").collect();
    assert_eq!(failed.len(), 2);
    for r in failed {
        assert!(r["input"].as_str().unwrap().ends_with("cloud.0002.vdb"));
        assert!(!r["error"].as_str().unwrap().is_empty());
    }
    assert!(String::from_utf8_lossy(&out.stderr).contains("cloud.0002.vdb"));
}

#[test]
fn killed_run_resumes_to_identical_outputs() {
    let whole = tempfile::tempdir().unwrap();
    let job = setup(whole.path(), "");
    assert!(batch(&job, &[]).status.success());
    let reference = outputs(whole.path());

    // Same directory (the EXR records the input path): start over.
    std::fs::remove_dir_all(whole.path().join("out")).unwrap();
    let part = &whole;
    // "Killed" after two tasks: only tasks 0 and 1 ran.
    assert!(batch(&job, &["--task", "0"]).status.success());
    assert!(batch(&job, &["--task", "1"]).status.success());
    assert_eq!(names(part.path()).len(), 2);
    let out = batch(&job, &[]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("4 baked, 2 skipped"));
    // A deleted output is re-baked, the others are skipped.
    std::fs::remove_file(part.path().join("out/shadow_sun.0002.exr")).unwrap();
    let out = batch(&job, &[]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("1 baked, 5 skipped"));
    assert_eq!(outputs(part.path()), reference);
}

#[test]
fn three_shards_equal_one_run_bit_identical() {
    let whole = tempfile::tempdir().unwrap();
    let job = setup(whole.path(), "");
    assert!(batch(&job, &[]).status.success());
    let reference = outputs(whole.path());

    // Same directory (the EXR records the input path): start over.
    std::fs::remove_dir_all(whole.path().join("out")).unwrap();
    let sharded = &whole;
    let mut counts = Vec::new();
    for s in ["1/3", "2/3", "3/3"] {
        let before = names(sharded.path()).len();
        let out = batch(&job, &["--shard", s, "--jobs", "1"]);
        assert!(out.status.success(), "{out:?}");
        counts.push(names(sharded.path()).len() - before);
    }
    assert_eq!(counts, [2, 2, 2]);
    assert_eq!(outputs(sharded.path()), reference);
}

/// `--task I-J` runs consecutive tasks as one process (OpenCue's chunks, Deadline's); a range
/// outside the job names the flag, a backward one is a usage error.
#[test]
fn task_ranges_run_consecutive_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let out = batch(&job, &["--task", "1-3"]);
    assert!(out.status.success(), "{out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("3 baked, 0 skipped"));
    let mut rows: Vec<u64> = log_records(dir.path())
        .iter()
        .filter_map(|r| r["task"].as_u64())
        .collect();
    rows.sort_unstable();
    assert_eq!(rows, [1, 2, 3]);
    let out = batch(&job, &["--task", "4-9"]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("'--task'") && err.contains("4-9") && err.contains("6 tasks"),
        "{err}"
    );
    assert_eq!(batch(&job, &["--task", "3-1"]).status.code(), Some(2));
}

#[test]
fn plan_lists_one_command_per_task() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let out = umbra(&["batch", job.to_str().unwrap(), "--plan"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 6);
    for (i, l) in lines.iter().enumerate() {
        assert!(l.contains(" batch "), "{l}");
        assert!(l.contains("job.toml"), "{l}");
        assert!(l.ends_with(&format!("--task {i}")), "{l}");
    }
    assert!(!dir.path().join("out").exists(), "--plan runs nothing");
}

#[test]
fn job_errors_name_the_key_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "colour = 3\n");
    let out = umbra(&["batch", job.to_str().unwrap(), "--plan"]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("colour") && e.contains("line 3"), "{e}");

    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("colour = 3\n", "")
        .replace("dir = [0.3, -1.0, 0.2]", "dir = [0.0, 0.0, 0.0]");
    std::fs::write(&job, text).unwrap();
    let out = umbra(&["batch", job.to_str().unwrap(), "--plan"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("lights[0].dir"), "{e}");

    let text = std::fs::read_to_string(&job)
        .unwrap()
        .replace("dir = [0.0, 0.0, 0.0]", "dir = [0.3, -1.0, 0.2]")
        .replace("shadow_{light}.", "shadow.");
    std::fs::write(&job, text).unwrap();
    let out = umbra(&["batch", job.to_str().unwrap(), "--plan"]);
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(e.contains("output") && e.contains("{light}"), "{e}");
}

#[test]
fn patterns_and_placeholders() {
    use umbra::batch::{expand_pattern, fill_output, in_shard, parse_shard};
    assert_eq!(
        expand_pattern("a/cloud.####.vdb", 7).unwrap(),
        "a/cloud.0007.vdb"
    );
    assert_eq!(
        expand_pattern("cloud.$F4.vdb", 12).unwrap(),
        "cloud.0012.vdb"
    );
    assert_eq!(expand_pattern("cloud.$F.vdb", 12).unwrap(), "cloud.12.vdb");
    assert_eq!(expand_pattern("cloud.vdb", 1), None);
    // printf's %04d and %d (the token Nuke, ffmpeg and most farm tools write).
    assert_eq!(
        expand_pattern("cache/cloud.%04d.vdb", 12).unwrap(),
        "cache/cloud.0012.vdb"
    );
    assert_eq!(expand_pattern("cloud.%d.vdb", 5).unwrap(), "cloud.5.vdb");
    assert_eq!(expand_pattern("100%.%03d.vdb", 7).unwrap(), "100%.007.vdb");
    assert_eq!(expand_pattern("cloud.%4d.vdb", 1), None); // space padding: not a frame token
    assert_eq!(expand_pattern("cloud.%s.vdb", 1), None);
    assert_eq!(
        fill_output(
            "s_{light}.{stem}.{frame:04}.{frame}.exr",
            "sun",
            "c",
            Some(3)
        )
        .unwrap(),
        "s_sun.c.0003.3.exr"
    );
    assert!(fill_output("{frame}", "sun", "c", None).is_err());
    assert!(fill_output("{colour}", "sun", "c", None).is_err());
    assert_eq!(parse_shard("2/3").unwrap(), (2, 3));
    assert!(parse_shard("0/3").is_err() && parse_shard("4/3").is_err());
    let shards: Vec<Vec<usize>> = (1..=3)
        .map(|i| (0..7).filter(|&t| in_shard(t, (i, 3))).collect())
        .collect();
    assert_eq!(shards, [vec![0, 3, 6], vec![1, 4], vec![2, 5]]);
}

/// A job file takes every option of `umbra bake`, and a task runs the same pipeline: the batch
/// map has the same channels and pixels as `umbra bake` with the same options, and its preview.
#[test]
fn job_files_take_every_bake_option_and_match_umbra_bake() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(data("cloud.vdb"), d.join("cloud.vdb")).unwrap();
    std::fs::write(
        d.join("job.toml"),
        r#"output = "out/{stem}_{light}.exr"
[[inputs]]
file = "cloud.vdb"
[[lights]]
name = "lamp"
pos = [0.5, 5.0, 2.0]
[bake]
res = [24, 16]
estimator = "jittered"
step = 0.5
spp = 8
seed = 3
density_scale = 2.0
interp = "nearest"
granularity = "lower"
slices = 3
stderr = true
fov = 50.0
target_error = 0.05
max_spp = 32
preview = "out/{stem}_{light}.png"
"#,
    )
    .unwrap();
    let o = batch(&d.join("job.toml"), &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let map = d.join("out/cloud_lamp.exr");
    assert!(d.join("out/cloud_lamp.png").exists());
    let cloud = d.join("cloud.vdb");
    let direct = d.join("direct.exr");
    let o = umbra(&[
        "bake",
        cloud.to_str().unwrap(),
        "--light-pos=0.5,5,2",
        "--res",
        "24x16",
        "--estimator",
        "jittered",
        "--step",
        "0.5",
        "--spp",
        "8",
        "--seed",
        "3",
        "--density-scale",
        "2",
        "--interp",
        "nearest",
        "--granularity",
        "lower",
        "--slices",
        "3",
        "--stderr",
        "--fov",
        "50",
        "--target-error",
        "0.05",
        "--max-spp",
        "32",
        "-q",
        "-o",
        direct.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (
        bake_support::read_exr(&map),
        bake_support::read_exr(&direct),
    );
    let mut names: Vec<&String> = a.ch.keys().collect();
    names.sort();
    assert_eq!(
        names,
        ["T", "T.stderr", "slice00.T", "slice01.T", "slice02.T"]
    );
    for (k, v) in &a.ch {
        assert_eq!(v, &b.ch[k], "channel {k}");
    }
    for k in [
        "estimator",
        "estimator_params",
        "interp",
        "camera_kind",
        "fov_deg",
    ] {
        assert_eq!(a.attr(k), b.attr(k), "{k}");
    }
    assert_eq!(
        a.text("estimator_params"),
        r#"{"name":"jittered","step":0.5}"#
    );
}

/// Frames of different size (the sample cloud and cloud_fbm, both `density`): by default every
/// map of a light has one camera, framing both boxes (every corner of either inside the image),
/// and the union is found without decoding voxels; `framing = "per-frame"` frames each on its
/// own; `up`, `frame_box` and `camera` work in job files; a missing frame fails the job before
/// any task runs.
#[test]
fn sequence_of_different_sizes_shares_one_camera() {
    use bake_support::read_exr;
    let fbm = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/cloud_fbm.vdb");
    let camera_of = |p: &Path| {
        let e = read_exr(p);
        let attrs: Vec<String> = [
            "camera_origin",
            "camera_step_x",
            "camera_step_y",
            "camera_direction",
        ]
        .iter()
        .map(|k| format!("{:?}", e.v3d(k)))
        .collect();
        (attrs, e.w, e.h)
    };
    for (framing, shared) in [("", true), ("framing = \"per-frame\"", false)] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let job = setup(d, "");
        std::fs::copy(&fbm, d.join("cloud.0002.vdb")).unwrap();
        let text = std::fs::read_to_string(&job).unwrap();
        std::fs::write(
            &job,
            text.replace("[bake]\n", &format!("[bake]\n{framing}\n")),
        )
        .unwrap();
        let out = batch(&job, &[]);
        assert!(out.status.success(), "{out:?}");
        for light in ["sun", "lamp"] {
            let cams: Vec<_> = (1..=3)
                .map(|f| camera_of(&d.join(format!("out/shadow_{light}.{f:04}.exr"))))
                .collect();
            assert_eq!(
                cams[0], cams[2],
                "{light}: frames 1 and 3 are the same file"
            );
            assert_eq!(cams[0] == cams[1], shared, "{light} {framing:?}");
            if shared {
                // Every corner of both volumes lands inside the shared image.
                let e = read_exr(&d.join(format!("out/shadow_{light}.0002.exr")));
                let c =
                    umbra::bake::read_camera(&d.join(format!("out/shadow_{light}.0002.exr")), None)
                        .unwrap();
                for file in [data("cloud.vdb"), fbm.clone()] {
                    let v = umbra::Volume::load(&file, "density", 1.0).unwrap();
                    for p in v.box_corners().unwrap() {
                        let (i, j) = pixel_of(&c, p);
                        let (w, h) = (e.w as f64, e.h as f64);
                        assert!(
                            (-0.5 - 1e-9..=w - 0.5 + 1e-9).contains(&i)
                                && (-0.5 - 1e-9..=h - 0.5 + 1e-9).contains(&j),
                            "{light}: corner at pixel ({i}, {j}) of {w}x{h}"
                        );
                    }
                }
            }
        }
    }
    // up and frame_box in the job file give the maps umbra bake gives with --up/--frame-box
    // (per-frame framing: the same view as the command line).
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let job = setup(d, "");
    let text = std::fs::read_to_string(&job).unwrap();
    std::fs::write(
        &job,
        text.replace(
            "[bake]\n",
            "[bake]\nframing = \"per-frame\"\nup = [0.0, 0.0, 1.0]\nframe_box = [[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]]\n",
        ),
    )
    .unwrap();
    assert!(batch(&job, &[]).status.success());
    let cli = d.join("cli.exr");
    let o = umbra(&[
        "bake",
        d.join("cloud.0001.vdb").to_str().unwrap(),
        "--light-dir=0.3,-1,0.2",
        "--res",
        "32x32",
        "--up",
        "0,0,1",
        "--frame-box=-1,0,-1,1,2,1",
        "--estimator",
        "ratio",
        "--spp",
        "4",
        "--seed",
        "7",
        "--density-scale",
        "2",
        "-q",
        "-o",
        cli.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    assert_eq!(
        camera_of(&cli),
        camera_of(&d.join("out/shadow_sun.0001.exr"))
    );
    // camera = an earlier map: every task uses it as it is.
    let job2 = d.join("job2.toml");
    std::fs::write(
        &job2,
        "grid = \"density\"\noutput = \"again/{frame:04}.exr\"\n[[inputs]]\npattern = \"cloud.####.vdb\"\nframes = [1, 2]\n[[lights]]\nname = \"sun\"\ndir = [1.0, 0.0, 0.0]\n[bake]\ncamera = \"cli.exr\"\n",
    )
    .unwrap();
    let out = batch(&job2, &[]);
    assert!(out.status.success(), "{out:?}");
    for f in 1..=2 {
        assert_eq!(
            camera_of(&d.join(format!("again/{f:04}.exr"))),
            camera_of(&cli)
        );
    }
    // A missing frame: an error naming it before any task runs (exit 1, nothing written).
    std::fs::remove_file(d.join("cloud.0002.vdb")).unwrap();
    std::fs::remove_dir_all(d.join("again")).unwrap();
    let out = batch(&job2.with_file_name("job.toml"), &["--force"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let text = std::fs::read_to_string(&job).unwrap();
    std::fs::write(&job, text.replace("framing = \"per-frame\"\n", "")).unwrap();
    let before = names(d);
    let out = batch(&job, &["--force"]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("cloud.0002.vdb"),
        "{out:?}"
    );
    assert_eq!(names(d), before);
}

/// Column and row (fractional) of world point `p` in a camera's image.
fn pixel_of(c: &umbra::bake::Camera, p: glam::DVec3) -> (f64, f64) {
    use glam::DVec3;
    let (sx, sy) = (DVec3::from(c.step_x()), DVec3::from(c.step_y()));
    let s2 = c.pixel_size().powi(2);
    match c.kind() {
        umbra::bake::Projection::Ortho => {
            let v = p - DVec3::from(c.origin());
            (v.dot(sx) / s2, v.dot(sy) / s2)
        }
        umbra::bake::Projection::Perspective => {
            // p - P = z (D + i sx + j sy) with D . sx = D . sy = 0 up to the pixel offsets.
            let v = p - DVec3::from(c.origin());
            let f = DVec3::from(c.forward());
            let z = v.dot(f);
            let q = v / z - DVec3::from(c.direction());
            (q.dot(sx) / s2, q.dot(sy) / s2)
        }
        other => panic!("a batch job's shared camera is ortho or perspective, not {other:?}"),
    }
}

/// A point light inside the sequence's union box cannot frame the shared camera: the job fails
/// before any task, naming the job file and the light.
#[test]
fn a_light_inside_the_shared_box_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for f in 1..=2 {
        std::fs::copy(data("cloud.vdb"), d.join(format!("c.{f:04}.vdb"))).unwrap();
    }
    let job = d.join("j.toml");
    std::fs::write(
        &job,
        "grid = \"density\"\noutput = \"o/{light}.{frame:04}.exr\"\n[[inputs]]\npattern = \"c.####.vdb\"\nframes = [1, 2]\n[[lights]]\nname = \"inside\"\npos = [0.0, 1.5, 0.0]\n[bake]\nres = [8, 8]\n",
    )
    .unwrap();
    let out = batch(&job, &[]);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("j.toml") && err.contains("lights 'inside'"),
        "{err}"
    );
    assert!(!d.join("o/inside.0001.exr").exists());
}

/// The shared cameras are cached beside the log, so a farm's `--task` processes read the
/// frames' topology once between them: a cache newer than the job file and every input, with
/// the job's fingerprint, is used as it is (shown by editing a camera in it); an input newer
/// than the cache, or a cache that does not parse, makes the cameras be computed again.
#[test]
fn shared_cameras_are_cached_for_farm_tasks() {
    use bake_support::read_exr;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let job = setup(d, "");
    assert!(batch(&job, &["--task", "0"]).status.success());
    let cache = d.join("out/umbra_batch.cameras.json");
    let first = read_exr(&d.join("out/shadow_sun.0001.exr"));
    let (fresh, step_x) = (first.v3d("camera_origin"), first.v3d("camera_step_x"));
    let mut stored: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&cache).unwrap()).unwrap();
    let cams = stored["cameras"].as_array_mut().unwrap();
    assert_eq!(cams.len(), 2, "one camera per light of the one sequence");
    let sun = cams.iter_mut().find(|c| c["light"] == "sun").unwrap();
    // Moved four pixels across the image plane (along step_x): the same depth range, so the
    // bake uses it exactly as cached (a move along the light would be extended to cover the
    // frame, see tests/library/camera_reuse.rs).
    let moved = [0, 1, 2].map(|k| fresh[k] + 4.0 * step_x[k]);
    sun["camera"]["spec"]["origin"] = serde_json::json!(moved);
    std::fs::write(&cache, serde_json::to_vec(&stored).unwrap()).unwrap();
    let origin = || read_exr(&d.join("out/shadow_sun.0002.exr")).v3d("camera_origin");
    // Task 2 is frame 2 under the sun: it takes the cached (edited) camera.
    assert!(batch(&job, &["--task", "2", "--force"]).status.success());
    assert_eq!(origin(), moved);
    // An input newer than the cache: computed again (and the cache rewritten).
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::copy(data("cloud.vdb"), d.join("cloud.0003.vdb")).unwrap();
    assert!(batch(&job, &["--task", "2", "--force"]).status.success());
    assert_eq!(origin(), fresh);
    // A cache that does not parse is ignored.
    std::fs::write(&cache, b"not json").unwrap();
    assert!(batch(&job, &["--task", "2", "--force"]).status.success());
    assert_eq!(origin(), fresh);
    assert!(serde_json::from_slice::<serde_json::Value>(&std::fs::read(&cache).unwrap()).is_ok());
}

#[test]
fn a_scene_input_is_stale_when_a_file_it_names_changes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(data("cloud.vdb"), d.join("a.vdb")).unwrap();
    std::fs::write(
        d.join("scene.toml"),
        "[[volume]]\nfile = \"a.vdb\"\ngrid = \"density\"\n",
    )
    .unwrap();
    let job = d.join("job.toml");
    std::fs::write(
        &job,
        "output = \"out/{light}.exr\"\n[[inputs]]\nfile = \"scene.toml\"\n\
         [[lights]]\nname = \"sun\"\ndir = [0.3, -1.0, 0.2]\n[bake]\nres = 16\n",
    )
    .unwrap();
    let out = batch(&job, &[]);
    assert!(out.status.success(), "{out:?}");
    let out = batch(&job, &[]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("0 baked, 1 skipped"));
    // The scene file is untouched; the grid it names is touched (the same content: no
    // change), then re-simulated (other content).
    let later = std::time::SystemTime::now() + std::time::Duration::from_secs(5);
    std::fs::File::options()
        .write(true)
        .open(d.join("a.vdb"))
        .unwrap()
        .set_modified(later)
        .unwrap();
    let out = batch(&job, &[]);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("0 baked, 1 skipped"),
        "{out:?}"
    );
    std::fs::copy(data("cloud_half.vdb"), d.join("a.vdb")).unwrap();
    let out = batch(&job, &[]);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("1 baked, 0 skipped"),
        "{out:?}"
    );
}

#[test]
fn status_reports_done_failed_and_missing_from_outputs_and_logs() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path(), "");
    let status = |extra: &[&str]| {
        let mut a = vec!["batch", job.to_str().unwrap(), "--status", "--json"];
        a.extend_from_slice(extra);
        let out = umbra(&a);
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let tasks = |k: &str| -> Vec<u64> {
            v[k].as_array()
                .unwrap()
                .iter()
                .map(|t| t["task"].as_u64().unwrap())
                .collect()
        };
        (
            out.status.code(),
            tasks("done"),
            tasks("failed"),
            tasks("missing"),
            v,
        )
    };
    // Nothing run yet: everything missing.
    let (code, done, failed, missing, _) = status(&[]);
    assert_eq!(
        (code, done.len(), failed.len(), missing.len()),
        (Some(3), 0, 0, 6)
    );
    // Frame 2 corrupt; shard 1/2 writes its log elsewhere, shard 2/2 to the default log.
    let bad = dir.path().join("cloud.0002.vdb");
    let good = std::fs::read(&bad).unwrap();
    std::fs::write(&bad, &good[..good.len() / 3]).unwrap();
    let elsewhere = dir.path().join("shard1.jsonl");
    batch(
        &job,
        &["--shard", "1/2", "--log", elsewhere.to_str().unwrap()],
    );
    batch(&job, &["--shard", "2/2"]);
    // Without the other log, shard 1's failures are unknown (missing); with it, named.
    let (_, _, failed_default, _, _) = status(&[]);
    let (code, done, failed, missing, v) = status(&["--log", elsewhere.to_str().unwrap()]);
    assert_eq!(code, Some(3));
    assert_eq!((done.len(), failed.len(), missing.len()), (4, 2, 0), "{v}");
    assert!(failed_default.len() < 2);
    for f in v["failed"].as_array().unwrap() {
        assert!(
            f["input"].as_str().unwrap().ends_with("cloud.0002.vdb"),
            "{f}"
        );
        assert!(!f["error"].as_str().unwrap().is_empty(), "{f}");
    }
    // A deleted output is missing again; the text form names it; fixed and re-run: all done.
    std::fs::remove_file(dir.path().join("out/shadow_sun.0001.exr")).unwrap();
    let out = umbra(&[
        "batch",
        job.to_str().unwrap(),
        "--status",
        "--log",
        elsewhere.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("3 done, 2 failed, 0 stale, 1 not yet run"),
        "{text}"
    );
    assert!(
        text.contains("shadow_sun.0001.exr") && text.contains("cloud.0002.vdb"),
        "{text}"
    );
    std::fs::write(&bad, &good).unwrap();
    assert_eq!(batch(&job, &[]).status.code(), Some(0));
    let (code, done, _, _, _) = status(&[]);
    assert_eq!((code, done.len()), (Some(0), 6));
}

/// A job of point lights takes `omni` like every bake option: each task writes a cube map
/// (N x 6N, `envmap = cube`) around its light; a sun cannot have one and the job says so
/// before anything runs.
#[test]
fn omni_jobs_bake_environment_maps_around_point_lights() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(data("cloud.vdb"), dir.path().join("cloud.0001.vdb")).unwrap();
    let job = dir.path().join("job.toml");
    let text = |light: &str| {
        format!(
            "output = \"out/omni_{{light}}.{{frame:04}}.exr\"\n[[inputs]]\npattern = \
             \"cloud.$F4.vdb\"\nframes = [1, 1]\n[[lights]]\n{light}\n[bake]\nomni = \
             \"cube\"\nres = 8\n"
        )
    };
    std::fs::write(&job, text("name = \"lamp\"\npos = [0.0, 1.5, 0.0]")).unwrap();
    let out = batch(&job, &[]);
    assert!(out.status.success(), "{out:?}");
    let meta =
        exr::meta::MetaData::read_from_file(dir.path().join("out/omni_lamp.0001.exr"), false)
            .unwrap();
    let h = &meta.headers[0];
    assert_eq!((h.layer_size.0, h.layer_size.1), (8, 48));
    assert_eq!(
        h.own_attributes.environment_map,
        Some(exr::meta::attribute::EnvironmentMap::Cube)
    );
    std::fs::write(&job, text("name = \"sun\"\ndir = [0.0, -1.0, 0.0]")).unwrap();
    let out = batch(&job, &["--force"]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("omni") && err.contains("light-pos"), "{err}");
}

/// A liquid (a level set, `ls_sphere`) and a smoke (`density`) in one job: each `[[inputs]]`
/// entry carries its own `grid`, `density_scale`, `levelset` and `xform` (the job's values
/// stay the default). Without them the job is unrunnable and `--plan` says so (exit 1, naming
/// the input and the grid) before anything is made; with them `--plan` passes, the run bakes
/// each input as `umbra bake` does with the same options, and the log records each task's
/// grid.
#[test]
fn inputs_carry_their_own_grid_scale_levelset_and_xform() {
    let Some(corpus) = common::corpus_dir() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(data("cloud.vdb"), d.join("smoke.vdb")).unwrap();
    std::fs::copy(corpus.join("gen/sphere_levelset.vdb"), d.join("liquid.vdb")).unwrap();
    let job = |entries: &str| {
        let text = format!(
            r#"grid = "density"
output = "out/{{stem}}.exr"
{entries}
[[lights]]
name = "sun"
dir = [0.3, -1.0, 0.2]
[bake]
res = 24
density_scale = 2.0
"#
        );
        std::fs::write(d.join("job.toml"), text).unwrap();
        d.join("job.toml")
    };
    // One grid for both: the liquid has no `density`.
    let j = job("[[inputs]]\nfile = \"smoke.vdb\"\n[[inputs]]\nfile = \"liquid.vdb\"\n");
    let o = batch(&j, &["--plan"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("liquid.vdb") && err.contains("density"),
        "{err}"
    );
    assert!(o.stdout.is_empty() && !d.join("out").exists());
    // Each entry its own.
    let j = job("[[inputs]]\nfile = \"smoke.vdb\"\ndensity_scale = 3.0\n\
         xform = [1, 0, 0, 0.5, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n\
         [[inputs]]\nfile = \"liquid.vdb\"\ngrid = \"ls_sphere\"\nlevelset = \"solid\"\n");
    let o = batch(&j, &["--plan"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout).lines().count(), 2);
    let o = batch(&j, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut grids: Vec<(u64, String)> = log_records(d)
        .iter()
        .map(|r| {
            let g = r["grid"].as_str().unwrap().to_string();
            (r["task"].as_u64().unwrap(), g)
        })
        .collect();
    grids.sort();
    assert_eq!(
        grids,
        [(0, "density".to_string()), (1, "ls_sphere".to_string())]
    );
    for (input, extra) in [
        (
            "smoke",
            &[
                "--density-scale",
                "3",
                "--xform=1,0,0,0.5,0,1,0,0,0,0,1,0,0,0,0,1",
            ][..],
        ),
        (
            "liquid",
            &[
                "--density-scale",
                "2",
                "--grid",
                "ls_sphere",
                "--levelset",
                "solid",
            ][..],
        ),
    ] {
        let direct = d.join(format!("direct_{input}.exr"));
        let file = d.join(format!("{input}.vdb"));
        let mut args = vec![
            "bake",
            file.to_str().unwrap(),
            "--light-dir=0.3,-1,0.2",
            "--res",
            "24",
            "-q",
            "-o",
            direct.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        let o = umbra(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (a, b) = (
            bake_support::read_exr(&d.join(format!("out/{input}.exr"))),
            bake_support::read_exr(&direct),
        );
        assert_eq!(a.ch["T"], b.ch["T"], "{input}");
    }
    // A bad entry value is named by its key.
    let j = job("[[inputs]]\nfile = \"smoke.vdb\"\ndensity_scale = -1.0\n");
    let o = batch(&j, &["--plan"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("inputs[0].density_scale"), "{err}");
}
