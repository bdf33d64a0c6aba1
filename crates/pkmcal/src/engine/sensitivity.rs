//! Exact derivatives of the predicted tool position with respect to every
//! parameter (`[ρ, Δq, k]`), for each forward model: the identification
//! Jacobian of eq. 12, by implicit differentiation of the loop closure and of
//! the equilibrium (never finite differences around a nested solve).

use crate::engine::linearized::load_vector;
use crate::engine::models::{Model, Pose, Prediction, independent_actuators, predict_pose};
use crate::error::{Error, Result};
use crate::linalg::solve::{solve_scaled, solve_scaled_in_place};
use crate::mechanism::autodiff::jacobians_into;
use crate::mechanism::{Mechanism, Params};
use nalgebra::{DMatrix, DVector};

/// A prediction with its derivatives.
#[derive(Debug, Clone)]
pub struct Sensitivity {
    /// The prediction itself.
    pub prediction: Prediction,
    /// `∂x/∂p`: tool coordinates per parameter (nx × n_params), mm per unit.
    pub jacobian: DMatrix<f64>,
}

/// Prediction of `pose` under `params` with `model`, and `∂x/∂p` for every
/// parameter (`[ρ, Δq, k]`).
///
/// * rigid: `x = x(q(q_u, ρ), ρ)` with `q_u = c_u + Δq_u`: loop-closure
///   sensitivities (eq. 5) at the actual configuration;
/// * linear: `q_u = c_u + dq_u(Δq, ρ, k)` from eq. 11, whose derivatives are
///   linear in Δq and ρ and rational in k (`∂Λ/∂k_j` analytic), then the
///   loop-closure sensitivities at the actual configuration;
/// * exact: implicit differentiation of the KKT system of [`equilibrium`]
///   with fresh second derivatives at the solution: `dz/dp = −F_z⁻¹ F_p`.
pub fn sensitivity<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
) -> Result<Sensitivity> {
    let prediction = predict_pose(mech, pose, params, model, force)?;
    sensitivity_at(mech, pose, params, model, force, prediction)
}

/// [`sensitivity`] for a prediction already computed (with the same pose,
/// parameters, model and force).
pub fn sensitivity_at<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    prediction: Prediction,
) -> Result<Sensitivity> {
    let jacobian = tool_sensitivity(mech, pose, params, model, force, &prediction)?;
    Ok(Sensitivity {
        prediction,
        jacobian,
    })
}

/// `∂x/∂p` of [`sensitivity_at`], for a prediction the caller keeps.
pub(crate) fn tool_sensitivity<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    prediction: &Prediction,
) -> Result<DMatrix<f64>> {
    let spec = mech.spec();
    let ng = spec.n_geometric();
    let nx = spec.tool_axes.len();
    let np = spec.n_params();
    let rho = params.geometric();
    let force = crate::engine::models::effective_force(mech, pose, force)?;
    let effective = crate::engine::models::effective_model(spec, model, &force);
    match effective {
        Model::Rigid | Model::Linear => {
            let ind = independent_actuators(spec);
            let mut jac = DMatrix::zeros(nx, np);
            let (jf, jx_rho) = crate::engine::linearized::tool_derivatives(
                mech,
                &prediction.q,
                rho,
                &spec.independent,
            )?;
            // ∂x/∂ρ at fixed independent joints.
            jac.columns_mut(0, ng).copy_from(&jx_rho);
            // ∂q_u/∂p, then through J_f.
            let mut dqu = DMatrix::zeros(spec.dof(), np);
            // The model that computes (the exact and linear models are the
            // rigid one when nothing loads the actuators).
            if effective == Model::Rigid {
                for (k, &a) in ind.iter().enumerate() {
                    dqu[(k, ng + a)] = 1.0;
                }
            } else {
                dqu = linear_qu_derivatives(mech, pose, params, &force)?;
            }
            jac += &jf * dqu;
            Ok(jac)
        }
        Model::Exact => exact_sensitivity(mech, params, &pose.commands, &force, prediction),
    }
}

