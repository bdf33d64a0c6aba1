//! Spatial mechanisms from descriptions (`type = "spatial"`): the shipped
//! examples (linear and rotary deltas, a redundant 4-tower delta, a 3-PRS
//! head, a Gough–Stewart platform written in this form), their derivatives,
//! their agreement with the built-in Gough–Stewart platform, calibration, and
//! the messages of bad descriptions.

use crate::common;
use common::{gough_stewart, perturbed_by_unit, spatial, table};
use pkmcal::kinds::description::Value;
use pkmcal::kinds::spatial::*;
use pkmcal::linalg::small::dot;
use pkmcal::mechanism::autodiff::{automatic_jacobians, jacobians, output_hessians, weighted_sum};
use pkmcal::{Mechanism, Model, Params, SpatialDescription, SpatialMechanism};
use rand::{RngExt, SeedableRng};

/// The shipped spatial examples.
const EXAMPLES: [&str; 5] = [
    "linear-delta",
    "linear-delta-4",
    "rotary-delta",
    "3-prs",
    "spatial-gough-stewart-6",
];

/// Per-leg derivatives agree with whole-mechanism automatic differentiation
/// (relative).
const PER_LEG_REL: f64 = 1e-12;
/// Central differences agree with exact first derivatives (relative to the
/// entry's scale).
const CENTRAL_DIFF_REL: f64 = 1e-6;
/// Two descriptions of one mechanism agree (mm, rad).
const SAME_MECHANISM: f64 = 1e-9;
/// The adjoint and the direct linearisation agree (relative).
const ADJOINT_REL: f64 = 1e-9;
/// Identification recovers simulated errors to within this (mm, rad).
const RECOVERED: f64 = 1e-6;

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * (1.0 + b.abs())
}

/// A configuration near the reference, not closed: every derivative must
/// hold away from closure too.
fn jittered(spec: &pkmcal::Spec, rng: &mut rand::rngs::StdRng) -> Vec<f64> {
    spec.reference_q
        .iter()
        .zip(&spec.joint_units)
        .map(|(v, u)| {
            v + match u {
                pkmcal::Unit::Radian => rng.random_range(-0.1..0.1),
                _ => rng.random_range(-5.0..5.0),
            }
        })
        .collect()
}

/// The per-leg first and second derivatives equal automatic differentiation
/// of the whole mechanism, on every column range, at perturbed parameters
/// and joints away from closure; the first ones equal central differences.
#[test]
fn per_leg_derivatives_equal_automatic_and_central_ones() {
    let mechanisms = EXAMPLES
        .iter()
        .map(|n| (*n, spatial(n)))
        .chain([("U-P-S hexapod", ups_hexapod())]);
    for (name, m) in mechanisms {
        let spec = m.spec();
        let (nq, ng) = (spec.joints.len(), spec.n_geometric());
        let rho = perturbed_by_unit(spec, 3, 0.5, 0.01).values[..ng].to_vec();
        let mut rng = rand::rngs::StdRng::seed_from_u64(17);
        let n = nq + ng;
        for _ in 0..5 {
            let q = jittered(spec, &mut rng);
            for cols in [0..n, 0..nq, 2..n.min(17), n - 5..n, 0..0] {
                let leg = jacobians(&m, &q, &rho, cols.clone());
                let auto = automatic_jacobians(&m, &q, &rho, cols.clone());
                assert!(
                    leg.g
                        .iter()
                        .zip(&auto.g)
                        .all(|(a, b)| close(*a, *b, PER_LEG_REL)),
                    "{name} g"
                );
                assert_eq!(leg.x, auto.x, "{name} x");
                for (a, b) in [(&leg.dg, &auto.dg), (&leg.dx, &auto.dx)] {
                    assert_eq!(a.shape(), b.shape());
                    assert!(
                        a.iter()
                            .zip(b.iter())
                            .all(|(a, b)| close(*a, *b, PER_LEG_REL)),
                        "{name} {cols:?}"
                    );
                }
            }
            // Central differences of g in every variable of [q; ρ].
            let j = jacobians(&m, &q, &rho, 0..n);
            let mut v: Vec<f64> = q.iter().chain(&rho).copied().collect();
            for c in 0..n {
                let h = 1e-6 * v[c].abs().max(1.0);
                let x0 = v[c];
                v[c] = x0 + h;
                let gp = jacobians(&m, &v[..nq], &v[nq..], 0..0).g;
                v[c] = x0 - h;
                let gm = jacobians(&m, &v[..nq], &v[nq..], 0..0).g;
                v[c] = x0;
                for r in 0..spec.n_constraints {
                    let fd = (gp[r] - gm[r]) / (2.0 * h);
                    let scale = 1.0 + j.dg.column(c).amax();
                    assert!(
                        (fd - j.dg[(r, c)]).abs() <= CENTRAL_DIFF_REL * scale,
                        "{name}: ∂g{r}/∂{} = {} by central differences, {} exactly",
                        if c < nq {
                            &spec.joints[c]
                        } else {
                            &spec.geometric[c - nq]
                        },
                        fd,
                        j.dg[(r, c)]
                    );
                }
            }
            let lambda: Vec<f64> = (0..spec.n_constraints)
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let mu: Vec<f64> = (0..spec.tool_axes.len())
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let leg = m.weighted_hessian(&q, &rho, &lambda, &mu);
            let h = output_hessians(&m, &q, &rho, 0..nq, 0..n);
            let w: Vec<f64> = lambda.iter().chain(&mu).copied().collect();
            let auto = weighted_sum(&h, &w);
            assert_eq!(leg.shape(), auto.shape());
            assert!(
                leg.iter()
                    .zip(auto.iter())
                    .all(|(a, b)| close(*a, *b, PER_LEG_REL)),
                "{name} weighted Hessian"
            );
            let leg = m.joint_hessians(&q, &rho);
            let auto = output_hessians(&m, &q, &rho, 0..nq, 0..nq);
            assert_eq!(leg.len(), auto.len());
            for (a, b) in leg.iter().zip(&auto) {
                assert!(
                    a.iter()
                        .zip(b.iter())
                        .all(|(a, b)| close(*a, *b, PER_LEG_REL)),
                    "{name} joint Hessians"
                );
            }
        }
    }
}

