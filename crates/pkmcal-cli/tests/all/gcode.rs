//! `gcode` on real slicers' programs (tests/data/gcode, sources in its
//! SOURCES.md) and on what each firmware reads its own way (issue 34, F15).

use crate::common::{example, fails, ok, run};
use std::path::Path;

/// G-code coordinates are written to 0.1 µm; the tool lands within this of
/// the programmed point (mm).
const GCODE_MM: f64 = 1e-3;
/// Every this many rewritten moves is driven through the machine.
const SAMPLE_EVERY: usize = 61;

/// A calibrated linear delta (not the nominal one).
const DELTA_CAL: &str = "delta_radius = 130.4\narm_a = 250.3\narm_b = 249.8\narm_c = 250.1\nangle_a = 3.667\nda = 0.4\ndb = -0.3\n";

const DIALECTS: [&str; 4] = ["strict", "klipper", "reprap", "marlin"];

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/gcode")
        .join(name)
}

/// Lines with their line ends.
fn lines(b: &[u8]) -> Vec<&[u8]> {
    b.split_inclusive(|&c| c == b'\n').collect()
}

fn is_move(l: &[u8]) -> bool {
    l.starts_with(b"G0 ") || l.starts_with(b"G1 ")
}

/// The word `c` of a line (before its comment).
fn word(l: &str, c: char) -> Option<f64> {
    l.split(';')
        .next()?
        .split_whitespace()
        .find(|w| w.starts_with(c))
        .map(|w| w[1..].parse().unwrap())
}

/// The X Y Z words of a written move.
fn xyz(l: &str) -> Option<[f64; 3]> {
    Some([word(l, 'X')?, word(l, 'Y')?, word(l, 'Z')?])
}

/// The programmed point after each line in absolute mode (`None` in relative
/// mode or while unknown), followed independently of the rewrite:
/// `G90`/`G91`, `G28` (unknown again), `G0`/`G1` words.
fn programmed(lines: &[&[u8]]) -> Vec<Option<[f64; 3]>> {
    let (mut p, mut absolute) = ([f64::NAN; 3], true);
    lines
        .iter()
        .map(|l| {
            let l = String::from_utf8_lossy(l);
            let cmd = l.split_whitespace().next().unwrap_or("");
            match cmd {
                "G90" => absolute = true,
                "G91" => absolute = false,
                "G28" => p = [f64::NAN; 3],
                "G0" | "G1" => {
                    for (k, c) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                        if let Some(v) = word(&l, c) {
                            p[k] = if absolute { v } else { p[k] + v };
                        }
                    }
                }
                _ => {}
            }
            (absolute && p.iter().all(|v| v.is_finite())).then_some(p)
        })
        .collect()
}

