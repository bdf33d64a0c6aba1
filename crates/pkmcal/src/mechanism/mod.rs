//! The mechanism abstraction: joints, parameters, loop closure `g(q, ρ) = 0`
//! (docs/model.md eq. 3) and the tool map `x(q, ρ)`.
//!
//! A mechanism is plain data ([`Spec`]) plus two functions written once, generic
//! over the scalar type, so that every derivative the method needs (∂g/∂q, ∂g/∂ρ,
//! ∂x/∂q, ∂x/∂ρ and the second derivatives of the equilibrium) comes exactly from
//! forward-mode automatic differentiation ([`crate::mechanism::autodiff`]).
//!
//! Parameter vectors are laid out as `[ρ (geometric), Δq (encoder offsets, one per
//! actuated joint), k (stiffness, one per actuated joint)]`; [`Spec::param_names`]
//! gives the names in that order.

pub mod autodiff;
pub mod tool;

use crate::error::{Error, Result};
use crate::units::{ParamKind, Unit};

pub use crate::linalg::Scalar;

/// The most legs a mechanism may have (a spatial mechanism's `[[leg]]`s, a
/// Gough–Stewart platform's): the work of every command grows with the cube
/// of the joints (a workspace lattice's conditioning, each pose's Newton
/// steps), so that `simulate` on 1,000 towers ran for minutes; 128 legs
/// take about 4 s there (BENCHMARKS.md). Real parallel machines have up to
/// about a dozen.
pub const MAX_LEGS: usize = 128;

/// The most joints a mechanism may have, all legs together (see
/// [`MAX_LEGS`]).
pub const MAX_JOINTS: usize = 512;

/// A description's size refused by name, or `Ok`: `legs` legs and `joints`
/// joints against [`MAX_LEGS`] and [`MAX_JOINTS`].
pub fn check_size(legs: usize, joints: usize) -> Result<()> {
    if legs > MAX_LEGS {
        return Err(Error::InvalidMechanism(format!(
            "{legs} legs, more than the {MAX_LEGS} a mechanism may have (the work grows with the cube of the joints); describe fewer legs"
        )));
    }
    if joints > MAX_JOINTS {
        return Err(Error::InvalidMechanism(format!(
            "{joints} joints, more than the {MAX_JOINTS} a mechanism may have (the work grows with the cube of the joints); describe fewer joints"
        )));
    }
    Ok(())
}

/// The plain description of a mechanism: names, indices, nominal values.
#[derive(Debug, Clone, PartialEq)]
pub struct Spec {
    /// Human-readable name.
    pub name: String,
    /// Joint names, in the order of the joint vector `q`.
    pub joints: Vec<String>,
    /// Indices (into `joints`) of the actuated joints `q_r`, in actuator order.
    pub actuated: Vec<usize>,
    /// Indices of the independent joints `q_u` (as many as degrees of freedom).
    /// The rigid and linear forward models drive these joints.
    pub independent: Vec<usize>,
    /// Number of loop-closure equations (= joints − degrees of freedom).
    pub n_constraints: usize,
    /// Names of the geometric parameters ρ.
    pub geometric: Vec<String>,
    /// Names of the encoder offsets, one per actuated joint.
    pub offsets: Vec<String>,
    /// Names of the stiffness parameters, one per actuated joint.
    pub stiffness: Vec<String>,
    /// Names of the tool coordinates (`x`, `y`, …).
    pub tool_axes: Vec<String>,
    /// Unit of each joint coordinate (rad for revolute, mm for prismatic
    /// joints and positions); encoder offsets take their joint's unit and
    /// stiffness the matching N·m/rad or N/mm.
    pub joint_units: Vec<Unit>,
    /// Unit of each geometric parameter.
    pub geometric_units: Vec<Unit>,
    /// Unit of each tool coordinate (mm for positions, rad for orientations).
    pub tool_units: Vec<Unit>,
    /// What the tool coordinates are geometrically (how a change of the
    /// instrument's frame acts on them).
    pub tool_layout: crate::mechanism::tool::ToolLayout,
    /// Nominal values of all parameters, in [`Spec::param_names`] order.
    pub nominal: Vec<f64>,
    /// A configuration of the nominal mechanism on the wanted assembly branch.
    pub reference_q: Vec<f64>,
    /// Parameters identified by default (the paper's set for the reference).
    pub default_free: Vec<String>,
    /// Box `[min, max]` per tool axis that contains the workspace (mm).
    pub workspace_box: Vec<[f64; 2]>,
    /// Factor that turns the work of a tool force (N × mm) into the unit of the
    /// elastic energy `½ k δ²`: [`crate::units::MM_TO_M`] (10⁻³) when the
    /// stiffness is in N·m/rad (revolute actuators, energy in N·m), 1 when it is
    /// in N/mm (prismatic actuators, energy in N·mm). Only the load term uses it.
    pub work_scale: f64,
    /// Length (mm) that one unit of each joint stands for when conditioning is
    /// judged (e.g. a link length for a revolute joint of a linkage with
    /// prismatic joints); empty means 1 for every joint.
    pub joint_scale: Vec<f64>,
    /// Length (mm) that one unit of each tool axis stands for when conditioning
    /// is judged and the workspace is sampled (e.g. a platform radius for an
    /// orientation in rad); empty means 1 for every axis.
    pub axis_scale: Vec<f64>,
    /// Smallest inverse condition number ([`crate::engine::atlas::conditioning`])
    /// of a usable workspace pose: [`crate::engine::atlas::MIN_CONDITIONING`] for
    /// the reference mechanism; for a described mechanism, a fraction
    /// ([`crate::engine::atlas::RELATIVE_CONDITIONING`]) of its reference pose's.
    pub min_conditioning: f64,
    /// Parameters that had another name before: each old name is still
    /// accepted wherever a parameter is named ([`Spec::parameter_index`]),
    /// so that files and calibration records written under it keep
    /// working, and the front ends say so ([`Spec::renamed_among`]).
    pub renamed: Vec<Renamed>,
}

