//! The identification least-squares problem (docs/model.md eq. 12): residuals
//! of the measurement model's predicted readings, their exact Jacobian, and
//! the caches that share poses and evaluations within one calibration.

use super::identifiability::{Columns, Identifiability};
use super::result::FinalPredictions;
use crate::engine::models::{
    Ahead, Model, Pose, Prediction, pose_ahead, predict_pose_warm_into, prepare_pose,
    prepare_pose_ahead,
};
use crate::engine::sensitivity::tool_sensitivity;
use crate::error::Origin;
use crate::error::{Error, Result};
use crate::lm::Problem;
use crate::measurement::data::Measurement;
use crate::measurement::{MeasurementModel, ObserveJacobian};
use crate::mechanism::{Mechanism, Params};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Parameters, residuals and Jacobian of the last Jacobian evaluation
/// (shared with [`IdentificationProblem::saved`], not copied).
type CachedJacobian = Arc<(Vec<f64>, DVector<f64>, DMatrix<f64>)>;

/// An identification problem's kept evaluations ([`IdentificationProblem::saved`]).
type Saved = (Option<CachedPredictions>, Option<CachedJacobian>);

/// Rows whose sensitivities are computed together (in parallel) and written
/// into the Jacobian before the next rows': the poses' sensitivities are
/// not all held at once.
const JACOBIAN_CHUNK: usize = 512;

/// Parameters and the predictions at every pose under them.
pub(super) type CachedPredictions = (Vec<f64>, Arc<Vec<Prediction>>);

/// One data row of an [`IdentificationProblem`]: a pose read by the
/// instrument, or two poses whose distance was measured.
#[derive(Debug, Clone, Copy)]
struct Row {
    /// Index of its (first) pose.
    first: usize,
    /// Index of the second pose of a distance.
    second: Option<usize>,
    /// Index of its first reading in the residual vector.
    offset: usize,
    /// Number of readings.
    len: usize,
}

/// Most measured rows one identification takes: it keeps each pose's
/// linearisation (7 kB a pose on the reference mechanism, 21 kB on a 6-leg
/// Gough–Stewart platform), so that memory stays within a few gigabytes.
pub const MAX_POSES: usize = 100_000;

/// The error for `n` rows, more than [`MAX_POSES`] (`n` may be a lower
/// bound: "more than").
pub fn too_many_poses(n: usize) -> Error {
    Error::InvalidRequest(format!(
        "{n} or more measured rows, more than one identification takes ({MAX_POSES}: it keeps each pose's linearisation, kilobytes each); thin the data evenly, a few hundred well-spread poses identify every parameter"
    ))
}

/// The identification least-squares problem: residuals are the readings
/// predicted by the measurement model minus those measured, row by row (a
/// row is a pose, or two poses whose distance was measured,
/// [`Measurement::partner`]). The parameter vector is the mechanism's
/// `[ρ, Δq, k]` followed by the measurement model's
/// ([`MeasurementModel::param_names`]).
pub struct IdentificationProblem<'a, M: Mechanism> {
    pub(super) mech: &'a M,
    pub(super) measurement: &'a MeasurementModel,
    /// Every pose: each row's first, then the second poses of distances
    /// (shared with the other problems of a calibration, [`PoseCache`]).
    poses: Vec<Arc<Pose>>,
    /// Where each pose came from (its row's origin).
    pose_origins: Vec<Origin>,
    rows: Vec<Row>,
    n_readings: usize,
    measured: Vec<Vec<f64>>,
    /// Each row's point of the tool body read ([`Measurement::point`]).
    points: Vec<Option<Vec<f64>>>,
    model: Model,
    force: Vec<f64>,
    /// The last parameters evaluated and their predictions: a Jacobian at an
    /// accepted trial point reuses them, and equilibria start from them
    /// (shared with the callers, not copied).
    cache: RefCell<Option<CachedPredictions>>,
    /// The predictions before the cache's, whose vectors the next
    /// evaluation writes into when no one else holds them (a fit's
    /// evaluations then allocate no prediction; not for a large problem,
    /// whose predictions are not held twice between evaluations).
    spare: RefCell<Option<Arc<Vec<Prediction>>>>,
    /// The last Jacobian evaluated, with its parameters.
    jacobian_cache: RefCell<Option<CachedJacobian>>,
    /// Readings × parameters at least [`crate::lm::LARGE_JACOBIAN`]: no
    /// Jacobian is kept between evaluations, and the solver's columns are
    /// written directly ([`IdentificationProblem::is_large`]).
    large: bool,
    /// Set from another thread to stop at the next pose
    /// ([`Error::Cancelled`]).
    cancel: Option<Arc<std::sync::atomic::AtomicBool>>,
    /// The cache its poses came from, shared with the other calibrations
    /// that use it (its identifiability analysis, [`PoseCache::analysis`]).
    pub(super) shared: Option<&'a PoseCache>,
}

