//! Simulated measurements: commands from nominal inverse kinematics, tool
//! positions from the true parameters (exact model) plus Gaussian noise.

use crate::error::Result;
use crate::kinematics::inverse_kinematics;
use crate::mechanism::{Mechanism, Params};
use crate::models::{Model, predict_pose, prepare_pose};
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

/// Simulate measurements at `targets` for a mechanism whose true parameters are
/// `truth`, with independent Gaussian noise of standard deviation `noise` (mm)
/// on each tool coordinate, seeded by `seed`.
pub fn simulate<M: Mechanism>(
    mech: &M,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: f64,
    seed: u64,
) -> Result<Vec<Measurement>> {
    simulate_with_progress(mech, truth, targets, noise, seed, &|| {})
}

/// [`simulate`], calling `progress` after each target.
pub fn simulate_with_progress<M: Mechanism>(
    mech: &M,
    truth: &Params,
    targets: &[Vec<f64>],
    noise: f64,
    seed: u64,
    progress: &dyn Fn(),
) -> Result<Vec<Measurement>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise.max(0.0)).map_err(|e| {
        crate::Error::InvalidRequest(format!(
            "noise {noise} is not a valid standard deviation: {e}"
        ))
    })?;
    let spec = mech.spec();
    let mut out = Vec::with_capacity(targets.len());
    for target in targets {
        // Nominal inverse kinematics gives the commands and the exact nominal
        // configuration.
        let q = inverse_kinematics(mech, &spec.nominal[..spec.n_geometric()], target)?;
        let commands: Vec<f64> = spec.actuated.iter().map(|&j| q[j]).collect();
        let pose = prepare_pose(mech, &commands, Some(&q))?;
        let p = predict_pose(mech, &pose, truth, Model::Exact, &[])?;
        let measured = p.x.iter().map(|x| x + normal.sample(&mut rng)).collect();
        out.push(Measurement {
            target: Some(target.clone()),
            commands,
            measured,
        });
        progress();
    }
    Ok(out)
}
