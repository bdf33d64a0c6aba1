//! Plausibility of a data file's numbers before a fit: commands that only
//! assemble in another unit, positions a thousand times too small or large.
//! A wrong unit otherwise surfaces as "loop closure did not converge" or as
//! every pose being an outlier; here it is named with the units that fix it
//! ([`crate::Error::Units`], which each front end words as its own option).

use crate::error::{Error, Result};
use pkmcal::{FileUnits, Measurement, MeasurementModel, Mechanism, Model, Params, Role, Unit};
use std::path::Path;

/// Poses checked (spread evenly over the file).
const SAMPLE_POSES: usize = 12;
/// Share of sampled poses that must fail to assemble before another unit is
/// tried.
const FAILING_SHARE: f64 = 0.5;
/// Share that must assemble in the other unit for it to be suggested.
const ASSEMBLING_SHARE: f64 = 0.75;
/// A spread ratio within this factor of 1000 (or 1/1000, or 180/π) names a
/// unit.
const RATIO_TOLERANCE: f64 = 3.0;

/// Data-file units that fit: the key (`length`, `angle`) and the unit
/// (`m`, `deg`).
pub type UnitsHint = (&'static str, &'static str);

/// Largest disagreement of a redundant actuator with the driven ones that
/// counts as assembled (rad): far beyond any encoder offset.
const MISMATCH_RAD: f64 = 0.2;
/// The same for prismatic actuators (mm).
const MISMATCH_MM: f64 = 20.0;

/// Length units by their factor to mm.
const LENGTHS: [(&str, f64); 3] = [("mm", 1.0), ("m", 1e3), ("um", 1e-3)];

/// Check the data read under `units`: refuse (with the fix) commands that
/// assemble only in another unit and readings whose spread is a unit factor
/// away from the mechanism's predictions.
pub fn check_data<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    units: &FileUnits,
    path: &Path,
) -> Result<()> {
    if data.is_empty() {
        return Ok(());
    }
    let step = data.len().div_ceil(SAMPLE_POSES).max(1);
    let sample: Vec<&Measurement> = data.iter().step_by(step).collect();
    let commands: Vec<&[f64]> = sample.iter().map(|m| m.commands.as_slice()).collect();
    let check = Assembly::new(mech);
    // The sample's poses in parallel (each a forward kinematics from scratch).
    let predicted: Vec<Option<pkmcal::Prediction>> = {
        use rayon::prelude::*;
        commands.par_iter().map(|c| check.assembles(c)).collect()
    };
    let failed = predicted.iter().filter(|p| p.is_none()).count();
    if failed as f64 >= FAILING_SHARE * sample.len() as f64 {
        if let Some((key, value)) = check.other_unit(&commands, units) {
            return Err(Error::Units {
                path: path.to_path_buf(),
                message: format!(
                    "the commands do not assemble the mechanism as read ({failed} of {} poses checked fail, units: {}), but they do in another unit",
                    sample.len(),
                    units.describe()
                ),
                key,
                value,
            });
        }
        return Ok(());
    }
    // Readings: compare their spread with the nominal model's, per unit.
    let mv = measurement.nominal();
    let ny = measurement.axes().len();
    let mut pred_rows = vec![];
    let mut meas_rows = vec![];
    for (m, p) in sample.iter().zip(&predicted) {
        if let Some(p) = p {
            let mut y = vec![0.0; ny];
            measurement.observe_point(&p.x, mv, m.point.as_deref(), &mut y);
            pred_rows.push(y);
            meas_rows.push(m.measured.clone());
        }
    }
    if pred_rows.len() < 3 {
        return Ok(());
    }
    for (unit, key) in [(Unit::Millimetre, "length"), (Unit::Radian, "angle")] {
        let cols: Vec<usize> = (0..ny)
            .filter(|&k| measurement.units()[k] == unit)
            .collect();
        if cols.is_empty() {
            continue;
        }
        let (sp, sm) = (spread(&pred_rows, &cols), spread(&meas_rows, &cols));
        if !(sp > 0.0 && sm > 0.0) {
            continue;
        }
        let ratio = sm / sp;
        let now = units.factor(unit, Role::Reading);
        let choices: Vec<(&'static str, f64)> = if unit == Unit::Millimetre {
            LENGTHS.to_vec()
        } else {
            vec![("rad", 1.0), ("deg", std::f64::consts::PI / 180.0)]
        };
        // The file unit that would bring the ratio to 1.
        let wanted = now / ratio;
        if let Some((name, _)) = choices.iter().find(|(_, f)| {
            (f - now).abs() > 1e-15 && (f / wanted).max(wanted / f) < RATIO_TOLERANCE
        }) {
            let what = if unit == Unit::Millimetre {
                "lengths"
            } else {
                "angles"
            };
            return Err(Error::Units {
                path: path.to_path_buf(),
                message: format!(
                    "the measured {what} spread over {} where the mechanism's nominal predictions for the same commands spread over {} ({ratio:.3e} times): they look like {name}, not {}",
                    show(sm, unit),
                    show(sp, unit),
                    units.symbol(unit, Role::Reading),
                ),
                key,
                value: name,
            });
        }
    }
    Ok(())
}

