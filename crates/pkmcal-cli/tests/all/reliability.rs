//! Never lose a user's file: outputs that are inputs or each other, devices,
//! pipes and links, runs that fail late, interrupted runs, piped inputs.

use crate::common::{fails, ok, run};
use std::os::unix::fs::FileTypeExt;
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
}

/// SIGTERM at moments spread over a run that writes many outputs (the
/// parameters and a report directory): each run either leaves every earlier
/// file as it was and no temporary (exit 130), or puts the whole new set in
/// place (exit 0; or 130 when the signal came during the renames, which it
/// waits for and reports). Never a temporary left, never part of the set.
#[test]
fn an_interruption_at_any_moment_leaves_the_old_files_or_the_whole_new_set() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(
        d,
        &[
            "simulate", "--grid", "35", "--noise", "0.002", "--out", "d.csv",
        ],
    );
    let args = [
        "calibrate",
        "--data",
        "d.csv",
        "--out",
        "p.toml",
        "--report-dir",
        "rep",
        "--quiet",
    ];
    let start = std::time::Instant::now();
    ok(d, &args);
    let whole = start.elapsed();
    let files = std::fs::read_dir(d.join("rep")).unwrap().count();
    for k in 0..12 {
        std::fs::write(d.join("p.toml"), "mine").unwrap();
        let _ = std::fs::remove_dir_all(d.join("rep"));
        let child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
            .args(args)
            .current_dir(d)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(whole.mul_f64(0.3 + 0.07 * k as f64));
        let _ = std::process::Command::new("kill")
            .args(["-TERM", &child.id().to_string()])
            .status();
        let o = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        let params = read(d, "p.toml");
        let report = std::fs::read_dir(d.join("rep")).map_or(0, |r| r.count());
        let complete = params.starts_with("# pkmcal") && report == files;
        match o.status.code() {
            Some(0) => assert!(
                complete,
                "run {k}: {report} of {files} report files, params {:?}, {err}",
                &params[..params.len().min(20)]
            ),
            Some(130) if err.contains("after the outputs were written") => {
                assert!(complete, "run {k}: {err}")
            }
            Some(130) => {
                assert_eq!(params, "mine", "run {k}: {err}");
                let names: Vec<String> = std::fs::read_dir(d.join("rep"))
                    .map(|r| {
                        r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                            .collect()
                    })
                    .unwrap_or_default();
                assert_eq!(report, 0, "run {k}: {err} {names:?}");
            }
            c => panic!("run {k}: exit {c:?}: {err}"),
        }
        no_temporaries(d);
        if d.join("rep").exists() {
            no_temporaries(&d.join("rep"));
        }
    }
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
                "--load",
                "a,b",
                "--out",
                "p.toml",
            ],
            "--load",
        ),
        (
            &[
                "calibrate",
                "--data",
                "d.csv",
                "--load",
                "1,2,3",
                "--out",
                "p.toml",
            ],
            "--load",
        ),
        // The old spelling is still read, and the message names the option
        // by its name.
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
            "--load",
        ),
        (
            &[
                "predict",
                "--commands",
                "d.csv",
                "--force",
                "x",
                "--out",
                "o.csv",
            ],
            "--load",
        ),
        (&["montecarlo", "--poses", "d.csv", "--runs", "0"], "--runs"),
        (
            &[
                "plan",
                "--count",
                "5",
                "--candidate-spacing",
                "0",
                "--out",
                "p.csv",
            ],
            "--candidate-spacing",
        ),
        (
            &[
                "trilaterate",
                "--data",
                "d.csv",
                "--stated-noise",
                "0",
                "--out",
                "x.csv",
            ],
            "--stated-noise",
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

/// Extreme but finite numbers: a clear error (or a correct result), never a
/// panic, NaN output or hang.
#[test]
fn extreme_values_give_an_error_or_a_result_never_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let sockets = "sockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n";
    std::fs::write(d.join("s.toml"), format!("bar_offset = 0.0\n{sockets}")).unwrap();
    std::fs::write(
        d.join("s-off.toml"),
        format!("bar_offset = -1e300\n{sockets}"),
    )
    .unwrap();
    std::fs::write(
        d.join("s-far.toml"),
        "sockets = [[-1e200, -60.0], [260.0, -40.0], [20.0, 480.0]]\n",
    )
    .unwrap();
    std::fs::write(d.join("huge.csv"), "d1,d2,d3\n1e155,300,300\n").unwrap();
    let tri = |setup: &str| -> Vec<String> {
        [
            "trilaterate",
            "--setup",
            setup,
            "--data",
            "huge.csv",
            "--out",
            "x.csv",
        ]
        .map(String::from)
        .to_vec()
    };
    for (setup, needle) in [
        ("s.toml", "huge.csv:2"),
        ("s-off.toml", "in ball-bar setup s-off.toml"),
        ("s-far.toml", "in ball-bar setup s-far.toml"),
    ] {
        let args = tri(setup);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        fails(d, &args, 1, needle);
    }
    // A measured coordinate of 1e308: named by file and line.
    let text = read(d, "d.csv");
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header: Vec<&str> = lines[1].split(',').collect();
    let x = header.iter().position(|h| *h == "x").unwrap();
    let mut row: Vec<String> = lines[4].split(',').map(String::from).collect();
    row[x] = "1e308".into();
    lines[4] = row.join(",");
    std::fs::write(d.join("big.csv"), lines.join("\n") + "\n").unwrap();
    fails(
        d,
        &["calibrate", "--data", "big.csv", "--out", "p.toml"],
        1,
        "big.csv:5: pose 3: measured `x` = 1e308 mm",
    );
    // Loads beyond reason, and a preload that would twist an actuator.
    fails(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--load",
            "1e308,0",
            "--out",
            "x.csv",
        ],
        2,
        "--load",
    );
    fails(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--preload",
            "1e5,0,0",
            "--out",
            "x.csv",
        ],
        1,
        "small deflections",
    );
    // A zero length in a parameter file is the parameter file's fault.
    std::fs::write(d.join("l0.toml"), "l11 = 0\n").unwrap();
    fails(
        d,
        &[
            "predict",
            "--params",
            "l0.toml",
            "--commands",
            "c.csv",
            "--out",
            "x.csv",
        ],
        1,
        "in parameter file l0.toml",
    );
    fails(
        d,
        &[
            "calibrate",
            "--start",
            "l0.toml",
            "--data",
            "d.csv",
            "--out",
            "x.toml",
        ],
        1,
        "`l11`: a length must be positive",
    );
    // A platform coordinate of -1e154: the mechanism file is refused at once.
    let gs = std::fs::read_to_string(crate::common::example("gough-stewart-6")).unwrap();
    let bad = gs.replacen(
        "platform = [192.836, -229.813, 0.0]",
        "platform = [-1e154, -229.813, 0.0]",
        1,
    );
    assert_ne!(gs, bad);
    std::fs::write(d.join("gs.toml"), bad).unwrap();
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "gs.toml",
            "--grid",
            "3",
            "--out",
            "x.csv",
        ],
        1,
        "beyond ±1e6 mm",
    );
    // A revolute command ten million radians out: the same joint position
    // (modulo 2π), predicted at once.
    std::fs::write(
        d.join("turns.csv"),
        format!(
            "q1,q2,q3\n1.46,3.56,-2.59\n{},3.56,-2.59\n",
            1.46 + 2.0 * std::f64::consts::PI * 1.6e6
        ),
    )
    .unwrap();
    ok(
        d,
        &[
            "predict",
            "--commands",
            "turns.csv",
            "--out",
            "turns-out.csv",
        ],
    );
    let (_, rows) = crate::common::read_csv(&d.join("turns-out.csv"));
    assert!(
        (rows[0][3] - rows[1][3]).abs() < 1e-5 && (rows[0][4] - rows[1][4]).abs() < 1e-5,
        "{rows:?}"
    );
    // An impossible spacing is coarsened, and the spacing used is reported.
    let out = ok(
        d,
        &[
            "plan",
            "--count",
            "10",
            "--candidate-spacing",
            "0.01",
            "--out",
            "plan.csv",
        ],
    );
    assert!(out.contains("coarsened from 0.01 mm"), "{out}");
    no_temporaries(d);
}

