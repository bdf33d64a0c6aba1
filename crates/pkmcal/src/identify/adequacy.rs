//! The model-adequacy test (docs/model.md §6), two-sided: residuals larger
//! than the instrument's stated noise can explain mean the model misses
//! something or the noise is understated; residuals well below it mean the
//! noise is overstated. Each group of readings with a stated σ₀ is tested,
//! `Σ r² / σ₀²` against χ² with the group's redundancy `Σ (1 − h)`; a fit
//! whose σ are all given in the data, `Σ (r/σ)²` against χ² with the
//! readings' redundancy. Each tail is judged at half of
//! [`ADEQUACY_ALPHA`].
//!
//! When the residuals are too large, the parameters left out of the fit
//! are tested one at a time against the data's own noise level (the score
//! test by forward selection: the share of the weighted residual each would
//! remove, the squared projection of the residuals on its Jacobian column
//! orthogonal to the free columns over that column's squared norm, judged
//! by Fisher's F against what is left, Bonferroni over those not yet
//! named, at [`SUSPECT_ALPHA`]). The ones it singles out are named; when
//! none is, the misfit is spread like noise and the stated noise is blamed.

use super::identifiability::Columns;
use super::problem::IdentificationProblem;
use super::result::{Calibration, Warning, WarningKind};
use crate::error::Result;
use crate::mechanism::Mechanism;
use crate::units::Unit;
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF, FisherSnedecor};

/// The two-sided test's level: a test below half of it in either tail is
/// a warning. One in a thousand well-modelled fits with a right noise is
/// flagged.
pub const ADEQUACY_ALPHA: f64 = 1e-3;

/// Parameters named as the likely missing ones, at most.
pub const SUSPECTS: usize = 5;

/// A parameter is named only when freeing it would remove at least this
/// share of the weighted sum of squares…
pub const SUSPECT_SHARE: f64 = 0.05;

/// …and its score test singles it out at this familywise level (Bonferroni
/// over the parameters not yet named): a misfit spread like noise names a
/// parameter in at most one fit in a hundred.
pub const SUSPECT_ALPHA: f64 = 0.01;

/// One adequacy test of a fit: a group of readings against its stated σ,
/// or every reading against the σ given in the data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdequacyTest {
    /// Unit of the readings tested.
    pub unit: Unit,
    /// Their axes (`distance` for distances between poses; empty with
    /// `given`: all readings).
    pub axes: Vec<String>,
    /// Whether the σ tested were given in the data (else stated).
    pub given: bool,
    /// The σ the residuals show, `√(Σ r² / ν)` (with `given`: the
    /// readings' standard deviation of unit weight).
    pub found: f64,
    /// The σ tested against (with `given`: 1).
    pub stated: f64,
    /// `Σ r² / σ₀²`.
    pub statistic: f64,
    /// Its degrees of freedom, the readings' redundancy `ν`.
    pub dof: f64,
    /// `P(χ²_ν ≥ statistic)`: small when the residuals exceed the noise.
    pub p_upper: f64,
    /// `P(χ²_ν ≤ statistic)`: small when the noise exceeds the residuals.
    pub p_lower: f64,
}

impl AdequacyTest {
    /// The two-sided p-value, `2 min(p_upper, p_lower)`.
    pub fn p_value(&self) -> f64 {
        (2.0 * self.p_upper.min(self.p_lower)).min(1.0)
    }
}

fn test(
    statistic: f64,
    dof: f64,
    unit: Unit,
    axes: Vec<String>,
    given: bool,
    stated: f64,
) -> AdequacyTest {
    let chi2 = ChiSquared::new(dof).ok();
    AdequacyTest {
        unit,
        axes,
        given,
        found: stated * (statistic / dof).sqrt(),
        stated,
        statistic,
        dof,
        p_upper: chi2.as_ref().map_or(f64::NAN, |c| c.sf(statistic)),
        p_lower: chi2.as_ref().map_or(f64::NAN, |c| c.cdf(statistic)),
    }
}

/// The adequacy tests of a finished fit: each group with an absolute
/// stated σ, and every reading when all σ were given in the data.
pub(super) fn adequacy_tests(cal: &Calibration) -> Vec<AdequacyTest> {
    let mut out = vec![];
    for g in &cal.noise {
        let (Some(s0), Some(red)) = (g.stated, g.redundancy) else {
            continue;
        };
        if red < 1.0 || g.count == 0 || g.stated_relative {
            continue;
        }
        let ss = g.residual_rms.powi(2) * g.count as f64;
        out.push(test(ss / (s0 * s0), red, g.unit, g.axes.clone(), false, s0));
    }
    if !cal.noise.is_empty() && cal.noise.iter().all(|g| !g.estimated) && cal.redundancy >= 1.0 {
        let ss: f64 = cal
            .residuals
            .iter()
            .zip(&cal.sigmas)
            .map(|(r, s)| (r / s).powi(2))
            .sum();
        out.push(test(
            ss,
            cal.redundancy,
            cal.noise[0].unit,
            vec![],
            true,
            1.0,
        ));
    }
    out
}

