//! `montecarlo`: the accuracy a measurement plan gives after calibration, by
//! simulation.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
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
    #[arg(value_parser = args::values::count, long, default_value_t = 50, value_name = "N")]
    pub validation: usize,
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

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::usecal::run_montecarlo(
        run,
        pkmcal_io::usecal::MonteCarloConfig {
            mechanism: a.mech.mechanism,
            poses: a.poses,
            runs: a.runs,
            noise: a.noise,
            seed: a.seed,
            model: a.model,
            free: a.params_set.free,
            fix: a.params_set.fix,
            length_error: a.length_error,
            angle_error: a.angle_error,
            angle_noise: a.angle_noise,
            validation: a.validation,
            out: a.out,
            tolerances: a.priors.tolerance,
            no_tolerances: a.priors.no_tolerances,
        },
    )
}
