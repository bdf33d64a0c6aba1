//! The steps every described kind's builder shares (planar linkages,
//! Gough–Stewart platforms, spatial mechanisms): each validates its
//! description and indexes its joints and parameters its own way, then
//! [`assemble`] makes the [`Spec`] by one rule (encoder offsets,
//! stiffness names, nominal vector, default free set, workspace box), the
//! kind closes its reference configuration, and [`finish`] checks and
//! completes it (branch, atlas, usable conditioning).

use crate::engine::atlas::{Atlas, RELATIVE_CONDITIONING, conditioning};
use crate::engine::kinematics::branch_signs;
use crate::error::{Error, Result};
use crate::kinds::description::{Names, bad, box_from_description, stiffness_name};
use crate::mechanism::tool::ToolLayout;
use crate::mechanism::{Mechanism, Renamed, Spec};
use crate::units::Unit;
use std::collections::BTreeMap;

/// A described mechanism's joints as its builder indexes them: names and
/// units in the order of `q`, and the actuated ones with their stiffness
/// and kind.
#[derive(Debug, Clone, Default)]
pub(crate) struct Joints {
    pub(crate) names: Vec<String>,
    pub(crate) units: Vec<Unit>,
    /// Indices of the actuated joints, in actuator order.
    pub(crate) actuated: Vec<usize>,
    /// Each actuator's stiffness (N·m/rad or N/mm).
    pub(crate) stiffness: Vec<f64>,
    /// Whether each actuator is revolute.
    pub(crate) revolute: Vec<bool>,
}

impl Joints {
    /// Add a joint; its index in `q`.
    pub(crate) fn push(&mut self, name: &str, unit: Unit) -> usize {
        self.names.push(name.to_string());
        self.units.push(unit);
        self.names.len() - 1
    }

    /// Make joint `q` an actuator of stiffness `k`.
    pub(crate) fn actuate(&mut self, q: usize, k: f64, revolute: bool) {
        self.actuated.push(q);
        self.stiffness.push(k);
        self.revolute.push(revolute);
    }

    /// The work scale of the actuators ([`Spec::work_scale`]): one kind of
    /// actuator per mechanism, since revolute and prismatic stiffness are
    /// in different units. There is at least one actuator.
    pub(crate) fn work_scale(&self) -> Result<f64> {
        if self.revolute.iter().any(|r| *r != self.revolute[0]) {
            return bad(
                "mixing revolute and prismatic actuators is not supported (their stiffness units differ)"
                    .into(),
            );
        }
        Ok(if self.revolute[0] {
            crate::units::MM_TO_M
        } else {
            1.0
        })
    }
}

/// A joint's stiffness as a description gives it: positive when actuated,
/// absent otherwise. `context` starts the message (`leg `a`: `, or empty).
pub(crate) fn stiffness_of(
    context: &str,
    joint: &str,
    revolute: bool,
    actuated: bool,
    stiffness: Option<f64>,
) -> Result<Option<f64>> {
    match (actuated, stiffness) {
        (true, Some(k)) if k.is_finite() && k > 0.0 => Ok(Some(k)),
        (true, _) => bad(format!(
            "{context}actuated joint `{joint}` needs a positive `stiffness` ({})",
            if revolute { "N·m/rad" } else { "N/mm" }
        )),
        (false, Some(_)) => bad(format!(
            "{context}joint `{joint}` has a stiffness but is not actuated; only actuated joints are compliant"
        )),
        (false, None) => Ok(None),
    }
}

/// A joint's approximate value from a description's `[assembly]` (`unit`
/// as the message names it).
pub(crate) fn assembly_value(given: &BTreeMap<String, f64>, name: &str, unit: &str) -> Result<f64> {
    let v = *given.get(name).ok_or_else(|| {
        Error::InvalidMechanism(format!(
            "[assembly] needs an approximate value of joint `{name}` ({unit}) on the wanted assembly branch"
        ))
    })?;
    if !v.is_finite() {
        return bad(format!("[assembly]: `{name}` must be finite"));
    }
    Ok(v)
}

/// What [`assemble`] makes a [`Spec`] of.
pub(crate) struct Parts<'a> {
    /// The mechanism's name.
    pub(crate) name: String,
    /// The geometric parameters, in order of first use.
    pub(crate) parameters: Names<'a>,
    pub(crate) joints: Joints,
    pub(crate) n_constraints: usize,
    pub(crate) tool_axes: Vec<String>,
    pub(crate) tool_units: Vec<Unit>,
    pub(crate) tool_layout: ToolLayout,
    /// The description's `[workspace]`.
    pub(crate) workspace: &'a BTreeMap<String, [f64; 2]>,
    /// The description's `free`.
    pub(crate) free: &'a Option<Vec<String>>,
    pub(crate) work_scale: f64,
    pub(crate) joint_scale: Vec<f64>,
    pub(crate) axis_scale: Vec<f64>,
    /// The description's `[renamed]` table: old name → current name.
    pub(crate) renamed: &'a BTreeMap<String, String>,
}

