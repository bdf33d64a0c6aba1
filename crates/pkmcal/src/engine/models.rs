//! The three forward models of docs/model.md §4: for actuator commands and a
//! parameter set, where is the tool?
//!
//! (A long file: the three models and the exact equilibrium they share are
//! one job.)
//!
//! * [`Model::Rigid`]: the independent actuated joints sit at `command + Δq`;
//!   loop closure gives the rest; the other actuators are ignored.
//! * [`Model::Linear`]: the paper's eq. 11 evaluated at the nominal configuration
//!   of the command, then exact loop closure with the true parameters.
//! * [`Model::Exact`]: the static equilibrium itself ([`equilibrium`]): minimum
//!   elastic energy minus load work on the exact constraint manifold.
//!
//! A command that is inconsistent with the nominal geometry (the actuators do
//! not agree on one pose) acts exactly like an extra encoder offset `e = c −
//! q_r,nominal`; the linear model adds it to `Δq` so that it stays the
//! first-order expansion of the exact model.

use crate::engine::curvature::JointHessians;
use crate::engine::kinematics::{forward_kinematics, reference_configuration};
use crate::engine::linearized::{Linearization, joint_errors, linearize, load_vector};
use crate::error::{Error, Result};
use crate::linalg::product_into;
use crate::mechanism::autodiff::{jacobians, jacobians_into};
use crate::mechanism::{Mechanism, Params};
use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

/// Which forward model to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// Conventional non-redundant treatment: no compliance.
    Rigid,
    /// The paper's linearised compliance model (eq. 11).
    Linear,
    /// Exact static equilibrium on the constraint manifold.
    Exact,
}

impl Model {
    /// All models, in order of fidelity.
    pub const ALL: [Model; 3] = [Model::Rigid, Model::Linear, Model::Exact];
    /// Lower-case name (`rigid`, `linear`, `exact`).
    pub fn name(self) -> &'static str {
        match self {
            Model::Rigid => "rigid",
            Model::Linear => "linear",
            Model::Exact => "exact",
        }
    }
}

impl std::str::FromStr for Model {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "rigid" => Ok(Model::Rigid),
            "linear" => Ok(Model::Linear),
            "exact" => Ok(Model::Exact),
            _ => Err(Error::InvalidRequest(format!(
                "unknown model `{s}`; use exact, linear or rigid"
            ))),
        }
    }
}

/// A commanded pose prepared once: its nominal configuration and the paper's
/// matrices there (nominal parameters).
#[derive(Debug, Clone)]
pub struct Pose {
    /// Actuator commands (rad or mm), one per actuated joint.
    pub commands: Vec<f64>,
    /// Nominal configuration: forward kinematics of the independent commands
    /// with nominal parameters.
    pub nominal_q: Vec<f64>,
    /// Φ, J_p, Γ, H, J_f at the nominal configuration (computed on first use:
    /// only the linear model needs them).
    lin: OnceLock<Box<Result<Linearization>>>,
    /// Second derivatives of each constraint and tool coordinate with respect
    /// to the joints at the nominal configuration (computed on first use by the
    /// exact model; Newton's curvature there is good to ~1e-6 relative), kept
    /// without their zeros.
    hessians: OnceLock<JointHessians>,
    /// Set when the pose belongs to a large problem ([`Pose::transient_hessians`]):
    /// its joint Hessians are then computed for each equilibrium from the
    /// nominal configuration, the same numbers, and not kept.
    transient: OnceLock<()>,
    /// The prediction at nominal parameters from the nominal configuration
    /// (no warm start), with the model and load it was made for: a
    /// calibration that starts at nominal parameters and the accuracy it
    /// reports before calibration make it once ([`Pose::predict_at_nominal`]).
    at_nominal: OnceLock<Box<(Model, Vec<f64>, Prediction)>>,
    /// The sensitivity at nominal parameters, with the model and load it
    /// was computed for ([`Pose::tool_sensitivity_at_nominal`]): every fit
    /// that starts at nominal parameters (each run of a Monte Carlo study)
    /// computes the same Jacobian there.
    sensitivity_at_nominal: OnceLock<Box<KeptSensitivity>>,
}

/// The derivatives a pose keeps at nominal parameters
/// ([`Pose::tool_sensitivity_at_nominal`]) and what they were computed for.
#[derive(Debug, Clone)]
struct KeptSensitivity {
    model: Model,
    force: Vec<f64>,
    prediction: Prediction,
    /// `∂x/∂p`.
    tool: DMatrix<f64>,
}

impl Pose {
    /// A pose of (reduced) `commands` at the configuration `nominal_q`,
    /// nothing computed yet.
    fn at(commands: Vec<f64>, nominal_q: Vec<f64>) -> Self {
        Pose {
            commands,
            nominal_q,
            lin: OnceLock::new(),
            hessians: OnceLock::new(),
            transient: OnceLock::new(),
            at_nominal: OnceLock::new(),
            sensitivity_at_nominal: OnceLock::new(),
        }
    }

    /// [`predict_pose`] at nominal parameters `nominal` (the caller's, equal
    /// to `Params::nominal`), computed once per model and load: the first
    /// computed is kept, any other is computed each time. The same
    /// prediction, bit for bit, as `predict_pose`.
    #[doc(hidden)] // public for the integration tests only
    pub fn predict_at_nominal<M: Mechanism>(
        &self,
        mech: &M,
        nominal: &Params,
        model: Model,
        force: &[f64],
    ) -> Result<Prediction> {
        debug_assert_eq!(nominal.values, mech.spec().nominal);
        if let Some((m, f, p)) = self.at_nominal.get().map(|b| &**b)
            && *m == model
            && f == force
        {
            return Ok(p.clone());
        }
        let p = predict_pose(mech, self, nominal, model, force)?;
        // (Another thread may have kept its own, the same, first.)
        let _ = self
            .at_nominal
            .set(Box::new((model, force.to_vec(), p.clone())));
        Ok(p)
    }

    /// [`Pose::predict_at_nominal`] written into `out` (its vectors keep
    /// their storage when the kept prediction is taken).
    #[doc(hidden)] // public for the integration tests only
    pub fn predict_at_nominal_into<M: Mechanism>(
        &self,
        mech: &M,
        nominal: &Params,
        model: Model,
        force: &[f64],
        out: &mut Prediction,
    ) -> Result<()> {
        if let Some((m, f, p)) = self.at_nominal.get().map(|b| &**b)
            && *m == model
            && f == force
        {
            out.clone_from(p);
            return Ok(());
        }
        *out = self.predict_at_nominal(mech, nominal, model, force)?;
        Ok(())
    }

