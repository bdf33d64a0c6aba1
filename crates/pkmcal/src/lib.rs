//! # pkmcal
//!
//! Kinematic calibration of parallel mechanisms, first of all redundantly
//! actuated ones, after Jeong & Kim (*Kinematic Calibration Method for
//! Redundantly Actuated Parallel Mechanisms*). The crate knows no files: a
//! mechanism is plain data plus loop-closure and tool functions ([`Mechanism`]);
//! algorithms are free functions.
//!
//! Where each relation of docs/model.md lives:
//!
//! | relation | function |
//! |---|---|
//! | eq. 3 loop closure, tool map | [`Mechanism::constraints`], [`Mechanism::tool`] |
//! | eq. 4 derivatives | [`mechanism::autodiff::jacobians`] |
//! | eq. 5–7, 9: Φ, J_p, Γ, H, J_f | [`linearize`] |
//! | eq. 10 load `P` | [`load_vector`] |
//! | eq. 11 Λ and joint errors | [`projection`], [`joint_errors`] |
//! | eq. 2 torques | [`engine::linearized::torques`] |
//! | exact equilibrium | [`equilibrium`] |
//! | three forward models | [`predict_pose`], [`Model`] |
//!
//! ```
//! use pkmcal::{JeongKim2Dof, Mechanism, Model, Params, inverse_kinematics, predict};
//! let mech = JeongKim2Dof::new();
//! let spec = mech.spec();
//! let nominal = Params::nominal(spec);
//! let q = inverse_kinematics(&mech, nominal.geometric(), &[-30.0, 165.0]).unwrap();
//! let commands: Vec<f64> = spec.actuated.iter().map(|&j| q[j]).collect();
//! // A 0.1 mm longer link 1 and a 1 mrad offset on actuator 3.
//! let truth = Params::from_named(spec, [("l11", 280.1), ("dq3", 1e-3)]).unwrap();
//! let p = predict(&mech, &truth, &commands, Model::Exact, &[]).unwrap();
//! assert!((p.x[0] + 30.0).abs() < 1.0 && (p.x[1] - 165.0).abs() < 1.0);
//! assert!(p.torque.iter().any(|t| t.abs() > 1.0)); // the actuators fight
//! ```

pub mod apply;
pub mod engine;
pub mod error;
pub mod identify;
pub mod kinds;
pub mod linalg;
pub mod lm;
pub mod measurement;
pub mod mechanism;
pub mod units;

pub use apply::compensation::{
    Compensation, CompensationOptions, CorrectionGrid, GridAxis, InterpolationError, Predistortion,
    compensate, compensate_rows, controller_commands, correction_grid,
    correction_grid_with_progress, interpolation_error, predistort,
};
pub use apply::montecarlo::{
    MonteCarloOptions, MonteCarloSummary, monte_carlo, validation_targets,
};
pub use apply::planning::{
    Plan, PlanCriterion, PlanOptions, candidate_jacobians, plan, plan_observability, plan_poses,
    plan_poses_with_progress,
};
pub use apply::rows::{RowBuffers, RowPrediction, RowSettings, predict_rows, predict_rows_into};
pub use apply::simulate::{
    simulate, simulate_cancellable, simulate_distances, simulate_with_progress,
};
pub use apply::workspace::{
    MAX_TARGETS, WorkspacePoint, grid_targets, nominal_commands, random_targets, sample_workspace,
    spread_targets,
};
pub use engine::kinematics::{
    check_params, forward_kinematics, inverse_kinematics, reference_configuration, solve_closure,
};
pub use engine::linearized::{
    Linearization, joint_errors, linearize, load_vector, projection, tool_derivatives,
};
pub use engine::models::{
    Equilibrium, Model, Pose, Prediction, equilibrium, predict, predict_near, predict_pose,
    predict_pose_warm, prepare_pose,
};
pub use error::{Error, Field, Origin, RequestError, Result, Suggestion};
pub use identify::noise::{NoiseGroup, VarianceRatio, variance_ratio};
pub use identify::stats::{ErrorStats, error_stats, improvement_percent};
pub use identify::{
    Accuracy, Calibration, CalibrationOptions, DistanceAccuracy, Identifiability, Loss, Outlier,
    ParameterCovariance, PoseCache, accuracy, analyze, calibrate, calibrate_with_cache,
    calibration_accuracy, calibration_accuracy_with_cache, cross_validate,
    cross_validate_with_progress, holdout_split, predict_with_uncertainty, tool_covariance,
};
pub use identify::{FrameChoice, Request};
pub use kinds::any::AnyMechanism;
pub use kinds::gough_stewart::{GoughStewart, GoughStewartAssembly, GoughStewartDescription};
pub use kinds::planar::{PlanarDescription, PlanarLinkage};
pub use kinds::reference::JeongKim2Dof;
pub use kinds::spatial::{SpatialDescription, SpatialMechanism};
pub use measurement::ballbar::{Setup, trilaterate};
pub use measurement::data::{Measurement, Noise};
pub use measurement::{
    DISTANCE_AXIS, Frame, FrameRequest, FrameRequestError, Instrument, MeasurementModel,
    MeasurementSummary, requested_frame,
};
pub use mechanism::tool::ToolLayout;
pub use mechanism::{
    AxisInfo, JointInfo, MAX_JOINTS, MAX_LEGS, Mechanism, MechanismSummary, ParameterInfo, Params,
    Renamed, Scalar, Spec, summary,
};
pub use units::{AngleUnit, FileUnits, LengthUnit, ParamKind, PartialUnits, Quantity, Role, Unit};

/// Runs `f` on a thread of rayon's pool (at once when called from one):
/// work that evaluates poses in parallel many times over (a calibration:
/// each evaluation of the fit is a parallel section) then starts each
/// section on a worker, which takes its share at once, instead of on a
/// thread outside the pool, which hands the whole section over and sleeps
/// until it is done. Measured in BENCHMARKS.md (issue 12).
pub(crate) fn on_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        f()
    } else {
        rayon::scope(|_| f())
    }
}

thread_local! {
    /// Whether the parallel loops over a calibration's poses run on the
    /// calling thread alone ([`serially`]).
    static SERIAL: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs `f` with the loops over a calibration's poses on the calling thread
/// ([`pose_chunk`]): for work that is itself one of many parallel tasks (a
/// run of a Monte Carlo study), where splitting each evaluation's 35 poses
/// over the pool costs more than it shares. The results are the same: the
/// loops assemble their poses in order either way.
pub(crate) fn serially<R>(f: impl FnOnce() -> R) -> R {
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            SERIAL.with(|s| s.set(self.0));
        }
    }
    let _restore = Restore(SERIAL.with(|s| s.replace(true)));
    f()
}

/// The fewest poses one task of a parallel loop over a calibration's poses
/// takes (rayon's `with_min_len`): all of them under [`serially`], else 1.
pub(crate) fn pose_chunk() -> usize {
    if SERIAL.with(std::cell::Cell::get) {
        usize::MAX
    } else {
        1
    }
}
