//! Error statistics as the paper reports them: per-axis error ranges and the
//! distance error (Euclidean norm of measured minus commanded position).

use serde::Serialize;

/// Summary of a set of position errors.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrorStats {
    /// Number of poses.
    pub count: usize,
    /// Smallest error per tool axis (mm).
    pub axis_min: Vec<f64>,
    /// Largest error per tool axis (mm).
    pub axis_max: Vec<f64>,
    /// Smallest distance error (mm).
    pub distance_min: f64,
    /// Mean distance error (mm).
    pub distance_mean: f64,
    /// Root mean square distance error (mm).
    pub distance_rms: f64,
    /// Largest distance error (mm).
    pub distance_max: f64,
}

/// Statistics of error vectors (each `measured − reference`, mm).
pub fn error_stats(errors: &[Vec<f64>]) -> ErrorStats {
    let n = errors.first().map_or(0, Vec::len);
    let mut axis_min = vec![f64::INFINITY; n];
    let mut axis_max = vec![f64::NEG_INFINITY; n];
    let mut dmin = f64::INFINITY;
    let mut dmax: f64 = 0.0;
    let (mut sum, mut sum2) = (0.0, 0.0);
    for e in errors {
        for (k, v) in e.iter().enumerate() {
            axis_min[k] = axis_min[k].min(*v);
            axis_max[k] = axis_max[k].max(*v);
        }
        let d = e.iter().map(|v| v * v).sum::<f64>().sqrt();
        dmin = dmin.min(d);
        dmax = dmax.max(d);
        sum += d;
        sum2 += d * d;
    }
    let count = errors.len();
    let c = count.max(1) as f64;
    ErrorStats {
        count,
        axis_min,
        axis_max,
        distance_min: if count > 0 { dmin } else { 0.0 },
        distance_mean: sum / c,
        distance_rms: (sum2 / c).sqrt(),
        distance_max: dmax,
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