    /// [`crate::engine::sensitivity::tool_sensitivity`] at nominal
    /// parameters `nominal` (the caller's, equal to `Params::nominal`) for
    /// `prediction`: the one kept for this model and load when it was
    /// computed for the same prediction (then the same, bit for bit, as it
    /// is a function of them alone), else computed (and kept if it is the
    /// first).
    pub(crate) fn tool_sensitivity_at_nominal<M: Mechanism>(
        &self,
        mech: &M,
        nominal: &Params,
        model: Model,
        force: &[f64],
        prediction: &Prediction,
    ) -> Result<DMatrix<f64>> {
        debug_assert_eq!(nominal.values, mech.spec().nominal);
        let kept = self.sensitivity_at_nominal.get().map(|b| &**b);
        if let Some(k) = kept
            && k.model == model
            && k.force == force
            && k.prediction.same_bits(prediction)
        {
            return Ok(k.tool.clone());
        }
        let tool = crate::engine::sensitivity::tool_sensitivity(
            mech, self, nominal, model, force, prediction,
        )?;
        if kept.is_none() {
            // (Another thread may have kept its own, the same, first.)
            let _ = self.sensitivity_at_nominal.set(Box::new(KeptSensitivity {
                model,
                force: force.to_vec(),
                prediction: prediction.clone(),
                tool: tool.clone(),
            }));
        }
        Ok(tool)
    }

    /// Φ, J_p, Γ, H, J_f at the nominal configuration (eq. 4–7, 9), the
    /// linear model's matrices.
    pub fn lin<M: Mechanism>(&self, mech: &M) -> Result<&Linearization> {
        let spec = mech.spec();
        self.lin
            .get_or_init(|| {
                Box::new(linearize(
                    mech,
                    &self.nominal_q,
                    &spec.nominal[..spec.n_geometric()],
                    &spec.independent,
                ))
            })
            .as_ref()
            .as_ref()
            .map_err(Clone::clone)
    }

    /// Per-output joint Hessians at the nominal configuration.
    pub fn hessians<M: Mechanism>(&self, mech: &M) -> &JointHessians {
        self.hessians.get_or_init(|| self.joint_hessians(mech))
    }

    /// The joint Hessians at the nominal configuration, computed into `out`.
    fn joint_hessians_into<M: Mechanism>(&self, mech: &M, out: &mut JointHessians) {
        let spec = mech.spec();
        let (q, rho) = (&self.nominal_q, &spec.nominal[..spec.n_geometric()]);
        out.clear(q.len());
        if !mech.joint_hessian_blocks(q, rho, &mut |joints, block| out.push(joints, block)) {
            *out = JointHessians::from_dense(&mech.joint_hessians(q, rho));
        }
    }

    /// The joint Hessians at the nominal configuration, computed.
    fn joint_hessians<M: Mechanism>(&self, mech: &M) -> JointHessians {
        let mut h = JointHessians::empty();
        self.joint_hessians_into(mech, &mut h);
        h.shrink_to_fit();
        h
    }

    /// Compute this pose's joint Hessians for each equilibrium rather than
    /// keep them (unless they are kept already): a pose of a large problem
    /// (tens of thousands of poses) would otherwise hold them, 2.5 kB a pose
    /// on an 8-leg platform, for the whole calibration. The numbers are the
    /// same, computed from the same nominal configuration. For mechanisms
    /// that compute them cheaply ([`Mechanism::joint_hessians_cheap`],
    /// [`Mechanism::joint_hessian_blocks`]).
    pub(crate) fn transient_hessians(&self) {
        let _ = self.transient.set(());
    }

    /// `f` of the joint Hessians: the kept ones, or, for a pose whose
    /// Hessians are transient, ones computed for this call.
    fn with_hessians<M: Mechanism, R>(&self, mech: &M, f: impl FnOnce(&JointHessians) -> R) -> R {
        match self.hessians.get() {
            Some(h) => f(h),
            // Computed into a buffer of the thread's (a nested call, which
            // nothing makes today, would get one of its own).
            None if self.transient.get().is_some() => {
                TRANSIENT_HESSIANS.with(|cell| match cell.try_borrow_mut() {
                    Ok(mut h) => {
                        self.joint_hessians_into(mech, &mut h);
                        f(&h)
                    }
                    Err(_) => f(&self.joint_hessians(mech)),
                })
            }
            None => f(self.hessians(mech)),
        }
    }
}

/// Where the tool is and what the actuators feel.
#[derive(Debug, Default, PartialEq)]
pub struct Prediction {
    /// Full joint vector.
    pub q: Vec<f64>,
    /// Tool coordinates (mm).
    pub x: Vec<f64>,
    /// Twist of each actuated joint through its stiffness: link side minus motor
    /// side, `q_r − (command + Δq)` (rad). For the rigid model, the mismatch the
    /// rigid model ignores (zero at the driven joints).
    pub deflection: Vec<f64>,
    /// Internal torque of each actuator on its link, `τ = K(command + Δq − q_r)`
    /// (eq. 2; N·m). Zero for the rigid model.
    pub torque: Vec<f64>,
    /// Newton iterations of the equilibrium (exact model), else 0.
    pub iterations: usize,
    /// Lagrange multipliers of the constraints at the equilibrium (exact
    /// model), else empty.
    pub multipliers: Vec<f64>,
}

impl Clone for Prediction {
    fn clone(&self) -> Self {
        Self {
            q: self.q.clone(),
            x: self.x.clone(),
            deflection: self.deflection.clone(),
            torque: self.torque.clone(),
            iterations: self.iterations,
            multipliers: self.multipliers.clone(),
        }
    }

    /// Into this prediction's vectors, which keep their storage.
    fn clone_from(&mut self, source: &Self) {
        self.q.clone_from(&source.q);
        self.x.clone_from(&source.x);
        self.deflection.clone_from(&source.deflection);
        self.torque.clone_from(&source.torque);
        self.iterations = source.iterations;
        self.multipliers.clone_from(&source.multipliers);
    }
}

