//! What a new user ran into (issue 30), each held to its fix: `info` on a valid file with a grid
//! umbra does not trace (point data) exits 0 and describes it from its header; long grid names
//! keep the columns aligned; a refused job file creates nothing; a bad `res` in a job file says
//! which forms are accepted; a refused level set names `--levelset solid`; `bake --help` names
//! the deep colour channels a deep map really carries.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::vdb_writer;

use crate::bake_support;

use assert_cmd::Command;
use std::path::Path;
use vdb_writer::{Grid, Leaf, Map, VdbFile};

fn umbra() -> Command {
    Command::cargo_bin("umbra").unwrap()
}

/// A liquid cache's shape: a fog grid with a long name and a point-data grid (its header as
/// OpenVDB writes it; umbra reads only the header of a tree type it does not decode).
fn liquid_cache(path: &Path) {
    let fog = Grid::fog(
        "liquid_surface_density_with_a_long_name",
        vec![Leaf::filled([0, 0, 0], 0.5)],
    )
    .with_map(Map::UniformScale(0.1));
    let mut points =
        Grid::fog("points", vec![Leaf::filled([8, 0, 0], 1.0)]).with_map(Map::UniformScale(0.1));
    points.tree_type = Some("Tree_ptdataidx32_ptdataidx32_5_4_3".into());
    points.class = None;
    VdbFile::new(vec![fog, points]).write(path);
}

#[test]
fn info_describes_point_data_from_its_header_and_exits_0() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("liquid.vdb");
    liquid_cache(&path);
    let o = umbra().arg("info").arg(&path).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!out.contains("error"), "{out}");
    let lines: Vec<&str> = out.lines().skip(1).collect();
    assert_eq!(lines.len(), 2, "{out}");
    assert!(
        lines[1].contains("point data") && lines[1].contains("header"),
        "{out}"
    );
    // The type column starts at the same place on both lines, after the longest name.
    let col = |l: &str, w: &str| l.find(w).unwrap();
    assert_eq!(
        col(lines[0], "float"),
        col(lines[1], "ptdataidx32"),
        "{out}"
    );
    // JSON: the header's facts and a note, no error.
    let o = umbra()
        .args(["info", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &v["grids"][1];
    assert!(g["error"].is_null(), "{g}");
    assert!(g["note"].as_str().unwrap().contains("point data"), "{g}");
    assert_eq!(g["voxel_size"], serde_json::json!([0.1, 0.1, 0.1]), "{g}");
    assert_eq!(g["map"], "UniformScaleMap", "{g}");
    // -v too.
    let o = umbra().args(["info", "-v"]).arg(&path).output().unwrap();
    assert_eq!(o.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&o.stdout).contains("note: point data"));
}

/// A job whose input is missing, or whose grid is not in its file, is refused before anything
/// is created: no output directory, no log.
#[test]
fn a_refused_job_creates_nothing() {
    let cloud = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    for (grid, file) in [
        ("density", "missing.vdb".to_string()),
        ("nope", cloud.display().to_string()),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let job = dir.path().join("job.toml");
        std::fs::write(
            &job,
            format!(
                "grid = {grid:?}\noutput = \"out/{{stem}}.exr\"\n[[inputs]]\nfile = {file:?}\n\
                 [[lights]]\nname = \"sun\"\ndir = [0, -1, 0]\n"
            ),
        )
        .unwrap();
        let o = umbra()
            .args(["batch", "-q"])
            .arg(&job)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(
            left,
            vec![std::ffi::OsString::from("job.toml")],
            "{grid}: {err}"
        );
    }
}

