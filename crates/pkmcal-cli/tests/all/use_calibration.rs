//! End-to-end tests of `compensate`, `plan` and `montecarlo`.

use crate::common::{example, fails, ok, read_csv, run};

#[test]
fn compensated_commands_bring_the_tool_to_the_targets() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("p.toml"),
        "l11 = 280.4\nB3x = 149.6\ndq1 = 0.001\ndq3 = -0.0012\nD2 = 215.2\n",
    )
    .unwrap();
    std::fs::write(
        d.join("t.csv"),
        "target_y,target_x\n180,0\n120,40\n230,-60\n160,100\n",
    )
    .unwrap();
    for extra in [
        vec![],
        vec!["--load", "10,-30"],
        vec!["--preload", "20,-5,10"],
    ] {
        let mut args = vec![
            "compensate",
            "--params",
            "p.toml",
            "--targets",
            "t.csv",
            "--out",
            "c.csv",
        ];
        args.extend(extra.iter());
        ok(d, &args);
        let (h, rows) = read_csv(&d.join("c.csv"));
        assert_eq!(
            h,
            [
                "target_x",
                "target_y",
                "q1",
                "q2",
                "q3",
                "delta_q1",
                "delta_q2",
                "delta_q3",
                "torque_q1",
                "torque_q2",
                "torque_q3"
            ]
        );
        assert_eq!(rows.len(), 4);
        let mut pargs = vec![
            "predict",
            "--params",
            "p.toml",
            "--commands",
            "c.csv",
            "--out",
            "pr.csv",
        ];
        if extra.first() == Some(&"--load") {
            pargs.extend(["--force", "10,-30"]);
        }
        ok(d, &pargs);
        let (_, pred) = read_csv(&d.join("pr.csv"));
        for (c, p) in rows.iter().zip(&pred) {
            let err = (c[0] - p[3]).hypot(c[1] - p[4]);
            assert!(err < 1e-6, "{extra:?}: {err} mm");
        }
    }
}

#[test]
fn compensate_reports_unreachable_rows() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("t.csv"),
        "target_x,target_y\n0,180\n900,900\n40,120\n",
    )
    .unwrap();
    fails(
        d,
        &["compensate", "--targets", "t.csv", "--out", "c.csv"],
        1,
        "t.csv:3",
    );
    assert!(!d.join("c.csv").exists());
    let o = crate::common::run(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--skip-unreachable",
            "--out",
            "c.csv",
        ],
    );
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("t.csv:3: skipped"));
    assert_eq!(read_csv(&d.join("c.csv")).1.len(), 2);
    std::fs::write(d.join("bad.csv"), "target_x,target_y\n0,abc\n").unwrap();
    fails(
        d,
        &["compensate", "--targets", "bad.csv", "--out", "c2.csv"],
        1,
        "bad.csv:2: column `target_y`",
    );
    fails(
        d,
        &[
            "compensate",
            "--targets",
            "t.csv",
            "--model",
            "linear",
            "--out",
            "c2.csv",
        ],
        2,
        "linear",
    );
}

#[test]
fn plan_then_montecarlo() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = ok(
        d,
        &[
            "plan",
            "--count",
            "20",
            "--candidate-spacing",
            "15",
            "--out",
            "plan.csv",
            "--grid-out",
            "grid.csv",
        ],
    );
    assert!(
        out.contains("planned") && out.contains("plain grid"),
        "{out}"
    );
    let (h, rows) = read_csv(&d.join("plan.csv"));
    assert_eq!(h, ["target_x", "target_y", "q1", "q2", "q3"]);
    assert_eq!(rows.len(), 20);
    assert_eq!(read_csv(&d.join("grid.csv")).1.len(), 20);
    let out = ok(
        d,
        &[
            "montecarlo",
            "--poses",
            "plan.csv",
            "--runs",
            "6",
            "--validation",
            "10",
            "--out",
            "runs.csv",
        ],
    );
    assert!(out.contains("6 converged"), "{out}");
    let (h, runs) = read_csv(&d.join("runs.csv"));
    assert_eq!(runs.len(), 6);
    assert_eq!(h.len(), 4 + 16);
    fails(
        d,
        &["plan", "--count", "5", "--out", "p.csv"],
        2,
        "--count: 5 poses give too few coordinates for 16 free parameters; plan at least 9",
    );
    fails(
        d,
        &["montecarlo", "--poses", "plan.csv", "--runs", "0"],
        2,
        "--runs",
    );
}

