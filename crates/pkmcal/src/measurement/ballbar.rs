//! The laser ball bar as it measures: distances from the tool ball to fixed
//! base sockets (paper §3: three readings per pose, trilateration).
//!
//! Two routes to calibration:
//! * [`trilaterate`] each pose's distances to a position (least squares, any
//!   number ≥ dimension + 1 of sockets, planar or 3-D) with its covariance, then
//!   calibrate on positions;
//! * calibrate directly on the distances with the ball-bar measurement model
//!   ([`crate::MeasurementModel::ball_bar`]), whose readings are the bar
//!   lengths `|b − s_j| + d`: the socket coordinates and the bar length offset
//!   `d` are its parameters (named `s1x s1y … dbar`), fixed by default and
//!   identifiable on request.

use crate::engine::newton::{self, LSTSQ_RCOND};
use crate::error::{Error, Result};
use nalgebra::{DMatrix, DVector};

/// Largest length accepted (mm).
const MAX: f64 = crate::units::MAX_LENGTH_MM;

/// Where the sockets are and what the bar reads.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Setup {
    /// Socket centre positions in the base frame (mm), one per distance.
    pub sockets: Vec<Vec<f64>>,
    /// Bar length offset `b` (mm): reading minus true ball–socket distance.
    pub bar_offset: f64,
}

impl Setup {
    /// Check the setup against a tool dimension.
    pub fn validate(&self, dim: usize) -> Result<()> {
        if self.sockets.len() < dim + 1 {
            return Err(Error::InvalidRequest(format!(
                "{} sockets given; trilateration in {dim} dimensions needs at least {}",
                self.sockets.len(),
                dim + 1
            )));
        }
        for (i, s) in self.sockets.iter().enumerate() {
            if s.len() != dim || s.iter().any(|v| !(v.is_finite() && v.abs() <= MAX)) {
                return Err(Error::InvalidRequest(format!(
                    "socket {} needs {dim} finite coordinates within ±{MAX:e} mm, got {s:?}",
                    i + 1
                )));
            }
        }
        if !(self.bar_offset.is_finite() && self.bar_offset.abs() <= MAX) {
            return Err(Error::InvalidRequest(format!(
                "the bar offset {:?} must be finite and within ±{MAX:e} mm",
                self.bar_offset
            )));
        }
        Ok(())
    }

    /// Bar readings for a tool position.
    pub fn distances(&self, x: &[f64]) -> Vec<f64> {
        self.sockets
            .iter()
            .map(|s| {
                s.iter()
                    .zip(x)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    .sqrt()
                    + self.bar_offset
            })
            .collect()
    }
}

/// Trilateration: the position whose distances to the sockets best match the
/// readings (Gauss–Newton on `|x − s_j| + b − d_j`, started at the socket
/// centroid pushed along +y… then refined), and its covariance for readings of
/// standard deviation `sigma` (mm): `σ² (JᵀJ)⁻¹`.
pub fn trilaterate(
    setup: &Setup,
    readings: &[f64],
    sigma: f64,
    guess: Option<&[f64]>,
) -> Result<(Vec<f64>, DMatrix<f64>)> {
    let k = setup.sockets.len();
    let dim = setup.sockets.first().map_or(0, Vec::len);
    setup.validate(dim)?;
    if readings.len() != k {
        return Err(Error::Dimension {
            what: "bar readings".into(),
            expected: k,
            got: readings.len(),
        });
    }
    if readings
        .iter()
        .any(|d| !(d.is_finite() && d.abs() <= MAX) || *d - setup.bar_offset <= 0.0)
    {
        return Err(Error::InvalidRequest(format!(
            "bar readings {readings:?} must be finite, within ±{MAX:e} mm and longer than the bar offset"
        )));
    }
    if !(sigma.is_finite() && sigma > 0.0 && sigma <= MAX) {
        return Err(Error::InvalidRequest(format!(
            "the reading noise σ = {sigma:?} must be a positive number of mm, at most {MAX:e}"
        )));
    }
    // Start: linearised solution (differences of squared distances), which
    // needs no guess; the caller's guess if given.
    let r: Vec<f64> = readings.iter().map(|d| d - setup.bar_offset).collect();
    let x: DVector<f64> = match guess {
        Some(g) => DVector::from_column_slice(g),
        None => {
            let s0 = &setup.sockets[0];
            let a = DMatrix::from_fn(k - 1, dim, |i, j| 2.0 * (setup.sockets[i + 1][j] - s0[j]));
            let b = DVector::from_fn(k - 1, |i, _| {
                let si = &setup.sockets[i + 1];
                r[0] * r[0] - r[i + 1] * r[i + 1] + si.iter().map(|v| v * v).sum::<f64>()
                    - s0.iter().map(|v| v * v).sum::<f64>()
            });
            lstsq(a, &b)?
        }
    };
    let mut jac = DMatrix::zeros(k, dim);
    // The position and the step; iterations that run out keep the last
    // position (the covariance below judges it).
    let mut state = (x, DVector::zeros(dim));
    newton::run(
        &newton::TRILATERATION,
        &mut state,
        |(x, step), _| -> Result<Option<newton::Step>> {
            let mut res = DVector::zeros(k);
            for (j, s) in setup.sockets.iter().enumerate() {
                let d = DVector::from_fn(dim, |i, _| x[i] - s[i]);
                let n = d.norm();
                if n == 0.0 {
                    return Err(Error::Singular {
                        q: x.iter().copied().collect(),
                        reason: format!("the ball sits on socket {}", j + 1),
                    });
                }
                res[j] = n - r[j];
                jac.row_mut(j).copy_from(&(d / n).transpose());
            }
            if !(res.iter().all(|v| v.is_finite()) && jac.iter().all(|v| v.is_finite())) {
                return Err(Error::InvalidRequest(format!(
                    "trilateration of {readings:?} diverged; check the readings and the socket positions"
                )));
            }
            *step = lstsq(jac.clone(), &res)?;
            // Undamped (no turn), a Gauss–Newton step in mm.
            Ok(Some(newton::Step {
                size: step.amax(),
                turn: 0.0,
            }))
        },
        |(x, step), scale| {
            for (x, s) in x.iter_mut().zip(step.iter()) {
                *x -= scale * s;
            }
        },
    )?;
    let x = state.0;
    let jtj = jac.transpose() * &jac;
    let cov = jtj.try_inverse().ok_or_else(|| Error::Singular {
        q: x.iter().copied().collect(),
        reason: "the sockets are aligned with the ball: trilateration is singular; move a socket"
            .into(),
    })? * (sigma * sigma);
    if !(x.iter().all(|v| v.is_finite()) && cov.iter().all(|v| v.is_finite())) {
        return Err(Error::Singular {
            q: x.iter().copied().collect(),
            reason: "the trilateration is numerically singular (sockets nearly aligned with the ball); move a socket".into(),
        });
    }
    Ok((x.iter().copied().collect(), cov))
}

/// The least-squares solution of `a x = b`, singular values below
/// [`LSTSQ_RCOND`] times the largest dropped.
fn lstsq(a: DMatrix<f64>, b: &DVector<f64>) -> Result<DVector<f64>> {
    let svd = a.svd(true, true);
    let eps = LSTSQ_RCOND * svd.singular_values.max();
    svd.solve(b, eps)
        .map_err(|e| Error::InvalidRequest(format!("trilateration failed: {e}")))
}
