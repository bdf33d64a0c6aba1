//! Measurement models (what the instrument reads) on every mechanism kind:
//! exact identification Jacobians, target points rigid with the tool, a
//! subset of axes, targets on a planar tool seen from a tracker far away.

use crate::common;
use common::{gough_stewart, perturbed, planar, spread};
use pkmcal::identify::IdentificationProblem;
use pkmcal::kinds::reference::JeongKim2Dof;
use pkmcal::*;

/// Exact Jacobian against central differences, relative to the largest
/// entry of each column (the differences' truncation and round-off).
const JACOBIAN_REL: f64 = 1e-6;
/// Recovery of the truth from noise-free data (mm, rad).
const RECOVERY: f64 = 1e-6;
/// Round-off of rigid-body arithmetic (mm).
const ROUND_OFF_MM: f64 = 1e-9;

fn sockets_3d() -> Setup {
    Setup {
        sockets: vec![
            vec![600.0, 0.0, 0.0],
            vec![-300.0, 520.0, 0.0],
            vec![-300.0, -520.0, 0.0],
            vec![0.0, 0.0, 1400.0],
        ],
        bar_offset: 0.5,
    }
}

/// Every column of the identification Jacobian (mechanism's parameters and
/// the measurement model's) against central differences of the residuals.
fn check_jacobian<M: Mechanism>(mech: &M, measurement: &MeasurementModel, m: &[f64], poses: usize) {
    let spec = mech.spec();
    let truth = perturbed(spec, 7, 0.2, 0.002);
    let data = simulate(mech, measurement, &truth, &spread(mech, poses), 0.0, 1).unwrap();
    let problem = IdentificationProblem::new(mech, measurement, &data, Model::Exact, &[]).unwrap();
    let x: Vec<f64> = truth.values.iter().chain(m).copied().collect();
    let (_, j) = problem.residuals_and_jacobian(&x).unwrap();
    assert_eq!(j.ncols(), spec.n_params() + measurement.n_params());
    let names = measurement.all_names(spec);
    for c in 0..x.len() {
        let h = 1e-6 * (1.0 + x[c].abs());
        let (mut a, mut b) = (x.clone(), x.clone());
        a[c] += h;
        b[c] -= h;
        let fd = (problem.residuals(&a).unwrap() - problem.residuals(&b).unwrap()) / (2.0 * h);
        let scale = j.column(c).amax().max(fd.amax()).max(1e-12);
        let diff = (&fd - j.column(c)).amax();
        assert!(
            diff < JACOBIAN_REL * scale.max(1.0),
            "{} / {}: column {} differs by {diff:e} (scale {scale:e})",
            spec.name,
            measurement.describe(),
            names[c]
        );
    }
}

#[test]
fn identification_jacobians_match_central_differences_for_every_model() {
    let jk = JeongKim2Dof::new();
    let only_y = MeasurementModel::tool_axes(jk.spec(), &["y"]).unwrap();
    check_jacobian(&jk, &only_y, &[], 6);
    let tracker = MeasurementModel::tool(jk.spec())
        .in_frame(Frame::Known(vec![800.0, -300.0, 0.03]))
        .unwrap();
    check_jacobian(&jk, &tracker, tracker.nominal(), 6);
    let bar = MeasurementModel::ball_bar(
        jk.spec(),
        &Setup {
            sockets: vec![vec![-250.0, -60.0], vec![260.0, -40.0], vec![20.0, 480.0]],
            bar_offset: 0.2,
        },
    )
    .unwrap();
    check_jacobian(&jk, &bar, bar.nominal(), 6);

    let gs = gough_stewart("gough-stewart-6");
    let targets = MeasurementModel::targets(
        gs.spec(),
        &[vec![150.0, 0.0, 60.0], vec![-80.0, 120.0, 40.0]],
    )
    .unwrap()
    .in_frame(Frame::Free)
    .unwrap();
    let mut m = targets.nominal().to_vec();
    let f = targets.frame_range();
    m[f].copy_from_slice(&[900.0, -400.0, 200.0, 0.02, -0.03, 0.04]);
    check_jacobian(&gs, &targets, &m, 4);
    // A ball off the platform's origin: its offset is a parameter.
    let bar = MeasurementModel::ball_bar(gs.spec(), &sockets_3d()).unwrap();
    assert!(bar.param_names().iter().any(|n| n == "ball.z"));
    let mut m = bar.nominal().to_vec();
    let n = m.len();
    m[n - 3..].copy_from_slice(&[10.0, -5.0, 30.0]);
    check_jacobian(&gs, &bar, &m, 4);
    let z = MeasurementModel::tool_axes(gs.spec(), &["z", "rx"]).unwrap();
    check_jacobian(&gs, &z, &[], 4);

    let rrr = planar("3-rrr");
    let targets =
        MeasurementModel::targets(rrr.spec(), &[vec![30.0, 10.0], vec![-20.0, 25.0]]).unwrap();
    check_jacobian(&rrr, &targets, targets.nominal(), 5);
}

