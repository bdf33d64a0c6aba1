//! Noise and units through the CLI: σ columns (any subset) and estimated
//! groups, mixed-unit summaries, units in the JSON report, errors located in
//! the data file.

use crate::common::{example, fails, json, ok};

/// Add `sigma_<axis>` columns with `value` to a CSV.
fn add_sigma(text: &str, axes: &[&str], value: &str) -> String {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .enumerate()
        .map(|(i, l)| {
            let extra: Vec<String> = axes
                .iter()
                .map(|a| {
                    if i == 0 {
                        format!("sigma_{a}")
                    } else {
                        value.to_string()
                    }
                })
                .collect();
            format!("{l},{}\n", extra.join(","))
        })
        .collect()
}

#[test]
fn mixed_units_partial_sigma_and_estimated_noise() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("4-rrr");
    let m = ["--mechanism", mech.as_str()];
    std::fs::write(
        d.join("truth.toml"),
        "a2 = 200.3\nb3 = 199.8\nC2x = -113.3\ndq1 = 0.002\n",
    )
    .unwrap();
    let sim = [
        "simulate",
        "--truth",
        "truth.toml",
        "--grid",
        "40",
        "--noise",
        "0.002",
        "--angle-noise",
        "1e-5",
        "--out",
        "data.csv",
    ];
    ok(d, &[&sim[..], &m].concat());
    let cal = |data: &str, extra: &[&str]| {
        ok(
            d,
            &[
                &[
                    "calibrate",
                    "--data",
                    data,
                    "--out",
                    "p.toml",
                    "--report",
                    "r.json",
                ][..],
                &m,
                extra,
            ]
            .concat(),
        )
    };
    // No σ columns: both groups estimated, printed with their units.
    let summary = cal("data.csv", &[]);
    assert!(
        summary.contains("noise of lengths (x, y, 80 coordinates)")
            && summary.contains("noise of angles (phi, 40 coordinates)")
            && summary.contains("µrad estimated from the residuals"),
        "{summary}"
    );
    assert!(!summary.contains("outlier"), "{summary}");
    let r = json(&d.join("r.json"));
    let noise = r["noise"].as_array().unwrap();
    assert_eq!(noise[0]["unit"], "mm");
    assert_eq!(noise[1]["unit"], "rad");
    let phi_sigma = noise[1]["sigma"].as_f64().unwrap();
    assert!(phi_sigma > 5e-6 && phi_sigma < 2e-5, "{phi_sigma}");
    assert!(r["validation"].is_null());
    // σ for x and y only: used, and phi estimated.
    let text = std::fs::read_to_string(d.join("data.csv")).unwrap();
    std::fs::write(d.join("xy.csv"), add_sigma(&text, &["x", "y"], "0.002")).unwrap();
    let summary = cal("xy.csv", &["--kfold", "4"]);
    assert!(
        summary.contains("noise of lengths (x, y, 80 coordinates): σ 2.000 µm given in the data")
            && summary.contains("noise of angles (phi, 40 coordinates)")
            && summary.contains("4-fold cross-validation"),
        "{summary}"
    );
    // A σ column of an axis the mechanism does not measure is refused.
    std::fs::write(d.join("z.csv"), add_sigma(&text, &["z"], "0.002")).unwrap();
    fails(
        d,
        &[&["calibrate", "--data", "z.csv", "--out", "p.toml"][..], &m].concat(),
        1,
        "sigma_z name nothing measured",
    );
    // One `sigma` column cannot cover mm and rad.
    let one: String = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .enumerate()
        .map(|(i, l)| format!("{l},{}\n", if i == 0 { "sigma" } else { "0.002" }))
        .collect();
    std::fs::write(d.join("one.csv"), one).unwrap();
    fails(
        d,
        &[
            &["calibrate", "--data", "one.csv", "--out", "p.toml"][..],
            &m,
        ]
        .concat(),
        1,
        "give per-axis columns sigma_x, sigma_y, sigma_phi",
    );
}

