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

use crate::apply::workspace::nominal_commands;
use crate::engine::kinematics::inverse_kinematics;
use crate::engine::linearized::{linearize, load_vector};
use crate::engine::models::Model;
use crate::error::{Error, Result};
use crate::linalg::solve::checked_lu;
use crate::mechanism::autodiff::jacobians;
use crate::mechanism::{Mechanism, Params};
use nalgebra::{DMatrix, DVector};

/// Commands for one target.
#[derive(Debug, Clone, PartialEq)]
pub struct Compensation {
    /// Actuator commands (rad or mm), one per actuated joint.
    pub commands: Vec<f64>,
    /// What the nominal model commands for the same target (inverse
    /// kinematics of the nominal geometry, zero encoder offsets): what an
    /// uncalibrated controller sends.
    pub nominal: Vec<f64>,
    /// The correction `commands − nominal` a controller adds to its own
    /// commands (rad or mm).
    pub correction: Vec<f64>,
    /// Internal torque each actuator will hold (N·m), `τ = K(c + Δq − q_r)`.
    pub torque: Vec<f64>,
    /// The joint configuration the mechanism reaches.
    pub q: Vec<f64>,
}

/// What the commands must achieve besides the position.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CompensationOptions {
    /// External load on the tool, a wrench ([`crate::engine::load`]: N along lengths,
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
            "compensation inverts the exact model (or the rigid one); use the exact model".into(),
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
        let m = crate::engine::linearized::stiffness_inverse(gamma, k, &q)?;
        let mut tau = DVector::zeros(l);
        if loaded {
            let q_load =
                crate::engine::load::generalized_forces(spec.tool_layout, target, &opts.force);
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
    let nominal = nominal_commands(mech, target)?;
    let correction = commands.iter().zip(&nominal).map(|(c, n)| c - n).collect();
    if commands.iter().chain(&torque).any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(format!(
            "the compensated commands for target {target:?} are not finite: the load is more than the model can represent"
        )));
    }
    Ok(Compensation {
        commands,
        nominal,
        correction,
        torque,
        q,
    })
}

