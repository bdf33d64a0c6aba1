//! The reachable, well-conditioned workspace: where targets and measurement
//! poses may be placed.

use crate::error::{Error, Result};
use crate::kinematics::inverse_kinematics;
use crate::linearized::linearize;
use crate::mechanism::{Mechanism, Params};

/// Smallest inverse condition number (of `∂g/∂q_v` and of `J_f`) accepted for a
/// usable pose.
pub const MIN_CONDITIONING: f64 = 0.2;

/// A reachable tool position with its nominal joints.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkspacePoint {
    /// Tool coordinates (mm).
    pub target: Vec<f64>,
    /// Joint vector from inverse kinematics (nominal parameters).
    pub q: Vec<f64>,
    /// Inverse condition number, the smaller of `∂g/∂q_v` and `J_f`'s (0 at a
    /// singularity, 1 at best).
    pub conditioning: f64,
}

fn inverse_condition(m: &nalgebra::DMatrix<f64>) -> f64 {
    let sv = m.clone().svd(false, false).singular_values;
    let max = sv.max();
    if max > 0.0 { sv.min() / max } else { 0.0 }
}

/// Inverse condition number of a configuration: the smaller of `∂g/∂q_v`'s
/// (distance from a constraint singularity) and `J_f`'s (distance from a
/// singularity of the tool motion).
pub fn conditioning<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64]) -> f64 {
    let spec = mech.spec();
    let Ok(lin) = linearize(mech, q, rho, &spec.independent) else {
        return 0.0;
    };
    let nq = spec.joints.len();
    let dependent: Vec<usize> = (0..nq).filter(|i| !spec.independent.contains(i)).collect();
    let j = crate::autodiff::jacobians(mech, q, rho, 0..nq);
    let gv = j.dg.select_columns(&dependent);
    inverse_condition(&gv).min(inverse_condition(&lin.jf))
}

/// Evaluate one target: inverse kinematics and conditioning (nominal
/// parameters). An error if it is unreachable.
pub fn workspace_point<M: Mechanism>(mech: &M, target: &[f64]) -> Result<WorkspacePoint> {
    let spec = mech.spec();
    let rho = &spec.nominal[..spec.n_geometric()];
    let q = inverse_kinematics(mech, rho, target)?;
    let conditioning = conditioning(mech, &q, rho);
    Ok(WorkspacePoint {
        target: target.to_vec(),
        q,
        conditioning,
    })
}

/// All lattice points with spacing `spacing` (mm) in the mechanism's workspace
/// box that are reachable with conditioning ≥ [`MIN_CONDITIONING`].
pub fn sample_workspace<M: Mechanism>(mech: &M, spacing: f64) -> Vec<WorkspacePoint> {
    let spec = mech.spec();
    let axes: Vec<Vec<f64>> = spec
        .workspace_box
        .iter()
        .map(|&[lo, hi]| {
            let n = ((hi - lo) / spacing).floor() as usize;
            (0..=n).map(|i| lo + i as f64 * spacing).collect()
        })
        .collect();
    let mut points = Vec::new();
    let mut idx = vec![0usize; axes.len()];
    'outer: loop {
        let target: Vec<f64> = idx.iter().zip(&axes).map(|(&i, a)| a[i]).collect();
        if let Ok(p) = workspace_point(mech, &target)
            && p.conditioning >= MIN_CONDITIONING
        {
            points.push(p);
        }
        for d in 0..idx.len() {
            idx[d] += 1;
            if idx[d] < axes[d].len() {
                continue 'outer;
            }
            idx[d] = 0;
        }
        break;
    }
    points
}

/// `count` targets spread evenly over the usable workspace: farthest-point
/// sampling of a fine lattice, starting from the point nearest the centroid.
/// Deterministic.
pub fn spread_targets<M: Mechanism>(mech: &M, count: usize) -> Result<Vec<WorkspacePoint>> {
    let spec = mech.spec();
    let extent = spec
        .workspace_box
        .iter()
        .map(|[a, b]| b - a)
        .fold(0.0, f64::max);
    let dims = spec.workspace_box.len() as f64;
    // About 40 lattice points per target, at least a 60-per-axis lattice.
    let spacing = (extent / 60.0).min(extent / (40.0 * count as f64).powf(1.0 / dims));
    let pool = sample_workspace(mech, spacing);
    if pool.len() < count {
        return Err(Error::InvalidRequest(format!(
            "only {} usable workspace points were found for {count} targets; ask for fewer",
            pool.len()
        )));
    }
    let d2 = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>();
    let n = spec.tool_axes.len();
    let centroid: Vec<f64> = (0..n)
        .map(|k| pool.iter().map(|p| p.target[k]).sum::<f64>() / pool.len() as f64)
        .collect();
    let first = (0..pool.len())
        .min_by(|&a, &b| d2(&pool[a].target, &centroid).total_cmp(&d2(&pool[b].target, &centroid)))
        .expect("pool is not empty");
    let mut chosen = vec![first];
    let mut nearest: Vec<f64> = pool
        .iter()
        .map(|p| d2(&p.target, &pool[first].target))
        .collect();
    while chosen.len() < count {
        let next = (0..pool.len())
            .max_by(|&a, &b| nearest[a].total_cmp(&nearest[b]))
            .expect("pool is not empty");
        chosen.push(next);
        for (i, p) in pool.iter().enumerate() {
            nearest[i] = nearest[i].min(d2(&p.target, &pool[next].target));
        }
    }
    Ok(chosen.into_iter().map(|i| pool[i].clone()).collect())
}

/// Commands (one per actuator) that put the nominal mechanism's tool at
/// `target`: nominal inverse kinematics.
pub fn nominal_commands<M: Mechanism>(mech: &M, target: &[f64]) -> Result<Vec<f64>> {
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let q = inverse_kinematics(mech, nominal.geometric(), target)?;
    Ok(spec.actuated.iter().map(|&j| q[j]).collect())
}

/// `count` distinct usable targets drawn at random (seeded) from a 5 mm
/// lattice of the usable workspace: unseen poses for validation.
pub fn random_targets<M: Mechanism>(mech: &M, count: usize, seed: u64) -> Result<Vec<Vec<f64>>> {
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    let mut pool = sample_workspace(mech, 5.0);
    if pool.len() < count {
        return Err(Error::InvalidRequest(format!(
            "only {} usable workspace points for {count} random targets",
            pool.len()
        )));
    }
    pool.shuffle(&mut rand::rngs::StdRng::seed_from_u64(seed));
    Ok(pool.into_iter().take(count).map(|p| p.target).collect())
}

/// A plain grid of `count` usable targets: the coarsest square lattice over the
/// workspace box with at least `count` usable points, thinned evenly to
/// `count`. The baseline measurement plan.
pub fn grid_targets<M: Mechanism>(mech: &M, count: usize) -> Result<Vec<WorkspacePoint>> {
    let spec = mech.spec();
    let extent = spec
        .workspace_box
        .iter()
        .map(|[a, b]| b - a)
        .fold(0.0, f64::max);
    let (mut lo, mut hi) = (extent / 400.0, extent);
    if sample_workspace(mech, lo).len() < count {
        return Err(Error::InvalidRequest(format!(
            "the usable workspace holds fewer than {count} lattice points; ask for fewer"
        )));
    }
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if sample_workspace(mech, mid).len() >= count {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let lattice = sample_workspace(mech, lo);
    let n = lattice.len();
    Ok((0..count).map(|i| lattice[i * n / count].clone()).collect())
}
