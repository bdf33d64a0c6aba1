//! `gcode`: rewrite a G-code program's moves so that a controller running the
//! nominal kinematics makes the calibrated machine reach the programmed points.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Calibrated parameters (flat TOML): the real machine.
    #[arg(long, value_name = "P.toml")]
    pub params: PathBuf,
    /// The controller's own parameter values (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub controller: Option<PathBuf>,
    /// Model of the real machine: exact (deflections included) or rigid.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::INVERTIBLE_MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// The G-code program to rewrite.
    #[arg(long = "in", value_name = "PROGRAM.gcode")]
    pub input: PathBuf,
    /// Added to the programmed coordinates to give tool coordinates (mm; degrees for angles), one per tool axis.
    #[arg(long, value_name = "X,Y,…", allow_hyphen_values = true)]
    pub offset: Option<String>,
    /// Split moves longer than this (mm) so that the correction follows the path.
    #[arg(long, value_name = "MM")]
    pub max_segment: Option<f64>,
    /// Read the program as this firmware does: strict (what Klipper,
    /// RepRapFirmware and Marlin all read alike; the rest refused), klipper,
    /// reprap or marlin.
    #[arg(long, default_value = "strict", value_parser = dialect)]
    pub dialect: pkmcal_io::gcode::Dialect,
    /// The rewritten program (`-` for standard output).
    #[arg(long, value_name = "OUT.gcode")]
    pub out: PathBuf,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                Some(self.params.clone()),
                self.controller.clone(),
                Some(self.input.clone()),
            ],
            [self.out.clone()],
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::gcode::run_gcode(
        run,
        pkmcal_io::gcode::GcodeConfig {
            mechanism: a.mech.mechanism,
            params: a.params,
            controller: a.controller,
            model: a.model,
            load: a.load.values(),
            input: a.input,
            offset: a.offset,
            max_segment: a.max_segment,
            dialect: a.dialect,
            out: a.out,
        },
    )
}

fn dialect(s: &str) -> Result<pkmcal_io::gcode::Dialect, String> {
    pkmcal_io::gcode::Dialect::from_name(s).ok_or_else(|| {
        format!(
            "unknown dialect `{s}`; choose one of {}",
            pkmcal_io::gcode::Dialect::ALL.map(|d| d.name()).join(", ")
        )
    })
}
