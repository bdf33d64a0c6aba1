//! The instrument frame: data measured from a tracker standing 1 m and 2°
//! away from the base frame give the same mechanism parameters and the same
//! validation accuracy as the same data seen from the base frame.

use crate::common;
use common::{gough_stewart, perturbed, spread};
use pkmcal::ToolLayout;
use pkmcal::measurement::frame::*;
use pkmcal::measurement::frame::{observe, to_base};
use pkmcal::{
    CalibrationOptions, Frame, JeongKim2Dof, Measurement, MeasurementModel, Mechanism, Model,
    Noise, Params, calibrate, calibration_accuracy, simulate,
};

/// Two fits of the same data seen from two frames agree to this (mm, rad)…
const SAME_FIT: f64 = 1e-6;
/// …or to this fraction of the parameter's standard deviation: the problem
/// is invariant, but the noise levels are estimated iteratively and the
/// iterations stop at a tolerance.
const SAME_FIT_SIGMAS: f64 = 0.02;

/// `data` as seen from an instrument at `frame`.
fn seen_from<M: Mechanism>(m: &M, data: &[Measurement], frame: &[f64]) -> Vec<Measurement> {
    let layout = m.spec().tool_layout;
    data.iter()
        .map(|d| {
            let mut y = vec![0.0; d.measured.len()];
            observe(layout, &d.measured, frame, &mut y);
            Measurement {
                measured: y,
                ..d.clone()
            }
        })
        .collect()
}

fn check_invariance<M: Mechanism>(m: &M, truth: &Params, poses: usize, far: &[f64]) {
    let spec = m.spec();
    let data = simulate(
        m,
        &MeasurementModel::tool(m.spec()),
        truth,
        &spread(m, poses),
        Noise::lengths(0.002),
        3,
    )
    .unwrap();
    let unseen = simulate(
        m,
        &MeasurementModel::tool(m.spec()),
        truth,
        &spread(m, 20),
        Noise::NONE,
        4,
    )
    .unwrap();
    let opts = CalibrationOptions::new(spec, Model::Exact);
    let tool = MeasurementModel::tool(spec);
    let tracker = tool.clone().in_frame(Frame::Free).unwrap();
    let start = Params::nominal(spec);
    let near = calibrate(m, &tracker, &data, &start, &opts).unwrap();
    let moved = calibrate(m, &tracker, &seen_from(m, &data, far), &start, &opts).unwrap();
    assert!(near.converged && moved.converged);
    for (i, (a, b)) in near
        .params
        .values
        .iter()
        .zip(&moved.params.values)
        .enumerate()
    {
        let sigma = near.parameters[i].std_dev;
        assert!(
            (a - b).abs() < (SAME_FIT * (1.0 + a.abs())).max(SAME_FIT_SIGMAS * sigma),
            "{}: {} {a} vs {b} (σ {sigma}); fixed {:?} vs {:?}",
            spec.name,
            spec.param_names()[i],
            near.parameters
                .iter()
                .filter(|p| p.note.is_some())
                .map(|p| &p.name)
                .collect::<Vec<_>>(),
            moved
                .parameters
                .iter()
                .filter(|p| p.note.is_some())
                .map(|p| &p.name)
                .collect::<Vec<_>>()
        );
    }
    // The identified frame is where the tracker stands, composed with the
    // frame found for the base-frame data (near identity): a point seen by
    // the tracker lands in the same place either way.
    let f = moved.frame.as_ref().unwrap();
    let f0 = near.frame.as_ref().unwrap();
    let layout = spec.tool_layout;
    for d in data.iter().take(5) {
        let direct = to_base(layout, &d.measured, f);
        let composed = to_base(layout, &to_base(layout, &d.measured, far), f0);
        for (x, y) in direct.iter().zip(&composed) {
            assert!(
                (x - y).abs() < 1e-2,
                "{}: {direct:?} vs {composed:?}",
                spec.name
            );
        }
    }
    let (acc_near, _, _) = calibration_accuracy(m, &tracker, &unseen, &near, &[]).unwrap();
    let (acc_far, _, _) =
        calibration_accuracy(m, &tracker, &seen_from(m, &unseen, far), &moved, &[]).unwrap();
    assert!(
        (acc_near.after.distance_rms / acc_far.after.distance_rms - 1.0).abs() < SAME_FIT_SIGMAS,
        "{}: {} vs {}",
        spec.name,
        acc_near.after.distance_rms,
        acc_far.after.distance_rms
    );
    assert!(acc_far.after.distance_max < 0.01, "{:?}", acc_far.after);
    // The "before" errors are judged after the best rigid registration, not
    // against a tracker 1 m away.
    assert!(acc_far.before.distance_max < 5.0, "{:?}", acc_far.before);
    // Pretending the data were in the base frame cannot fit them, unless the
    // geometry absorbs the frame: a platform whose every base joint centre is
    // free is the same machine described in the tracker's frame (its centres
    // then move by about the frame's metre).
    if let Ok(c) = calibrate(m, &tool, &seen_from(m, &data, far), &start, &opts) {
        let moved_by = c
            .params
            .geometric()
            .iter()
            .zip(near.params.geometric())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            c.noise[0].residual_rms > 100.0 * near.noise[0].residual_rms || moved_by > 100.0,
            "{:?}, parameters moved by {moved_by} mm",
            c.noise
        );
    }
}

