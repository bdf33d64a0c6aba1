//! Errors for bad input and impossible requests. Each message says what to do.

use thiserror::Error;

/// Everything that can go wrong in the library. Disappointing results (no
/// convergence of a fit, rank deficiency) are *not* errors: they are reported in
/// the result with a reason.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    /// A parameter name that the mechanism does not know, with the nearest
    /// known one when it is a likely typo.
    #[error("unknown parameter `{name}`{}; known parameters are: {known}", suggestion.as_ref().map(|s| format!(" (did you mean `{s}`?)")).unwrap_or_default())]
    UnknownParameter {
        name: String,
        known: String,
        suggestion: Option<String>,
    },

    /// A parameter value that is not allowed (non-finite, non-positive stiffness…).
    #[error("invalid value {value:?} for parameter `{name}`: {reason}")]
    InvalidParameter {
        name: String,
        value: f64,
        reason: String,
    },

    /// A vector or matrix of the wrong size.
    #[error("{what}: expected {expected} values, got {got}")]
    Dimension {
        what: String,
        expected: usize,
        got: usize,
    },

    /// A target tool position outside the reachable workspace.
    #[error("target {target:?} is not reachable: {reason}; choose a target inside the workspace")]
    Unreachable { target: Vec<f64>, reason: String },

    /// A configuration where the loop closure cannot be solved for the dependent
    /// joints (or the equilibrium is degenerate).
    #[error(
        "singular configuration at joints {q:?}: {reason}; move the pose away from the singularity"
    )]
    Singular { q: Vec<f64>, reason: String },

    /// Forward kinematics reached a configuration on another assembly branch
    /// (or with a leg in another working mode) than the reference
    /// configuration's.
    #[error(
        "the commands put the mechanism on another assembly branch (joints {q:?}): {reason}; check the commands, or move the pose away from the singularity between the branches"
    )]
    OtherBranch { q: Vec<f64>, reason: String },

    /// The loop closure has no solution for these actuator values (the legs cannot
    /// be assembled) or Newton did not converge.
    #[error("{what} did not converge: {reason}")]
    NoConvergence { what: String, reason: String },

    /// A mechanism description that is inconsistent.
    #[error("invalid mechanism: {0}")]
    InvalidMechanism(String),

    /// A request the data cannot support (too few poses, nothing free…).
    #[error("{0}")]
    InvalidRequest(String),

    /// A user's choice refused, naming the choice.
    #[error(transparent)]
    Request(#[from] RequestError),

    /// A number outside the range where it means something (a σ of 0, a
    /// weight that overflows): which input, as the library names it
    /// (`noise.length`, `tolerance of l11`), its value and the range.
    #[error("{field} = {value:e} is out of range: {expected}")]
    OutOfRange {
        /// The input, as the library names it.
        field: String,
        /// Its value.
        value: f64,
        /// What it must be.
        expected: String,
    },

    /// The caller's cancel flag was set (a front end's Ctrl-C): the work
    /// stopped before it finished, and nothing it computed is returned.
    #[error("cancelled by the caller")]
    Cancelled,

    /// Something went wrong at one measured pose: which pose (data-file
    /// numbering when the data carry it), its line, and what.
    #[error("{} {pose}{}: {source}", if *distance { "distance" } else { "pose" }, line.map(|l| format!(" (line {l})")).unwrap_or_default())]
    Pose {
        /// Pose number (1-based).
        pose: usize,
        /// Line in the data file, when known.
        line: Option<u64>,
        /// Whether the row is a distance between two poses (`pose` is then
        /// its number among the distances).
        distance: bool,
        /// What went wrong there.
        source: Box<Error>,
    },
}

impl Error {
    /// This error located at a measured pose.
    pub fn at_pose(self, origin: crate::error::Origin) -> Error {
        match self {
            e @ Error::Pose { .. } => e,
            e => Error::Pose {
                pose: origin.pose,
                line: origin.line,
                distance: origin.distance,
                source: Box::new(e),
            },
        }
    }
}

