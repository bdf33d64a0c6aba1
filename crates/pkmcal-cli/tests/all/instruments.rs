//! Every instrument on one path: ball-bar readings, target points on a
//! planar tool seen from a tracker, and a subset of the tool axes, through
//! simulate, calibrate (with --report-dir, --kfold, --validate) and analyze.

use crate::common::{example, fails, json, ok, read_csv};

/// The report directory holds the page and its figures.
fn assert_report(dir: &std::path::Path) {
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.contains("<svg"), "no inline figure");
    assert!(dir.join("errors.svg").exists());
}

#[test]
fn ball_bar_readings_get_a_report_and_cross_validation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("setup.toml"),
        "bar_offset = 0.0\nsockets = [[-250.0, -60.0], [260.0, -40.0], [20.0, 480.0]]\n",
    )
    .unwrap();
    std::fs::write(d.join("truth.toml"), "l11 = 280.4\ndq3 = -0.0012\n").unwrap();
    for (out, grid, seed) in [("bb.csv", "30", "1"), ("val.csv", "12", "2")] {
        ok(
            d,
            &[
                "simulate",
                "--truth",
                "truth.toml",
                "--grid",
                grid,
                "--setup",
                "setup.toml",
                "--noise",
                "0.002",
                "--seed",
                seed,
                "--out",
                out,
            ],
        );
    }
    let out = ok(
        d,
        &[
            "calibrate",
            "--data",
            "bb.csv",
            "--setup",
            "setup.toml",
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--report-dir",
            "rep",
            "--kfold",
            "3",
            "--validate",
            "val.csv",
            "--quiet",
        ],
    );
    assert!(out.contains("D1min mm"), "{out}");
    assert_report(&d.join("rep"));
    let r = json(&d.join("r.json"));
    assert_eq!(r["measurement"]["kind"], "ball_bar");
    assert_eq!(r["measurement"]["axes"][2], "d3");
    assert!(
        r["validation"]["accuracy"]["after"]["distance_max"]
            .as_f64()
            .unwrap()
            < 0.05
    );
    assert_eq!(r["cross_validation"]["folds"], 3);
    // The parameter file holds the mechanism's parameters only.
    let p = std::fs::read_to_string(d.join("p.toml")).unwrap();
    assert!(p.contains("l11 = ") && !p.contains("dbar"), "{p}");
    fails(
        d,
        &[
            "calibrate",
            "--data",
            "bb.csv",
            "--setup",
            "setup.toml",
            "--out",
            "p2.toml",
            "--frame",
            "free",
        ],
        2,
        "sockets are in the base frame",
    );
}

#[test]
fn targets_on_a_planar_tool_seen_from_a_tracker() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut text = std::fs::read_to_string(example("3-rrr")).unwrap();
    text.push_str("\n[[target]]\nat = [40.0, 0.0]\n\n[[target]]\nat = [-20.0, 35.0]\n");
    std::fs::write(d.join("m.toml"), text).unwrap();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            "m.toml",
            "--grid",
            "30",
            "--measure-targets",
            "--instrument-frame",
            "1000,-400,0.035",
            "--noise",
            "0.002",
            "--out",
            "t.csv",
        ],
    );
    let (h, _) = read_csv(&d.join("t.csv"));
    assert_eq!(&h[h.len() - 4..], ["t1x", "t1y", "t2x", "t2y"]);
    let out = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            "m.toml",
            "--data",
            "t.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--report-dir",
            "rep",
            "--quiet",
        ],
    );
    assert!(out.contains("instrument frame in the base frame"), "{out}");
    assert_report(&d.join("rep"));
    let r = json(&d.join("r.json"));
    assert_eq!(r["measurement"]["kind"], "targets");
    assert_eq!(r["measurement"]["frame"], "free");
    let frame = r["frame"].as_array().unwrap();
    assert!(
        (frame[0].as_f64().unwrap() - 1000.0).abs() < 2.0,
        "{frame:?}"
    );
    assert!(r["accuracy"]["after"]["distance_max"].as_f64().unwrap() < 0.05);
    let a = ok(d, &["analyze", "--mechanism", "m.toml", "--data", "t.csv"]);
    assert!(a.contains("frame.phi"), "{a}");
}

