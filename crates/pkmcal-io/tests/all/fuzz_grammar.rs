//! Fuzzing of what issue 50 added, by grammar rather than by bytes (the
//! byte-level fuzzing is `fuzz_readers`): RepRapFirmware `config.g` texts
//! built from expressions nested beyond the depth bound, globals, `if`/
//! `elif`/`else`, `while` loops, `M98` and `M665`/`M666` words given twice;
//! G-code programs of every dialect built from moves with repeated,
//! lower-case, hexadecimal and exponent words, `G53`, relative moves and
//! checksummed lines; calibration records with a member deleted, a number
//! made extreme or a key given twice. Each must answer `Ok` or a typed
//! error naming the file and, where there is one, the line; the G-code
//! rewrite under the identity is a fixed point (rewriting its output again
//! changes nothing), and a record read and written comes back the same.
//! Proptest with a fixed seed and bounded sizes: a few hundred cases per
//! property, about a second each in the suite; `PKMCAL_FUZZ_CASES=N` for
//! long runs.

use proptest::prelude::*;
use std::path::Path;

fn cases() -> u32 {
    std::env::var("PKMCAL_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256)
}

/// Numbers as a user or a slicer writes them, ordinary and extreme.
fn number() -> impl Strategy<Value = String> {
    prop_oneof![
        6 => (-500.0..500.0f64).prop_map(|v| format!("{v:.3}")),
        1 => prop::sample::select(vec![
            "0", "-0", "1e1", "1e308", "1e400", "-1e-300", "0x10", ".5", "5.", "+2", "nan",
            "inf", "", "1e", "--1", "9999999999999999999999",
        ])
        .prop_map(str::to_string),
    ]
}

/// A RepRapFirmware expression of at most `depth` nested levels (the
/// reader's bound is [`pkmcal_io::firmware::reprap::script::MAX_EXPRESSION_DEPTH`];
/// deeper ones must be refused, never overflow the stack).
fn expression() -> impl Strategy<Value = String> {
    let leaf = prop_oneof![
        number(),
        Just("global.g1".to_string()),
        Just("var.v".to_string()),
        Just("iterations".to_string()),
        Just("true".to_string()),
        Just("\"text\"".to_string()),
        Just("move.axes[0].max".to_string()),
    ];
    leaf.prop_recursive(6, 48, 3, |inner| {
        prop_oneof![
            (
                inner.clone(),
                prop::sample::select(vec![
                    "+", "-", "*", "/", "<", ">", "=", "!=", "&&", "||", "^"
                ]),
                inner.clone()
            )
                .prop_map(|(a, o, b)| format!("{a} {o} {b}")),
            inner.clone().prop_map(|a| format!("({a})")),
            inner.clone().prop_map(|a| format!("-{a}")),
            inner.clone().prop_map(|a| format!("!{a}")),
            (inner.clone(), inner.clone(), inner).prop_map(|(c, a, b)| format!("{c} ? {a} : {b}")),
        ]
    })
}

/// An expression wrapped in `depth` parentheses (beyond the bound at 64).
fn deep(e: String, depth: usize) -> String {
    format!("{}{e}{}", "(".repeat(depth), ")".repeat(depth))
}

/// One `config.g` statement at `indent`, with its body where it has one.
fn statement() -> impl Strategy<Value = Vec<(usize, String)>> {
    let simple = prop_oneof![
        (expression(), expression(), number())
            .prop_map(|(r, l, h)| vec![(0, format!("M665 R{{{r}}} L{{{l}}} H{h} B150"))]),
        (number(), number()).prop_map(|(a, b)| vec![(0, format!("M665 R{a} R{b} L360 H420"))]),
        (number(), number(), number())
            .prop_map(|(x, y, z)| vec![(0, format!("M666 X{x} Y{y} Z{z} X{z}"))]),
        (expression(), 0usize..80)
            .prop_map(|(e, d)| vec![(0, format!("global g1 = {}", deep(e, d)))]),
        expression().prop_map(|e| vec![(0, format!("var v = {e}"))]),
        expression().prop_map(|e| vec![(0, format!("set global.g1 = {e}"))]),
        expression().prop_map(|e| vec![(0, format!("echo {e}"))]),
        Just(vec![(0, "M98 P\"other.g\"".to_string())]),
        Just(vec![(0, "M501".to_string())]),
        Just(vec![(0, "break".to_string())]),
        Just(vec![(0, "M99".to_string())]),
        Just(vec![(0, "M558 P5 ; probe".to_string())]),
    ];
    simple.prop_recursive(3, 24, 4, |inner| {
        let body = prop::collection::vec(inner, 1..3).prop_map(|b| {
            b.into_iter()
                .flatten()
                .map(|(i, l)| (i + 2, l))
                .collect::<Vec<_>>()
        });
        prop_oneof![
            (expression(), body.clone(), prop::option::of(body.clone())).prop_map(
                |(c, then, otherwise)| {
                    let mut out = vec![(0, format!("if {c}"))];
                    out.extend(then);
                    if let Some(o) = otherwise {
                        out.push((0, "else".into()));
                        out.extend(o);
                    }
                    out
                }
            ),
            (expression(), expression(), body.clone(), body.clone()).prop_map(|(c, d, a, b)| {
                let mut out = vec![(0, format!("if {c}"))];
                out.extend(a);
                out.push((0, format!("elif {d}")));
                out.extend(b);
                out
            }),
            (0u32..50, body.clone()).prop_map(|(k, b)| {
                let mut out = vec![(0, format!("while iterations < {k}"))];
                out.extend(b);
                out
            }),
            (expression(), body).prop_map(|(c, b)| {
                let mut out = vec![(0, format!("while {c}"))];
                out.extend(b);
                out
            }),
        ]
    })
}

/// A whole `config.g`: the statements, then the geometry it must end with.
fn config() -> impl Strategy<Value = String> {
    prop::collection::vec(statement(), 0..8).prop_map(|s| {
        let mut text = String::from("; fuzzed\n");
        for (indent, line) in s.into_iter().flatten() {
            text.push_str(&" ".repeat(indent));
            text.push_str(&line);
            text.push('\n');
        }
        text.push_str("M665 L360 R190 H420 B150\nM666 X0 Y0 Z0\n");
        text
    })
}

/// The line an error names in `file` (`file:LINE: …`), if any.
fn line_named(message: &str, file: &str) -> Option<u64> {
    let rest = message.split(&format!("{file}:")).nth(1)?;
    rest.split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

/// One G-code line of a dialect's moves and modes, with words a firmware
/// reads in its own way.
fn gcode_line() -> impl Strategy<Value = String> {
    let word = (
        prop::sample::select(vec!['X', 'Y', 'Z', 'E', 'F', 'x', 'z']),
        number(),
    )
        .prop_map(|(w, n)| format!("{w}{n}"));
    let command = prop::sample::select(vec![
        "G0", "G1", "G1", "G1", "G90", "G91", "G92", "G53 G1", "G28", "G21", "M82", "M83", "G4 P5",
        "T0", "g1", "G01",
    ]);
    let plain = (
        command,
        prop::collection::vec(word, 0..4),
        prop::option::of(prop::sample::select(vec!["; note", "(note)", "; G1 X5"])),
    )
        .prop_map(|(c, w, comment)| {
            let mut l = c.to_string();
            for w in w {
                l.push(' ');
                l.push_str(&w);
            }
            if let Some(c) = comment {
                l.push(' ');
                l.push_str(c);
            }
            l
        });
    (plain, 0u8..4, any::<u8>(), 1u32..1000).prop_map(|(l, kind, wrong, n)| match kind {
        // A line number and its checksum, right or wrong.
        0 => {
            let body = format!("N{n} {l}");
            let sum = body.bytes().fold(0u8, |a, b| a ^ b);
            format!("{body}*{sum}")
        }
        1 => format!("N{n} {l}*{wrong}"),
        _ => l,
    })
}

/// The identity pre-distortion: every target sent as it is.
fn identity(t: &[f64]) -> pkmcal::Result<pkmcal::Predistortion> {
    Ok(pkmcal::Predistortion {
        command_target: t.to_vec(),
        commands: vec![],
        residual: 0.0,
        iterations: 0,
    })
}

/// The shipped calibration record, as JSON.
fn record() -> serde_json::Value {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/record.json"),
    )
    .expect("shipped record");
    serde_json::from_str(&text).expect("the shipped record is JSON")
}

/// The members every use of a record needs.
const REQUIRED: [&str; 8] = [
    "format",
    "version",
    "mechanism",
    "mechanism_identity",
    "model",
    "noise",
    "parameters",
    "covariance",
];

/// Every number of a JSON value, by the path to it.
fn numbers(v: &serde_json::Value, path: Vec<String>, out: &mut Vec<Vec<String>>) {
    match v {
        serde_json::Value::Number(_) => out.push(path),
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                let mut p = path.clone();
                p.push(i.to_string());
                numbers(x, p, out);
            }
        }
        serde_json::Value::Object(o) => {
            for (k, x) in o {
                let mut p = path.clone();
                p.push(k.clone());
                numbers(x, p, out);
            }
        }
        _ => {}
    }
}

