//! What a calibration returns: the identified parameters with their
//! uncertainty, typed warnings, and the calibration itself.

use super::identifiability::{Correlation, Identifiability};
use super::loss::{Loss, Outlier};
use super::problem::CachedPredictions;
use super::uncertainty::ParameterCovariance;
use crate::engine::models::{Model, Pose};
use crate::error::Origin;
use crate::identify::noise::NoiseGroup;
use crate::lm::Termination;
use crate::mechanism::Params;
use crate::units::{ParamKind, Unit};
use nalgebra::DMatrix;
use serde::Serialize;
use std::sync::Arc;

/// One row of the parameter table.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct ParameterResult {
    /// Name.
    pub name: String,
    /// Unit of the values (declared by the mechanism).
    pub unit: Unit,
    /// Role of the parameter (geometry, encoder offset, stiffness, instrument).
    pub kind: ParamKind,
    /// Nominal value.
    pub nominal: f64,
    /// Identified value (the starting value if fixed).
    pub identified: f64,
    /// Identified minus nominal.
    pub change: f64,
    /// Standard deviation (0 when fixed).
    pub std_dev: f64,
    /// Whether it was identified.
    pub free: bool,
    /// Why it is fixed, when it was requested free.
    pub note: Option<String>,
    /// Its tolerance (one standard deviation of its prior), when it had one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    /// The share of its posterior information that came from the data,
    /// `1 − σ_post²/σ_prior²` ([`super::prior::information_from_data`]),
    /// when it had a prior and was free.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub from_data: Option<f64>,
}