/// Planning a 6-DOF platform: the candidates are thinned to a count, the
/// large problem is screened (seconds, not hours), and the plan beats the
/// plain grid on the criterion it maximises, with the mechanism's
/// tolerances as priors (where the screened selection alone ended 4 % below
/// the grid; the exchanges then restart from it) and without.
#[test]
fn planning_a_platform_is_bounded_and_beats_the_grid() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gs = crate::common::example("gough-stewart-6");
    for priors in [None, Some("--no-tolerances")] {
        let mut args = vec![
            "plan",
            "--mechanism",
            &gs,
            "--count",
            "50",
            "--max-candidates",
            "600",
            "--out",
            "p.csv",
        ];
        args.extend(priors);
        let out = ok(d, &args);
        assert!(
            out.contains("of 600 candidates") && out.contains("thinned evenly"),
            "{out}"
        );
        assert_eq!(
            out.contains("given 43 tolerances"),
            priors.is_none(),
            "{out}"
        );
        let o5 = |label: &str| -> f64 {
            let line = out
                .lines()
                .find(|l| l.starts_with("  ") && l.trim_start().starts_with(label))
                .unwrap();
            line.split_whitespace()
                .rev()
                .nth(1)
                .unwrap()
                .parse()
                .unwrap()
        };
        assert!(o5("planned") > o5("plain grid"), "{out}");
        assert_eq!(read_csv(&d.join("p.csv")).1.len(), 50);
        std::fs::remove_file(d.join("p.csv")).unwrap();
    }
}

/// A calibration report is a versioned record of the calibration: it names
/// its format, version and mechanism identity, and `predict --uncertainty`
/// takes its parameters (unless --params gives others) and its covariance:
/// the same predictions as with the parameter file, with standard deviations.
#[test]
fn the_calibration_record_serves_predict() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("truth.toml"), "l11 = 280.3\ndq3 = 0.002\n").unwrap();
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--grid",
            "30",
            "--noise",
            "0.002",
            "--out",
            "data.csv",
        ],
    );
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--out",
            "cal.toml",
            "--report",
            "r.json",
        ],
    );
    let r = crate::common::json(&d.join("r.json"));
    assert_eq!(r["format"], "pkmcal calibration");
    assert_eq!(r["version"], 1);
    assert!(
        r["mechanism_identity"]
            .as_str()
            .is_some_and(|s| s.starts_with("fnv1a64:")),
        "{}",
        r["mechanism_identity"]
    );
    ok(
        d,
        &[
            "predict",
            "--params",
            "cal.toml",
            "--uncertainty",
            "r.json",
            "--commands",
            "data.csv",
            "--out",
            "with-params.csv",
        ],
    );
    ok(
        d,
        &[
            "predict",
            "--uncertainty",
            "r.json",
            "--commands",
            "data.csv",
            "--out",
            "from-record.csv",
        ],
    );
    let (h, rows) = read_csv(&d.join("from-record.csv"));
    assert!(h.iter().any(|c| c == "sigma_x"), "{h:?}");
    let (_, with_params) = read_csv(&d.join("with-params.csv"));
    // The parameter file holds the values to the last digit printed (the
    // shortest round trip), the record too: the same predictions.
    assert_eq!(rows, with_params);
    let sx = h.iter().position(|c| c == "sigma_x").unwrap();
    assert!(rows.iter().all(|r| r[sx] > 0.0 && r[sx] < 0.01), "{rows:?}");
}

/// Compensated commands predicted back reach their targets (mm).
const PREDICTED_BACK: f64 = 1e-9;