#[test]
fn messages_blame_the_right_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // An indented comment is a comment: line numbers stay right.
    std::fs::write(
        d.join("c.csv"),
        "q1,q2,q3\n1.46,3.56,-2.59\n   # a note\n1.46,3.56\n",
    )
    .unwrap();
    fails(
        d,
        &["predict", "--commands", "c.csv", "--out", "x.csv"],
        1,
        "c.csv:4",
    );
    // Data of an 8-leg platform given to a 6-leg one.
    let m8 = crate::common::example("gough-stewart-8");
    let m6 = crate::common::example("gough-stewart-6");
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &m8,
            "--grid",
            "20",
            "--out",
            "g8.csv",
        ],
    );
    fails(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m6,
            "--data",
            "g8.csv",
            "--out",
            "x.toml",
        ],
        1,
        "L7, L8 name actuators",
    );
    // An unreachable target row, named by line in simulate and montecarlo.
    std::fs::write(
        d.join("unr.csv"),
        "target_x,target_y\n0,180\n10,190\n0,5000\n20,200\n-10,170\n5,185\n15,175\n-5,195\n",
    )
    .unwrap();
    fails(
        d,
        &["simulate", "--targets", "unr.csv", "--out", "x.csv"],
        1,
        "unr.csv:4: target [0.0, 5000.0]",
    );
    fails(
        d,
        &["montecarlo", "--poses", "unr.csv", "--runs", "2"],
        1,
        "unr.csv:4: target [0.0, 5000.0]",
    );
    // Each thing said once.
    let o = run(d, &["simulate", "--targets", "unr.csv", "--out", "x.csv"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.matches("[0.0, 5000.0]").count(), 1, "{err}");
    // A workspace box outside the mechanism's reach.
    let text = std::fs::read_to_string(crate::common::example("five-bar")).unwrap();
    let start = text.find("[workspace]").unwrap();
    let mut far = text[..start].to_string();
    far.push_str("[workspace]\nx = [5000.0, 5100.0]\ny = [5000.0, 5100.0]\n");
    let rest = &text[start + "[workspace]".len()..];
    if let Some(next) = rest.find("\n[") {
        far.push_str(&rest[next..]);
    }
    std::fs::write(d.join("far.toml"), far).unwrap();
    let o = run(
        d,
        &[
            "simulate",
            "--mechanism",
            "far.toml",
            "--grid",
            "5",
            "--out",
            "x.csv",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no reachable, well-conditioned pose") || err.contains("far.toml"),
        "{err}"
    );
}

/// A gross error (500 mm on one reading) is named before it can drag the
/// fit anywhere; with --drop-outliers it is dropped and the fit is clean.
#[test]
fn a_gross_error_is_named_or_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let text = read(d, "d.csv");
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let header: Vec<&str> = lines[1].split(',').collect();
    let y = header.iter().position(|h| *h == "y").unwrap();
    let mut row: Vec<String> = lines[6].split(',').map(String::from).collect();
    row[y] = format!("{}", row[y].parse::<f64>().unwrap() + 500.0);
    lines[6] = row.join(",");
    std::fs::write(d.join("gross.csv"), lines.join("\n") + "\n").unwrap();
    fails(
        d,
        &["calibrate", "--data", "gross.csv", "--out", "p.toml"],
        1,
        "gross.csv:7: pose 5: the measurement is 5.0000e2 mm from the nominal prediction",
    );
    let out = ok(
        d,
        &[
            "calibrate",
            "--data",
            "gross.csv",
            "--out",
            "p.toml",
            "--drop-outliers",
            "--report",
            "r.json",
        ],
    );
    assert!(
        out.contains("dropped before the final fit: pose 5 (line 7)"),
        "{out}"
    );
    let r = crate::common::json(&d.join("r.json"));
    assert!(
        r["accuracy"]["after"]["distance_max"].as_f64().unwrap() < 0.02,
        "{}",
        r["accuracy"]
    );
    assert_eq!(r["accuracy"]["poses"], 29);
}

