//! Identification of parameter errors and encoder offsets (docs/model.md eq. 12):
//! minimise `Σ_i ‖x̂_i − h(c_i, p)‖²` over the free parameters with one of the
//! three forward models, with identifiability analysis before fitting,
//! uncertainty after, and validation on held-out poses.

use super::gross::{check_sigma, gross_errors};
use super::identifiability::{Columns, Identifiability, Unidentifiable, analyze_identifiability};
use super::loss::{Loss, Outlier};
use super::prior::{Prior, PriorTerm, WithPriors};
use super::problem::{IdentificationProblem, PoseCache, mask};
use super::result::{Calibration, ParameterResult, Warning, WarningKind};
use super::uncertainty::ParameterCovariance;
use super::weights::calibrate_weighted;
use crate::engine::models::Model;
use crate::error::Origin;
use crate::error::{Error, Result};
use crate::lm;
use crate::measurement::data::{Measurement, numbered};
use crate::measurement::{Frame, MeasurementModel};
use crate::mechanism::{Mechanism, Params, Spec};
use nalgebra::DMatrix;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

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
    /// Fix unidentifiable parameters automatically (with a warning).
    pub auto_fix: bool,
    /// Solver settings (tolerances, bounds; `free` and `weights` are set here).
    pub solver: lm::Options,
    /// Accept as many readings as free parameters: the fit then solves its
    /// equations exactly, as a firmware's own calibration does from as many
    /// probe points as factors, with nothing left to estimate the noise or
    /// an uncertainty from (its standard deviations are NaN). By default a
    /// fit needs at least one reading more than parameters.
    pub exactly_determined: bool,
    /// Priors (tolerances) of parameters (docs/model.md eq. 13): the fit is
    /// then the maximum a posteriori estimate. A prior acts on a free
    /// parameter (a free frame's included); one on a fixed parameter is
    /// unused ([`crate::identify::resolve_free_set`] frees the parameters
    /// with a tolerance unless they are fixed by name).
    pub priors: Vec<Prior>,
    /// The instrument's stated noise (a datasheet's, a probe's
    /// repeatability): a prior of its readings' noise estimates, worth
    /// `stated_noise_readings` readings, and what the model-adequacy test
    /// holds the residuals against ([`super::adequacy`]). `None`: the noise
    /// is estimated from the data alone and not tested.
    pub stated_noise: Option<crate::measurement::data::Noise>,
    /// The stated noise of the distances between poses (mm; calipers on a
    /// printed part, a ball bar: another instrument than the readings'), a
    /// prior of their noise estimate as `stated_noise` is of the readings'.
    pub stated_distance_noise: Option<f64>,
    /// How many readings each stated noise is worth
    /// ([`DEFAULT_STATED_NOISE_READINGS`] by default; infinite: the stated
    /// σ are taken as they are).
    pub stated_noise_readings: f64,
    /// Only the stated noises' ratios are known (a weighing rule such as
    /// Klipper's heights against distances), not their scale: the scale is
    /// estimated from every stated group's residuals pooled, each group's σ
    /// shrinks towards its stated share of it, and no adequacy test holds
    /// the residuals to it.
    pub stated_noise_relative: bool,
    /// The fit alone (Monte Carlo's runs, which read the parameters and
    /// whether the fit converged): everything computed after it only for
    /// the report is skipped (the standard deviations and covariance, the
    /// noise report, outliers when none is dropped, prior warnings and
    /// conflicts, adequacy, final predictions). The parameters and
    /// `converged` are those of the full calibration, bit for bit: what
    /// can change them (reweighting, noise refits, outliers dropped, the
    /// gross-error screening) is kept. Where a report-only step can fail
    /// (an adequacy test's Jacobian, with a stated noise or given σ) the
    /// full calibration is made.
    #[doc(hidden)] // public for the integration tests only
    pub fit_only: bool,
}

/// Readings a stated noise is worth by default: a group of fewer readings'
/// redundancy leans on it, a larger one on its own residuals.
pub const DEFAULT_STATED_NOISE_READINGS: f64 = 10.0;

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
            auto_fix: true,
            solver: lm::Options {
                ftol: 1e-12,
                xtol: 1e-12,
                max_evaluations: 200,
                ..lm::Options::default()
            },
            exactly_determined: false,
            priors: vec![],
            stated_noise: None,
            stated_distance_noise: None,
            stated_noise_readings: DEFAULT_STATED_NOISE_READINGS,
            stated_noise_relative: false,
            fit_only: false,
        }
    }
}

/// Largest share of the poses that dropping outliers may remove.
pub const MAX_DROPPED_FRACTION: f64 = 0.2;

