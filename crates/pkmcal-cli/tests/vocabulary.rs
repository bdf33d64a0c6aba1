//! The option table of docs/cli.md is the CLI's vocabulary: every option it lists
//! is in the help of every command it names, and the old spellings it lists
//! are still read.

mod common;
use common::run;

/// Every command.
const COMMANDS: [&str; 15] = [
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

/// The old spellings are read (hidden from the help): a run with one gets as
/// far as reading its files, never "unexpected argument".
#[test]
fn old_spellings_still_work() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [&[&str]; 6] = [
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
    ];
    for args in cases {
        let o = run(dir.path(), args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "pkmcal {args:?}: {err}");
        assert!(err.contains("none."), "pkmcal {args:?}: {err}");
    }
}