impl Prediction {
    /// Whether `other` is this prediction bit for bit (a signed zero or a
    /// NaN as well).
    #[doc(hidden)] // public for the integration tests only
    pub fn same_bits(&self, other: &Self) -> bool {
        let same = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        self.iterations == other.iterations
            && same(&self.q, &other.q)
            && same(&self.x, &other.x)
            && same(&self.deflection, &other.deflection)
            && same(&self.torque, &other.torque)
            && same(&self.multipliers, &other.multipliers)
    }
}

/// Result of the exact equilibrium.
#[derive(Debug, Clone, PartialEq)]
pub struct Equilibrium {
    /// Joint vector at equilibrium.
    pub q: Vec<f64>,
    /// Lagrange multipliers of the constraints.
    pub lambda: Vec<f64>,
    /// Internal torques `τ = K(command + Δq − q_r)` (N·m).
    pub torque: Vec<f64>,
    /// Newton iterations.
    pub iterations: usize,
}

fn check_commands(spec: &crate::Spec, commands: &[f64]) -> Result<()> {
    if commands.len() != spec.n_actuated() {
        return Err(Error::Dimension {
            what: "actuator commands".into(),
            expected: spec.n_actuated(),
            got: commands.len(),
        });
    }
    for (k, (&j, c)) in spec.actuated.iter().zip(commands).enumerate() {
        let unit = spec.joint_units[j];
        if !c.is_finite() {
            return Err(Error::InvalidRequest(format!(
                "actuator command {c:?} of `{}` is not a finite number",
                spec.actuated_names()[k]
            )));
        }
        if unit == crate::Unit::Millimetre && c.abs() > crate::units::MAX_LENGTH_MM {
            return Err(Error::InvalidRequest(format!(
                "actuator command {c:?} mm of `{}` is beyond ±{:e} mm; no machine moves that far",
                spec.actuated_names()[k],
                crate::units::MAX_LENGTH_MM
            )));
        }
    }
    Ok(())
}

/// Revolute commands more than a turn from the reference configuration,
/// reduced modulo 2π to within π of it (the same joint position): forward
/// kinematics then never travels further than a turn and a half, whatever the
/// encoder's turn count. Commands within a turn are kept as given.
pub(crate) fn reduced_commands(spec: &crate::Spec, commands: &[f64]) -> Vec<f64> {
    use std::f64::consts::{PI, TAU};
    spec.actuated
        .iter()
        .zip(commands)
        .map(|(&j, &c)| {
            let r = spec.reference_q[j];
            if spec.joint_units[j] != crate::Unit::Radian || (c - r).abs() <= TAU {
                return c;
            }
            let d = (c - r).rem_euclid(TAU);
            if d > PI { r + d - TAU } else { r + d }
        })
        .collect()
}

/// Position of each independent joint in the actuator list.
pub(crate) fn independent_actuators(spec: &crate::Spec) -> Vec<usize> {
    spec.independent
        .iter()
        .map(|j| {
            spec.actuated
                .iter()
                .position(|a| a == j)
                .expect("validated: independent joints are actuated")
        })
        .collect()
}

/// Prepare a pose: nominal forward kinematics of the independent commands
/// (from `start`, or from the reference configuration); the linearisation is computed on first use ([`Pose::lin`]).
pub fn prepare_pose<M: Mechanism>(
    mech: &M,
    commands: &[f64],
    start: Option<&[f64]>,
) -> Result<Pose> {
    prepare_pose_ahead(mech, commands, start, None)
}

/// The part of [`prepare_pose`] that does not depend on the caller's start,
/// done ahead (in parallel over a sequence of poses, each of which starts
/// from the one before): the mechanism's guess and, when forward kinematics
/// from it agrees with the commands, the pose `prepare_pose` returns
/// whenever it tries the guess first.
#[doc(hidden)] // public for the integration tests only
pub struct Ahead {
    guess: Option<Vec<f64>>,
    /// (Boxed: a sequence of these is collected before the poses are
    /// taken out, most of them `None` when the poses are cached.)
    #[doc(hidden)] // public for the integration tests only
    pub pose: Option<Box<Pose>>,
}

/// [`Ahead`] for `commands` (`None` for commands `prepare_pose` rejects).
#[doc(hidden)] // public for the integration tests only
pub fn pose_ahead<M: Mechanism>(mech: &M, commands: &[f64]) -> Option<Ahead> {
    let spec = mech.spec();
    check_commands(spec, commands).ok()?;
    let (reduced, q_u) = pose_commands(spec, commands);
    let commands = reduced.as_slice();
    let rho = &spec.nominal[..spec.n_geometric()];
    let guess = mech.configuration_guess(commands, rho);
    let pose = guess.as_ref().and_then(|g| {
        let q = forward_kinematics(mech, rho, &q_u, g).ok()?;
        (commands_mismatch(spec, commands, &q) < CONSISTENT)
            .then(|| Box::new(Pose::at(commands.to_vec(), q)))
    });
    Some(Ahead { guess, pose })
}

/// A pose's commands as [`prepare_pose`] uses them ([`reduced_commands`]),
/// and the independent joints' values among them.
fn pose_commands(spec: &crate::Spec, commands: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let reduced = reduced_commands(spec, commands);
    let q_u = independent_actuators(spec)
        .iter()
        .map(|&a| reduced[a])
        .collect();
    (reduced, q_u)
}

/// Largest difference between the actuated joints of `q` and the commands.
fn commands_mismatch(spec: &crate::Spec, commands: &[f64], q: &[f64]) -> f64 {
    spec.actuated
        .iter()
        .zip(commands)
        .map(|(&j, c)| (q[j] - c).abs())
        .fold(0.0, f64::max)
}

/// Forward kinematics whose actuated joints agree with the (redundant)
/// commands to this (mm or rad) is taken at once.
const CONSISTENT: f64 = 1e-6;

/// Largest disagreement (rad; a length counts at 100 mm per rad, as
/// continuation stages do) of forward kinematics' actuated joints with the
/// redundant commands that the first starts may leave before the commands'
/// nominal pose is tried too: beyond any encoder offset or compensation (a
/// few mrad, a fraction of a mm), short of another assembly's.
const PLAUSIBLE_MISMATCH: f64 = 0.05;

