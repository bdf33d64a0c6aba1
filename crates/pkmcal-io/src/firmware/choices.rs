//! The rules of a firmware command's choices (`klipper`, `reprap`,
//! `marlin`, as the command line and the Python package give them):
//! which belong to the physical model, which exclude each other, and the
//! bounds of the numbers a user types. Checked once here; each front end
//! words a refusal as its own option or keyword ([`pkmcal::Field`]).

use pkmcal::{Field, RequestError};

/// The largest probe noise a user may state (mm): a probe whose readings
/// scatter by a millimetre cannot calibrate a printer (the parts'
/// tolerances, tenths of a millimetre, would then hold every value).
pub const MAX_PROBE_NOISE_MM: f64 = 1.0;

/// What a firmware command was asked for, as far as its rules go.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Choices {
    /// The physical model (`--physical`).
    pub physical: bool,
    /// Tolerances given in place of the physical model's.
    pub tolerances: bool,
    /// A height map to write.
    pub height_map: bool,
    /// The nodes across the height map.
    pub mesh_points: Option<usize>,
    /// A report directory to write.
    pub report_dir: bool,
    /// A directory of the firmware's model as pkmcal files (Klipper).
    pub out_dir: bool,
    /// A previous calibration to compare with (Klipper).
    pub previous: bool,
    /// The probe's noise, stated (mm).
    pub probe_noise: Option<f64>,
    /// Heights measured by hand to read.
    pub heights: bool,
    /// Options of Marlin's G33 comparison given (its points, fixed tower
    /// angles): it compares the firmware's own fit, which `--physical`
    /// does not write.
    pub g33: bool,
}

impl Choices {
    /// Refuse a choice that has no place with the others, or a number out
    /// of its bounds.
    pub fn check(&self) -> Result<(), RequestError> {
        let needs_physical = |field, why| RequestError::Belongs {
            field,
            needs: Field::Physical,
            why,
        };
        if self.physical && self.out_dir {
            return Err(RequestError::Excluded {
                field: Field::OutDir,
                with: Field::Physical,
                why: "writes the firmware's own model",
            });
        }
        if self.physical && self.g33 {
            return Err(RequestError::Excluded {
                field: Field::G33Points,
                with: Field::Physical,
                why: "sets the run of Marlin's own G33 beside the firmware's own fit",
            });
        }
        if !self.physical && self.previous {
            return Err(needs_physical(
                Field::Previous,
                "compares physical calibrations",
            ));
        }
        if !self.physical && self.tolerances {
            return Err(needs_physical(
                Field::Tolerances,
                "belongs to the physical model",
            ));
        }
        if !self.physical && self.height_map {
            return Err(needs_physical(
                Field::HeightMap,
                "maps what the physical model's values leave",
            ));
        }
        if !self.physical && self.heights {
            return Err(needs_physical(
                Field::Heights,
                "are read by the physical model",
            ));
        }
        if !self.physical && self.report_dir {
            return Err(needs_physical(
                Field::ReportDir,
                "writes the physical model's report",
            ));
        }
        if !self.height_map && self.mesh_points.is_some() {
            return Err(RequestError::Belongs {
                field: Field::MeshPoints,
                needs: Field::HeightMap,
                why: "sets the height map's mesh",
            });
        }
        if let Some(n) = self.mesh_points {
            mesh_points(n)?;
        }
        if let Some(s) = self.probe_noise {
            if !self.physical {
                return Err(needs_physical(
                    Field::ProbeNoise,
                    "weighs the physical fit's probe heights",
                ));
            }
            probe_noise(s)?;
        }
        Ok(())
    }
}

/// A stated probe noise (mm), checked: positive, finite, at most
/// [`MAX_PROBE_NOISE_MM`].
pub fn probe_noise(mm: f64) -> Result<f64, RequestError> {
    if mm.is_finite() && mm > 0.0 && mm <= MAX_PROBE_NOISE_MM {
        Ok(mm)
    } else {
        Err(RequestError::invalid(
            Field::ProbeNoise,
            format!(
                "{mm} mm: a probe's σ is above 0 and at most {MAX_PROBE_NOISE_MM} mm (its repeatability, e.g. the standard deviation Klipper's PROBE_ACCURACY reports)"
            ),
        ))
    }
}

/// Nodes across a height map, checked ([`super::height_map::mesh_points`]).
pub fn mesh_points(n: usize) -> Result<usize, RequestError> {
    super::height_map::mesh_points(n).map_err(|p| RequestError::invalid(Field::MeshPoints, p))
}

/// The largest σ of a written value before a warning, checked: above 0,
/// at most [`super::MAX_SIGMA_LIMIT`].
pub fn max_sigma(v: f64) -> Result<f64, RequestError> {
    let top = super::MAX_SIGMA_LIMIT;
    if v > 0.0 && v <= top {
        Ok(v)
    } else {
        Err(RequestError::invalid(
            Field::MaxSigma,
            format!("{v} must be above 0 and at most {top}"),
        ))
    }
}

/// Whether a user set Marlin's G33 comparison (`points` read, its tower
/// angles held): [`Choices::g33`]. The points are compared with G33's
/// default, which both front ends pass when none is given.
pub fn g33_given(points: usize, fixed_angles: bool) -> bool {
    points != usize::from(super::g33::DEFAULT_POINTS) || fixed_angles
}

/// G33's probe points for a comparison (its `P`), checked:
/// [`super::g33::FEWEST_POINTS`] to [`super::g33::MOST_POINTS`]. The
/// problem names no value: each front end gives the one it read.
pub fn g33_points(n: usize) -> Result<u8, RequestError> {
    use super::g33::{FEWEST_POINTS, MOST_POINTS};
    u8::try_from(n)
        .ok()
        .filter(|p| (FEWEST_POINTS..=MOST_POINTS).contains(p))
        .ok_or_else(|| {
            RequestError::invalid(
                Field::G33Points,
                format!("G33's probe points (its P) are {FEWEST_POINTS} to {MOST_POINTS}"),
            )
        })
}

/// G33's calibration radius (mm), checked: finite, above 0.
pub fn g33_radius(mm: f64) -> Result<f64, RequestError> {
    if mm.is_finite() && mm > 0.0 {
        Ok(mm)
    } else {
        Err(RequestError::invalid(
            Field::G33Radius,
            format!("{mm} mm: G33's calibration radius is a distance above 0"),
        ))
    }
}
