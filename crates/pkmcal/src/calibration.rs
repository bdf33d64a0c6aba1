//! Identification of parameter errors and encoder offsets (MODEL.md eq. 12):
//! minimise `Σ_i ‖x̂_i − h(c_i, p)‖²` over the free parameters with one of the
//! three forward models, with identifiability analysis before fitting,
//! uncertainty after, and validation on held-out poses.

use crate::error::{Error, Result};
use crate::lm::{self, Problem, Termination};
use crate::mechanism::{Mechanism, Params, Spec};
use crate::models::{Model, Pose, Prediction, predict_pose_warm, prepare_pose};
use crate::sensitivity::{sensitivity, sensitivity_at};
use crate::simulate::Measurement;
use crate::stats::{ErrorStats, error_stats, improvement_percent};
use crate::units::{ParamKind, Unit};
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use serde::Serialize;
use std::cell::RefCell;

/// Singular values below this fraction of the largest (of the column-scaled
/// identification Jacobian) count as unidentifiable directions.
pub const RANK_TOL: f64 = 1e-8;
/// A Jacobian column whose effect is below this fraction of the largest counts
/// as zero (the parameter does not act on the tool at all).
pub const ZERO_COLUMN: f64 = 1e-10;
/// Correlations above this are reported.
pub const CORRELATION_REPORT: f64 = 0.9;
/// Components below this are left out of a named unidentifiable combination.
const COMBINATION_CUTOFF: f64 = 0.05;

/// How residuals are penalised (the robust loss; `ρ` is taken by the
/// parameters, hence `Loss`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "lowercase", tag = "kind", content = "scale")]
pub enum Loss {
    /// Ordinary least squares.
    Squared,
    /// Huber: quadratic within `k` robust standard deviations, linear beyond
    /// (k = 1.345 gives 95 % efficiency under Gaussian noise).
    Huber(f64),
    /// Cauchy: `log(1 + (u/c)²)` (c = 2.385 gives 95 % efficiency).
    Cauchy(f64),
}

impl Loss {
    /// IRLS weight `ψ(u)/u` of a standardised residual `u`.
    pub fn weight(self, u: f64) -> f64 {
        match self {
            Loss::Squared => 1.0,
            Loss::Huber(k) => {
                if u.abs() <= k {
                    1.0
                } else {
                    k / u.abs()
                }
            }
            Loss::Cauchy(c) => 1.0 / (1.0 + (u / c).powi(2)),
        }
    }
}

/// A pose whose residual is far beyond the noise.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Outlier {
    /// Pose number (1-based, in data order).
    pub pose: usize,
    /// Residual vector, predicted minus measured (mm, per tool coordinate).
    pub residual: Vec<f64>,
    /// Largest standardised residual |r|/s of the pose (robust scale s).
    pub standardized: f64,
}

/// Settings of a calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// Loss applied to the standardised residuals (iteratively reweighted).
    pub loss: Loss,
    /// Poses with a standardised residual above this are reported as outliers.
    pub outlier_threshold: f64,
    /// Drop the outliers and refit.
    pub drop_outliers: bool,
    /// Forward model used for identification.
    pub model: Model,
    /// Indices of the parameters to identify.
    pub free: Vec<usize>,
    /// External force applied to the tool during the measurements (N).
    pub force: Vec<f64>,
    /// Standard deviation of each residual (pose-major, tool axes inner), mm;
    /// `None`: all equal.
    pub sigma: Option<Vec<f64>>,
    /// Fix unidentifiable parameters automatically (with a warning).
    pub auto_fix: bool,
    /// Solver settings (tolerances, bounds; `free` and `weights` are set here).
    pub solver: lm::Options,
}

impl CalibrationOptions {
    /// The mechanism's default free set with the given model.
    pub fn new(spec: &Spec, model: Model) -> Self {
        Self {
            loss: Loss::Squared,
            outlier_threshold: 4.0,
            drop_outliers: false,
            model,
            free: spec
                .default_free
                .iter()
                .filter_map(|n| spec.param_index(n).ok())
                .collect(),
            force: vec![],
            sigma: None,
            auto_fix: true,
            solver: lm::Options {
                ftol: 1e-12,
                xtol: 1e-12,
                max_evaluations: 200,
                ..lm::Options::default()
            },
        }
    }
}

/// Parameters, residuals and Jacobian of the last Jacobian evaluation.
type CachedJacobian = (Vec<f64>, DVector<f64>, DMatrix<f64>);

/// The identification least-squares problem: residuals are predicted minus
/// measured tool coordinates, pose by pose.
pub struct IdentificationProblem<'a, M: Mechanism> {
    mech: &'a M,
    poses: Vec<Pose>,
    measured: Vec<Vec<f64>>,
    model: Model,
    force: Vec<f64>,
    /// The last parameters evaluated and their predictions: a Jacobian at an
    /// accepted trial point reuses them, and equilibria start from them.
    cache: RefCell<Option<(Vec<f64>, Vec<Prediction>)>>,
    /// The last Jacobian evaluated, with its parameters.
    jacobian_cache: RefCell<Option<CachedJacobian>>,
}