/// The Gough–Stewart platform written as a spatial description predicts the
/// poses of the built-in one (exact model: deflections included), for
/// perturbed parameters, and its inverse kinematics gives the same legs.
#[test]
fn gough_stewart_as_spatial_predicts_like_the_builtin() {
    let builtin = gough_stewart("gough-stewart-6");
    let sp = spatial("spatial-gough-stewart-6");
    let (bs, ss) = (builtin.spec(), sp.spec());
    let targets = common::spread(&builtin, 20);
    for seed in 0..3 {
        let truth = perturbed_by_unit(bs, seed, 0.5, 0.0);
        let mut truth_s = Params::nominal(ss);
        for (i, name) in bs.param_names().iter().enumerate() {
            truth_s.set(ss, name, truth.values[i]).unwrap();
        }
        for t in &targets {
            let qb = pkmcal::inverse_kinematics(&builtin, truth.geometric(), t).unwrap();
            let qs = pkmcal::inverse_kinematics(&sp, truth_s.geometric(), t).unwrap();
            assert!(
                qb.iter()
                    .zip(&qs)
                    .all(|(a, b)| (a - b).abs() < SAME_MECHANISM),
                "{qb:?} {qs:?}"
            );
            let commands: Vec<f64> = qb[..6].iter().map(|l| l + 0.3).collect();
            let pb = pkmcal::predict(&builtin, &truth, &commands, Model::Exact, &[]).unwrap();
            let ps = pkmcal::predict(&sp, &truth_s, &commands, Model::Exact, &[]).unwrap();
            assert!(
                pb.x.iter()
                    .zip(&ps.x)
                    .all(|(a, b)| (a - b).abs() < SAME_MECHANISM),
                "{:?} {:?}",
                pb.x,
                ps.x
            );
        }
    }
}

/// Every example calibrates its default free parameters back to the truth
/// from noise-free simulated measurements (the default sets are
/// identifiable); on the redundant delta the actuators fight.
#[test]
fn examples_calibrate_to_the_truth_without_noise() {
    for (name, poses) in [
        ("linear-delta", 30),
        ("linear-delta-4", 30),
        ("rotary-delta", 30),
        ("3-prs", 30),
    ] {
        let m = spatial(name);
        let spec = m.spec();
        let all = perturbed_by_unit(spec, 11, 0.3, 0.002);
        let mut truth = Params::nominal(spec);
        for n in &spec.default_free {
            let i = spec.param_index(n).unwrap();
            if i < spec.n_geometric() + spec.n_actuated() {
                truth.values[i] = all.values[i];
            }
        }
        let targets = common::spread(&m, poses);
        let model = pkmcal::MeasurementModel::tool(spec);
        let data = pkmcal::simulate(&m, &model, &truth, &targets, 0.0, 1).unwrap();
        let mut opts = pkmcal::CalibrationOptions::new(spec, Model::Exact);
        opts.free = spec
            .default_free
            .iter()
            .map(|n| spec.param_index(n).unwrap())
            .collect();
        let cal = pkmcal::calibrate(&m, &model, &data, &Params::nominal(spec), &opts).unwrap();
        assert!(
            cal.identifiability.unidentifiable.is_empty(),
            "{name}: the default free set must be identifiable"
        );
        for &i in &opts.free {
            let d = (cal.params.values[i] - truth.values[i]).abs();
            let scale = if i >= spec.n_geometric() + spec.n_actuated() {
                truth.values[i]
            } else {
                1.0
            };
            assert!(
                d < RECOVERED * scale,
                "{name}: {} off by {d}",
                spec.param_names()[i]
            );
        }
        if name == "linear-delta-4" {
            let p = pkmcal::predict(&m, &truth, &data[0].commands, Model::Exact, &[]).unwrap();
            assert!(
                p.torque.iter().any(|t| t.abs() > 1.0),
                "the redundant delta's actuators must fight: {:?}",
                p.torque
            );
        }
    }
}

