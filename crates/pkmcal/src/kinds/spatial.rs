//! Spatial parallel mechanisms described as a platform and legs
//! ([`SpatialDescription`], plain data a user writes in TOML), turned into a
//! [`Mechanism`] ([`SpatialMechanism`]) whose loop closure (docs/model.md
//! eq. 3) and parameter names are derived from the description.
//!
//! (A long file: the spatial description's builder, its joints and their
//! exact derivatives are one job.)
//!
//! Conventions (docs/mechanisms.md explains them with examples):
//!
//! - The base frame is the measurement frame. The platform (the moving body)
//!   has a frame whose origin is at `(x, y, z)` in the base frame; with
//!   `motion = "full"` it turns by `R = Rz(rz) · Ry(ry) · Rx(rx)` (as on a
//!   Gough–Stewart platform), with `motion = "translation"` it keeps the base
//!   frame's orientation (a delta robot's parallelograms).
//! - Each leg is a chain from the base to the platform. Its frame starts at
//!   the base origin, turned about the base z axis by the leg's `angle` (if
//!   given). Each joint of the chain sits at `at` in the current frame and
//!   moves along or about `axis` (a direction in the current frame, tilted by
//!   the joint's two tilt parameters); a revolute joint turns the frame that
//!   follows by `q` (rad), a prismatic joint moves it `q` (mm) along the axis.
//! - The chain ends at the point `at` of the last frame and meets the platform
//!   point `platform` (platform frame) through its `end`:
//!   - `spherical`: the two points coincide (three equations);
//!   - `rod`: a link between two spherical joints (a Gough–Stewart leg, a
//!     delta's parallelogram) keeps them `length` apart (one equation); an
//!     actuated rod's length is a joint (a Gough–Stewart leg).
//! - Joints `q = [each leg's joints (and actuated rod), in file order, then
//!   the platform coordinates]`. The tool coordinates are the platform
//!   coordinates (or the subset `tool` names, as many as degrees of freedom).
//! - Every number of the geometry is a parameter. Its name is the one the user
//!   writes (a string in place of a number, its value in `[parameters]`; one
//!   name used twice is one parameter) or derived: `<leg>.angle`, `<joint>.x`,
//!   `<joint>.y`, `<joint>.z`, `<joint>.tilt1`, `<joint>.tilt2`, `<leg>.ex`,
//!   `<leg>.ey`, `<leg>.ez` (chain end), `<leg>.px`, `<leg>.py`, `<leg>.pz`
//!   (platform point), `<leg>.length` (rod).
//! - A joint's axis is `n + tan(tilt1) e1 + tan(tilt2) e2`, normalised, where
//!   `n` is the written `axis` (normalised), `e1` is `n × z` normalised (`x`
//!   when `n` is along `z`) and `e2 = n × e1`: the tilts turn the axis by
//!   small angles about two directions across it.
//! - An actuated joint `J` has the encoder offset `dJ` and the stiffness `kN`
//!   where `N` is `J` without a leading `q`. Revolute actuators: N·m/rad;
//!   prismatic ones and actuated rods: N/mm (one kind per mechanism).

use crate::error::{Error, Result};
use crate::kinds::build::{Built, Joints, Parts, assemble, assembly_value, finish, stiffness_of};
use crate::kinds::description::{Names, Value, bad};
use crate::linalg::small::{
    Mat3, apply, apply_transposed, axis_basis, column, cross, dot, identity, mat_mul, norm,
    normalized, rotation_about, sub,
};
use crate::mechanism::tool::ToolLayout;
use crate::mechanism::{Mechanism, Scalar, Spec};
use crate::units::Unit;
use serde::Deserialize;
use std::collections::BTreeMap;

/// Names of the platform coordinates, in order (`motion = "full"`; the first
/// three with `motion = "translation"`).
pub const PLATFORM_AXES: [&str; 6] = ["x", "y", "z", "rx", "ry", "rz"];

/// How the platform moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Motion {
    /// Position only, orientation fixed (delta robots): coordinates `x y z`.
    Translation,
    /// Position and orientation: `x y z rx ry rz`.
    Full,
}

impl Motion {
    /// Number of platform coordinates.
    pub fn coordinates(self) -> usize {
        match self {
            Motion::Translation => 3,
            Motion::Full => 6,
        }
    }
}

/// Revolute, prismatic, universal or spherical.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SpatialJointKind {
    /// Rotation about the axis (coordinate in rad).
    Revolute,
    /// Translation along the axis (coordinate in mm).
    Prismatic,
    /// Two rotations, about `axis` then about `axis2` (in the frame the first
    /// one turned): revolute joints `<name>_1` and `<name>_2`, the second at
    /// the first's centre. Its errors are parameters like any joint's: the
    /// second axis's offset `<name>_2.x …` and tilts `<name>_2.tilt1 …`
    /// (nominally 0). Passive.
    Universal,
    /// Three rotations, about `axis`, `axis2`, `axis3`: revolute joints
    /// `<name>_1`, `<name>_2`, `<name>_3` about one centre. Passive. (A
    /// spherical joint that meets the platform is the leg's `end`.)
    Spherical,
}

/// How a leg's chain meets the platform.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EndKind {
    /// A spherical joint: the chain's end point is the platform point.
    Spherical,
    /// A rod between two spherical joints: the points are `length` apart.
    Rod,
}

#[doc(hidden)] // public for the integration tests only
pub fn origin() -> [Value; 3] {
    [Value::Number(0.0), Value::Number(0.0), Value::Number(0.0)]
}

/// One joint of a leg's chain.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialJoint {
    /// Joint name (the coordinate's name in `q`, and the command column when
    /// actuated).
    pub name: String,
    /// Revolute or prismatic.
    pub kind: SpatialJointKind,
    /// Position of the joint in the current frame (mm); the origin if left out.
    #[serde(default = "origin")]
    pub at: [Value; 3],
    /// Direction of the joint's axis in the current frame (normalised).
    pub axis: [f64; 3],
    /// Universal and spherical joints: the second axis, in the frame the
    /// first rotation turned; perpendicular to `axis` if left out.
    #[serde(default)]
    pub axis2: Option<[f64; 3]>,
    /// Spherical joints: the third axis; perpendicular to the first two if
    /// left out.
    #[serde(default)]
    pub axis3: Option<[f64; 3]>,
    /// The axis's two tilts (rad); 0 if left out.
    #[serde(default)]
    pub tilt: Option<[Value; 2]>,
    /// Whether a motor drives it.
    #[serde(default)]
    pub actuated: bool,
    /// Stiffness of the actuated joint (N·m/rad or N/mm).
    #[serde(default)]
    pub stiffness: Option<f64>,
}

/// The end of a leg: how its chain meets the platform.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LegEnd {
    /// Spherical joint or rod.
    pub kind: EndKind,
    /// The chain's end point in the last joint's frame (the leg's frame when
    /// it has no joint), mm; the origin if left out.
    #[serde(default = "origin")]
    pub at: [Value; 3],
    /// The point on the platform, in the platform frame (mm).
    pub platform: [Value; 3],
    /// Rod: its length (mm), unless actuated.
    #[serde(default)]
    pub length: Option<Value>,
    /// Actuated rod: the name of its length coordinate.
    #[serde(default)]
    pub name: Option<String>,
    /// Whether the rod's length is driven (a Gough–Stewart leg).
    #[serde(default)]
    pub actuated: bool,
    /// Axial stiffness of an actuated rod (N/mm).
    #[serde(default)]
    pub stiffness: Option<f64>,
}

/// One leg: a chain of joints from the base, and its end.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialLeg {
    /// Leg name (prefix of its derived parameter names).
    pub name: String,
    /// Rotation of the leg's frame about the base z axis (rad), if any.
    #[serde(default)]
    pub angle: Option<Value>,
    /// The joints from the base outward.
    #[serde(rename = "joint", default)]
    pub joints: Vec<SpatialJoint>,
    /// The name of an earlier leg whose chain this leg shares (its angle,
    /// joints and their coordinates: one carriage carrying two rods, as a
    /// delta's parallelogram); then the leg has no `angle` or joints of its
    /// own, only its end.
    #[serde(default)]
    pub chain: Option<String>,
    /// How the chain meets the platform.
    pub end: LegEnd,
}

/// The moving platform.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialPlatform {
    /// Translation only, or full pose.
    pub motion: Motion,
    /// The tool axes among the platform coordinates (as many as degrees of
    /// freedom); all of them if left out.
    #[serde(default)]
    pub tool: Option<Vec<String>>,
}

