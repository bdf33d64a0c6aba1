//! Weights: the fit repeated with noise levels re-estimated per noise group
//! (variance-component estimation) until they settle.

use super::driver::{CalibrationOptions, calibrate_once};
use super::loss::{Loss, MAX_REWEIGHTS, find_outliers, group_scales, standardized};
use super::problem::IdentificationProblem;
use super::result::{Calibration, Warning, WarningKind};
use super::uncertainty::{Scale, apply_scale};
use crate::error::Result;
use crate::identify::noise::{
    NoiseModel, VCE_MAX_ROUNDS, VCE_TOL, by_row_blocks, covariance_by_rows, factor_by_rows,
    is_large, leverages, leverages_by_rows, leverages_with,
};
use crate::lm;
use crate::measurement::data::Measurement;
use crate::mechanism::{Mechanism, Params};
use nalgebra::{DMatrix, DVector};

/// One weighted fit: noise groups estimated, robust reweighting, outliers.
pub(super) fn calibrate_weighted<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    let measurement = problem.measurement;
    let noise = NoiseModel::new(data, measurement);
    let mut noise = noise.with_stated(
        opts.stated_noise,
        opts.stated_distance_noise,
        opts.stated_noise_readings,
        opts.stated_noise_relative,
    );
    // One estimated group and nothing given, without priors: the weights
    // are uniform whatever its σ (below); the fit alone with the squared
    // loss and no outlier dropped then reads no covariance.
    let one_group = noise.estimated_groups() == 1 && !noise.any_given();
    let unread = opts.fit_only
        && opts.loss == Loss::Squared
        && !opts.drop_outliers
        && one_group
        && opts.priors.is_empty();
    // `(JᵀJ)⁺` of `cal.jacobian` (the fit's own, for the leverages) while
    // that Jacobian is the fit's.
    let (mut cal, cov) = calibrate_once(
        problem,
        data,
        start,
        None,
        opts,
        &noise.sigmas(),
        None,
        None,
        None,
        !unread,
    )?;
    // The free set and identifiability of the first fit hold for the refits.
    let mut refit_opts = opts.clone();
    refit_opts.auto_fix = false;
    let mut cov = Some(cov);
    let refit = |cal: &Calibration, sigma: &[f64]| -> Result<(Calibration, DMatrix<f64>)> {
        let (mut next, cov) = calibrate_once(
            problem,
            data,
            &cal.params,
            Some(&cal.measurement),
            &refit_opts,
            sigma,
            Some(&cal.free),
            Some(&cal.identifiability),
            Some(&cal.priors),
            true,
        )?;
        next.identifiability = cal.identifiability.clone();
        for (p, first) in next.parameters.iter_mut().zip(&cal.parameters) {
            p.note = first.note.clone();
        }
        // Identifiability warnings from the first fit, the solver's from
        // this one.
        let solver_kind = |w: &Warning| {
            matches!(
                w.kind,
                WarningKind::NotConverged { .. } | WarningKind::RankDeficient { .. }
            )
        };
        let mut warnings: Vec<Warning> = cal
            .warnings
            .iter()
            .filter(|w| !solver_kind(w))
            .cloned()
            .collect();
        warnings.extend(next.warnings.drain(..).filter(solver_kind));
        next.warnings = warnings;
        Ok((next, cov))
    };
    let lev = |cal: &Calibration, cov: &Option<DMatrix<f64>>| match cov {
        Some(c) => leverages_with(&cal.jacobian, c),
        None => leverages(&cal.jacobian),
    };
    if noise.estimated_groups() > 0 {
        // One estimated group and nothing given: the weights are uniform
        // whatever its σ, so one estimate after the fit is exact (not with
        // priors, whose weights are known: the group's σ moves the fit).
        let uniform = one_group && cal.priors.is_empty();
        // (The fit alone skips it with the squared loss and no outlier
        // dropped: the σ then weigh nothing after this fit.)
        let unused = opts.fit_only && opts.loss == Loss::Squared && !opts.drop_outliers;
        if uniform {
            if !unused {
                let h = lev(&cal, &cov);
                noise.update(&cal.residuals, &h);
                rescale(&mut cal, &noise.sigmas());
            }
            cov = None;
        } else {
            // Iterate the estimates on the fit linearised at the current
            // solution (the reweighted solution moves by a fraction of the
            // noise, where the problem is linear), then refit once with them;
            // repeat while the refit still moves the estimates.
            for _ in 0..VCE_MAX_REFITS {
                linearized_vce(&mut noise, &cal);
                // (The refit does not read the Jacobian: freed before it
                // makes its own.)
                cal.jacobian = DMatrix::zeros(0, 0);
                let (next, c) = refit(&cal, &noise.sigmas())?;
                (cal, cov) = (next, Some(c));
                let mut check = noise.clone();
                if check.update(&cal.residuals, &lev(&cal, &cov)) < VCE_TOL {
                    break;
                }
            }
        }
    }
    let base = noise.sigmas();
    let keys = noise.keys();
    // Each reading's σ over the σ it was weighed with: a robust loss's
    // group scale for the estimated groups (1 otherwise).
    let mut factor = vec![];
    if opts.loss != Loss::Squared {
        let mut robust = vec![1.0; base.len()];
        for _ in 0..MAX_REWEIGHTS {
            let u = standardized(&cal.residuals, &base, &keys);
            let next: Vec<f64> = u.iter().map(|ui| opts.loss.weight(*ui)).collect();
            let change = next
                .iter()
                .zip(&robust)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            robust = next;
            let sigma: Vec<f64> = base
                .iter()
                .zip(&robust)
                .map(|(s, w)| s / w.max(f64::MIN_POSITIVE).sqrt())
                .collect();
            cal.jacobian = DMatrix::zeros(0, 0);
            let (next, c) = refit(&cal, &sigma)?;
            (cal, cov) = (next, Some(c));
            if change < 1e-3 {
                break;
            }
        }
        // Report robust noise levels: the outliers must not inflate them.
        let scales = group_scales(&cal.residuals, &base, &keys);
        for (g, s) in noise.sigma.iter_mut().enumerate() {
            if let Some(f) = scales.get(&g).filter(|f| **f > 0.0) {
                *s *= f;
            }
        }
        let estimated = noise.estimated_groups();
        factor = keys
            .iter()
            .map(|k| {
                scales
                    .get(k)
                    .filter(|f| *k < estimated && **f > 0.0)
                    .copied()
                    .unwrap_or(1.0)
            })
            .collect();
    }
    // The fit alone: outliers only where they are dropped.
    if opts.fit_only && !opts.drop_outliers {
        return Ok(cal);
    }
    // Studentised: a pose that pulls the fit towards itself (high leverage)
    // shows a small residual for a large error.
    let h = lev(&cal, &cov);
    let student: Vec<f64> = base
        .iter()
        .zip(&h)
        .map(|(s, hi)| s * (1.0 - hi).max(1e-6).sqrt())
        .collect();
    let u = standardized(&cal.residuals, &student, &keys);
    cal.outliers = find_outliers(
        measurement,
        data,
        &cal.residuals,
        &u,
        opts.outlier_threshold,
    );
    if opts.fit_only {
        return Ok(cal);
    }
    cal.noise = noise.report(&cal.residuals);
    cal.loss = opts.loss;
    // The one scale rule (docs/model.md §6): the covariance at the final σ.
    let scale = Scale::of(&cal.noise);
    apply_scale(&mut cal, scale, &factor);
    Ok(cal)
}