/// Identify the free parameters from measurements (eq. 12), starting from
/// `start` (usually nominal).
///
/// Weighting: each measured coordinate is weighted by 1/σ, its known σ
/// ([`Measurement::sigma`]) or its group's, estimated from the residuals
/// ([`crate::identify::noise`]): lengths and angles each get their own.
/// With a robust [`Loss`], iteratively reweighted least squares: standardise
/// the residuals by their group's robust scale, reweight by `ψ(u)/u`, refit,
/// until the weights settle. Poses beyond `outlier_threshold` are reported;
/// with `drop_outliers` the worst is removed and the fit repeated, until none
/// is left or [`MAX_DROPPED_FRACTION`] of the poses are gone.
pub fn calibrate<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    calibrate_with_cache(mech, measurement, data, start, opts, &PoseCache::default())
}

/// [`calibrate`] with the poses prepared in `cache` (those missing are
/// prepared and left there).
pub fn calibrate_with_cache<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    cache: &PoseCache,
) -> Result<Calibration> {
    crate::on_pool(|| calibrate_on(mech, measurement, data, start, opts, cache))
}

/// [`calibrate_with_cache`] on the calling thread.
fn calibrate_on<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    cache: &PoseCache,
) -> Result<Calibration> {
    // (Rows numbered already, a calibration's own, are not copied.)
    let data = crate::measurement::data::numbered_cow(data);
    // The adequacy tests need a stated noise or given σ, and can then fail
    // (their score test's Jacobian): the fit alone only without them.
    let full;
    let opts = if opts.fit_only
        && (opts.stated_noise.is_some()
            || opts.stated_distance_noise.is_some()
            || data.iter().any(|m| m.sigma.iter().any(Option::is_some)))
    {
        full = CalibrationOptions {
            fit_only: false,
            ..opts.clone()
        };
        &full
    } else {
        opts
    };
    check_sigma(measurement, &data)?;
    let cap = (data.len() as f64 * MAX_DROPPED_FRACTION).floor() as usize;
    let mut kept = data;
    let mut dropped: Vec<Origin> = vec![];
    let mut found: Vec<Outlier> = vec![];
    // Gross errors (a misread, a swapped column) would drag the first,
    // unweighted fit to parameters where poses cannot be assembled: find
    // them first, drop them when asked to, name them otherwise.
    // One identification problem per set of poses: its last predictions
    // start the next evaluation's equilibria, from the screening to the last
    // refit.
    let problem_of = |kept: &[Measurement]| {
        IdentificationProblem::with_cache(
            mech,
            measurement,
            kept,
            opts.model,
            &opts.force,
            Some(cache),
        )
    };
    let mut problem = problem_of(&kept)?;
    for g in gross_errors(&problem, &kept, start)? {
        if !opts.drop_outliers || dropped.len() >= cap {
            return Err(Error::InvalidRequest(format!(
                "the measurement is {:.4e} mm from the nominal prediction, where the median pose is {:.4e} mm: a gross error (a misread, a swapped column, another pose's row); fix or remove it, or calibrate dropping outliers",
                g.distance, g.median
            ))
            .at_pose(g.origin));
        }
        kept.to_mut().retain(|m| m.origin != Some(g.origin));
        dropped.push(g.origin);
    }
    if !dropped.is_empty() {
        problem = problem_of(&kept)?;
    }
    loop {
        let mut cal = calibrate_weighted(&problem, &kept, start, opts)?;
        let more = opts.drop_outliers && !cal.outliers.is_empty() && dropped.len() < cap;
        if !more {
            if !dropped.is_empty() {
                cal.warnings.push(Warning::new(WarningKind::Dropped {
                    poses: dropped.clone(),
                }));
            }
            if !cal.outliers.is_empty() {
                cal.warnings.push(Warning::new(WarningKind::Outliers {
                    poses: cal.outliers.iter().map(|o| o.origin).collect(),
                    threshold: opts.outlier_threshold,
                    robust_loss: opts.loss != Loss::Squared,
                    dropping: opts.drop_outliers,
                }));
            }
            cal.dropped = dropped;
            found.append(&mut cal.outliers);
            cal.outliers = found;
            if opts.fit_only {
                return Ok(cal);
            }
            let beyond = super::prior::prior_warnings(&mut cal);
            cal.warnings.extend(beyond);
            cal.adequacy = super::adequacy::adequacy_tests(&cal);
            if let Some(w) = super::adequacy::adequacy(&problem, &cal)? {
                cal.warnings.push(w);
            }
            cal.final_predictions = problem.final_predictions(&cal.params);
            return Ok(cal);
        }
        // Drop the worst pose only, then refit: one gross error can make its
        // neighbours look bad (masking), and a second one can hide behind it.
        let worst = cal
            .outliers
            .iter()
            .max_by(|a, b| a.standardized.total_cmp(&b.standardized))
            .expect("not empty")
            .clone();
        kept.to_mut().retain(|m| m.origin != Some(worst.origin));
        dropped.push(worst.origin);
        found.push(worst);
        problem = problem_of(&kept)?;
    }
}