/// A parameter named as it was before: `old` is still accepted, and means
/// `new`. Plain data for a front end to word as a note.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Renamed {
    /// The name it had.
    pub old: String,
    /// Its name now.
    pub new: String,
}

impl Renamed {
    /// `old` → `new`.
    pub fn new(old: impl Into<String>, new: impl Into<String>) -> Self {
        Renamed {
            old: old.into(),
            new: new.into(),
        }
    }
}

impl Spec {
    /// Degrees of freedom.
    pub fn dof(&self) -> usize {
        self.independent.len()
    }
    /// Number of geometric parameters.
    pub fn n_geometric(&self) -> usize {
        self.geometric.len()
    }
    /// Number of actuators.
    pub fn n_actuated(&self) -> usize {
        self.actuated.len()
    }
    /// Total number of parameters (geometric, offsets, stiffness).
    pub fn n_params(&self) -> usize {
        self.geometric.len() + 2 * self.actuated.len()
    }
    /// All parameter names in vector order.
    pub fn param_names(&self) -> Vec<&str> {
        self.geometric
            .iter()
            .chain(&self.offsets)
            .chain(&self.stiffness)
            .map(String::as_str)
            .collect()
    }
    /// Index of a parameter (in [`Spec::param_names`] order) by its name,
    /// or by a name it had ([`Spec::renamed`]), then with the renaming: the
    /// one lookup of parameter names, which every reader goes through.
    pub fn parameter_index(&self, name: &str) -> Option<(usize, Option<&Renamed>)> {
        let current = |n: &str| {
            self.geometric
                .iter()
                .chain(&self.offsets)
                .chain(&self.stiffness)
                .position(|c| c == n)
        };
        if let Some(i) = current(name) {
            return Some((i, None));
        }
        let r = self.renamed.iter().find(|r| r.old == name)?;
        current(&r.new).map(|i| (i, Some(r)))
    }
    /// The name a parameter has now: `name` itself, or what an old name
    /// became.
    pub fn canonical<'a>(&'a self, name: &'a str) -> &'a str {
        match self.parameter_index(name) {
            Some((_, Some(r))) => &r.new,
            _ => name,
        }
    }
    /// The renamings among `names` (old names a user gave, each once, in
    /// the order given): the notes a front end words ("`k1` is now `kL1`").
    pub fn renamed_among<'a>(&self, names: impl IntoIterator<Item = &'a str>) -> Vec<Renamed> {
        let mut out: Vec<Renamed> = vec![];
        for n in names {
            if let Some((_, Some(r))) = self.parameter_index(n.trim())
                && !out.contains(r)
            {
                out.push(r.clone());
            }
        }
        out
    }
    /// All parameter names in vector order as they were before every
    /// renaming (the identity of records saved under them).
    pub fn param_names_before(&self) -> Vec<&str> {
        self.param_names()
            .into_iter()
            .map(|n| {
                self.renamed
                    .iter()
                    .find(|r| r.new == n)
                    .map_or(n, |r| r.old.as_str())
            })
            .collect()
    }
    /// Index of a parameter by name (or an old name, [`Spec::parameter_index`]).
    pub fn param_index(&self, name: &str) -> Result<usize> {
        self.parameter_index(name)
            .map(|(i, _)| i)
            .ok_or_else(|| Error::UnknownParameter {
                name: name.to_string(),
                known: self.param_names().join(" "),
                suggestion: crate::error::did_you_mean(name, self.param_names()),
            })
    }
    /// Kind of parameter `i` (in [`Spec::param_names`] order).
    pub fn param_kind(&self, i: usize) -> ParamKind {
        let (ng, na) = (self.n_geometric(), self.n_actuated());
        if i < ng {
            ParamKind::Geometry
        } else if i < ng + na {
            ParamKind::Offset
        } else {
            ParamKind::Stiffness
        }
    }
    /// Unit of parameter `i` (in [`Spec::param_names`] order): declared for
    /// the geometry, the actuated joint's unit for an offset, N·m/rad or N/mm
    /// for a stiffness.
    pub fn param_unit(&self, i: usize) -> Unit {
        let (ng, na) = (self.n_geometric(), self.n_actuated());
        if i < ng {
            self.geometric_units[i]
        } else if i < ng + na {
            self.joint_units[self.actuated[i - ng]]
        } else {
            self.joint_units[self.actuated[i - ng - na]].stiffness_of_joint()
        }
    }
    /// Unit of each actuator command (its joint's unit), in actuator order.
    pub fn command_units(&self) -> Vec<Unit> {
        self.actuated.iter().map(|&j| self.joint_units[j]).collect()
    }
    /// [`Spec::joint_scale`] of joint `j`.
    pub fn joint_scale(&self, j: usize) -> f64 {
        self.joint_scale.get(j).copied().unwrap_or(1.0)
    }
    /// [`Spec::axis_scale`] of tool axis `k`.
    pub fn axis_scale(&self, k: usize) -> f64 {
        self.axis_scale.get(k).copied().unwrap_or(1.0)
    }
    /// Names of the actuated joints.
    pub fn actuated_names(&self) -> Vec<&str> {
        self.actuated
            .iter()
            .map(|&i| self.joints[i].as_str())
            .collect()
    }

    /// Check the description for internal consistency.
    pub fn validate(&self) -> Result<()> {
        let nq = self.joints.len();
        let bad = |m: String| Err(Error::InvalidMechanism(m));
        if self
            .actuated
            .iter()
            .chain(&self.independent)
            .any(|&i| i >= nq)
        {
            return bad("a joint index is out of range".into());
        }
        if self.independent.len() + self.n_constraints != nq {
            return bad(format!(
                "{} joints must equal {} independent joints plus {} constraints",
                nq,
                self.independent.len(),
                self.n_constraints
            ));
        }
        if self.independent.iter().any(|j| !self.actuated.contains(j)) {
            return bad(
                "every independent joint must be actuated (the rigid and linear models drive them)"
                    .into(),
            );
        }
        if self.actuated.len() < self.independent.len() {
            return bad("fewer actuated joints than degrees of freedom".into());
        }
        if self.offsets.len() != self.actuated.len() || self.stiffness.len() != self.actuated.len()
        {
            return bad(
                "one encoder offset and one stiffness per actuated joint are needed".into(),
            );
        }
        if self.nominal.len() != self.n_params() {
            return bad(format!(
                "{} nominal values for {} parameters",
                self.nominal.len(),
                self.n_params()
            ));
        }
        if self.reference_q.len() != nq {
            return bad(format!(
                "reference configuration has {} values for {} joints",
                self.reference_q.len(),
                nq
            ));
        }
        if self.joint_units.len() != nq
            || self.geometric_units.len() != self.geometric.len()
            || self.tool_units.len() != self.tool_axes.len()
        {
            return bad(format!(
                "units are needed for every joint ({nq}), geometric parameter ({}) and tool axis ({}); got {}, {} and {}",
                self.geometric.len(),
                self.tool_axes.len(),
                self.joint_units.len(),
                self.geometric_units.len(),
                self.tool_units.len()
            ));
        }
        if self
            .joint_units
            .iter()
            .chain(&self.geometric_units)
            .chain(&self.tool_units)
            .any(|u| !matches!(u, Unit::Millimetre | Unit::Radian))
        {
            return bad("joints, geometric parameters and tool axes are in mm or rad".into());
        }
        let layout_size = match self.tool_layout {
            crate::mechanism::tool::ToolLayout::PlanarPoint => Some(2),
            crate::mechanism::tool::ToolLayout::PlanarPose => Some(3),
            crate::mechanism::tool::ToolLayout::SpatialPose => Some(6),
            crate::mechanism::tool::ToolLayout::Points { dim, count } => Some(dim * count),
            crate::mechanism::tool::ToolLayout::Readings => None,
        };
        if layout_size.is_some_and(|n| n != self.tool_axes.len()) {
            return bad(format!(
                "the tool layout {:?} does not fit {} tool axes",
                self.tool_layout,
                self.tool_axes.len()
            ));
        }
        if !(self.work_scale.is_finite() && self.work_scale > 0.0) {
            return bad("work_scale must be a positive number".into());
        }
        if !(self.joint_scale.is_empty() || self.joint_scale.len() == nq)
            || !(self.axis_scale.is_empty() || self.axis_scale.len() == self.tool_axes.len())
            || self
                .joint_scale
                .iter()
                .chain(&self.axis_scale)
                .any(|s| !(s.is_finite() && *s > 0.0))
        {
            return bad("joint_scale and axis_scale need one positive value per joint / tool axis (or none)".into());
        }
        if !(self.min_conditioning.is_finite() && (0.0..1.0).contains(&self.min_conditioning)) {
            return bad("min_conditioning must be in [0, 1)".into());
        }
        if self.workspace_box.len() != self.tool_axes.len() {
            return bad("one workspace interval per tool axis is needed".into());
        }
        for ((axis, b), u) in self
            .tool_axes
            .iter()
            .zip(&self.workspace_box)
            .zip(&self.tool_units)
        {
            if b.iter()
                .any(|v| !(v.is_finite() && v.abs() <= u.max_magnitude()))
            {
                return bad(format!(
                    "the workspace interval of `{axis}` {b:?} must be finite and within ±{:e} {u}",
                    u.max_magnitude()
                ));
            }
        }
        let mut names = self.param_names();
        names.sort_unstable();
        if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
            return bad(format!("parameter `{}` is defined twice", w[0]));
        }
        let params = crate::Params::new(self, self.nominal.clone())?;
        params.validate(self)?;
        for name in &self.default_free {
            self.param_index(name)?;
        }
        for (k, r) in self.renamed.iter().enumerate() {
            if names.binary_search(&r.old.as_str()).is_ok() {
                return bad(format!(
                    "`{}` is a parameter, so it cannot also be the old name of `{}`",
                    r.old, r.new
                ));
            }
            if names.binary_search(&r.new.as_str()).is_err() {
                return bad(format!(
                    "`{}` is renamed `{}`, which is not a parameter",
                    r.old, r.new
                ));
            }
            if self.renamed[..k].iter().any(|o| o.old == r.old) {
                return bad(format!("the old name `{}` is given twice", r.old));
            }
        }
        Ok(())
    }
}

