//! The calibration study every front end runs (the command line, Python and
//! the firmware commands): the free set resolved from the names a user
//! gives, the fit of the poses and of the distances measured between poses,
//! the accuracy before and after on the poses the fit kept, and validation on
//! given poses, on poses held out, or by k-fold cross-validation. One typed
//! result, from which each front end makes its report, summary and objects;
//! errors say which stage failed, so a front end can name the file or array
//! that stage read.

use super::driver::{CalibrationOptions, calibrate_with_cache};
use super::problem::PoseCache;
use super::result::Calibration;
use super::validation::{
    Accuracy, CrossValidation, ErrorVectors, calibration_accuracy, calibration_accuracy_with_cache,
    cross_validate_with_progress, holdout_split,
};
use crate::error::{Error, Result};
use crate::measurement::MeasurementModel;
use crate::measurement::data::Measurement;
use crate::mechanism::{Mechanism, Params, Spec};
use std::borrow::Cow;

/// Which list of parameter names a user gave: the free set or the names to
/// remove from it (each front end words it: `--free`/`--fix` on the command
/// line, `free=`/`fix=` in Python).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NameList {
    /// The parameters to identify.
    Free,
    /// The parameters to remove from the free set.
    Fix,
}

/// Why a free set cannot be resolved. Typed, so that each front end says
/// what to change in its own terms.
#[derive(Debug, Clone, PartialEq)]
pub enum FreeSetError {
    /// A name the mechanism and the instrument do not know (the library's
    /// error says which names are known).
    Unknown {
        /// The list it was in.
        list: NameList,
        /// The error naming it.
        error: Error,
    },
    /// A parameter of the instrument frame, which the frame choice sets
    /// (free: identified; base: the data are in the base frame).
    FrameParameter {
        /// The list it was in.
        list: NameList,
        /// The name.
        name: String,
    },
    /// Nothing is left free.
    Empty,
}

impl std::fmt::Display for FreeSetError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FreeSetError::Unknown { error, .. } => write!(f, "{error}"),
            FreeSetError::FrameParameter { name, .. } => write!(
                f,
                "`{name}` belongs to the instrument frame, which the frame choice sets (free: identified; base: the data are in the base frame)"
            ),
            FreeSetError::Empty => write!(f, "no parameter is left free"),
        }
    }
}

impl std::error::Error for FreeSetError {}

/// The free set (indices of the identification vector: the mechanism's
/// parameters, then the instrument's) from the names a user gives: `free`
/// (`None`: the default set `default`, usually [`Spec::default_free`]) may
/// name parameters, `all` (every mechanism and instrument parameter but the
/// frame's) and `default` (the default set; `paper` is the same); the names
/// in `fix` are then removed.
/// The instrument frame's parameters cannot be named: the frame choice
/// frees or fixes them.
pub fn resolve_free_set(
    spec: &Spec,
    measurement: &MeasurementModel,
    default: &[String],
    free: Option<&[String]>,
    fix: &[String],
) -> std::result::Result<Vec<usize>, FreeSetError> {
    let frame: Vec<usize> = measurement
        .frame_range()
        .map(|i| spec.n_params() + i)
        .collect();
    let index = |n: &str, list: NameList| -> std::result::Result<usize, FreeSetError> {
        let i = measurement
            .index_of(spec, n)
            .map_err(|error| FreeSetError::Unknown { list, error })?;
        if frame.contains(&i) {
            return Err(FreeSetError::FrameParameter {
                list,
                name: n.to_string(),
            });
        }
        Ok(i)
    };
    let default = || -> std::result::Result<Vec<usize>, FreeSetError> {
        default.iter().map(|n| index(n, NameList::Free)).collect()
    };
    let mut set: Vec<usize> = match free {
        None => default()?,
        Some(list) => {
            let mut out = vec![];
            for n in list.iter().map(|n| n.trim()).filter(|n| !n.is_empty()) {
                match n {
                    "all" => {
                        out.extend(0..spec.n_params());
                        out.extend(
                            (0..measurement.frame_range().start).map(|i| spec.n_params() + i),
                        );
                    }
                    "default" | "paper" => out.extend(default()?),
                    _ => out.push(index(n, NameList::Free)?),
                }
            }
            out
        }
    };
    for n in fix.iter().map(|n| n.trim()).filter(|n| !n.is_empty()) {
        let i = index(n, NameList::Fix)?;
        set.retain(|&k| k != i);
    }
    set.sort_unstable();
    set.dedup();
    if set.is_empty() {
        return Err(FreeSetError::Empty);
    }
    Ok(set)
}

