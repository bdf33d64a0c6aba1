//! `plan`: choose measurement poses that make the parameters most observable.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Number of poses to choose.
    #[arg(value_parser = args::values::count, long, value_name = "N")]
    pub count: usize,
    /// Spacing of the candidate lattice over the usable workspace, mm (an
    /// axis in rad is spaced by it over the mechanism's lever arm).
    #[arg(value_parser = args::values::positive, long, default_value_t = 6.0, value_name = "SPACING")]
    pub candidates: f64,
    /// Most candidates: a lattice with more usable points is thinned evenly
    /// to this many (a 6-DOF workspace has many at any spacing).
    #[arg(value_parser = args::values::count, long, default_value_t = 4000, value_name = "N")]
    pub max_candidates: usize,
    /// Observability index to maximise.
    #[arg(long, default_value = "O5", value_parser = ["O1", "O3", "O5"], ignore_case = true)]
    pub criterion: String,
    /// Model whose identification Jacobian is used.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    /// Expected parameters (nominal if omitted).
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    /// With tolerances: the instrument's noise on each length coordinate
    /// (mm), which weighs what the poses tell against what the tolerances
    /// already tell.
    #[arg(value_parser = args::values::length_noise, long, default_value_t = 0.002, value_name = "MM")]
    pub noise: f64,
    /// With tolerances: the noise on each angle coordinate, rad (default:
    /// the length noise over a 200 mm lever arm).
    #[arg(value_parser = args::values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Output CSV: targets and commands (target_x,target_y,q1,q2,q3 for the reference).
    #[arg(long, value_name = "POSES.csv")]
    pub out: PathBuf,
    /// Also write the plain grid of the same size (the baseline), same columns.
    #[arg(long, value_name = "GRID.csv")]
    pub grid_out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone(), self.params.clone()],
            std::iter::once(self.out.clone()).chain(self.grid_out.clone()),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::usecal::run_plan(
        run,
        pkmcal_io::usecal::PlanConfig {
            mechanism: a.mech.mechanism,
            count: a.count,
            candidates: a.candidates,
            max_candidates: a.max_candidates,
            criterion: a.criterion.parse()?,
            model: a.model,
            params: a.params,
            free: a.params_set.free,
            fix: a.params_set.fix,
            out: a.out,
            grid_out: a.grid_out,
            tolerances: a.priors.tolerance,
            no_tolerances: a.priors.no_tolerances,
            noise: a.noise,
            angle_noise: a.angle_noise,
        },
    )
}
