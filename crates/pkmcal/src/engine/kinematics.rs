//! Loop-closure kinematics: forward (actuated/independent joints → pose, by
//! Newton on `g(q, ρ) = 0`, docs/model.md eq. 3) and inverse (tool position → all
//! joints, closed form where the mechanism has one, Newton otherwise).

use crate::error::{Error, Result};
use crate::linalg::solve::{checked_lu, solve_square_in_place};
use crate::mechanism::Mechanism;
use crate::mechanism::autodiff::jacobians;
use nalgebra::DMatrix;

pub use crate::engine::newton::STEP_TOL;
use crate::engine::newton::{self, End};
/// Largest revolute joint step (rad) of one continuation stage.
const CONTINUATION_STEP: f64 = 0.1;
/// Largest prismatic joint step (mm) of one continuation stage.
const CONTINUATION_STEP_MM: f64 = 10.0;
/// Tool travel (mm, or rad) of one inverse-kinematics continuation stage.
const IK_STAGE: f64 = 10.0;
/// The stage tried first: most paths need no shorter one.
const IK_STAGE_LONG: f64 = 50.0;
/// Newton's step (rad or mm) below which an intermediate inverse-kinematics
/// stage counts as reached: the next stage starts within its quadratic
/// convergence, and the last one converges to [`STEP_TOL`].
const INTERMEDIATE_TOL: f64 = 1e-3;
/// Most inverse-kinematics continuation stages (10 m of travel).
pub const MAX_IK_STAGES: usize = 1000;
/// Most continuation stages of one forward-kinematics solve: the work is
/// bounded whatever the distance asked for.
pub const MAX_CONTINUATION_STAGES: usize = 20_000;
/// How many mm of a length joint weigh like one rad of a revolute joint when
/// steps are limited (the ratio of the continuation stages).
const MM_PER_RAD: f64 = CONTINUATION_STEP_MM / CONTINUATION_STEP;
/// Solve `g(q, ρ) = 0` for the joints not in `fixed`, starting from `q`
/// (modified in place). `fixed` must hold as many joints as degrees of freedom.
pub fn solve_closure<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    q: &mut [f64],
    fixed: &[usize],
) -> Result<usize> {
    solve_closure_keeping(mech, rho, q, fixed).map(|(n, _)| n)
}

/// [`solve_closure`], also returning the derivatives (joint columns) of its
/// last iteration, within Newton's tolerance of the solution (`None` when it
/// stopped on the residual instead).
fn solve_closure_keeping<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    q: &mut [f64],
    fixed: &[usize],
) -> Result<(usize, Option<crate::mechanism::autodiff::Jacobians>)> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let free: Vec<usize> = (0..nq).filter(|i| !fixed.contains(i)).collect();
    if free.len() != spec.n_constraints {
        return Err(Error::InvalidRequest(format!(
            "{} fixed joints leave {} unknowns for {} constraints",
            fixed.len(),
            free.len(),
            spec.n_constraints
        )));
    }
    let policy = &newton::CLOSURE;
    let mut j = crate::mechanism::autodiff::Jacobians::empty();
    // The square system's matrix and right-hand side, sized once per solve.
    let n = free.len();
    let mut gv = DMatrix::zeros(n, n);
    // The joints and the step (the right-hand side, solved in place).
    let mut state = (q, vec![0.0; n]);
    let end = newton::run(
        policy,
        &mut state,
        |(q, step), _| -> Result<Option<newton::Step>> {
            crate::mechanism::autodiff::jacobians_into(mech, q, rho, 0..nq, &mut j);
            for (c, &f) in free.iter().enumerate() {
                gv.column_mut(c).copy_from(&j.dg.column(f));
            }
            step.copy_from_slice(&j.g);
            if !solve_square_in_place(&mut gv, step) {
                return Err(Error::Singular {
                    q: q.to_vec(),
                    reason: "the loop-closure Jacobian of the dependent joints is singular".into(),
                });
            }
            // nalgebra's `amax`: NaN entries after the first skipped.
            let big = step
                .iter()
                .skip(1)
                .fold(step.first().map_or(0.0, |v| v.abs()), |a, b| a.max(b.abs()));
            Ok(Some(newton::Step {
                size: if big.is_finite() { big } else { f64::INFINITY },
                turn: step_turn(spec, free.iter().copied(), step),
            }))
        },
        |(q, step), scale| {
            for (k, &i) in free.iter().enumerate() {
                q[i] -= scale * step[k];
            }
        },
    )?;
    let q = state.0;
    if let End::Converged(iterations) = end {
        return Ok((iterations, Some(j)));
    }
    let g = jacobians(mech, q, rho, 0..0).g;
    let scale = newton::parameter_scale(rho);
    if g.iter()
        .all(|v| v.abs() < policy.residual_limit(scale) * scale)
    {
        return Ok((policy.max_iterations, None));
    }
    Err(Error::NoConvergence {
        what: "loop closure".into(),
        reason: format!(
            "the legs cannot be assembled at joints {q:?} (residual {g:?}); the actuator values are probably outside the workspace"
        ),
    })
}

