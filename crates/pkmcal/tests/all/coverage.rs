//! The certificate's intervals mean what they say (docs/model.md §6, the
//! scale of the uncertainties): over seeded repeats, the 95 % intervals
//! `p̂ ± q·σ` (q normal where σ is known, Student's t with the fit's degrees
//! of freedom where it was estimated) hold the true parameter 95 % of the
//! time, pooled over the free parameters, in four settings on two kinds of
//! mechanism: the truth drawn from the tolerances the fit is given; the
//! tolerances five times looser than the truth's spread; σ given in the
//! data; σ estimated. The full figures (500 runs a setting) are an ignored
//! test, `cargo test --release -p pkmcal --test all coverage -- --ignored
//! --nocapture`, in BENCHMARKS.md; the test kept on runs fewer.

use crate::common::{gough_stewart, spread};
use pkmcal::identify::Prior;
use pkmcal::{CalibrationOptions, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params};
use rand::SeedableRng;
use rand_distr::Distribution;

/// The intervals' confidence.
const LEVEL: f64 = 0.95;
/// The pooled coverage must lie within this of `LEVEL` (the 93–97 %).
const BAND: f64 = 0.02;
/// Runs of a setting in the full study.
const FULL_RUNS: u64 = 500;
/// Poses of the hexapod's calibrations ([`hexapod`]).
const HEXAPOD_POSES: usize = 200;

/// How the fit is weighed and what it knows before the data.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Setting {
    /// Priors of the tolerances, the truth drawn from them, σ estimated.
    TruthFromTolerances,
    /// Priors five times looser than the truth's spread, σ estimated.
    LooseTolerances,
    /// No priors, σ given in the data (the true one).
    SigmaGiven,
    /// No priors, σ estimated from the residuals.
    SigmaEstimated,
}

const SETTINGS: [Setting; 4] = [
    Setting::TruthFromTolerances,
    Setting::LooseTolerances,
    Setting::SigmaGiven,
    Setting::SigmaEstimated,
];

/// A mechanism under study: its measurement, poses, noise and tolerances
/// (name, σ) of the parameters it frees.
struct Case<M> {
    mech: M,
    measurement: MeasurementModel,
    targets: Vec<Vec<f64>>,
    noise: f64,
    tolerances: Vec<(String, f64)>,
}

/// The built-in reference mechanism: 35 spread poses, 2 µm, tolerances of
/// 0.1 mm on its 16 default parameters' lengths and 1 mrad on its offsets.
fn reference() -> Case<JeongKim2Dof> {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec().clone();
    let tolerances = spec
        .default_free
        .iter()
        .map(|n| {
            let i = spec.param_index(n).unwrap();
            let t = match spec.param_unit(i) {
                pkmcal::Unit::Radian => 1e-3,
                _ => 0.1,
            };
            (n.clone(), t)
        })
        .collect();
    Case {
        measurement: MeasurementModel::tool(&spec),
        targets: spread(&mech, 35),
        mech,
        noise: 0.002,
        tolerances,
    }
}

/// `examples/gough-stewart-6` with its tolerances (its `[tolerances]`
/// table: joint centres 0.05 mm, leg offsets 0.02 mm, `kL1` 20 %), a
/// tracker's three target points, 5 µm, at 200 spread poses: at 40 the data
/// see the leg offsets and the base joints' heights weakly (13–70 % of what
/// is known of them), and with tolerances five times too loose their
/// intervals, mostly the tolerances', hold a truth drawn five times
/// tighter nearly always (98 % pooled: conservative, as a Bayesian
/// interval is where the prior is wider than the truth's spread).
fn hexapod() -> Case<pkmcal::GoughStewart> {
    let mech = gough_stewart("gough-stewart-6");
    let spec = mech.spec().clone();
    let points = [
        vec![150.0, 0.0, 60.0],
        vec![-75.0, 129.904, 60.0],
        vec![-75.0, -129.904, 60.0],
    ];
    let measurement = MeasurementModel::targets(&spec, &points).unwrap();
    let tolerances = crate::common::example_tolerances(&spec, "gough-stewart-6");
    Case {
        targets: spread(&mech, HEXAPOD_POSES),
        mech,
        measurement,
        noise: 0.005,
        tolerances,
    }
}

