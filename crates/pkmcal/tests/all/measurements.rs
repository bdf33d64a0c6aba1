//! Ball-bar measurements, weights and robust fitting (issue 4).

use crate::common;

use pkmcal::kinds::reference::{JeongKim2Dof, demo_truth};
use pkmcal::*;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Reading noise of the simulated ball bar (mm).
const NOISE_MM: f64 = 0.002;

fn setup() -> Setup {
    Setup {
        sockets: vec![vec![-250.0, -60.0], vec![260.0, -40.0], vec![20.0, 480.0]],
        bar_offset: 0.0,
    }
}

#[test]
fn trilateration_recovers_positions_with_their_covariance() {
    // Planar, 3 and 4 sockets, and 3-D with 4 sockets.
    let cases = [
        (setup(), vec![12.0, 190.0]),
        (
            Setup {
                sockets: vec![
                    vec![-250.0, -60.0],
                    vec![260.0, -40.0],
                    vec![20.0, 480.0],
                    vec![-300.0, 400.0],
                ],
                bar_offset: 1.5,
            },
            vec![-40.0, 260.0],
        ),
        (
            Setup {
                sockets: vec![
                    vec![0.0, 0.0, 0.0],
                    vec![500.0, 0.0, 10.0],
                    vec![0.0, 500.0, 20.0],
                    vec![250.0, 250.0, 400.0],
                ],
                bar_offset: 0.0,
            },
            vec![200.0, 180.0, 150.0],
        ),
    ];
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let normal = Normal::new(0.0, NOISE_MM).unwrap();
    for (s, x) in cases {
        let exact = s.distances(&x);
        let (got, cov) = trilaterate(&s, &exact, NOISE_MM, None).unwrap();
        for (a, b) in got.iter().zip(&x) {
            assert!((a - b).abs() < 1e-9, "{got:?} vs {x:?}");
        }
        // The covariance matches the scatter of noisy trilaterations.
        let runs = 400;
        let mut var = vec![0.0; x.len()];
        for _ in 0..runs {
            let d: Vec<f64> = exact.iter().map(|d| d + normal.sample(&mut rng)).collect();
            let (p, _) = trilaterate(&s, &d, NOISE_MM, None).unwrap();
            for k in 0..x.len() {
                var[k] += (p[k] - x[k]).powi(2) / runs as f64;
            }
        }
        for k in 0..x.len() {
            let ratio = var[k].sqrt() / cov[(k, k)].sqrt();
            assert!(
                (0.85..1.15).contains(&ratio),
                "axis {k}: empirical/predicted σ = {ratio}"
            );
        }
    }
    let bad = Setup {
        sockets: vec![vec![0.0, 0.0], vec![1.0, 0.0]],
        bar_offset: 0.0,
    };
    assert!(trilaterate(&bad, &[1.0, 1.0], 0.0, None).is_err());
    assert!(trilaterate(&setup(), &[1.0, f64::NAN, 2.0], 0.0, None).is_err());
}

fn distance_data(truth: &Params, targets: &[Vec<f64>], noise: f64, seed: u64) -> Vec<Measurement> {
    let mech = JeongKim2Dof::new();
    let s = setup();
    let exact = simulate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        truth,
        targets,
        0.0,
        seed,
    )
    .unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed + 1000);
    let normal = Normal::new(0.0, noise.max(f64::MIN_POSITIVE)).unwrap();
    exact
        .into_iter()
        .map(|m| Measurement {
            point: None,
            target: None,
            sigma: vec![],
            origin: None,
            commands: m.commands,
            partner: None,
            measured: s
                .distances(&m.measured)
                .into_iter()
                .map(|d| {
                    if noise > 0.0 {
                        d + normal.sample(&mut rng)
                    } else {
                        d
                    }
                })
                .collect(),
        })
        .collect()
}