/// `∂q_u/∂p` of the linear model (eq. 11 rows of the independent joints).
fn linear_qu_derivatives<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    force: &[f64],
) -> Result<DMatrix<f64>> {
    let spec = mech.spec();
    let (ng, na) = (spec.n_geometric(), spec.n_actuated());
    let np = spec.n_params();
    let ind = independent_actuators(spec);
    let lin = pose.lin(mech)?;
    let k = params.stiffness();
    let kd = DMatrix::from_diagonal(&DVector::from_column_slice(k));
    let gamma = &lin.gamma;
    let m = crate::engine::linearized::stiffness_inverse(gamma, k, &pose.nominal_q)?;
    let lambda = crate::engine::linearized::projection_with(gamma, k, &m);
    let eye = DMatrix::<f64>::identity(na, na);
    let ih = (&eye - &lambda) * &lin.h;
    let nominal = &spec.nominal[..ng];
    let offsets: DVector<f64> = DVector::from_iterator(
        na,
        spec.actuated
            .iter()
            .enumerate()
            .map(|(a, &j)| params.offsets()[a] + pose.commands[a] - pose.nominal_q[j]),
    );
    let drho = DVector::from_iterator(
        ng,
        params.geometric().iter().zip(nominal).map(|(a, b)| a - b),
    );
    let p = load_vector(lin, force);
    let mut d = DMatrix::zeros(spec.dof(), np);
    let v = &offsets - &lin.h * &drho;
    for (r, &a) in ind.iter().enumerate() {
        for c in 0..ng {
            d[(r, c)] = ih[(a, c)];
        }
        for c in 0..na {
            d[(r, ng + c)] = lambda[(a, c)];
        }
    }
    for j in 0..na {
        // ∂M/∂k_j = −M Γᵀ E_j Γ M;  ∂Λ/∂k_j = Γ ∂M ΓᵀK + Γ M Γᵀ E_j.
        let gj = gamma.row(j).transpose();
        let dm = -(&m * &gj * gj.transpose() * &m);
        let mut ej = DMatrix::zeros(na, na);
        ej[(j, j)] = 1.0;
        let dl = gamma * &dm * gamma.transpose() * &kd + gamma * &m * gamma.transpose() * ej;
        let ddq = &dl * &v - gamma * (&dm * &p);
        for (r, &a) in ind.iter().enumerate() {
            d[(r, ng + na + j)] = ddq[a];
        }
    }
    Ok(d)
}

/// `∂q/∂p` of the exact model's equilibrium at `prediction` (nq × n_params):
/// `dz/dp = −F_z⁻¹ F_p` of the KKT conditions, the joints' rows, the same
/// blocks as [`exact_sensitivity`] differentiates. `None` where the exact
/// model is not what computes (no load on the actuators: the rigid one) or
/// the system is singular. A start `q + ∂q/∂p Δp` for parameters `Δp`
/// away is then second-order close to their equilibrium (a Monte Carlo
/// run's truth, [`crate::apply::montecarlo`]).
#[doc(hidden)] // public for the integration tests only
pub fn joint_sensitivity<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    force: &[f64],
    prediction: &Prediction,
) -> Option<DMatrix<f64>> {
    let spec = mech.spec();
    let force = crate::engine::models::effective_force(mech, pose, force).ok()?;
    if crate::engine::models::effective_model(spec, Model::Exact, &force) != Model::Exact {
        return None;
    }
    let (ng, na) = (spec.n_geometric(), spec.n_actuated());
    let nq = spec.joints.len();
    let m = spec.n_constraints;
    let np = spec.n_params();
    if prediction.multipliers.len() != m {
        return None;
    }
    let (rho, k, q) = (params.geometric(), params.stiffness(), &prediction.q);
    let w: Vec<f64> = force.iter().map(|f| -f * spec.work_scale).collect();
    let j = crate::mechanism::autodiff::jacobians(mech, q, rho, 0..nq + ng);
    let lag = mech.weighted_hessian(q, rho, &prediction.multipliers, &w);
    let mut fz = DMatrix::zeros(nq + m, nq + m);
    fz.view_mut((0, 0), (nq, nq)).copy_from(&lag.columns(0, nq));
    for (a, &jt) in spec.actuated.iter().enumerate() {
        fz[(jt, jt)] += k[a];
    }
    for c in 0..nq {
        for r in 0..m {
            fz[(c, nq + r)] = j.dg[(r, c)];
            fz[(nq + r, c)] = j.dg[(r, c)];
        }
    }
    // −F_p: the ρ columns `−[∂²L/∂q∂ρ; ∂g/∂ρ]`; an offset's `k_a` and a
    // stiffness's `c_a + Δq_a − q_a` on its joint's row.
    let mut rhs = DMatrix::zeros(nq + m, np);
    rhs.view_mut((0, 0), (nq, ng))
        .copy_from(&(-lag.columns(nq, ng)));
    rhs.view_mut((nq, 0), (m, ng))
        .copy_from(&(-j.dg.columns(nq, ng)));
    for (a, &jt) in spec.actuated.iter().enumerate() {
        rhs[(jt, ng + a)] = k[a];
        rhs[(jt, ng + na + a)] = pose.commands[a] + params.offsets()[a] - q[jt];
    }
    let dz = solve_scaled(fz, rhs)?;
    Some(dz.rows(0, nq).into_owned())
}

/// The buffers of [`exact_sensitivity`], reused from one call to the next
/// on a thread (as the equilibrium's): a call allocates its result and the
/// mechanism's weighted Hessian only.
#[derive(Default)]
struct SensitivityWork {
    /// `−force · work_scale`.
    w: Vec<f64>,
    /// Derivatives at the solution.
    j: Option<crate::mechanism::autodiff::Jacobians>,
    /// `F_z`, then its transpose, factorised in place.
    fz: DMatrix<f64>,
    fzt: DMatrix<f64>,
    /// `[X_q 0]ᵀ`, then the adjoint `Y`.
    y: DMatrix<f64>,
}

thread_local! {
    static SENSITIVITY_WORK: std::cell::RefCell<SensitivityWork> =
        std::cell::RefCell::new(SensitivityWork::default());
}

