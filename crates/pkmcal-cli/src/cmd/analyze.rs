//! `analyze`: the identifiability of the parameters from a data set, without
//! fitting.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Measurements (only the commands are used).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    #[command(flatten)]
    pub weighing: args::WeighingNoiseArgs,
    /// Parameter values at which to analyse; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Output: JSON report of the analysis.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    #[command(flatten)]
    pub instrument: args::InstrumentArgs,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                Some(self.data.clone()),
                self.params.clone(),
                self.instrument.setup.clone(),
                self.instrument.distances.clone(),
            ],
            self.report.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::calibrate::run_analyze(
        run,
        pkmcal_io::calibrate::AnalyzeConfig {
            mechanism: a.mech.mechanism,
            data: a.data,
            model: a.model,
            free: a.params_set.free,
            fix: a.params_set.fix,
            params: a.params,
            load: a.load.values(),
            report: a.report,
            setup: a.instrument.setup,
            frame: a.instrument.frame,
            axes: a.instrument.axes,
            distances: a.instrument.distances,
            tolerances: a.priors.tolerance,
            no_tolerances: a.priors.no_tolerances,
            noise: a.weighing.noise,
            angle_noise: a.weighing.angle_noise,
        },
    )
}