impl<'a, M: Mechanism> IdentificationProblem<'a, M> {
    /// Prepare every pose (nominal configuration and linearisation).
    pub fn new(mech: &'a M, data: &[Measurement], model: Model, force: &[f64]) -> Result<Self> {
        let mut poses: Vec<Pose> = Vec::with_capacity(data.len());
        for (i, m) in data.iter().enumerate() {
            let start = poses.last().map(|p| p.nominal_q.clone());
            let pose = prepare_pose(mech, &m.commands, start.as_deref()).map_err(|e| {
                Error::InvalidRequest(format!("pose {} (commands {:?}): {e}", i + 1, m.commands))
            })?;
            poses.push(pose);
        }
        Ok(Self {
            mech,
            poses,
            measured: data.iter().map(|m| m.measured.clone()).collect(),
            model,
            force: force.to_vec(),
            cache: RefCell::new(None),
            jacobian_cache: RefCell::new(None),
        })
    }

    /// Predictions at every pose, warm-started from (or taken from) the cache.
    fn predictions(&self, params: &Params) -> Result<Vec<Prediction>> {
        let cached = self.cache.borrow();
        if let Some((x, p)) = cached.as_ref()
            && *x == params.values
        {
            return Ok(p.clone());
        }
        let out: Result<Vec<Prediction>> = self
            .poses
            .iter()
            .enumerate()
            .map(|(i, pose)| {
                let warm = cached.as_ref().map(|(_, p)| p[i].q.as_slice());
                predict_pose_warm(self.mech, pose, params, self.model, &self.force, warm)
                    .map_err(|e| Error::InvalidRequest(format!("pose {}: {e}", i + 1)))
            })
            .collect();
        drop(cached);
        let out = out?;
        *self.cache.borrow_mut() = Some((params.values.clone(), out.clone()));
        Ok(out)
    }

    /// The prepared poses.
    pub fn poses(&self) -> &[Pose] {
        &self.poses
    }

    /// Predicted tool coordinates at every pose under `params`.
    pub fn predict(&self, params: &Params) -> Result<Vec<Vec<f64>>> {
        Ok(self.predictions(params)?.into_iter().map(|p| p.x).collect())
    }

    /// Residuals and the full Jacobian (all parameters) under `params`.
    pub fn jacobian(&self, params: &Params) -> Result<(DVector<f64>, DMatrix<f64>)> {
        if let Some((x, r, j)) = self.jacobian_cache.borrow().as_ref()
            && *x == params.values
        {
            return Ok((r.clone(), j.clone()));
        }
        let nx = self.mech.spec().tool_axes.len();
        let np = self.mech.spec().n_params();
        let mut r = DVector::zeros(self.poses.len() * nx);
        let mut j = DMatrix::zeros(self.poses.len() * nx, np);
        let predictions = self.predictions(params)?;
        for (i, (pose, pred)) in self.poses.iter().zip(predictions).enumerate() {
            let s = sensitivity_at(self.mech, pose, params, self.model, &self.force, pred)
                .map_err(|e| Error::InvalidRequest(format!("pose {}: {e}", i + 1)))?;
            for a in 0..nx {
                r[i * nx + a] = s.prediction.x[a] - self.measured[i][a];
            }
            j.view_mut((i * nx, 0), (nx, np)).copy_from(&s.jacobian);
        }
        *self.jacobian_cache.borrow_mut() = Some((params.values.clone(), r.clone(), j.clone()));
        Ok((r, j))
    }
}

impl<M: Mechanism> Problem for IdentificationProblem<'_, M> {
    fn n_params(&self) -> usize {
        self.mech.spec().n_params()
    }
    fn n_residuals(&self) -> usize {
        self.poses.len() * self.mech.spec().tool_axes.len()
    }
    fn evaluate(
        &self,
        x: &[f64],
        jacobian: bool,
    ) -> std::result::Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        let params = Params::new(self.mech.spec(), x.to_vec()).map_err(|e| e.to_string())?;
        if params.stiffness().iter().any(|k| *k <= 0.0) {
            return Err("non-positive stiffness".into());
        }
        if jacobian {
            let (r, j) = self.jacobian(&params).map_err(|e| e.to_string())?;
            return Ok((r, Some(j)));
        }
        let pred = self.predict(&params).map_err(|e| e.to_string())?;
        let nx = self.mech.spec().tool_axes.len();
        let mut r = DVector::zeros(self.poses.len() * nx);
        for (i, p) in pred.iter().enumerate() {
            for a in 0..nx {
                r[i * nx + a] = p[a] - self.measured[i][a];
            }
        }
        Ok((r, None))
    }
}