/// The README's flow on its own data: plan 35 poses, simulate a machine with
/// `l11 = 280.3` and `dq3 = 0.002`, calibrate, compensate the planned
/// targets, then predict those commands under the calibration: every row
/// comes back to its target (eight of them lie where forward kinematics
/// from the reference configuration alone crosses a singularity).
#[test]
fn predict_reads_back_what_compensate_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("truth.toml"), "l11 = 280.3\ndq3 = 0.002\n").unwrap();
    ok(
        d,
        &["plan", "--quiet", "--count", "35", "--out", "plan.csv"],
    );
    ok(
        d,
        &[
            "simulate",
            "--quiet",
            "--targets",
            "plan.csv",
            "--truth",
            "truth.toml",
            "--noise",
            "0.002",
            "--seed",
            "1",
            "--out",
            "data.csv",
        ],
    );
    ok(
        d,
        &[
            "calibrate",
            "--quiet",
            "--data",
            "data.csv",
            "--out",
            "cal.toml",
        ],
    );
    ok(
        d,
        &[
            "compensate",
            "--quiet",
            "--params",
            "cal.toml",
            "--targets",
            "plan.csv",
            "--out",
            "comp.csv",
        ],
    );
    ok(
        d,
        &[
            "predict",
            "--quiet",
            "--params",
            "cal.toml",
            "--commands",
            "comp.csv",
            "--out",
            "back.csv",
        ],
    );
    let (h, comp) = read_csv(&d.join("comp.csv"));
    let (hb, back) = read_csv(&d.join("back.csv"));
    let col = |h: &[String], n: &str| h.iter().position(|c| c == n).unwrap();
    assert_eq!(comp.len(), 35);
    for (c, b) in comp.iter().zip(&back) {
        for (t, x) in [("target_x", "x"), ("target_y", "y")] {
            let (t, x) = (c[col(&h, t)], b[col(&hb, x)]);
            assert!((t - x).abs() < PREDICTED_BACK, "{t} came back as {x}");
        }
    }
}

/// `predict --skip-unreachable` writes NaN outputs for a row whose commands
/// do not assemble, lists it, and goes on; without it the run stops at that
/// row's line with exit 1 and writes nothing.
#[test]
fn predict_skips_rows_that_do_not_assemble_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("c.csv"),
        "q1,q2,q3\n1.4614514491574517,3.560908006381431,-2.593867715612745\n5,5,5\n1.4614514491574517,3.560908006381431,-2.593867715612745\n",
    )
    .unwrap();
    fails(
        d,
        &["predict", "--commands", "c.csv", "--out", "p.csv"],
        1,
        "c.csv:3",
    );
    assert!(!d.join("p.csv").exists());
    let o = run(
        d,
        &[
            "predict",
            "--commands",
            "c.csv",
            "--out",
            "p.csv",
            "--skip-unreachable",
        ],
    );
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("c.csv:3: skipped"), "{err}");
    assert!(
        err.contains("predicted 2 poses") && err.contains("skipped 1"),
        "{err}"
    );
    let text = std::fs::read_to_string(d.join("p.csv")).unwrap();
    let rows: Vec<&str> = text.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows.len(), 4);
    assert!(rows[2].starts_with("5,5,5,NaN,NaN"), "{}", rows[2]);
    assert!(!rows[1].contains("NaN") && !rows[3].contains("NaN"));
}

/// On the linear delta, commands that put two legs in the other working mode
/// (carriages b and c below the nozzle) are refused, naming a leg: the two
/// flips no longer cancel in a product of signs. And an out-of-workspace
/// refusal does not suggest a unit that puts the tool a metre under the bed.
#[test]
fn a_delta_with_two_legs_folded_the_other_way_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("linear-delta");
    std::fs::write(d.join("flip.csv"), "a,b,c\n469.915,213.392,219.315\n").unwrap();
    fails(
        d,
        &[
            "predict",
            "--mechanism",
            &mech,
            "--commands",
            "flip.csv",
            "--out",
            "p.csv",
        ],
        1,
        "is in the other working mode",
    );
    std::fs::write(d.join("far.csv"), "a,b,c\n900,900,1900\n").unwrap();
    let o = run(
        d,
        &[
            "predict",
            "--mechanism",
            &mech,
            "--commands",
            "far.csv",
            "--out",
            "p.csv",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("--units"), "{err}");
    assert!(!d.join("p.csv").exists());
}