/// Poses prepared once and shared by the identification problems of one
/// calibration (the gross-error screening, each reweighted fit, each refit
/// after an outlier is dropped), by their row's origin (and whether it is a
/// distance's second pose). Their nominal forward kinematics and joint
/// Hessians are then computed once per calibration; pass the same cache to
/// [`calibrate_with_cache`] and [`calibration_accuracy_with_cache`] to
/// compute them once for both.
///
/// It also keeps the last identifiability analysis made at a fit's start
/// ([`PoseCache::analysis`]): the runs of a Monte Carlo study start at the
/// same parameters with the same weights, where the Jacobian does not
/// depend on their truth or noise, and analyse the same matrix.
#[derive(Default)]
pub struct PoseCache {
    poses: Mutex<HashMap<PoseKey, CachedPose>>,
    analysis: Mutex<Option<Arc<KeptAnalysis>>>,
}

/// An identifiability analysis with everything it was a function of: the
/// weighted Jacobian, the columns' names, units, kinds and nominal values,
/// the parameters requested, the number of poses and `auto_fix`.
pub(super) struct KeptAnalysis {
    jacobian: DMatrix<f64>,
    columns: Columns,
    requested: Vec<usize>,
    poses: usize,
    auto_fix: bool,
    /// The analysis and the free set it left.
    pub(super) result: (Identifiability, Vec<usize>),
}

impl KeptAnalysis {
    /// Whether this analysis was made of the same inputs, bit for bit.
    fn is_for(
        &self,
        jacobian: &DMatrix<f64>,
        columns: &Columns,
        requested: &[usize],
        poses: usize,
        auto_fix: bool,
    ) -> bool {
        let bits = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        self.poses == poses
            && self.auto_fix == auto_fix
            && self.requested == requested
            && self.jacobian.shape() == jacobian.shape()
            && bits(self.jacobian.as_slice(), jacobian.as_slice())
            && self.columns.names == columns.names
            && self.columns.units == columns.units
            && self.columns.kinds == columns.kinds
            && bits(&self.columns.nominal, &columns.nominal)
    }
}

/// The commands a pose was prepared for, and the pose.
type CachedPose = (Vec<f64>, Arc<Pose>);

/// A row's origin, and whether the pose is a distance's second.
type PoseKey = (Origin, bool);

impl PoseCache {
    /// An empty cache.
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether `cache` holds the pose of `key` for these commands.
    fn holds(cache: Option<&Self>, key: PoseKey, commands: &[f64]) -> bool {
        cache.is_some_and(|c| {
            c.poses
                .lock()
                .expect("not poisoned")
                .get(&key)
                .is_some_and(|(c, _)| c == commands)
        })
    }

    /// A cached pose is used only for the same commands (a Monte Carlo
    /// study shares one cache between runs measuring the same plan).
    fn get_or_prepare(
        cache: Option<&Self>,
        key: PoseKey,
        commands: &[f64],
        prepare: impl FnOnce() -> Result<Pose>,
    ) -> Result<Arc<Pose>> {
        let Some(cache) = cache else {
            return prepare().map(Arc::new);
        };
        if let Some((c, p)) = cache.poses.lock().expect("not poisoned").get(&key)
            && c == commands
        {
            return Ok(p.clone());
        }
        let pose = Arc::new(prepare()?);
        cache
            .poses
            .lock()
            .expect("not poisoned")
            .insert(key, (commands.to_vec(), pose.clone()));
        Ok(pose)
    }
}

