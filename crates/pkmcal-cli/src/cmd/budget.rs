//! `budget`: how tight the parts must be: the tool error over the workspace
//! that the parameter tolerances give, each tolerance's share, and what a
//! planned calibration would leave.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Tolerances NAME=SIGMA (one standard deviation in the parameter's unit,
    /// or a percentage of its nominal value: k1=20%), comma-separated or
    /// repeated; they replace the mechanism file's [tolerances] for the same
    /// names.
    #[arg(long, value_name = "NAME=SIGMA")]
    pub tolerance: Vec<String>,
    /// Machines drawn from the tolerances to check the first-order figures
    /// through the exact model (0: none).
    #[arg(long, default_value_t = 3000, value_name = "N")]
    pub samples: usize,
    /// Random seed of the samples.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Targets spread over the workspace (a plain grid) the error is taken
    /// over.
    #[arg(value_parser = args::values::count, long, default_value_t = 200, value_name = "N")]
    pub grid: usize,
    /// A planned calibration: CSV with target_<axis> columns (e.g. from
    /// `plan`); the budget then says what calibrating there would leave.
    #[arg(long, value_name = "POSES.csv")]
    pub poses: Option<PathBuf>,
    /// The planned calibration's noise on each length coordinate, mm.
    #[arg(value_parser = args::values::length_noise, long, default_value_t = 0.002, value_name = "MM")]
    pub noise: f64,
    /// Its noise on each angle coordinate, rad (default: the length noise
    /// over a 200 mm lever arm).
    #[arg(value_parser = args::values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    /// Write the budget as JSON.
    #[arg(long, value_name = "BUDGET.json")]
    pub out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone(), self.poses.clone()],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::budget::run_budget(
        run,
        pkmcal_io::budget::BudgetConfig {
            mechanism: a.mech.mechanism,
            tolerances: a.tolerance,
            samples: a.samples,
            seed: a.seed,
            targets: a.grid,
            poses: a.poses,
            noise: a.noise,
            angle_noise: a.angle_noise,
            model: a.model,
            json: a.out,
        },
    )
}
