//! A calibration as it is kept: the versioned record every front end saves
//! (the command line's `--report`, Python's `Calibration.save`) and reads
//! back (`predict --uncertainty`, `pkmcal.load_calibration`), with the
//! identity of the mechanism it is of, so that a calibration is never
//! applied to another mechanism. Plain data; the file side writes and reads
//! it as JSON.

use super::uncertainty::ParameterCovariance;
use crate::error::Error;
use crate::mechanism::{Params, Spec};
use serde::{Deserialize, Serialize};

/// The `format` of a calibration record.
pub const CALIBRATION_FORMAT: &str = "pkmcal calibration";
/// The newest record version this build writes and reads. Version 1 is
/// the first with a format and an identity; a record without them (a report
/// written before) is read as version 0, checked by parameter names only.
pub const CALIBRATION_VERSION: u32 = 1;

/// What tells one mechanism from another for a calibration: a 64-bit
/// FNV-1a hash (written here: a fixed, documented function of a few
/// hundred bytes, stable across builds and platforms, which `std`'s hasher
/// is not) of its joints, actuators, parameters (names, units, nominal
/// values to the bit) and tool axes. The name, the workspace box, the
/// default free set and the assembly configuration do not count: renaming a
/// mechanism keeps its calibrations, changing a nominal length does not.
pub fn mechanism_identity(spec: &Spec) -> String {
    identity_with_names(spec, &spec.param_names())
}

/// Every identity a record of the mechanism may carry: its
/// [`mechanism_identity`] first, then, when parameters were renamed
/// ([`Spec::renamed`]), the identity under their old names (a record saved
/// before the renaming).
pub fn mechanism_identities(spec: &Spec) -> Vec<String> {
    let mut out = vec![mechanism_identity(spec)];
    if !spec.renamed.is_empty() {
        out.push(identity_with_names(spec, &spec.param_names_before()));
    }
    out
}

/// [`mechanism_identity`] with the parameters named `names`.
fn identity_with_names(spec: &Spec, names: &[&str]) -> String {
    let mut text = String::new();
    let mut list = |tag: &str, items: &mut dyn Iterator<Item = String>| {
        text.push_str(tag);
        for i in items {
            text.push('\u{1f}');
            text.push_str(&i);
        }
        text.push('\u{1e}');
    };
    list("joints", &mut spec.joints.iter().cloned());
    list("actuated", &mut spec.actuated.iter().map(|a| a.to_string()));
    list(
        "parameters",
        &mut names.iter().enumerate().map(|(i, n)| {
            format!(
                "{n}:{}:{:016x}",
                spec.param_unit(i),
                spec.nominal[i].to_bits()
            )
        }),
    );
    list(
        "tool",
        &mut spec
            .tool_axes
            .iter()
            .zip(&spec.tool_units)
            .map(|(a, u)| format!("{a}:{u}")),
    );
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let hash = text
        .bytes()
        .fold(OFFSET, |h, b| (h ^ u64::from(b)).wrapping_mul(PRIME));
    format!("fnv1a64:{hash:016x}")
}

/// One parameter's identified value, as a record keeps it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordedParameter {
    /// Name.
    pub name: String,
    /// Identified value (the starting value if fixed).
    pub identified: f64,
}

/// The header and the parts of a calibration record a calibration is used
/// by: its parameters and their covariance. (A full record, a calibration
/// report, holds more: accuracy, identifiability, validation; they are read
/// past.)
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// [`CALIBRATION_FORMAT`]; empty in a record written before versions.
    #[serde(default)]
    pub format: String,
    /// The record's version; 0 for one written before versions.
    #[serde(default)]
    pub version: u32,
    /// The mechanism's name.
    pub mechanism: String,
    /// [`mechanism_identity`] of the mechanism calibrated; empty before
    /// version 1.
    #[serde(default)]
    pub mechanism_identity: String,
    /// The model the parameters were identified with.
    pub model: crate::engine::models::Model,
    /// Every parameter of the mechanism and the instrument.
    pub parameters: Vec<RecordedParameter>,
    /// The covariance of the identified parameters.
    pub covariance: ParameterCovariance,
    /// The priors the calibration was fitted with (a report's `priors`):
    /// the drift test compares what the data added to them. Empty in a
    /// record written before priors, or without them.
    #[serde(default)]
    pub priors: Vec<super::prior::PriorTerm>,
    /// How its uncertainties were scaled (a report's `scale`): the degrees
    /// of freedom of an estimated σ. `None` in a record written before.
    #[serde(default)]
    pub scale: Option<super::uncertainty::Scale>,
}