#[test]
fn target_points_are_rigid_with_the_tool() {
    let gs = gough_stewart("gough-stewart-6");
    let t = MeasurementModel::targets(gs.spec(), &[vec![150.0, 0.0, 60.0], vec![0.0; 3]]).unwrap();
    assert_eq!(t.axes(), ["t1x", "t1y", "t1z", "t2x", "t2y", "t2z"]);
    let pose = [10.0, -5.0, 720.0, 0.05, -0.03, 0.1];
    let mut y = vec![0.0; 6];
    t.observe(&pose, t.nominal(), &mut y);
    // The second target is the platform origin; the first keeps its
    // distance from it whatever the orientation.
    for k in 0..3 {
        assert!((y[3 + k] - pose[k]).abs() < ROUND_OFF_MM);
    }
    let d = ((y[0] - y[3]).powi(2) + (y[1] - y[4]).powi(2) + (y[2] - y[5]).powi(2)).sqrt();
    assert!((d - 150f64.hypot(60.0)).abs() < ROUND_OFF_MM);
    // In the plane: a point 100 mm along the tool's x axis at phi = 90°.
    let rrr = planar("3-rrr");
    let t = MeasurementModel::targets(rrr.spec(), &[vec![100.0, 0.0]]).unwrap();
    let mut y = vec![0.0; 2];
    t.observe(
        &[5.0, 7.0, std::f64::consts::FRAC_PI_2],
        t.nominal(),
        &mut y,
    );
    assert!((y[0] - 5.0).abs() < ROUND_OFF_MM && (y[1] - 107.0).abs() < ROUND_OFF_MM);
    // Refused where they make no sense.
    let e = MeasurementModel::targets(JeongKim2Dof::new().spec(), &[vec![1.0, 2.0]]);
    assert!(e.unwrap_err().to_string().contains("orientation"));
    let e = MeasurementModel::targets(gs.spec(), &[vec![1.0, 2.0]]);
    assert!(e.unwrap_err().to_string().contains("3 finite coordinates"));
    let e = MeasurementModel::tool_axes(gs.spec(), &["w"]);
    assert!(e.unwrap_err().to_string().contains("x y z rx ry rz"));
    let e = MeasurementModel::ball_bar(gs.spec(), &sockets_3d())
        .unwrap()
        .in_frame(Frame::Free);
    assert!(e.unwrap_err().to_string().contains("base frame"));
}

/// A height probe on a Gough–Stewart platform reads only z: the fit
/// identifies what z sees, names what it cannot, and predicts z exactly.
#[test]
fn only_z_calibrates_what_z_sees() {
    let gs = gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let z = MeasurementModel::tool_axes(spec, &["z"]).unwrap();
    let mut truth = Params::nominal(spec);
    for (i, name) in spec.offsets.iter().enumerate() {
        truth.set(spec, name, 0.1 * (i as f64 - 2.5)).unwrap();
    }
    let data = simulate(&gs, &z, &truth, &spread(&gs, 40), 0.0, 1).unwrap();
    assert!(data.iter().all(|d| d.measured.len() == 1));
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    opts.free = spec
        .offsets
        .iter()
        .map(|n| spec.param_index(n).unwrap())
        .collect();
    let cal = calibrate(&gs, &z, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.converged);
    for name in &spec.offsets {
        let got = cal.params.get(spec, name).unwrap();
        let want = truth.get(spec, name).unwrap();
        assert!((got - want).abs() < RECOVERY, "{name}: {got} vs {want}");
    }
    let unseen = simulate(&gs, &z, &truth, &spread(&gs, 12), 0.0, 2).unwrap();
    let (acc, _, _) = calibration_accuracy(&gs, &z, &unseen, &cal, &[]).unwrap();
    assert!(acc.after.distance_max < RECOVERY, "{:?}", acc.after);
    assert_eq!(acc.after.axis_units, [Unit::Millimetre]);
    // Analysed with every geometric parameter free, the lateral ones are
    // named unidentifiable.
    let all: Vec<usize> = (0..spec.n_params() - spec.n_actuated()).collect();
    let id = analyze(&gs, &z, &data, &truth, Model::Exact, &all, &[]).unwrap();
    assert!(!id.unidentifiable.is_empty());
}

