//! Planar linkages described as bodies connected by revolute and prismatic
//! joints ([`PlanarDescription`], plain data a user writes in TOML), turned into
//! a [`Mechanism`] ([`PlanarLinkage`]) whose loop closure (docs/model.md eq. 3) and
//! parameter names are derived from the description.
//!
//! (A long file: the planar description's builder and its exact derivatives
//! are one job.)
//!
//! Conventions (docs/mechanisms.md explains them with examples):
//!
//! - Every body has a frame. The ground frame is the measurement frame. Joints
//!   are read in order; the first joint that reaches a body *places* it (a tree
//!   joint): the body's frame origin is the joint, and
//!   - revolute: the body's x axis is the parent's x axis turned by `q`;
//!   - prismatic: the body's x axis points along the slide (the parent's x axis
//!     turned by `axis`) and its origin is `q` further along it.
//! - A joint whose child is already placed closes a loop: three equations
//!   (revolute: the joint's point on both bodies coincides, and `q` is the
//!   child's angle minus the parent's; prismatic: the child's point lies at `q`
//!   along the slide and the child's angle is the slide's plus `child_angle`).
//! - Every joint has one coordinate in `q` (rad or mm), in file order, so
//!   `joints − 3 × closing joints` is the number of degrees of freedom.
//! - Every number of the geometry is a parameter. Its name is the one the user
//!   writes (a string in place of a number, its value in `[parameters]`; one
//!   name used twice is one parameter) or derived from the joint:
//!   `<joint>.x`, `<joint>.y` (position on the parent), `<joint>.axis`
//!   (prismatic slide direction), `<joint>.cx`, `<joint>.cy` (closing joint:
//!   position on the child), `<joint>.child_angle`, `tool.x`, `tool.y`.
//! - An actuated joint `J` has the encoder offset `dJ` and the stiffness `kN`
//!   where `N` is `J` without a leading `q` (`q1` → `dq1`, `k1`). Revolute
//!   actuators: N·m/rad; prismatic ones: N/mm (one kind per linkage).

use crate::engine::kinematics::solve_closure;
use crate::error::{Error, Result};
use crate::kinds::build::{Built, Joints, Parts, assemble, assembly_value, finish, stiffness_of};
use crate::kinds::description::{Names, Value, bad};
use crate::mechanism::tool::ToolLayout;
use crate::mechanism::{Mechanism, Scalar, Spec};
use crate::units::Unit;
use serde::Deserialize;
use std::collections::BTreeMap;

/// Revolute or prismatic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JointKind {
    /// Rotation about the joint point (coordinate in rad).
    Revolute,
    /// Translation along a slide (coordinate in mm).
    Prismatic,
}

/// One joint between two bodies.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanarJoint {
    /// Joint name (the coordinate's name in `q`, and the command column when
    /// actuated).
    pub name: String,
    /// Revolute or prismatic.
    pub kind: JointKind,
    /// The body it is mounted on (`ground` is the fixed frame).
    pub parent: String,
    /// The body it moves.
    pub child: String,
    /// Position of the joint on the parent, in the parent's frame (mm).
    pub at: [Value; 2],
    /// Prismatic: direction of the slide in the parent's frame (rad); 0 if left
    /// out.
    #[serde(default)]
    pub axis: Option<Value>,
    /// Closing joint: position of the joint on the child, in the child's
    /// frame (mm). Required when the child is already placed.
    #[serde(default)]
    pub child_at: Option<[Value; 2]>,
    /// Closing prismatic joint: the child's angle minus the slide's (rad); 0
    /// if left out.
    #[serde(default)]
    pub child_angle: Option<Value>,
    /// Whether a motor drives it.
    #[serde(default)]
    pub actuated: bool,
    /// Stiffness of the actuated joint (N·m/rad or N/mm).
    #[serde(default)]
    pub stiffness: Option<f64>,
}

/// The tool point.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanarTool {
    /// The body that carries it.
    pub body: String,
    /// Its position in that body's frame (mm).
    pub at: [Value; 2],
    /// Whether the body's orientation (`phi`, rad, from the ground x axis) is
    /// a tool coordinate too (3-DOF linkages).
    #[serde(default)]
    pub orientation: bool,
}

/// A planar linkage as a user describes it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlanarDescription {
    /// Human-readable name.
    #[serde(default)]
    pub name: Option<String>,
    /// The joints, from the ground outward (each tree joint's parent placed
    /// before it).
    #[serde(rename = "joint")]
    pub joints: Vec<PlanarJoint>,
    /// The tool point.
    pub tool: PlanarTool,
    /// Values of the named parameters.
    #[serde(default)]
    pub parameters: BTreeMap<String, f64>,
    /// Approximate values of every tree joint on the wanted assembly branch
    /// (rad, mm); they are polished so that the loops close. Closing joints
    /// are computed.
    pub assembly: BTreeMap<String, f64>,
    /// Box `[min, max]` per tool axis (`x`, `y`, and `phi` with orientation).
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
    /// Parameters renamed: old name → current name. Files and calibration
    /// records that use an old name keep working (with a note).
    #[serde(default)]
    pub renamed: BTreeMap<String, String>,
}

#[derive(Debug, Clone, PartialEq)]
struct Closing {
    child_at: [usize; 2],
    child_angle: Option<usize>,
}

