//! The layering ARCHITECTURE.md draws, held by the code: no module imports one of a higher
//! layer, and every module of `src/` has a layer. Read from the sources as text (every
//! `crate::NAME` path outside comments), so a new import that climbs fails here, in CI.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The layers from the bottom, with their modules (top-level modules of `src/`). A module may
/// import its own layer and those below it. ARCHITECTURE.md's table lists the same.
const LAYERS: &[(&str, &[&str])] = &[
    (
        "foundation",
        &[
            "error", "math", "text", "rng", "output", "memory", "progress",
        ],
    ),
    ("data", &["tree", "ray", "xform"]),
    ("input", &["input", "vdb", "nvdb", "usd"]),
    ("model", &["volume", "motion"]),
    ("traversal", &["traverse", "demand"]),
    (
        "answers",
        &["regular", "solid", "estimate", "scene", "light"],
    ),
    (
        "products",
        &["bake", "compare", "request", "batch", "info", "points"],
    ),
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

/// The top-level module a library file belongs to (`src/bake/trace/sweep/kernel.rs` -> `bake`).
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
    names_after(code, "crate::")
}

/// The first path segment after every `prefix` (`crate::`, `super::`) in `code`, every name of
/// a group (`prefix{a, b::c}` gives `a` and `b`).
fn names_after(code: &str, prefix: &str) -> BTreeSet<String> {
    let ident = |t: &str| -> String {
        t.trim()
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect()
    };
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices(prefix) {
        let after = &code[i + prefix.len()..];
        let names: Vec<String> = match after.strip_prefix('{') {
            Some(group) => group[..group.find('}').unwrap_or(group.len())]
                .split(',')
                .map(ident)
                .collect(),
            None => vec![ident(after)],
        };
        out.extend(names.into_iter().filter(|n| !n.is_empty()));
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

/// `pub use child::{a, b}` / `pub(crate) use child::a;` lines of a `mod.rs`: item -> child.
fn reexports(mod_rs: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let text = code(mod_rs);
    for stmt in text.split(';') {
        let s = stmt.trim();
        let Some(rest) = s
            .strip_prefix("pub use ")
            .or_else(|| s.strip_prefix("pub(crate) use "))
            .or_else(|| s.strip_prefix("pub(super) use "))
        else {
            continue;
        };
        let Some((child, items)) = rest.split_once("::") else {
            continue;
        };
        let items = items.trim().trim_start_matches('{').trim_end_matches('}');
        for item in items.split(',') {
            let name = item.trim().split(" as ").last().unwrap_or("").trim();
            if !name.is_empty() {
                out.push((name.to_string(), child.trim().to_string()));
            }
        }
    }
    out
}

/// The names a file takes from its parent module: `super::NAME` and `use super::{A, B}`.
fn super_names(code: &str) -> BTreeSet<String> {
    names_after(code, "super::")
}

/// No two files of one module import each other round a loop (`bake/output.rs` and
/// `bake/summary.rs` once did): within every directory of `src/`, a file naming a sibling
/// module or an item its parent re-exports from a sibling is an arrow to that sibling, and the
/// arrows have no cycle. Between top-level modules `no_import_climbs_a_layer` rules; within a
/// layer, the top-level modules have no cycle either.
#[test]
fn no_import_loops() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    // Arrows between sibling files, per directory with a mod.rs.
    let mut arrows: Vec<(String, String)> = Vec::new();
    for f in &files {
        // A `dir/mod.rs` is module `dir` among its parent's files; its `super` is the parent.
        let (dir, own) = if f.ends_with("mod.rs") {
            let d = f.parent().unwrap();
            (
                d.parent().unwrap(),
                d.file_name().unwrap().to_string_lossy().to_string(),
            )
        } else {
            (
                f.parent().unwrap(),
                f.file_stem().unwrap().to_string_lossy().to_string(),
            )
        };
        let mod_rs = dir.join("mod.rs");
        if !mod_rs.exists() || dir.starts_with(src.join("bin")) {
            continue;
        }
        let items = reexports(&std::fs::read_to_string(&mod_rs).unwrap());
        let text = code(&std::fs::read_to_string(f).unwrap());
        for name in super_names(&text) {
            let sibling = if dir.join(format!("{name}.rs")).exists()
                || dir.join(&name).join("mod.rs").exists()
            {
                Some(name.clone())
            } else {
                items
                    .iter()
                    .find(|(i, _)| *i == name)
                    .map(|(_, c)| c.clone())
            };
            if let Some(s) = sibling.filter(|s| *s != own) {
                let rel = |n: &str| format!("{}/{n}", dir.strip_prefix(&src).unwrap().display());
                arrows.push((rel(&own), rel(&s)));
            }
        }
    }
    // Arrows between top-level modules.
    for f in &files {
        let module = module_of(&src, f);
        if module == "bin" || module == "lib" {
            continue;
        }
        for target in crate_paths(&code(&std::fs::read_to_string(f).unwrap())) {
            if target != module && layer_of(&target).is_some() {
                arrows.push((module.clone(), target));
            }
        }
    }
    arrows.sort();
    arrows.dedup();
    assert!(arrows.len() > 60, "only {} arrows read", arrows.len());
    let loops = cycles(&arrows);
    assert!(loops.is_empty(), "import loops:\n{}", loops.join("\n"));
}

/// Every cycle of `arrows` (`a -> b`), each as `a -> ... -> a`: a node that reaches itself.
fn cycles(arrows: &[(String, String)]) -> Vec<String> {
    let next = |n: &str| -> Vec<String> {
        arrows
            .iter()
            .filter(|(a, _)| a == n)
            .map(|(_, b)| b.clone())
            .collect()
    };
    let mut loops = Vec::new();
    let nodes: BTreeSet<String> = arrows.iter().map(|(a, _)| a.clone()).collect();
    for start in &nodes {
        let mut seen = BTreeSet::new();
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        while let Some((n, path)) = stack.pop() {
            for m in next(&n) {
                if m == *start {
                    loops.push(path.join(" -> ") + " -> " + start);
                } else if seen.insert(m.clone()) {
                    let mut p = path.clone();
                    p.push(m.clone());
                    stack.push((m, p));
                }
            }
        }
    }
    loops
}

/// The Python module's files (`python/src`) import each other without a loop (issue 59: its
/// `volume.rs`, `functions.rs`, `trace.rs` and `motion.rs` once did): a file naming
/// `crate::SIBLING` is an arrow to that sibling, and the arrows have no cycle. What they all
/// share sits in `native.rs`, below them.
#[test]
fn no_import_loops_in_the_python_module() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/src");
    let arrows = python_arrows(&dir);
    assert!(
        arrows.len() >= 8,
        "only {} arrows read: {arrows:?}",
        arrows.len()
    );
    let loops = cycles(&arrows);
    assert!(
        loops.is_empty(),
        "import loops in python/src:\n{}",
        loops.join("\n")
    );
}

