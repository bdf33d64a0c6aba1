//! Simulated measurements: commands from nominal inverse kinematics, tool
//! positions from the true parameters (exact model) plus Gaussian noise.

use crate::error::Result;
use crate::kinematics::inverse_kinematics;
use crate::mechanism::{Mechanism, Params};
use crate::models::{Model, predict_pose, prepare_pose};
use crate::units::{Quantity, Unit};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

/// One measured pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// The target the commands were computed for (mm), if known.
    pub target: Option<Vec<f64>>,
    /// Actuator commands (rad or mm).
    pub commands: Vec<f64>,
    /// Measured tool position (mm).
    pub measured: Vec<f64>,
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

/// Simulate measurements at `targets` for a mechanism whose true parameters are
/// `truth`, with independent Gaussian noise on each tool coordinate (lengths
/// and angles each their own, [`Noise`]), seeded by `seed`.
pub fn simulate<M: Mechanism>(
    mech: &M,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: impl Into<Noise>,
    seed: u64,
) -> Result<Vec<Measurement>> {
    simulate_with_progress(mech, truth, targets, noise, seed, &|| {})
}

/// [`simulate`], calling `progress` after each target.
pub fn simulate_with_progress<M: Mechanism>(
    mech: &M,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: impl Into<Noise>,
    seed: u64,
    progress: &dyn Fn(),
) -> Result<Vec<Measurement>> {
    let noise = noise.into();
    let mut rng = StdRng::seed_from_u64(seed);
    let spec = mech.spec();
    let normals = spec
        .tool_units
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
        .collect::<Result<Vec<_>>>()?;
    let mut out = Vec::with_capacity(targets.len());
    for target in targets {
        // Nominal inverse kinematics gives the commands and the exact nominal
        // configuration.
        let q = inverse_kinematics(mech, &spec.nominal[..spec.n_geometric()], target)?;
        let commands: Vec<f64> = spec.actuated.iter().map(|&j| q[j]).collect();
        let pose = prepare_pose(mech, &commands, Some(&q))?;
        let p = predict_pose(mech, &pose, truth, Model::Exact, &[])?;
        let measured =
            p.x.iter()
                .zip(&normals)
                .map(|(x, n)| x + n.sample(&mut rng))
                .collect();
        out.push(Measurement {
            target: Some(target.clone()),
            commands,
            measured,
        });
        progress();
    }
    Ok(out)
}