/// One least-squares fit with the residuals weighted by 1/`sigma`, from the
/// mechanism's `start` and the measurement model's `m_given` (default: its
/// nominal values, the frame registered when free).
#[allow(clippy::too_many_arguments)]
pub(super) fn calibrate_once<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    start: &Params,
    m_given: Option<&[f64]>,
    opts: &CalibrationOptions,
    sigma: &[f64],
    exact_free: Option<&[usize]>,
    known: Option<&Identifiability>,
    terms: Option<&[PriorTerm]>,
    covariance: bool,
) -> Result<(Calibration, DMatrix<f64>)> {
    let (mech, measurement) = (problem.mech, problem.measurement);
    let spec = mech.spec();
    let np = spec.n_params();
    let mut warnings = vec![];
    let frame_free = *measurement.frame() == Frame::Free;
    let mut requested = opts.free.clone();
    if frame_free {
        requested.extend(measurement.frame_range().map(|i| np + i));
    }
    if let Some(f) = exact_free {
        requested = f.to_vec();
    }
    let given = |p: &&Prior| requested.contains(&p.index);
    let n_priors = terms.map_or_else(|| opts.priors.iter().filter(given).count(), <[_]>::len);
    let m = check_request(problem, data, opts, exact_free, n_priors)?;
    let m0 = measurement_start(problem, m_given, start, data)?;
    let nf = m0.len();
    let cols = Columns::with_measurement(spec, measurement, &m0);
    // The priors of the requested parameters, centred once (a refit keeps
    // the first fit's centres): the mechanism's on nominal, the
    // instrument's on their start.
    for p in opts.priors.iter().filter(given) {
        super::prior::check_sigma(&cols.names[p.index], p.sigma, cols.units[p.index])?;
    }
    let all_terms: Vec<PriorTerm> = match terms {
        Some(t) => t.to_vec(),
        None => opts
            .priors
            .iter()
            .filter(given)
            .map(|p| {
                let centre = if p.index < np {
                    spec.nominal[p.index]
                } else {
                    m0[p.index - np]
                };
                PriorTerm {
                    name: cols.names[p.index].clone(),
                    index: p.index,
                    centre,
                    sigma: p.sigma,
                    constraint: super::prior::is_constraint(p.sigma, centre),
                }
            })
            .collect(),
    };
    if sigma.len() != m || sigma.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(Error::InvalidRequest(
            "one positive finite standard deviation per measured coordinate is needed".into(),
        ));
    }
    let mut x0: Vec<f64> = start.values.iter().chain(&m0).copied().collect();
    // A constraint holds its parameter at its centre, out of the fit; the
    // other priors are rows of it.
    for t in all_terms.iter().filter(|t| t.constraint) {
        x0[t.index] = t.centre;
        requested.retain(|&i| i != t.index);
    }
    let terms: Vec<PriorTerm> = all_terms
        .iter()
        .filter(|t| !t.constraint)
        .cloned()
        .collect();
    let weights: Vec<f64> = sigma
        .iter()
        .map(|v| 1.0 / v)
        .chain(terms.iter().map(|t| 1.0 / t.sigma))
        .collect();
    let stiff: Vec<usize> = (spec.n_geometric() + spec.n_actuated()..np).collect();
    if !stiff
        .iter()
        .any(|k| all_terms.iter().any(|t| t.index == *k))
    {
        fix_a_stiffness_ratio(opts, &stiff, &cols, &mut requested, &mut warnings);
    }
    let mut solver = opts.solver.clone();
    solver.weights = Some(weights.clone());
    let augmented = WithPriors {
        inner: problem,
        terms: &terms,
    };
    let (identifiability, free, speculative) = free_set(
        &augmented, data, opts, &solver, &cols, &requested, &stiff, &weights, nf, known, &mut x0,
    )?;
    identifiability_warnings(opts, frame_free, &identifiability, &mut warnings);
    solver.free = Some(mask(np + nf, &free));
    let report = match speculative {
        Some(r) => r,
        None => fit_with_priors(&augmented, &x0, &solver),
    };
    if !report.termination.converged() {
        warnings.push(Warning::new(WarningKind::NotConverged {
            reason: report.termination.reason(),
        }));
    }
    let fit = Fit {
        report,
        identifiability,
        free,
        requested,
        warnings,
        terms: all_terms,
        rows: terms.len(),
    };
    assemble(problem, data, opts, sigma, &cols, m, fit, covariance)
}

