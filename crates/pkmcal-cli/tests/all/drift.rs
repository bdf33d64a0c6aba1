//! `drift`: two calibrations of an unchanged machine agree; a changed arm is
//! found and named first; against nominal; bad input.

use crate::common::{fails, json, ok};

fn calibrated(dir: &std::path::Path, name: &str, l11: f64, seed: &str) {
    std::fs::write(
        dir.join(format!("{name}.truth.toml")),
        format!("l11 = {l11}\n"),
    )
    .unwrap();
    ok(
        dir,
        &[
            "simulate",
            "--grid",
            "35",
            "--truth",
            &format!("{name}.truth.toml"),
            "--noise",
            "0.002",
            "--seed",
            seed,
            "--out",
            &format!("{name}.csv"),
            "--quiet",
        ],
    );
    ok(
        dir,
        &[
            "calibrate",
            "--data",
            &format!("{name}.csv"),
            "--out",
            &format!("{name}.toml"),
            "--report",
            &format!("{name}.json"),
            "--quiet",
        ],
    );
}

#[test]
fn a_changed_arm_is_found_and_noise_is_not_a_change() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    calibrated(d, "a", 280.3, "1");
    calibrated(d, "b", 280.3, "2");
    calibrated(d, "c", 280.35, "3");
    let same = ok(
        d,
        &[
            "drift", "--old", "a.json", "--new", "b.json", "--out", "ab.json",
        ],
    );
    assert!(same.contains("0 of 16 parameters changed"), "{same}");
    assert!(same.contains("Holm–Bonferroni"), "{same}");
    let ab = json(&d.join("ab.json"));
    assert_eq!(ab["joint_drift"], false);
    // Both calibrations estimated their noise: Student's t and F.
    assert!(ab["noise_dof"].as_f64().unwrap() > 30.0);
    let moved = ok(
        d,
        &[
            "drift", "--old", "a.json", "--new", "c.json", "--out", "ac.json",
        ],
    );
    let ac = json(&d.join("ac.json"));
    assert_eq!(ac["parameters"][0]["name"], "l11", "{moved}");
    assert_eq!(ac["parameters"][0]["drifted"], true);
    assert_eq!(ac["joint_drift"], true);
    // Against the nominal values: l11 is 0.3 mm off.
    let nominal = ok(d, &["drift", "--new", "a.json"]);
    assert!(nominal.contains("from the nominal values"), "{nominal}");
}

#[test]
fn bad_drift_requests_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    calibrated(d, "a", 280.3, "1");
    fails(
        d,
        &["drift", "--new", "a.json", "--alpha", "2"],
        2,
        "--alpha",
    );
    fails(d, &["drift", "--new", "missing.json"], 1, "missing.json");
    std::fs::write(d.join("x.json"), "{}").unwrap();
    fails(d, &["drift", "--new", "x.json"], 1, "covariance");
    // A calibration of another mechanism.
    let hexapod = crate::common::example("gough-stewart-6");
    fails(
        d,
        &["drift", "--mechanism", &hexapod, "--new", "a.json"],
        1,
        "another mechanism",
    );
    assert!(!d.join("d.json").exists());
}