/// `--out -` streams predictions and compensated commands to standard
/// output; nothing is written to disk.
#[test]
fn predictions_and_commands_stream_to_standard_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let out = ok(d, &["predict", "--commands", "c.csv", "--out", "-"]);
    let mut lines = out.lines();
    assert!(lines.next().unwrap().starts_with("q1,q2,q3,x,y,"), "{out}");
    assert_eq!(lines.count(), 1);
    let out = ok(d, &["compensate", "--targets", "t.csv", "--out", "-"]);
    assert_eq!(out.lines().count(), 3, "{out}");
    assert!(!d.join("-").exists());
    no_temporaries(d);
}

/// A temporary left by a killed run (SIGKILL cannot be caught) is removed by
/// the next run that writes the same output.
#[test]
fn a_killed_runs_temporary_is_swept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    // No process has this PID (above the kernel's maximum).
    std::fs::write(d.join(".p.csv.tmp-4194999"), vec![b'x'; 1000]).unwrap();
    ok(d, &["predict", "--commands", "c.csv", "--out", "p.csv"]);
    no_temporaries(d);
}

/// A full standard output is a one-line error and exit 1, not a panic.
#[test]
fn a_full_standard_output_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
        .args(["analyze", "--data", "d.csv"])
        .current_dir(d)
        .stdout(std::fs::File::create("/dev/full").unwrap())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.starts_with("error: cannot write to standard output"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "{err}");
    // Upper- or lower-case criteria, listed once.
    let help = crate::common::ok(d, &["plan", "--help"]);
    assert!(help.contains("[possible values: O1, O3, O5]"), "{help}");
    ok(
        d,
        &[
            "plan",
            "--count",
            "9",
            "--criterion",
            "o3",
            "--candidate-spacing",
            "20",
            "--out",
            "p.csv",
        ],
    );
}

/// A closed standard output (`pkmcal montecarlo … | head`, the reader
/// gone) cuts the summary short, not the run: its `--out` file is written
/// whole, and the error names the pipe and the file (issue 50: the file was
/// lost).
#[test]
fn a_closed_standard_output_keeps_the_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(d, &["plan", "--count", "12", "--out", "p.csv", "--quiet"]);
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
        .args([
            "montecarlo",
            "--poses",
            "p.csv",
            "--runs",
            "30",
            "--out",
            "runs.csv",
        ])
        .current_dir(d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reader is gone before anything is written.
    drop(child.stdout.take());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cannot write to standard output") && err.contains("runs.csv written"),
        "{err}"
    );
    let runs = read(d, "runs.csv");
    assert_eq!(
        runs.lines().filter(|l| !l.starts_with('#')).count(),
        31,
        "{runs}"
    );
    no_temporaries(d);
}

/// Every file a command reads is an input, whatever option names it:
/// measured distances, a second output path spelled differently, a
/// temporary-looking input name (issue 34, A).
#[test]
fn inputs_named_by_any_option_are_never_replaced() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let mech = crate::common::example("linear-delta");
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &mech,
            "--grid",
            "20",
            "--probe",
            "--noise",
            "0.005",
            "--out",
            "probes.csv",
            "--distances-out",
            "pairs.csv",
        ],
    );
    let pairs = read(d, "pairs.csv");
    for args in [
        vec![
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "probes.csv",
            "--distances",
            "pairs.csv",
            "--out",
            "pairs.csv",
        ],
        vec![
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "probes.csv",
            "--distances",
            "pairs.csv",
            "--out",
            "p.toml",
            "--report",
            "./pairs.csv",
        ],
        vec![
            "analyze",
            "--mechanism",
            &mech,
            "--data",
            "probes.csv",
            "--distances",
            "pairs.csv",
            "--report",
            "pairs.csv",
        ],
    ] {
        fails(d, &args, 2, "also an input");
        assert_eq!(read(d, "pairs.csv"), pairs, "{args:?}");
        assert!(!d.join("p.toml").exists(), "{args:?}");
    }
    // simulate --distances-out: an input, a link, a pipe, a device, a
    // directory, the other output; nothing written by any of them.
    std::fs::write(
        d.join("targets.csv"),
        "target_x,target_y,target_z\n0,0,100\n10,0,100\n0,10,110\n",
    )
    .unwrap();
    let targets = read(d, "targets.csv");
    std::os::unix::fs::symlink(d.join("v.csv"), d.join("link.csv")).unwrap();
    assert!(
        std::process::Command::new("mkfifo")
            .arg(d.join("fifo"))
            .status()
            .unwrap()
            .success()
    );
    std::fs::create_dir(d.join("adir")).unwrap();
    for (target, needle) in [
        ("targets.csv", "also an input"),
        ("link.csv", "symbolic link"),
        ("fifo", "not a regular file"),
        ("/dev/full", "not a regular file"),
        ("adir", "not a regular file"),
        ("./new.csv", "same file"),
    ] {
        fails(
            d,
            &[
                "simulate",
                "--mechanism",
                &mech,
                "--targets",
                "targets.csv",
                "--probe",
                "--out",
                "new.csv",
                "--distances-out",
                target,
            ],
            2,
            needle,
        );
        assert!(!d.join("new.csv").exists(), "{target}");
        assert_eq!(read(d, "targets.csv"), targets);
    }
    assert!(
        std::fs::symlink_metadata(d.join("link.csv"))
            .unwrap()
            .file_type()
            .is_symlink()
    );
    assert!(
        std::fs::symlink_metadata("/dev/full")
            .unwrap()
            .file_type()
            .is_char_device() // std::os::unix::fs::FileTypeExt
            || !Path::new("/dev/full").exists()
    );
    // An input whose name looks like a temporary of the output (a dead
    // process's): read, not swept, not renamed.
    let commands = read(d, "c.csv");
    std::fs::write(d.join(".h1.csv.tmp-4194999"), &commands).unwrap();
    std::fs::write(d.join(".h1.csv.tmp-4194999-7"), &commands).unwrap();
    ok(
        d,
        &[
            "predict",
            "--commands",
            ".h1.csv.tmp-4194999",
            "--out",
            "h1.csv",
        ],
    );
    assert_eq!(read(d, ".h1.csv.tmp-4194999"), commands);
    assert!(d.join("h1.csv").exists());
    // A name as long as the file system allows (the temporary's is cut).
    let long = format!("{}.csv", "p".repeat(250));
    ok(d, &["predict", "--commands", "c.csv", "--out", &long]);
    assert!(d.join(&long).exists());
}

