//! A calibration record that holds the whole calibration: besides what a
//! report shows (and [`pkmcal::identify::CalibrationRecord`] reads), a
//! `state` member with the mechanism's description, the measurement model
//! and the whole study ([`pkmcal::identify::Study`]), so that a calibration
//! read back is, to the bit, the one written: Python's `Calibration.save`
//! and `Calibration.load`, and pickling, which uses the same record.
//!
//! JSON has no NaN or infinity, and a calibration holds them (the standard
//! deviations of an exactly determined fit, the condition number of a
//! rank-deficient one). In `state`, a number that is not finite is written
//! `{"$f64": "NaN"}`, `{"$f64": "inf"}` or `{"$f64": "-inf"}`; every other
//! number is written as JSON writes it, exactly (shortest round trip).
//! The state goes through CBOR's data model (`ciborium`, which keeps every
//! float and integer as it is) on its way to and from JSON's.

use crate::error::{Error, Result, Within};
use crate::invalid;
use pkmcal::MeasurementModel;
use pkmcal::identify::CrossValidation;
use pkmcal::identify::Study;
use pkmcal::{Accuracy, Calibration};
use serde::{Deserialize, Serialize};

/// The key of a number JSON cannot write.
const NON_FINITE: &str = "$f64";

/// Where a recorded calibration's mechanism comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MechanismSource {
    /// The built-in reference mechanism.
    Reference,
    /// A description's text (TOML).
    Description(String),
}

/// What a complete record holds beyond the report: everything to rebuild
/// the calibration.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CalibrationState {
    /// The mechanism calibrated.
    pub mechanism: MechanismSource,
    /// The instrument's model.
    pub measurement: MeasurementModel,
    /// The fit, its accuracy, the poses, the validation and the
    /// cross-validation.
    pub study: Study,
    /// The tool load during the measurements (N, N·m; one value per tool
    /// axis), empty for none (and in records written before it was kept).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub load: Vec<f64>,
}

