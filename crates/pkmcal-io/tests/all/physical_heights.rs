//! Heights measured by hand for `--physical` (`--heights`, issue 54 item
//! 2): the shipped example's file is read as written; every field is
//! checked at its line and column; a nozzle touch becomes a reading of the
//! nozzle through the firmware's current values, which the firmware's own
//! model predicts to 1e-9 mm where the printer is the firmware's picture;
//! a probe touch reads the surface plus the firmware's trigger height; a
//! reading the fit cannot use is named by the file's line.

use pkmcal::{Mechanism, Params};
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::physical;
use pkmcal_io::firmware::physical_heights::{self, Tool};
use std::path::{Path, PathBuf};

/// Rigid-body round-off over a delta's size (mm).
const ROUND_OFF_MM: f64 = 1e-9;

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../examples/klipper-delta")
        .join(name)
}

fn printer() -> KlipperPrinter {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    KlipperPrinter::read(&run, &example("printer.cfg"), Weighting::Klipper).unwrap()
}

fn read_text(text: &str) -> pkmcal_io::Result<physical_heights::Touches> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("heights.csv");
    std::fs::write(&path, text).unwrap();
    let files = pkmcal_io::Files::new();
    physical_heights::read(&pkmcal_io::Run::quiet(&files), &path)
}

#[test]
fn the_examples_heights_are_read_as_written() {
    let files = pkmcal_io::Files::new();
    let t =
        physical_heights::read(&pkmcal_io::Run::quiet(&files), &example("heights.csv")).unwrap();
    assert_eq!(t.rows.len(), 11);
    assert_eq!(t.rows.iter().filter(|r| r.tool == Tool::Nozzle).count(), 7);
    let last = &t.rows[10];
    assert_eq!(last.tool, Tool::Probe);
    assert_eq!(last.surface, 50.0);
    assert_eq!(last.sigma, None);
    assert_eq!(last.position[0], 52.0);
}

#[test]
fn every_field_is_checked_at_its_line_and_column() {
    let header = "x,y,z,tool,surface,sigma\n0,0,0.1,nozzle,0.1,\n";
    for (row, said) in [
        ("0,0,0.1,nozle,0,", "column `tool`: `nozle`"),
        ("0,0,abc,nozzle,0,", "column `z`: `abc` is not a number"),
        (
            "0,0,0.1,nozzle,-0.5,",
            "column `surface`: -0.5 mm is below the bed",
        ),
        ("0,0,0.1,nozzle,0,0", "column `sigma`: 0 mm"),
        ("0,0,0.1,nozzle,0,9", "column `sigma`: 9 mm"),
        (
            "0,0,1e9,nozzle,0,",
            "column `z`: 1e9 mm is beyond any printer",
        ),
        ("0,0,0.1", "no value for column `surface`"),
    ] {
        let e = read_text(&format!("{header}{row}\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("heights.csv:3:") && e.contains(said),
            "{row}: {e}"
        );
    }
    let e = read_text("x,y,tool,surface\n0,0,nozzle,0\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing column `z`"), "{e}");
    // The σ column may be left out, and a row's σ empty.
    let t = read_text("X,Y,Z,Tool,Surface\n0,0,0.1,Probe,0\n").unwrap();
    assert_eq!((t.rows[0].tool, t.rows[0].sigma), (Tool::Probe, None));
}

#[test]
fn a_touch_is_a_reading_through_the_firmwares_current_values() {
    let printer = printer();
    let ld = printer.linear_delta().unwrap().unwrap();
    let fw = printer.mechanism().unwrap();
    let (mech, _) = physical::physical_mechanism_with(&ld, true).unwrap();
    let t = read_text(
        "x,y,z,tool,surface,sigma\n30,-40,0.25,nozzle,0.1,\n-50,20,50.2,probe,50,0.005\n",
    )
    .unwrap();
    let rows = physical_heights::readings(&t, &ld, &fw, None, 13).unwrap();
    assert_eq!(rows[0].origin.unwrap().pose, 14);
    assert_eq!(rows[0].origin.unwrap().line, Some(2));
    assert_eq!(rows[0].sigma, vec![Some(physical_heights::TOUCH_NOISE_MM)]);
    assert_eq!(rows[1].sigma, vec![Some(0.005)]);
    assert_eq!(rows[0].measured, vec![0.1]);
    // The probe's trigger height: Klipper's saved heights (0 here).
    assert_eq!(rows[1].measured, vec![50.0 + ld.probe_height]);
    assert_eq!(rows[1].point, None);
    // The physical model at its nominal values is the firmware's: the
    // nozzle stands where the firmware was told it was.
    let p = Params::nominal(mech.spec());
    for (row, at) in rows.iter().zip([[30.0, -40.0, 0.25], [-50.0, 20.0, 50.2]]) {
        let n = physical::nozzle_at(&mech, &p, &row.commands, ld.nozzle()).unwrap();
        for k in 0..3 {
            assert!((n[k] - at[k]).abs() < ROUND_OFF_MM, "{n:?} {at:?}");
        }
        let h = pkmcal_io::firmware::probe_errors(
            &mech,
            &pkmcal::MeasurementModel::probe(mech.spec()).unwrap(),
            &p,
            &[0.0; 3],
            std::slice::from_ref(row),
        )
        .unwrap();
        // Predicted height less the reading: the position's z less the
        // surface (plus the trigger height for the probe).
        assert!(
            (h[0] - (at[2] - row.measured[0])).abs() < ROUND_OFF_MM,
            "{h:?}"
        );
    }
    // Outside the build volume, and out of reach, by line.
    let t = read_text("x,y,z,tool,surface\n0,0,0,nozzle,0\n0,150,0,nozzle,0\n").unwrap();
    let e = physical_heights::readings(&t, &ld, &fw, None, 13)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("heights.csv:3:") && e.contains("outside the build volume"),
        "{e}"
    );
    let t = read_text("x,y,z,tool,surface\n0,0,-20,nozzle,0\n").unwrap();
    let e = physical_heights::readings(&t, &ld, &fw, None, 0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("heights.csv:2:") && e.contains("z -20 mm"),
        "{e}"
    );
}

/// With a nozzle touch, the physical fit's tool is the effector's whole
/// pose; the fit of the example's file runs, its touches counted.
#[test]
fn the_fit_reads_the_touches() {
    let printer = printer();
    let ld = printer.linear_delta().unwrap().unwrap();
    let files = pkmcal_io::Files::new();
    let t =
        physical_heights::read(&pkmcal_io::Run::quiet(&files), &example("heights.csv")).unwrap();
    let fit = physical::calibrate_with(
        &printer,
        &ld,
        pkmcal::Request::new(pkmcal::Model::Exact),
        Some(&t),
    )
    .unwrap();
    assert_eq!(fit.touches, (11, 7));
    assert_eq!(fit.readings.poses.len(), 13 + 11);
    assert_eq!(fit.mech.spec().tool_axes.len(), 6);
    // The residuals of the touches within 4 of their σ (paper tests of
    // 0.02 mm, probe touches of 3 µm simulated).
    let cal = &fit.study.calibration;
    let h = pkmcal_io::firmware::probe_errors(
        &fit.mech,
        &fit.readings.measurement,
        &cal.params,
        &cal.measurement,
        &fit.readings.poses[13..],
    )
    .unwrap();
    assert!(
        h.iter()
            .all(|e| e.abs() < 4.0 * physical_heights::TOUCH_NOISE_MM),
        "{h:?}"
    );
}