/// Observability indices of the column-scaled identification Jacobian with
/// singular values σ₁ ≥ … ≥ σ_L over m poses (Sun & Hollerbach, "Observability
/// index selection for robot calibration", ICRA 2008, which collects them):
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Observability {
    /// O1 = (σ₁⋯σ_L)^(1/L) / √m (Borm & Menq 1991): the volume of the error ellipsoid.
    pub o1: f64,
    /// O2 = σ_L / σ₁ (Driels & Pathre 1990): inverse condition number.
    pub o2: f64,
    /// O3 = σ_L (Nahvi, Hollerbach & Hayward 1994): minimum singular value.
    pub o3: f64,
    /// O4 = σ_L² / σ₁ (Nahvi & Hollerbach 1996): noise amplification index.
    pub o4: f64,
    /// O5 = 1 / Σ 1/σ_i (Sun & Hollerbach 2008): inverse of the summed variances.
    pub o5: f64,
}

/// A direction in parameter space the data cannot see.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Unidentifiable {
    /// The combination, e.g. `0.71·l11 − 0.71·B1x` (column-scaled units).
    pub combination: String,
    /// `(name, coefficient)` of the combination.
    pub terms: Vec<(String, f64)>,
    /// The parameter fixed to remove it (when fixing automatically).
    pub fixed: Option<String>,
}

/// A pair of strongly correlated parameters.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Correlation {
    /// First parameter.
    pub a: String,
    /// Second parameter.
    pub b: String,
    /// Correlation coefficient.
    pub r: f64,
}

/// Identifiability of the free parameters from the poses.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Identifiability {
    /// Free parameters analysed (names).
    pub free: Vec<String>,
    /// Singular values of the column-scaled Jacobian (descending).
    pub singular_values: Vec<f64>,
    /// Numerical rank.
    pub rank: usize,
    /// σ₁ / σ_L (infinite when rank deficient).
    pub condition_number: f64,
    /// Observability indices O1–O5 (over the identifiable part).
    pub observability: Observability,
    /// Unidentifiable directions.
    pub unidentifiable: Vec<Unidentifiable>,
    /// Pairs of free parameters correlated above 0.9.
    pub correlations: Vec<Correlation>,
}

pub(crate) fn observability(sv: &[f64], poses: usize) -> Observability {
    let l = sv.len().max(1) as f64;
    let last = sv.last().copied().unwrap_or(0.0);
    let first = sv.first().copied().unwrap_or(0.0);
    let logsum: f64 = sv.iter().map(|s| s.ln()).sum();
    Observability {
        o1: (logsum / l).exp() / (poses as f64).sqrt(),
        o2: if first > 0.0 { last / first } else { 0.0 },
        o3: last,
        o4: if first > 0.0 {
            last * last / first
        } else {
            0.0
        },
        o5: 1.0 / sv.iter().map(|s| 1.0 / s).sum::<f64>(),
    }
}

fn correlations(spec: &Spec, free: &[usize], cov: &DMatrix<f64>) -> Vec<Correlation> {
    let names = spec.param_names();
    let mut out = vec![];
    for a in 0..free.len() {
        for b in a + 1..free.len() {
            let d = (cov[(a, a)] * cov[(b, b)]).sqrt();
            if d > 0.0 {
                let r = cov[(a, b)] / d;
                if r.abs() > CORRELATION_REPORT {
                    out.push(Correlation {
                        a: names[free[a]].to_string(),
                        b: names[free[b]].to_string(),
                        r,
                    });
                }
            }
        }
    }
    out
}

