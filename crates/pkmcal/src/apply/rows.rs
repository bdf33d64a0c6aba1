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
                .map(|c| chained(mech, settings, c, &mut start))
                .collect();
            tick(chunk.len() as u64);
            out
        })
        .collect();
    chunks.into_iter().flatten().collect()
}

/// One row of a chunk: its prediction warm-started from `start` (the
/// configuration of the chunk's last row that succeeded), which it then
/// becomes.
fn chained<M: Mechanism>(
    mech: &M,
    settings: &RowSettings,
    commands: &[f64],
    start: &mut Option<Vec<f64>>,
) -> Result<RowPrediction> {
    let pose = match start
        .as_deref()
        .map(|s| prepare_pose(mech, commands, Some(s)))
    {
        Some(Ok(p)) => p,
        _ => prepare_pose(mech, commands, None)?,
    };
    let row = row_prediction(mech, settings, &pose)?;
    *start = Some(pose.nominal_q);
    Ok(row)
}

/// Where [`predict_rows_into`] writes each row's outputs, row after row
/// (`x`: one value per tool axis; `q`: per joint; `torque` and
/// `deflection`: per actuator; `covariance`: the tool axes squared). An
/// output left out is not kept (computed, then dropped): a front end asks
/// only for what it returns.
#[derive(Debug, Default)]
pub struct RowBuffers<'a> {
    /// Tool coordinates.
    pub x: Option<&'a mut [f64]>,
    /// Joint configurations.
    pub q: Option<&'a mut [f64]>,
    /// Internal actuator loads.
    pub torque: Option<&'a mut [f64]>,
    /// Deflections of the actuated joints.
    pub deflection: Option<&'a mut [f64]>,
    /// Tool covariances (with [`RowSettings::covariance`]), row-major.
    pub covariance: Option<&'a mut [f64]>,
}

/// One chunk's share of the [`RowBuffers`].
struct ChunkBuffers<'a> {
    rows: std::ops::Range<usize>,
    x: Option<&'a mut [f64]>,
    q: Option<&'a mut [f64]>,
    torque: Option<&'a mut [f64]>,
    deflection: Option<&'a mut [f64]>,
    covariance: Option<&'a mut [f64]>,
}

/// `buf` cut into pieces of `width` values per row, [`CHUNK_ROWS`] rows
/// each (one piece per chunk, `None` for every chunk when left out).
fn pieces(buf: Option<&mut [f64]>, width: usize, chunks: usize) -> Vec<Option<&mut [f64]>> {
    match buf {
        Some(b) if width > 0 => b.chunks_mut(CHUNK_ROWS * width).map(Some).collect(),
        _ => (0..chunks).map(|_| None).collect(),
    }
}

/// [`predict_rows`] writing into the caller's buffers instead of keeping
/// each row's prediction: `commands` holds the rows one after the other
/// (`n_actuated` values each), every buffer given holds as many rows. The
/// rows are chunked and warm-started as [`predict_rows`] does, so that the
/// values are the same. A row that fails (or holds a value that is not
/// finite) has NaN in every output and is returned with its error (row numbers from 0, in order); `cancel` stops
/// the work at the next row once set (each chunk stopped then reports
/// [`Error::Cancelled`] at its first row not done, and leaves the others
/// unwritten).
///
/// [`Error::Cancelled`]: crate::Error::Cancelled
pub fn predict_rows_into<M: Mechanism>(
    mech: &M,
    settings: &RowSettings,
    commands: &[f64],
    out: RowBuffers<'_>,
    cancel: Option<&std::sync::atomic::AtomicBool>,
) -> Vec<(usize, crate::Error)> {
    let spec = mech.spec();
    let width = spec.n_actuated();
    let n = commands.len().checked_div(width).unwrap_or(0);
    let (nx, nq, na) = (spec.tool_axes.len(), spec.joints.len(), width);
    let chunks = n.div_ceil(CHUNK_ROWS);
    let mut x = pieces(out.x, nx, chunks).into_iter();
    let mut q = pieces(out.q, nq, chunks).into_iter();
    let mut t = pieces(out.torque, na, chunks).into_iter();
    let mut d = pieces(out.deflection, na, chunks).into_iter();
    let mut c = pieces(out.covariance, nx * nx, chunks).into_iter();
    let work: Vec<ChunkBuffers> = (0..chunks)
        .map(|k| ChunkBuffers {
            rows: k * CHUNK_ROWS..((k + 1) * CHUNK_ROWS).min(n),
            x: x.next().flatten(),
            q: q.next().flatten(),
            torque: t.next().flatten(),
            deflection: d.next().flatten(),
            covariance: c.next().flatten(),
        })
        .collect();
    let failed: Vec<Vec<(usize, crate::Error)>> = work
        .into_par_iter()
        .map(|mut b| {
            let mut start: Option<Vec<f64>> = None;
            let mut failed = vec![];
            for (k, i) in b.rows.clone().enumerate() {
                let row = &commands[i * width..(i + 1) * width];
                if let Err(e) = crate::error::check_cancel(cancel) {
                    // The rest of the chunk is not done: one error says so.
                    failed.push((i, e));
                    break;
                }
                // A row with a missing value (NaN) is one that failed.
                let result = if row.iter().all(|v| v.is_finite()) {
                    chained(mech, settings, row, &mut start)
                } else {
                    Err(crate::Error::InvalidRequest(
                        "the commands hold a value that is not a finite number".into(),
                    ))
                };
                let put = |buf: &mut Option<&mut [f64]>, w: usize, v: Option<&[f64]>| {
                    if let Some(buf) = buf {
                        let slot = &mut buf[k * w..(k + 1) * w];
                        match v {
                            Some(v) => slot.copy_from_slice(v),
                            None => slot.fill(f64::NAN),
                        }
                    }
                };
                match result {
                    Ok(r) => {
                        let p = &r.prediction;
                        put(&mut b.x, nx, Some(&p.x));
                        put(&mut b.q, nq, Some(&p.q));
                        put(&mut b.torque, na, Some(&p.torque));
                        put(&mut b.deflection, na, Some(&p.deflection));
                        // Row-major, as the caller reads it.
                        let cov = r.covariance.as_ref().map(|m| {
                            (0..nx)
                                .flat_map(|j| (0..nx).map(move |l| m[(j, l)]))
                                .collect::<Vec<f64>>()
                        });
                        put(&mut b.covariance, nx * nx, cov.as_deref());
                    }
                    Err(e) => {
                        put(&mut b.x, nx, None);
                        put(&mut b.q, nq, None);
                        put(&mut b.torque, na, None);
                        put(&mut b.deflection, na, None);
                        put(&mut b.covariance, nx * nx, None);
                        failed.push((i, e));
                    }
                }
            }
            failed
        })
        .collect();
    failed.into_iter().flatten().collect()
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