/// A parallel mechanism: loop closure plus tool map, generic over the scalar.
///
/// Implement this trait to bring your own mechanism; every algorithm of the
/// crate then works on it. Both functions receive the joint vector `q` (rad or
/// mm for prismatic joints) and the geometric parameters ρ (mm, rad).
pub trait Mechanism: Send + Sync {
    /// The plain description (names, indices, nominal values).
    fn spec(&self) -> &Spec;

    /// Loop-closure constraints `g(q, ρ) = 0` (docs/model.md eq. 3); `g` has
    /// `spec().n_constraints` entries.
    fn constraints<D: Scalar>(&self, q: &[D], rho: &[D], g: &mut [D]);

    /// Tool coordinates `x(q, ρ)` in mm (`spec().tool_axes`).
    fn tool<D: Scalar>(&self, q: &[D], rho: &[D], x: &mut [D]);

    /// Closed-form inverse kinematics (tool position → all joints) on the
    /// assembly branch of the reference configuration, if the mechanism has one.
    /// The default (`None`) makes [`crate::inverse_kinematics`] use Newton.
    fn inverse_kinematics_closed(&self, _target: &[f64], _rho: &[f64]) -> Option<Result<Vec<f64>>> {
        None
    }

    /// A configuration near the one the actuator `commands` (one per actuated
    /// joint) put the mechanism in, on the assembly branch, if the mechanism can
    /// compute one directly (e.g. in closed form from all actuators). Forward
    /// kinematics polishes it with Newton. The default (`None`) makes
    /// [`crate::prepare_pose`] use continuation from the reference configuration.
    fn configuration_guess(&self, _commands: &[f64], _rho: &[f64]) -> Option<Vec<f64>> {
        None
    }