/// Real programs: what is not a move comes back byte for byte, line ends
/// included; every move keeps its other words; sampled moves, sent through
/// the nominal controller and the calibrated machine, land on the programmed
/// point; in every dialect the same bytes. Programs the delta cannot follow
/// are refused at the first line it cannot (an arc, a point out of reach).
#[test]
fn real_slicer_programs_are_rewritten_byte_for_byte_around_their_moves() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), DELTA_CAL).unwrap();
    let mech = example("linear-delta");
    for (name, offset, refused) in [
        ("cura_slicer.gcode", [-150.0, -150.0, 0.0], None),
        ("idea_maker.gcode", [-120.0, -80.0, 0.0], None),
        ("Kreistest.gcode", [0.0, 0.0, 0.0], None),
        ("hex2.gcode", [0.0, 0.0, 0.0], None),
        (
            "creality_print.gcode",
            [-150.0, -150.0, 0.0],
            Some("creality_print.gcode:64: target [-94.91, 96.172, 0.2] is not reachable"),
        ),
        (
            "bambu_lab.gcode",
            [-150.0, -150.0, 0.0],
            Some("bambu_lab.gcode:523: arcs (G2/G3) are not rewritten"),
        ),
        (
            "EVT_v4.gcode",
            [0.0, 0.0, 0.0],
            Some("EVT_v4.gcode:368: target [100.255, 106.5, 1.3] is not reachable"),
        ),
    ] {
        let original = std::fs::read(data(name)).unwrap();
        std::fs::write(d.join(name), &original).unwrap();
        let off = format!("--offset={},{},{}", offset[0], offset[1], offset[2]);
        let mut first: Option<Vec<u8>> = None;
        for dialect in DIALECTS {
            let args = [
                "gcode",
                "--mechanism",
                &mech,
                "--params",
                "cal.toml",
                "--program",
                name,
                &off,
                "--dialect",
                dialect,
                "--out",
                "out.gcode",
            ];
            if let Some(needle) = refused {
                fails(d, &args, 1, needle);
                assert!(!d.join("out.gcode").exists());
                continue;
            }
            ok(d, &args);
            let out = std::fs::read(d.join("out.gcode")).unwrap();
            std::fs::remove_file(d.join("out.gcode")).unwrap();
            match &first {
                Some(f) => assert!(f == &out, "{name}: --dialect {dialect} differs"),
                None => first = Some(out),
            }
        }
        let Some(out) = first else { continue };
        assert_eq!(std::fs::read(d.join(name)).unwrap(), original, "input kept");
        let (a, b) = (lines(&original), lines(&out));
        let wanted = programmed(&a);
        assert_eq!(a.len(), b.len(), "{name}: one line for each");
        let mut sampled = vec![];
        let mut rewritten = 0usize;
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            if x == y {
                continue;
            }
            assert!(is_move(x) && is_move(y), "{name}:{}: {x:?} -> {y:?}", k + 1);
            let (sx, sy) = (
                String::from_utf8_lossy(x).into_owned(),
                String::from_utf8_lossy(y).into_owned(),
            );
            assert_eq!(x[..2], y[..2], "{name}:{}: the same G0/G1", k + 1);
            assert_eq!(x.ends_with(b"\r\n"), y.ends_with(b"\r\n"));
            // The feed rate and the comment come back as they were.
            for w in sx.split(';').next().unwrap().split_whitespace() {
                if w.starts_with('F') {
                    assert!(
                        sy.split_whitespace().any(|v| v == w),
                        "{name}:{}: {w}",
                        k + 1
                    );
                }
            }
            if let Some(c) = sx.find(';') {
                assert!(
                    sy.trim_end().ends_with(sx[c..].trim_end()),
                    "{name}:{}",
                    k + 1
                );
            }
            rewritten += 1;
            if (rewritten - 1).is_multiple_of(SAMPLE_EVERY) {
                sampled.push((wanted[k], xyz(&sy).expect("every axis written"), k + 1));
            }
        }
        assert!(rewritten > 0, "{name}");
        // Sampled moves that give every axis themselves: the programmed
        // point is where the calibrated machine lands.
        let sampled: Vec<([f64; 3], [f64; 3], usize)> = sampled
            .into_iter()
            .filter_map(|(p, s, l)| Some((p?, s, l)))
            .collect();
        assert!(!sampled.is_empty(), "{name}");
        let mut t = String::from("target_x,target_y,target_z\n");
        for (_, s, _) in &sampled {
            t.push_str(&format!(
                "{},{},{}\n",
                s[0] + offset[0],
                s[1] + offset[1],
                s[2] + offset[2]
            ));
        }
        std::fs::write(d.join("sent.csv"), t).unwrap();
        let (h, p) = crate::common::reached_from_sent(d, Some(&mech), "cal.toml", "sent.csv");
        let c = |n: &str| h.iter().position(|x| x == n).unwrap();
        for (r, (want, _, line)) in p.iter().zip(&sampled) {
            let e = (0..3)
                .map(|i| (r[c(["x", "y", "z"][i])] - want[i] - offset[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(e < GCODE_MM, "{name}:{line}: {e} mm");
        }
    }
}

/// Run `gcode` on a program in a dialect: the output text, or the error.
fn rewrite(d: &Path, program: &str, dialect: &str) -> Result<String, String> {
    std::fs::write(d.join("p.gcode"), program).unwrap();
    let _ = std::fs::remove_file(d.join("o.gcode"));
    let out = run(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "p.gcode",
            "--dialect",
            dialect,
            "--out",
            "o.gcode",
        ],
    );
    if out.status.success() {
        Ok(std::fs::read_to_string(d.join("o.gcode")).unwrap())
    } else {
        assert_eq!(out.status.code(), Some(1));
        assert!(!d.join("o.gcode").exists());
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// Calibrated parameters of the reference mechanism.
const CAL: &str = "l11 = 280.4\nB3x = 149.6\ndq1 = 0.001\ndq3 = -0.0012\nD2 = 215.2\n";

/// Each construct that firmwares read differently: refused where the named
/// firmware would read it otherwise than the rewrite, read where it reads it
/// as the rewrite does; the strict default refuses what any of them reads
/// differently.
#[test]
fn each_dialect_reads_what_its_firmware_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    let head = "G21\nG90\nG1 X5 Y190\n";
    // (line 4, accepted by strict/klipper/reprap/marlin, the needle when refused)
    // RepRapFirmware reads `(…)` as a comment and a line without a command
    // as a move only in CNC or laser mode: refused until the program says
    // M453 (or M452), read after it (the second table).
    let cases: [(&str, [bool; 4], &str); 11] = [
        (
            "G1 X5 (note) Y200",
            [false, false, false, false],
            "a (comment)",
        ),
        (
            "(go) G1 X5 Y200",
            [false, false, false, false],
            "a (comment)",
        ),
        (
            "G1 X5 Y200 (end)",
            [false, false, false, false],
            "a (comment)",
        ),
        ("g1 x5 y200", [false, true, true, false], "lower case"),
        ("X5 Y200", [false, false, false, false], "no command word"),
        (
            "N10G1 X5 Y200",
            [false, true, true, false],
            "a line number not followed by a space",
        ),
        (
            "G90 G1 X5 Y200",
            [false, false, false, false],
            "a second command `G1`",
        ),
        ("N10 G1 X5 Y200*31", [true, true, true, true], ""),
        (
            "N10 G1 X5 Y200*71",
            [false, false, false, false],
            "the checksum *71 does not match the line (its characters give *31)",
        ),
        ("G1X5Y200", [true, true, true, true], ""),
        (
            "G53 G1 X5 Y200",
            [false, false, false, false],
            "G53 with a move",
        ),
    ];
    for (line, accepted, needle) in cases {
        let program = format!("{head}{line}\n");
        let mut outs = vec![];
        for (k, dialect) in DIALECTS.iter().enumerate() {
            match rewrite(d, &program, dialect) {
                Ok(o) => {
                    assert!(accepted[k], "`{line}` accepted as {dialect}:\n{o}");
                    outs.push(o);
                }
                Err(e) => {
                    assert!(!accepted[k], "`{line}` refused as {dialect}: {e}");
                    assert!(e.contains("p.gcode:4: ") && e.contains(needle), "{e}");
                }
            }
        }
        // Where it is read, the moved-to point is the same (Y200, X5).
        for o in outs {
            let last = o.lines().nth(3).unwrap();
            let first = rewrite(d, &format!("{head}G1 X5 Y200\n"), "strict").unwrap();
            let plain = first.lines().nth(3).unwrap();
            let words = |l: &str| -> Vec<String> {
                l.split(['*', ';', '('])
                    .next()
                    .unwrap()
                    .split_whitespace()
                    .filter(|w| w.starts_with(['X', 'Y', 'Z']))
                    .map(String::from)
                    .collect()
            };
            assert_eq!(words(last), words(plain), "{line}: {last}");
        }
    }
    // Issue 50, 5: a word given twice and an exponent are read as each
    // firmware reads them (Klipper and Marlin the last of a letter, `X0.5E1`
    // as X0.5 and E1; RepRapFirmware the first, `X0.5E1` as X5), and refused
    // by strict, which they read differently; a move after another command
    // moves in RepRapFirmware only. Before, X9 of `G1 X9 X5` was compensated
    // in every dialect and X5 dropped.
    let point = |o: &str, n: usize| -> (f64, f64) {
        let l = o.lines().nth(n).unwrap();
        (word(l, 'X').unwrap(), word(l, 'Y').unwrap())
    };
    let plain = |x: f64, y: f64| {
        let o = rewrite(d, &format!("{head}G1 X{x} Y{y}\n"), "strict").unwrap();
        point(&o, 3)
    };
    for (line, k, r, m) in [
        ("G1 X9 X5 Y200", (5.0, 200.0), (9.0, 200.0), (5.0, 200.0)),
        ("G1 X5 Y190Y200", (5.0, 200.0), (5.0, 190.0), (5.0, 200.0)),
        ("G1 X0.5E1 Y200", (0.5, 200.0), (5.0, 200.0), (0.5, 200.0)),
    ] {
        for (dialect, (x, y)) in [("klipper", k), ("reprap", r), ("marlin", m)] {
            let o = rewrite(d, &format!("{head}{line}\n"), dialect).unwrap();
            assert_eq!(point(&o, 3), plain(x, y), "{line} {dialect}");
        }
        let e = rewrite(d, &format!("{head}{line}\n"), "strict").unwrap_err();
        assert!(
            e.contains("p.gcode:4: ") && e.contains("the firmwares read it differently"),
            "{e}"
        );
    }
    let o = rewrite(d, &format!("{head}G1 X0.5E1 Y200\n"), "klipper").unwrap();
    assert!(o.lines().nth(3).unwrap().contains(" E1.00000"), "{o}");
    for (dialect, kept) in [
        ("strict", false),
        ("klipper", true),
        ("reprap", false),
        ("marlin", true),
    ] {
        match rewrite(d, &format!("{head}M400 G1 X5 Y200\n"), dialect) {
            Ok(o) => {
                assert!(kept, "{dialect}");
                assert_eq!(o.lines().nth(3).unwrap(), "M400 G1 X5 Y200");
            }
            Err(e) => {
                assert!(!kept, "{dialect}: {e}");
                assert!(e.contains("RepRapFirmware runs the G1"), "{e}");
            }
        }
    }
    // In RepRapFirmware's CNC mode (M453 in the program), `(…)` comments
    // and lines without a command are read; in its 3D printer mode (M451),
    // a line without a command does not move and is kept as it is.
    for (line, mode) in [
        ("G1 X5 (note) Y200", "M453"),
        ("(go) G1 X5 Y200", "M452"),
        ("X5 Y200", "M453"),
    ] {
        let o = rewrite(d, &format!("{mode}\n{head}{line}\n"), "reprap").unwrap();
        assert!(o.lines().nth(4).unwrap().starts_with("G1 X"), "{line}: {o}");
    }
    let o = rewrite(d, &format!("M451\n{head}X5 Y200\n"), "reprap").unwrap();
    assert_eq!(o.lines().nth(4).unwrap(), "X5 Y200");
    // A line number stays in front and the checksum is computed anew.
    let o = rewrite(d, &format!("{head}N10 G1 X5 Y200*31 ; c\n"), "strict").unwrap();
    let l = o.lines().nth(3).unwrap();
    let (body, rest) = l.split_once('*').unwrap();
    assert!(body.starts_with("N10 G1 X"), "{l}");
    let cs: u8 = body.bytes().fold(0, |a, b| a ^ b);
    assert_eq!(rest, format!("{cs} ; c"));
    // RepRapFirmware reads the words on both sides of a (comment): the
    // comment is kept, after the words.
    let o = rewrite(d, &format!("M453\n{head}G1 X5 (note) Y200\n"), "reprap").unwrap();
    assert!(o.lines().nth(4).unwrap().ends_with(" (note)"), "{o}");
    // A line ended by a carriage return alone, or a byte-order mark: refused
    // in every dialect.
    for dialect in DIALECTS {
        let e = rewrite(d, "G21\rG1 X5 Y190\r", dialect).unwrap_err();
        assert!(
            e.contains("p.gcode:1: a line ends in a carriage return alone"),
            "{e}"
        );
        let e = rewrite(d, "\u{feff}G1 X5 Y190\n", dialect).unwrap_err();
        assert!(
            e.contains("p.gcode:1: the file starts with a byte-order mark"),
            "{e}"
        );
    }
    // Split moves cannot keep line numbers.
    std::fs::write(d.join("p.gcode"), format!("{head}N10 G1 X5 Y240\n")).unwrap();
    fails(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "p.gcode",
            "--max-segment",
            "5",
            "--out",
            "o.gcode",
        ],
        1,
        "p.gcode:4: a numbered line would be split",
    );
    // An unknown dialect is a usage error naming the choices.
    fails(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "p.gcode",
            "--dialect",
            "grbl",
            "--out",
            "o.gcode",
        ],
        2,
        "strict, klipper, reprap, marlin",
    );
}

/// Moves before every axis is known (after the start or a G28: slicers lift
/// Z first) are sent as written and told; the first move giving every axis is
/// corrected, and relative moves after them count from what was sent.
#[test]
fn moves_before_the_position_is_known_are_sent_as_written_and_told() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(d.join("cal.toml"), CAL).unwrap();
    std::fs::write(d.join("p.gcode"), "G28\nG1 Y190 F600\nG1 X5 Y200\n").unwrap();
    let out = run(
        d,
        &[
            "gcode",
            "--params",
            "cal.toml",
            "--program",
            "p.gcode",
            "--out",
            "o.gcode",
        ],
    );
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("1 move sent as written (line 2)"), "{err}");
    let o = std::fs::read_to_string(d.join("o.gcode")).unwrap();
    let l: Vec<&str> = o.lines().collect();
    assert_eq!(l[1], "G1 Y190 F600");
    assert!(l[2].starts_with("G1 X") && l[2] != "G1 X5 Y200", "{o}");
}
