//! `klipper`: calibrate a linear or rotary delta printer from its Klipper
//! configuration and write Klipper's values back.

use crate::args;
use anyhow::Context as _;
use anyhow::Result;
use pkmcal::{Mechanism, Params, Request};
use pkmcal_io::Run;
use pkmcal_io::firmware::klipper::{
    self, DISTANCES_FILE, KlipperPrinter, OUT_DIR_FILES, Weighting, klipper_z_weight,
};
use pkmcal_io::firmware::klipper_rotary::{self, RotaryPrinter};
use pkmcal_io::firmware::{self, Firmware, Spread};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The printer's Klipper configuration (kinematics: delta or
    /// rotary_delta), with the [delta_calibrate] probe results (height0,
    /// height0_pos, …) that DELTA_CALIBRATE and SAVE_CONFIG wrote.
    #[arg(long, value_name = "printer.cfg")]
    pub config: PathBuf,
    /// Parameters to identify (`--free`, comma separated): Klipper's by
    /// default (delta_radius, angle_a, angle_b, da, db, dc; the d's are
    /// endstop errors; with DELTA_ANALYZE distances arm_a, arm_b, arm_c too)
    /// or more (arm_a, arm_b, arm_c, angle_c, the towers' tilts a.tilt1, …);
    /// a rotary delta's: hb (shoulder_height), dq1, dq2, dq3 (endstop
    /// angles), with distances rb (shoulder_radius), arm1.angle, arm2.angle
    /// too, or more (arm3.angle, la1…, lf1… for the upper and lower arms);
    /// `--fix` removes names.
    #[command(flatten)]
    pub params_set: args::FreeArgs,
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
    pub weighting: Weighting,
    #[command(flatten)]
    pub physical: args::PhysicalArgs,
    /// With --physical: the printer's previous configuration (with the
    /// SAVE_CONFIG probe results of an earlier DELTA_CALIBRATE): whether the
    /// physical printer changed since, beyond both calibrations'
    /// uncertainty.
    #[arg(long, value_name = "OLD.cfg")]
    pub previous: Option<PathBuf>,
    /// Warn of a written value whose σ exceeds this, in the value's own
    /// unit (mm, °, %).
    #[arg(long, value_name = "SIGMA", default_value_t = pkmcal_io::firmware::DEFAULT_MAX_SIGMA, allow_negative_numbers = true, value_parser = args::values::max_sigma)]
    pub max_sigma: f64,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        let mut out: Vec<PathBuf> = self.out.iter().cloned().collect();
        out.extend(self.physical.outputs()?);
        let mut dirs = self.physical.dirs();
        if let Some(d) = &self.out_dir {
            out.extend(pkmcal_io::output::in_dir(d, &OUT_DIR_FILES)?);
            out.extend(pkmcal_io::output::in_dir(d, &[DISTANCES_FILE])?);
            dirs.push(d.clone());
        }
        Ok(args::Paths::new(
            [Some(self.config.clone()), self.previous.clone()]
                .into_iter()
                .chain(self.physical.inputs()),
            out,
        )
        .with_dirs(dirs))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    pkmcal_io::firmware::choices::Choices {
        out_dir: a.out_dir.is_some(),
        previous: a.previous.is_some(),
        ..a.physical.choices()
    }
    .check()?;
    let (text, ini) = klipper::read_config(run, &a.config)?;
    let previous = match (&a.previous, a.physical.physical) {
        (Some(p), true) if !klipper_rotary::is_rotary(&ini) => {
            let before = KlipperPrinter::read(run, p, a.weighting)
                .with_context(|| format!("--previous {}", p.display()))?;
            // Its readings as this configuration reads them (the same
            // geometry labels both).
            let (text, ini) = klipper::read_config(run, &a.config)?;
            Some(
                KlipperPrinter::from_parsed(&a.config, text, ini, a.weighting)?
                    .with_readings_of(before),
            )
        }
        _ => None,
    };
    if a.physical.physical {
        let mut request = Request::new(pkmcal::Model::Exact);
        a.params_set.apply(&mut request);
        a.physical.apply(&mut request)?;
        let output = crate::cmd::physical::Output {
            out: a.out.as_deref(),
            physical: &a.physical,
            written: "(values in its SAVE_CONFIG block)",
            previous: previous
                .as_ref()
                .zip(a.previous.as_ref())
                .map(|(p, path)| (p as &dyn Firmware, path.display().to_string())),
            max_sigma: a.max_sigma,
        };
        let source = a.config.display().to_string();
        if klipper_rotary::is_rotary(&ini) {
            let printer = RotaryPrinter::from_parsed(&a.config, text, ini, a.weighting)?;
            return crate::cmd::physical::run(run, &printer, request, &source, output);
        }
        let printer = KlipperPrinter::from_parsed(&a.config, text, ini, a.weighting)?;
        return crate::cmd::physical::run(run, &printer, request, &source, output);
    }
    if klipper_rotary::is_rotary(&ini) {
        let printer = RotaryPrinter::from_parsed(&a.config, text, ini, a.weighting)?;
        let (n, z_weight) = (printer.delta.distances.len(), printer.z_weight());
        return report(run, &a, &printer, n, z_weight);
    }
    let printer = KlipperPrinter::from_parsed(&a.config, text, ini, a.weighting)?;
    let (n, z_weight) = (
        printer.delta.distances.len(),
        klipper_z_weight(&printer.delta),
    );
    report(run, &a, &printer, n, z_weight)
}