/// [`commands_mismatch`] in rad-equivalents
/// ([`crate::engine::kinematics::step_turn`]).
fn scaled_mismatch(spec: &crate::Spec, commands: &[f64], q: &[f64]) -> f64 {
    crate::engine::kinematics::turn_of(
        spec,
        spec.actuated
            .iter()
            .zip(commands)
            .map(|(&j, c)| (j, q[j] - c)),
    )
}

/// [`prepare_pose`] with the work of [`pose_ahead`] done (the same result).
#[doc(hidden)] // public for the integration tests only
pub fn prepare_pose_ahead<M: Mechanism>(
    mech: &M,
    commands: &[f64],
    start: Option<&[f64]>,
    ahead: Option<Ahead>,
) -> Result<Pose> {
    let spec = mech.spec();
    check_commands(spec, commands)?;
    let (reduced, q_u) = pose_commands(spec, commands);
    let commands = reduced.as_slice();
    let rho = &spec.nominal[..spec.n_geometric()];
    // Candidate starts: the mechanism's own guess from all commands, the
    // caller's configuration, the reference configuration. Forward kinematics
    // may find other assembly modes from a poor start, so keep the solution
    // that agrees best with the redundant commands (for consistent commands,
    // exactly), and stop at the first that agrees to `CONSISTENT`.
    let mismatch = |q: &[f64]| commands_mismatch(spec, commands, q);
    let (mut ahead_guess, ahead_pose) = match ahead {
        Some(a) => (Some(a.guess), a.pose.map(|p| *p)),
        None => (None, None),
    };
    let mut guess_of = || {
        ahead_guess
            .take()
            .unwrap_or_else(|| mech.configuration_guess(commands, rho))
    };
    let mut best: Option<(f64, Vec<f64>)> = None;
    let mut first_error = None;
    // The starts tried, for the last one's nearest known configuration.
    let mut tried: Vec<Vec<f64>> = Vec::with_capacity(3);
    // The caller's start first when it is one continuation stage away (the
    // previous pose of a sequence; no search for a stored configuration),
    // else the nearer of the two first.
    #[derive(Clone, Copy)]
    enum Start {
        Guess,
        Caller,
        Reference,
    }
    let stages = |s: &[f64]| crate::engine::kinematics::continuation_stages(spec, s, &q_u);
    let caller_stages = start.map(stages);
    let mut guess = None;
    let mut guessed = false;
    let order = if caller_stages.is_some_and(|n| n <= 1.0) {
        [Start::Caller, Start::Guess, Start::Reference]
    } else {
        guess = guess_of();
        guessed = true;
        match (&guess, caller_stages) {
            (Some(g), Some(n)) if n < stages(g) => [Start::Caller, Start::Guess, Start::Reference],
            _ => {
                // The guess first: the pose found ahead from it is the answer.
                if let Some(p) = ahead_pose {
                    return Ok(p);
                }
                [Start::Guess, Start::Caller, Start::Reference]
            }
        }
    };
    for which in order {
        let s = match which {
            Start::Guess => {
                if !guessed {
                    guess = guess_of();
                    guessed = true;
                }
                match guess.take() {
                    Some(g) => g,
                    None => continue,
                }
            }
            Start::Caller => match start {
                Some(s) => s.to_vec(),
                None => continue,
            },
            Start::Reference => match reference_configuration(mech, rho) {
                Ok(r) => r,
                Err(e) => {
                    first_error.get_or_insert(e);
                    continue;
                }
            },
        };
        let result = forward_kinematics(mech, rho, &q_u, &s);
        tried.push(s);
        match result {
            Ok(q) => {
                let m = mismatch(&q);
                // Consistent commands are answered at once; inconsistent
                // ones (calibrated, measured) once an answer is within a
                // plausible disagreement of every command: another start
                // would only find the same configuration again.
                let done =
                    m < CONSISTENT || scaled_mismatch(spec, commands, &q) <= PLAUSIBLE_MISMATCH;
                if best.as_ref().is_none_or(|b| m < b.0) {
                    best = Some((m, q));
                }
                if done {
                    break;
                }
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    // No start reached a configuration near every command (a path crossed
    // a singularity, or the guess failed on inconsistent commands): start
    // from the commands' nominal pose, fitted to all of them from the
    // nearest configuration tried (the last of the bounded starts,
    // docs/model.md §2).
    if best
        .as_ref()
        .is_none_or(|b| scaled_mismatch(spec, commands, &b.1) > PLAUSIBLE_MISMATCH)
    {
        let near = tried
            .iter()
            .chain(best.as_ref().map(|b| &b.1))
            .min_by(|a, b| {
                scaled_mismatch(spec, commands, a).total_cmp(&scaled_mismatch(spec, commands, b))
            })
            .cloned();
        let fitted = match near {
            Some(n) => crate::engine::kinematics::commands_configuration(mech, rho, commands, &n),
            None => None,
        };
        if let Some(s) = fitted {
            match forward_kinematics(mech, rho, &q_u, &s) {
                Ok(q) => {
                    let m = mismatch(&q);
                    if best.as_ref().is_none_or(|b| m < b.0) {
                        best = Some((m, q));
                    }
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
    }
    let nominal_q = match best {
        Some((_, q)) => q,
        None => return Err(first_error.expect("at least one attempt was made")),
    };
    Ok(Pose::at(commands.to_vec(), nominal_q))
}

/// The rigid model's prediction of a pose: forward kinematics of the
/// independent commands plus encoder offsets, from `start`.
fn rigid_from<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    start: &[f64],
) -> Result<Prediction> {
    let spec = mech.spec();
    let rho = params.geometric();
    let q_u: Vec<f64> = independent_actuators(spec)
        .iter()
        .map(|&a| pose.commands[a] + params.offsets()[a])
        .collect();
    let q = crate::engine::kinematics::forward_kinematics_from_nominal(mech, rho, &q_u, start)?;
    let x = jacobians(mech, &q, rho, 0..0).x;
    let deflection = spec
        .actuated
        .iter()
        .enumerate()
        .map(|(a, &j)| q[j] - pose.commands[a] - params.offsets()[a])
        .collect();
    Ok(Prediction {
        q,
        x,
        deflection,
        torque: vec![0.0; spec.n_actuated()],
        iterations: 0,
        multipliers: vec![],
    })
}

/// The model that computes `model`'s prediction: the exact model is the
/// rigid one when nothing loads the actuators, a mechanism with no more
/// actuators than degrees of freedom and no external force (eq. 1 and 3:
/// the actuators cannot fight, so every joint torque is zero and every
/// deflection too). The rigid model needs no second derivatives.
pub(crate) fn effective_model(spec: &crate::Spec, model: Model, force: &[f64]) -> Model {
    if model == Model::Exact && spec.n_actuated() == spec.dof() && force.iter().all(|f| *f == 0.0) {
        Model::Rigid
    } else {
        model
    }
}

/// Prediction of one prepared pose with one model (docs/model.md §4).
/// `force` is the external load on the tool, a wrench ([`crate::engine::load`]: N
/// along each length coordinate, N·m about each angle's axis), empty for none.
pub fn predict_pose<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
) -> Result<Prediction> {
    let spec = mech.spec();
    let force = effective_force(mech, pose, force)?;
    match effective_model(spec, model, &force) {
        Model::Rigid => rigid_from(mech, pose, params, &pose.nominal_q),
        Model::Linear => linear_prediction(mech, pose, params, &force),
        Model::Exact => {
            // From the nominal configuration (parameter errors are small),
            // else from the linear model's pose (one more forward kinematics
            // and the linearisation).
            if let Ok(p) = exact_from(mech, pose, params, &force, &pose.nominal_q) {
                return Ok(p);
            }
            let lin = linear_prediction(mech, pose, params, &force)?;
            exact_from(mech, pose, params, &force, &lin.q)
        }
    }
}

/// The exact model's prediction by [`equilibrium`] from `start`.
fn exact_from<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    force: &[f64],
    start: &[f64],
) -> Result<Prediction> {
    let mut p = Prediction::default();
    exact_into(mech, pose, params, force, start, &mut p)?;
    Ok(p)
}

/// [`exact_from`] written into `out`, whose vectors keep their storage
/// (the same numbers; `out` is left unspecified on an error).
fn exact_into<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    force: &[f64],
    start: &[f64],
    out: &mut Prediction,
) -> Result<()> {
    let Prediction {
        q,
        x,
        deflection,
        torque,
        iterations,
        multipliers,
    } = out;
    *iterations = pose.with_hessians(mech, |h| {
        equilibrium_into(
            mech,
            params,
            &pose.commands,
            force,
            start,
            Some(h),
            (q, multipliers, torque),
        )
    })?;
    x.clear();
    x.resize(mech.spec().tool_axes.len(), 0.0);
    mech.tool(q, params.geometric(), x);
    deflection.clear();
    deflection.extend(torque.iter().zip(params.stiffness()).map(|(t, k)| -t / k));
    Ok(())
}

/// Like [`predict_pose`], with a warm start for the exact model: the
/// equilibrium starts from `warm` (e.g. the solution for nearby parameters)
/// and falls back to the linear model's pose if that fails.
pub fn predict_pose_warm<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    warm: Option<&[f64]>,
) -> Result<Prediction> {
    let mut p = Prediction::default();
    predict_pose_warm_into(mech, pose, params, model, force, warm, &mut p)?;
    Ok(p)
}

/// [`predict_pose_warm`] written into `out`: a warm-started equilibrium
/// keeps `out`'s storage (a fit's evaluations reuse their predictions'
/// vectors; the same numbers). `out` is left unspecified on an error.
#[doc(hidden)] // public for the integration tests only
pub fn predict_pose_warm_into<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    warm: Option<&[f64]>,
    out: &mut Prediction,
) -> Result<()> {
    let f = effective_force(mech, pose, force)?;
    let effective = effective_model(mech.spec(), model, &f);
    if let (Model::Exact, Some(w)) = (effective, warm)
        && exact_into(mech, pose, params, &f, w, out).is_ok()
    {
        return Ok(());
    }
    // The rigid model: forward kinematics from the neighbouring solution.
    if let (Model::Rigid, Some(w)) = (effective, warm)
        && let Ok(p) = rigid_from(mech, pose, params, w)
    {
        *out = p;
        return Ok(());
    }
    *out = predict_pose(mech, pose, params, model, force)?;
    Ok(())
}

