//! Helpers shared by the corpus-driven integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The shared test corpus (`../shared/corpus` next to the crate). A missing corpus fails the test
/// unless `UMBRA_SKIP_CORPUS=1`, in which case `None` is returned and the caller skips.
pub fn corpus_dir() -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/corpus");
    if p.join("manifest.json").is_file() {
        return Some(p);
    }
    assert!(
        std::env::var("UMBRA_SKIP_CORPUS").as_deref() == Ok("1"),
        "test corpus not found at {} (expected manifest.json there); \
         set UMBRA_SKIP_CORPUS=1 to skip the corpus tests",
        p.display()
    );
    eprintln!("UMBRA_SKIP_CORPUS=1: corpus missing, test skipped");
    None
}

/// Whether Debian's pyopenvdb is there for the OpenVDB oracle (`../shared/tools/oracle.py`).
/// Missing, it fails the test unless `UMBRA_SKIP_ORACLE=1` (then the caller skips).
pub fn oracle_available() -> bool {
    let ok = std::process::Command::new("/usr/bin/python3")
        .args(["-c", "import pyopenvdb"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        assert!(
            std::env::var("UMBRA_SKIP_ORACLE").as_deref() == Ok("1"),
            "pyopenvdb is not installed (apt-get install python3-openvdb) and UMBRA_SKIP_ORACLE is not 1"
        );
    }
    ok
}

/// A sample of the crate's `data/` directory.
pub fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

/// The parsed `manifest.json` of the corpus.
pub fn manifest(dir: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("read manifest.json");
    serde_json::from_str(&text).expect("manifest.json is not valid JSON")
}

/// The manifest's `files` array.
pub fn manifest_files(m: &serde_json::Value) -> &Vec<serde_json::Value> {
    m["files"].as_array().expect("manifest has a `files` array")
}

/// A manifest file entry's relative path.
pub fn entry_path(f: &serde_json::Value) -> &str {
    f["path"]
        .as_str()
        .expect("manifest file entry has a `path`")
}

/// Files OpenVDB reads and umbra must read too: everything under `gen/` and `real/`, plus
/// `bad/corrupt_leaf_payload.vdb` (structurally valid, only leaf values were scrambled).
pub fn must_read(path: &str) -> bool {
    path.starts_with("gen/") || path.starts_with("real/") || path == "bad/corrupt_leaf_payload.vdb"
}

/// Peak resident set size of this process (`VmHWM`), in bytes, if the platform reports it.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The message of a caught panic payload (the library's own helper).
#[allow(unused_imports)]
pub use umbra::batch::panic_message;

/// `name args` stdout for an OpenImageIO tool (`oiiotool`, `iinfo`; Debian `openimageio-tools`),
/// asserting success; `None` when the tool is missing and `UMBRA_SKIP_OIIO=1` (else the missing
/// tool fails the test).
pub fn oiio_tool(name: &str, args: &[&str]) -> Option<String> {
    let o = match std::process::Command::new(name).args(args).output() {
        Ok(o) => o,
        Err(e) => {
            assert!(
                std::env::var("UMBRA_SKIP_OIIO").as_deref() == Ok("1"),
                "{name} (Debian openimageio-tools) is needed ({e}); set UMBRA_SKIP_OIIO=1 to skip"
            );
            return None;
        }
    };
    assert!(
        o.status.success(),
        "{name} {args:?}: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    Some(String::from_utf8_lossy(&o.stdout).into_owned())
}

/// One deep sample as `oiiotool --dumpdata` prints it: `(channel, value)` in printed order.
pub type DumpedSample = Vec<(String, f32)>;

/// Every pixel of a `w x h` deep file as `oiiotool --dumpdata` prints it, row-major: its
/// samples. Lines read `Pixel (x, y): n samples : A=1 Z=2 / A=3 Z=4`. `None` as
/// [`oiio_tool`].
pub fn deep_dump(path: &std::path::Path, w: usize, h: usize) -> Option<Vec<Vec<DumpedSample>>> {
    let text = oiio_tool("oiiotool", &["--dumpdata", path.to_str()?])?;
    let mut pixels: Vec<Option<Vec<DumpedSample>>> = vec![None; w * h];
    for line in text
        .lines()
        .map(str::trim)
        .filter(|l| l.starts_with("Pixel ("))
    {
        let (pos, rest) = line["Pixel (".len()..]
            .split_once("): ")
            .unwrap_or_default();
        let (x, y) = pos.split_once(", ").unwrap_or_default();
        let (x, y): (usize, usize) = (x.parse().unwrap_or(usize::MAX), y.parse().unwrap_or(0));
        let (n, samples) = rest.split_once(" : ").unwrap_or((rest, ""));
        let n: usize = n
            .trim()
            .strip_suffix(" samples")
            .and_then(|n| n.parse().ok())
            .unwrap_or(usize::MAX);
        let list: Vec<DumpedSample> = samples
            .split(" / ")
            .filter(|s| !s.trim().is_empty())
            .map(|s| {
                s.split_whitespace()
                    .map(|cv| {
                        let (c, v) = cv.split_once('=').unwrap_or((cv, "?"));
                        let v: f32 = v
                            .parse()
                            .unwrap_or_else(|e| panic!("oiiotool printed {v:?}, not a float: {e}"));
                        (c.to_string(), v)
                    })
                    .collect()
            })
            .collect();
        assert_eq!(list.len(), n, "{line}");
        assert!(x < w && y < h, "{line}");
        let slot = &mut pixels[y * w + x];
        assert!(slot.is_none(), "pixel ({x}, {y}) printed twice");
        *slot = Some(list);
    }
    Some(
        pixels
            .into_iter()
            .enumerate()
            .map(|(p, s)| s.unwrap_or_else(|| panic!("oiiotool did not print pixel {p}")))
            .collect(),
    )
}

/// Run NanoVDB's converter, `nanovdb_convert -f ARGS SRC DST` (`.vdb` to `.nvdb` or back). A
/// missing tool fails the test, saying to install Debian's `libnanovdb-tools`.
pub fn nanovdb_convert(args: &[&str], src: &std::path::Path, dst: &std::path::Path) {
    let out = std::process::Command::new("nanovdb_convert")
        .arg("-f")
        .args(args)
        .arg(src)
        .arg(dst)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "nanovdb_convert could not be run ({e}): install Debian's libnanovdb-tools \
                 (apt-get install libnanovdb-tools); the .nvdb tests need NanoVDB's own converter"
            )
        });
    assert!(
        out.status.success() && dst.is_file(),
        "nanovdb_convert {args:?} {} failed: {}",
        src.display(),
        String::from_utf8_lossy(&out.stderr)
    );
}
