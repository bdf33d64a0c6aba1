//! `--physical` on `klipper`, `reprap` and `marlin`: the linear delta as
//! built, fitted to the firmware's readings within its parts' tolerances,
//! projected onto the firmware's values for the nozzle over the build
//! volume, and written by the firmware's own writer (issue 54).

use anyhow::Result;
use pkmcal::{Mechanism, Request};
use pkmcal_io::Run;
use pkmcal_io::firmware::physical;
use pkmcal_io::firmware::physical_report;
use pkmcal_io::firmware::{self, Firmware, Spread};
use std::path::Path;

/// Where and how the firmware's values are written.
pub struct Output<'a> {
    /// The file (`--out`), if any.
    pub out: Option<&'a Path>,
    /// What the command says of the written file.
    pub written: &'a str,
    /// The --physical options (the height map's).
    pub physical: &'a crate::args::PhysicalArgs,
    /// The printer's previous readings, compared with these (`--previous`),
    /// and where they came from.
    pub previous: Option<(&'a dyn Firmware, String)>,
    /// The largest σ of a written value before a warning (`--max-sigma`).
    pub max_sigma: f64,
}

/// Fit, project, print, and write as `output` says.
pub fn run(
    run: &Run<'_>,
    printer: &dyn Firmware,
    request: Request,
    source: &str,
    output: Output<'_>,
) -> Result<()> {
    let touches = match &output.physical.heights {
        Some(path) => Some(pkmcal_io::firmware::physical_heights::read(run, path)?),
        None => None,
    };
    if output.physical.height_map.is_some() || output.physical.report_dir.is_some() {
        physical::mesh_layout(printer, output.physical.mesh_points)?;
    }
    let Some(assessed) = physical::assess(printer, request.clone(), touches.as_ref())? else {
        return crate::words::usage(format!(
            "--physical models linear deltas (towers with carriages); this {} printer is a rotary delta, whose arms and their errors it has no model of: calibrate its firmware values without --physical",
            printer.name()
        ));
    };
    let physical::Assessment {
        delta: ld,
        fw_mech,
        own,
        fit,
        choice,
        before,
        heights: [h_before, h_after],
        cubes,
        values,
    } = &assessed;
    let fw_spec = fw_mech.spec();
    let cal = &fit.study.calibration;
    let proj = &choice.written;
    let with_own = choice.own.summary;
    let heights = &fit.readings.poses;
    say!(
        "Physical model: {} probe heights{} from {source} ({}){}, {} parameters within their tolerances ({}; probe σ {} mm{}); effector radius {} mm, rod spacing {} mm, probe offset ({}, {}) mm",
        heights.len() - fit.touches.0,
        if fit.readings.distances.is_empty() {
            String::new()
        } else {
            format!(" and {} distances", fit.readings.distances.len())
        },
        printer.name(),
        match &touches {
            Some(t) => format!(
                " and {} touches ({} of the nozzle, σ {} mm unless given) from {}",
                fit.touches.0,
                fit.touches.1,
                pkmcal_io::firmware::physical_heights::TOUCH_NOISE_MM,
                t.path.display()
            ),
            None => String::new(),
        },
        fit.free_names.len(),
        physical::tolerance_groups(fit)
            .iter()
            .map(physical::ToleranceGroup::words)
            .collect::<Vec<_>>()
            .join(", "),
        fit.probe_noise.mm(),
        physical_report::stated_words(fit.probe_noise),
        physical::EFFECTOR_RADIUS_MM,
        physical::ROD_SPACING_MM,
        ld.probe_offset[0],
        ld.probe_offset[1],
    );
    if !request.tolerances.is_empty() {
        let given: Vec<String> = request
            .tolerances
            .iter()
            .map(|(name, t)| match t {
                pkmcal::apply::budget::Tolerance::Absolute(s) => format!("{name} {s}"),
                pkmcal::apply::budget::Tolerance::Relative(f) => format!("{name} {}%", f * 100.0),
            })
            .collect();
        say!(
            "tolerances given in place of those (--tolerance, in each one's unit): {}",
            given.join(", ")
        );
    }
    say!("{}", cal.termination.reason());
    let (h_before, h_after) = (Spread::of(h_before), Spread::of(h_after));
    say!(
        "height errors of the physical fit: before max {:.4} mm, RMS {:.4} mm; after max {:.4} mm, RMS {:.4} mm",
        h_before.max,
        h_before.rms,
        h_after.max,
        h_after.rms
    );
    // What the tolerances hold is said part by part below, not direction
    // by direction.
    use pkmcal::identify::WarningKind;
    for w in cal.warnings.iter().filter(|w| {
        !matches!(
            w.kind,
            WarningKind::HeldByTolerance { .. } | WarningKind::PriorDominated { .. }
        )
    }) {
        match physical::NoiseNote::of(fit, w) {
            Some(note) => say!("{}", crate::words::noise_note(&note)),
            None => say!("warning: {}\n  hint: {}", w.message, crate::words::hint(w)),
        }
    }
    let unseen: Vec<String> = physical_report::unseen(fit)
        .iter()
        .map(|u| format!("{} ({} of {})", u.part, u.blind, u.of))
        .collect();
    if !unseen.is_empty() {
        say!(
            "the probe pattern cannot see (the readings take less than {:.0} % of their uncertainty): {}",
            100.0 * physical_report::UNSEEN_FROM_DATA,
            unseen.join(", ")
        );
    }
    say!(
        "\nnozzle error over the build volume of the fitted printer, in the bed's frame ({} points within {:.0} mm of the centre, z {} mm; x, y less the shift and turn no part shows, z over the bed):",
        proj.targets.len(),
        ld.print_radius(),
        physical::GRID_HEIGHTS_MM.map(|z| format!("{z}")).join(", ")
    );
    let z_weighed = if choice.z_weight > 1.0 {
        format!(
            ", Z weighing {}× XY to stay no worse than {}'s",
            choice.z_weight,
            printer.name()
        )
    } else {
        String::new()
    };
    for (what, e) in [
        ("the current values".to_string(), *before),
        (
            format!("{}'s own fit of the probe", printer.name()),
            with_own,
        ),
        (
            format!("the values for the nozzle{z_weighed}"),
            choice.projected.summary,
        ),
    ] {
        say!(
            "  {what:<40} XY RMS {:.4} mm, max {:.4} mm; Z RMS {:.4} mm, max {:.4} mm",
            e.xy_rms,
            e.xy_max,
            e.z_rms,
            e.z_max
        );
    }
    let gain = |g: [f64; 2]| format!("{:+.5} ± {:.5} mm²", g[0], g[1]);
    if choice.projection_written {
        say!(
            "the values for the nozzle are written: over the fit's uncertainty they lower the mean square error by {} (Z alone {})",
            gain(choice.gain),
            gain(choice.z_gain)
        );
    } else {
        say!(
            "{}'s own fit is written: over the fit's uncertainty the values for the nozzle would lower the mean square error by {} (Z alone {}), not beyond {} standard deviation{}: the readings cannot show them better",
            printer.name(),
            gain(choice.gain),
            gain(choice.z_gain),
            physical::CHOICE_SIGMAS,
            if physical::CHOICE_SIGMAS == 1.0 {
                ""
            } else {
                "s"
            }
        );
    }
    let fw_bed = assessed.fw_bed();
    say!(
        "\npredicted {} mm cube printed with the values written (± one standard deviation from the fit's uncertainty, {} draws):",
        physical::CUBE_MM,
        physical::CUBE_DRAWS
    );
    for (where_, c) in ["at the centre", "at the edge"].iter().zip(cubes.iter()) {
        say!(
            "  {where_} ({:.0}, {:.0}): X size {:+.3} ± {:.3} mm, Y size {:+.3} ± {:.3} mm, top flatness {:.3} ± {:.3} mm",
            c.centre[0],
            c.centre[1],
            c.size[0],
            c.size_sd[0],
            c.size[1],
            c.size_sd[1],
            c.flatness,
            c.flatness_sd
        );
    }
    crate::cmd::print_values(&format!("{} value", printer.name()), values);
    if let Some(w) = physical::uncertain(&assessed, output.max_sigma)? {
        let (message, hint) = crate::words::firmware_warning(&w);
        say!("warning: {message}\n  hint: {hint}");
    }
    let mapped = crate::cmd::physical_outputs::Mapped {
        fit,
        fw_mech,
        fw_params: &proj.params,
        fw_bed,
        source,
    };
    let suggestions = crate::cmd::physical_outputs::suggestion(printer, &mapped);
    let drift = match &output.previous {
        Some((previous, from)) => Some((
            from.clone(),
            crate::cmd::physical_outputs::drift(*previous, from, own)?,
        )),
        None => None,
    };
    if let Some(path) = &output.physical.height_map {
        crate::cmd::physical_outputs::height_map(run, printer, &mapped, path, output.physical)?;
    }
    if let Some(dir) = &output.physical.report_dir {
        let page = physical_report::Page::build(&physical_report::Inputs {
            printer,
            source,
            own,
            fit,
            fw_mech,
            projection: proj,
            values,
            projected: (choice.projected.summary, choice.projection_written),
            before: [*before, with_own],
            cubes,
            suggestions: &suggestions,
            shown: pkmcal_io::firmware::physical_plan::SHOWN,
            drift,
            mesh_points: output.physical.mesh_points,
            wording: &crate::words::WORDING,
            height_map: output.physical.height_map.as_deref(),
        })?;
        physical_report::write_report_dir(run, dir, &page)?;
        say!("\nreport -> {}", dir.display());
    }
    if let Some(out) = output.out {
        let text = firmware::out_file(
            printer,
            &printer.updated(fw_spec, &proj.params, &proj.bed)?,
            source,
            own.readings.poses.len(),
            // The header says the physical model's values only where they
            // are written (else the firmware's own fit is).
            choice.projection_written,
        );
        run.files.stage(out, text.as_bytes())?;
        let what = if choice.projection_written {
            "values for the nozzle".to_string()
        } else {
            format!("{}'s own fit", printer.name())
        };
        say!("\n{what} -> {} {}", out.display(), output.written);
    }
    Ok(())
}
