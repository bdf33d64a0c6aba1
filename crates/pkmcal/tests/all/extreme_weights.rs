//! Extreme weights (issue 50, item 1): a tolerance far below what any
//! measurement resolves is a constraint, not a weight (docs/model.md eq. 13):
//! its parameter is held at its value with its own σ and the others are
//! identified as without it; every σ that weighs readings or priors is
//! bounded where it enters, the refusal naming the field. Each case once
//! hung in the SVD, or wrote nominal values with exit 0.

use crate::common::{spatial, spread};
use pkmcal::identify::{Prior, information_from_data, is_constraint};
use pkmcal::{
    CalibrationOptions, Error, Frame, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise,
    Params,
};

/// Agreement of the others' values with the fit that fixes the held
/// parameter (mm, rad; the solver's tolerance).
const SAME: f64 = 1e-7;

/// The reference with every default parameter off by up to 0.9 mm / 3 mrad
/// but `l11`, 35 spread poses at 2 µm.
fn reference_data() -> (
    JeongKim2Dof,
    MeasurementModel,
    Params,
    Vec<pkmcal::Measurement>,
) {
    let m = JeongKim2Dof::new();
    let spec = m.spec().clone();
    let off = crate::common::perturbed(&spec, 5, 0.9, 0.003);
    let mut truth = Params::nominal(&spec);
    for n in spec.default_free.iter().filter(|n| *n != "l11") {
        let i = spec.param_index(n).unwrap();
        truth.values[i] = off.values[i];
    }
    let tool = MeasurementModel::tool(&spec);
    let data =
        pkmcal::simulate(&m, &tool, &truth, &spread(&m, 35), Noise::lengths(0.002), 5).unwrap();
    (m, tool, truth, data)
}

/// `l11` held by a tolerance of 1e-12 mm, and of 1e-200 mm (which once
/// spun forever in the SVD): held at nominal with that σ and nothing from
/// the data; every other parameter identified as in the fit with `l11`
/// fixed, the 0.9 mm errors corrected.
#[test]
fn a_tight_tolerance_holds_its_parameter_and_the_others_are_identified() {
    let (m, tool, truth, data) = reference_data();
    let spec = m.spec();
    let l11 = spec.param_index("l11").unwrap();
    let mut fixed = CalibrationOptions::new(spec, Model::Exact);
    fixed.free.retain(|&i| i != l11);
    let without = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &fixed).unwrap();
    for sigma in [1e-12, 1e-200] {
        assert!(is_constraint(sigma, spec.nominal[l11]));
        let mut opts = CalibrationOptions::new(spec, Model::Exact);
        opts.priors = vec![Prior { index: l11, sigma }];
        let cal = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &opts).unwrap();
        let p = &cal.parameters[l11];
        assert_eq!(p.identified, spec.nominal[l11]);
        assert_eq!(p.std_dev, sigma);
        assert_eq!(p.from_data, Some(0.0));
        assert!(p.note.is_some(), "the table says why it is held");
        assert_eq!(cal.free, without.free);
        assert!(cal.identifiability.unidentifiable.is_empty());
        for &i in &cal.free {
            let (a, b) = (
                cal.parameters[i].identified,
                without.parameters[i].identified,
            );
            assert!(
                (a - b).abs() < SAME,
                "{}: {a} against {b}",
                spec.param_names()[i]
            );
            assert!(
                (a - truth.values[i]).abs() < 0.01,
                "{} not corrected",
                spec.param_names()[i]
            );
            let (a, b) = (cal.parameters[i].std_dev, without.parameters[i].std_dev);
            assert!(
                (a / b - 1.0).abs() < SAME,
                "σ of {}: {a} against {b}",
                spec.param_names()[i]
            );
        }
        // It travels into predictions with its own σ.
        let c = &cal.parameter_covariance;
        let k = c.names.iter().position(|n| n == "l11").unwrap();
        assert_eq!(c.matrix[k][k], sigma * sigma);
    }
}

