//! The option table of docs/cli.md is the CLI's vocabulary: every option it lists
//! is in the help of every command it names, no option stands for two
//! meanings, every option a command's help lists is in that command's
//! synopsis, and the old spellings it lists are still read.

use crate::common::run;

/// Every command.
const COMMANDS: [&str; 16] = [
    "budget",
    "drift",
    "predict",
    "simulate",
    "calibrate",
    "analyze",
    "compensate",
    "gcode",
    "plan",
    "montecarlo",
    "trilaterate",
    "parameters",
    "klipper",
    "reprap",
    "marlin",
    "demo",
];

/// The rows of docs/cli.md's table `| option | meaning | commands |`: the
/// options of the first cell and the commands of the third.
fn table() -> Vec<(Vec<String>, Vec<&'static str>)> {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/cli.md"))
        .expect("docs/cli.md");
    let start = readme
        .find("| option | meaning | commands |")
        .expect("the option table in docs/cli.md");
    let mut rows = vec![];
    for line in readme[start..].lines().skip(2) {
        if !line.starts_with('|') {
            break;
        }
        let cells: Vec<&str> = line.trim_matches('|').split(" | ").map(str::trim).collect();
        assert_eq!(cells.len(), 3, "option table (docs/cli.md) row: {line}");
        let ticked = |cell: &str| -> Vec<String> {
            cell.split('`')
                .skip(1)
                .step_by(2)
                .map(str::to_string)
                .collect()
        };
        let options: Vec<String> = ticked(cells[0])
            .iter()
            .filter_map(|t| t.split_whitespace().next().map(str::to_string))
            .filter(|t| t.starts_with("--"))
            .collect();
        let named: Vec<String> = ticked(cells[2]);
        let commands: Vec<&'static str> = if cells[2].starts_with("all but") {
            COMMANDS
                .into_iter()
                .filter(|c| !named.iter().any(|n| n == c))
                .collect()
        } else if cells[2] == "all" {
            COMMANDS.to_vec()
        } else {
            COMMANDS
                .into_iter()
                .filter(|c| named.iter().any(|n| n == c))
                .collect()
        };
        assert!(
            !options.is_empty() && !commands.is_empty(),
            "option table (docs/cli.md) row names no option or no command: {line}"
        );
        rows.push((options, commands));
    }
    assert!(
        rows.len() >= 10,
        "the option table (docs/cli.md) has {} rows",
        rows.len()
    );
    rows
}

#[test]
fn the_readme_option_table_holds_for_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let help: Vec<(&str, String)> = COMMANDS
        .iter()
        .map(|c| {
            let o = run(dir.path(), &[c, "--help"]);
            assert!(o.status.success(), "pkmcal {c} --help");
            (*c, String::from_utf8_lossy(&o.stdout).into_owned())
        })
        .collect();
    for (options, commands) in table() {
        for c in commands {
            let h = &help.iter().find(|(n, _)| *n == c).unwrap().1;
            for o in &options {
                let listed = h
                    .split(|ch: char| !(ch.is_ascii_alphanumeric() || ch == '-'))
                    .any(|w| w == o);
                assert!(
                    listed,
                    "docs/cli.md says `pkmcal {c}` takes {o}; its help does not list it"
                );
            }
        }
    }
}

/// One name, one meaning: no option is in two rows of the table.
#[test]
fn no_option_has_two_meanings() {
    let mut seen: Vec<String> = vec![];
    for (options, _) in table() {
        for o in options {
            assert!(
                !seen.contains(&o),
                "docs/cli.md's option table gives {o} two meanings (two rows)"
            );
            seen.push(o);
        }
    }
}

/// The synopsis of docs/cli.md: each command's text, from its `pkmcal
/// <command>` line to the next.
fn synopsis() -> Vec<(String, String)> {
    let doc = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../docs/cli.md"))
        .expect("docs/cli.md");
    let start = doc
        .find("```sh\npkmcal demo")
        .expect("the synopsis in docs/cli.md");
    let end = start + 5 + doc[start + 5..].find("```").expect("the synopsis ends");
    let mut out: Vec<(String, String)> = vec![];
    for line in doc[start + 6..end].lines() {
        if let Some(rest) = line.strip_prefix("pkmcal ") {
            let name = rest.split_whitespace().next().unwrap_or("").to_string();
            out.push((name, rest.to_string()));
        } else if let Some(last) = out.last_mut() {
            last.1.push(' ');
            last.1.push_str(line);
        }
    }
    out
}