/// Analyse the identifiability of `free` from the full identification
/// Jacobian `jac` (weighted): scale every column to unit norm, take the SVD,
/// name each direction below [`RANK_TOL`]. With `auto_fix`, fix one parameter
/// per unidentifiable direction (the one that dominates it) until the rest
/// has full rank. Returns the analysis and the remaining free set.
pub fn analyze_identifiability(
    spec: &Spec,
    jac: &DMatrix<f64>,
    free: &[usize],
    poses: usize,
    auto_fix: bool,
) -> (Identifiability, Vec<usize>) {
    let names = spec.param_names();
    let mut free = free.to_vec();
    let mut unidentifiable = vec![];
    let mut first_sv: Option<Vec<f64>> = None;
    loop {
        if free.is_empty() {
            let ident = Identifiability {
                free: vec![],
                singular_values: first_sv.unwrap_or_default(),
                rank: 0,
                condition_number: f64::INFINITY,
                observability: observability(&[], poses),
                unidentifiable,
                correlations: vec![],
            };
            return (ident, free);
        }
        let sub = jac.select_columns(&free);
        // A column counts as zero when its effect over a typical parameter
        // change (its nominal size, or 1 unit) is negligible next to the
        // largest one: round-off must not be scaled up into a direction.
        let effect: Vec<f64> = free
            .iter()
            .enumerate()
            .map(|(k, &i)| sub.column(k).norm() * spec.nominal[i].abs().max(1.0))
            .collect();
        let biggest = effect.iter().copied().fold(0.0, f64::max);
        let norms: Vec<f64> = (0..free.len())
            .map(|k| {
                if effect[k] > ZERO_COLUMN * biggest {
                    sub.column(k).norm()
                } else {
                    0.0
                }
            })
            .collect();
        let mut scaled = sub.clone();
        for (k, n) in norms.iter().enumerate() {
            if *n > 0.0 {
                scaled.column_mut(k).unscale_mut(*n);
            }
        }
        let svd = scaled.clone().svd(false, true);
        let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
        order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
        let sv: Vec<f64> = order.iter().map(|&i| svd.singular_values[i]).collect();
        let vt = svd.v_t.expect("requested");
        if first_sv.is_none() {
            first_sv = Some(sv.clone());
        }
        let smax = sv.first().copied().unwrap_or(0.0);
        // Directions: zero columns, then small singular values.
        let mut dirs: Vec<Vec<f64>> = norms
            .iter()
            .enumerate()
            .filter(|(_, n)| **n == 0.0)
            .map(|(k, _)| {
                let mut v = vec![0.0; free.len()];
                v[k] = 1.0;
                v
            })
            .collect();
        if dirs.is_empty() {
            for &i in &order {
                if svd.singular_values[i] <= RANK_TOL * smax {
                    dirs.push(vt.row(i).iter().copied().collect());
                }
            }
            // A tall matrix has as many singular values as columns; a wide one
            // (fewer residuals than free parameters) is rank deficient too.
            if sv.len() < free.len() && dirs.is_empty() {
                dirs.push(vec![1.0; free.len()]);
            }
        }
        if dirs.is_empty() || !auto_fix {
            for d in &dirs {
                unidentifiable.push(direction(&names, &free, d, None));
            }
            let rank = sv.iter().filter(|s| **s > RANK_TOL * smax).count();
            let kept: Vec<f64> = sv[..rank].to_vec();
            let cov = if rank == free.len() {
                let (c, _) = lm::covariance(&sub, 1e-14);
                correlations(spec, &free, &c)
            } else {
                vec![]
            };
            let all_sv = first_sv.unwrap_or_default();
            let cond = if rank == all_sv.len() && rank > 0 {
                all_sv[0] / all_sv[rank - 1]
            } else {
                f64::INFINITY
            };
            let ident = Identifiability {
                free: free.iter().map(|&i| names[i].to_string()).collect(),
                rank: all_sv
                    .iter()
                    .filter(|s| **s > RANK_TOL * all_sv.first().copied().unwrap_or(0.0))
                    .count(),
                condition_number: cond,
                observability: observability(&kept, poses),
                singular_values: all_sv,
                unidentifiable,
                correlations: cov,
            };
            return (ident, free);
        }
        // Fix the parameter that dominates the first direction.
        let d = &dirs[0];
        let k = (0..d.len())
            .max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
            .expect("non-empty");
        unidentifiable.push(direction(
            &names,
            &free,
            d,
            Some(names[free[k]].to_string()),
        ));
        free.remove(k);
    }
}

fn direction(names: &[&str], free: &[usize], d: &[f64], fixed: Option<String>) -> Unidentifiable {
    let big = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let sign = d
        .iter()
        .find(|v| v.abs() == big)
        .map_or(1.0, |v| v.signum());
    let mut terms: Vec<(String, f64)> = d
        .iter()
        .enumerate()
        .filter(|(_, v)| v.abs() >= COMBINATION_CUTOFF * big)
        .map(|(k, v)| (names[free[k]].to_string(), sign * v))
        .collect();
    terms.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let combination = terms
        .iter()
        .enumerate()
        .map(|(i, (n, c))| {
            let s = if *c < 0.0 {
                " − "
            } else if i > 0 {
                " + "
            } else {
                ""
            };
            format!("{s}{:.3}·{n}", c.abs())
        })
        .collect::<String>();
    Unidentifiable {
        combination,
        terms,
        fixed,
    }
}

/// One row of the parameter table.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ParameterResult {
    /// Name.
    pub name: String,
    /// Unit of the values (declared by the mechanism).
    pub unit: Unit,
    /// Role of the parameter (geometry, encoder offset, stiffness, instrument).
    pub kind: ParamKind,
    /// Nominal value.
    pub nominal: f64,
    /// Identified value (the starting value if fixed).
    pub identified: f64,
    /// Identified minus nominal.
    pub change: f64,
    /// Standard deviation (0 when fixed).
    pub std_dev: f64,
    /// Whether it was identified.
    pub free: bool,
    /// Why it is fixed, when it was requested free.
    pub note: Option<String>,
}

/// A warning with what to do about it.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Warning {
    /// What happened.
    pub message: String,
    /// What to do.
    pub hint: String,
}

