//! The paper's linearised relations (docs/model.md §3, eq. 2 and 4–11).
//!
//! At a configuration `q` (on `g(q, ρ) = 0`) with independent joints `q_u` and
//! dependent joints `q_v`:
//!
//! * eq. 5: `dq_v = Φ dq_u + J_p Δρ`, `Φ = −(∂g/∂q_v)⁻¹ ∂g/∂q_u`, `J_p = −(∂g/∂q_v)⁻¹ ∂g/∂ρ`;
//! * eq. 7: `dq_r = Γ dq_u + H Δρ`;
//! * eq. 9: `J_f = dx/dq_u` (through the dependent joints);
//! * eq. 10: `Γᵀ τ_r = P`, `P = J_fᵀ (Q + N)`;
//! * eq. 11: `dq_r = Λ Δq_r + (I − Λ) H Δρ − Γ (Γᵀ K Γ)⁻¹ P`, `Λ = Γ (ΓᵀKΓ)⁻¹ ΓᵀK`.
//!
//! Load convention: [`load_vector`] takes the external force applied *to* the
//! tool (N, e.g. a payload's weight `m·g`); the paper's `Q + N` (the force the
//! actuators must deliver at the tool) is its negative.

use crate::error::{Error, Result};
use crate::linalg::solve::checked_lu;
use crate::mechanism::Mechanism;
use crate::mechanism::autodiff::jacobians;
use nalgebra::{DMatrix, DVector};

/// The paper's matrices at one configuration.
#[derive(Debug, Clone)]
pub struct Linearization {
    /// Independent joints used (indices into the joint vector).
    pub independent: Vec<usize>,
    /// Φ (eq. 5): dependent joints per independent joint.
    pub phi: DMatrix<f64>,
    /// J_p (eq. 5): dependent joints per geometric parameter.
    pub jp: DMatrix<f64>,
    /// Full joint sensitivity to `q_u` (`U [I; Φ]`, nq × n).
    pub dq_du: DMatrix<f64>,
    /// Full joint sensitivity to ρ (`U [0; J_p]`, nq × nρ).
    pub dq_drho: DMatrix<f64>,
    /// Γ (eq. 7): actuated joints per independent joint (l × n).
    pub gamma: DMatrix<f64>,
    /// H (eq. 7): actuated joints per geometric parameter (l × nρ).
    pub h: DMatrix<f64>,
    /// J_f (eq. 9): tool per independent joint (nx × n), mm/rad.
    pub jf: DMatrix<f64>,
    /// Tool per geometric parameter at fixed `q_u` (nx × nρ).
    pub jx_rho: DMatrix<f64>,
    /// [`crate::Spec::work_scale`] of the mechanism (force × mm → energy unit).
    pub work_scale: f64,
}

/// Φ, J_p, Γ, H and J_f at configuration `q` (eq. 4–7, 9), with the given
/// independent joints.
pub fn linearize<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    independent: &[usize],
) -> Result<Linearization> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let nr = rho.len();
    let dependent = dependent_joints(spec, independent)?;
    let j = jacobians(mech, q, rho, 0..nq + nr);
    let gq = j.dg.columns(0, nq);
    let gu = gq.select_columns(independent);
    let gv = gq.select_columns(&dependent);
    let grho = j.dg.columns(nq, nr).into_owned();
    let mut rhs = DMatrix::zeros(spec.n_constraints, independent.len() + nr);
    rhs.columns_mut(0, independent.len()).copy_from(&(-gu));
    rhs.columns_mut(independent.len(), nr).copy_from(&(-grho));
    let sol = solve_square_multi(gv, rhs).ok_or_else(|| Error::Singular {
        q: q.to_vec(),
        reason: "∂g/∂q_v is singular (the dependent joints are not determined)".into(),
    })?;
    let phi = sol.columns(0, independent.len()).into_owned();
    let jp = sol.columns(independent.len(), nr).into_owned();
    let dq_du = joint_sensitivity(nq, independent, &dependent, &phi);
    let mut dq_drho = DMatrix::zeros(nq, nr);
    for (k, &i) in dependent.iter().enumerate() {
        dq_drho.row_mut(i).copy_from(&jp.row(k));
    }
    let gamma = dq_du.select_rows(&spec.actuated);
    let h = dq_drho.select_rows(&spec.actuated);
    let xq = j.dx.columns(0, nq);
    let jf = xq * &dq_du;
    let jx_rho = j.dx.columns(nq, nr) + xq * &dq_drho;
    Ok(Linearization {
        independent: independent.to_vec(),
        phi,
        jp,
        dq_du,
        dq_drho,
        gamma,
        h,
        jf,
        jx_rho,
        work_scale: spec.work_scale,
    })
}