/// An input reached through another file (a Klipper include) is an input:
/// `--out` onto it is refused and the file is kept (issue 34, A3).
#[test]
fn an_included_file_is_an_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let printer = std::fs::read_to_string(format!(
        "{}/../../examples/klipper-delta/printer.cfg",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    // Macros in an included file.
    std::fs::write(d.join("macros.cfg"), "[gcode_macro HOME]\ngcode:\n  G28\n").unwrap();
    let start = printer.find("[printer]").unwrap();
    let main = format!(
        "{}[include macros.cfg]\n\n{}",
        &printer[..start],
        &printer[start..]
    );
    std::fs::write(d.join("printer.cfg"), &main).unwrap();
    let macros = read(d, "macros.cfg");
    fails(
        d,
        &["klipper", "--config", "printer.cfg", "--out", "macros.cfg"],
        2,
        "also an input",
    );
    assert_eq!(read(d, "macros.cfg"), macros);
    assert_eq!(read(d, "printer.cfg"), main);
    no_temporaries_but(d, &[]);
}

/// No hidden temporary of this run in `d` (names in `keep` are the test's own).
fn no_temporaries_but(d: &Path, keep: &[&str]) {
    let left: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-") && !keep.contains(&n.as_str()))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// A demo interrupted or failing leaves no directory it created behind,
/// however deep (issue 34, B6).
#[test]
fn an_interrupted_demo_leaves_no_directory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
        .args(["demo", "--out-dir", "a/b/demo"])
        .current_dir(d)
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Interrupt once the output directory exists.
    let start = std::time::Instant::now();
    while !d.join("a/b/demo").exists() {
        if start.elapsed().as_secs() > 60 || child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let pid = child.id().to_string();
    let _ = std::process::Command::new("kill")
        .args(["-INT", &pid])
        .status();
    let o = child.wait_with_output().unwrap();
    if o.status.code() == Some(130) {
        let left: Vec<_> = std::fs::read_dir(d).unwrap().collect();
        assert!(left.is_empty(), "{left:?}");
    } else {
        // The demo finished before the signal: its whole set is there.
        assert!(o.status.success());
        assert!(d.join("a/b/demo/report/report.html").exists());
    }
}

/// Counts that no machine could hold are refused as usage errors, not a
/// panic or an abort (issue 34, C7).
#[test]
fn huge_run_counts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    // A plan of more poses than any lattice holds: an error, not an
    // overflow.
    fails(
        d,
        &["plan", "--count", "18446744073709551615", "--out", "p.csv"],
        2,
        "--count",
    );
    for runs in ["18446744073709551615", "1000000000"] {
        fails(
            d,
            &["montecarlo", "--poses", "d.csv", "--runs", runs],
            2,
            "at most 1000000 runs",
        );
    }
}

/// Counts of targets and samples, offsets and segment lengths beyond what
/// pkmcal takes are usage errors naming the option, before any work, with
/// the number as typed (issue 50, rough edges: `budget --grid` failed after
/// 4 s of work, `budget --samples`, `montecarlo --validation` and `--offset
/// 1e300` exited 1 naming no option, `--max-segment 1e-300` printed a
/// 300-digit number).
#[test]
fn out_of_range_counts_and_lengths_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    std::fs::write(d.join("cal.toml"), "").unwrap();
    std::fs::write(d.join("p.gcode"), "G21\nG90\nG1 X0 Y180\nG1 X10 Y190\n").unwrap();
    let cases: &[(&[&str], &str)] = &[
        (&["budget", "--samples", "2000000"], "--samples"),
        (
            &["budget", "--samples", "99999999999999999999"],
            "--samples",
        ),
        (&["budget", "--grid", "1000000"], "--grid"),
        (&["drift", "--new", "r.json", "--grid", "1000000"], "--grid"),
        (&["simulate", "--grid", "10001", "--out", "s.csv"], "--grid"),
        (
            &["montecarlo", "--poses", "d.csv", "--validation", "1000000"],
            "--validation-targets",
        ),
        (&["plan", "--count", "20000", "--out", "p.csv"], "--count"),
        (
            &[
                "gcode",
                "--params",
                "cal.toml",
                "--program",
                "p.gcode",
                "--offset",
                "1e300,0",
                "--out",
                "o.gcode",
            ],
            "--offset: 1e300 is beyond",
        ),
        (
            &[
                "gcode",
                "--params",
                "cal.toml",
                "--program",
                "p.gcode",
                "--max-segment",
                "1e-300",
                "--out",
                "o.gcode",
            ],
            "1e-300 must be a length",
        ),
    ];
    for (args, needle) in cases {
        fails(d, args, 2, needle);
    }
    for out in ["s.csv", "p.csv", "o.gcode"] {
        assert!(!d.join(out).exists(), "{out} written");
    }
}