/// The stated noises make sense: positive σ, a non-negative worth, distances
/// for a distances' σ, and a σ for a stated ratio to keep.
fn check_stated(opts: &CalibrationOptions, data: &[Measurement]) -> Result<()> {
    let bad = |what: String| Err(Error::InvalidRequest(what));
    if let Some(n) = opts.stated_noise {
        n.check("stated noise")?;
    }
    if let Some(s) = opts.stated_distance_noise {
        crate::measurement::data::Noise::lengths(s).check("stated distance noise")?;
        if !data.iter().any(|d| d.partner.is_some()) {
            return bad(
                "a stated distance noise is the noise of distances between poses; give the distances too".into(),
            );
        }
    }
    if opts.stated_noise_readings.is_nan() || opts.stated_noise_readings < 0.0 {
        return bad(format!(
            "a stated noise is worth a non-negative number of readings, not {}",
            opts.stated_noise_readings
        ));
    }
    if opts.stated_noise_relative
        && opts.stated_noise.is_none()
        && opts.stated_distance_noise.is_none()
    {
        return bad(
            "only the stated noises' ratios are known, but no noise is stated: state the readings' and/or the distances' noise".into(),
        );
    }
    Ok(())
}

/// The checks before a fit: something free, indices in range, more readings
/// than free parameters. The number of readings.
fn check_request<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    opts: &CalibrationOptions,
    exact_free: Option<&[usize]>,
    n_priors: usize,
) -> Result<usize> {
    let (mech, measurement) = (problem.mech, problem.measurement);
    let spec = mech.spec();
    let nx = measurement.len();
    let np = spec.n_params();
    let frame_free = *measurement.frame() == Frame::Free;
    check_stated(opts, data)?;
    if opts.free.is_empty() && !frame_free {
        return Err(Error::InvalidRequest(
            "no parameter is free; free at least one".into(),
        ));
    }
    if let Some(&i) = opts
        .free
        .iter()
        .find(|&&i| i >= np + measurement.n_params())
    {
        return Err(Error::InvalidRequest(format!(
            "free parameter index {i} is out of range: the mechanism has {np} parameters and the measurement model {}",
            measurement.n_params()
        )));
    }
    let n_free_frame = if frame_free {
        measurement.frame_range().len()
    } else {
        0
    };
    let m: usize = data.iter().map(|d| measurement.row_len(d)).sum();
    let n_requested = exact_free.map_or(opts.free.len() + n_free_frame, <[usize]>::len);
    // Each prior is one more row (docs/model.md eq. 13).
    let rows = m + n_priors;
    if rows < n_requested || (rows == n_requested && !opts.exactly_determined) {
        return Err(Error::InvalidRequest(format!(
            "{} {} give {m} readings{} for {n_requested} free parameters{}; measure more poses (at least {}) or identify fewer parameters{}",
            data.len(),
            if data.iter().any(|d| d.partner.is_some()) {
                "rows"
            } else {
                "poses"
            },
            if n_priors > 0 {
                format!(
                    " and {}",
                    crate::error::count(n_priors, "tolerance", "tolerances")
                )
            } else {
                String::new()
            },
            if n_free_frame > 0 {
                " (with the instrument frame's)"
            } else {
                ""
            },
            if opts.exactly_determined {
                n_requested.saturating_sub(n_priors).div_ceil(nx)
            } else {
                n_requested.saturating_sub(n_priors) / nx + 1
            },
            if nx < spec.tool_axes.len() {
                format!(
                    "; {} alone cannot see every parameter of the default set (an identifiability analysis names the combinations they cannot separate)",
                    measurement.axes().join(", ")
                )
            } else {
                String::new()
            }
        )));
    }
    Ok(m)
}

/// With every stiffness free and no load, only their ratios act: the first
/// is fixed (with a warning).
fn fix_a_stiffness_ratio(
    opts: &CalibrationOptions,
    stiff: &[usize],
    cols: &Columns,
    requested: &mut Vec<usize>,
    warnings: &mut Vec<Warning>,
) {
    let unloaded = opts.force.iter().all(|f| *f == 0.0);
    if opts.auto_fix && unloaded && !stiff.is_empty() && stiff.iter().all(|k| requested.contains(k))
    {
        // Only the ratios act without a load: fix exactly one.
        let k = stiff[0];
        requested.retain(|&i| i != k);
        warnings.push(Warning::new(WarningKind::StiffnessRatios {
            fixed: cols.names[k].clone(),
        }));
    }
}