#[derive(Debug, Clone, PartialEq)]
struct Joint {
    kind: JointKind,
    parent: usize,
    child: usize,
    at: [usize; 2],
    axis: Option<usize>,
    closing: Option<Closing>,
}

/// A planar linkage built from a [`PlanarDescription`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlanarLinkage {
    spec: Spec,
    joints: Vec<Joint>,
    /// Characteristic length (mm): the mean distance between joints on a body.
    /// It scales the angle equations of closing joints to mm.
    length: f64,
    n_bodies: usize,
    tool_body: usize,
    tool_at: [usize; 2],
    orientation: bool,
    atlas: crate::engine::atlas::Atlas,
    /// [`crate::engine::kinematics::branch_signs`] at the reference configuration.
    branch: [i8; 2],
}

/// The bodies and joints of a planar description, indexed: each joint
/// placing a body or closing a loop, and the tool's body and point.
struct Tree {
    bodies: Vec<String>,
    joints: Vec<Joint>,
    tool_body: usize,
    tool_at: [usize; 2],
}

/// Index the joints in file order, each checked as it comes: a unique
/// name, a parent already placed, its parameters named (`names`), and
/// whether it places its child body or closes a loop; then the tool.
fn index_tree(d: &PlanarDescription, names: &mut Names) -> Result<Tree> {
    if d.joints.is_empty() {
        return bad("a planar linkage needs at least one [[joint]]".into());
    }
    crate::mechanism::check_size(0, d.joints.len())?;
    let mut bodies: Vec<String> = vec!["ground".into()];
    let mut joints = Vec::with_capacity(d.joints.len());
    for (i, j) in d.joints.iter().enumerate() {
        if j.name.is_empty() || d.joints[..i].iter().any(|o| o.name == j.name) {
            return bad(format!(
                "joint {} has an empty or repeated name `{}`",
                i + 1,
                j.name
            ));
        }
        joints.push(index_joint(j, &mut bodies, names)?);
    }
    let tool_body = bodies
        .iter()
        .position(|b| *b == d.tool.body)
        .ok_or_else(|| {
            Error::InvalidMechanism(format!(
                "the tool's body `{}` is not moved by any joint (bodies: {})",
                d.tool.body,
                bodies.join(", ")
            ))
        })?;
    let tool_at = [
        names.add(&d.tool.at[0], "tool.x".into(), Unit::Millimetre)?,
        names.add(&d.tool.at[1], "tool.y".into(), Unit::Millimetre)?,
    ];
    Ok(Tree {
        bodies,
        joints,
        tool_body,
        tool_at,
    })
}

/// One joint: its parent among the `bodies` placed so far, its parameters,
/// and its child placed by it (added to `bodies`) or already placed (the
/// joint closes a loop and needs its position on the child).
fn index_joint(j: &PlanarJoint, bodies: &mut Vec<String>, names: &mut Names) -> Result<Joint> {
    let parent = bodies.iter().position(|b| *b == j.parent).ok_or_else(|| {
        Error::InvalidMechanism(format!(
            "joint `{}`: its parent body `{}` is not placed yet; list the joints from the ground outward",
            j.name, j.parent
        ))
    })?;
    if j.child == j.parent {
        return bad(format!(
            "joint `{}` connects `{}` to itself",
            j.name, j.child
        ));
    }
    let at = [
        names.add(&j.at[0], format!("{}.x", j.name), Unit::Millimetre)?,
        names.add(&j.at[1], format!("{}.y", j.name), Unit::Millimetre)?,
    ];
    let axis = match j.kind {
        JointKind::Prismatic => Some(names.add(
            j.axis.as_ref().unwrap_or(&Value::Number(0.0)),
            format!("{}.axis", j.name),
            Unit::Radian,
        )?),
        JointKind::Revolute => {
            if j.axis.is_some() {
                return bad(format!(
                    "joint `{}`: `axis` is for prismatic joints",
                    j.name
                ));
            }
            None
        }
    };
    let closing = match bodies.iter().position(|b| *b == j.child) {
        None => {
            if j.child_at.is_some() || j.child_angle.is_some() {
                return bad(format!(
                    "joint `{}` places body `{}` (its frame starts at the joint); `child_at` and `child_angle` are for joints that close a loop",
                    j.name, j.child
                ));
            }
            bodies.push(j.child.clone());
            None
        }
        Some(_) => {
            let ca = j.child_at.as_ref().ok_or_else(|| {
                Error::InvalidMechanism(format!(
                    "joint `{}` closes a loop (body `{}` is already placed): give its position on `{}` as `child_at = [x, y]`",
                    j.name, j.child, j.child
                ))
            })?;
            let child_at = [
                names.add(&ca[0], format!("{}.cx", j.name), Unit::Millimetre)?,
                names.add(&ca[1], format!("{}.cy", j.name), Unit::Millimetre)?,
            ];
            let child_angle = match j.kind {
                JointKind::Prismatic => Some(names.add(
                    j.child_angle.as_ref().unwrap_or(&Value::Number(0.0)),
                    format!("{}.child_angle", j.name),
                    Unit::Radian,
                )?),
                JointKind::Revolute => None,
            };
            Some(Closing {
                child_at,
                child_angle,
            })
        }
    };
    let child = bodies.iter().position(|b| *b == j.child).expect("placed");
    Ok(Joint {
        kind: j.kind,
        parent,
        child,
        at,
        axis,
        closing,
    })
}

