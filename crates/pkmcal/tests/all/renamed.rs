//! Parameters renamed: one name per meaning across the kinds (the
//! Gough–Stewart platform's stiffness `kL1…`, as on its spatial twin; the
//! four-tower delta's `delta_radius`, as with three towers), the old names
//! still read wherever a parameter is named, each time with a typed note.

use crate::common;
use pkmcal::apply::budget::{Tolerance, resolve_tolerances};
use pkmcal::identify::{
    CalibrationRecord, RecordError, free_with_priors, mechanism_identities, mechanism_identity,
    named_priors, resolve_free_set,
};
use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::*;

fn kl(n: usize) -> Renamed {
    Renamed::new(format!("k{n}"), format!("kL{n}"))
}

/// The Gough–Stewart stiffness follows the rule of every kind (`k` and the
/// joint's name), so the built-in platform and its spatial twin name it
/// alike; `k1` is an old name of `kL1`.
#[test]
fn the_hexapods_name_their_stiffness_alike() {
    let gs = common::gough_stewart("gough-stewart-6");
    let twin = common::spatial("spatial-gough-stewart-6");
    assert_eq!(gs.spec().stiffness, twin.spec().stiffness);
    assert_eq!(gs.spec().stiffness[0], "kL1");
    let spec = gs.spec();
    let k1 = spec.param_index("kL1").unwrap();
    assert_eq!(spec.parameter_index("kL1"), Some((k1, None)));
    assert_eq!(spec.parameter_index("k1"), Some((k1, Some(&kl(1)))));
    assert_eq!(spec.param_index("k1"), Ok(k1));
    assert_eq!(spec.canonical("k1"), "kL1");
    assert_eq!(spec.canonical("a1x"), "a1x");
    assert_eq!(spec.parameter_index("k7"), None);
    assert!(spec.param_index("k7").is_err());
    // The reference mechanism's joints are q1…: its k1 is its current name.
    let r = JeongKim2Dof::new();
    assert_eq!(
        r.spec().parameter_index("k1"),
        Some((r.spec().n_params() - 3, None))
    );
}

/// An old name in a free list, a fix list and a tolerance: accepted, read
/// as the parameter it names now, and noted.
#[test]
fn an_old_name_in_a_free_list_or_a_tolerance_is_read_with_a_note() {
    let gs = common::gough_stewart("gough-stewart-8");
    let spec = gs.spec();
    let tool = MeasurementModel::tool(spec);
    let (k1, k2) = (
        spec.param_index("kL1").unwrap(),
        spec.param_index("kL2").unwrap(),
    );
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let free = names(&["a1x", "k1", "k2"]);
    let set = resolve_free_set(
        spec,
        &tool,
        &spec.default_free,
        Some(&free),
        &names(&["k2"]),
    )
    .unwrap();
    assert!(set.contains(&k1) && !set.contains(&k2));
    assert_eq!(
        set,
        resolve_free_set(
            spec,
            &tool,
            &spec.default_free,
            Some(&names(&["a1x", "kL1"])),
            &[]
        )
        .unwrap()
    );
    assert_eq!(
        spec.renamed_among(free.iter().map(String::as_str)),
        [kl(1), kl(2)]
    );
    // A tolerance under the old name is the new one's.
    let given = vec![("k2".to_string(), Tolerance::Relative(0.2))];
    let resolved = resolve_tolerances(spec, &given).unwrap();
    assert_eq!(resolved, [(k2, 0.2 * spec.nominal[k2])]);
    let priors = named_priors(spec, &tool, &given).unwrap();
    assert_eq!(priors[0].index, k2);
    // ... and frees it, unless the fix list names it (old or new).
    let with = free_with_priors(spec, &tool, &set, &priors, &[]);
    assert!(with.contains(&k2));
    assert_eq!(
        free_with_priors(spec, &tool, &set, &priors, &names(&["k2"])),
        set
    );
    assert_eq!(spec.renamed_among(["k2", "kL2", "a1x"]), [kl(2)]);
}

