//! Every value a firmware command writes comes with its σ and a check
//! (issue 49, part 5): the σ in the firmware's own units, agreeing with the
//! calibration's own; values the readings cannot tell apart named in pairs
//! with what would separate them; a σ beyond the limit asked; and a
//! tolerance that frees its parameter said where the free set is shown.

use crate::common::{example, fails, ok};

/// The examples' directory.
fn examples() -> String {
    format!("{}/../../examples", env!("CARGO_MANIFEST_DIR"))
}

/// A σ printed in the firmware's units and the calibration's own, converted,
/// agree to the printed digits (4 decimals).
const SAME_SIGMA: f64 = 1e-4;

/// The σ column of a summary's row for `name` (`fixed`: None).
fn sigma_of(out: &str, name: &str) -> Option<f64> {
    let line = out
        .lines()
        .find(|l| {
            l.trim_start()
                .strip_prefix(name)
                .is_some_and(|r| r.starts_with("  "))
        })
        .unwrap_or_else(|| panic!("no row {name}: {out}"));
    let w: Vec<&str> = line.split_whitespace().collect();
    match w[w.len() - 1] {
        "fixed" => None,
        _ => Some(w[w.len() - 2].parse().unwrap()),
    }
}

/// The ±σ of a parameter in `pkmcal calibrate`'s table.
fn calibrated_sigma(out: &str, name: &str) -> f64 {
    let line = out
        .lines()
        .find(|l| l.split_whitespace().next() == Some(name))
        .unwrap_or_else(|| panic!("no parameter {name}: {out}"));
    line.split_whitespace().nth(4).unwrap().parse().unwrap()
}

#[test]
fn klipper_written_values_carry_the_calibrations_sigma() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = format!("{}/klipper-delta/printer.cfg", examples());
    let out = ok(d, &["klipper", "--config", &cfg, "--out-dir", "o"]);
    // The same fit in pkmcal's own terms: delta_radius is written as it is,
    // angle_a in degrees (the free set named in Klipper's order, not the
    // mechanism's, must not shuffle the covariance).
    let cal = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            "o/mechanism.toml",
            "--data",
            "o/probes.csv",
            "--out",
            "c.toml",
        ],
    );
    let r = sigma_of(&out, "[printer] delta_radius").unwrap();
    assert!(
        (r - calibrated_sigma(&cal, "delta_radius")).abs() < SAME_SIGMA,
        "{out}\n{cal}"
    );
    let a = sigma_of(&out, "[stepper_a] angle").unwrap();
    assert!(
        (a - calibrated_sigma(&cal, "angle_a").to_degrees()).abs() < SAME_SIGMA,
        "{out}\n{cal}"
    );
    assert_eq!(sigma_of(&out, "[stepper_a] arm_length"), None, "{out}");
    // Klipper's own fit on these 13 heights: nothing moves together.
    assert!(!out.contains("move together"), "{out}");
}

#[test]
fn klipper_arm_lengths_from_heights_alone_are_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cfg = format!("{}/klipper-delta/printer.cfg", examples());
    let out = ok(
        d,
        &[
            "klipper",
            "--config",
            &cfg,
            "--free",
            "default,arm_a,arm_b,arm_c",
        ],
    );
    for t in ["a", "b", "c"] {
        let line = out
            .lines()
            .find(|l| l.contains(&format!("`arm_{t}` and `d{t}`")))
            .unwrap_or_else(|| panic!("arm_{t} not paired with its endstop: {out}"));
        assert!(
            line.contains("13 probe heights cannot tell them apart"),
            "{line}"
        );
        let r: f64 = line
            .split("(r = ")
            .nth(1)
            .and_then(|s| s.split(')').next())
            .unwrap()
            .parse()
            .unwrap();
        assert!(r > pkmcal_io_max_correlation() && r <= 1.0, "{line}");
        let hint = out.lines().skip_while(|l| *l != line).nth(1).unwrap();
        assert!(
            hint.contains("add DELTA_ANALYZE distances")
                && hint.contains(&format!("--fix arm_{t}")),
            "{hint}"
        );
        // Each arm's σ is far beyond the default limit.
        assert!(
            sigma_of(&out, &format!("[stepper_{t}] arm_length")).unwrap() > 0.5,
            "{out}"
        );
    }
    assert!(out.contains("written with a σ beyond 0.05"), "{out}");
    // The limit is the user's, bounded where read.
    let loose = ok(
        d,
        &[
            "klipper",
            "--config",
            &cfg,
            "--free",
            "default,arm_a,arm_b,arm_c",
            "--max-sigma",
            "10",
        ],
    );
    assert!(!loose.contains("σ beyond"), "{loose}");
    for bad in ["0", "-1", "1e9", "nan"] {
        fails(
            d,
            &["klipper", "--config", &cfg, &format!("--max-sigma={bad}")],
            2,
            "--max-sigma",
        );
    }
}

/// The CLI's threshold of correlation (pkmcal_io::firmware::MAX_CORRELATION).
fn pkmcal_io_max_correlation() -> f64 {
    0.99
}

#[test]
fn marlin_and_rotary_summaries_show_each_written_sigma() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let ex = examples();
    let out = ok(
        d,
        &[
            "marlin",
            "--config",
            &format!("{ex}/marlin-delta/M503.txt"),
            "--probes",
            &format!("{ex}/marlin-delta/G30.log"),
        ],
    );
    let r = sigma_of(&out, "M665 R").unwrap();
    assert!(r > 0.0 && r < 0.05, "{out}");
    assert_eq!(sigma_of(&out, "M665 L"), None, "{out}");
    let out = ok(
        d,
        &[
            "klipper",
            "--config",
            &format!("{ex}/klipper-rotary-delta/printer.cfg"),
        ],
    );
    let h = sigma_of(&out, "[printer] shoulder_height").unwrap();
    assert!(h > 0.0, "{out}");
}

#[test]
fn a_tolerance_frees_its_parameter_where_the_free_set_is_shown() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mech = example("gough-stewart-6");
    // `kL1 = "20%"` in the example's [tolerances]: free, and said so.
    let out = ok(d, &["parameters", "--mechanism", &mech]);
    let row = |name: &str| {
        out.lines()
            .find(|l| l.split_whitespace().next() == Some(name))
            .unwrap()
            .to_string()
    };
    assert!(row("kL1").contains("yes, by its tolerance"), "{out}");
    assert!(!row("kL2").contains("yes"), "{out}");
    assert!(row("dL1").ends_with("yes"), "{out}");
    // A calibration says so before its table.
    ok(
        d,
        &[
            "simulate",
            "--mechanism",
            &mech,
            "--grid",
            "40",
            "--seed",
            "3",
            "--noise",
            "0.002",
            "--out",
            "data.csv",
        ],
    );
    let cal = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "data.csv",
            "--out",
            "c.toml",
        ],
    );
    assert!(
        cal.lines()
            .any(|l| l.starts_with("free by their tolerances") && l.ends_with(": kL1")),
        "{cal}"
    );
    // Fixed by name, it is not freed.
    let fixed = ok(
        d,
        &[
            "calibrate",
            "--mechanism",
            &mech,
            "--data",
            "data.csv",
            "--fix",
            "kL1",
            "--out",
            "c2.toml",
        ],
    );
    assert!(!fixed.contains("free by their tolerances"), "{fixed}");
}
