//! Whether this calibration differs from a previous one beyond their
//! uncertainty (`--physical --previous`, issue 54).
//!
//! Both sets of saved probe results are read with one configuration
//! ([`super::klipper::KlipperPrinter::with_readings_of`]: the saved
//! positions are steps from the endstops, which belong to the printer) and
//! fitted with the firmware's own model, whose values the probe heights
//! determine; the two fits are compared by the drift test
//! ([`pkmcal::identify::drift`]: in a basis scaled by the combined σ, so
//! that no unit swamps another; Holm–Bonferroni over the parameters, a χ²
//! over the directions both see). The physical fits (59 parameters held
//! mostly by their tolerances) could be compared too, on the 11 directions
//! 13 heights show of them, at the test's false-alarm rate; but the
//! firmware's fits tell a small change better: carriage a moved 0.1 mm at
//! every probe was found in 40 of 40 seeded pairs by theirs, 23 of 40 by
//! the physical fits' (BENCHMARKS.md, issue 54).

use crate::error::Result;
use pkmcal::identify::{Compared, Drift};

/// Whether the printer changed since its `previous` readings (read with
/// the configuration of `now`:
/// [`super::klipper::KlipperPrinter::with_readings_of`]): they are fitted
/// with the firmware's own model and its default choices, and compared
/// with `now` at the drift test's default false-alarm rate.
pub fn since(previous: &dyn super::Firmware, now: &super::PrinterCalibration) -> Result<Drift> {
    let before = super::calibrate(previous, pkmcal::Request::new(pkmcal::Model::Exact))?;
    firmware_drift(&before, now, pkmcal::identify::DEFAULT_ALPHA)
}

/// The drift from the `previous` firmware fit to `now` (both read with one
/// configuration) at familywise false-alarm rate `alpha`.
pub fn firmware_drift(
    previous: &super::PrinterCalibration,
    now: &super::PrinterCalibration,
    alpha: f64,
) -> Result<Drift> {
    Ok(pkmcal::identify::drift(
        &Compared::from_calibration(previous.calibration()),
        &Compared::from_calibration(now.calibration()),
        alpha,
    )?)
}
