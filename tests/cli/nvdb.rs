//! `.nvdb` files (NanoVDB, issue 49) wherever a `.vdb` goes on the command line: `query`,
//! `--grid` in a multi-grid file, `info` (text and JSON), a scene file, a USD stage and a batch
//! pattern naming them; bad `.nvdb` files end in exit 1 and one `umbra: error:` line naming the file.
//! The files are made by Debian's `nanovdb_convert` (libnanovdb-tools) at test time.

use crate::common::{self, nanovdb_convert};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Output;

fn umbra(args: &[&str]) -> Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `data/cloud.vdb` as a ZIP `.nvdb` in `dir`.
fn cloud(dir: &Path) -> (PathBuf, PathBuf) {
    let vdb = common::data("cloud.vdb");
    let nvdb = dir.join("cloud.nvdb");
    nanovdb_convert(&["-z"], &vdb, &nvdb);
    (vdb, nvdb)
}

fn transmittance(file: &str, extra: &[&str]) -> f64 {
    let mut a = vec![
        "query",
        file,
        "--json",
        "--from",
        "-2,0.2,0",
        "--to",
        "2,0.7,0.3",
    ];
    a.extend_from_slice(extra);
    let o = umbra(&a);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    v["T"].as_f64().unwrap()
}

#[test]
fn query_scene_and_batch_read_nvdb_as_they_read_vdb() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (vdb, nvdb) = cloud(d);
    let t = transmittance(s(&vdb), &[]);
    assert!(t > 0.0 && t < 1.0, "{t}");
    assert_eq!(transmittance(s(&nvdb), &[]), t);
    let upper = d.join("CLOUD.NVDB");
    std::fs::copy(&nvdb, &upper).unwrap();
    assert_eq!(
        transmittance(s(&upper), &[]),
        t,
        "the extension in any case"
    );
    // A scene file naming the .nvdb.
    let scene = d.join("scene.toml");
    std::fs::write(
        &scene,
        "[[volume]]\nfile = \"cloud.nvdb\"\ngrid = \"density\"\n",
    )
    .unwrap();
    assert_eq!(transmittance(s(&scene), &[]), t);
    // A USD stage whose OpenVDBAsset names the .nvdb.
    let stage = d.join("shot.usda");
    std::fs::write(
        &stage,
        "#usda 1.0\n\ndef Volume \"cloud\"\n{\n    rel field:density = </cloud/density>\n\n    \
         def OpenVDBAsset \"density\"\n    {\n        asset filePath = @cloud.nvdb@\n        \
         token fieldName = \"density\"\n    }\n}\n",
    )
    .unwrap();
    assert_eq!(transmittance(s(&stage), &[]), t);
    // A budget a NanoVDB grid cannot honour (it loads whole) is said to be ignored.
    let map = d.join("map.exr");
    let o = umbra(&[
        "bake",
        s(&nvdb),
        "--light-dir",
        "1,-1,0",
        "--res",
        "32",
        "--max-memory",
        "2M",
        "-o",
        s(&map),
    ]);
    assert!(o.status.success() && map.is_file());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--max-memory is not honoured: NanoVDB grids"),
        "{err}"
    );
    // A batch over a frame pattern of .nvdb files.
    for f in 1..=2 {
        std::fs::copy(&nvdb, d.join(format!("cloud.{f:04}.nvdb"))).unwrap();
    }
    let job = d.join("job.toml");
    std::fs::write(
        &job,
        "grid = \"density\"\noutput = \"out/sun.{frame:04}.exr\"\n[[inputs]]\n\
         pattern = \"cloud.####.nvdb\"\nframes = [1, 2]\n[[lights]]\nname = \"sun\"\n\
         dir = [0.3, -1.0, 0.2]\n[bake]\nres = 16\n",
    )
    .unwrap();
    let o = umbra(&["batch", s(&job)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for f in 1..=2 {
        assert!(d.join(format!("out/sun.{f:04}.exr")).is_file(), "frame {f}");
    }
}

#[test]
fn grid_selection_and_info_on_a_multi_grid_nvdb() {
    let Some(corpus) = common::corpus_dir() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let nvdb = dir.path().join("smoke.nvdb");
    nanovdb_convert(&["-b"], &corpus.join("gen/multigrid_smoke.vdb"), &nvdb);
    let t = transmittance(
        s(&nvdb),
        &["--grid", "temperature", "--density-scale", "1e-4"],
    );
    assert!(t > 0.0 && t < 1.0, "{t}");
    let o = umbra(&[
        "query",
        s(&nvdb),
        "--grid",
        "nope",
        "--from",
        "0,0,0",
        "--to",
        "1,1,1",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(
        err.starts_with("umbra: error:") && err.contains("smoke.nvdb"),
        "{err}"
    );
    assert!(err.contains("density, temperature, velocity"), "{err}");
    let o = umbra(&["info", "--json", s(&nvdb)]);
    assert!(o.status.success());
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["format"], "nvdb");
    let grids = v["grids"].as_array().unwrap();
    assert_eq!(grids.len(), 3);
    for g in grids {
        assert_eq!(g["codec"], "BLOSC");
        assert_eq!(g["quantisation"], "none");
        assert_eq!(g["checksum"], "partial");
        assert_eq!(g["nanovdb_version"], "32.4.2");
        assert!(g["active_voxels"].as_u64().unwrap() > 0);
    }
    assert_eq!(grids[2]["value_stats_of"], "vector length");
    let o = umbra(&["info", "-v", "--grid", "density", s(&nvdb)]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("NanoVDB format 32, library 32.4.2, ")
            && text.contains(" 1 of 3 grids shown (--grid)"),
        "{text}"
    );
    assert!(
        text.contains(
            "NanoVDB 32.4.2  codec: BLOSC  quantisation: none  checksum: partial (head only: \
             the headers checked, not the nodes)"
        ),
        "{text}"
    );
    assert_eq!(v["grid_count"], 3);
    let vdb = umbra(&["info", "--json", s(&common::data("cloud.vdb"))]);
    let v: Value = serde_json::from_slice(&vdb.stdout).unwrap();
    assert_eq!(v["format"], "vdb");
    assert!(
        v["grids"][0].get("codec").is_none(),
        "no NanoVDB keys on a .vdb"
    );
}

#[test]
fn bad_nvdb_files_end_in_one_error_line_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (_, nvdb) = cloud(d);
    let good = std::fs::read(&nvdb).unwrap();
    // A flipped byte in the map of an uncompressed grid: only its checksum tells.
    let plain = d.join("plain.nvdb");
    nanovdb_convert(&[], &common::data("cloud.vdb"), &plain);
    let mut flipped = std::fs::read(&plain).unwrap();
    flipped[16 + 176 + 8 + 300] ^= 2;
    let cases: [(&str, Vec<u8>, &str); 4] = [
        ("empty.nvdb", Vec::new(), "not a NanoVDB file (empty file)"),
        (
            "text.nvdb",
            b"just text, not NanoVDB\n".to_vec(),
            "not a NanoVDB file",
        ),
        (
            "cut.nvdb",
            good[..good.len() / 3].to_vec(),
            "corrupt NanoVDB file",
        ),
        ("flip.nvdb", flipped, "checksum mismatch"),
    ];
    for (name, bytes, want) in cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let out = d.join("out.exr");
        for args in [
            vec!["query", s(&p), "--from", "0,0,0", "--to", "1,1,1"],
            vec!["bake", s(&p), "--light-dir", "1,0,0", "-o", s(&out)],
        ] {
            let o = umbra(&args);
            assert_eq!(o.status.code(), Some(1), "{name} {args:?}");
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(err.lines().count(), 1, "{name}: {err}");
            assert!(err.starts_with("umbra: error:"), "{err}");
            assert!(err.contains(name) && err.contains(want), "{name}: {err}");
            assert!(o.stdout.is_empty() && !out.exists(), "{name}: output left");
        }
    }
}

