//! `compensate`: the actuator commands (or Cartesian targets) that bring the
//! tool to targets under calibrated parameters.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Calibrated parameters (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Targets: CSV with one column target_<axis> per tool axis.
    #[arg(
        long,
        value_name = "T.csv",
        required_unless_present = "grid",
        conflicts_with = "grid"
    )]
    pub targets: Option<PathBuf>,
    /// A regular grid of corrections instead of a targets file: per tool axis
    /// `start:stop:step` (gridded) or one value (held), e.g.
    /// `x=-100:100:10,y=50:250:10`; axes not named are held at the middle of
    /// the workspace box. Written as CSV, or JSON if --out ends in .json, with
    /// the interpolation error checked at the cell centres.
    #[arg(
        long,
        value_name = "AXIS=START:STOP:STEP,…",
        allow_hyphen_values = true
    )]
    pub grid: Option<String>,
    /// Cartesian pre-distortion for a controller that accepts only tool
    /// targets: write the target to send (command_<axis>) so that the real
    /// machine reaches the wanted one, instead of actuator commands.
    #[arg(long, conflicts_with = "grid")]
    pub cartesian: bool,
    /// The controller's own parameter values (flat TOML) for --cartesian;
    /// nominal if omitted. (Corrections are always against the nominal model.)
    #[arg(long, value_name = "P.toml")]
    pub controller: Option<PathBuf>,
    /// Model to invert: exact (deflections included) or rigid.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::INVERTIBLE_MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Actuator torques (N·m) whose internal part is held as a preload.
    #[arg(long, value_name = "T1,T2,T3", allow_hyphen_values = true)]
    pub preload: Option<String>,
    /// Report unreachable or singular targets and skip them instead of stopping.
    #[arg(long)]
    pub skip_unreachable: bool,
    /// Output CSV: targets, commands, corrections (delta_<actuator>, to add to
    /// the nominal model's commands) and the actuators' internal torques
    /// (torque_<actuator> in N·m) or forces (force_<actuator> in N).
    #[arg(long, value_name = "COMMANDS.csv")]
    pub out: PathBuf,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.params.clone(),
                self.targets.clone(),
                self.controller.clone(),
            ],
            [self.out.clone()],
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::usecal::run_compensate(
        run,
        pkmcal_io::usecal::CompensateConfig {
            mechanism: a.mech.mechanism,
            params: a.params,
            targets: a.targets,
            grid: a.grid,
            cartesian: a.cartesian,
            controller: a.controller,
            model: a.model,
            load: a.load.values(),
            preload: a.preload,
            skip_unreachable: a.skip_unreachable,
            out: a.out,
        },
    )
}
