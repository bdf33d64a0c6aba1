//! The physical linear delta (`--physical`, issue 54) against each
//! firmware's own model: with every extra error zero, the nozzle it
//! predicts at the firmware's carriage heights over the build volume, and
//! each probe reading, are the firmware model's to 1e-9 mm (Klipper with
//! and without a probe offset, RepRapFirmware, Marlin); one extra error
//! moves the nozzle.

use pkmcal::{Mechanism, Params};
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting, read_config};
use pkmcal_io::firmware::marlin::MarlinPrinter;
use pkmcal_io::firmware::physical::{self, LinearDelta};
use pkmcal_io::firmware::reprap::RrfPrinter;
use std::path::{Path, PathBuf};

/// Agreement of the physical model with the firmware's (mm).
const SAME_MM: f64 = 1e-9;
/// A rod 0.1 mm long moves the nozzle at least this much somewhere (mm).
const MOVED_MM: f64 = 1e-3;

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

fn klipper(text_prefix: &str) -> KlipperPrinter {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("printer.cfg");
    let text = std::fs::read_to_string(examples().join("klipper-delta/printer.cfg")).unwrap();
    std::fs::write(&path, format!("{text_prefix}{text}")).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let (text, ini) = read_config(&run, &path).unwrap();
    KlipperPrinter::from_parsed(&path, text, ini, Weighting::Klipper).unwrap()
}

fn reprap() -> RrfPrinter {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let d = examples().join("reprap-delta");
    RrfPrinter::read(&run, &d.join("config.g"), &d.join("probes.csv"), None).unwrap()
}

/// Marlin's example, its probe moved to `offset` from the nozzle.
fn marlin(offset: &str) -> MarlinPrinter {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let d = examples().join("marlin-delta");
    let dir = tempfile::tempdir().unwrap();
    let settings = std::fs::read_to_string(d.join("M503.txt"))
        .unwrap()
        .replace("M851 X0.0000 Y0.0000", offset);
    std::fs::write(dir.path().join("M503.txt"), settings).unwrap();
    MarlinPrinter::read(
        &run,
        &dir.path().join("M503.txt"),
        &d.join("G30.log"),
        None,
        None,
        None,
        None,
    )
    .unwrap()
}

/// The largest difference between the firmware's nozzle and the physical
/// model's (`params`, or its nominal) over the build volume, and between
/// their probe readings.
fn largest_difference<F: Firmware>(printer: &F, change: Option<(&str, f64)>) -> (f64, f64) {
    let ld: LinearDelta = printer.linear_delta().unwrap().expect("a linear delta");
    let fw = printer.mechanism().unwrap();
    let fw_p = Params::nominal(fw.spec());
    let (mech, tolerances) = physical::physical_mechanism(&ld).unwrap();
    assert!(!tolerances.is_empty());
    let mut p = Params::nominal(mech.spec());
    if let Some((name, dv)) = change {
        let v = p.get(mech.spec(), name).unwrap();
        p.set(mech.spec(), name, v + dv).unwrap();
    }
    let mut nozzle = 0.0_f64;
    for t in physical::build_volume(ld.print_radius()) {
        let c = pkmcal::controller_commands(&fw, &fw_p, &t).unwrap();
        let a = pkmcal::predict(&fw, &fw_p, &c, pkmcal::Model::Exact, &[])
            .unwrap()
            .x;
        let b = physical::nozzle_at(&mech, &p, &c, ld.nozzle()).unwrap();
        for k in 0..3 {
            nozzle = nozzle.max((a[k] - b[k]).abs());
        }
    }
    let mut reading = 0.0_f64;
    let (rf, rp) = (
        printer.readings(fw.spec()).unwrap(),
        printer.readings(mech.spec()).unwrap(),
    );
    assert_eq!(rf.poses.len(), rp.poses.len());
    for (a, b) in rf.poses.iter().zip(&rp.poses) {
        let ya = pkmcal_io::firmware::probe_errors(
            &fw,
            &rf.measurement,
            &fw_p,
            rf.measurement.nominal(),
            std::slice::from_ref(a),
        )
        .unwrap();
        let yb = pkmcal_io::firmware::probe_errors(
            &mech,
            &rp.measurement,
            &p,
            rp.measurement.nominal(),
            std::slice::from_ref(b),
        )
        .unwrap();
        reading = reading.max((ya[0] - yb[0]).abs());
    }
    (nozzle, reading)
}

