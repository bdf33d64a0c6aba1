//! `budget`: the tolerances of a mechanism file and of `--tolerance`, the
//! first-order error against Monte Carlo in the JSON, a planned calibration,
//! and bad input named with the way out.

use crate::common::{example, fails, json, ok};

/// First order against Monte Carlo (3000 samples): relative agreement.
const FIRST_ORDER_AGREES: f64 = 0.05;

#[test]
fn a_mechanism_files_tolerances_give_a_budget_that_monte_carlo_confirms() {
    let dir = tempfile::tempdir().unwrap();
    let hexapod = example("gough-stewart-6");
    let out = ok(
        dir.path(),
        &[
            "budget",
            "--mechanism",
            &hexapod,
            "--grid",
            "60",
            "--out",
            "b.json",
        ],
    );
    assert!(out.contains("tolerance budget of"), "{out}");
    assert!(
        out.contains("3000 machines drawn from the tolerances"),
        "{out}"
    );
    let b = json(&dir.path().join("b.json"));
    let first = b["first_order"]["position_rms"].as_f64().unwrap();
    let mc = b["monte_carlo"]["position_rms"].as_f64().unwrap();
    assert!(
        (first - mc).abs() / mc < FIRST_ORDER_AGREES,
        "{first} against {mc}"
    );
    let shares: f64 = b["tolerances"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["share"].as_f64().unwrap())
        .sum();
    assert!((shares - 1.0).abs() < 1e-9);
    // The file's 43 tolerances, kL1's relative one among them.
    assert_eq!(b["tolerances"].as_array().unwrap().len(), 43);
    // Other commands read past the table.
    ok(dir.path(), &["parameters", "--mechanism", &hexapod]);
}

#[test]
fn options_replace_the_tables_tolerances_and_a_plan_says_what_calibration_leaves() {
    let dir = tempfile::tempdir().unwrap();
    ok(
        dir.path(),
        &["plan", "--count", "20", "--out", "plan.csv", "--quiet"],
    );
    let out = ok(
        dir.path(),
        &[
            "budget",
            "--tolerance",
            "l11=0.05,l12=0.05",
            "--tolerance",
            "dq1=0.0005",
            "--samples",
            "0",
            "--poses",
            "plan.csv",
            "--out",
            "b.json",
        ],
    );
    assert!(
        out.contains("after a calibration measuring the tool at the poses of plan.csv"),
        "{out}"
    );
    assert!(!out.contains("machines drawn"), "{out}");
    let b = json(&dir.path().join("b.json"));
    let before = b["first_order"]["position_rms"].as_f64().unwrap();
    let after = b["after_calibration"]["position_rms"].as_f64().unwrap();
    assert!(after < 0.1 * before, "{after} against {before}");
    for t in b["tolerances"].as_array().unwrap() {
        assert!(t["sigma_after"].as_f64().unwrap() < t["sigma"].as_f64().unwrap());
    }
}

#[test]
fn bad_tolerances_are_named() {
    let dir = tempfile::tempdir().unwrap();
    fails(dir.path(), &["budget"], 2, "[tolerances]");
    fails(dir.path(), &["budget", "--tolerance", "l99=0.1"], 2, "l99");
    fails(
        dir.path(),
        &["budget", "--tolerance", "l11"],
        2,
        "NAME=SIGMA",
    );
    fails(
        dir.path(),
        &["budget", "--tolerance", "l11=-1"],
        2,
        "standard deviation",
    );
    fails(
        dir.path(),
        &["budget", "--tolerance", "dq1=20%"],
        2,
        "0 nominally",
    );
    std::fs::write(
        dir.path().join("m.toml"),
        "type = \"jeong-kim-2dof\"\n[tolerances]\nl11 = \"wide\"\n",
    )
    .unwrap();
    fails(dir.path(), &["budget", "--mechanism", "m.toml"], 1, "`l11`");
    assert!(!dir.path().join("b.json").exists());
}

/// A budget of tolerances that move nothing to first order (a stiffness
/// without a load) says so, not "+6042.8 %" of rounding (issue 50).
#[test]
fn a_budget_with_nothing_to_first_order_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(
        dir.path(),
        &[
            "budget",
            "--tolerance",
            "k1=10%",
            "--samples",
            "50",
            "--grid",
            "10",
        ],
    );
    assert!(out.contains("none, as to first order"), "{out}");
    assert!(!out.contains("% from first order"), "{out}");
    assert!(out.contains("0.0%"), "{out}");
}