/// `res = "64by48"` names the key and the accepted forms; `"64x48"` is one of them.
#[test]
fn a_bad_res_in_a_job_says_what_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.toml");
    let cloud = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cloud.vdb");
    let text = |res: &str| {
        format!(
            "grid = \"density\"\noutput = \"{{stem}}.exr\"\n[[inputs]]\nfile = {:?}\n\
             [[lights]]\nname = \"sun\"\ndir = [0, -1, 0]\n[bake]\nres = {res}\n",
            cloud.display().to_string()
        )
    };
    std::fs::write(&job, text("\"64by48\"")).unwrap();
    let o = umbra()
        .args(["batch", "--plan"])
        .arg(&job)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("res") && err.contains("WxH") && err.contains("[W, H]"),
        "{err}"
    );
    assert!(!err.contains("untagged"), "{err}");
    for ok in ["\"64x48\"", "[64, 48]", "64"] {
        std::fs::write(&job, text(ok)).unwrap();
        let o = umbra()
            .args(["batch", "--plan"])
            .arg(&job)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{ok}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

#[test]
fn a_refused_level_set_names_the_solid_option() {
    let ls = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus/gen/sphere_levelset.vdb");
    if !ls.exists() {
        assert!(std::env::var("CI").is_err(), "the corpus is missing");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let o = umbra()
        .arg("bake")
        .arg(&ls)
        .args([
            "--grid",
            "ls_sphere",
            "--light-dir=0,-1,0",
            "--res",
            "8",
            "-q",
            "-o",
        ])
        .arg(dir.path().join("x.exr"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--levelset solid"), "{err}");
}

#[test]
fn bake_help_names_the_deep_colour_channels() {
    let o = umbra().args(["bake", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&o.stdout);
    assert!(help.contains("AR, AG, AB"), "{help}");
    assert!(!help.contains("R, G, B with colour"), "{help}");
}

/// Issue 46's friction, each held to its mend: `--quiet` prints no summary (warnings still go
/// to stderr); an exact map's header records one sample, not `--spp`; a `--fov` that crops the
/// volume is warned about; an empty `--grid` is a usage error (exit 2); `info` says a sum is
/// over finite values when some are not, and writes "half" only after grids stored as halves
/// (real-valued ones, not int32).
#[test]
fn issue_46_friction_is_mended() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.exr");
    let o = umbra()
        .args([
            "bake",
            "data/cloud.vdb",
            "--light-pos=0,6,0",
            "--fov",
            "10",
            "--res",
            "16",
        ])
        .args(["--spp", "64", "-q", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        o.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("--fov 10 crops the volume"), "{err}");
    match bake_support::read_exr(&out).attr("spp") {
        exr::meta::attribute::AttributeValue::I32(n) => assert_eq!(*n, 1),
        other => panic!("{other:?}"),
    }
    for args in [
        &[
            "query",
            "data/cloud.vdb",
            "--grid",
            "",
            "--from",
            "0,0,0",
            "--to",
            "1,1,1",
        ][..],
        &[
            "bake",
            "data/cloud.vdb",
            "--grid",
            "",
            "--light-dir=0,-1,0",
            "-o",
            "x.exr",
        ][..],
        &["info", "data/cloud.vdb", "--grid", ""][..],
    ] {
        let o = umbra().args(args).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}");
    }
    let blender = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/corpus/real/blender_smoke_fluid_data_0050.vdb");
    if !blender.exists() {
        assert!(std::env::var("UMBRA_SKIP_CORPUS").as_deref() == Ok("1"));
        return;
    }
    let o = umbra().arg("info").arg(&blender).output().unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let line = |name: &str| {
        out.lines()
            .find(|l| l.trim_start().starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no {name}: {out}"))
            .to_string()
    };
    assert!(
        line("flags").contains("int32") && !line("flags").contains("half"),
        "{out}"
    );
    assert!(line("density").contains("float (half)"), "{out}");
    let o = umbra()
        .arg("info")
        .arg(&blender)
        .args(["--grid", "phi_obstacle", "-v"])
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        out.contains("sum: 0 over finite values (56606 not finite)"),
        "{out}"
    );
}

/// Issue 58's `info` frictions, on real files: a vector grid's `-v` report says what a TD needs
/// of its vectors (value type, staggered or not, `vector_type`, `is_local_space` as the file has
/// them); `--grid` on a file of 17 grids says it shows 1 of 17; a file with no grids says so.
#[test]
fn info_tells_vectors_grid_selections_and_empty_files() {
    let Some(corpus) = crate::common::corpus_dir() else {
        return;
    };
    let blender = corpus.join("real/blender_smoke_fluid_data_0050.vdb");
    let o = umbra()
        .args(["info", "-v", "--grid", "velocity"])
        .arg(&blender)
        .output()
        .unwrap();
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains(", 1 of 17 grids shown (--grid)"), "{text}");
    assert!(
        text.contains("  vector: vec3s  staggered: yes  vector_type: "),
        "{text}"
    );
    let o = umbra()
        .args(["info", "--json", "--grid", "velocity"])
        .arg(&blender)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["grid_count"], 17);
    let vector = &v["grids"][0]["vector"];
    assert_eq!(
        (&vector["value_type"], &vector["staggered"]),
        (&"vec3s".into(), &true.into())
    );
    // A scalar grid has no vector report.
    let o = umbra()
        .args(["info", "--json", "--grid", "density"])
        .arg(&blender)
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(v["grids"][0].get("vector").is_none(), "{v}");
    let empty = corpus.join("real/houdini20_no_grids.vdb");
    for args in [&["info"][..], &["info", "-v"]] {
        let o = umbra().args(args).arg(&empty).output().unwrap();
        assert!(o.status.success(), "{args:?}");
        let text = String::from_utf8_lossy(&o.stdout);
        assert!(
            text.trim_end().ends_with("no grids (the file holds none)"),
            "{args:?}: {text}"
        );
    }
}

/// Issue 58: a point light inside the cloud with `--fov` is told what works (an omni map), not
/// to drop `--fov` (which is refused, naming `--omni`); the omni map it names bakes.
#[test]
fn issue_58_a_light_inside_the_cloud_is_told_what_works() {
    let dir = tempfile::tempdir().unwrap();
    let bake = |extra: &[&str], out: &str| {
        umbra()
            .args([
                "bake",
                "data/cloud.vdb",
                "--light-pos=0,1.5,0",
                "--res",
                "16",
                "-q",
            ])
            .args(extra)
            .arg("-o")
            .arg(dir.path().join(out))
            .output()
            .unwrap()
    };
    let o = bake(&["--fov", "60"], "fov.exr");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("--fov 60 crops the volume"), "{err}");
    assert!(
        err.contains("behind the light") && err.contains("--omni"),
        "{err}"
    );
    assert!(!err.contains("drop --fov") && !err.contains("inf"), "{err}");
    let o = bake(&[], "none.exr");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("--omni cube|latlong"), "{err}");
    assert!(!dir.path().join("none.exr").exists());
    let o = bake(&["--omni", "cube"], "omni.exr");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        o.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Issue 58: queries that meet no active voxel (T = 1 for each) say so, on stderr and in each
/// `--json` line's `warnings`; a query through the cloud, or a file where one ray meets it,
/// does not.
#[test]
fn issue_58_a_query_missing_every_voxel_says_so() {
    let query = |args: &[&str]| {
        let o = umbra()
            .args(["query", "data/cloud.vdb"])
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (
            String::from_utf8_lossy(&o.stdout).to_string(),
            String::from_utf8_lossy(&o.stderr).to_string(),
        )
    };
    let miss = ["--from", "100,100,100", "--to", "101,100,100"];
    let (out, err) = query(&miss);
    assert!(out.starts_with("T = 1.0"), "{out}");
    assert!(
        err.contains("warning: the query met no active voxel (T = 1)") && err.contains("--xform"),
        "{err}"
    );
    let (out, _) = query(&[&miss[..], &["--json"]].concat());
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["warnings"][0]["kind"], "missed-every-voxel", "{out}");
    assert_eq!(v["warnings"][0]["queries"], 1, "{out}");
    // A light direction pointing away from the cloud from outside it: the same.
    let (_, err) = query(&["--at", "0,20,0", "--light-dir=0,-1,0"]);
    assert!(err.contains("met no active voxel"), "{err}");
    // Through the cloud: no warning, an empty list.
    let (out, err) = query(&["--at", "0,1.5,0", "--light-dir=-1,-1,0", "--json"]);
    assert!(err.is_empty(), "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["warnings"], serde_json::json!([]), "{out}");
    // A file of rays: one through the cloud silences it; all missing names the count.
    let dir = tempfile::tempdir().unwrap();
    let rays = dir.path().join("r.csv");
    std::fs::write(&rays, "100,100,100,101,100,100\n-5,1.5,0,5,1.5,0\n").unwrap();
    let (_, err) = query(&["--rays", rays.to_str().unwrap()]);
    assert!(err.is_empty(), "{err}");
    std::fs::write(&rays, "100,100,100,101,100,100\n-5,90,0,5,90,0\n").unwrap();
    let (_, err) = query(&["--rays", rays.to_str().unwrap()]);
    assert!(
        err.contains("warning: none of the 2 queries met an active voxel (T = 1)"),
        "{err}"
    );
}

/// The budget labels of `error_vs_time.svg`: (x, y, text) of every coloured `<text>` (the axes,
/// caption and legend are black).
fn budget_labels(svg: &str) -> Vec<(i32, i32, String)> {
    let mut out = Vec::new();
    for el in svg.split("<text ").skip(1) {
        let (attrs, rest) = el.split_once('>').unwrap();
        let attr = |k: &str| {
            let at = attrs.find(&format!(" {k}=\"")).map(|i| i + k.len() + 3);
            at.map(|i| attrs[i..].split('"').next().unwrap().to_string())
        };
        if attr("fill").is_none_or(|f| f == "#000000") {
            continue;
        }
        let x = attrs
            .strip_prefix("x=\"")
            .and_then(|s| s.split('"').next())
            .unwrap();
        let text = rest.split("</text>").next().unwrap().trim().to_string();
        out.push((
            x.parse().unwrap(),
            attr("y").unwrap().parse().unwrap(),
            text,
        ));
    }
    out
}

/// Issue 58: `compare` says when collision scores as track-length (crossing rays), and the
/// plot's budget labels do not overprint (coinciding points share one label).
#[test]
fn issue_58_compare_says_collision_is_track_length_and_labels_do_not_overlap() {
    let dir = tempfile::tempdir().unwrap();
    let run = |estimators: &str, out: &str| {
        let o = umbra()
            .args([
                "compare",
                "data/cloud.vdb",
                "--rays",
                "300",
                "--repeats",
                "1",
                "-q",
            ])
            .args(["--estimators", estimators, "-o"])
            .arg(dir.path().join(out))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let read = |f: &str| std::fs::read_to_string(dir.path().join(out).join(f)).unwrap();
        (
            read("report.md"),
            read("report.json"),
            read("error_vs_time.svg"),
        )
    };
    let (md, json, svg) = run("collision,track-length,ratio", "a");
    assert!(
        md.contains("Note: collision's errors equal track-length's at every budget"),
        "{md}"
    );
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["notes"].as_array().unwrap().len(), 1, "{json}");
    let labels = budget_labels(&svg);
    // 12 budget points; coinciding ones may share a label, every budget is labelled once.
    assert!(labels.len() >= 8 && labels.len() <= 12, "{labels:?}");
    for budget in ["1", "4", "16", "64"] {
        assert!(labels.iter().any(|l| l.2 == budget), "{budget}: {labels:?}");
    }
    // Boxes of 12 px sans-serif labels (drawn at 9.7 px): no two overlap.
    let boxes: Vec<[i32; 4]> = labels
        .iter()
        .map(|(x, y, t)| [*x, *y, x + 7 * t.len() as i32, y + 12])
        .collect();
    for (i, a) in boxes.iter().enumerate() {
        for b in &boxes[i + 1..] {
            let apart = a[2] <= b[0] || b[2] <= a[0] || a[3] <= b[1] || b[3] <= a[1];
            assert!(apart, "labels overlap: {a:?} {b:?} in {labels:?}");
        }
    }
    let (md, json, _) = run("track-length,ratio", "b");
    assert!(!md.contains("Note:"), "{md}");
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    assert_eq!(v["notes"], serde_json::json!([]), "{json}");
}
