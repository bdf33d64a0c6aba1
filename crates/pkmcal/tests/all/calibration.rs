//! Tests of the identification (issue 3): exact Jacobians, recovery of the
//! true parameters, identifiability, uncertainty and validation.

use crate::common;

use pkmcal::engine::sensitivity::sensitivity;
use pkmcal::identify::{Columns, IdentificationProblem, analyze_identifiability};
use pkmcal::kinds::reference::{JeongKim2Dof, demo_truth};
use pkmcal::*;

/// Exact Jacobian against Richardson-extrapolated central differences,
/// relative to the largest entry of each column.
const JACOBIAN_REL: f64 = 1e-8;
/// Noise of the simulated measurements (mm per axis), as the demo's
/// (README, "Measured figures").
const NOISE_MM: f64 = 0.002;
/// Recovery of the true parameters from noise-free data (mm).
const RECOVERY_MM: f64 = 1e-6;

/// A fit restarted from its own answer stays there (mm or rad): the final
/// Gauss–Newton polish settles the weak directions, which the trust region
/// alone leaves a few 1e-7 mm apart on gough-stewart-8; the polished
/// answers agree to about 1e-9 mm there (the weakest direction's rounding).
const RESTART: f64 = 2e-9;

fn data(n: usize, noise: f64, seed: u64) -> Vec<Measurement> {
    let mech = JeongKim2Dof::new();
    simulate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &demo_truth(),
        &common::targets(n),
        noise,
        seed,
    )
    .unwrap()
}

fn fd_column(
    mech: &JeongKim2Dof,
    pose: &Pose,
    p: &Params,
    model: Model,
    force: &[f64],
    c: usize,
) -> [f64; 2] {
    let h = if c < 16 {
        1e-2
    } else if c < 19 {
        1e-4
    } else {
        10.0
    };
    let d = |h: f64| {
        let (mut a, mut b) = (p.clone(), p.clone());
        a.values[c] += h;
        b.values[c] -= h;
        let pa = predict_pose(mech, pose, &a, model, force).unwrap();
        let pb = predict_pose(mech, pose, &b, model, force).unwrap();
        [
            (pa.x[0] - pb.x[0]) / (2.0 * h),
            (pa.x[1] - pb.x[1]) / (2.0 * h),
        ]
    };
    let (d1, d2) = (d(h), d(h / 2.0));
    [(4.0 * d2[0] - d1[0]) / 3.0, (4.0 * d2[1] - d1[1]) / 3.0]
}

