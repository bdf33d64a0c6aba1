//! Bad input never hurts (issue 4): every malformed file gets a message naming
//! the file and line (or pose), exit code 1 for bad data and 2 for bad usage,
//! and no clobbered output.

use crate::common::{fails, ok, run};

const GOOD: &str = "q1,q2,q3\n1.4614,3.5609,-2.5939\n";

#[test]
fn malformed_csv_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases: [(&str, &str, &str); 8] = [
        (
            "long.csv",
            "q1,q2,q3\n1.46,3.56,-2.59\n1,46,3.56,-2.59\n",
            "long.csv:3: 4 fields, but the header names 3 columns (q1, q2, q3, separated by commas); name every column in the header, and write decimals with a point",
        ),
        (
            "dup.csv",
            "q1,q2,q3,q2\n1.46,3.56,-2.59,3.56\n",
            "column `q2` appears 2 times",
        ),
        (
            "word.csv",
            "q1,q2,q3\n1.46,abc,-2.59\n",
            "word.csv:2: column `q2`: `abc` is not a number",
        ),
        ("inf.csv", "q1,q2,q3\n1.46,inf,-2.59\n", "word.csv"),
        (
            "short.csv",
            "q1,q2,q3\n1.46,3.56\n",
            "short.csv:2: the row is short",
        ),
        ("empty.csv", "", "empty.csv: the file is empty"),
        ("header.csv", "q1,q2,q3\n", "header.csv: no data rows"),
        ("quote.csv", "q1,q2,q3\n\"1.46,3.56,-2.59\n", "quote.csv"),
    ];
    for (name, text, needle) in cases {
        std::fs::write(d.join(name), text).unwrap();
        let needle = if name == "inf.csv" {
            "inf.csv:2: column `q2`: `inf` is not a finite number"
        } else {
            needle
        };
        fails(
            d,
            &["predict", "--commands", name, "--out", "o.csv"],
            1,
            needle,
        );
    }
    assert!(!d.join("o.csv").exists(), "nothing written on failure");
    // A trailing separator is no field.
    std::fs::write(
        d.join("trailing.csv"),
        "q1,q2,q3,\n1.4614,3.5609,-2.5939,\n",
    )
    .unwrap();
    ok(
        d,
        &["predict", "--commands", "trailing.csv", "--out", "o.csv"],
    );
    // Files read whole keep the same rule: a hand-written heights file.
    let cfg = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/klipper-delta/printer.cfg");
    std::fs::write(
        d.join("heights.csv"),
        "x,y,z,tool,surface\n0,0,0.013,nozzle,0.1\n0,45,-0.036,nozzle,0.1,0.02\n",
    )
    .unwrap();
    fails(
        d,
        &[
            "klipper",
            "--config",
            cfg.to_str().unwrap(),
            "--physical",
            "--heights",
            "heights.csv",
        ],
        1,
        "heights.csv:3: 6 fields, but the header names 5 columns (x, y, z, tool, surface, separated by commas)",
    );
}

#[test]
fn malformed_parameter_and_mechanism_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.csv"), GOOD).unwrap();
    let params: [(&str, &str); 4] = [
        (
            "l11 = \"long\"\n",
            "parameter `l11` must be a number, found string",
        ),
        ("L11 = 280.0\n", "unknown parameter `L11`"),
        ("k1 = 0\n", "stiffness must be positive"),
        ("[l11]\nx = 1\n", "unknown parameter `l11.x`"),
    ];
    for (text, needle) in params {
        std::fs::write(d.join("p.toml"), text).unwrap();
        fails(
            d,
            &[
                "predict",
                "--params",
                "p.toml",
                "--commands",
                "c.csv",
                "--out",
                "o.csv",
            ],
            1,
            needle,
        );
    }
    let mechs: [(&str, &str); 6] = [
        ("type = \"hexapod\"\n", "unknown mechanism type `hexapod`"),
        (
            "type = \"jeong-kim-2dof\"\n[nominal]\nk2 = -5.0\n",
            "stiffness must be positive",
        ),
        (
            "type = \"jeong-kim-2dof\"\n[nominal]\nl11 = 20.0\nl12 = 20.0\n",
            "does not close",
        ),
        (
            "type = \"jeong-kim-2dof\"\nextra = 1\n",
            "unknown field `extra`",
        ),
        (
            "type = \"jeong-kim-2dof\"\n[workspace]\nx = [5.0, -5.0]\n",
            "min < max",
        ),
        (
            "type = \"jeong-kim-2dof\"\n[nominal]\nD1 = 0\n",
            "must be positive",
        ),
    ];
    for (text, needle) in mechs {
        std::fs::write(d.join("m.toml"), text).unwrap();
        fails(
            d,
            &[
                "predict",
                "--mechanism",
                "m.toml",
                "--commands",
                "c.csv",
                "--out",
                "o.csv",
            ],
            1,
            needle,
        );
        let err = String::from_utf8_lossy(
            &run(
                d,
                &[
                    "predict",
                    "--mechanism",
                    "m.toml",
                    "--commands",
                    "c.csv",
                    "--out",
                    "o.csv",
                ],
            )
            .stderr,
        )
        .into_owned();
        assert!(err.contains("m.toml"), "the message names the file: {err}");
    }
}