/// The largest joint step of `step` (on `joints`, in order) in rad, a
/// length step counted at [`MM_PER_RAD`]; infinite when a step is not finite.
pub(crate) fn step_turn(
    spec: &crate::Spec,
    joints: impl Iterator<Item = usize>,
    step: &[f64],
) -> f64 {
    turn_of(spec, joints.zip(step.iter().copied()))
}

/// [`step_turn`] of `(joint, step)` pairs, computed as they come (no
/// buffer).
pub(crate) fn turn_of(spec: &crate::Spec, steps: impl Iterator<Item = (usize, f64)>) -> f64 {
    let turn = steps
        .map(|(i, d)| match spec.joint_units[i] {
            crate::Unit::Radian => d.abs(),
            _ => d.abs() / MM_PER_RAD,
        })
        .fold(0.0, f64::max);
    if turn.is_finite() {
        turn
    } else {
        f64::INFINITY
    }
}

/// Signs of the determinants that identify an assembly branch: of the
/// constraint Jacobian with respect to the dependent joints (forward
/// kinematics), and of `[∂g/∂q; ∂x/∂q]` (inverse kinematics) when the tool has
/// as many coordinates as degrees of freedom. Along a continuous path a sign
/// changes only through a singularity, so a configuration whose signs differ
/// from the reference configuration's is on another branch.
pub fn branch_signs<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64]) -> [i8; 2] {
    branch_signs_of(mech.spec(), &jacobians(mech, q, rho, 0..q.len()))
}

/// The sign of a determinant (0 for zero or NaN).
fn sign(d: f64) -> i8 {
    if d > 0.0 {
        1
    } else if d < 0.0 {
        -1
    } else {
        0
    }
}

/// The forward-kinematics sign of [`branch_signs_of`] alone (its first),
/// for mechanisms whose branch that one sign fixes.
pub fn forward_branch_sign_of(spec: &crate::Spec, j: &crate::mechanism::autodiff::Jacobians) -> i8 {
    let nq = spec.joints.len();
    let dependent: Vec<usize> = (0..nq).filter(|i| !spec.independent.contains(i)).collect();
    sign(crate::linalg::lu::determinant(
        j.dg.select_columns(&dependent),
    ))
}

/// [`branch_signs`] from the derivatives (joint columns) at the configuration.
pub fn branch_signs_of(spec: &crate::Spec, j: &crate::mechanism::autodiff::Jacobians) -> [i8; 2] {
    let nq = spec.joints.len();
    let fk = forward_branch_sign_of(spec, j);
    let ik = if spec.n_constraints + spec.tool_axes.len() == nq {
        let mut a = DMatrix::zeros(nq, nq);
        a.view_mut((0, 0), (spec.n_constraints, nq))
            .copy_from(&j.dg);
        a.view_mut((spec.n_constraints, 0), (spec.tool_axes.len(), nq))
            .copy_from(&j.dx);
        sign(crate::linalg::lu::determinant(a))
    } else {
        0
    };
    [fk, ik]
}

