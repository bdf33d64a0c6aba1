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

/// An angle unit a data file may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum AngleUnit {
    /// Radian (the internal unit).
    #[default]
    #[serde(rename = "rad")]
    Radian,
    /// Degree.
    #[serde(rename = "deg")]
    Degree,
}

/// A length unit a data file may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum LengthUnit {
    /// Millimetre (the internal unit).
    #[default]
    #[serde(rename = "mm")]
    Millimetre,
    /// Metre.
    #[serde(rename = "m")]
    Metre,
    /// Micrometre.
    #[serde(rename = "um")]
    Micrometre,
}

impl AngleUnit {
    /// Radians per unit.
    pub fn to_rad(self) -> f64 {
        match self {
            AngleUnit::Radian => 1.0,
            AngleUnit::Degree => std::f64::consts::PI / 180.0,
        }
    }
    /// The symbol (`rad`, `deg`).
    pub fn symbol(self) -> &'static str {
        match self {
            AngleUnit::Radian => "rad",
            AngleUnit::Degree => "deg",
        }
    }
}

impl LengthUnit {
    /// Millimetres per unit.
    pub fn to_mm(self) -> f64 {
        match self {
            LengthUnit::Millimetre => 1.0,
            LengthUnit::Metre => 1e3,
            LengthUnit::Micrometre => 1e-3,
        }
    }
    /// The symbol (`mm`, `m`, `um`).
    pub fn symbol(self) -> &'static str {
        match self {
            LengthUnit::Millimetre => "mm",
            LengthUnit::Metre => "m",
            LengthUnit::Micrometre => "um",
        }
    }
}

/// The units of the numbers in a user's data files (commands, measured
/// positions, targets, σ, bar lengths), converted to the internal ones on
/// read and back on write. Parameter files and reports stay in the internal
/// units (mm, rad), which they name.
///
/// Commands of revolute actuators are in `angle`, or in encoder counts when
/// `counts_per_rev` is given; commands of prismatic actuators in `length`, or
/// in counts when `counts_per_mm` is given. Tool positions and distances are
/// in `length`, tool orientations in `angle`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FileUnits {
    /// Unit of angles (revolute commands, orientations).
    #[serde(default)]
    pub angle: AngleUnit,
    /// Unit of lengths (prismatic commands, positions, distances).
    #[serde(default)]
    pub length: LengthUnit,
    /// Encoder counts per revolution of a revolute actuator: its commands are
    /// then counts.
    #[serde(default)]
    pub counts_per_rev: Option<f64>,
    /// Encoder counts per millimetre of a prismatic actuator: its commands
    /// are then counts.
    #[serde(default)]
    pub counts_per_mm: Option<f64>,
}

/// Whether a number in a data file is an actuator command or a reading
/// (position, orientation, distance, target, σ).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// An actuator command (may be in encoder counts).
    Command,
    /// Any other number: measured, target or predicted coordinates, σ.
    Reading,
}

impl FileUnits {
    /// Internal value per file unit of a number of internal unit `unit`
    /// playing `role` (`internal = file × factor`).
    pub fn factor(&self, unit: Unit, role: Role) -> f64 {
        match (unit, role) {
            (Unit::Radian, Role::Command) if self.counts_per_rev.is_some() => {
                std::f64::consts::TAU / self.counts_per_rev.unwrap_or(1.0)
            }
            (Unit::Millimetre, Role::Command) if self.counts_per_mm.is_some() => {
                1.0 / self.counts_per_mm.unwrap_or(1.0)
            }
            (Unit::Radian, _) => self.angle.to_rad(),
            (Unit::Millimetre, _) => self.length.to_mm(),
            _ => 1.0,
        }
    }

