//! `umbra batch` re-runs by task key (issue 68 item 1): a job edited key by key re-bakes exactly
//! the tasks the edit changes, each with its reason in the log and in `--status`; a touched
//! file is no change, a re-simulated one of the same size and time is found with `--verify`;
//! an output without a key is stale unless `--keep-unkeyed`.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn umbra(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap()
}

/// A 3-frame sequence and a hero file under two lights: 8 tasks, input-major
/// (`cloud.0001` sun, lamp, ..., `hero` sun 6, lamp 7).
fn setup(dir: &Path) -> PathBuf {
    for f in 1..=3 {
        std::fs::copy(data("cloud.vdb"), dir.join(format!("cloud.{f:04}.vdb"))).unwrap();
    }
    std::fs::copy(data("cloud.vdb"), dir.join("hero.vdb")).unwrap();
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        r#"grid = "density"
output = "out/{stem}_{light}.exr"

[[inputs]]
pattern = "cloud.$F4.vdb"
frames = [1, 3]

[[inputs]]
file = "hero.vdb"

[[lights]]
name = "sun"
dir = [0.3, -1.0, 0.2]

[[lights]]
name = "lamp"
pos = [0.0, 4.0, 3.0]

[bake]
res = [16, 16]
estimator = "ratio"
spp = 2
seed = 7
density_scale = 2.0
"#,
    )
    .unwrap();
    job
}

/// Replace `from` by `to` in the job file (exactly once).
fn edit(job: &Path, from: &str, to: &str) {
    let text = std::fs::read_to_string(job).unwrap();
    assert_eq!(text.matches(from).count(), 1, "{from:?} in {text}");
    std::fs::write(job, text.replacen(from, to, 1)).unwrap();
}

/// Run the job (`extra` flags) and return this run's records: (task, status, reason).
fn run(job: &Path, extra: &[&str]) -> Vec<(u64, String, String)> {
    let log = job.parent().unwrap().join("out/umbra_batch.jsonl");
    let before = std::fs::read_to_string(&log).map_or(0, |t| t.lines().count());
    let mut a = vec!["batch", job.to_str().unwrap(), "--quiet"];
    a.extend_from_slice(extra);
    let out = umbra(&a);
    assert!(out.status.success(), "{out:?}");
    let mut recs: Vec<(u64, String, String)> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .skip(before)
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (
                v["task"].as_u64().unwrap(),
                v["status"].as_str().unwrap().to_string(),
                v["reason"].as_str().unwrap_or("").to_string(),
            )
        })
        .collect();
    recs.sort();
    recs
}

/// The tasks a run baked, and each one's reason.
fn baked(recs: &[(u64, String, String)]) -> Vec<(u64, String)> {
    recs.iter()
        .filter(|r| r.1 == "ok")
        .map(|r| (r.0, r.2.clone()))
        .collect()
}

fn indices(b: &[(u64, String)]) -> Vec<u64> {
    b.iter().map(|(i, _)| *i).collect()
}

fn read(dir: &Path, name: &str) -> Vec<u8> {
    std::fs::read(dir.join("out").join(name)).unwrap()
}

/// `--status --json` of the job: (exit code, tasks per list, the document).
fn status(job: &Path, extra: &[&str]) -> (Option<i32>, [usize; 4], serde_json::Value) {
    let mut a = vec!["batch", job.to_str().unwrap(), "--status", "--json"];
    a.extend_from_slice(extra);
    let out = umbra(&a);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let n = |k: &str| v[k].as_array().map_or(usize::MAX, Vec::len);
    (
        out.status.code(),
        [n("done"), n("failed"), n("stale"), n("missing")],
        v,
    )
}

