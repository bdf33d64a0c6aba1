//! Tests of `pkmcal_io::gcode`.

use pkmcal_io::gcode::*;

/// Lines that neither move nor change a followed mode are written back
/// as they are in every dialect, whatever their words.
#[test]
fn lines_that_are_not_followed_are_raw() {
    for line in [
        "",
        "; a comment (with parentheses)",
        "EXCLUDE_OBJECT_START NAME=part_1.stl_id_0_copy_0",
        "SET_VELOCITY_LIMIT ACCEL=5000 ACCEL_TO_DECEL=2500",
        "START_PRINT EXTRUDER_TEMP=220 BED_TEMP=60",
        "M117 G1 X5 (printing)",
        "M486 S0 AObject name",
        "T0",
        "G4 P500",
        "G29.1 X5",
        "M572 D0 S0.03",
    ] {
        for d in Dialect::ALL {
            assert_eq!(
                parse(line.as_bytes(), d, Mode::Unknown),
                Ok(Parsed::Raw),
                "{line} ({d:?})"
            );
        }
    }
}

#[test]
fn a_move_is_read_with_its_number_checksum_and_comment() {
    let Ok(Parsed::Code(c)) = parse(
        b"N7 G01 X5 Y-.5 F1200*120 ; go",
        Dialect::Strict,
        Mode::Unknown,
    ) else {
        panic!("a move")
    };
    assert_eq!(c.number.as_deref(), Some("N7"));
    assert!(c.checksum);
    assert_eq!(c.command, Some(('G', 1)));
    let words: Vec<(char, &str)> = c.words.iter().map(|(w, v)| (*w, v.as_str())).collect();
    assert_eq!(words, [('X', "5.0"), ('Y', "-0.5"), ('F', "1200")]);
    assert_eq!(c.comment, b"; go");
    // RepRapFirmware: (comments) anywhere, both sides read.
    let Ok(Parsed::Code(c)) = parse(b"(a) G1 X5 (b) Y6 ; c", Dialect::RepRap, Mode::Cnc) else {
        panic!("a move")
    };
    assert_eq!(c.words.len(), 2);
    assert_eq!(c.comment, b"(a) (b) ; c");
    assert_eq!(checksum("N7 G1"), b"N7 G1".iter().fold(0, |a, b| a ^ b));
}

/// The value of `letter` in a move `line` read in `dialect`, or the
/// refusal.
fn value(line: &str, dialect: Dialect, letter: char) -> std::result::Result<Option<f64>, String> {
    match parse(line.as_bytes(), dialect, Mode::Unknown) {
        Ok(Parsed::Code(c)) => Ok(c
            .words
            .iter()
            .find(|(w, _)| *w == letter)
            .map(|(_, v)| v.parse().unwrap())),
        Ok(Parsed::Raw) => Err("raw".into()),
        Err(Refused(m, _)) => Err(m),
    }
}

/// Issue 50, 5: each firmware's reading of repeated words and of
/// numbers, as its own parser reads them: Klipper's `gcode.py` (the
/// line upper-cased and split at letters, the last of a key kept,
/// Python's `float`), RepRapFirmware's `StringParser` (`Seen` finds the
/// first, `SafeStrtod` reads an exponent, an `E` after a digit is no
/// parameter), Marlin's `FASTER_GCODE_PARSER` (the last of a letter, the
/// characters `0-9.+-` after it); strict refuses where they differ.
/// Before, every dialect compensated X5 of `G1 X5 X20` and dropped X20,
/// and read `X1e1` as X1 and E1 (or refused it as lower case).
#[test]
fn each_firmware_reads_words_as_its_parser_does() {
    use Dialect::*;
    // (line, letter, Klipper, RepRapFirmware, Marlin); NaN: refused.
    let nan = f64::NAN;
    let cases: &[(&str, char, f64, f64, f64)] = &[
        ("G1 X5 X20", 'X', 20.0, 5.0, 20.0),
        ("G1 X0X10", 'X', 10.0, 0.0, 10.0),
        ("G1 X0x10", 'X', 10.0, 0.0, nan),
        ("G1 X1E1", 'X', 1.0, 10.0, 1.0),
        ("G1 X1E1", 'E', 1.0, nan, 1.0),
        ("G1 X1e1", 'X', 1.0, 10.0, nan),
        ("G1 X 5", 'X', 5.0, 5.0, 5.0),
        ("G1 X-.5", 'X', -0.5, -0.5, -0.5),
        ("G1 X1..0", 'X', nan, nan, nan),
        ("G1 X", 'X', nan, nan, nan),
        ("G1 X5 E2 E3", 'E', 3.0, 2.0, 3.0),
    ];
    for &(line, letter, k, r, m) in cases {
        for (d, want) in [(Klipper, k), (RepRap, r), (Marlin, m)] {
            let got = value(line, d, letter);
            if want.is_nan() {
                assert!(
                    got.as_ref().is_err() || got == Ok(None),
                    "{line} {d:?}: {got:?}"
                );
            } else {
                assert_eq!(got, Ok(Some(want)), "{line} {d:?}");
            }
        }
        let strict = value(line, Strict, letter);
        if k == r && r == m {
            assert_eq!(strict, Ok(Some(k)), "{line}");
        } else {
            assert!(strict.is_err(), "{line}: {strict:?}");
        }
    }
    let e = value("G1 X5 X20", Strict, 'X').unwrap_err();
    assert!(
        e.contains("Klipper X20, RepRapFirmware X5, Marlin X20"),
        "{e}"
    );
    // G53 with a move on its line, in every dialect.
    for d in Dialect::ALL {
        let e = value("G53 G1 X20", d, 'X').unwrap_err();
        assert!(e.contains("G53 with a move on its line"), "{d:?}: {e}");
        assert_eq!(parse(b"G53", d, Mode::Unknown), Ok(Parsed::Raw));
    }
    // A move after another command: RepRapFirmware runs it.
    for d in [Strict, RepRap] {
        let e = value("M400 G1 X20", d, 'X').unwrap_err();
        assert!(e.contains("RepRapFirmware runs the G1"), "{d:?}: {e}");
    }
    for d in [Klipper, Marlin] {
        assert_eq!(value("M400 G1 X20", d, 'X'), Err("raw".into()));
    }
    // A wrong checksum: refused, never written anew.
    for d in Dialect::ALL {
        let e = value("N10 G1 X5 Y200*71", d, 'X').unwrap_err();
        assert!(
            e.contains("the checksum *71 does not match the line (its characters give *31)"),
            "{e}"
        );
        assert_eq!(value("N10 G1 X5 Y200*31", d, 'X'), Ok(Some(5.0)));
    }
    // RepRapFirmware's (comments) and lines without a command, by mode.
    let cnc = parse(b"G1 X5 (note) Y200", RepRap, Mode::Cnc);
    assert!(matches!(cnc, Ok(Parsed::Code(_))), "{cnc:?}");
    for mode in [Mode::Unknown, Mode::Printer] {
        let e = parse(b"G1 X5 (note) Y200", RepRap, mode).unwrap_err();
        assert!(e.0.contains("M453"), "{e:?}");
    }
    assert!(matches!(
        parse(b"X5 Y6", RepRap, Mode::Cnc),
        Ok(Parsed::Code(_))
    ));
    assert_eq!(parse(b"X5 Y6", RepRap, Mode::Printer), Ok(Parsed::Raw));
    assert!(
        parse(b"X5 Y6", RepRap, Mode::Unknown)
            .unwrap_err()
            .0
            .contains("M453")
    );
}
