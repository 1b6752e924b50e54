//! Tiled and mip-mapped maps (`bake --tile N [--mipmap]`), read back by OpenImageIO: the tile
//! size and levels `iinfo -v` reports, level 0 equal to the scanline map (`oiiotool --diff`),
//! every level OIIO extracts (`--selectmip`) equal to the box filter of `bake::mip_levels`.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use crate::bake_support;

use bake_support::read_exr;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn umbra(args: &[&str]) -> Output {
    assert_cmd::Command::cargo_bin("umbra")
        .unwrap()
        .args(args)
        .output()
        .unwrap()
}

fn tool(name: &str, args: &[&str]) -> String {
    let o = Command::new(name)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("{name} (Debian's openimageio-tools) is needed: {e}"));
    assert!(
        o.status.success(),
        "{name} {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn bake(out: &Path, extra: &[&str]) {
    let cloud = data("cloud.vdb");
    let mut args = vec![
        "bake",
        cloud.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--force",
        "-q",
    ];
    args.extend_from_slice(extra);
    let o = umbra(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn tiles_and_levels_read_back_by_openimageio() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, &[&str]); 4] = [
        ("100x70", &["--tile", "32"]),
        ("64x64", &["--tile", "64"]),
        ("33x17", &["--tile", "8"]),
        // Several channels: the standard error and slices, each tiled and mip-mapped.
        (
            "40x30",
            &[
                "--tile",
                "16",
                "--estimator",
                "ratio",
                "--stderr",
                "--slices",
                "2",
            ],
        ),
    ];
    let common = ["--light-dir=-1,-1,0.3", "--spp", "4"];
    for (res, extra) in cases {
        let scan = dir.path().join(format!("s{res}.exr"));
        let tiled = dir.path().join(format!("t{res}.exr"));
        let mip = dir.path().join(format!("m{res}.exr"));
        let untiled: Vec<&str> = extra.iter().skip(2).copied().collect();
        bake(&scan, &[&common[..], &["--res", res], &untiled].concat());
        bake(&tiled, &[&common[..], &["--res", res], extra].concat());
        bake(
            &mip,
            &[&common[..], &["--res", res], extra, &["--mipmap"]].concat(),
        );
        let (w, h) = res.split_once('x').unwrap();
        let (w, h): (usize, usize) = (w.parse().unwrap(), h.parse().unwrap());
        let n = extra[1];
        for f in [&tiled, &mip] {
            let info = tool("iinfo", &["-v", f.to_str().unwrap()]);
            assert!(info.contains(&format!("tile size: {n} x {n}")), "{info}");
            // Level 0, every channel, equals the scanline map.
            let diff = tool(
                "oiiotool",
                &[f.to_str().unwrap(), scan.to_str().unwrap(), "--diff"],
            );
            assert!(diff.contains("PASS"), "{diff}");
        }
        let info = tool("iinfo", &["-v", mip.to_str().unwrap()]);
        let sizes = umbra::bake::mip_sizes(w, h);
        let listed: Vec<String> = sizes.iter().map(|(a, b)| format!("{a}x{b}")).collect();
        assert!(
            info.contains(&format!("MIP-map levels: {}", listed.join(" "))),
            "{info}"
        );
        assert!(!tool("iinfo", &["-v", tiled.to_str().unwrap()]).contains("MIP-map"));
        // Every level, as OpenImageIO reads it, is the box filter of level 0, channel by channel.
        let base = read_exr(&scan);
        for (l, &(lw, lh)) in sizes.iter().enumerate() {
            let lvl = dir.path().join(format!("l{res}_{l}.exr"));
            tool(
                "oiiotool",
                &[
                    mip.to_str().unwrap(),
                    "--selectmip",
                    &l.to_string(),
                    "-d",
                    "float",
                    "-o",
                    lvl.to_str().unwrap(),
                ],
            );
            let got = read_exr(&lvl);
            assert_eq!((got.w, got.h), (lw, lh));
            for (name, plane) in &base.ch {
                let want = &umbra::bake::mip_levels(plane, w, h)[l];
                let g = &got
                    .ch
                    .iter()
                    .find(|(n, _)| n.as_str() == name.as_str())
                    .unwrap()
                    .1;
                assert!(
                    g.as_slice() == want.as_slice(),
                    "level {l} of {name} ({res})"
                );
            }
        }
    }
}

#[test]
fn layouts_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m.exr");
    let o = out.to_str().unwrap();
    let cloud = data("cloud.vdb");
    let c = cloud.to_str().unwrap();
    for (args, flag) in [
        (vec!["--mipmap"], "--mipmap"),
        (vec!["--tile", "0"], "--tile"),
        (vec!["--tile", "5000"], "--tile"),
    ] {
        let mut all = vec!["bake", c, "--light-dir=0,-1,0", "--res", "16", "-o", o];
        all.extend(args);
        let r = umbra(&all);
        assert_eq!(r.status.code(), Some(1));
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(
            err.starts_with("umbra: error:") && err.contains(flag),
            "{err}"
        );
        assert!(!out.exists());
    }
}

#[test]
fn batch_jobs_write_tiled_maps() {
    let dir = tempfile::tempdir().unwrap();
    let job = |extra: &str| {
        let p = dir.path().join("job.toml");
        std::fs::write(
            &p,
            format!(
                "output = \"{}/{{stem}}_{{light}}.exr\"\n[[inputs]]\nfile = {:?}\n\
                 [[lights]]\nname = \"sun\"\ndir = [0.3, -1, 0.2]\n[bake]\nres = [60, 40]\n\
                 spp = 1\n{extra}\n",
                dir.path().display(),
                data("cloud.vdb").display().to_string()
            ),
        )
        .unwrap();
        umbra(&["batch", p.to_str().unwrap(), "-q", "--force"])
    };
    let o = job("tile = 16\nmipmap = true");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from_batch = std::fs::read(dir.path().join("cloud_sun.exr")).unwrap();
    let cli = dir.path().join("cli.exr");
    bake(
        &cli,
        &[
            "--light-dir=0.3,-1,0.2",
            "--res",
            "60x40",
            "--spp",
            "1",
            "--tile",
            "16",
            "--mipmap",
        ],
    );
    // The same pixels, tiles and levels (oiiotool below); the headers differ by the source
    // path each records (both absolute here) and by the batch task's key (`umbra:key`, issue
    // 68), which only the batch's output holds.
    let from_cli = std::fs::read(&cli).unwrap();
    let has_key = |b: &[u8]| b.windows(9).any(|w| w == b"umbra:key");
    assert!(has_key(&from_batch) && !has_key(&from_cli));
    assert!(from_batch.len() > from_cli.len());
    let diff = tool(
        "oiiotool",
        &[
            "-a",
            dir.path().join("cloud_sun.exr").to_str().unwrap(),
            cli.to_str().unwrap(),
            "--diff",
        ],
    );
    assert!(diff.contains("PASS"), "{diff}");
    let o = job("mipmap = true");
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("bake.mipmap"));
}