#[test]
fn prismatic_units_in_the_report_and_parameter_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("gough-stewart-6");
    let m = ["--mechanism", mech.as_str()];
    std::fs::write(d.join("truth.toml"), "a1x = 492.7\ndL2 = 0.2\n").unwrap();
    ok(
        d,
        &[
            &[
                "simulate",
                "--truth",
                "truth.toml",
                "--grid",
                "40",
                "--noise",
                "0.001",
                "--out",
                "data.csv",
            ][..],
            &m,
        ]
        .concat(),
    );
    let summary = ok(
        d,
        &[
            &[
                "calibrate",
                "--data",
                "data.csv",
                "--out",
                "p.toml",
                "--report",
                "r.json",
            ][..],
            &m,
        ]
        .concat(),
    );
    // A 6-DOF table: each row's ranges per axis below it, angles in mrad.
    assert!(
        summary
            .lines()
            .any(|l| l.trim_start().starts_with("RX ") && l.ends_with(" mrad")),
        "{summary}"
    );
    let r = json(&d.join("r.json"));
    let unit_of = |name: &str| {
        let p = r["parameters"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["name"] == name)
            .unwrap()
            .clone();
        (
            p["unit"].as_str().unwrap().to_string(),
            p["kind"].as_str().unwrap().to_string(),
        )
    };
    assert_eq!(unit_of("dL2"), ("mm".into(), "offset".into()));
    assert_eq!(unit_of("kL1"), ("N/mm".into(), "stiffness".into()));
    assert_eq!(unit_of("b3z"), ("mm".into(), "geometry".into()));
    let acc = &r["accuracy"]["after"];
    assert!(acc["angle_rms"].as_f64().is_some());
    assert_eq!(acc["axis_units"][3], "rad");
    let params = std::fs::read_to_string(d.join("p.toml")).unwrap();
    assert!(
        params.contains("# N/mm") && !params.contains("dL1 = 0.0  # rad"),
        "{params}"
    );
    assert!(
        params
            .lines()
            .any(|l| l.starts_with("dL1 ") && l.ends_with("# mm")),
        "{params}"
    );
}

#[test]
fn a_pose_that_cannot_be_assembled_is_named_with_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(
        d,
        &[
            "simulate", "--grid", "20", "--noise", "0.002", "--out", "data.csv",
        ],
    );
    let text = std::fs::read_to_string(d.join("data.csv")).unwrap();
    let mut lines: Vec<String> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(String::from)
        .collect();
    // A comment shifts the lines; pose 5 gets commands that cannot assemble.
    lines.insert(1, "# measured on Monday".into());
    let mut cells: Vec<String> = lines[6].split(',').map(String::from).collect();
    cells[2] = "3.0".into();
    cells[3] = "-2.5".into();
    lines[6] = cells.join(",");
    std::fs::write(d.join("bad.csv"), lines.join("\n")).unwrap();
    fails(
        d,
        &["calibrate", "--data", "bad.csv", "--out", "p.toml"],
        1,
        "bad.csv:7: pose 5:",
    );
    assert!(!d.join("p.toml").exists());
}

#[test]
fn tracker_data_from_a_frame_1_m_and_2_degrees_away() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("t.toml"), "l11 = 280.4\nB3x = 149.6\ndq3 = 0.002\n").unwrap();
    let frame = format!("1000,-300,{}", 2f64.to_radians());
    for (out, n, seed) in [("data.csv", "35", "1"), ("val.csv", "20", "2")] {
        ok(
            d,
            &[
                "simulate",
                "--truth",
                "t.toml",
                "--grid",
                n,
                "--seed",
                seed,
                "--noise",
                "0.002",
                "--instrument-frame",
                &frame,
                "--out",
                out,
            ],
        );
    }
    // The tracker's file does not claim the base frame: the frame is found.
    let text = std::fs::read_to_string(d.join("data.csv")).unwrap();
    assert!(!text.contains("# frame: base"));
    let summary = ok(
        d,
        &[
            "calibrate",
            "--data",
            "data.csv",
            "--validate",
            "val.csv",
            "--out",
            "p.toml",
            "--report",
            "r.json",
        ],
    );
    assert!(
        summary.contains("instrument frame in the base frame"),
        "{summary}"
    );
    assert!(!summary.contains("outlier"), "{summary}");
    let r = json(&d.join("r.json"));
    let f = r["frame"].as_array().unwrap();
    assert!((f[0].as_f64().unwrap() - 1000.0).abs() < 0.1, "{f:?}");
    assert!(
        (f[2].as_f64().unwrap() - 2f64.to_radians()).abs() < 1e-3,
        "{f:?}"
    );
    let after = r["validation"]["accuracy"]["after"]["distance_max"]
        .as_f64()
        .unwrap();
    assert!(after < 0.01, "{after}");
    let l11 = r["parameters"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == "l11")
        .unwrap()["identified"]
        .as_f64()
        .unwrap();
    assert!((l11 - 280.4).abs() < 0.02, "{l11}");
    // The parameter file holds the mechanism's parameters only.
    let params = std::fs::read_to_string(d.join("p.toml")).unwrap();
    assert!(!params.contains("frame."), "{params}");
}