/// Forward kinematics: the full joint vector with the independent joints
/// (`spec().independent`) at `q_u`, by Newton from `start` with continuation
/// (the independent joints move from their start values to `q_u` in stages, so
/// the solution stays on the assembly branch of `start`).
pub fn forward_kinematics<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    q_u: &[f64],
    start: &[f64],
) -> Result<Vec<f64>> {
    let spec = mech.spec();
    let ind = &spec.independent;
    if q_u.len() != ind.len() {
        return Err(Error::Dimension {
            what: "independent joint values".into(),
            expected: ind.len(),
            got: q_u.len(),
        });
    }
    if q_u.iter().any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(format!(
            "joint values must be finite, got {q_u:?}"
        )));
    }
    let mut q = start.to_vec();
    let from: Vec<f64> = ind.iter().map(|&i| start[i]).collect();
    let span = from
        .iter()
        .zip(q_u)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    let stages = continuation_stages(spec, start, q_u);
    if stages.is_nan() || stages > MAX_CONTINUATION_STAGES as f64 {
        return Err(Error::InvalidRequest(format!(
            "the joint values {q_u:?} are {span:.4e} away from the start configuration; no machine moves that far between two poses (check the units: rad and mm)"
        )));
    }
    let stages = (stages as usize).max(1);
    let mut last = None;
    for s in 1..=stages {
        let t = s as f64 / stages as f64;
        for (k, &i) in ind.iter().enumerate() {
            q[i] = from[k] + t * (q_u[k] - from[k]);
        }
        last = solve_closure_keeping(mech, rho, &mut q, ind)?.1;
    }
    let on_branch = match &last {
        Some(j) => mech.on_branch_near(&q, rho, j),
        None => mech.on_branch(&q, rho),
    };
    if !on_branch {
        let reason = match mech.leg_in_other_mode(&q, rho) {
            Some(leg) => format!(
                "leg `{leg}` is in the other working mode there (its joints fold the other way than at the reference configuration)"
            ),
            None => "the path from the start configuration crossed a singularity".into(),
        };
        return Err(Error::OtherBranch { q, reason });
    }
    Ok(q)
}

/// How many continuation stages [`forward_kinematics`] takes from `start`
/// to the independent joint values `q_u`: stages of at most 0.1 rad on a
/// revolute joint, 10 mm on a prismatic one (NaN for non-finite values).
pub(crate) fn continuation_stages(spec: &crate::Spec, start: &[f64], q_u: &[f64]) -> f64 {
    spec.independent
        .iter()
        .zip(q_u)
        .map(|(&i, b)| {
            let step = match spec.joint_units[i] {
                crate::Unit::Radian => CONTINUATION_STEP,
                _ => CONTINUATION_STEP_MM,
            };
            ((start[i] - b) / step).abs()
        })
        .fold(0.0, f64::max)
        .ceil()
}

/// Most stages of [`forward_kinematics_from_nominal`]'s walk in the
/// parameters.
pub const PARAMETER_STAGES: usize = 64;

/// [`forward_kinematics`] under parameters `rho` from `start`, a
/// configuration that closes under the nominal parameters: directly, and if
/// that fails by continuation in the parameters, walking them from nominal
/// to `rho` in stages (halved when a stage fails, at most
/// [`PARAMETER_STAGES`]), each solved from the last. Parameters far from
/// nominal (an identification wandering along a poorly determined
/// direction) can move the assembled configuration further than one Newton
/// continuation in the joints reaches.
pub fn forward_kinematics_from_nominal<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    q_u: &[f64],
    start: &[f64],
) -> Result<Vec<f64>> {
    let first = match forward_kinematics(mech, rho, q_u, start) {
        Ok(q) => return Ok(q),
        Err(e) => e,
    };
    let spec = mech.spec();
    let nominal = &spec.nominal[..spec.n_geometric()];
    let from: Vec<f64> = spec.independent.iter().map(|&i| start[i]).collect();
    let mut q = start.to_vec();
    let (mut t, mut step) = (0.0_f64, 0.25_f64);
    let mut stages = 0;
    while t < 1.0 {
        let next = (t + step).min(1.0);
        let r: Vec<f64> = nominal
            .iter()
            .zip(rho)
            .map(|(a, b)| a + next * (b - a))
            .collect();
        let u: Vec<f64> = from
            .iter()
            .zip(q_u)
            .map(|(a, b)| a + next * (b - a))
            .collect();
        stages += 1;
        if stages > PARAMETER_STAGES {
            return Err(first);
        }
        match forward_kinematics(mech, &r, &u, &q) {
            Ok(s) => {
                q = s;
                t = next;
            }
            Err(_) => step /= 2.0,
        }
    }
    Ok(q)
}

