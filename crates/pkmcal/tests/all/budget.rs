//! Tolerance budgets: the first-order error over the workspace agrees with
//! machines drawn from the tolerances through the exact model (Monte Carlo),
//! on a planar redundant mechanism and on a Gough–Stewart platform; shares
//! add up and rank what they should; a planned calibration leaves less; the
//! tolerance text rule and bad input.

use crate::common::{gough_stewart, spread};
use pkmcal::apply::budget::{
    Budget, BudgetOptions, PlannedCalibration, Tolerance, budget, resolve_tolerances,
};
use pkmcal::{JeongKim2Dof, Mechanism, Model, Noise};

/// Monte Carlo samples (the minimum).
const SAMPLES: usize = 3000;
/// First order against Monte Carlo: relative agreement of the RMS errors.
const FIRST_ORDER_AGREES: f64 = 0.05;
/// Shares add up to 1 to rounding.
const SUM_TOL: f64 = 1e-12;

fn run<M: Mechanism>(
    m: &M,
    names: &[(&str, &str)],
    samples: usize,
    plan: Option<PlannedCalibration>,
) -> Budget {
    let given: Vec<(String, Tolerance)> = names
        .iter()
        .map(|(n, t)| (n.to_string(), Tolerance::parse(t).unwrap()))
        .collect();
    let tol = resolve_tolerances(m.spec(), &given).unwrap();
    budget(
        m,
        &spread(m, 30),
        &tol,
        &BudgetOptions {
            model: Model::Exact,
            force: vec![],
            samples,
            seed: 7,
            calibration: plan,
        },
    )
    .unwrap()
}

fn agrees(b: &Budget) {
    let mc = b.monte_carlo.as_ref().unwrap();
    let gap = (mc.position_rms - b.first_order.position_rms).abs() / mc.position_rms;
    assert!(
        gap < FIRST_ORDER_AGREES,
        "first order {} mm, Monte Carlo {} mm ({:.1} %)",
        b.first_order.position_rms,
        mc.position_rms,
        100.0 * gap
    );
    for (a, (f, m)) in b.first_order.axis_rms.iter().zip(&mc.axis_rms).enumerate() {
        assert!(
            (f - m).abs() / m < FIRST_ORDER_AGREES,
            "axis {a}: {f} against {m}"
        );
    }
    let total: f64 = b.tolerances.iter().map(|t| t.share).sum();
    assert!((total - 1.0).abs() < SUM_TOL, "shares add up to {total}");
    assert!(b.tolerances.windows(2).all(|w| w[0].share >= w[1].share));
}

#[test]
fn first_order_matches_monte_carlo_on_the_reference() {
    let m = JeongKim2Dof::new();
    let b = run(
        &m,
        &[
            ("l11", "0.05"),
            ("l12", "0.05"),
            ("B2x", "0.1"),
            ("dq1", "0.0005"),
            ("l31", "0.02%"),
        ],
        SAMPLES,
        None,
    );
    agrees(&b);
    assert_eq!(b.samples, SAMPLES);
    // A relative tolerance is a fraction of the nominal value.
    let l31 = b.tolerances.iter().find(|t| t.name == "l31").unwrap();
    let nominal = m.spec().nominal[m.spec().param_index("l31").unwrap()];
    assert_eq!(l31.sigma, 0.0002 * nominal.abs());
}

#[test]
fn first_order_matches_monte_carlo_on_a_hexapod() {
    let m = gough_stewart("gough-stewart-6");
    let names: Vec<(String, String)> = m
        .spec()
        .param_names()
        .iter()
        .filter(|n| n.starts_with('a') || n.starts_with('b') || n.starts_with("dL"))
        .map(|n| (n.to_string(), "0.05".to_string()))
        .collect();
    let refs: Vec<(&str, &str)> = names
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    agrees(&run(&m, &refs, SAMPLES, None));
}

#[test]
fn the_largest_tolerance_has_the_largest_share_and_calibration_leaves_less() {
    let m = JeongKim2Dof::new();
    let b = run(
        &m,
        &[("l11", "0.5"), ("l12", "0.01"), ("l21", "0.01")],
        0,
        None,
    );
    assert_eq!(b.tolerances[0].name, "l11");
    assert!(b.tolerances[0].share > 0.9);
    assert!(b.monte_carlo.is_none());
    let plan = PlannedCalibration {
        targets: spread(&m, 12),
        noise: Noise::lengths(0.002),
    };
    let c = run(
        &m,
        &[("l11", "0.5"), ("l12", "0.01"), ("l21", "0.01")],
        0,
        Some(plan),
    );
    let after = c.after_calibration.as_ref().unwrap();
    assert!(after.position_rms < 0.1 * c.first_order.position_rms);
    for t in &c.tolerances {
        assert!(t.sigma_after.unwrap() < t.sigma, "{}", t.name);
    }
    // The same numbers without the plan.
    assert_eq!(c.first_order, b.first_order);
}

#[test]
fn tolerance_text_and_bad_input() {
    assert_eq!(Tolerance::parse("0.1").unwrap(), Tolerance::Absolute(0.1));
    assert_eq!(Tolerance::parse(" 20% ").unwrap(), Tolerance::Relative(0.2));
    for bad in ["", "-1", "0", "abc", "nan", "inf", "%", "-5%"] {
        assert!(Tolerance::parse(bad).is_err(), "{bad}");
    }
    let m = JeongKim2Dof::new();
    let spec = m.spec();
    let err = |g: &[(&str, Tolerance)]| {
        let g: Vec<(String, Tolerance)> = g.iter().map(|(n, t)| (n.to_string(), *t)).collect();
        resolve_tolerances(spec, &g).unwrap_err().to_string()
    };
    assert!(err(&[("l99", Tolerance::Absolute(0.1))]).contains("l99"));
    assert!(
        err(&[
            ("l11", Tolerance::Absolute(0.1)),
            ("l11", Tolerance::Absolute(0.2))
        ])
        .contains("two tolerances")
    );
    // dq1 is 0 nominally: a percentage of it is nothing.
    assert!(err(&[("dq1", Tolerance::Relative(0.2))]).contains("0 nominally"));
    let none = budget(
        &m,
        &spread(&m, 5),
        &[],
        &BudgetOptions {
            model: Model::Exact,
            force: vec![],
            samples: 0,
            seed: 1,
            calibration: None,
        },
    );
    assert!(none.unwrap_err().to_string().contains("no tolerance"));
}