/// The joints of `q` (every joint, in file order) and the actuators: at
/// least as many as the `dof` degrees of freedom, of one kind, each with a
/// positive stiffness; and their work scale.
fn planar_joints(d: &PlanarDescription, dof: usize) -> Result<(Joints, f64)> {
    let mut joints = Joints::default();
    for j in &d.joints {
        joints.push(&j.name, joint_unit(j.kind));
    }
    joints.actuated = (0..d.joints.len())
        .filter(|&i| d.joints[i].actuated)
        .collect();
    if joints.actuated.len() < dof {
        return bad(format!(
            "the linkage has {dof} degrees of freedom but only {} actuated joints",
            joints.actuated.len()
        ));
    }
    joints.revolute = joints
        .actuated
        .iter()
        .map(|&i| d.joints[i].kind == JointKind::Revolute)
        .collect();
    let work_scale = joints.work_scale()?;
    for j in &d.joints {
        let revolute = j.kind == JointKind::Revolute;
        if let Some(k) = stiffness_of("", &j.name, revolute, j.actuated, j.stiffness)? {
            joints.stiffness.push(k);
        }
    }
    Ok((joints, work_scale))
}

/// The unit of a joint's coordinate.
fn joint_unit(kind: JointKind) -> Unit {
    match kind {
        JointKind::Revolute => Unit::Radian,
        JointKind::Prismatic => Unit::Millimetre,
    }
}

/// The tool axes (`x y`, with `phi` when the tool's orientation counts):
/// one per degree of freedom.
fn planar_tool_axes(d: &PlanarDescription, dof: usize) -> Result<Vec<String>> {
    let tool_axes: Vec<String> = if d.tool.orientation {
        vec!["x".into(), "y".into(), "phi".into()]
    } else {
        vec!["x".into(), "y".into()]
    };
    if tool_axes.len() != dof {
        return bad(format!(
            "the linkage has {dof} degrees of freedom but {} tool coordinates ({}); {}",
            tool_axes.len(),
            tool_axes.join(", "),
            if dof == 3 {
                "set `orientation = true` in [tool]"
            } else {
                "planar linkages need 2 DOF (tool x, y) or 3 DOF (x, y, phi)"
            }
        ));
    }
    Ok(tool_axes)
}

/// The characteristic length (mm): the mean distance between joints on a
/// body (1 when there is none).
fn characteristic_length(joints: &[Joint], values: &[f64]) -> f64 {
    let lengths: Vec<f64> = joints
        .iter()
        .flat_map(|j| {
            let mut v = vec![values[j.at[0]].hypot(values[j.at[1]])];
            if let Some(c) = &j.closing {
                v.push(values[c.child_at[0]].hypot(values[c.child_at[1]]));
            }
            v
        })
        .filter(|l| *l > 1e-9)
        .collect();
    if lengths.is_empty() {
        1.0
    } else {
        lengths.iter().sum::<f64>() / lengths.len() as f64
    }
}

impl PlanarLinkage {
    /// Build the linkage from its description, in steps: index the bodies
    /// and joints (each checked as it comes), count the degrees of freedom
    /// and check the actuators and the tool against them, assemble the
    /// [`Spec`] by the rule of every described kind
    /// ([`crate::kinds::build::assemble`]), close the reference
    /// configuration, and finish ([`crate::kinds::build::finish`]).
    pub fn new(d: &PlanarDescription) -> Result<Self> {
        let mut names = Names::new(&d.parameters);
        let tree = index_tree(d, &mut names)?;
        names.check_used("any joint or the tool")?;
        let nq = tree.joints.len();
        let n_closing = tree.joints.iter().filter(|j| j.closing.is_some()).count();
        let nc = 3 * n_closing;
        if nc >= nq {
            return bad(format!(
                "{nq} joints and {n_closing} closing joints leave no degree of freedom"
            ));
        }
        let dof = nq - nc;
        let (joints, work_scale) = planar_joints(d, dof)?;
        let tool_axes = planar_tool_axes(d, dof)?;
        let length = characteristic_length(&tree.joints, &names.values);
        let spec = assemble(Parts {
            name: d.name.clone().unwrap_or_else(|| "planar linkage".into()),
            parameters: names,
            joints,
            n_constraints: nc,
            tool_units: tool_axes
                .iter()
                .map(|a| {
                    if a == "phi" {
                        Unit::Radian
                    } else {
                        Unit::Millimetre
                    }
                })
                .collect(),
            tool_axes,
            tool_layout: if d.tool.orientation {
                ToolLayout::PlanarPose
            } else {
                ToolLayout::PlanarPoint
            },
            workspace: &d.workspace,
            free: &d.free,
            work_scale,
            joint_scale: d
                .joints
                .iter()
                .map(|j| match j.kind {
                    JointKind::Revolute => length,
                    JointKind::Prismatic => 1.0,
                })
                .collect(),
            axis_scale: if d.tool.orientation {
                vec![1.0, 1.0, length]
            } else {
                vec![]
            },
            renamed: &d.renamed,
        })?;
        let mut linkage = PlanarLinkage {
            spec,
            joints: tree.joints,
            length,
            n_bodies: tree.bodies.len(),
            tool_body: tree.tool_body,
            tool_at: tree.tool_at,
            orientation: d.tool.orientation,
            atlas: Default::default(),
            branch: [0, 0],
        };
        linkage.close_reference(d)?;
        finish(linkage, None)
    }

