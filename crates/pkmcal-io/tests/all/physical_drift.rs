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

/// Pairs of physical fits compared.
const PHYSICAL_PAIRS: usize = 40;
/// The directions 13 heights show of the physical model, the bed's tilt
/// (the instrument's, integrated out) less.
const PHYSICAL_SEEN: usize = 11;

fn physical_fit(text: &str) -> firmware::physical::PhysicalFit {
    use firmware::Firmware;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("printer.cfg");
    std::fs::write(&path, text).unwrap();
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    firmware::physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap()
}

/// The drift test on two physical fits, 59 parameters held mostly by their
/// tolerances and 13 heights (what `--previous` does not compare, but
/// `pkmcal::identify::drift` must get right for any prior-held fit): it
/// compares the 11 directions the heights show, the bed's tilt integrated
/// out, and false-alarms at about its rate. It once counted 20 directions
/// and said "changed" on 40 of 40 pairs.
#[test]
fn physical_fits_compare_what_the_heights_show() {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg"),
    )
    .unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(59);
    let mut alarms = 0;
    for _ in 0..PHYSICAL_PAIRS {
        let a = physical_fit(&reprobed(&text, &mut rng, 0.0));
        let b = physical_fit(&reprobed(&text, &mut rng, 0.0));
        let d = pkmcal::identify::drift(
            &pkmcal::identify::Compared::from_calibration(&a.study.calibration),
            &pkmcal::identify::Compared::from_calibration(&b.study.calibration),
            ALPHA,
        )
        .unwrap();
        assert_eq!(d.dof, PHYSICAL_SEEN, "{d:?}");
        alarms += usize::from(d.joint_drift);
    }
    let bound = ALPHA + 4.0 * (ALPHA * (1.0 - ALPHA) / PHYSICAL_PAIRS as f64).sqrt();
    assert!(
        alarms as f64 / PHYSICAL_PAIRS as f64 <= bound,
        "false alarms {alarms} of {PHYSICAL_PAIRS}"
    );
}