/// `info` tells the checksum kinds apart, in text and JSON (issue 58): `nanovdb_convert -c full`
/// writes head and tail (`full`), its default the head alone (`partial`), `-c none` nothing.
#[test]
fn info_tells_full_from_partial_checksums() {
    let dir = tempfile::tempdir().unwrap();
    let vdb = common::data("cloud.vdb");
    for (flags, kind, text) in [
        (
            &["-c", "full"][..],
            "full",
            "checksum: full (head and nodes: every byte of the grid checked)",
        ),
        (
            &[][..],
            "partial",
            "checksum: partial (head only: the headers checked, not the nodes)",
        ),
        (
            &["-c", "none"][..],
            "absent",
            "checksum: absent (the file carries none)",
        ),
    ] {
        let nvdb = dir.path().join(format!("{kind}.nvdb"));
        nanovdb_convert(flags, &vdb, &nvdb);
        let o = umbra(&["info", "--json", s(&nvdb)]);
        assert!(o.status.success());
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(v["grids"][0]["checksum"], kind);
        let o = umbra(&["info", "-v", s(&nvdb)]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(out.contains(text), "{kind}: {out}");
    }
}

/// A full checksum of NanoVDB 32.4 on an FpN grid covers each leaf's first 96 bytes, not its
/// codes (issue 68, item 2): `nanovdb_validate` passes a flipped code. `info` says which bytes
/// it checked and which it did not, never "every byte"; a flipped code (the byte
/// 2488336, bit 2) moves the value sum and `info` still says those bytes were not checked.
/// Raw and fixed-width quantised grids are covered whole.
#[test]
fn info_says_which_bytes_an_fpn_checksum_leaves_out() {
    let dir = tempfile::tempdir().unwrap();
    let vdb = common::data("cloud.vdb");
    let fpn = dir.path().join("c.nvdb");
    nanovdb_convert(&["--fpN", "-a", "0.01", "-c", "full"], &vdb, &fpn);
    let o = umbra(&["info", "--json", s(&fpn)]);
    assert!(o.status.success());
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    let g = &v["grids"][0];
    assert_eq!(g["checksum"], "full");
    let c = &g["checksum_coverage"];
    let [checked, grid, unchecked, codes] = [
        "checked_bytes",
        "grid_bytes",
        "unchecked_bytes",
        "unchecked_code_bytes",
    ]
    .map(|k| c[k].as_u64().unwrap());
    assert_eq!(checked + unchecked, grid, "{c}");
    // 427 leaves: their codes are all that is not covered.
    assert!(codes > 0 && codes == unchecked, "{c}");
    let sum = g["value_sum"].as_f64().unwrap();
    let text = |p: &Path| {
        let o = umbra(&["info", "-v", s(p)]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    let want = format!(
        "checksum: full (head and nodes: {checked} of {grid} bytes checked; not checked: \
         {codes} bytes of FpN leaf codes"
    );
    let out = text(&fpn);
    assert!(out.contains(&want) && !out.contains("every byte"), "{out}");
    let mut b = std::fs::read(&fpn).unwrap();
    b[2_488_336] ^= 1 << 2;
    let flip = dir.path().join("flip.nvdb");
    std::fs::write(&flip, &b).unwrap();
    let out = text(&flip);
    assert!(out.contains(&want) && !out.contains("every byte"), "{out}");
    let o = umbra(&["info", "--json", s(&flip)]);
    let v: Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_ne!(v["grids"][0]["value_sum"].as_f64().unwrap(), sum);
    for (flags, name) in [
        (&["-c", "full"][..], "raw"),
        (&["--fp16", "-c", "full"][..], "fp16"),
    ] {
        let p = dir.path().join(format!("{name}.nvdb"));
        nanovdb_convert(flags, &vdb, &p);
        let out = text(&p);
        assert!(
            out.contains("checksum: full (head and nodes: every byte of the grid checked)"),
            "{name}: {out}"
        );
        let o = umbra(&["info", "--json", s(&p)]);
        let v: Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(
            v["grids"][0]["checksum_coverage"]["unchecked_bytes"], 0,
            "{name}"
        );
    }
}
