//! `pkmcal klipper` on a rotary delta, end to end: the shipped example
//! (simulated with Klipper's own formulas, which
//! `crates/pkmcal-io/tests/all/klipper_rotary.rs` checks) gives its printer
//! back to the noise, written into the SAVE_CONFIG block; bad input is
//! refused by name with a non-zero exit and nothing written.

use crate::common::{fails, ok};

fn example() -> String {
    format!(
        "{}/../../examples/klipper-rotary-delta/printer.cfg",
        env!("CARGO_MANIFEST_DIR")
    )
}

/// The value of `key` in the SAVE_CONFIG block's `[section]`.
fn saved(cfg: &str, section: &str, key: &str) -> f64 {
    let block = &cfg[cfg.find("#*# <----").expect("a SAVE_CONFIG block")..];
    let start = block
        .find(&format!("#*# [{section}]\n"))
        .unwrap_or_else(|| panic!("no [{section}]"));
    block[start..]
        .lines()
        .skip(1)
        .take_while(|l| !l.starts_with("#*# ["))
        .find_map(|l| l.strip_prefix(&format!("#*# {key} = ")))
        .unwrap_or_else(|| panic!("no {key} in [{section}]"))
        .parse()
        .unwrap()
}

#[test]
fn the_rotary_example_gives_its_printer_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = ok(
        dir.path(),
        &[
            "klipper",
            "--config",
            &example(),
            "--out",
            "new.cfg",
            "--out-dir",
            "rotary",
        ],
    );
    assert!(out.contains("4 parameters free: hb dq1 dq2 dq3"), "{out}");
    // Simulated for shoulder_height 400.6 and endstops 241.1, 239.3, 240.5
    // with 3 µm of probe noise: 7 heights hold the four to a few 0.01 mm.
    let new = std::fs::read_to_string(dir.path().join("new.cfg")).unwrap();
    for (section, key, want, tol) in [
        ("printer", "shoulder_height", 400.6, 0.05),
        ("printer", "shoulder_radius", 35.0, 0.0),
        ("stepper_a", "position_endstop", 241.1, 0.05),
        ("stepper_b", "position_endstop", 239.3, 0.05),
        ("stepper_c", "position_endstop", 240.5, 0.05),
        ("stepper_a", "angle", 30.0, 0.0),
    ] {
        let got = saved(&new, section, key);
        assert!((got - want).abs() <= tol, "{section} {key}: {got}");
    }
    // The printer for the other commands: commands named after its motors.
    let probes = std::fs::read_to_string(dir.path().join("rotary/probes.csv")).unwrap();
    assert!(
        probes.starts_with("# frame: base\nq1,q2,q3,probe\n"),
        "{probes}"
    );
    let m = std::fs::read_to_string(dir.path().join("rotary/mechanism.toml")).unwrap();
    assert!(
        m.contains("at = [\"rb\", 0.0, \"hb\"]") && m.contains("length = \"lf1\""),
        "{m}"
    );
    // More than Klipper holds: fitted and shown, not written.
    let many = dir.path().join("many.cfg");
    let text = std::fs::read_to_string(example()).unwrap();
    std::fs::write(&many, &text).unwrap();
    fails(
        dir.path(),
        &[
            "klipper",
            "--config",
            "many.cfg",
            "--free",
            "hb,dq1,dq2,arm1.pz",
            "--out",
            "never.cfg",
        ],
        1,
        "`arm1.pz`",
    );
    assert!(!dir.path().join("never.cfg").exists());
}

#[test]
fn bad_rotary_configurations_are_refused_and_nothing_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read_to_string(example()).unwrap();
    for (from, to, needle) in [
        (
            "shoulder_radius: 35.000\n",
            "",
            "[printer] needs a positive `shoulder_radius`",
        ),
        (
            "gear_ratio: 80:16, 60:15\nendstop_pin: ^PJ0",
            "endstop_pin: ^PJ0",
            "[stepper_b] needs `gear_ratio`",
        ),
        (
            "microsteps: 16\ngear_ratio: 80:16, 60:15\nendstop_pin: ^PD2",
            "microsteps: 16\nrotation_distance: 40\ngear_ratio: 80:16, 60:15\nendstop_pin: ^PD2",
            "[stepper_c] rotation_distance",
        ),
        (
            "position_endstop: 240",
            "position_endstop: 1e9",
            "position_endstop = 1e9 mm must be",
        ),
        (
            "upper_arm_length: 165.000",
            "upper_arm_length: nan",
            "upper_arm_length must be finite",
        ),
        (
            "#*# height3 = 1.25",
            "#*# height3 = 1.25.0",
            "height3 = `1.25.0` is not a number",
        ),
        (
            "kinematics: rotary_delta",
            "kinematics: corexy",
            "rotary_delta",
        ),
    ] {
        assert!(good.contains(from), "{from}");
        std::fs::write(dir.path().join("bad.cfg"), good.replacen(from, to, 1)).unwrap();
        fails(
            dir.path(),
            &["klipper", "--config", "bad.cfg", "--out", "new.cfg"],
            1,
            needle,
        );
        assert!(!dir.path().join("new.cfg").exists(), "{to}");
    }
}
