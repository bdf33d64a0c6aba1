//! The Newton policy every nonlinear solve of the engine follows: how far
//! one step may go, when a solve has converged, how many iterations it may
//! take. Each loop (loop closure, inverse kinematics, a spatial leg's
//! inverse kinematics, the exact equilibrium, trilateration) takes its
//! limits from here, so that one reading of "converged" holds everywhere
//! (docs/model.md, "Numerical policy").

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
