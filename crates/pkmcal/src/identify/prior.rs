//! Priors (docs/model.md eq. 13): what is known of a parameter before the
//! data, its tolerance, as a Gaussian `N(μ, σ²)` about its nominal value
//! (the mechanism's parameters) or its start (the instrument's, a free
//! frame's registered one). The fit then minimises the data misfit plus
//! `Σ_j ((p_j − μ_j)/σ_j)²`: each prior is one more row of the least-squares
//! problem, `p_j − μ_j` weighted by `1/σ_j`, with a unit row in the
//! Jacobian. Prior rows are not readings: they take no part in noise
//! estimation, reweighting, outlier flags or the scale of the
//! uncertainties ([`super::uncertainty::Scale`]). A prior far tighter than
//! any measurement resolves is a constraint ([`is_constraint`]).

use super::result::{ParameterResult, Warning, WarningKind};
use crate::error::{Error, Result};
use crate::lm::Problem;
use crate::measurement::MeasurementModel;
use crate::mechanism::Spec;
use crate::units::Unit;

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

/// A parameter's tolerance as a user states it: one standard deviation in
/// the parameter's unit, or a fraction of its nominal value.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Tolerance {
    /// σ in the parameter's unit (mm, rad, N·m/rad…).
    Absolute(f64),
    /// σ as a fraction of the nominal value's magnitude (`"20%"` is 0.2).
    Relative(f64),
}

impl Tolerance {
    /// A tolerance from text: a number (`"0.1"`, σ in the parameter's unit)
    /// or a percentage of the nominal value (`"20%"`). The one rule every
    /// front end reads tolerances by.
    pub fn parse(text: &str) -> Result<Self> {
        let t = text.trim();
        let bad = || {
            Error::InvalidRequest(format!(
                "tolerance `{text}`: give one standard deviation in the parameter's unit (e.g. 0.05) or a percentage of its nominal value (e.g. \"20%\")"
            ))
        };
        let tol = match t.strip_suffix('%') {
            Some(p) => Tolerance::Relative(p.trim().parse::<f64>().map_err(|_| bad())? / 100.0),
            None => Tolerance::Absolute(t.parse::<f64>().map_err(|_| bad())?),
        };
        tol.check().map_err(|_| bad())?;
        Ok(tol)
    }

    fn check(&self) -> Result<()> {
        let v = match self {
            Tolerance::Absolute(v) | Tolerance::Relative(v) => *v,
        };
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(Error::InvalidRequest(format!(
                "a tolerance must be a positive finite number, got {v}"
            )))
        }
    }

    /// σ for a parameter of nominal value `nominal`.
    pub fn sigma(&self, nominal: f64) -> f64 {
        match self {
            Tolerance::Absolute(v) => *v,
            Tolerance::Relative(f) => f * nominal.abs(),
        }
    }
}

/// The standard deviation of each named parameter of `spec`: `(index, σ)`
/// in the order given. Unknown names (with a suggestion), a name given
/// twice, a non-positive σ and a relative tolerance of a parameter whose
/// nominal value is 0 are refused.
pub fn resolve_tolerances(spec: &Spec, given: &[(String, Tolerance)]) -> Result<Vec<(usize, f64)>> {
    resolve_named(
        given,
        |n| spec.param_index(n),
        |i| spec.nominal[i],
        |i| spec.param_unit(i),
    )
}

/// [`resolve_tolerances`] over any vector of named parameters: `index`
/// names them (its error for an unknown one), `nominal` and `unit` describe
/// each. The one rule of tolerances and priors.
pub(crate) fn resolve_named(
    given: &[(String, Tolerance)],
    index: impl Fn(&str) -> Result<usize>,
    nominal: impl Fn(usize) -> f64,
    unit: impl Fn(usize) -> Unit,
) -> Result<Vec<(usize, f64)>> {
    let mut out: Vec<(usize, f64)> = vec![];
    for (name, tol) in given {
        tol.check()
            .map_err(|e| Error::InvalidRequest(format!("tolerance of `{name}`: {e}")))?;
        let i = index(name)?;
        if out.iter().any(|(j, _)| *j == i) {
            return Err(Error::InvalidRequest(format!(
                "`{name}` has two tolerances; give one"
            )));
        }
        let sigma = tol.sigma(nominal(i));
        if sigma == 0.0 {
            return Err(Error::InvalidRequest(format!(
                "`{name}` is 0 nominally, so a tolerance relative to it is 0; give its σ in {}",
                unit(i)
            )));
        }
        check_sigma(name, sigma, unit(i))?;
        out.push((i, sigma));
    }
    Ok(out)
}

/// A prior's σ that can enter a fit: positive, finite and at most its
/// unit's largest magnitude (a tolerance of 1e300 mm is a typing error).
/// A σ however small is accepted: below [`CONSTRAINT_RELATIVE`] of its
/// parameter it is a constraint ([`is_constraint`]), never a weight.
pub(crate) fn check_sigma(name: &str, sigma: f64, unit: Unit) -> Result<()> {
    if sigma.is_finite() && sigma > 0.0 && sigma <= unit.max_magnitude() {
        return Ok(());
    }
    Err(Error::OutOfRange {
        field: format!("tolerance of {name}"),
        value: sigma,
        expected: format!(
            "one standard deviation, positive and at most {:e} {unit}",
            unit.max_magnitude()
        ),
    })
}