#[test]
fn a_planar_tracker_frame_1_m_and_2_degrees_away_changes_nothing() {
    let m = JeongKim2Dof::new();
    let truth = Params::from_named(
        m.spec(),
        [
            ("l11", 280.3),
            ("B3x", 149.6),
            ("D2", 215.2),
            ("dq3", 0.002),
        ],
    )
    .unwrap();
    check_invariance(&m, &truth, 35, &[1000.0, -300.0, 2f64.to_radians()]);
}

#[test]
fn a_spatial_tracker_frame_1_m_and_2_degrees_away_changes_nothing() {
    let m = gough_stewart("gough-stewart-6");
    let spec = m.spec();
    let all = perturbed(spec, 4, 0.2, 0.1);
    let mut truth = Params::nominal(spec);
    for n in &spec.default_free {
        truth.set(spec, n, all.get(spec, n).unwrap()).unwrap();
    }
    // About a tilted axis: 2° in total.
    let a = 2f64.to_radians() / 3f64.sqrt();
    check_invariance(&m, &truth, 50, &[800.0, -500.0, 300.0, a, -a, a]);
}

/// The frame rule every front end applies (`requested_frame`): whole
/// positions and target points take a free frame unless the data are in the
/// base frame; some axes, a ball bar and a probe carry none or the base
/// frame; a free frame is refused, typed, where it cannot be identified.
#[test]
fn the_frame_rule_is_one_rule() {
    use pkmcal::{FrameRequest, FrameRequestError, requested_frame};
    let auto = |base| FrameRequest::Auto { data_in_base: base };
    // A hexapod's whole pose.
    let g = gough_stewart("gough-stewart-6");
    let spec = g.spec();
    let tool = MeasurementModel::tool(spec);
    assert_eq!(
        requested_frame(&tool, spec, auto(false)),
        Ok(Some(Frame::Free))
    );
    assert_eq!(
        requested_frame(&tool, spec, auto(true)),
        Ok(Some(Frame::Base))
    );
    assert_eq!(
        requested_frame(&tool, spec, FrameRequest::Base),
        Ok(Some(Frame::Base))
    );
    assert_eq!(
        requested_frame(&tool, spec, FrameRequest::Free),
        Ok(Some(Frame::Free))
    );
    // Some axes: the base frame, never a free one.
    let z = MeasurementModel::tool_axes(spec, &["z"]).unwrap();
    assert_eq!(
        requested_frame(&z, spec, auto(false)),
        Ok(Some(Frame::Base))
    );
    assert_eq!(
        requested_frame(&z, spec, FrameRequest::Free),
        Err(FrameRequestError::PartialAxes {
            axes: vec!["z".to_string()]
        })
    );
    // Target points are positions.
    let t = MeasurementModel::targets(
        spec,
        &[
            vec![10.0, 0.0, 0.0],
            vec![0.0, 10.0, 0.0],
            vec![0.0, 0.0, 10.0],
        ],
    )
    .unwrap();
    assert_eq!(
        requested_frame(&t, spec, auto(false)),
        Ok(Some(Frame::Free))
    );
    // A probe carries no frame, and refuses a free one.
    let d = common::spatial("linear-delta");
    let probe = MeasurementModel::probe(d.spec()).unwrap();
    assert_eq!(requested_frame(&probe, d.spec(), auto(false)), Ok(None));
    assert_eq!(
        requested_frame(&probe, d.spec(), FrameRequest::Free),
        Err(FrameRequestError::Probe)
    );
    // A ball bar carries none either.
    let r = JeongKim2Dof::new();
    let setup = pkmcal::Setup {
        sockets: vec![vec![0.0, 0.0], vec![400.0, 0.0], vec![200.0, 300.0]],
        bar_offset: 0.0,
    };
    let bar = MeasurementModel::ball_bar(r.spec(), &setup).unwrap();
    assert_eq!(
        requested_frame(&bar, r.spec(), FrameRequest::Base),
        Ok(None)
    );
    assert_eq!(
        requested_frame(&bar, r.spec(), FrameRequest::Free),
        Err(FrameRequestError::BallBar)
    );
    // No library message names a front end's option.
    for e in [
        FrameRequestError::BallBar,
        FrameRequestError::Probe,
        FrameRequestError::PartialAxes {
            axes: vec!["z".into()],
        },
    ] {
        let m = e.to_string();
        assert!(!m.contains("--") && !m.contains('='), "{m}");
    }
}

