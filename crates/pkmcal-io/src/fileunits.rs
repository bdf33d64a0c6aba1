//! Units of the numbers in data files: the run's units (`--units` on the
//! command line) over a mechanism file's `[units]` table over the internal
//! units (mm, rad).
//! Numbers are converted on read (`internal = file × factor`) and back on
//! write; parameter files and reports stay in mm and rad, which they name.

use pkmcal::{FileUnits, Role, Spec, Unit};

/// The data-file units for a command run with the mechanism description
/// `d`: its `[units]` table, then the run's units (`--units`).
pub fn of(run: &crate::Run<'_>, d: &crate::io::Description) -> FileUnits {
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
    Some(format!("# units: {}", u.describe()))
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