/// Every option a command's help lists (but the global ones and `--help`)
/// is in its synopsis in docs/cli.md.
#[test]
fn every_option_of_every_help_is_documented() {
    let dir = tempfile::tempdir().unwrap();
    let syn = synopsis();
    for c in COMMANDS {
        let o = run(dir.path(), &[c, "--help"]);
        let help = String::from_utf8_lossy(&o.stdout).into_owned();
        let (_, text) = syn
            .iter()
            .find(|(n, _)| n == c)
            .unwrap_or_else(|| panic!("docs/cli.md's synopsis has no `pkmcal {c}`"));
        let words: Vec<&str> = text
            .split(|ch: char| !(ch.is_ascii_alphanumeric() || ch == '-'))
            .collect();
        for line in help.lines() {
            let Some(opt) = line
                .trim_start()
                .split([' ', ','])
                .find(|w| w.starts_with("--"))
            else {
                continue;
            };
            if ["--help", "--units", "--max-input-mb", "--quiet"].contains(&opt) {
                continue;
            }
            assert!(
                words.contains(&opt),
                "`pkmcal {c}` takes {opt} (its help lists it), but docs/cli.md's synopsis of {c} does not"
            );
        }
    }
}

/// The old spellings are read (hidden from the help): a run with one gets as
/// far as reading its files, never "unexpected argument".
#[test]
fn old_spellings_still_work() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [&[&str]; 14] = [
        &[
            "predict",
            "--commands",
            "none.csv",
            "--force",
            "0,0",
            "--out",
            "o.csv",
        ],
        &[
            "calibrate",
            "--data",
            "none.csv",
            "--force",
            "0,0",
            "--out",
            "o.toml",
        ],
        &["analyze", "--data", "none.csv", "--force", "0,0"],
        &[
            "predict",
            "--commands",
            "none.csv",
            "--out",
            "o.csv",
            "--quiet",
        ],
        &[
            "montecarlo",
            "--poses",
            "none.csv",
            "--offset-error",
            "0.001",
            "--quiet",
        ],
        &["klipper", "--config", "none.cfg", "--quiet"],
        &["analyze", "--data", "none.csv", "--noise", "0.001"],
        &["analyze", "--data", "none.csv", "--angle-noise", "0.001"],
        &[
            "plan",
            "--count",
            "20",
            "--candidates",
            "10",
            "--noise",
            "0.001",
            "--params",
            "none.toml",
            "--out",
            "p.csv",
        ],
        &["montecarlo", "--poses", "none.csv", "--validation", "10"],
        &[
            "trilaterate",
            "--setup",
            "none.toml",
            "--data",
            "none.csv",
            "--sigma",
            "0.001",
            "--out",
            "o.csv",
        ],
        &[
            "gcode",
            "--params",
            "none.toml",
            "--in",
            "none.gcode",
            "--out",
            "o.gcode",
        ],
        &[
            "compensate",
            "--params",
            "none.toml",
            "--grid",
            "x=0:1:1",
            "--out",
            "o.csv",
        ],
        &[
            "budget",
            "--poses",
            "none.csv",
            "--noise",
            "0.001",
            "--tolerance",
            "l11=0.1",
        ],
    ];
    for args in cases {
        let o = run(dir.path(), args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "pkmcal {args:?}: {err}");
        assert!(err.contains("none."), "pkmcal {args:?}: {err}");
    }
}

/// Every relative link of the README and the docs resolves from the file it
/// is in (issue 50: docs/cli.md and docs/formats.md linked
/// `examples/…` and `docs/model.md` from inside docs/).
#[test]
fn relative_links_in_the_docs_resolve() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut files: Vec<std::path::PathBuf> = ["README.md", "CHANGELOG.md", "BENCHMARKS.md"]
        .iter()
        .map(|f| root.join(f))
        .collect();
    for e in std::fs::read_dir(root.join("docs")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "md") {
            files.push(p);
        }
    }
    let mut broken = vec![];
    let mut checked = 0;
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let dir = f.parent().unwrap();
        for (at, _) in text.match_indices("](") {
            let rest = &text[at + 2..];
            let Some(end) = rest.find(')') else { continue };
            let target = rest[..end].split('#').next().unwrap();
            if target.is_empty()
                || target.contains(char::is_whitespace)
                || target.contains("://")
                || target.starts_with("mailto:")
            {
                continue;
            }
            checked += 1;
            if !dir.join(target).exists() {
                broken.push(format!("{}: {target}", f.display()));
            }
        }
    }
    assert!(checked > 20, "only {checked} links found");
    assert!(broken.is_empty(), "broken links: {broken:#?}");
}
