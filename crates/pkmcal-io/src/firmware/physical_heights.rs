//! Heights a printer's owner measured by hand, for the physical model
//! (`--physical`): where the nozzle (or the probe) touched a surface at a
//! known height over the bed, the bed itself, a gauge block, or a second
//! level. The firmware's probe heights cannot see the effector's tilt from
//! a parallelogram's rod mismatch (the nozzle's Z error is the probe's
//! offset times the tilt); the nozzle touching where the probe triggered
//! does.
//!
//! A CSV file with a header, one touch a row: `x`, `y`, `z`, the position
//! the firmware displays when the tool touches (firmware coordinates, the
//! nozzle's, mm); `tool`, `nozzle` or `probe`; `surface`, the height of
//! what it touched over the bed (mm: 0 for the bed, a sheet of paper's
//! thickness for a paper test, a gauge block's height); optionally `sigma`,
//! the touch's standard deviation (mm; by default [`TOUCH_NOISE_MM`] for the
//! nozzle, the probe's own for the probe). Each row becomes a reading of
//! the physical fit: the carriages where the firmware's current values put
//! the nozzle at `x, y, z` (as the saved probe results are carriage
//! positions), reading the height of the nozzle (at minus the probe's
//! offset in the effector's frame) or of the probe's point over the bed.

use super::physical::{LinearDelta, firmware_commands};
use crate::description::Mech;
use crate::error::{Error, Result};
use crate::refuse;
use pkmcal::{Mechanism, Params};
use std::path::{Path, PathBuf};

/// Default σ (mm) of a nozzle touch, where the file gives none: a paper
/// test's (the drag felt on a sheet of paper under the nozzle).
pub const TOUCH_NOISE_MM: f64 = 0.02;
/// The smallest σ a row may state (mm): below any hand measurement.
pub const MIN_TOUCH_SIGMA_MM: f64 = 1e-4;
/// The largest σ a row may state (mm): beyond it the touch says nothing.
pub const MAX_TOUCH_SIGMA_MM: f64 = 5.0;
/// How far below the bed (mm) a displayed z may be: a nozzle touching
/// where the firmware's z is off by that much is not calibrated yet.
pub const MAX_BELOW_BED_MM: f64 = 10.0;
/// The most rows a file may hold (a hand-written file has tens).
pub const MAX_TOUCHES: usize = 1000;
/// The columns, in the order a file is best written.
pub const COLUMNS: [&str; 6] = ["x", "y", "z", "tool", "surface", "sigma"];

/// What touched.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tool {
    /// The nozzle (a paper test, a feeler gauge, a nozzle touch plate).
    Nozzle,
    /// The probe, triggering.
    Probe,
}

impl Tool {
    /// Its name in the file.
    pub fn name(self) -> &'static str {
        match self {
            Tool::Nozzle => "nozzle",
            Tool::Probe => "probe",
        }
    }
}

/// One touch, as the file gives it.
#[derive(Debug, Clone, PartialEq)]
pub struct Touch {
    /// The file's line.
    pub line: u64,
    /// The position displayed (firmware coordinates, the nozzle's, mm).
    pub position: [f64; 3],
    /// What touched.
    pub tool: Tool,
    /// The surface's height over the bed (mm).
    pub surface: f64,
    /// The touch's σ (mm), where the file states one.
    pub sigma: Option<f64>,
}

/// A file of touches, read and checked.
#[derive(Debug, Clone, PartialEq)]
pub struct Touches {
    /// The file.
    pub path: PathBuf,
    /// Its rows.
    pub rows: Vec<Touch>,
}

/// Read a file of touches ([`COLUMNS`]); every field checked, an error
/// naming the file, line and column.
pub fn read(run: &crate::Run<'_>, path: &Path) -> Result<Touches> {
    let csv = crate::csv::Csv::read(run, path)?;
    csv.require_rows()?;
    if csv.rows.len() > MAX_TOUCHES {
        refuse!(
            path,
            Some(csv.line(MAX_TOUCHES)),
            "more than {MAX_TOUCHES} touches; a hand-measured file holds tens, spread over the bed"
        );
    }
    let cols: Vec<Option<usize>> = COLUMNS
        .iter()
        .map(|c| match *c {
            "sigma" if !csv.has(c) => Ok(None),
            c => csv.column(c).map(Some),
        })
        .collect::<Result<_>>()?;
    let numbers = csv.named(&["x", "y", "z", "surface"].map(String::from))?;
    let mut rows = vec![];
    for (k, (line, rec)) in csv.rows.iter().enumerate() {
        let field = |c: usize| rec.get(cols[c].expect("required")).map(|s| s.trim());
        let tool = match field(3) {
            Some(t) if t.eq_ignore_ascii_case("nozzle") => Tool::Nozzle,
            Some(t) if t.eq_ignore_ascii_case("probe") => Tool::Probe,
            Some(t) => refuse!(
                path,
                Some(*line),
                "column `tool`: `{t}` is neither `nozzle` nor `probe` (what touched the surface)"
            ),
            None => refuse!(
                path,
                Some(*line),
                "the row is short: no value for column `tool`"
            ),
        };
        let [x, y, z, surface] = [0, 1, 2, 3].map(|i| numbers[k][i]);
        for (name, v) in [("x", x), ("y", y), ("z", z), ("surface", surface)] {
            if v.abs() > pkmcal::units::MAX_LENGTH_MM {
                refuse!(
                    path,
                    Some(*line),
                    "column `{name}`: {v:e} mm is beyond any printer (at most {:e} mm)",
                    pkmcal::units::MAX_LENGTH_MM
                );
            }
        }
        if surface < 0.0 {
            refuse!(
                path,
                Some(*line),
                "column `surface`: {surface} mm is below the bed; give the height of what the {} touched over the bed (0 for the bed itself)",
                tool.name()
            );
        }
        let sigma = match cols[5].and_then(|c| rec.get(c)).map(|s| s.trim()) {
            None | Some("") => None,
            Some(s) => {
                let Ok(v) = s.parse::<f64>() else {
                    refuse!(path, Some(*line), "column `sigma`: `{s}` is not a number");
                };
                if !(MIN_TOUCH_SIGMA_MM..=MAX_TOUCH_SIGMA_MM).contains(&v) {
                    refuse!(
                        path,
                        Some(*line),
                        "column `sigma`: {s} mm is not a touch's standard deviation (from {MIN_TOUCH_SIGMA_MM} to {MAX_TOUCH_SIGMA_MM} mm; leave it empty for the default)"
                    );
                }
                Some(v)
            }
        };
        rows.push(Touch {
            line: *line,
            position: [x, y, z],
            tool,
            surface,
            sigma,
        });
    }
    Ok(Touches {
        path: path.to_path_buf(),
        rows,
    })
}

