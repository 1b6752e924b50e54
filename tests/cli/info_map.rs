//! `umbra info MAP.exr` (issue 68 item 5): what a map umbra baked says about itself (its
//! request from the header, its batch key, whether it is stale against its inputs today), text
//! and `--json`; a transmittance `.vdb` too; a foreign EXR gets its size and channels.
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

fn text(args: &[&str]) -> String {
    let o = umbra(args);
    assert!(o.status.success(), "{args:?}: {o:?}");
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn json(args: &[&str]) -> serde_json::Value {
    serde_json::from_str(&text(args)).unwrap()
}

/// A one-input job in `dir` writing `out/cloud_sun.EXT`.
fn job(dir: &Path, ext: &str) -> PathBuf {
    std::fs::copy(data("cloud.vdb"), dir.join("cloud.vdb")).unwrap();
    let job = dir.join("job.toml");
    std::fs::write(
        &job,
        format!(
            "output = \"out/{{stem}}_{{light}}.{ext}\"\n[[inputs]]\nfile = \"cloud.vdb\"\n\
             [[lights]]\nname = \"sun\"\ndir = [0.3, -1.0, 0.2]\n[bake]\nseed = 9\n\
             density_scale = 2.0\n{}",
            if ext == "exr" { "res = 16\n" } else { "" }
        ),
    )
    .unwrap();
    let o = umbra(&["batch", job.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{o:?}");
    dir.join(format!("out/cloud_sun.{ext}"))
}

#[test]
fn info_on_a_map_says_what_it_was_baked_from_and_whether_it_is_stale() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let map = job(d, "exr");
    let m = map.to_str().unwrap();
    let t = text(&["info", m]);
    assert!(t.contains("OpenEXR 14 x 16, channels T"), "{t}");
    assert!(t.contains("baked by umbra from:"), "{t}");
    assert!(t.contains("cloud.vdb") && t.contains("density"), "{t}");
    assert!(t.contains("light dir") && t.contains("0.3"), "{t}");
    assert!(
        t.contains("estimator") && t.contains("seed") && t.contains('9'),
        "{t}"
    );
    assert!(t.contains("up to date with its inputs"), "{t}");
    let v = json(&["info", "--json", m]);
    assert_eq!(v["baked_by_umbra"], true, "{v}");
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(14), Some(16)),
        "{v}"
    );
    assert_eq!(v["attributes"]["seed"], "9", "{v}");
    assert_eq!(v["attributes"]["light_dir"][0], 0.3, "{v}");
    assert_eq!(v["key"]["request"]["density_scale"], 2.0, "{v}");
    assert_eq!(v["stale"], false, "{v}");
    assert_eq!(v["inputs"][0]["state"], "unchanged", "{v}");
    // The cache re-simulated: the map says it is stale, naming the file.
    std::fs::copy(data("cloud_half.vdb"), d.join("cloud.vdb")).unwrap();
    let v = json(&["info", "--json", m]);
    assert_eq!(v["stale"], true, "{v}");
    assert_eq!(v["inputs"][0]["state"], "changed", "{v}");
    assert!(text(&["info", m]).contains("stale: an input changed"));
    std::fs::remove_file(d.join("cloud.vdb")).unwrap();
    assert_eq!(
        json(&["info", "--json", m])["inputs"][0]["state"],
        "missing"
    );
    // A map `umbra bake` wrote has its request but no key.
    let plain = d.join("plain.exr");
    let o = umbra(&[
        "bake",
        data("cloud.vdb").to_str().unwrap(),
        "--light-dir=0,-1,0",
        "--res=8",
        "-o",
        plain.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{o:?}");
    let t = text(&["info", plain.to_str().unwrap()]);
    assert!(
        t.contains("baked by umbra from:") && t.contains("no batch key"),
        "{t}"
    );
    assert!(json(&["info", "--json", plain.to_str().unwrap()])["stale"].is_null());
}

#[test]
fn info_on_a_foreign_exr_gives_its_size_and_channels() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("plate.exr");
    exr::prelude::write_rgb_file(&p, 4, 3, |_, _| (0.5_f32, 0.25_f32, 1.0_f32)).unwrap();
    let s = p.to_str().unwrap();
    let t = text(&["info", s]);
    assert!(t.contains("OpenEXR 4 x 3"), "{t}");
    assert!(t.contains("(not baked by umbra)"), "{t}");
    assert!(t.contains('R') && t.contains('G') && t.contains('B'), "{t}");
    let v = json(&["info", "--json", s]);
    assert_eq!(v["baked_by_umbra"], false, "{v}");
    assert_eq!(v["channels"].as_array().unwrap().len(), 3, "{v}");
}

#[test]
fn info_on_a_transmittance_volume_says_what_it_was_baked_from() {
    let dir = tempfile::tempdir().unwrap();
    let vol = job(dir.path(), "vdb");
    let s = vol.to_str().unwrap();
    let t = text(&["info", s]);
    assert!(t.contains("transmittance"), "{t}");
    assert!(
        t.contains("baked by umbra from:") && t.contains("up to date"),
        "{t}"
    );
    let v = json(&["info", "--json", s]);
    assert_eq!(v["umbra"]["baked_by_umbra"], true, "{v}");
    assert_eq!(v["umbra"]["stale"], false, "{v}");
    assert_eq!(v["umbra"]["key"]["format"], "volume/1", "{v}");
}
