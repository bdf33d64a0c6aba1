//! Measurement planning: choose the poses that make the free parameters most
//! observable (greedy selection, then DETMAX-style exchange), on the
//! information matrix `M = Σ AᵀA` of column-scaled identification Jacobians.

use crate::calibration::{Observability, observability};
use crate::error::{Error, Result};
use crate::mechanism::{Mechanism, Params};
use crate::models::{Model, prepare_pose};
use crate::sensitivity::sensitivity;
use crate::workspace::WorkspacePoint;
use nalgebra::DMatrix;
use rayon::prelude::*;
use serde::Serialize;

/// Most lattice points over the workspace box that `plan` evaluates as
/// candidates: a finer `--candidates` spacing is coarsened to respect it
/// ([`crate::workspace::lattice_spacing`]), so planning time is bounded.
pub const MAX_CANDIDATE_LATTICE: usize = 20_000;

/// The observability index a plan maximises.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum PlanCriterion {
    /// Product of the singular values (D-optimal).
    O1,
    /// Smallest singular value (E-optimal).
    O3,
    /// Inverse of the summed inverse singular values.
    O5,
}

impl std::str::FromStr for PlanCriterion {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_uppercase().as_str() {
            "O1" => Ok(Self::O1),
            "O3" => Ok(Self::O3),
            "O5" => Ok(Self::O5),
            _ => Err(Error::InvalidRequest(format!(
                "unknown criterion `{s}`; use O1, O3 or O5"
            ))),
        }
    }
}

/// Column-scaled identification Jacobians of candidate poses.
pub struct Candidates {
    /// The candidate poses.
    pub points: Vec<WorkspacePoint>,
    /// Per candidate, `nx × n_free` rows of the scaled Jacobian.
    pub rows: Vec<DMatrix<f64>>,
}

/// Identification Jacobians (free columns, scaled to unit norm over all
/// candidates) of every candidate pose, at `params` with `model`.
pub fn candidate_jacobians<M: Mechanism>(
    mech: &M,
    points: Vec<WorkspacePoint>,
    params: &Params,
    model: Model,
    free: &[usize],
) -> Result<Candidates> {
    let spec = mech.spec();
    let raw: Vec<Result<DMatrix<f64>>> = points
        .par_iter()
        .map(|p| {
            let commands: Vec<f64> = spec.actuated.iter().map(|&j| p.q[j]).collect();
            let pose = prepare_pose(mech, &commands, Some(&p.q))?;
            Ok(sensitivity(mech, &pose, params, model, &[])?
                .jacobian
                .select_columns(free))
        })
        .collect();
    let raw: Vec<DMatrix<f64>> = raw.into_iter().collect::<Result<_>>()?;
    let mut norms = vec![0.0; free.len()];
    for a in &raw {
        for (k, n) in norms.iter_mut().enumerate() {
            *n += a.column(k).norm_squared();
        }
    }
    let rows = raw
        .into_iter()
        .map(|mut a| {
            for (k, n) in norms.iter().enumerate() {
                if *n > 0.0 {
                    a.column_mut(k).unscale_mut(n.sqrt());
                }
            }
            a
        })
        .collect();
    Ok(Candidates { points, rows })
}

/// The [`SCREENED`] candidates (not in `chosen`) with the largest D-optimal
/// gain `log det(I + A (M + reg·I)⁻¹ Aᵀ)`, in parallel.
fn screen(c: &Candidates, m: &DMatrix<f64>, reg: f64, chosen: &[usize]) -> Vec<usize> {
    let n = m.nrows();
    let mut mr = m.clone();
    for i in 0..n {
        mr[(i, i)] += reg;
    }
    let Some(chol) = mr.cholesky() else {
        return (0..c.rows.len()).filter(|i| !chosen.contains(i)).collect();
    };
    let l = chol.l();
    let mut gains: Vec<(f64, usize)> = (0..c.rows.len())
        .into_par_iter()
        .filter(|i| !chosen.contains(i))
        .map(|i| {
            let a = &c.rows[i];
            let b = l
                .solve_lower_triangular(&a.transpose())
                .unwrap_or_else(|| DMatrix::zeros(n, a.nrows()));
            let s = DMatrix::identity(a.nrows(), a.nrows()) + b.transpose() * b;
            let gain = s.cholesky().map_or(0.0, |c| {
                c.l().diagonal().iter().map(|d| 2.0 * d.ln()).sum::<f64>()
            });
            (gain, i)
        })
        .collect();
    gains.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    gains.into_iter().take(SCREENED).map(|(_, i)| i).collect()
}