/// The reference configuration: the platform coordinates and approximate
/// values of every chain joint on the wanted assembly branch.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct SpatialAssembly {
    /// Platform coordinates `[x, y, z]` or `[x, y, z, rx, ry, rz]` (mm, rad);
    /// the tool axes are kept, the rest is polished so that the legs close.
    pub pose: Vec<f64>,
    /// Approximate values of the chain joints (rad, mm), by name.
    #[serde(flatten)]
    pub joints: BTreeMap<String, f64>,
}

/// A spatial parallel mechanism as a user describes it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpatialDescription {
    /// Human-readable name.
    #[serde(default)]
    pub name: Option<String>,
    /// The platform.
    pub platform: SpatialPlatform,
    /// The legs.
    #[serde(rename = "leg")]
    pub legs: Vec<SpatialLeg>,
    /// Values of the named parameters.
    #[serde(default)]
    pub parameters: BTreeMap<String, f64>,
    /// The reference configuration (assembly mode).
    pub assembly: SpatialAssembly,
    /// Box `[min, max]` per tool axis.
    pub workspace: BTreeMap<String, [f64; 2]>,
    /// Parameters identified by default (all geometric parameters and encoder
    /// offsets if left out).
    #[serde(default)]
    pub free: Option<Vec<String>>,
    /// Independent joints (as many as degrees of freedom, all actuated); the
    /// first actuated joints that are not singular at the reference if left
    /// out.
    #[serde(default)]
    pub independent: Option<Vec<String>>,
    /// Parameters renamed: old name → current name (`[renamed] radius =
    /// "delta_radius"`). Files and calibration records that use an old name
    /// keep working (with a note).
    #[serde(default)]
    pub renamed: BTreeMap<String, String>,
}

