//! Weighting on real computations: mixed-unit data (lengths and angles) with
//! known noise, noise estimated per group of like coordinates, outliers judged
//! per group, the drop cap, cross-validation with weights, stiffness ratios
//! where the actuators fight, units of every parameter.

use crate::common;
use common::{gough_stewart, perturbed, planar, spread};
use pkmcal::identify::WarningKind;
use pkmcal::{
    CalibrationOptions, JeongKim2Dof, Mechanism, Model, Noise, ParamKind, Params, Unit, accuracy,
    calibrate, cross_validate, simulate,
};

/// Simulated noise on lengths (mm) and angles (rad), as in a tracker that
/// measures position and orientation.
const NOISE: Noise = Noise {
    length: 0.002,
    angle: 1e-5,
};
use nalgebra::DMatrix;
use pkmcal::identify::noise::*;
use pkmcal::measurement::MeasurementModel;
use pkmcal::measurement::data::Measurement;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
/// Estimated and known-σ fits may differ by this fraction in accuracy (mean
/// over the seeds).
const SAME_ACCURACY: f64 = 0.05;
/// Mean estimated noise level within this fraction of the simulated one.
const SIGMA_RECOVERED: f64 = 0.1;
/// Simulated data sets per comparison.
const SEEDS: u64 = 6;

/// Random errors on the parameters a calibration identifies by default (the
/// others stay nominal, as the calibration assumes).
fn truth(spec: &pkmcal::Spec, seed: u64) -> Params {
    let all = perturbed(spec, seed, 0.3, 0.002);
    let mut truth = Params::nominal(spec);
    for n in &spec.default_free {
        truth.set(spec, n, all.get(spec, n).unwrap()).unwrap();
    }
    truth
}

