//! The workspace lattice reaches both ends of every axis: `simulate --grid
//! N`'s targets (a plain grid) and `plan`'s candidates used to start at each
//! axis's minimum and stop up to a whole step short of its maximum.

use crate::common::*;
use pkmcal::Mechanism;

/// Values closer than this (in units of the axis's extent) are the same
/// lattice coordinate.
const SAME_COORDINATE: f64 = 1e-9;

/// For every axis of `targets` that takes at least two values: the extreme
/// values lie within half a lattice step (the smallest gap between distinct
/// values) of both ends of the workspace box, as a lattice centred in a box
/// that is usable to its ends does (gough-stewart-6's `--grid 60` used to
/// span x = −80 … 42.6 with a 40.9 mm step).
fn reaches_both_ends<M: Mechanism>(m: &M, targets: &[Vec<f64>]) {
    let spec = m.spec();
    for (k, &[lo, hi]) in spec.workspace_box.iter().enumerate() {
        let eps = SAME_COORDINATE * (hi - lo).max(1.0);
        let mut v: Vec<f64> = targets.iter().map(|t| t[k]).collect();
        v.sort_by(f64::total_cmp);
        v.dedup_by(|a, b| (*a - *b).abs() < eps);
        if v.len() < 2 {
            continue;
        }
        let step = v
            .windows(2)
            .map(|w| w[1] - w[0])
            .fold(f64::INFINITY, f64::min);
        let (first, last) = (v[0], v[v.len() - 1]);
        assert!(
            first - lo <= 0.5 * step + eps && hi - last <= 0.5 * step + eps,
            "{}: axis {} spans {first}..{last} of [{lo}, {hi}] with step {step}",
            spec.name,
            spec.tool_axes[k]
        );
    }
}

#[test]
fn grids_reach_both_ends_of_every_axis() {
    fn grid<M: Mechanism>(m: &M, count: usize) {
        let g: Vec<Vec<f64>> = pkmcal::grid_targets(m, count)
            .unwrap()
            .into_iter()
            .map(|p| p.target)
            .collect();
        reaches_both_ends(m, &g);
    }
    for count in [35, 60, 200] {
        grid(&gough_stewart("gough-stewart-6"), count);
        grid(&planar("4-rrr"), count);
    }
}
