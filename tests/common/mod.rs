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
pub use umbra::batch::panic_message;
