//! `pkmcal marlin` end to end: the shipped example (probes simulated with
//! Marlin's own formulas for a known printer, `crates/pkmcal-io/tests/all/marlin.rs`
//! checks the formulas) gives that printer's M665/M666 back to the probe
//! noise, with G33's answer beside it; bad input is refused by name with a
//! non-zero exit and nothing written.

use crate::common::{fails, ok};
use std::path::{Path, PathBuf};

fn example(name: &str) -> String {
    format!(
        "{}/../../examples/marlin-delta/{name}",
        env!("CARGO_MANIFEST_DIR")
    )
}

/// The letters of an `M665`/`M666` line: (letter, value).
fn letters(gcode: &str, code: &str) -> Vec<(char, f64)> {
    let line = gcode
        .lines()
        .find(|l| l.starts_with(code))
        .unwrap_or_else(|| panic!("no {code} in {gcode}"));
    line.split_whitespace()
        .skip(1)
        .map(|w| {
            let mut c = w.chars();
            (c.next().unwrap(), c.as_str().parse().unwrap())
        })
        .collect()
}

fn value(v: &[(char, f64)], letter: char) -> f64 {
    v.iter().find(|(l, _)| *l == letter).unwrap().1
}

#[test]
fn the_example_gives_its_printer_back_to_the_noise() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            &example("M503.txt"),
            "--probes",
            &example("G30.log"),
            "--out",
            "new.gcode",
        ],
    );
    // Simulated for R 134.1, trims X 0.3 Y −0.25, endstops −0.45, 0, −0.1,
    // H 270.85 with 3 µm of probe noise and Marlin 2.0's two decimals.
    let written = std::fs::read_to_string(dir.path().join("new.gcode")).unwrap();
    let m665 = letters(&written, "M665");
    let m666 = letters(&written, "M666");
    for (got, want, tol) in [
        (value(&m665, 'R'), 134.1, 0.02),
        (value(&m665, 'X'), 0.3, 0.02),
        (value(&m665, 'Y'), -0.25, 0.02),
        (value(&m665, 'Z'), 0.0, 0.0),
        (value(&m665, 'H'), 270.85, 0.01),
        (value(&m665, 'L'), 267.0, 0.0),
        (value(&m665, 'S'), 80.0, 0.0),
        (value(&m666, 'X'), -0.45, 0.01),
        (value(&m666, 'Y'), 0.0, 0.0),
        (value(&m666, 'Z'), -0.1, 0.01),
    ] {
        assert!(
            (got - want).abs() <= tol,
            "{got} against {want}:\n{written}"
        );
    }
    // Marlin 2.0's letters, the rod trims kept; M500 said.
    assert!(written.contains(" A0.0000 B0.0000 C0.0000\n"), "{written}");
    assert!(written.contains("M500"), "{written}");
    assert!(out.contains("after max 0.00"), "{out}");
    // G33's answer beside: its factors, iterations and what it would set.
    assert!(
        out.contains(
            "G33 P4 (6 factors: the height, the endstops, the radius and the tower angles)"
        ),
        "{out}"
    );
    assert!(
        out.contains("it would set:\n  M665 L267.0000 R134.0"),
        "{out}"
    );
    // Its other forms.
    let t = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            &example("M503.txt"),
            "--probes",
            &example("G30.log"),
            "--g33-points",
            "2",
            "--g33-radius",
            "60",
        ],
    );
    assert!(
        t.contains("G33 P2 (4 factors: the height, the endstops and the radius), as Marlin's G33.cpp runs it on the printer this fit found, at radius 60.00 mm (given)"),
        "{t}"
    );
    let t = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            &example("M503.txt"),
            "--probes",
            &example("G30.log"),
            "--g33-fixed-angles",
        ],
    );
    assert!(t.contains("G33 P4 T (4 factors"), "{t}");
}

