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
    #[command(flatten)]
    pub weighing: args::WeighingNoiseArgs,
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
            noise: a.weighing.noise,
            angle_noise: a.weighing.angle_noise,
        },
    )
}