/// What a warning is about, with its data: the CLI and other callers match on
/// the kind, never on the message.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum WarningKind {
    /// All stiffness parameters were free without an external load: only
    /// their ratios are identifiable, so `fixed` was fixed.
    StiffnessRatios {
        /// The stiffness fixed.
        fixed: String,
    },
    /// A direction of parameter space that the data cannot see.
    Unidentifiable {
        /// Model used.
        model: Model,
        /// The combination, e.g. `0.71·l11 − 0.71·B1x`.
        combination: String,
        /// The parameter fixed to remove it, if any.
        fixed: Option<String>,
    },
    /// The instrument frame is identified and, with it, parameters that
    /// also place the mechanism in space (e.g. base joint centres): the
    /// directions that only move everything together are unidentifiable, and
    /// `fixed` were fixed to remove them (they then define the base frame).
    FrameGauge {
        /// Model used.
        model: Model,
        /// The parameters fixed, one per direction.
        fixed: Vec<String>,
        /// Directions that no parameter could remove (none when fixing).
        unfixed: usize,
    },
    /// The fit did not converge.
    NotConverged {
        /// The solver's reason.
        reason: String,
    },
    /// The Jacobian at the solution is rank deficient.
    RankDeficient {
        /// Its rank.
        rank: usize,
        /// Free parameters.
        free: usize,
    },
    /// A measurement plan's poses determine fewer parameter directions than
    /// there are free parameters.
    PlanRankDeficient {
        /// Poses planned.
        poses: usize,
        /// Directions they determine.
        rank: usize,
        /// Free parameters.
        free: usize,
    },
    /// Poses with residuals beyond the outlier threshold at the final fit.
    Outliers {
        /// Where they came from.
        poses: Vec<Origin>,
        /// The threshold (robust standard deviations).
        threshold: f64,
        /// Whether a robust loss was in use.
        robust_loss: bool,
        /// Whether dropping was requested (and stopped at the cap).
        dropping: bool,
    },
    /// Poses dropped as outliers before the final fit.
    Dropped {
        /// Where they came from.
        poses: Vec<Origin>,
    },
    /// An identified value more than [`super::prior::BEYOND_TOLERANCES`]
    /// of its tolerances from its prior's centre.
    BeyondTolerance {
        /// The parameter.
        name: String,
        /// Its identified value.
        value: f64,
        /// Its prior's centre (nominal, or the instrument's start).
        centre: f64,
        /// Its tolerance (σ).
        tolerance: f64,
        /// Its unit.
        unit: Unit,
        /// Whether its own prior is in conflict with the data
        /// ([`WarningKind::PriorConflict`]).
        #[serde(default)]
        conflict: bool,
        /// Otherwise, the prior whose conflict most likely explains it: the
        /// one whose release, with the others in conflict, brings it back
        /// within its tolerances.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        explained_by: Option<String>,
        /// Its value with the priors in conflict released.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        released: Option<f64>,
    },
    /// Priors the data push against ([`super::prior::prior_conflicts`]):
    /// each released in turn, most significant first, while its release
    /// lowers the fit's χ² beyond chance (Holm at
    /// [`super::prior::CONFLICT_ALPHA`]).
    PriorConflict {
        /// The priors in conflict, most significant first.
        conflicts: Vec<super::prior::PriorConflict>,
    },
    /// Parameters whose posterior σ is above [`super::prior::TAUGHT_LITTLE`]
    /// of their prior σ: the data taught little about them, their values
    /// are mostly the tolerances' assumption.
    PriorDominated {
        /// The parameters, with the share of their information from the data.
        parameters: Vec<(String, f64)>,
    },
    /// The residuals are well below the stated noise (or the σ given in the
    /// data), two-sided χ² test ([`super::adequacy`]): the noise is
    /// overstated, and every uncertainty with it.
    NoiseOverstated {
        /// Unit of the readings tested.
        unit: Unit,
        /// Their axes (empty with `given`: all readings).
        #[serde(default)]
        axes: Vec<String>,
        /// Their σ as the residuals give it (with `given`: the standard
        /// deviation of unit weight).
        found: f64,
        /// The stated σ (with `given`: 1).
        stated: f64,
        /// Whether the σ tested were given in the data.
        given: bool,
        /// The lower tail's p-value.
        p: f64,
    },
    /// The residuals exceed the stated noise (or the σ given in the data),
    /// and no parameter left out of the fit explains them: the misfit is
    /// spread like noise, so the noise is understated (or the model misses
    /// an effect none of its parameters describes).
    NoiseUnderstated {
        /// Unit of the readings tested.
        unit: Unit,
        /// Their axes (empty with `given`: all readings).
        #[serde(default)]
        axes: Vec<String>,
        /// Their σ as the residuals give it (with `given`: the standard
        /// deviation of unit weight).
        found: f64,
        /// The stated σ (with `given`: 1).
        stated: f64,
        /// Whether the σ tested were given in the data.
        given: bool,
        /// The upper tail's p-value.
        p: f64,
    },
    /// The residuals exceed what the instrument's noise explains and
    /// parameters left out of the fit explain them ([`super::adequacy`]):
    /// the model misses something.
    ModelInadequate {
        /// Unit of the readings tested.
        unit: Unit,
        /// Their axes (`distance` for distances between poses; empty with
        /// `given`: all readings).
        #[serde(default)]
        axes: Vec<String>,
        /// Their σ as the residuals give it (with `given`: the standard
        /// deviation of unit weight).
        found: f64,
        /// The instrument's stated σ (with `given`: 1).
        stated: f64,
        /// Whether the σ tested were given in the data.
        given: bool,
        /// The χ² test's p-value.
        p: f64,
        /// Parameters left out of the fit that the score test singles out,
        /// with the share of the weighted sum of squares each would remove
        /// (after those before it).
        suspects: Vec<(String, f64)>,
    },
    /// Directions the data alone cannot see, held by the parameters'
    /// tolerances (the fit keeps them near their prior's centre).
    HeldByTolerance {
        /// Model used.
        model: Model,
        /// The combinations.
        combinations: Vec<String>,
    },
}

/// A warning: its kind (with data), what happened and what to do.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct Warning {
    /// What it is about.
    #[serde(flatten)]
    pub kind: WarningKind,
    /// What happened.
    pub message: String,
    /// What to do.
    pub hint: String,
}

