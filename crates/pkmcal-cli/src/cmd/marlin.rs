//! `marlin`: calibrate a linear delta printer run by Marlin from its M503
//! settings and a console log of probes, print (and write) the new
//! M665/M666 lines, and what Marlin's own G33 would set on the same printer.

use crate::args;
use anyhow::Result;
use pkmcal::{Mechanism, Request};
use pkmcal_io::Run;
use pkmcal_io::firmware::g33::{self, G33Ask, G33Compared, RadiusFrom};
use pkmcal_io::firmware::marlin::{LetterB, MarlinPrinter, ProbeKind};
use pkmcal_io::firmware::{self, Firmware, Spread};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The printer's settings as M503 prints them (a console log is fine:
    /// its `M665`, `M666` and `M851` lines are read, later ones
    /// overriding), or a file of M665/M666 lines.
    #[arg(long, value_name = "M503.txt")]
    pub config: PathBuf,
    /// A console log of probes: G30 (or G29 V3) reports `Bed X: … Y: … Z:
    /// …`, and the heights G33 prints with V3 (`c:… x:… y:… z:…`, with
    /// the settings it printed before them). Taken with the settings of
    /// --config.
    #[arg(long, value_name = "G30.log")]
    pub probes: PathBuf,
    /// Parameters to identify (`--free`, comma separated): G33's by default
    /// (delta_radius, angle_a, angle_b and the endstop errors da, db, dc:
    /// M665 R X Y Z, H and M666) or more (arm_a, arm_b, arm_c for the rods
    /// L with the trims A B C, or `diagonal` for L alone; angle_c); `all` is
    /// every parameter M665/M666 hold; `--fix` removes names.
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    /// Write the new M665 and M666 lines here (send them, then M500; or put
    /// them in the start G-code). Never over --config.
    /// Warn of a written value whose σ exceeds this, in the value's own
    /// unit (mm, °, %).
    #[arg(long, value_name = "SIGMA", default_value_t = pkmcal_io::firmware::DEFAULT_MAX_SIGMA, allow_negative_numbers = true, value_parser = args::values::max_sigma)]
    pub max_sigma: f64,
    #[arg(long, value_name = "NEW.gcode")]
    pub out: Option<PathBuf>,
    /// What M665 B means in this Marlin, where --config does not say (M503
    /// prints a `; Delta settings:` heading that does): `calibration-radius`
    /// (Marlin 1.1 to 2.0.x) or `rod-trim` (later versions, with A and C).
    #[arg(long = "m665-b", value_name = "MEANING", value_parser = args::values::letter_b)]
    pub m665_b: Option<LetterB>,
    /// The probe's x, y offset from the nozzle (mm), where --config has no
    /// `M851 X… Y…` line (Marlin 1.1 keeps it in Configuration.h).
    #[arg(long, value_name = "X,Y", value_parser = args::values::probe_offset)]
    pub probe_offset: Option<[f64; 2]>,
    /// G33's probe points for the comparison (its `P`, 1 to 10; 4 is
    /// Marlin's default DELTA_CALIBRATION_DEFAULT_POINTS).
    #[arg(long, value_name = "P", default_value_t = g33::DEFAULT_POINTS, value_parser = g33_points)]
    pub g33_points: u8,
    /// G33 without the tower angles (its `T`).
    #[arg(long)]
    pub g33_fixed_angles: bool,
    /// G33's calibration radius (mm), as it prints it (`Checking... AC at
    /// radius:…`): where the comparison probes, and where the heights of a
    /// G33 log lie when the log does not say. Default: the log's, else M665
    /// B (Marlin 1.1 to 2.0.x), else the farthest probed point.
    #[arg(long, value_name = "MM", value_parser = g33_radius)]
    pub g33_radius: Option<f64>,
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
    pkmcal_io::firmware::choices::Choices {
        g33: pkmcal_io::firmware::choices::g33_given(usize::from(a.g33_points), a.g33_fixed_angles),
        ..a.physical.choices()
    }
    .check()?;
    let mut request = Request::new(pkmcal::Model::Exact);
    a.params_set.apply(&mut request);
    let printer = MarlinPrinter::read(
        run,
        &a.config,
        &a.probes,
        a.m665_b,
        a.probe_offset,
        a.g33_radius,
        request.free.as_deref(),
    )?;
    a.physical.apply(&mut request)?;
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
                written: "(send the two lines to the printer, then M500 to keep them)",
                max_sigma: a.max_sigma,
            },
        );
    }
    let calibrated = firmware::calibrate(&printer, request)?;
    let study = &calibrated.study;
    let (cal, acc) = (&study.calibration, &study.accuracy);
    let mech = &calibrated.mech;
    let spec = mech.spec();
    let new = printer.delta().identified(spec, &cal.params)?;
    let heights = |e: &[Vec<f64>]| -> Spread {
        let v: Vec<f64> = e.iter().map(|r| r[0]).collect();
        Spread::of(&v)
    };
    let (before, after) = (heights(&study.before), heights(&study.after));
    let g33_points = printer
        .log
        .points
        .iter()
        .filter(|p| matches!(p.kind, ProbeKind::G33 { .. }))
        .count();
    let o = printer.probe_offset;
    say!(
        "{} probe heights{} from {} with the settings of {} (Marlin; probe offset X{} Y{} Z{}), {} parameters free: {}",
        acc.poses,
        if g33_points > 0 {
            format!(" ({g33_points} of them printed by G33)")
        } else {
            String::new()
        },
        a.probes.display(),
        a.config.display(),
        o[0],
        o[1],
        o[2],
        calibrated.free_names.len(),
        calibrated.free_names.join(" ")
    );
    say!("{}", cal.termination.reason());
    say!(
        "height errors: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm",
        before.max,
        before.rms,
        after.max,
        after.rms
    );
    for w in &cal.warnings {
        say!("warning: {}\n  hint: {}", w.message, crate::words::hint(w));
    }
    say!(
        "\nbefore:\n{}after:\n{}",
        printer.delta().gcode(),
        new.gcode()
    );
    let written = super::print_written(&printer, &calibrated, "written value")?;
    super::print_checks(&printer, &calibrated, &written, a.max_sigma)?;
    // Marlin's own G33 on the printer the fit found.
    let ask = G33Ask {
        points: a.g33_points,
        towers: !a.g33_fixed_angles,
        radius: a.g33_radius,
    };
    let c = g33::compare(&printer, &calibrated, &ask)?;
    let whence = match c.radius_from {
        RadiusFrom::Given => "given",
        RadiusFrom::Log => "the radius the G33 log printed",
        RadiusFrom::M665B => "M665 B",
        RadiusFrom::FarthestProbe => "the farthest probed point; --g33-radius sets it",
    };
    let (factors, what) = c.factors;
    say!(
        "G33 P{}{} ({factors} factors: {what}), as Marlin's G33.cpp runs it on the printer this fit found, at radius {:.2} mm ({whence}):",
        c.options.points,
        if c.options.towers { "" } else { " T" },
        c.options.radius,
    );
    match &c.outcome {
        Ok(G33Compared {
            run: g,
            points,
            with_g33,
            with_calibration: with_new,
        }) => {
            let sd: Vec<String> = g.std_devs.iter().map(|s| format!("{s:.3}")).collect();
            say!(
                "  {} iteration{} of {} points, std dev {} mm{}; it would set:",
                g.std_devs.len(),
                if g.std_devs.len() == 1 { "" } else { "s" },
                g.probes,
                sd.join(" → "),
                if g.rolled_back {
                    ", rolled back to the best"
                } else {
                    ""
                }
            );
            say_raw!("{}", indent(&g.settings.gcode()));
            say!(
                "  height errors at the {points} probed points with G33's values: max {:.4} mm, RMS {:.4} mm; with pkmcal's: max {:.4} mm, RMS {:.4} mm (the fit's residuals and the change the fitted printer predicts)",
                with_g33.max,
                with_g33.rms,
                with_new.max,
                with_new.rms
            );
        }
        Err(e) => say!("  not run: {}", crate::words::io(e)),
    }
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
            "\nnew M665/M666 -> {} (send the two lines to the printer, then M500 to keep them; or put them in the start G-code)",
            out.display()
        );
    }
    Ok(())
}

fn indent(s: &str) -> String {
    s.lines().map(|l| format!("  {l}\n")).collect()
}

/// G33's probe points (its `P`), bounded by the library's rule.
fn g33_points(s: &str) -> Result<u8, String> {
    let n = s
        .trim()
        .parse::<usize>()
        .map_err(|_| format!("`{s}` is not a count of probe points"))?;
    pkmcal_io::firmware::choices::g33_points(n).map_err(|e| match e {
        pkmcal::RequestError::Invalid { problem, .. } => problem,
        e => e.to_string(),
    })
}

/// G33's calibration radius (mm), bounded by the library's rule.
fn g33_radius(s: &str) -> Result<f64, String> {
    let v = s
        .trim()
        .parse::<f64>()
        .map_err(|_| format!("`{s}` is not a number"))?;
    pkmcal_io::firmware::choices::g33_radius(v).map_err(|e| match e {
        pkmcal::RequestError::Invalid { problem, .. } => problem,
        e => e.to_string(),
    })
}