#[test]
fn identification_jacobians_are_exact() {
    let mech = JeongKim2Dof::new();
    let truth = demo_truth();
    let rho = &mech.spec().nominal[..16];
    for t in [[0.0, 180.0], [60.0, 100.0], [-90.0, 240.0]] {
        let q = inverse_kinematics(&mech, rho, &t).unwrap();
        let pose = prepare_pose(&mech, &q[..3], Some(&q)).unwrap();
        for model in Model::ALL {
            for force in [vec![], vec![20.0, -30.0]] {
                let s = sensitivity(&mech, &pose, &truth, model, &force).unwrap();
                for c in 0..22 {
                    let fd = fd_column(&mech, &pose, &truth, model, &force, c);
                    let scale = s.jacobian.column(c).amax();
                    for (r, &fdr) in fd.iter().enumerate() {
                        let err = (fdr - s.jacobian[(r, c)]).abs();
                        if scale > 1e-12 {
                            assert!(
                                err <= JACOBIAN_REL * scale,
                                "{t:?} {model:?} force {force:?} column {c}: {} vs {} ",
                                s.jacobian[(r, c)],
                                fdr
                            );
                        } else {
                            assert!(fdr.abs() < 1e-9, "column {c} should vanish: {fdr}");
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn exact_model_recovers_the_truth_from_noise_free_data() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(35, 0.0, 1);
    let cal = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &d,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    assert!(cal.converged, "{}", cal.termination_reason);
    let truth = demo_truth();
    for p in &cal.parameters {
        let t = truth.get(spec, &p.name).unwrap();
        assert!(
            (p.identified - t).abs() < RECOVERY_MM,
            "{}: {} vs {t}",
            p.name,
            p.identified
        );
    }
    assert!(cal.noise[0].sigma < 1e-7);
}

/// A calibration and its statistics sharing one `PoseCache` give what they
/// give apart: the same parameters, the same before/after errors.
#[test]
fn a_shared_pose_cache_changes_no_result() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let d = data(30, 0.002, 4);
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let start = Params::nominal(spec);
    let apart = calibrate(&mech, &tool, &d, &start, &opts).unwrap();
    let cache = PoseCache::new();
    let shared = calibrate_with_cache(&mech, &tool, &d, &start, &opts, &cache).unwrap();
    assert_eq!(apart.params.values, shared.params.values);
    assert_eq!(apart.covariance, shared.covariance);
    let (a, before_a, after_a) = calibration_accuracy(&mech, &tool, &d, &apart, &[]).unwrap();
    let (b, before_b, after_b) =
        calibration_accuracy_with_cache(&mech, &tool, &d, &shared, &[], &cache).unwrap();
    assert_eq!(a, b);
    assert_eq!(before_a, before_b);
    assert_eq!(after_a, after_b);
    assert!(a.after.distance_rms < a.before.distance_rms);
    // A second fit from the same cache, on other readings of the same poses
    // (a Monte Carlo study's next run), takes the Jacobian at nominal
    // parameters the first kept with each pose: as apart, bit for bit.
    let d2 = data(30, 0.002, 5);
    let apart2 = calibrate(&mech, &tool, &d2, &start, &opts).unwrap();
    let shared2 = calibrate_with_cache(&mech, &tool, &d2, &start, &opts, &cache).unwrap();
    assert_ne!(apart.params.values, apart2.params.values);
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&apart2.params.values), bits(&shared2.params.values));
    assert_eq!(
        bits(apart2.jacobian.as_slice()),
        bits(shared2.jacobian.as_slice())
    );
    assert_eq!(apart2.covariance, shared2.covariance);
}

/// The errors after a calibration, from the fit's own predictions at the
/// identified parameters (what `calibration_accuracy_with_cache` takes when
/// the fit's last evaluation was there), agree with predictions computed
/// afresh to this (mm).
const SAME_ERRORS: f64 = 1e-9;

type AccuracyOf = (
    Accuracy,
    pkmcal::identify::ErrorVectors,
    pkmcal::identify::ErrorVectors,
);

/// The accuracy of `cal` on `d` through `calibration_accuracy_with_cache`
/// (with the calibration's cache) and through `accuracy` (every
/// prediction afresh).
fn reused_and_fresh<M: Mechanism>(
    mech: &M,
    cal: &Calibration,
    cache: &PoseCache,
    d: &[Measurement],
) -> (AccuracyOf, AccuracyOf) {
    let tool = MeasurementModel::tool(mech.spec());
    let reused = calibration_accuracy_with_cache(mech, &tool, d, cal, &[], cache).unwrap();
    let fresh = pkmcal::identify::accuracy(
        mech,
        &tool,
        d,
        &cal.params,
        &cal.measurement,
        cal.model,
        &[],
    )
    .unwrap();
    (reused, fresh)
}

/// `calibration_accuracy_with_cache` gives the errors that `accuracy`,
/// computing every prediction afresh, gives: on the reference and, with a
/// load-free platform's pose and orientation readings, on gough-stewart-6.
#[test]
fn the_accuracy_after_a_fit_is_that_of_fresh_predictions() {
    let check = |(a, b): &(AccuracyOf, AccuracyOf), what: &str| {
        for (u, v) in [(&a.1, &b.1), (&a.2, &b.2)] {
            for (x, y) in u.iter().zip(v.iter()) {
                for (p, q) in x.iter().zip(y) {
                    assert!((p - q).abs() <= SAME_ERRORS, "{what}: {p} vs {q}");
                }
            }
        }
        assert!((a.0.after.distance_rms - b.0.after.distance_rms).abs() <= SAME_ERRORS);
    };
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let d = data(30, 0.002, 4);
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cache = PoseCache::new();
    let cal =
        calibrate_with_cache(&mech, &tool, &d, &Params::nominal(spec), &opts, &cache).unwrap();
    check(&reused_and_fresh(&mech, &cal, &cache, &d), "reference");
    // Another data set's accuracy with this calibration: nothing reused.
    let (a, b) = reused_and_fresh(&mech, &cal, &cache, &data(20, 0.002, 5));
    assert_eq!(a.1, b.1);
    assert_eq!(a.2, b.2);

    let gs = common::gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let tool = MeasurementModel::tool(spec);
    let truth = common::perturbed_by_unit(spec, 7, 0.3, 1e-3);
    let d = simulate(&gs, &tool, &truth, &common::spread(&gs, 40), 0.002, 3).unwrap();
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cache = PoseCache::new();
    let cal = calibrate_with_cache(&gs, &tool, &d, &Params::nominal(spec), &opts, &cache).unwrap();
    check(&reused_and_fresh(&gs, &cal, &cache, &d), "gough-stewart-6");
}

/// The caller's cancel flag, set, stops every fit of a calibration (the
/// first fit included, which otherwise runs beside the identifiability
/// analysis with a flag of its own): nothing moves from the start.
#[test]
fn a_set_cancel_flag_stops_every_fit() {
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let d = data(30, 0.002, 4);
    let start = Params::nominal(spec);
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.solver.cancel = Some(Arc::new(AtomicBool::new(true)));
    let cal = calibrate(&mech, &tool, &d, &start, &opts).unwrap();
    assert_eq!(cal.params.values, start.values);
    assert!(
        cal.warnings
            .iter()
            .any(|w| matches!(w.kind, pkmcal::identify::WarningKind::NotConverged { .. })),
        "{:?}",
        cal.warnings
    );
    opts.solver.cancel = Some(Arc::new(AtomicBool::new(false)));
    let free = calibrate(&mech, &tool, &d, &start, &opts).unwrap();
    let plain = calibrate(
        &mech,
        &tool,
        &d,
        &start,
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    assert_eq!(free.params.values, plain.params.values);
}

#[test]
fn compliance_aware_models_reach_the_noise_floor_where_rigid_cannot() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(35, NOISE_MM, 7);
    let unseen = simulate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &demo_truth(),
        &random_targets(&mech, 40, 3).unwrap(),
        NOISE_MM,
        8,
    )
    .unwrap();
    let truth = demo_truth();
    for model in Model::ALL {
        let cal = calibrate(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &d,
            &Params::nominal(spec),
            &CalibrationOptions::new(spec, model),
        )
        .unwrap();
        let (val, _, _) = accuracy(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &unseen,
            &cal.params,
            &[],
            model,
            &[],
        )
        .unwrap();
        match model {
            Model::Rigid => {
                // dq3 cannot be seen by a rigid model driven by q1, q2.
                assert!(cal.warnings.iter().any(|w| w.message.contains("dq3")));
                assert!(cal.parameters.iter().any(|p| p.name == "dq3" && !p.free));
                assert!(
                    cal.noise[0].sigma > 10.0 * NOISE_MM,
                    "rigid σ {}",
                    cal.noise[0].sigma
                );
                assert!(val.after.distance_max > 0.05);
            }
            _ => {
                assert!(cal.warnings.is_empty(), "{:?}", cal.warnings);
                assert!(
                    cal.noise[0].sigma > 0.6 * NOISE_MM && cal.noise[0].sigma < 1.4 * NOISE_MM,
                    "{model:?} σ {}",
                    cal.noise[0].sigma
                );
                assert!(
                    val.after.distance_rms < 3.0 * NOISE_MM,
                    "{model:?} {:?}",
                    val.after
                );
                // Every identified parameter within 4.5 σ of the truth.
                for p in cal.parameters.iter().filter(|p| p.free) {
                    let t = truth.get(spec, &p.name).unwrap();
                    assert!(
                        (p.identified - t).abs() < 4.5 * p.std_dev + 1e-9,
                        "{model:?} {}: {} ± {} vs {t}",
                        p.name,
                        p.identified,
                        p.std_dev
                    );
                }
            }
        }
    }
}

#[test]
fn reported_standard_deviations_match_the_scatter_over_noise_draws() {
    // Seeded repeats: the spread of the estimates agrees with the reported σ.
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let targets = common::targets(35);
    let opts = CalibrationOptions::new(spec, Model::Linear);
    let names = ["l11", "B3x", "dq3", "Ptx"];
    let mut est: Vec<Vec<f64>> = vec![vec![]; names.len()];
    let mut sd = vec![0.0; names.len()];
    let runs = 40;
    for seed in 0..runs {
        let d = simulate(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &demo_truth(),
            &targets,
            NOISE_MM,
            100 + seed,
        )
        .unwrap();
        let cal = calibrate(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &d,
            &Params::nominal(spec),
            &opts,
        )
        .unwrap();
        for (k, n) in names.iter().enumerate() {
            let p = cal.parameters.iter().find(|p| p.name == *n).unwrap();
            est[k].push(p.identified);
            sd[k] += p.std_dev / runs as f64;
        }
    }
    for (k, n) in names.iter().enumerate() {
        let mean = est[k].iter().sum::<f64>() / runs as f64;
        let var = est[k].iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (runs - 1) as f64;
        let ratio = var.sqrt() / sd[k];
        assert!(
            (0.6..1.6).contains(&ratio),
            "{n}: empirical/reported σ = {ratio}"
        );
    }
}

#[test]
fn predicted_position_uncertainty_is_of_the_noise_size() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(35, NOISE_MM, 11);
    let cal = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &d,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    let q = inverse_kinematics(&mech, &spec.nominal[..16], &[0.0, 180.0]).unwrap();
    let (x, cov) = predict_with_uncertainty(&mech, &cal, &q[..3], &[]).unwrap();
    assert!((x[0]).abs() < 2.0 && (x[1] - 180.0).abs() < 2.0);
    for a in 0..2 {
        let s = cov[(a, a)].sqrt();
        assert!(s > 0.05 * NOISE_MM && s < 2.0 * NOISE_MM, "σ {s}");
    }
}

#[test]
fn stiffness_ratios_only_without_load() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(35, 0.0, 1);
    let mut free: Vec<usize> = CalibrationOptions::new(spec, Model::Exact).free;
    free.extend(19..22);
    let tool = MeasurementModel::tool(spec);
    let problem = IdentificationProblem::new(&mech, &tool, &d, Model::Exact, &[]).unwrap();
    let (_, jac) = problem.jacobian(&demo_truth()).unwrap();
    let (id, kept) = analyze_identifiability(&Columns::of(spec), &jac, &free, d.len(), true);
    assert_eq!(id.unidentifiable.len(), 1, "{:?}", id.unidentifiable);
    let u = &id.unidentifiable[0];
    let names: Vec<&str> = u.terms.iter().map(|t| t.0.as_str()).collect();
    for k in ["k1", "k2", "k3"] {
        assert!(names.contains(&k), "{}", u.combination);
    }
    assert_eq!(kept.len(), free.len() - 1);
    // Under a tool load the absolute stiffness shows.
    let loaded =
        IdentificationProblem::new(&mech, &tool, &d, Model::Exact, &[30.0, -60.0]).unwrap();
    let (_, jac) = loaded.jacobian(&demo_truth()).unwrap();
    let (id, _) = analyze_identifiability(&Columns::of(spec), &jac, &free, d.len(), true);
    assert!(id.unidentifiable.is_empty(), "{:?}", id.unidentifiable);
    // And calibrate says so in a warning.
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free = free;
    let cal = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &d,
        &Params::nominal(spec),
        &opts,
    )
    .unwrap();
    assert!(cal.warnings.iter().any(|w| w.message.contains("ratios")));
}

