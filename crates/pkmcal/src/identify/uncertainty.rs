//! Uncertainty after a fit: the one rule for the scale of the uncertainties
//! (docs/model.md §6), the parameters' covariance `(J̃ᵀW̃J̃)⁻¹` formed in one
//! place, and the predicted tool-position uncertainty at any pose.
//!
//! The rule: the covariance is the inverse of the information of the
//! readings (weighted by their σ) and of the priors, with no factor after
//! it. What scales it is the σ the readings were weighted with:
//!
//! * σ known (given in the data, or stated and taken as it is): the
//!   covariance is absolute, intervals are normal ([`Scale::Known`]);
//! * σ estimated from the readings' residuals, over the readings'
//!   redundancy `Σ (1 − h)` (the priors' rows take no part), a stated noise
//!   a prior of it worth `ν₀` readings: intervals are Student's t with
//!   the redundancy (plus `ν₀`) as degrees of freedom ([`Scale::Estimated`]).

use super::noise::NoiseGroup;
use super::prior::PriorTerm;
use super::result::Calibration;
use crate::engine::models::{Model, Pose, Prediction, prepare_pose};
use crate::engine::sensitivity::sensitivity;
use crate::error::{Error, Result};
use crate::mechanism::{Mechanism, Params, Spec};
use nalgebra::DMatrix;
use serde::Serialize;

/// Degrees of freedom from which an estimated σ's intervals and tests are
/// drawn as for a known σ (normal, χ²): Student's t's 97.5 % quantile is
/// then the normal's 1.959964 to 2.4e-6 (the first term of its expansion,
/// (z³ + z)/4ν), below any figure shown.
pub const NORMAL_LIMIT_DOF: f64 = 1e6;

/// How a calibration's uncertainties are scaled (docs/model.md §6, "The
/// scale of the uncertainties"): what a front end says beside each σ and
/// what its intervals and tests are drawn from.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize, Default)]
#[serde(tag = "rule", rename_all = "snake_case")]
pub enum Scale {
    /// Every σ known: given in the data, or stated and taken as it is. The
    /// covariance is absolute; intervals and tests are normal and χ².
    #[default]
    Known,
    /// Some σ estimated from the readings' residuals (a stated noise a
    /// prior of it): intervals and tests are Student's t and Fisher's F
    /// with `dof` degrees of freedom, the estimated groups' redundancy plus
    /// the readings each stated noise is worth (0: no uncertainty).
    Estimated {
        /// The degrees of freedom of the estimated σ.
        dof: f64,
    },
}

impl Scale {
    /// The rule of a fit whose noise groups are `groups`: known when no
    /// group was estimated or every estimated one leaned on a stated σ
    /// worth infinitely many readings.
    pub fn of(groups: &[NoiseGroup]) -> Scale {
        let mut dof = 0.0;
        let mut estimated = false;
        for g in groups.iter().filter(|g| g.estimated) {
            let worth = g.stated.and(g.stated_readings).unwrap_or(0.0);
            if worth == f64::INFINITY && !g.stated_relative {
                continue;
            }
            estimated = true;
            dof += g.redundancy.unwrap_or(0.0).max(0.0) + worth.min(f64::MAX);
        }
        if estimated {
            Scale::Estimated { dof }
        } else {
            Scale::Known
        }
    }

    /// The degrees of freedom of an estimated σ; `None` when known.
    pub fn dof(&self) -> Option<f64> {
        match self {
            Scale::Known => None,
            Scale::Estimated { dof } => Some(*dof),
        }
    }

    /// The degrees of freedom the intervals and tests are drawn with:
    /// [`Self::dof`], or `None` (the normal and χ² limits) from
    /// [`NORMAL_LIMIT_DOF`] on, where Student's t and Fisher's F are those
    /// limits to the digits shown and their tails lose all precision (a
    /// record's 1e308 degrees of freedom gave p = 1 for a 128σ change).
    fn drawn_dof(&self) -> Option<f64> {
        self.dof().filter(|n| n.is_nan() || *n < NORMAL_LIMIT_DOF)
    }

    /// The half-width, in standard deviations, of a two-sided interval of
    /// confidence `level` (0.95: 1.96 when σ is known, Student's t with the
    /// degrees of freedom when it was estimated; NaN with none).
    pub fn quantile(&self, level: f64) -> f64 {
        use statrs::distribution::{ContinuousCDF, Normal, StudentsT};
        let p = 0.5 + 0.5 * level;
        match self.drawn_dof() {
            None => Normal::standard().inverse_cdf(p),
            Some(n) if n > 0.0 => {
                StudentsT::new(0.0, 1.0, n).map_or(f64::NAN, |t| t.inverse_cdf(p))
            }
            Some(_) => f64::NAN,
        }
    }

