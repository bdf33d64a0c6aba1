//! End-to-end tests of the command-line tool.

/// Agreement of predict with simulate on noise-free data (mm).
const SAME_MM: f64 = 1e-9;

use crate::common::{fails, ok, read_csv, run};
use std::path::{Path, PathBuf};

fn example_mechanism() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/jeong-kim-2dof/mechanism.toml")
}

#[test]
fn simulate_then_predict_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example_mechanism();
    let mech = mech.to_str().unwrap();
    std::fs::write(
        d.join("truth.toml"),
        "l11 = 280.3\ndq3 = 0.002\nD2 = 214.8\n",
    )
    .unwrap();
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            mech,
            "--truth",
            "truth.toml",
            "--grid",
            "12",
            "--out",
            "data.csv",
        ],
    );
    let (header, rows) = read_csv(&d.join("data.csv"));
    assert_eq!(header, ["target_x", "target_y", "q1", "q2", "q3", "x", "y"]);
    assert_eq!(rows.len(), 12);
    ok(
        d,
        &[
            "predict",
            "--mechanism",
            mech,
            "--params",
            "truth.toml",
            "--commands",
            "data.csv",
            "--out",
            "pred.csv",
        ],
    );
    let (ph, prows) = read_csv(&d.join("pred.csv"));
    assert_eq!(
        ph,
        [
            "q1",
            "q2",
            "q3",
            "x",
            "y",
            "deflection_q1",
            "deflection_q2",
            "deflection_q3",
            "torque_q1",
            "torque_q2",
            "torque_q3"
        ]
    );
    for (a, b) in rows.iter().zip(&prows) {
        assert!(
            (a[5] - b[3]).abs() < SAME_MM && (a[6] - b[4]).abs() < SAME_MM,
            "{a:?} vs {b:?}"
        );
        // Internal torques appear: the actuators fight.
        assert!(b[8..11].iter().any(|t| t.abs() > 0.1));
        // Deflection = −torque/stiffness.
        assert!((b[5] + b[8] / 8360.0).abs() < 1e-12);
    }
    // The other models run and differ from exact by little.
    for model in ["linear", "rigid"] {
        ok(
            d,
            &[
                "predict",
                "--params",
                "truth.toml",
                "--model",
                model,
                "--commands",
                "data.csv",
                "--out",
                "m.csv",
            ],
        );
        let (_, m) = read_csv(&d.join("m.csv"));
        for (a, b) in m.iter().zip(&prows) {
            assert!((a[3] - b[3]).hypot(a[4] - b[4]) < 1.0);
        }
    }
}

#[test]
fn simulate_with_targets_file_and_noise_is_seeded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("t.csv"),
        "name,target_y,target_x\na,165,-30\nb,180,0\n",
    )
    .unwrap();
    for out in ["a.csv", "b.csv"] {
        ok(
            d,
            &[
                "simulate",
                "--targets",
                "t.csv",
                "--noise",
                "0.002",
                "--seed",
                "5",
                "--out",
                out,
            ],
        );
    }
    let a = std::fs::read(d.join("a.csv")).unwrap();
    assert_eq!(a, std::fs::read(d.join("b.csv")).unwrap());
    let (_, rows) = read_csv(&d.join("a.csv"));
    assert_eq!(rows[0][0], -30.0);
    assert!((rows[0][2].to_degrees() - 83.735).abs() < 1e-3);
    // Noise of 2 µm: the measured point is within 10 µm of the target.
    assert!((rows[0][5] + 30.0).abs() < 0.01 && (rows[0][6] - 165.0).abs() < 0.01);
}

#[test]
fn demo_prints_the_before_statistics() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(dir.path(), &["demo", "--out-dir", "demo"]);
    assert!(out.contains("before calibration"), "{out}");
    assert!(dir.path().join("demo/measurements.csv").exists());
}