/// Refits of the noise estimation (each after a linearised estimation).
const VCE_MAX_REFITS: usize = 4;

/// Variance-component estimation on the fit linearised at `cal`'s solution:
/// residuals `r0 + J δp(σ)` with `δp` the weighted least-squares step under
/// the current σ (the priors' rows, of known σ, included), iterated until
/// the σ settle. Only the readings' residuals and leverages estimate the
/// noise.
fn linearized_vce(noise: &mut NoiseModel, cal: &Calibration) {
    if is_large(&cal.jacobian) {
        return linearized_vce_by_rows(noise, cal);
    }
    // Unweighted Jacobian of the free parameters.
    let mut j = cal.jacobian.clone();
    lm::scale_rows(&mut j, &cal.sigmas);
    let r0 = DVector::from_column_slice(&cal.residuals);
    let (m, k) = (j.nrows(), cal.priors.len());
    // The priors' weighted rows and residuals.
    let mut prior_j = DMatrix::zeros(k, j.ncols());
    let mut prior_r = DVector::zeros(k);
    for (a, t) in cal.priors.iter().enumerate().filter(|(_, t)| !t.constraint) {
        if let Some(c) = cal.free.iter().position(|&f| f == t.index) {
            prior_j[(a, c)] = 1.0 / t.sigma;
        }
        prior_r[a] = (cal.parameters[t.index].identified - t.centre) / t.sigma;
    }
    for _ in 0..VCE_MAX_ROUNDS {
        let s = noise.sigmas();
        let mut jw = j.clone();
        let mut rw = r0.clone();
        lm::unscale_rows(&mut jw, &s);
        for (ri, si) in rw.iter_mut().zip(&s) {
            *ri /= si;
        }
        if k > 0 {
            jw = jw.resize_vertically(m + k, 0.0);
            jw.rows_mut(m, k).copy_from(&prior_j);
            rw = rw.resize_vertically(m + k, 0.0);
            rw.rows_mut(m, k).copy_from(&prior_r);
        }
        let (c, _) = lm::covariance(&jw, lm::COVARIANCE_RANK_TOL);
        let step = -(&c * (jw.transpose() * &rw));
        let r = &r0 + &j * &step;
        // The readings' leverages (each row's alone: the priors' follow).
        let mut h = leverages_with(&jw, &c);
        h.truncate(m);
        if noise.update(r.as_slice(), &h) < VCE_TOL {
            break;
        }
    }
}