/// `J_f` (eq. 9) alone, the same numbers as [`linearize`]'s `jf` (the same
/// factorisation, and each right-hand side solved on its own), without the
/// columns of the parameters: what a lattice point's conditioning needs. Its
/// cost does not grow with the number of parameters (a 100-leg delta has
/// 1,200).
pub fn joint_tool_jacobian<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    independent: &[usize],
) -> Result<DMatrix<f64>> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let dependent = dependent_joints(spec, independent)?;
    let j = jacobians(mech, q, rho, 0..nq);
    let gq = j.dg.columns(0, nq);
    let rhs = -gq.select_columns(independent);
    let phi =
        solve_square_multi(gq.select_columns(&dependent), rhs).ok_or_else(|| Error::Singular {
            q: q.to_vec(),
            reason: "∂g/∂q_v is singular (the dependent joints are not determined)".into(),
        })?;
    let dq_du = joint_sensitivity(nq, independent, &dependent, &phi);
    Ok(j.dx.columns(0, nq) * &dq_du)
}

/// `U [I; Φ]` (eq. 5): every joint's sensitivity to the independent joints,
/// from `Φ` (one row per dependent joint).
fn joint_sensitivity(
    nq: usize,
    independent: &[usize],
    dependent: &[usize],
    phi: &DMatrix<f64>,
) -> DMatrix<f64> {
    let mut dq_du = DMatrix::zeros(nq, independent.len());
    for (k, &i) in independent.iter().enumerate() {
        dq_du[(i, k)] = 1.0;
    }
    for (k, &i) in dependent.iter().enumerate() {
        dq_du.row_mut(i).copy_from(&phi.row(k));
    }
    dq_du
}

/// `J_f` (eq. 9) and the tool's derivatives in ρ at fixed `q_u` (the
/// `jf` and `jx_rho` of [`linearize`]) without the joints' sensitivities:
/// with `Y = ∂x/∂q_v (∂g/∂q_v)⁻¹` (one solve with as many right-hand sides as
/// tool coordinates), `J_f = ∂x/∂q_u − Y ∂g/∂q_u` and
/// `∂x/∂ρ = ∂x/∂ρ|_q − Y ∂g/∂ρ` (eq. 5 substituted into the tool map).
pub fn tool_derivatives<M: Mechanism>(
    mech: &M,
    q: &[f64],
    rho: &[f64],
    independent: &[usize],
) -> Result<(DMatrix<f64>, DMatrix<f64>)> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let nr = rho.len();
    let dependent = dependent_joints(spec, independent)?;
    let j = jacobians(mech, q, rho, 0..nq + nr);
    let gq = j.dg.columns(0, nq);
    let xq = j.dx.columns(0, nq);
    // Yᵀ = (∂g/∂q_v)⁻ᵀ (∂x/∂q_v)ᵀ.
    let yt = checked_lu(gq.select_columns(&dependent).transpose())
        .and_then(|lu| lu.solve_matrix(&xq.select_columns(&dependent).transpose()))
        .ok_or_else(|| Error::Singular {
            q: q.to_vec(),
            reason: "∂g/∂q_v is singular (the dependent joints are not determined)".into(),
        })?;
    let jf = xq.select_columns(independent) - yt.tr_mul(&gq.select_columns(independent));
    let jx_rho = j.dx.columns(nq, nr) - yt.tr_mul(&j.dg.columns(nq, nr));
    Ok((jf, jx_rho))
}

/// The joints not in `independent`, as many as constraints.
fn dependent_joints(spec: &crate::Spec, independent: &[usize]) -> Result<Vec<usize>> {
    let dependent: Vec<usize> = (0..spec.joints.len())
        .filter(|i| !independent.contains(i))
        .collect();
    if dependent.len() != spec.n_constraints {
        return Err(Error::InvalidRequest(format!(
            "{} independent joints given, the mechanism has {} degrees of freedom",
            independent.len(),
            spec.dof()
        )));
    }
    Ok(dependent)
}

