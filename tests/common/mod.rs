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

/// Whether the transmittance volume a batch task wrote (`batch`) is the file `umbra bake`
/// wrote for the same request (`cli`) but for the task's `umbra:key` metadata entry: byte for
/// byte once the entry is cut out (and the grid's offsets moved back), apart from the file's
/// UUID (36 characters at byte 21), which umbra derives from the content.
pub fn same_volume_but_key(batch: &std::path::Path, cli: &std::path::Path) -> bool {
    let uuid = 21..57;
    let mut a = vdb_without_key(batch);
    let mut b = std::fs::read(cli).unwrap();
    if a.len() != b.len() || a.len() < uuid.end {
        return false;
    }
    a[uuid.clone()].fill(0);
    b[uuid].fill(0);
    a == b
}

/// A transmittance volume a batch task wrote, without the `umbra:key` metadata entry its task
/// added (and with the grid's offsets moved back). A file without the entry is returned as it
/// is.
pub fn vdb_without_key(path: &std::path::Path) -> Vec<u8> {
    let mut bytes = std::fs::read(path).unwrap();
    let archive = umbra::internals::vdb::open(path).unwrap();
    let gd = &archive.grids[0];
    let name = b"umbra:key";
    let mut pattern = (name.len() as u32).to_le_bytes().to_vec();
    pattern.extend_from_slice(name);
    let Some(at) = bytes
        .windows(pattern.len())
        .position(|w| w == pattern.as_slice())
    else {
        return bytes;
    };
    let u32_at = |b: &[u8], i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap()) as usize;
    let type_at = at + 4 + name.len();
    let value_at = type_at + 4 + u32_at(&bytes, type_at);
    let end = value_at + 4 + u32_at(&bytes, value_at);
    let cut = (end - at) as u64;
    bytes.drain(at..end);
    // The grid's metadata count (after its compression flags at grid_pos).
    let count_at = gd.grid_pos as usize + 4;
    let count = u32_at(&bytes, count_at) as u32 - 1;
    bytes[count_at..count_at + 4].copy_from_slice(&count.to_le_bytes());
    // Its descriptor's block and end offsets, stored one after the other before the grid.
    let mut offsets = gd.block_pos.to_le_bytes().to_vec();
    offsets.extend_from_slice(&gd.end_pos.to_le_bytes());
    let o = bytes[..gd.grid_pos as usize]
        .windows(16)
        .position(|w| w == offsets.as_slice())
        .unwrap();
    bytes[o..o + 8].copy_from_slice(&(gd.block_pos - cut).to_le_bytes());
    bytes[o + 8..o + 16].copy_from_slice(&(gd.end_pos - cut).to_le_bytes());
    bytes
}

/// The answer to the one ray a query asks about (`at`, a segment); a query that answered
/// points, or an error, fails the test.
pub fn one_answer(r: &umbra::request::QueryRequest) -> umbra::request::Answered {
    let umbra::request::QueryOutcome::Rays(a) = r.run(&mut |_| {}).unwrap() else {
        panic!("a query of one ray answered points")
    };
    a.answers[0].result.clone().unwrap()
}