#[test]
fn each_edit_of_the_job_rebakes_exactly_the_tasks_it_changes_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let job = setup(d);
    let first = run(&job, &[]);
    assert_eq!(baked(&first).len(), 8, "{first:?}");
    assert!(first.iter().all(|r| r.2 == "output missing"), "{first:?}");
    let original = read(d, "cloud.0001_sun.exr");
    // The header carries the key: its request, its camera and the file it read.
    let key = exr_key(&d.join("out/cloud.0001_sun.exr")).expect("an umbra:key attribute");
    let key: serde_json::Value = serde_json::from_str(&key).unwrap();
    assert_eq!(key["request"]["density_scale"], 2.0, "{key}");
    assert_eq!(key["request"]["light_dir"][0], 0.3, "{key}");
    assert!(key["files"][0]["path"]
        .as_str()
        .unwrap()
        .ends_with("cloud.0001.vdb"));
    assert!(key["camera"].is_object(), "{key}");
    // Nothing changed: all skipped, up to date.
    let again = run(&job, &[]);
    assert!(baked(&again).is_empty(), "{again:?}");
    assert!(again.iter().all(|r| r.2 == "up to date"), "{again:?}");

    // Every [bake] key that changes bytes re-bakes every task, naming the key.
    let all: Vec<u64> = (0..8).collect();
    for (from, to, name) in [
        ("seed = 7", "seed = 8", "bake.seed"),
        ("spp = 2", "spp = 3", "bake.samples"),
        (
            "density_scale = 2.0",
            "density_scale = 3.0",
            "bake.density_scale",
        ),
        ("res = [16, 16]", "res = [16, 12]", "bake.res"),
        (
            "estimator = \"ratio\"",
            "estimator = \"track-length\"",
            "bake.estimator",
        ),
        ("seed = 8", "seed = 8\ninterp = \"nearest\"", "bake.interp"),
        ("seed = 8", "seed = 8\nstderr = true", "bake.stderr"),
        ("seed = 8", "seed = 8\nup = [0.0, 0.0, 1.0]", "bake.up"),
    ] {
        edit(&job, from, to);
        let b = baked(&run(&job, &[]));
        assert_eq!(indices(&b), all, "{name}: {b:?}");
        for (_, why) in &b {
            assert!(
                why.contains(&format!("settings changed: {name}")),
                "{name}: {why}"
            );
        }
    }
    // Keys that cannot change a byte change nothing.
    edit(
        &job,
        "seed = 8",
        "seed = 8\nthreads = 1\nmax_memory = \"4G\"",
    );
    assert!(baked(&run(&job, &[])).is_empty());
    // Back to the first settings: the maps are the first run's, byte for byte.
    let text = std::fs::read_to_string(&job).unwrap();
    let reverted = text
        .replace("seed = 8", "seed = 7")
        .replace("spp = 3", "spp = 2")
        .replace("density_scale = 3.0", "density_scale = 2.0")
        .replace("res = [16, 12]", "res = [16, 16]")
        .replace("\"track-length\"", "\"ratio\"")
        .replace("interp = \"nearest\"\n", "")
        .replace("stderr = true\n", "")
        .replace("up = [0.0, 0.0, 1.0]\n", "");
    std::fs::write(&job, reverted).unwrap();
    assert_eq!(baked(&run(&job, &[])).len(), 8);
    assert_eq!(read(d, "cloud.0001_sun.exr"), original);

    // A light: its own tasks only.
    edit(&job, "dir = [0.3, -1.0, 0.2]", "dir = [1.0, -1.0, 0.0]");
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [0, 2, 4, 6], "{b:?}");
    assert!(
        b.iter().all(|(_, w)| w.contains("light sun changed")),
        "{b:?}"
    );
    // An input's own key: its tasks only, named by its entry.
    edit(
        &job,
        "file = \"hero.vdb\"",
        "file = \"hero.vdb\"\ndensity_scale = 5.0",
    );
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [6, 7], "{b:?}");
    assert!(
        b.iter()
            .all(|(_, w)| w == "settings changed: inputs[1].density_scale"),
        "{b:?}"
    );

    // A grid file re-simulated: its tasks, naming it (and the sequence's shared camera when
    // the frame moves it); the hero is untouched.
    std::fs::copy(data("cloud_half.vdb"), d.join("cloud.0002.vdb")).unwrap();
    let b = baked(&run(&job, &[]));
    assert!(
        !indices(&b).contains(&6) && !indices(&b).contains(&7),
        "{b:?}"
    );
    for t in [2, 3] {
        let why = &b.iter().find(|(i, _)| *i == t).unwrap().1;
        assert!(why.contains("input changed: cloud.0002.vdb"), "{why}");
    }
    // A touched but identical file is no change.
    let hero = d.join("hero.vdb");
    let mtime = std::fs::metadata(&hero).unwrap().modified().unwrap();
    let later = std::time::SystemTime::now() + std::time::Duration::from_secs(5);
    let touch = |p: &Path, t: std::time::SystemTime| {
        std::fs::File::options()
            .write(true)
            .open(p)
            .unwrap()
            .set_modified(t)
            .unwrap();
    };
    touch(&d.join("hero.vdb"), later);
    assert!(baked(&run(&job, &[])).is_empty());
    // Re-simulated with the size and time its maps' keys record (a byte of the file's UUID):
    // only --verify, which hashes every input, finds it.
    let mut bytes = std::fs::read(&hero).unwrap();
    let at = bytes.windows(1).position(|w| w[0] == b'-').unwrap() - 1;
    bytes[at] = if bytes[at] == b'0' { b'1' } else { b'0' };
    std::fs::write(&hero, &bytes).unwrap();
    touch(&hero, mtime);
    assert!(baked(&run(&job, &[])).is_empty());
    let b = baked(&run(&job, &["--verify"]));
    assert_eq!(indices(&b), [6, 7], "{b:?}");
    assert!(
        b.iter().all(|(_, w)| w == "input changed: hero.vdb"),
        "{b:?}"
    );

    // `--force` bakes all, saying so.
    let b = baked(&run(&job, &["--force"]));
    assert_eq!(b.len(), 8);
    assert!(b.iter().all(|(_, w)| w == "forced"), "{b:?}");
}

