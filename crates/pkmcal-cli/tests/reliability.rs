//! Never lose a user's file: outputs that are inputs or each other, devices,
//! pipes and links, runs that fail late, interrupted runs, piped inputs.

mod common;
use common::{fails, ok, run};
use std::path::Path;

/// A calibration data file, a commands file and a parameter file.
fn files(d: &Path) {
    ok(
        d,
        &[
            "simulate", "--grid", "30", "--noise", "0.002", "--out", "d.csv",
        ],
    );
    ok(
        d,
        &["simulate", "--grid", "12", "--seed", "2", "--out", "v.csv"],
    );
    std::fs::write(d.join("c.csv"), "q1,q2,q3\n1.46,3.56,-2.59\n").unwrap();
    std::fs::write(d.join("t.csv"), "target_x,target_y\n0,180\n10,190\n").unwrap();
}

fn read(d: &Path, f: &str) -> String {
    std::fs::read_to_string(d.join(f)).unwrap()
}

/// No hidden temporary is left in `d`.
fn no_temporaries(d: &Path) {
    let left: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

#[test]
fn an_output_is_never_an_input_or_another_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let data = read(d, "d.csv");
    let cases: &[(&[&str], &str)] = &[
        (
            &["calibrate", "--data", "d.csv", "--out", "d.csv"],
            "also an input",
        ),
        (
            &["calibrate", "--data", "d.csv", "--out", "./sub/../d.csv"],
            "directory",
        ),
        (
            &["calibrate", "--data", "d.csv", "--out", "././d.csv"],
            "also an input",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--validate",
                "v.csv",
                "--out",
                "v.csv",
            ],
            "also an input",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--out",
                "p.toml",
                "--report",
                "p.toml",
            ],
            "same file",
        ),
        (
            &["predict", "--commands", "c.csv", "--out", "c.csv"],
            "also an input",
        ),
        (
            &["analyze", "--data", "d.csv", "--report", "d.csv"],
            "also an input",
        ),
        (
            &["compensate", "--targets", "t.csv", "--out", "t.csv"],
            "also an input",
        ),
        (
            &[
                "plan",
                "--count",
                "5",
                "--out",
                "p.csv",
                "--grid-out",
                "./p.csv",
            ],
            "same file",
        ),
        (
            &["montecarlo", "--poses", "d.csv", "--out", "d.csv"],
            "also an input",
        ),
    ];
    for (args, needle) in cases {
        fails(d, args, 2, needle);
        assert_eq!(read(d, "d.csv"), data, "{args:?}");
    }
    std::fs::write(d.join("m.toml"), "type = \"jeong-kim-2dof\"\n").unwrap();
    let mech = read(d, "m.toml");
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "m.toml",
            "--grid",
            "3",
            "--out",
            "m.toml",
        ],
        2,
        "also an input",
    );
    assert_eq!(read(d, "m.toml"), mech);
    // Through a hard link too.
    std::fs::hard_link(d.join("d.csv"), d.join("same.csv")).unwrap();
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "same.csv"],
        2,
        "also an input",
    );
    // A report directory whose page would replace the data.
    std::fs::create_dir(d.join("rep")).unwrap();
    std::fs::write(d.join("rep/report.html"), "mine").unwrap();
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "rep/report.html",
            "--out",
            "p.toml",
            "--report-dir",
            "rep",
        ],
        2,
        "also an input",
    );
    no_temporaries(d);
}

#[test]
fn devices_pipes_links_and_directories_are_not_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    std::os::unix::fs::symlink(d.join("v.csv"), d.join("link.csv")).unwrap();
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "link.csv"],
        2,
        "symbolic link",
    );
    assert!(
        std::fs::symlink_metadata(d.join("link.csv"))
            .unwrap()
            .file_type()
            .is_symlink()
    );
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "/dev/null"],
        2,
        "not a regular file",
    );
    let status = std::process::Command::new("mkfifo")
        .arg(d.join("fifo"))
        .status()
        .unwrap();
    assert!(status.success());
    fails(
        d,
        &["predict", "--commands", "c.csv", "--out", "fifo"],
        2,
        "not a regular file",
    );
    std::fs::write(d.join("file"), "x").unwrap();
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--out",
            "p.toml",
            "--report-dir",
            "file",
        ],
        2,
        "not a directory",
    );
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "nodir/p.toml"],
        2,
        "does not exist",
    );
}