/// Validation RMS of position (mm) and angle (rad) after calibrating `data`.
fn validation<M: Mechanism>(
    m: &M,
    data: &[pkmcal::Measurement],
    unseen: &[pkmcal::Measurement],
) -> (f64, f64, pkmcal::Calibration) {
    let spec = m.spec();
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cal = calibrate(
        m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        data,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    let tool = pkmcal::MeasurementModel::tool(m.spec());
    let (acc, _, _) = accuracy(m, &tool, unseen, &cal.params, &[], Model::Exact, &[]).unwrap();
    (acc.after.distance_rms, acc.after.angle_rms.unwrap(), cal)
}

fn with_sigma(data: &[pkmcal::Measurement], sigma: &[Option<f64>]) -> Vec<pkmcal::Measurement> {
    data.iter()
        .map(|m| pkmcal::Measurement {
            sigma: sigma.to_vec(),
            ..m.clone()
        })
        .collect()
}

#[test]
fn mixed_units_are_weighted_by_estimated_noise() {
    let m = planar("4-rrr");
    let spec = m.spec();
    let truth = truth(spec, 5);
    let unseen = simulate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &truth,
        &spread(&m, 30),
        Noise::NONE,
        8,
    )
    .unwrap();
    // Over several data sets (one estimate of σ scatters by about ±20 %
    // with 50 poses): the accuracy of the fit with estimated σ against the
    // fit with the simulated σ given, and the σ estimates.
    let (mut pos_ratio, mut ang_ratio) = (vec![], vec![]);
    let (mut len_sigma, mut ang_sigma) = (vec![], vec![]);
    for seed in 1..=SEEDS {
        let data = simulate(
            &m,
            &pkmcal::MeasurementModel::tool(m.spec()),
            &truth,
            &spread(&m, 50),
            NOISE,
            seed,
        )
        .unwrap();
        let known = with_sigma(
            &data,
            &[Some(NOISE.length), Some(NOISE.length), Some(NOISE.angle)],
        );
        let (pos_known, ang_known, _) = validation(&m, &known, &unseen);
        let (pos_est, ang_est, cal) = validation(&m, &data, &unseen);
        pos_ratio.push(pos_est / pos_known);
        ang_ratio.push(ang_est / ang_known);
        assert_eq!(cal.noise.len(), 2, "{:?}", cal.noise);
        assert!(cal.noise.iter().all(|g| g.estimated));
        len_sigma.push(cal.noise[0].sigma / NOISE.length);
        ang_sigma.push(cal.noise[1].sigma / NOISE.angle);
        assert!((cal.unit_weight_sigma - 1.0).abs() < 0.05);
        // Clean data: no pose is an outlier once lengths and angles are
        // judged apart.
        assert!(cal.outliers.is_empty(), "seed {seed}: {:?}", cal.outliers);
        if seed == 1 {
            // What 1 mm = 1 rad weighting gives: the angle is fitted far worse.
            let equal = with_sigma(&data, &[Some(1.0); 3]);
            let (_, ang_equal, _) = validation(&m, &equal, &unseen);
            assert!(
                ang_equal > 3.0 * ang_est,
                "equal weights {ang_equal} vs estimated {ang_est}"
            );
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        (mean(&pos_ratio) - 1.0).abs() < SAME_ACCURACY,
        "position: {pos_ratio:?}"
    );
    assert!(
        (mean(&ang_ratio) - 1.0).abs() < SAME_ACCURACY,
        "angle: {ang_ratio:?}"
    );
    assert!(
        (mean(&len_sigma) - 1.0).abs() < SIGMA_RECOVERED,
        "{len_sigma:?}"
    );
    assert!(
        (mean(&ang_sigma) - 1.0).abs() < SIGMA_RECOVERED,
        "{ang_sigma:?}"
    );
}

#[test]
fn a_partial_set_of_sigma_is_used_and_the_rest_estimated() {
    let m = planar("4-rrr");
    let spec = m.spec();
    let truth = truth(spec, 5);
    let data = simulate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &truth,
        &spread(&m, 40),
        NOISE,
        9,
    )
    .unwrap();
    let partial = with_sigma(&data, &[Some(NOISE.length), Some(NOISE.length), None]);
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cal = calibrate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &partial,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    let angles = cal.noise.iter().find(|g| g.unit == Unit::Radian).unwrap();
    assert!(angles.estimated && angles.axes == ["phi"]);
    assert!((angles.sigma / NOISE.angle - 1.0).abs() < 2.5 * SIGMA_RECOVERED);
    let lengths = cal
        .noise
        .iter()
        .find(|g| g.unit == Unit::Millimetre)
        .unwrap();
    assert!(!lengths.estimated && (lengths.sigma - NOISE.length).abs() < 1e-15);
    // A wrong-length σ row is refused with the pose named.
    let mut bad = partial.clone();
    bad[3].sigma = vec![Some(0.002)];
    let e = calibrate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &bad,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap_err();
    assert!(e.to_string().starts_with("pose 4"), "{e}");
}