    /// The reference configuration: the tree joints from the description's
    /// `[assembly]`, the closing joints computed from the body poses, the
    /// independent joints chosen there (or named), then Newton on the loop
    /// closure with the independent joints held.
    fn close_reference(&mut self, d: &PlanarDescription) -> Result<()> {
        let joint_names = &self.spec.joints;
        for k in d.assembly.keys() {
            match joint_names.iter().position(|n| n == k) {
                None => {
                    return bad(format!(
                        "[assembly]: unknown joint `{k}` (joints: {})",
                        joint_names.join(", ")
                    ));
                }
                Some(i) if self.joints[i].closing.is_some() => {
                    return bad(format!(
                        "[assembly]: `{k}` closes a loop; its value is computed, leave it out"
                    ));
                }
                _ => {}
            }
        }
        let mut q0 = vec![0.0; joint_names.len()];
        for (i, j) in self.joints.iter().enumerate() {
            if j.closing.is_none() {
                q0[i] = assembly_value(&d.assembly, &joint_names[i], "rad or mm")?;
            }
        }
        let rho = self.spec.nominal[..self.spec.geometric.len()].to_vec();
        self.fill_closing(&mut q0, &rho);
        self.spec.independent = crate::engine::kinematics::independent_joints(
            self,
            d.independent.as_deref(),
            &q0,
            &rho,
        )?;
        self.spec.reference_q = q0.clone();
        self.spec.validate()?;
        solve_closure(self, &rho, &mut q0, &self.spec.independent).map_err(|e| {
            Error::InvalidMechanism(format!(
                "the [assembly] configuration does not close ({e}); check the lengths and give joint values nearer the wanted assembly"
            ))
        })?;
        self.spec.reference_q = q0;
        Ok(())
    }

    /// Names of the bodies (ground first).
    pub fn n_bodies(&self) -> usize {
        self.n_bodies
    }

    /// Body poses `[x, y, θ]` from the tree joints.
    fn poses<D: Scalar>(&self, q: &[D], rho: &[D]) -> Vec<[D; 3]> {
        let zero = D::from(0.0);
        let mut p = vec![[zero; 3]; self.n_bodies];
        for (i, j) in self.joints.iter().enumerate() {
            if j.closing.is_some() {
                continue;
            }
            let [px, py, th] = p[j.parent];
            let (s, c) = th.sin_cos();
            let (a0, a1) = (rho[j.at[0]], rho[j.at[1]]);
            let ax = px + c * a0 - s * a1;
            let ay = py + s * a0 + c * a1;
            p[j.child] = match j.kind {
                JointKind::Revolute => [ax, ay, th + q[i]],
                JointKind::Prismatic => {
                    let ang = th + rho[j.axis.expect("prismatic")];
                    let (s, c) = ang.sin_cos();
                    [ax + c * q[i], ay + s * q[i], ang]
                }
            };
        }
        p
    }

    /// Set the closing joints' coordinates from the body poses of the tree
    /// joints.
    fn fill_closing(&self, q: &mut [f64], rho: &[f64]) {
        let p = self.poses(q, rho);
        for (i, j) in self.joints.iter().enumerate() {
            if j.closing.is_none() {
                continue;
            }
            let a = world(&p[j.parent], rho[j.at[0]], rho[j.at[1]]);
            q[i] = match j.kind {
                JointKind::Revolute => p[j.child][2] - p[j.parent][2],
                JointKind::Prismatic => {
                    let c = j.closing.as_ref().expect("closing");
                    let b = world(&p[j.child], rho[c.child_at[0]], rho[c.child_at[1]]);
                    let ang = p[j.parent][2] + rho[j.axis.expect("prismatic")];
                    (b[0] - a[0]) * ang.cos() + (b[1] - a[1]) * ang.sin()
                }
            };
        }
    }
}

/// The closing joints' equations and the tool map with their derivatives in
/// the first `nd` variables of `[q; ρ]`, and the body poses they are built
/// from, in flat buffers that one evaluation after another reuses: row `r`
/// of a derivative block is `[r·nd, (r + 1)·nd)`.
struct ClosedForm<D> {
    nd: usize,
    /// Body poses `[x, y, θ]`.
    p: Vec<[D; 3]>,
    /// Their derivatives: body `b`'s component `c` is row `3b + c`.
    dp: Vec<D>,
    /// Three rows of scratch.
    scratch: Vec<D>,
    g: Vec<D>,
    x: Vec<D>,
    /// `∂g/∂v`, one row per constraint.
    dg: Vec<D>,
    /// `∂x/∂v`, one row per tool coordinate.
    dx: Vec<D>,
}

impl<D> ClosedForm<D> {
    const fn new() -> Self {
        Self {
            nd: 0,
            p: Vec::new(),
            dp: Vec::new(),
            scratch: Vec::new(),
            g: Vec::new(),
            x: Vec::new(),
            dg: Vec::new(),
            dx: Vec::new(),
        }
    }
}

thread_local! {
    /// The first derivatives' buffers, one set per thread (the mechanism is
    /// shared and immutable).
    static FIRST: std::cell::RefCell<ClosedForm<f64>> =
        const { std::cell::RefCell::new(ClosedForm::new()) };
}

