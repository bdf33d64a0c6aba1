//! Predictions of a sequence of command rows (a file's, an array's): the
//! one loop the command-line tool and the Python package share, each row's
//! result kept on its own so that a front end can stop at the first failure
//! or mark the row and go on.

use crate::engine::models::{Model, Prediction, predict_pose, prepare_pose};
use crate::error::Result;
use crate::identify::uncertainty::{ParameterCovariance, tool_covariance};
use crate::mechanism::{Mechanism, Params};
use nalgebra::DMatrix;
use rayon::prelude::*;

/// Rows per sequential chunk: each row of a chunk starts its forward
/// kinematics from the previous row's configuration (a neighbouring row is
/// usually one continuation stage away); the chunks run in parallel.
pub const CHUNK_ROWS: usize = 512;

/// What to predict for every row.
#[derive(Debug, Clone, Copy)]
pub struct RowSettings<'a> {
    /// Parameter values.
    pub params: &'a Params,
    /// Forward model.
    pub model: Model,
    /// External load on the tool (a wrench, [`crate::engine::load`]), empty
    /// for none.
    pub force: &'a [f64],
    /// The parameters' covariance, for each prediction's tool covariance.
    pub covariance: Option<&'a ParameterCovariance>,
}

/// One row's prediction and, with a parameter covariance, its tool
/// covariance (mm², rad²).
#[derive(Debug, Clone, PartialEq)]
pub struct RowPrediction {
    /// The prediction.
    pub prediction: Prediction,
    /// The tool covariance `J_p C J_pᵀ`, when a covariance was given.
    pub covariance: Option<DMatrix<f64>>,
}

/// Predict every row of `commands` (one command per actuator, internal
/// units), in parallel over chunks of [`CHUNK_ROWS`], each row warm-started
/// from the row before it that succeeded; `tick(n)` after each chunk of `n`
/// rows. Every row's result is its own: one row's failure (commands beyond
/// the workspace, another assembly branch) does not stop the others.
pub fn predict_rows<M: Mechanism>(
    mech: &M,
    settings: &RowSettings,
    commands: &[Vec<f64>],
    tick: &(dyn Fn(u64) + Sync),
) -> Vec<Result<RowPrediction>> {
    let chunks: Vec<Vec<Result<RowPrediction>>> = commands
        .par_chunks(CHUNK_ROWS)
        .map(|chunk| {
            let mut start: Option<Vec<f64>> = None;
            let out = chunk
                .iter()
                .map(|c| {
                    let pose = match start.as_deref().map(|s| prepare_pose(mech, c, Some(s))) {
                        Some(Ok(p)) => p,
                        _ => prepare_pose(mech, c, None)?,
                    };
                    let row = row_prediction(mech, settings, &pose)?;
                    start = Some(pose.nominal_q);
                    Ok(row)
                })
                .collect();
            tick(chunk.len() as u64);
            out
        })
        .collect();
    chunks.into_iter().flatten().collect()
}

fn row_prediction<M: Mechanism>(
    mech: &M,
    s: &RowSettings,
    pose: &crate::engine::models::Pose,
) -> Result<RowPrediction> {
    Ok(match s.covariance {
        None => RowPrediction {
            prediction: predict_pose(mech, pose, s.params, s.model, s.force)?,
            covariance: None,
        },
        Some(cov) => {
            let (prediction, c) = tool_covariance(mech, pose, s.params, s.model, s.force, cov)?;
            RowPrediction {
                prediction,
                covariance: Some(c),
            }
        }
    })
}
