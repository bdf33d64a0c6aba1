//! Mechanisms from descriptions: the reference mechanism written as a general
//! planar linkage (same predictions as the built-in one), the shipped planar
//! examples and the Gough–Stewart platforms.

use crate::common;
use common::{gough_stewart, perturbed, planar, table};
use pkmcal::{
    GoughStewart, GoughStewartDescription, JeongKim2Dof, Mechanism, Model, Params,
    PlanarDescription, PlanarLinkage, predict_pose, prepare_pose,
};

/// Agreement of two descriptions of one mechanism (mm).
const SAME_MECHANISM_MM: f64 = 1e-9;
/// Agreement of the three forward models on a non-redundant mechanism (mm).
const MODELS_AGREE_MM: f64 = 1e-9;

/// Built-in parameters carried over to the planar description: the platform's
/// third joint from the side lengths D1, D2, D3.
fn to_planar(builtin: &JeongKim2Dof, p: &Params, linkage: &PlanarLinkage) -> Params {
    let bs = builtin.spec();
    let ls = linkage.spec();
    let mut out = Params::nominal(ls);
    for (i, name) in ls.param_names().iter().enumerate() {
        if let Ok(v) = p.get(bs, name) {
            out.values[i] = v;
        }
    }
    let (d1, d2, d3) = (
        p.get(bs, "D1").unwrap(),
        p.get(bs, "D2").unwrap(),
        p.get(bs, "D3").unwrap(),
    );
    let cx = (d1 * d1 + d3 * d3 - d2 * d2) / (2.0 * d1);
    out.set(ls, "P3.cx", cx).unwrap();
    out.set(ls, "P3.cy", (d3 * d3 - cx * cx).sqrt()).unwrap();
    out
}