/// `v` resized to `n` entries, the kept ones left as they are (each caller
/// writes every entry before reading it).
fn sized<D: Scalar>(v: &mut Vec<D>, n: usize) {
    v.resize(n, D::from(0.0));
}

/// The point of a body's frame at the parameters `at` (`ρ[at[0]]`,
/// `ρ[at[1]]`, variables `nq + at[k]` of `[q; ρ]`) in the ground frame; its
/// derivatives go to `ox`, `oy` from the body's pose `p` and pose
/// derivatives `d` (three rows of `ox.len()`).
fn world_derivative<D: Scalar>(
    (p, d): (&[D; 3], &[D]),
    rho: &[D],
    nq: usize,
    at: [usize; 2],
    ox: &mut [D],
    oy: &mut [D],
) -> [D; 2] {
    let (x, y, ix, iy) = (rho[at[0]], rho[at[1]], nq + at[0], nq + at[1]);
    let nd = ox.len();
    let (s, c) = p[2].sin_cos();
    let pt = [p[0] + c * x - s * y, p[1] + s * x + c * y];
    let (kx, ky) = (-(s * x) - c * y, c * x - s * y);
    let (d0, rest) = d.split_at(nd);
    let (d1, d2) = rest.split_at(nd);
    for v in 0..nd {
        ox[v] = d0[v] + kx * d2[v];
        oy[v] = d1[v] + ky * d2[v];
    }
    if ix < nd {
        ox[ix] += c;
        oy[ix] += s;
    }
    if iy < nd {
        ox[iy] -= s;
        oy[iy] += c;
    }
    pt
}

/// Three consecutive rows of `nd` of `v`, from row `r`.
fn rows3<D>(v: &mut [D], r: usize, nd: usize) -> (&mut [D], &mut [D], &mut [D]) {
    let (a, rest) = v[r * nd..(r + 3) * nd].split_at_mut(nd);
    let (b, c) = rest.split_at_mut(nd);
    (a, b, c)
}

impl PlanarLinkage {
    /// Fill `f` with the closed form in the first `nd` variables of
    /// `[q; ρ]`, in any scalar: plain numbers for the first derivatives,
    /// dual numbers over it for the second
    /// ([`PlanarLinkage::second_derivatives`]). The body poses and their
    /// derivatives are propagated along the tree joints (the chain rule of
    /// [`PlanarLinkage::poses`]), then the closing joints' equations and the
    /// tool map are differentiated from them.
    fn closed_form_into<D: Scalar>(&self, q: &[D], rho: &[D], nd: usize, f: &mut ClosedForm<D>) {
        let nq = q.len();
        let zero = D::from(0.0);
        let one = D::from(1.0);
        let body = |b: usize| 3 * b * nd..3 * (b + 1) * nd;
        f.nd = nd;
        f.p.clear();
        f.p.resize(self.n_bodies, [zero; 3]);
        // Every row below is written before it is read (each body but the
        // ground is placed by one tree joint, after its parent), but the
        // ground's, which are zero: sized, not cleared.
        sized(&mut f.dp, 3 * self.n_bodies * nd);
        f.dp[body(0)].fill(zero);
        sized(&mut f.scratch, 3 * nd);
        for (i, j) in self.joints.iter().enumerate() {
            if j.closing.is_some() {
                continue;
            }
            let pp = f.p[j.parent];
            let dpp = &f.dp[body(j.parent)];
            let (s0, s1, s2) = rows3(&mut f.scratch, 0, nd);
            let a = world_derivative((&pp, dpp), rho, nq, j.at, s0, s1);
            s2.copy_from_slice(&dpp[2 * nd..]);
            f.p[j.child] = match j.kind {
                JointKind::Revolute => {
                    if i < nd {
                        s2[i] += one;
                    }
                    [a[0], a[1], pp[2] + q[i]]
                }
                JointKind::Prismatic => {
                    let axis = j.axis.expect("prismatic");
                    let ang = pp[2] + rho[axis];
                    if nq + axis < nd {
                        s2[nq + axis] += one;
                    }
                    let (sa, ca) = ang.sin_cos();
                    let (ks, kc) = (sa * q[i], ca * q[i]);
                    for v in 0..nd {
                        s0[v] -= ks * s2[v];
                        s1[v] += kc * s2[v];
                    }
                    if i < nd {
                        s0[i] += ca;
                        s1[i] += sa;
                    }
                    [a[0] + ca * q[i], a[1] + sa * q[i], ang]
                }
            };
            f.dp[body(j.child)].copy_from_slice(&f.scratch);
        }
        let m = self.spec.n_constraints;
        let length = D::from(self.length);
        sized(&mut f.g, m);
        sized(&mut f.dg, m * nd);
        let mut k = 0;
        for (i, j) in self.joints.iter().enumerate() {
            let Some(c) = &j.closing else { continue };
            let (pp, pc) = (f.p[j.parent], f.p[j.child]);
            let (dpp, dpc) = (&f.dp[body(j.parent)], &f.dp[body(j.child)]);
            let (r0, r1, r2) = rows3(&mut f.dg, k, nd);
            let a = world_derivative((&pp, dpp), rho, nq, j.at, r0, r1);
            let (s0, s1, s2) = rows3(&mut f.scratch, 0, nd);
            let b = world_derivative((&pc, dpc), rho, nq, c.child_at, s0, s1);
            for v in 0..nd {
                r0[v] -= s0[v];
                r1[v] -= s1[v];
            }
            match j.kind {
                JointKind::Revolute => {
                    f.g[k] = a[0] - b[0];
                    f.g[k + 1] = a[1] - b[1];
                    f.g[k + 2] = (pc[2] - pp[2] - q[i]) * length;
                    for v in 0..nd {
                        r2[v] = dpc[2 * nd + v] - dpp[2 * nd + v];
                    }
                    if i < nd {
                        r2[i] -= one;
                    }
                }
                JointKind::Prismatic => {
                    let axis = j.axis.expect("prismatic");
                    let ca_idx = c.child_angle.expect("prismatic");
                    let ang = pp[2] + rho[axis];
                    s2.copy_from_slice(&dpp[2 * nd..]);
                    if nq + axis < nd {
                        s2[nq + axis] += one;
                    }
                    let (sn, cs) = ang.sin_cos();
                    f.g[k] = a[0] + cs * q[i] - b[0];
                    f.g[k + 1] = a[1] + sn * q[i] - b[1];
                    f.g[k + 2] = (pc[2] - ang - rho[ca_idx]) * length;
                    let (ks, kc) = (sn * q[i], cs * q[i]);
                    for v in 0..nd {
                        r0[v] -= ks * s2[v];
                        r1[v] += kc * s2[v];
                    }
                    if i < nd {
                        r0[i] += cs;
                        r1[i] += sn;
                    }
                    for v in 0..nd {
                        r2[v] = dpc[2 * nd + v] - s2[v];
                    }
                    if nq + ca_idx < nd {
                        r2[nq + ca_idx] -= one;
                    }
                }
            }
            r2.iter_mut().for_each(|v| *v *= length);
            k += 3;
        }
        let nx = 2 + usize::from(self.orientation);
        sized(&mut f.x, nx);
        sized(&mut f.dx, 3 * nd);
        let tb = f.p[self.tool_body];
        let dtb = &f.dp[body(self.tool_body)];
        let (r0, r1, r2) = rows3(&mut f.dx, 0, nd);
        let t = world_derivative((&tb, dtb), rho, nq, self.tool_at, r0, r1);
        f.x[0] = t[0];
        f.x[1] = t[1];
        if self.orientation {
            f.x[2] = tb[2];
            r2.copy_from_slice(&dtb[2 * nd..]);
        }
        f.dx.truncate(nx * nd);
    }

