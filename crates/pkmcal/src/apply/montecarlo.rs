//! Monte Carlo prediction of calibration accuracy for a measurement plan:
//! random parameter errors and measurement noise, simulated measurements,
//! calibration, and the resulting accuracy on unseen poses and parameters.

use crate::apply::simulate::{noise_normals, prepare_target, reading};
use crate::engine::models::{Model, Pose, Prediction, predict_pose, predict_pose_near_into};
use crate::engine::sensitivity::joint_sensitivity;
use crate::error::Result;
use crate::identify::stats::{ErrorStats, error_stats};
use crate::identify::{Calibration, CalibrationOptions, PoseCache, Prior, calibrate_with_cache};
use crate::measurement::MeasurementModel;
use crate::measurement::data::Measurement;
use crate::measurement::data::Noise;
use crate::mechanism::{Mechanism, Params};
use crate::units::{ParamKind, Unit};
use nalgebra::DMatrix;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;
use serde::Serialize;

/// The unseen poses a study is judged on: `count` random usable targets,
/// drawn from a stream apart from the noise's (`seed` mixed with a constant),
/// so that the CLI and the Python package judge the same study alike.
pub fn validation_targets<M: Mechanism>(
    mech: &M,
    count: usize,
    seed: u64,
) -> Result<Vec<Vec<f64>>> {
    if count == 0 {
        return Err(crate::error::RequestError::invalid(
            crate::error::Field::ValidationTargets,
            "no validation target asked for; judge the runs on at least 1",
        )
        .into());
    }
    crate::apply::workspace::random_targets(mech, count, seed ^ 0x5eed)
}

/// Settings of a Monte Carlo study.
#[derive(Debug, Clone)]
pub struct MonteCarloOptions {
    /// Number of simulated calibrations.
    pub runs: usize,
    /// Measurement noise per kind of coordinate.
    pub noise: Noise,
    /// Seed; run `r` uses `seed + r`.
    pub seed: u64,
    /// Standard deviation of the random errors of the free parameters in mm
    /// (lengths, positions, offsets of prismatic actuators). A parameter
    /// with a prior (`calibration.priors`, a tolerance) is drawn from it
    /// instead, free or fixed, and the fits use the priors.
    pub length_error: f64,
    /// Standard deviation of the random errors of the free parameters in rad
    /// (encoder offsets of revolute actuators, axis angles).
    pub angle_error: f64,
    /// Calibration settings (model, free set).
    pub calibration: CalibrationOptions,
}

/// One simulated calibration.
#[derive(Debug, Clone, Serialize)]
pub struct Run {
    /// Whether the fit converged.
    pub converged: bool,
    /// Accuracy on the validation targets (noise-free truth vs calibrated model).
    pub validation: ErrorStats,
    /// Identified minus true value of each free parameter.
    pub parameter_errors: Vec<f64>,
}

/// Summary over all runs.
#[derive(Debug, Clone, Serialize)]
pub struct MonteCarloSummary {
    /// Runs made.
    pub runs: usize,
    /// Runs that converged.
    pub converged: usize,
    /// Median of the validation RMS distance error (mm).
    pub validation_rms_median: f64,
    /// 95th percentile of the validation RMS distance error (mm).
    pub validation_rms_p95: f64,
    /// Median of the validation maximum distance error (mm).
    pub validation_max_median: f64,
    /// Free parameter names.
    pub parameters: Vec<String>,
    /// RMS over runs of each free parameter's error.
    pub parameter_rms_error: Vec<f64>,
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return f64::NAN;
    }
    let k = ((v.len() - 1) as f64 * p).round() as usize;
    v[k]
}

/// The most runs one study makes: each run is kept (its parameter errors),
/// so memory grows with them (about 200 bytes a run on the reference, some
/// hundred MB at the bound), and at thousands of calibrations a second this
/// is minutes already.
pub const MAX_RUNS: usize = 1_000_000;

