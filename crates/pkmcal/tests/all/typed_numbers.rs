//! Every number a user types is bounded where the library reads it and
//! shown sensibly in the refusal (issue 50, fourth round): tolerances (as a
//! σ or a percentage of the nominal value), stated and simulated noise, a
//! record's degrees of freedom. Fuzzed with proptest (seeded by proptest's
//! own deterministic runner, a few hundred cases: well under a second): no
//! panic, a σ that enters a fit finite and in range, a refusal that names
//! the parameter and never prints `inf` or a 300-digit number.

use crate::common::spread;
use pkmcal::identify::prior::{MAX_RELATIVE_TOLERANCE, Tolerance, resolve_tolerances};
use pkmcal::identify::{CalibrationRecord, RecordError, Scale};
use pkmcal::{CalibrationOptions, JeongKim2Dof, MeasurementModel, Mechanism, Model, Noise, Params};
use proptest::prelude::*;

/// Whether a message shows a number sensibly: no `inf`/`NaN` the user did
/// not type, no run of more than 20 digits.
fn sensible(message: &str) -> bool {
    let mut run = 0;
    for c in message.chars() {
        run = if c.is_ascii_digit() { run + 1 } else { 0 };
        if run > 20 {
            return false;
        }
    }
    !message.contains("inf") && !message.contains("NaN")
}

/// `l11=1e308%` was refused as "tolerance of l11 = inf": the percentage is
/// bounded where it is read, and the refusal shows what was typed.
#[test]
fn a_huge_percentage_is_refused_as_typed() {
    let e = Tolerance::parse("1e308%").unwrap_err().to_string();
    assert!(e.contains("1e308 %") && sensible(&e), "{e}");
    let m = JeongKim2Dof::new();
    // Within the percentage bound, but a σ beyond any length: named with
    // the percentage and the nominal value.
    let given = vec![(
        "l11".to_string(),
        Tolerance::Relative(MAX_RELATIVE_TOLERANCE),
    )];
    assert!(resolve_tolerances(m.spec(), &given).is_ok());
    let e = resolve_tolerances(m.spec(), &[("l11".into(), Tolerance::Absolute(1e300))])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("l11") && e.contains("1e300") && sensible(&e),
        "{e}"
    );
    let e = resolve_tolerances(m.spec(), &[("l11".into(), Tolerance::Relative(1e306))])
        .unwrap_err()
        .to_string();
    assert!(e.contains("l11") && sensible(&e), "{e}");
}

/// Ordinary values mostly, and every kind of extreme a user can type.
fn typed() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => 1e-6..1e3f64,
        2 => prop::sample::select(vec![
            0.0, -0.0, 1e-300, 5e-324, 1e-12, 1e-9, 1e6, 1e7, 1e155, 1e300, f64::MAX,
            -1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY,
        ]),
        1 => any::<f64>(),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// A tolerance typed as a σ or a percentage, on any parameter: read
    /// and resolved without a panic; a σ that enters is finite, positive
    /// and within its unit's range; a refusal names the parameter (or the
    /// text) and shows the number sensibly.
    #[test]
    fn tolerances_typed_are_bounded_where_read(v in typed(), percent in any::<bool>(), which in 0usize..16) {
        let m = JeongKim2Dof::new();
        let spec = m.spec();
        let name = spec.param_names()[which].to_string();
        let text = if percent { format!("{v}%") } else { format!("{v}") };
        match Tolerance::parse(&text) {
            // A typed `inf` or `NaN` may be echoed as such.
            Err(e) => prop_assert!(!v.is_finite() || sensible(&e.to_string().replace(&text, "")), "{e}"),
            Ok(t) => match resolve_tolerances(spec, &[(name.clone(), t)]) {
                Ok(r) => {
                    let unit = spec.param_unit(r[0].0);
                    prop_assert!(r[0].1.is_finite() && r[0].1 > 0.0 && r[0].1 <= unit.max_magnitude());
                }
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(e.contains(&name) && sensible(&e), "{e}");
                }
            },
        }
    }

    /// A stated or simulated noise: checked once, in range or refused
    /// naming its field, never a panic.
    #[test]
    fn noise_values_are_bounded_where_read(length in typed(), angle in typed()) {
        let noise = Noise { length, angle };
        match noise.check("noise") {
            Ok(()) => prop_assert!(length.is_finite() && length > 0.0 && angle.is_finite() && angle > 0.0),
            Err(e) => prop_assert!(e.to_string().contains("noise."), "{e}"),
        }
    }
}

/// A record's `scale` with 1e308 degrees of freedom (more than its readings)
/// was taken as the normal limit, silently: refused, the number shown in
/// exponent form.
#[test]
fn a_record_with_more_degrees_of_freedom_than_readings_is_refused() {
    let mech = JeongKim2Dof::new();
    let spec = mech.spec();
    let tool = MeasurementModel::tool(spec);
    let data = pkmcal::simulate(
        &mech,
        &tool,
        &Params::nominal(spec),
        &spread(&mech, 20),
        Noise::lengths(0.002),
        3,
    )
    .unwrap();
    let cal = pkmcal::calibrate(
        &mech,
        &tool,
        &data,
        &Params::nominal(spec),
        &CalibrationOptions::new(spec, Model::Exact),
    )
    .unwrap();
    let mut record = CalibrationRecord::new(spec, &cal);
    assert_eq!(record.check(spec), Ok(()));
    for dof in [1e308, 41.0] {
        record.scale = Some(Scale::Estimated { dof });
        match record.check(spec) {
            Err(RecordError::Member(m)) => assert!(m.contains("`scale`") && sensible(&m), "{m}"),
            other => panic!("{other:?}"),
        }
    }
    record.scale = Some(Scale::Estimated { dof: 40.0 });
    assert_eq!(record.check(spec), Ok(()));
}

/// A tolerance in range but wider than the mechanism holds together
/// (`l11=30%`): the budget's machines drawn from it cannot reach a target,
/// which was blamed on "pose 7" of a grid the user never gave; it names
/// the tolerances and what to do.
#[test]
fn a_budget_whose_draws_fall_apart_blames_the_tolerances() {
    use pkmcal::apply::budget::{BudgetOptions, budget};
    let m = JeongKim2Dof::new();
    let tol = resolve_tolerances(
        m.spec(),
        &[("l11".into(), Tolerance::parse("30%").unwrap())],
    )
    .unwrap();
    let e = budget(
        &m,
        &spread(&m, 200),
        &tol,
        &BudgetOptions {
            model: Model::Exact,
            force: vec![],
            samples: 3000,
            seed: 1,
            calibration: None,
        },
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("drawn from the tolerances") && !e.starts_with("pose"),
        "{e}"
    );
}
