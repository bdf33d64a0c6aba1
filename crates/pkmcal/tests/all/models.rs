//! Tests of `pkmcal::engine::models`.

use crate::common::table as example;
use pkmcal::engine::models::*;
use pkmcal::{Mechanism, Params};

/// Poses prepared with the start-independent work done ahead are, bit
/// for bit, those prepared in turn from the pose before (on a planar
/// linkage and a Gough–Stewart platform, near and far successors, and
/// commands that cannot be assembled).
fn same_ahead<M: Mechanism>(mech: &M) {
    let spec = mech.spec();
    let targets = pkmcal::apply::workspace::spread_targets(mech, 30).unwrap();
    let mut commands: Vec<Vec<f64>> = targets
        .iter()
        .map(|p| spec.actuated.iter().map(|&j| p.q[j]).collect())
        .collect();
    // A near successor (one continuation stage away), and one beyond reach.
    let near: Vec<f64> = commands[3].iter().map(|c| c + 1e-3).collect();
    commands.insert(4, near);
    commands.insert(9, commands[8].iter().map(|c| c + 1e4).collect());
    let mut prev: Option<Vec<f64>> = None;
    let mut prev_ahead: Option<Vec<f64>> = None;
    let mut from_guess = 0;
    for c in &commands {
        let a = prepare_pose(mech, c, prev.as_deref());
        let ahead = pose_ahead(mech, c);
        from_guess += ahead.as_ref().is_some_and(|a| a.pose.is_some()) as usize;
        let b = prepare_pose_ahead(mech, c, prev_ahead.as_deref(), ahead);
        match (a, b) {
            (Ok(a), Ok(b)) => {
                assert_eq!(a.nominal_q, b.nominal_q);
                assert_eq!(a.commands, b.commands);
                prev = Some(a.nominal_q);
                prev_ahead = Some(b.nominal_q);
            }
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
            (a, b) => panic!("prepared in turn: {a:?}; ahead: {b:?}"),
        }
    }
    assert!(
        from_guess > commands.len() / 2,
        "{from_guess} poses from the guess"
    );
}

#[test]
fn poses_prepared_ahead_are_those_prepared_in_turn() {
    same_ahead(&pkmcal::PlanarLinkage::new(&example("4-rrr").try_into().unwrap()).unwrap());
    same_ahead(
        &pkmcal::GoughStewart::new(&example("gough-stewart-8").try_into().unwrap()).unwrap(),
    );
}

/// A prediction started from one for parameters a calibration's error
/// away is the one started from the nominal configuration to within
/// the equilibrium's tolerance (same assembly mode), on the reference
/// (whose equilibrium keeps its KKT factors between steps) and the
/// 4-RRR (null-space solves); a start on another assembly mode is not
/// taken: the prediction is then the cold one, bit for bit.
fn near_starts<M: Mechanism>(mech: &M) {
    use rand::{RngExt, SeedableRng};
    let spec = mech.spec();
    let mut rng = rand::rngs::StdRng::seed_from_u64(3);
    let nominal = Params::nominal(spec);
    let mut checked = 0;
    for target in pkmcal::apply::workspace::spread_targets(mech, 12).unwrap() {
        let c: Vec<f64> = spec.actuated.iter().map(|&j| target.q[j]).collect();
        let pose = prepare_pose(mech, &c, Some(&target.q)).unwrap();
        let mut truth = nominal.clone();
        for v in &mut truth.values[..spec.n_geometric()] {
            *v += rng.random_range(-0.3..0.3);
        }
        let mut cal = truth.clone();
        for v in &mut cal.values[..spec.n_geometric()] {
            *v += rng.random_range(-1e-3..1e-3);
        }
        let (Ok(t), Ok(cold)) = (
            predict_pose(mech, &pose, &truth, Model::Exact, &[]),
            predict_pose(mech, &pose, &cal, Model::Exact, &[]),
        ) else {
            continue;
        };
        let warm = predict_pose_near(mech, &pose, &cal, Model::Exact, &[], &t.q).unwrap();
        let far = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        };
        assert!(far(&warm.q, &cold.q) < 1e-10, "{:?} {:?}", warm.q, cold.q);
        assert!(far(&warm.x, &cold.x) < 1e-9, "{:?} {:?}", warm.x, cold.x);
        assert!(far(&warm.torque, &cold.torque) < 1e-6);
        // A start a radian away on every joint (another assembly's
        // neighbourhood) is refused or lands on the cold answer.
        let mut other = t.clone();
        other.q.iter_mut().for_each(|q| *q += 1.0);
        let p = predict_pose_near(mech, &pose, &cal, Model::Exact, &[], &other.q).unwrap();
        assert!(far(&p.q, &cold.q) < 1e-10, "{:?} {:?}", p.q, cold.q);
        checked += 1;
    }
    assert!(checked >= 8, "{checked} poses");
}