impl PoseCache {
    /// [`super::identifiability::analyze_identifiability`] of these inputs: the kept analysis when
    /// it was made of the same ones (then the same, bit for bit, as it is
    /// a function of them alone), else `analyze()`, kept for the next
    /// caller.
    pub(super) fn analysis(
        &self,
        jacobian: &DMatrix<f64>,
        columns: &Columns,
        requested: &[usize],
        poses: usize,
        auto_fix: bool,
    ) -> Option<(Identifiability, Vec<usize>)> {
        let kept = self.analysis.lock().expect("not poisoned").clone()?;
        kept.is_for(jacobian, columns, requested, poses, auto_fix)
            .then(|| kept.result.clone())
    }

    /// Keep `result`, the analysis of these inputs, for [`Self::analysis`].
    pub(super) fn keep_analysis(
        &self,
        jacobian: &DMatrix<f64>,
        columns: &Columns,
        requested: &[usize],
        poses: usize,
        auto_fix: bool,
        result: &(Identifiability, Vec<usize>),
    ) {
        *self.analysis.lock().expect("not poisoned") = Some(Arc::new(KeptAnalysis {
            jacobian: jacobian.clone(),
            columns: columns.clone(),
            requested: requested.to_vec(),
            poses,
            auto_fix,
            result: result.clone(),
        }));
    }
}

/// A row's readings: as many as the measurement model takes, finite and
/// within range (a distance only where the model measures distances).
fn check_row(measurement: &MeasurementModel, m: &Measurement) -> Result<()> {
    let origin = m.origin.expect("numbered");
    measurement.check_point(m).map_err(|e| e.at_pose(origin))?;
    let len = measurement.row_len(m);
    if let Some(partner) = &m.partner {
        measurement
            .check_distances()
            .map_err(|e| e.at_pose(origin))?;
        if *partner == m.commands {
            return Err(Error::InvalidRequest(
                "its two poses have the same commands: the distance between a pose and itself is always 0; check the pair".into(),
            )
            .at_pose(origin));
        }
        if m.measured.first().is_some_and(|d| *d < 0.0) {
            return Err(Error::InvalidRequest(format!(
                "the measured distance {:?} mm is negative; a distance is at least 0",
                m.measured[0]
            ))
            .at_pose(origin));
        }
    }
    if m.measured.len() != len {
        let what = if m.partner.is_some() {
            "readings (distance)".to_string()
        } else {
            format!("readings ({})", measurement.axes().join(" "))
        };
        return Err(Error::Dimension {
            what,
            expected: len,
            got: m.measured.len(),
        }
        .at_pose(origin));
    }
    for (a, v) in m.measured.iter().enumerate() {
        let (u, axis) = (measurement.row_unit(m, a), measurement.row_axis(m, a));
        if !(v.is_finite() && v.abs() <= u.max_magnitude()) {
            return Err(Error::InvalidRequest(format!(
                "measured `{axis}` = {v:?} {u} is not a finite value within ±{:e} {u}; check the measurement",
                u.max_magnitude()
            ))
            .at_pose(origin));
        }
    }
    Ok(())
}

impl<'a, M: Mechanism> IdentificationProblem<'a, M> {
    /// Prepare every pose (nominal configuration and linearisation).
    pub fn new(
        mech: &'a M,
        measurement: &'a MeasurementModel,
        data: &[Measurement],
        model: Model,
        force: &[f64],
    ) -> Result<Self> {
        Self::with_cache(mech, measurement, data, model, force, None)
    }

    /// [`IdentificationProblem::new`] that stops preparing its poses, and
    /// later evaluating them, at the next pose once `cancel` is set
    /// ([`Error::Cancelled`]).
    pub fn cancellable(
        mech: &'a M,
        measurement: &'a MeasurementModel,
        data: &[Measurement],
        model: Model,
        force: &[f64],
        cancel: Option<Arc<std::sync::atomic::AtomicBool>>,
    ) -> Result<Self> {
        let check = || crate::error::check_cancel(cancel.as_deref());
        check()?;
        let mut problem = Self::prepared(mech, measurement, data, model, force, None, &check)?;
        problem.cancel = cancel;
        Ok(problem)
    }

    /// [`IdentificationProblem::new`], taking the poses already prepared
    /// from `cache` and leaving the new ones there.
    pub(super) fn with_cache(
        mech: &'a M,
        measurement: &'a MeasurementModel,
        data: &[Measurement],
        model: Model,
        force: &[f64],
        cache: Option<&'a PoseCache>,
    ) -> Result<Self> {
        Self::prepared(mech, measurement, data, model, force, cache, &|| Ok(()))
    }

