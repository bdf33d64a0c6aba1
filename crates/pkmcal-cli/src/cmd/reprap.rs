//! `reprap`: calibrate a linear delta printer run by RepRapFirmware from its
//! M665/M666 settings and probed heights.

use crate::args;
use anyhow::Result;
use pkmcal::{Mechanism, Request};
use pkmcal_io::Run;
use pkmcal_io::firmware::reprap::RrfPrinter;
use pkmcal_io::firmware::{self, Firmware};
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
    /// Parameters to identify (`--free`, comma separated): RepRapFirmware's
    /// 6 factors by default (delta_radius, angle_a, angle_b and the endstop
    /// errors da, db, dc) or more (arm_a, arm_b, arm_c for the diagonals, or
    /// `diagonal` for one shared by the three towers, as the firmware's 7-
    /// and 9-factor calibrations fit it; bed.rx, bed.ry for the bed tilts
    /// M666 A B); `--fix` removes names.
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    /// Write the new M665 and M666 lines here (never over --config).
    /// Warn of a written value whose σ exceeds this, in the value's own
    /// unit (mm, °, %).
    #[arg(long, value_name = "SIGMA", default_value_t = pkmcal_io::firmware::DEFAULT_MAX_SIGMA, allow_negative_numbers = true, value_parser = args::values::max_sigma)]
    pub max_sigma: f64,
    #[arg(long, value_name = "NEW.g")]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub physical: args::PhysicalArgs,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        self.physical.paths(
            [Some(self.config.clone()), Some(self.probes.clone())],
            self.out.as_ref(),
        )
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let mut request = Request::new(pkmcal::Model::Exact);
    a.params_set.apply(&mut request);
    a.physical.apply(&mut request)?;
    let printer = RrfPrinter::read(run, &a.config, &a.probes, request.free.as_deref())?;
    if a.physical.physical {
        return crate::cmd::physical::run(
            run,
            &printer,
            request,
            &a.probes.display().to_string(),
            crate::cmd::physical::Output {
                out: a.out.as_deref(),
                physical: &a.physical,
                previous: None,
                written: "(replace the M665 and M666 lines of the file the firmware takes them from with these two)",
                max_sigma: a.max_sigma,
            },
        );
    }
    let calibrated = firmware::calibrate(&printer, request)?;
    let study = &calibrated.study;
    let (cal, acc, before, after) = (
        &study.calibration,
        &study.accuracy,
        &study.before,
        &study.after,
    );
    let spec = calibrated.mech.spec();
    let new = printer
        .delta
        .identified(spec, &cal.params, &cal.measurement)?;
    let heights = |e: &[Vec<f64>]| -> (f64, f64) {
        let v: Vec<f64> = e.iter().map(|r| r[0]).collect();
        let max = v.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
        (max, rms)
    };
    let ((bm, br), (am, ar)) = (heights(before), heights(after));
    say!(
        "{} probe heights from {} with the geometry of {} (RepRapFirmware), {} parameters free: {}",
        acc.poses,
        a.probes.display(),
        a.config.display(),
        calibrated.free_names.len(),
        calibrated.free_names.join(" ")
    );
    say!("{}", cal.termination.reason());
    say!(
        "height errors: before max {bm:.4} mm, RMS {br:.4} mm; after max {am:.4} mm, RMS {ar:.4} mm"
    );
    for w in &cal.warnings {
        say!("warning: {}\n  hint: {}", w.message, crate::words::hint(w));
    }
    say!(
        "\nbefore:\n{}after:\n{}",
        printer.delta.gcode(),
        new.gcode()
    );
    let written = super::print_written(&printer, &calibrated, "written value")?;
    super::print_checks(&printer, &calibrated, &written, a.max_sigma)?;
    let note = firmware::out_file(
        &printer,
        &printer.updated(spec, &cal.params, &cal.measurement)?,
        &a.probes.display().to_string(),
        acc.poses,
        false,
    );
    if let Some(out) = &a.out {
        run.files.stage(out, note.as_bytes())?;
        say!(
            "new M665/M666 -> {} (replace the M665 and M666 lines of the file the firmware takes them from with these two, and keep that file's other lines: config-override.g when config.g runs M501, else config.g)",
            out.display()
        );
    }
    Ok(())
}