fn pose_list(poses: &[Origin]) -> String {
    poses
        .iter()
        .map(Origin::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The residuals' σ against the noise they were tested with, in words.
fn residuals_against(
    found: f64,
    stated: f64,
    unit: Unit,
    axes: &[String],
    given: bool,
    verb: &str,
) -> String {
    if given {
        format!("the residuals are {found:.2} times the σ given in the data")
    } else {
        format!(
            "the residuals' σ of {found:.3e} {unit} ({} readings) {verb} the stated {stated:.3e} {unit}",
            axes.join(", ")
        )
    }
}

/// The family a warning belongs to, for front ends that sort warnings into
/// their own categories (Python's warning classes) without knowing each
/// kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WarningCategory {
    /// The fit did not converge.
    Convergence,
    /// Outlying poses, reported or dropped.
    Outliers,
    /// What the data show against what the tolerances assumed.
    Tolerance,
    /// The model or the noise against the residuals.
    Model,
    /// What the data can and cannot identify.
    Identifiability,
}

impl WarningKind {
    /// The kind's name, as written in reports (`model_inadequate`).
    pub fn name(&self) -> &'static str {
        match self {
            WarningKind::StiffnessRatios { .. } => "stiffness_ratios",
            WarningKind::Unidentifiable { .. } => "unidentifiable",
            WarningKind::FrameGauge { .. } => "frame_gauge",
            WarningKind::NotConverged { .. } => "not_converged",
            WarningKind::RankDeficient { .. } => "rank_deficient",
            WarningKind::PlanRankDeficient { .. } => "plan_rank_deficient",
            WarningKind::Outliers { .. } => "outliers",
            WarningKind::Dropped { .. } => "dropped",
            WarningKind::BeyondTolerance { .. } => "beyond_tolerance",
            WarningKind::PriorDominated { .. } => "prior_dominated",
            WarningKind::PriorConflict { .. } => "prior_conflict",
            WarningKind::NoiseOverstated { .. } => "noise_overstated",
            WarningKind::NoiseUnderstated { .. } => "noise_understated",
            WarningKind::ModelInadequate { .. } => "model_inadequate",
            WarningKind::HeldByTolerance { .. } => "held_by_tolerance",
        }
    }

    /// The family the kind belongs to.
    pub fn category(&self) -> WarningCategory {
        match self {
            WarningKind::NotConverged { .. } => WarningCategory::Convergence,
            WarningKind::Outliers { .. } | WarningKind::Dropped { .. } => WarningCategory::Outliers,
            WarningKind::BeyondTolerance { .. }
            | WarningKind::PriorDominated { .. }
            | WarningKind::PriorConflict { .. } => WarningCategory::Tolerance,
            WarningKind::NoiseOverstated { .. }
            | WarningKind::NoiseUnderstated { .. }
            | WarningKind::ModelInadequate { .. } => WarningCategory::Model,
            WarningKind::StiffnessRatios { .. }
            | WarningKind::HeldByTolerance { .. }
            | WarningKind::Unidentifiable { .. }
            | WarningKind::FrameGauge { .. }
            | WarningKind::RankDeficient { .. }
            | WarningKind::PlanRankDeficient { .. } => WarningCategory::Identifiability,
        }
    }
}