#[derive(Debug, Clone, PartialEq)]
struct JointIx {
    prismatic: bool,
    /// Index in `q`.
    q: usize,
    at: [usize; 3],
    tilt: [usize; 2],
    /// `n`, `e1`, `e2` of the axis.
    basis: [[f64; 3]; 3],
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Rod {
    /// A fixed length: the parameter's index.
    Fixed(usize),
    /// An actuated length: the joint's index.
    Joint(usize),
}

#[derive(Debug, Clone, PartialEq)]
struct LegIx {
    angle: Option<usize>,
    joints: Vec<JointIx>,
    end_at: [usize; 3],
    platform: [usize; 3],
    /// `None` for a spherical end.
    rod: Option<Rod>,
    /// First constraint row.
    row: usize,
    /// Every variable of `v = [q; ρ]` the leg's equations depend on, sorted
    /// (its joints, the platform coordinates, then its parameters).
    vars: Vec<usize>,
    /// How many of `vars` are joints.
    n_joint_vars: usize,
}

/// A spatial parallel mechanism built from a [`SpatialDescription`].
#[derive(Debug, Clone, PartialEq)]
pub struct SpatialMechanism {
    spec: Spec,
    legs: Vec<LegIx>,
    leg_names: Vec<String>,
    motion: Motion,
    /// Index in `q` of the first platform coordinate.
    pose0: usize,
    /// Platform coordinate (0..6) of each tool axis.
    tool: Vec<usize>,
    /// Characteristic length (mm): the mean of the joint offsets and rod
    /// lengths.
    length: f64,
    atlas: crate::engine::atlas::Atlas,
    /// The closed-form start of forward kinematics, when the mechanism has
    /// one (then the atlas is not built).
    trilateration: Option<Trilateration>,
    /// [`crate::engine::kinematics::branch_signs`] at the reference configuration.
    branch: [i8; 2],
    /// Sign of each leg's own inverse-kinematics determinant (its equations
    /// against its joints, the platform held) at the reference: its working
    /// mode. Empty when some leg has not as many joints as equations.
    leg_signs: Vec<i8>,
}

/// A leg's joints with every universal and spherical joint written as the
/// revolute joints it is (`<name>_1`, `<name>_2`[, `<name>_3`]).
#[doc(hidden)] // public for the integration tests only
pub fn expand_joints(leg: &SpatialLeg) -> Result<Vec<SpatialJoint>> {
    let mut out = Vec::with_capacity(leg.joints.len());
    for j in &leg.joints {
        let (ln, jn) = (&leg.name, &j.name);
        let n = match j.kind {
            SpatialJointKind::Revolute | SpatialJointKind::Prismatic => {
                if j.axis2.is_some() || j.axis3.is_some() {
                    return bad(format!(
                        "leg `{ln}`, joint `{jn}`: `axis2` and `axis3` are for universal and spherical joints"
                    ));
                }
                out.push(j.clone());
                continue;
            }
            SpatialJointKind::Universal => 2,
            SpatialJointKind::Spherical => 3,
        };
        if j.actuated || j.stiffness.is_some() {
            return bad(format!(
                "leg `{ln}`, joint `{jn}`: a {} joint is passive; drive a revolute or prismatic joint",
                if n == 2 { "universal" } else { "spherical" }
            ));
        }
        if n == 2 && j.axis3.is_some() {
            return bad(format!(
                "leg `{ln}`, joint `{jn}`: a universal joint has two axes; remove `axis3`"
            ));
        }
        for (k, a) in [Some(j.axis), j.axis2, j.axis3].iter().enumerate().take(n) {
            if let Some(a) = a {
                let len2 = dot(*a, *a);
                if !(len2.is_finite() && len2 > 1e-18) {
                    let key = ["axis", "axis2", "axis3"][k];
                    return bad(format!(
                        "leg `{ln}`, joint `{jn}`: `{key}` must be a non-zero direction [x, y, z]"
                    ));
                }
            }
        }
        let first = normalized(j.axis);
        let second = normalized(j.axis2.unwrap_or_else(|| axis_basis(first)[1]));
        if dot(cross(first, second), cross(first, second)) < 1e-12 {
            return bad(format!(
                "leg `{ln}`, joint `{jn}`: `axis2` must not be parallel to `axis`"
            ));
        }
        let third = normalized(j.axis3.unwrap_or_else(|| cross(first, second)));
        let axes = [first, second, third];
        for (k, axis) in axes.iter().enumerate().take(n) {
            out.push(SpatialJoint {
                name: format!("{jn}_{}", k + 1),
                kind: SpatialJointKind::Revolute,
                at: if k == 0 { j.at.clone() } else { origin() },
                axis: *axis,
                axis2: None,
                axis3: None,
                tilt: if k == 0 { j.tilt.clone() } else { None },
                actuated: false,
                stiffness: None,
            });
        }
    }
    Ok(out)
}

/// Leg, joint and rod names taken so far: each must be new, and none a
/// platform coordinate.
#[derive(Default)]
struct Claimed(Vec<String>);

impl Claimed {
    /// Take `name` (a `what`, as the message says).
    fn claim(&mut self, name: &str, what: &str) -> Result<()> {
        if name.is_empty() || name.contains(char::is_whitespace) {
            return bad(format!(
                "{what} `{name}`: names must be non-empty and without spaces"
            ));
        }
        if self.0.iter().any(|u| u == name) || PLATFORM_AXES.contains(&name) {
            return bad(format!(
                "{what} `{name}`: the name is already used (leg and joint names must differ from each other and from x y z rx ry rz)"
            ));
        }
        self.0.push(name.to_string());
        Ok(())
    }
}

/// Millimetres, the unit of positions and prismatic joints.
const MM: Unit = Unit::Millimetre;

/// Index one leg whose equations start at `row`: its name, angle, chain
/// joints (universal and spherical ones expanded, each added to `joints`)
/// and end, every number named in `names`.
fn index_leg(
    leg: &SpatialLeg,
    row: usize,
    earlier: &[(&str, &LegIx)],
    names: &mut Names,
    claimed: &mut Claimed,
    joints: &mut Joints,
) -> Result<LegIx> {
    claimed.claim(&leg.name, "leg")?;
    let ln = &leg.name;
    let (angle, chain) = match &leg.chain {
        Some(other) => {
            if leg.angle.is_some() || !leg.joints.is_empty() {
                return bad(format!(
                    "leg `{ln}`: a leg that shares `chain = \"{other}\"` takes that leg's angle and joints; remove its own `angle` and [[leg.joint]]"
                ));
            }
            let Some((_, shared)) = earlier.iter().find(|(n, _)| *n == other.as_str()) else {
                return bad(format!(
                    "leg `{ln}`: `chain = \"{other}\"` names no earlier leg (the leg whose chain is shared comes first)"
                ));
            };
            if shared.joints.is_empty() {
                return bad(format!(
                    "leg `{ln}`: leg `{other}` has no chain joints to share"
                ));
            }
            (shared.angle, shared.joints.clone())
        }
        None => {
            let angle = match &leg.angle {
                Some(v) => Some(names.add(v, format!("{ln}.angle"), Unit::Radian)?),
                None => None,
            };
            let expanded = expand_joints(leg)?;
            let mut chain = Vec::with_capacity(expanded.len());
            for j in &expanded {
                chain.push(index_chain_joint(ln, j, names, claimed, joints)?);
            }
            (angle, chain)
        }
    };
    let (end_at, platform, rod) = index_end(leg, names, claimed, joints)?;
    Ok(LegIx {
        angle,
        joints: chain,
        end_at,
        platform,
        rod,
        row,
        vars: vec![],
        n_joint_vars: 0,
    })
}

/// One revolute or prismatic joint of leg `ln`'s chain: its name, axis,
/// position and tilts, and, when actuated, its stiffness.
fn index_chain_joint(
    ln: &str,
    j: &SpatialJoint,
    names: &mut Names,
    claimed: &mut Claimed,
    joints: &mut Joints,
) -> Result<JointIx> {
    claimed.claim(&j.name, &format!("leg `{ln}`: joint"))?;
    let jn = &j.name;
    let len2 = dot(j.axis, j.axis);
    if !(len2.is_finite() && len2 > 1e-18) {
        return bad(format!(
            "leg `{ln}`, joint `{jn}`: `axis` must be a non-zero direction [x, y, z]"
        ));
    }
    let at = [
        names.add(&j.at[0], format!("{jn}.x"), MM)?,
        names.add(&j.at[1], format!("{jn}.y"), MM)?,
        names.add(&j.at[2], format!("{jn}.z"), MM)?,
    ];
    let zero = [Value::Number(0.0), Value::Number(0.0)];
    let t = j.tilt.as_ref().unwrap_or(&zero);
    let tilt = [
        names.add(&t[0], format!("{jn}.tilt1"), Unit::Radian)?,
        names.add(&t[1], format!("{jn}.tilt2"), Unit::Radian)?,
    ];
    let prismatic = j.kind == SpatialJointKind::Prismatic;
    let q = joints.push(jn, if prismatic { MM } else { Unit::Radian });
    let revolute = j.kind == SpatialJointKind::Revolute;
    let context = format!("leg `{ln}`: ");
    if let Some(k) = stiffness_of(&context, jn, revolute, j.actuated, j.stiffness)? {
        joints.actuate(q, k, revolute);
    }
    Ok(JointIx {
        prismatic,
        q,
        at,
        tilt,
        basis: axis_basis(j.axis),
    })
}

/// A leg's end: the chain's end point and the platform point, and its rod
/// (a fixed length, or an actuated one added to `joints`), if any.
fn index_end(
    leg: &SpatialLeg,
    names: &mut Names,
    claimed: &mut Claimed,
    joints: &mut Joints,
) -> Result<([usize; 3], [usize; 3], Option<Rod>)> {
    let (ln, e) = (&leg.name, &leg.end);
    let end_at = [
        names.add(&e.at[0], format!("{ln}.ex"), MM)?,
        names.add(&e.at[1], format!("{ln}.ey"), MM)?,
        names.add(&e.at[2], format!("{ln}.ez"), MM)?,
    ];
    let platform = [
        names.add(&e.platform[0], format!("{ln}.px"), MM)?,
        names.add(&e.platform[1], format!("{ln}.py"), MM)?,
        names.add(&e.platform[2], format!("{ln}.pz"), MM)?,
    ];
    let rod = match (e.kind, e.actuated) {
        (EndKind::Spherical, _) => {
            if e.actuated || e.length.is_some() || e.name.is_some() || e.stiffness.is_some() {
                return bad(format!(
                    "leg `{ln}`: a spherical end has no `length`, `name`, `actuated` or `stiffness` (those are for rods)"
                ));
            }
            None
        }
        (EndKind::Rod, false) => {
            let Some(l) = &e.length else {
                return bad(format!(
                    "leg `{ln}`: a rod needs `length = …` (mm), or `actuated = true` with a `name` when its length is driven"
                ));
            };
            if e.name.is_some() || e.stiffness.is_some() {
                return bad(format!(
                    "leg `{ln}`: `name` and `stiffness` are for actuated rods; add `actuated = true` or remove them"
                ));
            }
            Some(Rod::Fixed(names.add(l, format!("{ln}.length"), MM)?))
        }
        (EndKind::Rod, true) => {
            if e.length.is_some() {
                return bad(format!(
                    "leg `{ln}`: an actuated rod's length is a joint; remove `length`"
                ));
            }
            let Some(jn) = &e.name else {
                return bad(format!(
                    "leg `{ln}`: an actuated rod needs `name = \"…\"` for its length (the command column)"
                ));
            };
            claimed.claim(jn, &format!("leg `{ln}`: rod"))?;
            let Some(k) = e.stiffness.filter(|k| k.is_finite() && *k > 0.0) else {
                return bad(format!(
                    "leg `{ln}`: actuated rod `{jn}` needs a positive axial `stiffness` (N/mm)"
                ));
            };
            let q = joints.push(jn, MM);
            joints.actuate(q, k, false);
            Some(Rod::Joint(q))
        }
    };
    Ok((end_at, platform, rod))
}

/// The degrees of freedom `nq − nc` the legs leave (`nc` equations on `nq`
/// joint and platform coordinates): at least one, at most the platform's
/// coordinates, and no more than the actuators.
fn degrees_of_freedom(
    d: &SpatialDescription,
    nc: usize,
    nq: usize,
    joints: &Joints,
) -> Result<usize> {
    if nc >= nq {
        return bad(format!(
            "{} legs impose {nc} equations on {nq} joint and platform coordinates: no degree of freedom is left; a leg has too few joints",
            d.legs.len()
        ));
    }
    let dof = nq - nc;
    let coordinates = d.platform.motion.coordinates();
    if dof > coordinates {
        return bad(format!(
            "the legs leave {dof} degrees of freedom, more than the platform's {coordinates} coordinates: some leg has joints that move freely; remove joints or add legs"
        ));
    }
    if joints.actuated.len() < dof {
        return bad(format!(
            "the mechanism has {dof} degrees of freedom but only {} actuated joints",
            joints.actuated.len()
        ));
    }
    Ok(dof)
}

/// The tool axes (`[platform] tool`, all the platform coordinates if left
/// out), one per degree of freedom, and each one's platform coordinate.
fn tool_axes(
    d: &SpatialDescription,
    pose_axes: &[&str],
    dof: usize,
) -> Result<(Vec<String>, Vec<usize>)> {
    let tool_axes: Vec<String> = match &d.platform.tool {
        Some(t) => t.clone(),
        None => pose_axes.iter().map(|s| s.to_string()).collect(),
    };
    let mut tool = Vec::with_capacity(tool_axes.len());
    for a in &tool_axes {
        match pose_axes.iter().position(|p| p == a) {
            Some(i) if !tool.contains(&i) => tool.push(i),
            Some(_) => return bad(format!("[platform] `tool`: `{a}` is listed twice")),
            None => {
                return bad(format!(
                    "[platform] `tool`: `{a}` is not a platform coordinate ({})",
                    pose_axes.join(" ")
                ));
            }
        }
    }
    // A turning platform's whole pose, listed, may be read beyond its
    // degrees of freedom (a delta's effector, whose tilt a second point on
    // it shows): it is then observed, not commanded. Left out, the tool is
    // one axis per degree of freedom.
    let whole = d.platform.tool.is_some()
        && d.platform.motion == Motion::Full
        && tool.len() == pose_axes.len();
    if tool.len() != dof && !whole {
        return bad(format!(
            "the mechanism has {dof} degrees of freedom but {} tool axes ({}); list {dof} of {} as `tool = [...]` in [platform]",
            tool.len(),
            tool_axes.join(", "),
            pose_axes.join(" ")
        ));
    }
    Ok((tool_axes, tool))
}

/// The characteristic lengths (mm) of the nominal geometry (`values`): a
/// revolute joint's lever (the mean of the joint offsets, end offsets and
/// fixed rod lengths) and the platform radius for its rotations (the mean
/// distance of the platform points from its origin); 1 where there is none.
fn characteristic_lengths(legs: &[LegIx], values: &[f64]) -> (f64, f64) {
    let norm = |ix: &[usize; 3]| {
        ix.iter()
            .map(|&i| values[i] * values[i])
            .sum::<f64>()
            .sqrt()
    };
    let mean = |v: Vec<f64>| {
        let v: Vec<f64> = v.into_iter().filter(|l| *l > 1e-9).collect();
        if v.is_empty() {
            1.0
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    let length = mean(
        legs.iter()
            .flat_map(|l| {
                let mut v: Vec<f64> = l.joints.iter().map(|j| norm(&j.at)).collect();
                v.push(norm(&l.end_at));
                if let Some(Rod::Fixed(i)) = l.rod {
                    v.push(values[i].abs());
                }
                v
            })
            .collect(),
    );
    let radius = mean(legs.iter().map(|l| norm(&l.platform)).collect());
    (length, radius)
}

impl JointIx {
    /// The tilted unit axis in the current frame.
    fn axis<D: Scalar>(&self, rho: &impl Fn(usize) -> D) -> [D; 3] {
        let (t1, t2) = (rho(self.tilt[0]).tan(), rho(self.tilt[1]).tan());
        let [n, e1, e2] = self.basis;
        let v = [0, 1, 2].map(|k| D::from(n[k]) + t1 * e1[k] + t2 * e2[k]);
        let len = norm(v);
        v.map(|c| c / len)
    }
}

impl LegIx {
    /// The variables of `v = [q; ρ]` its equations depend on (its joints,
    /// the platform coordinates from `pose0`, then its parameters after
    /// the `nq` joints), sorted ([`LegIx::vars`]).
    fn index_variables(&mut self, pose0: usize, nq: usize) {
        let mut v: Vec<usize> = self.unknowns().chain(pose0..nq).collect();
        self.n_joint_vars = v.len();
        let mut p: Vec<usize> = self.angle.into_iter().collect();
        for j in &self.joints {
            p.extend(j.at);
            p.extend(j.tilt);
        }
        p.extend(self.end_at);
        p.extend(self.platform);
        if let Some(Rod::Fixed(i)) = self.rod {
            p.push(i);
        }
        p.sort_unstable();
        p.dedup();
        v.extend(p.into_iter().map(|i| nq + i));
        self.vars = v;
    }

    /// Number of equations.
    fn rows(&self) -> usize {
        if self.rod.is_some() { 1 } else { 3 }
    }
    /// The leg's joints in `q` (chain, then actuated rod): a contiguous range.
    fn unknowns(&self) -> std::ops::Range<usize> {
        let last = match self.rod {
            Some(Rod::Joint(i)) => Some(i),
            _ => self.joints.last().map(|j| j.q),
        };
        match (self.joints.first(), last) {
            (Some(j), Some(l)) => j.q..l + 1,
            (None, Some(l)) => l..l + 1,
            _ => 0..0,
        }
    }
}

/// A translating platform held by legs that are each a chain of actuated
/// joints ending in a fixed rod (linear and rotary deltas): the actuators fix
/// each chain's end, so the platform point of each leg lies on a sphere, and
/// three spheres meet in two points (closed-form forward kinematics).
#[derive(Debug, Clone, PartialEq)]
struct Trilateration {
    /// The three legs whose spheres are intersected.
    legs: [usize; 3],
    /// The side of the spheres' centres' plane the platform is on in the
    /// reference configuration (its assembly mode), `1.0` or `-1.0`.
    side: f64,
}

/// The two points at distances `r` from the three centres `c`: the foot on
/// the centres' plane, the plane's unit normal `(c1 − c0) × (c2 − c0)` and the
/// height along it, or `None` when the spheres do not meet (or the centres
/// are collinear).
fn sphere_intersection(c: [[f64; 3]; 3], r: [f64; 3]) -> Option<([f64; 3], [f64; 3], f64)> {
    let (u, v) = (sub(c[1], c[0]), sub(c[2], c[0]));
    let d = dot(u, u).sqrt();
    if d.is_nan() || d <= 0.0 {
        return None;
    }
    let ex = u.map(|x| x / d);
    let i = dot(ex, v);
    let w = [0, 1, 2].map(|k| v[k] - i * ex[k]);
    let j = dot(w, w).sqrt();
    if j.is_nan() || j <= 1e-9 * d {
        return None;
    }
    let ey = w.map(|x| x / j);
    let ez = cross(ex, ey);
    let x = (r[0] * r[0] - r[1] * r[1] + d * d) / (2.0 * d);
    let y = (r[0] * r[0] - r[2] * r[2] + i * i + j * j) / (2.0 * j) - i * x / j;
    let h2 = r[0] * r[0] - x * x - y * y;
    // Slightly negative: the spheres (almost) touch; the Newton polish decides.
    if h2.is_nan() || h2 < -1e-6 * r[0] * r[0] {
        return None;
    }
    let foot = [0, 1, 2].map(|k| c[0][k] + x * ex[k] + y * ey[k]);
    Some((foot, ez, h2.max(0.0).sqrt()))
}

use crate::engine::newton;

impl SpatialMechanism {
    /// Leg `leg`'s equations and their derivatives with respect to its own
    /// joints (a square system: at most three of each).
    fn leg_system(
        &self,
        leg: &LegIx,
        q: &[f64],
        rho: &[f64],
    ) -> (nalgebra::DVector<f64>, nalgebra::DMatrix<f64>) {
        use nalgebra::{Const, U1};
        use num_dual::DualSVec64;
        type D = DualSVec64<3>;
        let cols = leg.unknowns();
        let n = leg.rows();
        if leg.joints.len() <= MAX_CHAIN {
            let nc = self.spec.n_constraints;
            let mut g = vec![0.0; nc];
            let mut dg = nalgebra::DMatrix::zeros(nc, cols.len());
            let frame = self.platform_frame(q);
            self.leg_closed_derivatives(leg, q, rho, &cols, &frame, (&mut g, &mut dg));
            return (
                nalgebra::DVector::from_column_slice(&g[leg.row..leg.row + n]),
                dg.rows(leg.row, n).into_owned(),
            );
        }
        let mut out = [D::from_re(0.0); 3];
        let seed = |i: usize, x: f64| {
            if cols.contains(&i) {
                D::from_re(x).derivative(i - cols.start)
            } else {
                D::from_re(x)
            }
        };
        self.leg_residual(
            leg,
            &|i| seed(i, q[i]),
            &|i| D::from_re(rho[i]),
            &mut out[..n],
        );
        let g = nalgebra::DVector::from_iterator(n, out[..n].iter().map(|d| d.re));
        let j = nalgebra::DMatrix::from_fn(n, cols.len(), |r, c| {
            out[r].eps.unwrap_generic(Const::<3>, U1)[c]
        });
        (g, j)
    }

    /// Each leg's sphere for the actuator values in `q` (the platform
    /// coordinates of `q` must be 0): the centre (chain end less the platform
    /// point) and the rod's length.
    fn leg_sphere(&self, leg: &LegIx, q: &[f64], rho: &[f64]) -> Option<([f64; 3], f64)> {
        let Some(Rod::Fixed(l)) = leg.rod else {
            return None;
        };
        let (e, b) = self.leg_points(leg, q, rho);
        Some(([0, 1, 2].map(|k| e[k] - b[k]), rho[l]))
    }

    /// The closed-form start of [`Trilateration`] if the mechanism allows it:
    /// the three legs whose centres span the largest triangle at `q0`, and
    /// the side the platform is on there.
    fn trilateration_at(&self, q0: &[f64], rho: &[f64]) -> Option<Trilateration> {
        let chains_actuated = self.legs.iter().all(|leg| {
            matches!(leg.rod, Some(Rod::Fixed(_)))
                && leg.joints.iter().all(|j| self.spec.actuated.contains(&j.q))
        });
        if self.motion != Motion::Translation || self.legs.len() < 3 || !chains_actuated {
            return None;
        }
        let mut q = q0.to_vec();
        q[self.pose0..self.pose0 + 3].fill(0.0);
        let spheres: Vec<([f64; 3], f64)> = self
            .legs
            .iter()
            .map(|leg| self.leg_sphere(leg, &q, rho))
            .collect::<Option<_>>()?;
        let n = spheres.len();
        let mut best: Option<(f64, [usize; 3])> = None;
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    let [p, r, s] = [a, b, c].map(|i| spheres[i].0);
                    let u = [0, 1, 2].map(|k| r[k] - p[k]);
                    let v = [0, 1, 2].map(|k| s[k] - p[k]);
                    let n = cross(u, v);
                    let area = dot(n, n);
                    if best.is_none_or(|(m, _)| area > m) {
                        best = Some((area, [a, b, c]));
                    }
                }
            }
        }
        let legs = best?.1;
        let (foot, normal, _) =
            sphere_intersection(legs.map(|i| spheres[i].0), legs.map(|i| spheres[i].1))?;
        let p0 = &q0[self.pose0..self.pose0 + 3];
        let side: f64 = (0..3).map(|k| (p0[k] - foot[k]) * normal[k]).sum();
        (side.abs() > 1e-9 * self.length).then_some(Trilateration {
            legs,
            side: side.signum(),
        })
    }