/// A choice a user makes through a front end, by what it means. The library
/// and the file side name the choice a refusal is about with it; each front
/// end names it in its own words (the command line `--free`, Python
/// `free=`), so that no message below them names an option.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[non_exhaustive]
pub enum Field {
    /// The mechanism description.
    Mechanism,
    /// The measurements.
    Data,
    /// The forward model.
    Model,
    /// The parameters to identify.
    Free,
    /// The parameters kept fixed.
    Fix,
    /// Tolerances given as priors.
    Tolerances,
    /// No priors at all.
    NoTolerances,
    /// Starting parameter values.
    Start,
    /// Parameter values to evaluate at.
    Params,
    /// The tool load (a wrench).
    Load,
    /// Internal actuator loads to hold.
    Preload,
    /// The robust loss.
    Loss,
    /// The robust loss's tuning constant.
    LossScale,
    /// The outlier threshold.
    OutlierThreshold,
    /// Validation poses measured apart.
    Validation,
    /// The fraction of poses held out.
    Holdout,
    /// k-fold cross-validation.
    Kfold,
    /// A random seed.
    Seed,
    /// Where the instrument stands.
    Frame,
    /// The tool axes the instrument read.
    Axes,
    /// A ball bar's setup.
    Setup,
    /// Distances measured between poses.
    Distances,
    /// The instrument's stated noise (lengths).
    StatedNoise,
    /// The instrument's stated noise (angles).
    StatedAngleNoise,
    /// The stated noise of the distances between poses.
    StatedDistanceNoise,
    /// What a stated noise is worth, in readings.
    StatedReadings,
    /// Only the stated noises' ratios are known.
    StatedRelative,
    /// An instrument's noise on lengths (simulated, or weighed against
    /// tolerances).
    Noise,
    /// An instrument's noise on angles.
    AngleNoise,
    /// The solver's evaluation budget.
    MaxEvaluations,
    /// The solver's tolerance on the sum of squares.
    Ftol,
    /// The solver's tolerance on the step.
    Xtol,
    /// The solver's tolerance on the gradient.
    Gtol,
    /// Bounds on parameters.
    Bounds,
    /// Starting values of the free parameters as a vector.
    X0,
    /// How many poses to plan.
    Count,
    /// The spacing of candidate poses.
    Candidates,
    /// The most candidate poses.
    MaxCandidates,
    /// Simulated runs.
    Runs,
    /// Random errors on lengths (simulated truths).
    LengthError,
    /// Random errors on angles (simulated truths).
    AngleError,
    /// Unseen validation targets of a simulation.
    ValidationTargets,
    /// Machines drawn by Monte Carlo.
    Samples,
    /// Workspace targets.
    Targets,
    /// A false-alarm rate.
    Alpha,
    /// The units of data files.
    Units,
    /// The size limit of files read whole.
    MaxInputSize,
    /// How readings of two instruments are weighed against each other.
    Weighting,
    /// A shift between programmed and tool coordinates (G-code).
    Offset,
    /// The longest segment of a rewritten move (G-code).
    MaxSegment,
    /// The firmware whose reading of G-code is followed.
    Dialect,
    /// A correction table's grid.
    Grid,
    /// An output file or directory.
    Out,
    /// What a firmware's letters mean where its version changed them
    /// (Marlin's `M665 B`).
    FirmwareLetters,
    /// A probe's offset from the nozzle.
    ProbeOffset,
    /// The radius a firmware's own calibration probed at (Marlin's G33).
    G33Radius,
    /// The probe points of a firmware's own calibration (Marlin's G33 `P`).
    G33Points,
    /// A printer fitted as built (the physical delta model), not as its
    /// firmware describes it.
    Physical,
    /// A height map in the firmware's own format.
    HeightMap,
    /// The nodes across a height map.
    MeshPoints,
    /// A report's directory.
    ReportDir,
    /// A directory of the firmware's model as pkmcal files.
    OutDir,
    /// A printer's previous calibration, to compare with.
    Previous,
    /// The probe's noise, stated by its user.
    ProbeNoise,
    /// Heights measured by hand (a nozzle's or probe's touches).
    Heights,
    /// A firmware's probe readings (RepRapFirmware's probe file, Marlin's
    /// console log).
    Probes,
    /// The largest σ of a written value before a warning.
    MaxSigma,
}

