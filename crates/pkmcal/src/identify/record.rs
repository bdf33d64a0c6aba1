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
/// the first with a format and an identity, and the oldest read: a record
/// without them cannot be told to be of the mechanism it is given for.
pub const CALIBRATION_VERSION: u32 = 1;

/// Relative asymmetry a covariance may have (`|c_ij − c_ji|` over
/// `√(c_ii c_jj)`): what its computation in floating point leaves, far
/// below any tampering or other matrix.
pub const COVARIANCE_SYMMETRY: f64 = 1e-9;

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

/// One group of readings' noise level, as a record keeps it: how many
/// coordinates, whether its σ was estimated from the residuals, and its
/// share of the redundancy (the degrees of freedom of that estimate; null
/// when σ was given).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordedNoise {
    /// Measured coordinates in the group.
    pub count: usize,
    /// Whether σ was estimated from the residuals.
    pub estimated: bool,
    /// The group's σ.
    pub sigma: f64,
    /// Its share of the redundancy, `Σ (1 − h_ii)` (null when σ was given).
    #[serde(deserialize_with = "present")]
    pub redundancy: Option<f64>,
}

/// An `Option` member that must be present (null for none): serde reads a
/// missing `Option` as `None` otherwise.
fn present<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    Option::<f64>::deserialize(d)
}

