//! Whether this physical calibration differs from a previous one
//! (`--physical --previous`, issue 54): the same readings give no drift;
//! a configuration whose endstop differs but whose probe results (steps
//! from the endstops) are the same describes the same printer, and the
//! endstop offsets compared as absolute homed heights agree; carriage a's
//! probe results all moved by 1 mm is a drift.

use pkmcal::Request;
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::physical::{self, PhysicalFit};
use pkmcal_io::firmware::physical_drift;
use std::path::Path;

/// Agreement of the absolute endstop heights of one printer (mm).
const SAME_MM: f64 = 1e-5;

fn fit(text: &str) -> PhysicalFit {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("printer.cfg");
    std::fs::write(&path, text).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap()
}

fn value(c: &pkmcal::identify::Compared, name: &str) -> f64 {
    c.values.iter().find(|(n, _)| n == name).unwrap().1
}

#[test]
fn drift_tells_a_moved_carriage_from_a_renamed_endstop() {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg"),
    )
    .unwrap();
    let base = fit(&text);
    let same = physical_drift::drift(&base, &fit(&text), 0.05).unwrap();
    assert!(!same.joint_drift && same.chi2 < 1e-6, "{same:?}");

    // Tower a's endstop said 1 mm higher, the same steps probed: the same
    // printer.
    let renamed = text.replacen("position_endstop: 297.05", "position_endstop: 298.05", 1);
    assert_ne!(renamed, text);
    let other = fit(&renamed);
    let (a, b) = (
        physical_drift::compared(&base),
        physical_drift::compared(&other),
    );
    assert!((value(&a, "da") - value(&b, "da")).abs() < SAME_MM);
    let raw = |f: &PhysicalFit| {
        let c = pkmcal::identify::Compared::from_calibration(&f.study.calibration);
        value(&c, "da")
    };
    assert!(
        (raw(&base) - raw(&other) - 1.0).abs() < 1e-3,
        "the offsets differ by the 1 mm"
    );
    let d = physical_drift::drift(&base, &other, 0.05).unwrap();
    assert!(!d.joint_drift, "{d:?}");

    // Carriage a 1 mm (80 steps of 12.5 µm) further from its endstop at
    // every probe: a printer that changed.
    let moved: String = text
        .lines()
        .map(|l| match l.split_once("_pos = ") {
            Some((head, steps)) if l.starts_with("#*# height") => {
                let mut v: Vec<f64> = steps
                    .split(',')
                    .map(|s| s.trim().parse().unwrap())
                    .collect();
                v[0] += 80.0;
                format!("{head}_pos = {:.3},{:.3},{:.3}", v[0], v[1], v[2])
            }
            _ => l.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\n");
    assert_ne!(moved, text);
    let d = physical_drift::drift(&base, &fit(&moved), 0.05).unwrap();
    assert!(d.joint_drift && d.p_joint < 1e-6, "{d:?}");
}