/// Everything a calibration produces.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// Model used.
    pub model: Model,
    /// Identified parameters (full vector).
    #[serde(skip)]
    pub params: Params,
    /// Why the solver stopped.
    pub termination: Termination,
    /// Readable reason.
    pub termination_reason: String,
    /// Whether it converged.
    pub converged: bool,
    /// Solver iterations.
    pub iterations: usize,
    /// Residual evaluations.
    pub evaluations: usize,
    /// Number of poses.
    pub poses: usize,
    /// Weighted residual sum of squares at the solution.
    pub sum_of_squares: f64,
    /// Residual standard deviation `√(RSS/(m − n))` (weighted units; mm when
    /// unweighted).
    pub residual_sigma: f64,
    /// Parameter table.
    pub parameters: Vec<ParameterResult>,
    /// Identifiability before fitting (at the starting parameters).
    pub identifiability: Identifiability,
    /// Covariance of the free parameters (scaled by the residual variance),
    /// in `free` order.
    #[serde(skip)]
    pub covariance: DMatrix<f64>,
    /// Free parameter indices actually identified.
    #[serde(skip)]
    pub free: Vec<usize>,
    /// The covariance with parameter names (serialised as `covariance`).
    #[serde(rename = "covariance")]
    pub parameter_covariance: ParameterCovariance,
    /// Correlations above 0.9 at the solution.
    pub correlations: Vec<Correlation>,
    /// Loss used.
    pub loss: Loss,
    /// Robust scale of the residuals (1.4826 × median absolute deviation of
    /// the weighted residuals), mm when unweighted.
    pub robust_scale: f64,
    /// Poses with residuals beyond the outlier threshold (at the final fit).
    pub outliers: Vec<Outlier>,
    /// Poses dropped as outliers before the final fit (1-based).
    pub dropped: Vec<usize>,
    /// Residuals at the solution, predicted minus measured, pose-major (mm).
    #[serde(skip)]
    pub residuals: Vec<f64>,
    /// Warnings.
    pub warnings: Vec<Warning>,
}

/// Identify the free parameters from measurements (eq. 12), starting from
/// `start` (usually nominal). With a robust [`Loss`], iteratively reweighted
/// least squares: fit, standardise the residuals by their robust scale, reweight
/// by `ψ(u)/u`, refit from the last solution, until the weights settle. Poses
/// beyond `outlier_threshold` are reported; with `drop_outliers` they are
/// removed and the fit repeated.
pub fn calibrate<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    let nx = mech.spec().tool_axes.len();
    let base: Vec<f64> = match &opts.sigma {
        Some(s) => s.clone(),
        None => vec![1.0; data.len() * nx],
    };
    let mut cal = calibrate_once(mech, data, start, opts)?;
    let mut robust = vec![1.0; base.len()];
    let mut scale = robust_scale(&cal.residuals, &base);
    if opts.loss != Loss::Squared {
        for _ in 0..MAX_REWEIGHTS {
            let r = cal.residuals.clone();
            scale = robust_scale(&r, &base);
            let next: Vec<f64> = r
                .iter()
                .zip(&base)
                .map(|(ri, si)| opts.loss.weight(ri / si / scale.max(f64::MIN_POSITIVE)))
                .collect();
            let change = next
                .iter()
                .zip(&robust)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            robust = next;
            let mut o = opts.clone();
            o.sigma = Some(
                base.iter()
                    .zip(&robust)
                    .map(|(s, w)| s / w.sqrt())
                    .collect(),
            );
            o.loss = Loss::Squared;
            cal = calibrate_once(mech, data, &cal.params, &o)?;
            if change < 1e-3 {
                break;
            }
        }
    }
    let r = cal.residuals.clone();
    let outliers = find_outliers(&r, &base, scale, nx, opts.outlier_threshold);
    let max_drops = data.len() / 5;
    if opts.drop_outliers && !outliers.is_empty() && max_drops > 0 {
        // Drop the worst pose only, then refit: one gross error can make its
        // neighbours look bad under least squares (masking).
        let worst = outliers
            .iter()
            .max_by(|a, b| a.standardized.total_cmp(&b.standardized))
            .expect("not empty")
            .clone();
        let kept: Vec<Measurement> = data
            .iter()
            .enumerate()
            .filter(|(i, _)| i + 1 != worst.pose)
            .map(|(_, m)| m.clone())
            .collect();
        let mut o = opts.clone();
        o.sigma = opts.sigma.as_ref().map(|s| {
            s.chunks(nx)
                .enumerate()
                .filter(|(i, _)| i + 1 != worst.pose)
                .flat_map(|(_, c)| c.to_vec())
                .collect()
        });
        let mut refit = calibrate(mech, &kept, start, &o)?;
        let worst_pose = worst.pose;
        let original = |k: usize| if k >= worst_pose { k + 1 } else { k };
        let mut dropped = vec![worst.pose];
        dropped.extend(refit.dropped.iter().map(|&k| original(k)));
        let mut found = vec![worst];
        found.extend(refit.outliers.iter().map(|x| Outlier {
            pose: original(x.pose),
            ..x.clone()
        }));
        // Only the outermost call reports; inner calls' warnings are replaced.
        refit
            .warnings
            .retain(|w| !w.message.contains("outlier pose(s) dropped"));
        refit.warnings.push(Warning {
            message: format!(
                "{} outlier pose(s) dropped before the final fit: {}",
                dropped.len(),
                dropped.iter().map(|p| p.to_string()).collect::<Vec<_>>().join(", ")
            ),
            hint: "check those measurements (a misread, a bumped instrument) before trusting the result".into(),
        });
        refit.dropped = dropped;
        refit.outliers = found;
        return Ok(refit);
    }
    if !outliers.is_empty() {
        cal.warnings.push(Warning {
            message: format!(
                "{} pose(s) with residuals beyond {} robust standard deviations: {}",
                outliers.len(),
                opts.outlier_threshold,
                outliers
                    .iter()
                    .map(|o| format!("pose {} ({:.1}σ)", o.pose, o.standardized))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            hint: "inspect them; --loss huber or cauchy limits their influence, --drop-outliers refits without them".into(),
        });
    }
    cal.loss = opts.loss;
    cal.robust_scale = scale;
    cal.outliers = outliers;
    Ok(cal)
}

