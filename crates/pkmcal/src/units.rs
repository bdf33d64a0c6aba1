//! Units and kinds of quantities, declared by each mechanism and carried from
//! the description to the report: nothing downstream guesses a unit from a
//! name or an index range.
//!
//! Internal units are fixed (docs/model.md §9): lengths in mm, angles in rad,
//! rotational stiffness in N·m/rad, linear stiffness in N/mm. A [`Unit`]
//! says which of them a number is in; [`Unit::readable`] chooses a display
//! scale (µm, mrad, µrad) for small values.

use serde::{Deserialize, Serialize};

/// The unit a number is expressed in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Unit {
    /// Millimetre (lengths, positions, prismatic joints).
    #[serde(rename = "mm")]
    Millimetre,
    /// Radian (angles, revolute joints, orientations).
    #[serde(rename = "rad")]
    Radian,
    /// Newton metre per radian (stiffness of a revolute actuator).
    #[serde(rename = "N·m/rad")]
    NewtonMetrePerRadian,
    /// Newton per millimetre (stiffness of a prismatic actuator).
    #[serde(rename = "N/mm")]
    NewtonPerMillimetre,
}

/// Largest length that means anything to a machine (mm, 1 km): lengths,
/// positions and prismatic commands beyond it are refused as input errors
/// (they would only overflow the arithmetic).
pub const MAX_LENGTH_MM: f64 = 1e6;
/// Largest measured orientation angle accepted (rad); revolute commands are
/// reduced modulo 2π instead.
pub const MAX_ANGLE_RAD: f64 = 1e3;
/// Largest actuator deflection the elastic model is used for (rad).
pub const MAX_DEFLECTION_RAD: f64 = 0.1;
/// Largest actuator deflection the elastic model is used for (mm).
pub const MAX_DEFLECTION_MM: f64 = 10.0;
/// Largest load component accepted (N or N·m).
pub const MAX_LOAD: f64 = 1e9;
/// Largest stiffness accepted (N·m/rad or N/mm).
pub const MAX_STIFFNESS: f64 = 1e15;

impl Unit {
    /// Largest magnitude of a value of this unit that is accepted as input.
    pub fn max_magnitude(self) -> f64 {
        match self {
            Unit::Millimetre => MAX_LENGTH_MM,
            Unit::Radian => MAX_ANGLE_RAD,
            _ => MAX_STIFFNESS,
        }
    }

    /// The unit's symbol as printed (`mm`, `rad`, `N·m/rad`, `N/mm`).
    pub fn symbol(self) -> &'static str {
        match self {
            Unit::Millimetre => "mm",
            Unit::Radian => "rad",
            Unit::NewtonMetrePerRadian => "N·m/rad",
            Unit::NewtonPerMillimetre => "N/mm",
        }
    }

    /// What the unit measures.
    pub fn quantity(self) -> Quantity {
        match self {
            Unit::Millimetre => Quantity::Length,
            Unit::Radian => Quantity::Angle,
            Unit::NewtonMetrePerRadian | Unit::NewtonPerMillimetre => Quantity::Stiffness,
        }
    }

    /// The stiffness unit of an actuator whose joint moves in this unit.
    pub fn stiffness_of_joint(self) -> Unit {
        match self {
            Unit::Radian => Unit::NewtonMetrePerRadian,
            _ => Unit::NewtonPerMillimetre,
        }
    }

    /// A display scale for numbers of size about `magnitude` in this unit:
    /// the factor to multiply by and the symbol to print (mm → µm below
    /// 0.1 mm, rad → mrad below 0.1 rad and µrad below 0.1 mrad).
    pub fn readable(self, magnitude: f64) -> (f64, &'static str) {
        let m = magnitude.abs();
        match self {
            Unit::Millimetre if m < 0.1 => (1e3, "µm"),
            Unit::Radian if m < 1e-4 => (1e6, "µrad"),
            Unit::Radian if m < 0.1 => (1e3, "mrad"),
            _ => (1.0, self.symbol()),
        }
    }

    /// A name for a group of quantities in this unit, for tables and figures.
    pub fn group_name(self) -> &'static str {
        match self {
            Unit::Millimetre => "lengths",
            Unit::Radian => "angles",
            Unit::NewtonMetrePerRadian => "rotational stiffness",
            Unit::NewtonPerMillimetre => "linear stiffness",
        }
    }
}

impl std::fmt::Display for Unit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.symbol())
    }
}

/// What a quantity measures: like quantities share a noise level and a scale;
/// unlike ones never meet without one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Quantity {
    /// A length or position (mm).
    Length,
    /// An angle or orientation (rad).
    Angle,
    /// An actuator stiffness.
    Stiffness,
}

/// The role of a parameter in the model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ParamKind {
    /// A number of the geometry ρ (link length, joint position, axis angle).
    Geometry,
    /// An encoder (zero) offset Δq of an actuator, in the unit of its joint.
    Offset,
    /// An actuator stiffness k.
    Stiffness,
    /// A parameter of the measuring instrument (its frame, sockets, bar offset,
    /// target points).
    Instrument,
}

impl ParamKind {
    /// Readable name of the kind.
    pub fn name(self) -> &'static str {
        match self {
            ParamKind::Geometry => "geometry",
            ParamKind::Offset => "encoder offset",
            ParamKind::Stiffness => "stiffness",
            ParamKind::Instrument => "instrument",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readable_scales() {
        assert_eq!(Unit::Millimetre.readable(0.002), (1e3, "µm"));
        assert_eq!(Unit::Millimetre.readable(2.0), (1.0, "mm"));
        assert_eq!(Unit::Radian.readable(1e-5), (1e6, "µrad"));
        assert_eq!(Unit::Radian.readable(2e-3), (1e3, "mrad"));
        assert_eq!(
            Unit::Radian.stiffness_of_joint(),
            Unit::NewtonMetrePerRadian
        );
        assert_eq!(
            Unit::Millimetre.stiffness_of_joint(),
            Unit::NewtonPerMillimetre
        );
    }
}
