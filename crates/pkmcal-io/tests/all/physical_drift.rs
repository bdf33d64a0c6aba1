//! Whether this calibration differs from a previous one (`--physical
//! --previous`, issue 54), as a statistician checks a test: its false-alarm
//! rate over seeded re-probes of one unchanged printer, and its power
//! against a carriage moved at every probe.

use pkmcal::Request;
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::{self, physical_drift};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use std::path::Path;

/// Re-probes of the unchanged printer.
const RUNS: usize = 200;
/// The probe's noise on each re-probe (mm): the physical model's assumed one.
const NOISE_MM: f64 = 0.01;
/// The drift test's familywise false-alarm rate.
const ALPHA: f64 = 0.05;
/// The false-alarm rate allowed over [`RUNS`] runs: α plus four binomial
/// standard deviations.
const MAX_FALSE_ALARMS: f64 = 0.05 + 4.0 * 0.0154;
/// Steps of 12.5 µm that carriage a is moved in the changed printer (1 mm).
const MOVED_STEPS: f64 = 80.0;

fn fitted(text: &str) -> firmware::PrinterCalibration {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("printer.cfg");
    std::fs::write(&path, text).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    firmware::calibrate(&printer, Request::new(pkmcal::Model::Exact)).unwrap()
}

/// The example with each saved height given noise, carriage a moved by
/// `steps` at every probe.
fn reprobed(text: &str, rng: &mut rand::rngs::StdRng, steps: f64) -> String {
    let noise = Normal::new(0.0, NOISE_MM).unwrap();
    text.lines()
        .map(|l| {
            if let Some((head, v)) = l.split_once("_pos = ")
                && l.starts_with("#*# height")
            {
                let mut x: Vec<f64> = v.split(',').map(|t| t.trim().parse().unwrap()).collect();
                x[0] += steps;
                format!("{head}_pos = {:.3},{:.3},{:.3}\n", x[0], x[1], x[2])
            } else if let Some((head, v)) = l.split_once(" = ")
                && l.starts_with("#*# height")
            {
                let h: f64 = v.trim().parse().unwrap();
                format!("{head} = {:.5}\n", h + noise.sample(rng))
            } else {
                format!("{l}\n")
            }
        })
        .collect()
}

#[test]
fn drift_false_alarms_at_its_rate_and_sees_a_moved_carriage() {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg"),
    )
    .unwrap();
    let base = fitted(&text);
    let same = physical_drift::firmware_drift(&base, &fitted(&text), ALPHA).unwrap();
    assert!(!same.joint_drift && same.chi2 < 1e-6, "{same:?}");
    let mut rng = rand::rngs::StdRng::seed_from_u64(54);
    let mut alarms = 0;
    for _ in 0..RUNS {
        let a = fitted(&reprobed(&text, &mut rng, 0.0));
        let b = fitted(&reprobed(&text, &mut rng, 0.0));
        alarms += physical_drift::firmware_drift(&a, &b, ALPHA)
            .unwrap()
            .joint_drift as usize;
    }
    let rate = alarms as f64 / RUNS as f64;
    assert!(rate <= MAX_FALSE_ALARMS, "false alarms {alarms} of {RUNS}");
    let mut seen = 0;
    for _ in 0..RUNS / 10 {
        let a = fitted(&reprobed(&text, &mut rng, 0.0));
        let b = fitted(&reprobed(&text, &mut rng, MOVED_STEPS));
        seen += physical_drift::firmware_drift(&a, &b, ALPHA)
            .unwrap()
            .joint_drift as usize;
    }
    assert_eq!(
        seen,
        RUNS / 10,
        "a 1 mm carriage move seen {seen} of {}",
        RUNS / 10
    );
}