#[test]
fn dropping_stops_at_the_cap_and_rechecks_after_each_drop() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let truth = pkmcal::Params::from_named(spec, [("l11", 280.3), ("dq3", 0.002)]).unwrap();
    let clean = simulate(
        &mech,
        &pkmcal::MeasurementModel::tool(mech.spec()),
        &truth,
        &common::targets(35),
        0.002,
        3,
    )
    .unwrap();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.drop_outliers = true;
    // Two gross errors: both found, one after the other.
    let mut two = clean.clone();
    two[5].measured[0] += 0.08;
    two[20].measured[1] += 0.06;
    let cal = calibrate(
        &mech,
        &pkmcal::MeasurementModel::tool(mech.spec()),
        &two,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    let mut dropped: Vec<usize> = cal.dropped.iter().map(|o| o.pose).collect();
    dropped.sort_unstable();
    assert_eq!(dropped, [6, 21]);
    assert_eq!(cal.poses, 33);
    // Ten gross errors in 35 poses: at most 20 % (7) are dropped, and the
    // rest are reported with a warning that says the cap was reached.
    let mut many = clean.clone();
    for (k, i) in (0..35).step_by(3).take(10).enumerate() {
        many[i].measured[k % 2] += 0.1 + 0.02 * k as f64;
    }
    let cal = calibrate(
        &mech,
        &pkmcal::MeasurementModel::tool(mech.spec()),
        &many,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    assert_eq!(cal.dropped.len(), 7, "{:?}", cal.dropped);
    assert!(
        cal.warnings
            .iter()
            .any(|w| matches!(w.kind, WarningKind::Outliers { dropping: true, .. }))
    );
}

#[test]
fn cross_validation_keeps_each_poses_sigma() {
    let m = planar("4-rrr");
    let spec = m.spec();
    let truth = truth(spec, 5);
    let data = simulate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &truth,
        &spread(&m, 40),
        NOISE,
        11,
    )
    .unwrap();
    let known = with_sigma(
        &data,
        &[Some(NOISE.length), Some(NOISE.length), Some(NOISE.angle)],
    );
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cv = cross_validate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &known,
        &Params::nominal(spec),
        &opts,
        4,
        1,
    )
    .unwrap();
    assert_eq!(cv.fold_rms.len(), 4);
    assert!(cv.pooled.distance_rms < 0.01, "{:?}", cv.pooled);
    assert!(cv.pooled.angle_rms.unwrap() < 1e-4);
}

#[test]
fn stiffness_ratios_are_identified_where_the_actuators_fight() {
    let m = gough_stewart("gough-stewart-8");
    let spec = m.spec();
    let mut truth = perturbed(spec, 3, 0.2, 0.1);
    // Another stiffness ratio than nominal.
    let k3 = spec.param_index("kL3").unwrap();
    truth.values[k3] *= 1.5;
    let data = simulate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &truth,
        &spread(&m, 60),
        0.0,
        2,
    )
    .unwrap();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free = (0..spec.n_params()).collect();
    let cal = calibrate(
        &m,
        &pkmcal::MeasurementModel::tool(m.spec()),
        &data,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    let fixed: Vec<&str> = cal
        .parameters
        .iter()
        .filter(|p| p.kind == ParamKind::Stiffness && !p.free)
        .map(|p| p.name.as_str())
        .collect();
    assert_eq!(fixed, ["kL1"], "exactly one stiffness is fixed");
    assert!(cal.warnings.iter().any(|w| matches!(
        &w.kind,
        WarningKind::StiffnessRatios { fixed } if fixed == "kL1"
    )));
    // kL1 is nominal in the truth too, so the ratios give the values.
    let found = cal.params.values[k3];
    assert!(
        (found / truth.values[k3] - 1.0).abs() < 1e-3,
        "kL3 {found} vs {}",
        truth.values[k3]
    );
}

#[test]
fn every_parameter_carries_its_declared_unit() {
    let gs = gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let unit = |n: &str| spec.param_unit(spec.param_index(n).unwrap());
    assert_eq!(unit("a1x"), Unit::Millimetre);
    assert_eq!(unit("dL1"), Unit::Millimetre);
    assert_eq!(unit("kL1"), Unit::NewtonPerMillimetre);
    assert_eq!(
        spec.param_kind(spec.param_index("dL1").unwrap()),
        ParamKind::Offset
    );
    assert_eq!(spec.tool_units[3], Unit::Radian);
    let r = JeongKim2Dof::new();
    let s = r.spec();
    assert_eq!(s.param_unit(s.param_index("dq3").unwrap()), Unit::Radian);
    assert_eq!(
        s.param_unit(s.param_index("k2").unwrap()),
        Unit::NewtonMetrePerRadian
    );
    let p = planar("3-rrr");
    let s = p.spec();
    assert!(s.geometric_units.iter().all(|u| *u == Unit::Millimetre));
    assert_eq!(
        s.tool_units,
        [Unit::Millimetre, Unit::Millimetre, Unit::Radian]
    );
}