#[test]
fn a_run_that_fails_late_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    std::fs::write(d.join("p.toml"), "# mine\n").unwrap();
    // The report's directory is missing: refused before any work.
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--out",
            "p.toml",
            "--report",
            "nodir/r.json",
        ],
        2,
        "does not exist",
    );
    assert_eq!(read(d, "p.toml"), "# mine\n");
    // A validation file that fails after the calibration: nothing written,
    // not even the parameters computed before it.
    std::fs::write(d.join("bad.csv"), "q1,q2,q3,x,y\n1,2\n").unwrap();
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--validate",
            "bad.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--report-dir",
            "rep",
        ],
        1,
        "bad.csv",
    );
    assert_eq!(read(d, "p.toml"), "# mine\n");
    assert!(!d.join("r.json").exists() && !d.join("rep").exists());
    no_temporaries(d);
}

#[test]
fn a_piped_input_is_read_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut rows = String::from("target_x,target_y\n");
    for i in 0..2000 {
        let x = -20.0 + (i % 40) as f64;
        let y = if i % 100 == 7 {
            5000.0
        } else {
            170.0 + (i / 40) as f64 * 0.2
        };
        rows.push_str(&format!("{x},{y}\n"));
    }
    use std::io::Write;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
        .args([
            "compensate",
            "--targets",
            "/dev/stdin",
            "--skip-unreachable",
            "--out",
            "out.csv",
        ])
        .current_dir(d)
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(rows.as_bytes())
        .unwrap();
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = read(d, "out.csv");
    // Every reachable row, each once; the unreachable ones named by line.
    assert_eq!(out.lines().count() - 1, 1980, "{}", &out[..200]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("/dev/stdin:9: skipped"), "{err}");
    assert!(err.contains("skipped 20"), "{err}");
}

#[test]
fn an_interrupted_run_leaves_no_temporary() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("p.csv"), "mine").unwrap();
    // compensate streams into its temporary while stdin stays open.
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
        .args(["compensate", "--targets", "/dev/stdin", "--out", "p.csv"])
        .current_dir(d)
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    let mut stdin = child.stdin.take().unwrap();
    stdin.write_all(b"target_x,target_y\n0,180\n").unwrap();
    stdin.flush().unwrap();
    // Wait for the temporary, then interrupt.
    let start = std::time::Instant::now();
    while std::fs::read_dir(d).unwrap().count() < 2 {
        assert!(start.elapsed().as_secs() < 20, "no temporary appeared");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let pid = child.id().to_string();
    assert!(
        std::process::Command::new("kill")
            .args(["-TERM", &pid])
            .status()
            .unwrap()
            .success()
    );
    let o = child.wait_with_output().unwrap();
    drop(stdin);
    assert_eq!(
        o.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert_eq!(read(d, "p.csv"), "mine");
    no_temporaries(d);
    let _ = run;
}

#[test]
fn bad_option_values_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let cases: &[(&[&str], &str)] = &[
        (
            &["simulate", "--grid", "3", "--noise=-1", "--out", "s.csv"],
            "--noise",
        ),
        (
            &[
                "simulate", "--grid", "3", "--noise", "1e308", "--out", "s.csv",
            ],
            "--noise",
        ),
        (&["simulate", "--grid", "0", "--out", "s.csv"], "--grid"),
        (
            &[
                "simulate",
                "--grid",
                "3",
                "--angle-noise",
                "nan",
                "--out",
                "s.csv",
            ],
            "--angle-noise",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--kfold",
                "0",
                "--out",
                "p.toml",
            ],
            "--kfold",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--kfold",
                "1",
                "--out",
                "p.toml",
            ],
            "--kfold",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--holdout",
                "1",
                "--out",
                "p.toml",
            ],
            "--holdout",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--loss",
                "huber",
                "--loss-scale",
                "0",
                "--out",
                "p.toml",
            ],
            "--loss-scale",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--force",
                "a,b",
                "--out",
                "p.toml",
            ],
            "--force",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--force",
                "1,2,3",
                "--out",
                "p.toml",
            ],
            "--force",
        ),
        (&["montecarlo", "--poses", "d.csv", "--runs", "0"], "--runs"),
        (
            &[
                "plan",
                "--count",
                "5",
                "--candidates",
                "0",
                "--out",
                "p.csv",
            ],
            "--candidates",
        ),
        (
            &[
                "trilaterate",
                "--data",
                "d.csv",
                "--sigma",
                "0",
                "--out",
                "x.csv",
            ],
            "--sigma",
        ),
        (
            &[
                "compensate",
                "--targets",
                "t.csv",
                "--load",
                "1,x",
                "--out",
                "x.csv",
            ],
            "--load",
        ),
    ];
    for (args, needle) in cases {
        fails(d, args, 2, needle);
    }
    no_temporaries(d);
}
