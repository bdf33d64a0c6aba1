//! The calibration record: a mechanism's identity, and a record that comes
//! back from JSON exactly and serves only the mechanism it is of.

use crate::common;
use pkmcal::identify::{CALIBRATION_VERSION, CalibrationRecord, RecordError, mechanism_identity};
use pkmcal::kinds::reference::{JeongKim2Dof, demo_truth};
use pkmcal::*;

#[test]
fn the_identity_is_what_the_model_is() {
    let mech = JeongKim2Dof::new();
    let id = mechanism_identity(mech.spec());
    assert!(id.starts_with("fnv1a64:") && id.len() == 8 + 16, "{id}");
    // A name, a workspace box or a default free set is not the model.
    let mut renamed = mech.spec().clone();
    renamed.name = "another name".into();
    renamed.workspace_box[0][1] += 10.0;
    renamed.default_free.clear();
    assert_eq!(mechanism_identity(&renamed), id);
    // A nominal value is, to the last bit.
    let mut longer = mech.spec().clone();
    longer.nominal[0] = f64::from_bits(longer.nominal[0].to_bits() + 1);
    assert_ne!(mechanism_identity(&longer), id);
    // Every shipped example has its own.
    let ids: Vec<String> = ["gough-stewart-6", "gough-stewart-8"]
        .iter()
        .map(|n| mechanism_identity(common::gough_stewart(n).spec()))
        .chain(
            ["linear-delta", "rotary-delta"]
                .iter()
                .map(|n| mechanism_identity(common::spatial(n).spec())),
        )
        .chain([id.clone()])
        .collect();
    for (i, a) in ids.iter().enumerate() {
        assert!(!ids[i + 1..].contains(a), "{ids:?}");
    }
}

#[test]
fn a_record_comes_back_exactly_and_serves_only_its_mechanism() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let poses: Vec<Vec<f64>> = spread_targets(&mech, 30)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    let tool = MeasurementModel::tool(spec);
    let data = simulate(
        &mech,
        &tool,
        &demo_truth(),
        &poses,
        Noise::lengths(0.002),
        7,
    )
    .unwrap();
    let cal = calibrate(
        &mech,
        &tool,
        &data,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    let record = CalibrationRecord::new(spec, &cal);
    assert_eq!(record.version, CALIBRATION_VERSION);
    let back: CalibrationRecord =
        serde_json::from_str(&serde_json::to_string_pretty(&record).unwrap()).unwrap();
    assert_eq!(back, record);
    assert_eq!(back.check(spec), Ok(()));
    assert_eq!(back.params(spec).unwrap().values, cal.params.values);
    // Another mechanism.
    let other = common::gough_stewart("gough-stewart-6");
    assert!(matches!(
        back.check(other.spec()),
        Err(RecordError::OtherMechanism { .. })
    ));
    // The same mechanism with another nominal value.
    let mut moved = spec.clone();
    moved.nominal[0] += 0.1;
    assert!(matches!(
        back.check(&moved),
        Err(RecordError::OtherMechanism { .. })
    ));
    // A newer version, another format.
    let newer = CalibrationRecord {
        version: CALIBRATION_VERSION + 1,
        ..back.clone()
    };
    assert_eq!(
        newer.check(spec),
        Err(RecordError::Version {
            found: CALIBRATION_VERSION + 1
        })
    );
    let other_format = CalibrationRecord {
        format: "x".into(),
        ..back.clone()
    };
    assert!(matches!(
        other_format.check(spec),
        Err(RecordError::Format(_))
    ));
    // A report written before versions: its mechanism cannot be told, so
    // it is refused (it was read by names, and another mechanism's
    // calibration with the same names was taken).
    let legacy = CalibrationRecord {
        format: String::new(),
        version: 0,
        mechanism_identity: String::new(),
        ..back.clone()
    };
    assert!(legacy.check(spec).is_err());
    let legacy = CalibrationRecord {
        version: 0,
        ..back.clone()
    };
    assert_eq!(legacy.check(spec), Err(RecordError::Version { found: 0 }));
    // Every member checked (issue 50, 6).
    let member = |r: CalibrationRecord| match r.check(spec) {
        Err(RecordError::Member(m)) => m,
        other => panic!("{other:?}"),
    };
    let mut missing = back.clone();
    missing.parameters.retain(|p| p.name != "k1");
    assert!(member(missing).contains("lacks `k1`"));
    let mut twice = back.clone();
    twice.parameters.push(twice.parameters[0].clone());
    assert!(member(twice).contains("twice"));
    let mut asymmetric = back.clone();
    asymmetric.covariance.matrix[0][1] *= 1.01;
    assert!(member(asymmetric).contains("not symmetric"));
    let mut correlated = back.clone();
    let v = correlated.covariance.matrix[0][0].sqrt() * correlated.covariance.matrix[1][1].sqrt();
    correlated.covariance.matrix[0][1] = 2.0 * v;
    correlated.covariance.matrix[1][0] = 2.0 * v;
    assert!(member(correlated).contains("beyond ±1"));
    let mut huge = back.clone();
    huge.noise[0].redundancy = Some(1e308);
    assert!(member(huge).contains("redundancy of 1e308"));
    let mut given = back.clone();
    given.noise[0].estimated = false;
    assert!(member(given).contains("must be null"));
    assert_eq!(back.dof(), cal.noise[0].redundancy);
    // A value the mechanism cannot have: refused by the record, with the
    // mechanism at hand.
    let mut impossible = back.clone();
    impossible.parameters[0].identified = -280.0;
    assert_eq!(impossible.check(spec), Ok(()));
    assert!(matches!(
        impossible.checked_params(&mech),
        Err(RecordError::Invalid(_))
    ));
    assert_eq!(
        back.checked_params(&mech).unwrap().values,
        cal.params.values
    );
}

/// A tool load is a working load or a named mistake: on every shipped
/// mechanism a load of 10 N (and 1 N·m) passes, one of 10⁹ is refused with a
/// message naming the load and its units.
#[test]
fn a_load_beyond_any_working_load_is_named() {
    use pkmcal::engine::load::check_load;
    fn check<M: Mechanism>(m: &M) {
        let spec = m.spec();
        let nominal = Params::nominal(spec);
        let small: Vec<f64> = spec
            .tool_units
            .iter()
            .map(|u| if *u == Unit::Radian { 1.0 } else { 10.0 })
            .collect();
        assert_eq!(check_load(m, &nominal, &small), Ok(()), "{}", spec.name);
        assert_eq!(check_load(m, &nominal, &[]), Ok(()), "{}", spec.name);
        let huge = vec![1e9; spec.tool_axes.len()];
        let e = check_load(m, &nominal, &huge).unwrap_err().to_string();
        assert!(
            e.contains("the tool load") && e.contains("N·m"),
            "{}: {e}",
            spec.name
        );
    }
    check(&JeongKim2Dof::new());
    for name in ["3-rrr", "4-rrr", "five-bar", "jeong-kim-planar"] {
        check(&common::planar(name));
    }
    for name in ["gough-stewart-6", "gough-stewart-8"] {
        check(&common::gough_stewart(name));
    }
    for name in [
        "3-prs",
        "linear-delta",
        "linear-delta-4",
        "rotary-delta",
        "spatial-gough-stewart-6",
    ] {
        check(&common::spatial(name));
    }
}