    /// The configuration of `commands` (one per actuated joint) in closed
    /// form ([`Trilateration`]), on the reference configuration's side.
    fn trilaterate(&self, t: &Trilateration, commands: &[f64], rho: &[f64]) -> Option<Vec<f64>> {
        let mut q = self.spec.reference_q.clone();
        for (&j, &c) in self.spec.actuated.iter().zip(commands) {
            q[j] = c;
        }
        q[self.pose0..self.pose0 + 3].fill(0.0);
        let mut c = [[0.0; 3]; 3];
        let mut r = [0.0; 3];
        for (k, &i) in t.legs.iter().enumerate() {
            (c[k], r[k]) = self.leg_sphere(&self.legs[i], &q, rho)?;
        }
        let (foot, normal, h) = sphere_intersection(c, r)?;
        for k in 0..3 {
            q[self.pose0 + k] = foot[k] + t.side * h * normal[k];
        }
        Some(q)
    }

    /// Sign of the determinant of leg `i`'s equations against its joints.
    fn leg_sign(&self, i: usize, q: &[f64], rho: &[f64]) -> i8 {
        let (_, j) = self.leg_system(&self.legs[i], q, rho);
        let d = crate::linalg::lu::determinant(j);
        if d > 0.0 {
            1
        } else if d < 0.0 {
            -1
        } else {
            0
        }
    }