/// The arrows between the files of the Python module's crate in `dir`.
fn python_arrows(dir: &Path) -> Vec<(String, String)> {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    let stems: BTreeSet<String> = files
        .iter()
        .map(|f| f.file_stem().unwrap().to_string_lossy().to_string())
        .collect();
    let mut arrows = Vec::new();
    for f in &files {
        let own = f.file_stem().unwrap().to_string_lossy().to_string();
        for target in crate_paths(&code(&std::fs::read_to_string(f).unwrap())) {
            if target != own && stems.contains(&target) {
                arrows.push((own.clone(), target));
            }
        }
    }
    arrows.sort();
    arrows.dedup();
    arrows
}

/// The rooms of `bake`, by stage, from the bottom: what a map is and its camera; the two stages
/// that make and write a map (tracing and encoding, which never import each other); the
/// products that run them. A file may import its own room and those of lower stages
/// (ARCHITECTURE.md draws the same).
const BAKE_ROOMS: &[(&str, &[&str])] = &[
    ("vocabulary", &["map", "camera"]),
    ("stages", &["trace", "encode"]),
    ("products", &["product"]),
];

/// `pub use room::path::{a, b}` lines of `bake/mod.rs`: item -> room (the first segment).
fn room_reexports(mod_rs: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for stmt in code(mod_rs).split(';') {
        let s = stmt.trim();
        let Some(rest) = s
            .strip_prefix("pub use ")
            .or_else(|| s.strip_prefix("pub(crate) use "))
        else {
            continue;
        };
        let Some((room, path)) = rest.split_once("::") else {
            continue;
        };
        let list = match path.rfind('{') {
            Some(i) => &path[i + 1..],
            None => path.rsplit("::").next().unwrap_or(""),
        };
        for item in list.trim_end_matches('}').split(',') {
            let name = item.trim().split(" as ").last().unwrap_or("").trim();
            if !name.is_empty() {
                out.push((name.to_string(), room.trim().to_string()));
            }
        }
    }
    out
}

fn room_stage(room: &str) -> Option<usize> {
    BAKE_ROOMS.iter().position(|(_, rs)| rs.contains(&room))
}