/// Run `pkmcal marlin` on settings and probes written in `dir`, with
/// `--out`; it must fail with `code` and `needle`, writing nothing.
fn refused(dir: &Path, settings: &str, probes: &str, extra: &[&str], code: i32, needle: &str) {
    std::fs::write(dir.join("m503.txt"), settings).unwrap();
    std::fs::write(dir.join("g30.log"), probes).unwrap();
    let out: PathBuf = dir.join("new.gcode");
    let _ = std::fs::remove_file(&out);
    let mut args = vec![
        "marlin",
        "--config",
        "m503.txt",
        "--probes",
        "g30.log",
        "--out",
        "new.gcode",
    ];
    args.extend_from_slice(extra);
    fails(dir, &args, code, needle);
    assert!(!out.exists(), "{needle}: new.gcode written");
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains("new.gcode"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn bad_input_is_refused_by_name_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = std::fs::read_to_string(example("M503.txt")).unwrap();
    let probes = std::fs::read_to_string(example("G30.log")).unwrap();
    // The settings.
    for (settings, needle) in [
        ("M666 X0 Y0 Z0\n", "m503.txt: no M665 line"),
        ("M665 L267 R133.6 H270.6\nM851 X0 Y0 Z0\n", "no M666 line"),
        (
            "M665 L267 R133.6 H270.6 W3\nM666 X0 Y0 Z0\n",
            "m503.txt:1: `W3` in `M665 L267 R133.6 H270.6 W3`: M665 has no letter W",
        ),
        ("M665 L267 RNaN H270.6\nM666 X0 Y0 Z0\n", "`RNaN`"),
        (
            "M665 L267 R133.6 H270.6\nM666 X0 Y-1e7 Z0\n",
            "m503.txt:2: `Y-1e7`",
        ),
        ("M665 L267 R133.6 H270.6\nM666 X0.25 Y0 Z0\n", "at most 0"),
        (
            "M665 L267 R13#3.6 H270.6\nM666 X0 Y0 Z0\n",
            "m503.txt:1: `R13#3.6`",
        ),
    ] {
        refused(d, settings, &probes, &[], 1, needle);
    }
    // Asked for: what M665 B means, the probe's offset.
    refused(
        d,
        "M665 L267 R133.6 H270.6 B80\nM666 X0 Y0 Z0\nM851 X0 Y0 Z0\n",
        &probes,
        &[],
        2,
        "--m665-b: line 1",
    );
    refused(
        d,
        "M665 L267 R133.6 H270.6\nM666 X0 Y0 Z0\n",
        &probes,
        &[],
        2,
        "--probe-offset: no `M851 X… Y…` line",
    );
    // The probes.
    for (log, needle) in [
        ("Recv: ok\n", "g30.log: no probed heights"),
        ("Bed X: 0.00 Y: 0.00 Z: inf\n", "g30.log:1: `Z:inf`"),
        (
            "Bed X: 0.00 Z: 0.1\n",
            "g30.log:1: `Bed X: 0.00 Z: 0.1` has no Y",
        ),
        (
            "Bed X: 300.00 Y: 0.00 Z: 0.12\n",
            "g30.log:1: the probed point (300, 0) is out of reach",
        ),
        (".      c:+0.12  x:+0.1\n", "g30.log:1: G33's heights"),
    ] {
        refused(d, &good, log, &[], 1, needle);
    }
    // A fit Marlin cannot hold.
    refused(
        d,
        &good,
        &probes,
        &["--free", "default,bed.rx,bed.ry"],
        2,
        "--free: `bed.rx` has no place in M665/M666",
    );
    // Options out of their range.
    refused(
        d,
        &good,
        &probes,
        &["--g33-points", "11"],
        2,
        "--g33-points",
    );
    refused(
        d,
        &good,
        &probes,
        &["--probe-offset", "0"],
        2,
        "two numbers",
    );
    refused(
        d,
        &good,
        &probes,
        &["--m665-b", "radius"],
        2,
        "calibration-radius",
    );
}

/// G33's own options set the comparison with Marlin's own fit, which
/// `--physical` does not write: refused with it, before any work, not
/// read past; and the physical summary's hint names only what Marlin can
/// read back (no calibration object's distances).
#[test]
fn g33_options_are_refused_with_physical() {
    let dir = tempfile::tempdir().unwrap();
    let (cfg, log) = (example("M503.txt"), example("G30.log"));
    for extra in [vec!["--g33-points", "7"], vec!["--g33-fixed-angles"]] {
        let mut args = vec!["marlin", "--config", &cfg, "--probes", &log, "--physical"];
        args.extend(extra);
        fails(
            dir.path(),
            &args,
            2,
            "--g33-points sets the run of Marlin's own G33 beside the firmware's own fit; leave it out with --physical",
        );
    }
    let out = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            &cfg,
            "--probes",
            &log,
            "--physical",
            "--height-map",
            "map.gcode",
        ],
    );
    assert!(!out.contains("calibration object"), "{out}");
    assert!(!out.contains("DELTA_ANALYZE"), "{out}");
}
