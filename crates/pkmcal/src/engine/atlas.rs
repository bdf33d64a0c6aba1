//! The usable workspace as the engine sees it: the inverse condition number
//! of a configuration, the lattice over the workspace box, and the atlas of
//! known configurations that starts forward kinematics near its answer.

use crate::error::Result;
use crate::mechanism::Mechanism;

/// Smallest inverse condition number (of `∂g/∂q_v` and of `J_f`) accepted for a
/// usable pose.
pub const MIN_CONDITIONING: f64 = 0.2;

/// Fraction of the reference pose's conditioning that a pose of a described
/// mechanism needs to be usable (0.45 × 0.444 ≈ [`MIN_CONDITIONING`] for the
/// reference mechanism).
pub const RELATIVE_CONDITIONING: f64 = 0.45;

fn inverse_condition(m: &nalgebra::DMatrix<f64>) -> f64 {
    if m.iter().any(|v| !v.is_finite()) {
        return 0.0;
    }
    let sv = m.clone().svd(false, false).singular_values;
    let max = sv.max();
    if max > 0.0 { sv.min() / max } else { 0.0 }
}

/// Inverse condition number of a configuration: the smaller of `∂g/∂q_v`'s
/// (distance from a constraint singularity) and `J_f`'s (distance from a
/// singularity of the tool motion).
pub fn conditioning<M: Mechanism>(mech: &M, q: &[f64], rho: &[f64]) -> f64 {
    let spec = mech.spec();
    let Ok(jf) = crate::engine::linearized::joint_tool_jacobian(mech, q, rho, &spec.independent)
    else {
        return 0.0;
    };
    let nq = spec.joints.len();
    let dependent: Vec<usize> = (0..nq).filter(|i| !spec.independent.contains(i)).collect();
    let j = crate::mechanism::autodiff::jacobians(mech, q, rho, 0..nq);
    // Joints and tool axes in mm-equivalent units (Spec::joint_scale,
    // Spec::axis_scale), so that mixed units do not pass for ill-conditioning.
    let mut gv = j.dg.select_columns(&dependent);
    for (c, &d) in dependent.iter().enumerate() {
        gv.column_mut(c).unscale_mut(spec.joint_scale(d));
    }
    let mut jf = jf;
    for (c, &u) in spec.independent.iter().enumerate() {
        jf.column_mut(c).unscale_mut(spec.joint_scale(u));
    }
    for r in 0..jf.nrows() {
        jf.row_mut(r).scale_mut(spec.axis_scale(r));
    }
    inverse_condition(&gv).min(inverse_condition(&jf))
}

/// Most lattice points [`sample_workspace`] evaluates; a finer spacing is
/// coarsened to respect it (it matters for mechanisms with many tool axes).
pub const MAX_LATTICE_POINTS: usize = 200_000;

/// Lattice coordinates per axis: spacing `spacing` mm-equivalent
/// ([`crate::Spec::axis_scale`]), coarsened to at most [`MAX_LATTICE_POINTS`].
pub(crate) fn lattice_axes(spec: &crate::Spec, spacing: f64) -> Vec<Vec<f64>> {
    axes_at(spec, lattice_spacing(spec, spacing, MAX_LATTICE_POINTS))
}

/// Each axis's coordinates at `spacing`: as many steps as fit in the box,
/// centred in it (the leftover split between both ends), so that the lattice
/// reaches within half a step of both ends of every axis.
#[doc(hidden)] // public for the integration tests only
pub fn axes_at(spec: &crate::Spec, spacing: f64) -> Vec<Vec<f64>> {
    spec.workspace_box
        .iter()
        .enumerate()
        .map(|(k, &[lo, hi])| {
            let step = spacing / spec.axis_scale(k);
            let n = ((hi - lo) / step).floor() as usize;
            let first = lo + 0.5 * ((hi - lo) - n as f64 * step);
            (0..=n).map(|i| first + i as f64 * step).collect()
        })
        .collect()
}

/// The indices of `keep` of `n` items spread evenly and centred (the middle
/// of each of `keep` equal runs), in order; all of them when `keep ≥ n`.
pub fn thin_evenly(n: usize, keep: usize) -> Vec<usize> {
    if keep >= n {
        return (0..n).collect();
    }
    (0..keep)
        .map(|k| ((2 * k + 1) as u128 * n as u128 / (2 * keep) as u128) as usize)
        .collect()
}

/// The lattice spacing actually used for `spacing` (mm, scaled per axis):
/// `spacing`, coarsened by steps of 10 % until the lattice over the
/// workspace box has at most `max_points` points, so that the work is
/// bounded whatever spacing is asked for.
pub fn lattice_spacing(spec: &crate::Spec, spacing: f64, max_points: usize) -> f64 {
    let extent = scaled_extent(spec).max(f64::MIN_POSITIVE);
    let mut spacing = if spacing.is_finite() && spacing > 0.0 {
        spacing
    } else {
        extent
    };
    // Start no finer than the budget allows on a full box.
    let dims = spec.workspace_box.len().max(1) as f64;
    spacing = spacing.max(extent / (max_points as f64).powf(1.0 / dims) / 2.0);
    loop {
        let total = axes_at(spec, spacing)
            .iter()
            .map(Vec::len)
            .fold(1usize, |a, b| a.saturating_mul(b));
        if total <= max_points {
            return spacing;
        }
        spacing *= 1.1;
    }
}

/// The inverse kinematics of many targets under the same parameters, from
/// one reference configuration (computed when the first target without a
/// closed form needs it): what [`inverse_kinematics`] does for each.
pub(crate) struct Reference<'a, M> {
    mech: &'a M,
    rho: &'a [f64],
    q: std::sync::OnceLock<Option<Vec<f64>>>,
}