/// Scale a calibration's weighted quantities to new uniform-ratio σ: the
/// solution is unchanged (all weights scale alike), the statistics follow.
fn rescale(cal: &mut Calibration, sigma: &[f64]) {
    let f = sigma
        .first()
        .map_or(1.0, |s| cal.sigmas.first().map_or(1.0, |o| o / s));
    cal.sum_of_squares *= f * f;
    cal.unit_weight_sigma *= f;
    cal.jacobian.scale_mut(f);
    cal.sigmas = sigma.to_vec();
}

/// [`linearized_vce`] of a large Jacobian, row by row: the same estimates
/// without its copies (its rows rescaled as they are read).
fn linearized_vce_by_rows(noise: &mut NoiseModel, cal: &Calibration) {
    let (m, n) = cal.jacobian.shape();
    let r0 = &cal.residuals;
    let k = cal.priors.len();
    let mut prior_j = DMatrix::zeros(k, n);
    let mut prior_r = DVector::zeros(k);
    for (a, t) in cal.priors.iter().enumerate().filter(|(_, t)| !t.constraint) {
        if let Some(c) = cal.free.iter().position(|&f| f == t.index) {
            prior_j[(a, c)] = 1.0 / t.sigma;
        }
        prior_r[a] = (cal.parameters[t.index].identified - t.centre) / t.sigma;
    }
    for _ in 0..VCE_MAX_ROUNDS {
        let s = noise.sigmas();
        // Row `i` of the Jacobian weighted by the new σ: the fit's weighted
        // row times σ_fit / σ.
        let ratio: Vec<f64> = cal.sigmas.iter().zip(&s).map(|(a, b)| a / b).collect();
        // (JᵀJ)⁺ of the readings' rows and the priors'.
        let c = if k == 0 {
            covariance_by_rows(&cal.jacobian, Some(&ratio))
        } else {
            let r = factor_by_rows(&cal.jacobian, Some(&ratio));
            let mut stacked = DMatrix::zeros(n + k, n);
            stacked.rows_mut(0, n).copy_from(&r);
            stacked.rows_mut(n, k).copy_from(&prior_j);
            lm::covariance(&stacked, lm::COVARIANCE_RANK_TOL).0
        };
        // Jᵀ r (weighted), the readings' then the priors'.
        let mut g = DVector::zeros(n);
        by_row_blocks(&cal.jacobian, Some(&ratio), |start, rows| {
            for (t, row) in rows.chunks_exact(n).enumerate() {
                let rw = r0[start + t] / s[start + t];
                for (gk, v) in g.iter_mut().zip(row) {
                    *gk += v * rw;
                }
            }
        });
        if k > 0 {
            g += prior_j.transpose() * &prior_r;
        }
        let step = -(&c * g);
        // r = r0 + J step (unweighted J: the fit's row times σ_fit).
        let mut r = vec![0.0; m];
        by_row_blocks(&cal.jacobian, Some(&cal.sigmas), |start, rows| {
            for (t, row) in rows.chunks_exact(n).enumerate() {
                let d: f64 = row.iter().zip(step.iter()).map(|(a, b)| a * b).sum();
                r[start + t] = r0[start + t] + d;
            }
        });
        let h = leverages_by_rows(&cal.jacobian, Some(&ratio), &c);
        if noise.update(&r, &h) < VCE_TOL {
            break;
        }
    }
}
