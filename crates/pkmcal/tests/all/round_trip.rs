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

/// `$f(&mechanism, seed)` on every shipped mechanism (a seed for each
/// kind): the reference, the planar linkages, the Gough–Stewart platforms
/// and the spatial mechanisms.
macro_rules! on_every_shipped_mechanism {
    ($f:ident) => {
        $f(&pkmcal::JeongKim2Dof::new(), 1);
        for name in ["five-bar", "3-rrr", "4-rrr", "jeong-kim-planar"] {
            $f(&planar(name), 2);
        }
        for name in ["gough-stewart-6", "gough-stewart-8"] {
            $f(&gough_stewart(name), 3);
        }
        for name in [
            "linear-delta",
            "linear-delta-4",
            "rotary-delta",
            "3-prs",
            "spatial-gough-stewart-6",
        ] {
            $f(&spatial(name), 4);
        }
    };
}

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
    on_every_shipped_mechanism!(round_trip);
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

/// A prediction from a nearby start ([`pkmcal::predict_near`]) agrees with
/// the cold one ([`pkmcal::predict`]) to this (mm, or rad): both converged
/// to the solvers' tolerances from different starts.
const NEAR_AGREES: f64 = 1e-9;

/// `predict_near` started from the joints at nearby commands (a projection's
/// step) or on the nominal mechanism (a posterior's draw) is the cold
/// prediction on every shipped mechanism, redundant ones included (the exact
/// model's equilibrium); from a start far off, or of the wrong length, the
/// prediction made as the cold one is (the start only among its pose's
/// candidate starts).
fn near_starts<M: Mechanism>(m: &M, seed: u64) {
    let spec = m.spec();
    let truth = perturbed_by_unit(spec, seed, 0.2, 2e-3);
    let nominal = Params::nominal(spec);
    let mut checked = 0;
    for t in spread(m, 12) {
        let Ok(c) = pkmcal::nominal_commands(m, &t) else {
            continue;
        };
        let Ok(cold) = pkmcal::predict(m, &truth, &c, Model::Exact, &[]) else {
            continue;
        };
        // From the nominal mechanism's joints at the same commands, and from
        // the truth's at commands a step away.
        let at_nominal = pkmcal::predict(m, &nominal, &c, Model::Exact, &[]).unwrap();
        let stepped: Vec<f64> = c.iter().map(|v| v + 1e-3).collect();
        let starts = [at_nominal.q.clone()];
        let near_step = pkmcal::predict(m, &truth, &stepped, Model::Exact, &[]);
        for start in starts.iter().chain(near_step.as_ref().map(|p| &p.q)) {
            let near = pkmcal::predict_near(m, &truth, &c, Model::Exact, &[], start).unwrap();
            let gap = near
                .x
                .iter()
                .zip(&cold.x)
                .chain(near.q.iter().zip(&cold.q))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(gap <= NEAR_AGREES, "{}: {gap:e} at {t:?}", spec.name);
        }
        // A start far off (every joint moved by 0.5, rad or mm) is not taken
        // unless it converges back to the same answer; one of the wrong
        // length is not taken.
        let far: Vec<f64> = cold.q.iter().map(|q| q + 0.5).collect();
        for start in [far.as_slice(), &cold.q[1..]] {
            let p = pkmcal::predict_near(m, &truth, &c, Model::Exact, &[], start).unwrap();
            if p.q != cold.q {
                let gap =
                    p.q.iter()
                        .zip(&cold.q)
                        .map(|(a, b)| (a - b).abs())
                        .fold(0.0, f64::max);
                assert!(gap <= NEAR_AGREES, "{}: far start {gap:e}", spec.name);
            }
        }
        checked += 1;
    }
    assert!(checked >= 6, "{}: {checked} targets checked", spec.name);
}

#[test]
fn predictions_from_near_starts_are_the_cold_ones_on_every_shipped_mechanism() {
    on_every_shipped_mechanism!(near_starts);
}
