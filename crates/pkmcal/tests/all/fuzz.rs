//! Fuzzing of the computations (not only the readers): every mechanism kind,
//! driven with extreme but representable numbers (±1e300, 1e155, subnormals,
//! NaN, infinities, zero lengths…) through prediction, sensitivities,
//! inverse kinematics, compensation, trilateration, the measurement models
//! and calibration. Each call must return `Ok` or `Err`, never panic, and an
//! `Ok` must hold finite numbers. The suite runs a hundred cases per
//! property; run more with
//! `PKMCAL_FUZZ_CASES=100000 cargo test --release -p pkmcal --test all fuzz`.

use crate::common;
use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::*;
use proptest::prelude::*;
use std::sync::OnceLock;

/// Cases per property: a hundred in the test suite, more on request.
fn cases() -> u32 {
    std::env::var("PKMCAL_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(100)
}

/// Every shipped mechanism kind.
fn mechanisms() -> &'static [AnyMechanism] {
    static M: OnceLock<Vec<AnyMechanism>> = OnceLock::new();
    M.get_or_init(|| {
        vec![
            JeongKim2Dof::new().into(),
            common::planar("five-bar").into(),
            common::planar("3-rrr").into(),
            common::planar("4-rrr").into(),
            common::gough_stewart("gough-stewart-6").into(),
            common::gough_stewart("gough-stewart-8").into(),
        ]
    })
}

/// A small, clean data set per mechanism kind (the first three).
fn data(m: usize) -> &'static [Measurement] {
    static D: OnceLock<Vec<Vec<Measurement>>> = OnceLock::new();
    &D.get_or_init(|| {
        mechanisms()[..3]
            .iter()
            .map(|mech| {
                let t = common::spread(mech, 12);
                simulate(
                    mech,
                    &MeasurementModel::tool(mech.spec()),
                    &Params::nominal(mech.spec()),
                    &t,
                    0.002,
                    1,
                )
                .unwrap()
            })
            .collect()
    })[m]
}

