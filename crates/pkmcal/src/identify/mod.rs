//! Identification (docs/model.md eq. 12): the least-squares problem, its
//! identifiability, noise groups and weights, gross errors, robust losses
//! and outliers, the fit, uncertainty and validation.

pub mod adequacy;
pub mod drift;
pub mod driver;
pub mod gross;
pub mod identifiability;
pub mod loss;
pub mod noise;
pub mod prior;
pub mod problem;
pub mod record;
pub mod request;
pub mod result;
pub mod stats;
pub mod study;
pub mod uncertainty;
pub mod validation;
pub mod weights;

pub use adequacy::{
    ADEQUACY_ALPHA, AdequacyTest, OMITTED_ALPHA, OmittedTest, SUSPECT_ALPHA, SUSPECT_SHARE,
    SUSPECTS, omitted_test,
};
pub use drift::{Compared, DEFAULT_ALPHA, Drift, ParameterDrift, drift, noise_dof};
pub use driver::{
    AnalysisOptions, CalibrationOptions, DEFAULT_STATED_NOISE_READINGS, MAX_DROPPED_FRACTION,
    analyze, analyze_cancellable, analyze_with_priors, calibrate, calibrate_with_cache,
};
pub use gross::{GROSS_EXTENT_SHARE, GROSS_FACTOR, MIN_SIGMA};
pub(crate) use identifiability::observability;
pub use identifiability::{
    CORRELATION_REPORT, Columns, Correlation, Identifiability, Observability, RANK_TOL,
    Unidentifiable, ZERO_COLUMN, analyze_identifiability,
};
pub use loss::{Loss, OUTLIER_FLOOR_MM, OUTLIER_FLOOR_RAD, Outlier};
pub use prior::{
    BEYOND_TOLERANCES, CONFLICT_ALPHA, CONSTRAINT_RELATIVE, Prior, PriorConflict, PriorTerm,
    SEEN_SHARE, TAUGHT_LITTLE, free_with_priors, information_from_data, is_constraint,
    named_priors, prior_conflicts,
};
pub use problem::{IdentificationProblem, MAX_POSES, PoseCache, too_many_poses};
pub use record::{
    CALIBRATION_FORMAT, CALIBRATION_VERSION, COVARIANCE_SYMMETRY, CalibrationRecord, RecordError,
    RecordedNoise, RecordedParameter, mechanism_identities, mechanism_identity,
};
pub use request::{FrameChoice, Request, SolverRequest};
pub use result::{Calibration, ParameterResult, Warning, WarningCategory, WarningKind};
pub use study::{
    FreeSetError, NameList, Study, StudyError, StudyOptions, StudyStage, StudyValidation,
    ValidationPlan, ValidationSource, named_bounds, resolve_free_set, study,
};
pub use uncertainty::{ParameterCovariance, Scale, predict_with_uncertainty, tool_covariance};
pub use validation::{
    Accuracy, CrossValidation, DistanceAccuracy, ErrorVectors, accuracy, calibration_accuracy,
    calibration_accuracy_with_cache, cross_validate, cross_validate_with_progress, holdout_split,
};