    /// The poses prepared, `check` called before each (its error stops).
    fn prepared(
        mech: &'a M,
        measurement: &'a MeasurementModel,
        data: &[Measurement],
        model: Model,
        force: &[f64],
        cache: Option<&'a PoseCache>,
        check: &(dyn Fn() -> Result<()> + Sync),
    ) -> Result<Self> {
        if data.len() > MAX_POSES {
            return Err(too_many_poses(data.len()));
        }
        let data = crate::measurement::data::numbered_cow(data);
        let mut poses: Vec<Arc<Pose>> = Vec::with_capacity(data.len());
        let mut pose_origins: Vec<Origin> = Vec::with_capacity(data.len());
        let mut rows: Vec<Row> = Vec::with_capacity(data.len());
        let mut offset = 0;
        let mut seconds: Vec<(usize, &[f64])> = vec![];
        // The rows checked first (the first that fails is reported after the
        // poses before it are prepared, as when each row was checked, then
        // prepared, in turn).
        let mut invalid = None;
        for (i, m) in data.iter().enumerate() {
            if let Err(e) = check_row(measurement, m) {
                invalid = Some((i, e));
                break;
            }
        }
        let valid = &data[..invalid.as_ref().map_or(data.len(), |(i, _)| *i)];
        // Each pose starts from the one before; what does not depend on that
        // start is done ahead, in parallel.
        let mut ahead: Vec<Option<Ahead>> = valid
            .par_iter()
            .with_min_len(crate::pose_chunk())
            .map(|m| {
                let key = (m.origin.expect("numbered"), false);
                if check().is_err() || PoseCache::holds(cache, key, &m.commands) {
                    None
                } else {
                    pose_ahead(mech, &m.commands)
                }
            })
            .collect();
        for (i, m) in valid.iter().enumerate() {
            check()?;
            let origin = m.origin.expect("numbered");
            let len = measurement.row_len(m);
            let start = poses.last().map(|p| p.nominal_q.clone());
            let pose = PoseCache::get_or_prepare(cache, (origin, false), &m.commands, || {
                prepare_pose_ahead(mech, &m.commands, start.as_deref(), ahead[i].take())
            })
            .map_err(|e| e.at_pose(origin))?;
            poses.push(pose);
            pose_origins.push(origin);
            if let Some(b) = &m.partner {
                seconds.push((i, b));
            }
            rows.push(Row {
                first: i,
                second: None,
                offset,
                len,
            });
            offset += len;
        }
        if let Some((_, e)) = invalid {
            return Err(e);
        }
        for (i, commands) in seconds {
            let origin = pose_origins[i];
            let pose = PoseCache::get_or_prepare(cache, (origin, true), commands, || {
                prepare_pose(mech, commands, Some(&poses[i].nominal_q))
            })
            .map_err(|e| e.at_pose(origin))?;
            rows[i].second = Some(poses.len());
            poses.push(pose);
            pose_origins.push(origin);
        }
        let large = offset.saturating_mul(mech.spec().n_params() + measurement.n_params())
            >= crate::lm::LARGE_JACOBIAN;
        // (Where the mechanism computes its joint Hessians cheaply.)
        if large && mech.joint_hessians_cheap() {
            for pose in &poses {
                pose.transient_hessians();
            }
        }
        Ok(Self {
            mech,
            measurement,
            poses,
            pose_origins,
            rows,
            n_readings: offset,
            measured: data.iter().map(|m| m.measured.clone()).collect(),
            points: data.iter().map(|m| m.point.clone()).collect(),
            model,
            force: force.to_vec(),
            cache: RefCell::new(None),
            spare: RefCell::new(None),
            jacobian_cache: RefCell::new(None),
            large,
            cancel: None,
            shared: cache,
        })
    }

    /// Whether the problem is large (readings × parameters at least
    /// [`crate::lm::LARGE_JACOBIAN`], e.g. 10,000 poses of a 6-DOF
    /// platform): its Jacobians are not kept between evaluations, the
    /// solver's columns are written without the full Jacobian, and a
    /// calibration analyses identifiability before fitting rather than
    /// alongside (one Jacobian in memory at a time, not four).
    pub fn is_large(&self) -> bool {
        self.large
    }