/// Ordinary values mostly, and every kind of extreme.
fn extreme() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -500.0..500.0f64,
        2 => prop::sample::select(vec![
            0.0, -0.0, 1e-300, -1e-300, 5e-324, f64::EPSILON, 1e-9, 1e6, -1e6, 1e7, -1e7,
            1e155, -1e155, 1e300, -1e300, f64::MAX, f64::MIN, f64::NAN, f64::INFINITY,
            f64::NEG_INFINITY,
        ]),
        1 => any::<f64>(),
    ]
}

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The nominal parameters with a few values replaced.
fn perturbed(spec: &Spec, edits: &[(usize, f64)]) -> Params {
    let mut p = Params::nominal(spec);
    for &(i, v) in edits {
        let i = i % p.values.len();
        p.values[i] = v;
    }
    p
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        rng_seed: proptest::test_runner::RngSeed::Fixed(16),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn fuzz_prediction_and_sensitivity(
        m in 0usize..6,
        commands in prop::collection::vec(extreme(), 8),
        edits in prop::collection::vec((0usize..200, extreme()), 0..3),
        model in 0usize..3,
        force in prop::collection::vec(extreme(), 6),
        loaded in any::<bool>(),
    ) {
        let mech = &mechanisms()[m];
        let spec = mech.spec();
        let c = &commands[..spec.n_actuated()];
        let params = perturbed(spec, &edits);
        let model = Model::ALL[model];
        let force: Vec<f64> = if loaded { force[..spec.tool_axes.len()].to_vec() } else { vec![] };
        let _ = check_params(mech, &params);
        if let Ok(pose) = prepare_pose(mech, c, None)
            && params.validate(spec).is_ok()
        {
            if let Ok(p) = predict_pose(mech, &pose, &params, model, &force) {
                prop_assert!(finite(&p.x) || !finite(&force), "{:?}", p.x);
            }
            let _ = pkmcal::engine::sensitivity::sensitivity(mech, &pose, &params, model, &force);
        }
    }

    #[test]
    fn fuzz_inverse_kinematics_and_compensation(
        m in 0usize..6,
        target in prop::collection::vec(extreme(), 6),
        load in prop::collection::vec(extreme(), 6),
        preload in prop::collection::vec(extreme(), 8),
        exact in any::<bool>(),
    ) {
        let mech = &mechanisms()[m];
        let spec = mech.spec();
        let t = &target[..spec.tool_axes.len()];
        let params = Params::nominal(spec);
        let _ = inverse_kinematics(mech, params.geometric(), t);
        let opts = CompensationOptions {
            force: load[..spec.tool_axes.len()].to_vec(),
            preload: preload[..spec.n_actuated()].to_vec(),
        };
        let model = if exact { Model::Exact } else { Model::Rigid };
        if let Ok(c) = compensate(mech, &params, t, model, &opts) {
            prop_assert!(finite(&c.commands) && finite(&c.torque), "{c:?}");
        }
    }

    #[test]
    fn fuzz_trilateration_and_measurement_models(
        sockets in prop::collection::vec(prop::collection::vec(extreme(), 3), 3..6),
        offset in extreme(),
        readings in prop::collection::vec(extreme(), 6),
        sigma in extreme(),
        x in prop::collection::vec(extreme(), 6),
        planar in any::<bool>(),
    ) {
        let dim = if planar { 2 } else { 3 };
        let setup = Setup {
            sockets: sockets.iter().map(|s| s[..dim].to_vec()).collect(),
            bar_offset: offset,
        };
        let k = setup.sockets.len();
        if let Ok((p, cov)) = trilaterate(&setup, &readings[..k.min(6)], sigma, None) {
            prop_assert!(finite(&p) && cov.iter().all(|v| v.is_finite()), "{p:?}");
        }
        let mech = &mechanisms()[if planar { 2 } else { 4 }];
        let spec = mech.spec();
        let x = &x[..spec.tool_axes.len()];
        if let Ok(bb) = MeasurementModel::ball_bar(spec, &setup) {
            let _ = bb.observe_jacobian(x, bb.nominal());
        }
        let points: Vec<Vec<f64>> = sockets.iter().map(|s| s[..dim].to_vec()).collect();
        if let Ok(t) = MeasurementModel::targets(spec, &points) {
            let t = t.in_frame(Frame::Known(vec![offset; if planar { 3 } else { 6 }]));
            if let Ok(t) = t {
                let _ = t.observe_jacobian(x, t.nominal());
                let _ = t.registered(t.nominal(), &[x.to_vec(), x.to_vec()], &[vec![offset; t.len()], vec![sigma; t.len()]]);
            }
        }
    }
}

proptest! {
    // Calibrations are costlier: a fifth of the cases.
    #![proptest_config(ProptestConfig {
        cases: (cases() / 5).max(10),
        rng_seed: proptest::test_runner::RngSeed::Fixed(17),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn fuzz_calibration(
        m in 0usize..3,
        pose in 0usize..12,
        axis in 0usize..6,
        value in extreme(),
        command in any::<bool>(),
        sigma in prop::option::of(extreme()),
        start in prop::collection::vec((0usize..200, extreme()), 0..2),
    ) {
        if std::env::var_os("PKMCAL_FUZZ_TRACE").is_some() {
            eprintln!("case: m {m} pose {pose} axis {axis} value {value:?} command {command} sigma {sigma:?} start {start:?}");
        }
        let mech = &mechanisms()[m];
        let spec = mech.spec();
        let mut d = data(m).to_vec();
        if command {
            let a = axis % spec.n_actuated();
            d[pose].commands[a] = value;
        } else {
            let a = axis % spec.tool_axes.len();
            d[pose].measured[a] = value;
            if let Some(s) = sigma {
                d[pose].sigma = vec![Some(s); spec.tool_axes.len()];
            }
        }
        let start = perturbed(spec, &start);
        let opts = CalibrationOptions::new(spec, Model::Exact);
        let tool = MeasurementModel::tool(spec);
        if let Ok(cal) = calibrate(mech, &tool, &d, &start, &opts) {
            prop_assert!(finite(&cal.params.values), "{:?}", cal.params.values);
        }
    }
}