#[test]
fn impossible_requests() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A singular target: leg 1 fully stretched.
    std::fs::write(d.join("t.csv"), "target_x,target_y\n-300,559.999\n").unwrap();
    let o = run(d, &["compensate", "--targets", "t.csv", "--out", "c.csv"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("t.csv:2"));
    // Commands that cannot be assembled, in calibration data: the pose is named.
    ok(d, &["simulate", "--grid", "12", "--out", "g.csv"]);
    let mut text = std::fs::read_to_string(d.join("g.csv")).unwrap();
    text.push_str("0,0,0,3,1,0,0\n");
    std::fs::write(d.join("bad.csv"), text).unwrap();
    fails(
        d,
        &["calibrate", "--data", "bad.csv", "--out", "p.toml"],
        1,
        "pose 13",
    );
    // Standard deviations must be positive.
    ok(d, &["simulate", "--grid", "20", "--out", "s.csv"]);
    let text = std::fs::read_to_string(d.join("s.csv")).unwrap();
    let mut lines: Vec<String> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(String::from)
        .collect();
    lines[0].push_str(",sigma");
    for (i, l) in lines.iter_mut().enumerate().skip(1) {
        l.push_str(if i == 3 { ",0" } else { ",0.002" });
    }
    std::fs::write(d.join("sig.csv"), lines.join("\n")).unwrap();
    fails(
        d,
        &["calibrate", "--data", "sig.csv", "--out", "p.toml"],
        1,
        "sig.csv:4: standard deviations must be positive",
    );
    // Usage errors exit with 2.
    fails(d, &["calibrate", "--data", "s.csv"], 2, "--out");
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "s.csv",
            "--loss",
            "tukey",
            "--out",
            "p.toml",
        ],
        2,
        "tukey",
    );
    fails(d, &["frobnicate"], 2, "frobnicate");
    assert!(!d.join("p.toml").exists());
}

#[test]
fn line_numbers_are_right_with_crlf_comments_and_blank_lines() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("crlf.csv"),
        "q1,q2,q3\r\n1.4614,3.5609,-2.5939\r\n1.46,abc,-2.59\r\n",
    )
    .unwrap();
    fails(
        d,
        &["predict", "--commands", "crlf.csv", "--out", "o.csv"],
        1,
        "crlf.csv:3: column `q2`",
    );
    std::fs::write(
        d.join("com.csv"),
        "q1,q2,q3\n# note\n\n1.4614,3.5609,-2.5939\n# x\n1.46,abc,-2.59\n",
    )
    .unwrap();
    fails(
        d,
        &["predict", "--commands", "com.csv", "--out", "o.csv"],
        1,
        "com.csv:6: column `q2`",
    );
    std::fs::write(
        d.join("t.csv"),
        "target_x,target_y\r\n0,180\r\n# far\r\n900,900\r\n",
    )
    .unwrap();
    fails(
        d,
        &["compensate", "--targets", "t.csv", "--out", "c.csv"],
        1,
        "t.csv:4:",
    );
}

