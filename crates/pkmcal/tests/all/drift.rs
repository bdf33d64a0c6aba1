//! The drift test: over seeded repeats of two calibrations of an unchanged
//! machine (drawn from the covariances the test is given), its false-alarm
//! rate is at its stated level, per parameter (Holm–Bonferroni, familywise)
//! and jointly; a 3σ change is found; bad requests are refused.

use pkmcal::identify::{Compared, DEFAULT_ALPHA, drift};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

/// Repeats of the false-alarm study.
const REPEATS: usize = 2000;
/// Allowed distance of a rate from its level: four binomial standard
/// deviations at `REPEATS`.
fn slack() -> f64 {
    4.0 * (DEFAULT_ALPHA * (1.0 - DEFAULT_ALPHA) / REPEATS as f64).sqrt()
}

/// A correlated 5-parameter covariance (σ from 1 µm to 50 µm, correlations
/// up to 0.8) and its Cholesky factor.
fn covariance() -> (Vec<Vec<f64>>, nalgebra::DMatrix<f64>) {
    let sd = [0.001, 0.005, 0.01, 0.02, 0.05];
    let c = nalgebra::DMatrix::from_fn(5, 5, |i, j| {
        let r = if i == j {
            1.0
        } else {
            0.8f64.powi((i as i32 - j as i32).abs())
        };
        r * sd[i] * sd[j]
    });
    let l = c.clone().cholesky().unwrap().l();
    (
        (0..5)
            .map(|i| (0..5).map(|j| c[(i, j)]).collect())
            .collect(),
        l,
    )
}

const NAMES: [&str; 5] = ["l11", "l12", "B2x", "B2y", "D1"];

/// A calibration of truth `t` (+ `shift` on the first parameter) with the
/// covariance's noise.
fn draw(rng: &mut StdRng, cov: &[Vec<f64>], l: &nalgebra::DMatrix<f64>, shift: f64) -> Compared {
    let z = nalgebra::DVector::from_fn(5, |_, _| StandardNormal.sample(rng));
    let e = l * z;
    Compared {
        values: NAMES
            .iter()
            .enumerate()
            .map(|(i, n)| {
                (
                    n.to_string(),
                    100.0 + e[i] + if i == 0 { shift } else { 0.0 },
                )
            })
            .collect(),
        names: NAMES.iter().map(|n| n.to_string()).collect(),
        covariance: cov.to_vec(),
        dof: None,
    }
}

#[test]
fn false_alarms_are_at_their_level_and_a_three_sigma_change_is_found() {
    let (cov, l) = covariance();
    let mut rng = StdRng::seed_from_u64(11);
    let (mut any, mut joint) = (0, 0);
    for _ in 0..REPEATS {
        let (a, b) = (draw(&mut rng, &cov, &l, 0.0), draw(&mut rng, &cov, &l, 0.0));
        let d = drift(&a, &b, DEFAULT_ALPHA).unwrap();
        any += usize::from(d.parameters.iter().any(|p| p.drifted));
        joint += usize::from(d.joint_drift);
        assert_eq!(d.dof, 5);
    }
    let (any, joint) = (any as f64 / REPEATS as f64, joint as f64 / REPEATS as f64);
    // Holm–Bonferroni holds the familywise rate at or below its level
    // (below with correlated tests); the joint χ² test at it.
    assert!(
        any <= DEFAULT_ALPHA + slack(),
        "familywise false alarms {any}"
    );
    assert!(
        any >= 0.5 * DEFAULT_ALPHA - slack(),
        "familywise false alarms {any}"
    );
    assert!(
        (joint - DEFAULT_ALPHA).abs() <= slack(),
        "joint false alarms {joint}"
    );
    // A change of 3σ (of the difference) on one parameter.
    let sigma = (2.0 * cov[0][0]).sqrt();
    let mut found = 0;
    for _ in 0..REPEATS {
        let (a, b) = (
            draw(&mut rng, &cov, &l, 0.0),
            draw(&mut rng, &cov, &l, 3.0 * sigma),
        );
        let d = drift(&a, &b, DEFAULT_ALPHA).unwrap();
        found += usize::from(d.parameters.iter().any(|p| p.drifted && p.name == "l11"));
    }
    let power = found as f64 / REPEATS as f64;
    // P(|Z + 3| > z(α/10)) ≈ 0.66 for the smallest of five p-values.
    assert!(power > 0.55, "power {power}");
}