/// Check parameter values for a mechanism before using them: finite and
/// within range ([`crate::Params::validate`]), the mechanism's own rules
/// ([`Mechanism::check_params`], e.g. positive lengths), and the mechanism
/// still assembles at its reference configuration.
pub fn check_params<M: Mechanism>(mech: &M, params: &crate::Params) -> Result<()> {
    params.validate(mech.spec())?;
    mech.check_params(params.geometric())?;
    reference_configuration(mech, params.geometric())?;
    Ok(())
}

/// The reference configuration (`spec().reference_q`) made to close exactly
/// for parameters ρ (its independent joints kept).
pub fn reference_configuration<M: Mechanism>(mech: &M, rho: &[f64]) -> Result<Vec<f64>> {
    let spec = mech.spec();
    let mut q = spec.reference_q.clone();
    solve_closure(mech, rho, &mut q, &spec.independent).map_err(|e| {
        Error::InvalidMechanism(format!(
            "the reference configuration does not close with these parameters ({e}); check the lengths and the reference joint values"
        ))
    })?;
    Ok(q)
}

/// Inverse kinematics: all joints for a tool position, on the assembly branch
/// of the reference configuration. Closed form where the mechanism provides it,
/// otherwise Newton on `[g; x − target] = 0` with continuation from the
/// reference configuration.
pub fn inverse_kinematics<M: Mechanism>(mech: &M, rho: &[f64], target: &[f64]) -> Result<Vec<f64>> {
    inverse_kinematics_from(mech, rho, target, || reference_configuration(mech, rho))
}

/// [`inverse_kinematics`] with the reference configuration from `reference`
/// (asked only when there is no closed form): many targets under the same
/// parameters share one.
pub(crate) fn inverse_kinematics_from<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    target: &[f64],
    reference: impl FnOnce() -> Result<Vec<f64>>,
) -> Result<Vec<f64>> {
    let spec = mech.spec();
    if target.len() != spec.tool_axes.len() {
        return Err(Error::Dimension {
            what: "target".into(),
            expected: spec.tool_axes.len(),
            got: target.len(),
        });
    }
    for (t, u) in target.iter().zip(&spec.tool_units) {
        if !(t.is_finite() && t.abs() <= u.max_magnitude()) {
            return Err(Error::Unreachable {
                target: target.to_vec(),
                reason: format!(
                    "every coordinate must be finite and within ±{:e} {u}",
                    u.max_magnitude()
                ),
            });
        }
    }
    if let Some(r) = mech.inverse_kinematics_closed(target, rho) {
        return r;
    }
    let nq = spec.joints.len();
    if spec.n_constraints + target.len() != nq {
        return Err(Error::InvalidRequest(
            "inverse kinematics by Newton needs as many tool coordinates as degrees of freedom"
                .into(),
        ));
    }
    // Long stages first (few Newton iterations); if that path leaves the
    // branch or Newton fails on it, the short stages, which follow the
    // branch more closely.
    let start = reference()?;
    ik_continuation(mech, rho, target, &start, IK_STAGE_LONG)
        .or_else(|_| ik_continuation(mech, rho, target, &start, IK_STAGE))
}

/// Inverse kinematics from `neighbour`, a configuration whose tool is near
/// `target` (one lattice step): the closed form where the mechanism has
/// one, else one continuation stage from there, on the reference's branch
/// ([`Mechanism::on_branch`]) or an error (the caller then takes the path
/// from the reference configuration).
pub(crate) fn inverse_kinematics_near<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    target: &[f64],
    neighbour: &[f64],
) -> Result<Vec<f64>> {
    if let Some(r) = mech.inverse_kinematics_closed(target, rho) {
        return r;
    }
    ik_continuation(mech, rho, target, neighbour, IK_STAGE_LONG)
}