/// A warm-started solution farther than this from its start (rad; a length
/// counted at 100 mm per rad, [`crate::engine::kinematics::step_turn`]) is
/// not taken by [`predict_pose_near_into`]: a start that close to the answer
/// (parameters a calibration's error apart, micrometres) moves the joints
/// by far less, and another assembly mode is tenths of a radian away.
pub(crate) const NEAR_TURN: f64 = PLAUSIBLE_MISMATCH;

/// [`predict_pose`] from `start`, joints near the answer (e.g. the true
/// parameters' equilibrium at the same pose where `params` are calibrated
/// ones, or a first-order prediction), written into `out` (whose vectors
/// keep their storage when the start is taken; unspecified on an error):
/// Newton starts there, and its answer is taken when it converged within
/// [`NEAR_TURN`] of it (the same assembly mode); else the prediction is
/// made from the nominal configuration as `predict_pose` makes it.
/// Converged to the same tolerances as `predict_pose`'s; the last bits may
/// differ (another start).
#[doc(hidden)] // public for the integration tests only
pub fn predict_pose_near_into<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    start: &[f64],
    out: &mut Prediction,
) -> Result<()> {
    let f = effective_force(mech, pose, force)?;
    if near_taken(mech, pose, params, model, &f, start, out) {
        return Ok(());
    }
    *out = predict_pose(mech, pose, params, model, force)?;
    Ok(())
}

/// The start of [`predict_pose_near_into`] and [`predict_near`]: the
/// rigid or exact model's prediction from `start` (`f` the load's
/// generalised forces) written into `out`, and whether it is taken:
/// converged within [`NEAR_TURN`] of `start` (the same assembly mode).
fn near_taken<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    f: &[f64],
    start: &[f64],
    out: &mut Prediction,
) -> bool {
    let spec = mech.spec();
    let warm = match effective_model(spec, model, f) {
        Model::Exact => exact_into(mech, pose, params, f, start, out).is_ok(),
        Model::Rigid => rigid_from(mech, pose, params, start)
            .map(|p| *out = p)
            .is_ok(),
        Model::Linear => false,
    };
    warm && out.q.len() == start.len() && {
        let moved = crate::engine::kinematics::turn_of(
            spec,
            out.q.iter().zip(start).map(|(a, b)| a - b).enumerate(),
        );
        moved <= NEAR_TURN
    }
}