/// Why a calibration record cannot serve a mechanism. Typed, so that each
/// front end says what to give instead.
#[derive(Debug, Clone, PartialEq)]
pub enum RecordError {
    /// Not a calibration record (another `format`).
    Format(String),
    /// Written by a newer pkmcal.
    Version {
        /// The record's version.
        found: u32,
    },
    /// A calibration of another mechanism.
    OtherMechanism {
        /// The name the record gives.
        name: String,
    },
    /// Its parameters or covariance do not fit the mechanism.
    Invalid(Error),
}

impl std::fmt::Display for RecordError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RecordError::Format(found) => write!(
                f,
                "its format is `{found}`, not `{CALIBRATION_FORMAT}`; it is no calibration record"
            ),
            RecordError::Version { found } => write!(
                f,
                "it is a calibration record of version {found}, newer than this pkmcal reads ({CALIBRATION_VERSION}); update pkmcal"
            ),
            RecordError::OtherMechanism { name } => write!(
                f,
                "it is a calibration of another mechanism ({name}: other joints, parameters, nominal values or tool axes)"
            ),
            RecordError::Invalid(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RecordError {}

impl CalibrationRecord {
    /// The record of a calibration of the mechanism `spec`.
    pub fn new(spec: &Spec, cal: &super::result::Calibration) -> Self {
        CalibrationRecord {
            format: CALIBRATION_FORMAT.into(),
            version: CALIBRATION_VERSION,
            mechanism: spec.name.clone(),
            mechanism_identity: mechanism_identity(spec),
            model: cal.model,
            parameters: cal
                .parameters
                .iter()
                .map(|p| RecordedParameter {
                    name: p.name.clone(),
                    identified: p.identified,
                })
                .collect(),
            covariance: cal.parameter_covariance.clone(),
            priors: cal.priors.clone(),
            scale: Some(cal.scale),
        }
    }

    /// Check that the record can serve the mechanism `spec`: its format, a
    /// version this build reads, the mechanism's identity (any of
    /// [`mechanism_identities`]: a record saved before parameters were
    /// renamed serves; by parameter names for a record written before
    /// versions), a covariance that fits.
    pub fn check(&self, spec: &Spec) -> std::result::Result<(), RecordError> {
        if self.version > CALIBRATION_VERSION {
            return Err(RecordError::Version {
                found: self.version,
            });
        }
        if self.version >= 1 {
            if self.format != CALIBRATION_FORMAT {
                return Err(RecordError::Format(self.format.clone()));
            }
            if !mechanism_identities(spec).contains(&self.mechanism_identity) {
                return Err(RecordError::OtherMechanism {
                    name: self.mechanism.clone(),
                });
            }
        }
        self.covariance
            .resolve(spec)
            .map_err(RecordError::Invalid)?;
        self.params(spec).map(|_| ())
    }

    /// The parameters the record names by an old name ([`Spec::renamed`]),
    /// among its values and its covariance: the notes a front end words
    /// for a record saved before a renaming.
    pub fn renamed(&self, spec: &Spec) -> Vec<crate::mechanism::Renamed> {
        spec.renamed_among(
            self.parameters
                .iter()
                .map(|p| p.name.as_str())
                .chain(self.covariance.names.iter().map(String::as_str)),
        )
    }

    /// The record as it would be saved today: its parameters and its
    /// covariance under their current names, and the identity under the
    /// old names ([`mechanism_identities`]) replaced by the current one; for
    /// whatever compares records by name (two calibrations' drift).
    pub fn in_current_names(&self, spec: &Spec) -> Self {
        let mut out = self.clone();
        for p in &mut out.parameters {
            p.name = spec.canonical(&p.name).to_string();
        }
        for t in &mut out.priors {
            t.name = spec.canonical(&t.name).to_string();
        }
        for n in &mut out.covariance.names {
            *n = spec.canonical(n).to_string();
        }
        if mechanism_identities(spec)[1..].contains(&self.mechanism_identity) {
            out.mechanism_identity = mechanism_identity(spec);
        }
        out
    }

    /// The mechanism's parameter values the record holds (those it does not
    /// name stay nominal; instrument parameters are left out; old names
    /// read as the current ones).
    pub fn params(&self, spec: &Spec) -> std::result::Result<Params, RecordError> {
        let mut p = Params::nominal(spec);
        for r in &self.parameters {
            if !r.identified.is_finite() {
                return Err(RecordError::Invalid(Error::InvalidRequest(format!(
                    "parameter `{}` is {}; every value must be a finite number",
                    r.name, r.identified
                ))));
            }
            if let Some((i, _)) = spec.parameter_index(&r.name) {
                p.values[i] = r.identified;
            }
        }
        Ok(p)
    }
}
