//! The Newton policy every nonlinear solve of the engine follows: how far
//! one step may go, when a solve has converged, how many iterations it may
//! take, and when a solve whose iterations ran out is still accepted. Each
//! loop (loop closure, inverse kinematics, a spatial leg's inverse
//! kinematics, the exact equilibrium, trilateration) is [`run`] with its
//! [`Policy`] and a closure that computes its own step, so that one reading
//! of "converged" holds everywhere (docs/model.md, "Numerical policy").
//!
//! Two Gauss–Newton loops keep their own shape: the Gough–Stewart
//! platform's guess refinement (a step is kept only while the commands'
//! mismatch shrinks) and `commands_configuration` (each step halved while
//! its pose is out of reach): neither has a step tolerance to converge to.

/// Newton has converged when its largest joint step falls below this (rad,
/// or mm on a length joint): a few ulps of the joint values.
pub const STEP_TOL: f64 = 1e-13;

/// The final stage of an inverse-kinematics continuation, and a spatial
/// leg's own inverse kinematics, stop at this step (rad or mm): the square
/// systems there mix the tool's and the joints' scales.
pub const IK_STEP_TOL: f64 = 10.0 * STEP_TOL;

/// Newton has also converged once its step is below this and stopped
/// shrinking (rounding has taken over; rad or mm).
pub const STALL_TOL: f64 = 1e-9;

/// A loop closure whose iterations ran out is still accepted when every
/// constraint residual is below this times the square of the largest
/// parameter magnitude (the constraints are squared lengths, mm²).
pub const CLOSURE_RESIDUAL_TOL: f64 = 1e-8;

/// A spatial leg's inverse kinematics whose iterations ran out is accepted
/// when its residual is below this times the largest parameter magnitude
/// (its equations are lengths, mm).
pub const LEG_RESIDUAL_TOL: f64 = 1e-9;

/// Most iterations of one loop-closure or inverse-kinematics solve.
pub const MAX_ITERATIONS: usize = 40;

/// Most iterations of a spatial leg's inverse kinematics (its start, the
/// reference configuration, may be far from the target).
pub const MAX_LEG_ITERATIONS: usize = 50;

/// Most iterations of the exact equilibrium (it starts within the linear
/// model's distance of its answer).
pub const MAX_EQUILIBRIUM_ITERATIONS: usize = 30;

/// The equilibrium has converged when its largest joint step falls below
/// this (rad, or mm).
pub const EQUILIBRIUM_TOL: f64 = 1e-14;

/// The equilibrium has also converged once its step is below this and
/// stopped shrinking (rad or mm).
pub const EQUILIBRIUM_STALL_TOL: f64 = 1e-10;

/// The largest step (rad; a length counted at
/// [`crate::engine::kinematics::step_turn`]'s 100 mm per rad) that loop
/// closure and inverse kinematics take at once.
pub const MAX_TURN: f64 = 0.5;

/// The largest step the exact equilibrium takes at once (rad, lengths as
/// for [`MAX_TURN`]): its Hessians are those of a nearby configuration, so
/// it moves more cautiously.
pub const MAX_EQUILIBRIUM_TURN: f64 = 0.2;

/// Most iterations of a ball-bar trilateration.
pub const MAX_TRILATERATION_ITERATIONS: usize = 50;

/// A trilateration has converged when its largest coordinate step falls
/// below this (mm).
pub const TRILATERATION_TOL: f64 = 1e-12;

/// Singular values below this times the largest are dropped from a
/// least-squares step (the linearised trilateration's start and its Gauss–
/// Newton steps): the sockets' geometry decides the rank, not rounding.
pub const LSTSQ_RCOND: f64 = 1e-12;

/// The factor that limits a Newton step whose largest joint step is `turn`
/// (rad-equivalent) to `max_turn`: 1 for a short step; 0 for a step that
/// is not finite (the caller then stops on the step's own test).
pub fn damping(turn: f64, max_turn: f64) -> f64 {
    if !turn.is_finite() {
        0.0
    } else if turn > max_turn {
        max_turn / turn
    } else {
        1.0
    }
}

/// How a Newton loop judges that the step it has just taken converged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Convergence {
    /// The step is below [`Policy::step_tol`], or below
    /// [`Policy::stall_tol`] and no shorter than the step before.
    Step,
    /// As [`Convergence::Step`], and also when the rate `r` (the step over
    /// the one before, 1 at the first) is below ½ and predicts an error
    /// `r × step` below [`Policy::step_tol`] after it; a first step below
    /// [`Policy::stall_tol`] counts as stalled. For a solve that starts
    /// within a short distance of its answer (the exact equilibrium).
    Rate,
}

/// The limits of one Newton loop: everything but its residual and step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Policy {
    /// Most iterations.
    pub max_iterations: usize,
    /// The loop has converged when its step falls below this (rad or mm).
    pub step_tol: f64,
    /// It has also converged once its step is below this and stopped
    /// shrinking (0: never).
    pub stall_tol: f64,
    /// How convergence is judged.
    pub convergence: Convergence,
    /// The largest turn one step takes (rad-equivalent, as the loop's
    /// closure measures it); a longer step is scaled down to it.
    pub max_turn: f64,
    /// A loop whose iterations ran out is still accepted when its residual
    /// is below this times the scale of its equations
    /// ([`Policy::residual_limit`]); 0 when it never is.
    pub residual_tol: f64,
}