/// The touches as readings of the physical printer `ld` (its description's
/// tool the effector's whole pose): the carriages where the firmware's
/// current values (`fw_mech`'s nominal, tilting with `fw_bed` where the
/// firmware does) put the nozzle at each displayed position; a nozzle
/// touch reads the nozzle's height over the bed, a probe's the probe
/// point's as the firmware's saved results read it
/// ([`LinearDelta::probe_height`] over the surface). Numbered from `first`
/// (after the firmware's own readings). A position outside the build
/// volume (beyond its radius, below the bed by more than
/// [`MAX_BELOW_BED_MM`], above the towers' reach) or out of the
/// firmware's reach is refused at its line.
pub fn readings(
    touches: &Touches,
    ld: &LinearDelta,
    fw_mech: &Mech,
    fw_bed: Option<&[f64]>,
    first: usize,
) -> Result<Vec<pkmcal::Measurement>> {
    let path = &touches.path;
    let fw_params = Params::nominal(fw_mech.spec());
    let radius = ld.print_radius();
    let top = ld.homed_height;
    touches
        .rows
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let [x, y, z] = t.position;
            let line = Some(t.line);
            if x.hypot(y) > radius * (1.0 + 1e-9) {
                refuse!(
                    path,
                    line,
                    "({x}, {y}) is {:.1} mm from the centre, outside the build volume (at most {radius} mm by {}'s configuration): give touches on the bed",
                    x.hypot(y),
                    ld.firmware
                );
            }
            if z < -MAX_BELOW_BED_MM || z > top {
                refuse!(
                    path,
                    line,
                    "z {z} mm is outside the build volume (from {} to {top} mm, where the nozzle is homed): give the z the firmware displays when the {} touches",
                    -MAX_BELOW_BED_MM,
                    t.tool.name()
                );
            }
            if t.surface > top {
                refuse!(
                    path,
                    line,
                    "surface {} mm is above the build volume (at most {top} mm)",
                    t.surface
                );
            }
            let commands = firmware_commands(fw_mech, &fw_params, fw_bed, [x, y, z])
                .ok()
                .filter(|c| c.iter().all(|v| v.is_finite()));
            let Some(commands) = commands else {
                refuse!(
                    path,
                    line,
                    "the nozzle at ({x}, {y}, {z}) is out of reach of {}'s current values: check the position",
                    ld.firmware
                );
            };
            let (point, measured) = match t.tool {
                Tool::Nozzle => (Some(ld.nozzle().to_vec()), t.surface),
                Tool::Probe => (None, t.surface + ld.probe_height),
            };
            let sigma = match (t.sigma, t.tool) {
                (Some(s), _) => vec![Some(s)],
                (None, Tool::Nozzle) => vec![Some(TOUCH_NOISE_MM)],
                // The probe's own noise (stated, or pkmcal's assumption).
                (None, Tool::Probe) => vec![],
            };
            Ok(pkmcal::Measurement {
                target: None,
                commands,
                partner: None,
                measured: vec![measured],
                sigma,
                origin: Some(pkmcal::Origin {
                    pose: first + k + 1,
                    line,
                    distance: false,
                }),
                point,
            })
        })
        .collect()
}

/// An error at the touch of reading `pose` (numbered from `first + 1`),
/// named by its file and line; `None` for another reading's.
pub fn located(touches: &Touches, first: usize, e: &pkmcal::Error) -> Option<Error> {
    match e {
        pkmcal::Error::Pose {
            pose,
            distance: false,
            source,
            ..
        } if *pose > first => {
            let t = touches.rows.get(pose - first - 1)?;
            Some(Error::at(
                &touches.path,
                Some(t.line),
                format!("the {} touch: {source}", t.tool.name()),
            ))
        }
        _ => None,
    }
}