/// The description's tolerances (`table`) with `given` ones replacing them
/// for the same names: the one merge rule of the front ends.
pub fn merged_tolerances(
    table: &[(String, Tolerance)],
    given: Vec<(String, Tolerance)>,
) -> Vec<(String, Tolerance)> {
    let mut out: Vec<(String, Tolerance)> = table
        .iter()
        .filter(|(n, _)| !given.iter().any(|(g, _)| g == n))
        .cloned()
        .collect();
    out.extend(given);
    out
}

/// A prior asked for: one parameter of the identification vector (the
/// mechanism's, then the instrument's) and its standard deviation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Prior {
    /// Index in the identification vector.
    pub index: usize,
    /// One standard deviation, in the parameter's unit.
    pub sigma: f64,
}

/// A prior as the fit used it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PriorTerm {
    /// The parameter's name.
    pub name: String,
    /// Its index in the identification vector.
    pub index: usize,
    /// The prior's centre: the nominal value (the mechanism's parameters)
    /// or the start (the instrument's).
    pub centre: f64,
    /// One standard deviation.
    pub sigma: f64,
    /// Whether the prior is a constraint ([`is_constraint`]): its parameter
    /// is held at the centre, not fitted, with `sigma` as its standard
    /// deviation and nothing from the data.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub constraint: bool,
}

/// A prior the data push against (docs/model.md eq. 13, "Priors in
/// conflict with the data"): releasing it lowers the fit's χ² by more than
/// chance allows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PriorConflict {
    /// The parameter.
    pub name: String,
    /// Its unit.
    pub unit: Unit,
    /// The prior's centre (the drawing's value).
    pub centre: f64,
    /// Its tolerance (σ).
    pub tolerance: f64,
    /// The drop of `Σ (r/σ)²` when the prior is released, those named
    /// before it released already (its row's score statistic,
    /// `e² / (1 − h)`).
    pub statistic: f64,
    /// Its p-value (χ² with one degree of freedom, or F(1, ν) with the
    /// degrees of freedom of an estimated σ).
    pub p_value: f64,
    /// The value the data choose with it released (the others named
    /// before it released too), where they see it: its share of
    /// information from the data at least [`SEEN_SHARE`].
    pub data_value: Option<f64>,
    /// That value's standard deviation.
    pub data_sd: Option<f64>,
}

/// A prior the data see less than this share of is not given the value
/// the data alone would choose ([`PriorConflict::data_value`]): they
/// hardly see it.
pub const SEEN_SHARE: f64 = 0.01;

/// A prior whose σ is below this fraction of its parameter's size
/// (`max(|μ|, 1)` in the parameter's unit) is a constraint
/// ([`is_constraint`]).
pub const CONSTRAINT_RELATIVE: f64 = 1e-8;

/// Whether a prior of standard deviation `sigma` centred on `centre` is an
/// equality constraint rather than a weight (docs/model.md eq. 13): below
/// [`CONSTRAINT_RELATIVE`] of the parameter's size no measurement can move
/// it, and its row's weight `1/σ` would only swamp every other column of
/// the least-squares problem (and overflow below ~1e-154). Its parameter is
/// then held at `centre` with `sigma` as its standard deviation, and the
/// others are identified as they would be without it.
pub fn is_constraint(sigma: f64, centre: f64) -> bool {
    sigma < CONSTRAINT_RELATIVE * centre.abs().max(1.0)
}

/// A value more than this many tolerances from its prior's centre is
/// warned about ([`super::WarningKind::BeyondTolerance`]).
pub const BEYOND_TOLERANCES: f64 = 3.0;

/// A posterior σ above this fraction of the prior σ (less than
/// `1 − 0.8² = 36 %` of the information from the data) means the data taught
/// little ([`super::WarningKind::PriorDominated`]).
pub const TAUGHT_LITTLE: f64 = 0.8;

/// The priors of named parameters (the mechanism's or the instrument's,
/// the frame's included): each tolerance resolved by the one rule of
/// [`crate::apply::budget::resolve_tolerances`], relative ones against the
/// mechanism's nominal value or the instrument's.
pub fn named_priors(
    spec: &Spec,
    measurement: &MeasurementModel,
    given: &[(String, Tolerance)],
) -> Result<Vec<Prior>> {
    let np = spec.n_params();
    let nominal = |i: usize| {
        if i < np {
            spec.nominal[i]
        } else {
            measurement.nominal()[i - np]
        }
    };
    let unit = |i: usize| {
        if i < np {
            spec.param_unit(i)
        } else {
            measurement.param_units()[i - np]
        }
    };
    Ok(
        resolve_named(given, |n| measurement.index_of(spec, n), nominal, unit)?
            .into_iter()
            .map(|(index, sigma)| Prior { index, sigma })
            .collect(),
    )
}

