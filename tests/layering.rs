//! The layering ARCHITECTURE.md draws, held by the code: no module imports one of a higher
//! layer, and every module of `src/` has a layer. Read from the sources as text (every
//! `crate::NAME` path outside comments), so a new import that climbs fails here, in CI.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers from the bottom, with their modules (top-level modules of `src/`). A module may
/// import its own layer and those below it. ARCHITECTURE.md's table lists the same.
const LAYERS: &[(&str, &[&str])] = &[
    ("foundation", &["error", "math", "text", "rng", "output"]),
    ("data", &["tree", "ray", "xform"]),
    ("input", &["vdb"]),
    ("model", &["volume"]),
    ("traversal", &["traverse", "demand"]),
    (
        "answers",
        &["regular", "solid", "estimate", "scene", "light"],
    ),
    ("products", &["bake", "compare", "batch", "info"]),
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, ms)| ms.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a library file belongs to (`src/bake/sweep/kernel.rs` -> `bake`).
fn module_of(src: &Path, file: &Path) -> String {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel
        .components()
        .next()
        .unwrap()
        .as_os_str()
        .to_string_lossy();
    first.trim_end_matches(".rs").to_string()
}

/// Code without comments (line comments and doc comments: links in docs are not imports) and
/// without its unit tests (from the first `#[cfg(test)]` on: a test may check a lower module
/// against a higher one, as hdda's does against regular tracking).
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Every `crate::NAME` the code names.
fn crate_paths(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        let name: String = after
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        // `use crate::{a, b}`: every name of the group.
        if after.starts_with('{') {
            let group = &after[1..after.find('}').unwrap_or(after.len())];
            for n in group.split(',') {
                let n: String = n
                    .trim()
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if !n.is_empty() {
                    out.insert(n);
                }
            }
        } else if !name.is_empty() {
            out.insert(name);
        }
        rest = &rest[i + 1..];
    }
    out
}

#[test]
fn no_import_climbs_a_layer() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut climbs = Vec::new();
    let mut unplaced = BTreeSet::new();
    let mut seen = 0;
    for f in &files {
        let module = module_of(&src, f);
        if module == "bin" || module == "lib" {
            continue; // the front end: above every layer
        }
        let Some(own) = layer_of(&module) else {
            unplaced.insert(module);
            continue;
        };
        let text = std::fs::read_to_string(f).unwrap();
        for target in crate_paths(&code(&text)) {
            let Some(t) = layer_of(&target) else {
                // Items re-exported at the crate root (`crate::Error`, `crate::Result`).
                continue;
            };
            seen += 1;
            if t > own {
                climbs.push(format!(
                    "{} ({}, layer {}) imports crate::{target} (layer {})",
                    f.strip_prefix(&src).unwrap().display(),
                    module,
                    LAYERS[own].0,
                    LAYERS[t].0
                ));
            }
        }
    }
    assert!(seen > 100, "only {seen} imports read");
    assert!(
        unplaced.is_empty(),
        "modules without a layer (add them to LAYERS and ARCHITECTURE.md): {unplaced:?}"
    );
    assert!(
        climbs.is_empty(),
        "imports that climb:\n{}",
        climbs.join("\n")
    );
}
