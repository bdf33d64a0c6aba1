//! Tolerance budgets at design time: from the mechanism's parameter
//! tolerances alone, before any machine exists, the tool error over the
//! workspace (first order: each tolerance's covariance through the exact
//! model's `∂x/∂p` at the nominal commands of each target; checked by Monte
//! Carlo through the exact model itself), each tolerance's share of it, and
//! what a calibration with a given plan and instrument noise would leave.
//!
//! A machine built within its tolerances and driven by the nominal model
//! (commands from nominal inverse kinematics) misses target `t` by
//! `e_t = x(q_nom(t); p_nom + Δp) − t ≈ J_t Δp`, with `J_t = ∂x/∂p` at the
//! nominal commands. With independent tolerances `Δp_i ~ N(0, σ_i²)`, `e_t`
//! has covariance `C_t = J_t Σ J_tᵀ`, `Σ = diag(σ_i²)`. A calibration that
//! measures the tool at the plan's poses with noise `σ_n` identifies `Δp`
//! with the posterior covariance `(AᵀWA + Σ⁻¹)⁻¹` (`A` the stacked `J` of the
//! plan's poses, `W = diag(1/σ_n²)`); what it leaves at `t` is `J_t` times
//! that times `J_tᵀ`. Parameters without a tolerance are taken as exact.

use crate::engine::models::{Model, Pose, predict_pose, prepare_pose};
use crate::engine::sensitivity::sensitivity;
use crate::error::{Error, Result};
use crate::measurement::data::Noise;
use crate::mechanism::{Mechanism, Params};
use crate::units::Unit;
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::sync::atomic::AtomicBool;

pub use crate::identify::prior::{Tolerance, merged_tolerances, resolve_tolerances};

/// The targets a budget takes the error over: `count` of them, a plain grid
/// over the usable workspace ([`crate::apply::workspace::grid_targets`]).
pub fn budget_targets<M: Mechanism>(mech: &M, count: usize) -> Result<Vec<Vec<f64>>> {
    budget_targets_cancellable(mech, count, None)
}

/// [`budget_targets`], stopped between its lattices once `cancel` is set.
pub fn budget_targets_cancellable<M: Mechanism>(
    mech: &M,
    count: usize,
    cancel: Option<&AtomicBool>,
) -> Result<Vec<Vec<f64>>> {
    if count == 0 {
        return Err(Error::InvalidRequest(
            "a budget needs at least one workspace target".into(),
        ));
    }
    Ok(
        crate::apply::workspace::grid_targets_cancellable(mech, count, cancel)?
            .into_iter()
            .map(|p| p.target)
            .collect(),
    )
}

/// A calibration planned at design time: the tool measured at these targets
/// with this noise per coordinate.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedCalibration {
    /// The poses measured (tool coordinates).
    pub targets: Vec<Vec<f64>>,
    /// The instrument's noise (one σ per coordinate).
    pub noise: Noise,
}

/// What to compute.
#[derive(Debug, Clone, PartialEq)]
pub struct BudgetOptions {
    /// The forward model.
    pub model: Model,
    /// The tool load (one value per tool axis; empty for none).
    pub force: Vec<f64>,
    /// Monte Carlo samples of the tolerances (0: first order only).
    pub samples: usize,
    /// Seed of the samples.
    pub seed: u64,
    /// A calibration to judge, if any.
    pub calibration: Option<PlannedCalibration>,
}

/// Most Monte Carlo samples one budget draws (each is a forward solve per
/// target).
pub const MAX_SAMPLES: usize = 1_000_000;

/// A position error RMS below this (mm) is none: what rounding leaves of
/// an exact zero (a stiffness tolerance without a load gives 1e-15 mm), a
/// million times below any machine's error. Shares of it and ratios to it
/// would be noise ("+6042.8 % from first order").
pub const NEGLIGIBLE_ERROR_MM: f64 = 1e-9;