// The tests of `pkmcal::identify::noise` itself.

/// The variance ratio's interval against F quantiles from tables
/// (F(10, 20): 0.975 quantile 2.7737, 0.025 quantile 1/3.4185).
#[test]
fn variance_ratio_interval_is_fishers() {
    let group = |sigma: f64, nu: f64| NoiseGroup {
        unit: Unit::Millimetre,
        axes: vec![],
        count: 0,
        estimated: true,
        sigma,
        residual_rms: sigma,
        redundancy: Some(nu),
        stated: None,
        stated_readings: None,
        stated_relative: false,
    };
    let r = variance_ratio(&group(2.0, 10.5), &group(1.0, 20.0), 0.95).unwrap();
    assert_eq!(r.ratio, 4.0);
    assert!((r.low - 4.0 / 2.7737).abs() < 1e-3, "{r:?}");
    assert!((r.high - 4.0 * 3.4185).abs() < 1e-3, "{r:?}");
    assert!(variance_ratio(&group(2.0, 0.5), &group(1.0, 20.0), 0.95).is_none());
    let mut given = group(1.0, 3.0);
    given.redundancy = None;
    assert!(variance_ratio(&given, &group(1.0, 20.0), 0.95).is_none());
}

#[test]
fn leverages_sum_to_the_number_of_parameters() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let n = Normal::new(0.0, 1.0).unwrap();
    let j = DMatrix::from_fn(20, 4, |_, _| n.sample(&mut rng));
    let h = leverages(&j);
    assert!((h.iter().sum::<f64>() - 4.0).abs() < 1e-10);
    assert!(h.iter().all(|v| (0.0..=1.0 + 1e-12).contains(v)));
}

fn hexapod() -> pkmcal::GoughStewart {
    let t = crate::common::table("gough-stewart-6");
    pkmcal::GoughStewart::new(&t.try_into().unwrap()).unwrap()
}

#[test]
fn groups_by_unit_and_given_sigma() {
    use pkmcal::Mechanism;
    let mech = hexapod();
    let tool = MeasurementModel::tool_axes(mech.spec(), &["x", "y", "rx"]).unwrap();
    let m = Measurement {
        measured: vec![0.0; 3],
        sigma: vec![Some(0.002), None, None],
        ..Default::default()
    };
    let mut nm = NoiseModel::new(&[m.clone(), m], &tool);
    assert_eq!(nm.estimated_groups(), 2);
    nm.sigma = vec![0.003, 1e-5];
    assert_eq!(nm.sigmas(), vec![0.002, 0.003, 1e-5, 0.002, 0.003, 1e-5]);
    let rep = nm.report(&[0.0; 6]);
    assert_eq!(rep.len(), 3);
    assert_eq!(rep[0].axes, vec!["y".to_string()]);
    assert_eq!(rep[1].unit, Unit::Radian);
    assert!(!rep[2].estimated && rep[2].count == 2);
}

#[test]
fn distances_between_poses_are_a_group_of_their_own() {
    use pkmcal::Mechanism;
    let mech = hexapod();
    let tool = MeasurementModel::tool_axes(mech.spec(), &["x", "y", "rx"]).unwrap();
    let pose = Measurement {
        measured: vec![0.0; 3],
        ..Default::default()
    };
    let pair = Measurement {
        measured: vec![0.0],
        partner: Some(vec![]),
        ..Default::default()
    };
    let mut nm = NoiseModel::new(&[pose, pair.clone(), pair], &tool);
    assert_eq!(nm.estimated_groups(), 3);
    nm.sigma = vec![0.003, 1e-5, 0.02];
    assert_eq!(nm.sigmas(), vec![0.003, 0.003, 1e-5, 0.02, 0.02]);
    assert_eq!(nm.keys(), vec![0, 0, 1, 2, 2]);
    let rep = nm.report(&[0.0; 5]);
    assert_eq!(rep[2].axes, vec!["distance".to_string()]);
    assert_eq!(rep[2].count, 2);
    assert_eq!(rep[2].unit, Unit::Millimetre);
}