impl Field {
    /// The choice in plain words (for a message no front end has worded).
    pub fn describe(self) -> &'static str {
        use Field::*;
        match self {
            Mechanism => "the mechanism",
            Data => "the data",
            Model => "the model",
            Free => "the free parameters",
            Fix => "the fixed parameters",
            Tolerances => "the tolerances",
            NoTolerances => "no tolerances",
            Start => "the start values",
            Params => "the parameter values",
            Load => "the tool load",
            Preload => "the preload",
            Loss => "the loss",
            LossScale => "the loss scale",
            OutlierThreshold => "the outlier threshold",
            Validation => "the validation poses",
            Holdout => "the hold-out fraction",
            Kfold => "the cross-validation folds",
            Seed => "the seed",
            Frame => "the instrument frame",
            Axes => "the measured axes",
            Setup => "the ball-bar setup",
            Distances => "the distances between poses",
            StatedNoise => "the stated noise",
            StatedAngleNoise => "the stated angle noise",
            StatedDistanceNoise => "the stated distance noise",
            StatedReadings => "the stated noise's worth in readings",
            StatedRelative => "stated ratios only",
            Noise => "the noise",
            AngleNoise => "the angle noise",
            MaxEvaluations => "the evaluation budget",
            Ftol => "ftol",
            Xtol => "xtol",
            Gtol => "gtol",
            Bounds => "the bounds",
            X0 => "the start vector",
            Count => "the pose count",
            Candidates => "the candidate spacing",
            MaxCandidates => "the most candidates",
            Runs => "the runs",
            LengthError => "the length error",
            AngleError => "the angle error",
            ValidationTargets => "the validation targets",
            Samples => "the samples",
            Targets => "the targets",
            Alpha => "the false-alarm rate",
            Units => "the units",
            MaxInputSize => "the input size limit",
            Weighting => "the weighting",
            Offset => "the offset",
            MaxSegment => "the segment length",
            Dialect => "the G-code dialect",
            Grid => "the grid",
            Out => "the output",
            FirmwareLetters => "the meaning of the firmware's letters",
            ProbeOffset => "the probe's offset from the nozzle",
            G33Radius => "G33's calibration radius",
            G33Points => "G33's probe points",
            Physical => "the physical model",
            HeightMap => "the height map",
            MeshPoints => "the height map's nodes",
            ReportDir => "the report's directory",
            OutDir => "the output directory",
            Previous => "the previous calibration",
            ProbeNoise => "the probe's noise",
            Heights => "the heights measured by hand",
            Probes => "the probe readings",
            MaxSigma => "the largest σ before a warning",
        }
    }
}

impl std::fmt::Display for Field {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.describe())
    }
}

/// A value to give a choice instead, which a front end words as its own
/// option (`--free default,bed.rx`) or keyword (`free="default,bed.rx"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Suggestion {
    /// The choice.
    pub field: Field,
    /// The value, as a user types it.
    pub value: String,
}

/// A user's choice refused, typed so that each front end names the choice in
/// its own terms. Every rule of what a user may ask is checked once, in the
/// library ([`crate::identify::request`]).
#[derive(Debug, Clone, PartialEq, Error)]
pub enum RequestError {
    /// One choice refused: what is wrong with it, and what to give instead
    /// where one value would do.
    #[error("{field}: {problem}{}", suggest.as_ref().map(|s| format!(" (try {} = {})", s.field, s.value)).unwrap_or_default())]
    Invalid {
        /// The choice.
        field: Field,
        /// What is wrong, and what to do, in words that name no option.
        problem: String,
        /// A value to give instead (of this choice or another).
        suggest: Option<Suggestion>,
    },
    /// Two choices that exclude each other.
    #[error("give either {a} or {b}, not both")]
    Exclusive {
        /// One.
        a: Field,
        /// The other.
        b: Field,
    },
    /// A choice that needs another one.
    #[error("{field} needs {needs}")]
    Needs {
        /// The choice given.
        field: Field,
        /// The choice it needs.
        needs: Field,
    },
    /// An entry of the mechanism description's `[tolerances]` table (a
    /// file's error, not a choice: the front end names the file).
    #[error("in the [tolerances] table: {0}")]
    ToleranceTable(String),
    /// A choice that only means something with another: what it does
    /// (`why`, in words that name no option), and the choice to add.
    #[error("{field} {why}: add {needs}")]
    Belongs {
        /// The choice given.
        field: Field,
        /// The choice it belongs to.
        needs: Field,
        /// What the choice does, which the other one makes possible.
        why: &'static str,
    },
    /// A choice that another one leaves no place for: what it does, and
    /// the choice it is to be left out with.
    #[error("{field} {why}; leave it out with {with}")]
    Excluded {
        /// The choice given.
        field: Field,
        /// The choice that excludes it.
        with: Field,
        /// What the choice does, which the other one has no use for.
        why: &'static str,
    },
}

