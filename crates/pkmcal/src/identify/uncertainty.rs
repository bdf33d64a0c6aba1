//! Uncertainty after a fit: the parameters' covariance scaled by the variance
//! of unit weight, and the predicted tool-position uncertainty at any pose.

use super::result::Calibration;
use crate::engine::models::{Model, Pose, Prediction, prepare_pose};
use crate::engine::sensitivity::sensitivity;
use crate::error::{Error, Result};
use crate::mechanism::{Mechanism, Params, Spec};
use nalgebra::DMatrix;
use serde::Serialize;

/// Covariance of identified parameters, by name: plain data that travels in
/// the calibration report (`covariance`) and back into `predict`.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct ParameterCovariance {
    /// Parameter names, in matrix order.
    pub names: Vec<String>,
    /// Covariance matrix (units² of the parameters), row by row.
    pub matrix: Vec<Vec<f64>>,
}

impl ParameterCovariance {
    /// Parameter indices and the matrix, checked against the mechanism. The
    /// instrument frame's parameters are left out (the marginal covariance
    /// of the mechanism's is the sub-matrix): predictions are in the base
    /// frame.
    pub fn resolve(&self, spec: &Spec) -> Result<(Vec<usize>, DMatrix<f64>)> {
        let n = self.names.len();
        if self.matrix.len() != n || self.matrix.iter().any(|r| r.len() != n) {
            return Err(Error::InvalidRequest(format!(
                "the covariance must be {n} × {n} for {n} names"
            )));
        }
        if self.matrix.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::InvalidRequest(
                "the covariance has non-finite entries".into(),
            ));
        }
        if let Some(a) = (0..n).find(|&a| self.matrix[a][a] < 0.0) {
            return Err(Error::InvalidRequest(format!(
                "the covariance gives `{}` a negative variance ({:e}); it is not a covariance",
                self.names[a], self.matrix[a][a]
            )));
        }
        for (a, name) in self.names.iter().enumerate() {
            if name.trim().is_empty() {
                return Err(Error::InvalidRequest(format!(
                    "the covariance's name {} is empty",
                    a + 1
                )));
            }
            if self.names[..a].contains(name) {
                return Err(Error::InvalidRequest(format!(
                    "the covariance names `{name}` twice"
                )));
            }
        }
        let frame = spec.tool_layout.frame_names();
        let keep: Vec<usize> = (0..n)
            .filter(|&a| !frame.contains(&self.names[a]))
            .collect();
        let idx = keep
            .iter()
            .map(|&a| spec.param_index(&self.names[a]))
            .collect::<Result<Vec<_>>>()?;
        Ok((
            idx,
            DMatrix::from_fn(keep.len(), keep.len(), |a, b| self.matrix[keep[a]][keep[b]]),
        ))
    }
}

/// Predicted tool position under `params` and its covariance (mm²) from the
/// parameters' covariance: `J_p C J_pᵀ` with the model's exact sensitivities.
pub fn tool_covariance<M: Mechanism>(
    mech: &M,
    pose: &Pose,
    params: &Params,
    model: Model,
    force: &[f64],
    covariance: &ParameterCovariance,
) -> Result<(Prediction, DMatrix<f64>)> {
    let (idx, c) = covariance.resolve(mech.spec())?;
    let s = sensitivity(mech, pose, params, model, force)?;
    let j = s.jacobian.select_columns(&idx);
    let cov = &j * c * j.transpose();
    // A covariance that overflows here, or is not positive semi-definite
    // enough to give non-negative variances, gives no standard deviation:
    // an error, never a σ of 0 or NaN.
    if let Some(a) = (0..cov.nrows()).find(|&a| !(cov[(a, a)].is_finite() && cov[(a, a)] >= 0.0)) {
        return Err(Error::InvalidRequest(format!(
            "the parameters' covariance gives tool coordinate {} a variance of {:e}; it is not a covariance of these parameters (check the report it came from)",
            a + 1,
            cov[(a, a)]
        )));
    }
    Ok((s.prediction, cov))
}

/// Predicted tool position and its covariance (mm²) at `commands`, from a
/// calibration's parameters and their covariance.
pub fn predict_with_uncertainty<M: Mechanism>(
    mech: &M,
    cal: &Calibration,
    commands: &[f64],
    force: &[f64],
) -> Result<(Vec<f64>, DMatrix<f64>)> {
    let pose = prepare_pose(mech, commands, None)?;
    let (p, cov) = tool_covariance(
        mech,
        &pose,
        &cal.params,
        cal.model,
        force,
        &cal.parameter_covariance,
    )?;
    Ok((p.x, cov))
}