    /// Inverse kinematics leg by leg when the target fixes the platform: each
    /// leg's joints by Newton on its own equations from the reference
    /// configuration (an actuated rod alone: its length), checked to keep the
    /// leg's working mode.
    fn ik_by_leg(&self, target: &[f64], rho: &[f64]) -> Result<Vec<f64>> {
        let mut q = self.spec.reference_q.clone();
        for (&k, &t) in self.tool.iter().zip(target) {
            q[self.pose0 + k] = t;
        }
        let unreachable = |reason: String| Error::Unreachable {
            target: target.to_vec(),
            reason,
        };
        for (i, (leg, name)) in self.legs.iter().zip(&self.leg_names).enumerate() {
            let cols = leg.unknowns();
            if let (true, Some(Rod::Joint(l))) = (leg.joints.is_empty(), leg.rod) {
                let (e, w) = self.leg_points(leg, &q, rho);
                let d = (0..3).map(|k| (w[k] - e[k]).powi(2)).sum::<f64>().sqrt();
                if d < 1e-9 {
                    return Err(unreachable(format!("leg `{name}` would have zero length")));
                }
                q[l] = d;
                continue;
            }
            let policy = &newton::LEG;
            let mut residual = f64::INFINITY;
            // The joints and the step (a leg's system is at most 3 × 3).
            let mut state = (&mut q, nalgebra::DVector::zeros(0));
            let end = newton::run(
                policy,
                &mut state,
                |(q, step), _| -> Result<Option<newton::Step>> {
                    let (g, a) = self.leg_system(leg, q, rho);
                    residual = g.amax();
                    *step = crate::linalg::solve::solve_square(a, g).ok_or_else(|| {
                        unreachable(format!("leg `{name}` meets a singularity on the way"))
                    })?;
                    let big = step.amax();
                    if !big.is_finite() {
                        return Ok(None);
                    }
                    // At most 0.5 rad, or half the characteristic length on
                    // a prismatic joint, at once.
                    let turn = cols
                        .clone()
                        .zip(step.iter())
                        .map(|(c, d)| match self.spec.joint_units[c] {
                            Unit::Radian => d.abs(),
                            _ => d.abs() / self.length,
                        })
                        .fold(0.0, f64::max);
                    Ok(Some(newton::Step { size: big, turn }))
                },
                |(q, step), scale| {
                    for (k, c) in cols.clone().enumerate() {
                        q[c] -= scale * step[k];
                    }
                },
            )?;
            let scale = newton::parameter_scale(rho);
            if !matches!(end, newton::End::Converged(_))
                && (residual.is_nan() || residual >= policy.residual_limit(scale))
            {
                return Err(unreachable(format!(
                    "leg `{name}` cannot reach the platform there"
                )));
            }
            if self.leg_signs[i] != 0 && self.leg_sign(i, &q, rho) != self.leg_signs[i] {
                return Err(unreachable(format!(
                    "leg `{name}` would have to change its working mode (the way from the reference configuration crosses a singularity)"
                )));
            }
        }
        Ok(q)
    }