    /// The first derivatives in `cols` into `out` (the per-thread buffers
    /// of [`FIRST`], no allocation once they have grown).
    fn closed_form_jacobians_into(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
        out: &mut crate::mechanism::autodiff::Jacobians,
    ) {
        FIRST.with_borrow_mut(|f| {
            self.closed_form_into(q, rho, cols.end, f);
            let (m, nx, nd) = (f.g.len(), f.x.len(), f.nd);
            out.resize(m, nx, cols.len());
            out.g.copy_from_slice(&f.g);
            out.x.copy_from_slice(&f.x);
            for (k, c) in cols.enumerate() {
                for r in 0..m {
                    out.dg[(r, k)] = f.dg[r * nd + c];
                }
                for r in 0..nx {
                    out.dx[(r, k)] = f.dx[r * nd + c];
                }
            }
        })
    }

    /// The gradient of `φ = Σ_o w_o y_o` (outputs `y`: the constraints, then
    /// the tool coordinates) in `[q; ρ]` into `grad`, by reverse mode over
    /// [`PlanarLinkage::poses`]: the outputs' weights flow back through the
    /// closing joints and the tool to the body poses, then along the tree
    /// joints in reverse order. In any scalar: dual numbers seeded on the
    /// joints make it the weighted Hessian's rows
    /// ([`Mechanism::weighted_hessian`]).
    fn weighted_gradient<D: Scalar>(&self, q: &[D], rho: &[D], w: &[D], grad: &mut [D]) {
        let nq = q.len();
        let zero = D::from(0.0);
        let p = self.poses(q, rho);
        let mut bar = vec![[zero; 3]; self.n_bodies];
        grad.iter_mut().for_each(|g| *g = zero);
        let (gq, gr) = grad.split_at_mut(nq);
        let length = D::from(self.length);
        let mut k = 0;
        for (i, j) in self.joints.iter().enumerate() {
            let Some(c) = &j.closing else { continue };
            let (wa, wb, wt) = (w[k], w[k + 1], w[k + 2] * length);
            let (pp, pc) = (p[j.parent], p[j.child]);
            let (pa, ra) = world_adjoint(&pp, rho[j.at[0]], rho[j.at[1]], [wa, wb]);
            add3(&mut bar[j.parent], pa);
            gr[j.at[0]] += ra[0];
            gr[j.at[1]] += ra[1];
            let (pb, rb) = world_adjoint(&pc, rho[c.child_at[0]], rho[c.child_at[1]], [-wa, -wb]);
            add3(&mut bar[j.child], pb);
            gr[c.child_at[0]] += rb[0];
            gr[c.child_at[1]] += rb[1];
            bar[j.child][2] += wt;
            match j.kind {
                JointKind::Revolute => {
                    bar[j.parent][2] -= wt;
                    gq[i] -= wt;
                }
                JointKind::Prismatic => {
                    let axis = j.axis.expect("prismatic");
                    let (sn, cs) = (pp[2] + rho[axis]).sin_cos();
                    gq[i] += wa * cs + wb * sn;
                    let ang = wb * (cs * q[i]) - wa * (sn * q[i]) - wt;
                    bar[j.parent][2] += ang;
                    gr[axis] += ang;
                    gr[c.child_angle.expect("prismatic")] -= wt;
                }
            }
            k += 3;
        }
        let m = self.spec.n_constraints;
        let tb = self.tool_body;
        let (pt, rt) = world_adjoint(
            &p[tb],
            rho[self.tool_at[0]],
            rho[self.tool_at[1]],
            [w[m], w[m + 1]],
        );
        add3(&mut bar[tb], pt);
        gr[self.tool_at[0]] += rt[0];
        gr[self.tool_at[1]] += rt[1];
        if self.orientation {
            bar[tb][2] += w[m + 2];
        }
        for (i, j) in self.joints.iter().enumerate().rev() {
            if j.closing.is_some() {
                continue;
            }
            let cb = bar[j.child];
            let pp = p[j.parent];
            let th = match j.kind {
                JointKind::Revolute => {
                    gq[i] += cb[2];
                    cb[2]
                }
                JointKind::Prismatic => {
                    let axis = j.axis.expect("prismatic");
                    let (sa, ca) = (pp[2] + rho[axis]).sin_cos();
                    gq[i] += cb[0] * ca + cb[1] * sa;
                    let ang = cb[2] + cb[1] * (ca * q[i]) - cb[0] * (sa * q[i]);
                    gr[axis] += ang;
                    ang
                }
            };
            let (pa, ra) = world_adjoint(&pp, rho[j.at[0]], rho[j.at[1]], [cb[0], cb[1]]);
            add3(&mut bar[j.parent], [pa[0], pa[1], pa[2] + th]);
            gr[j.at[0]] += ra[0];
            gr[j.at[1]] += ra[1];
        }
    }