/// A JSON value from CBOR's data model, non-finite numbers tagged;
/// stopped at its next value once `cancel` is set.
#[doc(hidden)] // public for the integration tests only
pub fn to_json_cancellable(
    v: ciborium::Value,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<serde_json::Value> {
    use ciborium::Value as C;
    use serde_json::Value as J;
    pkmcal::error::check_cancel(cancel)?;
    let to_json = |v| to_json_cancellable(v, cancel);
    Ok(match v {
        C::Null => J::Null,
        C::Bool(b) => J::Bool(b),
        C::Text(s) => J::String(s),
        C::Integer(i) => {
            let i = i128::from(i);
            if let Ok(u) = u64::try_from(i) {
                J::from(u)
            } else if let Ok(s) = i64::try_from(i) {
                J::from(s)
            } else {
                invalid!("the integer {i} does not fit 64 bits")
            }
        }
        C::Float(f) => match serde_json::Number::from_f64(f) {
            Some(n) => J::Number(n),
            None => {
                let text = if f.is_nan() {
                    "NaN"
                } else if f > 0.0 {
                    "inf"
                } else {
                    "-inf"
                };
                J::Object(
                    [(NON_FINITE.to_string(), J::from(text))]
                        .into_iter()
                        .collect(),
                )
            }
        },
        C::Array(a) => J::Array(a.into_iter().map(to_json).collect::<Result<_>>()?),
        C::Map(m) => J::Object(
            m.into_iter()
                .map(|(k, v)| match k {
                    C::Text(k) => Ok((k, to_json(v)?)),
                    other => invalid!("a map key that is not text: {other:?}"),
                })
                .collect::<Result<_>>()?,
        ),
        other => invalid!("a value JSON cannot hold: {other:?}"),
    })
}

/// CBOR's data model from a JSON value [`to_json_cancellable`] wrote.
#[doc(hidden)] // public for the integration tests only
pub fn from_json(v: serde_json::Value) -> Result<ciborium::Value> {
    use ciborium::Value as C;
    use serde_json::Value as J;
    Ok(match v {
        J::Null => C::Null,
        J::Bool(b) => C::Bool(b),
        J::String(s) => C::Text(s),
        J::Number(n) => {
            if let Some(u) = n.as_u64() {
                C::Integer(u.into())
            } else if let Some(i) = n.as_i64() {
                C::Integer(i.into())
            } else {
                C::Float(
                    n.as_f64()
                        .ok_or_else(|| Error::Content("a number out of range".into()))?,
                )
            }
        }
        J::Array(a) => C::Array(a.into_iter().map(from_json).collect::<Result<_>>()?),
        J::Object(o) => {
            if o.len() == 1
                && let Some(J::String(t)) = o.get(NON_FINITE)
            {
                return Ok(C::Float(match t.as_str() {
                    "NaN" => f64::NAN,
                    "inf" => f64::INFINITY,
                    "-inf" => f64::NEG_INFINITY,
                    _ => {
                        invalid!("`{NON_FINITE}` must be \"NaN\", \"inf\" or \"-inf\", not \"{t}\"")
                    }
                }));
            }
            C::Map(
                o.into_iter()
                    .map(|(k, v)| Ok((C::Text(k), from_json(v)?)))
                    .collect::<Result<_>>()?,
            )
        }
    })
}

/// `state` as the JSON a record holds.
pub fn state_to_json(state: &CalibrationState) -> Result<serde_json::Value> {
    state_to_json_cancellable(state, None)
}

/// [`state_to_json`], stopped at its next value once `cancel` is set.
fn state_to_json_cancellable(
    state: &CalibrationState,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<serde_json::Value> {
    let v = ciborium::Value::serialized(state)
        .map_err(|e| Error::Content(format!("cannot encode the calibration: {e}")))?;
    to_json_cancellable(v, cancel)
}

/// The state a record's `state` member holds.
pub fn state_from_json(v: serde_json::Value) -> Result<CalibrationState> {
    let c = from_json(v)?;
    c.deserialized().map_err(|e| {
        Error::Content(format!(
            "its `state` is not a calibration this pkmcal reads: {e}"
        ))
    })
}

/// The state as bytes that are equal exactly when the states are (NaN
/// equal to itself): what Python's `==` on calibrations compares.
pub fn state_bytes(state: &CalibrationState) -> Result<Vec<u8>> {
    let mut out = vec![];
    encode(state, &mut out)?;
    Ok(out)
}

/// `v` as CBOR bytes (every number kept as it is), appended to `out`:
/// how Python pickles results that hold library data.
pub fn encode<T: Serialize>(v: &T, out: &mut Vec<u8>) -> Result<()> {
    ciborium::into_writer(v, out)
        .map_err(|e| Error::Content(format!("cannot encode a result: {e}")))
}

/// What [`encode`] wrote.
pub fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T> {
    ciborium::from_reader(bytes).map_err(|e| Error::Content(format!("cannot decode a result: {e}")))
}

/// A record read without decoding its state: the header, the `state`
/// member as JSON (decoded only by those who need the whole calibration,
/// [`record_from_str`]), and the degrees of freedom of its estimated noise
/// levels (the redundancy of the groups its `noise` says were estimated;
/// `None` when it records none).
pub struct RecordParts {
    pub record: pkmcal::identify::CalibrationRecord,
    pub state: Option<serde_json::Value>,
    pub dof: Option<f64>,
}

/// A JSON text as a value, refusing a key given twice in one object (a
/// JSON reader would keep one of them without a word).
fn strict_json(text: &str) -> std::result::Result<serde_json::Value, serde_json::Error> {
    use serde::de::{Error as _, MapAccess, SeqAccess, Visitor};
    struct Strict(serde_json::Value);
    struct V;
    impl<'de> Visitor<'de> for V {
        type Value = serde_json::Value;
        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a JSON value")
        }
        fn visit_bool<E>(self, v: bool) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_i64<E>(self, v: i64) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_u64<E>(self, v: u64) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_f64<E>(self, v: f64) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_str<E>(self, v: &str) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_string<E>(self, v: String) -> std::result::Result<Self::Value, E> {
            Ok(v.into())
        }
        fn visit_unit<E>(self) -> std::result::Result<Self::Value, E> {
            Ok(serde_json::Value::Null)
        }
        fn visit_seq<A: SeqAccess<'de>>(
            self,
            mut a: A,
        ) -> std::result::Result<Self::Value, A::Error> {
            let mut out = vec![];
            while let Some(Strict(v)) = a.next_element()? {
                out.push(v);
            }
            Ok(out.into())
        }
        fn visit_map<A: MapAccess<'de>>(
            self,
            mut a: A,
        ) -> std::result::Result<Self::Value, A::Error> {
            let mut out = serde_json::Map::new();
            while let Some(k) = a.next_key::<String>()? {
                if out.contains_key(&k) {
                    return Err(A::Error::custom(format!(
                        "the key `{k}` appears twice in one object (which one counts is not defined); keep one"
                    )));
                }
                let Strict(v) = a.next_value()?;
                out.insert(k, v);
            }
            Ok(out.into())
        }
    }
    impl<'de> Deserialize<'de> for Strict {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
            d.deserialize_any(V).map(Strict)
        }
    }
    serde_json::from_str::<Strict>(text).map(|s| s.0)
}

