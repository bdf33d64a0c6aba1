//! The shipped examples end to end through the CLI: simulate → analyze →
//! calibrate → validate → compensate, then the compensated commands run on the
//! simulated true machine.

use crate::common::{example, ok, read_csv};

/// Largest validation error after calibration (mm or rad): a few times the
/// 1 µm simulated noise.
const CALIBRATED_MAX: f64 = 0.01;
/// Largest error of compensated commands on the true machine (mm or rad).
const COMPENSATED_MAX: f64 = 0.01;
/// The uncalibrated machine must be off by more than this (mm or rad), so
/// that the checks above mean something.
const UNCALIBRATED_MIN: f64 = 0.05;

/// The largest error of a report's validation statistics (`before` or
/// `after`): the distance error (mm) and, for tools with an orientation, the
/// angle error (rad).
fn worst(report: &serde_json::Value, which: &str) -> f64 {
    let s = &report["validation"]["accuracy"][which];
    let d = s["distance_max"].as_f64().unwrap();
    s["angle_max"].as_f64().map_or(d, |a| d.max(a))
}

fn end_to_end(name: &str, truth: &str, poses: &str) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example(name);
    std::fs::write(d.join("truth.toml"), truth).unwrap();
    let m = ["--mechanism", mech.as_str()];
    let sim = |out: &str, n: &str, seed: &str| {
        let mut a = vec![
            "simulate",
            "--quiet",
            "--truth",
            "truth.toml",
            "--noise",
            "0.001",
        ];
        a.extend(["--grid", n, "--seed", seed, "--out", out]);
        a.extend(m);
        ok(d, &a);
    };
    sim("data.csv", poses, "1");
    sim("val.csv", "20", "2");
    let analysis = ok(d, &[&["analyze", "--data", "data.csv"][..], &m].concat());
    assert!(analysis.contains("are identifiable"), "{name}: {analysis}");
    let summary = ok(
        d,
        &[
            &[
                "calibrate",
                "--data",
                "data.csv",
                "--validate",
                "val.csv",
                "--out",
                "cal.toml",
                "--report",
                "cal.json",
            ][..],
            &m,
        ]
        .concat(),
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("cal.json")).unwrap()).unwrap();
    assert!(
        report["validation"]["accuracy"]["before"]["distance_max"]
            .as_f64()
            .unwrap()
            > UNCALIBRATED_MIN,
        "{name}: {summary}"
    );
    assert!(
        worst(&report, "after") < CALIBRATED_MAX,
        "{name}: {summary}"
    );
    // Compensate the validation targets with the calibrated parameters and
    // run the commands on the true machine.
    ok(
        d,
        &[
            &[
                "compensate",
                "--params",
                "cal.toml",
                "--targets",
                "val.csv",
                "--out",
                "comp.csv",
            ][..],
            &m,
        ]
        .concat(),
    );
    ok(
        d,
        &[
            &[
                "predict",
                "--quiet",
                "--params",
                "truth.toml",
                "--commands",
                "comp.csv",
                "--out",
                "reached.csv",
            ][..],
            &m,
        ]
        .concat(),
    );
    let (h, targets) = read_csv(&d.join("val.csv"));
    let (hr, reached) = read_csv(&d.join("reached.csv"));
    let tcols: Vec<usize> = (0..h.len())
        .filter(|&i| h[i].starts_with("target_"))
        .collect();
    for (t, r) in targets.iter().zip(&reached) {
        for &c in &tcols {
            let axis = h[c].trim_start_matches("target_");
            let k = hr.iter().position(|x| x == axis).unwrap();
            assert!(
                (t[c] - r[k]).abs() < COMPENSATED_MAX,
                "{name}: target {} reached {}",
                t[c],
                r[k]
            );
        }
    }
}

#[test]
fn five_bar_end_to_end() {
    end_to_end(
        "five-bar",
        "l1 = 200.3\nl4 = 249.8\nA2x = 100.2\ndq1 = 0.002\n",
        "25",
    );
}

#[test]
fn three_rrr_end_to_end() {
    end_to_end(
        "3-rrr",
        "a2 = 200.3\nb3 = 199.8\nA3y = -149.7\nC2x = -69.1\ndq1 = 0.002\ndq3 = -0.001\n",
        "40",
    );
}

#[test]
fn four_rrr_end_to_end() {
    end_to_end(
        "4-rrr",
        "a2 = 200.3\nb3 = 199.8\nA3y = -233.0\nC2x = -113.3\ndq1 = 0.002\ndq4 = -0.002\n",
        "40",
    );
}

#[test]
fn gough_stewart_6_end_to_end() {
    end_to_end(
        "gough-stewart-6",
        "a1x = 492.7\nb3z = 0.3\na5y = -383.2\ndL2 = 0.2\ndL6 = -0.15\n",
        "60",
    );
}

#[test]
fn gough_stewart_8_end_to_end() {
    end_to_end(
        "gough-stewart-8",
        "a1x = 489.4\nb3z = 0.3\na5y = 103.7\ndL2 = 0.2\ndL8 = -0.15\n",
        "60",
    );
}