    /// The two-sided p-value of a standardised value `z`.
    pub fn two_sided(&self, z: f64) -> f64 {
        use statrs::distribution::{ContinuousCDF, StudentsT};
        match self.drawn_dof() {
            Some(n) if n > 0.0 => {
                StudentsT::new(0.0, 1.0, n).map_or(f64::NAN, |t| 2.0 * t.sf(z.abs()))
            }
            Some(_) => f64::NAN,
            None => statrs::function::erf::erfc(z.abs() / std::f64::consts::SQRT_2),
        }
    }

    /// The upper tail of a quadratic form `q` of `k` standardised values:
    /// `P(χ²_k ≥ q)`, or `P(F(k, dof) ≥ q/k)` when σ was estimated.
    pub fn quadratic_tail(&self, q: f64, k: f64) -> f64 {
        use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};
        if k.is_nan() || k <= 0.0 {
            return f64::NAN;
        }
        match self.drawn_dof() {
            None => ChiSquared::new(k).map_or(f64::NAN, |c| c.sf(q)),
            Some(n) if n > 0.0 => FisherSnedecor::new(k, n).map_or(f64::NAN, |f| f.sf(q / k)),
            Some(_) => f64::NAN,
        }
    }
}

/// The covariance `(J̃ᵀW̃J̃)⁻¹` of the free parameters (docs/model.md eq.
/// 12, 13): the readings' Jacobian `readings` (rows weighted by 1/σ,
/// columns the free parameters) with one row `1/σ_j` appended per prior of
/// a free parameter (a constraint has none: its parameter is not free).
/// The one place a parameter covariance is formed; nothing scales it
/// afterwards. Returns it and its numerical rank.
pub(crate) fn posterior_covariance(
    readings: &DMatrix<f64>,
    free: &[usize],
    terms: &[PriorTerm],
) -> (DMatrix<f64>, usize) {
    let m = readings.nrows();
    let rows: Vec<(usize, f64)> = terms
        .iter()
        .filter(|t| !t.constraint)
        .filter_map(|t| {
            free.iter()
                .position(|&f| f == t.index)
                .map(|k| (k, 1.0 / t.sigma))
        })
        .collect();
    // A large Jacobian's rows are stood for by its triangular factor `R`
    // (`RᵀR = JᵀJ`, by blocks of rows, no copy of it): the same covariance
    // but for rounding.
    let (mut a, top) = if super::noise::is_large(readings) {
        let r = super::noise::factor_by_rows(readings, None);
        let n = r.nrows();
        (r.resize_vertically(n + rows.len(), 0.0), n)
    } else {
        (readings.clone().resize_vertically(m + rows.len(), 0.0), m)
    };
    for (r, (k, w)) in rows.iter().enumerate() {
        a[(top + r, *k)] = *w;
    }
    crate::lm::covariance(&a, crate::lm::COVARIANCE_RANK_TOL)
}