/// Size a matrix to `r × c` (zeros), keeping its storage when the shape fits.
fn zeroed(m: &mut DMatrix<f64>, r: usize, c: usize) {
    if m.shape() == (r, c) {
        m.fill(0.0);
    } else {
        *m = DMatrix::zeros(r, c);
    }
}

/// Implicit differentiation of the KKT conditions of the equilibrium at its
/// solution `prediction.q` (exact model).
fn exact_sensitivity<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    force: &[f64],
    prediction: &Prediction,
) -> Result<DMatrix<f64>> {
    // (A nested call, which nothing makes today, would get buffers of its
    // own.)
    SENSITIVITY_WORK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut ws) => exact_sensitivity_in(mech, params, commands, force, prediction, &mut ws),
        Err(_) => exact_sensitivity_in(
            mech,
            params,
            commands,
            force,
            prediction,
            &mut SensitivityWork::default(),
        ),
    })
}

/// [`exact_sensitivity`] in the workspace `ws`.
fn exact_sensitivity_in<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    force: &[f64],
    prediction: &Prediction,
    ws: &mut SensitivityWork,
) -> Result<DMatrix<f64>> {
    let spec = mech.spec();
    let (ng, na) = (spec.n_geometric(), spec.n_actuated());
    let nq = spec.joints.len();
    let m = spec.n_constraints;
    let nx = spec.tool_axes.len();
    let np = spec.n_params();
    let rho = params.geometric();
    let k = params.stiffness();
    let q = &prediction.q;
    let SensitivityWork { w, j, fz, fzt, y } = ws;
    w.clear();
    w.extend(force.iter().map(|f| -f * spec.work_scale));
    let j = j.get_or_insert_with(crate::mechanism::autodiff::Jacobians::empty);
    jacobians_into(mech, q, rho, 0..nq + ng, j);
    // Multipliers from stationarity: Gqᵀλ = Sᵀτ − Xqᵀw (least squares),
    // where the prediction has none.
    let estimated;
    let lambda: &[f64] = if prediction.multipliers.len() == m {
        &prediction.multipliers
    } else {
        let gq = j.dg.columns(0, nq).into_owned();
        let xq = j.dx.columns(0, nq).into_owned();
        let mut rhs = -(xq.transpose() * DVector::from_column_slice(w));
        for (a, &jt) in spec.actuated.iter().enumerate() {
            rhs[jt] += prediction.torque[a];
        }
        estimated = crate::linalg::lu::Lu::new(&gq * gq.transpose())
            .solve(&(&gq * rhs))
            .ok_or_else(|| Error::Singular {
                q: q.clone(),
                reason: "the constraint Jacobian is rank deficient".into(),
            })?;
        estimated.as_slice()
    };
    let lag = mech.weighted_hessian(q, rho, lambda, w);
    zeroed(fz, nq + m, nq + m);
    fz.view_mut((0, 0), (nq, nq)).copy_from(&lag.columns(0, nq));
    for (a, &jt) in spec.actuated.iter().enumerate() {
        fz[(jt, jt)] += k[a];
    }
    for c in 0..nq {
        for r in 0..m {
            fz[(c, nq + r)] = j.dg[(r, c)];
            fz[(nq + r, c)] = j.dg[(r, c)];
        }
    }
    // By the adjoint: `∂x/∂p = X_q dq/dp = −[X_q 0] F_z⁻¹ F_p = −Yᵀ F_p`
    // with `F_zᵀ Y = [X_q 0]ᵀ`: one solve per tool coordinate instead of one
    // per parameter.
    if fzt.shape() != (nq + m, nq + m) {
        *fzt = DMatrix::zeros(nq + m, nq + m);
    }
    fz.transpose_to(fzt);
    zeroed(y, nq + m, nx);
    for c in 0..nq {
        for r in 0..nx {
            y[(c, r)] = j.dx[(r, c)];
        }
    }
    if !solve_scaled_in_place(fzt, y) {
        return Err(Error::Singular {
            q: q.clone(),
            reason: "the equilibrium (KKT) system is singular".into(),
        });
    }
    // F_p's blocks: ρ columns `[∂²L/∂q∂ρ; ∂g/∂ρ]`; the offset and stiffness
    // columns are nonzero only on the actuated joints' rows
    // (`−k_a` and `−(c_a + Δq_a − q_a)`).
    let mut jac = DMatrix::zeros(nx, np);
    let mut left = jac.columns_mut(0, ng);
    left.gemm_tr(-1.0, &y.rows(0, nq), &lag.columns(nq, ng), 0.0);
    left.gemm_tr(-1.0, &y.rows(nq, m), &j.dg.columns(nq, ng), 1.0);
    left += j.dx.columns(nq, ng);
    for (a, &jt) in spec.actuated.iter().enumerate() {
        let stretch = commands[a] + params.offsets()[a] - q[jt];
        for r in 0..nx {
            jac[(r, ng + a)] = k[a] * y[(jt, r)];
            jac[(r, ng + na + a)] = stretch * y[(jt, r)];
        }
    }
    debug_assert_eq!(jac.nrows(), nx);
    Ok(jac)
}
