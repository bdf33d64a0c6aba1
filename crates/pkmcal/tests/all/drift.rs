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
        priors: vec![],
        nuisance: vec![],
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
        priors: vec![],
        nuisance: vec![],
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
        priors: vec![],
        nuisance: vec![],
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

/// Drift between calibrations of `examples/gough-stewart-6` as shipped,
/// with its tolerances (a tracker's three target points, 40 spread poses,
/// 5 µm, each pair's machine drawn from the tolerances): an unchanged
/// machine is called drifted by the joint test, the verdict, at its level;
/// base joint 2 moved 0.08 mm along x (`a2x`, about 3 of its calibrated σ)
/// is found by it in at least 90 % of pairs.
fn hexapod_drift(first: u64, pairs: u64) -> (f64, f64, f64, f64) {
    use pkmcal::identify::Prior;
    use pkmcal::{CalibrationOptions, MeasurementModel, Mechanism, Model, Noise, Params};
    use rand_distr::Normal;
    let m = crate::common::gough_stewart("gough-stewart-6");
    let spec = m.spec();
    let points = [
        vec![150.0, 0.0, 60.0],
        vec![-75.0, 129.904, 60.0],
        vec![-75.0, -129.904, 60.0],
    ];
    let tracker = MeasurementModel::targets(spec, &points).unwrap();
    let tolerances = crate::common::example_tolerances(spec, "gough-stewart-6");
    let targets = crate::common::spread(&m, 40);
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.priors = tolerances
        .iter()
        .map(|(n, sigma)| Prior {
            index: spec.param_index(n).unwrap(),
            sigma: *sigma,
        })
        .collect();
    opts.free = pkmcal::identify::free_with_priors(spec, &tracker, &opts.free, &opts.priors, &[]);
    let a2x = spec.param_index("a2x").unwrap();
    let calibrate = |truth: &Params, seed: u64| {
        let data =
            pkmcal::simulate(&m, &tracker, truth, &targets, Noise::lengths(0.005), seed).unwrap();
        Compared::from_calibration(
            &pkmcal::calibrate(&m, &tracker, &data, &Params::nominal(spec), &opts).unwrap(),
        )
    };
    let (mut false_joint, mut false_any, mut found_joint, mut found_a2x) = (0, 0, 0, 0);
    let mut found_before = 0;
    for r in first..first + pairs {
        let mut rng = StdRng::seed_from_u64(r);
        let mut truth = Params::nominal(spec);
        for (n, t) in &tolerances {
            truth.values[spec.param_index(n).unwrap()] +=
                Normal::new(0.0, *t).unwrap().sample(&mut rng);
        }
        let mut moved = truth.clone();
        moved.values[a2x] += 0.08;
        let base = calibrate(&truth, 3 * r);
        let same = drift(&base, &calibrate(&truth, 3 * r + 1), DEFAULT_ALPHA).unwrap();
        false_joint += usize::from(same.joint_drift);
        false_any += usize::from(same.parameters.iter().any(|p| p.drifted));
        let later = calibrate(&moved, 3 * r + 2);
        let changed = drift(&base, &later, DEFAULT_ALPHA).unwrap();
        found_before += usize::from(joint_before(&base, &later) < DEFAULT_ALPHA);
        assert!(changed.data_only);
        assert_eq!(changed.untested, vec!["kL1".to_string()]);
        found_joint += usize::from(changed.joint_drift);
        found_a2x += usize::from(
            changed
                .parameters
                .iter()
                .any(|p| p.drifted && p.name == "a2x"),
        );
    }
    let rate = |k: usize| k as f64 / pairs as f64;
    let out = (
        rate(false_joint),
        rate(false_any),
        rate(found_joint),
        rate(found_a2x),
    );
    println!(
        "gough-stewart-6, {pairs} pairs: false alarms {:.3} (joint), {:.3} (Holm); a2x + 0.08 mm found {:.3} (joint), {:.3} (a2x named by Holm), {:.3} by the joint test before",
        out.0,
        out.1,
        out.2,
        out.3,
        rate(found_before)
    );
    out
}