#[test]
fn outputs_without_a_key_are_stale_and_status_counts_stale_apart_from_missing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let job = setup(d);
    assert_eq!(status(&job, &[]).1, [0, 0, 0, 8]);
    run(&job, &[]);
    assert_eq!(
        status(&job, &[]),
        (Some(0), [8, 0, 0, 0], status(&job, &[]).2)
    );
    // The hero's sun map baked by hand (as an older umbra did: no key), one map missing, one
    // written over with garbage, and a setting changed for frame 1 only by its light.
    let hero_sun = d.join("out/hero_sun.exr");
    std::fs::remove_file(&hero_sun).unwrap();
    let out = umbra(&[
        "bake",
        d.join("hero.vdb").to_str().unwrap(),
        "--light-dir=0.3,-1.0,0.2",
        "--res=16",
        "--estimator=ratio",
        "--spp=2",
        "--seed=7",
        "--density-scale=2",
        "-o",
        hero_sun.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{out:?}");
    std::fs::remove_file(d.join("out/cloud.0003_lamp.exr")).unwrap();
    std::fs::write(d.join("out/cloud.0002_lamp.exr"), b"not an exr").unwrap();
    let (code, counts, v) = status(&job, &[]);
    assert_eq!((code, counts), (Some(3), [5, 0, 2, 1]), "{v}");
    let reason = |list: &str, task: u64| -> String {
        v[list]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["task"] == task)
            .map(|t| t["reason"].as_str().unwrap().to_string())
            .unwrap_or_default()
    };
    assert!(reason("stale", 6).contains("no key"), "{v}");
    assert!(reason("stale", 3).contains("output unreadable"), "{v}");
    assert_eq!(reason("missing", 5), "output missing", "{v}");
    // The text form counts them apart and says why.
    let out = umbra(&["batch", job.to_str().unwrap(), "--status"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("5 done, 0 failed, 2 stale, 1 not yet run"),
        "{text}"
    );
    assert!(
        text.contains("stale   task 6") && text.contains("no key"),
        "{text}"
    );
    // --keep-unkeyed takes the hand-made map as done, and a run keeps it.
    assert_eq!(status(&job, &["--keep-unkeyed"]).1, [6, 0, 1, 1]);
    let hand = std::fs::read(&hero_sun).unwrap();
    let b = baked(&run(&job, &["--keep-unkeyed"]));
    assert_eq!(indices(&b), [3, 5], "{b:?}");
    assert_eq!(std::fs::read(&hero_sun).unwrap(), hand);
    // Without it, the map is baked again, saying why.
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [6], "{b:?}");
    assert!(b[0].1.contains("no key"), "{b:?}");
    assert_eq!(status(&job, &[]).1, [8, 0, 0, 0]);
}