fn refused(edit: impl FnOnce(&mut toml::Table), base: &str) -> String {
    let mut t = table(base);
    edit(&mut t);
    match t.try_into::<SpatialDescription>() {
        Err(e) => e.to_string(),
        Ok(d) => SpatialMechanism::new(&d).unwrap_err().to_string(),
    }
}

fn leg(t: &mut toml::Table, i: usize) -> &mut toml::Table {
    t.get_mut("leg").unwrap().as_array_mut().unwrap()[i]
        .as_table_mut()
        .unwrap()
}

/// Bad descriptions are refused with a message that names the leg and joint.
#[test]
fn bad_descriptions_name_the_leg_and_joint() {
    // An unknown joint kind.
    let e = refused(
        |t| {
            leg(t, 1).get_mut("joint").unwrap().as_array_mut().unwrap()[0]
                .as_table_mut()
                .unwrap()
                .insert("kind".into(), "helical".into());
        },
        "linear-delta",
    );
    assert!(e.contains("helical") && e.contains("revolute"), "{e}");
    // A rod without its length.
    let e = refused(
        |t| {
            leg(t, 2)
                .get_mut("end")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .remove("length");
        },
        "linear-delta",
    );
    assert!(e.contains("leg `tower_c`") && e.contains("length"), "{e}");
    // Too few joints: a leg without its hinge takes a degree of freedom.
    let e = refused(
        |t| {
            leg(t, 0)
                .get_mut("joint")
                .unwrap()
                .as_array_mut()
                .unwrap()
                .pop();
            t.get_mut("assembly")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .remove("r1");
        },
        "3-prs",
    );
    assert!(e.contains("2 degrees of freedom"), "{e}");
    // A leg that cannot reach the platform at the reference pose.
    let e = refused(
        |t| {
            t.get_mut("parameters")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .insert("arm_b".into(), 90.0.into());
        },
        "linear-delta",
    );
    assert!(
        e.contains("[assembly]") && e.contains("does not close"),
        "{e}"
    );
    // An actuated joint without stiffness.
    let e = refused(
        |t| {
            leg(t, 0).get_mut("joint").unwrap().as_array_mut().unwrap()[0]
                .as_table_mut()
                .unwrap()
                .remove("stiffness");
        },
        "rotary-delta",
    );
    assert!(
        e.contains("leg `arm1`") && e.contains("`q1`") && e.contains("stiffness"),
        "{e}"
    );
    // A missing assembly guess.
    let e = refused(
        |t| {
            t.get_mut("assembly")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .remove("r2");
        },
        "3-prs",
    );
    assert!(e.contains("joint `r2`"), "{e}");
    // A singular reference: the rotary delta's arms stretched along the
    // forearms (the elbow straight).
    let e = refused(
        |t| {
            let p = t.get_mut("assembly").unwrap().as_table_mut().unwrap();
            p.insert(
                "pose".into(),
                toml::Value::Array(vec![0.0.into(), 0.0.into(), (-150.0).into()]),
            );
        },
        "rotary-delta",
    );
    assert!(
        e.contains("singular") || e.contains("does not close"),
        "{e}"
    );
    // Wrong number of tool axes for the degrees of freedom.
    let e = refused(
        |t| {
            t.get_mut("platform")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .remove("tool");
        },
        "3-prs",
    );
    assert!(
        e.contains("3 degrees of freedom") && e.contains("tool = ["),
        "{e}"
    );
    // Listed as the whole pose, it is observed beyond them; then the
    // workspace names every axis.
    let e = refused(
        |t| {
            t.get_mut("platform")
                .unwrap()
                .as_table_mut()
                .unwrap()
                .insert(
                    "tool".into(),
                    toml::Value::Array(
                        ["x", "y", "z", "rx", "ry", "rz"]
                            .map(toml::Value::from)
                            .to_vec(),
                    ),
                );
        },
        "3-prs",
    );
    assert!(e.contains("[workspace] needs `x = [min, max]`"), "{e}");
}