    /// Build the mechanism from its description, in steps: index the legs
    /// (each joint, end and parameter checked as it comes), count the
    /// degrees of freedom and check the actuators and the tool axes against
    /// them, assemble the [`Spec`] by the rule of every described kind
    /// ([`crate::kinds::build::assemble`]), close the reference
    /// configuration, and finish ([`crate::kinds::build::finish`]).
    pub fn new(d: &SpatialDescription) -> Result<Self> {
        if d.legs.is_empty() {
            return bad("a spatial mechanism needs at least one [[leg]]".into());
        }
        crate::mechanism::check_size(d.legs.len(), d.legs.iter().map(|l| l.joints.len()).sum())?;
        let mut names = Names::new(&d.parameters);
        let motion = d.platform.motion;
        let pose_axes = &PLATFORM_AXES[..motion.coordinates()];
        let mut claimed = Claimed::default();
        let mut joints = Joints::default();
        let mut legs = Vec::with_capacity(d.legs.len());
        let mut row = 0;
        for leg in &d.legs {
            let earlier: Vec<(&str, &LegIx)> =
                d.legs.iter().map(|l| l.name.as_str()).zip(&legs).collect();
            let ix = index_leg(leg, row, &earlier, &mut names, &mut claimed, &mut joints)?;
            row += ix.rows();
            legs.push(ix);
        }
        names.check_used("any leg")?;
        let nc = row;
        let pose0 = joints.names.len();
        for a in pose_axes {
            joints.push(a, if a.starts_with('r') { Unit::Radian } else { MM });
        }
        let nq = joints.names.len();
        for leg in &mut legs {
            leg.index_variables(pose0, nq);
        }
        let dof = degrees_of_freedom(d, nc, nq, &joints)?;
        let work_scale = joints.work_scale()?;
        let (tool_axes, tool) = tool_axes(d, pose_axes, dof)?;
        let (length, radius) = characteristic_lengths(&legs, &names.values);
        let joint_scale: Vec<f64> = joints
            .units
            .iter()
            .enumerate()
            .map(|(i, u)| match (u, i >= pose0) {
                (Unit::Radian, true) => radius,
                (Unit::Radian, false) => length,
                _ => 1.0,
            })
            .collect();
        let spec = assemble(Parts {
            name: d.name.clone().unwrap_or_else(|| "spatial mechanism".into()),
            parameters: names,
            joints,
            n_constraints: nc,
            tool_axes,
            tool_units: tool
                .iter()
                .map(|&k| if k >= 3 { Unit::Radian } else { MM })
                .collect(),
            tool_layout: match (motion, tool.len()) {
                (Motion::Translation, 3) => ToolLayout::Points { dim: 3, count: 1 },
                // A turning platform whose tool is its origin's x, y, z (a
                // delta whose parallelograms are rods of their own): a point.
                (Motion::Full, 3) if tool == [0, 1, 2] => ToolLayout::Points { dim: 3, count: 1 },
                (Motion::Full, 6) => ToolLayout::SpatialPose,
                _ => ToolLayout::Readings,
            },
            workspace: &d.workspace,
            free: &d.free,
            work_scale,
            joint_scale,
            axis_scale: tool
                .iter()
                .map(|&k| if k >= 3 { radius } else { 1.0 })
                .collect(),
            renamed: &d.renamed,
        })?;
        let mut mech = SpatialMechanism {
            spec,
            legs,
            leg_names: d.legs.iter().map(|l| l.name.clone()).collect(),
            motion,
            pose0,
            tool,
            length,
            atlas: Default::default(),
            trilateration: None,
            branch: [0, 0],
            leg_signs: vec![],
        };
        mech.close_reference(d)?;
        finish(
            mech,
            Some(&|spec: &Spec| {
                format!(
                    "the reference configuration is singular: the actuators {} do not determine the platform there; move [assembly] `pose` away from the singularity or choose `independent`",
                    spec.independent
                        .iter()
                        .map(|&i| spec.joints[i].as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }),
        )
    }

    /// The reference configuration: the chain joints from the
    /// description's `[assembly]`, the platform from its `pose`, the
    /// actuated rods' lengths computed; Newton on the loop closure with the
    /// tool axes held, then the independent joints chosen there (or named).
    fn close_reference(&mut self, d: &SpatialDescription) -> Result<()> {
        let motion = self.motion;
        if d.assembly.pose.len() != motion.coordinates()
            || d.assembly.pose.iter().any(|v| !v.is_finite())
        {
            return bad(format!(
                "[assembly]: `pose` must be {} finite numbers [{}] (mm, rad)",
                motion.coordinates(),
                PLATFORM_AXES[..motion.coordinates()].join(", ")
            ));
        }
        let chain: Vec<usize> = self
            .legs
            .iter()
            .flat_map(|l| l.joints.iter().map(|j| j.q))
            .collect();
        for k in d.assembly.joints.keys() {
            let known = chain.iter().any(|&i| self.spec.joints[i] == *k);
            if !known {
                return bad(format!(
                    "[assembly]: `{k}` is not a joint of a leg's chain (chain joints: {}; actuated rods' lengths are computed)",
                    chain
                        .iter()
                        .map(|&i| self.spec.joints[i].as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ));
            }
        }
        let mut q0 = vec![0.0; self.spec.joints.len()];
        for &i in &chain {
            let unit = self.spec.joint_units[i].to_string();
            q0[i] = assembly_value(&d.assembly.joints, &self.spec.joints[i], &unit)?;
        }
        q0[self.pose0..].copy_from_slice(&d.assembly.pose);
        let rho = self.spec.nominal[..self.spec.geometric.len()].to_vec();
        for (leg, name) in self.legs.iter().zip(&self.leg_names) {
            if let Some(Rod::Joint(i)) = leg.rod {
                let (e, w) = self.leg_points(leg, &q0, &rho);
                let dist = (0..3).map(|k| (w[k] - e[k]).powi(2)).sum::<f64>().sqrt();
                if dist < 1e-9 {
                    return bad(format!(
                        "leg `{name}`: its rod has zero length at the reference pose"
                    ));
                }
                q0[i] = dist;
            }
        }
        self.spec.reference_q = q0.clone();
        self.spec.validate()?;
        // A whole pose read beyond the degrees of freedom: its first
        // coordinates (the position) hold the assembly, the rest follow.
        let dof = q0.len() - self.spec.n_constraints;
        let fixed: Vec<usize> = self
            .tool
            .iter()
            .take(dof)
            .map(|&k| self.pose0 + k)
            .collect();
        crate::engine::kinematics::solve_closure(self, &rho, &mut q0, &fixed).map_err(|e| {
            Error::InvalidMechanism(format!(
                "the [assembly] configuration does not close ({e}); check the lengths, the pose and the joint values (a leg that cannot reach the platform there, or guesses far from the wanted assembly)"
            ))
        })?;
        self.spec.independent = crate::engine::kinematics::independent_joints(
            self,
            d.independent.as_deref(),
            &q0,
            &rho,
        )?;
        self.spec.reference_q = q0;
        Ok(())
    }

    /// Names of the legs, in order.
    pub fn leg_names(&self) -> &[String] {
        &self.leg_names
    }

    /// How the platform moves.
    pub fn motion(&self) -> Motion {
        self.motion
    }

    /// The chain's end point and the platform point of a leg, in the base
    /// frame.
    fn leg_points<D: Scalar>(&self, leg: &LegIx, q: &[D], rho: &[D]) -> ([D; 3], [D; 3]) {
        self.leg_points_with(leg, &|i| q[i], &|i| rho[i])
    }

    /// [`Self::leg_points`] reading joint `i` as `q(i)` and geometric
    /// parameter `i` as `rho(i)`.
    fn leg_points_with<D: Scalar>(
        &self,
        leg: &LegIx,
        q: &impl Fn(usize) -> D,
        rho: &impl Fn(usize) -> D,
    ) -> ([D; 3], [D; 3]) {
        let mut r = match leg.angle {
            Some(a) => rotation_about([D::from(0.0), D::from(0.0), D::from(1.0)], rho(a)),
            None => identity(),
        };
        let mut p = [D::from(0.0); 3];
        for j in &leg.joints {
            let at = apply(&r, j.at.map(rho));
            for k in 0..3 {
                p[k] += at[k];
            }
            let u = j.axis(rho);
            if j.prismatic {
                let du = apply(&r, u);
                let t = q(j.q);
                for k in 0..3 {
                    p[k] += du[k] * t;
                }
            } else {
                r = mat_mul(&r, &rotation_about(u, q(j.q)));
            }
        }
        let e = apply(&r, leg.end_at.map(rho));
        let end = [0, 1, 2].map(|k| p[k] + e[k]);
        let pose: [D; 6] = std::array::from_fn(|k| {
            if k < self.motion.coordinates() {
                q(self.pose0 + k)
            } else {
                D::from(0.0)
            }
        });
        let b = leg.platform.map(rho);
        let w = match self.motion {
            Motion::Translation => [0, 1, 2].map(|k| pose[k] + b[k]),
            Motion::Full => crate::linalg::pose::transform(&pose, b),
        };
        (end, w)
    }

    /// A leg's equations (docs/model.md eq. 3): `end − w` for a spherical
    /// end (three), `|w − end| − L` for a rod (one), into `out`.
    fn leg_residual<D: Scalar>(
        &self,
        leg: &LegIx,
        q: &impl Fn(usize) -> D,
        rho: &impl Fn(usize) -> D,
        out: &mut [D],
    ) {
        let (e, w) = self.leg_points_with(leg, q, rho);
        match leg.rod {
            None => {
                for k in 0..3 {
                    out[k] = e[k] - w[k];
                }
            }
            Some(rod) => {
                let mut s = D::from(0.0);
                for k in 0..3 {
                    s += (w[k] - e[k]) * (w[k] - e[k]);
                }
                let l = match rod {
                    Rod::Fixed(i) => rho(i),
                    Rod::Joint(i) => q(i),
                };
                out[0] = s.sqrt() - l;
            }
        }
    }

    /// Leg `leg`'s equations with every variable of `v = [q; ρ]` read through
    /// `seed(index, value)` (which makes some of them dual numbers).
    fn leg_eval<D: Scalar>(
        &self,
        leg: &LegIx,
        v: &[f64],
        seed: &impl Fn(usize, f64) -> D,
        out: &mut [D],
    ) {
        let nq = self.spec.joints.len();
        self.leg_residual(
            leg,
            &|i| seed(i, v[i]),
            &|i| seed(nq + i, v[nq + i]),
            &mut out[..leg.rows()],
        );
    }
}

impl SpatialMechanism {
    /// A leg's equations and their first derivatives with respect to the
    /// variables of `v = [q; ρ]` in `cols`, in closed form (docs/model.md
    /// eq. 3 differentiated by hand). The chain's end `e` moves:
    ///
    /// * with a revolute joint by `w × (e − o)` (world axis `w` through the
    ///   joint's origin `o`), with a prismatic one by `w`;
    /// * with a joint's position `at` by the columns of the frame before it,
    ///   with the end offset by those of the last frame, with the leg's
    ///   `angle` by `z × e`;
    /// * with an axis tilt `t` through `δu = (I − u uᵀ) ∂v/∂t / |v|`
    ///   (`v = n + tan t₁ e₁ + tan t₂ e₂`): a prismatic joint moves what
    ///   follows by `R δu q`, a revolute one turns it by the derivative of
    ///   Rodrigues' formula, `(δu × s) sin q + (δu (u·s) + u (δu·s))(1 − cos q)`
    ///   for the rest `s` of the chain in the joint's frame.
    ///
    /// The platform point `p + R(rx, ry, rz) b` (`R = Rz Ry Rx`) moves with
    /// `x y z` by the unit vectors, with `rz, ry, rx` by `ω × (R b)`,
    /// `ω = z, Rz y, Rz Ry x`, and with `b` by the columns of `R`.
    /// Equations `e − w` (spherical end) or `|w − e| − L` (rod). The tests
    /// check every column against automatic differentiation to 1e-12.
    fn leg_closed_derivatives(
        &self,
        leg: &LegIx,
        q: &[f64],
        rho: &[f64],
        cols: &std::ops::Range<usize>,
        frame: &PlatformFrame,
        (g, dg): (&mut [f64], &mut nalgebra::DMatrix<f64>),
    ) {
        let nq = q.len();
        let mut r = match leg.angle {
            Some(a) => rotation_about([0.0, 0.0, 1.0], rho[a]),
            None => identity(),
        };
        let mut p = [0.0; 3];
        /// One chain joint: its frame before and after, world axis, origin,
        /// local axis.
        #[derive(Clone, Copy)]
        struct Step {
            before: Mat3<f64>,
            after: Mat3<f64>,
            w: [f64; 3],
            o: [f64; 3],
            u: [f64; 3],
        }
        let zero = [[0.0; 3]; 3];
        let mut steps = [Step {
            before: zero,
            after: zero,
            w: [0.0; 3],
            o: [0.0; 3],
            u: [0.0; 3],
        }; MAX_CHAIN];
        for (k, j) in leg.joints.iter().enumerate() {
            let at = apply(&r, j.at.map(|i| rho[i]));
            for c in 0..3 {
                p[c] += at[c];
            }
            let u = j.axis(&|i| rho[i]);
            let w = apply(&r, u);
            let (before, o) = (r, p);
            if j.prismatic {
                for c in 0..3 {
                    p[c] += w[c] * q[j.q];
                }
            } else {
                r = mat_mul(&r, &rotation_about(u, q[j.q]));
            }
            steps[k] = Step {
                before,
                after: r,
                w,
                o,
                u,
            };
        }
        let ea = apply(&r, leg.end_at.map(|i| rho[i]));
        let e = [0, 1, 2].map(|c| p[c] + ea[c]);
        let b = leg.platform.map(|i| rho[i]);
        let np = self.motion.coordinates();
        let PlatformFrame { pose, rot, omega } = *frame;
        let unit = |c: usize| std::array::from_fn::<f64, 3, _>(|k| if k == c { 1.0 } else { 0.0 });
        // R b, and ∂w/∂(platform coordinate k).
        let rb = apply(&rot, b);
        let dw: [[f64; 3]; 6] = [
            unit(0),
            unit(1),
            unit(2),
            cross(omega[0], rb),
            cross(omega[1], rb),
            cross(omega[2], rb),
        ];
        let w = [0, 1, 2].map(|c| pose[c] + rb[c]);
        // The equations, and how a change of the end (de) and of the
        // platform point (dw) enters them.
        let (u, length) = match leg.rod {
            None => ([0.0; 3], 0.0),
            Some(rod) => {
                let diff = sub(w, e);
                let len = norm(diff);
                let l = match rod {
                    Rod::Fixed(i) => rho[i],
                    Rod::Joint(i) => q[i],
                };
                (diff.map(|c| c / len), len - l)
            }
        };
        match leg.rod {
            None => {
                for c in 0..3 {
                    g[leg.row + c] = e[c] - w[c];
                }
            }
            Some(_) => g[leg.row] = length,
        }
        let mut add = |var: usize, de: [f64; 3], dwv: [f64; 3]| {
            if !cols.contains(&var) {
                return;
            }
            let cc = var - cols.start;
            match leg.rod {
                None => {
                    for c in 0..3 {
                        dg[(leg.row + c, cc)] += de[c] - dwv[c];
                    }
                }
                Some(_) => {
                    dg[(leg.row, cc)] += (0..3).map(|c| u[c] * (dwv[c] - de[c])).sum::<f64>();
                }
            }
        };
        let none = [0.0; 3];
        let rel = |o: [f64; 3]| sub(e, o);
        // Only joint columns asked (forward kinematics, branch checks): the
        // parameters' blocks (tilts and all) are skipped.
        let params_wanted = cols.end > nq;
        for (k, j) in leg.joints.iter().enumerate() {
            let st = steps[k];
            // The joint's own coordinate.
            let d = if j.prismatic {
                st.w
            } else {
                cross(st.w, rel(st.o))
            };
            add(j.q, d, none);
            if !params_wanted {
                continue;
            }
            // Its position.
            for c in 0..3 {
                add(nq + j.at[c], column(&st.before, c), none);
            }
            // Its axis tilts.
            let v = {
                let [n, e1, e2] = j.basis;
                let (t1, t2) = (rho[j.tilt[0]].tan(), rho[j.tilt[1]].tan());
                [0, 1, 2].map(|c| n[c] + t1 * e1[c] + t2 * e2[c])
            };
            let vlen = norm(v);
            let s_local = if j.prismatic {
                [0.0; 3]
            } else {
                // The rest of the chain in the joint's frame (after it).
                apply_transposed(&st.after, rel(st.o))
            };
            let (sq, cq) = q[j.q].sin_cos();
            for (t, basis) in [(j.tilt[0], j.basis[1]), (j.tilt[1], j.basis[2])] {
                let sec2 = 1.0 + rho[t].tan().powi(2);
                let dv = basis.map(|c| c * sec2);
                let along = dot(st.u, dv);
                let du = [0, 1, 2].map(|c| (dv[c] - st.u[c] * along) / vlen);
                let de = if j.prismatic {
                    apply(&st.before, du).map(|c| c * q[j.q])
                } else {
                    let us = dot(st.u, s_local);
                    let dus = dot(du, s_local);
                    let x = cross(du, s_local);
                    let local =
                        [0, 1, 2].map(|c| x[c] * sq + (du[c] * us + st.u[c] * dus) * (1.0 - cq));
                    apply(&st.before, local)
                };
                add(nq + t, de, none);
            }
        }
        if params_wanted {
            if let Some(a) = leg.angle {
                add(nq + a, cross([0.0, 0.0, 1.0], e), none);
            }
            for c in 0..3 {
                add(nq + leg.end_at[c], column(&r, c), none);
                add(nq + leg.platform[c], none, column(&rot, c));
            }
        }
        for (k, d) in dw.iter().enumerate().take(np) {
            add(self.pose0 + k, none, *d);
        }
        if let Some(rod) = leg.rod {
            let var = match rod {
                Rod::Fixed(i) => nq + i,
                Rod::Joint(i) => i,
            };
            if cols.contains(&var) {
                dg[(leg.row, var - cols.start)] -= 1.0;
            }
        }
    }
}

/// The platform's pose, rotation and the world axes of its three angles
/// (`ω_k`, so that `∂(R b)/∂(angle k) = ω_k × R b`), shared by every leg.
#[derive(Clone, Copy)]
struct PlatformFrame {
    pose: [f64; 6],
    rot: Mat3<f64>,
    omega: [[f64; 3]; 3],
}

impl SpatialMechanism {
    /// The [`PlatformFrame`] of configuration `q`.
    fn platform_frame(&self, q: &[f64]) -> PlatformFrame {
        let np = self.motion.coordinates();
        let pose: [f64; 6] = std::array::from_fn(|k| if k < np { q[self.pose0 + k] } else { 0.0 });
        match self.motion {
            Motion::Translation => PlatformFrame {
                pose,
                rot: identity(),
                omega: [[0.0; 3]; 3],
            },
            Motion::Full => PlatformFrame {
                pose,
                rot: crate::linalg::pose::rotation(pose[3], pose[4], pose[5]),
                omega: crate::linalg::pose::euler_axes(pose[4], pose[5]),
            },
        }
    }
}

/// Most joints in one leg's chain with closed-form first derivatives
/// (longer chains use automatic differentiation).
const MAX_CHAIN: usize = 12;

/// Chunk size of the per-leg automatic differentiation.
const CHUNK: usize = 8;
/// A variable outside the chunk being differentiated.
const NOT_SEEDED: u8 = u8::MAX;

impl SpatialMechanism {
    /// Second derivatives of leg `leg`'s equations with respect to its joint
    /// variables (rows) and `cols` (a subset of `leg.vars`), by hyper-dual
    /// numbers over those variables only: `put(row of the leg, joint, column,
    /// value)` for each entry.
    fn leg_hessians(
        &self,
        leg: &LegIx,
        v: &[f64],
        cols: &[usize],
        put: &mut impl FnMut(usize, usize, usize, f64),
    ) {
        use nalgebra::Const;
        use num_dual::HyperDualSVec64;
        type H = HyperDualSVec64<CHUNK, CHUNK>;
        let rows = &leg.vars[..leg.n_joint_vars];
        let mut out = [H::from_re(0.0); 3];
        for rc in rows.chunks(CHUNK) {
            for cc in cols.chunks(CHUNK) {
                let seed = |i: usize, x: f64| {
                    let mut d = H::from_re(x);
                    if let Some(k) = rc.iter().position(|&c| c == i) {
                        d = d.derivative1(k);
                    }
                    if let Some(k) = cc.iter().position(|&c| c == i) {
                        d = d.derivative2(k);
                    }
                    d
                };
                self.leg_eval(leg, v, &seed, &mut out);
                for (r, o) in out.iter().enumerate().take(leg.rows()) {
                    let block = o.eps1eps2.unwrap_generic(Const::<CHUNK>, Const::<CHUNK>);
                    for (a, &ra) in rc.iter().enumerate() {
                        for (b, &cb) in cc.iter().enumerate() {
                            put(r, ra, cb, block[(a, b)]);
                        }
                    }
                }
            }
        }
    }
}

impl Built for SpatialMechanism {
    const ATLAS_POINTS: usize = 800;
    fn spec_mut(&mut self) -> &mut Spec {
        &mut self.spec
    }
    /// The branch signs, each leg's working mode when every leg has as
    /// many joints as equations, and the closed-form start of forward
    /// kinematics when the mechanism has one.
    fn keep_reference(&mut self, signs: [i8; 2]) {
        self.branch = signs;
        let q0 = self.spec.reference_q.clone();
        let rho = self.spec.nominal[..self.spec.n_geometric()].to_vec();
        if self.legs.iter().all(|l| l.unknowns().len() == l.rows()) {
            self.leg_signs = (0..self.legs.len())
                .map(|i| self.leg_sign(i, &q0, &rho))
                .collect();
        }
        self.trilateration = self.trilateration_at(&q0, &rho);
    }
    /// None with a closed-form start.
    fn atlas_mut(&mut self) -> Option<&mut crate::engine::atlas::Atlas> {
        match self.trilateration {
            None => Some(&mut self.atlas),
            Some(_) => None,
        }
    }
}

impl Mechanism for SpatialMechanism {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    /// Per leg (docs/model.md eq. 3): `end − w = 0` for a spherical end (three
    /// equations), `|w − end| − L = 0` for a rod, where `end` is the chain's
    /// end point and `w` the platform point, both in the base frame.
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        for leg in &self.legs {
            let n = leg.rows();
            self.leg_residual(leg, &|i| q[i], &|i| rho[i], &mut g[leg.row..leg.row + n]);
        }
    }

    /// Per leg, by automatic differentiation over the leg's own variables
    /// only (its joints, the platform and its parameters): every other entry
    /// of a leg's rows is zero, so this costs a fraction of differentiating
    /// the whole mechanism at once.
    fn first_derivatives(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        use nalgebra::{Const, DMatrix, U1};
        use num_dual::DualSVec64;
        type D = DualSVec64<CHUNK>;
        let (nc, nt) = (self.spec.n_constraints, self.tool.len());
        let mut g = vec![0.0; nc];
        let mut dg = DMatrix::zeros(nc, cols.len());
        let mut dx = DMatrix::zeros(nt, cols.len());
        let frame = self.platform_frame(q);
        for leg in &self.legs {
            if leg.joints.len() <= MAX_CHAIN {
                self.leg_closed_derivatives(leg, q, rho, &cols, &frame, (&mut g, &mut dg));
            }
        }
        // Longer chains: automatic differentiation of the leg.
        let mut long = self
            .legs
            .iter()
            .filter(|l| l.joints.len() > MAX_CHAIN)
            .peekable();
        let v: Vec<f64> = match long.peek() {
            Some(_) => q.iter().chain(rho).copied().collect(),
            None => vec![],
        };
        let mut slot = vec![NOT_SEEDED; v.len()];
        let mut out = [D::from_re(0.0); 3];
        for leg in long {
            let local: Vec<usize> = leg
                .vars
                .iter()
                .copied()
                .filter(|i| cols.contains(i))
                .collect();
            let n = leg.rows();
            if local.is_empty() {
                let mut o = [0.0; 3];
                self.leg_eval(leg, &v, &|_, x| x, &mut o);
                g[leg.row..leg.row + n].copy_from_slice(&o[..n]);
                continue;
            }
            for chunk in local.chunks(CHUNK) {
                // Each variable's place in the chunk, looked up on every read.
                for (k, &c) in chunk.iter().enumerate() {
                    slot[c] = k as u8;
                }
                let seed = |i: usize, x: f64| match slot[i] {
                    NOT_SEEDED => D::from_re(x),
                    k => D::from_re(x).derivative(k as usize),
                };
                self.leg_eval(leg, &v, &seed, &mut out);
                for &c in chunk {
                    slot[c] = NOT_SEEDED;
                }
                for r in 0..n {
                    g[leg.row + r] = out[r].re;
                    let e = out[r].eps.unwrap_generic(Const::<CHUNK>, U1);
                    for (k, &c) in chunk.iter().enumerate() {
                        dg[(leg.row + r, c - cols.start)] = e[k];
                    }
                }
            }
        }
        let mut x = vec![0.0; nt];
        for (r, &k) in self.tool.iter().enumerate() {
            let c = self.pose0 + k;
            x[r] = q[c];
            if cols.contains(&c) {
                dx[(r, c - cols.start)] = 1.0;
            }
        }
        Some(crate::mechanism::autodiff::Jacobians { g, x, dg, dx })
    }

    fn weighted_hessian(
        &self,
        q: &[f64],
        rho: &[f64],
        lambda: &[f64],
        _mu: &[f64],
    ) -> nalgebra::DMatrix<f64> {
        // The tool map is linear in q: only the constraints curve.
        let nq = q.len();
        let mut h = nalgebra::DMatrix::zeros(nq, nq + rho.len());
        let v: Vec<f64> = q.iter().chain(rho).copied().collect();
        for leg in &self.legs {
            let w = &lambda[leg.row..leg.row + leg.rows()];
            if w.iter().all(|l| *l == 0.0) {
                continue;
            }
            self.leg_hessians(leg, &v, &leg.vars, &mut |r, a, b, val| {
                h[(a, b)] += w[r] * val;
            });
        }
        h
    }

    fn joint_hessians(&self, q: &[f64], rho: &[f64]) -> Vec<nalgebra::DMatrix<f64>> {
        let nq = q.len();
        let mut out =
            vec![nalgebra::DMatrix::zeros(nq, nq); self.spec.n_constraints + self.tool.len()];
        let v: Vec<f64> = q.iter().chain(rho).copied().collect();
        for leg in &self.legs {
            let joints = &leg.vars[..leg.n_joint_vars];
            self.leg_hessians(leg, &v, joints, &mut |r, a, b, val| {
                out[leg.row + r][(a, b)] = val;
            });
        }
        out
    }

    /// The platform coordinates named in `tool`.
    fn tool<D: Scalar>(&self, q: &[D], _rho: &[D], x: &mut [D]) {
        for (x, &k) in x.iter_mut().zip(&self.tool) {
            *x = q[self.pose0 + k];
        }
    }

    /// Leg by leg when the tool axes fix the platform and every leg has as
    /// many joints as equations (deltas, Gough–Stewart legs); Newton on the
    /// whole mechanism otherwise.
    fn inverse_kinematics_closed(&self, target: &[f64], rho: &[f64]) -> Option<Result<Vec<f64>>> {
        if self.leg_signs.is_empty() || self.tool.len() != self.motion.coordinates() {
            return None;
        }
        Some(self.ik_by_leg(target, rho))
    }

    fn configuration_guess(&self, commands: &[f64], rho: &[f64]) -> Option<Vec<f64>> {
        match &self.trilateration {
            Some(t) => self.trilaterate(t, commands, rho),
            None => self.atlas.nearest(commands),
        }
    }

    /// Fixed rod lengths must be positive.
    fn check_params(&self, rho: &[f64]) -> Result<()> {
        for (leg, name) in self.legs.iter().zip(&self.leg_names) {
            if let Some(Rod::Fixed(i)) = leg.rod
                && rho[i] <= 0.0
            {
                return Err(Error::InvalidParameter {
                    name: self.spec.geometric[i].clone(),
                    value: rho[i],
                    reason: format!("the rod of leg `{name}` must have a positive length"),
                });
            }
        }
        Ok(())
    }

    /// The assembly and working modes of the reference configuration: the
    /// same signs of the forward and inverse kinematics determinants.
    /// The whole mechanism's signs, and each leg's working mode on its own
    /// (a product of signs would let two legs' flips cancel).
    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        self.same_branch(crate::engine::kinematics::branch_signs(self, q, rho))
            && self.leg_in_other_mode(q, rho).is_none()
    }

    fn on_branch_near(
        &self,
        q: &[f64],
        rho: &[f64],
        jac: &crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        self.same_branch(crate::engine::kinematics::branch_signs_of(&self.spec, jac))
            && self.leg_in_other_mode(q, rho).is_none()
    }

    fn leg_in_other_mode(&self, q: &[f64], rho: &[f64]) -> Option<&str> {
        self.leg_signs
            .iter()
            .enumerate()
            .find(|&(i, &s)| s != 0 && self.leg_sign(i, q, rho) != s)
            .map(|(i, _)| self.leg_names[i].as_str())
    }
}

impl SpatialMechanism {
    /// Whether determinant signs `s` are the reference configuration's.
    fn same_branch(&self, s: [i8; 2]) -> bool {
        (self.branch[0] == 0 || s[0] == self.branch[0])
            && (self.branch[1] == 0 || s[1] == self.branch[1])
    }
}