fn both_routes(data: &[Measurement]) -> (Params, Params) {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let bb = MeasurementModel::ball_bar(spec, &setup()).unwrap();
    let tri: Vec<Measurement> = data
        .iter()
        .map(|m| Measurement {
            point: None,
            target: None,
            sigma: vec![],
            origin: None,
            commands: m.commands.clone(),
            partner: None,
            measured: trilaterate(&setup(), &m.measured, NOISE_MM, None)
                .unwrap()
                .0,
        })
        .collect();
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let start = Params::nominal(spec);
    let a = calibrate(&mech, &MeasurementModel::tool(spec), &tri, &start, &opts).unwrap();
    let b = calibrate(&mech, &bb, data, &start, &opts).unwrap();
    (a.params, b.params)
}

#[test]
fn ball_bar_routes_agree_without_noise_and_the_direct_one_is_at_least_as_accurate_with_it() {
    let mech = JeongKim2Dof::new();
    let truth = demo_truth();
    let targets = common::targets(35);
    let (a, b) = both_routes(&distance_data(&truth, &targets, 0.0, 1));
    for (i, (x, y)) in a.values.iter().zip(&b.values).enumerate() {
        assert!((x - y).abs() < 1e-7, "parameter {i}: {x} vs {y}");
        assert!((x - truth.values[i]).abs() < 1e-6);
    }
    // With noise: validation error on unseen poses, averaged over seeds.
    let unseen = simulate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &truth,
        &random_targets(&mech, 40, 9).unwrap(),
        0.0,
        1,
    )
    .unwrap();
    let (mut tri, mut direct) = (0.0, 0.0);
    let seeds = 16;
    for seed in 0..seeds {
        let (a, b) = both_routes(&distance_data(&truth, &targets, NOISE_MM, 50 + seed));
        let tool = MeasurementModel::tool(mech.spec());
        tri += accuracy(&mech, &tool, &unseen, &a, &[], Model::Exact, &[])
            .unwrap()
            .0
            .after
            .distance_rms;
        direct += accuracy(&mech, &tool, &unseen, &b, &[], Model::Exact, &[])
            .unwrap()
            .0
            .after
            .distance_rms;
    }
    assert!(
        direct <= tri,
        "direct {} vs trilateration {}",
        direct / seeds as f64,
        tri / seeds as f64
    );
}

#[test]
fn socket_positions_and_bar_offset_are_identifiable() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let truth = demo_truth();
    let mut true_setup = setup();
    true_setup.sockets[2][0] = 20.4;
    true_setup.bar_offset = 0.3;
    let exact = simulate(
        &mech,
        &MeasurementModel::tool(spec),
        &truth,
        &common::targets(40),
        0.0,
        1,
    )
    .unwrap();
    // Readings computed independently of the measurement model.
    let data: Vec<Measurement> = exact
        .iter()
        .map(|m| Measurement {
            commands: m.commands.clone(),
            measured: true_setup.distances(&m.measured),
            ..Default::default()
        })
        .collect();
    let bb = MeasurementModel::ball_bar(spec, &setup()).unwrap();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free.push(bb.index_of(spec, "s3x").unwrap());
    opts.free.push(bb.index_of(spec, "dbar").unwrap());
    let cal = calibrate(&mech, &bb, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.warnings.is_empty(), "{:?}", cal.warnings);
    let m = |n: &str| cal.measurement[bb.index_of(spec, n).unwrap() - spec.n_params()];
    assert!((m("s3x") - 20.4).abs() < 1e-6);
    assert!((m("dbar") - 0.3).abs() < 1e-6);
    let row = cal.parameters.iter().find(|p| p.name == "dbar").unwrap();
    assert_eq!(
        (row.kind, row.unit),
        (ParamKind::Instrument, Unit::Millimetre)
    );
    assert!(row.free && (row.identified - 0.3).abs() < 1e-6);
    for (i, v) in truth.values.iter().enumerate() {
        if opts.free.contains(&i) {
            assert!((cal.params.values[i] - v).abs() < 1e-6, "parameter {i}");
        }
    }
}