#[test]
fn observability_indices_and_condition_are_consistent() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(35, 0.0, 1);
    let free = CalibrationOptions::new(spec, Model::Exact).free;
    let tool = MeasurementModel::tool(spec);
    let id = analyze(
        &mech,
        &tool,
        &d,
        &Params::nominal(spec),
        Model::Exact,
        &free,
        &[],
    )
    .unwrap();
    let sv = &id.singular_values;
    assert_eq!(id.rank, 16);
    assert!((id.condition_number - sv[0] / sv[15]).abs() < 1e-9 * id.condition_number);
    let o = &id.observability;
    assert!((o.o2 - 1.0 / id.condition_number).abs() < 1e-12);
    assert!((o.o3 - sv[15]).abs() < 1e-15);
    assert!((o.o4 - sv[15] * sv[15] / sv[0]).abs() < 1e-15);
    assert!(o.o5 < o.o3 && o.o1 > 0.0);
    // Fewer, clustered poses observe worse.
    let few: Vec<Measurement> = d.iter().take(12).cloned().collect();
    let id2 = analyze(
        &mech,
        &tool,
        &few,
        &Params::nominal(spec),
        Model::Exact,
        &free,
        &[],
    )
    .unwrap();
    assert!(id2.observability.o3 < o.o3);
}