/// A prediction for `commands` from a configuration `start` near the
/// answer (the solution at nearby commands or parameters, as a projection
/// or a scan of neighbouring points has it), without the nominal forward
/// kinematics [`predict`] makes first: forward kinematics (the rigid model)
/// or the equilibrium (the exact one) starts at `start`, and its answer is
/// taken when it converged within 0.05 rad of it (a length counted at 100
/// mm per rad: the same assembly mode). `start` is a whole configuration
/// (`mech.spec().joints.len()` values in joint order, e.g. an earlier
/// [`Prediction::q`]); one of another length is not used. Otherwise, and
/// for the linear model or a load, the prediction is made as [`predict`]
/// makes it, with `start` also offered to [`prepare_pose`] as a candidate
/// start. Converged to the same tolerances as `predict`'s; the last bits
/// may differ (another start).
pub fn predict_near<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    model: Model,
    force: &[f64],
    start: &[f64],
) -> Result<Prediction> {
    let spec = mech.spec();
    check_commands(spec, commands)?;
    check_load(spec, force)?;
    if start.len() == spec.joints.len() && force.iter().all(|f| *f == 0.0) {
        // The start stands for the pose's nominal configuration: only the
        // rigid and exact models read it (as their start and, for the
        // exact one, where Newton's curvature is taken).
        let pose = Pose::at(reduced_commands(spec, commands), start.to_vec());
        let f = effective_force(mech, &pose, force)?;
        let mut out = Prediction::default();
        if near_taken(mech, &pose, params, model, &f, start, &mut out) {
            return Ok(out);
        }
    }
    let start = (start.len() == spec.joints.len()).then_some(start);
    let pose = prepare_pose(mech, commands, start)?;
    predict_pose(mech, &pose, params, model, force)
}

/// The generalised forces of the load `force` (a wrench, [`crate::engine::load`])
/// at the pose's nominal configuration.
pub(crate) fn effective_force<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    force: &[f64],
) -> Result<std::borrow::Cow<'static, [f64]>> {
    let spec = mech.spec();
    let nx = spec.tool_axes.len();
    if force.is_empty() || force.iter().all(|f| *f == 0.0) {
        check_load(spec, force)?;
        // (No load: zeros, borrowed where there are few enough, as on
        // every mechanism today: nothing allocated for each prediction.)
        const NO_LOAD: [f64; 8] = [0.0; 8];
        return Ok(match NO_LOAD.get(..nx) {
            Some(zeros) => std::borrow::Cow::Borrowed(zeros),
            None => std::borrow::Cow::Owned(vec![0.0; nx]),
        });
    }
    check_load(spec, force)?;
    let x = jacobians(
        mech,
        &pose.nominal_q,
        &spec.nominal[..spec.n_geometric()],
        0..0,
    )
    .x;
    Ok(std::borrow::Cow::Owned(
        crate::engine::load::generalized_forces(spec.tool_layout, &x, force),
    ))
}

fn check_load(spec: &crate::Spec, force: &[f64]) -> Result<()> {
    let nx = spec.tool_axes.len();
    if force.is_empty() {
        return Ok(());
    }
    if force.len() != nx {
        return Err(Error::Dimension {
            what: "tool force".into(),
            expected: nx,
            got: force.len(),
        });
    }
    if force.iter().any(|f| !f.is_finite()) {
        return Err(Error::InvalidRequest(
            "the tool force must be finite".into(),
        ));
    }
    Ok(())
}

fn linear_prediction<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    force: &[f64],
) -> Result<Prediction> {
    let spec = mech.spec();
    let rho = params.geometric();
    let nominal = &spec.nominal[..spec.n_geometric()];
    // Effective motor-side offset: encoder offset plus command inconsistency.
    let offsets: Vec<f64> = spec
        .actuated
        .iter()
        .enumerate()
        .map(|(a, &j)| params.offsets()[a] + pose.commands[a] - pose.nominal_q[j])
        .collect();
    let drho: Vec<f64> = rho.iter().zip(nominal).map(|(a, b)| a - b).collect();
    let lin = pose.lin(mech)?;
    let p = load_vector(lin, force);
    let dq = joint_errors(lin, params.stiffness(), &offsets, &drho, &p)?;
    let q_u: Vec<f64> = spec
        .independent
        .iter()
        .zip(independent_actuators(spec))
        .map(|(&j, a)| pose.nominal_q[j] + dq[a])
        .collect();
    let q = crate::engine::kinematics::forward_kinematics_from_nominal(
        mech,
        rho,
        &q_u,
        &pose.nominal_q,
    )?;
    let x = jacobians(mech, &q, rho, 0..0).x;
    let torque = crate::engine::linearized::torques(params.stiffness(), &offsets, dq.as_slice());
    let deflection = torque
        .iter()
        .zip(params.stiffness())
        .map(|(t, k)| -t / k)
        .collect();
    Ok(Prediction {
        q,
        x,
        deflection,
        torque,
        iterations: 0,
        multipliers: vec![],
    })
}

/// Convenience: prepare the pose from the reference configuration and predict.
pub fn predict<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    model: Model,
    force: &[f64],
) -> Result<Prediction> {
    let pose = prepare_pose(mech, commands, None)?;
    predict_pose(mech, &pose, params, model, force)
}

use crate::engine::newton;
pub use crate::engine::newton::EQUILIBRIUM_TOL;