/// Calibrate a Klipper printer holding `n_distances` distances and whose
/// heights Klipper weighs `z_weight` times a distance; print and write as
/// asked.
fn report(
    run: &Run<'_>,
    a: &Args,
    printer: &dyn Firmware,
    n_distances: usize,
    z_weight: f64,
) -> Result<()> {
    let mut request = Request::new(pkmcal::Model::Exact);
    a.params_set.apply(&mut request);
    a.physical.apply(&mut request)?;
    let calibrated = firmware::calibrate(printer, request)?;
    let (mech, readings, study) = (&calibrated.mech, &calibrated.readings, &calibrated.study);
    let spec = mech.spec();
    let measurement = &readings.measurement;
    let heights = &readings.poses;
    let cal = &study.calibration;
    let nominal = Params::nominal(spec);
    let before =
        firmware::probe_errors(mech, measurement, &nominal, measurement.nominal(), heights)?;
    let after = firmware::probe_errors(mech, measurement, &cal.params, &cal.measurement, heights)?;
    say!(
        "{} probe heights{} from {} (Klipper), {} parameters free: {}",
        heights.len(),
        if n_distances == 0 {
            String::new()
        } else {
            format!(" and {n_distances} distances measured on the calibration object")
        },
        a.config.display(),
        calibrated.free_names.len(),
        calibrated.free_names.join(" ")
    );
    say!("{}", cal.termination.reason());
    let (before, after) = (Spread::of(&before), Spread::of(&after));
    say!(
        "height errors: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm",
        before.max,
        before.rms,
        after.max,
        after.rms
    );
    if n_distances > 0
        && let Some(d) = &study.accuracy.distances
    {
        let weighing = match a.weighting {
            Weighting::Estimated => format!(
                "noise σ: heights {}, distances {}, estimated apart",
                noise_of(cal, "probe"),
                noise_of(cal, pkmcal::DISTANCE_AXIS)
            ),
            Weighting::Klipper => "heights and distances weighed as Klipper weighs them".into(),
            Weighting::Shrunk(n) => format!(
                "noise σ: heights {}, distances {}, estimated and shrunk towards Klipper's ratio with {n} pseudo-readings",
                noise_of(cal, "probe"),
                noise_of(cal, pkmcal::DISTANCE_AXIS)
            ),
        };
        say!(
            "distance errors: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm ({weighing})",
            d.before_max,
            d.before_rms,
            d.after_max,
            d.after_rms,
        );
        // How well the data fix the weighting: the variance ratio with its
        // interval, against Klipper's fixed ratio.
        let group = |axis: &str| cal.noise.iter().find(|g| g.axes.iter().any(|a| a == axis));
        if let (Some(h), Some(dg), Weighting::Shrunk(n)) =
            (group("probe"), group(pkmcal::DISTANCE_AXIS), a.weighting)
        {
            say!(
                "variance ratio heights/distances: {:.3}, from the data's {:.1} and {:.1} degrees of freedom and Klipper's fixed {:.3} worth {n} readings a group",
                (h.sigma / dg.sigma).powi(2),
                h.redundancy.unwrap_or(f64::NAN),
                dg.redundancy.unwrap_or(f64::NAN),
                1.0 / z_weight
            );
        }
        if let (Some(h), Some(dg)) = (group("probe"), group(pkmcal::DISTANCE_AXIS))
            && let Some(r) = pkmcal::variance_ratio(h, dg, VARIANCE_RATIO_LEVEL)
        {
            say!(
                "variance ratio heights/distances: {:.3} ({:.0} % interval {:.3} to {:.3}, from {:.1} and {:.1} degrees of freedom); Klipper's fixed weighting takes {:.3}",
                r.ratio,
                100.0 * r.level,
                r.low,
                r.high,
                h.redundancy.unwrap_or(f64::NAN),
                dg.redundancy.unwrap_or(f64::NAN),
                1.0 / z_weight
            );
        }
    }
    for w in &cal.warnings {
        say!("warning: {}\n  hint: {}", w.message, crate::words::hint(w));
    }
    let written = super::print_written(printer, &calibrated, "Klipper value")?;
    for (i, n) in measurement.param_names().iter().enumerate() {
        if calibrated.free.contains(&(spec.n_params() + i)) {
            say!(
                "  {:<28} {:>14.6} {:>14.6}   ({}; not a Klipper value: level the bed or let Klipper's bed mesh take it)",
                n,
                measurement.nominal()[i],
                cal.measurement[i],
                measurement.param_units()[i]
            );
        }
    }
    super::print_checks(printer, &calibrated, &written, a.max_sigma)?;
    if let Some(out) = &a.out {
        run.files.stage(
            out,
            printer
                .updated(spec, &cal.params, &cal.measurement)?
                .as_bytes(),
        )?;
        say!(
            "\nupdated configuration -> {} (values in its SAVE_CONFIG block)",
            out.display()
        );
    }
    if let Some(dir) = &a.out_dir {
        run.files.create_dir(dir)?;
        for (path, bytes) in klipper::out_dir_files(printer, &calibrated, &a.config, dir) {
            run.files.stage(&path, &bytes)?;
        }
        let dist = if readings.distances.is_empty() {
            String::new()
        } else {
            format!(" --distances {}/{DISTANCES_FILE}", dir.display())
        };
        say!(
            "mechanism, probe data and parameters -> {} (e.g. `pkmcal calibrate --mechanism {0}/mechanism.toml --data {0}/probes.csv{dist}`)",
            dir.display()
        );
    }
    Ok(())
}

/// Confidence level of the printed height/distance variance ratio.
const VARIANCE_RATIO_LEVEL: f64 = 0.95;

/// The noise σ of a group of readings, for the summary.
fn noise_of(cal: &pkmcal::Calibration, axis: &str) -> String {
    cal.noise
        .iter()
        .find(|g| g.axes.iter().any(|a| a == axis))
        .map_or("—".into(), |g| format!("{:.1} µm", g.sigma * 1e3))
}
