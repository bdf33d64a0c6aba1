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

/// The largest relative tolerance, as a fraction of the nominal value
/// (10,000 %: a σ a hundred times the value itself says nothing more).
pub const MAX_RELATIVE_TOLERANCE: f64 = 100.0;

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
        match tol {
            // A percentage too large: the range said, with what was typed.
            Tolerance::Relative(f) if f.is_finite() && f > 0.0 => tol.check()?,
            _ => tol.check().map_err(|_| bad())?,
        }
        Ok(tol)
    }

    /// A tolerance's number in range: positive and finite, a percentage at
    /// most [`MAX_RELATIVE_TOLERANCE`] times the nominal value (a larger
    /// one is a typing error: `1e308%` would make σ infinite).
    fn check(&self) -> Result<()> {
        match *self {
            Tolerance::Absolute(v) if v.is_finite() && v > 0.0 => Ok(()),
            Tolerance::Absolute(v) => Err(Error::InvalidRequest(format!(
                "a tolerance must be a positive finite number, got {}",
                crate::error::shown(v)
            ))),
            Tolerance::Relative(f) if f.is_finite() && f > 0.0 && f <= MAX_RELATIVE_TOLERANCE => {
                Ok(())
            }
            Tolerance::Relative(f) => Err(Error::InvalidRequest(format!(
                "a tolerance of {} % of the nominal value is out of range: a percentage must be positive and at most {} %",
                crate::error::shown(f * 100.0),
                MAX_RELATIVE_TOLERANCE * 100.0
            ))),
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
        if let Tolerance::Relative(f) = tol {
            // σ from a percentage: the percentage and the nominal value
            // named with it, not a σ the user never typed.
            check_sigma(name, sigma, unit(i)).map_err(|_| {
                Error::InvalidRequest(format!(
                    "tolerance of `{name}`: {} % of its nominal {} {} is a σ of {} {}, out of range (positive and at most {:e} {})",
                    crate::error::shown(f * 100.0),
                    crate::error::shown(nominal(i)),
                    unit(i),
                    crate::error::shown(sigma),
                    unit(i),
                    unit(i).max_magnitude(),
                    unit(i)
                ))
            })?;
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
    /// The value the data choose with it and every other prior in
    /// conflict released (the data see at least [`SEEN_SHARE`] of what is
    /// known of it, or it is not tested).
    pub data_value: Option<f64>,
    /// That value's standard deviation.
    pub data_sd: Option<f64>,
}

/// A prior the data see less than this share of is not tested for
/// conflict ([`prior_conflicts`]): the data hardly see its parameter, and
/// cannot push against it.
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

/// Priors in conflict are named while the next one's release is below
/// this familywise level (Holm over the priors the data see): with right
/// tolerances, one fit in a thousand names one.
pub const CONFLICT_ALPHA: f64 = 1e-3;

/// The fit linearised at its solution, in the free parameters: the
/// readings' information `JᵀJ` and gradient `Jᵀr` (weighted by their final
/// σ), and each prior of a free parameter (its column, weight `1/σ²`,
/// `p̂ − μ`).
struct Linearised {
    information: DMatrix<f64>,
    gradient: DVector<f64>,
    priors: Vec<(usize, f64, f64)>,
}

impl Linearised {
    fn of(cal: &super::result::Calibration) -> Self {
        let j = &cal.jacobian;
        let r = DVector::from_iterator(
            j.nrows(),
            cal.residuals.iter().zip(&cal.sigmas).map(|(r, s)| r / s),
        );
        let priors = cal
            .priors
            .iter()
            .filter(|t| !t.constraint)
            .filter_map(|t| {
                let k = cal.free.iter().position(|&f| f == t.index)?;
                Some((
                    k,
                    1.0 / (t.sigma * t.sigma),
                    cal.parameters[t.index].identified - t.centre,
                ))
            })
            .collect();
        Linearised {
            information: j.transpose() * j,
            gradient: j.transpose() * r,
            priors,
        }
    }

    /// With the priors `released` (indices into `priors`) left out: the
    /// step from the solution to the new minimum and the inverse of the
    /// new information, or `None` where it is singular.
    fn released(&self, released: &[usize]) -> Option<(DVector<f64>, DMatrix<f64>)> {
        let mut h = self.information.clone();
        let mut g = self.gradient.clone();
        for (a, &(k, w, e)) in self.priors.iter().enumerate() {
            if !released.contains(&a) {
                h[(k, k)] += w;
                g[k] += w * e;
            }
        }
        // Scaled to a unit diagonal: mm, rad and N/mm meet here.
        let n = h.nrows();
        let d: Vec<f64> = (0..n)
            .map(|k| 1.0 / h[(k, k)].max(f64::MIN_POSITIVE).sqrt())
            .collect();
        let hs = DMatrix::from_fn(n, n, |a, b| h[(a, b)] * d[a] * d[b]);
        let inv_s = hs.cholesky()?.inverse();
        let inv = DMatrix::from_fn(n, n, |a, b| inv_s[(a, b)] * d[a] * d[b]);
        let step = -(&inv * g);
        step.iter().all(|v| v.is_finite()).then_some((step, inv))
    }
}

/// The priors the data push against (docs/model.md eq. 13, "Priors in
/// conflict"), on the fit linearised at its solution: the prior whose
/// release lowers `Σ (r/σ)²` most (its row's score statistic
/// `e² / (1 − h)`, `e` its standardised residual and `h` its leverage) is
/// released while that drop is significant (χ² with one degree of freedom,
/// or F(1, ν) for an estimated σ; Holm at [`CONFLICT_ALPHA`] over the
/// priors the data see at least [`SEEN_SHARE`] of), and the next is judged
/// with it released. Each with the value the data choose for it, and its
/// standard deviation, with every prior in conflict released; also that
/// solution, in `free` order.
pub fn prior_conflicts(cal: &super::result::Calibration) -> (Vec<PriorConflict>, DVector<f64>) {
    let lin = Linearised::of(cal);
    let n = cal.free.len();
    let mut released: Vec<usize> = vec![];
    let mut out = vec![];
    let Some((mut step, mut inv)) = lin.released(&[]) else {
        return (vec![], DVector::zeros(n));
    };
    let seen = |inv: &DMatrix<f64>, k: usize, w: f64| 1.0 - w * inv[(k, k)];
    let testable = lin
        .priors
        .iter()
        .filter(|&&(k, w, _)| seen(&inv, k, w) >= SEEN_SHARE)
        .count();
    loop {
        let best = lin
            .priors
            .iter()
            .enumerate()
            .filter(|(a, _)| !released.contains(a))
            .filter_map(|(a, &(k, w, e))| {
                let share = seen(&inv, k, w);
                (share >= SEEN_SHARE).then(|| (a, w * (e + step[k]).powi(2) / share))
            })
            .max_by(|x, y| x.1.total_cmp(&y.1));
        let Some((a, statistic)) = best else {
            break;
        };
        let p_value = cal.scale.quadratic_tail(statistic, 1.0);
        let left = testable.saturating_sub(released.len()).max(1);
        if p_value.is_nan() || p_value >= CONFLICT_ALPHA / left as f64 {
            break;
        }
        released.push(a);
        let Some((s, i)) = lin.released(&released) else {
            released.pop();
            break;
        };
        (step, inv) = (s, i);
        let (k, _, _) = lin.priors[a];
        let i = cal.free[k];
        let t = cal
            .priors
            .iter()
            .find(|t| t.index == i)
            .expect("a prior of this parameter");
        out.push((
            k,
            PriorConflict {
                name: t.name.clone(),
                unit: cal.parameters[i].unit,
                centre: t.centre,
                tolerance: t.sigma,
                statistic,
                p_value,
                data_value: None,
                data_sd: None,
            },
        ));
    }
    // The values the data choose with every prior in conflict released.
    let out = out
        .into_iter()
        .map(|(k, mut c)| {
            c.data_value = Some(cal.parameters[cal.free[k]].identified + step[k]);
            c.data_sd = Some(inv[(k, k)].max(0.0).sqrt());
            c
        })
        .collect();
    let values = DVector::from_iterator(
        n,
        cal.free
            .iter()
            .enumerate()
            .map(|(k, &i)| cal.parameters[i].identified + step[k]),
    );
    (out, values)
}

/// The warnings of a fit with priors: the priors in conflict with the data
/// ([`prior_conflicts`], kept in the calibration), each value beyond
/// [`BEYOND_TOLERANCES`] of its tolerances from its prior's centre with the
/// conflict that most likely explains it, and the parameters the data
/// taught little ([`TAUGHT_LITTLE`]).
pub(super) fn prior_warnings(cal: &mut super::result::Calibration) -> Vec<Warning> {
    let mut out = vec![];
    if cal.priors.iter().all(|t| t.constraint) {
        return out;
    }
    let (conflicts, released) = prior_conflicts(cal);
    let lin = Linearised::of(cal);
    let named: Vec<usize> = conflicts
        .iter()
        .map(|c| {
            lin.priors
                .iter()
                .position(|&(k, _, _)| cal.parameters[cal.free[k]].name == c.name)
                .expect("a prior in conflict is a prior")
        })
        .collect();
    if !conflicts.is_empty() {
        out.push(Warning::new(WarningKind::PriorConflict {
            conflicts: conflicts.clone(),
        }));
    }
    for t in cal.priors.iter().filter(|t| !t.constraint) {
        let p = &cal.parameters[t.index];
        let far = |v: f64| (v - t.centre).abs() > BEYOND_TOLERANCES * t.sigma;
        if !(p.free && far(p.identified)) {
            continue;
        }
        let conflict = conflicts.iter().any(|c| c.name == t.name);
        let k = cal.free.iter().position(|&f| f == t.index);
        let value = k.map(|k| released[k]);
        // The conflict whose prior, restored alone, takes it farthest.
        let explained_by = match (conflict, k, value) {
            (false, Some(k), Some(v)) if !far(v) && !named.is_empty() => named
                .iter()
                .zip(&conflicts)
                .filter_map(|(a, c)| {
                    let others: Vec<usize> = named.iter().copied().filter(|b| b != a).collect();
                    let (s, _) = lin.released(&others)?;
                    Some(((p.identified + s[k] - t.centre).abs(), c.name.clone()))
                })
                .max_by(|x, y| x.0.total_cmp(&y.0))
                .map(|(_, n)| n),
            _ => None,
        };
        out.push(Warning::new(WarningKind::BeyondTolerance {
            name: t.name.clone(),
            value: p.identified,
            centre: t.centre,
            tolerance: t.sigma,
            unit: p.unit,
            conflict,
            released: explained_by.as_ref().and(value),
            explained_by,
        }));
    }
    cal.prior_conflicts = conflicts;
    let little: Vec<(String, f64)> = cal
        .priors
        .iter()
        .filter(|t| !t.constraint)
        .filter_map(|t| {
            let p = &cal.parameters[t.index];
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