#[test]
fn each_unidentifiable_direction_is_the_one_its_fix_removes() {
    // At nominal parameters the actuators do not fight: the three
    // stiffnesses have no effect, three zero columns. Each is named alone,
    // next to the parameter fixed for it.
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(20, 0.0, 1);
    let all: Vec<usize> = (0..spec.n_params()).collect();
    let tool = MeasurementModel::tool(spec);
    let id = analyze(
        &mech,
        &tool,
        &d,
        &Params::nominal(spec),
        Model::Exact,
        &all,
        &[],
    )
    .unwrap();
    assert_eq!(id.unidentifiable.len(), 3);
    let mut fixed = vec![];
    for u in &id.unidentifiable {
        let f = u.fixed.clone().expect("a parameter is fixed for each");
        assert_eq!(u.terms.len(), 1, "{}", u.combination);
        assert_eq!(
            u.terms[0].0, f,
            "{} is removed by fixing {f}",
            u.combination
        );
        fixed.push(f);
    }
    fixed.sort();
    assert_eq!(fixed, ["k1", "k2", "k3"]);
}

#[test]
fn too_few_poses_and_empty_free_sets_are_errors() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(6, 0.0, 1);
    let err = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &d,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap_err();
    assert!(err.to_string().contains("measure more poses"), "{err}");
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free.clear();
    assert!(
        calibrate(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &d,
            &Params::nominal(spec),
            &opts
        )
        .is_err()
    );
}