/// `predict --joints` writes every joint, the platform coordinates outside
/// the tool axes included (a 3-PRS head's parasitic x, y, rz), in the
/// readings' units: the ones that are tool axes equal them.
#[test]
fn predict_writes_every_joint_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let m = crate::common::example("3-prs");
    crate::common::ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &m,
            "--grid",
            "4",
            "--out",
            "s.csv",
        ],
    );
    for units in ["angle=rad", "angle=deg"] {
        crate::common::ok(
            d,
            &[
                "predict",
                "--mechanism",
                &m,
                "--commands",
                "s.csv",
                "--joints",
                "--units",
                units,
                "--out",
                "p.csv",
            ],
        );
        let (h, rows) = crate::common::read_csv(&d.join("p.csv"));
        let c = |n: &str| {
            h.iter()
                .position(|x| x == n)
                .unwrap_or_else(|| panic!("{n} in {h:?}"))
        };
        for n in ["joint_x", "joint_y", "joint_rz", "joint_s1", "joint_r1"] {
            c(n);
        }
        for r in &rows {
            for a in ["z", "rx", "ry"] {
                assert_eq!(r[c(a)], r[c(&format!("joint_{a}"))], "{a} ({units})");
            }
            assert_eq!(r[c("s1")], r[c("joint_s1")]);
        }
    }
}

