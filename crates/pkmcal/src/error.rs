//! Errors for bad input and impossible requests. Each message says what to do.

use thiserror::Error;

/// Everything that can go wrong in the library. Disappointing results (no
/// convergence of a fit, rank deficiency) are *not* errors: they are reported in
/// the result with a reason.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    /// A parameter name that the mechanism does not know.
    #[error("unknown parameter `{name}`; known parameters are: {known}")]
    UnknownParameter { name: String, known: String },

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

/// Result type of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Where a pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
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
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub distance: bool,
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