/// A parameter file's names (`k1 = 5000`, `radius = 130.2`): read as the
/// current parameters, with the old names noted.
#[test]
fn a_parameter_file_under_old_names_is_read_with_a_note() {
    let gs = common::gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let (p, notes) =
        Params::from_named_noting(spec, [("k1", 5000.0), ("a1x", 1.0), ("kL3", 7000.0)]).unwrap();
    assert_eq!(p.get(spec, "kL1").unwrap(), 5000.0);
    assert_eq!(p.get(spec, "k3").unwrap(), 7000.0);
    assert_eq!(notes, [kl(1)]);
    assert_eq!(Params::from_named(spec, [("k1", 5000.0)]).unwrap(), {
        let mut q = Params::nominal(spec);
        q.set(spec, "kL1", 5000.0).unwrap();
        q
    });
    // A description declares its own: the four-tower delta's radius.
    let delta = common::spatial("linear-delta-4");
    let ds = delta.spec();
    assert_eq!(ds.renamed, [Renamed::new("radius", "delta_radius")]);
    let (p, notes) = Params::from_named_noting(ds, [("radius", 130.2)]).unwrap();
    assert_eq!(p.get(ds, "delta_radius").unwrap(), 130.2);
    assert_eq!(notes, [Renamed::new("radius", "delta_radius")]);
}

/// A calibration record saved before the renaming (old names, and the
/// identity they gave) serves the mechanism, its values read as the
/// current parameters, the renaming noted; one of another mechanism still
/// does not.
#[test]
fn a_record_saved_under_old_names_is_accepted() {
    let gs = common::gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let ids = mechanism_identities(spec);
    assert_eq!(ids.len(), 2);
    assert_eq!(ids[0], mechanism_identity(spec));
    // The identity under the old names is the one the platform had.
    let mut before = spec.clone();
    before.stiffness = (1..=6).map(|i| format!("k{i}")).collect();
    before.renamed.clear();
    assert_eq!(ids[1], mechanism_identity(&before));
    let old = before.param_names();
    let values: Vec<f64> = (0..spec.n_params())
        .map(|i| spec.nominal[i] * 1.001 + 0.01)
        .collect();
    let record = CalibrationRecord {
        format: pkmcal::identify::CALIBRATION_FORMAT.into(),
        version: pkmcal::identify::CALIBRATION_VERSION,
        mechanism: spec.name.clone(),
        mechanism_identity: ids[1].clone(),
        model: Model::Exact,
        parameters: old
            .iter()
            .zip(&values)
            .map(|(n, v)| pkmcal::identify::RecordedParameter {
                name: n.to_string(),
                identified: *v,
            })
            .collect(),
        covariance: pkmcal::identify::ParameterCovariance {
            names: vec!["a1x".into(), "k1".into()],
            matrix: vec![vec![1e-4, 0.0], vec![0.0, 25.0]],
        },
        noise: vec![],
        priors: vec![],
        scale: None,
    };
    assert_eq!(record.check(spec), Ok(()));
    assert_eq!(record.params(spec).unwrap().values, values);
    assert_eq!(record.renamed(spec), (1..=6).map(kl).collect::<Vec<_>>());
    let (idx, _) = record.covariance.resolve(spec).unwrap();
    assert_eq!(idx, [0, spec.param_index("kL1").unwrap()]);
    // As saved today: current names and identity, nothing left to note.
    let today = record.in_current_names(spec);
    assert_eq!(today.mechanism_identity, ids[0]);
    assert_eq!(today.covariance.names, ["a1x", "kL1"]);
    let names: Vec<&str> = today.parameters.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, spec.param_names());
    assert_eq!(today.params(spec), record.params(spec));
    assert!(today.renamed(spec).is_empty() && today.check(spec).is_ok());
    // Another mechanism's record is still refused, and a mechanism with no
    // renaming has one identity.
    let other = common::gough_stewart("gough-stewart-8");
    assert!(matches!(
        record.check(other.spec()),
        Err(RecordError::OtherMechanism { .. })
    ));
    assert_eq!(mechanism_identities(JeongKim2Dof::new().spec()).len(), 1);
}

/// A `[renamed]` table whose old name is still a parameter, or whose new
/// name is none, is refused, naming the table.
#[test]
fn a_renamed_table_must_name_an_old_name_and_a_parameter() {
    for (table, needle) in [
        (
            "arm_a = \"delta_radius\"",
            "`arm_a` is a parameter of the mechanism",
        ),
        (
            "radius = \"tower_radius\"",
            "`tower_radius` is not a parameter",
        ),
    ] {
        let mut t = common::table("linear-delta-4");
        t.insert("renamed".into(), toml::Value::Table(table.parse().unwrap()));
        let d: SpatialDescription = t.try_into().unwrap();
        let e = SpatialMechanism::new(&d).unwrap_err().to_string();
        assert!(e.contains("[renamed]") && e.contains(needle), "{e}");
    }
}
