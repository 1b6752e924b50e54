//! docs/commands.md's flag reference is the CLI's own `--help`, rendered into the marked
//! section so it cannot drift from the binary: the test fails, printing the command that
//! regenerates it, when the file differs; `UMBRA_BLESS=1` (that command) rewrites the section.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use assert_cmd::Command;
use std::path::Path;

/// The commands whose `--help` the reference holds, in the README's order.
const COMMANDS: [&str; 6] = ["info", "query", "bake", "batch", "compare", "estimators"];
const BEGIN: &str = "<!-- BEGIN flag reference: generated from `umbra COMMAND --help` by \
                     tests/cli/commands_doc.rs; do not edit by hand -->";
const END: &str = "<!-- END flag reference -->";
const REGENERATE: &str =
    "UMBRA_BLESS=1 cargo test --profile quick --ignore-rust-version --test cli commands_doc";

/// `umbra COMMAND --help`, trailing spaces trimmed from each line.
fn help(command: &str) -> String {
    let o = Command::cargo_bin("umbra")
        .unwrap()
        .args([command, "--help"])
        .env_remove("COLUMNS")
        .env_remove("CLICOLOR_FORCE")
        .output()
        .unwrap();
    assert!(o.status.success(), "umbra {command} --help");
    let text = String::from_utf8(o.stdout).unwrap();
    text.lines()
        .map(str::trim_end)
        .collect::<Vec<_>>()
        .join("\n")
}

/// The generated section: one heading and one text block per command.
fn reference() -> String {
    let mut s = String::new();
    for c in COMMANDS {
        s.push_str(&format!(
            "### `umbra {c}`\n\n```text\n{}\n```\n\n",
            help(c).trim_end()
        ));
    }
    s
}

#[test]
fn commands_doc_is_the_clis_help() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/commands.md");
    let text = std::fs::read_to_string(&path).unwrap();
    let (head, rest) = text
        .split_once(BEGIN)
        .unwrap_or_else(|| panic!("docs/commands.md has no line '{BEGIN}'"));
    let (_, tail) = rest
        .split_once(END)
        .unwrap_or_else(|| panic!("docs/commands.md has no line '{END}'"));
    let want = format!("{head}{BEGIN}\n\n{}{END}{tail}", reference());
    if std::env::var_os("UMBRA_BLESS").is_some() {
        std::fs::write(&path, &want).unwrap();
        return;
    }
    assert!(
        text == want,
        "docs/commands.md's flag reference is not the CLI's --help: regenerate it with\n  {REGENERATE}"
    );
}
