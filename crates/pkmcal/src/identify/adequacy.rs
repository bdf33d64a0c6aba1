//! The model-adequacy test (docs/model.md §6): residuals larger than the
//! instrument's stated noise can explain mean the model misses something.
//! Each group of readings with a stated σ₀ is tested, `Σ r² / σ₀²` against
//! χ² with the group's redundancy `Σ (1 − h)`; a fit whose σ are all given
//! in the data, `Σ (r/σ)²` against χ² with the fit's redundancy. When a
//! test fails, the parameters left out of the fit are ranked by how much of
//! the weighted residual freeing each would remove (the score test: the
//! squared projection of the residuals on its Jacobian column, orthogonal
//! to the free columns, over that column's squared norm).

use super::identifiability::Columns;
use super::problem::IdentificationProblem;
use super::result::{Calibration, Warning, WarningKind};
use crate::error::Result;
use crate::mechanism::Mechanism;
use nalgebra::{DMatrix, DVector};

/// A test below this p-value says the model misses something: one in a
/// thousand well-modelled fits is flagged.
pub const ADEQUACY_ALPHA: f64 = 1e-3;

/// Parameters named as the likely missing ones, at most.
pub const SUSPECTS: usize = 5;

/// A parameter is named when freeing it would remove at least this share of
/// the weighted sum of squares.
pub const SUSPECT_SHARE: f64 = 0.05;

/// The χ² upper tail `P(X ≥ x)` with `dof` degrees of freedom.
fn chi2_tail(x: f64, dof: f64) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    ChiSquared::new(dof).map_or(f64::NAN, |c| c.sf(x))
}

/// The adequacy warning of a finished fit, if a test fails.
pub(super) fn adequacy<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    cal: &Calibration,
) -> Result<Option<Warning>> {
    // The worst failing test (lowest p).
    let mut worst: Option<(f64, WarningKind)> = None;
    let mut keep = |p: f64, kind: WarningKind| {
        if p < ADEQUACY_ALPHA && worst.as_ref().is_none_or(|w| p < w.0) {
            worst = Some((p, kind));
        }
    };
    for g in &cal.noise {
        let (Some(s0), Some(red)) = (g.stated, g.redundancy) else {
            continue;
        };
        if red < 1.0 || g.count == 0 || g.stated_relative {
            continue;
        }
        let ss = g.residual_rms.powi(2) * g.count as f64;
        let p = chi2_tail(ss / (s0 * s0), red);
        keep(
            p,
            WarningKind::ModelInadequate {
                unit: g.unit,
                axes: g.axes.clone(),
                found: (ss / red).sqrt(),
                stated: s0,
                given: false,
                p,
                suspects: vec![],
            },
        );
    }
    if !cal.noise.is_empty() && cal.noise.iter().all(|g| !g.estimated) {
        let dof = (cal.residuals.len() + cal.priors.len()).saturating_sub(cal.free.len());
        if dof > 0 {
            let p = chi2_tail(cal.sum_of_squares, dof as f64);
            keep(
                p,
                WarningKind::ModelInadequate {
                    unit: cal.noise[0].unit,
                    axes: vec![],
                    found: cal.unit_weight_sigma,
                    stated: 1.0,
                    given: true,
                    p,
                    suspects: vec![],
                },
            );
        }
    }
    let Some((_, mut kind)) = worst else {
        return Ok(None);
    };
    if let WarningKind::ModelInadequate { suspects: s, .. } = &mut kind {
        *s = suspects(problem, cal)?;
    }
    Ok(Some(Warning::new(kind)))
}

/// The parameters left out of the fit that would explain most of its
/// weighted residual, with the share each would remove (largest first).
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
    let r = DVector::from_iterator(m, cal.residuals.iter().zip(&cal.sigmas).map(|(r, s)| r / s));
    let total = r.norm_squared();
    if total.is_nan() || total <= 0.0 || jac.iter().any(|v| !v.is_finite()) {
        return Ok(vec![]);
    }
    let free = jac.select_columns(&cal.free);
    let q: DMatrix<f64> = if free.ncols() > 0 {
        free.qr().q()
    } else {
        DMatrix::zeros(m, 0)
    };
    let cols =
        Columns::with_measurement(problem.mech.spec(), problem.measurement, &cal.measurement);
    let mut out: Vec<(String, f64)> = (0..jac.ncols())
        .filter(|j| !cal.free.contains(j))
        .filter_map(|j| {
            let c = jac.column(j).into_owned();
            let perp = &c - &q * (q.transpose() * &c);
            let den = perp.norm_squared();
            (den > 1e-12 * c.norm_squared().max(f64::MIN_POSITIVE))
                .then(|| (cols.names[j].clone(), r.dot(&perp).powi(2) / den / total))
        })
        .filter(|(_, share)| *share >= SUSPECT_SHARE)
        .collect();
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out.truncate(SUSPECTS);
    Ok(out)
}