/// The adequacy warning of a finished fit, if a test fails (the worst):
/// the noise overstated, the noise understated, or the model missing the
/// parameters the score test singles out.
pub(super) fn adequacy<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    cal: &Calibration,
) -> Result<Option<Warning>> {
    let worst = cal
        .adequacy
        .iter()
        .filter(|t| t.p_upper.min(t.p_lower) < 0.5 * ADEQUACY_ALPHA)
        .min_by(|a, b| {
            a.p_upper
                .min(a.p_lower)
                .total_cmp(&b.p_upper.min(b.p_lower))
        });
    let Some(t) = worst else {
        return Ok(None);
    };
    let (unit, axes, found, stated, given) = (t.unit, t.axes.clone(), t.found, t.stated, t.given);
    if t.p_lower < t.p_upper {
        return Ok(Some(Warning::new(WarningKind::NoiseOverstated {
            unit,
            axes,
            found,
            stated,
            given,
            p: t.p_lower,
        })));
    }
    let suspects = suspects(problem, cal)?;
    let p = t.p_upper;
    Ok(Some(Warning::new(if suspects.is_empty() {
        WarningKind::NoiseUnderstated {
            unit,
            axes,
            found,
            stated,
            given,
            p,
        }
    } else {
        WarningKind::ModelInadequate {
            unit,
            axes,
            found,
            stated,
            given,
            p,
            suspects,
        }
    })))
}