/// [`lm::minimize`] of the readings with their priors' rows; without
/// priors, of the readings' problem itself (the same residuals and
/// Jacobian), which writes the solver's Jacobian columns directly
/// ([`IdentificationProblem::is_large`]).
fn fit_with_priors<M: Mechanism>(
    augmented: &WithPriors<'_, IdentificationProblem<'_, M>>,
    x0: &[f64],
    opts: &lm::Options,
) -> lm::Report {
    if augmented.terms.is_empty() {
        lm::minimize(augmented.inner, x0, opts)
    } else {
        lm::minimize(augmented, x0, opts)
    }
}

/// The free set the data can identify, from `requested`: identifiability
/// analysed at the start (the fit of `requested` computed meanwhile on
/// another thread, kept when the analysis frees them all), and for
/// stiffness again at the solution without it (moving `x0` there). The
/// analysis, the free set and the speculative fit if it was kept.
#[allow(clippy::too_many_arguments)]
fn free_set<M: Mechanism>(
    augmented: &WithPriors<'_, IdentificationProblem<'_, M>>,
    data: &[Measurement],
    opts: &CalibrationOptions,
    solver: &lm::Options,
    cols: &Columns,
    requested: &[usize],
    stiff: &[usize],
    weights: &[f64],
    nf: usize,
    known: Option<&Identifiability>,
    x0: &mut Vec<f64>,
) -> Result<(Identifiability, Vec<usize>, Option<lm::Report>)> {
    let problem = augmented.inner;
    let terms = augmented.terms;
    let np = problem.mech.spec().n_params();
    // The data's Jacobian with the priors' rows, weighted.
    let weigh = |jac: DMatrix<f64>| -> Result<DMatrix<f64>> {
        let mut jac = super::prior::append_rows(jac, terms);
        lm::scale_rows(&mut jac, weights);
        if jac.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidRequest(
                "the weighted identification Jacobian is not finite: a standard deviation is too small for the values measured; check the sigma columns and the data".into(),
            ));
        }
        Ok(jac)
    };
    // Identifiability at the start.
    let (_, jac) = problem.residuals_and_jacobian(x0)?;
    let weighted = weigh(jac)?;
    // The fit of the requested parameters, computed while identifiability is
    // analysed (on another thread) and kept when the analysis frees them all
    // (as it usually does); stopped, and its evaluations undone, when it
    // fixes one.
    let mut speculative = None;
    let analyze = |jac: &DMatrix<f64>| {
        analyze_identifiability(cols, jac, requested, data.len(), opts.auto_fix)
    };
    // The analysis another calibration made of the same matrix (a Monte
    // Carlo study's runs start alike), the same bit for bit; a large
    // problem's Jacobian is not kept for it.
    let shared = problem.shared.filter(|_| !problem.is_large());
    let kept = match (known, shared) {
        (None, Some(c)) => c.analysis(&weighted, cols, requested, data.len(), opts.auto_fix),
        _ => None,
    };
    let reused = kept.is_some();
    let (mut identifiability, mut free) = match known {
        // A refit keeps the first fit's analysis (its free set is `exact_free`).
        Some(ident) if !opts.auto_fix => (ident.clone(), requested.to_vec()),
        _ if reused => {
            let (ident, free) = kept.expect("matched");
            if free == requested {
                // The fit the speculation would have kept (its cancel flag
                // is never set then).
                let mut fit = solver.clone();
                fit.free = Some(mask(np + nf, requested));
                speculative = Some(fit_with_priors(augmented, x0, &fit));
            }
            (ident, free)
        }
        // The caller's own cancel flag governs every fit: no speculation.
        _ if opts.solver.cancel.is_some() => analyze(&weighted),
        // A large problem keeps one Jacobian at a time: the analysis, then
        // the fit.
        _ if problem.is_large() => analyze(&weighted),
        _ => {
            let saved = problem.saved();
            let cancel = Arc::new(AtomicBool::new(false));
            let mut fit = solver.clone();
            fit.free = Some(mask(np + nf, requested));
            fit.cancel = Some(cancel.clone());
            let mut analysis = None;
            let report = rayon::in_place_scope(|s| {
                s.spawn(|_| {
                    let a = analyze(&weighted);
                    if a.1 != requested {
                        cancel.store(true, Ordering::Relaxed);
                    }
                    analysis = Some(a);
                });
                fit_with_priors(augmented, x0, &fit)
            });
            let (ident, free) = analysis.expect("the scope waits for the analysis");
            if free == requested {
                speculative = Some(report);
            } else {
                problem.restore(saved);
            }
            (ident, free)
        }
    };
    if let (None, false, Some(c)) = (known, reused, shared) {
        let result = (identifiability.clone(), free.clone());
        c.keep_analysis(
            &weighted,
            cols,
            requested,
            data.len(),
            opts.auto_fix,
            &result,
        );
    }
    // Stiffness acts only where the actuators fight, which they do not at
    // nominal parameters: judge its identifiability where they do, at the
    // solution without it.
    let idle: Vec<usize> = stiff
        .iter()
        .copied()
        .filter(|k| requested.contains(k) && !free.contains(k))
        .collect();
    if opts.auto_fix && !idle.is_empty() && !free.is_empty() {
        let mut fit = solver.clone();
        fit.free = Some(mask(np + nf, &free));
        *x0 = fit_with_priors(augmented, x0, &fit).x;
        let (_, jac) = problem.residuals_and_jacobian(x0)?;
        (identifiability, free) = analyze(&weigh(jac)?);
    }
    // What the data alone cannot see among what the priors identify: held
    // by the tolerances.
    if !terms.is_empty() && known.is_none() {
        let rows = weighted.nrows() - terms.len();
        let data_only = weighted.rows(0, rows).into_owned();
        identifiability.held = held_by_priors(cols, &data_only, &free, data.len());
    }
    Ok((identifiability, free, speculative))
}