#[test]
fn reference_as_planar_linkage_predicts_like_the_builtin() {
    let builtin = JeongKim2Dof::new();
    let linkage = planar("jeong-kim-planar");
    assert_eq!(linkage.spec().actuated_names(), ["q1", "q2", "q3"]);
    let targets: Vec<Vec<f64>> = pkmcal::spread_targets(&linkage, 25)
        .unwrap()
        .into_iter()
        .map(|p| p.target)
        .collect();
    for seed in 0..4 {
        let truth = perturbed(builtin.spec(), seed, 0.5, 0.004);
        let truth_l = to_planar(&builtin, &truth, &linkage);
        // The linear model is a first-order expansion in the parameter
        // errors, so it depends on the parametrisation: compare it with
        // errors on the shared parameters only (not the platform's sides).
        let mut shared = truth.clone();
        for n in ["D1", "D2", "D3"] {
            shared.set(builtin.spec(), n, 215.0).unwrap();
        }
        let shared_l = to_planar(&builtin, &shared, &linkage);
        for t in &targets {
            let c = pkmcal::nominal_commands(&builtin, t).unwrap();
            let pb = prepare_pose(&builtin, &c, None).unwrap();
            let pl = prepare_pose(&linkage, &c, None).unwrap();
            for (model, a, b) in [
                (Model::Exact, &truth, &truth_l),
                (Model::Rigid, &truth, &truth_l),
                (Model::Linear, &shared, &shared_l),
            ] {
                let xb = predict_pose(&builtin, &pb, a, model, &[]).unwrap().x;
                let xl = predict_pose(&linkage, &pl, b, model, &[]).unwrap().x;
                for (u, v) in xb.iter().zip(&xl) {
                    assert!(
                        (u - v).abs() < SAME_MECHANISM_MM,
                        "{model:?} seed {seed} target {t:?}: {xb:?} vs {xl:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn five_bar_models_coincide() {
    let m = planar("five-bar");
    assert_eq!(m.spec().n_actuated(), m.spec().dof());
    let truth = perturbed(m.spec(), 3, 0.5, 0.004);
    for p in pkmcal::spread_targets(&m, 20).unwrap() {
        let c = pkmcal::nominal_commands(&m, &p.target).unwrap();
        let pose = prepare_pose(&m, &c, None).unwrap();
        let x: Vec<Vec<f64>> = [Model::Rigid, Model::Linear, Model::Exact]
            .iter()
            .map(|&model| predict_pose(&m, &pose, &truth, model, &[]).unwrap().x)
            .collect();
        for k in 0..2 {
            assert!((x[0][k] - x[2][k]).abs() < MODELS_AGREE_MM, "{x:?}");
            assert!((x[1][k] - x[2][k]).abs() < MODELS_AGREE_MM, "{x:?}");
        }
    }
}

/// Nominal inverse then forward kinematics returns the target (mm, rad).
const ROUND_TRIP: f64 = 1e-9;

#[test]
fn examples_round_trip_and_have_internal_torques_when_redundant() {
    fn check<M: Mechanism>(m: &M, redundant: bool) {
        let spec = m.spec();
        let truth = perturbed(spec, 5, 0.3, 0.002);
        let targets = pkmcal::spread_targets(m, 12).unwrap();
        let mut max_torque: f64 = 0.0;
        for p in &targets {
            let c = pkmcal::nominal_commands(m, &p.target).unwrap();
            let pose = prepare_pose(m, &c, None).unwrap();
            let nominal =
                predict_pose(m, &pose, &Params::nominal(spec), Model::Exact, &[]).unwrap();
            for (a, b) in nominal.x.iter().zip(&p.target) {
                assert!(
                    (a - b).abs() < ROUND_TRIP,
                    "{}: {:?} vs {:?}",
                    spec.name,
                    nominal.x,
                    p.target
                );
            }
            let e = predict_pose(m, &pose, &truth, Model::Exact, &[]).unwrap();
            max_torque = e.torque.iter().fold(max_torque, |a, t| a.max(t.abs()));
        }
        // Errors make redundant actuators fight; others stay torque free.
        if redundant {
            assert!(max_torque > 1.0, "{}: {max_torque}", spec.name);
        } else {
            assert!(max_torque < 1e-6, "{}: {max_torque}", spec.name);
        }
    }
    check(&planar("five-bar"), false);
    check(&planar("3-rrr"), false);
    check(&planar("4-rrr"), true);
    check(&gough_stewart("gough-stewart-6"), false);
    check(&gough_stewart("gough-stewart-8"), true);
}

/// Identification recovers simulated errors (mm, rad) to within this.
const RECOVERED: f64 = 1e-6;

#[test]
fn examples_calibrate_to_the_truth_without_noise() {
    fn check<M: Mechanism>(m: &M, poses: usize) {
        let spec = m.spec();
        // Errors on the identified parameters only (the others stay nominal,
        // as the calibration assumes).
        let all = perturbed(spec, 11, 0.3, 0.002);
        let mut truth = Params::nominal(spec);
        for n in &spec.default_free {
            truth.set(spec, n, all.get(spec, n).unwrap()).unwrap();
        }
        let targets: Vec<Vec<f64>> = pkmcal::spread_targets(m, poses)
            .unwrap()
            .into_iter()
            .map(|p| p.target)
            .collect();
        let data = pkmcal::simulate(
            m,
            &pkmcal::MeasurementModel::tool(m.spec()),
            &truth,
            &targets,
            0.0,
            1,
        )
        .unwrap();
        let mut opts = pkmcal::CalibrationOptions::new(spec, Model::Exact);
        opts.free = spec
            .default_free
            .iter()
            .map(|n| spec.param_index(n).unwrap())
            .collect();
        let cal = pkmcal::calibrate(
            m,
            &pkmcal::MeasurementModel::tool(m.spec()),
            &data,
            &Params::nominal(spec),
            &opts,
        )
        .unwrap();
        assert!(
            cal.identifiability.unidentifiable.is_empty(),
            "{}: the default free set must be identifiable",
            spec.name
        );
        for &i in &opts.free {
            let d = (cal.params.values[i] - truth.values[i]).abs();
            assert!(
                d < RECOVERED,
                "{}: {} off by {d}",
                spec.name,
                spec.param_names()[i]
            );
        }
        assert!(
            cal.noise.iter().all(|g| g.residual_rms < RECOVERED),
            "{}: {:?}",
            spec.name,
            cal.noise
        );
    }
    check(&gough_stewart("gough-stewart-8"), 60);
    check(&planar("4-rrr"), 40);
    check(&planar("3-rrr"), 40);
    check(&planar("five-bar"), 20);
}

#[test]
fn bad_descriptions_are_refused_with_a_reason() {
    let mut t = table("five-bar");
    t.get_mut("parameters")
        .unwrap()
        .as_table_mut()
        .unwrap()
        .remove("l3");
    let d: PlanarDescription = t.try_into().unwrap();
    let e = PlanarLinkage::new(&d).unwrap_err().to_string();
    assert!(e.contains("`l3` has no value"), "{e}");

    let mut t = table("3-rrr");
    t.get_mut("tool")
        .unwrap()
        .as_table_mut()
        .unwrap()
        .remove("orientation");
    let d: PlanarDescription = t.try_into().unwrap();
    let e = PlanarLinkage::new(&d).unwrap_err().to_string();
    assert!(e.contains("orientation = true"), "{e}");

    let mut t = table("gough-stewart-6");
    t.get_mut("leg").unwrap().as_array_mut().unwrap().pop();
    let d: GoughStewartDescription = t.try_into().unwrap();
    let e = GoughStewart::new(&d).unwrap_err().to_string();
    assert!(e.contains("at least 6 legs"), "{e}");
}

/// Closed-form first derivatives agree with automatic differentiation.
const CLOSED_FORM_REL: f64 = 1e-12;

/// A biglide: two prismatic actuators on (nearly) one rail, two links meeting
/// at the tool through a closing revolute joint. (No shipped or tested
/// linkage closes a loop through a prismatic joint; its closed-form
/// equations follow the tree joint's and are checked by the same code path
/// in `PlanarLinkage::closed_form_jacobians`.)
const BIGLIDE: &str = r#"
name = "biglide"
[[joint]]
name = "q1"
kind = "prismatic"
parent = "ground"
child = "s1"
at = [0.0, 0.0]
axis = 0.1
actuated = true
stiffness = 5000.0
[[joint]]
name = "q2"
kind = "prismatic"
parent = "ground"
child = "s2"
at = [0.0, 5.0]
axis = 0.0
actuated = true
stiffness = 5000.0
[[joint]]
name = "q3"
kind = "revolute"
parent = "s1"
child = "l1"
at = ["u1", 3.0]
[[joint]]
name = "q4"
kind = "revolute"
parent = "s2"
child = "l2"
at = [2.0, 1.0]
[[joint]]
name = "P"
kind = "revolute"
parent = "l2"
child = "l1"
at = ["b", 0.0]
child_at = ["a", 0.0]
[tool]
body = "l1"
at = ["a", 10.0]
[parameters]
u1 = 1.0
a = 200.0
b = 200.0
[assembly]
q1 = -100.0
q2 = 100.0
q3 = 0.95
q4 = 2.1
[workspace]
x = [-60.0, 60.0]
y = [120.0, 200.0]
"#;

/// The planar closed-form Jacobians equal automatic differentiation's on
/// every shipped planar linkage and a prismatic one, on every column range,
/// at perturbed parameters and joints away from closure.
#[test]
fn planar_closed_form_derivatives_equal_automatic_ones() {
    use pkmcal::mechanism::autodiff::{automatic_jacobians, jacobians, output_hessians};
    use rand::{RngExt, SeedableRng};
    let mut linkages: Vec<PlanarLinkage> = ["five-bar", "3-rrr", "4-rrr", "jeong-kim-planar"]
        .iter()
        .map(|n| common::planar(n))
        .collect();
    let d: PlanarDescription = toml::from_str(BIGLIDE).unwrap();
    linkages.push(PlanarLinkage::new(&d).unwrap());
    let mut rng = rand::rngs::StdRng::seed_from_u64(17);
    let close = |a: f64, b: f64| (a - b).abs() <= CLOSED_FORM_REL * (1.0 + b.abs());
    for l in &linkages {
        let spec = l.spec();
        let ng = spec.n_geometric();
        let mut rho = spec.nominal[..ng].to_vec();
        for v in &mut rho {
            *v += rng.random_range(-0.5..0.5);
        }
        let n = spec.joints.len() + ng;
        for _ in 0..10 {
            let q: Vec<f64> = spec
                .reference_q
                .iter()
                .map(|v| v + rng.random_range(-0.2..0.2))
                .collect();
            for cols in [0..n, 0..spec.joints.len(), 2..n.min(9), n - 3..n, 0..0] {
                let c = jacobians(l, &q, &rho, cols.clone());
                let a = automatic_jacobians(l, &q, &rho, cols.clone());
                let name = &spec.name;
                assert!(c.g.iter().zip(&a.g).all(|(x, y)| close(*x, *y)), "{name} g");
                assert!(c.x.iter().zip(&a.x).all(|(x, y)| close(*x, *y)), "{name} x");
                assert_eq!(c.dg.shape(), a.dg.shape());
                assert!(
                    c.dg.iter().zip(a.dg.iter()).all(|(x, y)| close(*x, *y)),
                    "{name} dg {cols:?}\n{}\n{}",
                    c.dg,
                    a.dg
                );
                assert!(
                    c.dx.iter().zip(a.dx.iter()).all(|(x, y)| close(*x, *y)),
                    "{name} dx {cols:?}"
                );
            }
            // Second derivatives (forward mode over the closed form) against
            // hyper-dual numbers over the loop closure.
            let name = &spec.name;
            let nq = spec.joints.len();
            let closed = l.joint_hessians(&q, &rho);
            let auto = output_hessians(l, &q, &rho, 0..nq, 0..nq);
            assert_eq!(closed.len(), auto.len());
            for (c, a) in closed.iter().zip(&auto) {
                assert_eq!(c.shape(), a.shape());
                assert!(
                    c.iter().zip(a.iter()).all(|(x, y)| close(*x, *y)),
                    "{name} joint"
                );
            }
            let weights: Vec<f64> = (0..auto.len())
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            let m = spec.n_constraints;
            let closed = l.weighted_hessian(&q, &rho, &weights[..m], &weights[m..]);
            let h = output_hessians(l, &q, &rho, 0..nq, 0..n);
            let auto = pkmcal::mechanism::autodiff::weighted_sum(&h, &weights);
            assert_eq!(closed.shape(), auto.shape());
            assert!(
                closed.iter().zip(auto.iter()).all(|(x, y)| close(*x, *y)),
                "{name} weighted"
            );
        }
    }
}

/// A workspace lattice's inverse kinematics share one reference
/// configuration: every point is, bit for bit, the one inverse kinematics
/// finds for its target alone (on the 4-RRR and the five-bar, whose inverse
/// kinematics is Newton from the reference configuration).
#[test]
fn lattice_points_are_each_targets_own_inverse_kinematics() {
    for name in ["4-rrr", "five-bar"] {
        let mech = planar(name);
        let points = pkmcal::sample_workspace(&mech, 20.0);
        assert!(points.len() > 20, "{name}: {} points", points.len());
        for p in &points {
            let alone = pkmcal::apply::workspace::workspace_point(&mech, &p.target).unwrap();
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&alone.q), bits(&p.q), "{name} at {:?}", p.target);
            assert_eq!(alone.conditioning.to_bits(), p.conditioning.to_bits());
        }
    }
}