/// One target is "1 target" (issue 50: "compensated 1 targets").
#[test]
fn one_target_is_counted_in_the_singular() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("one.csv"), "target_x,target_y\n0,200\n").unwrap();
    let o = run(d, &["compensate", "--targets", "one.csv", "--out", "c.csv"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("compensated 1 target (exact model)"), "{err}");
}

/// A standard error that cannot be written (full) loses the messages, not
/// the run: exit 0 and the outputs in place (issue 34, C8).
#[test]
fn an_unwritable_standard_error_loses_messages_not_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    for args in [
        vec!["predict", "--commands", "c.csv", "--out", "p.csv"],
        vec!["calibrate", "--data", "d.csv", "--out", "cal.toml"],
        vec!["simulate", "--grid", "5", "--out", "s.csv"],
        vec!["compensate", "--targets", "t.csv", "--out", "k.csv"],
    ] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
            .args(&args)
            .current_dir(d)
            .stderr(std::fs::File::create("/dev/full").unwrap())
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(0), "{args:?}");
        assert!(d.join(args[args.len() - 1]).exists(), "{args:?}");
    }
}

/// Options and reports that were taken silently or blamed on the wrong
/// file (issue 34, E13, E16, E18): each is refused with the exit code of
/// its kind (2: the command line; 1: a file's contents), naming the culprit.
#[test]
fn the_culprit_is_named_with_the_right_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    // The command line: exit 2.
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "newdir/"],
        2,
        "names a directory",
    );
    fails(
        d,
        &["predict", "--commands", "c.csv", "--out", "out/."],
        2,
        "names a directory",
    );
    fails(
        d,
        &[
            "predict",
            "--units",
            "angle=deg,angle=rad",
            "--commands",
            "c.csv",
            "--out",
            "p.csv",
        ],
        2,
        "given twice",
    );
    fails(
        d,
        &["calibrate", "--data", "d.csv", "--out", "-"],
        2,
        "summary on standard output",
    );
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--free",
            "",
            "--out",
            "p.toml",
        ],
        2,
        "no parameter is left free",
    );
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--fix",
            "l111",
            "--out",
            "p.toml",
        ],
        2,
        "--fix: unknown parameter `l111`",
    );
    // A calibration report whose covariance is not one: blamed on the report.
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--out",
            "cal.toml",
            "--report",
            "r.json",
        ],
    );
    let report: serde_json::Value = serde_json::from_str(&read(d, "r.json")).unwrap();
    let mut bad = report.clone();
    bad["covariance"]["matrix"][0][0] = serde_json::json!(-1.0);
    std::fs::write(d.join("neg.json"), bad.to_string()).unwrap();
    let mut twice = report.clone();
    let first = twice["covariance"]["names"][0].clone();
    twice["covariance"]["names"][1] = first;
    std::fs::write(d.join("twice.json"), twice.to_string()).unwrap();
    for (f, needle) in [("neg.json", "negative variance"), ("twice.json", "twice")] {
        fails(
            d,
            &[
                "predict",
                "--params",
                "cal.toml",
                "--uncertainty",
                f,
                "--commands",
                "c.csv",
                "--out",
                "p.csv",
            ],
            1,
            &format!("{f}: `covariance`"),
        );
        fails(
            d,
            &[
                "predict",
                "--params",
                "cal.toml",
                "--uncertainty",
                f,
                "--commands",
                "c.csv",
                "--out",
                "p.csv",
            ],
            1,
            needle,
        );
    }
    // A report of another mechanism: blamed on the report.
    let mech = crate::common::example("linear-delta");
    std::fs::write(d.join("abc.csv"), "a,b,c\n300,300,300\n").unwrap();
    fails(
        d,
        &[
            "predict",
            "--mechanism",
            &mech,
            "--uncertainty",
            "r.json",
            "--commands",
            "abc.csv",
            "--out",
            "p.csv",
        ],
        1,
        "r.json: this calibration cannot serve",
    );
    fails(
        d,
        &[
            "predict",
            "--mechanism",
            &mech,
            "--uncertainty",
            "r.json",
            "--commands",
            "abc.csv",
            "--out",
            "p.csv",
        ],
        1,
        "another mechanism",
    );
    // The report is a versioned calibration record: one of a newer pkmcal,
    // or of another format, is refused by name.
    let mut newer = report.clone();
    newer["version"] = serde_json::json!(99);
    std::fs::write(d.join("newer.json"), newer.to_string()).unwrap();
    let mut other = report.clone();
    other["format"] = serde_json::json!("something else");
    std::fs::write(d.join("other.json"), other.to_string()).unwrap();
    for (f, needle) in [
        ("newer.json", "version 99, newer"),
        ("other.json", "no calibration record"),
    ] {
        fails(
            d,
            &[
                "predict",
                "--uncertainty",
                f,
                "--commands",
                "c.csv",
                "--out",
                "p.csv",
            ],
            1,
            needle,
        );
    }
    // An infinite condition number is written as such, not as null.
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "d.csv",
            "--model",
            "rigid",
            "--free",
            "default,dq3",
            "--out",
            "rigid.toml",
            "--report",
            "rigid.json",
        ],
    );
    let rigid: serde_json::Value = serde_json::from_str(&read(d, "rigid.json")).unwrap();
    // (The rigid model never sees the third actuator: `dq3` is
    // unidentifiable, the analysis rank deficient.)
    assert_eq!(rigid["identifiability"]["condition_number"], "inf");
}

