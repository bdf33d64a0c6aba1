//! `drift`: has the machine changed since its last calibration, or only the
//! noise? Two saved calibrations compared, or one against nominal.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// The earlier calibration's report (`calibrate --report`); without it,
    /// the nominal values.
    #[arg(long, value_name = "OLD.json")]
    pub old: Option<PathBuf>,
    /// The later calibration's report.
    #[arg(long, value_name = "NEW.json")]
    pub new: PathBuf,
    /// The familywise false-alarm rate (the chance of calling any parameter
    /// drifted when none is).
    #[arg(long, default_value_t = pkmcal::identify::DEFAULT_ALPHA)]
    pub alpha: f64,
    /// Write the comparison as JSON.
    #[arg(long, value_name = "DRIFT.json")]
    pub out: Option<PathBuf>,
    /// Targets spread over the workspace (a plain grid) where the change at
    /// the tool is judged (0: none).
    #[arg(long, default_value_t = 100, value_name = "N")]
    pub grid: usize,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.old.clone(),
                Some(self.new.clone()),
            ],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::drift::run_drift(
        run,
        pkmcal_io::drift::DriftConfig {
            mechanism: a.mech.mechanism,
            old: a.old,
            new: a.new,
            alpha: a.alpha,
            out: a.out,
            grid: a.grid,
        },
    )
}