/// The joint test's p-value as it was before (issue 49): the calibrations'
/// posterior values and covariances, the pseudo-inverse of `C_a + C_b`
/// cut at 1e-12 of its largest eigenvalue in the parameters' own units.
fn joint_before(a: &Compared, b: &Compared) -> f64 {
    use statrs::distribution::{ContinuousCDF, FisherSnedecor};
    let n = a.names.len();
    let value = |c: &Compared, x: &str| c.values.iter().find(|(m, _)| m == x).unwrap().1;
    let c = nalgebra::DMatrix::from_fn(n, n, |i, j| a.covariance[i][j] + b.covariance[i][j]);
    let d = nalgebra::DVector::from_fn(n, |i, _| value(b, &a.names[i]) - value(a, &a.names[i]));
    let eig = c.symmetric_eigen();
    let top = eig.eigenvalues.max();
    let (mut chi2, mut dof) = (0.0, 0);
    for (k, &l) in eig.eigenvalues.iter().enumerate() {
        if l > 1e-12 * top {
            chi2 += eig.eigenvectors.column(k).dot(&d).powi(2) / l;
            dof += 1;
        }
    }
    let nu = a.dof.unwrap() + b.dof.unwrap();
    FisherSnedecor::new(dof as f64, nu)
        .unwrap()
        .sf(chi2 / dof as f64)
}

#[test]
fn a_hexapod_s_moved_joint_is_found_and_unchanged_pairs_are_not() {
    let (false_joint, false_any, found, _) = hexapod_drift(1, 60);
    assert!((false_joint - DEFAULT_ALPHA).abs() <= 0.06, "{false_joint}");
    assert!(false_any <= DEFAULT_ALPHA + 0.06, "{false_any}");
    assert!(found >= 0.85, "{found}");
}

#[test]
#[ignore = "the full study, 500 pairs (minutes); figures in BENCHMARKS.md"]
fn a_hexapod_s_moved_joint_is_found_over_500_pairs() {
    let (false_joint, false_any, found, _) = hexapod_drift(1000, 500);
    assert!((false_joint - DEFAULT_ALPHA).abs() <= 0.02, "{false_joint}");
    assert!(false_any <= DEFAULT_ALPHA + 0.02, "{false_any}");
    assert!(found >= 0.90, "{found}");
}

/// Parameters of the prior-held study: the mechanism's, then the
/// instrument's.
const HELD_MECHANISM: usize = 20;
const HELD_INSTRUMENT: usize = 2;
/// Readings of each calibration in it: far fewer than parameters.
const HELD_READINGS: usize = 8;
/// Mechanism parameters without a prior (seen by the data only).
const HELD_FREE: usize = 3;
/// Each calibration's Jacobian differs from the other's by this much
/// (relative): two fits linearised at nearby solutions.
const HELD_WOBBLE: f64 = 1e-4;
/// Repeats of the prior-held study.
const HELD_REPEATS: usize = 600;

/// One MAP calibration of the linear model `y = J θ + ε` (unit noise) with
/// priors `σ` (0: none) centred on `μ`, as a fit reports it: its values,
/// its covariance `(JᵀJ + P)⁻¹` and its priors, the instrument's
/// parameters as nuisance.
fn map_calibration(
    j: &nalgebra::DMatrix<f64>,
    truth: &nalgebra::DVector<f64>,
    mu: &nalgebra::DVector<f64>,
    sigma: &[f64],
    rng: &mut StdRng,
) -> Compared {
    let n = truth.len();
    let noise = nalgebra::DVector::from_fn(j.nrows(), |_, _| StandardNormal.sample(rng));
    let y = j * truth + noise;
    let p = nalgebra::DVector::from_fn(n, |i, _| {
        if sigma[i] > 0.0 {
            sigma[i].powi(-2)
        } else {
            0.0
        }
    });
    let f = j.transpose() * j + nalgebra::DMatrix::from_diagonal(&p);
    let c = f.clone().try_inverse().unwrap();
    let est = &c * (j.transpose() * y + p.component_mul(mu));
    let name = |i: usize| {
        if i < HELD_MECHANISM {
            format!("m{i}")
        } else {
            format!("bed.{}", i - HELD_MECHANISM)
        }
    };
    Compared {
        values: (0..n).map(|i| (name(i), est[i])).collect(),
        names: (0..n).map(name).collect(),
        covariance: (0..n)
            .map(|a| (0..n).map(|b| c[(a, b)]).collect())
            .collect(),
        dof: None,
        priors: (0..n)
            .filter(|&i| sigma[i] > 0.0)
            .map(|i| pkmcal::identify::PriorTerm {
                name: name(i),
                index: i,
                centre: mu[i],
                sigma: sigma[i],
                constraint: false,
            })
            .collect(),
        nuisance: (HELD_MECHANISM..n).map(name).collect(),
    }
}