/// A height probe on a tilted bed: its reading is the tool's height above
/// the plane (checked against the formula), and a linear delta calibrates
/// Klipper's six parameters and the bed's two tilts from probe heights alone;
/// the bed's height trades with the three endstops and is named.
#[test]
fn probe_heights_on_a_tilted_bed_calibrate_a_delta() {
    let m = spatial("linear-delta");
    let spec = m.spec();
    let bed = [0.2, 0.003, -0.002];
    let probe = pkmcal::MeasurementModel::probe(spec).unwrap();
    let tilted = probe.clone().with_own(&bed).unwrap();
    let x = [10.0, -20.0, 5.0];
    let mut y = [0.0];
    tilted.observe(&x, tilted.nominal(), &mut y);
    let h = bed[0] - x[0] * bed[2].tan() + x[1] * bed[1].tan();
    assert!((y[0] - (x[2] - h)).abs() < 1e-12);
    let truth = Params::from_named(
        spec,
        [
            ("delta_radius", 130.5),
            ("angle_a", 3.67),
            ("angle_b", 5.755),
            ("da", 0.4),
            ("db", -0.2),
            ("dc", 0.1),
        ],
    )
    .unwrap();
    let targets = common::spread(&m, 30);
    let data = pkmcal::simulate(&m, &tilted, &truth, &targets, 0.0, 1).unwrap();
    let mut opts = pkmcal::CalibrationOptions::new(spec, Model::Exact);
    let names = [
        "delta_radius",
        "angle_a",
        "angle_b",
        "da",
        "db",
        "dc",
        "bed.rx",
        "bed.ry",
    ];
    opts.free = names
        .iter()
        .map(|n| probe.index_of(spec, n).unwrap())
        .collect();
    let cal = pkmcal::calibrate(&m, &probe, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.identifiability.unidentifiable.is_empty());
    for n in &names[..3] {
        let (a, b) = (
            cal.params.get(spec, n).unwrap(),
            truth.get(spec, n).unwrap(),
        );
        assert!((a - b).abs() < RECOVERED, "{n}: {a} vs {b}");
    }
    // The endstops absorb the bed's height (0.2 mm higher reads as
    // carriages 0.2 mm lower): each off by the same −0.2 mm.
    for n in ["da", "db", "dc"] {
        let d = cal.params.get(spec, n).unwrap() - truth.get(spec, n).unwrap();
        assert!((d + bed[0]).abs() < RECOVERED, "{n}: {d}");
    }
    assert!((cal.measurement[1] - bed[1]).abs() < RECOVERED);
    assert!((cal.measurement[2] - bed[2]).abs() < RECOVERED);
    // With the bed's height free too, that direction is named.
    opts.free.push(probe.index_of(spec, "bed.z").unwrap());
    let a = pkmcal::analyze(
        &m,
        &probe,
        &data,
        &Params::nominal(spec),
        Model::Exact,
        &opts.free,
        &[],
    )
    .unwrap();
    assert_eq!(a.unidentifiable.len(), 1, "{:?}", a.unidentifiable);
}

/// Fewer readings than free parameters (8 probe heights, every geometric
/// parameter of a delta free): the rank is at most 8 and every other
/// direction is named, one per missing rank (not one placeholder).
#[test]
fn fewer_readings_than_parameters_name_every_null_direction() {
    let m = spatial("linear-delta");
    let spec = m.spec();
    let probe = pkmcal::MeasurementModel::probe(spec).unwrap();
    let targets = common::spread(&m, 8);
    let data = pkmcal::simulate(&m, &probe, &Params::nominal(spec), &targets, 0.0, 1).unwrap();
    let free: Vec<usize> = (0..spec.n_geometric()).collect();
    let a = pkmcal::analyze(
        &m,
        &probe,
        &data,
        &Params::nominal(spec),
        Model::Exact,
        &free,
        &[],
    )
    .unwrap();
    assert!(a.rank <= 8, "{}", a.rank);
    assert_eq!(a.rank + a.unidentifiable.len(), free.len());
}

/// Pairs of points on the bed (z = 0) as Klipper's calibration object
/// measures them: from near the centre outwards at six angles, and between
/// neighbouring outer pillars.
fn object_pairs() -> Vec<(Vec<f64>, Vec<f64>)> {
    let at = |deg: f64, r: f64| {
        let a = deg.to_radians();
        vec![r * a.cos(), r * a.sin(), 0.0]
    };
    let angles = [210.0, 270.0, 330.0, 30.0, 90.0, 150.0];
    let mut pairs: Vec<(Vec<f64>, Vec<f64>)> =
        angles.iter().map(|&a| (at(a, 4.5), at(a, 69.5))).collect();
    for k in 0..6 {
        pairs.push((at(angles[k], 60.0), at(angles[(k + 1) % 6], 60.0)));
    }
    pairs
}