// The tests of `pkmcal::measurement::frame` itself.

/// Round-off agreement of exact computations.
const EXACT: f64 = 1e-9;

fn poses() -> Vec<Vec<f64>> {
    vec![
        vec![10.0, 20.0, 700.0, 0.01, -0.02, 0.03],
        vec![-50.0, 35.0, 650.0, -0.05, 0.04, 0.2],
        vec![80.0, -60.0, 720.0, 0.1, 0.0, -0.1],
        vec![0.0, 0.0, 690.0, 0.0, 0.07, 0.0],
    ]
}

#[test]
fn observe_and_to_base_are_inverse() {
    let frame = [1000.0, -200.0, 50.0, 0.02, -0.03, 0.035];
    for x in poses() {
        let mut y = vec![0.0; 6];
        observe(ToolLayout::SpatialPose, &x, &frame, &mut y);
        let back = to_base(ToolLayout::SpatialPose, &y, &frame);
        for (a, b) in x.iter().zip(&back) {
            assert!((a - b).abs() < EXACT, "{x:?} -> {back:?}");
        }
    }
    let frame = [500.0, 300.0, 0.4];
    let x = [10.0, 20.0, 0.3];
    let mut y = [0.0; 3];
    observe(ToolLayout::PlanarPose, &x, &frame, &mut y);
    let back = to_base(ToolLayout::PlanarPose, &y, &frame);
    assert!(x.iter().zip(&back).all(|(a, b)| (a - b).abs() < EXACT));
}

#[test]
fn registration_recovers_the_frame() {
    let frame = [1000.0, -200.0, 50.0, 0.02, -0.03, 0.035];
    let x = poses();
    let y: Vec<Vec<f64>> = x
        .iter()
        .map(|p| {
            let mut o = vec![0.0; 6];
            observe(ToolLayout::SpatialPose, p, &frame, &mut o);
            o
        })
        .collect();
    let f = register(ToolLayout::SpatialPose, &x, &y).unwrap();
    for (a, b) in f.iter().zip(&frame) {
        assert!((a - b).abs() < 1e-6, "{f:?}");
    }
    let frame2 = [500.0, 300.0, 0.4];
    let x2: Vec<Vec<f64>> = vec![vec![0.0, 0.0], vec![100.0, 0.0], vec![30.0, 80.0]];
    let y2: Vec<Vec<f64>> = x2
        .iter()
        .map(|p| {
            let mut o = vec![0.0; 2];
            observe(ToolLayout::PlanarPoint, p, &frame2, &mut o);
            o
        })
        .collect();
    let f2 = register(ToolLayout::PlanarPoint, &x2, &y2).unwrap();
    for (a, b) in f2.iter().zip(&frame2) {
        assert!((a - b).abs() < 1e-9, "{f2:?}");
    }
}

#[test]
fn derivatives_match_central_differences() {
    let frame = vec![100.0, -20.0, 5.0, 0.2, -0.3, 0.35];
    let x = poses()[1].clone();
    let (_, dx, df) = observe_jacobian(ToolLayout::SpatialPose, &x, &frame);
    let h = 1e-6;
    for j in 0..12 {
        let (mut a, mut b) = (x.clone(), frame.clone());
        let (mut a2, mut b2) = (x.clone(), frame.clone());
        if j < 6 {
            a[j] += h;
            a2[j] -= h;
        } else {
            b[j - 6] += h;
            b2[j - 6] -= h;
        }
        let (mut yp, mut ym) = (vec![0.0; 6], vec![0.0; 6]);
        observe(ToolLayout::SpatialPose, &a, &b, &mut yp);
        observe(ToolLayout::SpatialPose, &a2, &b2, &mut ym);
        for i in 0..6 {
            let fd = (yp[i] - ym[i]) / (2.0 * h);
            let ad = if j < 6 { dx[(i, j)] } else { df[(i, j - 6)] };
            assert!(
                (fd - ad).abs() < 1e-6 * (1.0 + ad.abs()),
                "{i},{j}: {fd} {ad}"
            );
        }
    }
}
