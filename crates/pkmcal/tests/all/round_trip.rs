//! Compensate, then predict: on every shipped mechanism, commands that
//! `compensate` computes under perturbed parameters for a target bring the
//! tool back to that target when predicted from the commands alone (forward
//! kinematics finds the configuration compensation found, wherever the
//! targets are: the poses `plan` chooses at the edges of the workspace,
//! random lattice points, spread targets).

use crate::common::*;
use pkmcal::{
    CompensationOptions, Mechanism, Model, Params, PlanCriterion, PlanOptions, compensate,
    predict_pose, prepare_pose,
};

/// Compensated commands predicted back reach their target to this (mm, or
/// rad on an orientation axis).
const ROUND_TRIP: f64 = 1e-9;
/// Share of the targets that must stay reachable under the perturbed
/// parameters (a target on the workspace's edge may leave it).
const REACHABLE_SHARE: f64 = 0.8;

/// `count` poses `plan` chooses (O5, exact model, the default free set,
/// from at most `candidates` lattice points) at nominal parameters.
fn planned<M: Mechanism>(m: &M, count: usize, candidates: usize) -> Vec<Vec<f64>> {
    let spec = m.spec();
    let free: Vec<usize> = spec
        .default_free
        .iter()
        .map(|n| spec.param_index(n).unwrap())
        .collect();
    let opts = PlanOptions {
        count,
        criterion: PlanCriterion::O5,
        model: Model::Exact,
        free,
        spacing: 6.0,
        max_candidates: candidates,
        cancel: None,
        priors: vec![],
        noise: pkmcal::Noise::lengths(0.002),
    };
    pkmcal::plan(m, &Params::nominal(spec), &opts, &|_, _| {})
        .unwrap()
        .poses
        .into_iter()
        .map(|p| p.target)
        .collect()
}

fn round_trip<M: Mechanism + Sync>(m: &M, seed: u64) {
    let spec = m.spec();
    let truth = perturbed_by_unit(spec, seed, 0.3, 0.002);
    let count = 2 * spec.default_free.len().max(spec.tool_axes.len());
    let mut targets = planned(m, count, 600);
    targets.extend(pkmcal::random_targets(m, 30, seed).unwrap());
    targets.extend(spread(m, 12));
    let mut reached = 0;
    for t in &targets {
        let Ok(c) = compensate(m, &truth, t, Model::Exact, &CompensationOptions::default()) else {
            continue;
        };
        reached += 1;
        let pose = prepare_pose(m, &c.commands, None)
            .unwrap_or_else(|e| panic!("{}: target {t:?}: {e}", spec.name));
        let p = predict_pose(m, &pose, &truth, Model::Exact, &[])
            .unwrap_or_else(|e| panic!("{}: target {t:?}: {e}", spec.name));
        for (a, b) in p.x.iter().zip(t) {
            assert!(
                (a - b).abs() < ROUND_TRIP,
                "{}: target {t:?} came back as {:?}",
                spec.name,
                p.x
            );
        }
    }
    assert!(
        reached as f64 >= REACHABLE_SHARE * targets.len() as f64,
        "{}: {reached} of {} targets compensated",
        spec.name,
        targets.len()
    );
}

#[test]
fn compensated_commands_predict_back_to_their_targets_on_every_shipped_mechanism() {
    round_trip(&pkmcal::JeongKim2Dof::new(), 1);
    for name in ["five-bar", "3-rrr", "4-rrr", "jeong-kim-planar"] {
        round_trip(&planar(name), 2);
    }
    for name in ["gough-stewart-6", "gough-stewart-8"] {
        round_trip(&gough_stewart(name), 3);
    }
    for name in [
        "linear-delta",
        "linear-delta-4",
        "rotary-delta",
        "3-prs",
        "spatial-gough-stewart-6",
    ] {
        round_trip(&spatial(name), 4);
    }
}

/// The README's case: the reference mechanism with `l11 = 280.3` and
/// `dq3 = 0.002`, compensated at the 35 planned poses (eight of which lie
/// where forward kinematics from the reference configuration crosses a
/// singularity), predicted back.
#[test]
fn the_readme_plan_compensated_predicts_back() {
    let m = pkmcal::JeongKim2Dof::new();
    let spec = m.spec();
    let mut truth = Params::nominal(spec);
    truth.values[spec.param_index("l11").unwrap()] = 280.3;
    truth.values[spec.param_index("dq3").unwrap()] = 0.002;
    let c = pkmcal::nominal_commands(&m, &[232.0, 102.0]).unwrap();
    let shifted = [c[0], c[1] - 5e-4, c[2]];
    prepare_pose(&m, &shifted, None).unwrap();
    for t in planned(&m, 35, 4000) {
        let c = compensate(
            &m,
            &truth,
            &t,
            Model::Exact,
            &CompensationOptions::default(),
        )
        .unwrap();
        let pose = prepare_pose(&m, &c.commands, None).unwrap();
        let x = predict_pose(&m, &pose, &truth, Model::Exact, &[])
            .unwrap()
            .x;
        for (a, b) in x.iter().zip(&t) {
            assert!((a - b).abs() < ROUND_TRIP, "{t:?} came back as {x:?}");
        }
    }
}