/// Probe heights and caliper distances in one fit: the identification
/// Jacobian of the mixed rows equals central differences, and the arm
/// lengths, which heights alone leave to trade with the radius, come back
/// to the truth with Klipper's six parameters (its extended calibration).
#[test]
fn distances_between_poses_identify_a_deltas_arm_lengths() {
    let m = spatial("linear-delta");
    let spec = m.spec();
    let probe = pkmcal::MeasurementModel::probe(spec).unwrap();
    let truth = Params::from_named(
        spec,
        [
            ("delta_radius", 130.5),
            ("angle_a", 3.67),
            ("angle_b", 5.755),
            ("da", 0.4),
            ("db", -0.2),
            ("dc", 0.1),
            ("arm_a", 250.6),
            ("arm_b", 249.7),
            ("arm_c", 250.3),
        ],
    )
    .unwrap();
    let heights = pkmcal::simulate(&m, &probe, &truth, &common::spread(&m, 20), 0.0, 1).unwrap();
    let distances =
        pkmcal::simulate_distances(&m, &probe, &truth, &object_pairs(), 0.0, 2).unwrap();
    assert!(
        distances
            .iter()
            .all(|d| d.partner.is_some() && d.measured.len() == 1)
    );
    let data: Vec<pkmcal::Measurement> = heights.iter().chain(&distances).cloned().collect();

    // Exact Jacobian of mixed rows.
    let problem =
        pkmcal::identify::IdentificationProblem::new(&m, &probe, &data, Model::Exact, &[]).unwrap();
    assert_eq!(problem.n_readings(), heights.len() + distances.len());
    let x: Vec<f64> = truth
        .values
        .iter()
        .chain(probe.nominal())
        .copied()
        .collect();
    let (r, j) = problem.residuals_and_jacobian(&x).unwrap();
    assert!(r.amax() < 1e-9, "noise-free residuals {}", r.amax());
    for c in 0..x.len() {
        let h = 1e-6 * (1.0 + x[c].abs());
        let (mut a, mut b) = (x.clone(), x.clone());
        a[c] += h;
        b[c] -= h;
        let fd = (problem.residuals(&a).unwrap() - problem.residuals(&b).unwrap()) / (2.0 * h);
        let scale = j.column(c).amax().max(fd.amax()).max(1.0);
        assert!(
            (&fd - j.column(c)).amax() < CENTRAL_DIFF_REL * scale,
            "column {c}"
        );
    }

    let names = [
        "delta_radius",
        "angle_a",
        "angle_b",
        "da",
        "db",
        "dc",
        "arm_a",
        "arm_b",
        "arm_c",
    ];
    let free: Vec<usize> = names.iter().map(|n| spec.param_index(n).unwrap()).collect();
    // Heights alone: the arms trade with the endstops (correlation above
    // 0.999) and the radius; the distances make the problem much better
    // conditioned.
    let id = |rows: &[pkmcal::Measurement]| {
        pkmcal::analyze(
            &m,
            &probe,
            rows,
            &Params::nominal(spec),
            Model::Exact,
            &free,
            &[],
        )
        .unwrap()
    };
    let (alone, both) = (id(&heights), id(&data));
    assert!(
        alone.correlations.iter().any(|c| c.r.abs() > 0.999),
        "{alone:?}"
    );
    assert!(
        alone.condition_number > 5.0 * both.condition_number,
        "{} vs {}",
        alone.condition_number,
        both.condition_number
    );
    // With the distances every one of the nine is identified.
    let mut opts = pkmcal::CalibrationOptions::new(spec, Model::Exact);
    opts.free = free;
    let cal = pkmcal::calibrate(&m, &probe, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.identifiability.unidentifiable.is_empty());
    for n in names {
        let (a, b) = (
            cal.params.get(spec, n).unwrap(),
            truth.get(spec, n).unwrap(),
        );
        assert!((a - b).abs() < RECOVERED, "{n}: {a} vs {b}");
    }
    // Distances are their own noise group, and their accuracy is reported.
    assert!(
        cal.noise
            .iter()
            .any(|g| g.axes == ["distance"] && g.count == 12)
    );
    let (acc, _, _) = pkmcal::calibration_accuracy(&m, &probe, &data, &cal, &[]).unwrap();
    let d = acc.distances.expect("distances");
    assert_eq!((d.count, acc.poses), (12, 20));
    assert!(d.before_max > 0.1 && d.after_max < RECOVERED, "{d:?}");
}