    /// Predictions at every pose, warm-started from (or taken from) the cache.
    fn predictions(&self, params: &Params) -> Result<Arc<Vec<Prediction>>> {
        let cached = self.cache.borrow();
        if let Some((x, p)) = cached.as_ref()
            && *x == params.values
        {
            return Ok(Arc::clone(p));
        }
        // Each pose warm-started from the last evaluation's prediction.
        let last: Option<&[Prediction]> = cached.as_ref().map(|(_, p)| p.as_slice());
        let n = self.poses.len();
        // Written into the spare predictions' vectors when no one else
        // holds them, else into the thread's pooled ones (the same numbers
        // as into new ones).
        let mut out = self
            .spare
            .take()
            .and_then(|mut p| {
                Arc::get_mut(&mut p)
                    .is_some_and(|v| v.len() == n)
                    .then_some(p)
            })
            .unwrap_or_else(|| Arc::new(pooled_predictions(n)));
        let (mech, model, force, origins) =
            (self.mech, self.model, &self.force, &self.pose_origins);
        let cancel = self.cancel.as_deref();
        // From scratch at nominal parameters (a calibration's start, the
        // accuracy before it): each pose's prediction is made once.
        let at_nominal = last.is_none() && params.values == mech.spec().nominal;
        // Poses in parallel (each independent and written in its place, so
        // the result does not depend on the threads).
        let done: Result<()> = Arc::get_mut(&mut out)
            .expect("held here alone")
            .par_iter_mut()
            .zip(self.poses.par_iter())
            .with_min_len(crate::pose_chunk())
            .enumerate()
            .try_for_each(|(i, (out, pose))| {
                crate::error::check_cancel(cancel)?;
                if at_nominal {
                    pose.predict_at_nominal_into(mech, params, model, force, out)
                } else {
                    let warm = last.map(|p| p[i].q.as_slice());
                    predict_pose_warm_into(mech, pose, params, model, force, warm, out)
                }
                .map_err(|e| e.at_pose(origins[i]))
            });
        drop(cached);
        let keep = !self.large;
        if let Err(e) = done {
            if keep {
                *self.spare.borrow_mut() = Some(out);
            }
            return Err(e);
        }
        let mut values = params.values.clone();
        let before = self.cache.replace(None);
        if let Some((mut v, p)) = before {
            v.clone_from(&params.values);
            values = v;
            if keep {
                *self.spare.borrow_mut() = Some(p);
            }
        }
        *self.cache.borrow_mut() = Some((values, Arc::clone(&out)));
        Ok(out)
    }

    /// The last predictions and Jacobian kept (they start the next
    /// evaluation), to be put back with [`Self::restore`] (shared, not
    /// copied).
    pub(super) fn saved(&self) -> Saved {
        (
            self.cache.borrow().clone(),
            self.jacobian_cache.borrow().clone(),
        )
    }

    /// Put back what [`Self::saved`] returned: the evaluations since then
    /// leave no trace in the next ones.
    pub(super) fn restore(&self, saved: Saved) {
        *self.cache.borrow_mut() = saved.0;
        *self.jacobian_cache.borrow_mut() = saved.1;
    }

    /// The prepared poses: each row's (first) pose in row order, then the
    /// second poses of the distance rows.
    pub fn poses(&self) -> &[Arc<Pose>] {
        &self.poses
    }

    /// The measurement model.
    pub fn measurement(&self) -> &MeasurementModel {
        self.measurement
    }

    /// Number of readings (residuals): the instrument's per pose row, one
    /// per distance row.
    pub fn n_readings(&self) -> usize {
        self.n_readings
    }

    /// Predicted tool coordinates (base frame) at each row's (first) pose
    /// under `params`.
    pub fn predict(&self, params: &Params) -> Result<Vec<Vec<f64>>> {
        let p = self.predictions(params)?;
        Ok(p[..self.rows.len()].iter().map(|p| p.x.clone()).collect())
    }

    /// The predictions cached at `params` (the fit's last evaluation, when
    /// it was there), with the poses, model and load they are for.
    pub(super) fn final_predictions(&self, params: &Params) -> Option<FinalPredictions> {
        let cached = self.cache.borrow();
        let (x, p) = cached.as_ref()?;
        (*x == params.values).then(|| FinalPredictions {
            poses: self.poses.clone(),
            model: self.model,
            force: self.force.clone(),
            predictions: (x.clone(), Arc::clone(p)),
        })
    }

