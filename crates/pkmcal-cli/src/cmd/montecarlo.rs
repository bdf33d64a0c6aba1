//! `montecarlo`: the accuracy a measurement plan gives after calibration, by
//! simulation.

use crate::args;
use anyhow::Result;
use pkmcal::{CalibrationOptions, Mechanism, MonteCarloOptions, Request, monte_carlo};
use pkmcal_io::Run;
use pkmcal_io::csv::csv_bytes;
use pkmcal_io::data::read_plan_poses;
use pkmcal_io::description::read_description;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Measurement plan: CSV with target_<axis> columns (e.g. from `plan`).
    #[arg(long, value_name = "POSES.csv")]
    pub poses: PathBuf,
    /// Number of simulated calibrations (at most 1,000,000).
    #[arg(value_parser = args::values::runs, long, default_value_t = 200)]
    pub runs: usize,
    /// Measurement noise on each length coordinate, mm.
    #[arg(value_parser = args::values::length_noise, long, default_value_t = 0.002, value_name = "MM")]
    pub noise: f64,
    /// Measurement noise on each angle coordinate, rad (default: the length
    /// noise over a 200 mm lever arm).
    #[arg(value_parser = args::values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Model used to calibrate.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    /// Standard deviation of the random errors of the free parameters in mm
    /// (lengths, positions, offsets of prismatic actuators); a parameter with
    /// a tolerance is drawn from its tolerance instead.
    #[arg(value_parser = args::values::length_noise, long, default_value_t = 0.3, value_name = "MM")]
    pub length_error: f64,
    /// Standard deviation of the random errors of the free parameters in rad
    /// (encoder offsets of revolute actuators, axis angles); a parameter with
    /// a tolerance is drawn from its tolerance instead.
    #[arg(
        value_parser = args::values::angle_noise,
        long,
        default_value_t = 0.001,
        value_name = "RAD",
        alias = "offset-error"
    )]
    pub angle_error: f64,
    /// Unseen poses on which accuracy is judged.
    #[arg(value_parser = args::values::targets, long, alias = "validation", default_value_t = 50, value_name = "N")]
    pub validation_targets: usize,
    /// Output CSV with one row per run.
    #[arg(long, value_name = "RUNS.csv")]
    pub out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone(), Some(self.poses.clone())],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, c: Args) -> Result<()> {
    let description = read_description(run, c.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = &description.mech;
    let spec = mech.spec();
    let mut noise = pkmcal::Noise::lengths(c.noise);
    if let Some(a) = c.angle_noise {
        noise.angle = a;
    }
    let poses = read_plan_poses(run, &c.poses, mech, &units)?;
    let tool = pkmcal::MeasurementModel::tool(spec);
    let mut request = Request::new(c.model);
    c.params_set.apply(&mut request);
    c.priors.apply(&mut request)?;
    let mut cal = CalibrationOptions::new(spec, c.model);
    crate::cmd::note_renamed(run, spec, &request);
    (cal.priors, cal.free) = request
        .priors_and_free(spec, &tool, &description.tolerances)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    let validation = pkmcal::validation_targets(mech, c.validation_targets, c.seed)?;
    let bar = run.bar(c.runs as u64, false, "calibrations", 1);
    let opts = MonteCarloOptions {
        runs: c.runs,
        noise,
        seed: c.seed,
        length_error: c.length_error,
        angle_error: c.angle_error,
        calibration: cal,
    };
    let start = std::time::Instant::now();
    let (runs, summary) = monte_carlo(mech, &poses, &validation, &opts, &|| bar.inc(1))?;
    bar.finish();
    let secs = start.elapsed().as_secs_f64();
    say!(
        "{} simulated calibrations ({} model) from {} poses of {}: {} converged ({:.0} calibrations/s)",
        summary.runs,
        c.model.name(),
        poses.len(),
        c.poses.display(),
        summary.converged,
        summary.runs as f64 / secs
    );
    let n_priors = opts.calibration.priors.len();
    say!(
        "random errors: {}σ {} mm on free parameters in mm, σ {} rad on free parameters in rad{}; noise σ {} mm on lengths{}",
        if n_priors > 0 {
            format!(
                "drawn from {} (also the fits' priors), ",
                pkmcal::error::count(n_priors, "tolerance", "tolerances")
            )
        } else {
            String::new()
        },
        pkmcal::error::shown(c.length_error),
        pkmcal::error::shown(c.angle_error),
        if n_priors > 0 { " otherwise" } else { "" },
        pkmcal::error::shown(noise.length),
        if spec.tool_units.contains(&pkmcal::Unit::Radian) {
            format!(", {} rad on angles", pkmcal::error::shown(noise.angle))
        } else {
            String::new()
        }
    );
    say!(
        "accuracy on {} unseen poses after calibration: RMS median {:.4} mm, 95th percentile {:.4} mm; max error median {:.4} mm",
        c.validation_targets,
        summary.validation_rms_median,
        summary.validation_rms_p95,
        summary.validation_max_median
    );
    say!("parameter errors (RMS over runs):");
    for (n, e) in summary.parameters.iter().zip(&summary.parameter_rms_error) {
        let i = spec.param_index(n)?;
        say!("  {n:<6} {e:>12.4e} {}", spec.param_unit(i));
    }
    if let Some(out) = &c.out {
        let mut header = vec![
            "run".to_string(),
            "converged".into(),
            "validation_rms".into(),
            "validation_max".into(),
        ];
        header.extend(summary.parameters.iter().map(|n| format!("error_{n}")));
        let rows: Vec<Vec<f64>> = runs
            .iter()
            .enumerate()
            .map(|(i, r)| {
                [
                    i as f64,
                    f64::from(u8::from(r.converged)),
                    r.validation.distance_rms,
                    r.validation.distance_max,
                ]
                .into_iter()
                .chain(r.parameter_errors.iter().copied())
                .collect()
            })
            .collect();
        run.files.stage(out, &csv_bytes(&header, &rows))?;
        say!("runs -> {}", out.display());
    }
    Ok(())
}