    /// Values and exact first derivatives of the constraints and the tool map
    /// with respect to the columns `cols` of `[q; ρ]`, when the mechanism has
    /// them in closed form (cheaper than automatic differentiation). The
    /// default (`None`) makes [`crate::mechanism::autodiff::jacobians`] differentiate
    /// automatically; the tests compare the two.
    fn first_derivatives(
        &self,
        _q: &[f64],
        _rho: &[f64],
        _cols: std::ops::Range<usize>,
    ) -> Option<crate::mechanism::autodiff::Jacobians> {
        None
    }

    /// [`Mechanism::first_derivatives`] into `out`, reusing its buffers;
    /// `false` (and `out` untouched) when there is no closed form. The
    /// default moves [`Mechanism::first_derivatives`]'s result in; override
    /// it where the closed form can write in place (no allocation).
    fn first_derivatives_into(
        &self,
        q: &[f64],
        rho: &[f64],
        cols: std::ops::Range<usize>,
        out: &mut crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        match self.first_derivatives(q, rho, cols) {
            Some(j) => {
                *out = j;
                true
            }
            None => false,
        }
    }

    /// Second derivatives of `φ = λᵀg + μᵀx` with respect to the joints (rows)
    /// and to `[q; ρ]` (columns): `n_joints × (n_joints + n_geometric)`. The
    /// exact model's identification Jacobian needs them at every pose. The
    /// default uses automatic differentiation; override it with an analytic
    /// version for speed (the tests compare the two).
    fn weighted_hessian(
        &self,
        q: &[f64],
        rho: &[f64],
        lambda: &[f64],
        mu: &[f64],
    ) -> nalgebra::DMatrix<f64>
    where
        Self: Sized,
    {
        let nq = q.len();
        let h = crate::mechanism::autodiff::output_hessians(self, q, rho, 0..nq, 0..nq + rho.len());
        let weights: Vec<f64> = lambda.iter().chain(mu).copied().collect();
        crate::mechanism::autodiff::weighted_sum(&h, &weights)
    }

