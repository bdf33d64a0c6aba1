//! The README's walk-throughs run as written (issue 36, part 1): every
//! ```sh block after a `<!-- walkthrough -->` line is run with `sh`, in
//! order, from a scratch directory that sees the shipped `examples` (as the
//! README's set-up says), with this build's `pkmcal` first on the PATH; the
//! lines of the ```text block that follows it (those without "…", which
//! marks an elision) must appear in what the block printed.

use std::path::Path;

const README: &str = include_str!("../../../../README.md");

/// A walk-through block: the section it is in, its commands, and the output
/// shown after it.
struct Block {
    section: String,
    script: String,
    shown: Vec<String>,
}

fn blocks() -> Vec<Block> {
    let lines: Vec<&str> = README.lines().collect();
    let mut out = vec![];
    let mut section = String::new();
    let mut i = 0;
    while i < lines.len() {
        if lines[i].starts_with("## ") {
            section = lines[i][3..].to_string();
        }
        if lines[i].trim() == "<!-- walkthrough -->" {
            assert_eq!(
                lines[i + 1],
                "```sh",
                "a walk-through marker before a non-sh block"
            );
            let mut j = i + 2;
            let mut script = String::new();
            while lines[j] != "```" {
                script.push_str(lines[j]);
                script.push('\n');
                j += 1;
            }
            // The output shown next, if the next block is one.
            let mut k = j + 1;
            while k < lines.len() && lines[k].trim().is_empty() {
                k += 1;
            }
            let mut shown = vec![];
            if k < lines.len() && lines[k] == "```text" {
                k += 1;
                while lines[k] != "```" {
                    let l = lines[k].trim();
                    if !l.is_empty() && !l.contains('…') && !l.starts_with("$ ") {
                        shown.push(l.to_string());
                    }
                    k += 1;
                }
            }
            out.push(Block {
                section: section.clone(),
                script,
                shown,
            });
            i = j;
        }
        i += 1;
    }
    out
}

#[test]
fn the_readme_walkthroughs_run_as_written() {
    let bin = Path::new(env!("CARGO_BIN_EXE_pkmcal"));
    let path = format!(
        "{}:{}",
        bin.parent().unwrap().display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    let all = blocks();
    assert!(all.len() >= 6, "{} walk-through blocks", all.len());
    let mut dirs: Vec<(String, tempfile::TempDir)> = vec![];
    for b in &all {
        // One scratch directory per section, shared by its blocks in order.
        if dirs.last().is_none_or(|(s, _)| *s != b.section) {
            let d = tempfile::tempdir().unwrap();
            std::os::unix::fs::symlink(&examples, d.path().join("examples")).unwrap();
            dirs.push((b.section.clone(), d));
        }
        let d = dirs.last().unwrap().1.path();
        let out = std::process::Command::new("sh")
            .arg("-c")
            .arg(format!("set -e\n{}", b.script))
            .current_dir(d)
            .env("PATH", &path)
            .output()
            .expect("sh runs");
        let said = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(
            out.status.success(),
            "README, {}: the block\n{}\nfailed:\n{said}",
            b.section,
            b.script
        );
        for l in &b.shown {
            assert!(
                said.contains(l.as_str()),
                "README, {}: `{l}` is shown but the block printed:\n{said}",
                b.section
            );
        }
    }
}