#[test]
fn bad_input_gets_a_clear_message_and_exit_code() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("c.csv"), "q1,q2,q3\n1.4614,3.5609,-2.5939\n").unwrap();
    std::fs::write(d.join("bad.toml"), "l13 = 1.0\n").unwrap();
    fails(
        d,
        &[
            "predict",
            "--params",
            "bad.toml",
            "--commands",
            "c.csv",
            "--out",
            "o.csv",
        ],
        1,
        "unknown parameter `l13`",
    );
    std::fs::write(d.join("nan.csv"), "q1,q2,q3\n1.4614,NaN,-2.5939\n").unwrap();
    fails(
        d,
        &["predict", "--commands", "nan.csv", "--out", "o.csv"],
        1,
        "nan.csv:2: column `q2`",
    );
    std::fs::write(d.join("missing.csv"), "q1,q3\n1.4,2.0\n").unwrap();
    fails(
        d,
        &["predict", "--commands", "missing.csv", "--out", "o.csv"],
        1,
        "missing column `q2`",
    );
    fails(
        d,
        &["predict", "--commands", "nope.csv", "--out", "o.csv"],
        1,
        "nope.csv",
    );
    std::fs::write(d.join("far.csv"), "target_x,target_y\n900,900\n").unwrap();
    fails(
        d,
        &["simulate", "--targets", "far.csv", "--out", "o.csv"],
        1,
        "far.csv:2",
    );
    std::fs::write(d.join("syntax.toml"), "l11 = = 3\n").unwrap();
    fails(
        d,
        &[
            "predict",
            "--params",
            "syntax.toml",
            "--commands",
            "c.csv",
            "--out",
            "o.csv",
        ],
        1,
        "syntax.toml",
    );
    fails(d, &["predict", "--commands", "c.csv"], 2, "--out");
    fails(
        d,
        &[
            "predict",
            "--model",
            "stiff",
            "--commands",
            "c.csv",
            "--out",
            "o.csv",
        ],
        2,
        "stiff",
    );
    std::fs::write(
        d.join("mech.toml"),
        "type = \"jeong-kim-2dof\"\n[nominal]\nl11 = -5.0\n",
    )
    .unwrap();
    fails(
        d,
        &[
            "predict",
            "--mechanism",
            "mech.toml",
            "--commands",
            "c.csv",
            "--out",
            "o.csv",
        ],
        1,
        "must be positive",
    );
}

#[test]
fn a_failed_run_leaves_the_earlier_output_alone() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("out.csv"), "earlier\n").unwrap();
    std::fs::write(d.join("c.csv"), "q1,q2,q3\n1.4614,3.5609,-2.5939\n0,3,1\n").unwrap();
    let o = run(d, &["predict", "--commands", "c.csv", "--out", "out.csv"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("c.csv:3"));
    assert_eq!(
        std::fs::read_to_string(d.join("out.csv")).unwrap(),
        "earlier\n"
    );
    let names: Vec<_> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 2, "no temporary file left: {names:?}");
}

/// `parameters` lists every parameter with its kind, unit, nominal value and
/// default freedom, as text and as JSON, for every shipped mechanism; the
/// JSON's names are the ones a truth file may set (a simulation with one
/// runs) and its nominal values are the description's.
#[test]
fn parameters_lists_what_a_truth_file_may_set() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    let mut mechs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path().join("mechanism.toml"))
        .filter(|p| p.exists())
        .collect();
    mechs.sort();
    assert!(mechs.len() >= 12);
    for m in &mechs {
        let m = m.to_str().unwrap();
        let text = ok(d, &["parameters", "--mechanism", m]);
        let json: serde_json::Value =
            serde_json::from_str(&ok(d, &["parameters", "--mechanism", m, "--json"])).unwrap();
        let params = json["parameters"].as_array().unwrap();
        assert!(!params.is_empty(), "{m}");
        for p in params {
            let name = p["name"].as_str().unwrap();
            assert!(
                text.lines()
                    .any(|l| l.split_whitespace().next() == Some(name)),
                "{m}: {name} not in the text listing"
            );
            assert!(["geometry", "offset", "stiffness"].contains(&p["kind"].as_str().unwrap()));
        }
        // The first geometric parameter, moved by 0.1, is a valid truth.
        let first = params[0]["name"].as_str().unwrap();
        let nominal = params[0]["nominal"].as_f64().unwrap();
        std::fs::write(
            d.join("truth.toml"),
            format!("{first} = {}\n", nominal + 0.1),
        )
        .unwrap();
        ok(
            d,
            &[
                "simulate",
                "--quiet",
                "--mechanism",
                m,
                "--grid",
                "5",
                "--truth",
                "truth.toml",
                "--out",
                "s.csv",
            ],
        );
        assert_eq!(
            json["actuators"].as_array().unwrap().len(),
            json["joints"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|j| j["actuated"] == true)
                .count()
        );
    }
    // The built-in reference without --mechanism.
    assert!(ok(d, &["parameters"]).contains("dq3              encoder offset"));
}