impl Warning {
    /// The warning of `kind`, with its message and hint.
    pub fn new(kind: WarningKind) -> Self {
        let (message, hint) = match &kind {
            WarningKind::StiffnessRatios { fixed } => (
                format!(
                    "all stiffness parameters are free without an external load: only their ratios are identifiable, so `{fixed}` is fixed at its starting value"
                ),
                format!(
                    "give `{fixed}` its measured value as the start, or calibrate with a known tool load"
                ),
            ),
            WarningKind::Unidentifiable {
                model,
                combination,
                fixed,
            } => (
                match fixed {
                    Some(f) => format!(
                        "unidentifiable with the {} model: {combination} (fixed `{f}` at its starting value)",
                        model.name()
                    ),
                    None => format!("unidentifiable with the {} model: {combination}", model.name()),
                },
                "these parameters cannot be separated by these measurements at these poses; fix one of them, or add poses or measurements that see them".into(),
            ),
            WarningKind::FrameGauge {
                model,
                fixed,
                unfixed,
            } => (
                format!(
                    "the instrument frame is identified together with parameters that also place the mechanism: {} both together and {} unidentifiable with the {} model{}",
                    crate::error::count(fixed.len() + unfixed, "direction moves", "directions move"),
                    if fixed.len() + unfixed == 1 { "is" } else { "are" },
                    model.name(),
                    if fixed.is_empty() {
                        String::new()
                    } else {
                        format!(
                            "; fixed {} at {} (now defining the base frame)",
                            fixed
                                .iter()
                                .map(|f| format!("`{f}`"))
                                .collect::<Vec<_>>()
                                .join(", "),
                            if fixed.len() == 1 {
                                "its starting value"
                            } else {
                                "their starting values"
                            }
                        )
                    }
                ),
                "to choose which parameters define the base frame, fix them yourself, or measure in the base frame; the combinations are listed under identifiability".into(),
            ),
            WarningKind::NotConverged { reason } => (
                format!("the fit did not converge: {reason}"),
                "check the data for outliers or wrong columns, or start closer".into(),
            ),
            WarningKind::RankDeficient { rank, free } => (
                format!(
                    "the Jacobian at the solution has rank {rank} for {free} free parameters; their uncertainties are not defined"
                ),
                "fix parameters named in the identifiability report".into(),
            ),
            WarningKind::PlanRankDeficient { poses, rank, free } => (
                format!(
                    "the {poses} planned poses determine only {rank} of the {free} free parameters' directions: the others cannot be identified from them"
                ),
                "plan more poses, or identify fewer parameters (an analysis names the combinations that cannot be identified)".into(),
            ),
            WarningKind::Outliers {
                poses,
                threshold,
                robust_loss,
                dropping,
            } => (
                format!(
                    "{} with residuals beyond {threshold} robust standard deviations: {}",
                    crate::error::count(poses.len(), "pose", "poses"),
                    pose_list(poses)
                ),
                if *dropping {
                    "the drop limit (20 % of the poses) is reached; inspect these measurements".into()
                } else if *robust_loss {
                    "the robust loss already limits their influence; inspect them, or refit without them (dropping outliers)".into()
                } else {
                    "inspect them; a robust loss (huber, cauchy) limits their influence, dropping refits without them".into()
                },
            ),
            WarningKind::BeyondTolerance {
                name,
                value,
                centre,
                tolerance,
                unit,
                conflict,
                explained_by,
                released,
            } => {
                // Digits down to a tenth of the tolerance.
                let d = (1.0 - tolerance.log10().floor()).clamp(0.0, 12.0) as usize;
                let far = format!(
                    "`{name}` = {value:.d$} {unit} is {:.1} tolerances (σ = {tolerance} {unit}) from {centre:.d$} {unit}",
                    (value - centre).abs() / tolerance
                );
                match (conflict, explained_by) {
                    (true, _) => (
                        format!("{far}: its tolerance is in conflict with the data"),
                        format!(
                            "check `{name}`'s drawing value (or the part: moved, worn, assembled otherwise); correct it, or widen its tolerance"
                        ),
                    ),
                    (false, Some(cause)) => (
                        format!(
                            "{far}, most likely through `{cause}`'s tolerance in conflict{}",
                            released.map_or_else(String::new, |r| format!(
                                ": with the tolerances in conflict released it is {r:.d$} {unit}"
                            ))
                        ),
                        format!(
                            "check `{cause}` rather than `{name}`: `{name}` absorbs an error of `{cause}`, which its tolerance holds too tightly"
                        ),
                    ),
                    (false, None) => (
                        far,
                        format!(
                            "a value this far from what was known usually means a wrong nominal value or tolerance, a unit error, or `{name}` absorbing an error the model does not have; check the drawing and the data"
                        ),
                    ),
                }
            }
            WarningKind::PriorConflict { conflicts } => (
                format!(
                    "the data push against {} (χ² drop when each is released, then the value the data choose): {}",
                    crate::error::count(conflicts.len(), "tolerance", "tolerances"),
                    conflicts
                        .iter()
                        .map(|c| {
                            let d = (1.0 - c.tolerance.log10().floor()).clamp(0.0, 12.0) as usize;
                            format!(
                                "`{}` {:.1}, p = {:.1e}, {}",
                                c.name,
                                c.statistic,
                                c.p_value,
                                match (c.data_value, c.data_sd) {
                                    (Some(v), Some(sd)) => {
                                        format!("{v:.d$} ± {sd:.d$} {}", c.unit)
                                    }
                                    _ => "not seen".into(),
                                }
                            )
                        })
                        .collect::<Vec<_>>()
                        .join("; ")
                ),
                "check these drawing values (or the parts: a joint moved, a leg zeroed otherwise) and correct them, or widen their tolerances; the values near them absorb what these tolerances hold back".into(),
            ),
            WarningKind::PriorDominated { parameters } => (
                format!(
                    "the data taught little about {}: {} mostly what {} assumed ({})",
                    crate::error::count(parameters.len(), "parameter", "parameters"),
                    if parameters.len() == 1 { "its value is" } else { "their values are" },
                    if parameters.len() == 1 { "its tolerance" } else { "their tolerances" },
                    parameters
                        .iter()
                        .map(|(n, f)| format!("`{n}` {:.0} % from the data", 100.0 * f))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                "measure poses or quantities that see them (a plan with these priors chooses such poses), or accept the tolerance as their uncertainty".into(),
            ),
            WarningKind::NoiseOverstated {
                unit,
                axes,
                found,
                stated,
                given,
                p,
            } => (
                format!(
                    "{} (χ² test, lower tail p = {p:.1e}): the {} noise is larger than the data show",
                    residuals_against(*found, *stated, *unit, axes, *given, "is below"),
                    if *given { "given" } else { "stated" }
                ),
                "every uncertainty is as much too large; state the noise the data show (the instrument may be better than its datasheet, or its readings averaged), or let it be estimated from the residuals".into(),
            ),
            WarningKind::NoiseUnderstated {
                unit,
                axes,
                found,
                stated,
                given,
                p,
            } => (
                format!(
                    "{} (χ² test, p = {p:.1e}), and no parameter left out of the fit explains it: the {} noise is smaller than the data show",
                    residuals_against(*found, *stated, *unit, axes, *given, "exceeds"),
                    if *given { "given" } else { "stated" }
                ),
                "every uncertainty is as much too small; check the stated noise against the conditions of the measurement (distance, temperature, averaging), or let it be estimated; if it is right, the model misses an effect none of its parameters describes (thermal drift, backlash, a loose instrument)".into(),
            ),
            WarningKind::ModelInadequate {
                unit,
                axes,
                found,
                stated,
                given,
                p,
                suspects,
            } => (
                format!(
                    "{} (χ² test, p = {p:.1e}): the model misses something; freeing {} would remove the share of the misfit given: {}",
                    residuals_against(*found, *stated, *unit, axes, *given, "exceeds"),
                    if suspects.len() == 1 { "this parameter" } else { "these parameters" },
                    suspects
                        .iter()
                        .map(|(n, s)| format!("`{n}` ({:.0} %)", 100.0 * s))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                "free the parameters named and calibrate again, or look for the effect they stand for (a tilt, an offset the model fixes)".into(),
            ),
            WarningKind::HeldByTolerance {
                model,
                combinations,
            } => (
                format!(
                    "the data alone cannot see {} with the {} model, held by the tolerances: {}",
                    crate::error::count(combinations.len(), "direction", "directions"),
                    model.name(),
                    combinations.join("; ")
                ),
                "these values stay near their prior's centre, within their tolerances; measure what sees them to identify them".into(),
            ),
            WarningKind::Dropped { poses } => (
                format!(
                    "{} dropped before the final fit: {}",
                    crate::error::count(poses.len(), "outlier pose", "outlier poses"),
                    pose_list(poses)
                ),
                "check those measurements (a misread, a bumped instrument) before trusting the result".into(),
            ),
        };
        Self {
            kind,
            message,
            hint,
        }
    }
}

/// Everything a calibration produces. Its `Serialize` writes what a report
/// shows (the vectors and matrices below marked so are left out);
/// [`full`] writes and reads all of it.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct Calibration {
    /// Model used.
    pub model: Model,
    /// Identified parameters of the mechanism (full vector).
    #[serde(skip, default = "Params::empty")]
    pub params: Params,
    /// Identified (or given) pose of the instrument frame in the base frame
    /// ([`crate::measurement::frame`]); `None` when the data are in the base frame. Also
    /// in `parameters`, kind `instrument`.
    pub frame: Option<Vec<f64>>,
    /// Identified (or given) values of all the measurement model's
    /// parameters ([`MeasurementModel::param_names`]), the frame's last.
    #[serde(skip)]
    pub measurement: Vec<f64>,
    /// Why the solver stopped.
    pub termination: Termination,
    /// Readable reason.
    pub termination_reason: String,
    /// Whether it converged.
    pub converged: bool,
    /// Solver iterations (of the final fit).
    pub iterations: usize,
    /// Residual evaluations (of the final fit).
    pub evaluations: usize,
    /// Number of poses (rows read by the instrument).
    pub poses: usize,
    /// Number of distances measured between two poses.
    pub distances: usize,
    /// Sum of squared standardised residuals `Σ (r/σ)²` at the solution.
    pub sum_of_squares: f64,
    /// The readings' standard deviation of unit weight
    /// `√(Σ (r/σ)² / Σ (1 − h))` over the readings alone, `h` their
    /// leverages in the fit with its priors (dimensionless): about 1 when
    /// the noise levels are right (1 by construction where σ was estimated
    /// without a stated noise).
    pub unit_weight_sigma: f64,
    /// How the uncertainties are scaled ([`super::uncertainty::Scale`]):
    /// absolute for σ known, Student's t with its degrees of freedom for σ
    /// estimated.
    #[serde(default)]
    pub scale: super::uncertainty::Scale,
    /// The readings' redundancy `Σ (1 − h)`, their leverages `h` in the fit
    /// with its priors: the degrees of freedom of their residuals.
    #[serde(default)]
    pub redundancy: f64,
    /// The model-adequacy tests ([`super::adequacy`]): each group of
    /// readings against its stated σ, or all against the σ given.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub adequacy: Vec<super::adequacy::AdequacyTest>,
    /// Noise of each group of like coordinates: estimated from the residuals
    /// or given in the data.
    pub noise: Vec<NoiseGroup>,
    /// Parameter table.
    pub parameters: Vec<ParameterResult>,
    /// Identifiability (at the starting parameters, or where the actuators
    /// fight when stiffness is free; see [`calibrate`]).
    pub identifiability: Identifiability,
    /// Covariance of the free parameters, `(J̃ᵀW̃J̃)⁻¹` at the final σ (the
    /// scale rule, [`super::uncertainty::Scale`]), in `free` order.
    #[serde(skip, default = "empty_matrix")]
    pub covariance: DMatrix<f64>,
    /// Free parameter indices actually identified.
    #[serde(skip)]
    pub free: Vec<usize>,
    /// The covariance with parameter names (serialised as `covariance`).
    #[serde(rename = "covariance")]
    pub parameter_covariance: ParameterCovariance,
    /// Correlations above 0.9 at the solution.
    pub correlations: Vec<Correlation>,
    /// Loss used.
    pub loss: Loss,
    /// Poses with residuals beyond the outlier threshold: those dropped (with
    /// their residual when they were dropped), then those left in the final
    /// fit.
    pub outliers: Vec<Outlier>,
    /// Poses dropped as outliers before the final fit.
    pub dropped: Vec<Origin>,
    /// Residuals at the solution, predicted minus measured, pose-major (each
    /// in its axis's unit).
    #[serde(skip)]
    pub residuals: Vec<f64>,
    /// Standard deviation each residual was weighted with (same order).
    #[serde(skip)]
    pub sigmas: Vec<f64>,
    /// Weighted Jacobian of the free parameters at the solution.
    #[serde(skip, default = "empty_matrix")]
    pub jacobian: DMatrix<f64>,
    /// Warnings.
    pub warnings: Vec<Warning>,
    /// The priors the fit used (docs/model.md eq. 13), in the order of their
    /// rows after the readings'.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub priors: Vec<super::prior::PriorTerm>,
    /// The priors the data push against, most significant first
    /// ([`super::prior::prior_conflicts`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prior_conflicts: Vec<super::prior::PriorConflict>,
    /// The fit's predictions at the identified parameters, when its last
    /// evaluation was there: [`calibration_accuracy_with_cache`] then
    /// computes them no second time.
    #[serde(skip)]
    pub(crate) final_predictions: Option<FinalPredictions>,
}

/// A calibration's predictions at its identified parameters and what they
/// were computed for: the prepared poses (shared through a [`PoseCache`]),
/// the model and the load.
#[derive(Debug, Clone)]
pub(crate) struct FinalPredictions {
    pub(super) poses: Vec<Arc<Pose>>,
    pub(super) model: Model,
    pub(super) force: Vec<f64>,
    pub(super) predictions: CachedPredictions,
}

fn empty_matrix() -> DMatrix<f64> {
    DMatrix::zeros(0, 0)
}

/// A matrix as plain data: its shape and its entries column by column.
#[derive(Serialize, serde::Deserialize)]
struct MatrixData {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

impl From<&DMatrix<f64>> for MatrixData {
    fn from(m: &DMatrix<f64>) -> Self {
        MatrixData {
            rows: m.nrows(),
            cols: m.ncols(),
            data: m.as_slice().to_vec(),
        }
    }
}

/// A whole [`Calibration`] as data, for `#[serde(with = "full")]`: what a
/// report shows plus the identified vector, the measurement model's values,
/// the covariance, the free indices, the residuals, their σ and the
/// weighted Jacobian, so that a calibration read back is the one written
/// (only the cache of its last predictions is left out).
pub mod full {
    use super::{Calibration, MatrixData};
    use crate::mechanism::Params;
    use nalgebra::DMatrix;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize)]
    struct Written<'a> {
        report: &'a Calibration,
        params: &'a Params,
        measurement: &'a [f64],
        covariance: MatrixData,
        free: &'a [usize],
        residuals: &'a [f64],
        sigmas: &'a [f64],
        jacobian: MatrixData,
    }

    #[derive(Deserialize)]
    struct Read {
        report: Calibration,
        params: Params,
        measurement: Vec<f64>,
        covariance: MatrixData,
        free: Vec<usize>,
        residuals: Vec<f64>,
        sigmas: Vec<f64>,
        jacobian: MatrixData,
    }

    fn matrix<E: serde::de::Error>(m: MatrixData) -> Result<DMatrix<f64>, E> {
        if m.rows.checked_mul(m.cols) != Some(m.data.len()) {
            return Err(E::custom(format!(
                "a {}×{} matrix needs {} entries, not {}",
                m.rows,
                m.cols,
                m.rows.saturating_mul(m.cols),
                m.data.len()
            )));
        }
        Ok(DMatrix::from_vec(m.rows, m.cols, m.data))
    }

    /// Write every part of `c`.
    pub fn serialize<S: Serializer>(c: &Calibration, s: S) -> Result<S::Ok, S::Error> {
        Written {
            report: c,
            params: &c.params,
            measurement: &c.measurement,
            covariance: (&c.covariance).into(),
            free: &c.free,
            residuals: &c.residuals,
            sigmas: &c.sigmas,
            jacobian: (&c.jacobian).into(),
        }
        .serialize(s)
    }

    /// Read what [`serialize`] wrote.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Calibration, D::Error> {
        let r = Read::deserialize(d)?;
        let mut c = r.report;
        c.params = r.params;
        c.measurement = r.measurement;
        c.covariance = matrix(r.covariance)?;
        c.free = r.free;
        c.residuals = r.residuals;
        c.sigmas = r.sigmas;
        c.jacobian = matrix(r.jacobian)?;
        Ok(c)
    }
}