#[test]
fn a_typo_in_the_ballbar_table_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let reference = format!(
        "{}/../../examples/jeong-kim-2dof/mechanism.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let mut text = std::fs::read_to_string(reference).unwrap();
    text.push_str("\n[ballbar]\nbar_ofset = 0.0\nsockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n");
    std::fs::write(d.join("m.toml"), text).unwrap();
    std::fs::write(
        d.join("s.toml"),
        "sockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate", "--grid", "10", "--setup", "s.toml", "--out", "bb.csv",
        ],
    );
    fails(
        d,
        &[
            "calibrate",
            "--mechanism",
            "m.toml",
            "--data",
            "bb.csv",
            "--out",
            "p.toml",
        ],
        1,
        "unknown field `bar_ofset`",
    );
}

/// Spreadsheet exports: semicolons with decimal commas, tabs, headers in
/// another case; a near-miss header gets a "did you mean".
#[test]
fn spreadsheet_exports_are_read() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    crate::common::ok(
        d,
        &[
            "simulate", "--grid", "30", "--noise", "0.002", "--out", "d.csv",
        ],
    );
    let text = std::fs::read_to_string(d.join("d.csv")).unwrap();
    let semi: String = text
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                l.to_string()
            } else {
                l.replace(',', ";")
                    .replace('.', ",")
                    .replace("target_x", "TARGET_X")
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(d.join("semi.csv"), semi + "\n").unwrap();
    crate::common::ok(d, &["calibrate", "--data", "d.csv", "--out", "a.toml"]);
    crate::common::ok(d, &["calibrate", "--data", "semi.csv", "--out", "b.toml"]);
    let params = |f: &str| -> Vec<String> {
        std::fs::read_to_string(d.join(f))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(String::from)
            .collect()
    };
    assert_eq!(params("a.toml"), params("b.toml"));
    // Whitespace-separated (numpy.savetxt, instrument logs): runs of blanks,
    // aligned columns, leading blanks; read by the whole-file reader.
    let spaced: String = text
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                l.to_string()
            } else {
                format!("  {}  ", l.replace(',', " \t  "))
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(d.join("spaced.txt"), spaced + "\n").unwrap();
    crate::common::ok(d, &["calibrate", "--data", "spaced.txt", "--out", "c.toml"]);
    assert_eq!(params("a.toml"), params("c.toml"));
    // ... and by the streamed one, decimal commas included.
    std::fs::write(d.join("ws.txt"), "q1 q2   q3\n 1,46  3,56 -2,59\n").unwrap();
    std::fs::write(d.join("cs.csv"), "q1,q2,q3\n1.46,3.56,-2.59\n").unwrap();
    let ws = crate::common::ok(d, &["predict", "--commands", "ws.txt", "--out", "-"]);
    let cs = crate::common::ok(d, &["predict", "--commands", "cs.csv", "--out", "-"]);
    assert_eq!(ws, cs);
    std::fs::write(d.join("tab.csv"), "Q1\tQ2\tQ3\n1.46\t3.56\t-2.59\n").unwrap();
    let out = crate::common::ok(d, &["predict", "--commands", "tab.csv", "--out", "-"]);
    assert_eq!(out.lines().count(), 2, "{out}");
    // A missing column names how the fields were separated.
    std::fs::write(d.join("semi-bad.csv"), "a;q2;q3\n1,46;3,56;-2,59\n").unwrap();
    crate::common::fails(
        d,
        &["predict", "--commands", "semi-bad.csv", "--out", "x.csv"],
        1,
        "missing column `q1` (columns found, separated by semicolons: a, q2, q3)",
    );
    std::fs::write(d.join("typo.csv"), "q_1,q2,q3\n1.46,3.56,-2.59\n").unwrap();
    crate::common::fails(
        d,
        &["predict", "--commands", "typo.csv", "--out", "x.csv"],
        1,
        "missing column `q1`; did you mean `q_1`?",
    );
}