#[test]
fn a_subset_of_axes_is_declared_not_guessed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let m = example("gough-stewart-6");
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &m,
            "--grid",
            "30",
            "--axes",
            "z",
            "--noise",
            "0.002",
            "--out",
            "z.csv",
        ],
    );
    let (h, _) = read_csv(&d.join("z.csv"));
    assert_eq!(h.last().unwrap(), "z");
    assert!(!h.contains(&"x".to_string()));
    fails(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m,
            "--data",
            "z.csv",
            "--out",
            "p.toml",
        ],
        1,
        "say so with --axes z",
    );
    let out = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m,
            "--data",
            "z.csv",
            "--out",
            "p.toml",
            "--axes",
            "z",
            "--free",
            "dL1,dL2,dL3,dL4,dL5,dL6",
            "--report",
            "r.json",
        ],
    );
    assert!(out.contains("Zmin mm"), "{out}");
    let r = json(&d.join("r.json"));
    assert_eq!(r["measurement"]["axes"], serde_json::json!(["z"]));
    fails(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m,
            "--data",
            "z.csv",
            "--out",
            "p.toml",
            "--axes",
            "z",
            "--frame",
            "free",
        ],
        2,
        "needs whole positions",
    );
    fails(
        d,
        &[
            "calibrate",
            "--mechanism",
            &m,
            "--data",
            "z.csv",
            "--out",
            "p.toml",
            "--axes",
            "w",
        ],
        2,
        "not a tool axis",
    );
}

/// A tracker's frame identified with a platform's base joint centres: the
/// directions that move both together are one warning, not six.
#[test]
fn frame_gauge_is_one_warning() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let gs = crate::common::example("gough-stewart-6");
    crate::common::ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &gs,
            "--grid",
            "30",
            "--instrument-frame",
            "800,-500,300,0.02,-0.02,0.02",
            "--out",
            "t.csv",
        ],
    );
    let out = crate::common::ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &gs,
            "--data",
            "t.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--no-tolerances",
        ],
    );
    assert_eq!(out.matches("warning:").count(), 1, "{out}");
    let r = crate::common::json(&d.join("r.json"));
    let w = r["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 1, "{w:?}");
    assert_eq!(w[0]["kind"], "frame_gauge");
    assert_eq!(w[0]["fixed"].as_array().unwrap().len(), 6);
    assert_eq!(
        r["identifiability"]["unidentifiable"]
            .as_array()
            .unwrap()
            .len(),
        6
    );
    // With the mechanism file's tolerances as priors, the same directions
    // are held by them: identified, nothing fixed.
    crate::common::ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &gs,
            "--data",
            "t.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
        ],
    );
    let r = crate::common::json(&d.join("r.json"));
    let kinds: Vec<&str> = r["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["kind"].as_str().unwrap())
        .collect();
    assert!(kinds.contains(&"held_by_tolerance"), "{kinds:?}");
    assert!(!kinds.contains(&"frame_gauge"), "{kinds:?}");
    assert!(
        r["identifiability"]
            .get("unidentifiable")
            .unwrap()
            .as_array()
            .unwrap()
            .is_empty()
    );
    // The six of the gauge and the stiffness kL1 (no load: no data see it).
    assert_eq!(r["identifiability"]["held"].as_array().unwrap().len(), 7);
}

