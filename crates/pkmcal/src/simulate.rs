//! Simulated measurements: commands from nominal inverse kinematics, tool
//! positions from the true parameters (exact model) plus Gaussian noise.

use crate::error::Result;
use crate::kinematics::inverse_kinematics;
use crate::measurement::MeasurementModel;
use crate::mechanism::{Mechanism, Params};
use crate::models::{Model, predict_pose, prepare_pose};
use crate::units::{Quantity, Unit};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

/// One measured pose: what was commanded, what was measured, how well, and
/// where it came from. Every subset of a data set (held-out poses, folds,
/// poses left after dropping outliers) keeps each pose's σ and origin.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Measurement {
    /// The target the commands were computed for (tool coordinates), if known.
    pub target: Option<Vec<f64>>,
    /// Actuator commands (each in its joint's unit, rad or mm).
    pub commands: Vec<f64>,
    /// The commands of a second pose when the row is a distance between two
    /// poses (a printed object or a gauge measured with calipers): `measured`
    /// is then one value, the distance between the tool points at `commands`
    /// and at `partner` (mm, [`crate::measurement::DISTANCE_AXIS`]), whatever
    /// the instrument of the other rows.
    pub partner: Option<Vec<f64>>,
    /// Measured coordinates (each in its axis's unit, mm or rad).
    pub measured: Vec<f64>,
    /// Known standard deviation of each measured coordinate (same unit);
    /// `None` where it is to be estimated from the residuals. Empty: none
    /// known.
    pub sigma: Vec<Option<f64>>,
    /// Where the pose came from, for messages and reports; `None`: its
    /// position in the data given to the library.
    pub origin: Option<Origin>,
}

/// Where a pose came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
pub struct Origin {
    /// Pose number in the data file (1-based, file order).
    pub pose: usize,
    /// Line in the data file.
    pub line: Option<u64>,
    /// Whether the row is a distance between two poses
    /// ([`Measurement::partner`]); `pose` is then its number among the
    /// distances (their own file's numbering in the command-line tool).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub distance: bool,
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = if self.distance { "distance" } else { "pose" };
        write!(f, "{what} {}", self.pose)?;
        if let Some(l) = self.line {
            write!(f, " (line {l})")?;
        }
        Ok(())
    }
}

impl Measurement {
    /// The known standard deviation of coordinate `axis`, if any.
    pub fn sigma_of(&self, axis: usize) -> Option<f64> {
        self.sigma.get(axis).copied().flatten()
    }
}

/// `data` with every pose's [`Origin`] filled in (its 1-based position where
/// none was given), so that subsets still name the original poses.
pub fn numbered(data: &[Measurement]) -> Vec<Measurement> {
    data.iter()
        .enumerate()
        .map(|(i, m)| {
            let mut m = m.clone();
            let distance = m.partner.is_some();
            m.origin.get_or_insert(Origin {
                pose: i + 1,
                line: None,
                distance,
            });
            m
        })
        .collect()
}

/// Standard deviations of simulated measurement noise, per kind of
/// coordinate: a length noise never lands on an angle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// On every length coordinate (positions, distances), mm.
    pub length: f64,
    /// On every angle coordinate (orientations), rad.
    pub angle: f64,
}

/// The default angle noise of [`Noise::lengths`]: the length noise over this
/// lever arm (mm), e.g. 10 µrad for 2 µm.
pub const DEFAULT_ANGLE_LEVER_MM: f64 = 200.0;

impl Noise {
    /// No noise.
    pub const NONE: Noise = Noise {
        length: 0.0,
        angle: 0.0,
    };
    /// Length noise `mm` and the angle noise of a tracker of that quality:
    /// `mm /` [`DEFAULT_ANGLE_LEVER_MM`] rad.
    pub fn lengths(mm: f64) -> Self {
        Noise {
            length: mm,
            angle: mm / DEFAULT_ANGLE_LEVER_MM,
        }
    }
    /// The standard deviation for a coordinate in `unit`.
    pub fn for_unit(&self, unit: Unit) -> f64 {
        match unit.quantity() {
            Quantity::Angle => self.angle,
            _ => self.length,
        }
    }
}

impl From<f64> for Noise {
    /// [`Noise::lengths`].
    fn from(mm: f64) -> Self {
        Noise::lengths(mm)
    }
}

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
    let noise = noise.into();
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
        progress();
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
) -> Result<(Vec<f64>, crate::models::Pose)> {
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
    pose: &crate::models::Pose,
    normals: &[Normal<f64>],
    rng: &mut StdRng,
) -> Result<Measurement> {
    let p = predict_pose(mech, pose, truth, Model::Exact, &[])?;
    let mut read = vec![0.0; measurement.len()];
    measurement.observe(&p.x, measurement.nominal(), &mut read);
    let measured = read
        .iter()
        .zip(normals)
        .map(|(y, n)| y + n.sample(rng))
        .collect();
    Ok(Measurement {
        target: Some(target.to_vec()),
        commands,
        measured,
        ..Default::default()
    })
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
