//! The README's Rust example is `examples/readme.rs` verbatim (its `main` and imports), and
//! that example runs and prints the transmittance it promises.
//! ARCHITECTURE.md keeps short lines and its links to its own headings resolve.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

#[test]
fn readme_rust_example_is_the_example_and_runs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let section = readme.split("## Rust library").nth(1).unwrap();
    let block = section
        .split("```rust\n")
        .nth(1)
        .unwrap()
        .split("```")
        .next()
        .unwrap();
    let example = std::fs::read_to_string(root.join("examples/readme.rs")).unwrap();
    let code: String = example
        .lines()
        .skip_while(|l| l.starts_with("//!") || l.is_empty())
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(
        block, code,
        "the README's Rust example differs from examples/readme.rs"
    );
    // Run it from the repository, as `cargo run --release --example readme` does (`cargo
    // test` builds the examples of its profile beside the test binaries, in the profile's
    // directory, the parent of this binary's `deps/`: a test cannot call cargo, which holds the
    // build directory while the tests run).
    let this = std::env::current_exe().unwrap();
    let profile_dir = this.parent().and_then(Path::parent).unwrap();
    let exe = profile_dir.join("examples/readme");
    if !exe.exists() {
        // A filtered `cargo test --test library` builds no examples; the whole suite (CI) does.
        assert!(
            std::env::var_os("CI").is_none(),
            "{} is not built (cargo test builds examples)",
            exe.display()
        );
        eprintln!("{} is not built: run the whole suite", exe.display());
        return;
    }
    let o = std::process::Command::new(&exe)
        .current_dir(root)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2, "{out}");
    assert!(
        lines[0].starts_with("T = ") && lines[0].contains("tau = Some("),
        "{out}"
    );
    assert!(lines[1].contains(" +- "), "{out}");
}

/// The README's install lists are what a fresh machine needs: its `apt-get install` (and
/// docs/testing.md's) names the Debian packages `.ci/run` installs, and it names every package `python/run_tests.sh` takes
/// from PyPI.
#[test]
fn readme_install_lists_match_what_ci_installs() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let read = |p: &str| std::fs::read_to_string(root.join(p)).unwrap();
    // The words of a shell command starting at `start`, over its `\` continuations.
    let command = |text: &str, start: &str| -> Vec<String> {
        let at = text.find(start).unwrap_or_else(|| panic!("no '{start}'"));
        let mut words = Vec::new();
        for line in text[at + start.len()..].lines() {
            let body = line.trim_end();
            let cont = body.ends_with('\\');
            words.extend(
                body.trim_end_matches('\\')
                    .split_whitespace()
                    .filter(|w| !w.starts_with('-') && !w.starts_with('>') && !w.starts_with('$'))
                    .map(str::to_string),
            );
            if !cont {
                break;
            }
        }
        words
    };
    let mut ci = command(&read(".ci/run"), "apt-get install");
    let mut readme = command(&read("README.md"), "sudo apt-get install");
    ci.sort();
    readme.sort();
    assert_eq!(readme, ci, "README's apt-get list vs .ci/run's");
    let mut testing = command(&read("docs/testing.md"), "sudo apt-get install");
    testing.sort();
    assert_eq!(testing, ci, "docs/testing.md's apt-get list vs .ci/run's");
    let readme_text = read("README.md");
    let pip = command(
        &read("python/run_tests.sh"),
        "pip install -q \"$repo/python\"",
    );
    for p in pip {
        let name = p
            .trim_matches('"')
            .split(['>', '=', '<'])
            .next()
            .unwrap()
            .to_string();
        assert!(
            readme_text.contains(&format!("`{name}`")) || readme_text.contains(&name),
            "README does not name {name}, which python/run_tests.sh installs"
        );
    }
}

/// ARCHITECTURE.md stays short prose and tables (issue 59): no line over 400 characters (a
/// table row that long is a section's worth of prose in one cell), and every link to one of
/// its own headings (`](#anchor)`) names a heading it has, by GitHub's anchor rules.
#[test]
fn architecture_has_short_lines_and_its_anchors_resolve() {
    const LIMIT: usize = 400;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("ARCHITECTURE.md")).unwrap();
    let long: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.chars().count()))
        .filter(|&(_, n)| n > LIMIT)
        .map(|(line, n)| format!("line {line}: {n} characters"))
        .collect();
    assert!(
        long.is_empty(),
        "ARCHITECTURE.md has lines over {LIMIT} characters:\n{}",
        long.join("\n")
    );
    // GitHub's anchor of a heading: lower case, punctuation but `-` and `_` dropped, spaces
    // to `-` (a repeated heading's `-1` suffix is not needed here: none repeats).
    let mut in_code = false;
    let mut anchors = Vec::new();
    for line in text.lines() {
        if line.starts_with("```") {
            in_code = !in_code;
        } else if !in_code && line.starts_with('#') {
            let title = line.trim_start_matches('#').trim();
            let anchor: String = title
                .chars()
                .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
                .map(|c| if c == ' ' { '-' } else { c })
                .collect::<String>()
                .to_lowercase();
            anchors.push(anchor);
        }
    }
    let mut missing = Vec::new();
    for (i, line) in text.lines().enumerate() {
        for link in line.split("](#").skip(1) {
            let anchor = link.split(')').next().unwrap_or("");
            if !anchors.iter().any(|a| a == anchor) {
                missing.push(format!("line {}: #{anchor}", i + 1));
            }
        }
    }
    assert!(
        missing.is_empty(),
        "ARCHITECTURE.md links to headings it does not have:\n{}",
        missing.join("\n")
    );
}
