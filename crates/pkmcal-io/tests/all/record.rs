//! Tests of `pkmcal_io::record`.

use pkmcal_io::record::*;
use serde::{Deserialize, Serialize};

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
    let v = to_json_cancellable(ciborium::Value::serialized(&s).unwrap(), None).unwrap();
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
