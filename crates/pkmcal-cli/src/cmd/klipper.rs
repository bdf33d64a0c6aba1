//! `klipper`: calibrate a linear delta printer from its Klipper configuration
//! and write Klipper's values back.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The printer's Klipper configuration (kinematics: delta), with the
    /// [delta_calibrate] probe results (height0, height0_pos, …) that
    /// DELTA_CALIBRATE and SAVE_CONFIG wrote.
    #[arg(long, value_name = "printer.cfg")]
    pub config: PathBuf,
    /// Parameters to identify, comma separated: Klipper's (`default`:
    /// delta_radius, angle_a, angle_b, da, db, dc; the d's are endstop errors)
    /// or more (arm_a, arm_b, arm_c, angle_c, the towers' tilts a.tilt1, …).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed, comma separated (removed from the free set).
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
    /// Write the configuration with the new values (in its SAVE_CONFIG block,
    /// as Klipper writes them) here; never over --config.
    #[arg(long, value_name = "NEW.cfg")]
    pub out: Option<PathBuf>,
    /// Also write the printer as a pkmcal mechanism (mechanism.toml), the
    /// probe data (probes.csv) and the identified parameters
    /// (calibration.toml) here, for the other commands.
    #[arg(long, value_name = "DIR")]
    pub out_dir: Option<PathBuf>,
    /// How probe heights and DELTA_ANALYZE distances are weighed against
    /// each other: `klipper` (Klipper's fixed ratio: heights weigh
    /// n_distances / (0.5 · n_probed) times a distance; the default, which
    /// predicted left-out readings better on 10 of 11 real printers) or
    /// `estimated` (a noise level each, estimated from the residuals; 7
    /// heights and 12 distances leave its ratio uncertain by two decades)
    /// or `shrunk[:N]` (the estimates shrunk towards Klipper's ratio, worth
    /// N readings a group, 10 by default; on the real printers more
    /// pseudo-readings predicted better, up to Klipper's ratio).
    #[arg(long, default_value = "klipper", value_parser = args::values::weighting)]
    pub weighting: pkmcal_io::klipper::Weighting,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        use pkmcal_io::klipper::{DISTANCES_FILE, OUT_DIR_FILES};
        let mut out: Vec<PathBuf> = self.out.iter().cloned().collect();
        let mut dirs = vec![];
        if let Some(d) = &self.out_dir {
            out.extend(pkmcal_io::output::in_dir(d, &OUT_DIR_FILES)?);
            out.extend(pkmcal_io::output::in_dir(d, &[DISTANCES_FILE])?);
            dirs.push(d.clone());
        }
        Ok(args::Paths::new([Some(self.config.clone())], out).with_dirs(dirs))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::klipper::run_klipper(
        run,
        pkmcal_io::klipper::KlipperConfig {
            config: a.config,
            free: a.free,
            fix: a.fix,
            out: a.out,
            out_dir: a.out_dir,
            weighting: a.weighting,
        },
    )
}