/// A distance row needs a tool with every position coordinate, and one
/// reading.
#[test]
fn distance_rows_are_checked() {
    let m = spatial("3-prs");
    let spec = m.spec();
    let tool = pkmcal::MeasurementModel::tool(spec);
    let row = pkmcal::Measurement {
        commands: spec.actuated.iter().map(|&j| spec.reference_q[j]).collect(),
        partner: Some(spec.actuated.iter().map(|&j| spec.reference_q[j]).collect()),
        measured: vec![0.0],
        ..Default::default()
    };
    let e = pkmcal::identify::IdentificationProblem::new(&m, &tool, &[row], Model::Exact, &[])
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("distances between poses") && e.contains("distance 1"),
        "{e}"
    );
    let delta = spatial("linear-delta");
    let spec = delta.spec();
    let probe = pkmcal::MeasurementModel::probe(spec).unwrap();
    let mut rows = pkmcal::simulate_distances(
        &delta,
        &probe,
        &Params::nominal(spec),
        &object_pairs()[..2],
        0.0,
        1,
    )
    .unwrap();
    rows[1].measured.push(1.0);
    let e = pkmcal::identify::IdentificationProblem::new(&delta, &probe, &rows, Model::Exact, &[])
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("distance 2: readings (distance)"), "{e}");
}

/// The hexapod of `examples/gough-stewart-6` written with universal joints:
/// each leg a universal joint at the base (`u{i}`, about x then y), an
/// actuated prismatic joint along the leg, and a spherical end on the
/// platform (U-P-S).
fn ups_hexapod() -> SpatialMechanism {
    let t = table("gough-stewart-6");
    let legs = t["leg"].as_array().unwrap();
    let mut s = String::from("[platform]\nmotion = \"full\"\n");
    let mut assembly = String::from("[assembly]\npose = [0.0, 0.0, 700.0, 0.0, 0.0, 0.0]\n");
    for (i, leg) in legs.iter().enumerate() {
        let n = i + 1;
        let v = |k: &str| -> Vec<f64> {
            leg[k]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_float().unwrap())
                .collect()
        };
        let (a, b) = (v("base"), v("platform"));
        s.push_str(&format!(
            "[[leg]]\nname = \"leg{n}\"\n\
             [[leg.joint]]\nname = \"u{n}\"\nkind = \"universal\"\nat = [\"a{n}x\", \"a{n}y\", \"a{n}z\"]\naxis = [1.0, 0.0, 0.0]\naxis2 = [0.0, 1.0, 0.0]\n\
             [[leg.joint]]\nname = \"L{n}\"\nkind = \"prismatic\"\naxis = [0.0, 0.0, 1.0]\nactuated = true\nstiffness = 50000.0\n\
             [leg.end]\nkind = \"spherical\"\nplatform = [\"b{n}x\", \"b{n}y\", \"b{n}z\"]\n"
        ));
        let d = [b[0] - a[0], b[1] - a[1], b[2] + 700.0 - a[2]];
        let len = d.iter().map(|x| x * x).sum::<f64>().sqrt();
        assembly.push_str(&format!(
            "u{n}_1 = {}\nu{n}_2 = {}\nL{n} = {len}\n",
            (-d[1]).atan2(d[2]),
            (d[0] / len).asin()
        ));
    }
    let mut params = String::from("[parameters]\n");
    for (i, leg) in legs.iter().enumerate() {
        let n = i + 1;
        for (key, p) in [("base", 'a'), ("platform", 'b')] {
            for (k, c) in ["x", "y", "z"].iter().enumerate() {
                let v = leg[key].as_array().unwrap()[k].as_float().unwrap();
                params.push_str(&format!("{p}{n}{c} = {v}\n"));
            }
        }
    }
    s.push_str(&params);
    s.push_str(&assembly);
    s.push_str(
        "[workspace]\nx = [-80.0, 80.0]\ny = [-80.0, 80.0]\nz = [640.0, 760.0]\n\
         rx = [-0.12, 0.12]\nry = [-0.12, 0.12]\nrz = [-0.15, 0.15]\n",
    );
    let d: SpatialDescription = toml::from_str(&s).unwrap_or_else(|e| panic!("{e}\n{s}"));
    SpatialMechanism::new(&d).unwrap_or_else(|e| panic!("{e}"))
}