    /// Take `known` as the last evaluation when it is for this problem's
    /// poses (the same prepared ones, or prepared alike: the same commands
    /// and nominal configurations, bit for bit), model and load, at
    /// `params`.
    pub(super) fn seed(&self, known: &FinalPredictions, params: &Params) {
        let alike = |a: &Arc<Pose>, b: &Arc<Pose>| {
            Arc::ptr_eq(a, b) || (a.commands == b.commands && a.nominal_q == b.nominal_q)
        };
        let same = known.poses.len() == self.poses.len()
            && known
                .poses
                .iter()
                .zip(&self.poses)
                .all(|(a, b)| alike(a, b))
            && known.model == self.model
            && known.force == self.force
            && known.predictions.0 == params.values;
        if same {
            *self.cache.borrow_mut() = Some(known.predictions.clone());
        }
    }

    /// Predicted distance of each row that pairs two poses (`None` for the
    /// other rows) under `params`.
    pub fn predict_distances(&self, params: &Params) -> Result<Vec<Option<f64>>> {
        let p = self.predictions(params)?;
        Ok(self
            .rows
            .iter()
            .map(|r| {
                r.second
                    .map(|b| self.measurement.distance(&p[r.first].x, &p[b].x))
            })
            .collect())
    }

    /// Split a full parameter vector into the mechanism's and the
    /// measurement model's.
    fn split(&self, x: &[f64]) -> Result<(Params, Vec<f64>)> {
        let n = self.mech.spec().n_params();
        let nm = self.measurement.n_params();
        if x.len() != n + nm {
            return Err(Error::Dimension {
                what: "identification parameter vector".into(),
                expected: n + nm,
                got: x.len(),
            });
        }
        Ok((
            Params::new(self.mech.spec(), x[..n].to_vec())?,
            x[n..].to_vec(),
        ))
    }

    /// Residuals (predicted minus measured readings) under a full parameter
    /// vector.
    pub fn residuals(&self, x: &[f64]) -> Result<DVector<f64>> {
        let (params, m) = self.split(x)?;
        let mut r = DVector::zeros(self.n_readings);
        let mut y = vec![0.0; self.measurement.len()];
        let predictions = self.predictions(&params)?;
        for ((row, measured), point) in self.rows.iter().zip(&self.measured).zip(&self.points) {
            let xa = &predictions[row.first].x;
            match row.second {
                Some(b) => {
                    r[row.offset] = self.measurement.distance(xa, &predictions[b].x) - measured[0];
                }
                None => {
                    self.measurement
                        .observe_point(xa, &m, point.as_deref(), &mut y);
                    for a in 0..row.len {
                        r[row.offset + a] = y[a] - measured[a];
                    }
                }
            }
        }
        Ok(r)
    }

    /// Residuals and the Jacobian (every parameter of the full vector):
    /// `∂h/∂x · ∂x/∂p` for the mechanism's, `∂h/∂m` for the model's; a
    /// distance row's is `∂d/∂x_a · ∂x_a/∂p + ∂d/∂x_b · ∂x_b/∂p`.
    pub fn residuals_and_jacobian(&self, x: &[f64]) -> Result<(DVector<f64>, DMatrix<f64>)> {
        if self.large {
            let all: Vec<usize> = (0..x.len()).collect();
            return self.assemble(x, &all, None);
        }
        let c = self.kept_jacobian(x)?;
        Ok((c.1.clone(), c.2.clone()))
    }

    /// Residuals and the whole Jacobian at `x`, kept for the next
    /// evaluation there (shared, not copied; not for a large problem).
    fn kept_jacobian(&self, x: &[f64]) -> Result<CachedJacobian> {
        if let Some(c) = self.jacobian_cache.borrow().as_ref()
            && c.0 == x
        {
            return Ok(Arc::clone(c));
        }
        let all: Vec<usize> = (0..x.len()).collect();
        let (r, j) = self.assemble(x, &all, None)?;
        let c = Arc::new((x.to_vec(), r, j));
        *self.jacobian_cache.borrow_mut() = Some(Arc::clone(&c));
        Ok(c)
    }