fn at<'a>(v: &'a mut serde_json::Value, path: &[String]) -> &'a mut serde_json::Value {
    path.iter().fold(v, |v, k| match v {
        serde_json::Value::Array(a) => &mut a[k.parse::<usize>().expect("an index")],
        other => &mut other[k.as_str()],
    })
}

/// Read `text` as a record at `dir/record.json` and check it against the
/// reference mechanism: the error's text, or `None` when it serves.
fn read_record(dir: &Path, text: &str) -> Option<String> {
    let p = dir.join("record.json");
    std::fs::write(&p, text).expect("write");
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let spec = pkmcal::kinds::reference::JeongKim2Dof::default_spec();
    match pkmcal_io::record::read_calibration_record(&run, &p) {
        Err(e) => Some(e.to_string()),
        Ok(r) => match r.check(&spec).and_then(|()| r.params(&spec).map(|_| ())) {
            Ok(()) => None,
            Err(e) => Some(format!("record.json: {e}")),
        },
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(), rng_seed: proptest::test_runner::RngSeed::Fixed(50), failure_persistence: None, ..ProptestConfig::default() })]

    /// RepRapFirmware's control flow and expressions: an answer, or a
    /// refusal naming `config.g` and a line of it (a macro's refusal names
    /// the line that calls it); never a stack overflow, never a hang.
    #[test]
    fn reprap_configurations_answer_or_name_their_line(text in config()) {
        let lines = text.lines().count() as u64;
        if let Err(e) = pkmcal_io::firmware::reprap::delta_from_gcode(&text, "config.g") {
            // What the whole file sets (no geometry, when an `M99` ends it
            // early, or an impossible one) is refused naming the file;
            // anything else at its line.
            let m = e.to_string();
            prop_assert!(m.starts_with("config.g"), "{m}\n{text}");
            let line = line_named(&m, "config.g");
            prop_assert!(line.is_none_or(|l| (1..=lines).contains(&l)), "{m}\n{text}");
        }
    }

    /// G-code words per dialect: a program rewritten under the identity is
    /// refused at a line of it, or is a fixed point of the rewrite (`G0
    /// X-1e-300` was written `X-0.0000`, then `X0.0000`).
    #[test]
    fn gcode_programs_answer_or_name_their_line(lines in prop::collection::vec(gcode_line(), 1..20)) {
        let mut text = String::from("G28\nG90\nG1 X0 Y0 Z10\n");
        for l in &lines {
            text.push_str(l);
            text.push('\n');
        }
        let n = text.lines().count() as u64;
        let axes = ["x".to_string(), "y".to_string(), "z".to_string()];
        let units = [pkmcal::Unit::Millimetre; 3];
        for dialect in pkmcal_io::gcode::Dialect::ALL {
            let settings = pkmcal_io::gcode::Rewrite { dialect, offset: vec![], max_segment: None };
            let path = Path::new("part.gcode");
            match pkmcal_io::gcode::rewrite(path, text.as_bytes(), &axes, &units, &settings, identity) {
                Err(pkmcal_io::Error::Gcode { line, .. }) => prop_assert!((1..=n).contains(&line), "{line} of {n}\n{text}"),
                Err(e) => prop_assert!(e.to_string().contains("part.gcode"), "{e}"),
                Ok(once) => {
                    let twice = pkmcal_io::gcode::rewrite(path, &once.bytes, &axes, &units, &settings, identity);
                    prop_assert!(twice.as_ref().is_ok_and(|t| t.bytes == once.bytes), "{}: {text}\n->\n{}\n->\n{:?}", dialect.name(), String::from_utf8_lossy(&once.bytes), twice.map(|t| String::from_utf8_lossy(&t.bytes).into_owned()));
                }
            }
        }
    }

    /// A record with a required member deleted, a number made extreme, or
    /// a key given twice: refused naming the record, never served with a
    /// value it does not hold; never a panic.
    #[test]
    fn records_are_read_by_their_schema(which in any::<prop::sample::Index>(), kind in 0u8..3, value in prop::sample::select(vec![f64::MAX, -1e308, 1e-320, 0.0, -1.0, 1e15])) {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut r = record();
        match kind {
            0 => {
                let key = REQUIRED[which.index(REQUIRED.len())];
                r.as_object_mut().expect("an object").remove(key);
                let m = read_record(dir.path(), &r.to_string());
                prop_assert!(m.as_ref().is_some_and(|m| m.contains("record.json")), "{key}: {m:?}");
            }
            1 => {
                let mut paths = vec![];
                numbers(&r, vec![], &mut paths);
                let path = which.get(&paths).clone();
                *at(&mut r, &path) = serde_json::json!(value);
                if let Some(m) = read_record(dir.path(), &r.to_string()) {
                    prop_assert!(m.contains("record.json"), "{path:?}: {m}");
                }
            }
            _ => {
                let key = REQUIRED[which.index(REQUIRED.len())];
                let text = r.to_string();
                let twice = text.replacen('{', &format!("{{\"{key}\": {},", r[key]), 1);
                let m = read_record(dir.path(), &twice);
                prop_assert!(m.as_ref().is_some_and(|m| m.contains("record.json") && m.contains(key)), "{key}: {m:?}");
            }
        }
    }
}