/// Targets on a planar tool (3-RRR), seen by a tracker 1 m and 2° away:
/// the frame is registered and identified, the truth recovered.
#[test]
fn targets_on_a_planar_tool_from_a_tracker_far_away() {
    let rrr = planar("3-rrr");
    let spec = rrr.spec();
    let points = [vec![40.0, 0.0], vec![-20.0, 35.0]];
    let far = vec![1000.0, -400.0, 2f64.to_radians()];
    let seen = MeasurementModel::targets(spec, &points)
        .unwrap()
        .in_frame(Frame::Known(far.clone()))
        .unwrap();
    let truth = perturbed(spec, 3, 0.2, 0.002);
    let data = simulate(&rrr, &seen, &truth, &spread(&rrr, 30), 0.0, 1).unwrap();
    let tracker = MeasurementModel::targets(spec, &points)
        .unwrap()
        .in_frame(Frame::Free)
        .unwrap();
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let cal = calibrate(&rrr, &tracker, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.converged, "{:?}", cal.warnings);
    // The frame trades off against the base geometry (a gauge that the
    // identifiability analysis fixes): it lands within the size of the
    // parameter errors of where the tracker stands.
    let frame = cal.frame.as_ref().unwrap();
    for (a, b) in frame.iter().zip(&far) {
        assert!((a - b).abs() < 1.0, "{frame:?} vs {far:?}");
    }
    let unseen = simulate(&rrr, &seen, &truth, &spread(&rrr, 10), 0.0, 2).unwrap();
    let (acc, _, _) = calibration_accuracy(&rrr, &tracker, &unseen, &cal, &[]).unwrap();
    assert!(acc.after.distance_max < 1e-5, "{:?}", acc.after);
    assert!(acc.before.distance_max > 1e-2, "{:?}", acc.before);
}

/// A ball bar on a Gough–Stewart platform with the ball off the tool point:
/// its offset is identified with the leg offsets, from 3-D sockets.
#[test]
fn ball_offset_on_a_platform_is_identified() {
    let gs = gough_stewart("gough-stewart-6");
    let spec = gs.spec();
    let nominal = MeasurementModel::ball_bar(spec, &sockets_3d()).unwrap();
    let truth = Params::from_named(spec, [("dL2", 0.2), ("dL5", -0.1)]).unwrap();
    // Readings with the ball at (10, −5, 30) mm in the platform frame,
    // computed independently: the platform pose, then the ball, then the bar.
    let targets = spread(&gs, 40);
    let poses = simulate(&gs, &MeasurementModel::tool(spec), &truth, &targets, 0.0, 1).unwrap();
    let setup = sockets_3d();
    let data: Vec<Measurement> = poses
        .into_iter()
        .map(|m| {
            let p = &m.measured;
            let r = pkmcal::linalg::pose::rotation(p[3], p[4], p[5]);
            let t = [10.0, -5.0, 30.0];
            let ball: Vec<f64> = (0..3)
                .map(|i| p[i] + (0..3).map(|j| r[i][j] * t[j]).sum::<f64>())
                .collect();
            Measurement {
                measured: setup.distances(&ball),
                target: None,
                ..m
            }
        })
        .collect();
    let mut opts = CalibrationOptions::new(spec, Model::Exact);
    let names: Vec<&str> = spec
        .offsets
        .iter()
        .map(String::as_str)
        .chain(["ball.x", "ball.y", "ball.z"])
        .collect();
    opts.free = names
        .iter()
        .map(|n| nominal.index_of(spec, n).unwrap())
        .collect();
    let cal = calibrate(&gs, &nominal, &data, &Params::nominal(spec), &opts).unwrap();
    assert!(cal.warnings.is_empty(), "{:?}", cal.warnings);
    let n = cal.measurement.len();
    for (got, want) in cal.measurement[n - 3..].iter().zip([10.0, -5.0, 30.0]) {
        assert!(
            (got - want).abs() < RECOVERY,
            "{:?}",
            &cal.measurement[n - 3..]
        );
    }
    for (name, want) in [("dL2", 0.2), ("dL5", -0.1), ("dL1", 0.0)] {
        let got = cal.params.get(spec, name).unwrap();
        assert!((got - want).abs() < RECOVERY, "{name}: {got}");
    }
}