/// The [`RecordParts`] of a record's JSON text; `source` names it in
/// messages. A key given twice, a missing member or one of another kind is
/// refused here; what the members mean, against the mechanism they serve,
/// by [`pkmcal::identify::CalibrationRecord::check`].
pub fn record_parts(text: &str, source: &str) -> Result<RecordParts> {
    let mut v: serde_json::Value = strict_json(text)
        .map_err(|e| Error::Content(format!("{source}: not a JSON calibration report: {e}")))?;
    if v.get("covariance").is_none() {
        return Err(Error::NotARecord {
            source_name: source.to_string(),
        });
    }
    let state = v.as_object_mut().and_then(|o| o.remove("state"));
    let record: pkmcal::identify::CalibrationRecord = serde_json::from_value(v).map_err(|e| {
        Error::Content(format!(
            "{source}: malformed calibration report: {e}; give a calibration record as pkmcal wrote it"
        ))
    })?;
    record
        .check_members()
        .map_err(|e| Error::Content(format!("{source}: {e}")))?;
    let dof = record.dof();
    Ok(RecordParts { record, state, dof })
}

/// A record's header and, when it is complete, its state, from the
/// record's JSON text; `source` names it in messages.
pub fn record_from_str(
    text: &str,
    source: &str,
) -> Result<(
    pkmcal::identify::CalibrationRecord,
    Option<CalibrationState>,
)> {
    let parts = record_parts(text, source)?;
    let state = match parts.state {
        Some(s) => {
            Some(state_from_json(s).within(|| format!("{source}: malformed calibration state"))?)
        }
        None => None,
    };
    Ok((parts.record, state))
}

/// Validation results in the report.
#[derive(Serialize, Clone)]
pub struct Validation {
    /// Where the validation poses came from.
    pub source: String,
    /// Before/after on the validation poses.
    pub accuracy: Accuracy,
}

/// The JSON report of `calibrate` (and of Python's `Calibration.save`): a
/// versioned calibration record ([`pkmcal::identify::CalibrationRecord`]
/// reads it back) with everything a reader wants to see, and in `state` the
/// whole calibration ([`crate::record`]).
#[derive(Serialize, Clone)]
pub struct Report<'a> {
    /// [`pkmcal::identify::CALIBRATION_FORMAT`].
    pub format: &'static str,
    /// [`pkmcal::identify::CALIBRATION_VERSION`].
    pub version: u32,
    pub pkmcal_version: &'static str,
    pub mechanism: String,
    /// [`pkmcal::identify::mechanism_identity`] of the mechanism.
    pub mechanism_identity: String,
    pub data: String,
    /// What the instrument read.
    pub measurement: pkmcal::MeasurementSummary,
    #[serde(flatten)]
    pub calibration: &'a Calibration,
    pub accuracy: &'a Accuracy,
    pub validation: Option<Validation>,
    pub cross_validation: &'a Option<CrossValidation>,
    /// The whole calibration, to read it back.
    pub state: StateRecord<'a>,
}

/// A record's `state`: the whole calibration, written as JSON (stopped
/// once `cancel` is set: [`Report::to_json_cancellable`]).
#[derive(Clone, Copy)]
pub struct StateRecord<'a> {
    pub state: &'a CalibrationState,
    pub cancel: Option<&'a std::sync::atomic::AtomicBool>,
}

impl Serialize for StateRecord<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        state_to_json_cancellable(self.state, self.cancel)
            .map_err(|e| serde::ser::Error::custom(format!("{e}")))?
            .serialize(s)
    }
}

