//! `--physical` on `klipper`, `reprap` and `marlin` (issue 54): the values
//! are written by the firmware's own writer (every other byte as without
//! it), the build-volume error is reported, and misuse is refused by name.

use crate::common::{fails, ok};
use std::path::{Path, PathBuf};

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

/// The text before Klipper's SAVE_CONFIG block.
fn regular(text: &str) -> &str {
    &text[..text.find("#*# <----").unwrap_or(text.len())]
}

#[test]
fn klipper_physical_writes_klippers_values_with_klippers_writer() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    ok(
        dir.path(),
        &["klipper", "--config", cfg, "--out", "own.cfg"],
    );
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--out",
            "phys.cfg",
        ],
    );
    for says in [
        "Physical model: 13 probe heights",
        "nozzle error over the build volume",
        "in the bed's frame",
        "Klipper's own fit of the probe",
        "the values for the nozzle",
        "the probe pattern cannot see",
        "position_endstop",
    ] {
        assert!(out.contains(says), "`{says}` not in:\n{out}");
    }
    // Pkmcal's assumed probe noise is no stated one: a note, no warning.
    assert!(!out.contains("the stated noise is larger"), "{out}");
    let own = std::fs::read_to_string(dir.path().join("own.cfg")).unwrap();
    let phys = std::fs::read_to_string(dir.path().join("phys.cfg")).unwrap();
    assert_eq!(regular(&own), regular(&phys));
    // The same options in the block.
    let keys = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| l.starts_with("#*# ") && l.contains(" = "))
            .map(|l| l.split(" = ").next().unwrap().to_string())
            .collect()
    };
    assert_eq!(keys(&own), keys(&phys));
    // Thirteen heights of the shipped example cannot show the values for
    // the nozzle better than Klipper's own fit over the fit's
    // uncertainty: Klipper's own fit is written, as the plain command
    // writes it, each value with its σ.
    assert!(out.contains("Klipper's own fit is written"), "{out}");
    assert_eq!(own, phys);
    let endstop = out
        .lines()
        .find(|l| l.contains("[stepper_a] position_endstop"))
        .unwrap();
    assert!(endstop.trim_end().ends_with(" mm"), "{endstop}");
}

#[test]
fn reprap_and_marlin_physical_write_their_lines() {
    let dir = tempfile::tempdir().unwrap();
    let r = examples().join("reprap-delta");
    let reprap = ok(
        dir.path(),
        &[
            "reprap",
            "--config",
            r.join("config.g").to_str().unwrap(),
            "--probes",
            r.join("probes.csv").to_str().unwrap(),
            "--physical",
            "--out",
            "new.g",
        ],
    );
    let g = std::fs::read_to_string(dir.path().join("new.g")).unwrap();
    assert!(g.contains("\nM665 L") && g.contains("\nM666 X"), "{g}");
    // The file's header says what the summary says was written: the
    // physical model's values, or the firmware's own fit.
    let header_agrees = |out: &str, file: &str| {
        let first = file.lines().next().unwrap_or_default();
        let own = out.contains("'s own fit ->");
        assert_ne!(
            own,
            out.contains("values for the nozzle ->"),
            "one of the two is said: {out}"
        );
        assert_eq!(!own, first.contains("the physical model"), "{first}\n{out}");
    };
    header_agrees(&reprap, &g);
    let m = examples().join("marlin-delta");
    let marlin = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            m.join("M503.txt").to_str().unwrap(),
            "--probes",
            m.join("G30.log").to_str().unwrap(),
            "--physical",
            "--tolerance",
            "rod_a1=0.05,bed.rx=0.001",
            "--out",
            "new.gcode",
        ],
    );
    let g = std::fs::read_to_string(dir.path().join("new.gcode")).unwrap();
    assert!(g.contains("\nM665 L") && g.contains("M500"), "{g}");
    header_agrees(&marlin, &g);
}