/// Inputs are read with bounds: a file read whole up to its kind's limit
/// (`--max-input-mb` raises it), a streamed file line by line up to 1 MiB a
/// line; `/dev/zero` under every option is an error, not gigabytes
/// (issue 34, D9).
#[test]
fn inputs_are_read_within_bounds() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    ok(d, &["calibrate", "--data", "d.csv", "--out", "cal.toml"]);
    for (args, needle) in [
        (
            vec!["calibrate", "--data", "/dev/zero", "--out", "x.toml"],
            "larger than 256 MiB",
        ),
        (
            vec!["predict", "--commands", "/dev/zero", "--out", "p.csv"],
            "longer than 1 MiB",
        ),
        (
            vec!["compensate", "--targets", "/dev/zero", "--out", "p.csv"],
            "longer than 1 MiB",
        ),
        (
            vec![
                "simulate",
                "--mechanism",
                "/dev/zero",
                "--grid",
                "3",
                "--out",
                "s.csv",
            ],
            "larger than 16 MiB",
        ),
        (
            vec![
                "predict",
                "--params",
                "/dev/zero",
                "--commands",
                "c.csv",
                "--out",
                "p.csv",
            ],
            "larger than 16 MiB",
        ),
        (
            vec!["reprap", "--config", "/dev/zero", "--probes", "d.csv"],
            "larger than 16 MiB",
        ),
        (
            vec!["klipper", "--config", "/dev/zero"],
            "larger than 16 MiB",
        ),
        (
            vec![
                "gcode",
                "--params",
                "cal.toml",
                "--program",
                "/dev/zero",
                "--out",
                "o.gcode",
            ],
            "larger than 256 MiB",
        ),
    ] {
        fails(d, &args, 1, needle);
    }
    // A data file over a lowered limit, then read with it raised.
    let big = read(d, "d.csv").repeat(2000);
    std::fs::write(d.join("big.csv"), &big).unwrap();
    assert!(big.len() > 1 << 20);
    fails(
        d,
        &["analyze", "--data", "big.csv", "--max-input-mb", "1"],
        1,
        "--max-input-mb",
    );
    // (Repeated headers are comment-free rows of text: the reader gets past
    // the size and stops at their content.)
    let o = run(d, &["analyze", "--data", "big.csv", "--max-input-mb", "8"]);
    assert!(
        !String::from_utf8_lossy(&o.stderr).contains("--max-input-mb"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// A Klipper configuration's includes are bounded in number and bytes:
/// files that include each other many times over are an error, not a
/// minute of reading (issue 39, 4).
#[test]
fn klipper_includes_are_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // 9 levels of 12 includes each: 12^8 reads without a bound.
    for level in 0..9 {
        let mut text = String::new();
        if level < 8 {
            for _ in 0..12 {
                text.push_str(&format!("[include l{}.cfg]\n", level + 1));
            }
        } else {
            text.push_str("[gcode_macro M]\ngcode:\n  G28\n");
        }
        std::fs::write(d.join(format!("l{level}.cfg")), text).unwrap();
    }
    fails(
        d,
        &["klipper", "--config", "l0.cfg"],
        1,
        "included files are read in all",
    );
}

/// A workspace box thinner than 1e-6 along an axis is refused where it is
/// read; a thin one that is allowed still gives bounded lattices (the
/// report's maps were 22 GB for x = [0, 1e-12]) (issue 34, D11).
#[test]
fn degenerate_workspace_boxes_are_refused_and_thin_ones_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = std::fs::read_to_string(crate::common::example("gough-stewart-6")).unwrap();
    let thin = text.replace("x = [-80.0, 80.0]", "x = [0.0, 1e-12]");
    assert_ne!(thin, text);
    std::fs::write(d.join("thin.toml"), &thin).unwrap();
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "thin.toml",
            "--grid",
            "20",
            "--out",
            "s.csv",
        ],
        1,
        "is narrower than 1e-6",
    );
    std::fs::write(
        d.join("jk.toml"),
        "type = \"jeong-kim-2dof\"\n[workspace]\nx = [0.0, 1e-12]\n",
    )
    .unwrap();
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "jk.toml",
            "--grid",
            "20",
            "--out",
            "s.csv",
        ],
        1,
        "is narrower than 1e-6",
    );
    // 1e-3 mm wide: allowed; the report's maps stay bounded.
    let narrow = text.replace("x = [-80.0, 80.0]", "x = [0.0, 0.001]");
    std::fs::write(d.join("narrow.toml"), &narrow).unwrap();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            "narrow.toml",
            "--grid",
            "60",
            "--noise",
            "0.002",
            "--out",
            "n.csv",
        ],
    );
    ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            "narrow.toml",
            "--data",
            "n.csv",
            "--out",
            "n.toml",
            "--report-dir",
            "rep",
        ],
    );
    assert!(d.join("rep/report.html").exists());
}

