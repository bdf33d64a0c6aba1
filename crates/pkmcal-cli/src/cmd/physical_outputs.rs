//! What `--physical` writes and says besides the firmware's values: the
//! extra measurement that would shrink the cube's uncertainty most, and the
//! height map in the firmware's own format (`--height-map`, issue 54).

use anyhow::Result;
use pkmcal::Params;
use pkmcal_io::Run;
use pkmcal_io::description::Mech;
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::height_map::{self, KLIPPER_PROFILE, MeshFormat};
use pkmcal_io::firmware::physical::PhysicalFit;
use pkmcal_io::firmware::physical_drift;
use pkmcal_io::firmware::physical_plan::{self, Suggestion};
use pkmcal_io::firmware::physical_report;
use std::path::Path;

/// The fitted printer and the firmware's values written for it.
pub struct Mapped<'a> {
    /// The physical fit.
    pub fit: &'a PhysicalFit,
    /// The firmware's description.
    pub fw_mech: &'a Mech,
    /// Its written values.
    pub fw_params: &'a Params,
    /// The bed tilt the firmware applies, where it applies one.
    pub fw_bed: Option<&'a [f64]>,
    /// Where the readings came from.
    pub source: &'a str,
}

/// Map what the written values leave over the bed, stage it at `path` in
/// the firmware's format, and say so.
pub fn height_map(
    run: &Run<'_>,
    printer: &dyn Firmware,
    m: &Mapped<'_>,
    path: &Path,
    physical: &crate::args::PhysicalArgs,
) -> Result<()> {
    let Some(written) = height_map::for_printer(
        printer,
        m.fit,
        m.fw_mech,
        m.fw_params,
        m.fw_bed,
        m.source,
        physical.mesh_points,
    )?
    else {
        anyhow::bail!(
            "{} keeps no height map pkmcal can write: leave --height-map out",
            printer.name()
        );
    };
    let height_map::Written { map, layout, text } = written;
    run.files.stage(path, text.as_bytes())?;
    let v = map.values();
    let (min, max) = (
        v.iter().copied().fold(f64::INFINITY, f64::min),
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );
    let format = match layout.format {
        MeshFormat::Klipper => format!("Klipper [bed_mesh {KLIPPER_PROFILE}] profile"),
        MeshFormat::RepRap => "RepRapFirmware heightmap.csv".into(),
        MeshFormat::Marlin => "Marlin M421 lines".into(),
    };
    say!(
        "\nheight map of what the written values leave on the bed ({format}, {}): {} nodes, from {min:+.4} to {max:+.4} mm, σ up to {:.4} mm -> {}",
        layout.words(),
        v.len(),
        map.largest_sd().unwrap_or(f64::NAN),
        path.display()
    );
    if matches!(
        physical_report::map_advice(&map),
        physical_report::MapAdvice::Uncertain { .. }
    ) {
        say!(
            "  the map's uncertainty exceeds its values: what it corrects is not known yet; measure more ({}) before loading it",
            if printer.flavour().reads_object_distances() {
                "calibration object distances, nozzle touches, or probe heights further out"
            } else {
                "nozzle touches, or probe heights further out"
            }
        );
    }
    Ok(())
}

/// Say which extra measurements would shrink the predicted cube's
/// uncertainty most, in the firmware's commands, and return them (best
/// first); where they cannot be scored (a candidate the printer cannot
/// reach), say why and go on: the values are written all the same.
pub fn suggestion(printer: &dyn Firmware, m: &Mapped<'_>) -> Vec<Suggestion> {
    match suggest(printer, m) {
        Ok(list) => list,
        Err(e) => {
            say!("\nthe extra measurements could not be scored: {e:#}");
            vec![]
        }
    }
}

fn suggest(printer: &dyn Firmware, m: &Mapped<'_>) -> Result<Vec<Suggestion>> {
    let firmware = printer.flavour();
    let list = physical_plan::suggest(
        m.fit,
        m.fw_mech,
        m.fw_params,
        m.fw_bed,
        firmware.reads_object_distances(),
    )?;
    let Some(first) = list.first() else {
        return Ok(list);
    };
    say!(
        "\nthe extra measurements that would shrink the cube's uncertainty most (its largest σ now {:.3} mm; linearised, the fit's noise for each reading):",
        first.largest().0
    );
    for (k, s) in list.iter().take(physical_plan::SHOWN).enumerate() {
        let what = physical_report::measurement_words(
            &s.extra,
            firmware,
            m.fit.delta.probe_offset,
            &crate::words::WORDING,
        );
        let (before, after) = s.largest();
        say!(
            "  {}. {what}: largest σ {before:.3} -> {after:.3} mm ({:.0} % of the cube errors' variance)",
            k + 1,
            100.0 * s.variance_removed()
        );
    }
    Ok(list)
}

/// Fit the `previous` readings (from `from`) as these were fitted and say
/// whether the physical printer changed since, beyond both fits'
/// uncertainty.
pub fn drift(
    previous: &dyn Firmware,
    from: &str,
    now: &pkmcal_io::firmware::PrinterCalibration,
) -> Result<pkmcal::identify::Drift> {
    let d = physical_drift::since(previous, now)?;
    let changed: Vec<String> = d
        .parameters
        .iter()
        .filter(|p| p.drifted)
        .map(|p| format!("{} {:+.4} ± {:.4}", p.name, p.change, p.sigma))
        .collect();
    let alone = if d.parameters.is_empty() {
        "no parameter is seen alone by both".to_string()
    } else {
        format!(
            "{} of the {} parameters seen alone changed beyond both uncertainties{}{}",
            changed.len(),
            d.parameters.len(),
            if changed.is_empty() { "" } else { ": " },
            changed.join(", ")
        )
    };
    say!(
        "\nsince {from}: {} (joint test over the {} directions both calibrations' data see: χ² {:.1}, p {:.3}; {alone}; {} held by the tolerances not compared)",
        if d.joint_drift {
            "the printer changed"
        } else {
            "no change beyond the two calibrations' uncertainty"
        },
        d.dof,
        d.chi2,
        d.p_joint,
        d.untested.len()
    );
    Ok(d)
}
