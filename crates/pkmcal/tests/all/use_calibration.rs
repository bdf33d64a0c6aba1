//! Tests of compensation, measurement planning and Monte Carlo (issue 6).

use crate::common;

use pkmcal::engine::linearized::linearize;
use pkmcal::kinds::reference::{JeongKim2Dof, demo_truth};
use pkmcal::*;

/// Compensated commands must reach the target under the exact model (mm).
const REACH_MM: f64 = 1e-6;

#[test]
fn compensated_commands_reach_the_targets() {
    let mech = JeongKim2Dof::new();
    let truth = demo_truth();
    let cases = [
        CompensationOptions::default(),
        CompensationOptions {
            force: vec![25.0, -40.0],
            preload: vec![],
        },
        CompensationOptions {
            force: vec![],
            preload: vec![30.0, 10.0, -20.0],
        },
        CompensationOptions {
            force: vec![-10.0, 15.0],
            preload: vec![5.0, 5.0, 5.0],
        },
    ];
    for t in random_targets(&mech, 60, 9).unwrap() {
        for opts in &cases {
            let c = compensate(&mech, &truth, &t, Model::Exact, opts).unwrap();
            let p = predict(&mech, &truth, &c.commands, Model::Exact, &opts.force).unwrap();
            let err = (p.x[0] - t[0]).hypot(p.x[1] - t[1]);
            assert!(err < REACH_MM, "{t:?} {opts:?}: {err} mm");
            for (a, b) in p.torque.iter().zip(&c.torque) {
                assert!(
                    (a - b).abs() < 1e-6,
                    "torques {:?} vs {:?}",
                    p.torque,
                    c.torque
                );
            }
            // The torques balance the load and hold only internal preload.
            let lin = linearize(&mech, &c.q, truth.geometric(), &[0, 1]).unwrap();
            let lhs = lin.gamma.transpose() * nalgebra::DVector::from_column_slice(&c.torque);
            let rhs = load_vector(&lin, &opts.force);
            assert!((lhs - rhs).amax() < 1e-9);
        }
        // Without load: consistent commands, no internal torque, same as rigid.
        let e = compensate(
            &mech,
            &truth,
            &t,
            Model::Exact,
            &CompensationOptions::default(),
        )
        .unwrap();
        let r = compensate(
            &mech,
            &truth,
            &t,
            Model::Rigid,
            &CompensationOptions::default(),
        )
        .unwrap();
        assert_eq!(e.commands, r.commands);
        assert!(e.torque.iter().all(|v| *v == 0.0));
    }
}

#[test]
fn nominal_commands_miss_and_compensation_fixes_it() {
    let mech = JeongKim2Dof::new();
    let truth = demo_truth();
    let t = [20.0, 200.0];
    let nominal = nominal_commands(&mech, &t).unwrap();
    let before = predict(&mech, &truth, &nominal, Model::Exact, &[]).unwrap();
    assert!((before.x[0] - t[0]).hypot(before.x[1] - t[1]) > 0.1);
    let c = compensate(
        &mech,
        &truth,
        &t,
        Model::Exact,
        &CompensationOptions::default(),
    )
    .unwrap();
    let after = predict(&mech, &truth, &c.commands, Model::Exact, &[]).unwrap();
    assert!((after.x[0] - t[0]).hypot(after.x[1] - t[1]) < REACH_MM);
}

#[test]
fn compensation_refuses_unreachable_targets_and_the_linear_model() {
    let mech = JeongKim2Dof::new();
    let p = Params::nominal(mech.spec());
    let o = CompensationOptions::default();
    assert!(matches!(
        compensate(&mech, &p, &[1000.0, 0.0], Model::Exact, &o),
        Err(Error::Unreachable { .. })
    ));
    assert!(compensate(&mech, &p, &[0.0, 180.0], Model::Linear, &o).is_err());
    let bad = CompensationOptions {
        force: vec![],
        preload: vec![1.0],
    };
    assert!(compensate(&mech, &p, &[0.0, 180.0], Model::Exact, &bad).is_err());
}

#[test]
fn planned_poses_beat_a_plain_grid() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let free = CalibrationOptions::new(spec, Model::Exact).free;
    let mut points = sample_workspace(&mech, 12.0);
    let n = points.len();
    points.extend(grid_targets(&mech, 20).unwrap());
    let c =
        candidate_jacobians(&mech, points, &Params::nominal(spec), Model::Exact, &free).unwrap();
    let pool = pkmcal::apply::planning::Candidates {
        points: c.points[..n].to_vec(),
        rows: c.rows[..n].to_vec(),
    };
    let grid: Vec<usize> = (n..n + 20).collect();
    let (g, _) = plan_observability(&c, &grid);
    for (crit, value) in [
        (
            PlanCriterion::O1,
            (|o: &pkmcal::identify::Observability| o.o1) as fn(&_) -> f64,
        ),
        (PlanCriterion::O3, |o| o.o3),
        (PlanCriterion::O5, |o| o.o5),
    ] {
        let chosen = plan_poses(&pool, 20, crit).unwrap();
        let mut unique = chosen.clone();
        unique.sort_unstable();
        unique.dedup();
        assert_eq!(unique.len(), 20);
        let (o, _) = plan_observability(&c, &chosen);
        assert!(
            value(&o) > 1.2 * value(&g),
            "{crit:?}: {} vs grid {}",
            value(&o),
            value(&g)
        );
    }
    assert!(plan_poses(&pool, n + 1, PlanCriterion::O1).is_err());
}

