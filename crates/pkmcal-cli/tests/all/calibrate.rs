//! End-to-end tests of `calibrate`, `analyze` and the demo.

use crate::common::{fails, ok, read_csv};

fn simulated(d: &std::path::Path) {
    std::fs::write(
        d.join("truth.toml"),
        "l11 = 280.4\nl22 = 279.7\nB3x = 149.6\nD2 = 215.2\nPty = 62.3\ndq1 = 0.001\ndq3 = -0.0012\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--grid",
            "35",
            "--noise",
            "0.002",
            "--seed",
            "3",
            "--out",
            "data.csv",
        ],
    );
    std::fs::write(
        d.join("vt.csv"),
        "target_x,target_y\n0,180\n40,120\n-60,230\n100,160\n-20,300\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate",
            "--truth",
            "truth.toml",
            "--targets",
            "vt.csv",
            "--out",
            "val.csv",
        ],
    );
}

#[test]
fn calibrate_writes_params_that_predict_accepts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d);
    // Simulated data are in the base frame, as predict's output is.
    let out = ok(
        d,
        &[
            "calibrate",
            "--frame",
            "base",
            "--data",
            "data.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--validate",
            "val.csv",
        ],
    );
    assert!(out.contains("converged"), "{out}");
    assert!(out.contains("validation, after"), "{out}");
    let p = std::fs::read_to_string(d.join("p.toml")).unwrap();
    let l11: f64 = p.lines().find(|l| l.starts_with("l11 = ")).unwrap()[6..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((l11 - 280.4).abs() < 0.01, "{p}");
    // Predict the unseen poses with the identified parameters.
    ok(
        d,
        &[
            "predict",
            "--params",
            "p.toml",
            "--commands",
            "val.csv",
            "--out",
            "pred.csv",
        ],
    );
    let (_, val) = read_csv(&d.join("val.csv"));
    let (_, pred) = read_csv(&d.join("pred.csv"));
    for (v, p) in val.iter().zip(&pred) {
        let err = (v[5] - p[3]).hypot(v[6] - p[4]);
        assert!(err < 0.01, "validation error {err} mm");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("r.json")).unwrap()).unwrap();
    assert_eq!(report["model"], "exact");
    assert_eq!(report["converged"], true);
    assert_eq!(report["parameters"].as_array().unwrap().len(), 22);
    assert_eq!(report["identifiability"]["rank"], 16);
    assert!(
        report["validation"]["accuracy"]["after"]["distance_rms"]
            .as_f64()
            .unwrap()
            < 0.01
    );
    for key in ["o1", "o2", "o3", "o4", "o5"] {
        assert!(
            report["identifiability"]["observability"][key]
                .as_f64()
                .unwrap()
                > 0.0
        );
    }
}

#[test]
fn rigid_model_fixes_dq3_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d);
    let out = ok(
        d,
        &[
            "calibrate",
            "--model",
            "rigid",
            "--data",
            "data.csv",
            "--out",
            "p.toml",
            "--holdout",
            "0.2",
            "--seed",
            "4",
        ],
    );
    assert!(
        out.contains("unidentifiable with the rigid model: 1.000·dq3"),
        "{out}"
    );
    assert!(out.contains("held-out poses"), "{out}");
}

#[test]
fn free_fix_kfold_and_analyze() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d);
    let out = ok(
        d,
        &[
            "calibrate",
            "--model",
            "linear",
            "--data",
            "data.csv",
            "--fix",
            "Ptx,Pty",
            "--free",
            "default,k2,k3",
            "--kfold",
            "5",
            "--out",
            "p.toml",
        ],
    );
    assert!(out.contains("5-fold cross-validation"), "{out}");
    assert!(out.contains("fixed: B1x B1y B2x Ptx Pty k1"), "{out}");
    // At the nominal parameters the actuators do not fight: no stiffness shows.
    let out = ok(
        d,
        &[
            "analyze", "--data", "data.csv", "--free", "all", "--report", "a.json",
        ],
    );
    assert!(out.contains("unidentifiable: 1.000·k1"), "{out}");
    // At calibrated parameters, only the stiffness ratios show.
    ok(d, &["calibrate", "--data", "data.csv", "--out", "p2.toml"]);
    let out = ok(
        d,
        &[
            "analyze", "--data", "data.csv", "--free", "all", "--params", "p2.toml",
        ],
    );
    assert!(out.contains("1 direction cannot be identified"), "{out}");
    assert!(
        out.contains("k1") && out.contains("k2") && out.contains("k3"),
        "{out}"
    );
    assert!(d.join("a.json").exists());
    let out = ok(d, &["analyze", "--data", "data.csv"]);
    assert!(
        out.contains("all 16 free parameters are identifiable"),
        "{out}"
    );
}