/// Stated noise as a prior of each group, the distances' included, by
/// the formula of docs/model.md §6; with only the ratios stated, their
/// common scale is the pooled estimate, no readings' worth gives the
/// data's own estimates and an infinite worth the stated ratio.
#[test]
fn stated_noise_is_a_prior_of_every_group_and_a_ratio_shrinks() {
    use pkmcal::Mechanism;
    let mech = hexapod();
    let tool = MeasurementModel::tool_axes(mech.spec(), &["x", "y"]).unwrap();
    let pose = Measurement {
        measured: vec![0.0; 2],
        ..Default::default()
    };
    let pair = Measurement {
        measured: vec![0.0],
        partner: Some(vec![]),
        ..Default::default()
    };
    let data = [pose.clone(), pose, pair.clone(), pair.clone(), pair];
    let r = [0.01, -0.02, 0.015, 0.005, 0.3, -0.2, 0.25];
    let h = [0.3, 0.2, 0.4, 0.1, 0.5, 0.2, 0.3];
    let (ss0, red0) = (
        0.01f64.powi(2) + 0.02f64.powi(2) + 0.015f64.powi(2) + 0.005f64.powi(2),
        0.7 + 0.8 + 0.6 + 0.9,
    );
    let (ss1, red1) = (
        0.3f64.powi(2) + 0.2f64.powi(2) + 0.25f64.powi(2),
        0.5 + 0.8 + 0.7,
    );
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-14 * b.abs();
    // The distances' stated σ alone, worth 3 readings.
    let mut nm = NoiseModel::new(&data, &tool).with_stated(None, Some(0.2), 3.0, false);
    nm.update(&r, &h);
    assert!(close(nm.sigma[0], (ss0 / red0).sqrt()));
    assert!(close(
        nm.sigma[1],
        ((3.0 * 0.04 + ss1) / (3.0 + red1)).sqrt()
    ));
    let rep = nm.report(&r);
    assert_eq!((rep[0].stated, rep[1].stated), (None, Some(0.2)));
    // Only the ratio stated (readings 0.5, distances 1): the scale τ is
    // pooled over both groups.
    let relative = |nu: f64| {
        let mut nm = NoiseModel::new(&data, &tool).with_stated(
            Some(Noise::lengths(0.5)),
            Some(1.0),
            nu,
            true,
        );
        nm.update(&r, &h);
        nm
    };
    let tau2 = (ss0 / 0.25 + ss1) / (red0 + red1);
    let nm = relative(4.0);
    assert!(close(
        nm.sigma[0],
        ((4.0 * 0.25 * tau2 + ss0) / (4.0 + red0)).sqrt()
    ));
    assert!(close(
        nm.sigma[1],
        ((4.0 * tau2 + ss1) / (4.0 + red1)).sqrt()
    ));
    let rep = nm.report(&r);
    assert!(close(rep[0].stated.unwrap(), 0.5 * tau2.sqrt()));
    assert!(close(rep[1].stated.unwrap(), tau2.sqrt()));
    assert!(rep[0].stated_relative && rep[1].stated_relative);
    assert!(variance_ratio(&rep[0], &rep[1], 0.95).is_none());
    let nm = relative(0.0);
    assert!(close(nm.sigma[0], (ss0 / red0).sqrt()));
    assert!(close(nm.sigma[1], (ss1 / red1).sqrt()));
    let nm = relative(f64::INFINITY);
    assert!(close(nm.sigma[0] / nm.sigma[1], 0.5));
    assert!(close(nm.sigma[1], tau2.sqrt()));
}
