//! Bad input never hurts (issue 4): every malformed file gets a message naming
//! the file and line (or pose), exit code 1 for bad data and 2 for bad usage,
//! and no clobbered output.

mod common;
use common::{fails, ok, run};

const GOOD: &str = "q1,q2,q3\n1.4614,3.5609,-2.5939\n";

#[test]
fn malformed_csv_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cases: [(&str, &str, &str); 7] = [
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
    common::ok(
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
    common::ok(d, &["calibrate", "--data", "d.csv", "--out", "a.toml"]);
    common::ok(d, &["calibrate", "--data", "semi.csv", "--out", "b.toml"]);
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
    common::ok(d, &["calibrate", "--data", "spaced.txt", "--out", "c.toml"]);
    assert_eq!(params("a.toml"), params("c.toml"));
    // ... and by the streamed one, decimal commas included.
    std::fs::write(d.join("ws.txt"), "q1 q2   q3\n 1,46  3,56 -2,59\n").unwrap();
    std::fs::write(d.join("cs.csv"), "q1,q2,q3\n1.46,3.56,-2.59\n").unwrap();
    let ws = common::ok(d, &["predict", "--commands", "ws.txt", "--out", "-"]);
    let cs = common::ok(d, &["predict", "--commands", "cs.csv", "--out", "-"]);
    assert_eq!(ws, cs);
    std::fs::write(d.join("tab.csv"), "Q1\tQ2\tQ3\n1.46\t3.56\t-2.59\n").unwrap();
    let out = common::ok(d, &["predict", "--commands", "tab.csv", "--out", "-"]);
    assert_eq!(out.lines().count(), 2, "{out}");
    // A missing column names how the fields were separated.
    std::fs::write(d.join("semi-bad.csv"), "a;q2;q3\n1,46;3,56;-2,59\n").unwrap();
    common::fails(
        d,
        &["predict", "--commands", "semi-bad.csv", "--out", "x.csv"],
        1,
        "missing column `q1` (columns found, separated by semicolons: a, q2, q3)",
    );
    std::fs::write(d.join("typo.csv"), "q_1,q2,q3\n1.46,3.56,-2.59\n").unwrap();
    common::fails(
        d,
        &["predict", "--commands", "typo.csv", "--out", "x.csv"],
        1,
        "missing column `q1`; did you mean `q_1`?",
    );
}