/// [`compensate`] for every row of `targets` (one target after another,
/// a value per tool axis each), in parallel, each row's result its own (one
/// unreachable target does not stop the others). Once `cancel` is set, the
/// rows not yet started are [`Error::Cancelled`].
pub fn compensate_rows<M: Mechanism>(
    mech: &M,
    params: &Params,
    targets: &[f64],
    model: Model,
    opts: &CompensationOptions,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Vec<Result<Compensation>> {
    use rayon::prelude::*;
    let width = mech.spec().tool_axes.len().max(1);
    targets
        .par_chunks(width)
        .map(|t| {
            crate::error::check_cancel(cancel)?;
            if !t.iter().all(|v| v.is_finite()) {
                return Err(Error::InvalidRequest(
                    "the target holds a value that is not a finite number".into(),
                ));
            }
            compensate(mech, params, t, model, opts)
        })
        .collect()
}

/// The commands a controller whose model has parameters `controller`
/// (geometry and encoder offsets; rigid, as controllers are) sends for
/// `target`: `q_r − Δq` at the inverse kinematics.
pub fn controller_commands<M: Mechanism>(
    mech: &M,
    controller: &Params,
    target: &[f64],
) -> Result<Vec<f64>> {
    Ok(controller_configuration(mech, controller, target)?.0)
}

/// [`controller_commands`] and the controller's joint configuration.
fn controller_configuration<M: Mechanism>(
    mech: &M,
    controller: &Params,
    target: &[f64],
) -> Result<(Vec<f64>, Vec<f64>)> {
    let spec = mech.spec();
    let q = inverse_kinematics(mech, controller.geometric(), target)?;
    let c = spec
        .actuated
        .iter()
        .zip(controller.offsets())
        .map(|(&j, o)| q[j] - o)
        .collect();
    Ok((c, q))
}

/// Largest fixed-point iterations of [`predistort`].
pub const MAX_PREDISTORT_ITERATIONS: usize = 50;
/// [`predistort`] stops when the reached pose is within this of the wanted
/// one on every axis (mm or rad).
pub const PREDISTORT_TOL: f64 = 1e-9;

/// A Cartesian pre-distortion: the target to give a closed controller.
#[derive(Debug, Clone, PartialEq)]
pub struct Predistortion {
    /// The target to send to the controller (tool coordinates, mm or rad).
    pub command_target: Vec<f64>,
    /// The commands the controller then sends to the actuators.
    pub commands: Vec<f64>,
    /// Largest remaining difference between the reached and wanted pose
    /// (mm or rad).
    pub residual: f64,
    /// Fixed-point iterations used.
    pub iterations: usize,
}

/// For a controller that only accepts tool targets and runs its own (rigid)
/// model with parameters `controller` (usually the nominal ones): the target
/// `t'` to send so that the real machine, described by `real` with `model`
/// and loaded by `opts.force`, reaches `target`. Solved by the fixed-point
/// iteration `t' ← t' − (x(t') − target)`, which converges because the
/// map from sent to reached target is close to the identity.
pub fn predistort<M: Mechanism>(
    mech: &M,
    controller: &Params,
    real: &Params,
    target: &[f64],
    model: Model,
    opts: &CompensationOptions,
) -> Result<Predistortion> {
    let mut sent = target.to_vec();
    let mut residual = f64::INFINITY;
    for it in 0..MAX_PREDISTORT_ITERATIONS {
        // The controller's configuration starts the real machine's forward
        // kinematics (or equilibrium): the real machine is near it.
        let (commands, q) = controller_configuration(mech, controller, &sent)?;
        let reached =
            crate::engine::models::predict_near(mech, real, &commands, model, &opts.force, &q)?;
        residual = 0.0;
        for ((s, x), t) in sent.iter_mut().zip(&reached.x).zip(target) {
            let e = x - t;
            residual = f64::max(residual, e.abs());
            *s -= e;
        }
        if residual <= PREDISTORT_TOL {
            return Ok(Predistortion {
                // The sent target of this iteration, before the update.
                command_target: sent
                    .iter()
                    .zip(&reached.x)
                    .zip(target)
                    .map(|((s, x), t)| s + (x - t))
                    .collect(),
                commands,
                residual,
                iterations: it + 1,
            });
        }
    }
    Err(Error::NoConvergence {
        what: format!("pre-distortion of target {target:?}"),
        reason: format!(
            "the reached pose is still {residual:.3e} away after {MAX_PREDISTORT_ITERATIONS} iterations; the calibrated machine differs too much from the controller's model here"
        ),
    })
}

/// One axis of a regular grid of targets.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GridAxis {
    /// Tool axis name (`x`, `y`, …).
    pub name: String,
    /// Unit of the values (mm or rad).
    pub unit: crate::Unit,
    /// First node.
    pub start: f64,
    /// Distance between nodes (positive).
    pub step: f64,
    /// Number of nodes (≥ 1).
    pub count: usize,
}

impl GridAxis {
    /// The coordinate of node `i`.
    pub fn node(&self, i: usize) -> f64 {
        self.start + self.step * i as f64
    }
}

/// A regular grid of command corrections over the workspace: a controller
/// adds the interpolated correction to its own (nominal) commands.
#[derive(Debug, Clone, PartialEq)]
pub struct CorrectionGrid {
    /// The gridded tool axes (a subset of the tool's, in tool order).
    pub axes: Vec<GridAxis>,
    /// The value of every tool axis (the gridded ones are overwritten per
    /// node): where the grid's slice of the workspace lies.
    pub fixed: Vec<f64>,
    /// Index in the tool coordinates of each gridded axis.
    pub axis_index: Vec<usize>,
    /// Per node (row-major, the last axis fastest): the compensation, or
    /// `None` where the target is unreachable or outside the usable workspace
    /// (closer to a singularity than [`crate::Spec::min_conditioning`]).
    pub nodes: Vec<Option<Compensation>>,
}

/// Most nodes a correction grid may have: about 12 s and 100 MB on the
/// 3-PRS on 2 cores (1.5 million took 118 s and 814 MB), and more nodes than
/// a controller's table holds.
pub const MAX_GRID_NODES: usize = 200_000;