#[test]
fn against_nominal_and_bad_requests() {
    let (cov, l) = covariance();
    let mut rng = StdRng::seed_from_u64(3);
    let a = draw(&mut rng, &cov, &l, 0.0);
    let nominal = Compared {
        values: NAMES.iter().map(|n| (n.to_string(), 100.0)).collect(),
        names: vec![],
        covariance: vec![],
        dof: None,
    };
    let d = drift(&nominal, &a, DEFAULT_ALPHA).unwrap();
    assert_eq!(d.parameters.len(), 5);
    assert!(
        d.parameters
            .windows(2)
            .all(|w| w[0].p_value <= w[1].p_value)
    );
    assert!(drift(&a, &a, 0.0).is_err());
    assert!(drift(&a, &a, 1.5).is_err());
    let other = Compared {
        values: vec![("k1".into(), 1.0)],
        names: vec!["k1".into()],
        covariance: vec![vec![1.0]],
        dof: None,
    };
    assert!(
        drift(&a, &other, DEFAULT_ALPHA)
            .unwrap_err()
            .to_string()
            .contains("nothing to compare")
    );
    // Identical calibrations: no drift at all.
    let same = drift(&a, &a, DEFAULT_ALPHA).unwrap();
    assert!(same.parameters.iter().all(|p| !p.drifted && p.z == 0.0));
    assert_eq!(same.chi2, 0.0);
}

/// The change at the tool: over seeded pairs of calibrations of an
/// unchanged reference mechanism (drawn about nominal from a correlated
/// covariance), each target is called beyond the covariances at its stated
/// rate; a change of `l11` well beyond the tool's uncertainty is found at
/// most targets, its size the predicted tool change.
#[test]
fn the_change_at_the_tool_is_judged_against_both_covariances() {
    use pkmcal::Mechanism;
    let m = pkmcal::JeongKim2Dof::new();
    let spec = m.spec();
    let (cov, l) = covariance();
    let around = |rng: &mut StdRng, shift: f64| -> Compared {
        let mut c = draw(rng, &cov, &l, shift);
        for (n, v) in &mut c.values {
            *v += spec.nominal[spec.param_index(n).unwrap()] - 100.0;
        }
        c
    };
    let targets = pkmcal::apply::budget::budget_targets(&m, 12).unwrap();
    let mut rng = StdRng::seed_from_u64(17);
    let repeats = 300;
    let mut beyond = 0;
    for _ in 0..repeats {
        let (a, b) = (around(&mut rng, 0.0), around(&mut rng, 0.0));
        let w =
            pkmcal::apply::tooldrift::workspace_drift(&m, &a, &b, &targets, DEFAULT_ALPHA).unwrap();
        assert_eq!(w.targets.len(), targets.len());
        beyond += w.beyond;
    }
    let rate = beyond as f64 / (repeats * targets.len()) as f64;
    // Targets of one pair are correlated: a wider slack than independent
    // draws would need.
    assert!(
        (rate - DEFAULT_ALPHA).abs() < 0.025,
        "false alarms at {rate}"
    );
    let a = around(&mut rng, 0.0);
    let mut b = a.clone();
    b.values[0].1 += 0.2;
    let w = pkmcal::apply::tooldrift::workspace_drift(&m, &a, &b, &targets, DEFAULT_ALPHA).unwrap();
    assert!(w.beyond >= targets.len() / 2, "{}", w.beyond);
    let big = &w.targets[w.largest];
    assert!(
        big.distance > 0.05 && big.distance < 0.5,
        "{}",
        big.distance
    );
}