/// Newton inverse kinematics from the reference configuration, the target
/// approached from the reference configuration `start` in straight-line
/// stages of at most `stage` (mm or rad).
fn ik_continuation<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    target: &[f64],
    start: &[f64],
    stage: f64,
) -> Result<Vec<f64>> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let q = start.to_vec();
    let x0 = jacobians(mech, &q, rho, 0..0).x;
    let span = x0
        .iter()
        .zip(target)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    let stages = (span / stage).ceil();
    if stages.is_nan() || stages > MAX_IK_STAGES as f64 {
        return Err(Error::Unreachable {
            target: target.to_vec(),
            reason: format!(
                "it is {span:.4e} from the reference tool position, beyond the reach of any linkage"
            ),
        });
    }
    let stages = (stages as usize).max(1);
    let mut j = crate::mechanism::autodiff::Jacobians::empty();
    // Newton's system `[∂g/∂q; ∂x/∂q] step = [g; x − goal]`, in buffers
    // kept from one iteration to the next (every entry is rewritten).
    let mut a = DMatrix::zeros(nq, nq);
    let mut state = (q, vec![0.0; nq]);
    let mut goal = vec![0.0; x0.len()];
    for s in 1..=stages {
        let t = s as f64 / stages as f64;
        for (g, (a, b)) in goal.iter_mut().zip(x0.iter().zip(target)) {
            *g = a + t * (b - a);
        }
        // The intermediate stages only keep the path on its branch: they
        // stop well before Newton's full precision.
        let policy = if s < stages {
            newton::Policy {
                step_tol: INTERMEDIATE_TOL,
                ..newton::INVERSE_KINEMATICS
            }
        } else {
            newton::INVERSE_KINEMATICS
        };
        let end = newton::run(
            &policy,
            &mut state,
            |(q, step), _| -> Result<Option<newton::Step>> {
                crate::mechanism::autodiff::jacobians_into(mech, q, rho, 0..nq, &mut j);
                a.view_mut((0, 0), (spec.n_constraints, nq))
                    .copy_from(&j.dg);
                a.view_mut((spec.n_constraints, 0), (target.len(), nq))
                    .copy_from(&j.dx);
                step[..spec.n_constraints].copy_from_slice(&j.g);
                for (b, (x, t)) in step[spec.n_constraints..]
                    .iter_mut()
                    .zip(j.x.iter().zip(&goal))
                {
                    *b = x - t;
                }
                if !solve_square_in_place(&mut a, step) {
                    return Err(Error::Unreachable {
                        target: target.to_vec(),
                        reason: "the path from the reference configuration meets a singularity"
                            .into(),
                    });
                }
                Ok(Some(newton::Step {
                    size: nalgebra::DVectorView::from_slice(step, nq).amax(),
                    turn: step_turn(spec, 0..nq, step),
                }))
            },
            |(q, step), scale| {
                for i in 0..nq {
                    q[i] -= scale * step[i];
                }
            },
        )?;
        if !matches!(end, End::Converged(_)) {
            return Err(Error::Unreachable {
                target: target.to_vec(),
                reason: "Newton did not converge".into(),
            });
        }
    }
    let q = state.0;
    if !mech.on_branch(&q, rho) {
        return Err(Error::Unreachable {
            target: target.to_vec(),
            reason: "the path from the reference configuration crosses a singularity (the solution is on another assembly branch)".into(),
        });
    }
    Ok(q)
}

/// The independent joints a description names (`given`, joint names), or
/// [`choose_independent`]'s when it names none.
pub fn independent_joints<M: Mechanism>(
    mech: &M,
    given: Option<&[String]>,
    q: &[f64],
    rho: &[f64],
) -> Result<Vec<usize>> {
    let Some(list) = given else {
        return Ok(choose_independent(mech, q, rho));
    };
    let joints = &mech.spec().joints;
    list.iter()
        .map(|n| {
            joints.iter().position(|j| j == n).ok_or_else(|| {
                Error::InvalidMechanism(format!("`independent`: unknown joint `{n}`"))
            })
        })
        .collect()
}

/// The independent joints: the first combination of `dof` actuated joints (in
/// actuator order) whose complement is not singular at `q` (the rigid and
/// linear models drive them); the first `dof` actuated joints if every
/// combination is singular there.
pub fn choose_independent<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64]) -> Vec<usize> {
    let spec = mech.spec();
    let dof = spec.joints.len() - spec.n_constraints;
    let l = spec.actuated.len();
    let j = jacobians(mech, q, rho, 0..q.len());
    let mut pick: Vec<usize> = (0..dof).collect();
    loop {
        let ind: Vec<usize> = pick.iter().map(|&a| spec.actuated[a]).collect();
        let dep: Vec<usize> = (0..q.len()).filter(|i| !ind.contains(i)).collect();
        if checked_lu(j.dg.select_columns(&dep)).is_some() {
            return ind;
        }
        // Next combination in lexicographic order.
        let mut k = dof;
        loop {
            if k == 0 {
                return spec.actuated[..dof].to_vec();
            }
            k -= 1;
            if pick[k] < l - dof + k {
                pick[k] += 1;
                for m in k + 1..dof {
                    pick[m] = pick[m - 1] + 1;
                }
                break;
            }
        }
    }
}

