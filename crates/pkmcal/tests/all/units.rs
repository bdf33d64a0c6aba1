//! Tests of `pkmcal::units`.

use pkmcal::units::*;

/// What `describe` writes, `from_description` reads back, for every
/// combination of units and counts.
#[test]
fn the_units_line_reads_back() {
    for angle in [AngleUnit::Radian, AngleUnit::Degree] {
        for length in [
            LengthUnit::Millimetre,
            LengthUnit::Metre,
            LengthUnit::Micrometre,
        ] {
            for counts_per_rev in [None, Some(4096.0), Some(1e-3 + 2.5)] {
                for counts_per_mm in [None, Some(80.0)] {
                    let u = FileUnits {
                        angle,
                        length,
                        counts_per_rev,
                        counts_per_mm,
                    };
                    assert_eq!(FileUnits::from_description(&u.describe()).unwrap(), u);
                }
            }
        }
    }
    assert!(FileUnits::from_description("angles in grad").is_err());
    assert!(FileUnits::from_description("lengths in ft").is_err());
    assert!(FileUnits::from_description("revolute commands in counts (-1 per rev)").is_err());
}

/// A key given twice is refused (it would silently take the last);
/// spelled-out angle units are read.
#[test]
fn units_are_given_once() {
    assert!(PartialUnits::parse("angle=deg,angle=rad").is_err());
    assert!(PartialUnits::parse("length=m, length=m").is_err());
    let u = PartialUnits::parse("angle=degree,length=m").unwrap();
    assert_eq!(u.angle, Some(AngleUnit::Degree));
}

#[test]
fn readable_scales() {
    assert_eq!(Unit::Millimetre.readable(0.002), (1e3, "µm"));
    assert_eq!(Unit::Millimetre.readable(2.0), (1.0, "mm"));
    assert_eq!(Unit::Radian.readable(1e-5), (1e6, "µrad"));
    assert_eq!(Unit::Radian.readable(2e-3), (1e3, "mrad"));
    assert_eq!(
        Unit::Radian.stiffness_of_joint(),
        Unit::NewtonMetrePerRadian
    );
    assert_eq!(
        Unit::Millimetre.stiffness_of_joint(),
        Unit::NewtonPerMillimetre
    );
}

#[test]
fn file_units() {
    let u = FileUnits::default()
        .with(&PartialUnits::parse("angle=deg, length=m, counts_per_mm=100").unwrap());
    assert_eq!(u.factor(Unit::Radian, Role::Command), PI_180);
    assert_eq!(u.factor(Unit::Radian, Role::Reading), PI_180);
    assert_eq!(u.factor(Unit::Millimetre, Role::Reading), 1e3);
    assert_eq!(u.factor(Unit::Millimetre, Role::Command), 0.01);
    assert_eq!(u.symbol(Unit::Millimetre, Role::Command), "counts");
    let c = FileUnits::default().with(&PartialUnits::parse("counts_per_rev=4096").unwrap());
    assert_eq!(
        c.factor(Unit::Radian, Role::Command),
        std::f64::consts::TAU / 4096.0
    );
    assert_eq!(c.factor(Unit::Radian, Role::Reading), 1.0);
    assert!(PartialUnits::parse("angle=grad").is_err());
    assert!(PartialUnits::parse("counts_per_rev=-3").is_err());
    assert!(PartialUnits::parse("speed=1").is_err());
    assert!(FileUnits::default().is_internal());
}

const PI_180: f64 = std::f64::consts::PI / 180.0;