/// Residuals below this (mm) are never outliers: on noise-free data the
/// robust scale is round-off and would flag round-off.
pub const OUTLIER_FLOOR_MM: f64 = 1e-6;

/// Reweighting rounds of the robust fit.
const MAX_REWEIGHTS: usize = 20;

/// 1.4826 × median |r_i/σ_i|: a scale that outliers do not inflate.
fn robust_scale(r: &[f64], sigma: &[f64]) -> f64 {
    let mut a: Vec<f64> = r
        .iter()
        .zip(sigma)
        .map(|(ri, si)| (ri / si).abs())
        .collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    1.4826 * a[a.len() / 2]
}

fn find_outliers(r: &[f64], sigma: &[f64], scale: f64, nx: usize, threshold: f64) -> Vec<Outlier> {
    if scale <= 0.0 {
        return vec![];
    }
    r.chunks(nx)
        .zip(sigma.chunks(nx))
        .enumerate()
        .filter_map(|(i, (ri, si))| {
            let u = ri
                .iter()
                .zip(si)
                .map(|(a, b)| (a / b).abs() / scale)
                .fold(0.0, f64::max);
            let big = ri.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            (u > threshold && big > OUTLIER_FLOOR_MM).then(|| Outlier {
                pose: i + 1,
                residual: ri.to_vec(),
                standardized: u,
            })
        })
        .collect()
}

fn calibrate_once<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    let spec = mech.spec();
    let names = spec.param_names();
    let nx = spec.tool_axes.len();
    let mut warnings = vec![];
    if opts.free.is_empty() {
        return Err(Error::InvalidRequest(
            "no parameter is free; free at least one with --free".into(),
        ));
    }
    let m = data.len() * nx;
    if m <= opts.free.len() {
        return Err(Error::InvalidRequest(format!(
            "{} poses give {m} coordinates for {} free parameters; measure more poses (at least {}) or fix parameters",
            data.len(),
            opts.free.len(),
            opts.free.len() / nx + 1
        )));
    }
    let weights: Option<Vec<f64>> = match &opts.sigma {
        Some(s) => {
            if s.len() != m || s.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(Error::InvalidRequest(
                    "one positive finite standard deviation per measured coordinate is needed"
                        .into(),
                ));
            }
            Some(s.iter().map(|v| 1.0 / v).collect())
        }
        None => None,
    };
    let stiff: Vec<usize> = (spec.n_geometric() + spec.n_actuated()..spec.n_params()).collect();
    let unloaded = opts.force.iter().all(|f| *f == 0.0);
    if unloaded && stiff.iter().all(|k| opts.free.contains(k)) {
        warnings.push(Warning {
            message: "all stiffness parameters are free without an external load: only their ratios are identifiable, so one is fixed".into(),
            hint: "fix one stiffness at its measured value (e.g. --fix k1), or calibrate with a known tool load".into(),
        });
    }
    let problem = IdentificationProblem::new(mech, data, opts.model, &opts.force)?;
    // Identifiability at the start.
    let (_, mut jac) = problem.jacobian(start)?;
    if let Some(w) = &weights {
        for (i, wi) in w.iter().enumerate() {
            jac.row_mut(i).scale_mut(*wi);
        }
    }
    let (identifiability, free) =
        analyze_identifiability(spec, &jac, &opts.free, data.len(), opts.auto_fix);
    for u in &identifiability.unidentifiable {
        let message = match &u.fixed {
            Some(f) => format!(
                "unidentifiable with the {} model: {} (fixed `{f}` at its starting value)",
                opts.model.name(),
                u.combination
            ),
            None => format!(
                "unidentifiable with the {} model: {}",
                opts.model.name(),
                u.combination
            ),
        };
        warnings.push(Warning {
            message,
            hint: "these parameters cannot be separated by tool positions at these poses; fix one of them, or add poses or measurements that see them".into(),
        });
    }
    let mut solver = opts.solver.clone();
    let mut mask = vec![false; spec.n_params()];
    for &i in &free {
        mask[i] = true;
    }
    solver.free = Some(mask);
    solver.weights = weights.clone();
    let report = lm::minimize(&problem, &start.values, &solver);
    if !report.termination.converged() {
        warnings.push(Warning {
            message: format!("the fit did not converge: {}", report.termination.reason()),
            hint: "check the data for outliers or wrong columns, or start closer".into(),
        });
    }
    let params = Params::new(spec, report.x.clone())?;
    let dof = m.saturating_sub(free.len()).max(1);
    let s2 = report.sum_of_squares / dof as f64;
    let (cov_unit, rank) = lm::covariance(&report.jacobian, 1e-12);
    if rank < free.len() {
        warnings.push(Warning {
            message: format!(
                "the Jacobian at the solution has rank {rank} for {} free parameters; their uncertainties are not defined",
                free.len()
            ),
            hint: "fix parameters named in the identifiability report".into(),
        });
    }
    let covariance = cov_unit * s2;
    let mut parameters = vec![];
    for (i, name) in names.iter().enumerate() {
        let k = free.iter().position(|&f| f == i);
        let note = if k.is_none() && opts.free.contains(&i) {
            Some("unidentifiable: fixed at its starting value".into())
        } else {
            None
        };
        parameters.push(ParameterResult {
            name: name.to_string(),
            unit: spec.param_unit(i),
            kind: spec.param_kind(i),
            nominal: spec.nominal[i],
            identified: params.values[i],
            change: params.values[i] - spec.nominal[i],
            std_dev: k.map_or(0.0, |k| covariance[(k, k)].max(0.0).sqrt()),
            free: k.is_some(),
            note,
        });
    }
    let correlations = correlations(spec, &free, &covariance);
    let parameter_covariance = ParameterCovariance {
        names: free.iter().map(|&i| names[i].to_string()).collect(),
        matrix: (0..free.len())
            .map(|a| (0..free.len()).map(|b| covariance[(a, b)]).collect())
            .collect(),
    };
    Ok(Calibration {
        parameter_covariance,
        model: opts.model,
        params,
        converged: report.termination.converged(),
        termination_reason: report.termination.reason(),
        termination: report.termination,
        iterations: report.iterations,
        evaluations: report.evaluations,
        poses: data.len(),
        sum_of_squares: report.sum_of_squares,
        residual_sigma: s2.sqrt(),
        parameters,
        identifiability,
        covariance,
        free,
        correlations,
        loss: opts.loss,
        robust_scale: 0.0,
        outliers: vec![],
        dropped: vec![],
        residuals: report
            .residuals
            .iter()
            .enumerate()
            .map(|(i, v)| v / weights.as_ref().map_or(1.0, |w| w[i]))
            .collect(),
        warnings,
    })
}