#[test]
fn holdout_and_cross_validation() {
    let (train, held) = holdout_split(35, 0.2, 3).unwrap();
    assert_eq!(held.len(), 7);
    assert_eq!(train.len() + held.len(), 35);
    assert!(train.iter().all(|i| !held.contains(i)));
    assert_eq!(holdout_split(35, 0.2, 3).unwrap(), (train, held));
    assert!(holdout_split(10, 1.5, 1).is_err());
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let d = data(30, NOISE_MM, 5);
    let cv = cross_validate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &d,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Linear),
        5,
        1,
    )
    .unwrap();
    assert_eq!(cv.fold_rms.len(), 5);
    assert_eq!(cv.pooled.count, 30);
    assert!(cv.pooled.distance_rms < 4.0 * NOISE_MM, "{:?}", cv.pooled);
}

/// A calibration restarted from its own answer returns it (within
/// [`RESTART`]), on a redundant Gough–Stewart platform whose weakest
/// directions the sum of squares cannot resolve below rounding, and on a
/// redundant planar linkage: the answer is the minimum to working precision,
/// not wherever the trust region happened to stop.
#[test]
fn a_restarted_fit_stays_at_its_answer() {
    fn check<M: Mechanism>(name: &str, m: &M) {
        let spec = m.spec();
        let truth = common::perturbed(spec, 11, 0.3, 0.002);
        let tool = MeasurementModel::tool(spec);
        let d = simulate(m, &tool, &truth, &common::spread(m, 40), NOISE_MM, 5).unwrap();
        let opts = CalibrationOptions::new(spec, Model::Exact);
        let first = calibrate(m, &tool, &d, &Params::nominal(spec), &opts).unwrap();
        assert!(first.converged, "{name}: {}", first.termination_reason);
        let again = calibrate(m, &tool, &d, &first.params, &opts).unwrap();
        assert!(again.converged, "{name}: {}", again.termination_reason);
        for (i, (a, b)) in first
            .params
            .values
            .iter()
            .zip(&again.params.values)
            .enumerate()
        {
            assert!(
                (a - b).abs() <= RESTART,
                "{name}: {} moved from {a} to {b} ({:e})",
                spec.param_names()[i],
                (a - b).abs()
            );
        }
    }
    check("gough-stewart-8", &common::gough_stewart("gough-stewart-8"));
    check("4-rrr", &common::planar("4-rrr"));
}