#[test]
fn calibrate_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d);
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--free",
            "l11,l99",
            "--out",
            "p.toml",
        ],
        2,
        "unknown parameter `l99`",
    );
    std::fs::write(d.join("few.csv"), "q1,q2,q3,x,y\n1.46,3.56,-2.59,-30,165\n").unwrap();
    fails(
        d,
        &["calibrate", "--data", "few.csv", "--out", "p.toml"],
        1,
        "measure more poses",
    );
    std::fs::write(d.join("nox.csv"), "q1,q2,q3,y\n1.46,3.56,-2.59,165\n").unwrap();
    fails(
        d,
        &["calibrate", "--data", "nox.csv", "--out", "p.toml"],
        1,
        "missing column `x`",
    );
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--holdout",
            "0.2",
            "--validate",
            "val.csv",
            "--out",
            "p.toml",
        ],
        2,
        "cannot be used with",
    );
    assert!(!d.join("p.toml").exists());
}

#[test]
fn demo_runs_the_case_study() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(dir.path(), &["demo", "--out-dir", "demo"]);
    for needle in [
        "after, rigid model",
        "after, linear model",
        "after, exact model",
        "validation set",
    ] {
        assert!(out.contains(needle), "{needle}: {out}");
    }
    for f in [
        "measurements.csv",
        "validation.csv",
        "truth.toml",
        "params-exact.toml",
        "report-exact.json",
    ] {
        assert!(dir.path().join("demo").join(f).exists(), "{f}");
    }
    // Its reports are calibration records, as `calibrate --report` writes:
    // predict takes one's parameters and covariance.
    ok(
        dir.path(),
        &[
            "predict",
            "--uncertainty",
            "demo/report-exact.json",
            "--commands",
            "demo/validation.csv",
            "--out",
            "p.csv",
        ],
    );
    let p = std::fs::read_to_string(dir.path().join("p.csv")).unwrap();
    assert!(p.lines().next().unwrap().contains("sigma_x"), "{p}");
}

/// Tolerances and stated noise, refused by name with nothing written: an
/// unknown name (option: usage, exit 2; the mechanism file's table: exit 1
/// naming the file), both --tolerance and --no-tolerances, a relative
/// tolerance of a parameter nominally 0, a stated angle noise alone.
#[test]
fn calibrate_refuses_bad_tolerances_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulated(d);
    let base = ["calibrate", "--data", "data.csv", "--out", "p.toml"];
    let with = |extra: &[&'static str]| -> Vec<&'static str> {
        base.iter().copied().chain(extra.iter().copied()).collect()
    };
    fails(
        d,
        &with(&["--tolerance", "l99=0.1"]),
        2,
        "unknown parameter `l99`",
    );
    fails(
        d,
        &with(&["--tolerance", "l11=0.1", "--no-tolerances"]),
        2,
        "not both",
    );
    fails(d, &with(&["--tolerance", "dq1=10%"]), 2, "0 nominally");
    fails(
        d,
        &with(&["--stated-angle-noise", "1e-5"]),
        2,
        "--stated-noise",
    );
    let mech = std::fs::read_to_string(crate::common::example("jeong-kim-2dof")).unwrap();
    std::fs::write(
        d.join("m.toml"),
        format!("{mech}\n[tolerances]\nl1l = 0.05\n"),
    )
    .unwrap();
    fails(
        d,
        &with(&["--mechanism", "m.toml"]),
        1,
        "in mechanism file m.toml: in the [tolerances] table",
    );
    assert!(!d.join("p.toml").exists());
    // A good one is used: the summary has the tolerance column.
    let out = crate::common::ok(d, &with(&["--tolerance", "l11=0.05,k2=20%"]));
    assert!(out.contains("tolerance from data"), "{out}");
}