/// Identifiability analysis alone (no fit), at `params`.
pub fn analyze<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    params: &Params,
    model: Model,
    free: &[usize],
    force: &[f64],
) -> Result<Identifiability> {
    let problem = IdentificationProblem::new(mech, data, model, force)?;
    let (_, jac) = problem.jacobian(params)?;
    Ok(analyze_identifiability(mech.spec(), &jac, free, data.len(), false).0)
}

/// Covariance of identified parameters, by name: plain data that travels in
/// the calibration report (`covariance`) and back into `predict`.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct ParameterCovariance {
    /// Parameter names, in matrix order.
    pub names: Vec<String>,
    /// Covariance matrix (units² of the parameters), row by row.
    pub matrix: Vec<Vec<f64>>,
}

impl ParameterCovariance {
    /// Parameter indices and the matrix, checked against the mechanism.
    pub fn resolve(&self, spec: &Spec) -> Result<(Vec<usize>, DMatrix<f64>)> {
        let n = self.names.len();
        if self.matrix.len() != n || self.matrix.iter().any(|r| r.len() != n) {
            return Err(Error::InvalidRequest(format!(
                "the covariance must be {n} × {n} for {n} names"
            )));
        }
        if self.matrix.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::InvalidRequest(
                "the covariance has non-finite entries".into(),
            ));
        }
        let idx = self
            .names
            .iter()
            .map(|n| spec.param_index(n))
            .collect::<Result<Vec<_>>>()?;
        Ok((idx, DMatrix::from_fn(n, n, |a, b| self.matrix[a][b])))
    }
}

/// Predicted tool position under `params` and its covariance (mm²) from the
/// parameters' covariance: `J_p C J_pᵀ` with the model's exact sensitivities.
pub fn tool_covariance<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    covariance: &ParameterCovariance,
) -> Result<(Prediction, DMatrix<f64>)> {
    let (idx, c) = covariance.resolve(mech.spec())?;
    let s = sensitivity(mech, pose, params, model, force)?;
    let j = s.jacobian.select_columns(&idx);
    let cov = &j * c * j.transpose();
    Ok((s.prediction, cov))
}

/// Predicted tool position and its covariance (mm²) at `commands`, from a
/// calibration's parameters and their covariance.
pub fn predict_with_uncertainty<M: Mechanism>(
    mech: &M,
    cal: &Calibration,
    commands: &[f64],
    force: &[f64],
) -> Result<(Vec<f64>, DMatrix<f64>)> {
    let pose = prepare_pose(mech, commands, None)?;
    let (p, cov) = tool_covariance(
        mech,
        &pose,
        &cal.params,
        cal.model,
        force,
        &cal.parameter_covariance,
    )?;
    Ok((p.x, cov))
}

