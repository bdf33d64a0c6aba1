//! Tests of `pkmcal_io::firmware::choices`.

use pkmcal::{Field, RequestError};
use pkmcal_io::firmware::choices::*;

#[test]
fn probe_noise_is_bounded() {
    assert_eq!(probe_noise(0.005), Ok(0.005));
    for bad in [0.0, -0.01, f64::NAN, f64::INFINITY, 1.5] {
        let e = probe_noise(bad).unwrap_err();
        assert_eq!(e.field(), Some(Field::ProbeNoise), "{bad}");
    }
}

#[test]
fn g33_choices_are_bounded() {
    assert_eq!(g33_points(1), Ok(1));
    assert_eq!(g33_points(10), Ok(10));
    for bad in [0, 11, 256, usize::MAX] {
        let e = g33_points(bad).unwrap_err();
        assert_eq!(e.field(), Some(Field::G33Points), "{bad}");
    }
    assert_eq!(g33_radius(80.0), Ok(80.0));
    for bad in [0.0, -5.0, f64::NAN, f64::INFINITY] {
        let e = g33_radius(bad).unwrap_err();
        assert_eq!(e.field(), Some(Field::G33Radius), "{bad}");
    }
}

#[test]
fn physical_options_need_physical() {
    let c = Choices {
        probe_noise: Some(0.005),
        ..Choices::default()
    };
    assert!(matches!(
        c.check(),
        Err(RequestError::Belongs {
            field: Field::ProbeNoise,
            needs: Field::Physical,
            ..
        })
    ));
    let c = Choices {
        physical: true,
        probe_noise: Some(0.005),
        ..Choices::default()
    };
    assert_eq!(c.check(), Ok(()));
    let c = Choices {
        physical: true,
        out_dir: true,
        ..Choices::default()
    };
    assert_eq!(c.check().unwrap_err().field(), Some(Field::OutDir));
}