/// Bounds on named parameters (the mechanism's or the instrument's) as the
/// solver takes them: full vectors over the identification vector
/// (mechanism, then instrument), ±∞ where a parameter is not named. A NaN
/// bound, a lower bound above the upper one, or an unknown name is refused.
pub fn named_bounds(
    spec: &Spec,
    measurement: &MeasurementModel,
    bounds: &[(String, f64, f64)],
) -> Result<(Vec<f64>, Vec<f64>)> {
    let n = spec.n_params() + measurement.param_names().len();
    let (mut lower, mut upper) = (vec![f64::NEG_INFINITY; n], vec![f64::INFINITY; n]);
    for (name, lo, hi) in bounds {
        let i = measurement.index_of(spec, name)?;
        if lo.is_nan() || hi.is_nan() || lo > hi {
            return Err(Error::InvalidRequest(format!(
                "the bounds of `{name}` are ({lo}, {hi}); give a lower bound at most the upper one (±inf leaves a side open)"
            )));
        }
        lower[i] = *lo;
        upper[i] = *hi;
    }
    Ok((lower, upper))
}

/// Where a study's validation poses come from.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum ValidationPlan {
    /// No validation.
    #[default]
    None,
    /// Poses measured apart (a validation file or arrays).
    Given(Vec<Measurement>),
    /// A fraction of the poses held out of the fit (seeded by the study's
    /// seed).
    Holdout(f64),
}

/// A study: the fit's options, the validation and the cross-validation.
#[derive(Debug, Clone)]
pub struct StudyOptions {
    /// The fit.
    pub calibration: CalibrationOptions,
    /// Validation poses.
    pub validation: ValidationPlan,
    /// k-fold cross-validation of the fit (k ≥ 2), if asked for.
    pub kfold: Option<usize>,
    /// Seed of the hold-out split and of the folds.
    pub seed: u64,
    /// Keep the fit's weighted Jacobian in the result
    /// ([`Calibration::jacobian`], and so in a record of the study). A
    /// caller that reads neither frees it as soon as the fit is done, before
    /// the accuracy's predictions are made: on 10,000 tool poses of an
    /// 8-leg platform it is 27 MB of the peak.
    pub keep_jacobian: bool,
}

/// Where a study's validation poses came from, for the front ends to word.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ValidationSource {
    /// Given apart.
    Given,
    /// Held out of the poses given.
    HeldOut {
        /// How many.
        count: usize,
        /// The split's seed.
        seed: u64,
    },
}

/// Validation on poses the fit did not see.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct StudyValidation {
    /// Where they came from.
    pub source: ValidationSource,
    /// Before/after on them.
    pub accuracy: Accuracy,
}

/// What a study returns: plain data that serialises whole (a calibration
/// record keeps it, so that a calibration read back is the one computed).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct Study {
    /// The fit.
    #[serde(with = "super::result::full")]
    pub calibration: Calibration,
    /// Before/after on the rows the fit kept (poses and distances).
    pub accuracy: Accuracy,
    /// Error vectors before calibration at [`Study::poses`].
    pub before: ErrorVectors,
    /// Error vectors after calibration at [`Study::poses`].
    pub after: ErrorVectors,
    /// The poses the fit kept (without the distances), in order: what the
    /// figures show.
    pub poses: Vec<Measurement>,
    /// Validation on poses the fit did not see.
    pub validation: Option<StudyValidation>,
    /// k-fold cross-validation.
    pub cross_validation: Option<CrossValidation>,
}

/// The stage of a study that failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StudyStage {
    /// The options (a hold-out fraction, a number of folds).
    Options,
    /// The fit, or the accuracy at the fitted poses: the poses and distances
    /// given.
    Fit,
    /// The validation poses.
    Validation,
    /// The cross-validation's fits.
    CrossValidation,
}

