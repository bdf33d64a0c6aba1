//! The firmware rules both front ends (the command line, the Python
//! package) call, on the examples' real printers: Marlin's G33 compared
//! with a calibration ([`g33::compare`]), Klipper's model written as pkmcal
//! files ([`klipper::out_dir_files`]), a written value's σ as shown
//! ([`FirmwareValue::sigma_shown`]), the spread of height errors
//! ([`Spread`]) and the drift since a previous calibration
//! ([`physical_drift::since`]).

use pkmcal::{Mechanism, Request};
use pkmcal_io::firmware::g33::{self, G33Ask, RadiusFrom};
use pkmcal_io::firmware::klipper::{self, KlipperPrinter, OUT_DIR_FILES, Weighting};
use pkmcal_io::firmware::marlin::MarlinPrinter;
use pkmcal_io::firmware::{self, Sigma, Spread, physical_drift};
use std::path::{Path, PathBuf};

/// The probe's heights as Marlin's probing finds them against the fit's
/// own prediction (mm): its search stops within 1e-9 mm, well inside this.
const SAME_HEIGHT_MM: f64 = 1e-6;

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples")
}

fn marlin() -> MarlinPrinter {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let d = examples().join("marlin-delta");
    MarlinPrinter::read(
        &run,
        &d.join("M503.txt"),
        &d.join("G30.log"),
        None,
        None,
        None,
        None,
    )
    .unwrap()
}

fn calibrate(printer: &dyn firmware::Firmware) -> firmware::PrinterCalibration {
    firmware::calibrate(printer, Request::new(pkmcal::Model::Exact)).unwrap()
}

/// The fit's residuals at the probed points (mm).
fn after(c: &firmware::PrinterCalibration) -> Spread {
    let v: Vec<f64> = c.study.after.iter().map(|r| r[0]).collect();
    Spread::of(&v)
}

#[test]
fn spread_is_the_largest_and_the_rms() {
    let s = Spread::of(&[3.0, -4.0]);
    assert_eq!(s.max, 4.0);
    assert!((s.rms - 12.5_f64.sqrt()).abs() < 1e-15);
    assert_eq!(Spread::of(&[]), Spread { max: 0.0, rms: 0.0 });
}

#[test]
fn g33_on_marlins_example_against_the_fit() {
    let printer = marlin();
    let calibrated = calibrate(&printer);
    let residuals = after(&calibrated);
    // G33's defaults: P4 with the tower angles, at the farthest probed
    // point (the log prints no radius, M665 B is no radius here).
    let ask = G33Ask {
        points: g33::DEFAULT_POINTS,
        towers: true,
        radius: None,
    };
    let c = g33::compare(&printer, &calibrated, &ask).unwrap();
    assert_eq!(c.radius_from, RadiusFrom::FarthestProbe);
    assert_eq!(c.options.radius, printer.probe_radius());
    assert!(
        (c.options.radius - 90.0).abs() < 1e-9,
        "{}",
        c.options.radius
    );
    assert_eq!(c.factors.0, 6);
    let run = c.outcome.as_ref().expect("G33 runs on the example");
    assert_eq!(run.points, printer.log.points.len());
    assert_eq!(run.points, 19);
    assert_eq!(run.run.probes, 16);
    // With pkmcal's values the probe reads what the fit left: its residuals.
    assert!(
        (run.with_calibration.rms - residuals.rms).abs() < SAME_HEIGHT_MM,
        "{:?} against {residuals:?}",
        run.with_calibration
    );
    assert!((run.with_calibration.max - residuals.max).abs() < SAME_HEIGHT_MM);
    // G33 adjusts what the fit frees, by its approximate kinematics: no
    // better than the least squares at the points, and close to them.
    assert!(run.with_g33.rms >= run.with_calibration.rms - SAME_HEIGHT_MM);
    assert!(run.with_g33.rms < 2.0 * run.with_calibration.rms, "{run:?}");
    // Fewer factors (no tower angles), a radius given: G33 leaves more.
    let ask = G33Ask {
        points: g33::MOST_POINTS,
        towers: false,
        radius: Some(60.0),
    };
    let c = g33::compare(&printer, &calibrated, &ask).unwrap();
    assert_eq!(c.radius_from, RadiusFrom::Given);
    assert_eq!(c.factors.0, 4);
    let run = c.outcome.as_ref().unwrap();
    assert_eq!(run.run.probes, 100);
    assert!(
        run.with_g33.rms > 10.0 * run.with_calibration.rms,
        "{run:?}"
    );
    // A radius beyond the arms' reach: G33 cannot run, and says why.
    let ask = G33Ask {
        radius: Some(1000.0),
        ..ask
    };
    let c = g33::compare(&printer, &calibrated, &ask).unwrap();
    let e = c.outcome.expect_err("out of reach");
    assert!(e.to_string().contains("out of reach"), "{e}");
}