#[test]
fn klipper_physical_model_is_klippers_without_extra_errors() {
    for prefix in ["", "[probe]\npin: PD2\nx_offset: 25.0\ny_offset: -12.5\n\n"] {
        let printer = klipper(prefix);
        let (n, r) = largest_difference(&printer, None);
        assert!(n < SAME_MM && r < SAME_MM, "{prefix:?}: {n:e} {r:e}");
        let (n, _) = largest_difference(&printer, Some(("rod_a1", 0.1)));
        assert!(n > MOVED_MM, "{n:e}");
    }
    let ld = klipper("[probe]\nx_offset: 25.0\ny_offset: -12.5\n")
        .linear_delta()
        .unwrap()
        .unwrap();
    assert_eq!(ld.probe_offset, [25.0, -12.5]);
}

#[test]
fn reprap_physical_model_is_rrfs_without_extra_errors() {
    let (n, r) = largest_difference(&reprap(), None);
    assert!(n < SAME_MM && r < SAME_MM, "{n:e} {r:e}");
}

#[test]
fn marlin_physical_model_is_marlins_without_extra_errors() {
    for offset in ["M851 X0.0000 Y0.0000", "M851 X22.0 Y-10.0"] {
        let printer = marlin(offset);
        let (n, r) = largest_difference(&printer, None);
        assert!(n < SAME_MM && r < SAME_MM, "{offset}: {n:e} {r:e}");
        let (n, _) = largest_difference(&printer, Some(("a.tilt1", 0.001)));
        assert!(n > MOVED_MM, "{n:e}");
    }
    let ld = marlin("M851 X22.0 Y-10.0").linear_delta().unwrap().unwrap();
    assert_eq!(ld.probe_offset, [22.0, -10.0]);
}

#[test]
fn a_shared_chain_names_an_earlier_leg() {
    let ld = klipper("").linear_delta().unwrap().unwrap();
    let text = physical::physical_description(&ld);
    assert!(pkmcal_io::description::description_from_str(&text).is_ok());
    for (from, to, says) in [
        ("chain = \"a1\"", "chain = \"b1\"", "names no earlier leg"),
        (
            "chain = \"a1\"",
            "chain = \"a1\"\nangle = \"angle_a\"",
            "remove its own `angle`",
        ),
    ] {
        let bad = text.replacen(from, to, 1);
        let e = pkmcal_io::description::description_from_str(&bad)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("leg `a2`") && e.contains(says), "{e}");
    }
}

/// RepRapFirmware's probe offset is `G31 X Y` of Z probe 0 (the last one
/// the configuration runs; another probe's `K1` left), the probe's trigger
/// point at the nozzle's plus it: the physical model takes the readings
/// with the nozzle at each probe point less it; the firmware's own fit as
/// before.
#[test]
fn reprap_probe_offset_is_g31s() {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let d = examples().join("reprap-delta");
    let dir = tempfile::tempdir().unwrap();
    let config = std::fs::read_to_string(d.join("config.g")).unwrap();
    std::fs::write(
        dir.path().join("config.g"),
        format!("G31 P500 X3 Y3 Z1\n{config}\nG31 P500 X20 Y-15 Z1.2\nG31 K1 X5 Y5\n"),
    )
    .unwrap();
    let printer = RrfPrinter::read(
        &run,
        &dir.path().join("config.g"),
        &d.join("probes.csv"),
        None,
    )
    .unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    assert_eq!(ld.probe_offset, [20.0, -15.0]);
    let spec = printer.mechanism().unwrap();
    let (own, physical) = (
        printer.readings(spec.spec()).unwrap(),
        printer.physical_readings(spec.spec()).unwrap(),
    );
    let plain = reprap().readings(spec.spec()).unwrap();
    for ((a, b), c) in own.poses.iter().zip(&physical.poses).zip(&plain.poses) {
        assert_eq!(a.commands, c.commands);
        assert_ne!(a.commands, b.commands);
    }
    // Out of bounds: refused with its line.
    std::fs::write(
        dir.path().join("config.g"),
        format!("{config}\nG31 X5000\n"),
    )
    .unwrap();
    let e = RrfPrinter::read(
        &run,
        &dir.path().join("config.g"),
        &d.join("probes.csv"),
        None,
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("X5000") || e.contains("5000"), "{e}");
    assert_eq!(
        reprap().linear_delta().unwrap().unwrap().probe_offset,
        [0.0, 0.0]
    );
}
