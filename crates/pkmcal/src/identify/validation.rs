//! Validation: before/after accuracy on the calibration poses or unseen
//! ones, hold-out splits and k-fold cross-validation.

use super::driver::{CalibrationOptions, calibrate};
use super::problem::{IdentificationProblem, PoseCache};
use super::result::{Calibration, FinalPredictions};
use crate::engine::models::Model;
use crate::error::{Error, Result};
use crate::identify::stats::{ErrorStats, error_stats, improvement_percent};
use crate::measurement::data::{Measurement, numbered};
use crate::measurement::{Frame, MeasurementModel};
use crate::mechanism::{Mechanism, Params};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use serde::Serialize;

/// Before and after statistics of a data set.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
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
    /// Errors of the distances measured between two poses, when the data
    /// hold any (the statistics above are of the other rows).
    pub distances: Option<DistanceAccuracy>,
}

/// Errors of distances measured between two poses (mm): measured minus
/// predicted, before (nominal parameters) and after calibration.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct DistanceAccuracy {
    /// Number of distances.
    pub count: usize,
    /// Root mean square error before (mm).
    pub before_rms: f64,
    /// Largest absolute error before (mm).
    pub before_max: f64,
    /// Root mean square error after (mm).
    pub after_rms: f64,
    /// Largest absolute error after (mm).
    pub after_max: f64,
    /// Each distance's error before, in data order (mm).
    pub before: Vec<f64>,
    /// Each distance's error after (mm).
    pub after: Vec<f64>,
}

/// Error vectors (measured minus reference), one per pose, mm.
pub type ErrorVectors = Vec<Vec<f64>>;

/// Errors of `data` before (nominal) and after (calibrated: the
/// mechanism's `params` and the measurement model's `m`) with `model`.
///
/// Readings of the whole tool are compared in the base frame: after
/// calibration the readings are taken to the base by the identified frame;
/// before, by the frame that best registers them onto the targets (or the
/// nominal predictions), as a metrologist compares an uncalibrated machine.
/// Other readings (target points, bar lengths, a subset of axes) are compared
/// as read; before calibration against the model's nominal values, the frame
/// registered.
pub fn accuracy<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    m: &[f64],
    model: Model,
    force: &[f64],
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    accuracy_cached(mech, measurement, data, params, m, model, force, None, None)
}

/// [`accuracy`] with the poses prepared in `cache`.
#[allow(clippy::too_many_arguments)]
fn accuracy_cached<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    m: &[f64],
    model: Model,
    force: &[f64],
    cache: Option<&PoseCache>,
    known: Option<&FinalPredictions>,
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let all = numbered(data);
    let (pairs, data): (Vec<Measurement>, Vec<Measurement>) =
        all.into_iter().partition(|d| d.partner.is_some());
    let distances = if pairs.is_empty() {
        None
    } else {
        let problem =
            IdentificationProblem::with_cache(mech, measurement, &pairs, model, force, cache)?;
        let errors = |p: &Params| -> Result<Vec<f64>> {
            Ok(problem
                .predict_distances(p)?
                .iter()
                .zip(&pairs)
                .map(|(d, m)| m.measured[0] - d.expect("a pair"))
                .collect())
        };
        let (before, after) = (errors(&nominal)?, errors(params)?);
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let max = |v: &[f64]| v.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        Some(DistanceAccuracy {
            count: pairs.len(),
            before_rms: rms(&before),
            before_max: max(&before),
            after_rms: rms(&after),
            after_max: max(&after),
            before,
            after,
        })
    };
    let data = &data[..];
    let problem = IdentificationProblem::with_cache(mech, measurement, data, model, force, cache)?;
    let nominal_pred = problem.predict(&nominal)?;
    if let Some(k) = known {
        problem.seed(k, params);
    }
    let pred = problem.predict(params)?;
    let reference: Vec<Vec<f64>> = data
        .iter()
        .zip(&nominal_pred)
        .map(|(d, p)| d.target.clone().unwrap_or_else(|| p.clone()))
        .collect();
    let measured: Vec<Vec<f64>> = data.iter().map(|d| d.measured.clone()).collect();
    let m_before = if *measurement.frame() == Frame::Base || data.is_empty() {
        measurement.nominal().to_vec()
    } else {
        measurement.registered(measurement.nominal(), &reference, &measured)?
    };
    let errors = |tools: &[Vec<f64>], mv: &[f64]| -> Vec<Vec<f64>> {
        tools
            .iter()
            .zip(&measured)
            .zip(data)
            .map(|((x, y), d)| match measurement.to_base(y, mv) {
                Some(b) => b.iter().zip(x).map(|(p, q)| p - q).collect(),
                None => {
                    let mut h = vec![0.0; measurement.len()];
                    measurement.observe_point(x, mv, d.point.as_deref(), &mut h);
                    y.iter().zip(&h).map(|(p, q)| p - q).collect()
                }
            })
            .collect()
    };
    let before = errors(&reference, &m_before);
    let after = errors(&pred, m);
    let units = measurement.units();
    let b = error_stats(&before, units);
    let a = error_stats(&after, units);
    Ok((
        Accuracy {
            poses: data.len(),
            improvement_max_percent: improvement_percent(b.distance_max, a.distance_max),
            improvement_rms_percent: improvement_percent(b.distance_rms, a.distance_rms),
            before: b,
            after: a,
            distances,
        },
        before,
        after,
    ))
}

/// [`accuracy`] of a calibration: its parameters, model and measurement
/// model's values.
pub fn calibration_accuracy<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    cal: &Calibration,
    force: &[f64],
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    calibration_accuracy_with_cache(mech, measurement, data, cal, force, &PoseCache::default())
}

/// [`calibration_accuracy`] with the poses prepared in `cache` (the one the
/// calibration was given to [`calibrate_with_cache`]: the data's poses are
/// then prepared once for both, and the predictions at the identified
/// parameters, when the fit's last evaluation was there, are the fit's).
pub fn calibration_accuracy_with_cache<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    cal: &Calibration,
    force: &[f64],
    cache: &PoseCache,
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    crate::on_pool(|| {
        accuracy_cached(
            mech,
            measurement,
            data,
            &cal.params,
            &cal.measurement,
            cal.model,
            force,
            Some(cache),
            cal.final_predictions.as_ref(),
        )
    })
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
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
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
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    folds: usize,
    seed: u64,
) -> Result<CrossValidation> {
    cross_validate_with_progress(mech, measurement, data, start, opts, folds, seed, &|| {})
}

/// [`cross_validate`], calling `progress` after each fold.
#[allow(clippy::too_many_arguments)]
pub fn cross_validate_with_progress<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
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
        crate::error::check_cancel(opts.solver.cancel.as_deref())?;
        let held: Vec<usize> = idx.iter().copied().skip(f).step_by(folds).collect();
        let train: Vec<Measurement> = idx
            .iter()
            .filter(|i| !held.contains(i))
            .map(|&i| data[i].clone())
            .collect();
        let test: Vec<Measurement> = held.iter().map(|&i| data[i].clone()).collect();
        let cal = calibrate(mech, measurement, &train, start, opts)?;
        let (acc, _, after) = calibration_accuracy(mech, measurement, &test, &cal, &opts.force)?;
        fold_rms.push(acc.after.distance_rms);
        pooled.extend(after);
        progress();
    }
    Ok(CrossValidation {
        folds,
        fold_rms,
        pooled: error_stats(&pooled, measurement.units()),
    })
}