/// Issue 50, 6: the calibration record is an input with a schema: every
/// member is required and checked, and what is wrong is blamed on the record
/// (never on the commands file's line 2): a record missing one parameter
/// (before: predict used its nominal value, 0.25 mm off), without `format`
/// and `version` (before: read as a report from before versions, so another
/// mechanism's calibration was accepted), a key given twice (before: the
/// last won), a redundancy of 1e308 (before: drift's p-values were NaN and
/// read as "no change"), an asymmetric covariance and an impossible
/// `l11 = −280` (before: blamed on the commands file's line 2, with a hint to
/// skip unreachable rows).
#[test]
fn a_tampered_calibration_record_is_refused_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("truth.toml"), "l11 = 280.3\ndq3 = 0.002\n").unwrap();
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--grid",
            "30",
            "--noise",
            "0.002",
            "--out",
            "data.csv",
            "--quiet",
        ],
    );
    ok(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--out",
            "cal.toml",
            "--report",
            "r.json",
            "--quiet",
        ],
    );
    let text = std::fs::read_to_string(d.join("r.json")).unwrap();
    let record: serde_json::Value = serde_json::from_str(&text).unwrap();
    let edited = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut r = record.clone();
        f(&mut r);
        serde_json::to_string_pretty(&r).unwrap()
    };
    let cases: Vec<(&str, String, &str)> = vec![
        (
            "missing-parameter",
            edited(&|r| {
                let p = r["parameters"].as_array_mut().unwrap();
                p.retain(|x| x["name"] != "dq3");
                // Keep the covariance over held parameters.
                let c = &mut r["covariance"];
                let k = c["names"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .position(|n| n == "dq3")
                    .unwrap();
                c["names"].as_array_mut().unwrap().remove(k);
                let m = c["matrix"].as_array_mut().unwrap();
                m.remove(k);
                for row in m.iter_mut() {
                    row.as_array_mut().unwrap().remove(k);
                }
            }),
            "`parameters` lacks `dq3`",
        ),
        (
            "no-format",
            edited(&|r| {
                let o = r.as_object_mut().unwrap();
                o.remove("format");
                o.remove("version");
            }),
            "missing field `format`",
        ),
        (
            "old-version",
            edited(&|r| r["version"] = serde_json::json!(0)),
            "older than this pkmcal reads",
        ),
        (
            "duplicate",
            text.replacen("\"format\":", "\"format\": \"x\",\n  \"format\":", 1),
            "the key `format` appears twice",
        ),
        (
            "redundancy",
            edited(&|r| r["noise"][0]["redundancy"] = serde_json::json!(1e308)),
            "`noise` group 1 was estimated with a redundancy of 1e308",
        ),
        (
            "scale",
            edited(&|r| r["scale"]["dof"] = serde_json::json!(-3.0)),
            "`scale` has -3 degrees of freedom",
        ),
        (
            "prior-elsewhere",
            edited(&|r| {
                r["priors"] =
                    serde_json::json!([{"name": "zz", "index": 0, "centre": 0.0, "sigma": 1.0}])
            }),
            "`priors` names `zz`, which `parameters` does not hold",
        ),
        (
            "prior-sigma",
            edited(&|r| {
                r["priors"] =
                    serde_json::json!([{"name": "l11", "index": 0, "centre": 280.0, "sigma": 0.0}])
            }),
            "a prior is a finite centre and a positive, finite σ",
        ),
        (
            "asymmetric",
            edited(&|r| {
                let v = r["covariance"]["matrix"][0][1].as_f64().unwrap();
                r["covariance"]["matrix"][0][1] = serde_json::json!(v * 1.5 + 1e-9);
            }),
            "`covariance` is not symmetric",
        ),
        (
            "impossible",
            edited(&|r| {
                for p in r["parameters"].as_array_mut().unwrap() {
                    if p["name"] == "l11" {
                        p["identified"] = serde_json::json!(-280.0);
                    }
                }
            }),
            "l11",
        ),
    ];
    for (name, text, needle) in &cases {
        let file = format!("{name}.json");
        std::fs::write(d.join(&file), text).unwrap();
        let o = run(
            d,
            &[
                "predict",
                "--uncertainty",
                &file,
                "--commands",
                "data.csv",
                "--out",
                "p.csv",
            ],
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(&format!("{file}: ")), "{name}: {err}");
        assert!(err.contains(needle), "{name}: {err}");
        assert!(!err.contains("data.csv"), "{name}: {err}");
        assert!(!d.join("p.csv").exists(), "{name}");
        // drift reads the same records the same way.
        let o = run(d, &["drift", "--new", &file, "--old", "r.json"]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "drift {name}: {err}");
        assert!(err.contains(&file), "drift {name}: {err}");
    }
    // A scale with more degrees of freedom than the record's readings is
    // refused, the number in exponent form; degrees of freedom beyond any
    // calibration's (2e6, readings as many) are the normal limit, not NaN
    // or p = 1: a 0.5 mm change of l11 (128σ) with a scale of 1e308 degrees
    // of freedom was "no change".
    std::fs::write(
        d.join("dof.json"),
        edited(&|r| r["scale"]["dof"] = serde_json::json!(1e308)),
    )
    .unwrap();
    let o = run(d, &["drift", "--new", "dof.json", "--old", "r.json"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("dof.json") && err.contains("`scale` has 1e308 degrees of freedom"),
        "{err}"
    );
    let moved = edited(&|r| {
        r["scale"]["dof"] = serde_json::json!(2e6);
        r["noise"][0]["count"] = serde_json::json!(2_000_000);
        r["noise"][0]["redundancy"] = serde_json::json!(2e6);
        for p in r["parameters"].as_array_mut().unwrap() {
            if p["name"] == "l11" {
                p["identified"] = serde_json::json!(p["identified"].as_f64().unwrap() + 0.5);
            }
        }
    });
    std::fs::write(d.join("moved.json"), moved).unwrap();
    let o = run(d, &["drift", "--new", "moved.json", "--old", "r.json"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("1 of 16 parameters changed"), "{out}");
    assert!(out.contains("two-sided p (normal)"), "{out}");
}