/// The warnings of an identifiability analysis: the instrument frame's
/// gauge once, then each other unidentifiable direction.
fn identifiability_warnings(
    opts: &CalibrationOptions,
    frame_free: bool,
    identifiability: &Identifiability,
    warnings: &mut Vec<Warning>,
) {
    // Directions that move the instrument frame with the mechanism are one
    // matter (the gauge), said once.
    let (gauge, other): (Vec<&Unidentifiable>, Vec<&Unidentifiable>) = identifiability
        .unidentifiable
        .iter()
        .partition(|u| frame_free && u.terms.iter().any(|(n, _)| n.starts_with("frame.")));
    if !gauge.is_empty() {
        warnings.push(Warning::new(WarningKind::FrameGauge {
            model: opts.model,
            fixed: gauge.iter().filter_map(|u| u.fixed.clone()).collect(),
            unfixed: gauge.iter().filter(|u| u.fixed.is_none()).count(),
        }));
    }
    for u in other {
        warnings.push(Warning::new(WarningKind::Unidentifiable {
            model: opts.model,
            combination: u.combination.clone(),
            fixed: u.fixed.clone(),
        }));
    }
    if !identifiability.held.is_empty() {
        warnings.push(Warning::new(WarningKind::HeldByTolerance {
            model: opts.model,
            combinations: identifiability
                .held
                .iter()
                .map(|u| u.combination.clone())
                .collect(),
        }));
    }
}

/// A finished fit and what the free set's analysis left.
struct Fit {
    report: lm::Report,
    identifiability: Identifiability,
    free: Vec<usize>,
    requested: Vec<usize>,
    warnings: Vec<Warning>,
    /// The priors, those not constraints in the order of their rows after
    /// the readings'.
    terms: Vec<PriorTerm>,
    /// The priors' rows.
    rows: usize,
}