/// Files with a carriage return alone as line end (old Mac files) are read
/// line by line: comments found, errors on the right line, read and
/// streamed alike (issue 34, E14).
#[test]
fn carriage_return_line_ends_are_lines() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    let cr = read(d, "d.csv").replace('\n', "\r");
    assert!(cr.starts_with("# frame: base\r") || cr.contains('\r'));
    std::fs::write(d.join("cr.csv"), &cr).unwrap();
    let lf = ok(d, &["calibrate", "--data", "d.csv", "--out", "a.toml"]);
    let crs = ok(d, &["calibrate", "--data", "cr.csv", "--out", "b.toml"]);
    let tail = |s: &str| {
        s.lines()
            .skip(1)
            .filter(|l| !l.contains(".toml"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(tail(&lf), tail(&crs));
    std::fs::write(
        d.join("c4.csv"),
        "# commands\rq1,q2,q3\r1.46,3.56,-2.59\r1.46,oops,-2.59\r",
    )
    .unwrap();
    fails(
        d,
        &["predict", "--commands", "c4.csv", "--out", "p.csv"],
        1,
        "c4.csv:4",
    );
    let mut bad = cr.clone();
    let lines: Vec<&str> = cr.split('\r').collect();
    let n = lines.len() - 2;
    bad = bad.replacen(lines[n], "1,2,3,x,y", 1);
    std::fs::write(d.join("cr-bad.csv"), bad).unwrap();
    fails(
        d,
        &["calibrate", "--data", "cr-bad.csv", "--out", "c.toml"],
        1,
        &format!("cr-bad.csv:{}", n + 1),
    );
}

/// Mistakes in a mechanism file are blamed on the file: a target point that
/// is not finite, a workspace box out of reach (issue 34, E13).
#[test]
fn mechanism_file_mistakes_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let text = std::fs::read_to_string(crate::common::example("gough-stewart-6")).unwrap();
    std::fs::write(
        d.join("nan.toml"),
        format!("{text}\n[[target]]\nat = [nan, 0.0, 0.0]\n"),
    )
    .unwrap();
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "nan.toml",
            "--grid",
            "5",
            "--measure-targets",
            "--out",
            "t.csv",
        ],
        1,
        "in mechanism file nan.toml: [[target]] 4",
    );
    std::fs::write(
        d.join("far.toml"),
        text.replace("z = [640.0, 760.0]", "z = [5000.0, 5100.0]"),
    )
    .unwrap();
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "far.toml",
            "--grid",
            "5",
            "--out",
            "t.csv",
        ],
        1,
        "with the [workspace] box of far.toml",
    );
}

/// An instrument frame beyond any instrument's place is refused, not
/// written as positions of -1e300 (issue 34, F17).
#[test]
fn an_instrument_frame_out_of_range_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for frame in ["1e300,0,0", "0,0,1e4"] {
        fails(
            d,
            &[
                "simulate",
                "--grid",
                "5",
                "--instrument-frame",
                frame,
                "--out",
                "t.csv",
            ],
            2,
            "is beyond any instrument's place",
        );
    }
    assert!(!d.join("t.csv").exists());
    ok(
        d,
        &[
            "simulate",
            "--grid",
            "5",
            "--instrument-frame",
            "1000,-500,0.5",
            "--out",
            "t.csv",
        ],
    );
}

/// A grid step so small that its node count would wrap around is refused as
/// a usage error naming the option (issue 34, E13).
#[test]
fn a_tiny_grid_step_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fails(
        d,
        &[
            "compensate",
            "--table",
            "x=-100:100:1e-300,y=100:200:10",
            "--out",
            "g.json",
        ],
        2,
        "--table: `x=-100:100:1e-300`: too many nodes",
    );
    assert!(!d.join("g.json").exists());
}

/// A distance between a pose and itself, or a negative distance, is named
/// with its line in the distances file (issue 34, E13, E18).
#[test]
fn impossible_distances_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = crate::common::example("linear-delta");
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &mech,
            "--grid",
            "20",
            "--probe",
            "--noise",
            "0.005",
            "--out",
            "probes.csv",
            "--distances-out",
            "pairs.csv",
        ],
    );
    let pairs = read(d, "pairs.csv");
    let lines: Vec<&str> = pairs.lines().collect();
    let header = lines.iter().position(|l| l.starts_with("a_1")).unwrap();
    let row: Vec<&str> = lines[header + 2].split(',').collect();
    // The second pose made the first's, then a negative distance.
    let same = format!(
        "{},{},{},{},{},{},{}",
        row[0], row[1], row[2], row[0], row[1], row[2], row[6]
    );
    let negative = format!(
        "{},{},{},{},{},{},-{}",
        row[0], row[1], row[2], row[3], row[4], row[5], row[6]
    );
    for (bad_row, needle) in [(same, "the same commands"), (negative, "is negative")] {
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        l[header + 2] = bad_row;
        std::fs::write(d.join("bad.csv"), l.join("\n") + "\n").unwrap();
        fails(
            d,
            &[
                "calibrate",
                "--mechanism",
                &mech,
                "--data",
                "probes.csv",
                "--distances",
                "bad.csv",
                "--out",
                "c.toml",
            ],
            1,
            &format!("bad.csv:{}", header + 3),
        );
        fails(
            d,
            &[
                "calibrate",
                "--mechanism",
                &mech,
                "--data",
                "probes.csv",
                "--distances",
                "bad.csv",
                "--out",
                "c.toml",
            ],
            1,
            needle,
        );
    }
}

/// An impossible σ on the command line is a usage error naming the option,
/// not blamed on a data row (issue 34, E13).
#[test]
fn an_impossible_sigma_names_the_option() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    files(d);
    for sigma in ["2e6", "0", "1e-300"] {
        fails(
            d,
            &[
                "trilaterate",
                "--data",
                "d.csv",
                "--stated-noise",
                sigma,
                "--out",
                "t.csv",
            ],
            2,
            "--stated-noise",
        );
    }
}

