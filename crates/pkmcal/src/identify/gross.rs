//! Gross-error checks before the fit: known σ that are sane, and readings
//! so far from the nominal prediction that they are misreads or swapped
//! columns.

use super::driver::measurement_start;
use super::problem::IdentificationProblem;
use crate::error::Origin;
use crate::error::{Error, Result};
use crate::measurement::MeasurementModel;
use crate::measurement::data::Measurement;
use crate::mechanism::{Mechanism, Params};
use crate::units::Unit;

/// Smallest standard deviation accepted (mm or rad): no instrument is
/// better, and smaller ones only overflow the weights.
pub const MIN_SIGMA: f64 = crate::measurement::data::MIN_NOISE;

/// A pose whose measurement is grossly off ([`gross_errors`]).
pub(super) struct Gross {
    pub(super) origin: Origin,
    /// Its distance from the nominal prediction (mm).
    pub(super) distance: f64,
    /// The median pose's (mm).
    pub(super) median: f64,
}

/// A pose is a gross error when its readings (length axes) are more than
/// this many times the median pose's distance from the nominal prediction…
pub const GROSS_FACTOR: f64 = 50.0;
/// …and more than this share of the workspace's extent: far beyond what
/// parameter errors explain.
pub const GROSS_EXTENT_SHARE: f64 = 0.02;

/// Poses whose readings are grossly far from the nominal prediction (a free
/// frame registered first), worst first.
pub(super) fn gross_errors<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    start: &Params,
) -> Result<Vec<Gross>> {
    let spec = problem.mech.spec();
    let measurement = problem.measurement;
    let Ok(predicted) = problem.predict(start) else {
        return Ok(vec![]);
    };
    let Ok(m0) = measurement_start(problem, None, start, data) else {
        return Ok(vec![]);
    };
    let lengths: Vec<usize> = (0..measurement.len())
        .filter(|&a| measurement.units()[a] == Unit::Millimetre)
        .collect();
    if lengths.is_empty() || data.iter().filter(|d| d.partner.is_none()).count() < 4 {
        return Ok(vec![]);
    }
    let mut y = vec![0.0; measurement.len()];
    // Distances between poses are not positions: they are judged by the fit.
    let distance: Vec<f64> = predicted
        .iter()
        .zip(data)
        .filter(|(_, d)| d.partner.is_none())
        .map(|(x, d)| {
            measurement.observe_point(x, &m0, d.point.as_deref(), &mut y);
            lengths
                .iter()
                .map(|&a| (y[a] - d.measured[a]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    let mut sorted = distance.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let extent = spec
        .workspace_box
        .iter()
        .zip(&spec.tool_units)
        .filter(|(_, u)| **u == Unit::Millimetre)
        .map(|(b, _)| b[1] - b[0])
        .fold(0.0, f64::max);
    let limit = (GROSS_FACTOR * median).max(GROSS_EXTENT_SHARE * extent);
    let mut out: Vec<Gross> = distance
        .iter()
        .zip(data.iter().filter(|d| d.partner.is_none()))
        .filter(|(d, _)| **d > limit)
        .map(|(d, m)| Gross {
            origin: m.origin.expect("numbered"),
            distance: *d,
            median,
        })
        .collect();
    out.sort_by(|a, b| b.distance.total_cmp(&a.distance));
    Ok(out)
}

pub(super) fn check_sigma(measurement: &MeasurementModel, data: &[Measurement]) -> Result<()> {
    for m in data {
        let origin = m.origin.expect("numbered");
        let nx = measurement.row_len(m);
        if !(m.sigma.is_empty() || m.sigma.len() == nx) {
            return Err(Error::Dimension {
                what: "standard deviations of the measured coordinates".into(),
                expected: nx,
                got: m.sigma.len(),
            }
            .at_pose(origin));
        }
        if let Some((s, u)) = m
            .sigma
            .iter()
            .enumerate()
            .filter_map(|(a, s)| s.map(|s| (s, measurement.row_unit(m, a))))
            .find(|(s, u)| !(s.is_finite() && *s >= MIN_SIGMA && *s <= u.max_magnitude()))
        {
            return Err(Error::InvalidRequest(format!(
                "standard deviation {s:?} {u} must be a finite number between {MIN_SIGMA:e} and {:e}",
                u.max_magnitude()
            ))
            .at_pose(origin));
        }
    }
    Ok(())
}