#[test]
fn robust_losses_resist_gross_errors() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let truth = demo_truth();
    let clean = simulate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &truth,
        &common::targets(35),
        NOISE_MM,
        2,
    )
    .unwrap();
    let reference = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &clean,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    let mut data = clean.clone();
    data[4].measured[0] += 0.08;
    data[22].measured[1] -= 0.05;
    // Distance from the fit of the clean data (geometric parameters, mm).
    let err = |p: &Params| {
        p.geometric()
            .iter()
            .zip(reference.params.geometric())
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let plain = calibrate(
        &mech,
        &MeasurementModel::tool(mech.spec()),
        &data,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    for loss in [Loss::Huber(1.345), Loss::Cauchy(2.385)] {
        let mut opts = CalibrationOptions::new(spec, Model::Exact);
        opts.loss = loss;
        let cal = calibrate(
            &mech,
            &MeasurementModel::tool(mech.spec()),
            &data,
            &Params::nominal(spec),
            &opts,
        )
        .unwrap();
        let poses: Vec<usize> = cal.outliers.iter().map(|o| o.origin.pose).collect();
        assert_eq!(poses, [5, 23], "{loss:?}");
        assert!(
            err(&cal.params) < 0.2 * err(&plain.params),
            "{loss:?}: {} vs {}",
            err(&cal.params),
            err(&plain.params)
        );
        // The noise estimate is robust too: the gross errors do not inflate it.
        assert!(cal.noise[0].sigma < 1.5 * NOISE_MM, "{:?}", cal.noise);
    }
    assert_eq!(Loss::Huber(1.0).weight(0.5), 1.0);
    assert_eq!(Loss::Huber(1.0).weight(4.0), 0.25);
    assert!((Loss::Cauchy(1.0).weight(1.0) - 0.5).abs() < 1e-15);
}

/// A ball bar on a Gough–Stewart platform: the sockets are 3-D points, the
/// ball sits on the platform's tool point (x, y, z of the pose).
#[test]
fn ball_bar_on_a_spatial_platform_uses_3d_sockets() {
    let gs = common::gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let flat = Setup {
        sockets: vec![vec![0.0, 0.0]; 4],
        bar_offset: 0.0,
    };
    let e = MeasurementModel::ball_bar(spec, &flat)
        .unwrap_err()
        .to_string();
    assert!(e.contains("needs 3 finite coordinates"), "{e}");
    let setup = Setup {
        sockets: vec![
            vec![600.0, 0.0, 0.0],
            vec![-300.0, 520.0, 0.0],
            vec![-300.0, -520.0, 0.0],
            vec![0.0, 0.0, 1400.0],
            vec![400.0, 400.0, 1200.0],
        ],
        bar_offset: 0.0,
    };
    let bb = MeasurementModel::ball_bar(spec, &setup).unwrap();
    let truth = Params::from_named(spec, [("dL2", 0.2), ("dL5", -0.1)]).unwrap();
    let targets: Vec<Vec<f64>> = pkmcal::spread_targets(&gs, 40)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let exact = simulate(
        &gs,
        &MeasurementModel::tool(gs.spec()),
        &truth,
        &targets,
        0.0,
        1,
    )
    .unwrap();
    let data: Vec<Measurement> = exact
        .into_iter()
        .map(|m| Measurement {
            measured: setup.distances(&m.measured[..3]),
            target: None,
            ..m
        })
        .collect();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free = ["dL1", "dL2", "dL3", "dL4", "dL5", "dL6"]
        .iter()
        .map(|n| spec.param_index(n).unwrap())
        .collect();
    let cal = calibrate(&gs, &bb, &data, &Params::nominal(spec), &opts).unwrap();
    for (n, v) in [("dL2", 0.2), ("dL5", -0.1), ("dL1", 0.0)] {
        let got = cal.params.get(spec, n).unwrap();
        assert!((got - v).abs() < 1e-6, "{n}: {got}");
    }
}