fn singular_values(m: &DMatrix<f64>) -> Vec<f64> {
    let mut ev: Vec<f64> = m
        .clone()
        .symmetric_eigenvalues()
        .iter()
        .map(|e| e.max(0.0).sqrt())
        .collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    ev
}

fn score(m: &DMatrix<f64>, reg: f64, criterion: PlanCriterion) -> f64 {
    let mut mr = m.clone();
    for i in 0..mr.nrows() {
        mr[(i, i)] += reg;
    }
    let sv = singular_values(&mr);
    match criterion {
        PlanCriterion::O1 => sv.iter().map(|s| s.ln()).sum(),
        PlanCriterion::O3 => *sv.last().unwrap_or(&0.0),
        PlanCriterion::O5 => 1.0 / sv.iter().map(|s| 1.0 / s).sum::<f64>(),
    }
}

/// Observability of a set of candidates (indices into `c`).
pub fn plan_observability(c: &Candidates, set: &[usize]) -> (Observability, f64) {
    let n = c.rows[0].ncols();
    let mut m = DMatrix::zeros(n, n);
    for &i in set {
        m += c.rows[i].transpose() * &c.rows[i];
    }
    let sv = singular_values(&m);
    let cond = match (sv.first(), sv.last()) {
        (Some(a), Some(b)) if *b > 0.0 => a / b,
        _ => f64::INFINITY,
    };
    (observability(&sv, set.len()), cond)
}

/// Work (about `candidates × parameters³ × poses`) up to which every
/// candidate is scored exactly at every step; beyond it each step scores
/// exactly only the [`SCREENED`] candidates with the largest information
/// gain `log det(I + A M⁻¹ Aᵀ)` (one triangular solve each), so that planning
/// a 6-DOF platform with 56 parameters takes seconds, not hours.
pub const EXHAUSTIVE_WORK: f64 = 2e9;
/// Candidates scored exactly per step when screening.
pub const SCREENED: usize = 24;

/// Choose `count` candidates maximising `criterion`: greedy selection, then
/// exchanges (swap a chosen pose for a candidate while that improves the
/// criterion), as DETMAX does. Returns candidate indices.
pub fn plan_poses(c: &Candidates, count: usize, criterion: PlanCriterion) -> Result<Vec<usize>> {
    plan_poses_with_progress(c, count, criterion, &|| {})
}

/// [`plan_poses`], calling `tick` after each greedy step and each exchange
/// position (`count × (1 + passes)` ticks).
pub fn plan_poses_with_progress(
    c: &Candidates,
    count: usize,
    criterion: PlanCriterion,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<usize>> {
    let nc = c.rows.len();
    if count == 0 || count > nc {
        return Err(Error::InvalidRequest(format!(
            "cannot choose {count} poses from {nc} candidates; use a finer --candidates spacing or fewer poses"
        )));
    }
    let n = c.rows[0].ncols();
    let info: Vec<DMatrix<f64>> = c.rows.iter().map(|a| a.transpose() * a).collect();
    // A tiny ridge keeps the criterion defined while the set is rank deficient.
    let reg = 1e-9 * info.iter().map(|m| m.trace()).sum::<f64>() / (nc * n) as f64;
    let mut chosen: Vec<usize> = vec![];
    let mut m = DMatrix::zeros(n, n);
    let screening = (nc as f64) * (n as f64).powi(3) * count as f64 > EXHAUSTIVE_WORK;
    let best_addition = |m: &DMatrix<f64>, chosen: &[usize]| {
        let pool: Vec<usize> = if screening {
            screen(c, m, reg, chosen)
        } else {
            (0..nc).filter(|i| !chosen.contains(i)).collect()
        };
        pool.into_par_iter()
            .map(|i| (score(&(m + &info[i]), reg, criterion), i))
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)))
    };
    while chosen.len() < count {
        let (_, i) = best_addition(&m, &chosen).expect("enough candidates");
        m += &info[i];
        chosen.push(i);
        tick();
    }
    let mut current = score(&m, reg, criterion);
    for _pass in 0..20 {
        let mut improved = false;
        for k in 0..chosen.len() {
            let without = &m - &info[chosen[k]];
            if let Some((s, i)) = best_addition(&without, &chosen)
                && s > current * (1.0 + 1e-12) + 1e-300
            {
                m = without + &info[i];
                chosen[k] = i;
                current = s;
                improved = true;
            }
            tick();
        }
        if !improved {
            break;
        }
    }
    Ok(chosen)
}

