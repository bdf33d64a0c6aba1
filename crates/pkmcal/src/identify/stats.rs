//! Error statistics as the paper reports them: per-axis error ranges and the
//! distance error (Euclidean norm of measured minus commanded position).
//! Lengths and angles are never pooled: the distance is the norm over the
//! length axes, the angle error the norm over the angle axes.

use crate::units::{Quantity, Unit};
use serde::Serialize;

/// Summary of a set of position errors.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Number of poses.
    pub count: usize,
    /// Unit of each axis.
    pub axis_units: Vec<Unit>,
    /// Smallest error per axis (in its unit).
    pub axis_min: Vec<f64>,
    /// Largest error per axis (in its unit).
    pub axis_max: Vec<f64>,
    /// Root mean square error per axis (in its unit).
    pub axis_rms: Vec<f64>,
    /// Smallest distance error (mm): norm over the length axes.
    pub distance_min: f64,
    /// Mean distance error (mm).
    pub distance_mean: f64,
    /// Root mean square distance error (mm).
    pub distance_rms: f64,
    /// Largest distance error (mm).
    pub distance_max: f64,
    /// Root mean square angle error (rad): norm over the angle axes; absent
    /// when no axis is an angle.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle_rms: Option<f64>,
    /// Largest angle error (rad), as `angle_rms`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle_max: Option<f64>,
}

/// Statistics of error vectors (each `measured − reference`), whose axes are
/// in `units`.
pub fn error_stats(errors: &[Vec<f64>], units: &[Unit]) -> ErrorStats {
    let n = units.len();
    let mut axis_min = vec![f64::INFINITY; n];
    let mut axis_max = vec![f64::NEG_INFINITY; n];
    let mut axis_sum2 = vec![0.0; n];
    let mut dmin = f64::INFINITY;
    let (mut dmax, mut amax): (f64, f64) = (0.0, 0.0);
    let (mut sum, mut sum2, mut asum2) = (0.0, 0.0, 0.0);
    let is = |k: usize, q: Quantity| units[k].quantity() == q;
    for e in errors {
        for (k, v) in e.iter().enumerate().take(n) {
            axis_min[k] = axis_min[k].min(*v);
            axis_max[k] = axis_max[k].max(*v);
            axis_sum2[k] += v * v;
        }
        let norm = |q: Quantity| {
            e.iter()
                .enumerate()
                .filter(|(k, _)| *k < n && is(*k, q))
                .map(|(_, v)| v * v)
                .sum::<f64>()
                .sqrt()
        };
        let d = norm(Quantity::Length);
        dmin = dmin.min(d);
        dmax = dmax.max(d);
        sum += d;
        sum2 += d * d;
        let a = norm(Quantity::Angle);
        amax = amax.max(a);
        asum2 += a * a;
    }
    let count = errors.len();
    let c = count.max(1) as f64;
    let angles = (0..n).any(|k| is(k, Quantity::Angle));
    ErrorStats {
        count,
        axis_units: units.to_vec(),
        axis_min,
        axis_max,
        axis_rms: axis_sum2.iter().map(|s| (s / c).sqrt()).collect(),
        distance_min: if count > 0 { dmin } else { 0.0 },
        distance_mean: sum / c,
        distance_rms: (sum2 / c).sqrt(),
        distance_max: dmax,
        angle_rms: angles.then(|| (asum2 / c).sqrt()),
        angle_max: angles.then_some(amax),
    }
}

/// Relative improvement `(before − after)/before` in percent.
pub fn improvement_percent(before: f64, after: f64) -> f64 {
    if before > 0.0 {
        100.0 * (before - after) / before
    } else {
        0.0
    }
}