#[test]
fn bake_rooms_keep_their_stages() {
    let bake = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/bake");
    let items = room_reexports(&std::fs::read_to_string(bake.join("mod.rs")).unwrap());
    assert!(items.len() > 50, "only {} re-exports read", items.len());
    let mut files = Vec::new();
    rust_files(&bake, &mut files);
    let mut wrong = Vec::new();
    let mut unplaced = BTreeSet::new();
    let mut seen = 0;
    for f in &files {
        let rel = f.strip_prefix(&bake).unwrap();
        if rel == Path::new("mod.rs") {
            continue;
        }
        let own = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        let Some(own_stage) = room_stage(&own) else {
            unplaced.insert(own);
            continue;
        };
        let text = code(&std::fs::read_to_string(f).unwrap());
        for name in names_after(&text, "crate::bake::") {
            // A room by name, or an item bake/mod.rs re-exports from a room.
            let room = if room_stage(&name).is_some() {
                name.clone()
            } else if let Some((_, r)) = items.iter().find(|(i, _)| *i == name) {
                r.clone()
            } else {
                continue;
            };
            seen += 1;
            let stage = room_stage(&room).unwrap();
            let sideways = own != room && stage == own_stage && own_stage == 1;
            if stage > own_stage || sideways {
                wrong.push(format!(
                    "bake/{} ({own}) imports crate::bake::{name} ({room})",
                    rel.display()
                ));
            }
        }
    }
    assert!(seen > 40, "only {seen} imports read");
    assert!(
        unplaced.is_empty(),
        "bake rooms without a stage: {unplaced:?}"
    );
    assert!(
        wrong.is_empty(),
        "imports against the stages:\n{}",
        wrong.join("\n")
    );
}

/// The library's sources, the binary's (`src/bin`) and the Python module's (`python/src`).
fn all_sources() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    let python = root.join("python/src");
    if python.is_dir() {
        rust_files(&python, &mut files);
    }
    files.sort();
    files
}

/// `file` relative to the repository, with `/` separators (`src/request.rs`).
fn rel(file: &Path) -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let r = file.strip_prefix(root).unwrap();
    r.components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect::<Vec<_>>()
        .join("/")
}

/// For each file, how often its code (comments and unit tests left out) holds any of `needles`,
/// outside `skip` (directories whose files may).
fn hits(needles: &[&str], skip: &[&str]) -> Vec<(String, usize)> {
    let mut out = Vec::new();
    for f in all_sources() {
        let r = rel(&f);
        if skip.iter().any(|d| r.starts_with(d)) {
            continue;
        }
        let text = code(&std::fs::read_to_string(&f).unwrap());
        let n: usize = needles.iter().map(|x| text.matches(x).count()).sum();
        if n > 0 {
            out.push((r, n));
        }
    }
    out
}

/// Hits against an allow-list of (file, count, why): a file not listed, or with another count,
/// fails (a stale entry too, so the list stays the truth).
fn check_allowed(found: &[(String, usize)], allowed: &[(&str, usize, &str)], what: &str) {
    let mut wrong = Vec::new();
    for (file, n) in found {
        match allowed.iter().find(|(f, _, _)| f == file) {
            Some((_, m, _)) if m == n => {}
            Some((_, m, why)) => wrong.push(format!("{file}: {n} (allowed {m}: {why})")),
            None => wrong.push(format!("{file}: {n}")),
        }
    }
    for (f, m, _) in allowed {
        if !found.iter().any(|(file, _)| file == f) {
            wrong.push(format!("{f}: none, allowed {m} (a stale entry: remove it)"));
        }
    }
    assert!(wrong.is_empty(), "{what}:\n{}", wrong.join("\n"));
}

/// What kind of input a path is (`.vdb`, `.toml` scene, USD stage) is decided in one place,
/// `src/input/` (`InputKind::of`): no other file of the library, the binary or the Python
/// module reads a path's extension or spells an input's extension in code. An output's
/// product is still decided where it is planned (the allow-list, each with its reason).
#[test]
fn one_place_classifies_inputs() {
    let needles = [
        ".extension()",
        "\"toml\"",
        "\"usda\"",
        "\"usdc\"",
        "\"usdz\"",
        "\"nvdb\"",
        "== \"vdb\"",
        "(\"vdb\")",
        "\".vdb\"",
        "\".toml\"",
        "\".usd",
        "\".nvdb\"",
    ];
    let allowed: &[(&str, usize, &str)] = &[
        (
            "src/request/mod.rs",
            2,
            "is_volume_output: an output ending in .vdb is a transmittance volume, the product \
             BakeRequest::plan picks",
        ),
        (
            "src/bake/product/pipeline/mod.rs",
            1,
            "check_extension: an output's format (.exr map, .png preview, .vdb volume), checked \
             with the other outputs before any work",
        ),
        (
            "src/batch/key.rs",
            2,
            "Stored::read: where an output's key is kept (a .vdb volume's metadata, a .json \
             positions file's member, else an EXR header), by the output's own format",
        ),
    ];
    let found = hits(&needles, &["src/input/"]);
    check_allowed(
        &found,
        allowed,
        "files outside src/input/ telling inputs apart by extension (ask \
         umbra::input::InputKind::of, or input::is_usda_layer for a usd_out layer)",
    );
}