/// The files the README promises to read: single-space separated (numpy's
/// `savetxt`), a byte order mark before a comment line, upper-case headers
/// (`sigma_X` too). Each gives the same calibration, bit for bit, as the
/// comma-separated file it was made from; the streamed reader (`predict`)
/// reads them too. Headers that differ only in case are refused by name.
#[test]
fn files_as_users_write_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(
        d,
        &[
            "simulate", "--grid", "20", "--noise", "0.002", "--out", "data.csv",
        ],
    );
    let text = std::fs::read_to_string(d.join("data.csv")).unwrap();
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    // A σ column per axis, to check upper-case σ columns.
    let with_sigma: Vec<String> = lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            if i == 0 {
                format!("{l},sigma_x")
            } else {
                format!("{l},0.002")
            }
        })
        .collect();
    std::fs::write(d.join("comma.csv"), with_sigma.join("\n") + "\n").unwrap();
    let spaced: Vec<String> = with_sigma.iter().map(|l| l.replace(',', " ")).collect();
    std::fs::write(d.join("space.csv"), spaced.join("\n") + "\n").unwrap();
    std::fs::write(
        d.join("bom.csv"),
        format!(
            "\u{feff}# exported by a spreadsheet\n{}\n",
            with_sigma.join("\n")
        ),
    )
    .unwrap();
    let mut upper = with_sigma.clone();
    upper[0] = upper[0].to_uppercase();
    std::fs::write(d.join("upper.csv"), upper.join("\n") + "\n").unwrap();
    ok(
        d,
        &["calibrate", "--data", "comma.csv", "--out", "comma.toml"],
    );
    let want = std::fs::read_to_string(d.join("comma.toml")).unwrap();
    for f in ["space.csv", "bom.csv", "upper.csv"] {
        ok(d, &["calibrate", "--data", f, "--out", "p.toml"]);
        let got = std::fs::read_to_string(d.join("p.toml")).unwrap();
        // The header comment names the data file; the values are the same.
        let values = |t: &str| -> Vec<String> {
            t.lines()
                .filter(|l| !l.starts_with('#'))
                .map(String::from)
                .collect()
        };
        assert_eq!(values(&got), values(&want), "{f}");
        ok(d, &["predict", "--commands", f, "--out", "pred.csv"]);
    }
    // Names that differ only in case: which is meant is not guessed.
    let mut both = with_sigma.clone();
    both[0] = both[0].replace("target_x", "X");
    std::fs::write(d.join("both.csv"), both.join("\n") + "\n").unwrap();
    fails(
        d,
        &["calibrate", "--data", "both.csv", "--out", "p.toml"],
        1,
        "differ only in case",
    );
}

/// A data file pkmcal wrote in other units names them on its first line,
/// and is read back by that line, without options; `--units` still wins,
/// with a note where it disagrees with the line.
#[test]
fn a_file_written_with_units_is_read_back_without_options() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(
        d,
        &[
            "simulate",
            "--grid",
            "20",
            "--noise",
            "0.002",
            "--units",
            "angle=deg,length=m",
            "--out",
            "data.csv",
        ],
    );
    assert!(
        std::fs::read_to_string(d.join("data.csv"))
            .unwrap()
            .contains("# units: angles in deg, lengths in m")
    );
    ok(
        d,
        &["calibrate", "--data", "data.csv", "--out", "bare.toml"],
    );
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--units",
            "angle=deg,length=m",
            "--out",
            "given.toml",
        ],
    );
    let values = |f: &str| -> Vec<String> {
        std::fs::read_to_string(d.join(f))
            .unwrap()
            .lines()
            .filter(|l| !l.starts_with('#'))
            .map(String::from)
            .collect()
    };
    assert_eq!(values("bare.toml"), values("given.toml"));
    // The streamed reader, too: the commands in degrees, the output in the
    // run's units (here mm and rad).
    ok(
        d,
        &["predict", "--commands", "data.csv", "--out", "pred.csv"],
    );
    // An option that disagrees wins, and says so.
    let o = run(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--units",
            "angle=rad",
            "--out",
            "p.toml",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("data.csv says angles in deg (given: rad)"),
        "{err}"
    );
    // A units line pkmcal does not write is refused, naming file and line.
    std::fs::write(
        d.join("odd.csv"),
        std::fs::read_to_string(d.join("data.csv"))
            .unwrap()
            .replace("angles in deg", "angles in grad"),
    )
    .unwrap();
    fails(
        d,
        &["calibrate", "--data", "odd.csv", "--out", "p.toml"],
        1,
        "odd.csv:2:",
    );
}