/// Covered intervals, those the rule before would have covered, and
/// intervals, of one run of `setting` (seed `seed`).
fn run<M: Mechanism + Sync>(case: &Case<M>, setting: Setting, seed: u64) -> (usize, usize, usize) {
    let spec = case.mech.spec();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let spread_factor = if setting == Setting::LooseTolerances {
        0.2
    } else {
        1.0
    };
    let mut truth = Params::nominal(spec);
    for (name, t) in &case.tolerances {
        let i = spec.param_index(name).unwrap();
        let d = rand_distr::Normal::new(0.0, t * spread_factor).unwrap();
        truth.values[i] += d.sample(&mut rng);
    }
    let mut data = pkmcal::simulate(
        &case.mech,
        &case.measurement,
        &truth,
        &case.targets,
        Noise::lengths(case.noise),
        seed,
    )
    .unwrap();
    if setting == Setting::SigmaGiven {
        for m in &mut data {
            m.sigma = vec![Some(case.noise); m.measured.len()];
        }
    }
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    let with_priors = matches!(
        setting,
        Setting::TruthFromTolerances | Setting::LooseTolerances
    );
    let index = |n: &str| spec.param_index(n).unwrap();
    if with_priors {
        opts.priors = case
            .tolerances
            .iter()
            .map(|(n, t)| Prior {
                index: index(n),
                sigma: t / spread_factor,
            })
            .collect();
    }
    opts.free = case.tolerances.iter().map(|(n, _)| index(n)).collect();
    if !with_priors {
        // Without priors, only what the data can identify.
        opts.free.retain(|i| {
            spec.default_free
                .contains(&spec.param_names()[*i].to_string())
        });
    }
    let cal = pkmcal::calibrate(
        &case.mech,
        &case.measurement,
        &data,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    let q = cal.scale.quantile(LEVEL);
    // The rule before (issue 49): every σ scaled by the variance of unit
    // weight of readings and prior rows together, `Σ (r/σ)² / (m + k − n)`,
    // normal intervals.
    let z = pkmcal::identify::Scale::Known.quantile(LEVEL);
    let dof = cal.residuals.len() + cal.priors.len() - cal.free.len();
    let old_factor = (cal.sum_of_squares / dof as f64).sqrt();
    let (mut covered, mut covered_before, mut total) = (0, 0, 0);
    for &i in &cal.free {
        let p = &cal.parameters[i];
        total += 1;
        let error = (p.identified - truth.values[i]).abs();
        if error <= q * p.std_dev {
            covered += 1;
        }
        if error <= z * p.std_dev * old_factor {
            covered_before += 1;
        }
    }
    (covered, covered_before, total)
}

/// The pooled coverage of `runs` runs of `setting` from seed `first`, and
/// what the rule before would have given.
fn coverage<M: Mechanism + Sync>(
    case: &Case<M>,
    setting: Setting,
    first: u64,
    runs: u64,
) -> (f64, f64) {
    let (mut c, mut b, mut t) = (0, 0, 0);
    for seed in first..first + runs {
        let (x, y, z) = run(case, setting, seed);
        c += x;
        b += y;
        t += z;
    }
    (c as f64 / t as f64, b as f64 / t as f64)
}

fn check(name: &str, setting: Setting, (cover, before): (f64, f64), band: f64) {
    println!(
        "{name:<16} {setting:<20}: coverage {:.2} % (the rule before: {:.2} %)",
        100.0 * cover,
        100.0 * before,
        setting = format!("{setting:?}")
    );
    assert!(
        (cover - LEVEL).abs() <= band,
        "{name}, {setting:?}: the 95 % intervals hold the truth {:.2} % of the time",
        100.0 * cover
    );
}

/// Runs of the tests kept on, and their band: fewer runs, a pooled
/// coverage with a larger spread.
const QUICK_RUNS: u64 = 100;
const QUICK_BAND: f64 = 0.03;

#[test]
fn intervals_cover_the_truth_on_the_reference() {
    let case = reference();
    for s in SETTINGS {
        check(
            "reference",
            s,
            coverage(&case, s, 1, QUICK_RUNS),
            QUICK_BAND,
        );
    }
}

#[test]
fn intervals_cover_the_truth_on_a_hexapod() {
    let case = hexapod();
    for s in SETTINGS {
        check(
            "gough-stewart-6",
            s,
            coverage(&case, s, 1, QUICK_RUNS / 4),
            QUICK_BAND,
        );
    }
}

/// The full study; the rule before (σ scaled with the prior rows counted
/// as readings) fails it where the tolerances are conservative.
#[test]
#[ignore = "the full study: 500 runs a setting on two mechanisms (about a minute); figures in BENCHMARKS.md"]
fn intervals_cover_the_truth_over_500_runs() {
    let case = reference();
    for s in SETTINGS {
        let c = coverage(&case, s, 1000, FULL_RUNS);
        if s == Setting::LooseTolerances {
            assert!(c.1 < LEVEL - BAND, "the rule before passes: {c:?}");
        }
        check("reference", s, c, BAND);
    }
    let case = hexapod();
    for s in SETTINGS {
        check(
            "gough-stewart-6",
            s,
            coverage(&case, s, 1000, FULL_RUNS),
            BAND,
        );
    }
}