    /// Second derivatives of each constraint, then each tool coordinate, with
    /// respect to the joints (one `n_joints × n_joints` matrix per output):
    /// the curvature the equilibrium's Newton iteration uses. The default uses
    /// automatic differentiation.
    fn joint_hessians(&self, q: &[f64], rho: &[f64]) -> Vec<nalgebra::DMatrix<f64>>
    where
        Self: Sized,
    {
        crate::mechanism::autodiff::output_hessians(self, q, rho, 0..q.len(), 0..q.len())
    }

    /// Whether [`Mechanism::joint_hessian_blocks`] gives the joint
    /// Hessians cheaply beside an equilibrium: a large
    /// calibration then computes them for each equilibrium instead of
    /// keeping them with every pose. The default: no.
    fn joint_hessians_cheap(&self) -> bool {
        false
    }

    /// Each output's joint Hessian (the order of
    /// [`Mechanism::joint_hessians`]) given to `out` as the joints it
    /// involves (ascending) and its block over them (column-major; every
    /// other entry zero), without the dense matrices. Returns whether it
    /// gave them: the default gives none (the dense matrices serve).
    fn joint_hessian_blocks(
        &self,
        _q: &[f64],
        _rho: &[f64],
        _out: &mut dyn FnMut(&[usize], &[f64]),
    ) -> bool {
        false
    }