impl MonteCarloOptions {
    /// Refuse what cannot be simulated: more than [`MAX_RUNS`] runs, none,
    /// random errors or noise that are negative, not finite or beyond any
    /// machine ([`crate::identify::request::MAX_LENGTH_MM`],
    /// [`crate::identify::request::MAX_ANGLE_RAD`]).
    pub fn check(&self) -> std::result::Result<(), crate::error::RequestError> {
        use crate::error::{Field, RequestError};
        use crate::identify::request::{MAX_ANGLE_RAD, MAX_LENGTH_MM, bounded};
        if self.runs == 0 || self.runs > MAX_RUNS {
            return Err(RequestError::invalid(
                Field::Runs,
                format!(
                    "{} runs asked for; give 1 to {MAX_RUNS} (each is kept in memory)",
                    self.runs
                ),
            ));
        }
        bounded(Field::LengthError, self.length_error, MAX_LENGTH_MM, "mm")?;
        bounded(Field::AngleError, self.angle_error, MAX_ANGLE_RAD, "rad")?;
        bounded(Field::Noise, self.noise.length, MAX_LENGTH_MM, "mm")?;
        bounded(Field::AngleNoise, self.noise.angle, MAX_ANGLE_RAD, "rad")?;
        Ok(())
    }
}

/// The first-order prediction of the exact model's equilibrium at a pose
/// for parameters near nominal: the nominal one and its `∂q/∂p`
/// ([`joint_sensitivity`]).
struct FirstOrder {
    /// `∂q/∂p` at nominal parameters (joints × parameters).
    dq: DMatrix<f64>,
    /// The nominal equilibrium's joints.
    q: Vec<f64>,
}

impl FirstOrder {
    /// At `pose` with `nominal` parameters, unloaded; `None` where the
    /// exact model is not what computes or its derivative is singular
    /// (the truth's equilibria then start from the nominal configuration).
    fn at_nominal<M: Mechanism>(mech: &M, pose: &Pose, nominal: &Params) -> Option<Self> {
        let p = predict_pose(mech, pose, nominal, Model::Exact, &[]).ok()?;
        let dq = joint_sensitivity(mech, pose, nominal, &[], &p)?;
        Some(Self { dq, q: p.q })
    }

    /// `from + ∂q/∂p · delta` into `out`.
    fn start(&self, from: &[f64], delta: &[f64], out: &mut Vec<f64>) {
        out.clear();
        out.extend_from_slice(from);
        // (Over the column-major storage: a column per parameter.)
        let rows = self.dq.nrows().max(1);
        for (column, d) in self.dq.as_slice().chunks_exact(rows).zip(delta) {
            if *d != 0.0 {
                for (o, v) in out.iter_mut().zip(column) {
                    *o += v * d;
                }
            }
        }
    }
}

/// The truth's exact prediction at `pose`, its equilibrium started from
/// the first-order prediction for the parameters' `error` from nominal
/// (else from the nominal configuration, as `predict_pose`), into `out`.
/// `start` is a buffer.
fn truth_at<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    truth: &Params,
    first: Option<&FirstOrder>,
    error: &[f64],
    start: &mut Vec<f64>,
    out: &mut Prediction,
) -> Result<()> {
    match first {
        Some(f) => {
            f.start(&f.q, error, start);
            predict_pose_near_into(mech, pose, truth, Model::Exact, &[], start, out)
        }
        None => {
            *out = predict_pose(mech, pose, truth, Model::Exact, &[])?;
            Ok(())
        }
    }
}