/// A free frame's `frame.x` held to 1e-12 mm: at its registered start,
/// the rest identified.
#[test]
fn a_tight_frame_prior_is_a_constraint() {
    let m = JeongKim2Dof::new();
    let spec = m.spec();
    let tracker = MeasurementModel::tool(spec).in_frame(Frame::Free).unwrap();
    let truth = crate::common::perturbed(spec, 3, 0.5, 0.002);
    let data = pkmcal::simulate(
        &m,
        &tracker,
        &truth,
        &spread(&m, 30),
        Noise::lengths(0.002),
        3,
    )
    .unwrap();
    let fx = tracker.index_of(spec, "frame.x").unwrap();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.priors = vec![Prior {
        index: fx,
        sigma: 1e-12,
    }];
    let cal = pkmcal::calibrate(&m, &tracker, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.converged);
    let t = &cal.priors[0];
    assert!(t.constraint);
    assert_eq!(cal.parameters[fx].identified, t.centre);
    assert_eq!(cal.parameters[fx].std_dev, 1e-12);
    assert!(
        cal.identifiability.unidentifiable.len() <= 1,
        "{:?}",
        cal.identifiability
    );
    assert!(cal.free.len() >= spec.default_free.len());
}

/// A probe's bed height held to 1e-200 mm: the fit finishes, the bed at 0.
#[test]
fn a_bed_height_of_1e_200_is_held_not_weighed() {
    let m = spatial("linear-delta");
    let spec = m.spec();
    let probe = MeasurementModel::probe(spec).unwrap();
    let data = pkmcal::simulate(
        &m,
        &probe,
        &Params::nominal(spec),
        &spread(&m, 20),
        Noise::lengths(0.005),
        1,
    )
    .unwrap();
    let bed = probe.index_of(spec, "bed.z").unwrap();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.priors = vec![Prior {
        index: bed,
        sigma: 1e-200,
    }];
    opts.free = pkmcal::identify::free_with_priors(spec, &probe, &opts.free, &opts.priors, &[]);
    let cal = pkmcal::calibrate(&m, &probe, &data, &Params::nominal(spec), &opts).unwrap();
    assert_eq!(cal.parameters[bed].identified, 0.0);
    assert_eq!(cal.parameters[bed].std_dev, 1e-200);
    assert!(cal.parameters.iter().all(|p| p.std_dev.is_finite()));
}

/// Every σ is bounded where it enters: a prior's σ of 0, NaN or beyond
/// its unit's range, the analysis's and the plan's noise of 0, a stated
/// noise of 1e-300; each refused naming the field. A tight prior in an
/// analysis or a plan holds its parameter: the others analysed as
/// without it.
#[test]
fn every_sigma_is_bounded_where_it_enters() {
    let (m, tool, _, data) = reference_data();
    let spec = m.spec();
    let l11 = spec.param_index("l11").unwrap();
    let field = |e: Error| match e {
        Error::OutOfRange { field, .. } => field,
        other => panic!("not a range error: {other}"),
    };
    for sigma in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e300] {
        let mut opts = CalibrationOptions::new(spec, Model::Exact);
        opts.priors = vec![Prior { index: l11, sigma }];
        let e = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &opts).unwrap_err();
        assert_eq!(field(e), "tolerance of l11", "σ {sigma}");
    }
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.stated_noise = Some(Noise::lengths(1e-300));
    let e = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &opts).unwrap_err();
    assert_eq!(field(e), "stated noise.length");
    let prior = [Prior {
        index: l11,
        sigma: 0.01,
    }];
    let free = CalibrationOptions::new(spec, Model::Exact).free;
    let analyze = |noise: Noise, priors: &[Prior]| {
        pkmcal::identify::analyze_with_priors(
            &m,
            &tool,
            &data,
            &Params::nominal(spec),
            Model::Exact,
            &free.clone(),
            &[],
            priors,
            noise,
        )
    };
    assert_eq!(
        field(analyze(Noise::lengths(0.0), &prior).unwrap_err()),
        "noise.length"
    );
    let held = analyze(
        Noise::lengths(0.002),
        &[Prior {
            index: l11,
            sigma: 1e-200,
        }],
    )
    .unwrap();
    assert!(!held.free.contains(&"l11".to_string()));
    assert_eq!(held.rank, free.len() - 1);
    let plan = pkmcal::PlanOptions {
        count: 20,
        criterion: pkmcal::PlanCriterion::O1,
        model: Model::Exact,
        free,
        spacing: 20.0,
        max_candidates: 100,
        cancel: None,
        priors: prior.to_vec(),
        noise: Noise::lengths(0.0),
    };
    let e = pkmcal::plan(&m, &Params::nominal(spec), &plan, &|_, _| {}).unwrap_err();
    assert_eq!(field(e), "noise.length");
}

/// The information share of a held parameter is 0 whatever its σ: the
/// share and the σ come from one covariance.
#[test]
fn a_held_parameter_s_share_is_zero() {
    assert_eq!(information_from_data(1e-200, 1e-200), 0.0);
}