/// A finished fit's uncertainties by the scale rule: the covariance
/// ([`posterior_covariance`]) of the readings weighted by their final σ
/// (each row's σ times `factor`, a robust loss's group scale; 1 otherwise)
/// and of the priors, the standard deviations, each prior's share of
/// information from the data (from the same covariance), the correlations,
/// the covariance by name (a constraint's parameter with its own σ), and
/// the readings' standard deviation of unit weight. With an estimated σ and
/// no degree of freedom, every standard deviation is NaN.
pub(crate) fn apply_scale(cal: &mut Calibration, scale: Scale, factor: &[f64]) {
    // The fit's Jacobian as it is, copied only to be rescaled.
    let scaled;
    let j = if factor.len() == cal.jacobian.nrows() {
        let mut j = cal.jacobian.clone();
        crate::lm::unscale_rows(&mut j, factor);
        scaled = j;
        &scaled
    } else {
        &cal.jacobian
    };
    let (mut c, _) = posterior_covariance(j, &cal.free, &cal.priors);
    let no_dof = scale.dof().is_some_and(|n| n.is_nan() || n <= 0.0);
    // The readings' redundancy and their weighted residuals.
    let h = super::noise::leverages_with(j, &c);
    let redundancy: f64 = h.iter().map(|h| (1.0 - h).max(0.0)).sum();
    let ss: f64 = cal
        .residuals
        .iter()
        .zip(&cal.sigmas)
        .enumerate()
        .map(|(i, (r, s))| (r / (s * factor.get(i).copied().unwrap_or(1.0))).powi(2))
        .sum();
    cal.redundancy = redundancy;
    cal.unit_weight_sigma = if redundancy > 0.0 {
        (ss / redundancy).sqrt()
    } else {
        f64::NAN
    };
    if no_dof {
        c.fill(f64::NAN);
    }
    for (k, &i) in cal.free.iter().enumerate() {
        cal.parameters[i].std_dev = c[(k, k)].max(0.0).sqrt();
        if c[(k, k)].is_nan() {
            cal.parameters[i].std_dev = f64::NAN;
        }
    }
    for t in cal.priors.iter().filter(|t| t.constraint) {
        cal.parameters[t.index].std_dev = t.sigma;
    }
    super::prior::annotate(&mut cal.parameters, &cal.priors, &cal.free, &c);
    let names: Vec<String> = cal.parameters.iter().map(|p| p.name.clone()).collect();
    cal.correlations = super::identifiability::correlations(&names, &cal.free, &c);
    // The mechanism's part travels with the parameters into predictions
    // (the marginal covariance is the sub-matrix; a constraint's
    // parameter with its own σ); the instrument's stays in the table.
    let np = cal.params.values.len();
    let mut names: Vec<String> = vec![];
    let mut at: Vec<Option<usize>> = vec![];
    for (k, &i) in cal.free.iter().enumerate() {
        if i < np {
            names.push(cal.parameters[i].name.clone());
            at.push(Some(k));
        }
    }
    let held: Vec<&PriorTerm> = cal
        .priors
        .iter()
        .filter(|t| t.constraint && t.index < np)
        .collect();
    for t in &held {
        names.push(t.name.clone());
        at.push(None);
    }
    let matrix = (0..names.len())
        .map(|a| {
            (0..names.len())
                .map(|b| match (at[a], at[b]) {
                    (Some(x), Some(y)) => c[(x, y)],
                    (None, None) if a == b => held[a - (names.len() - held.len())].sigma.powi(2),
                    _ => 0.0,
                })
                .collect()
        })
        .collect();
    cal.parameter_covariance = ParameterCovariance { names, matrix };
    cal.covariance = c;
    cal.scale = scale;
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
    /// Parameter indices and the matrix, checked against the mechanism. The
    /// instrument frame's parameters are left out (the marginal covariance
    /// of the mechanism's is the sub-matrix): predictions are in the base
    /// frame.
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
        if let Some(a) = (0..n).find(|&a| self.matrix[a][a] < 0.0) {
            return Err(Error::InvalidRequest(format!(
                "the covariance gives `{}` a negative variance ({:e}); it is not a covariance",
                self.names[a], self.matrix[a][a]
            )));
        }
        for (a, name) in self.names.iter().enumerate() {
            if name.trim().is_empty() {
                return Err(Error::InvalidRequest(format!(
                    "the covariance's name {} is empty",
                    a + 1
                )));
            }
            if self.names[..a].contains(name) {
                return Err(Error::InvalidRequest(format!(
                    "the covariance names `{name}` twice"
                )));
            }
        }
        let frame = spec.tool_layout.frame_names();
        let keep: Vec<usize> = (0..n)
            .filter(|&a| !frame.contains(&self.names[a]))
            .collect();
        let idx = keep
            .iter()
            .map(|&a| spec.param_index(&self.names[a]))
            .collect::<Result<Vec<_>>>()?;
        Ok((
            idx,
            DMatrix::from_fn(keep.len(), keep.len(), |a, b| self.matrix[keep[a]][keep[b]]),
        ))
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
    // A covariance that overflows here, or is not positive semi-definite
    // enough to give non-negative variances, gives no standard deviation:
    // an error, never a σ of 0 or NaN.
    if let Some(a) = (0..cov.nrows()).find(|&a| !(cov[(a, a)].is_finite() && cov[(a, a)] >= 0.0)) {
        return Err(Error::InvalidRequest(format!(
            "the parameters' covariance gives tool coordinate {} a variance of {:e}; it is not a covariance of these parameters (check the report it came from)",
            a + 1,
            cov[(a, a)]
        )));
    }
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