/// Before and after statistics of a data set.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Accuracy {
    /// Poses.
    pub poses: usize,
    /// Errors before calibration: measured minus target (or minus the
    /// nominal prediction when no target is known).
    pub before: ErrorStats,
    /// Errors after: measured minus the calibrated prediction.
    pub after: ErrorStats,
    /// Reduction of the largest distance error, percent.
    pub improvement_max_percent: f64,
    /// Reduction of the RMS distance error, percent.
    pub improvement_rms_percent: f64,
}

/// Error vectors (measured minus reference), one per pose, mm.
pub type ErrorVectors = Vec<Vec<f64>>;

/// Errors of `data` before (nominal) and after (calibrated `params`) with `model`.
pub fn accuracy<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    params: &Params,
    model: Model,
    force: &[f64],
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    let problem = IdentificationProblem::new(mech, data, model, force)?;
    let nominal = Params::nominal(mech.spec());
    let nominal_pred = problem.predict(&nominal)?;
    let pred = problem.predict(params)?;
    let before: Vec<Vec<f64>> = data
        .iter()
        .zip(&nominal_pred)
        .map(|(m, p)| {
            let reference = m.target.as_ref().unwrap_or(p);
            m.measured
                .iter()
                .zip(reference)
                .map(|(a, b)| a - b)
                .collect()
        })
        .collect();
    let after: Vec<Vec<f64>> = data
        .iter()
        .zip(&pred)
        .map(|(m, p)| m.measured.iter().zip(p).map(|(a, b)| a - b).collect())
        .collect();
    let units = &mech.spec().tool_units;
    let b = error_stats(&before, units);
    let a = error_stats(&after, units);
    Ok((
        Accuracy {
            poses: data.len(),
            improvement_max_percent: improvement_percent(b.distance_max, a.distance_max),
            improvement_rms_percent: improvement_percent(b.distance_rms, a.distance_rms),
            before: b,
            after: a,
        },
        before,
        after,
    ))
}

/// Split indices into a training and a held-out part (`fraction` held out),
/// shuffled with `seed`.
pub fn holdout_split(n: usize, fraction: f64, seed: u64) -> Result<(Vec<usize>, Vec<usize>)> {
    if !(fraction > 0.0 && fraction < 1.0) {
        return Err(Error::InvalidRequest(format!(
            "the held-out fraction must be between 0 and 1, got {fraction}"
        )));
    }
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut StdRng::seed_from_u64(seed));
    let k = ((n as f64) * fraction).round().max(1.0) as usize;
    if k >= n {
        return Err(Error::InvalidRequest(format!(
            "holding out {fraction} of {n} poses leaves none to calibrate on"
        )));
    }
    let mut held: Vec<usize> = idx[..k].to_vec();
    let mut train: Vec<usize> = idx[k..].to_vec();
    held.sort_unstable();
    train.sort_unstable();
    Ok((train, held))
}

/// Result of k-fold cross-validation.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CrossValidation {
    /// Number of folds.
    pub folds: usize,
    /// Held-out RMS distance error of each fold (mm).
    pub fold_rms: Vec<f64>,
    /// Pooled held-out error statistics.
    pub pooled: ErrorStats,
}

/// k-fold cross-validation: calibrate on k−1 folds, predict the held-out one.
pub fn cross_validate<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    folds: usize,
    seed: u64,
) -> Result<CrossValidation> {
    cross_validate_with_progress(mech, data, start, opts, folds, seed, &|| {})
}

/// [`cross_validate`], calling `progress` after each fold.
pub fn cross_validate_with_progress<M: Mechanism>(
    mech: &M,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    folds: usize,
    seed: u64,
    progress: &dyn Fn(),
) -> Result<CrossValidation> {
    if folds < 2 || folds > data.len() {
        return Err(Error::InvalidRequest(format!(
            "k-fold cross-validation needs 2 ≤ k ≤ {} poses, got k = {folds}",
            data.len()
        )));
    }
    let mut idx: Vec<usize> = (0..data.len()).collect();
    idx.shuffle(&mut StdRng::seed_from_u64(seed));
    let mut fold_rms = vec![];
    let mut pooled = vec![];
    for f in 0..folds {
        let held: Vec<usize> = idx.iter().copied().skip(f).step_by(folds).collect();
        let train: Vec<Measurement> = idx
            .iter()
            .filter(|i| !held.contains(i))
            .map(|&i| data[i].clone())
            .collect();
        let test: Vec<Measurement> = held.iter().map(|&i| data[i].clone()).collect();
        let cal = calibrate(mech, &train, start, opts)?;
        let (acc, _, after) = accuracy(mech, &test, &cal.params, opts.model, &opts.force)?;
        fold_rms.push(acc.after.distance_rms);
        pooled.extend(after);
        progress();
    }
    Ok(CrossValidation {
        folds,
        fold_rms,
        pooled: error_stats(&pooled, &mech.spec().tool_units),
    })
}