#[test]
fn monte_carlo_is_seeded_and_reaches_the_noise_floor() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let poses = common::targets(30);
    let validation = random_targets(&mech, 20, 4).unwrap();
    let opts = MonteCarloOptions {
        runs: 12,
        noise: 0.002.into(),
        seed: 5,
        length_error: 0.3,
        angle_error: 1e-3,
        calibration: CalibrationOptions::new(spec, Model::Linear),
    };
    let count = std::sync::atomic::AtomicUsize::new(0);
    let (runs, s) = monte_carlo(&mech, &poses, &validation, &opts, &|| {
        count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    })
    .unwrap();
    assert_eq!(count.into_inner(), 12);
    assert_eq!(s.converged, 12);
    assert!(
        s.validation_rms_median < 0.005 && s.validation_rms_median > 1e-5,
        "{s:?}"
    );
    assert_eq!(s.parameters.len(), 16);
    let (runs2, _) = monte_carlo(&mech, &poses, &validation, &opts, &|| {}).unwrap();
    for (a, b) in runs.iter().zip(&runs2) {
        assert_eq!(a.parameter_errors, b.parameter_errors);
    }
}

/// A wrench (force and moment on the tool point) on mechanisms whose tool
/// has an orientation: compensated commands reach the target under it, and
/// a moment turns the tool the way it pushes.
#[test]
fn a_wrench_on_an_oriented_tool() {
    // Redundant platform: 8 legs; force 200 N down, moment 30 N·m about z.
    let gs = common::gough_stewart("gough-stewart-8");
    let truth = common::perturbed(gs.spec(), 2, 0.2, 0.1);
    let wrench = vec![10.0, 0.0, -200.0, 5.0, -3.0, 30.0];
    let opts = CompensationOptions {
        force: wrench.clone(),
        preload: vec![],
    };
    // Near the home pose (sampling the 6-D workspace is slow).
    let home = gs
        .spec()
        .workspace_box
        .iter()
        .map(|b| 0.5 * (b[0] + b[1]))
        .collect::<Vec<_>>();
    let poses = [
        home.clone(),
        home.iter()
            .zip([20.0, -15.0, 10.0, 0.02, -0.01, 0.03])
            .map(|(a, b)| a + b)
            .collect(),
        home.iter()
            .zip([-30.0, 10.0, -20.0, -0.02, 0.03, -0.05])
            .map(|(a, b)| a + b)
            .collect::<Vec<f64>>(),
    ];
    for t in poses {
        let c = compensate(&gs, &truth, &t, Model::Exact, &opts).unwrap();
        let p = predict(&gs, &truth, &c.commands, Model::Exact, &wrench).unwrap();
        for (a, b) in p.x.iter().zip(&t) {
            assert!((a - b).abs() < REACH_MM, "{t:?}: reached {:?}", p.x);
        }
        // A moment about z alone turns the platform about z, positively.
        let free = predict(&gs, &truth, &c.commands, Model::Exact, &[]).unwrap();
        let mz = predict(
            &gs,
            &truth,
            &c.commands,
            Model::Exact,
            &[0.0, 0.0, 0.0, 0.0, 0.0, 50.0],
        )
        .unwrap();
        assert!(mz.x[5] > free.x[5], "{} vs {}", mz.x[5], free.x[5]);
    }
    // Planar pose: a moment about phi (N·m).
    let rrr = common::planar("4-rrr");
    let truth = common::perturbed(rrr.spec(), 2, 0.2, 0.002);
    let t = random_targets(&rrr, 1, 5).unwrap().remove(0);
    let opts = CompensationOptions {
        force: vec![20.0, -10.0, 2.0],
        preload: vec![],
    };
    let c = compensate(&rrr, &truth, &t, Model::Exact, &opts).unwrap();
    let p = predict(&rrr, &truth, &c.commands, Model::Exact, &opts.force).unwrap();
    for (a, b) in p.x.iter().zip(&t) {
        assert!((a - b).abs() < REACH_MM, "{t:?}: reached {:?}", p.x);
    }
    let free = predict(&rrr, &truth, &c.commands, Model::Exact, &[]).unwrap();
    let turned = predict(&rrr, &truth, &c.commands, Model::Exact, &[0.0, 0.0, 5.0]).unwrap();
    assert!(turned.x[2] > free.x[2]);
}