    /// Second derivatives by forward-mode differentiation of the closed-form
    /// first derivatives in the joints: `∂/∂v_c (∂y_o/∂q_i)` for every output
    /// `o` (constraints, then tool), joint `i` and column `c` of `cols`,
    /// passed to `sink(o, i, c − cols.start, value)`.
    fn second_derivatives(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
        mut sink: impl FnMut(usize, usize, usize, f64),
    ) {
        use nalgebra::{Const, U1};
        use num_dual::DualSVec64;
        const C: usize = 8;
        let nq = q.len();
        let v0: Vec<f64> = q.iter().chain(rho).copied().collect();
        let mut v: Vec<DualSVec64<C>> = v0.iter().map(|&a| DualSVec64::from_re(a)).collect();
        let mut f = ClosedForm::new();
        let mut start = cols.start;
        while start < cols.end {
            let end = (start + C).min(cols.end);
            for (k, i) in (start..end).enumerate() {
                v[i] = DualSVec64::from_re(v0[i]).derivative(k);
            }
            self.closed_form_into(&v[..nq], &v[nq..], nq, &mut f);
            for (o, row) in f.dg.chunks(nq).chain(f.dx.chunks(nq)).enumerate() {
                for (i, d) in row.iter().enumerate() {
                    let e = d.eps.unwrap_generic(Const::<C>, U1);
                    for k in 0..end - start {
                        sink(o, i, start - cols.start + k, e[k]);
                    }
                }
            }
            for i in start..end {
                v[i] = DualSVec64::from_re(v0[i]);
            }
            start = end;
        }
    }
}

/// The adjoint of [`world`]: for the weights `u` of the point's two
/// coordinates, those of the body's pose and of the point's coordinates in
/// the body frame.
fn world_adjoint<D: Scalar>(pose: &[D; 3], x: D, y: D, u: [D; 2]) -> ([D; 3], [D; 2]) {
    let (s, c) = pose[2].sin_cos();
    let th = u[0] * (-(s * x) - c * y) + u[1] * (c * x - s * y);
    ([u[0], u[1], th], [u[0] * c + u[1] * s, u[1] * c - u[0] * s])
}

/// `a += b`, component by component.
fn add3<D: Scalar>(a: &mut [D; 3], b: [D; 3]) {
    for (x, y) in a.iter_mut().zip(b) {
        *x += y;
    }
}

/// A point given in a body's frame, in the ground frame.
fn world<D: Scalar>(pose: &[D; 3], x: D, y: D) -> [D; 2] {
    let (s, c) = pose[2].sin_cos();
    [pose[0] + c * x - s * y, pose[1] + s * x + c * y]
}

impl Built for PlanarLinkage {
    const ATLAS_POINTS: usize = 400;
    fn spec_mut(&mut self) -> &mut Spec {
        &mut self.spec
    }
    fn keep_reference(&mut self, signs: [i8; 2]) {
        self.branch = signs;
    }
    fn atlas_mut(&mut self) -> Option<&mut crate::engine::atlas::Atlas> {
        Some(&mut self.atlas)
    }
}

impl Mechanism for PlanarLinkage {
    fn spec(&self) -> &Spec {
        &self.spec
    }

