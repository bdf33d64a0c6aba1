//! Tests of `pkmcal::engine::sensitivity`.

use nalgebra::DVector;
use pkmcal::engine::models::prepare_pose;
use pkmcal::engine::models::{Model, Pose, predict_pose};
use pkmcal::engine::sensitivity::*;
use pkmcal::{Mechanism, Params};

/// Relative error allowed between `∂q/∂p` and its finite differences.
const JOINT_REL: f64 = 1e-6;

/// `∂q/∂p` of the equilibrium is its finite differences (central,
/// Richardson-extrapolated) at nominal parameters, every column, on
/// the reference at spread poses; and a start `q + ∂q/∂p Δp` is
/// second-order close to the equilibrium for `Δp`.
#[test]
fn joint_sensitivities_are_exact() {
    let mech = pkmcal::JeongKim2Dof::new();
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let np = spec.n_params();
    let q_at = |pose: &Pose, p: &Params| predict_pose(&mech, pose, p, Model::Exact, &[]).unwrap().q;
    for target in pkmcal::apply::workspace::spread_targets(&mech, 4).unwrap() {
        let c: Vec<f64> = spec.actuated.iter().map(|&j| target.q[j]).collect();
        let pose = prepare_pose(&mech, &c, Some(&target.q)).unwrap();
        let p0 = predict_pose(&mech, &pose, &nominal, Model::Exact, &[]).unwrap();
        let dq = joint_sensitivity(&mech, &pose, &nominal, &[], &p0).unwrap();
        assert_eq!(dq.shape(), (spec.joints.len(), np));
        for col in 0..np {
            let h = 1e-4 * nominal.values[col].abs().max(1.0);
            let d = |h: f64| {
                let (mut a, mut b) = (nominal.clone(), nominal.clone());
                a.values[col] += h;
                b.values[col] -= h;
                let (qa, qb) = (q_at(&pose, &a), q_at(&pose, &b));
                qa.iter()
                    .zip(&qb)
                    .map(|(x, y)| (x - y) / (2.0 * h))
                    .collect::<Vec<_>>()
            };
            let (d1, d2) = (d(h), d(h / 2.0));
            let scale = dq.column(col).amax().max(1e-6);
            for (r, (a, b)) in d1.iter().zip(&d2).enumerate() {
                let fd = (4.0 * b - a) / 3.0;
                assert!(
                    (fd - dq[(r, col)]).abs() <= JOINT_REL * scale,
                    "column {col} row {r}: {} vs {fd}",
                    dq[(r, col)]
                );
            }
        }
        // Second order: halving Δp quarters the start's error.
        let miss = |s: f64| {
            let mut p = nominal.clone();
            let mut delta = vec![0.0; np];
            for (i, d) in delta.iter_mut().enumerate().take(spec.n_geometric()) {
                *d = s * if i % 2 == 0 { 0.1 } else { -0.07 };
                p.values[i] += *d;
            }
            let exact = q_at(&pose, &p);
            let start = &DVector::from_column_slice(&p0.q) + &dq * DVector::from_vec(delta);
            exact
                .iter()
                .zip(start.iter())
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
        };
        let (far, near) = (miss(1.0), miss(0.5));
        assert!(near < 0.3 * far, "{far:e} then {near:e}");
    }
}