#[test]
fn klippers_model_files_read_back_as_the_fit() {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let config = examples().join("klipper-delta/printer.cfg");
    let printer = KlipperPrinter::read(&run, &config, Weighting::Klipper).unwrap();
    let calibrated = calibrate(&printer);
    let dir = tempfile::tempdir().unwrap();
    let written = klipper::out_dir_files(&printer, &calibrated, &config, dir.path());
    // No distances in the example: the three files, in order.
    let names: Vec<PathBuf> = written.iter().map(|(p, _)| p.clone()).collect();
    let expected: Vec<PathBuf> = OUT_DIR_FILES.iter().map(|f| dir.path().join(f)).collect();
    assert_eq!(names, expected);
    for (path, bytes) in &written {
        std::fs::write(path, bytes).unwrap();
    }
    // The mechanism and the parameters read back: the fit's values.
    let d = pkmcal_io::description::read_description(&run, Some(&expected[0])).unwrap();
    assert_eq!(
        d.mech.spec().param_names(),
        calibrated.mech.spec().param_names()
    );
    let p = pkmcal_io::params::read_params(&run, &expected[2], &d.mech).unwrap();
    let fitted = &calibrated.calibration().params.values;
    for (a, b) in p.values.iter().zip(fitted) {
        assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{a} against {b}");
    }
    // The probe heights, every number as the fit read it.
    let text = std::fs::read_to_string(&expected[1]).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("# frame: base"));
    let header = lines.next().unwrap();
    assert!(header.ends_with(",probe"), "{header}");
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), calibrated.readings.poses.len());
    for (row, m) in rows.iter().zip(&calibrated.readings.poses) {
        assert_eq!(row[..3], m.commands[..3]);
        assert_eq!(row[3], m.measured[0]);
    }
    let header_of_params = String::from_utf8(written[2].1.clone()).unwrap();
    assert!(
        header_of_params.contains(&config.display().to_string()),
        "{header_of_params}"
    );
}

#[test]
fn a_written_values_sigma_as_shown() {
    assert_eq!(Sigma::of(0.01), Sigma::Known(0.01));
    assert_eq!(Sigma::of(f64::NAN), Sigma::Unknown);
    for fixed in [0.0, -0.0, -1.0] {
        assert_eq!(Sigma::of(fixed), Sigma::Fixed, "{fixed}");
    }
    // Marlin's example: its rods are not free (fixed), its radius is.
    let printer = marlin();
    let calibrated = calibrate(&printer);
    let written = firmware::written(&printer, &calibrated).unwrap();
    let shown = |name: &str| {
        written
            .values
            .iter()
            .find(|v| v.name == name)
            .unwrap_or_else(|| panic!("{name}"))
            .sigma_shown()
    };
    assert_eq!(shown("M665 L"), Sigma::Fixed);
    match shown("M665 R") {
        Sigma::Known(s) => assert!(s > 0.001 && s < 0.05, "{s}"),
        s => panic!("{s:?}"),
    }
    // A value with no σ yet is one no free parameter moves.
    let mut v = written.values[0].clone();
    v.sigma = None;
    assert_eq!(v.sigma_shown(), Sigma::Fixed);
}

#[test]
fn a_printer_compared_with_its_own_readings_has_not_changed() {
    let printer = marlin();
    let now = calibrate(&printer);
    let d = physical_drift::since(&printer, &now).unwrap();
    assert!(!d.joint_drift, "{d:?}");
    assert!(d.chi2 < 1e-6, "{}", d.chi2);
    assert!(d.parameters.iter().all(|p| !p.drifted));
}