/// Universal joints inside a chain: the U-P-S hexapod predicts the built-in
/// platform's poses (same commands) and inverse kinematics; its derivatives
/// equal central differences; the universal joint's second axis carries
/// its own error parameters; a bad universal joint is refused by name.
#[test]
fn universal_joints_make_a_ups_hexapod_like_the_builtin() {
    let builtin = gough_stewart("gough-stewart-6");
    let ups = ups_hexapod();
    let (bs, us) = (builtin.spec(), ups.spec());
    assert!(us.joints.iter().any(|j| j == "u3_2"));
    for n in ["u3_2.x", "u3_2.tilt1", "u3_1.tilt2"] {
        assert!(us.param_index(n).is_ok(), "{n}");
    }
    let truth = perturbed_by_unit(bs, 4, 0.5, 0.0);
    let mut truth_u = Params::nominal(us);
    for (i, name) in bs.param_names().iter().enumerate() {
        truth_u.set(us, name, truth.values[i]).unwrap();
    }
    for t in common::spread(&builtin, 12) {
        let qb = pkmcal::inverse_kinematics(&builtin, truth.geometric(), &t).unwrap();
        let qu = pkmcal::inverse_kinematics(&ups, truth_u.geometric(), &t).unwrap();
        let lengths: Vec<f64> = us.actuated.iter().map(|&j| qu[j]).collect();
        assert!(
            qb[..6]
                .iter()
                .zip(&lengths)
                .all(|(a, b)| (a - b).abs() < SAME_MECHANISM),
            "{qb:?} {lengths:?}"
        );
        let commands: Vec<f64> = qb[..6].iter().map(|l| l - 0.2).collect();
        let pb = pkmcal::predict(&builtin, &truth, &commands, Model::Exact, &[]).unwrap();
        let pu = pkmcal::predict(&ups, &truth_u, &commands, Model::Exact, &[]).unwrap();
        assert!(
            pb.x.iter()
                .zip(&pu.x)
                .all(|(a, b)| (a - b).abs() < SAME_MECHANISM),
            "{:?} {:?}",
            pb.x,
            pu.x
        );
    }
    // (Its derivatives are checked with the examples' in
    // per_leg_derivatives_equal_automatic_and_central_ones.)
    // A universal joint is passive, has two axes, and they differ.
    let joint = |t: &mut toml::Table| -> toml::Table {
        leg(t, 1).get_mut("joint").unwrap().as_array_mut().unwrap()[0]
            .as_table_mut()
            .unwrap()
            .clone()
    };
    let with = |edits: &[(&str, Option<toml::Value>)]| {
        let edits = edits.to_vec();
        refused(
            move |t| {
                let mut j = joint(t);
                j.insert("kind".into(), "universal".into());
                for (k, v) in edits {
                    match v {
                        Some(v) => j.insert(k.into(), v),
                        None => j.remove(k),
                    };
                }
                leg(t, 1).get_mut("joint").unwrap().as_array_mut().unwrap()[0] = j.into();
            },
            "linear-delta",
        )
    };
    let e = with(&[]);
    assert!(
        e.contains("leg `tower_b`, joint `b`") && e.contains("passive"),
        "{e}"
    );
    let axis = |v: [f64; 3]| Some(toml::Value::Array(v.iter().map(|x| (*x).into()).collect()));
    let passive = [("actuated", None), ("stiffness", None)];
    let e = with(&[
        passive[0].clone(),
        passive[1].clone(),
        ("axis3", axis([1.0, 0.0, 0.0])),
    ]);
    assert!(
        e.contains("joint `b`") && e.contains("remove `axis3`"),
        "{e}"
    );
    let e = with(&[
        passive[0].clone(),
        passive[1].clone(),
        ("axis", axis([0.0, 0.0, 1.0])),
        ("axis2", axis([0.0, 0.0, -2.0])),
    ]);
    assert!(
        e.contains("joint `b`") && e.contains("not be parallel"),
        "{e}"
    );
}

/// A poorly conditioned free set (the 3-PRS with its link lengths free too:
/// each trades with its radius and its slider offset) lets the fit wander
/// tens of millimetres along the valley; predictions from the nominal
/// configuration then need the continuation in the parameters, and the
/// calibration completes, reporting those parameters with standard
/// deviations of the same size (it stopped at pose 1 before).
#[test]
fn a_wandering_fit_still_assembles_every_pose() {
    let m = spatial("3-prs");
    let spec = m.spec();
    let tool = pkmcal::MeasurementModel::tool(spec);
    let data = pkmcal::simulate(
        &m,
        &tool,
        &Params::nominal(spec),
        &common::spread(&m, 60),
        pkmcal::Noise::lengths(0.002),
        1,
    )
    .unwrap();
    let mut opts = pkmcal::CalibrationOptions::new(spec, Model::Exact);
    for n in ["l1", "l2", "l3"] {
        opts.free.push(spec.param_index(n).unwrap());
    }
    let cal = pkmcal::calibrate(&m, &tool, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.identifiability.condition_number > 1e5);
    let l1 = cal.parameters.iter().find(|p| p.name == "l1").unwrap();
    assert!(l1.std_dev > 1.0, "{l1:?}");
    assert!((l1.identified - 250.0).abs() < 5.0 * l1.std_dev, "{l1:?}");
}