/// Exact static equilibrium (docs/model.md §4, the "exact" model): minimise
/// `E(q) = ½ Σ_j k_j (c_j + Δq_j − q_r,j)² + 10⁻³ wᵀ x(q)` subject to
/// `g(q, ρ) = 0`, with `w = −force` the force the actuators deliver at the tool
/// (the paper's `Q + N`). Newton on the KKT system
///
/// ```text
/// [ W   Gᵀ ] [δq]     [ ∇E + Gᵀλ ]
/// [ G   0  ] [δλ] = − [ g        ],   W = SᵀKS + ∇²(λᵀg + 10⁻³ wᵀx)
/// ```
///
/// from `start` (a configuration near the solution, e.g. the linear model's).
/// The curvature `∇²(λᵀg + 10⁻³ wᵀx)` uses per-output Hessians `hessians`
/// (from [`crate::mechanism::autodiff::output_hessians`] at a nearby configuration, e.g.
/// [`Pose::hessians`]; computed at `start` when `None`): their error is of the
/// order of the distance to the solution, so convergence stays quadratic-like
/// in practice while each iteration needs only first derivatives. Its
/// first-order expansion is eq. 11; at the solution `Γᵀτ = P` (eq. 10) holds to
/// machine precision.
pub fn equilibrium<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    force: &[f64],
    start: &[f64],
    hessians: Option<&JointHessians>,
) -> Result<Equilibrium> {
    let (mut q, mut lambda, mut torque) = (vec![], vec![], vec![]);
    let iterations = equilibrium_into(
        mech,
        params,
        commands,
        force,
        start,
        hessians,
        (&mut q, &mut lambda, &mut torque),
    )?;
    Ok(Equilibrium {
        q,
        lambda,
        torque,
        iterations,
    })
}

/// The joints, multipliers and torques an equilibrium is written into.
type EquilibriumOut<'a> = (&'a mut Vec<f64>, &'a mut Vec<f64>, &'a mut Vec<f64>);

/// [`equilibrium`] written into `out` (joints, multipliers, torques; their
/// storage kept, their contents unspecified on an error): its Newton
/// iterations.
fn equilibrium_into<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    force: &[f64],
    start: &[f64],
    hessians: Option<&JointHessians>,
    out: EquilibriumOut<'_>,
) -> Result<usize> {
    let spec = mech.spec();
    check_commands(spec, commands)?;
    // Generalised forces on the tool coordinates ([`crate::engine::load`]).
    check_load(spec, force)?;
    let own;
    let hessians = match hessians {
        Some(h) => h,
        None => {
            own = JointHessians::from_dense(&mech.joint_hessians(start, params.geometric()));
            &own
        }
    };
    // The iteration's buffers live in a per-thread workspace: the hot path
    // allocates nothing but what `out` lacks (a nested call, which nothing
    // makes today, would get buffers of its own).
    EQUILIBRIUM_WORK.with(|cell| match cell.try_borrow_mut() {
        Ok(mut ws) => equilibrium_in(mech, params, commands, force, start, hessians, &mut ws, out),
        Err(_) => equilibrium_in(
            mech,
            params,
            commands,
            force,
            start,
            hessians,
            &mut EquilibriumWork::default(),
            out,
        ),
    })
}

/// The buffers of [`equilibrium`]'s Newton iterations, reused from one call
/// to the next on a thread (Pinocchio's `Data` to the mechanism's `Model`).
#[derive(Default)]
struct EquilibriumWork {
    /// `−force · work_scale`.
    w: Vec<f64>,
    /// Commands plus encoder offsets.
    motor: Vec<f64>,
    /// The KKT matrix, factorised in place.
    kkt: DMatrix<f64>,
    /// Its right-hand side, overwritten by the step.
    step: DMatrix<f64>,
    /// ∇E.
    grad_e: Vec<f64>,
    /// The weights of the output Hessians: `[λ; w]`.
    weights: Vec<f64>,
    /// Derivatives at the current configuration.
    j: Option<crate::mechanism::autodiff::Jacobians>,
    /// `Gᵀ` (where `G Gᵀ` takes it), `G Gᵀ` and `−G ∇E` of the
    /// least-squares multipliers.
    gt: DMatrix<f64>,
    ggt: DMatrix<f64>,
    rhs: DVector<f64>,
    /// The buffers of the KKT solve on the constraints' null space.
    kkt_work: crate::linalg::kkt::KktWork,
    /// The whole KKT matrix's scaled LU factors, kept for the steps after
    /// the one that factored them.
    lu: crate::linalg::solve::ScaledLu,
}

/// The equilibrium's KKT factors are kept for the next step only after a
/// step shorter than this (rad; a length counted at 100 mm per rad,
/// [`crate::engine::kinematics::step_turn`]) that changed no multiplier by
/// more than [`KEPT_FACTORS_MULTIPLIERS`] of the largest: the kept matrix
/// then differs from the next iterate's by little against the stiffness
/// (the multipliers' curvature terms are a few per cent of it on the
/// reference), and the steps shrink about as fast as with fresh factors
/// (measured on the reference's Monte Carlo runs: 0.3 % more iterations,
/// 43 % fewer factorisations; BENCHMARKS.md, issue 52).
const KEPT_FACTORS_TURN: f64 = 1e-2;

/// See [`KEPT_FACTORS_TURN`]: the largest change of the multipliers, as a
/// fraction of the largest multiplier, after which the factors are kept.
const KEPT_FACTORS_MULTIPLIERS: f64 = 0.1;

/// A step computed with kept factors that is not at least this much
/// shorter than the one before has the factors computed afresh at the next
/// iteration.
const KEPT_FACTORS_RATE: f64 = 0.1;

thread_local! {
    /// The joint Hessians of a pose that keeps none ([`Pose::with_hessians`]).
    static TRANSIENT_HESSIANS: std::cell::RefCell<JointHessians> =
        std::cell::RefCell::new(JointHessians::empty());
    static EQUILIBRIUM_WORK: std::cell::RefCell<EquilibriumWork> =
        std::cell::RefCell::new(EquilibriumWork::default());
}

/// Size a matrix to `r × c`, keeping its storage when the shape fits.
fn shape(m: &mut DMatrix<f64>, r: usize, c: usize) {
    if m.shape() != (r, c) {
        *m = DMatrix::zeros(r, c);
    }
}