    /// The file unit's symbol for a number of internal unit `unit`.
    pub fn symbol(&self, unit: Unit, role: Role) -> &'static str {
        match (unit, role) {
            (Unit::Radian, Role::Command) if self.counts_per_rev.is_some() => "counts",
            (Unit::Millimetre, Role::Command) if self.counts_per_mm.is_some() => "counts",
            (Unit::Radian, _) => self.angle.symbol(),
            (Unit::Millimetre, _) => self.length.symbol(),
            _ => unit.symbol(),
        }
    }

    /// Whether every factor is 1 (the internal units).
    pub fn is_internal(&self) -> bool {
        *self == FileUnits::default()
    }

    /// Overlay `other`'s explicitly given settings (`Some`) on these.
    pub fn with(mut self, other: &PartialUnits) -> Self {
        if let Some(a) = other.angle {
            self.angle = a;
        }
        if let Some(l) = other.length {
            self.length = l;
        }
        if other.counts_per_rev.is_some() {
            self.counts_per_rev = other.counts_per_rev;
        }
        if other.counts_per_mm.is_some() {
            self.counts_per_mm = other.counts_per_mm;
        }
        self
    }

    /// Check that counts per revolution or per mm are positive and finite.
    pub fn validate(&self) -> crate::error::Result<()> {
        for (name, v) in [
            ("counts_per_rev", self.counts_per_rev),
            ("counts_per_mm", self.counts_per_mm),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0 && v < 1e15)
            {
                return Err(crate::error::Error::InvalidRequest(format!(
                    "units: {name} = {v} must be a positive number of encoder counts"
                )));
            }
        }
        Ok(())
    }

    /// Text for a summary line: `angles in deg, lengths in m, …`.
    pub fn describe(&self) -> String {
        let mut parts = vec![
            format!("angles in {}", self.angle.symbol()),
            format!("lengths in {}", self.length.symbol()),
        ];
        if let Some(c) = self.counts_per_rev {
            parts.push(format!("revolute commands in counts ({c} per rev)"));
        }
        if let Some(c) = self.counts_per_mm {
            parts.push(format!("prismatic commands in counts ({c} per mm)"));
        }
        parts.join(", ")
    }

    /// The units a [`FileUnits::describe`] text names (the `# units:` line
    /// pkmcal writes atop a data file), read back whole: what it does not
    /// name is the internal unit, and commands are not counts.
    pub fn from_description(text: &str) -> crate::error::Result<Self> {
        let bad = |what: &str| {
            crate::error::Error::InvalidRequest(format!(
                "`{what}` is not a unit pkmcal writes (`angles in rad|deg`, `lengths in mm|m|um`, `revolute commands in counts (N per rev)`, `prismatic commands in counts (N per mm)`)"
            ))
        };
        let mut u = FileUnits::default();
        for part in text.split(", ").map(str::trim).filter(|p| !p.is_empty()) {
            let counts = |rest: &str, per: &str| -> crate::error::Result<f64> {
                rest.strip_prefix('(')
                    .and_then(|r| r.strip_suffix(&format!(" per {per})")))
                    .and_then(|n| n.parse::<f64>().ok())
                    .ok_or_else(|| bad(part))
            };
            if let Some(a) = part.strip_prefix("angles in ") {
                u.angle = match a {
                    "rad" => AngleUnit::Radian,
                    "deg" => AngleUnit::Degree,
                    _ => return Err(bad(part)),
                };
            } else if let Some(l) = part.strip_prefix("lengths in ") {
                u.length = match l {
                    "mm" => LengthUnit::Millimetre,
                    "m" => LengthUnit::Metre,
                    "um" => LengthUnit::Micrometre,
                    _ => return Err(bad(part)),
                };
            } else if let Some(r) = part.strip_prefix("revolute commands in counts ") {
                u.counts_per_rev = Some(counts(r, "rev")?);
            } else if let Some(r) = part.strip_prefix("prismatic commands in counts ") {
                u.counts_per_mm = Some(counts(r, "mm")?);
            } else {
                return Err(bad(part));
            }
        }
        u.validate()?;
        Ok(u)
    }
}

/// Units given explicitly (on the command line, or in a mechanism file's
/// `[units]` table): what is `None` keeps the setting below it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartialUnits {
    /// Angle unit.
    pub angle: Option<AngleUnit>,
    /// Length unit.
    pub length: Option<LengthUnit>,
    /// Encoder counts per revolution.
    pub counts_per_rev: Option<f64>,
    /// Encoder counts per mm.
    pub counts_per_mm: Option<f64>,
}

impl PartialUnits {
    /// Parse `angle=deg,length=m,counts_per_rev=4096` (keys in any order,
    /// any subset; `µm` and `um` both accepted).
    pub fn parse(text: &str) -> crate::error::Result<Self> {
        let bad = |m: String| crate::error::Error::InvalidRequest(m);
        let mut out = PartialUnits::default();
        let mut seen: Vec<&str> = vec![];
        for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (k, v) = item.split_once('=').ok_or_else(|| {
                bad(format!(
                    "`{item}` is not key=value; use e.g. angle=deg,length=m,counts_per_rev=4096"
                ))
            })?;
            let v = v.trim();
            if seen.contains(&k.trim()) {
                return Err(bad(format!(
                    "`{}` is given twice; give each unit once",
                    k.trim()
                )));
            }
            seen.push(k.trim());
            match k.trim() {
                "angle" => {
                    out.angle = Some(match v {
                        "rad" | "radian" | "radians" => AngleUnit::Radian,
                        "deg" | "degree" | "degrees" | "°" => AngleUnit::Degree,
                        _ => return Err(bad(format!("angle unit `{v}`: use rad or deg"))),
                    })
                }
                "length" => {
                    out.length = Some(match v {
                        "mm" => LengthUnit::Millimetre,
                        "m" => LengthUnit::Metre,
                        "um" | "µm" => LengthUnit::Micrometre,
                        _ => return Err(bad(format!("length unit `{v}`: use mm, m or um"))),
                    })
                }
                key @ ("counts_per_rev" | "counts_per_mm") => {
                    let n: f64 = v
                        .parse()
                        .map_err(|_| bad(format!("{key} = `{v}` is not a number")))?;
                    if key == "counts_per_rev" {
                        out.counts_per_rev = Some(n);
                    } else {
                        out.counts_per_mm = Some(n);
                    }
                }
                other => {
                    return Err(bad(format!(
                        "unknown unit key `{other}`: the keys are angle, length, counts_per_rev, counts_per_mm"
                    )));
                }
            }
        }
        FileUnits::default().with(&out).validate()?;
        Ok(out)
    }
}

/// N·mm → N·m: a tool force (N) times a length in mm gives 1e-3 N·m.
pub const MM_TO_M: f64 = 1e-3;

/// N·m to N·mm.
pub const M_TO_MM: f64 = 1e3;
