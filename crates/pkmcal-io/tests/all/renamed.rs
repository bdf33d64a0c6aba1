//! A parameter file written before a parameter was renamed is still read:
//! its old names are the library's ([`pkmcal::Spec::renamed`]), mapped to
//! the current ones.

use pkmcal::Mechanism;
use pkmcal_io::description::mechanism_from_str;
use pkmcal_io::params::params_from_str;

fn example(name: &str) -> String {
    let path = format!(
        "{}/../../examples/{name}/mechanism.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    std::fs::read_to_string(path).unwrap()
}

#[test]
fn a_parameter_file_under_old_names_is_read_as_the_current_names() {
    let gs = mechanism_from_str(&example("gough-stewart-6")).unwrap();
    let spec = gs.spec();
    let p = params_from_str("k1 = 5000.0\nkL2 = 6000.0\na1x = 1.5\n", spec).unwrap();
    assert_eq!(p.get(spec, "kL1").unwrap(), 5000.0);
    assert_eq!(p.get(spec, "kL2").unwrap(), 6000.0);
    let delta = mechanism_from_str(&example("linear-delta-4")).unwrap();
    let spec = delta.spec();
    let p = params_from_str("radius = 130.2\n", spec).unwrap();
    assert_eq!(p.get(spec, "delta_radius").unwrap(), 130.2);
    assert_eq!(
        spec.renamed_among(["radius"]),
        [pkmcal::Renamed::new("radius", "delta_radius")]
    );
}