/// The calibration of a finished fit: parameters, the covariance
/// `(J̃ᵀW̃J̃)⁻¹` at the fit's weights (the standard deviations, shares and
/// correlations that the scale rule fills in the end,
/// [`super::uncertainty::apply_scale`], from it as they stand), and that
/// covariance again for the leverages of the noise estimation; without
/// `covariance`, neither (an empty matrix, and no rank warning: a fit
/// alone whose caller reads none).
#[allow(clippy::too_many_arguments)]
fn assemble<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    opts: &CalibrationOptions,
    sigma: &[f64],
    cols: &Columns,
    m: usize,
    fit: Fit,
    covariance: bool,
) -> Result<(Calibration, DMatrix<f64>)> {
    let (mech, measurement) = (problem.mech, problem.measurement);
    let spec = mech.spec();
    let np = spec.n_params();
    let Fit {
        report,
        identifiability,
        mut free,
        requested,
        mut warnings,
        terms,
        rows,
    } = fit;
    // The solver's columns (its covariance's and Jacobian's) are the free
    // mask's, in index order, whatever order the free set was named in.
    free.sort_unstable();
    let params = Params::new(spec, report.x[..np].to_vec())?;
    let m_values = report.x[np..].to_vec();
    let frame = m_values[measurement.frame_range()].to_vec();
    let (cov_unit, rank) = if covariance {
        report.covariance(crate::lm::COVARIANCE_RANK_TOL)
    } else {
        (DMatrix::zeros(0, 0), free.len())
    };
    if rank < free.len() {
        warnings.push(Warning::new(WarningKind::RankDeficient {
            rank,
            free: free.len(),
        }));
    }
    let mut parameters = vec![];
    for (i, name) in cols.names.iter().enumerate() {
        let k = free.iter().position(|&f| f == i);
        let constraint = terms.iter().any(|t| t.index == i && t.constraint);
        let note = if constraint {
            Some("held at its value by its tolerance, a constraint".into())
        } else if k.is_none() && requested.contains(&i) {
            Some("unidentifiable: fixed at its starting value".into())
        } else {
            None
        };
        parameters.push(ParameterResult {
            name: name.clone(),
            unit: cols.units[i],
            kind: cols.kinds[i],
            nominal: cols.nominal[i],
            identified: report.x[i],
            change: report.x[i] - cols.nominal[i],
            std_dev: 0.0,
            free: k.is_some(),
            note,
            tolerance: None,
            from_data: None,
        });
    }
    let readings = if rows == 0 {
        report.jacobian
    } else {
        report.jacobian.rows(0, m).into_owned()
    };
    let mut cal = Calibration {
        parameter_covariance: ParameterCovariance {
            names: vec![],
            matrix: vec![],
        },
        model: opts.model,
        params,
        frame: (!frame.is_empty()).then_some(frame),
        measurement: m_values,
        converged: report.termination.converged(),
        termination_reason: report.termination.reason(),
        termination: report.termination,
        iterations: report.iterations,
        evaluations: report.evaluations,
        poses: data.iter().filter(|d| d.partner.is_none()).count(),
        distances: data.iter().filter(|d| d.partner.is_some()).count(),
        sum_of_squares: report.sum_of_squares,
        unit_weight_sigma: f64::NAN,
        scale: super::uncertainty::Scale::Known,
        redundancy: f64::NAN,
        adequacy: vec![],
        noise: vec![],
        parameters,
        identifiability,
        covariance: DMatrix::zeros(0, 0),
        free,
        correlations: vec![],
        loss: opts.loss,
        outliers: vec![],
        dropped: vec![],
        residuals: report
            .residuals
            .iter()
            .zip(sigma)
            .map(|(v, s)| v * s)
            .collect(),
        sigmas: sigma.to_vec(),
        // The readings' rows (the priors' follow from `priors`).
        jacobian: readings,
        warnings,
        priors: terms,
        final_predictions: None,
        prior_conflicts: vec![],
    };
    if !opts.fit_only {
        super::uncertainty::apply_scale(&mut cal, super::uncertainty::Scale::Known, &[]);
    }
    Ok((cal, cov_unit))
}

/// The measurement model's parameters to start from: `given`, else its
/// nominal values with a free frame registered onto the readings predicted
/// under `params`.
pub(super) fn measurement_start<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    given: Option<&[f64]>,
    params: &Params,
    data: &[Measurement],
) -> Result<Vec<f64>> {
    let measurement = problem.measurement();
    if let Some(g) = given {
        return Ok(g.to_vec());
    }
    if *measurement.frame() != Frame::Free {
        return Ok(measurement.nominal().to_vec());
    }
    let (predicted, measured): (Vec<Vec<f64>>, Vec<Vec<f64>>) = problem
        .predict(params)?
        .into_iter()
        .zip(data)
        .filter(|(_, m)| m.partner.is_none())
        .map(|(p, m)| (p, m.measured.clone()))
        .unzip();
    measurement.registered(measurement.nominal(), &predicted, &measured)
}

/// Identifiability analysis alone (no fit), at `params` and the measurement
/// model's nominal values (a free frame registered). Rows are weighted by the
/// data's σ where given, otherwise by the default noise ratio of lengths and
/// angles ([`crate::Noise::lengths`]), so that mm and rad do not meet
/// unscaled. `free` indexes the mechanism's parameters then the model's; a
/// free frame's are added. Every unidentifiable direction is listed with the
/// parameter that [`calibrate`] would fix for it.
pub fn analyze<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    model: Model,
    free: &[usize],
    force: &[f64],
) -> Result<Identifiability> {
    let default = crate::measurement::data::Noise::lengths(1.0);
    analyze_with_priors(
        mech,
        measurement,
        data,
        params,
        model,
        free,
        force,
        &[],
        default,
    )
}

