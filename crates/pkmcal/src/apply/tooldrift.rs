//! Drift at the tool: two calibrations of one machine (or one against its
//! nominal values) compared where the user feels them, the predicted tool
//! pose over the workspace ([`crate::identify::drift`] compares the
//! parameters, and says what: with priors, what the data added to them). At
//! each target's nominal commands the change `Δx = x(q; p_b) − x(q; p_a)`
//! has, when the machine did not change, the covariance
//! `C = J (V_a + V_b) Jᵀ` to first order (`J = ∂x/∂p` at `p_a`, over the
//! parameters both identified, what neither's data see left out);
//! `Δxᵀ C⁺ Δx` in correlation form is then χ² with the rank of `C`
//! (Fisher's F with the noise levels' degrees of freedom when they were
//! estimated), the rule of the joint parameter test.

use crate::engine::models::{Model, predict_pose, prepare_pose};
use crate::engine::sensitivity::sensitivity;
use crate::error::{Error, Result};
use crate::identify::drift::{Compared, TargetDrift, WorkspaceDrift, prepare, quadratic_test};
use crate::mechanism::{Mechanism, Params};
use crate::units::Unit;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// The parameters a calibration gives, by name over `mech`'s (the others
/// nominal), the compared values of the tested ones replacing them.
fn params_of<M: Mechanism>(mech: &M, c: &Compared, tested: &[String], values: &[f64]) -> Params {
    let spec = mech.spec();
    let mut p = Params::nominal(spec);
    for (name, v) in &c.values {
        if let Ok(i) = spec.param_index(name) {
            p.values[i] = *v;
        }
    }
    for (name, v) in tested.iter().zip(values) {
        if let Ok(i) = spec.param_index(name) {
            p.values[i] = *v;
        }
    }
    p
}

/// The change at the tool from calibration `a` to `b` at each target (tool
/// poses, mm and rad), each judged at `alpha`.
pub fn workspace_drift<M: Mechanism>(
    mech: &M,
    a: &Compared,
    b: &Compared,
    targets: &[Vec<f64>],
    alpha: f64,
) -> Result<WorkspaceDrift> {
    workspace_drift_cancellable(mech, a, b, targets, alpha, None)
}

/// [`workspace_drift`], stopped at its next target once `cancel` is set
/// ([`Error::Cancelled`]).
pub fn workspace_drift_cancellable<M: Mechanism>(
    mech: &M,
    a: &Compared,
    b: &Compared,
    targets: &[Vec<f64>],
    alpha: f64,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<WorkspaceDrift> {
    if targets.is_empty() {
        return Err(Error::InvalidRequest(
            "a workspace drift needs at least one target".into(),
        ));
    }
    let spec = mech.spec();
    let prepared = prepare(a, b)?;
    let (va, ca) = prepared.in_units(false);
    let (vb, cb) = prepared.in_units(true);
    let (pa, pb) = (
        params_of(mech, a, &prepared.tested, &va),
        params_of(mech, b, &prepared.tested, &vb),
    );
    // The covariance of the change over all of `mech`'s parameters.
    let n = spec.n_params();
    let idx: Vec<Option<usize>> = prepared
        .tested
        .iter()
        .map(|m| spec.param_index(m).ok())
        .collect();
    let mut cov = DMatrix::zeros(n, n);
    for (x, ix) in idx.iter().enumerate() {
        for (y, iy) in idx.iter().enumerate() {
            if let (Some(i), Some(j)) = (ix, iy) {
                cov[(*i, *j)] = ca[(x, y)] + cb[(x, y)];
            }
        }
    }
    let nu = prepared.nu;
    let lengths: Vec<usize> = (0..spec.tool_axes.len())
        .filter(|&k| spec.tool_units[k] == Unit::Millimetre)
        .collect();
    let out: Vec<TargetDrift> = targets
        .par_iter()
        .enumerate()
        .map(|(k, t)| {
            crate::error::check_cancel(cancel)?;
            let at = |e: Error| e.at_pose(crate::error::Origin::row(k));
            let q = crate::apply::workspace::nominal_commands(mech, t).map_err(at)?;
            let pose = prepare_pose(mech, &q, None).map_err(at)?;
            let s = sensitivity(mech, &pose, &pa, Model::Exact, &[]).map_err(at)?;
            let xb = predict_pose(mech, &pose, &pb, Model::Exact, &[]).map_err(at)?;
            let change: Vec<f64> =
                xb.x.iter()
                    .zip(&s.prediction.x)
                    .map(|(b, a)| b - a)
                    .collect();
            let c = &s.jacobian * &cov * s.jacobian.transpose();
            let d = DVector::from_column_slice(&change);
            let (statistic, dof, p_value) = quadratic_test(&c, &d, nu)?;
            Ok(TargetDrift {
                target: t.clone(),
                distance: lengths
                    .iter()
                    .map(|&i| change[i] * change[i])
                    .sum::<f64>()
                    .sqrt(),
                change,
                statistic,
                dof,
                p_value,
            })
        })
        .collect::<Result<_>>()?;
    let largest = (0..out.len())
        .max_by(|&i, &j| out[i].distance.total_cmp(&out[j].distance))
        .unwrap_or(0);
    Ok(WorkspaceDrift {
        beyond: out.iter().filter(|t| t.p_value < alpha).count(),
        targets: out,
        largest,
        alpha,
    })
}