/// The tool error over the workspace targets: RMS over the targets (and the
/// samples) of the position error's length (mm) and of each axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorSpread {
    /// RMS position error (mm): the root of the mean squared length of the
    /// error over the length axes.
    pub position_rms: f64,
    /// The largest RMS position error at one target (mm).
    pub position_worst: f64,
    /// RMS error of each tool axis (its unit).
    pub axis_rms: Vec<f64>,
}

/// One tolerance and its part in the budget.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToleranceShare {
    /// The parameter.
    pub name: String,
    /// Its unit.
    pub unit: Unit,
    /// Its tolerance (one σ).
    pub sigma: f64,
    /// Its share of the position error variance over the workspace (the
    /// shares add up to 1).
    pub share: f64,
    /// Its σ after the planned calibration, if one was given.
    pub sigma_after: Option<f64>,
}

/// A tolerance budget.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    /// Names of the tool axes (columns of `axis_rms`).
    pub axes: Vec<String>,
    /// Their units.
    pub units: Vec<Unit>,
    /// Workspace targets the error is taken over.
    pub targets: usize,
    /// The tolerances, largest share first.
    pub tolerances: Vec<ToleranceShare>,
    /// The error to first order.
    pub first_order: ErrorSpread,
    /// The error of machines drawn from the tolerances, through the exact
    /// model (when samples were asked for).
    pub monte_carlo: Option<ErrorSpread>,
    /// Samples drawn.
    pub samples: usize,
    /// What the planned calibration would leave, to first order.
    pub after_calibration: Option<ErrorSpread>,
}

impl Budget {
    /// The sampled machines' position error RMS relative to first order
    /// (0.05: 5 % more); `None` without samples, or when first order has
    /// none ([`NEGLIGIBLE_ERROR_MM`]).
    pub fn sampled_change(&self) -> Option<f64> {
        let mc = self.monte_carlo.as_ref()?;
        (self.first_order.position_rms > NEGLIGIBLE_ERROR_MM)
            .then(|| mc.position_rms / self.first_order.position_rms - 1.0)
    }
}

/// The error spread of first-order covariances `covs` (one per target).
fn spread_of(covs: &[DMatrix<f64>], units: &[Unit]) -> ErrorSpread {
    let n = covs.len().max(1) as f64;
    let lengths: Vec<usize> = (0..units.len())
        .filter(|&a| units[a] == Unit::Millimetre)
        .collect();
    let pos = |c: &DMatrix<f64>| lengths.iter().map(|&a| c[(a, a)]).sum::<f64>();
    ErrorSpread {
        position_rms: (covs.iter().map(pos).sum::<f64>() / n).sqrt(),
        position_worst: covs.iter().map(|c| pos(c).sqrt()).fold(0.0, f64::max),
        axis_rms: (0..units.len())
            .map(|a| (covs.iter().map(|c| c[(a, a)]).sum::<f64>() / n).sqrt())
            .collect(),
    }
}

/// The tolerance budget of `mech` over the workspace `targets`, for the
/// tolerances `(index, σ)` ([`resolve_tolerances`]).
pub fn budget<M: Mechanism>(
    mech: &M,
    targets: &[Vec<f64>],
    tolerances: &[(usize, f64)],
    opts: &BudgetOptions,
) -> Result<Budget> {
    budget_cancellable(mech, targets, tolerances, opts, None)
}

/// Machines drawn from the tolerances at a time: their errors are summed in
/// sample order (the same sums as all at once) and the memory stays that
/// of one block, whatever the number of samples.
const SAMPLE_BLOCK: usize = 1024;

