//! `gcode`: rewrite a G-code program's moves so that a controller running the
//! nominal kinematics makes the calibrated machine reach the programmed points.

use crate::args;
use anyhow::Result;
use pkmcal::error::count;
use pkmcal::{CompensationOptions, Mechanism, predistort};
use pkmcal_io::Run;
use pkmcal_io::description::read_description;
use pkmcal_io::gcode::Rewrite;
use pkmcal_io::params::{params_or_nominal, read_params};
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
    /// The G-code program to rewrite (`--in` is its old spelling).
    #[arg(long, alias = "in", value_name = "PROGRAM.gcode")]
    pub program: PathBuf,
    /// Added to the programmed coordinates to give tool coordinates (mm; degrees for angles), one per tool axis.
    #[arg(long, value_name = "X,Y,…", allow_hyphen_values = true, value_parser = args::values::numbers)]
    pub offset: Option<args::Numbers>,
    /// Split moves longer than this (mm) so that the correction follows the path.
    #[arg(long, value_name = "MM", value_parser = args::values::segment)]
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
                Some(self.program.clone()),
            ],
            [self.out.clone()],
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let mech = read_description(run, a.mech.mechanism.as_deref())?.mech;
    let spec = mech.spec();
    let real = read_params(run, &a.params, &mech)?;
    let controller = params_or_nominal(run, a.controller.as_deref(), &mech)?;
    let force = pkmcal::identify::request::checked_load(
        &a.load.values(),
        &mech,
        &real,
        pkmcal::Field::Load,
    )?;
    let opts = CompensationOptions {
        force,
        preload: vec![],
    };
    let settings = Rewrite {
        dialect: a.dialect,
        offset: a.offset.map(|w| w.0).unwrap_or_default(),
        max_segment: a.max_segment,
    };
    let text = run
        .files
        .read(&a.program, pkmcal_io::output::InputKind::Data)
        .map_err(|e| e.named("G-code file"))?;
    let out = pkmcal_io::gcode::rewrite(
        &a.program,
        &text,
        &spec.tool_axes,
        &spec.tool_units,
        &settings,
        |target| predistort(&mech, &controller, &real, target, a.model, &opts),
    )?;
    if !out.as_written.is_empty() {
        let shown: Vec<String> = out
            .as_written
            .iter()
            .take(5)
            .map(|l| l.to_string())
            .collect();
        crate::note!(
            "{} sent as written ({} {}{}): the position of some axis was not known yet (after the start, a G28 or a start macro only the firmware knows it); give every axis on the first move to have it corrected too",
            count(out.as_written.len(), "move", "moves"),
            if out.as_written.len() == 1 {
                "line"
            } else {
                "lines"
            },
            shown.join(", "),
            if out.as_written.len() > 5 {
                ", …"
            } else {
                ""
            }
        );
    }
    run.files.stage(&a.out, &out.bytes)?;
    let (f, u) = pkmcal::Unit::Millimetre.readable(out.worst);
    crate::note!(
        "rewrote {} as {} pre-distorted {} (largest shift {:.3} {u}, {} model) -> {}",
        count(out.moves, "move", "moves"),
        out.segments,
        if out.segments == 1 { "move" } else { "moves" },
        out.worst * f,
        a.model.name(),
        a.out.display()
    );
    Ok(())
}

fn dialect(s: &str) -> Result<pkmcal_io::gcode::Dialect, String> {
    pkmcal_io::gcode::Dialect::from_name(s).ok_or_else(|| {
        format!(
            "unknown dialect `{s}`; choose one of {}",
            pkmcal_io::gcode::Dialect::ALL.map(|d| d.name()).join(", ")
        )
    })
}