/// A study's failure: where, and what.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyError {
    /// The stage that failed.
    pub stage: StudyStage,
    /// What went wrong.
    pub error: Error,
}

impl std::fmt::Display for StudyError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.error.fmt(f)
    }
}

impl std::error::Error for StudyError {}

fn at(stage: StudyStage) -> impl Fn(Error) -> StudyError {
    move |error| StudyError { stage, error }
}

/// Run a calibration study: `poses` (each with its origin, so that every
/// message and report names it) and `distances` (rows with a partner) from
/// `start`; the validation and cross-validation of `opts`; `fold_done` is
/// called after each fold of the cross-validation.
pub fn study<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    poses: &[Measurement],
    distances: Vec<Measurement>,
    start: &Params,
    opts: &StudyOptions,
    fold_done: &(dyn Fn() + Sync),
) -> std::result::Result<Study, StudyError> {
    if let Some(k) = opts.kfold
        && k < 2
    {
        return Err(at(StudyStage::Options)(Error::InvalidRequest(format!(
            "k-fold cross-validation needs at least 2 folds, got {k}"
        ))));
    }
    // The poses the fit sees are the caller's, copied only when some are
    // held out or distances follow them.
    type Held = Option<(ValidationSource, Vec<Measurement>)>;
    let (train, held): (Cow<'_, [Measurement]>, Held) = match &opts.validation {
        ValidationPlan::None => (Cow::Borrowed(poses), None),
        ValidationPlan::Given(v) => (
            Cow::Borrowed(poses),
            Some((ValidationSource::Given, v.clone())),
        ),
        ValidationPlan::Holdout(f) => {
            let (tr, he) =
                holdout_split(poses.len(), *f, opts.seed).map_err(at(StudyStage::Options))?;
            (
                Cow::Owned(tr.iter().map(|&i| poses[i].clone()).collect()),
                Some((
                    ValidationSource::HeldOut {
                        count: he.len(),
                        seed: opts.seed,
                    },
                    he.iter().map(|&i| poses[i].clone()).collect(),
                )),
            )
        }
    };
    // The distances all go into the fit, after the poses.
    let train: Cow<'_, [Measurement]> = if distances.is_empty() {
        train
    } else {
        Cow::Owned(train.iter().cloned().chain(distances).collect())
    };
    let copts = &opts.calibration;
    // The poses are prepared once, for the fit and its statistics.
    let cache = PoseCache::new();
    let mut cal = calibrate_with_cache(mech, measurement, &train, start, copts, &cache)
        .map_err(at(StudyStage::Fit))?;
    if !opts.keep_jacobian {
        cal.jacobian = nalgebra::DMatrix::zeros(0, 0);
    }
    // Statistics over the rows the fit kept (dropped outliers are listed).
    let kept: Cow<'_, [Measurement]> = if cal.dropped.is_empty() {
        Cow::Borrowed(&train)
    } else {
        Cow::Owned(
            train
                .iter()
                .filter(|m| m.origin.is_none_or(|o| !cal.dropped.contains(&o)))
                .cloned()
                .collect(),
        )
    };
    let (accuracy, before, after) =
        calibration_accuracy_with_cache(mech, measurement, &kept, &cal, &copts.force, &cache)
            .map_err(at(StudyStage::Fit))?;
    // The figures show the poses (the distances are in the accuracy).
    let poses: Vec<Measurement> = kept
        .iter()
        .filter(|m| m.partner.is_none())
        .cloned()
        .collect();
    let validation = match held {
        Some((source, data)) => Some(StudyValidation {
            source,
            accuracy: calibration_accuracy(mech, measurement, &data, &cal, &copts.force)
                .map_err(at(StudyStage::Validation))?
                .0,
        }),
        None => None,
    };
    let cross_validation = match opts.kfold {
        Some(k) => Some(
            cross_validate_with_progress(
                mech,
                measurement,
                &train,
                start,
                copts,
                k,
                opts.seed,
                fold_done,
            )
            .map_err(at(StudyStage::CrossValidation))?,
        ),
        None => None,
    };
    Ok(Study {
        calibration: cal,
        accuracy,
        before,
        after,
        poses,
        validation,
        cross_validation,
    })
}