/// Probe heights and caliper distances between poses on a delta: simulate
/// writes both files, calibrate fits them together (the distances their own
/// noise group, their errors before and after printed and in the report),
/// analyze reads both, and a bad distance is named by its file, line and
/// number.
#[test]
fn distances_between_poses_with_probe_heights() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("linear-delta");
    std::fs::write(
        d.join("truth.toml"),
        "delta_radius = 130.5\narm_a = 250.6\narm_b = 249.7\nda = 0.4\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &mech,
            "--truth",
            "truth.toml",
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
    let (header, rows) = read_csv(&d.join("pairs.csv"));
    assert_eq!(
        header,
        ["a_1", "b_1", "c_1", "a_2", "b_2", "c_2", "distance"]
    );
    assert_eq!(rows.len(), 20);
    let free = "delta_radius,angle_a,angle_b,da,db,dc,arm_a,arm_b,arm_c";
    let out = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "probes.csv",
            "--distances",
            "pairs.csv",
            "--free",
            free,
            "--out",
            "p.toml",
            "--report",
            "r.json",
            "--report-dir",
            "rep",
        ],
    );
    assert!(
        out.contains("20 poses and 20 distances between poses"),
        "{out}"
    );
    assert!(
        out.contains("noise of lengths (distance, 20 coordinates)"),
        "{out}"
    );
    assert!(
        out.contains("20 distances between poses: error max"),
        "{out}"
    );
    let r = json(&d.join("r.json"));
    let dist = &r["accuracy"]["distances"];
    assert!(dist["before_max"].as_f64().unwrap() > 0.3, "{dist}");
    assert!(dist["after_max"].as_f64().unwrap() < 0.03, "{dist}");
    let param = |n: &str| {
        r["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == n)
            .unwrap()["identified"]
            .as_f64()
            .unwrap()
    };
    // Five σ of the noise's effect (σ about 0.02 mm on the arms).
    assert!((param("arm_a") - 250.6).abs() < 0.1, "{}", param("arm_a"));
    assert!((param("delta_radius") - 130.5).abs() < 0.05);
    let html = std::fs::read_to_string(d.join("rep/report.html")).unwrap();
    assert!(html.contains("20 distances between poses"));
    let out = ok(
        d,
        &[
            "analyze",
            "--mechanism",
            &mech,
            "--data",
            "probes.csv",
            "--distances",
            "pairs.csv",
            "--free",
            free,
        ],
    );
    assert!(out.contains("and 20 distances of pairs.csv"), "{out}");
    assert!(
        out.contains("all 9 free parameters are identifiable"),
        "{out}"
    );
    // A pair the delta cannot reach is named in its own file.
    let text = std::fs::read_to_string(d.join("pairs.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let k = lines.iter().position(|l| l.starts_with("a_1")).unwrap() + 4;
    let mut f: Vec<&str> = lines[k].split(',').collect();
    f[1] = "900";
    lines[k] = f.join(",");
    std::fs::write(d.join("bad.csv"), lines.join("\n")).unwrap();
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
            "q.toml",
        ],
        1,
        &format!("bad.csv:{}: distance 4:", k + 1),
    );
    assert!(!d.join("q.toml").exists());
    // Overwriting the measurements is refused.
    fails(
        d,
        &[
            "simulate",
            "--mechanism",
            &mech,
            "--grid",
            "4",
            "--probe",
            "--out",
            "same.csv",
            "--distances-out",
            "same.csv",
        ],
        2,
        "same file",
    );
}

/// `--stated-distance-noise` is a prior of the distances' noise (the
/// calipers are another instrument than the probe): the summary says what
/// the estimate leaned on, distances far noisier than stated are called a
/// model that misses something, and it needs `--distances` (issue 37, 5).
#[test]
fn stated_distance_noise_is_the_distances_prior_and_reference() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("linear-delta");
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
    // calibrate with the probes, then `extra`.
    fn with_probes<'a>(mech: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
        let mut args = vec!["calibrate", "--mechanism", mech, "--data", "probes.csv"];
        args.extend(extra);
        args
    }
    let with_pairs = |stated: &str| {
        ok(
            d,
            &with_probes(
                &mech,
                &[
                    "--distances",
                    "pairs.csv",
                    "--free",
                    "delta_radius,angle_a,angle_b,da,db,dc,arm_a,arm_b,arm_c",
                    "--stated-distance-noise",
                    stated,
                    "--out",
                    "p.toml",
                ],
            ),
        )
    };
    let out = with_pairs("0.005");
    let line = out
        .lines()
        .find(|l| l.contains("noise of lengths (distance, 20 coordinates)"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        line.contains("estimated from the residuals and the stated 5.000 µm (worth 10 readings)"),
        "{line}"
    );
    assert!(!out.contains("misses"), "{out}");
    let out = with_pairs("0.0005");
    assert!(
        out.contains("(distance readings) exceeds the stated 5.000e-4 mm"),
        "{out}"
    );
    // With only the ratio stated, the scale is the residuals' and the
    // adequacy test is not made.
    let rel = ok(
        d,
        &with_probes(
            &mech,
            &[
                "--distances",
                "pairs.csv",
                "--stated-noise",
                "0.00005",
                "--stated-distance-noise",
                "0.00005",
                "--stated-relative",
                "--out",
                "p.toml",
            ],
        ),
    );
    assert!(rel.contains("stated share"), "{rel}");
    assert!(!rel.contains("misses"), "{rel}");
    let refused = [
        (vec!["--stated-relative"], "--stated-noise"),
        (vec!["--stated-distance-noise", "0.005"], "--distances"),
    ];
    for (extra, needle) in refused {
        let mut args = with_probes(&mech, &extra);
        args.extend(["--out", "q.toml"]);
        fails(d, &args, 2, needle);
        assert!(!d.join("q.toml").exists());
    }
}