impl RequestError {
    /// `field` refused for `problem`.
    pub fn invalid(field: Field, problem: impl Into<String>) -> Self {
        RequestError::Invalid {
            field,
            problem: problem.into(),
            suggest: None,
        }
    }

    /// The choice this error is about first.
    pub fn field(&self) -> Option<Field> {
        match self {
            RequestError::Invalid { field, .. }
            | RequestError::Needs { field, .. }
            | RequestError::Belongs { field, .. }
            | RequestError::Excluded { field, .. } => Some(*field),
            RequestError::Exclusive { a, .. } => Some(*a),
            RequestError::ToleranceTable(_) => None,
        }
    }
}

/// Result type of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Where a pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct Origin {
    /// The pose's number as its front end numbers its users' rows: the
    /// command-line tool by file order from 1 (with the file `line`), the
    /// Python package by array row from 0; the same way for poses and
    /// distances.
    pub pose: usize,
    /// Line in the data file.
    pub line: Option<u64>,
    /// Whether the row is a distance between two poses
    /// ([`Measurement::partner`]); `pose` is then its number among the
    /// distances (their own file's numbering in the command-line tool).
    #[serde(skip_serializing_if = "std::ops::Not::not", default)]
    pub distance: bool,
}

impl Origin {
    /// Row `k` (from 0) of a list the library was given (targets,
    /// commands), without a file line.
    pub fn row(k: usize) -> Self {
        Origin {
            pose: k,
            line: None,
            distance: false,
        }
    }
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = if self.distance { "distance" } else { "pose" };
        write!(f, "{what} {}", self.pose)?;
        if let Some(l) = self.line {
            write!(f, " (line {l})")?;
        }
        Ok(())
    }
}

/// The edit (Levenshtein) distance between two names, in characters.
pub fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// The known name nearest `name` when it is a likely typo: at most a third
/// of its length away (at least one edit), ignoring case, and the only one
/// that near.
pub fn did_you_mean<'a>(name: &str, known: impl IntoIterator<Item = &'a str>) -> Option<String> {
    let lower = name.to_lowercase();
    let limit = (name.chars().count() / 3).max(1);
    let mut best: Option<(usize, &str, bool)> = None;
    for k in known {
        let d = edit_distance(&lower, &k.to_lowercase());
        match best {
            Some((b, _, _)) if d > b => {}
            Some((b, _, _)) if d == b => best = best.map(|(b, n, _)| (b, n, true)),
            _ => best = Some((d, k, false)),
        }
    }
    match best {
        Some((d, k, false)) if d <= limit && k != name => Some(k.to_string()),
        _ => None,
    }
}

/// `Err(Error::Cancelled)` once `cancel` is set: the check long computations
/// make between their steps (runs, candidates, evaluations).
pub fn check_cancel(cancel: Option<&std::sync::atomic::AtomicBool>) -> Result<()> {
    match cancel {
        Some(c) if c.load(std::sync::atomic::Ordering::Relaxed) => Err(Error::Cancelled),
        _ => Ok(()),
    }
}

/// `n` and the noun in its number, for messages: "1 pose", "35 poses".
pub fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// A number a user typed, for messages: as written for ordinary
/// magnitudes (`0.05`, `280`), in exponent form beyond them (`1e308`,
/// `1e-200`), so that no message prints 300 digits.
pub fn shown(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 || !v.is_finite() || (1e-4..1e7).contains(&a) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}
