//! Tests of `pkmcal_io::firmware::reprap::script`.

use pkmcal_io::firmware::reprap::script::*;
use std::collections::HashMap;

fn value(text: &str) -> Eval {
    let globals = HashMap::new();
    let params = HashMap::new();
    let scope = Scope {
        globals: &globals,
        locals: &[],
        params: &params,
        iterations: None,
        line: 1,
    };
    evaluate(text, &scope)
}

/// The firmware's priorities, integer and 32-bit float arithmetic,
/// short cuts.
#[test]
fn expressions_evaluate_as_the_firmware_does() {
    assert_eq!(value("1 + 2 * 3"), Ok(Value::Int(7)));
    assert_eq!(value("(1 + 2) * 3"), Ok(Value::Int(9)));
    assert_eq!(value("7 / 2"), Ok(Value::float(3.5)));
    assert_eq!(value("-2 - -3"), Ok(Value::Int(1)));
    assert_eq!(value("1 < 2 && 3 >= 3"), Ok(Value::Bool(true)));
    assert_eq!(value("1 = 1 || move.x > 0"), Ok(Value::Bool(true)));
    assert_eq!(value("1 != 1 && move.x > 0"), Ok(Value::Bool(false)));
    assert_eq!(value("true ? 4 : move.x"), Ok(Value::Int(4)));
    // 0.1 + 0.2 = 0.3 in 32-bit floats, as in the firmware.
    assert_eq!(value("0.1 + 0.2 == 0.3"), Ok(Value::Bool(true)));
    assert_eq!(value("\"a\" ^ 1"), Ok(Value::Str("a1".into())));
    assert_eq!(value("max(1, 2.5, 2)"), Ok(Value::float(2.5)));
    assert_eq!(
        value("{1, 2}"),
        Ok(Value::Array(vec![Value::Int(1), Value::Int(2)]))
    );
    assert!(
        value("move.axes[0].max")
            .unwrap_err()
            .contains("object model")
    );
    assert!(value("if").is_err());
    assert!(value("1 +").is_err());
    assert!(value("5 && true").unwrap_err().contains("Boolean"));
}

/// 50,000 nested brackets or signs are refused by name, not by the
/// stack.
#[test]
fn deep_expressions_are_refused() {
    for text in [
        format!("{}1{}", "(".repeat(50_000), ")".repeat(50_000)),
        format!("{}1", "-".repeat(50_000)),
        format!("{}1{}", "{".repeat(50_000), "}".repeat(50_000)),
        format!("1{}", " + (1".repeat(50_000)),
    ] {
        let e = value(&text).unwrap_err();
        assert!(e.contains("nests more than"), "{e}");
    }
    let ok = format!("{}1{}", "(".repeat(30), ")".repeat(30));
    assert_eq!(value(&ok), Ok(Value::Int(1)));
}

#[test]
fn parameters_are_found_as_the_firmware_seen_finds_them() {
    assert_eq!(seen("R195 R196", 'R'), Some(1));
    assert_eq!(seen("L1E5 E2", 'E'), Some(6));
    assert_eq!(seen("P\"R.g\" R1", 'R'), Some(8));
    assert_eq!(seen("{global.r} R1", 'R'), Some(12));
    assert_eq!(seen("r5", 'R'), Some(1));
    assert_eq!(number_at(b"195 R196"), Some((195.0, 3)));
    assert_eq!(number_at(b"1e3"), Some((1000.0, 3)));
    assert_eq!(number_at(b"-.5:2"), Some((-0.5, 3)));
    assert_eq!(number_at(b"x"), None);
    let c = commands_of("M665 R1 M666 X2 M98 P\"m.g\"");
    let codes: Vec<(char, Option<u32>)> = c.iter().map(|x| (x.0, x.1)).collect();
    assert_eq!(codes, [('M', Some(665)), ('M', Some(666)), ('M', Some(98))]);
    assert_eq!(commands_of("echo \"M665\""), vec![]);
}