/// Whether commands assemble the nominal mechanism.
pub struct Assembly<'a, M: Mechanism> {
    mech: &'a M,
    params: Params,
    units: Vec<Unit>,
}

impl<'a, M: Mechanism> Assembly<'a, M> {
    pub fn new(mech: &'a M) -> Self {
        Self {
            mech,
            params: Params::nominal(mech.spec()),
            units: mech.spec().command_units(),
        }
    }

    /// The rigid prediction if the commands (internal units) assemble and
    /// the redundant actuators agree with the driven ones (garbage commands
    /// may still close the loops through the driven ones).
    pub fn assembles(&self, c: &[f64]) -> Option<pkmcal::Prediction> {
        pkmcal::predict(self.mech, &self.params, c, Model::Rigid, &[])
            .ok()
            .filter(|p| {
                p.deflection.iter().zip(&self.units).all(|(d, u)| match u {
                    Unit::Radian => {
                        let w = (d + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                            - std::f64::consts::PI;
                        w.abs() <= MISMATCH_RAD
                    }
                    _ => d.abs() <= MISMATCH_MM,
                })
            })
    }

    /// The data-file units under which most of `commands` (read under
    /// `units`, converted to internal units) assemble with the tool near the
    /// workspace ([`near_workspace`]), if there are such.
    pub fn other_unit(&self, commands: &[&[f64]], units: &FileUnits) -> Option<UnitsHint> {
        let mut tries: Vec<(UnitsHint, Vec<f64>)> = vec![];
        if self.units.contains(&Unit::Radian) && units.counts_per_rev.is_none() {
            let now = units.factor(Unit::Radian, Role::Command);
            for (name, f) in [("deg", std::f64::consts::PI / 180.0), ("rad", 1.0)] {
                if (f - now).abs() > 1e-15 {
                    tries.push((("angle", name), scale(&self.units, Unit::Radian, f / now)));
                }
            }
        }
        if self.units.contains(&Unit::Millimetre) && units.counts_per_mm.is_none() {
            let now = units.factor(Unit::Millimetre, Role::Command);
            for (name, f) in LENGTHS {
                if (f - now).abs() > 1e-15 {
                    tries.push((
                        ("length", name),
                        scale(&self.units, Unit::Millimetre, f / now),
                    ));
                }
            }
        }
        tries.into_iter().find_map(|(option, factors)| {
            let ok = commands
                .iter()
                .filter(|c| {
                    let c: Vec<f64> = c.iter().zip(&factors).map(|(c, f)| c * f).collect();
                    self.assembles(&c)
                        .is_some_and(|p| near_workspace(self.mech.spec(), &p.x))
                })
                .count();
            (ok as f64 >= ASSEMBLING_SHARE * commands.len() as f64).then_some(option)
        })
    }
}

/// After a failure to predict `commands` (internal units, read under
/// `units`): the data-file units in which they would assemble, if any.
pub fn other_units_for<M: Mechanism>(
    mech: &M,
    commands: &[Vec<f64>],
    units: &FileUnits,
) -> Option<UnitsHint> {
    let step = commands.len().div_ceil(SAMPLE_POSES).max(1);
    let sample: Vec<&[f64]> = commands.iter().step_by(step).map(Vec::as_slice).collect();
    Assembly::new(mech).other_unit(&sample, units)
}

/// Whether a tool position lies within the workspace box widened by its
/// own extent on every side (at least 1 mm or rad): a unit is suggested only
/// when the commands read in it put the tool where the machine works, not
/// merely somewhere it assembles (a delta's carriages in µm still assemble,
/// a metre below the bed).
fn near_workspace(spec: &pkmcal::Spec, x: &[f64]) -> bool {
    spec.workspace_box.iter().zip(x).all(|(&[lo, hi], &v)| {
        let margin = (hi - lo).max(1.0);
        v >= lo - margin && v <= hi + margin
    })
}

/// Command factors that rescale the actuators of one unit by `f`.
fn scale(units: &[Unit], which: Unit, f: f64) -> Vec<f64> {
    units
        .iter()
        .map(|&u| if u == which { f } else { 1.0 })
        .collect()
}

/// Root of the total variance of the given columns over the rows.
fn spread(rows: &[Vec<f64>], cols: &[usize]) -> f64 {
    let n = rows.len() as f64;
    cols.iter()
        .map(|&k| {
            let mean = rows.iter().map(|r| r[k]).sum::<f64>() / n;
            rows.iter().map(|r| (r[k] - mean).powi(2)).sum::<f64>() / n
        })
        .sum::<f64>()
        .sqrt()
}

fn show(v: f64, unit: Unit) -> String {
    format!("{v:.4} {}", unit.symbol())
}