    /// Check parameter values beyond finiteness (e.g. lengths that must be
    /// positive). The default accepts every value.
    fn check_params(&self, _rho: &[f64]) -> Result<()> {
        Ok(())
    }

    /// Whether a configuration lies on the assembly branch of the reference
    /// configuration. The default accepts every configuration.
    fn on_branch(&self, _q: &[f64], _rho: &[f64]) -> bool {
        true
    }

    /// [`Mechanism::on_branch`] given the derivatives (joint columns) at a
    /// configuration within Newton's tolerance of `q` (the last iteration of
    /// forward kinematics), for mechanisms that judge the branch from them.
    /// The default ignores them.
    fn on_branch_near(
        &self,
        q: &[f64],
        rho: &[f64],
        _jac: &crate::mechanism::autodiff::Jacobians,
    ) -> bool {
        self.on_branch(q, rho)
    }

    /// The name of a leg whose working mode at `q` differs from the
    /// reference configuration's, for mechanisms that tell working modes leg
    /// by leg (so that a configuration off the branch is refused for its real
    /// cause). The default (`None`) names none.
    fn leg_in_other_mode(&self, _q: &[f64], _rho: &[f64]) -> Option<&str> {
        None
    }
}

/// A full parameter vector `[ρ, Δq, k]` of a mechanism.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Params {
    /// Values in [`Spec::param_names`] order.
    pub values: Vec<f64>,
    n_geometric: usize,
    n_actuated: usize,
}

impl Params {
    /// No parameters (a placeholder to be filled in).
    pub(crate) fn empty() -> Self {
        Params {
            values: vec![],
            n_geometric: 0,
            n_actuated: 0,
        }
    }

    /// Wrap a full vector (checks its length).
    pub fn new(spec: &Spec, values: Vec<f64>) -> Result<Self> {
        if values.len() != spec.n_params() {
            return Err(Error::Dimension {
                what: "parameter vector".into(),
                expected: spec.n_params(),
                got: values.len(),
            });
        }
        Ok(Self {
            values,
            n_geometric: spec.n_geometric(),
            n_actuated: spec.n_actuated(),
        })
    }
    /// The nominal parameters.
    pub fn nominal(spec: &Spec) -> Self {
        Self {
            values: spec.nominal.clone(),
            n_geometric: spec.n_geometric(),
            n_actuated: spec.n_actuated(),
        }
    }
    /// Nominal values with some set by name (names not given stay nominal;
    /// old names are accepted, [`Spec::parameter_index`]).
    pub fn from_named<'a>(
        spec: &Spec,
        named: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<Self> {
        Self::from_named_noting(spec, named).map(|(p, _)| p)
    }
    /// [`Params::from_named`], with the old names it read (the notes a
    /// front end words: a parameter file written before a renaming).
    pub fn from_named_noting<'a>(
        spec: &Spec,
        named: impl IntoIterator<Item = (&'a str, f64)>,
    ) -> Result<(Self, Vec<Renamed>)> {
        let mut p = Self::nominal(spec);
        let mut notes: Vec<Renamed> = vec![];
        for (name, value) in named {
            let i = match spec.parameter_index(name) {
                Some((i, Some(r))) => {
                    if !notes.contains(r) {
                        notes.push(r.clone());
                    }
                    i
                }
                Some((i, None)) => i,
                None => spec.param_index(name)?,
            };
            p.values[i] = value;
        }
        p.validate(spec)?;
        Ok((p, notes))
    }
    /// Geometric parameters ρ.
    pub fn geometric(&self) -> &[f64] {
        &self.values[..self.n_geometric]
    }
    /// Encoder offsets Δq_r (rad), actual minus reported.
    pub fn offsets(&self) -> &[f64] {
        &self.values[self.n_geometric..self.n_geometric + self.n_actuated]
    }
    /// Stiffness of the actuated joints (N·m/rad, or N/mm for prismatic).
    pub fn stiffness(&self) -> &[f64] {
        &self.values[self.n_geometric + self.n_actuated..]
    }
    /// Value by name.
    pub fn get(&self, spec: &Spec, name: &str) -> Result<f64> {
        Ok(self.values[spec.param_index(name)?])
    }
    /// Set a value by name.
    pub fn set(&mut self, spec: &Spec, name: &str, value: f64) -> Result<()> {
        let i = spec.param_index(name)?;
        self.values[i] = value;
        Ok(())
    }
    /// Check that every value is finite and within the range its unit
    /// allows ([`Unit::max_magnitude`]) and every stiffness positive.
    pub fn validate(&self, spec: &Spec) -> Result<()> {
        for (i, (name, &v)) in spec.param_names().iter().zip(&self.values).enumerate() {
            if !v.is_finite() {
                return Err(Error::InvalidParameter {
                    name: name.to_string(),
                    value: v,
                    reason: "values must be finite numbers".into(),
                });
            }
            let unit = spec.param_unit(i);
            if v.abs() > unit.max_magnitude() {
                return Err(Error::InvalidParameter {
                    name: name.to_string(),
                    value: v,
                    reason: format!(
                        "beyond ±{:e} {unit}, no machine has such a value",
                        unit.max_magnitude()
                    ),
                });
            }
        }
        for (name, &k) in spec.stiffness.iter().zip(self.stiffness()) {
            if k <= 0.0 {
                return Err(Error::InvalidParameter {
                    name: name.clone(),
                    value: k,
                    reason: "stiffness must be positive".into(),
                });
            }
        }
        Ok(())
    }
}