    /// Residuals and the Jacobian's columns `cols` (indices of the full
    /// parameter vector), row `i` multiplied by `weights[i]` when given:
    /// the same numbers as the full Jacobian's entries (times the weight),
    /// the rows' sensitivities computed [`JACOBIAN_CHUNK`] at a time.
    fn assemble(
        &self,
        x: &[f64],
        cols: &[usize],
        weights: Option<&[f64]>,
    ) -> Result<(DVector<f64>, DMatrix<f64>)> {
        let (params, m) = self.split(x)?;
        let np = self.mech.spec().n_params();
        let mut r = DVector::zeros(self.n_readings);
        let mut j = DMatrix::zeros(self.n_readings, cols.len());
        let predictions = self.predictions(&params)?;
        let (mech, model, force, origins, poses) = (
            self.mech,
            self.model,
            &self.force,
            &self.pose_origins,
            &self.poses,
        );
        let cancel = self.cancel.as_deref();
        // At nominal parameters (where every fit starts) each pose's
        // sensitivity is kept with it, for the next fit from there (a large
        // problem's poses keep no more than they must).
        let at_nominal = !self.large && params.values == mech.spec().nominal;
        // Each output column `k`'s value for an entry computed as `v`.
        let put = |j: &mut DMatrix<f64>, i: usize, v: &DMatrix<f64>, a: usize, first: usize| {
            for (k, &c) in cols.iter().enumerate() {
                if c >= first && c < first + v.ncols() {
                    j[(i, k)] = match weights {
                        Some(w) => v[(a, c - first)] * w[i],
                        None => v[(a, c - first)],
                    };
                }
            }
        };
        // A row's readings and derivatives, and `∂h/∂x · ∂x/∂p`, kept from
        // one row to the next.
        let mut observed = ObserveJacobian::default();
        let mut jx = DMatrix::zeros(0, 0);
        let mut first_row = 0;
        for chunk in self.rows.chunks(JACOBIAN_CHUNK) {
            // Poses in parallel, assembled in order.
            let idx: Vec<usize> = chunk
                .iter()
                .flat_map(|row| std::iter::once(row.first).chain(row.second))
                .collect();
            let sens: Vec<_> = idx
                .par_iter()
                .with_min_len(crate::pose_chunk())
                .map(|&i| {
                    crate::error::check_cancel(cancel)?;
                    let prediction = &predictions[i];
                    if at_nominal {
                        poses[i]
                            .tool_sensitivity_at_nominal(mech, &params, model, force, prediction)
                    } else {
                        tool_sensitivity(mech, &poses[i], &params, model, force, prediction)
                    }
                    .map_err(|e| e.at_pose(origins[i]))
                })
                .collect::<Result<Vec<_>>>()?;
            let mut at = 0;
            for ((row, measured), point) in chunk
                .iter()
                .zip(&self.measured[first_row..])
                .zip(&self.points[first_row..])
            {
                let (sa, xa) = (&sens[at], &predictions[idx[at]].x);
                at += 1;
                match row.second {
                    Some(_) => {
                        let (sb, xb) = (&sens[at], &predictions[idx[at]].x);
                        at += 1;
                        let (d, da, db) = self.measurement.distance_jacobian(xa, xb);
                        r[row.offset] = d - measured[0];
                        let ga = DMatrix::from_row_slice(1, da.len(), &da);
                        let gb = DMatrix::from_row_slice(1, db.len(), &db);
                        let jx = ga * sa + gb * sb;
                        put(&mut j, row.offset, &jx, 0, 0);
                    }
                    None => {
                        self.measurement.observe_point_jacobian_into(
                            xa,
                            &m,
                            point.as_deref(),
                            &mut observed,
                        );
                        let ObserveJacobian { y, dx, dm, .. } = &observed;
                        for a in 0..row.len {
                            r[row.offset + a] = y[a] - measured[a];
                        }
                        let (ny, nx, ns) = (dx.nrows(), dx.ncols(), sa.ncols());
                        if jx.shape() != (ny, ns) {
                            jx = DMatrix::zeros(ny, ns);
                        }
                        crate::linalg::product_into(
                            dx.as_slice(),
                            sa.as_slice(),
                            jx.as_mut_slice(),
                            ny,
                            nx,
                            ns,
                        );
                        for a in 0..row.len {
                            put(&mut j, row.offset + a, &jx, a, 0);
                            put(&mut j, row.offset + a, dm, a, np);
                        }
                    }
                }
            }
            first_row += chunk.len();
        }
        Ok((r, j))
    }

