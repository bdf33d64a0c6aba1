//! The `--physical` report's data ([`physical_report::Page`]): the written
//! values' σ ([`physical::projection_sigmas`], linearised through the
//! projection) against full re-projections of the fitted printer's
//! posterior draws, the page showing them, and the bed's error maps
//! against the projection's own errors.

use pkmcal::{Mechanism, Request};
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::physical::{self, ErrorSummary};
use pkmcal_io::firmware::physical_report::{self, Inputs, Page};
use pkmcal_io::firmware::{self, Firmware};
use std::path::Path;

/// Re-projected draws compared with the linearised σ.
const DRAWS: usize = 24;
/// The re-projected σ is within this factor of the linearised one:
/// sampling error of a σ from 24 draws is about 15 %, and the projection is
/// nonlinear.
const FACTOR: f64 = 1.6;
/// Below this σ (mm, °) a value is one the projection holds.
const FIXED: f64 = 1e-9;

/// A front end's wording that names each input by its description.
const WORDING: pkmcal_io::text::Wording = pkmcal_io::text::Wording {
    frame_base: "identified",
    all_correlations: "the record",
    hint: |w| w.hint.clone(),
    input: |f| format!("«{}»", f.describe()),
};

#[test]
fn the_written_values_sigma_is_that_of_reprojected_draws() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg");
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    let fw = printer.mechanism().unwrap();
    let spec = fw.spec();
    let own = firmware::calibrate(&printer, Request::new(pkmcal::Model::Exact)).unwrap();
    let fit = physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap();
    let cal = &fit.study.calibration;
    let proj = physical::project(&ld, &fw, &fit.mech, &cal.params, &cal.measurement).unwrap();
    let cubes = physical::cube_errors(&fit, &fw, &proj.params, None).unwrap();
    let sigmas = physical::projection_sigmas(&printer, &fit, &fw, &proj, 1.0).unwrap();
    let mut written = printer.values(spec, &proj.params, &proj.bed).unwrap();
    for (v, s) in written.iter_mut().zip(&sigmas) {
        v.sigma = Some(*s);
    }
    let zero = ErrorSummary::of(&[[0.0; 3]]);
    let page = Page::build(&Inputs {
        printer: &printer,
        source: "printer.cfg",
        own: &own,
        fit: &fit,
        fw_mech: &fw,
        projection: &proj,
        values: &written,
        projected: (proj.summary, true),
        before: [zero, zero],
        cubes: &cubes,
        suggestions: &[],
        shown: 3,
        drift: None,
        mesh_points: None,
        height_map: None,
        wording: &WORDING,
    })
    .unwrap();
    // The page names its inputs as the front end does: no option of the
    // command line where another front end words it.
    let html = physical_report::html(&page, &[]);
    assert!(
        html.contains("give «the height map» to write it"),
        "the page names the height map as its front end does"
    );
    assert!(
        !html.contains("--"),
        "the page names no command-line option of its own"
    );
    // The written values are the projection's.
    let values = printer.values(spec, &proj.params, &proj.bed).unwrap();
    assert_eq!(page.values.len(), values.len());
    for (row, v) in page.values.iter().zip(&values) {
        assert_eq!(row.written, v.after);
    }
    for (row, s) in page.values.iter().zip(&sigmas) {
        assert_eq!(row.written_sd, Some(*s));
    }
    // Their σ: each draw projected in full, the tower angles' common turn
    // (which no printed part shows, left out of the σ) taken out.
    let draws = physical::posterior_draws(&fit, physical::CUBE_DRAWS, physical::CUBE_SEED).unwrap();
    let mut by_value = vec![vec![]; values.len()];
    for (p, bed) in draws.iter().take(DRAWS) {
        let q = physical::project(&ld, &fw, &fit.mech, p, bed).unwrap();
        let moved = printer.values(spec, &q.params, &q.bed).unwrap();
        let angles: Vec<usize> = (0..moved.len()).filter(|&k| moved[k].unit == "°").collect();
        let turn = angles
            .iter()
            .map(|&k| moved[k].after - values[k].after)
            .sum::<f64>()
            / angles.len().max(1) as f64;
        for (k, v) in moved.iter().enumerate() {
            let common = if angles.contains(&k) { turn } else { 0.0 };
            by_value[k].push(v.after - common);
        }
    }
    for ((row, drawn), &lin) in page.values.iter().zip(&by_value).zip(&sigmas) {
        let n = drawn.len() as f64;
        let mean = drawn.iter().sum::<f64>() / n;
        let sd = (drawn.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
        if sd < FIXED && lin < FIXED {
            continue; // a value the projection holds (an arm length, a fixed angle)
        }
        assert!(
            lin < FACTOR * sd && sd < FACTOR * lin,
            "{}: linearised σ {lin} against re-projected {sd}",
            row.name,
        );
    }
    // The bed map's centre is a point of the build volume's bottom layer:
    // the same Z error there (XY is in the bed's frame of each point set).
    let centre = page
        .bed
        .points
        .iter()
        .position(|p| p[0].abs() < 1e-9 && p[1].abs() < 1e-9)
        .unwrap();
    let at = proj
        .targets
        .iter()
        .position(|t| t.iter().all(|c| c.abs() < 1e-9))
        .unwrap();
    assert!((page.bed.written[centre][2] - proj.errors[at][2]).abs() < 1e-12);
    assert!(
        page.bed
            .written_sd_z
            .iter()
            .all(|s| s.is_finite() && *s > 0.0)
    );
}
