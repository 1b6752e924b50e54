//! The README's Rust example is `examples/readme.rs` verbatim (its `main` and imports), and
//! that example runs and prints the transmittance it promises.
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
    // test` builds the examples of its profile beside the test binaries: a test cannot call
    // cargo, which holds the build directory while the tests run).
    let target =
        std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), Into::into);
    let profile = if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    };
    let exe = Path::new(&target).join(profile).join("examples/readme");
    if !exe.exists() {
        // A filtered `cargo test --test readme` builds no examples; the whole suite (CI) does.
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
