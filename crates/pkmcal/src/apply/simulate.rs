//! Simulated measurements: commands from nominal inverse kinematics, tool
//! positions from the true parameters (exact model) plus Gaussian noise.

use crate::engine::kinematics::inverse_kinematics;
use crate::engine::models::{Model, predict_pose, prepare_pose};
use crate::error::Result;
use crate::measurement::MeasurementModel;
use crate::measurement::data::{Measurement, Noise};
use crate::mechanism::{Mechanism, Params};

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

/// Simulate measurements at `targets` (tool coordinates) for a mechanism
/// whose true parameters are `truth`, read by the instrument `measurement` at
/// its nominal values (e.g. a known frame, the true socket positions), with
/// independent Gaussian noise on each reading (lengths and angles each their
/// own, [`Noise`]), seeded by `seed`.
pub fn simulate<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: impl Into<Noise>,
    seed: u64,
) -> Result<Vec<Measurement>> {
    simulate_with_progress(mech, measurement, truth, targets, noise, seed, &|| {})
}

/// [`simulate`], calling `progress` after each target.
pub fn simulate_with_progress<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: impl Into<Noise>,
    seed: u64,
    progress: &dyn Fn(),
) -> Result<Vec<Measurement>> {
    simulate_steps(
        mech,
        measurement,
        truth,
        targets,
        noise.into(),
        seed,
        &|| {
            progress();
            Ok(())
        },
    )
}

/// [`simulate`], stopped before its next target once `cancel` is set
/// ([`crate::Error::Cancelled`]).
pub fn simulate_cancellable<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: impl Into<Noise>,
    seed: u64,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<Vec<Measurement>> {
    simulate_steps(
        mech,
        measurement,
        truth,
        targets,
        noise.into(),
        seed,
        &|| crate::error::check_cancel(cancel),
    )
}

/// The targets in turn (one noise stream, drawn in their order), `step`
/// called after each: an error from it stops the simulation.
fn simulate_steps<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: Noise,
    seed: u64,
    step: &dyn Fn() -> Result<()>,
) -> Result<Vec<Measurement>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let normals = noise_normals(measurement, noise)?;
    let mut out = Vec::with_capacity(targets.len());
    for target in targets {
        let (commands, pose) = prepare_target(mech, target)?;
        out.push(measure(
            mech,
            measurement,
            truth,
            target,
            commands,
            &pose,
            &normals,
            &mut rng,
        )?);
        step()?;
    }
    Ok(out)
}

/// The noise's distribution on each axis of `measurement`.
pub(crate) fn noise_normals(
    measurement: &MeasurementModel,
    noise: Noise,
) -> Result<Vec<Normal<f64>>> {
    measurement
        .units()
        .iter()
        .map(|u| {
            let s = noise.for_unit(*u);
            if !(s.is_finite() && s >= 0.0) {
                return Err(crate::Error::InvalidRequest(format!(
                    "noise {s} {u} is not a valid standard deviation; give a finite number ≥ 0"
                )));
            }
            Normal::new(0.0, s).map_err(|e| {
                crate::Error::InvalidRequest(format!(
                    "noise {s} {u} is not a valid standard deviation: {e}"
                ))
            })
        })
        .collect()
}

/// The commands of a target (nominal inverse kinematics) and its prepared
/// pose (the exact nominal configuration).
pub(crate) fn prepare_target<M: Mechanism>(
    mech: &M,
    target: &[f64],
) -> Result<(Vec<f64>, crate::engine::models::Pose)> {
    let spec = mech.spec();
    let q = inverse_kinematics(mech, &spec.nominal[..spec.n_geometric()], target)?;
    let commands: Vec<f64> = spec.actuated.iter().map(|&j| q[j]).collect();
    let pose = prepare_pose(mech, &commands, Some(&q))?;
    Ok((commands, pose))
}

/// The simulated reading of a prepared target: the true parameters' exact
/// prediction observed by `measurement`, plus one draw of each axis' noise.
#[allow(clippy::too_many_arguments)]
pub(crate) fn measure<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    target: &[f64],
    commands: Vec<f64>,
    pose: &crate::engine::models::Pose,
    normals: &[Normal<f64>],
    rng: &mut StdRng,
) -> Result<Measurement> {
    let p = predict_pose(mech, pose, truth, Model::Exact, &[])?;
    Ok(reading(measurement, target, commands, &p, normals, rng))
}

/// The simulated reading of the truth's prediction `p` at a target: `p`
/// observed by `measurement`, plus one draw of each axis' noise.
pub(crate) fn reading(
    measurement: &MeasurementModel,
    target: &[f64],
    commands: Vec<f64>,
    p: &crate::engine::models::Prediction,
    normals: &[Normal<f64>],
    rng: &mut StdRng,
) -> Measurement {
    let mut read = vec![0.0; measurement.len()];
    measurement.observe(&p.x, measurement.nominal(), &mut read);
    let measured = read
        .iter()
        .zip(normals)
        .map(|(y, n)| y + n.sample(rng))
        .collect();
    Measurement {
        target: Some(target.to_vec()),
        commands,
        measured,
        ..Default::default()
    }
}

/// Simulated distances between pairs of poses (a printed object or a gauge
/// measured with calipers): for each pair of targets, the commands of both
/// from nominal inverse kinematics and the distance between the tool points
/// under the true parameters (exact model), plus Gaussian noise of
/// `noise_mm`. Each row has [`Measurement::partner`] set.
pub fn simulate_distances<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    truth: &Params,
    pairs: &[(Vec<f64>, Vec<f64>)],
    noise_mm: f64,
    seed: u64,
) -> Result<Vec<Measurement>> {
    measurement.check_distances()?;
    if !(noise_mm.is_finite() && noise_mm >= 0.0) {
        return Err(crate::Error::InvalidRequest(format!(
            "noise {noise_mm} mm is not a valid standard deviation; give a finite number ≥ 0"
        )));
    }
    let normal = Normal::new(0.0, noise_mm).expect("checked");
    let mut rng = StdRng::seed_from_u64(seed);
    let at = |target: &[f64]| -> Result<(Vec<f64>, Vec<f64>)> {
        let (commands, pose) = prepare_target(mech, target)?;
        Ok((
            commands,
            predict_pose(mech, &pose, truth, Model::Exact, &[])?.x,
        ))
    };
    pairs
        .iter()
        .map(|(a, b)| {
            let (ca, xa) = at(a)?;
            let (cb, xb) = at(b)?;
            Ok(Measurement {
                commands: ca,
                partner: Some(cb),
                measured: vec![measurement.distance(&xa, &xb) + normal.sample(&mut rng)],
                ..Default::default()
            })
        })
        .collect()
}