/// [`equilibrium_into`] in the workspace `ws`.
#[allow(clippy::too_many_arguments)]
fn equilibrium_in<M: Mechanism>(
    mech: &M,
    params: &Params,
    commands: &[f64],
    force: &[f64],
    start: &[f64],
    hessians: &JointHessians,
    ws: &mut EquilibriumWork,
    (q, lambda, torque): EquilibriumOut<'_>,
) -> Result<usize> {
    let spec = mech.spec();
    let nq = spec.joints.len();
    let m = spec.n_constraints;
    let nx = spec.tool_axes.len();
    let rho = params.geometric();
    let k = params.stiffness();
    ws.w.clear();
    if force.is_empty() {
        ws.w.resize(nx, -0.0 * spec.work_scale);
    } else {
        ws.w.extend(force.iter().map(|f| -f * spec.work_scale));
    }
    ws.motor.clear();
    ws.motor
        .extend(commands.iter().zip(params.offsets()).map(|(c, o)| c + o));
    let n = nq + m;
    shape(&mut ws.kkt, n, n);
    shape(&mut ws.step, n, 1);
    ws.grad_e.clear();
    ws.grad_e.resize(nq, 0.0);
    ws.weights.clear();
    ws.weights.resize(m, 0.0);
    ws.weights.extend_from_slice(&ws.w);
    let EquilibriumWork {
        w,
        motor,
        kkt,
        step,
        grad_e,
        weights,
        j,
        gt,
        ggt,
        rhs,
        kkt_work,
        lu,
    } = ws;
    let j = j.get_or_insert_with(crate::mechanism::autodiff::Jacobians::empty);
    // Where the whole system is solved by its scaled LU (the null-space
    // solve does not pay), its factors are kept from one iteration to the
    // next once the iterate moves little (a chord step: the same
    // equations, a step's matrix an earlier iterate's), and computed
    // afresh at the first iteration, after a step longer than
    // [`KEPT_FACTORS_TURN`] or changing the multipliers by more than
    // [`KEPT_FACTORS_MULTIPLIERS`], and after a step that shrank by less
    // than [`KEPT_FACTORS_RATE`].
    let keep = !crate::linalg::kkt::tries_null_space(n, nq, &spec.independent);
    let mut refresh = true;
    let mut last = f64::INFINITY;
    // The joints, the multipliers (estimated at the first iteration) and
    // the step.
    q.clear();
    q.extend_from_slice(start);
    lambda.clear();
    lambda.resize(m, 0.0);
    let mut state = (q, lambda, step);
    let end = newton::run(
        &newton::EQUILIBRIUM,
        &mut state,
        |(q, lam, step), it| -> Result<Option<newton::Step>> {
            jacobians_into(mech, q, rho, 0..nq, j);
            // ∇E = −Sᵀτ + Xqᵀ w.
            grad_e.fill(0.0);
            for (ge, dx) in grad_e
                .iter_mut()
                .zip(j.dx.as_slice().chunks_exact(nx.max(1)))
            {
                *ge = dx.iter().zip(w.iter()).map(|(d, w)| d * w).sum();
            }
            for (a, &jt) in spec.actuated.iter().enumerate() {
                grad_e[jt] -= k[a] * (motor[a] - q[jt]);
            }
            if it == 0 {
                // Least-squares multipliers at the start: Gᵀλ ≈ −∇E (the same
                // products as `&G * Gᵀ` and `G * ∇E`, into the workspace).
                shape(ggt, m, m);
                crate::linalg::gram_into(&j.dg, gt, ggt.as_mut_slice());
                if rhs.len() != m {
                    *rhs = DVector::zeros(m);
                }
                product_into(j.dg.as_slice(), grad_e, rhs.as_mut_slice(), m, nq, 1);
                rhs.neg_mut();
                if crate::linalg::lu::solve_in_place(ggt, rhs.as_mut_slice()) {
                    lam.copy_from_slice(rhs.as_slice());
                }
            }
            let fresh = !keep || refresh;
            if fresh {
                // W = SᵀKS + Σ λ_k ∇²g_k + Σ w_i ∇²x_i, then the constraint blocks.
                weights[..m].copy_from_slice(lam);
                kkt.as_mut_slice().fill(0.0);
                hessians.add_weighted(weights, kkt.as_mut_slice(), n);
                for (a, &jt) in spec.actuated.iter().enumerate() {
                    kkt[(jt, jt)] += k[a];
                }
                for c in 0..nq {
                    for r in 0..m {
                        kkt[(nq + r, c)] = j.dg[(r, c)];
                        kkt[(c, nq + r)] = j.dg[(r, c)];
                    }
                }
            }
            step.as_mut_slice().fill(0.0);
            debug_assert!(hessians.is_empty() || hessians.joints() == nq);
            for ((st, ge), dg) in step
                .iter_mut()
                .zip(grad_e.iter())
                .zip(j.dg.as_slice().chunks_exact(m.max(1)))
            {
                let t: f64 = dg.iter().zip(lam.iter()).map(|(d, l)| d * l).sum();
                *st = ge + t;
            }
            for (r, g) in j.g.iter().enumerate() {
                step[nq + r] = *g;
            }
            let solved = if !keep {
                crate::linalg::kkt::solve_kkt_in_place(kkt, step, nq, &spec.independent, kkt_work)
            } else if fresh && !lu.factor(kkt.as_slice(), n) {
                false
            } else {
                lu.solve(step.as_mut_slice());
                true
            };
            if !solved {
                return Err(Error::Singular {
                    q: q.to_vec(),
                    reason: "the equilibrium (KKT) system is singular".into(),
                });
            }
            let big = step.as_slice()[..nq]
                .iter()
                .fold(0.0f64, |m, v| m.max(v.abs()));
            if !big.is_finite() {
                return Ok(None);
            }
            // At most 0.2 rad, or 20 mm on a length, per iteration.
            let turn = crate::engine::kinematics::step_turn(spec, 0..nq, step.as_slice());
            let largest = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            refresh = turn > KEPT_FACTORS_TURN
                || largest(&step.as_slice()[nq..]) > KEPT_FACTORS_MULTIPLIERS * largest(lam)
                || big > KEPT_FACTORS_RATE * last;
            last = big;
            Ok(Some(newton::Step { size: big, turn }))
        },
        |(q, lam, step), scale| {
            for i in 0..nq {
                q[i] -= scale * step[i];
            }
            for (r, l) in lam.iter_mut().enumerate() {
                *l -= step[nq + r] * scale;
            }
        },
    )?;
    if let newton::End::Converged(iterations) = end {
        let (q, _, _) = state;
        torque.clear();
        torque.extend(
            spec.actuated
                .iter()
                .enumerate()
                .map(|(a, &jt)| k[a] * (motor[a] - q[jt])),
        );
        return Ok(iterations);
    }
    Err(Error::NoConvergence {
        what: "static equilibrium".into(),
        reason: format!(
            "Newton on the KKT system did not converge from {start:?}; the commands may be far from consistent with the geometry or near a singularity"
        ),
    })
}