    /// Residuals and the Jacobian under the mechanism's `params` and the
    /// measurement model's nominal values.
    pub fn jacobian(&self, params: &Params) -> Result<(DVector<f64>, DMatrix<f64>)> {
        let x: Vec<f64> = params
            .values
            .iter()
            .chain(self.measurement.nominal())
            .copied()
            .collect();
        self.residuals_and_jacobian(&x)
    }
}

/// Most poses of a problem whose predictions go to the thread's pool when
/// it is dropped ([`SPARE_PREDICTIONS`]): a Monte Carlo run's hundred or
/// so, not a large calibration's.
const POOLED_POSES: usize = 1024;

/// Predictions pooled on a thread ([`SPARE_PREDICTIONS`]), at most.
const POOLED: usize = 2;

thread_local! {
    /// The predictions of the problems dropped on this thread (their last
    /// two evaluations'), whose vectors the next problem's first
    /// evaluations write into: a Monte Carlo run calibrates a new problem
    /// on the poses of the last.
    static SPARE_PREDICTIONS: RefCell<Vec<Vec<Prediction>>> = const { RefCell::new(Vec::new()) };
}

/// `n` predictions to write into: pooled ones when the thread has some
/// ([`SPARE_PREDICTIONS`]), else new ones.
fn pooled_predictions(n: usize) -> Vec<Prediction> {
    let pooled = SPARE_PREDICTIONS
        .try_with(|pool| pool.try_borrow_mut().ok()?.pop())
        .ok()
        .flatten();
    let mut p = pooled.unwrap_or_default();
    p.resize_with(n, Prediction::default);
    p
}

impl<M: Mechanism> Drop for IdentificationProblem<'_, M> {
    /// The last two evaluations' predictions go to the thread's pool when
    /// no one else holds them (for a problem of at most [`POOLED_POSES`]
    /// poses).
    fn drop(&mut self) {
        if self.poses.len() > POOLED_POSES {
            return;
        }
        let last = self.cache.get_mut().take().map(|(_, p)| p);
        let kept = [self.spare.get_mut().take(), last];
        // (Not when the thread is ending.)
        let _ = SPARE_PREDICTIONS.try_with(|pool| {
            let Ok(mut pool) = pool.try_borrow_mut() else {
                return;
            };
            for p in kept.into_iter().flatten() {
                if pool.len() < POOLED
                    && let Ok(p) = Arc::try_unwrap(p)
                {
                    pool.push(p);
                }
            }
        });
    }
}

impl<M: Mechanism> Problem for IdentificationProblem<'_, M> {
    fn n_params(&self) -> usize {
        self.mech.spec().n_params() + self.measurement.n_params()
    }
    fn n_residuals(&self) -> usize {
        self.n_readings
    }
    fn evaluate(
        &self,
        x: &[f64],
        jacobian: bool,
    ) -> std::result::Result<(DVector<f64>, Option<DMatrix<f64>>), String> {
        let (params, _) = self.split(x).map_err(|e| e.to_string())?;
        if params.stiffness().iter().any(|k| *k <= 0.0) {
            return Err("non-positive stiffness".into());
        }
        if jacobian {
            let (r, j) = self.residuals_and_jacobian(x).map_err(|e| e.to_string())?;
            return Ok((r, Some(j)));
        }
        Ok((self.residuals(x).map_err(|e| e.to_string())?, None))
    }
    fn jacobian_columns(
        &self,
        x: &[f64],
        free: &[usize],
        weights: Option<&[f64]>,
    ) -> std::result::Result<(DVector<f64>, DMatrix<f64>), String> {
        let (params, _) = self.split(x).map_err(|e| e.to_string())?;
        if params.stiffness().iter().any(|k| *k <= 0.0) {
            return Err("non-positive stiffness".into());
        }
        if !self.large {
            // The full Jacobian, kept for the next evaluation at `x`.
            let c = self.kept_jacobian(x).map_err(|e| e.to_string())?;
            let mut j = c.2.select_columns(free);
            if let Some(w) = weights {
                crate::lm::scale_rows(&mut j, w);
            }
            return Ok((c.1.clone(), j));
        }
        self.assemble(x, free, weights).map_err(|e| e.to_string())
    }
}

pub(super) fn mask(n: usize, free: &[usize]) -> Vec<bool> {
    let mut m = vec![false; n];
    for &i in free {
        m[i] = true;
    }
    m
}