#[test]
fn gough_stewart_measured_at_target_points() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("gough-stewart-8");
    std::fs::write(d.join("truth.toml"), "a1x = 489.4\nb3z = 0.3\ndL2 = 0.2\n").unwrap();
    for (out, seed) in [("data.csv", "1"), ("val.csv", "2")] {
        ok(
            d,
            &[
                "simulate",
                "--quiet",
                "--mechanism",
                &mech,
                "--truth",
                "truth.toml",
                "--grid",
                "60",
                "--seed",
                seed,
                "--noise",
                "0.001",
                "--measure-targets",
                "--out",
                out,
            ],
        );
    }
    let (h, _) = read_csv(&d.join("data.csv"));
    assert!(
        h.contains(&"t3z".to_string()) && !h.contains(&"x".to_string()),
        "{h:?}"
    );
    let analysis = ok(d, &["analyze", "--mechanism", &mech, "--data", "data.csv"]);
    assert!(analysis.contains("are identifiable"), "{analysis}");
    let summary = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "data.csv",
            "--validate",
            "val.csv",
            "--out",
            "cal.toml",
            "--report",
            "cal.json",
        ],
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("cal.json")).unwrap()).unwrap();
    assert!(worst(&report, "after") < CALIBRATED_MAX, "{summary}");
    let cal = std::fs::read_to_string(d.join("cal.toml")).unwrap();
    assert!(cal.contains("dL2") && !cal.contains("t1x"), "{cal}");
}

#[test]
fn many_correlated_pairs_are_capped_in_the_summary() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("gough-stewart-8");
    std::fs::write(d.join("truth.toml"), "a1x = 489.4\nb3z = 0.3\ndL2 = 0.2\n").unwrap();
    ok(
        d,
        &[
            "simulate",
            "--quiet",
            "--mechanism",
            &mech,
            "--truth",
            "truth.toml",
            "--grid",
            "60",
            "--noise",
            "0.002",
            "--out",
            "data.csv",
        ],
    );
    let summary = ok(
        d,
        &[
            "calibrate",
            "--quiet",
            "--mechanism",
            &mech,
            "--data",
            "data.csv",
            "--out",
            "cal.toml",
            "--report",
            "cal.json",
        ],
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("cal.json")).unwrap()).unwrap();
    // Every joint centre free: many correlated pairs. The summary prints the
    // strongest ten and counts the rest; the report holds them all.
    let pairs = report["identifiability"]["correlations"]
        .as_array()
        .unwrap()
        .len();
    let printed = summary
        .lines()
        .filter(|l| l.trim_start().starts_with("correlated:") && l.contains(" and "))
        .count();
    assert!(
        pairs > 10,
        "{pairs} correlated pairs: the case no longer tests the cap"
    );
    assert_eq!(printed, 10, "{summary}");
    assert!(
        summary.contains(&format!("{} more pairs with |r| > 0.9", pairs - 10)),
        "{summary}"
    );
}

#[test]
fn bad_mechanism_files_name_the_file_and_the_fix() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("m.toml"), "type = \"delta\"\n").unwrap();
    crate::common::fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "m.toml",
            "--grid",
            "3",
            "--out",
            "o.csv",
        ],
        1,
        "unknown mechanism type `delta`; supported: jeong-kim-2dof, planar, gough-stewart, spatial",
    );
    let five = std::fs::read_to_string(example("five-bar")).unwrap();
    let cut = five.replace("[workspace]\nx = [-150.0, 150.0]\n", "[workspace]\n");
    std::fs::write(d.join("m.toml"), cut).unwrap();
    crate::common::fails(
        d,
        &[
            "simulate",
            "--mechanism",
            "m.toml",
            "--grid",
            "3",
            "--out",
            "o.csv",
        ],
        1,
        "[workspace] needs `x = [min, max]`",
    );
    assert!(!d.join("o.csv").exists());
}

#[test]
fn linear_delta_end_to_end() {
    end_to_end(
        "linear-delta",
        "delta_radius = 130.6\nangle_a = 3.6700\nangle_b = 5.7570\narm_a = 250.4\narm_c = 249.7\nda = 0.8\ndb = -0.5\ndc = 0.3\n",
        "40",
    );
}

#[test]
fn redundant_linear_delta_end_to_end() {
    end_to_end(
        "linear-delta-4",
        "delta_radius = 130.4\narm_b = 250.3\nda = 0.4\ndd = -0.3\n",
        "40",
    );
}

#[test]
fn rotary_delta_end_to_end() {
    end_to_end(
        "rotary-delta",
        "rb = 100.3\nlf2 = 299.6\ndq1 = 0.004\ndq3 = -0.003\n\"q2.tilt1\" = 0.002\n",
        "40",
    );
}

#[test]
fn three_prs_end_to_end() {
    end_to_end(
        "3-prs",
        "rb2 = 200.6\nds1 = 0.5\nds3 = -0.4\n\"s2.tilt1\" = 0.001\n\"leg3.angle\" = 5.7605\n",
        "40",
    );
}