/// The decision of what kind of input a path is, is made once, when its `input::Source` is
/// made (and when `GridFile::open` picks a reader, or the USD reader tells a package): only
/// `src/input/source.rs` and `src/input/grid_file.rs` call `InputKind::of`; every other file
/// of the library, the binary and the Python module asks a `Source` (`source.kind()`).
#[test]
fn a_source_decides_its_kind_once() {
    let found = hits(&["InputKind::of("], &[]);
    check_allowed(
        &found,
        &[
            (
                "src/input/source.rs",
                2,
                "Source::new decides a source's kind; is_package tells the USD reader a package",
            ),
            (
                "src/input/grid_file.rs",
                1,
                "GridFile::open picks the reader of a grid file's format",
            ),
        ],
        "files deciding an input's kind (make a umbra::input::Source and ask its kind())",
    );
}

/// A volume is set moving at one site, `scene::blurred` (which `Source::load` and a
/// transmittance volume's load call): no other file calls `Volume::with_motion`.
#[test]
fn one_site_sets_a_volume_moving() {
    let found = hits(&[".with_motion("], &[]);
    check_allowed(
        &found,
        &[(
            "src/scene/file.rs",
            1,
            "blurred: the velocity field read and the volume set moving",
        )],
        "files setting a volume moving (load a Source with the motion keys, or call \
         scene::blurred)",
    );
}

/// Nothing above the input layer opens a grid file but through `input::GridFile` (or
/// `input::load_grid`), so a new grid format is read everywhere once `GridFile` knows it.
#[test]
fn grid_files_open_through_the_input_layer() {
    let needles = [
        "vdb::open(",
        "vdb::load_grid(",
        "Archive::open(",
        ".open_lazy(",
        "NvdbFile::open(",
    ];
    let allowed: &[(&str, usize, &str)] = &[
        (
            "src/info/mod.rs",
            3,
            "the report on a .vdb archive or a .nvdb file itself (its header, descriptors, each \
             grid's compression and buffers, a NanoVDB grid's codec and checksum), which only the \
             readers have",
        ),
        (
            "src/info/map.rs",
            1,
            "a transmittance volume umbra wrote, described from its first grid's umbra:* \
             metadata (an output, not an input)",
        ),
        (
            "src/batch/key.rs",
            1,
            "the umbra:key metadata of a transmittance volume a task wrote (an output, not an \
             input)",
        ),
    ];
    // The model takes its grids from the input layer, and names no file format.
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/volume.rs");
    let model = code(&std::fs::read_to_string(model).unwrap());
    assert!(
        !model.contains("crate::vdb"),
        "src/volume.rs names crate::vdb: take grids from crate::input"
    );
    let found = hits(
        &needles,
        &["src/input/", "src/vdb/", "src/nvdb/", "src/usd/"],
    );
    check_allowed(
        &found,
        allowed,
        "files above the input layer opening grid files themselves (use umbra::input::GridFile)",
    );
}

/// The library's public surface: at most 14 public modules in `src/lib.rs` (the API a library
/// user needs, plus `internals`, the one hidden module for umbra's own sibling crates), every
/// other module crate-private, and every crate-private module reachable only through
/// `internals` under its own name. The library itself never goes through `internals`.
#[test]
fn the_public_surface_stays_small() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lib = std::fs::read_to_string(root.join("src/lib.rs")).unwrap();
    let decl = |prefix: &str| -> Vec<String> {
        lib.lines()
            .filter_map(|l| l.strip_prefix(prefix)?.strip_suffix(';'))
            .map(str::to_string)
            .collect()
    };
    let public = decl("pub mod ");
    let private = decl("mod ");
    assert!(
        public.len() < 14,
        "{} public modules and `internals` (at most 14): {public:?}",
        public.len()
    );
    assert!(
        private.len() >= 10,
        "only {} private modules read",
        private.len()
    );
    let files_of =
        |m: &str| root.join("src").join(m).is_dir() || root.join(format!("src/{m}.rs")).is_file();
    for m in public.iter().chain(&private) {
        assert!(files_of(m), "src/lib.rs declares `{m}`, which has no file");
    }
    for m in &private {
        if m == "memory" {
            continue; // allocator housekeeping: used by the library alone
        }
        assert!(
            lib.contains(&format!("pub mod {m} {{\n        pub use crate::{m}::*;")),
            "crate-private `{m}` is not reachable as `internals::{m}`"
        );
    }
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    for f in files {
        let r = rel(&f);
        if r.starts_with("src/bin/") {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        assert!(
            !code(&text).contains("internals::"),
            "{r} goes through `internals`: the library names its own modules"
        );
    }
}