impl<'a> Report<'a> {
    /// The report of the calibration `state` of the mechanism `spec` from
    /// `data` (a file's name, or a description of arrays); `validation`
    /// words where the validation poses came from.
    pub fn new(
        spec: &pkmcal::Spec,
        data: String,
        state: &'a CalibrationState,
        validation: impl Fn(pkmcal::identify::ValidationSource) -> String,
    ) -> Self {
        let study = &state.study;
        Report {
            format: pkmcal::identify::CALIBRATION_FORMAT,
            version: pkmcal::identify::CALIBRATION_VERSION,
            pkmcal_version: env!("CARGO_PKG_VERSION"),
            mechanism: spec.name.clone(),
            mechanism_identity: pkmcal::identify::mechanism_identity(spec),
            data,
            measurement: state.measurement.summary(),
            calibration: &study.calibration,
            accuracy: &study.accuracy,
            validation: study.validation.as_ref().map(|v| Validation {
                source: validation(v.source),
                accuracy: v.accuracy.clone(),
            }),
            cross_validation: &study.cross_validation,
            state: StateRecord {
                state,
                cancel: None,
            },
        }
    }

    /// The report as JSON text (the calibration record's file).
    pub fn to_json(&self) -> Result<String> {
        self.to_json_cancellable(None)
    }

    /// [`Report::to_json`], stopped at its next piece of text once `cancel`
    /// is set (the library's [`pkmcal::Error::Cancelled`]): a record of a
    /// million poses takes seconds to write.
    pub fn to_json_cancellable(
        &self,
        cancel: Option<&std::sync::atomic::AtomicBool>,
    ) -> Result<String> {
        /// The text so far; refuses more once the flag is set.
        struct Watched<'a> {
            text: Vec<u8>,
            cancel: Option<&'a std::sync::atomic::AtomicBool>,
        }
        impl std::io::Write for Watched<'_> {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                // Not ErrorKind::Interrupted: write_all retries that one.
                pkmcal::error::check_cancel(self.cancel).map_err(std::io::Error::other)?;
                self.text.extend_from_slice(b);
                Ok(b.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let mut out = Watched {
            text: Vec::new(),
            cancel,
        };
        let mut report = self.clone();
        report.state.cancel = cancel;
        serde_json::to_writer_pretty(&mut out, &report).map_err(|e| {
            if pkmcal::error::check_cancel(cancel).is_err() {
                Error::from(pkmcal::Error::Cancelled)
            } else {
                Error::Content(format!("cannot write the report: {e}"))
            }
        })?;
        String::from_utf8(out.text)
            .map_err(|e| Error::Content(format!("cannot write the report: {e}")))
    }
}

/// A calibration record (a calibration's report, a Python
/// `Calibration.save`): its header, parameters and covariance, checked as
/// JSON here (the mechanism it serves is checked by
/// [`pkmcal::identify::CalibrationRecord::check`]).
pub fn read_calibration_record(
    run: &crate::Run<'_>,
    path: &std::path::Path,
) -> Result<pkmcal::identify::CalibrationRecord> {
    read_calibration_record_dof(run, path).map(|(r, _)| r)
}

/// [`read_calibration_record`] with the degrees of freedom of its estimated
/// noise level (the redundancy of the noise groups it estimated, from the
/// report's `noise`), when it records them. Its `state` is not decoded.
pub fn read_calibration_record_dof(
    run: &crate::Run<'_>,
    path: &std::path::Path,
) -> Result<(pkmcal::identify::CalibrationRecord, Option<f64>)> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)
        .map_err(|e| e.named("calibration report"))?;
    let parts = record_parts(&text, &path.display().to_string())?;
    Ok((parts.record, parts.dof))
}

/// Read a calibration record that holds the whole calibration (written by
/// this pkmcal's calibration report or Python's `Calibration.save`).
pub fn read_calibration_state(
    run: &crate::Run<'_>,
    path: &std::path::Path,
) -> Result<(pkmcal::identify::CalibrationRecord, CalibrationState)> {
    let text = run
        .files
        .read_to_string(path, crate::output::InputKind::Description)
        .map_err(|e| e.named("calibration report"))?;
    let (record, state) = record_from_str(&text, &path.display().to_string())?;
    let Some(state) = state else {
        crate::refuse!(
            path,
            None,
            "this calibration record holds only the parameters and their covariance (an older pkmcal wrote it): it serves predictions, not the whole calibration; calibrate again to keep the whole calibration"
        );
    };
    Ok((record, state))
}