/// A probe reading a second point of the tool (a printer's nozzle where its
/// probe triggers elsewhere): the point's height over the bed, turning with
/// the tool; its Jacobian exact; refused where no orientation carries it,
/// or on another instrument.
#[test]
fn a_probe_reads_a_second_point_of_the_tool() {
    let gs = gough_stewart("gough-stewart-6");
    let probe = MeasurementModel::probe(gs.spec()).unwrap();
    let bed: [f64; 3] = [1.5, 0.01, -0.02];
    let truth = perturbed(gs.spec(), 3, 0.2, 0.002);
    let point = vec![30.0, -20.0, 5.0];
    let mut data = simulate(&gs, &probe, &truth, &spread(&gs, 6), 0.0, 1).unwrap();
    for m in data.iter_mut().skip(1).step_by(2) {
        let x = predict(&gs, &truth, &m.commands, Model::Exact, &[])
            .unwrap()
            .x;
        let r = pkmcal::linalg::pose::rotation(x[3], x[4], x[5]);
        let p: [f64; 3] =
            std::array::from_fn(|i| x[i] + (0..3).map(|k| r[i][k] * point[k]).sum::<f64>());
        m.measured = vec![p[2] - (bed[0] - p[0] * bed[2].tan() + p[1] * bed[1].tan())];
        m.point = Some(point.clone());
        // The tool point alone reads another height once the tool turns.
        let mut y = [0.0];
        probe.observe(&x, &bed, &mut y);
        assert!(
            (y[0] - m.measured[0]).abs() > 1e-3,
            "{} {}",
            y[0],
            m.measured[0]
        );
    }
    for m in data.iter_mut().step_by(2) {
        let x = predict(&gs, &truth, &m.commands, Model::Exact, &[])
            .unwrap()
            .x;
        probe.observe(&x, &bed, &mut m.measured);
    }
    let problem = IdentificationProblem::new(&gs, &probe, &data, Model::Exact, &[]).unwrap();
    let x: Vec<f64> = truth.values.iter().chain(&bed).copied().collect();
    let (r, j) = problem.residuals_and_jacobian(&x).unwrap();
    assert!(r.amax() < ROUND_OFF_MM, "{r}");
    for c in 0..x.len() {
        let h = 1e-6 * (1.0 + x[c].abs());
        let (mut a, mut b) = (x.clone(), x.clone());
        a[c] += h;
        b[c] -= h;
        let fd = (problem.residuals(&a).unwrap() - problem.residuals(&b).unwrap()) / (2.0 * h);
        let scale = j.column(c).amax().max(fd.amax()).max(1.0);
        assert!(
            (&fd - j.column(c)).amax() < JACOBIAN_REL * scale,
            "column {c}"
        );
    }
    // Where the tool has no orientation, or the instrument is not a probe.
    let tool = MeasurementModel::tool(gs.spec());
    let err = IdentificationProblem::new(&gs, &tool, &data[1..2], Model::Exact, &[])
        .err()
        .unwrap();
    assert!(err.to_string().contains("only a probe"), "{err}");
    let rrr = planar("3-rrr");
    let flat = MeasurementModel::probe(rrr.spec());
    assert!(flat.is_err(), "a planar tool has no height to probe");
}
