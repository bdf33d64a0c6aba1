//! The data set: measured poses ([`Measurement`]), each with its commands,
//! readings, known σ and origin, and the noise levels of simulated readings.

use crate::error::Origin;
use crate::units::{Quantity, Unit};

/// One measured pose: what was commanded, what was measured, how well, and
/// where it came from. Every subset of a data set (held-out poses, folds,
/// poses left after dropping outliers) keeps each pose's σ and origin.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize, serde::Deserialize)]
pub struct Measurement {
    /// The target the commands were computed for (tool coordinates), if known.
    pub target: Option<Vec<f64>>,
    /// Actuator commands (each in its joint's unit, rad or mm).
    pub commands: Vec<f64>,
    /// The commands of a second pose when the row is a distance between two
    /// poses (a printed object or a gauge measured with calipers): `measured`
    /// is then one value, the distance between the tool points at `commands`
    /// and at `partner` (mm, [`crate::measurement::DISTANCE_AXIS`]), whatever
    /// the instrument of the other rows.
    pub partner: Option<Vec<f64>>,
    /// Measured coordinates (each in its axis's unit, mm or rad).
    pub measured: Vec<f64>,
    /// Known standard deviation of each measured coordinate (same unit);
    /// `None` where it is to be estimated from the residuals. Empty: none
    /// known.
    pub sigma: Vec<Option<f64>>,
    /// Where the pose came from, for messages and reports; `None`: its
    /// position in the data given to the library.
    pub origin: Option<Origin>,
    /// The point of the tool body read, in the tool frame (mm), where it is
    /// not the tool point: a probe reading a second point fixed on the tool
    /// (a printer's nozzle touching the bed where its probe triggers
    /// elsewhere). `None`: the tool point. Only a probe reads another point,
    /// and only on a spatial tool with an orientation
    /// ([`crate::MeasurementModel::check_point`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<Vec<f64>>,
}

impl Measurement {
    /// The known standard deviation of coordinate `axis`, if any.
    pub fn sigma_of(&self, axis: usize) -> Option<f64> {
        self.sigma.get(axis).copied().flatten()
    }
}

/// `data` with every pose's [`Origin`] filled in (its 1-based position where
/// none was given), so that subsets still name the original poses.
pub fn numbered(data: &[Measurement]) -> Vec<Measurement> {
    numbered_cow(data).into_owned()
}

/// [`numbered`] without a copy when every pose is numbered already (a
/// calibration's own rows: ten thousand poses are megabytes).
pub fn numbered_cow(data: &[Measurement]) -> std::borrow::Cow<'_, [Measurement]> {
    if data.iter().all(|m| m.origin.is_some()) {
        return std::borrow::Cow::Borrowed(data);
    }
    std::borrow::Cow::Owned(numbered_copy(data))
}

fn numbered_copy(data: &[Measurement]) -> Vec<Measurement> {
    let mut data = data.to_vec();
    number(&mut data);
    data
}

/// Fill in every pose's [`Origin`] where none was given, as [`numbered`]
/// does, in place.
pub(crate) fn number(data: &mut [Measurement]) {
    for (i, m) in data.iter_mut().enumerate() {
        let distance = m.partner.is_some();
        m.origin.get_or_insert(Origin {
            pose: i + 1,
            line: None,
            distance,
        });
    }
}

/// Standard deviations of simulated measurement noise, per kind of
/// coordinate: a length noise never lands on an angle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// On every length coordinate (positions, distances), mm.
    pub length: f64,
    /// On every angle coordinate (orientations), rad.
    pub angle: f64,
}

/// The default angle noise of [`Noise::lengths`]: the length noise over this
/// lever arm (mm), e.g. 10 µrad for 2 µm.
pub const DEFAULT_ANGLE_LEVER_MM: f64 = 200.0;

impl Noise {
    /// No noise.
    pub const NONE: Noise = Noise {
        length: 0.0,
        angle: 0.0,
    };
    /// Length noise `mm` and the angle noise of a tracker of that quality:
    /// `mm /` [`DEFAULT_ANGLE_LEVER_MM`] rad.
    pub fn lengths(mm: f64) -> Self {
        Noise {
            length: mm,
            angle: mm / DEFAULT_ANGLE_LEVER_MM,
        }
    }
    /// The standard deviation for a coordinate in `unit`.
    pub fn for_unit(&self, unit: Unit) -> f64 {
        match unit.quantity() {
            Quantity::Angle => self.angle,
            _ => self.length,
        }
    }

    /// A noise that can weigh readings: each σ finite, at least
    /// [`MIN_NOISE`] and at most its unit's largest magnitude. `field` names
    /// it in the error (`noise`, `stated noise`): a σ of 0 would give
    /// readings an infinite weight.
    pub fn check(&self, field: &str) -> crate::error::Result<()> {
        for (v, unit, part) in [
            (self.length, Unit::Millimetre, "length"),
            (self.angle, Unit::Radian, "angle"),
        ] {
            if !(v.is_finite() && (MIN_NOISE..=unit.max_magnitude()).contains(&v)) {
                return Err(crate::error::Error::OutOfRange {
                    field: format!("{field}.{part}"),
                    value: v,
                    expected: format!(
                        "a standard deviation, a positive number of {unit} between {MIN_NOISE:e} and {:e}",
                        unit.max_magnitude()
                    ),
                });
            }
        }
        Ok(())
    }
}

/// Smallest standard deviation a reading may be weighed with (mm or rad):
/// no instrument is better, and smaller ones only overflow the weights.
pub const MIN_NOISE: f64 = 1e-12;

impl From<f64> for Noise {
    /// [`Noise::lengths`].
    fn from(mm: f64) -> Self {
        Noise::lengths(mm)
    }
}
