//! Units of the numbers in data files: the run's units (the front end's
//! units option) over a mechanism file's `[units]` table over the internal
//! units (mm, rad).
//! Numbers are converted on read (`internal = file × factor`) and back on
//! write; parameter files and reports stay in mm and rad, which they name.

use pkmcal::{FileUnits, Role, Spec, Unit};

/// The comment line that says which units a data file is in
/// (`# units: angles in deg, lengths in m`), written atop every data file
/// pkmcal writes in other units than mm and rad, and read back.
pub const UNITS_COMMENT: &str = "# units:";

/// The units a line declares, if it is a units comment line ([`UNITS_COMMENT`]).
pub fn units_line(line: &str) -> Option<pkmcal::Result<FileUnits>> {
    line.trim()
        .strip_prefix(UNITS_COMMENT)
        .map(|rest| FileUnits::from_description(rest.trim()))
}

/// The units of one data file: the file's own units line (`line`) when it
/// has one, else the mechanism's `[units]` (`base`, which already holds
/// them and the run's units); the run's units (the front end's units option) over either. Where
/// the file's line and the run's units disagree, a note says so (the run's
/// units win).
pub fn for_file(
    run: &crate::Run<'_>,
    base: &FileUnits,
    line: Option<&FileUnits>,
    path: &std::path::Path,
) -> FileUnits {
    let Some(line) = line else {
        return *base;
    };
    let given = &run.units;
    let mut differ = vec![];
    if let Some(a) = given.angle.filter(|a| *a != line.angle) {
        differ.push(format!(
            "angles in {} (given: {})",
            line.angle.symbol(),
            a.symbol()
        ));
    }
    if let Some(l) = given.length.filter(|l| *l != line.length) {
        differ.push(format!(
            "lengths in {} (given: {})",
            line.length.symbol(),
            l.symbol()
        ));
    }
    if let Some(c) = given
        .counts_per_rev
        .filter(|c| Some(*c) != line.counts_per_rev)
    {
        differ.push(format!(
            "counts per rev {:?} (given: {c})",
            line.counts_per_rev
        ));
    }
    if let Some(c) = given
        .counts_per_mm
        .filter(|c| Some(*c) != line.counts_per_mm)
    {
        differ.push(format!(
            "counts per mm {:?} (given: {c})",
            line.counts_per_mm
        ));
    }
    if !differ.is_empty() {
        run.note(crate::Note::UnitsDiffer {
            path: path.to_path_buf(),
            differ,
        });
    }
    line.with(given)
}

/// The data-file units for a command run with the mechanism description
/// `d`: its `[units]` table, then the run's units (the front end's units option).
pub fn of(run: &crate::Run<'_>, d: &crate::description::Description) -> FileUnits {
    let mut u = FileUnits::default();
    if let Some(file) = &d.units {
        u = u.with(file);
    }
    u.with(&run.units)
}

/// Factors of the actuator commands, in actuator order.
pub fn commands(spec: &Spec, u: &FileUnits) -> Vec<f64> {
    spec.command_units()
        .iter()
        .map(|&k| u.factor(k, Role::Command))
        .collect()
}

/// Factors of readings of the given units (positions, orientations, bar
/// lengths, σ).
pub fn readings(units: &[Unit], u: &FileUnits) -> Vec<f64> {
    units.iter().map(|&k| u.factor(k, Role::Reading)).collect()
}

/// Factors of the tool coordinates (targets, predicted positions).
pub fn tool(spec: &Spec, u: &FileUnits) -> Vec<f64> {
    readings(&spec.tool_units, u)
}

/// Rows read from a file, to internal units.
pub fn to_internal(rows: &mut [Vec<f64>], factors: &[f64]) {
    for r in rows {
        for (v, f) in r.iter_mut().zip(factors) {
            *v *= f;
        }
    }
}

/// One internal value to the file's unit.
pub fn to_file(v: f64, factor: f64) -> f64 {
    if factor == 1.0 { v } else { v / factor }
}

/// A row of internal values to the file's units.
pub fn row_to_file(row: &[f64], factors: &[f64]) -> Vec<f64> {
    row.iter()
        .zip(factors)
        .map(|(v, f)| to_file(*v, *f))
        .collect()
}

/// The comment line that says which units an output file is in, or none for
/// the internal units.
pub fn comment(u: &FileUnits) -> Option<String> {
    if u.is_internal() {
        return None;
    }
    Some(format!("{UNITS_COMMENT} {}", u.describe()))
}

/// `bytes` with the units comment line in front.
pub fn with_comment(bytes: Vec<u8>, u: &FileUnits) -> Vec<u8> {
    match comment(u) {
        None => bytes,
        Some(c) => {
            let mut out = format!("{c}\n").into_bytes();
            out.extend(bytes);
            out
        }
    }
}
