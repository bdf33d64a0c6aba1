//! The reachable, well-conditioned workspace: where targets and measurement
//! poses may be placed.

use crate::engine::atlas::{Reference, conditioning, lattice_targets, scaled_extent};
use crate::engine::kinematics::inverse_kinematics;
use crate::error::{Error, Result};
use crate::mechanism::{Mechanism, Params};

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

/// Evaluate one target: inverse kinematics and conditioning (nominal
/// parameters). An error if it is unreachable.
pub fn workspace_point<M: Mechanism>(mech: &M, target: &[f64]) -> Result<WorkspacePoint> {
    let spec = mech.spec();
    let rho = &spec.nominal[..spec.n_geometric()];
    point_from(mech, target, inverse_kinematics(mech, rho, target)?)
}

/// The [`WorkspacePoint`] of `target` reached at `q` (nominal parameters).
fn point_from<M: Mechanism>(mech: &M, target: &[f64], q: Vec<f64>) -> Result<WorkspacePoint> {
    let spec = mech.spec();
    let rho = &spec.nominal[..spec.n_geometric()];
    let conditioning = conditioning(mech, &q, rho);
    Ok(WorkspacePoint {
        target: target.to_vec(),
        q,
        conditioning,
    })
}

/// All lattice points with spacing `spacing` (mm; an axis in other units is
/// spaced by `spacing / axis_scale`) in the mechanism's workspace box that are
/// reachable with conditioning ≥ [`crate::Spec::min_conditioning`]. The spacing is
/// coarsened if the lattice would exceed [`MAX_LATTICE_POINTS`].
pub fn sample_workspace<M: Mechanism>(mech: &M, spacing: f64) -> Vec<WorkspacePoint> {
    sample_workspace_cancellable(mech, spacing, None).expect("not cancelled")
}

/// [`sample_workspace`], stopped once `cancel` is set
/// ([`crate::Error::Cancelled`]).
pub fn sample_workspace_cancellable<M: Mechanism>(
    mech: &M,
    spacing: f64,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<Vec<WorkspacePoint>> {
    use rayon::prelude::*;
    let spec = mech.spec();
    let reference = Reference::new(mech, &spec.nominal[..spec.n_geometric()]);
    let points = lattice_targets(spec, spacing)
        .into_par_iter()
        .filter_map(|target| {
            crate::error::check_cancel(cancel).ok()?;
            let q = reference.inverse_kinematics(&target).ok()?;
            point_from(mech, &target, q)
                .ok()
                .filter(|p| p.conditioning >= spec.min_conditioning)
        })
        .collect();
    crate::error::check_cancel(cancel)?;
    Ok(points)
}

/// The most targets one request spreads over the workspace (a grid, a
/// spread, random validation targets, a plan's poses): each is drawn from a
/// lattice of at most [`crate::engine::atlas::MAX_LATTICE_POINTS`] (their usable part, often a
/// third), so that more could only fail after seconds of work; a
/// calibration has tens to thousands of poses.
pub const MAX_TARGETS: usize = 10_000;

/// `count` targets beyond [`MAX_TARGETS`], refused; or `Ok`.
pub fn check_target_count(count: usize) -> Result<()> {
    if count > MAX_TARGETS {
        return Err(Error::InvalidRequest(format!(
            "{count} targets are more than the {MAX_TARGETS} one request spreads over the workspace"
        )));
    }
    Ok(())
}

/// `count` targets spread evenly over the usable workspace: farthest-point
/// sampling of a fine lattice, starting from the point nearest the centroid.
/// Deterministic.
pub fn spread_targets<M: Mechanism>(mech: &M, count: usize) -> Result<Vec<WorkspacePoint>> {
    check_target_count(count)?;
    let spec = mech.spec();
    let extent = scaled_extent(spec);
    let dims = spec.workspace_box.len() as i32;
    // About 40 lattice points per target, at least 3600 (60 per axis in 2-D).
    let spacing = extent / (40.0 * count as f64).max(3600.0).powf(1.0 / dims as f64);
    let pool = sample_workspace(mech, spacing);
    if pool.len() < count {
        return Err(too_few(spec, pool.len(), count));
    }
    let d2 = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .enumerate()
            .map(|(k, (x, y))| ((x - y) * spec.axis_scale(k)).powi(2))
            .sum::<f64>()
    };
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

/// The largest extent of the workspace box, in mm-equivalent units.
/// The error for a workspace with too few usable points: none at all means
/// the box misses the reachable, well-conditioned region.
fn too_few(spec: &crate::Spec, found: usize, count: usize) -> Error {
    if found == 0 {
        Error::InvalidRequest(format!(
            "no reachable, well-conditioned pose of `{}` lies in its workspace box {:?}; check the box (`[workspace]`) against the mechanism's reach",
            spec.name, spec.workspace_box
        ))
    } else {
        Error::InvalidRequest(format!(
            "only {found} usable workspace points were found for {count} targets; ask for fewer"
        ))
    }
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
    check_target_count(count)?;
    use rand::SeedableRng;
    use rand::seq::SliceRandom;
    let mut pool = sample_workspace(mech, 5.0);
    if pool.len() < count {
        return Err(too_few(mech.spec(), pool.len(), count));
    }
    pool.shuffle(&mut rand::rngs::StdRng::seed_from_u64(seed));
    Ok(pool.into_iter().take(count).map(|p| p.target).collect())
}

/// A plain grid of `count` usable targets: the coarsest square lattice over the
/// workspace box with at least `count` usable points, thinned evenly to
/// `count`. The baseline measurement plan.
pub fn grid_targets<M: Mechanism>(mech: &M, count: usize) -> Result<Vec<WorkspacePoint>> {
    grid_targets_cancellable(mech, count, None)
}

/// [`grid_targets`], stopped between its lattices once `cancel` is set
/// ([`crate::Error::Cancelled`]).
pub fn grid_targets_cancellable<M: Mechanism>(
    mech: &M,
    count: usize,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Result<Vec<WorkspacePoint>> {
    check_target_count(count)?;
    let spec = mech.spec();
    let extent = scaled_extent(spec);
    let dims = spec.workspace_box.len() as f64;
    let finest = if dims <= 2.0 {
        extent / 400.0
    } else {
        extent / (200.0 * count as f64).powf(1.0 / dims)
    };
    let (mut lo, mut hi) = (finest, extent);
    // Bisection on the spacing; `lo` is known to give `count` usable points
    // once it has moved. The finest lattice (up to 160,000 points, seconds
    // of inverse kinematics on a planar linkage) is sampled only when it
    // never does.
    let mut verified = false;
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if sample_workspace_cancellable(mech, mid, cancel)?.len() >= count {
            lo = mid;
            verified = true;
        } else {
            hi = mid;
        }
    }
    let lattice = sample_workspace_cancellable(mech, lo, cancel)?;
    if !verified && lattice.len() < count {
        return Err(too_few(spec, lattice.len(), count));
    }
    Ok(crate::engine::atlas::thin_evenly(lattice.len(), count)
        .into_iter()
        .map(|i| lattice[i].clone())
        .collect())
}