/// A described mechanism's [`Spec`], by the rule every kind follows: an
/// actuated joint `J` has the encoder offset `dJ` and the stiffness
/// [`stiffness_name`]`(J)`; the nominal vector is the geometry, zero
/// offsets, then the stiffness; the default free set is the description's
/// `free`, or all the geometry and the offsets; the workspace box is the
/// `[workspace]` table's; old names are the `[renamed]` table's. The first
/// actuators are the independent joints and the reference configuration is
/// zero until the kind closes it.
pub(crate) fn assemble(p: Parts) -> Result<Spec> {
    let workspace_box = box_from_description(&p.tool_axes, p.workspace)?;
    let Parts {
        parameters: names,
        joints,
        ..
    } = p;
    let offsets: Vec<String> = joints
        .actuated
        .iter()
        .map(|&i| format!("d{}", joints.names[i]))
        .collect();
    let mut nominal = names.values;
    nominal.extend(std::iter::repeat_n(0.0, joints.actuated.len()));
    nominal.extend(&joints.stiffness);
    let default_free = match p.free {
        Some(f) => f.clone(),
        None => names.names.iter().chain(&offsets).cloned().collect(),
    };
    let nq = joints.names.len();
    let dof = nq - p.n_constraints;
    let stiffness: Vec<String> = joints
        .actuated
        .iter()
        .map(|&i| stiffness_name(&joints.names[i]))
        .collect();
    let renamed = renamings(p.renamed, |n| {
        names
            .names
            .iter()
            .chain(&offsets)
            .chain(&stiffness)
            .any(|c| c == n)
    })?;
    Ok(Spec {
        name: p.name,
        independent: joints.actuated[..dof].to_vec(),
        stiffness,
        actuated: joints.actuated,
        joints: joints.names,
        n_constraints: p.n_constraints,
        geometric: names.names,
        offsets,
        tool_axes: p.tool_axes,
        joint_units: joints.units,
        geometric_units: names.units,
        tool_units: p.tool_units,
        tool_layout: p.tool_layout,
        nominal,
        reference_q: vec![0.0; nq],
        default_free,
        workspace_box,
        work_scale: p.work_scale,
        joint_scale: p.joint_scale,
        axis_scale: p.axis_scale,
        min_conditioning: 0.0,
        renamed,
    })
}

/// A description's `[renamed]` table (old name → current name) as the
/// spec keeps it; `is_parameter` tells the current names.
fn renamings(
    table: &BTreeMap<String, String>,
    is_parameter: impl Fn(&str) -> bool,
) -> Result<Vec<Renamed>> {
    let mut out = Vec::with_capacity(table.len());
    for (old, new) in table {
        if is_parameter(old) {
            return bad(format!(
                "[renamed]: `{old}` is a parameter of the mechanism; an old name must be one it no longer has"
            ));
        }
        if !is_parameter(new) {
            return bad(format!(
                "[renamed]: `{old} = \"{new}\"`: `{new}` is not a parameter of the mechanism; give the name it has now"
            ));
        }
        out.push(Renamed::new(old, new));
    }
    Ok(out)
}

/// A kind built from its description, as [`finish`] completes it.
pub(crate) trait Built: Mechanism + Sized {
    /// Workspace configurations its atlas keeps for starting forward
    /// kinematics.
    const ATLAS_POINTS: usize;
    /// Its description, to complete.
    fn spec_mut(&mut self) -> &mut Spec;
    /// Keep what it takes from its closed reference configuration: the
    /// determinant signs of its branch
    /// ([`crate::engine::kinematics::branch_signs`]), and whatever else it
    /// judges or starts from there.
    fn keep_reference(&mut self, signs: [i8; 2]);
    /// Its atlas to build, or `None` when it starts forward kinematics
    /// another way.
    fn atlas_mut(&mut self) -> Option<&mut Atlas>;
}

/// The end every described kind shares, once its reference configuration
/// closes (in [`Spec::reference_q`]): the spec checked; the dependent
/// joints regular there, with `singular` wording the error (`None` for a
/// kind whose independent joints were chosen so); what it keeps of the
/// reference; the atlas of reachable configurations; and the least usable
/// conditioning, a fraction of the reference's (the atlas is built while it
/// is still 0, so that it covers every reachable pose).
pub(crate) fn finish<M: Built>(
    mut mech: M,
    singular: Option<&dyn Fn(&Spec) -> String>,
) -> Result<M> {
    mech.spec().validate()?;
    let spec = mech.spec();
    let rho = spec.nominal[..spec.n_geometric()].to_vec();
    let q0 = spec.reference_q.clone();
    if let Some(words) = singular {
        let nq = q0.len();
        let j = crate::mechanism::autodiff::jacobians(&mech, &q0, &rho, 0..nq);
        let dep: Vec<usize> = (0..nq).filter(|i| !spec.independent.contains(i)).collect();
        if crate::linalg::solve::checked_lu(j.dg.select_columns(&dep)).is_none() {
            return Err(Error::InvalidMechanism(words(spec)));
        }
    }
    let signs = branch_signs(&mech, &q0, &rho);
    mech.keep_reference(signs);
    if mech.atlas_mut().is_some() {
        let atlas = Atlas::build(&mech, M::ATLAS_POINTS);
        if let Some(a) = mech.atlas_mut() {
            *a = atlas;
        }
    }
    mech.spec_mut().min_conditioning = RELATIVE_CONDITIONING * conditioning(&mech, &q0, &rho);
    Ok(mech)
}