impl CorrectionGrid {
    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }
    /// Whether the grid has no node.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }
    /// The target (all tool coordinates) of node `n`.
    pub fn target(&self, n: usize) -> Vec<f64> {
        let mut t = self.fixed.clone();
        let mut rest = n;
        for (a, &k) in self.axes.iter().zip(&self.axis_index).rev() {
            t[k] = a.node(rest % a.count);
            rest /= a.count;
        }
        t
    }

    /// The correction at `target` by multilinear interpolation of the cell
    /// that holds it; `None` outside the grid or when a corner of the cell is
    /// unreachable.
    pub fn interpolate(&self, target: &[f64]) -> Option<Vec<f64>> {
        let d = self.axes.len();
        let mut base = vec![0usize; d];
        let mut frac = vec![0.0; d];
        for (i, (a, &k)) in self.axes.iter().zip(&self.axis_index).enumerate() {
            let u = (target[k] - a.start) / a.step;
            let last = (a.count - 1) as f64;
            if !(u >= -1e-9 && u <= last + 1e-9) {
                return None;
            }
            let u = u.clamp(0.0, last);
            let b = (u.floor() as usize).min(a.count.saturating_sub(2));
            base[i] = b;
            frac[i] = if a.count > 1 { u - b as f64 } else { 0.0 };
        }
        let l = self.nodes.iter().flatten().next()?.correction.len();
        let mut out = vec![0.0; l];
        for corner in 0..(1usize << d) {
            let mut w = 1.0;
            let mut n = 0;
            for (i, a) in self.axes.iter().enumerate() {
                let up = (corner >> (d - 1 - i)) & 1 == 1 && a.count > 1;
                if (corner >> (d - 1 - i)) & 1 == 1 && a.count == 1 {
                    w = 0.0;
                }
                w *= if up { frac[i] } else { 1.0 - frac[i] };
                n = n * a.count + base[i] + usize::from(up);
            }
            if w == 0.0 {
                continue;
            }
            let c = self.nodes[n].as_ref()?;
            for (o, v) in out.iter_mut().zip(&c.correction) {
                *o += w * v;
            }
        }
        Some(out)
    }
}

/// Compensate every node of a regular grid (in parallel): `axes` gives the
/// gridded tool axes, `fixed` the value of every tool axis (those not
/// gridded keep it). Unreachable nodes and nodes outside the usable
/// workspace are `None`.
pub fn correction_grid<M: Mechanism>(
    mech: &M,
    params: &Params,
    axes: &[GridAxis],
    fixed: &[f64],
    model: Model,
    opts: &CompensationOptions,
) -> Result<CorrectionGrid> {
    correction_grid_with_progress(mech, params, axes, fixed, model, opts, &|| {})
}

/// [`correction_grid`], calling `progress` once per node computed.
pub fn correction_grid_with_progress<M: Mechanism>(
    mech: &M,
    params: &Params,
    axes: &[GridAxis],
    fixed: &[f64],
    model: Model,
    opts: &CompensationOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<CorrectionGrid> {
    use rayon::prelude::*;
    let spec = mech.spec();
    if fixed.len() != spec.tool_axes.len() {
        return Err(Error::Dimension {
            what: "grid: tool coordinates".into(),
            expected: spec.tool_axes.len(),
            got: fixed.len(),
        });
    }
    let mut axis_index = vec![];
    let mut total: usize = 1;
    for a in axes {
        let k = spec
            .tool_axes
            .iter()
            .position(|n| *n == a.name)
            .ok_or_else(|| {
                Error::InvalidRequest(format!(
                    "grid axis `{}` is not a tool axis ({})",
                    a.name,
                    spec.tool_axes.join(", ")
                ))
            })?;
        if axis_index.contains(&k) {
            return Err(Error::InvalidRequest(format!(
                "grid axis `{}` given twice",
                a.name
            )));
        }
        if !(a.step.is_finite() && a.step > 0.0 && a.start.is_finite() && a.count >= 1) {
            return Err(Error::InvalidRequest(format!(
                "grid axis `{}`: needs a finite start, a positive step and at least one node",
                a.name
            )));
        }
        axis_index.push(k);
        total = total.saturating_mul(a.count);
    }
    if total > MAX_GRID_NODES {
        return Err(Error::InvalidRequest(format!(
            "the grid has {total} nodes, more than {MAX_GRID_NODES}; use a coarser step"
        )));
    }
    let mut grid = CorrectionGrid {
        axes: axes.to_vec(),
        fixed: fixed.to_vec(),
        axis_index,
        nodes: vec![],
    };
    // Nodes outside the usable workspace are left out: near a singularity
    // the correction changes too fast to interpolate.
    grid.nodes = (0..total)
        .into_par_iter()
        .map(|n| {
            let node = compensate(mech, params, &grid.target(n), model, opts)
                .ok()
                .filter(|c| {
                    crate::engine::atlas::conditioning(mech, &c.q, params.geometric())
                        >= spec.min_conditioning
                });
            progress();
            node
        })
        .collect();
    Ok(grid)
}

/// How well interpolating a [`CorrectionGrid`] stands in for exact
/// compensation, checked at cell centres.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct InterpolationError {
    /// Cell centres checked.
    pub points: usize,
    /// Largest difference between interpolated and exact commands, per
    /// actuator (rad or mm).
    pub command_max: Vec<f64>,
    /// Largest distance between the reached and the wanted tool position
    /// (length axes, mm) with the interpolated correction.
    pub position_max: f64,
    /// Root mean square of that distance (mm).
    pub position_rms: f64,
    /// Largest orientation difference (rad), where the tool has angles.
    pub angle_max: f64,
    /// The cell centre where the position error is largest (tool
    /// coordinates, mm or rad); empty when nothing was checked.
    pub worst_target: Vec<f64>,
}