/// Settings of [`plan`].
#[derive(Debug, Clone)]
pub struct PlanOptions {
    /// Poses to choose.
    pub count: usize,
    /// The observability index maximised.
    pub criterion: PlanCriterion,
    /// Forward model of the identification Jacobians.
    pub model: Model,
    /// Indices of the parameters to identify.
    pub free: Vec<usize>,
    /// Wanted candidate lattice spacing (mm; angle axes scaled by the
    /// mechanism's work scale); coarsened to stay within four lattice points
    /// per allowed candidate and [`MAX_CANDIDATE_LATTICE`].
    pub spacing: f64,
    /// Most candidates scored: a larger lattice is thinned evenly.
    pub max_candidates: usize,
}

/// A measurement plan and how it compares with a plain grid of the same size.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The chosen poses, in the candidates' (lattice) order: the same set
    /// gives the same file, whichever path the selection took.
    pub poses: Vec<WorkspacePoint>,
    /// Observability of the chosen poses and the condition number of their
    /// column-scaled identification Jacobian.
    pub observability: Observability,
    /// Condition number of the chosen poses.
    pub condition: f64,
    /// A plain grid of `count` poses ([`crate::workspace::grid_targets`]).
    pub grid: Vec<WorkspacePoint>,
    /// Observability of the grid, with the same column scaling.
    pub grid_observability: Observability,
    /// Condition number of the grid.
    pub grid_condition: f64,
    /// Lattice spacing used (mm).
    pub spacing: f64,
    /// Usable lattice points before thinning.
    pub lattice_points: usize,
    /// Candidates scored.
    pub candidates: usize,
}

/// Plan `opts.count` poses over the mechanism's usable workspace at
/// `params`: candidates on a lattice ([`crate::workspace::sample_workspace`]),
/// thinned evenly to `opts.max_candidates`, chosen by [`plan_poses`];
/// `tick` is called after each greedy step and exchange position.
pub fn plan<M: Mechanism>(
    mech: &M,
    params: &Params,
    opts: &PlanOptions,
    tick: &(dyn Fn() + Sync),
) -> Result<Plan> {
    let spec = mech.spec();
    let nx = spec.tool_axes.len();
    if opts.count * nx <= opts.free.len() {
        return Err(Error::InvalidRequest(format!(
            "{} poses give too few coordinates for {} free parameters; plan at least {}",
            opts.count,
            opts.free.len(),
            opts.free.len() / nx + 1
        )));
    }
    if !(opts.spacing.is_finite() && opts.spacing > 0.0) {
        return Err(Error::InvalidRequest(format!(
            "the candidate spacing must be a positive length in mm, got {}",
            opts.spacing
        )));
    }
    if opts.max_candidates == 0 {
        return Err(Error::InvalidRequest(
            "the number of candidates must be at least 1".into(),
        ));
    }
    let spacing = crate::workspace::lattice_spacing(
        spec,
        opts.spacing,
        MAX_CANDIDATE_LATTICE.min(opts.max_candidates.saturating_mul(4)),
    );
    let mut points = crate::workspace::sample_workspace(mech, spacing);
    let lattice_points = points.len();
    if points.len() > opts.max_candidates {
        let (keep, n) = (opts.max_candidates, points.len());
        points = (0..keep).map(|k| points[k * n / keep].clone()).collect();
    }
    let candidates = points.len();
    // The plain grid of the same size, judged with the same column scaling.
    points.extend(crate::workspace::grid_targets(mech, opts.count)?);
    let cands = candidate_jacobians(mech, points, params, opts.model, &opts.free)?;
    let pool = Candidates {
        points: cands.points[..candidates].to_vec(),
        rows: cands.rows[..candidates].to_vec(),
    };
    let mut chosen = plan_poses_with_progress(&pool, opts.count, opts.criterion, tick)?;
    chosen.sort_unstable();
    let (observability, condition) = plan_observability(&cands, &chosen);
    let grid_idx: Vec<usize> = (candidates..cands.points.len()).collect();
    let (grid_observability, grid_condition) = plan_observability(&cands, &grid_idx);
    Ok(Plan {
        poses: chosen.iter().map(|&i| cands.points[i].clone()).collect(),
        observability,
        condition,
        grid: grid_idx.iter().map(|&i| cands.points[i].clone()).collect(),
        grid_observability,
        grid_condition,
        spacing,
        lattice_points,
        candidates,
    })
}
