//! Whether this calibration differs from a previous one beyond their
//! uncertainty (`--physical --previous`, issue 54): the two physical fits
//! compared parameter by parameter and jointly with the drift test
//! ([`pkmcal::identify::drift`]: each calibration's data-only estimate, so
//! that the tolerances both share hide no change; in a basis scaled by the
//! combined σ, so that no unit swamps another; Holm–Bonferroni over the
//! parameters, a χ² over the directions both see).
//!
//! The physical model's endstop offsets (`da`, `db`, `dc`) are relative to
//! the firmware's homed carriage height, `position_endstop + √(arm² −
//! radius²)`, which a recalibration changes; they are compared as the
//! absolute heights they give. Every other parameter is absolute already.

use super::physical::PhysicalFit;
use crate::error::Result;
use pkmcal::identify::{Compared, Drift};

/// The towers' endstop offsets in the physical model.
const ENDSTOP_OFFSETS: [&str; 3] = ["da", "db", "dc"];

/// A physical fit as the drift test compares it: its values (the endstop
/// offsets as absolute homed heights), covariance and priors.
pub fn compared(fit: &PhysicalFit) -> Compared {
    let mut c = Compared::from_calibration(&fit.study.calibration);
    let d = &fit.delta.delta;
    for (i, name) in ENDSTOP_OFFSETS.iter().enumerate() {
        let homed = d.endstops[i] + (d.arms[i].powi(2) - d.radius.powi(2)).max(0.0).sqrt();
        for (n, v) in &mut c.values {
            if n == name {
                *v += homed;
            }
        }
    }
    c
}

/// The drift from the `previous` physical fit to `now`, at familywise
/// false-alarm rate `alpha`.
pub fn drift(previous: &PhysicalFit, now: &PhysicalFit, alpha: f64) -> Result<Drift> {
    Ok(pkmcal::identify::drift(
        &compared(previous),
        &compared(now),
        alpha,
    )?)
}