/// The identification problem with one row per prior appended:
/// `x_j − μ_j`, whose Jacobian row is the unit vector of `j` (the solver
/// weights it by `1/σ_j`).
pub(super) struct WithPriors<'a, P: Problem> {
    pub(super) inner: &'a P,
    pub(super) terms: &'a [PriorTerm],
}

impl<P: Problem> Problem for WithPriors<'_, P> {
    fn n_params(&self) -> usize {
        self.inner.n_params()
    }
    fn n_residuals(&self) -> usize {
        self.inner.n_residuals() + self.terms.len()
    }
    fn evaluate(
        &self,
        x: &[f64],
        jacobian: bool,
    ) -> std::result::Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        let (r, j) = self.inner.evaluate(x, jacobian)?;
        if self.terms.is_empty() {
            // Without priors, the readings' problem as it is (no copy).
            return Ok((r, j));
        }
        Ok((
            append_residuals(r, self.terms, x),
            j.map(|j| append_rows(j, self.terms)),
        ))
    }
}

/// Residuals with the priors' `x_j − μ_j` appended.
pub(super) fn append_residuals(r: DVector<f64>, terms: &[PriorTerm], x: &[f64]) -> DVector<f64> {
    let m = r.len();
    let mut r = r.resize_vertically(m + terms.len(), 0.0);
    for (a, t) in terms.iter().enumerate() {
        r[m + a] = x[t.index] - t.centre;
    }
    r
}

/// A full Jacobian (every parameter) with the priors' unit rows appended.
pub(super) fn append_rows(j: DMatrix<f64>, terms: &[PriorTerm]) -> DMatrix<f64> {
    if terms.is_empty() {
        return j;
    }
    let m = j.nrows();
    let mut j = j.resize_vertically(m + terms.len(), 0.0);
    for (a, t) in terms.iter().enumerate() {
        j[(m + a, t.index)] = 1.0;
    }
    j
}

/// The share of a parameter's posterior information that came from the
/// data, `1 − σ_post²/σ_prior²` (0: all from the tolerance; 1: all
/// measured), within [0, 1].
pub fn information_from_data(posterior: f64, prior: f64) -> f64 {
    (1.0 - (posterior / prior).powi(2)).clamp(0.0, 1.0)
}

/// Fill each parameter's tolerance and its information from the data, from
/// the posterior covariance `unit` (in `free` order) its standard deviation
/// comes from ([`super::uncertainty::apply_scale`]); a constraint's is 0.
pub(super) fn annotate(
    parameters: &mut [ParameterResult],
    terms: &[PriorTerm],
    free: &[usize],
    unit: &DMatrix<f64>,
) {
    for t in terms {
        let p = &mut parameters[t.index];
        p.tolerance = Some(t.sigma);
        p.from_data = if t.constraint {
            Some(0.0)
        } else {
            free.iter()
                .position(|&f| f == t.index)
                .map(|k| information_from_data(unit[(k, k)].max(0.0).sqrt(), t.sigma))
                .filter(|v| v.is_finite())
        };
    }
}

/// The warnings of a fit with priors: each value beyond
/// [`BEYOND_TOLERANCES`] of its tolerances from its prior's centre, and the
/// parameters the data taught little ([`TAUGHT_LITTLE`]).
pub(super) fn prior_warnings(parameters: &[ParameterResult], terms: &[PriorTerm]) -> Vec<Warning> {
    let mut out = vec![];
    for t in terms {
        let p = &parameters[t.index];
        if p.free && (p.identified - t.centre).abs() > BEYOND_TOLERANCES * t.sigma {
            out.push(Warning::new(WarningKind::BeyondTolerance {
                name: t.name.clone(),
                value: p.identified,
                centre: t.centre,
                tolerance: t.sigma,
                unit: p.unit,
            }));
        }
    }
    let little: Vec<(String, f64)> = terms
        .iter()
        .filter(|t| !t.constraint)
        .filter_map(|t| {
            let p = &parameters[t.index];
            p.from_data
                .filter(|f| *f < 1.0 - TAUGHT_LITTLE * TAUGHT_LITTLE)
                .map(|f| (t.name.clone(), f))
        })
        .collect();
    if !little.is_empty() {
        out.push(Warning::new(WarningKind::PriorDominated {
            parameters: little,
        }));
    }
    out
}

/// A tolerance frees its parameter unless the fix list names it: the free
/// set `set` ([`crate::identify::resolve_free_set`]'s) with the parameters
/// of `priors` added, but those named in `fix` and the instrument frame's
/// (the frame choice frees or fixes them), in index order.
pub fn free_with_priors(
    spec: &Spec,
    measurement: &MeasurementModel,
    set: &[usize],
    priors: &[Prior],
    fix: &[String],
) -> Vec<usize> {
    let np = spec.n_params();
    let fixed: Vec<usize> = fix
        .iter()
        .filter_map(|n| measurement.index_of(spec, n.trim()).ok())
        .collect();
    let mut out = set.to_vec();
    out.extend(
        priors
            .iter()
            .map(|p| p.index)
            .filter(|&i| !fixed.contains(&i) && !measurement.frame_range().any(|f| np + f == i)),
    );
    out.sort_unstable();
    out.dedup();
    out
}