/// The shipped record read, written and read again is the same record.
#[test]
fn a_record_read_and_written_comes_back() {
    let dir = tempfile::tempdir().expect("temp dir");
    let p = dir.path().join("record.json");
    std::fs::write(&p, record().to_string()).expect("write");
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let once = pkmcal_io::record::read_calibration_record(&run, &p).expect("the shipped record");
    std::fs::write(&p, serde_json::to_string(&once).expect("JSON")).expect("write");
    let twice = pkmcal_io::record::read_calibration_record(&run, &p).expect("read again");
    assert_eq!(once, twice);
}

/// Issue 50, 2: 50,000 nested parentheses (a 100 kB `config.g`), directly
/// and through `global`, aborted with a stack overflow; refused at the
/// line that reads it, saying how deep it nests.
#[test]
fn deep_expressions_are_refused_at_their_line() {
    for (text, line) in [
        (
            format!("M665 R{{{}}} L360 H420\n", deep("190".into(), 50_000)),
            1,
        ),
        (
            format!(
                "global r = {}\nM665 R{{global.r}} L360 H420\n",
                deep("190".into(), 50_000)
            ),
            2,
        ),
    ] {
        let e = pkmcal_io::firmware::reprap::delta_from_gcode(&text, "config.g")
            .unwrap_err()
            .to_string();
        assert_eq!(line_named(&e, "config.g"), Some(line), "{e}");
        assert!(e.contains("more than 64"), "{e}");
    }
}