#[test]
fn physical_misuse_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    fails(
        dir.path(),
        &["klipper", "--config", cfg, "--tolerance", "rod_a1=0.05"],
        2,
        "add --physical",
    );
    fails(
        dir.path(),
        &["klipper", "--config", cfg, "--physical", "--out-dir", "d"],
        2,
        "--out-dir",
    );
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--tolerance",
            "rod_z9=0.05",
        ],
        2,
        "rod_z9",
    );
    let rotary = examples().join("klipper-rotary-delta/printer.cfg");
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            rotary.to_str().unwrap(),
            "--physical",
        ],
        2,
        "rotary delta",
    );
    assert!(!dir.path().join("d").exists());
}

/// `--heights` without `--physical` is refused (exit 2); a bad row is
/// named by its file and line (exit 1) and nothing is written; the
/// example's file is read and counted.
#[test]
fn heights_are_read_with_physical_and_refused_by_line() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    let heights = examples().join("klipper-delta/heights.csv");
    let heights = heights.to_str().unwrap();
    fails(
        dir.path(),
        &["klipper", "--config", cfg, "--heights", heights],
        2,
        "--heights are read by the physical model: add --physical",
    );
    std::fs::write(
        dir.path().join("bad.csv"),
        "x,y,z,tool,surface\n0,0,0.1,nozzle,0.1\n10,10,0.2,extruder,0\n",
    )
    .unwrap();
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--heights",
            "bad.csv",
            "--out",
            "new.cfg",
        ],
        1,
        "bad.csv:3: column `tool`: `extruder`",
    );
    assert!(!dir.path().join("new.cfg").exists());
    let said = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg,
            "--physical",
            "--heights",
            heights,
            "--out",
            "new.cfg",
        ],
    );
    assert!(
        said.contains("and 11 touches (7 of the nozzle, σ 0.02 mm unless given)"),
        "{said}"
    );
    assert!(dir.path().join("new.cfg").exists());
}

#[test]
fn physical_says_the_tolerances_given() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg.to_str().unwrap(),
            "--physical",
            "--tolerance",
            "rod_a1=0.5,radius_b=2%",
        ],
    );
    assert!(
        out.contains(
            "tolerances given in place of those (--tolerance, in each one's unit): rod_a1 0.5, radius_b 2%"
        ),
        "{out}"
    );
}