/// Two calibrations held mostly by their tolerances (8 readings, 22
/// parameters, units 1e-3 to 1e3 apart, an instrument with tolerances of
/// its own), linearised at nearby solutions: the joint test compares the
/// directions the data see with the instrument integrated out (8 − 2),
/// never more than the readings, and false-alarms at its level. It once
/// counted rounding errors as 20 directions from 13 readings and said
/// "changed" on every pair.
#[test]
fn prior_held_calibrations_compare_what_the_data_see() {
    let n = HELD_MECHANISM + HELD_INSTRUMENT;
    let mut rng = StdRng::seed_from_u64(49);
    let units: Vec<f64> = (0..n).map(|i| 10f64.powi(i as i32 % 7 - 3)).collect();
    let base = nalgebra::DMatrix::from_fn(HELD_READINGS, n, |_, c| {
        let z: f64 = StandardNormal.sample(&mut rng);
        z / units[c]
    });
    let wobble = |rng: &mut StdRng| {
        nalgebra::DMatrix::from_fn(HELD_READINGS, n, |r, c| {
            let z: f64 = StandardNormal.sample(rng);
            base[(r, c)] * (1.0 + HELD_WOBBLE * z)
        })
    };
    let sigma: Vec<f64> = (0..n)
        .map(|i| if i < HELD_FREE { 0.0 } else { 0.5 * units[i] })
        .collect();
    let mu = nalgebra::DVector::from_fn(n, |i, _| 100.0 * units[i]);
    let truth = nalgebra::DVector::from_fn(n, |i, _| {
        let z: f64 = StandardNormal.sample(&mut rng);
        mu[i] + sigma[i].max(units[i]) * z
    });
    let (ja, jb) = (wobble(&mut rng), wobble(&mut rng));
    let mut alarms = 0;
    for _ in 0..HELD_REPEATS {
        let a = map_calibration(&ja, &truth, &mu, &sigma, &mut rng);
        let b = map_calibration(&jb, &truth, &mu, &sigma, &mut rng);
        let d = drift(&a, &b, DEFAULT_ALPHA).unwrap();
        assert_eq!(d.dof, HELD_READINGS - HELD_INSTRUMENT, "{d:?}");
        assert!(d.data_only);
        alarms += usize::from(d.joint_drift);
    }
    let rate = alarms as f64 / HELD_REPEATS as f64;
    let slack = 4.0 * (DEFAULT_ALPHA * (1.0 - DEFAULT_ALPHA) / HELD_REPEATS as f64).sqrt();
    assert!(
        (rate - DEFAULT_ALPHA).abs() < slack,
        "false alarms {alarms} of {HELD_REPEATS}"
    );
    // A change the data see, of 5 σ of the difference along it, is found.
    let mut moved = truth.clone();
    moved[0] += 5.0 * 2f64.sqrt() * units[0];
    let mut seen = 0;
    for _ in 0..HELD_REPEATS / 10 {
        let a = map_calibration(&ja, &truth, &mu, &sigma, &mut rng);
        let b = map_calibration(&jb, &moved, &mu, &sigma, &mut rng);
        seen += usize::from(drift(&a, &b, DEFAULT_ALPHA).unwrap().joint_drift);
    }
    assert!(
        seen >= HELD_REPEATS / 10 * 8 / 10,
        "seen {seen} of {}",
        HELD_REPEATS / 10
    );
}

/// Pairs a setting of the drift study on the reference mechanism is run
/// over.
const SETTING_PAIRS: u64 = 150;
/// The reference's measurement noise in that study (mm).
const SETTING_NOISE_MM: f64 = 0.002;
/// A tight prior's σ over the parameter's σ from the data alone; a loose
/// one's.
const TIGHT: f64 = 1.0;
const LOOSE: f64 = 10.0;

/// How the study's calibrations weigh their readings.
#[derive(Clone, Copy, Debug)]
enum Sigma {
    /// Each reading's σ given with the data: known.
    Given,
    /// Estimated from the residuals.
    Estimated,
    /// Stated, as a prior of the estimate worth its default readings.
    Stated,
}