    /// Three equations per closing joint (see the module documentation); the
    /// angle equation is multiplied by a characteristic length so that every
    /// equation is in mm.
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]) {
        let p = self.poses(q, rho);
        let mut k = 0;
        for (i, j) in self.joints.iter().enumerate() {
            let Some(c) = &j.closing else { continue };
            let a = world(&p[j.parent], rho[j.at[0]], rho[j.at[1]]);
            let b = world(&p[j.child], rho[c.child_at[0]], rho[c.child_at[1]]);
            match j.kind {
                JointKind::Revolute => {
                    g[k] = a[0] - b[0];
                    g[k + 1] = a[1] - b[1];
                    g[k + 2] = (p[j.child][2] - p[j.parent][2] - q[i]) * self.length;
                }
                JointKind::Prismatic => {
                    let ang = p[j.parent][2] + rho[j.axis.expect("prismatic")];
                    let (s, cs) = ang.sin_cos();
                    g[k] = a[0] + cs * q[i] - b[0];
                    g[k + 1] = a[1] + s * q[i] - b[1];
                    g[k + 2] = (p[j.child][2] - ang - rho[c.child_angle.expect("prismatic")])
                        * self.length;
                }
            }
            k += 3;
        }
    }

    /// Closed form: the body poses and their derivatives in every variable
    /// of `[q; ρ]` are propagated along the tree joints (the chain rule of
    /// [`PlanarLinkage::poses`], in plain numbers), then the closing joints'
    /// equations and the tool map are differentiated from them.
    fn first_derivatives(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        let mut out = crate::mechanism::autodiff::Jacobians::empty();
        self.closed_form_jacobians_into(q, rho, cols, &mut out);
        Some(out)
    }

    /// [`Mechanism::first_derivatives`] into `out`'s buffers.
    fn first_derivatives_into(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
        out: &mut crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        self.closed_form_jacobians_into(q, rho, cols, out);
        true
    }

    /// Forward-over-reverse: dual numbers seeded on the joints, eight at a
    /// time, through the reverse-mode gradient of `φ = λᵀg + μᵀx`
    /// ([`PlanarLinkage::weighted_gradient`]); each pass gives eight rows.
    /// The cost is a few passes over the bodies, whatever the number of
    /// parameters.
    fn weighted_hessian(
        &self,
        q: &[f64],
        rho: &[f64],
        lambda: &[f64],
        mu: &[f64],
    ) -> nalgebra::DMatrix<f64> {
        use nalgebra::{Const, U1};
        use num_dual::DualSVec64;
        const C: usize = 8;
        let nq = q.len();
        let n = nq + rho.len();
        let mut out = nalgebra::DMatrix::zeros(nq, n);
        let mut qd: Vec<DualSVec64<C>> = q.iter().map(|&a| DualSVec64::from_re(a)).collect();
        let rd: Vec<DualSVec64<C>> = rho.iter().map(|&a| DualSVec64::from_re(a)).collect();
        let w: Vec<DualSVec64<C>> = lambda
            .iter()
            .chain(mu)
            .map(|&a| DualSVec64::from_re(a))
            .collect();
        let mut grad = vec![DualSVec64::from_re(0.0); n];
        for start in (0..nq).step_by(C) {
            let end = (start + C).min(nq);
            for (k, i) in (start..end).enumerate() {
                qd[i] = DualSVec64::from_re(q[i]).derivative(k);
            }
            self.weighted_gradient(&qd, &rd, &w, &mut grad);
            for (c, g) in grad.iter().enumerate() {
                let e = g.eps.unwrap_generic(Const::<C>, U1);
                for k in 0..end - start {
                    out[(start + k, c)] = e[k];
                }
            }
            for i in start..end {
                qd[i] = DualSVec64::from_re(q[i]);
            }
        }
        out
    }

    /// The per-output joint Hessians by the same forward-mode route as
    /// [`Mechanism::weighted_hessian`].
    fn joint_hessians(&self, q: &[f64], rho: &[f64]) -> Vec<nalgebra::DMatrix<f64>> {
        let nq = q.len();
        let n_out = self.spec.n_constraints + self.spec.tool_axes.len();
        let mut out = vec![nalgebra::DMatrix::zeros(nq, nq); n_out];
        self.second_derivatives(q, rho, 0..nq, |o, i, c, v| out[o][(i, c)] = v);
        out
    }

    /// The tool point (and with `orientation`, the tool body's angle).
    fn configuration_guess(&self, commands: &[f64], _rho: &[f64]) -> Option<Vec<f64>> {
        self.atlas.nearest(commands)
    }

    /// Same determinant signs as the reference configuration
    /// ([`crate::engine::kinematics::branch_signs`]): no leg has flipped through a
    /// singularity.
    fn on_branch(&self, q: &[f64], rho: &[f64]) -> bool {
        self.branch == [0, 0]
            || crate::engine::kinematics::branch_signs(self, q, rho) == self.branch
    }

    fn on_branch_near(
        &self,
        _q: &[f64],
        _rho: &[f64],
        jac: &crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        self.branch == [0, 0]
            || crate::engine::kinematics::branch_signs_of(&self.spec, jac) == self.branch
    }

    fn tool<D: Scalar>(&self, q: &[D], rho: &[D], x: &mut [D]) {
        let p = self.poses(q, rho);
        let t = world(
            &p[self.tool_body],
            rho[self.tool_at[0]],
            rho[self.tool_at[1]],
        );
        x[0] = t[0];
        x[1] = t[1];
        if self.orientation {
            x[2] = p[self.tool_body][2];
        }
    }
}
