//! Tests of `pkmcal::apply::montecarlo`.

use pkmcal::apply::montecarlo::*;
use pkmcal::apply::workspace::random_targets;
use pkmcal::engine::models::Model;
use pkmcal::identify::Loss;
use pkmcal::identify::{Calibration, CalibrationOptions, PoseCache, Prior, calibrate_with_cache};
use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::measurement::MeasurementModel;
use pkmcal::measurement::data::Measurement;
use pkmcal::{Mechanism, Params};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A study of `runs` whose every run is calibrated twice, the fit alone
/// (as [`monte_carlo`] does) and the full calibration (first one, then
/// the other, alternately): the same parameters and `converged`, bit for
/// bit, and the fit alone without the report.
fn fit_alone_is_the_full_fit<M: Mechanism>(mech: &M, calibration: CalibrationOptions, runs: usize) {
    let poses = random_targets(mech, 35, 7).unwrap();
    let validation = validation_targets(mech, 5, 11).unwrap();
    let opts = MonteCarloOptions {
        runs,
        noise: 0.002.into(),
        seed: 3,
        length_error: 0.3,
        angle_error: 1e-3,
        calibration,
    };
    let spec = mech.spec();
    let (tool, nominal) = (MeasurementModel::tool(spec), Params::nominal(spec));
    let mut fit = opts.calibration.clone();
    fit.fit_only = true;
    let compared = AtomicUsize::new(0);
    let calibrate = |data: &[Measurement], cache: &PoseCache| {
        let k = compared.fetch_add(1, Ordering::Relaxed);
        let full = || calibrate_with_cache(mech, &tool, data, &nominal, &opts.calibration, cache);
        let alone = || calibrate_with_cache(mech, &tool, data, &nominal, &fit, cache);
        let (full, alone) = if k.is_multiple_of(2) {
            (full()?, alone()?)
        } else {
            let a = alone()?;
            (full()?, a)
        };
        let bits =
            |c: &Calibration| -> Vec<u64> { c.params.values.iter().map(|v| v.to_bits()).collect() };
        assert_eq!(bits(&alone), bits(&full), "run {k}");
        assert_eq!(alone.converged, full.converged, "run {k}");
        assert!(alone.noise.is_empty() && !full.noise.is_empty());
        Ok(alone)
    };
    let (_, summary) = study(mech, &poses, &validation, &opts, &|| {}, &calibrate).unwrap();
    assert_eq!(compared.into_inner(), runs);
    assert!(summary.converged > 0);
}

/// The reference with the defaults (one noise group: its σ estimated
/// after the fit, unread by the runs).
#[test]
fn the_fit_alone_on_the_reference() {
    let mech = JeongKim2Dof::new();
    fit_alone_is_the_full_fit(
        &mech,
        CalibrationOptions::new(mech.spec(), Model::Exact),
        50,
    );
}

/// The five-bar with a tolerance (the noise refitted with the prior),
/// and the reference with a robust loss dropping outliers (the
/// reweighting refits, the outliers found).
#[test]
fn the_fit_alone_with_priors_refits_and_outliers() {
    let d: pkmcal::PlanarDescription = crate::common::table("five-bar").try_into().unwrap();
    let five = pkmcal::PlanarLinkage::new(&d).unwrap();
    let mut opts = CalibrationOptions::new(five.spec(), Model::Exact);
    let index = opts.free[0];
    opts.priors.push(Prior { index, sigma: 0.5 });
    fit_alone_is_the_full_fit(&five, opts, 50);
    let mech = JeongKim2Dof::new();
    let mut opts = CalibrationOptions::new(mech.spec(), Model::Exact);
    opts.loss = Loss::Huber(Loss::HUBER_DEFAULT);
    opts.drop_outliers = true;
    fit_alone_is_the_full_fit(&mech, opts, 10);
}