/// The joint test's false-alarm rate over [`SETTING_PAIRS`] pairs of
/// calibrations of one unchanged reference machine (35 spread poses, each
/// pair's machine drawn from the priors), and the rate at which `l11`
/// moved by 4 σ of the difference (the data's σ) is found.
fn reference_setting(sigma: Sigma, prior: Option<f64>) -> (f64, f64) {
    use pkmcal::identify::Prior;
    use pkmcal::{
        CalibrationOptions, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params,
    };
    use rand_distr::Normal;
    let m = JeongKim2Dof::new();
    let spec = m.spec();
    let tool = MeasurementModel::tool(spec);
    let targets: Vec<Vec<f64>> = pkmcal::apply::workspace::spread_targets(&m, 35)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let base = CalibrationOptions::new(spec, Model::Exact);
    let run = |opts: &CalibrationOptions, truth: &Params, seed: u64| {
        let mut data = pkmcal::simulate(
            &m,
            &tool,
            truth,
            &targets,
            Noise::lengths(SETTING_NOISE_MM),
            seed,
        )
        .unwrap();
        if matches!(sigma, Sigma::Given) {
            for d in &mut data {
                d.sigma = vec![Some(SETTING_NOISE_MM); d.measured.len()];
            }
        }
        pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), opts).unwrap()
    };
    // The data's σ of each free parameter, from one calibration without
    // priors, σ given.
    let data_sd: Vec<(usize, f64)> = {
        let mut data = pkmcal::simulate(
            &m,
            &tool,
            &Params::nominal(spec),
            &targets,
            Noise::lengths(SETTING_NOISE_MM),
            1,
        )
        .unwrap();
        for d in &mut data {
            d.sigma = vec![Some(SETTING_NOISE_MM); d.measured.len()];
        }
        let c = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &base).unwrap();
        base.free
            .iter()
            .map(|&i| (i, c.parameters[i].std_dev))
            .collect()
    };
    let mut opts = base.clone();
    if let Some(k) = prior {
        opts.priors = data_sd
            .iter()
            .map(|&(index, s)| Prior {
                index,
                sigma: k * s,
            })
            .collect();
    }
    if matches!(sigma, Sigma::Stated) {
        opts.stated_noise = Some(Noise::lengths(SETTING_NOISE_MM));
    }
    let l11 = spec.param_index("l11").unwrap();
    let l11_sd = data_sd.iter().find(|(i, _)| *i == l11).unwrap().1;
    let spread = prior.unwrap_or(LOOSE);
    let (mut false_alarms, mut found) = (0, 0);
    for r in 0..SETTING_PAIRS {
        let mut rng = StdRng::seed_from_u64(7000 + r);
        let mut truth = Params::nominal(spec);
        for &(i, s) in &data_sd {
            truth.values[i] += Normal::new(0.0, spread * s).unwrap().sample(&mut rng);
        }
        let a = Compared::from_calibration(&run(&opts, &truth, 3 * r + 10));
        let b = Compared::from_calibration(&run(&opts, &truth, 3 * r + 11));
        false_alarms += usize::from(drift(&a, &b, DEFAULT_ALPHA).unwrap().joint_drift);
        let mut moved = truth.clone();
        moved.values[l11] += 4.0 * 2f64.sqrt() * l11_sd;
        let c = Compared::from_calibration(&run(&opts, &moved, 3 * r + 12));
        found += usize::from(drift(&a, &c, DEFAULT_ALPHA).unwrap().joint_drift);
    }
    let rate = |k: usize| k as f64 / SETTING_PAIRS as f64;
    (rate(false_alarms), rate(found))
}

/// The drift test in every setting a user can choose: σ given, estimated
/// or stated; priors absent, loose or tight. Its false-alarm rate is within
/// four binomial σ of its level in each, and a 4σ move of `l11` is found in
/// most pairs (less where a tight prior holds it: what the data add is
/// compared, and the prior leaves the data less to add).
#[test]
fn drift_holds_its_level_in_every_setting() {
    let slack = 4.0 * (DEFAULT_ALPHA * (1.0 - DEFAULT_ALPHA) / SETTING_PAIRS as f64).sqrt();
    let mut table = String::new();
    for sigma in [Sigma::Given, Sigma::Estimated, Sigma::Stated] {
        for prior in [None, Some(LOOSE), Some(TIGHT)] {
            let (fa, found) = reference_setting(sigma, prior);
            table += &format!("{sigma:?} {prior:?}: false alarms {fa:.3}, found {found:.3}\n");
            assert!((fa - DEFAULT_ALPHA).abs() <= slack, "{table}");
            assert!(found >= 0.5, "{table}");
        }
    }
    println!("{table}");
}