/// Loop closure: forward kinematics, the reference configuration.
pub const CLOSURE: Policy = Policy {
    max_iterations: MAX_ITERATIONS,
    step_tol: STEP_TOL,
    stall_tol: STALL_TOL,
    convergence: Convergence::Step,
    max_turn: MAX_TURN,
    residual_tol: CLOSURE_RESIDUAL_TOL,
};

/// The last stage of inverse kinematics by continuation (the intermediate
/// stages stop at a coarser step).
pub const INVERSE_KINEMATICS: Policy = Policy {
    max_iterations: MAX_ITERATIONS,
    step_tol: IK_STEP_TOL,
    stall_tol: 0.0,
    convergence: Convergence::Step,
    max_turn: MAX_TURN,
    residual_tol: 0.0,
};

/// A spatial leg's own inverse kinematics.
pub const LEG: Policy = Policy {
    max_iterations: MAX_LEG_ITERATIONS,
    step_tol: IK_STEP_TOL,
    stall_tol: 0.0,
    convergence: Convergence::Step,
    max_turn: MAX_TURN,
    residual_tol: LEG_RESIDUAL_TOL,
};

/// The exact equilibrium.
pub const EQUILIBRIUM: Policy = Policy {
    max_iterations: MAX_EQUILIBRIUM_ITERATIONS,
    step_tol: EQUILIBRIUM_TOL,
    stall_tol: EQUILIBRIUM_STALL_TOL,
    convergence: Convergence::Rate,
    max_turn: MAX_EQUILIBRIUM_TURN,
    residual_tol: 0.0,
};

/// Ball-bar trilateration: Gauss–Newton on coordinates in mm, undamped.
pub const TRILATERATION: Policy = Policy {
    max_iterations: MAX_TRILATERATION_ITERATIONS,
    step_tol: TRILATERATION_TOL,
    stall_tol: 0.0,
    convergence: Convergence::Step,
    max_turn: f64::INFINITY,
    residual_tol: 0.0,
};

impl Policy {
    /// Whether a step of size `size` (after one of size `last`, infinite at
    /// the first) has converged.
    pub fn converged(&self, size: f64, last: f64) -> bool {
        match self.convergence {
            Convergence::Step => size < self.step_tol || (size < self.stall_tol && size >= last),
            Convergence::Rate => {
                let rate = if last.is_finite() { size / last } else { 1.0 };
                size < self.step_tol
                    || (rate < 0.5 && rate * size < self.step_tol)
                    || (size < self.stall_tol && rate >= 1.0)
            }
        }
    }

    /// The largest residual accepted when the iterations ran out, for
    /// equations whose scale is `scale` (a length: the largest parameter
    /// magnitude, [`parameter_scale`]).
    pub fn residual_limit(&self, scale: f64) -> f64 {
        self.residual_tol * scale
    }
}

/// The scale of a mechanism's lengths for [`Policy::residual_limit`]: its
/// largest parameter magnitude, at least 1.
pub fn parameter_scale(rho: &[f64]) -> f64 {
    rho.iter().fold(1.0f64, |m, v| m.max(v.abs()))
}

/// One Newton step as a loop's closure computed it, measured its own way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// Its size, compared with the tolerances.
    pub size: f64,
    /// Its largest turn (rad-equivalent), compared with
    /// [`Policy::max_turn`].
    pub turn: f64,
}

/// How a Newton loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// Converged after this many iterations.
    Converged(usize),
    /// The iterations ran out.
    Exhausted,
    /// The closure found its step unusable (not finite) and stopped.
    Unusable,
}

/// The Newton loop: up to [`Policy::max_iterations`] times, `step`
/// computes the next step from `state` (its size and turn, the step itself
/// kept in `state`; `None` when it is unusable, which ends the loop, an
/// error when the system is singular), then `take` moves `state` by the
/// step times the damping factor ([`damping`] of its turn), then the step
/// is judged ([`Policy::converged`]). `step` is told the iteration (from
/// 0). Nothing is allocated here: the loops keep their buffers in `state`
/// or in what the closures hold.
pub fn run<S, E>(
    policy: &Policy,
    state: &mut S,
    mut step: impl FnMut(&mut S, usize) -> Result<Option<Step>, E>,
    mut take: impl FnMut(&mut S, f64),
) -> Result<End, E> {
    let mut last = f64::INFINITY;
    for it in 0..policy.max_iterations {
        let Some(s) = step(state, it)? else {
            return Ok(End::Unusable);
        };
        take(state, damping(s.turn, policy.max_turn));
        if policy.converged(s.size, last) {
            return Ok(End::Converged(it + 1));
        }
        last = s.size;
    }
    Ok(End::Exhausted)
}