impl<'a, M: Mechanism> Reference<'a, M> {
    pub(crate) fn new(mech: &'a M, rho: &'a [f64]) -> Self {
        Self {
            mech,
            rho,
            q: std::sync::OnceLock::new(),
        }
    }

    pub(crate) fn inverse_kinematics(&self, target: &[f64]) -> Result<Vec<f64>> {
        crate::engine::kinematics::inverse_kinematics_from(self.mech, self.rho, target, || {
            self.q
                .get_or_init(|| {
                    crate::engine::kinematics::reference_configuration(self.mech, self.rho).ok()
                })
                .clone()
                .ok_or_else(|| {
                    crate::Error::InvalidMechanism(
                        "the reference configuration does not close with these parameters".into(),
                    )
                })
        })
    }
}

/// The points of the lattice of [`sample_workspace`], in order.
pub(crate) fn lattice_targets(spec: &crate::Spec, spacing: f64) -> Vec<Vec<f64>> {
    let axes = lattice_axes(spec, spacing);
    let mut out = Vec::new();
    let mut idx = vec![0usize; axes.len()];
    'outer: loop {
        out.push(idx.iter().zip(&axes).map(|(&i, a)| a[i]).collect());
        for d in 0..idx.len() {
            idx[d] += 1;
            if idx[d] < axes[d].len() {
                continue 'outer;
            }
            idx[d] = 0;
        }
        break;
    }
    out
}

pub(crate) fn scaled_extent(spec: &crate::Spec) -> f64 {
    spec.workspace_box
        .iter()
        .enumerate()
        .map(|(k, [a, b])| (b - a) * spec.axis_scale(k))
        .fold(0.0, f64::max)
}

/// Known configurations spread over the usable workspace, for starting forward
/// kinematics near the answer: a mechanism without a closed-form guess
/// ([`Mechanism::configuration_guess`]) returns the configuration whose
/// actuators are nearest the commands, and Newton continues from there (a
/// straight path from one far reference configuration can leave the
/// workspace).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Atlas {
    /// `(actuator values, joint vector)` per entry.
    #[doc(hidden)] // public for the integration tests only
    pub entries: Vec<(Vec<f64>, Vec<f64>)>,
    /// The entries' actuator values by actuator (all the entries' first,
    /// then all their second, …), for [`Atlas::nearest`]'s scan: each
    /// entry's distance is still summed actuator by actuator, in order, and
    /// the entries side by side vectorise.
    by_actuator: Vec<f64>,
    /// Weight of each actuator in the distance ([`crate::Spec::joint_scale`]).
    #[doc(hidden)] // public for the integration tests only
    pub scale: Vec<f64>,
}

impl Atlas {
    /// About `points` lattice points of the usable workspace (nominal
    /// parameters).
    pub fn build<M: Mechanism>(mech: &M, points: usize) -> Self {
        use rayon::prelude::*;
        let spec = mech.spec();
        let dims = spec.workspace_box.len() as f64;
        let spacing = scaled_extent(spec) / (points.max(2) as f64).powf(1.0 / dims);
        let rho = &spec.nominal[..spec.n_geometric()];
        let reference = Reference::new(mech, rho);
        // The lattice of [`sample_workspace`], walked row by row (rows in
        // parallel): each point's inverse kinematics starts from its
        // neighbour's solution, one lattice step away, and from the
        // reference configuration only at a row's start or after a point
        // that failed — a few Newton iterations instead of a continuation
        // across the workspace. The conditioning is only computed when a
        // threshold asks for it (none while a mechanism builds its atlas).
        let row = lattice_axes(spec, spacing)
            .first()
            .map_or(1, |a| a.len().max(1));
        let reference = &reference;
        let entries = lattice_targets(spec, spacing)
            .par_chunks(row)
            .flat_map_iter(|targets| {
                let mut previous: Option<Vec<f64>> = None;
                targets.iter().filter_map(move |target| {
                    let near = previous.as_deref().and_then(|p| {
                        crate::engine::kinematics::inverse_kinematics_near(mech, rho, target, p)
                            .ok()
                    });
                    previous = near.or_else(|| reference.inverse_kinematics(target).ok());
                    let q = previous.clone()?;
                    if spec.min_conditioning > 0.0 {
                        let c = conditioning(mech, &q, rho);
                        if c.is_nan() || c < spec.min_conditioning {
                            return None;
                        }
                    }
                    Some((spec.actuated.iter().map(|&j| q[j]).collect(), q))
                })
            })
            .collect::<Vec<(Vec<f64>, Vec<f64>)>>();
        Self {
            by_actuator: (0..spec.n_actuated())
                .flat_map(|a| entries.iter().map(move |e| e.0[a]))
                .collect(),
            entries,
            scale: spec.actuated.iter().map(|&j| spec.joint_scale(j)).collect(),
        }
    }

    /// Number of configurations.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether it holds no configuration.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The configuration whose actuators are nearest `commands`.
    pub fn nearest(&self, commands: &[f64]) -> Option<Vec<f64>> {
        // The sums of squares of the scaled differences, actuator by
        // actuator (as `Iterator::sum` adds them, from −0), over the
        // commands given (at most one per actuator).
        let mut d = vec![-0.0f64; self.entries.len()];
        let columns = self.by_actuator.chunks_exact(self.entries.len().max(1));
        for ((column, c), s) in columns.zip(commands).zip(&self.scale) {
            for (d, x) in d.iter_mut().zip(column) {
                *d += ((x - c) * s).powi(2);
            }
        }
        // The first of equal distances (`min_by` keeps it).
        d.iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .map(|(i, _)| self.entries[i].1.clone())
    }
}