/// One parameter of a mechanism, as [`summary`] lists it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ParameterInfo {
    /// Its name (as parameter files, `--free` and Python dicts name it).
    pub name: String,
    /// What it is: geometry, an encoder offset, a stiffness.
    pub kind: ParamKind,
    /// Its unit.
    pub unit: Unit,
    /// Its nominal value.
    pub nominal: f64,
    /// Whether a calibration identifies it unless told otherwise.
    pub free_by_default: bool,
}

/// One joint of a mechanism, as [`summary`] lists it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JointInfo {
    /// Its name (an actuator's is its commands' column).
    pub name: String,
    /// Its unit (rad or mm).
    pub unit: Unit,
    /// Whether an actuator drives it.
    pub actuated: bool,
    /// Whether the rigid and linear models drive it (the independent joints).
    pub independent: bool,
}

/// One tool axis and the workspace box along it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AxisInfo {
    /// Its name (`x`, `rz`, …).
    pub name: String,
    /// Its unit.
    pub unit: Unit,
    /// The workspace box along it, `[min, max]`.
    pub workspace: [f64; 2],
}

/// What a mechanism is made of, for a user writing a parameter file, a data
/// file or a free set: its parameters, joints, actuators and tool axes.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MechanismSummary {
    /// The mechanism's name.
    pub name: String,
    /// Degrees of freedom.
    pub dof: usize,
    /// Every joint, in order.
    pub joints: Vec<JointInfo>,
    /// The actuated joints' names, in the commands' column order.
    pub actuators: Vec<String>,
    /// The tool coordinates with their workspace box.
    pub tool_axes: Vec<AxisInfo>,
    /// Every parameter, in [`Spec::param_names`] order.
    pub parameters: Vec<ParameterInfo>,
}

/// The [`MechanismSummary`] of a mechanism's description.
pub fn summary(spec: &Spec) -> MechanismSummary {
    MechanismSummary {
        name: spec.name.clone(),
        dof: spec.dof(),
        joints: spec
            .joints
            .iter()
            .enumerate()
            .map(|(j, name)| JointInfo {
                name: name.clone(),
                unit: spec.joint_units[j],
                actuated: spec.actuated.contains(&j),
                independent: spec.independent.contains(&j),
            })
            .collect(),
        actuators: spec
            .actuated_names()
            .iter()
            .map(|s| s.to_string())
            .collect(),
        tool_axes: spec
            .tool_axes
            .iter()
            .enumerate()
            .map(|(k, name)| AxisInfo {
                name: name.clone(),
                unit: spec.tool_units[k],
                workspace: spec.workspace_box[k],
            })
            .collect(),
        parameters: spec
            .param_names()
            .iter()
            .enumerate()
            .map(|(i, name)| ParameterInfo {
                name: name.to_string(),
                kind: spec.param_kind(i),
                unit: spec.param_unit(i),
                nominal: spec.nominal[i],
                free_by_default: spec.default_free.iter().any(|f| f == name),
            })
            .collect(),
    }
}