/// Run the study: calibrate from measurements at `poses` (targets), judge on
/// `validation` targets. `progress` is called after each run (from any thread).
pub fn monte_carlo<M: Mechanism>(
    mech: &M,
    poses: &[Vec<f64>],
    validation: &[Vec<f64>],
    opts: &MonteCarloOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<(Vec<Run>, MonteCarloSummary)> {
    // A run reads the calibration's parameters and whether it converged:
    // the fit alone, the same bit for bit, without its report.
    let mut fit = opts.calibration.clone();
    fit.fit_only = true;
    let (tool, nominal) = (
        MeasurementModel::tool(mech.spec()),
        Params::nominal(mech.spec()),
    );
    let calibrate = |data: &[Measurement], cache: &PoseCache| {
        calibrate_with_cache(mech, &tool, data, &nominal, &fit, cache)
    };
    study(mech, poses, validation, opts, progress, &calibrate)
}

/// [`monte_carlo`] with each run's data calibrated by `calibrate` (from
/// nominal parameters, the poses prepared in the cache it is given).
#[doc(hidden)] // public for the integration tests only
pub fn study<M: Mechanism>(
    mech: &M,
    poses: &[Vec<f64>],
    validation: &[Vec<f64>],
    opts: &MonteCarloOptions,
    progress: &(dyn Fn() + Sync),
    calibrate: &(dyn Fn(&[Measurement], &PoseCache) -> Result<Calibration> + Sync),
) -> Result<(Vec<Run>, MonteCarloSummary)> {
    opts.check()?;
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let free = &opts.calibration.free;
    let tool = MeasurementModel::tool(spec);
    // The mechanism's priors (the tool's measurement has no parameters).
    let priors: Vec<&Prior> = opts
        .calibration
        .priors
        .iter()
        .filter(|p| p.index < spec.n_params())
        .collect();
    // Every run measures the same commands and judges on the same unseen
    // ones: their poses are prepared once (nominal forward kinematics,
    // joint Hessians), and the calibrations share them.
    // With each, the first-order prediction of an equilibrium there, which
    // starts the truth's (a run's truth is a parameter error away from
    // nominal, its calibration a calibration's error from the truth).
    let training: Vec<(Vec<f64>, Pose, Option<FirstOrder>)> = poses
        .par_iter()
        .map(|t| {
            let (commands, pose) = prepare_target(mech, t)?;
            let first = FirstOrder::at_nominal(mech, &pose, &nominal);
            Ok((commands, pose, first))
        })
        .collect::<Result<_>>()?;
    let unseen: Vec<(Pose, Option<FirstOrder>)> = validation
        .par_iter()
        .map(|t| {
            let (_, pose) = prepare_target(mech, t)?;
            let first = FirstOrder::at_nominal(mech, &pose, &nominal);
            Ok((pose, first))
        })
        .collect::<Result<_>>()?;
    let normals = noise_normals(&tool, opts.noise)?;
    let cache = PoseCache::default();
    let one_run = |r: usize| -> Result<Run> {
        // The fits stop at their next evaluation once the caller's
        // cancel flag is set (their solver shares it); the runs not yet
        // started stop here.
        crate::error::check_cancel(opts.calibration.solver.cancel.as_deref())?;
        let seed = opts.seed.wrapping_add(r as u64);
        let mut rng = StdRng::seed_from_u64(seed);
        let len = Normal::new(0.0, opts.length_error.max(0.0)).expect("valid σ");
        let ang = Normal::new(0.0, opts.angle_error.max(0.0)).expect("valid σ");
        let unit = Normal::new(0.0, 1.0).expect("valid σ");
        let mut truth = nominal.clone();
        // A parameter with a tolerance is drawn from it (the machine is
        // built within its tolerances, calibrated or not).
        let prior = |i: usize| priors.iter().find(|p| p.index == i).map(|p| p.sigma);
        for &i in free {
            // Stiffness stays nominal without a tolerance: its errors are
            // a separate question.
            match (prior(i), spec.param_kind(i), spec.param_unit(i)) {
                (Some(s), ..) => truth.values[i] += s * unit.sample(&mut rng),
                (None, ParamKind::Stiffness, _) => {}
                (None, _, Unit::Radian) => truth.values[i] += ang.sample(&mut rng),
                _ => truth.values[i] += len.sample(&mut rng),
            }
        }
        for p in priors.iter().filter(|p| !free.contains(&p.index)) {
            truth.values[p.index] += p.sigma * unit.sample(&mut rng);
        }
        // The measurements `simulate` draws with this seed.
        let mut noise = StdRng::seed_from_u64(seed ^ 0x9e37_79b9);
        let error: Vec<f64> = truth
            .values
            .iter()
            .zip(&nominal.values)
            .map(|(t, n)| t - n)
            .collect();
        // The run's predictions are written into these two (the truth's,
        // the calibrated model's).
        let (mut start, mut t, mut c) = (vec![], Prediction::default(), Prediction::default());
        let mut data = training
            .iter()
            .zip(poses)
            .map(|((commands, pose, first), target)| {
                truth_at(
                    mech,
                    pose,
                    &truth,
                    first.as_ref(),
                    &error,
                    &mut start,
                    &mut t,
                )?;
                let c = commands.clone();
                Ok(reading(&tool, target, c, &t, &normals, &mut noise))
            })
            .collect::<Result<Vec<_>>>()?;
        // Numbered as the calibration numbers them, which then takes them
        // without a copy.
        crate::measurement::data::number(&mut data);
        let cal = calibrate(&data, &cache)?;
        // Accuracy on the unseen poses: the truth's exact prediction
        // (noise-free) minus the calibrated model's, in the base frame.
        // The calibration's error, for the first-order start of its
        // predictions from the truth's.
        let missed: Vec<f64> = cal
            .params
            .values
            .iter()
            .zip(&truth.values)
            .map(|(c, t)| c - t)
            .collect();
        let errors = unseen
            .iter()
            .map(|(pose, first)| {
                truth_at(
                    mech,
                    pose,
                    &truth,
                    first.as_ref(),
                    &error,
                    &mut start,
                    &mut t,
                )?;
                // From the truth's equilibrium, moved by the first-order
                // change: the calibrated parameters are micrometres from
                // the true ones.
                match first {
                    Some(f) => f.start(&t.q, &missed, &mut start),
                    None => start.clone_from(&t.q),
                }
                predict_pose_near_into(mech, pose, &cal.params, cal.model, &[], &start, &mut c)?;
                Ok(t.x.iter().zip(&c.x).map(|(a, b)| a - b).collect())
            })
            .collect::<Result<Vec<Vec<f64>>>>()?;
        progress();
        Ok(Run {
            converged: cal.converged,
            validation: error_stats(&errors, tool.units()),
            parameter_errors: free
                .iter()
                .map(|&i| cal.params.values[i] - truth.values[i])
                .collect(),
        })
    };
    // With a run for every thread, the runs are the parallel work: each
    // calibrates on its own thread.
    let serial = opts.runs >= rayon::current_num_threads();
    let runs: Vec<Result<Run>> = (0..opts.runs)
        .into_par_iter()
        .map(|r| {
            if serial {
                crate::serially(|| one_run(r))
            } else {
                one_run(r)
            }
        })
        .collect();
    crate::error::check_cancel(opts.calibration.solver.cancel.as_deref())?;
    let runs: Vec<Run> = runs.into_iter().collect::<Result<_>>()?;
    let mut rms: Vec<f64> = runs.iter().map(|r| r.validation.distance_rms).collect();
    let mut max: Vec<f64> = runs.iter().map(|r| r.validation.distance_max).collect();
    let n = runs.len().max(1) as f64;
    let names = spec.param_names();
    let summary = MonteCarloSummary {
        runs: runs.len(),
        converged: runs.iter().filter(|r| r.converged).count(),
        validation_rms_median: percentile(&mut rms, 0.5),
        validation_rms_p95: percentile(&mut rms, 0.95),
        validation_max_median: percentile(&mut max, 0.5),
        parameters: free.iter().map(|&i| names[i].to_string()).collect(),
        parameter_rms_error: (0..free.len())
            .map(|k| {
                (runs
                    .iter()
                    .map(|r| r.parameter_errors[k].powi(2))
                    .sum::<f64>()
                    / n)
                    .sqrt()
            })
            .collect(),
    };
    Ok((runs, summary))
}
