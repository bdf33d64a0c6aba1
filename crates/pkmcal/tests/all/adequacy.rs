//! The two-sided adequacy test (docs/model.md §6) blames the noise when the
//! noise is wrong: over seeded calibrations of the reference (35 poses,
//! 2 µm, a right model), a stated noise three times too large or too small
//! is flagged in nearly every run, as the noise overstated or understated,
//! never as parameters left out; a right one is flagged at the test's
//! level (500 runs each; the figures in BENCHMARKS.md).

use crate::common::spread;
use pkmcal::identify::{ADEQUACY_ALPHA, WarningKind};
use pkmcal::{CalibrationOptions, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params};

/// The instrument's true noise (mm).
const NOISE: f64 = 0.002;
/// A wrong noise is flagged, and blamed, in at least this share of runs.
const POWER: f64 = 0.95;
/// The two-sided p-values of a right noise fall below this level…
const LEVEL: f64 = 0.05;
/// …in this share of runs, within this.
const LEVEL_SLACK: f64 = 0.02;

/// What one calibration with a stated noise said: whether it flagged the
/// noise overstated, understated, or blamed parameters, and its two-sided
/// p-value.
#[derive(Default)]
struct Verdicts {
    runs: usize,
    overstated: usize,
    understated: usize,
    parameters: usize,
    below_level: usize,
}

fn study(stated: f64, first: u64, runs: u64) -> Verdicts {
    let m = JeongKim2Dof::new();
    let spec = m.spec();
    let tool = MeasurementModel::tool(spec);
    let targets = spread(&m, 35);
    let mut v = Verdicts::default();
    for seed in first..first + runs {
        // A right model: only the fitted parameters are off.
        let off = crate::common::perturbed(spec, seed, 0.3, 0.002);
        let mut truth = Params::nominal(spec);
        for n in &spec.default_free {
            let i = spec.param_index(n).unwrap();
            truth.values[i] = off.values[i];
        }
        let data =
            pkmcal::simulate(&m, &tool, &truth, &targets, Noise::lengths(NOISE), seed).unwrap();
        let mut opts = CalibrationOptions::new(spec, Model::Exact);
        opts.stated_noise = Some(Noise::lengths(stated));
        let cal = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &opts).unwrap();
        v.runs += 1;
        for w in &cal.warnings {
            match w.kind {
                WarningKind::NoiseOverstated { .. } => v.overstated += 1,
                WarningKind::NoiseUnderstated { .. } => v.understated += 1,
                WarningKind::ModelInadequate { .. } => v.parameters += 1,
                _ => {}
            }
        }
        let t = &cal.adequacy[0];
        v.below_level += usize::from(t.p_value() < LEVEL);
    }
    v
}

fn check(first: u64, runs: u64) {
    let share = |k: usize, v: &Verdicts| k as f64 / v.runs as f64;
    let large = study(3.0 * NOISE, first, runs);
    println!(
        "stated 3× too large: overstated {:.3}, understated {:.3}, parameters {:.3}",
        share(large.overstated, &large),
        share(large.understated, &large),
        share(large.parameters, &large)
    );
    assert!(share(large.overstated, &large) >= POWER);
    assert_eq!(large.parameters + large.understated, 0);
    let small = study(NOISE / 3.0, first, runs);
    println!(
        "stated 3× too small: overstated {:.3}, understated {:.3}, parameters {:.3}",
        share(small.overstated, &small),
        share(small.understated, &small),
        share(small.parameters, &small)
    );
    assert!(share(small.understated, &small) >= POWER);
    assert!(share(small.parameters, &small) <= 1.0 - POWER);
    let right = study(NOISE, first, runs);
    let alarms = right.overstated + right.understated + right.parameters;
    println!(
        "stated right: warnings {:.4} (level {ADEQUACY_ALPHA}), p < {LEVEL} in {:.4}",
        share(alarms, &right),
        share(right.below_level, &right)
    );
    // At the warning's level 1e-3: at most 3 of 500 (P ≈ 0.998).
    assert!(alarms as f64 <= 3.0 * (runs as f64 / 500.0).max(1.0));
    assert!((share(right.below_level, &right) - LEVEL).abs() <= LEVEL_SLACK);
}

/// 500 runs a noise (a few seconds).
#[test]
fn a_wrong_stated_noise_is_flagged_and_blamed() {
    check(1000, 500);
}