/// [`predict_pose_near_into`] into a new prediction.
fn predict_pose_near<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    start: &[f64],
) -> pkmcal::Result<Prediction> {
    let mut p = Prediction::default();
    predict_pose_near_into(mech, pose, params, model, force, start, &mut p)?;
    Ok(p)
}

#[test]
fn predictions_from_near_ones_are_the_cold_ones() {
    near_starts(&pkmcal::JeongKim2Dof::new());
    near_starts(&pkmcal::PlanarLinkage::new(&example("4-rrr").try_into().unwrap()).unwrap());
}

/// A pose's prediction at nominal parameters, kept for one model and
/// load, is `predict_pose`'s bit for bit, for that model and load and for
/// others asked afterwards (which are not served the kept one).
#[test]
fn predictions_kept_at_nominal_are_predict_pose_s() {
    let mech = pkmcal::PlanarLinkage::new(&example("4-rrr").try_into().unwrap()).unwrap();
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let bits = |p: &Prediction| {
        [&p.q, &p.x, &p.torque]
            .iter()
            .flat_map(|v| v.iter().map(|x| x.to_bits()))
            .collect::<Vec<_>>()
    };
    let load = [5.0, -3.0, 0.0];
    for target in pkmcal::apply::workspace::spread_targets(&mech, 5).unwrap() {
        let c: Vec<f64> = spec.actuated.iter().map(|&j| target.q[j]).collect();
        let pose = prepare_pose(&mech, &c, Some(&target.q)).unwrap();
        for (model, force) in [
            (Model::Exact, &[][..]),
            (Model::Exact, &[][..]),
            (Model::Linear, &[][..]),
            (Model::Exact, &load[..]),
            (Model::Exact, &[][..]),
        ] {
            let kept = pose
                .predict_at_nominal(&mech, &nominal, model, force)
                .unwrap();
            let fresh = predict_pose(&mech, &pose, &nominal, model, force).unwrap();
            assert_eq!(bits(&kept), bits(&fresh), "{model:?} {force:?}");
        }
    }
}

/// A prediction written into one that held another (another pose's,
/// another model's, a loaded one's) is the one made afresh, bit for
/// bit, warm-started or not, from a near start, and at nominal
/// parameters: a fit's evaluations and a Monte Carlo run's predictions
/// write into their previous ones.
fn reused(mech: &impl Mechanism, load: &[f64]) {
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let mut off = nominal.clone();
    for (v, d) in off
        .values
        .iter_mut()
        .zip([1e-3, -2e-3, 5e-4].iter().cycle())
    {
        *v += d * v.abs().max(1.0);
    }
    let mut used = Prediction::default();
    for target in pkmcal::apply::workspace::spread_targets(mech, 4).unwrap() {
        let c: Vec<f64> = spec.actuated.iter().map(|&j| target.q[j]).collect();
        let pose = prepare_pose(mech, &c, Some(&target.q)).unwrap();
        for model in [Model::Exact, Model::Linear, Model::Rigid] {
            for force in [&[][..], load] {
                let warm = predict_pose(mech, &pose, &nominal, model, force).unwrap();
                for start in [None, Some(warm.q.as_slice())] {
                    let fresh = predict_pose_warm(mech, &pose, &off, model, force, start).unwrap();
                    predict_pose_warm_into(mech, &pose, &off, model, force, start, &mut used)
                        .unwrap();
                    assert!(used.same_bits(&fresh), "{model:?} {force:?}");
                }
                let fresh = predict_pose_near(mech, &pose, &off, model, force, &warm.q).unwrap();
                predict_pose_near_into(mech, &pose, &off, model, force, &warm.q, &mut used)
                    .unwrap();
                assert!(used.same_bits(&fresh), "{model:?} {force:?} near");
                let fresh = pose
                    .predict_at_nominal(mech, &nominal, model, force)
                    .unwrap();
                pose.predict_at_nominal_into(mech, &nominal, model, force, &mut used)
                    .unwrap();
                assert!(used.same_bits(&fresh), "{model:?} {force:?} at nominal");
            }
        }
    }
}

#[test]
fn predictions_written_into_used_ones_are_fresh_ones() {
    reused(&pkmcal::JeongKim2Dof::new(), &[2.0, -1.0]);
    reused(
        &pkmcal::PlanarLinkage::new(&example("4-rrr").try_into().unwrap()).unwrap(),
        &[5.0, -3.0, 0.0],
    );
}