/// A USD stage input and a `[[positions]]` entry: the stage layer edited re-bakes both, naming
/// the stage; a grid file behind it re-simulated, naming the file; a positions key, the
/// positions task alone.
#[test]
fn a_stage_layer_a_grid_behind_it_and_a_positions_key_rebake_their_tasks() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(data("cloud.vdb"), d.join("cloud.vdb")).unwrap();
    let stage = |angle: i32| {
        let text = format!(
            "#usda 1.0\n(\n    startTimeCode = 1001\n    endTimeCode = 1001\n)\n\n\
             def Volume \"cloud\"\n{{\n    rel field:density = </cloud/density>\n\n    \
             def OpenVDBAsset \"density\"\n    {{\n        asset filePath = @./cloud.vdb@\n        \
             token fieldName = \"density\"\n    }}\n}}\n\n\
             def Points \"pts\"\n{{\n    point3f[] points = [(0, 0, 0), (1.9, -1, 0.3)]\n}}\n\n\
             def DistantLight \"sun\"\n{{\n    double3 xformOp:rotateXYZ = ({angle}, 0, 0)\n    \
             uniform token[] xformOpOrder = [\"xformOp:rotateXYZ\"]\n}}\n"
        );
        std::fs::write(d.join("shot.usda"), text).unwrap();
    };
    stage(-90);
    let job = d.join("job.toml");
    std::fs::write(
        &job,
        "output = \"out/{light}.exr\"\nlog = \"out/umbra_batch.jsonl\"\n\
         [[inputs]]\nusd = \"shot.usda\"\n[[lights]]\nusd = \"/sun\"\n\
         [[positions]]\nusd = \"shot.usda\"\nprim = \"/pts\"\nusd_out = \"out/pts.usda\"\n\
         density_scale = 2.0\n[bake]\nres = 16\n",
    )
    .unwrap();
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [0, 1], "{b:?}");
    assert!(baked(&run(&job, &[])).is_empty());
    // A positions key: the positions task alone, named by its entry.
    edit(&job, "density_scale = 2.0", "density_scale = 3.0");
    let b = baked(&run(&job, &[]));
    assert_eq!(
        b,
        [(1, "settings changed: positions[0].density_scale".into())]
    );
    // The stage layer edited (its sun turned): both, naming the stage.
    stage(-80);
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [0, 1], "{b:?}");
    assert!(
        b.iter()
            .all(|(_, w)| w.contains("input changed: shot.usda")),
        "{b:?}"
    );
    // The grid file the stage names re-simulated behind an unchanged stage: both, naming it.
    std::fs::copy(data("cloud_half.vdb"), d.join("cloud.vdb")).unwrap();
    let b = baked(&run(&job, &[]));
    assert_eq!(indices(&b), [0, 1], "{b:?}");
    assert!(
        b.iter()
            .all(|(_, w)| w.contains("input changed: cloud.vdb")),
        "{b:?}"
    );
    assert!(baked(&run(&job, &[])).is_empty());
}

/// The `umbra:key` text attribute of an EXR, read with the exr crate.
fn exr_key(path: &Path) -> Option<String> {
    let meta = exr::meta::MetaData::read_from_file(path, false).unwrap();
    let h = meta.headers.first()?;
    match h
        .own_attributes
        .other
        .get(&exr::meta::attribute::Text::from("umbra:key"))?
    {
        exr::meta::attribute::AttributeValue::Text(t) => Some(t.to_string()),
        _ => None,
    }
}

/// The `holds` of every record of the job's log, by task.
fn holds(job: &Path) -> Vec<(u64, Option<i64>)> {
    let log = job.parent().unwrap().join("out/umbra_batch.jsonl");
    let mut v: Vec<(u64, Option<i64>)> = std::fs::read_to_string(log)
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (v["task"].as_u64().unwrap(), v["holds"].as_i64())
        })
        .collect();
    v.sort_unstable();
    v
}

#[test]
fn held_frames_bake_once_and_their_copies_are_the_bytes_a_bake_writes() {
    let dir = tempfile::tempdir().unwrap();
    let job = setup(dir.path());
    // Frame 2 holds frame 1 (a copy of the same cache); frame 3 is re-simulated.
    std::fs::copy(data("cloud_half.vdb"), dir.path().join("cloud.0003.vdb")).unwrap();
    run(&job, &[]);
    // Tasks 0, 1: frame 1 (sun, lamp); 2, 3: frame 2 holds frame 1; 4, 5: frame 3; 6, 7: hero
    // (not a sequence).
    let h = holds(&job);
    assert_eq!(
        h,
        vec![
            (0, None),
            (1, None),
            (2, Some(1)),
            (3, Some(1)),
            (4, None),
            (5, None),
            (6, None),
            (7, None)
        ],
        "{h:?}"
    );
    let copies: Vec<Vec<u8>> = ["cloud.0002_sun.exr", "cloud.0002_lamp.exr"]
        .iter()
        .map(|n| read(dir.path(), n))
        .collect();
    // The copy names its own source file and key, not frame 1's.
    let key = exr_key(&dir.path().join("out/cloud.0002_sun.exr")).unwrap();
    assert!(
        key.contains("cloud.0002.vdb") && !key.contains("cloud.0001.vdb"),
        "{key}"
    );
    assert_ne!(copies[0], read(dir.path(), "cloud.0001_sun.exr"));
    // Each copy is what the task's own bake writes, byte for byte.
    for (task, name, copy) in [
        ("2", "cloud.0002_sun.exr", &copies[0]),
        ("3", "cloud.0002_lamp.exr", &copies[1]),
    ] {
        let recs = run(&job, &["--task", task, "--force"]);
        assert_eq!(baked(&recs).len(), 1);
        assert_eq!(
            &read(dir.path(), name),
            copy,
            "{name}: the copy differs from a bake"
        );
    }
    // The frames hold each other only while their content is the same.
    std::fs::copy(data("cloud_half.vdb"), dir.path().join("cloud.0002.vdb")).unwrap();
    let recs = run(&job, &[]);
    assert_eq!(indices(&baked(&recs)), vec![2, 3], "{recs:?}");
}