/// A missing column in a file of very many columns is a short message
/// (the first columns and how many more), not megabytes (issue 34, E18).
#[test]
fn a_missing_column_among_many_is_a_short_message() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let names: Vec<String> = std::iter::once("x".to_string())
        .chain(std::iter::once("y".to_string()))
        .chain((0..100_000).map(|i| format!("c{i}")))
        .collect();
    let ones = vec!["1"; names.len()].join(",");
    std::fs::write(d.join("wide.csv"), format!("{}\n{ones}\n", names.join(","))).unwrap();
    let o = run(d, &["calibrate", "--data", "wide.csv", "--out", "c.toml"]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("missing column `q1`"), "{err}");
    assert!(err.contains("(99972 more)"), "{err}");
    assert!(err.len() < 2000, "{} bytes", err.len());
}

/// The longest a command may take here before the test calls it stuck (s).
const STUCK_AFTER_S: u64 = 120;

/// The mechanism file is read once per command, whatever reads its parts
/// (the mechanism, `[[target]]`, `[ballbar]`, `[units]`): given as a named
/// pipe that is written once, a command that opened it twice would wait
/// forever for a second writer.
#[test]
fn the_mechanism_file_is_read_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let example = std::fs::read_to_string(crate::common::example("gough-stewart-6")).unwrap();
    // Tracker data on target points with data-file units: every part of the
    // description is used.
    std::fs::write(d.join("m.toml"), &example).unwrap();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            "m.toml",
            "--grid",
            "30",
            "--measure-targets",
            "--noise",
            "0.001",
            "--out",
            "data.csv",
        ],
    );
    assert!(
        example.contains("[[target]]"),
        "the example has target points"
    );
    for args in [
        &[
            "calibrate",
            "--mechanism",
            "pipe.toml",
            "--data",
            "data.csv",
            "--out",
            "p.toml",
        ][..],
        &[
            "simulate",
            "--mechanism",
            "pipe.toml",
            "--grid",
            "5",
            "--measure-targets",
            "--out",
            "s.csv",
        ][..],
        &[
            "predict",
            "--mechanism",
            "pipe.toml",
            "--commands",
            "data.csv",
            "--out",
            "o.csv",
        ][..],
    ] {
        let _ = std::fs::remove_file(d.join("pipe.toml"));
        let status = std::process::Command::new("mkfifo")
            .arg(d.join("pipe.toml"))
            .status()
            .unwrap();
        assert!(status.success());
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_pkmcal"))
            .args(args)
            .current_dir(d)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        // One writer, once.
        let pipe = d.join("pipe.toml");
        let text = example.clone();
        let writer = std::thread::spawn(move || std::fs::write(pipe, text));
        let start = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            if start.elapsed().as_secs() > STUCK_AFTER_S {
                let _ = child.kill();
                // Unblock the writer, if it still waits, and fail.
                let _ = std::fs::read(d.join("pipe.toml"));
                panic!("pkmcal {args:?} opened the mechanism file more than once");
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        writer.join().unwrap().unwrap();
        let mut err = String::new();
        use std::io::Read;
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        assert!(status.success(), "pkmcal {args:?}: {err}");
    }
}

/// A full disk: the run fails with exit 1, the message names the file and
/// says that no output was written (the summary printed before the commit
/// announced it), and the old file is intact. Needs a small tmpfs, which
/// only root may mount; elsewhere the test says it skipped.
#[test]
fn a_full_disk_fails_naming_the_file_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let small = dir.path().join("small");
    std::fs::create_dir(&small).unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs"])
        .arg(&small)
        .output()
        .is_ok_and(|o| o.status.success());
    if !mounted {
        crate::common::skipped("cannot mount a small tmpfs here (not root)");
        return;
    }
    struct Unmount<'a>(&'a Path);
    impl Drop for Unmount<'_> {
        fn drop(&mut self) {
            let _ = std::process::Command::new("umount").arg(self.0).status();
        }
    }
    let _unmount = Unmount(&small);
    std::fs::write(small.join("out.csv"), "old\n").unwrap();
    let o = run(
        &small,
        &["simulate", "--quiet", "--grid", "2000", "--out", "out.csv"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("no output was written"), "{err}");
    assert!(
        err.contains("out.csv") && err.contains("No space left"),
        "{err}"
    );
    assert_eq!(read(&small, "out.csv"), "old\n");
    no_temporaries(&small);
    // Outputs written as they are computed name their file too (issue 50:
    // "No space left on device" alone).
    ok(
        dir.path(),
        &["simulate", "--quiet", "--grid", "2000", "--out", "big.csv"],
    );
    for (command, input) in [("compensate", "--targets"), ("predict", "--commands")] {
        let o = run(&small, &[command, input, "../big.csv", "--out", "out.csv"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{command}: {err}");
        assert!(
            err.contains("cannot write out.csv: No space left"),
            "{command}: {err}"
        );
        assert_eq!(read(&small, "out.csv"), "old\n");
        no_temporaries(&small);
    }
}

/// Issue 50: every number a user types is printed sensibly: a simulated
/// noise of 1e-308 mm was echoed in the summary as 0.000… with 300 zeros.
#[test]
fn typed_numbers_are_echoed_in_exponent_form() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = run(
        d,
        &[
            "simulate", "--grid", "3", "--noise", "1e-308", "--out", "s.csv",
        ],
    );
    assert!(o.status.success());
    let said = String::from_utf8_lossy(&o.stderr);
    assert!(said.contains("noise 1e-308 mm"), "{said}");
}