/// Most Gauss–Newton steps of [`commands_configuration`].
pub const POSE_FIT_STEPS: usize = 16;
/// Most halvings of one [`commands_configuration`] step whose pose is out of
/// reach.
const POSE_FIT_HALVINGS: usize = 8;
/// [`commands_configuration`] stops when its pose step falls below this (mm,
/// or rad on an angle axis, scaled by [`crate::Spec::axis_scale`]).
pub const POSE_FIT_TOL: f64 = 1e-9;

/// The configuration of the commands' nominal pose: the tool position whose
/// inverse kinematics under `rho` (on the assembly branch by construction)
/// best matches every command (least squares over the actuators, each in
/// [`crate::Spec::joint_scale`] units; redundant commands need not agree),
/// by Gauss–Newton on the pose from the tool position of `near`, a known
/// configuration. Forward kinematics started there is within a continuation
/// stage of its answer whenever the commands are (the commands' own
/// inconsistency away), so it does not depend on a path that may cross a
/// singularity. `None` when the mechanism has fewer tool coordinates than
/// degrees of freedom, or inverse kinematics fails along the way.
pub fn commands_configuration<M: Mechanism>(
    mech: &M,
    rho: &[f64],
    commands: &[f64],
    near: &[f64],
) -> Option<Vec<f64>> {
    let spec = mech.spec();
    let (nq, nc, nx) = (spec.joints.len(), spec.n_constraints, spec.tool_axes.len());
    if nc + nx != nq || commands.len() != spec.n_actuated() {
        return None;
    }
    let ik = |x: &[f64], from: &[f64]| {
        inverse_kinematics_near(mech, rho, x, from)
            .or_else(|_| inverse_kinematics(mech, rho, x))
            .ok()
    };
    let mut x = jacobians(mech, near, rho, 0..0).x;
    let mut q = ik(&x, near)?;
    let mut a = DMatrix::zeros(nq, nq);
    // Not `newton::run`: each step is halved while its pose is out of reach.
    for _ in 0..POSE_FIT_STEPS {
        // ∂q/∂x on the branch: [∂g/∂q; ∂x/∂q] ∂q/∂x = [0; I].
        let j = jacobians(mech, &q, rho, 0..nq);
        a.view_mut((0, 0), (nc, nq)).copy_from(&j.dg);
        a.view_mut((nc, 0), (nx, nq)).copy_from(&j.dx);
        let mut rhs = DMatrix::zeros(nq, nx);
        rhs.view_mut((nc, 0), (nx, nx)).fill_with_identity();
        let dqdx = crate::linalg::solve::solve_scaled(a.clone(), rhs)?;
        // The actuators' rows and misfits, scaled to mm-equivalents.
        let na = spec.n_actuated();
        let mut s = DMatrix::zeros(na, nx);
        let mut r = nalgebra::DVector::zeros(na);
        for (k, (&jt, c)) in spec.actuated.iter().zip(commands).enumerate() {
            let w = spec.joint_scale(jt);
            s.row_mut(k).copy_from(&(dqdx.row(jt) * w));
            r[k] = (q[jt] - c) * w;
        }
        let svd = s.svd(true, true);
        let eps = svd.singular_values.max() * crate::linalg::solve::SINGULAR_RCOND;
        let dx = svd.solve(&r, eps).ok()?;
        // At most one long inverse-kinematics stage at once.
        let big = (0..nx)
            .map(|k| (dx[k] * spec.axis_scale(k)).abs())
            .fold(0.0, f64::max);
        if !big.is_finite() {
            return None;
        }
        // Halved while the pose it leads to is out of reach (the straight
        // way may cut across the workspace's boundary).
        let mut damp = if big > IK_STAGE_LONG {
            IK_STAGE_LONG / big
        } else {
            1.0
        };
        let mut next = None;
        for _ in 0..POSE_FIT_HALVINGS {
            let y: Vec<f64> = x.iter().zip(dx.iter()).map(|(x, d)| x - damp * d).collect();
            if let Some(p) = ik(&y, &q) {
                next = Some((y, p));
                break;
            }
            damp /= 2.0;
        }
        (x, q) = next?;
        if big < POSE_FIT_TOL {
            break;
        }
    }
    Some(q)
}