/// [`analyze`] counting the information of `priors` (docs/model.md eq. 13):
/// the readings without a given σ weighted by `noise` (the instrument's,
/// which sets what they tell against what the tolerances tell), one row per
/// prior of a free parameter appended. A direction the data cannot see but
/// a prior bounds is identified, listed in [`Identifiability::held`].
#[allow(clippy::too_many_arguments)]
pub fn analyze_with_priors<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    model: Model,
    free: &[usize],
    force: &[f64],
    priors: &[Prior],
    noise: crate::measurement::data::Noise,
) -> Result<Identifiability> {
    let opts = AnalysisOptions {
        model,
        free: free.to_vec(),
        force: force.to_vec(),
        priors: priors.to_vec(),
        noise,
        cancel: None,
    };
    analyze_cancellable(mech, measurement, data, params, &opts)
}

/// What [`analyze_cancellable`] analyses: the arguments of
/// [`analyze_with_priors`], and a flag that stops it.
#[derive(Debug, Clone)]
pub struct AnalysisOptions {
    /// The forward model.
    pub model: Model,
    /// The free parameters (the mechanism's, then the measurement model's).
    pub free: Vec<usize>,
    /// The tool load during the measurements (empty for none).
    pub force: Vec<f64>,
    /// Priors (tolerances) of free parameters.
    pub priors: Vec<Prior>,
    /// The readings' noise where the data give no σ (weighs them against
    /// the priors).
    pub noise: crate::measurement::data::Noise,
    /// Set from another thread to stop at the next pose
    /// ([`Error::Cancelled`]); `None` for none.
    pub cancel: Option<Arc<AtomicBool>>,
}

/// [`analyze_with_priors`] with its settings in one place, stopped at the
/// next pose once [`AnalysisOptions::cancel`] is set.
pub fn analyze_cancellable<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    opts: &AnalysisOptions,
) -> Result<Identifiability> {
    let AnalysisOptions {
        model,
        free,
        force,
        priors,
        noise,
        cancel,
    } = opts;
    let (model, noise) = (*model, *noise);
    let spec = mech.spec();
    let data = numbered(data);
    check_sigma(measurement, &data)?;
    noise.check("noise")?;
    let problem =
        IdentificationProblem::cancellable(mech, measurement, &data, model, force, cancel.clone())?;
    let np = spec.n_params();
    let m0 = measurement_start(&problem, None, params, &data)?;
    let mut free = free.to_vec();
    if *measurement.frame() == Frame::Free {
        free.extend(measurement.frame_range().map(|i| np + i));
    }
    let x: Vec<f64> = params.values.iter().chain(&m0).copied().collect();
    let (_, mut jac) = problem.residuals_and_jacobian(&x)?;
    crate::error::check_cancel(cancel.as_deref())?;
    if jac.iter().any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(
            "the identification Jacobian is not finite at these parameters".into(),
        ));
    }
    let mut row = 0;
    for m in &data {
        for a in 0..measurement.row_len(m) {
            let s = m
                .sigma_of(a)
                .unwrap_or_else(|| noise.for_unit(measurement.row_unit(m, a)));
            jac.row_mut(row).unscale_mut(s);
            row += 1;
        }
    }
    let cols = Columns::with_measurement(spec, measurement, &m0);
    for p in priors.iter().filter(|p| free.contains(&p.index)) {
        super::prior::check_sigma(&cols.names[p.index], p.sigma, cols.units[p.index])?;
    }
    // A constraint holds its parameter: the others are analysed as without it.
    let centre = |i: usize| if i < np { spec.nominal[i] } else { m0[i - np] };
    free.retain(|&i| {
        !priors
            .iter()
            .any(|p| p.index == i && super::prior::is_constraint(p.sigma, centre(i)))
    });
    let used: Vec<&Prior> = priors.iter().filter(|p| free.contains(&p.index)).collect();
    if used.is_empty() {
        return Ok(analyze_identifiability(&cols, &jac, &free, data.len(), true).0);
    }
    let readings = jac.nrows();
    let mut augmented = jac.clone().resize_vertically(readings + used.len(), 0.0);
    for (a, p) in used.iter().enumerate() {
        augmented[(readings + a, p.index)] = 1.0 / p.sigma;
    }
    let mut ident = analyze_identifiability(&cols, &augmented, &free, data.len(), true).0;
    ident.held = held_by_priors(&cols, &jac, &free, data.len());
    Ok(ident)
}

/// The directions the readings' weighted Jacobian `jac` alone cannot see
/// among `free` (which priors identify): each one, none fixed.
fn held_by_priors(
    cols: &Columns,
    jac: &DMatrix<f64>,
    free: &[usize],
    poses: usize,
) -> Vec<Unidentifiable> {
    analyze_identifiability(cols, jac, free, poses, true)
        .0
        .unidentifiable
        .into_iter()
        .map(|u| Unidentifiable { fixed: None, ..u })
        .collect()
}
