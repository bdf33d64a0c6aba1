//! `reprap`: calibrate a linear delta printer run by RepRapFirmware from its
//! M665/M666 settings and probed heights.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The G-code file that sets the delta's geometry: config.g, or
    /// config-override.g (every M665 and M666 line is read, later ones
    /// overriding).
    #[arg(long, value_name = "config.g")]
    pub config: PathBuf,
    /// The probe results: CSV with columns x, y (where the probe touched,
    /// mm) and z (the height at which it triggered, as `G30 S-1` reports it,
    /// mm).
    #[arg(long, value_name = "PROBES.csv")]
    pub probes: PathBuf,
    /// Parameters to identify, comma separated: RepRapFirmware's 6 factors
    /// (`default`: delta_radius, angle_a, angle_b and the endstop errors da,
    /// db, dc) or more (arm_a, arm_b, arm_c for the diagonals, or `diagonal`
    /// for one shared by the three towers, as the firmware's 7- and 9-factor
    /// calibrations fit it; bed.rx, bed.ry for the bed tilts M666 A B).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed, comma separated (removed from the free set).
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
    /// Write the new M665 and M666 lines here (never over --config).
    #[arg(long, value_name = "NEW.g")]
    pub out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [Some(self.config.clone()), Some(self.probes.clone())],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::reprap::run_reprap(
        run,
        pkmcal_io::reprap::ReprapConfig {
            config: a.config,
            probes: a.probes,
            free: a.free,
            fix: a.fix,
            out: a.out,
        },
    )
}