/// Most cell centres [`interpolation_error`] checks (spread evenly).
pub const MAX_CHECKED_CELLS: usize = 2_000;

/// Check the grid at the centres of its cells (all corners reachable; at most
/// [`MAX_CHECKED_CELLS`], spread evenly): the controller's nominal commands
/// plus the interpolated correction, driven through the calibrated model,
/// against the target.
pub fn interpolation_error<M: Mechanism>(
    mech: &M,
    params: &Params,
    grid: &CorrectionGrid,
    model: Model,
    opts: &CompensationOptions,
) -> Result<InterpolationError> {
    use rayon::prelude::*;
    let spec = mech.spec();
    let cells: usize = grid
        .axes
        .iter()
        .map(|a| a.count.saturating_sub(1).max(1))
        .product();
    let step = cells.div_ceil(MAX_CHECKED_CELLS).max(1);
    let centres: Vec<Vec<f64>> = (0..cells)
        .step_by(step)
        .map(|c| {
            let mut t = grid.fixed.clone();
            let mut rest = c;
            for (a, &k) in grid.axes.iter().zip(&grid.axis_index).rev() {
                let n = a.count.saturating_sub(1).max(1);
                let i = rest % n;
                rest /= n;
                t[k] = if a.count > 1 {
                    a.node(i) + 0.5 * a.step
                } else {
                    a.start
                };
            }
            t
        })
        .collect();
    let nominal = Params::nominal(spec);
    let checked: Vec<(Vec<f64>, Vec<f64>, Vec<f64>)> = centres
        .par_iter()
        .filter_map(|t| {
            let corr = grid.interpolate(t)?;
            let exact = compensate(mech, params, t, model, opts).ok()?;
            let sent: Vec<f64> = controller_commands(mech, &nominal, t)
                .ok()?
                .iter()
                .zip(&corr)
                .map(|(c, d)| c + d)
                .collect();
            let reached =
                crate::engine::models::predict(mech, params, &sent, model, &opts.force).ok()?;
            let dc: Vec<f64> = sent
                .iter()
                .zip(&exact.commands)
                .map(|(a, b)| (a - b).abs())
                .collect();
            let dx: Vec<f64> = reached.x.iter().zip(t).map(|(x, t)| x - t).collect();
            Some((t.clone(), dc, dx))
        })
        .collect();
    let l = spec.n_actuated();
    let mut out = InterpolationError {
        points: checked.len(),
        command_max: vec![0.0; l],
        position_max: 0.0,
        position_rms: 0.0,
        angle_max: 0.0,
        worst_target: vec![],
    };
    let mut sum = 0.0;
    for (t, dc, dx) in &checked {
        for (m, d) in out.command_max.iter_mut().zip(dc) {
            *m = m.max(*d);
        }
        let mut p2 = 0.0;
        for (k, e) in dx.iter().enumerate() {
            if spec.tool_units[k] == crate::Unit::Millimetre {
                p2 += e * e;
            } else {
                out.angle_max = out.angle_max.max(e.abs());
            }
        }
        if out.worst_target.is_empty() || p2.sqrt() > out.position_max {
            out.position_max = p2.sqrt();
            out.worst_target = t.clone();
        }
        sum += p2;
    }
    if !checked.is_empty() {
        out.position_rms = (sum / checked.len() as f64).sqrt();
    }
    Ok(out)
}
