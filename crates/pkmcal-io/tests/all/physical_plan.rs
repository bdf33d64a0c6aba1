//! Which extra measurement would shrink the predicted cube error most
//! (`--physical`, issue 54): Klipper's calibration object is laid out as
//! Klipper lays it out; the linearised cube σ the choice is scored by
//! agrees with the draws the verdict prints; no measurement adds
//! uncertainty; on the Klipper example, whose probe heights cannot see the
//! XY scale, the caliper distances come first.

use pkmcal::{Mechanism, Request};
use pkmcal_io::firmware::Firmware;
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::physical;
use pkmcal_io::firmware::physical_plan::{self, Extra};
use std::path::Path;

/// Klipper's object: every distance 65 mm on the part as drawn
/// (`MeasureOuterRadius`), the ridges 4.5 mm from the centres.
#[test]
fn klippers_calibration_object_is_laid_out_as_klipper_lays_it_out() {
    let pairs = physical_plan::object_pairs();
    assert_eq!(pairs.len(), 12);
    for (a, b) in &pairs {
        let d = (a[0] - b[0]).hypot(a[1] - b[1]);
        assert!((d - 65.0).abs() < 1e-12, "{d}");
    }
    // The first centre distance runs out along 210°.
    let (s, c) = 210f64.to_radians().sin_cos();
    assert!((pairs[0].1[0] - 69.5 * c).abs() < 1e-12 && (pairs[0].1[1] - 69.5 * s).abs() < 1e-12);
}

#[test]
fn the_suggestions_are_scored_by_the_cubes_own_uncertainty() {
    /// The draws' σ (64 of them) is within this factor of the linearised
    /// one: sampling error of a σ from 64 draws is about 9 %, and the model
    /// is nonlinear.
    const FACTOR: f64 = 1.5;
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg");
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    let fw = printer.mechanism().unwrap();
    let fit = physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap();
    let cal = &fit.study.calibration;
    let proj = physical::project(&ld, &fw, &fit.mech, &cal.params, &cal.measurement).unwrap();
    let list = physical_plan::suggest(&fit, &fw, &proj.params, None, true).unwrap();
    assert_eq!(
        list.len(),
        4,
        "the best probe point, the block, the nozzle touches, the object"
    );

    assert!(
        matches!(list[0].extra, Extra::ObjectDistances),
        "{:?}",
        list[0].extra
    );
    assert_eq!(list[0].readings, 12);
    for s in &list {
        assert!(s.sd_after.iter().zip(&s.sd_before).all(|(a, b)| a <= b));
        assert!(s.variance_removed() > 0.0 && s.variance_removed() < 1.0);
    }
    assert!(list[0].variance_removed() > list[1].variance_removed());
    let cubes = physical::cube_errors(&fit, &fw, &proj.params, None).unwrap();
    let drawn: Vec<f64> = cubes
        .iter()
        .flat_map(|c| [c.size_sd[0], c.size_sd[1]])
        .collect();
    let linear: Vec<f64> = [0, 1, 3, 4].map(|k| list[0].sd_before[k]).to_vec();
    for (d, l) in drawn.iter().zip(&linear) {
        assert!(
            d / l < FACTOR && l / d < FACTOR,
            "drawn {drawn:?}, linearised {linear:?}"
        );
    }
    // Without distances (a firmware that cannot read them) none is offered.
    let list = physical_plan::suggest(&fit, &fw, &proj.params, None, false).unwrap();
    assert!(
        list.iter()
            .all(|s| !matches!(s.extra, Extra::ObjectDistances))
    );
}

/// How far the variance the nozzle touches are scored to remove may lie
/// from what a fit that reads them leaves (shares of the cube errors'
/// variance): both are linearised, about two different estimates (the
/// refit moves the parameters) and two models (a touch needs the
/// effector's whole pose).
const SCORED_AGAINST_REFIT: f64 = 0.02;

/// The nozzle touches are scored as what they are: the fit that reads
/// them (`--heights`, taken where the fitted printer puts the nozzle on
/// the bed) leaves the cube's variance the candidate said it would.
#[test]
fn nozzle_touches_leave_what_they_were_scored_to_leave() {
    use pkmcal_io::firmware::physical_heights::{Tool, Touch, Touches};
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/klipper-delta/printer.cfg");
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    let printer = KlipperPrinter::read(&run, &path, Weighting::Klipper).unwrap();
    let ld = printer.linear_delta().unwrap().unwrap();
    let fw = printer.mechanism().unwrap();
    let fit = physical::calibrate(&printer, &ld, Request::new(pkmcal::Model::Exact)).unwrap();
    let cal = &fit.study.calibration;
    let proj = physical::project(&ld, &fw, &fit.mech, &cal.params, &cal.measurement).unwrap();
    let list = physical_plan::suggest(&fit, &fw, &proj.params, None, false).unwrap();
    let scored = list
        .iter()
        .find(|s| matches!(s.extra, Extra::NozzleTouches { .. }))
        .expect("the nozzle touches are a candidate");
    let Extra::NozzleTouches { points } = &scored.extra else {
        unreachable!()
    };
    assert_eq!(points.len(), 7);
    // Each touch where the fitted printer puts the nozzle on the bed with
    // the configuration's values: sent to (x, y, 0), it stands e_z above.
    let at: Vec<[f64; 3]> = points.iter().map(|p| [p[0], p[1], 0.0]).collect();
    let current = pkmcal::Params::nominal(fw.spec());
    let e = physical::nozzle_errors(
        &fw,
        &current,
        None,
        &fit.mech,
        &cal.params,
        &cal.measurement,
        ld.nozzle(),
        &at,
    )
    .unwrap();
    let touches = Touches {
        path: "touches.csv".into(),
        rows: points
            .iter()
            .zip(&e)
            .enumerate()
            .map(|(k, (p, e))| Touch {
                line: k as u64 + 2,
                position: [p[0], p[1], -e[2]],
                tool: Tool::Nozzle,
                surface: 0.0,
                sigma: None,
            })
            .collect(),
    };
    let refit = physical::calibrate_with(
        &printer,
        &ld,
        Request::new(pkmcal::Model::Exact),
        Some(&touches),
    )
    .unwrap();
    let cal = &refit.study.calibration;
    let proj = physical::project(&ld, &fw, &refit.mech, &cal.params, &cal.measurement).unwrap();
    let after = physical_plan::suggest(&refit, &fw, &proj.params, None, false).unwrap();
    let var = |sd: &[f64]| sd.iter().map(|s| s * s).sum::<f64>();
    let left = var(&after[0].sd_before) / var(&scored.sd_before);
    let said = 1.0 - scored.variance_removed();
    assert!(
        (left - said).abs() < SCORED_AGAINST_REFIT,
        "the refit leaves {left:.3} of the variance, the candidate said {said:.3}"
    );
}
