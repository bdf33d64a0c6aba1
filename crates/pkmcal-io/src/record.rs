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

use anyhow::{Context, Result, bail};
use pkmcal::MeasurementModel;
use pkmcal::identify::Study;
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
}

/// A JSON value from CBOR's data model, non-finite numbers tagged.
fn to_json(v: ciborium::Value) -> Result<serde_json::Value> {
    use ciborium::Value as C;
    use serde_json::Value as J;
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
                bail!("the integer {i} does not fit 64 bits")
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
                    other => bail!("a map key that is not text: {other:?}"),
                })
                .collect::<Result<_>>()?,
        ),
        other => bail!("a value JSON cannot hold: {other:?}"),
    })
}

/// CBOR's data model from a JSON value [`to_json`] wrote.
fn from_json(v: serde_json::Value) -> Result<ciborium::Value> {
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
                C::Float(n.as_f64().context("a number out of range")?)
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
                    _ => bail!("`{NON_FINITE}` must be \"NaN\", \"inf\" or \"-inf\", not \"{t}\""),
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
    let v = ciborium::Value::serialized(state).context("cannot encode the calibration")?;
    to_json(v)
}

/// The state a record's `state` member holds.
pub fn state_from_json(v: serde_json::Value) -> Result<CalibrationState> {
    let c = from_json(v)?;
    c.deserialized()
        .map_err(|e| anyhow::anyhow!("{e}"))
        .context("its `state` is not a calibration this pkmcal reads")
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
    ciborium::into_writer(v, out).map_err(|e| anyhow::anyhow!("cannot encode a result: {e}"))
}

/// What [`encode`] wrote.
pub fn decode<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T> {
    ciborium::from_reader(bytes).map_err(|e| anyhow::anyhow!("cannot decode a result: {e}"))
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

/// The [`RecordParts`] of a record's JSON text; `source` names it in
/// messages.
pub fn record_parts(text: &str, source: &str) -> Result<RecordParts> {
    let mut v: serde_json::Value = serde_json::from_str(text)
        .with_context(|| format!("{source}: not a JSON calibration report"))?;
    if v.get("covariance").is_none() {
        bail!(
            "{source}: no `covariance` entry; pass the report written by `pkmcal calibrate --report` or Python's Calibration.save"
        );
    }
    let dof = v
        .get("noise")
        .and_then(serde_json::Value::as_array)
        .map(|groups| {
            groups
                .iter()
                .filter(|g| g.get("estimated").and_then(serde_json::Value::as_bool) == Some(true))
                .filter_map(|g| g.get("redundancy").and_then(serde_json::Value::as_f64))
                .sum::<f64>()
        })
        .filter(|r| *r > 0.0);
    let state = v.as_object_mut().and_then(|o| o.remove("state"));
    let record = serde_json::from_value(v)
        .with_context(|| format!("{source}: malformed calibration report"))?;
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
        Some(s) => Some(
            state_from_json(s).with_context(|| format!("{source}: malformed calibration state"))?,
        ),
        None => None,
    };
    Ok((parts.record, state))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Serialize, Deserialize)]
    struct Sample {
        numbers: Vec<f64>,
        count: u64,
        offset: i64,
        maybe: Option<f64>,
        nothing: Option<String>,
        text: String,
        #[serde(rename = "$f64")]
        tricky: f64,
    }

    /// Every number comes back to the bit, the non-finite ones included,
    /// and a text that looks like the tag stays a text.
    #[test]
    fn numbers_survive_json_to_the_bit() {
        let s = Sample {
            numbers: vec![
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
                0.1 + 0.2,
                -0.0,
                f64::MIN_POSITIVE,
                1e308,
                5e-324,
            ],
            count: u64::MAX,
            offset: i64::MIN,
            maybe: Some(f64::NAN),
            nothing: None,
            text: "NaN".into(),
            tricky: 2.5,
        };
        let v = to_json(ciborium::Value::serialized(&s).unwrap()).unwrap();
        let text = serde_json::to_string(&v).unwrap();
        let back: Sample = from_json(serde_json::from_str(&text).unwrap())
            .unwrap()
            .deserialized()
            .unwrap();
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&back.numbers), bits(&s.numbers));
        assert_eq!(back.count, s.count);
        assert_eq!(back.offset, s.offset);
        assert!(back.maybe.unwrap().is_nan());
        assert_eq!(back.nothing, None);
        assert_eq!(back.text, "NaN");
        assert_eq!(back.tricky, 2.5);
    }

    /// A malformed tag is refused by name.
    #[test]
    fn a_bad_tag_is_refused() {
        let v: serde_json::Value = serde_json::from_str(r#"{"$f64": "huge"}"#).unwrap();
        let e = from_json(v).unwrap_err().to_string();
        assert!(e.contains("$f64"), "{e}");
    }
}