/// The σ-beyond-limit warning under `--physical` says what the nozzle is
/// left with, and blames the right cause: on the RepRapFirmware example
/// the arm lengths' σ (0.29–0.40 mm) are of each alone, and they move with
/// the endstops and radius so that the nozzle's σ is 0.07 mm XY and 0.02
/// mm Z: at a 0.1 limit, "they move together"; at 0.01 on the Klipper
/// example, whose own fit's values have σ 0.01–0.03 but whose nozzle the
/// heights place only to 0.2 mm XY, the nozzle itself is uncertain.
#[test]
fn the_uncertain_warning_names_the_nozzle_s_sigma_and_its_cause() {
    let dir = tempfile::tempdir().unwrap();
    let r = examples().join("reprap-delta");
    let out = ok(
        dir.path(),
        &[
            "reprap",
            "--config",
            r.join("config.g").to_str().unwrap(),
            "--probes",
            r.join("probes.csv").to_str().unwrap(),
            "--physical",
            "--max-sigma",
            "0.1",
            "--out",
            "new.g",
        ],
    );
    let warning = out
        .lines()
        .find(|l| l.starts_with("warning: written with a σ beyond 0.1"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(warning.contains("M665 L (Z) σ 0.4"), "{warning}");
    assert!(
        warning.contains("but they move together: the nozzle they place has σ 0.07"),
        "{warning}"
    );
    assert!(out.contains("each value's σ is of it alone"), "{out}");
    let cfg = examples().join("klipper-delta/printer.cfg");
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            cfg.to_str().unwrap(),
            "--physical",
            "--max-sigma",
            "0.01",
            "--out",
            "new.cfg",
        ],
    );
    let warning = out
        .lines()
        .find(|l| l.starts_with("warning: written with a σ beyond 0.01"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(!warning.contains("move together"), "{warning}");
    assert!(
        warning.contains("the nozzle they place has σ 0.19"),
        "{warning}"
    );
    assert!(
        out.contains("the readings leave the nozzle itself uncertain"),
        "{out}"
    );
}

/// The probe's σ stated (`--probe-noise`) or assumed: the summary says
/// which, and the adequacy note names it with a hint fit for its cause
/// (the example's heights scatter by 2 µm).
#[test]
fn probe_noise_stated_or_assumed_is_said() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = examples().join("klipper-delta/printer.cfg");
    let cfg = cfg.to_str().unwrap();
    let run = |noise: Option<&str>| {
        let mut args = vec!["klipper", "--config", cfg, "--physical"];
        args.extend(noise.iter().flat_map(|n| ["--probe-noise", n]));
        ok(dir.path(), &args)
    };
    // Assumed, and the heights scatter less: news, no warning.
    let out = run(None);
    assert!(out.contains("probe σ 0.01 mm)"), "{out}");
    assert!(
        out.contains("scatter less than a typical probe's") && out.contains("0.01 mm assumed"),
        "{out}"
    );
    assert!(!out.contains("--probe-noise"), "{out}");
    // Stated above what they show: a warning about the value stated.
    let out = run(Some("0.2"));
    assert!(out.contains("probe σ 0.2 mm as stated)"), "{out}");
    assert!(
        out.contains("warning: the probe's readings scatter less than the σ 0.2 mm stated"),
        "{out}"
    );
    assert!(
        out.contains("hint: the σ stated is larger than the heights show: check --probe-noise 0.2"),
        "{out}"
    );
    assert!(!out.contains("assumed"), "{out}");
    // Stated below what they show: check the value stated (not: state one).
    let out = run(Some("0.0002"));
    assert!(
        out.contains("scatter more than the σ 0.0002 mm stated (σ"),
        "{out}"
    );
    assert!(out.contains("hint: check --probe-noise 0.0002"), "{out}");
    assert!(!out.contains("was assumed"), "{out}");
    // Bounded where read, and only with --physical.
    for bad in ["0", "-0.01", "1.5", "inf", "nan"] {
        fails(
            dir.path(),
            &[
                "klipper",
                "--config",
                cfg,
                "--physical",
                &format!("--probe-noise={bad}"),
            ],
            2,
            "--probe-noise",
        );
    }
    // A negative number as its own argument reaches the bound, not clap's
    // "unexpected argument".
    for (option, says) in [
        ("--probe-noise", "a probe's σ is above 0"),
        ("--max-sigma", "must be above 0"),
    ] {
        fails(
            dir.path(),
            &["klipper", "--config", cfg, "--physical", option, "-1"],
            2,
            says,
        );
    }
    fails(
        dir.path(),
        &["klipper", "--config", cfg, "--probe-noise", "0.01"],
        2,
        "--probe-noise weighs the physical fit's probe heights: add --physical",
    );
}

/// `--heights` on RepRapFirmware and Marlin: the build volume's top is
/// where the nozzle is homed (`M665 H`), not Klipper's endstops (which
/// their descriptions hold as 0: every touch above the bed was refused).
#[test]
fn heights_are_read_on_reprap_and_marlin() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("h.csv"),
        "x,y,z,tool,surface\n0,0,0.05,nozzle,0.1\n40,0,0.02,nozzle,0\n0,40,50.3,nozzle,50\n",
    )
    .unwrap();
    let r = examples().join("reprap-delta");
    let out = ok(
        dir.path(),
        &[
            "reprap",
            "--config",
            r.join("config.g").to_str().unwrap(),
            "--probes",
            r.join("probes.csv").to_str().unwrap(),
            "--physical",
            "--heights",
            "h.csv",
        ],
    );
    assert!(out.contains("and 3 touches (3 of the nozzle"), "{out}");
    let m = examples().join("marlin-delta");
    let out = ok(
        dir.path(),
        &[
            "marlin",
            "--config",
            m.join("M503.txt").to_str().unwrap(),
            "--probes",
            m.join("G30.log").to_str().unwrap(),
            "--physical",
            "--heights",
            "h.csv",
        ],
    );
    assert!(out.contains("and 3 touches (3 of the nozzle"), "{out}");
}