/// On the deltas (a translating platform, legs of actuated joints and rods)
/// forward kinematics starts from the closed-form intersection of the legs'
/// spheres: it is the configuration itself, on the reference's assembly
/// mode, and commands the legs cannot meet give no start and a clear error.
#[test]
fn deltas_start_forward_kinematics_in_closed_form() {
    for name in ["linear-delta", "linear-delta-4", "rotary-delta"] {
        let m = spatial(name);
        let spec = m.spec();
        let rho = &spec.nominal[..spec.n_geometric()];
        for t in common::spread(&m, 25) {
            let q = pkmcal::inverse_kinematics(&m, rho, &t).unwrap();
            let commands: Vec<f64> = spec.actuated.iter().map(|&j| q[j]).collect();
            let guess = m.configuration_guess(&commands, rho).expect(name);
            assert!(
                guess
                    .iter()
                    .zip(&q)
                    .all(|(a, b)| (a - b).abs() < SAME_MECHANISM),
                "{name}: {guess:?} {q:?}"
            );
        }
        // Pull one actuator far out: the spheres no longer meet.
        let mut far: Vec<f64> = spec.actuated.iter().map(|&j| spec.reference_q[j]).collect();
        far[0] += if spec.joint_units[spec.actuated[0]] == pkmcal::Unit::Radian {
            3.0
        } else {
            1e4
        };
        assert!(m.configuration_guess(&far, rho).is_none(), "{name}");
        let err = pkmcal::predict(&m, &Params::nominal(spec), &far, Model::Rigid, &[]);
        assert!(err.is_err(), "{name}: {err:?}");
    }
}

/// The tool's derivatives by the adjoint ([`pkmcal::tool_derivatives`], one
/// solve per tool coordinate) equal the linearisation's (a solve per
/// parameter), on every kind of mechanism, at perturbed parameters.
#[test]
fn tool_derivatives_by_the_adjoint_equal_the_linearisation() {
    fn check<M: Mechanism>(name: &str, m: &M) {
        let spec = m.spec();
        let truth = perturbed_by_unit(spec, 3, 0.3, 0.002);
        let rho = truth.geometric();
        for t in common::spread(m, 6) {
            let q = pkmcal::inverse_kinematics(m, rho, &t).unwrap();
            let lin = pkmcal::linearize(m, &q, rho, &spec.independent).unwrap();
            let (jf, jx) = pkmcal::tool_derivatives(m, &q, rho, &spec.independent).unwrap();
            for (a, b) in lin
                .jf
                .iter()
                .zip(jf.iter())
                .chain(lin.jx_rho.iter().zip(jx.iter()))
            {
                assert!(close(*b, *a, ADJOINT_REL), "{name}: {a} vs {b}");
            }
        }
    }
    check(
        "jeong-kim-2dof",
        &pkmcal::kinds::reference::JeongKim2Dof::new(),
    );
    check("4-rrr", &common::planar("4-rrr"));
    check("gough-stewart-8", &gough_stewart("gough-stewart-8"));
    for name in EXAMPLES {
        check(name, &spatial(name));
    }
}

// The tests of `pkmcal::kinds::spatial` itself.

fn leg_with(kind: SpatialJointKind, axis2: Option<[f64; 3]>) -> SpatialLeg {
    SpatialLeg {
        name: "l".into(),
        angle: None,
        joints: vec![SpatialJoint {
            name: "s".into(),
            kind,
            at: [Value::Number(1.0), Value::Number(2.0), Value::Number(3.0)],
            axis: [0.0, 0.0, 2.0],
            axis2,
            axis3: None,
            tilt: None,
            actuated: false,
            stiffness: None,
        }],
        chain: None,
        end: LegEnd {
            kind: EndKind::Spherical,
            at: origin(),
            platform: origin(),
            length: None,
            name: None,
            actuated: false,
            stiffness: None,
        },
    }
}

/// A spherical joint is three revolute joints about one centre, with
/// mutually perpendicular axes unless given; a universal joint two.
#[test]
fn spherical_and_universal_joints_expand_to_revolute_ones() {
    let s = expand_joints(&leg_with(SpatialJointKind::Spherical, None)).unwrap();
    let names: Vec<&str> = s.iter().map(|j| j.name.as_str()).collect();
    assert_eq!(names, ["s_1", "s_2", "s_3"]);
    assert!(s.iter().all(|j| j.kind == SpatialJointKind::Revolute));
    assert_eq!(s[0].at[2], Value::Number(3.0));
    assert_eq!(s[1].at, origin());
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        assert!(dot(s[a].axis, s[b].axis).abs() < 1e-15);
    }
    assert!((dot(s[0].axis, s[0].axis) - 1.0).abs() < 1e-15);
    let u = expand_joints(&leg_with(
        SpatialJointKind::Universal,
        Some([1.0, 0.0, 0.0]),
    ))
    .unwrap();
    assert_eq!(u.len(), 2);
    assert_eq!(u[1].axis, [1.0, 0.0, 0.0]);
}