fn solve_square_multi(a: DMatrix<f64>, b: DMatrix<f64>) -> Option<DMatrix<f64>> {
    checked_lu(a)?.solve_matrix(&b)
}

/// `(ΓᵀKΓ)⁻¹` (eq. 11), the one place it is computed: by LU with the
/// relative pivot test of every square solve
/// ([`crate::linalg::solve::SINGULAR_RCOND`]). Singular when the actuators
/// do not control every degree of freedom at the configuration `q` (named in
/// the error; empty when unknown): an error, never zeros.
pub fn stiffness_inverse(gamma: &DMatrix<f64>, k: &[f64], q: &[f64]) -> Result<DMatrix<f64>> {
    let kd = DMatrix::from_diagonal(&DVector::from_column_slice(k));
    let gkg = gamma.transpose() * &kd * gamma;
    let n = gkg.nrows();
    checked_lu(gkg)
        .and_then(|lu| lu.solve_matrix(&DMatrix::identity(n, n)))
        .ok_or_else(|| Error::Singular {
            q: q.to_vec(),
            reason: "ΓᵀKΓ is singular (the actuators do not control every degree of freedom)"
                .into(),
        })
}

/// Λ = Γ (ΓᵀKΓ)⁻¹ ΓᵀK (eq. 11): the K-weighted projection onto feasible
/// actuated-joint motions. `Λ² = Λ`, `ΛΓ = Γ`; `Λ = I` without redundancy.
pub fn projection(gamma: &DMatrix<f64>, k: &[f64]) -> Result<DMatrix<f64>> {
    Ok(projection_with(
        gamma,
        k,
        &stiffness_inverse(gamma, k, &[])?,
    ))
}

/// [`projection`] from `(ΓᵀKΓ)⁻¹` already computed ([`stiffness_inverse`]).
pub fn projection_with(gamma: &DMatrix<f64>, k: &[f64], inverse: &DMatrix<f64>) -> DMatrix<f64> {
    let kd = DMatrix::from_diagonal(&DVector::from_column_slice(k));
    gamma * inverse * gamma.transpose() * kd
}

/// The generalised load `P` of eq. 10 (N·m, or N for prismatic actuation; see
/// [`crate::Spec::work_scale`]) for generalised forces `force` on the tool
/// coordinates (N on lengths, N·mm per rad on angles: [`crate::engine::load`] maps a
/// wrench to them): `P = J_fᵀ (Q + N)` with `Q + N = −force`.
/// An empty `force` means no load; otherwise it has one value per tool axis.
pub fn load_vector(lin: &Linearization, force: &[f64]) -> DVector<f64> {
    if force.is_empty() {
        return DVector::zeros(lin.jf.ncols());
    }
    assert_eq!(
        force.len(),
        lin.jf.nrows(),
        "one force component per tool axis"
    );
    let f = DVector::from_column_slice(force);
    -(lin.jf.transpose() * f) * lin.work_scale
}

/// Actual actuated joint errors `dq_r` by eq. 11 (rad):
/// `dq_r = Λ Δq_r + (I − Λ) H Δρ − Γ (ΓᵀKΓ)⁻¹ P`.
pub fn joint_errors(
    lin: &Linearization,
    k: &[f64],
    offsets: &[f64],
    drho: &[f64],
    p: &DVector<f64>,
) -> Result<DVector<f64>> {
    let l = lin.gamma.nrows();
    let inverse = stiffness_inverse(&lin.gamma, k, &[])?;
    let lambda = projection_with(&lin.gamma, k, &inverse);
    let load = &lin.gamma * (&inverse * p);
    let dq = &lambda * DVector::from_column_slice(offsets)
        + (DMatrix::identity(l, l) - &lambda) * (&lin.h * DVector::from_column_slice(drho))
        - load;
    Ok(dq)
}

/// Internal torques by eq. 2: `τ_r = K (Δq_r − dq_r)` (N·m).
pub fn torques(k: &[f64], offsets: &[f64], dq: &[f64]) -> Vec<f64> {
    k.iter()
        .zip(offsets)
        .zip(dq)
        .map(|((k, o), d)| k * (o - d))
        .collect()
}