/// The parameters left out of the fit that the score test singles out, by
/// forward selection (largest share first, each judged against what the
/// residuals leave after those before it), with the share of the weighted
/// sum of squares each removes.
fn suspects<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    cal: &Calibration,
) -> Result<Vec<(String, f64)>> {
    let x: Vec<f64> = cal
        .params
        .values
        .iter()
        .chain(&cal.measurement)
        .copied()
        .collect();
    let (_, mut jac) = problem.residuals_and_jacobian(&x)?;
    let m = cal.residuals.len();
    for (i, s) in cal.sigmas.iter().enumerate() {
        jac.row_mut(i).unscale_mut(*s);
    }
    let mut r =
        DVector::from_iterator(m, cal.residuals.iter().zip(&cal.sigmas).map(|(r, s)| r / s));
    let total = r.norm_squared();
    if total.is_nan() || total <= 0.0 || jac.iter().any(|v| !v.is_finite()) {
        return Ok(vec![]);
    }
    let free = jac.select_columns(&cal.free);
    let mut q: DMatrix<f64> = if free.ncols() > 0 {
        free.qr().q()
    } else {
        DMatrix::zeros(m, 0)
    };
    let cols =
        Columns::with_measurement(problem.mech.spec(), problem.measurement, &cal.measurement);
    let mut left: Vec<usize> = (0..jac.ncols())
        .filter(|j| !cal.free.contains(j) && !cal.priors.iter().any(|t| t.index == *j))
        .collect();
    let mut ss = total;
    let mut nu = cal.redundancy;
    let mut out = vec![];
    while out.len() < SUSPECTS && !left.is_empty() && nu > 2.0 {
        let best = left
            .iter()
            .enumerate()
            .filter_map(|(k, &j)| {
                let c = jac.column(j).into_owned();
                let perp = &c - &q * (q.transpose() * &c);
                let den = perp.norm_squared();
                (den > 1e-12 * c.norm_squared().max(f64::MIN_POSITIVE))
                    .then(|| (k, r.dot(&perp).powi(2) / den, perp))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((k, t, perp)) = best else {
            break;
        };
        let f = t / ((ss - t).max(f64::MIN_POSITIVE) / (nu - 1.0));
        let p = FisherSnedecor::new(1.0, nu - 1.0).map_or(f64::NAN, |d| d.sf(f));
        let share = t / total;
        if p.is_nan() || p >= SUSPECT_ALPHA / left.len() as f64 || share < SUSPECT_SHARE {
            break;
        }
        let j = left.remove(k);
        out.push((cols.names[j].clone(), share));
        // Project it out: the next is judged on what is left.
        let unit = &perp / perp.norm();
        r -= &unit * unit.dot(&r);
        let last = q.ncols();
        q = q.insert_column(last, 0.0);
        q.set_column(last, &unit);
        ss -= t;
        nu -= 1.0;
    }
    Ok(out)
}

/// The level of [`omitted_test`]: parameters a fit left out are said to be
/// seen by the data when their joint score test is below it (one fit in a
/// hundred whose left-out parameters are truly nominal is flagged).
pub const OMITTED_ALPHA: f64 = 0.01;

/// The joint score test of parameters a fit left out ([`omitted_test`]):
/// whether the data show them, what they show, and where the fit put it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OmittedTest {
    /// The parameters tested (indices of the identification vector).
    pub indices: Vec<usize>,
    /// The values the data give them: one Gauss–Newton step from the fit
    /// with them freed (the free parameters refitted beside them).
    pub values: Vec<f64>,
    /// The change that step makes to the free parameters, in
    /// [`Calibration::free`] order: what the fit put into them instead.
    pub free_shift: Vec<f64>,
    /// The share of the readings' weighted sum of squares they would
    /// remove.
    pub share: f64,
    /// Fisher's F of that share against what is left.
    pub f: f64,
    /// Its degrees of freedom: the directions tested, and the readings'
    /// redundancy less them.
    pub dof: (f64, f64),
    /// `P(F ≥ f)`: small when the data show them.
    pub p: f64,
}

/// The joint score test of the parameters `candidates` that `cal` left
/// out (those it freed are skipped): the squared projection of the weighted
/// residuals on their Jacobian columns orthogonal to the free ones, judged
/// by Fisher's F against what the residuals leave (the data's own noise
/// level, so a stated scale does not enter), with the value one step of
/// the fit with them freed would give them. `None` when nothing is left to
/// test, the data cannot see them, or the readings have no redundancy to
/// judge by.
pub fn omitted_test<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    cal: &Calibration,
    candidates: &[usize],
) -> Result<Option<OmittedTest>> {
    let x: Vec<f64> = cal
        .params
        .values
        .iter()
        .chain(&cal.measurement)
        .copied()
        .collect();
    let cands: Vec<usize> = candidates
        .iter()
        .copied()
        .filter(|j| !cal.free.contains(j) && *j < x.len())
        .collect();
    let m = cal.residuals.len();
    if cands.is_empty() || problem.n_readings() != m || m != cal.sigmas.len() {
        return Ok(None);
    }
    let (_, mut jac) = problem.residuals_and_jacobian(&x)?;
    for (i, s) in cal.sigmas.iter().enumerate() {
        jac.row_mut(i).unscale_mut(*s);
    }
    let r = DVector::from_iterator(m, cal.residuals.iter().zip(&cal.sigmas).map(|(r, s)| r / s));
    let ss = r.norm_squared();
    if !ss.is_finite() || jac.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    let free = jac.select_columns(&cal.free);
    let q: DMatrix<f64> = if free.ncols() > 0 {
        free.clone().qr().q()
    } else {
        DMatrix::zeros(m, 0)
    };
    let c = jac.select_columns(&cands);
    let perp = &c - &q * (q.transpose() * &c);
    // The directions of the left-out columns the free ones do not already
    // span: a column the fit's own parameters take whole is no test.
    let svd = perp.clone().svd(true, true);
    let top = svd.singular_values.max();
    let scale = c.column_iter().map(|c| c.norm()).fold(0.0, f64::max);
    if top.is_nan() || top <= OMITTED_RANK_TOL * scale {
        return Ok(None);
    }
    let eps = OMITTED_RANK_TOL * scale.max(top);
    let k = svd.singular_values.iter().filter(|s| **s > eps).count() as f64;
    let nu = cal.redundancy - k;
    if nu < 1.0 {
        return Ok(None);
    }
    let step = -svd
        .solve(&r, eps)
        .map_err(|e| crate::error::Error::InvalidRequest(format!("the score test's step: {e}")))?;
    let fitted = &perp * &step;
    let t = ss - (&r + &fitted).norm_squared();
    let f = (t / k) / ((ss - t).max(0.0) / nu);
    let p = if f.is_infinite() {
        0.0
    } else {
        FisherSnedecor::new(k, nu).map_or(f64::NAN, |d| d.sf(f))
    };
    // The free parameters' part of the same step, `(J_fᵀJ_f)⁻¹J_fᵀ C δ`
    // (the residuals are orthogonal to the free columns at the fit).
    let free_shift = if free.ncols() > 0 {
        let moved = &c * &step;
        free.svd(true, true)
            .solve(&moved, 0.0)
            .map(|s| s.iter().map(|v| -v).collect())
            .unwrap_or_else(|_| vec![f64::NAN; cal.free.len()])
    } else {
        vec![]
    };
    Ok(Some(OmittedTest {
        values: cands
            .iter()
            .zip(step.iter())
            .map(|(j, d)| x[*j] + d)
            .collect(),
        indices: cands,
        free_shift,
        share: if ss > 0.0 { t / ss } else { 0.0 },
        f,
        dof: (k, nu),
        p,
    }))
}

/// Singular values of the left-out columns (orthogonal to the free ones)
/// below this share of the largest column's norm are directions the data
/// cannot see.
const OMITTED_RANK_TOL: f64 = 1e-8;
