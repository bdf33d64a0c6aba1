//! Compensation: the actuator commands that put the tool on a target under a
//! calibrated model, including encoder offsets and the deflection of the
//! actuated joints under internal torques and an external load.
//!
//! At the target the mechanism must be in the configuration `q*` given by
//! inverse kinematics with the calibrated geometry. The exact model's
//! equilibrium there requires torques with `Γᵀτ = P` (eq. 10, at `q*`). Of
//! these, the least elastic energy `½ τᵀK⁻¹τ` gives `τ₀ = KΓ(ΓᵀKΓ)⁻¹P`: zero
//! without load, i.e. consistent commands. A preload adds internal torque in
//! `null(Γᵀ)` (it does no work on feasible motions, so the pose stays). The
//! commands follow from eq. 2: `c = q_r* − Δq + K⁻¹τ`.

use crate::autodiff::jacobians;
use crate::error::{Error, Result};
use crate::kinematics::{checked_lu, inverse_kinematics};
use crate::linearized::{linearize, load_vector};
use crate::mechanism::{Mechanism, Params};
use crate::models::Model;
use nalgebra::{DMatrix, DVector};

/// Commands for one target.
#[derive(Debug, Clone, PartialEq)]
pub struct Compensation {
    /// Actuator commands (rad or mm), one per actuated joint.
    pub commands: Vec<f64>,
    /// Internal torque each actuator will hold (N·m), `τ = K(c + Δq − q_r)`.
    pub torque: Vec<f64>,
    /// The joint configuration the mechanism reaches.
    pub q: Vec<f64>,
}

/// What the commands must achieve besides the position.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CompensationOptions {
    /// External load on the tool, a wrench ([`crate::load`]: N along lengths,
    /// N·m about angles); empty for none.
    pub force: Vec<f64>,
    /// Desired actuator torques (N·m) whose internal part (the projection on
    /// `null(Γᵀ)`, which does no work) is held as a preload; empty for none.
    pub preload: Vec<f64>,
}

/// Commands that bring the tool to `target` under `params` with `model`
/// (`Exact`: the deflections included; `Rigid`: consistent commands that ignore
/// deflection under load). The linear model is an approximation of the exact
/// one and is not inverted.
pub fn compensate<M: Mechanism>(
    mech: &M,
    params: &Params,
    target: &[f64],
    model: Model,
    opts: &CompensationOptions,
) -> Result<Compensation> {
    let spec = mech.spec();
    let rho = params.geometric();
    let q = inverse_kinematics(mech, rho, target)?;
    let nq = spec.joints.len();
    let l = spec.n_actuated();
    let loaded = opts.force.iter().any(|f| *f != 0.0);
    let preloaded = opts.preload.iter().any(|t| *t != 0.0);
    if !opts.preload.is_empty() && opts.preload.len() != l {
        return Err(Error::Dimension {
            what: "preload torques".into(),
            expected: l,
            got: opts.preload.len(),
        });
    }
    if !opts.force.is_empty() && opts.force.len() != spec.tool_axes.len() {
        return Err(Error::Dimension {
            what: "tool force".into(),
            expected: spec.tool_axes.len(),
            got: opts.force.len(),
        });
    }
    if model == Model::Linear {
        return Err(Error::InvalidRequest(
            "compensation inverts the exact model (or the rigid one); use --model exact".into(),
        ));
    }
    if let Some(v) = opts
        .force
        .iter()
        .chain(&opts.preload)
        .find(|v| !(v.is_finite() && v.abs() <= crate::units::MAX_LOAD))
    {
        return Err(Error::InvalidRequest(format!(
            "load or preload value {v:?} is beyond ±{:e} (N, N·m); no machine bears that",
            crate::units::MAX_LOAD
        )));
    }
    let mut torque = vec![0.0; l];
    if model == Model::Exact && (loaded || preloaded) {
        let lin = linearize(mech, &q, rho, &spec.independent).map_err(|_| Error::Singular {
            q: q.clone(),
            reason: format!("target {target:?} is at a singular configuration"),
        })?;
        let k = params.stiffness();
        let kd = DMatrix::from_diagonal(&DVector::from_column_slice(k));
        let gamma = &lin.gamma;
        let gkg = gamma.transpose() * &kd * gamma;
        let m = gkg.try_inverse().ok_or_else(|| Error::Singular {
            q: q.clone(),
            reason: "ΓᵀKΓ is singular".into(),
        })?;
        let mut tau = DVector::zeros(l);
        if loaded {
            let q_load = crate::load::generalized_forces(spec.tool_layout, target, &opts.force);
            let p = load_vector(&lin, &q_load);
            tau += &kd * gamma * (&m * p);
        }
        if preloaded {
            // Projection on null(Γᵀ): t − Γ(ΓᵀΓ)⁻¹Γᵀt.
            let t = DVector::from_column_slice(&opts.preload);
            let gg = (gamma.transpose() * gamma)
                .try_inverse()
                .ok_or_else(|| Error::Singular {
                    q: q.clone(),
                    reason: "Γ is rank deficient".into(),
                })?;
            tau += &t - gamma * (gg * (gamma.transpose() * &t));
        }
        torque = tau.iter().copied().collect();
    } else {
        // Singular configurations are refused even without load.
        let j = jacobians(mech, &q, rho, 0..nq);
        let dependent: Vec<usize> = (0..nq).filter(|i| !spec.independent.contains(i)).collect();
        if checked_lu(j.dg.select_columns(&dependent)).is_none() {
            return Err(Error::Singular {
                q,
                reason: format!("target {target:?} is at a singular configuration"),
            });
        }
    }
    let commands: Vec<f64> = spec
        .actuated
        .iter()
        .enumerate()
        .map(|(a, &j)| q[j] - params.offsets()[a] + torque[a] / params.stiffness()[a])
        .collect();
    for (a, &j) in spec.actuated.iter().enumerate() {
        let deflection = torque[a] / params.stiffness()[a];
        let limit = match spec.joint_units[j] {
            crate::Unit::Radian => crate::units::MAX_DEFLECTION_RAD,
            _ => crate::units::MAX_DEFLECTION_MM,
        };
        if deflection.abs() > limit {
            return Err(Error::InvalidRequest(format!(
                "at target {target:?} the load or preload deflects actuator `{}` by {deflection:.4e} {}; the model holds for small deflections (below {limit} {}): reduce the load",
                spec.actuated_names()[a],
                spec.joint_units[j],
                spec.joint_units[j]
            )));
        }
    }
    if commands.iter().chain(&torque).any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(format!(
            "the compensated commands for target {target:?} are not finite: the load is more than the model can represent"
        )));
    }
    Ok(Compensation {
        commands,
        torque,
        q,
    })
}