/// [`budget`], stopped at its next target or sample once `cancel` is set
/// ([`Error::Cancelled`]).
pub fn budget_cancellable<M: Mechanism>(
    mech: &M,
    targets: &[Vec<f64>],
    tolerances: &[(usize, f64)],
    opts: &BudgetOptions,
    cancel: Option<&AtomicBool>,
) -> Result<Budget> {
    let check = || crate::error::check_cancel(cancel);
    let spec = mech.spec();
    if tolerances.is_empty() {
        return Err(Error::InvalidRequest(
            "no tolerance is given; give at least one parameter's".into(),
        ));
    }
    if targets.is_empty() {
        return Err(Error::InvalidRequest(
            "no workspace target to take the error over".into(),
        ));
    }
    if opts.samples > MAX_SAMPLES {
        return Err(Error::InvalidRequest(format!(
            "{} samples are more than a budget draws ({MAX_SAMPLES}); a few thousand settle the RMS to a percent",
            opts.samples
        )));
    }
    let nominal = Params::nominal(spec);
    let idx: Vec<usize> = tolerances.iter().map(|t| t.0).collect();
    let var: Vec<f64> = tolerances.iter().map(|t| t.1 * t.1).collect();
    // Each target's pose at its nominal commands and `∂x/∂p` there.
    let prepared = |ts: &[Vec<f64>]| -> Result<Vec<(Pose, DMatrix<f64>)>> {
        ts.par_iter()
            .enumerate()
            .map(|(k, t)| {
                check()?;
                let at = |e: Error| e.at_pose(crate::error::Origin::row(k));
                let commands = crate::apply::workspace::nominal_commands(mech, t).map_err(at)?;
                let pose = prepare_pose(mech, &commands, None).map_err(at)?;
                let s = sensitivity(mech, &pose, &nominal, opts.model, &opts.force).map_err(at)?;
                Ok((pose, s.jacobian.select_columns(&idx)))
            })
            .collect()
    };
    let at_targets = prepared(targets)?;
    let units = spec.tool_units.clone();
    let nx = units.len();
    let cov_with = |j: &DMatrix<f64>, c: &DMatrix<f64>| j * c * j.transpose();
    let prior = DMatrix::from_diagonal(&nalgebra::DVector::from_vec(var.clone()));
    let covs: Vec<DMatrix<f64>> = at_targets
        .iter()
        .map(|(_, j)| cov_with(j, &prior))
        .collect();
    let first_order = spread_of(&covs, &units);
    // Shares of the position error variance, one independent tolerance each.
    let lengths: Vec<usize> = (0..nx).filter(|&a| units[a] == Unit::Millimetre).collect();
    let part: Vec<f64> = (0..idx.len())
        .map(|i| {
            at_targets
                .iter()
                .map(|(_, j)| lengths.iter().map(|&a| j[(a, i)] * j[(a, i)]).sum::<f64>())
                .sum::<f64>()
                * var[i]
        })
        .collect();
    let total: f64 = part.iter().sum();
    // The planned calibration's posterior.
    let (after_calibration, post_sigma) = match &opts.calibration {
        None => (None, None),
        Some(plan) => {
            plan.noise.check("noise")?;
            let at_plan = prepared(&plan.targets)?;
            // A tolerance that is a constraint ([`crate::identify::is_constraint`])
            // holds its parameter whatever the plan: its posterior is its
            // prior, and the others are calibrated as without it.
            let held: Vec<bool> = tolerances
                .iter()
                .map(|&(i, s)| crate::identify::is_constraint(s, spec.nominal[i]))
                .collect();
            let n = idx.len();
            let mut info = DMatrix::from_fn(n, n, |a, b| {
                if a == b && !held[a] {
                    1.0 / var[a]
                } else {
                    0.0
                }
            });
            for (_, j) in &at_plan {
                for (a, unit) in units.iter().enumerate() {
                    let s = plan.noise.for_unit(*unit);
                    let row = j.row(a);
                    info += row.transpose() * row / (s * s);
                }
            }
            let keep: Vec<usize> = (0..n).filter(|&a| !held[a]).collect();
            let inverse = info
                .select_rows(&keep)
                .select_columns(&keep)
                .try_inverse()
                .ok_or_else(|| {
                    Error::InvalidRequest(
                        "the planned calibration's information cannot be inverted".into(),
                    )
                })?;
            let mut post = DMatrix::zeros(n, n);
            for (x, &a) in keep.iter().enumerate() {
                for (y, &b) in keep.iter().enumerate() {
                    post[(a, b)] = inverse[(x, y)];
                }
            }
            for a in (0..n).filter(|&a| held[a]) {
                post[(a, a)] = var[a];
            }
            let covs: Vec<DMatrix<f64>> =
                at_targets.iter().map(|(_, j)| cov_with(j, &post)).collect();
            let sig: Vec<f64> = (0..idx.len())
                .map(|i| post[(i, i)].max(0.0).sqrt())
                .collect();
            (Some(spread_of(&covs, &units)), Some(sig))
        }
    };
    // Machines drawn from the tolerances, through the exact model.
    let monte_carlo = if opts.samples == 0 {
        None
    } else {
        let normals: Vec<Normal<f64>> = tolerances
            .iter()
            .map(|t| Normal::new(0.0, t.1).expect("a positive σ"))
            .collect();
        let sample = |s: usize| -> Result<Vec<f64>> {
            check()?;
            let mut rng = StdRng::seed_from_u64(opts.seed.wrapping_add(s as u64));
            let mut p = nominal.clone();
            for (k, &i) in idx.iter().enumerate() {
                p.values[i] += normals[k].sample(&mut rng);
            }
            // Per target: squared error of each axis.
            let mut out = vec![0.0; targets.len() * nx];
            for (k, ((pose, _), t)) in at_targets.iter().zip(targets).enumerate() {
                // A drawn machine that cannot reach a target says the
                // tolerances are wider than the mechanism holds together
                // (`l11=30%` blamed "pose 7" of a grid the user never gave).
                let x = predict_pose(mech, pose, &p, opts.model, &opts.force)
                    .map_err(|e| {
                        Error::InvalidRequest(format!(
                            "machine {} drawn from the tolerances cannot reach target {} of {} over the workspace ({e}): the tolerances are wider than the mechanism stays assembled within; narrow them, or take the first-order figures alone (no samples)",
                            s + 1,
                            k + 1,
                            targets.len()
                        ))
                    })?
                    .x;
                for a in 0..nx {
                    let e = x[a] - t[a];
                    out[k * nx + a] = e * e;
                }
            }
            Ok(out)
        };
        // Each target's squared error per axis summed over the samples, in
        // sample order, a block of samples at a time.
        let mut sums = vec![0.0; targets.len() * nx];
        for first in (0..opts.samples).step_by(SAMPLE_BLOCK) {
            let block: Vec<Vec<f64>> = (first..(first + SAMPLE_BLOCK).min(opts.samples))
                .into_par_iter()
                .map(sample)
                .collect::<Result<_>>()?;
            for squares in &block {
                for (sum, e) in sums.iter_mut().zip(squares) {
                    *sum += e;
                }
            }
        }
        // Each target's mean squared error per axis over the samples: the
        // diagonal `spread_of` reads.
        let per_target: Vec<DMatrix<f64>> = (0..targets.len())
            .map(|k| {
                DMatrix::from_fn(nx, nx, |a, b| {
                    if a == b {
                        sums[k * nx + a] / opts.samples as f64
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        let spread = spread_of(&per_target, &units);
        Some(spread)
    };
    let names = spec.param_names();
    let mut shares: Vec<ToleranceShare> = tolerances
        .iter()
        .enumerate()
        .map(|(k, &(i, sigma))| ToleranceShare {
            name: names[i].to_string(),
            unit: spec.param_unit(i),
            sigma,
            share: if total > 0.0 && first_order.position_rms > NEGLIGIBLE_ERROR_MM {
                part[k] / total
            } else {
                0.0
            },
            sigma_after: post_sigma.as_ref().map(|s| s[k]),
        })
        .collect();
    shares.sort_by(|a, b| b.share.total_cmp(&a.share));
    Ok(Budget {
        axes: spec.tool_axes.clone(),
        units,
        targets: targets.len(),
        tolerances: shares,
        first_order,
        monte_carlo,
        samples: opts.samples,
        after_calibration,
    })
}