/// The header and the parts of a calibration record a calibration is used
/// by: its parameters, their covariance and the noise levels' degrees of
/// freedom. Every member is required (a full record, a calibration report,
/// holds more: accuracy, identifiability, validation; they are read past).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// [`CALIBRATION_FORMAT`].
    pub format: String,
    /// The record's version.
    pub version: u32,
    /// The mechanism's name.
    pub mechanism: String,
    /// [`mechanism_identity`] of the mechanism calibrated.
    pub mechanism_identity: String,
    /// The model the parameters were identified with.
    pub model: crate::engine::models::Model,
    /// Every parameter of the mechanism and the instrument.
    pub parameters: Vec<RecordedParameter>,
    /// The covariance of the identified parameters.
    pub covariance: ParameterCovariance,
    /// The noise groups.
    pub noise: Vec<RecordedNoise>,
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
    /// A member missing its meaning (named, with what is wrong): a value a
    /// calibration cannot have.
    Member(String),
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
            RecordError::Version { found } if *found > CALIBRATION_VERSION => write!(
                f,
                "it is a calibration record of version {found}, newer than this pkmcal reads ({CALIBRATION_VERSION}); update pkmcal"
            ),
            RecordError::Version { found } => write!(
                f,
                "it is a calibration record of version {found}, older than this pkmcal reads (1, the first that names its mechanism's identity); calibrate again"
            ),
            RecordError::Member(m) => write!(f, "{m}"),
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
            noise: cal
                .noise
                .iter()
                .map(|g| RecordedNoise {
                    count: g.count,
                    estimated: g.estimated,
                    sigma: g.sigma,
                    redundancy: g.redundancy,
                })
                .collect(),
            priors: cal.priors.clone(),
            scale: Some(cal.scale),
        }
    }

    /// Check what the record's members hold, whatever mechanism it is
    /// given for: its format, a version this build reads, each parameter
    /// named once with a finite value, a covariance that is one (square,
    /// finite, symmetric to [`COVARIANCE_SYMMETRY`], variances not
    /// negative, correlations within ±1, over parameters the record holds),
    /// noise groups that hold (a redundancy within its group's count, given
    /// exactly for an estimated σ).
    pub fn check_members(&self) -> std::result::Result<(), RecordError> {
        if self.format != CALIBRATION_FORMAT {
            return Err(RecordError::Format(self.format.clone()));
        }
        if self.version != CALIBRATION_VERSION {
            return Err(RecordError::Version {
                found: self.version,
            });
        }
        let member = |m: String| Err(RecordError::Member(m));
        if self.mechanism_identity.trim().is_empty() {
            return member("`mechanism_identity` is empty".into());
        }
        for (k, r) in self.parameters.iter().enumerate() {
            if r.name.trim().is_empty() {
                return member(format!("`parameters` entry {} has no name", k + 1));
            }
            if self.parameters[..k].iter().any(|o| o.name == r.name) {
                return member(format!("`parameters` names `{}` twice", r.name));
            }
            if !r.identified.is_finite() {
                return member(format!(
                    "`parameters`: `{}` is identified as {}; every value must be a finite number",
                    r.name, r.identified
                ));
            }
        }
        // The covariance.
        let c = &self.covariance;
        let m = &c.matrix;
        let n = c.names.len();
        if m.len() != n || m.iter().any(|r| r.len() != n) {
            return member(format!("`covariance` must be {n} × {n} for its {n} names"));
        }
        if m.iter().flatten().any(|v| !v.is_finite()) {
            return member("`covariance` has entries that are not finite numbers".into());
        }
        for (a, name) in c.names.iter().enumerate() {
            if c.names[..a].contains(name) {
                return member(format!("`covariance` names `{name}` twice"));
            }
            if !self.parameters.iter().any(|r| r.name == *name) {
                return member(format!(
                    "`covariance` names `{name}`, which `parameters` does not hold"
                ));
            }
            if m[a][a] < 0.0 {
                return member(format!(
                    "`covariance` gives `{name}` a negative variance ({:e}); it is not a covariance",
                    m[a][a]
                ));
            }
        }
        for a in 0..n {
            for b in 0..a {
                let scale = (m[a][a] * m[b][b]).sqrt();
                if (m[a][b] - m[b][a]).abs() > COVARIANCE_SYMMETRY * scale.max(f64::MIN_POSITIVE) {
                    return member(format!(
                        "`covariance` is not symmetric: ({}, {}) is {:e} but ({}, {}) is {:e}; a covariance is",
                        c.names[a], c.names[b], m[a][b], c.names[b], c.names[a], m[b][a]
                    ));
                }
                if m[a][b].abs() > scale * (1.0 + COVARIANCE_SYMMETRY) {
                    return member(format!(
                        "`covariance` gives `{}` and `{}` a correlation of {:.3}, beyond ±1; it is not a covariance",
                        c.names[a],
                        c.names[b],
                        m[a][b] / scale
                    ));
                }
            }
        }
        // The noise groups.
        for (k, g) in self.noise.iter().enumerate() {
            let at = format!("`noise` group {}", k + 1);
            if g.count == 0 {
                return member(format!("{at} counts no reading"));
            }
            if !(g.sigma.is_finite() && g.sigma >= 0.0) {
                return member(format!(
                    "{at} has σ = {}; it must be a finite number, not negative",
                    g.sigma
                ));
            }
            match (g.estimated, g.redundancy) {
                (true, Some(r)) if r.is_finite() && (0.0..=g.count as f64).contains(&r) => {}
                (true, r) => {
                    return member(format!(
                        "{at} was estimated with a redundancy of {}, which must be a number between 0 and its {} readings",
                        r.map_or("null".into(), crate::error::shown),
                        g.count
                    ));
                }
                (false, None) => {}
                (false, Some(_)) => {
                    return member(format!(
                        "{at} was given, not estimated, so its redundancy must be null"
                    ));
                }
            }
        }
        // The priors and the scale.
        for t in &self.priors {
            if !self.parameters.iter().any(|r| r.name == t.name) {
                return member(format!(
                    "`priors` names `{}`, which `parameters` does not hold",
                    t.name
                ));
            }
            if !(t.centre.is_finite() && t.sigma.is_finite() && t.sigma > 0.0) {
                return member(format!(
                    "`priors`: `{}` has centre {:e} and σ {:e}; a prior is a finite centre and a positive, finite σ",
                    t.name, t.centre, t.sigma
                ));
            }
        }
        // The scale's degrees of freedom are the estimated groups'
        // redundancy: at most the readings the record counts.
        let readings = self
            .noise
            .iter()
            .fold(0usize, |a, g| a.saturating_add(g.count));
        if let Some(dof) = self.scale.and_then(|s| s.dof())
            && !(dof.is_finite() && dof >= 0.0 && (self.noise.is_empty() || dof <= readings as f64))
        {
            return member(format!(
                "`scale` has {} degrees of freedom; they must be a finite number, not negative and at most the {readings} readings its `noise` counts",
                crate::error::shown(dof)
            ));
        }
        Ok(())
    }

    /// Check that the record can serve the mechanism `spec`: its members
    /// ([`Self::check_members`]), the mechanism's identity (any of
    /// [`mechanism_identities`]: a record saved before parameters were
    /// renamed serves), every parameter of the mechanism held, a covariance
    /// over the mechanism's (and the instrument's) parameters.
    pub fn check(&self, spec: &Spec) -> std::result::Result<(), RecordError> {
        self.check_members()?;
        if !mechanism_identities(spec).contains(&self.mechanism_identity) {
            return Err(RecordError::OtherMechanism {
                name: self.mechanism.clone(),
            });
        }
        self.params(spec)?;
        self.covariance
            .resolve(spec)
            .map_err(RecordError::Invalid)?;
        Ok(())
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

    /// The degrees of freedom of the record's estimated noise level: the
    /// redundancy of the groups it estimated (`None` when it estimated
    /// none).
    pub fn dof(&self) -> Option<f64> {
        let r: f64 = self
            .noise
            .iter()
            .filter(|g| g.estimated)
            .filter_map(|g| g.redundancy)
            .sum();
        (r > 0.0).then_some(r)
    }

    /// The mechanism's parameter values, the record [checked](Self::check)
    /// first and the values then checked to describe the mechanism
    /// ([`crate::check_params`]: in range, lengths positive, the mechanism
    /// still assembles), so that an impossible value is blamed on the record
    /// and not on the first pose it is used at.
    pub fn checked_params<M: crate::Mechanism>(
        &self,
        mech: &M,
    ) -> std::result::Result<Params, RecordError> {
        self.check(mech.spec())?;
        let p = self.params(mech.spec())?;
        crate::check_params(mech, &p).map_err(RecordError::Invalid)?;
        Ok(p)
    }

    /// The mechanism's parameter values the record holds (every one of
    /// them: [`Self::check`]; instrument parameters are left out; old names
    /// read as the current ones, a parameter held under both refused).
    pub fn params(&self, spec: &Spec) -> std::result::Result<Params, RecordError> {
        let mut p = Params::nominal(spec);
        for (i, name) in spec.param_names().iter().enumerate() {
            let mut held = self
                .parameters
                .iter()
                .filter(|r| spec.parameter_index(&r.name).map(|(k, _)| k) == Some(i));
            let found = held.next();
            if let Some(again) = held.next() {
                return Err(RecordError::Member(format!(
                    "`parameters` holds `{name}` twice (as `{}` and `{}`)",
                    found.map_or("", |r| r.name.as_str()),
                    again.name
                )));
            }
            match found {
                Some(r) if r.identified.is_finite() => p.values[i] = r.identified,
                Some(r) => {
                    return Err(RecordError::Member(format!(
                        "`parameters`: `{name}` is identified as {}; every value must be a finite number",
                        r.identified
                    )));
                }
                None => {
                    return Err(RecordError::Member(format!(
                        "`parameters` lacks `{name}`, which the mechanism has (a record holds every parameter)"
                    )));
                }
            }
        }
        Ok(p)
    }
}
