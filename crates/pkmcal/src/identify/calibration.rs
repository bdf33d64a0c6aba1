//! Identification of parameter errors and encoder offsets (docs/model.md eq. 12):
//! minimise `Σ_i ‖x̂_i − h(c_i, p)‖²` over the free parameters with one of the
//! three forward models, with identifiability analysis before fitting,
//! uncertainty after, and validation on held-out poses.

use crate::engine::models::{
    Ahead, Model, Pose, Prediction, pose_ahead, predict_pose_warm, prepare_pose, prepare_pose_ahead,
};
use crate::engine::sensitivity::{sensitivity, sensitivity_at};
use crate::error::Origin;
use crate::error::{Error, Result};
use crate::identify::noise::{
    NoiseGroup, NoiseModel, VCE_MAX_ROUNDS, VCE_TOL, leverages, leverages_with,
};
use crate::identify::stats::{ErrorStats, error_stats, improvement_percent};
use crate::lm::{self, Problem, Termination};
use crate::measurement::data::{Measurement, numbered};
use crate::measurement::{Frame, MeasurementModel};
use crate::mechanism::{Mechanism, Params, Spec};
use crate::units::{ParamKind, Unit};
use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rayon::prelude::*;
use serde::Serialize;
use std::cell::RefCell;
use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

/// Singular values below this fraction of the largest (of the column-scaled
/// identification Jacobian) count as unidentifiable directions.
pub const RANK_TOL: f64 = 1e-8;
/// A Jacobian column whose effect is below this fraction of the largest counts
/// as zero (the parameter does not act on the tool at all).
pub const ZERO_COLUMN: f64 = 1e-10;
/// Correlations above this are reported.
pub const CORRELATION_REPORT: f64 = 0.9;
/// Components below this are left out of a named unidentifiable combination.
const COMBINATION_CUTOFF: f64 = 0.05;

/// How residuals are penalised (the robust loss; `ρ` is taken by the
/// parameters, hence `Loss`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "lowercase", tag = "kind", content = "scale")]
pub enum Loss {
    /// Ordinary least squares.
    Squared,
    /// Huber: quadratic within `k` robust standard deviations, linear beyond
    /// (k = 1.345 gives 95 % efficiency under Gaussian noise).
    Huber(f64),
    /// Cauchy: `log(1 + (u/c)²)` (c = 2.385 gives 95 % efficiency).
    Cauchy(f64),
}

impl Loss {
    /// Huber's default tuning constant (95 % efficiency under Gaussian noise).
    pub const HUBER_DEFAULT: f64 = 1.345;
    /// Cauchy's default tuning constant (95 % efficiency).
    pub const CAUCHY_DEFAULT: f64 = 2.385;

    /// The loss named `squared`, `huber` or `cauchy`, with the tuning
    /// constant `scale` (robust standard deviations; the default when
    /// `None`).
    pub fn named(name: &str, scale: Option<f64>) -> Result<Self> {
        if let Some(k) = scale
            && !(k.is_finite() && k > 0.0)
        {
            return Err(Error::InvalidRequest(format!(
                "the loss scale must be positive, got {k}"
            )));
        }
        match name {
            "squared" | "linear" => Ok(Loss::Squared),
            "huber" => Ok(Loss::Huber(scale.unwrap_or(Self::HUBER_DEFAULT))),
            "cauchy" => Ok(Loss::Cauchy(scale.unwrap_or(Self::CAUCHY_DEFAULT))),
            other => Err(Error::InvalidRequest(format!(
                "loss: unknown `{other}`; use \"squared\", \"huber\" or \"cauchy\""
            ))),
        }
    }

    /// IRLS weight `ψ(u)/u` of a standardised residual `u`.
    pub fn weight(self, u: f64) -> f64 {
        match self {
            Loss::Squared => 1.0,
            Loss::Huber(k) => {
                if u.abs() <= k {
                    1.0
                } else {
                    k / u.abs()
                }
            }
            Loss::Cauchy(c) => 1.0 / (1.0 + (u / c).powi(2)),
        }
    }
}

/// A pose whose residual is far beyond the noise.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Outlier {
    /// Where the pose came from (pose number, line).
    #[serde(flatten)]
    pub origin: Origin,
    /// Residual vector, predicted minus measured (per measured coordinate).
    pub residual: Vec<f64>,
    /// Unit of each residual.
    pub units: Vec<Unit>,
    /// Largest standardised residual of the pose: `|r/σ|` over its group's
    /// robust scale.
    pub standardized: f64,
}

/// Settings of a calibration.
#[derive(Debug, Clone)]
pub struct CalibrationOptions {
    /// Loss applied to the standardised residuals (iteratively reweighted).
    pub loss: Loss,
    /// Poses with a standardised residual above this are reported as outliers.
    pub outlier_threshold: f64,
    /// Drop the outliers and refit.
    pub drop_outliers: bool,
    /// Forward model used for identification.
    pub model: Model,
    /// Indices of the parameters to identify.
    pub free: Vec<usize>,
    /// External force applied to the tool during the measurements (N).
    pub force: Vec<f64>,
    /// Fix unidentifiable parameters automatically (with a warning).
    pub auto_fix: bool,
    /// Solver settings (tolerances, bounds; `free` and `weights` are set here).
    pub solver: lm::Options,
}

impl CalibrationOptions {
    /// The mechanism's default free set with the given model.
    pub fn new(spec: &Spec, model: Model) -> Self {
        Self {
            loss: Loss::Squared,
            outlier_threshold: 4.0,
            drop_outliers: false,
            model,
            free: spec
                .default_free
                .iter()
                .filter_map(|n| spec.param_index(n).ok())
                .collect(),
            force: vec![],
            auto_fix: true,
            solver: lm::Options {
                ftol: 1e-12,
                xtol: 1e-12,
                max_evaluations: 200,
                ..lm::Options::default()
            },
        }
    }
}

/// Parameters, residuals and Jacobian of the last Jacobian evaluation.
type CachedJacobian = (Vec<f64>, DVector<f64>, DMatrix<f64>);

/// An identification problem's kept evaluations ([`IdentificationProblem::saved`]).
type Saved = (Option<CachedPredictions>, Option<CachedJacobian>);

/// Parameters and the predictions at every pose under them.
type CachedPredictions = (Vec<f64>, Arc<Vec<Prediction>>);

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

/// The identification least-squares problem: residuals are the readings
/// predicted by the measurement model minus those measured, row by row (a
/// row is a pose, or two poses whose distance was measured,
/// [`Measurement::partner`]). The parameter vector is the mechanism's
/// `[ρ, Δq, k]` followed by the measurement model's
/// ([`MeasurementModel::param_names`]).
pub struct IdentificationProblem<'a, M: Mechanism> {
    mech: &'a M,
    measurement: &'a MeasurementModel,
    /// Every pose: each row's first, then the second poses of distances
    /// (shared with the other problems of a calibration, [`PoseCache`]).
    poses: Vec<Arc<Pose>>,
    /// Where each pose came from (its row's origin).
    pose_origins: Vec<Origin>,
    rows: Vec<Row>,
    n_readings: usize,
    measured: Vec<Vec<f64>>,
    model: Model,
    force: Vec<f64>,
    /// The last parameters evaluated and their predictions: a Jacobian at an
    /// accepted trial point reuses them, and equilibria start from them
    /// (shared with the callers, not copied).
    cache: RefCell<Option<CachedPredictions>>,
    /// The last Jacobian evaluated, with its parameters.
    jacobian_cache: RefCell<Option<CachedJacobian>>,
}

/// Poses prepared once and shared by the identification problems of one
/// calibration (the gross-error screening, each reweighted fit, each refit
/// after an outlier is dropped), by their row's origin (and whether it is a
/// distance's second pose). Their nominal forward kinematics and joint
/// Hessians are then computed once per calibration; pass the same cache to
/// [`calibrate_with_cache`] and [`calibration_accuracy_with_cache`] to
/// compute them once for both.
#[derive(Default)]
pub struct PoseCache(Mutex<HashMap<PoseKey, CachedPose>>);

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
            c.0.lock()
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
        if let Some((c, p)) = cache.0.lock().expect("not poisoned").get(&key)
            && c == commands
        {
            return Ok(p.clone());
        }
        let pose = Arc::new(prepare()?);
        cache
            .0
            .lock()
            .expect("not poisoned")
            .insert(key, (commands.to_vec(), pose.clone()));
        Ok(pose)
    }
}

/// A row's readings: as many as the measurement model takes, finite and
/// within range (a distance only where the model measures distances).
fn check_row(measurement: &MeasurementModel, m: &Measurement) -> Result<()> {
    let origin = m.origin.expect("numbered");
    let len = measurement.row_len(m);
    if m.partner.is_some() {
        measurement
            .check_distances()
            .map_err(|e| e.at_pose(origin))?;
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

    /// [`IdentificationProblem::new`], taking the poses already prepared
    /// from `cache` and leaving the new ones there.
    fn with_cache(
        mech: &'a M,
        measurement: &'a MeasurementModel,
        data: &[Measurement],
        model: Model,
        force: &[f64],
        cache: Option<&PoseCache>,
    ) -> Result<Self> {
        let data = numbered(data);
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
            .map(|m| {
                let key = (m.origin.expect("numbered"), false);
                if PoseCache::holds(cache, key, &m.commands) {
                    None
                } else {
                    pose_ahead(mech, &m.commands)
                }
            })
            .collect();
        for (i, m) in valid.iter().enumerate() {
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
        Ok(Self {
            mech,
            measurement,
            poses,
            pose_origins,
            rows,
            n_readings: offset,
            measured: data.iter().map(|m| m.measured.clone()).collect(),
            model,
            force: force.to_vec(),
            cache: RefCell::new(None),
            jacobian_cache: RefCell::new(None),
        })
    }

    /// Predictions at every pose, warm-started from (or taken from) the cache.
    fn predictions(&self, params: &Params) -> Result<Arc<Vec<Prediction>>> {
        let cached = self.cache.borrow();
        if let Some((x, p)) = cached.as_ref()
            && *x == params.values
        {
            return Ok(Arc::clone(p));
        }
        // Poses in parallel (each independent; assembled in order, so the
        // result does not depend on the threads).
        let warm: Vec<Option<&[f64]>> = (0..self.poses.len())
            .map(|i| cached.as_ref().map(|(_, p)| p[i].q.as_slice()))
            .collect();
        let (mech, model, force, origins) =
            (self.mech, self.model, &self.force, &self.pose_origins);
        // From scratch at nominal parameters (a calibration's start, the
        // accuracy before it): each pose's prediction is made once.
        let at_nominal = cached.is_none() && params.values == mech.spec().nominal;
        let out: Result<Vec<Prediction>> = self
            .poses
            .par_iter()
            .zip(warm.par_iter())
            .enumerate()
            .map(|(i, (pose, warm))| {
                if at_nominal {
                    pose.predict_at_nominal(mech, params, model, force)
                } else {
                    predict_pose_warm(mech, pose, params, model, force, *warm)
                }
                .map_err(|e| e.at_pose(origins[i]))
            })
            .collect();
        drop(cached);
        let out = Arc::new(out?);
        *self.cache.borrow_mut() = Some((params.values.clone(), Arc::clone(&out)));
        Ok(out)
    }

    /// The last predictions and Jacobian kept (they start the next
    /// evaluation), to be put back with [`Self::restore`].
    fn saved(&self) -> Saved {
        (
            self.cache.borrow().clone(),
            self.jacobian_cache.borrow().clone(),
        )
    }

    /// Put back what [`Self::saved`] returned: the evaluations since then
    /// leave no trace in the next ones.
    fn restore(&self, saved: Saved) {
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
    fn final_predictions(&self, params: &Params) -> Option<FinalPredictions> {
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
    fn seed(&self, known: &FinalPredictions, params: &Params) {
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
        for (row, measured) in self.rows.iter().zip(&self.measured) {
            let xa = &predictions[row.first].x;
            match row.second {
                Some(b) => {
                    r[row.offset] = self.measurement.distance(xa, &predictions[b].x) - measured[0];
                }
                None => {
                    self.measurement.observe(xa, &m, &mut y);
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
        if let Some((key, r, j)) = self.jacobian_cache.borrow().as_ref()
            && key == x
        {
            return Ok((r.clone(), j.clone()));
        }
        let (params, m) = self.split(x)?;
        let np = self.mech.spec().n_params();
        let nm = m.len();
        let mut r = DVector::zeros(self.n_readings);
        let mut j = DMatrix::zeros(self.n_readings, np + nm);
        let predictions = self.predictions(&params)?;
        // Poses in parallel, assembled in order.
        let (mech, model, force, origins) =
            (self.mech, self.model, &self.force, &self.pose_origins);
        let sens: Result<Vec<_>> = self
            .poses
            .par_iter()
            .zip(predictions.par_iter())
            .enumerate()
            .map(|(i, (pose, pred))| {
                sensitivity_at(mech, pose, &params, model, force, pred.clone())
                    .map_err(|e| e.at_pose(origins[i]))
            })
            .collect();
        let sens = sens?;
        for (row, measured) in self.rows.iter().zip(&self.measured) {
            let sa = &sens[row.first];
            match row.second {
                Some(b) => {
                    let sb = &sens[b];
                    let (d, da, db) = self
                        .measurement
                        .distance_jacobian(&sa.prediction.x, &sb.prediction.x);
                    r[row.offset] = d - measured[0];
                    let ga = DMatrix::from_row_slice(1, da.len(), &da);
                    let gb = DMatrix::from_row_slice(1, db.len(), &db);
                    let jx = ga * &sa.jacobian + gb * &sb.jacobian;
                    j.view_mut((row.offset, 0), (1, np)).copy_from(&jx);
                }
                None => {
                    let (y, dx, dm) = self.measurement.observe_jacobian(&sa.prediction.x, &m);
                    for a in 0..row.len {
                        r[row.offset + a] = y[a] - measured[a];
                    }
                    let jx = dx * &sa.jacobian;
                    j.view_mut((row.offset, 0), (row.len, np)).copy_from(&jx);
                    j.view_mut((row.offset, np), (row.len, nm)).copy_from(&dm);
                }
            }
        }
        *self.jacobian_cache.borrow_mut() = Some((x.to_vec(), r.clone(), j.clone()));
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
}

/// Observability indices of the column-scaled identification Jacobian with
/// singular values σ₁ ≥ … ≥ σ_L over m poses (Sun & Hollerbach, "Observability
/// index selection for robot calibration", ICRA 2008, which collects them):
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Observability {
    /// O1 = (σ₁⋯σ_L)^(1/L) / √m (Borm & Menq 1991): the volume of the error ellipsoid.
    pub o1: f64,
    /// O2 = σ_L / σ₁ (Driels & Pathre 1990): inverse condition number.
    pub o2: f64,
    /// O3 = σ_L (Nahvi, Hollerbach & Hayward 1994): minimum singular value.
    pub o3: f64,
    /// O4 = σ_L² / σ₁ (Nahvi & Hollerbach 1996): noise amplification index.
    pub o4: f64,
    /// O5 = 1 / Σ 1/σ_i (Sun & Hollerbach 2008): inverse of the summed variances.
    pub o5: f64,
}

/// A direction in parameter space the data cannot see.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Unidentifiable {
    /// The combination, e.g. `0.71·l11 − 0.71·B1x` (column-scaled units).
    pub combination: String,
    /// `(name, coefficient)` of the combination.
    pub terms: Vec<(String, f64)>,
    /// The parameter fixed to remove it (when fixing automatically).
    pub fixed: Option<String>,
}

/// A pair of strongly correlated parameters.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Correlation {
    /// First parameter.
    pub a: String,
    /// Second parameter.
    pub b: String,
    /// Correlation coefficient.
    pub r: f64,
}

/// Identifiability of the free parameters from the poses.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Identifiability {
    /// Free parameters analysed (names).
    pub free: Vec<String>,
    /// Singular values of the column-scaled Jacobian (descending).
    pub singular_values: Vec<f64>,
    /// Numerical rank.
    pub rank: usize,
    /// σ₁ / σ_L (infinite when rank deficient).
    pub condition_number: f64,
    /// Observability indices O1–O5 (over the identifiable part).
    pub observability: Observability,
    /// Unidentifiable directions.
    pub unidentifiable: Vec<Unidentifiable>,
    /// Pairs of free parameters correlated above 0.9.
    pub correlations: Vec<Correlation>,
}

pub(crate) fn observability(sv: &[f64], poses: usize) -> Observability {
    let l = sv.len().max(1) as f64;
    let last = sv.last().copied().unwrap_or(0.0);
    let first = sv.first().copied().unwrap_or(0.0);
    let logsum: f64 = sv.iter().map(|s| s.ln()).sum();
    Observability {
        o1: (logsum / l).exp() / (poses as f64).sqrt(),
        o2: if first > 0.0 { last / first } else { 0.0 },
        o3: last,
        o4: if first > 0.0 {
            last * last / first
        } else {
            0.0
        },
        o5: 1.0 / sv.iter().map(|s| 1.0 / s).sum::<f64>(),
    }
}

/// The columns of an identification Jacobian: each parameter's name, unit,
/// kind and typical size (its nominal value, for judging whether a column
/// acts at all).
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// Names, in column order.
    pub names: Vec<String>,
    /// Units.
    pub units: Vec<Unit>,
    /// Kinds.
    pub kinds: Vec<ParamKind>,
    /// Nominal values.
    pub nominal: Vec<f64>,
}

impl Columns {
    /// The mechanism's parameters.
    pub fn of(spec: &Spec) -> Self {
        let n = spec.n_params();
        Self {
            names: spec.param_names().iter().map(|s| s.to_string()).collect(),
            units: (0..n).map(|i| spec.param_unit(i)).collect(),
            kinds: (0..n).map(|i| spec.param_kind(i)).collect(),
            nominal: spec.nominal.clone(),
        }
    }

    /// The mechanism's parameters, then the measurement model's (`values`:
    /// theirs at the start).
    pub fn with_measurement(spec: &Spec, measurement: &MeasurementModel, values: &[f64]) -> Self {
        let mut c = Self::of(spec);
        c.names.extend(measurement.param_names().iter().cloned());
        c.units.extend(measurement.param_units());
        c.kinds
            .extend(std::iter::repeat_n(ParamKind::Instrument, values.len()));
        c.nominal.extend(values);
        c
    }
}

fn correlations(cols: &Columns, free: &[usize], cov: &DMatrix<f64>) -> Vec<Correlation> {
    let names = &cols.names;
    let mut out = vec![];
    for a in 0..free.len() {
        for b in a + 1..free.len() {
            let d = (cov[(a, a)] * cov[(b, b)]).sqrt();
            if d > 0.0 {
                let r = cov[(a, b)] / d;
                if r.abs() > CORRELATION_REPORT {
                    out.push(Correlation {
                        a: names[free[a]].to_string(),
                        b: names[free[b]].to_string(),
                        r,
                    });
                }
            }
        }
    }
    out
}

/// Analyse the identifiability of `free` from the full identification
/// Jacobian `jac` (weighted): scale every column to unit norm, take the SVD,
/// name each direction below [`RANK_TOL`]. With `auto_fix`, fix one parameter
/// per unidentifiable direction (the one that dominates it) until the rest
/// has full rank. Returns the analysis and the remaining free set.
pub fn analyze_identifiability(
    cols: &Columns,
    jac: &DMatrix<f64>,
    free: &[usize],
    poses: usize,
    auto_fix: bool,
) -> (Identifiability, Vec<usize>) {
    let names: Vec<&str> = cols.names.iter().map(String::as_str).collect();
    let mut free = free.to_vec();
    let mut unidentifiable = vec![];
    let mut first_sv: Option<Vec<f64>> = None;
    loop {
        if free.is_empty() {
            let ident = Identifiability {
                free: vec![],
                singular_values: first_sv.unwrap_or_default(),
                rank: 0,
                condition_number: f64::INFINITY,
                observability: observability(&[], poses),
                unidentifiable,
                correlations: vec![],
            };
            return (ident, free);
        }
        let sub = jac.select_columns(&free);
        // A column counts as zero when its effect over a typical parameter
        // change (its nominal size, or 1 unit) is negligible next to the
        // largest one: round-off must not be scaled up into a direction.
        let effect: Vec<f64> = free
            .iter()
            .enumerate()
            .map(|(k, &i)| sub.column(k).norm() * cols.nominal[i].abs().max(1.0))
            .collect();
        let biggest = effect.iter().copied().fold(0.0, f64::max);
        let norms: Vec<f64> = (0..free.len())
            .map(|k| {
                if effect[k] > ZERO_COLUMN * biggest {
                    sub.column(k).norm()
                } else {
                    0.0
                }
            })
            .collect();
        let (singular_values, vt, factored) = scaled_svd(&sub, &norms);
        let mut order: Vec<usize> = (0..singular_values.len()).collect();
        order.sort_by(|&a, &b| singular_values[b].total_cmp(&singular_values[a]));
        let sv: Vec<f64> = order.iter().map(|&i| singular_values[i]).collect();
        if first_sv.is_none() {
            first_sv = Some(sv.clone());
        }
        let smax = sv.first().copied().unwrap_or(0.0);
        // Directions: zero columns, then small singular values.
        let mut dirs: Vec<Vec<f64>> = norms
            .iter()
            .enumerate()
            .filter(|(_, n)| **n == 0.0)
            .map(|(k, _)| {
                let mut v = vec![0.0; free.len()];
                v[k] = 1.0;
                v
            })
            .collect();
        if dirs.is_empty() {
            for &i in &order {
                if singular_values[i] <= RANK_TOL * smax {
                    dirs.push(vt.row(i).iter().copied().collect());
                }
            }
        }
        if dirs.is_empty() || !auto_fix {
            for d in &dirs {
                unidentifiable.push(direction(&names, &free, d, None));
            }
            let rank = sv.iter().filter(|s| **s > RANK_TOL * smax).count();
            let kept: Vec<f64> = sv[..rank].to_vec();
            let cov = if rank == free.len() {
                let (c, _) = match &factored {
                    Some((qr, ipvt, rdiag)) => lm::covariance_of(qr, ipvt, rdiag, 1e-14),
                    None => lm::covariance(&sub, 1e-14),
                };
                correlations(cols, &free, &c)
            } else {
                vec![]
            };
            let all_sv = first_sv.unwrap_or_default();
            let cond = if rank == all_sv.len() && rank > 0 {
                all_sv[0] / all_sv[rank - 1]
            } else {
                f64::INFINITY
            };
            let ident = Identifiability {
                free: free.iter().map(|&i| names[i].to_string()).collect(),
                rank: all_sv
                    .iter()
                    .filter(|s| **s > RANK_TOL * all_sv.first().copied().unwrap_or(0.0))
                    .count(),
                condition_number: cond,
                observability: observability(&kept, poses),
                singular_values: all_sv,
                unidentifiable,
                correlations: cov,
            };
            return (ident, free);
        }
        let k = fix_choice(cols, &free, &dirs);
        // Report the direction that fixing `k` removes: the one it takes the
        // most part in (with zero columns, that parameter alone).
        let d = dirs
            .iter()
            .reduce(|a, b| if b[k].abs() > a[k].abs() { b } else { a })
            .expect("non-empty");
        unidentifiable.push(direction(
            &names,
            &free,
            d,
            Some(names[free[k]].to_string()),
        ));
        free.remove(k);
    }
}

/// A pivoted QR of a Jacobian ([`lm::qrfac`]: factors, column order, R's
/// diagonal).
type Factored = (DMatrix<f64>, Vec<usize>, Vec<f64>);

/// The singular values and right singular vectors (`Vᵀ`, one row per
/// value) of `sub` with each column `k` divided by `norms[k]` (left as it is
/// where that is 0), and the pivoted QR they came from. With at least as
/// many rows as columns, from `sub`'s QR: `sub P = Q R` makes the scaled
/// matrix `Q (R D⁻¹) Pᵀ` (`D` the norms in pivot order), whose singular
/// values and right vectors are those of the square `R D⁻¹`, columns put
/// back in order — an SVD of `n × n` instead of `m × n`, and the QR serves
/// the covariance. With fewer rows, zero rows make the matrix square, so
/// that the SVD also gives the null space (as many zero singular values as
/// missing rows, each with its direction).
fn scaled_svd(sub: &DMatrix<f64>, norms: &[f64]) -> (Vec<f64>, DMatrix<f64>, Option<Factored>) {
    let (m, n) = sub.shape();
    let divisor = |k: usize| if norms[k] > 0.0 { norms[k] } else { 1.0 };
    if m < n {
        let mut scaled = sub.clone();
        for k in 0..n {
            scaled.column_mut(k).unscale_mut(divisor(k));
        }
        let scaled = scaled.insert_rows(m, n - m, 0.0);
        let svd = scaled.svd(false, true);
        let vt = svd.v_t.expect("requested");
        return (svd.singular_values.iter().copied().collect(), vt, None);
    }
    let mut qr = sub.clone();
    let (ipvt, rdiag, _) = lm::qrfac(&mut qr);
    let rs = DMatrix::from_fn(n, n, |i, k| {
        let v = match i.cmp(&k) {
            std::cmp::Ordering::Less => qr[(i, k)],
            std::cmp::Ordering::Equal => rdiag[k],
            std::cmp::Ordering::Greater => 0.0,
        };
        v / divisor(ipvt[k])
    });
    let svd = rs.svd(false, true);
    let vt_pivoted = svd.v_t.expect("requested");
    let mut vt = DMatrix::zeros(vt_pivoted.nrows(), n);
    for (k, &c) in ipvt.iter().enumerate() {
        vt.set_column(c, &vt_pivoted.column(k));
    }
    let sv = svd.singular_values.iter().copied().collect();
    (sv, vt, Some((qr, ipvt, rdiag)))
}

/// Which free parameter (position in `free`) to fix for the unidentifiable
/// directions `dirs`: the mechanism's parameters before the instrument's (a
/// free instrument frame leaves the base frame to be defined by the
/// mechanism, e.g. `B2y = 0`), and among them the one that the space of
/// directions involves most (the largest row of an orthonormal basis of the
/// directions restricted to them; unlike "the largest entry of the first
/// direction", this does not depend on how the solver picked the basis, nor
/// on where the instrument stands).
fn fix_choice(cols: &Columns, free: &[usize], dirs: &[Vec<f64>]) -> usize {
    let preferred: Vec<usize> = (0..free.len())
        .filter(|&k| cols.kinds[free[k]] != ParamKind::Instrument)
        .collect();
    if !preferred.is_empty() {
        let d = DMatrix::from_fn(preferred.len(), dirs.len(), |r, c| dirs[c][preferred[r]]);
        let svd = d.svd(true, false);
        let smax = svd.singular_values.max();
        if smax > COMBINATION_CUTOFF {
            let u = svd.u.expect("requested");
            let keep: Vec<usize> = (0..svd.singular_values.len())
                .filter(|&j| svd.singular_values[j] > 1e-6 * smax)
                .collect();
            let weight = |r: usize| keep.iter().map(|&j| u[(r, j)].powi(2)).sum::<f64>();
            let r = (0..preferred.len())
                .max_by(|&a, &b| weight(a).total_cmp(&weight(b)))
                .expect("non-empty");
            return preferred[r];
        }
    }
    let d = &dirs[0];
    (0..d.len())
        .max_by(|&a, &b| d[a].abs().total_cmp(&d[b].abs()))
        .expect("non-empty")
}

fn direction(names: &[&str], free: &[usize], d: &[f64], fixed: Option<String>) -> Unidentifiable {
    let big = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let sign = d
        .iter()
        .find(|v| v.abs() == big)
        .map_or(1.0, |v| v.signum());
    let mut terms: Vec<(String, f64)> = d
        .iter()
        .enumerate()
        .filter(|(_, v)| v.abs() >= COMBINATION_CUTOFF * big)
        .map(|(k, v)| (names[free[k]].to_string(), sign * v))
        .collect();
    terms.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let combination = terms
        .iter()
        .enumerate()
        .map(|(i, (n, c))| {
            let s = if *c < 0.0 {
                " − "
            } else if i > 0 {
                " + "
            } else {
                ""
            };
            format!("{s}{:.3}·{n}", c.abs())
        })
        .collect::<String>();
    Unidentifiable {
        combination,
        terms,
        fixed,
    }
}

/// One row of the parameter table.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ParameterResult {
    /// Name.
    pub name: String,
    /// Unit of the values (declared by the mechanism).
    pub unit: Unit,
    /// Role of the parameter (geometry, encoder offset, stiffness, instrument).
    pub kind: ParamKind,
    /// Nominal value.
    pub nominal: f64,
    /// Identified value (the starting value if fixed).
    pub identified: f64,
    /// Identified minus nominal.
    pub change: f64,
    /// Standard deviation (0 when fixed).
    pub std_dev: f64,
    /// Whether it was identified.
    pub free: bool,
    /// Why it is fixed, when it was requested free.
    pub note: Option<String>,
}

/// What a warning is about, with its data: the CLI and other callers match on
/// the kind, never on the message.
#[derive(Debug, Clone, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum WarningKind {
    /// All stiffness parameters were free without an external load: only
    /// their ratios are identifiable, so `fixed` was fixed.
    StiffnessRatios {
        /// The stiffness fixed.
        fixed: String,
    },
    /// A direction of parameter space that the data cannot see.
    Unidentifiable {
        /// Model used.
        model: Model,
        /// The combination, e.g. `0.71·l11 − 0.71·B1x`.
        combination: String,
        /// The parameter fixed to remove it, if any.
        fixed: Option<String>,
    },
    /// The instrument frame is identified and, with it, parameters that
    /// also place the mechanism in space (e.g. base joint centres): the
    /// directions that only move everything together are unidentifiable, and
    /// `fixed` were fixed to remove them (they then define the base frame).
    FrameGauge {
        /// Model used.
        model: Model,
        /// The parameters fixed, one per direction.
        fixed: Vec<String>,
        /// Directions that no parameter could remove (none when fixing).
        unfixed: usize,
    },
    /// The fit did not converge.
    NotConverged {
        /// The solver's reason.
        reason: String,
    },
    /// The Jacobian at the solution is rank deficient.
    RankDeficient {
        /// Its rank.
        rank: usize,
        /// Free parameters.
        free: usize,
    },
    /// Poses with residuals beyond the outlier threshold at the final fit.
    Outliers {
        /// Where they came from.
        poses: Vec<Origin>,
        /// The threshold (robust standard deviations).
        threshold: f64,
        /// Whether a robust loss was in use.
        robust_loss: bool,
        /// Whether dropping was requested (and stopped at the cap).
        dropping: bool,
    },
    /// Poses dropped as outliers before the final fit.
    Dropped {
        /// Where they came from.
        poses: Vec<Origin>,
    },
}

/// A warning: its kind (with data), what happened and what to do.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Warning {
    /// What it is about.
    #[serde(flatten)]
    pub kind: WarningKind,
    /// What happened.
    pub message: String,
    /// What to do.
    pub hint: String,
}

fn pose_list(poses: &[Origin]) -> String {
    poses
        .iter()
        .map(Origin::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

impl Warning {
    /// The warning of `kind`, with its message and hint.
    pub fn new(kind: WarningKind) -> Self {
        let (message, hint) = match &kind {
            WarningKind::StiffnessRatios { fixed } => (
                format!(
                    "all stiffness parameters are free without an external load: only their ratios are identifiable, so `{fixed}` is fixed at its starting value"
                ),
                format!(
                    "give `{fixed}` its measured value (--start), or calibrate with a known tool load"
                ),
            ),
            WarningKind::Unidentifiable {
                model,
                combination,
                fixed,
            } => (
                match fixed {
                    Some(f) => format!(
                        "unidentifiable with the {} model: {combination} (fixed `{f}` at its starting value)",
                        model.name()
                    ),
                    None => format!("unidentifiable with the {} model: {combination}", model.name()),
                },
                "these parameters cannot be separated by these measurements at these poses; fix one of them, or add poses or measurements that see them".into(),
            ),
            WarningKind::FrameGauge {
                model,
                fixed,
                unfixed,
            } => (
                format!(
                    "the instrument frame is identified together with parameters that also place the mechanism: {} directions move both together and are unidentifiable with the {} model{}",
                    fixed.len() + unfixed,
                    model.name(),
                    if fixed.is_empty() {
                        String::new()
                    } else {
                        format!(
                            "; fixed {} at their starting values (they now define the base frame)",
                            fixed
                                .iter()
                                .map(|f| format!("`{f}`"))
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    }
                ),
                "to choose which parameters define the base frame, fix them yourself (--fix), or measure in the base frame (--frame base); the combinations are listed under identifiability".into(),
            ),
            WarningKind::NotConverged { reason } => (
                format!("the fit did not converge: {reason}"),
                "check the data for outliers or wrong columns, or start closer".into(),
            ),
            WarningKind::RankDeficient { rank, free } => (
                format!(
                    "the Jacobian at the solution has rank {rank} for {free} free parameters; their uncertainties are not defined"
                ),
                "fix parameters named in the identifiability report".into(),
            ),
            WarningKind::Outliers {
                poses,
                threshold,
                robust_loss,
                dropping,
            } => (
                format!(
                    "{} pose(s) with residuals beyond {threshold} robust standard deviations: {}",
                    poses.len(),
                    pose_list(poses)
                ),
                if *dropping {
                    "the drop limit (20 % of the poses) is reached; inspect these measurements".into()
                } else if *robust_loss {
                    "the robust loss already limits their influence; inspect them, or refit without them (--drop-outliers)".into()
                } else {
                    "inspect them; a robust loss (huber, cauchy) limits their influence, dropping refits without them".into()
                },
            ),
            WarningKind::Dropped { poses } => (
                format!(
                    "{} outlier pose(s) dropped before the final fit: {}",
                    poses.len(),
                    pose_list(poses)
                ),
                "check those measurements (a misread, a bumped instrument) before trusting the result".into(),
            ),
        };
        Self {
            kind,
            message,
            hint,
        }
    }
}

/// Everything a calibration produces.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// Model used.
    pub model: Model,
    /// Identified parameters of the mechanism (full vector).
    #[serde(skip)]
    pub params: Params,
    /// Identified (or given) pose of the instrument frame in the base frame
    /// ([`crate::measurement::frame`]); `None` when the data are in the base frame. Also
    /// in `parameters`, kind `instrument`.
    pub frame: Option<Vec<f64>>,
    /// Identified (or given) values of all the measurement model's
    /// parameters ([`MeasurementModel::param_names`]), the frame's last.
    #[serde(skip)]
    pub measurement: Vec<f64>,
    /// Why the solver stopped.
    pub termination: Termination,
    /// Readable reason.
    pub termination_reason: String,
    /// Whether it converged.
    pub converged: bool,
    /// Solver iterations (of the final fit).
    pub iterations: usize,
    /// Residual evaluations (of the final fit).
    pub evaluations: usize,
    /// Number of poses (rows read by the instrument).
    pub poses: usize,
    /// Number of distances measured between two poses.
    pub distances: usize,
    /// Sum of squared standardised residuals `Σ (r/σ)²` at the solution.
    pub sum_of_squares: f64,
    /// Standard deviation of unit weight `√(Σ (r/σ)² / (m − n))`
    /// (dimensionless): about 1 when the noise levels are right.
    pub unit_weight_sigma: f64,
    /// Noise of each group of like coordinates: estimated from the residuals
    /// or given in the data.
    pub noise: Vec<NoiseGroup>,
    /// Parameter table.
    pub parameters: Vec<ParameterResult>,
    /// Identifiability (at the starting parameters, or where the actuators
    /// fight when stiffness is free; see [`calibrate`]).
    pub identifiability: Identifiability,
    /// Covariance of the free parameters (scaled by the unit-weight
    /// variance), in `free` order.
    #[serde(skip)]
    pub covariance: DMatrix<f64>,
    /// Free parameter indices actually identified.
    #[serde(skip)]
    pub free: Vec<usize>,
    /// The covariance with parameter names (serialised as `covariance`).
    #[serde(rename = "covariance")]
    pub parameter_covariance: ParameterCovariance,
    /// Correlations above 0.9 at the solution.
    pub correlations: Vec<Correlation>,
    /// Loss used.
    pub loss: Loss,
    /// Poses with residuals beyond the outlier threshold: those dropped (with
    /// their residual when they were dropped), then those left in the final
    /// fit.
    pub outliers: Vec<Outlier>,
    /// Poses dropped as outliers before the final fit.
    pub dropped: Vec<Origin>,
    /// Residuals at the solution, predicted minus measured, pose-major (each
    /// in its axis's unit).
    #[serde(skip)]
    pub residuals: Vec<f64>,
    /// Standard deviation each residual was weighted with (same order).
    #[serde(skip)]
    pub sigmas: Vec<f64>,
    /// Weighted Jacobian of the free parameters at the solution.
    #[serde(skip)]
    pub jacobian: DMatrix<f64>,
    /// Warnings.
    pub warnings: Vec<Warning>,
    /// The fit's predictions at the identified parameters, when its last
    /// evaluation was there: [`calibration_accuracy_with_cache`] then
    /// computes them no second time.
    #[serde(skip)]
    pub(crate) final_predictions: Option<FinalPredictions>,
}

/// A calibration's predictions at its identified parameters and what they
/// were computed for: the prepared poses (shared through a [`PoseCache`]),
/// the model and the load.
#[derive(Debug, Clone)]
pub(crate) struct FinalPredictions {
    poses: Vec<Arc<Pose>>,
    model: Model,
    force: Vec<f64>,
    predictions: CachedPredictions,
}

/// Largest share of the poses that dropping outliers may remove.
pub const MAX_DROPPED_FRACTION: f64 = 0.2;

/// Identify the free parameters from measurements (eq. 12), starting from
/// `start` (usually nominal).
///
/// Weighting: each measured coordinate is weighted by 1/σ, its known σ
/// ([`Measurement::sigma`]) or its group's, estimated from the residuals
/// ([`crate::identify::noise`]): lengths and angles each get their own.
/// With a robust [`Loss`], iteratively reweighted least squares: standardise
/// the residuals by their group's robust scale, reweight by `ψ(u)/u`, refit,
/// until the weights settle. Poses beyond `outlier_threshold` are reported;
/// with `drop_outliers` the worst is removed and the fit repeated, until none
/// is left or [`MAX_DROPPED_FRACTION`] of the poses are gone.
pub fn calibrate<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    calibrate_with_cache(mech, measurement, data, start, opts, &PoseCache::default())
}

/// [`calibrate`] with the poses prepared in `cache` (those missing are
/// prepared and left there).
pub fn calibrate_with_cache<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    cache: &PoseCache,
) -> Result<Calibration> {
    crate::on_pool(|| calibrate_on(mech, measurement, data, start, opts, cache))
}

/// [`calibrate_with_cache`] on the calling thread.
fn calibrate_on<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    cache: &PoseCache,
) -> Result<Calibration> {
    let data = numbered(data);
    check_sigma(measurement, &data)?;
    let cap = (data.len() as f64 * MAX_DROPPED_FRACTION).floor() as usize;
    let mut kept = data;
    let mut dropped: Vec<Origin> = vec![];
    let mut found: Vec<Outlier> = vec![];
    // Gross errors (a misread, a swapped column) would drag the first,
    // unweighted fit to parameters where poses cannot be assembled: find
    // them first, drop them when asked to, name them otherwise.
    // One identification problem per set of poses: its last predictions
    // start the next evaluation's equilibria, from the screening to the last
    // refit.
    let problem_of = |kept: &[Measurement]| {
        IdentificationProblem::with_cache(
            mech,
            measurement,
            kept,
            opts.model,
            &opts.force,
            Some(cache),
        )
    };
    let mut problem = problem_of(&kept)?;
    for g in gross_errors(&problem, &kept, start)? {
        if !opts.drop_outliers || dropped.len() >= cap {
            return Err(Error::InvalidRequest(format!(
                "the measurement is {:.4e} mm from the nominal prediction, where the median pose is {:.4e} mm: a gross error (a misread, a swapped column, another pose's row); fix or remove it, or calibrate with --drop-outliers",
                g.distance, g.median
            ))
            .at_pose(g.origin));
        }
        kept.retain(|m| m.origin != Some(g.origin));
        dropped.push(g.origin);
    }
    if !dropped.is_empty() {
        problem = problem_of(&kept)?;
    }
    loop {
        let mut cal = calibrate_weighted(&problem, &kept, start, opts)?;
        let more = opts.drop_outliers && !cal.outliers.is_empty() && dropped.len() < cap;
        if !more {
            if !dropped.is_empty() {
                cal.warnings.push(Warning::new(WarningKind::Dropped {
                    poses: dropped.clone(),
                }));
            }
            if !cal.outliers.is_empty() {
                cal.warnings.push(Warning::new(WarningKind::Outliers {
                    poses: cal.outliers.iter().map(|o| o.origin).collect(),
                    threshold: opts.outlier_threshold,
                    robust_loss: opts.loss != Loss::Squared,
                    dropping: opts.drop_outliers,
                }));
            }
            cal.dropped = dropped;
            found.append(&mut cal.outliers);
            cal.outliers = found;
            cal.final_predictions = problem.final_predictions(&cal.params);
            return Ok(cal);
        }
        // Drop the worst pose only, then refit: one gross error can make its
        // neighbours look bad (masking), and a second one can hide behind it.
        let worst = cal
            .outliers
            .iter()
            .max_by(|a, b| a.standardized.total_cmp(&b.standardized))
            .expect("not empty")
            .clone();
        kept.retain(|m| m.origin != Some(worst.origin));
        dropped.push(worst.origin);
        found.push(worst);
        problem = problem_of(&kept)?;
    }
}

/// Smallest standard deviation accepted (mm or rad): no instrument is
/// better, and smaller ones only overflow the weights.
pub const MIN_SIGMA: f64 = 1e-12;

/// A pose whose measurement is grossly off ([`gross_errors`]).
struct Gross {
    origin: Origin,
    /// Its distance from the nominal prediction (mm).
    distance: f64,
    /// The median pose's (mm).
    median: f64,
}

/// A pose is a gross error when its readings (length axes) are more than
/// this many times the median pose's distance from the nominal prediction…
pub const GROSS_FACTOR: f64 = 50.0;
/// …and more than this share of the workspace's extent: far beyond what
/// parameter errors explain.
pub const GROSS_EXTENT_SHARE: f64 = 0.02;

/// Poses whose readings are grossly far from the nominal prediction (a free
/// frame registered first), worst first.
fn gross_errors<M: Mechanism>(
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
            measurement.observe(x, &m0, &mut y);
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

fn check_sigma(measurement: &MeasurementModel, data: &[Measurement]) -> Result<()> {
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

/// One weighted fit: noise groups estimated, robust reweighting, outliers.
fn calibrate_weighted<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
) -> Result<Calibration> {
    let measurement = problem.measurement;
    let mut noise = NoiseModel::new(data, measurement);
    // `(JᵀJ)⁺` of `cal.jacobian` (the fit's own, for the leverages) while
    // that Jacobian is the fit's.
    let (mut cal, cov) = calibrate_once(
        problem,
        data,
        start,
        None,
        opts,
        &noise.sigmas(),
        None,
        None,
    )?;
    // The free set and identifiability of the first fit hold for the refits.
    let mut refit_opts = opts.clone();
    refit_opts.auto_fix = false;
    let mut cov = Some(cov);
    let refit = |cal: &Calibration, sigma: &[f64]| -> Result<(Calibration, DMatrix<f64>)> {
        let (mut next, cov) = calibrate_once(
            problem,
            data,
            &cal.params,
            Some(&cal.measurement),
            &refit_opts,
            sigma,
            Some(&cal.free),
            Some(&cal.identifiability),
        )?;
        next.identifiability = cal.identifiability.clone();
        for (p, first) in next.parameters.iter_mut().zip(&cal.parameters) {
            p.note = first.note.clone();
        }
        // Identifiability warnings from the first fit, the solver's from
        // this one.
        let solver_kind = |w: &Warning| {
            matches!(
                w.kind,
                WarningKind::NotConverged { .. } | WarningKind::RankDeficient { .. }
            )
        };
        let mut warnings: Vec<Warning> = cal
            .warnings
            .iter()
            .filter(|w| !solver_kind(w))
            .cloned()
            .collect();
        warnings.extend(next.warnings.drain(..).filter(solver_kind));
        next.warnings = warnings;
        Ok((next, cov))
    };
    let lev = |cal: &Calibration, cov: &Option<DMatrix<f64>>| match cov {
        Some(c) => leverages_with(&cal.jacobian, c),
        None => leverages(&cal.jacobian),
    };
    if noise.estimated_groups() > 0 {
        // One estimated group and nothing given: the weights are uniform
        // whatever its σ, so one estimate after the fit is exact.
        let uniform = noise.estimated_groups() == 1 && !noise.any_given();
        if uniform {
            let h = lev(&cal, &cov);
            noise.update(&cal.residuals, &h);
            rescale(&mut cal, &noise.sigmas());
            cov = None;
        } else {
            // Iterate the estimates on the fit linearised at the current
            // solution (the reweighted solution moves by a fraction of the
            // noise, where the problem is linear), then refit once with them;
            // repeat while the refit still moves the estimates.
            for _ in 0..VCE_MAX_REFITS {
                linearized_vce(&mut noise, &cal);
                let (next, c) = refit(&cal, &noise.sigmas())?;
                (cal, cov) = (next, Some(c));
                let mut check = noise.clone();
                if check.update(&cal.residuals, &lev(&cal, &cov)) < VCE_TOL {
                    break;
                }
            }
        }
    }
    let base = noise.sigmas();
    let keys = noise.keys();
    if opts.loss != Loss::Squared {
        let mut robust = vec![1.0; base.len()];
        for _ in 0..MAX_REWEIGHTS {
            let u = standardized(&cal.residuals, &base, &keys);
            let next: Vec<f64> = u.iter().map(|ui| opts.loss.weight(*ui)).collect();
            let change = next
                .iter()
                .zip(&robust)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            robust = next;
            let sigma: Vec<f64> = base
                .iter()
                .zip(&robust)
                .map(|(s, w)| s / w.max(f64::MIN_POSITIVE).sqrt())
                .collect();
            let (next, c) = refit(&cal, &sigma)?;
            (cal, cov) = (next, Some(c));
            if change < 1e-3 {
                break;
            }
        }
        // Report robust noise levels: the outliers must not inflate them.
        let scales = group_scales(&cal.residuals, &base, &keys);
        for (g, s) in noise.sigma.iter_mut().enumerate() {
            if let Some(f) = scales.get(&g).filter(|f| **f > 0.0) {
                *s *= f;
            }
        }
    }
    // Studentised: a pose that pulls the fit towards itself (high leverage)
    // shows a small residual for a large error.
    let h = lev(&cal, &cov);
    let student: Vec<f64> = base
        .iter()
        .zip(&h)
        .map(|(s, hi)| s * (1.0 - hi).max(1e-6).sqrt())
        .collect();
    let u = standardized(&cal.residuals, &student, &keys);
    cal.outliers = find_outliers(
        measurement,
        data,
        &cal.residuals,
        &u,
        opts.outlier_threshold,
    );
    cal.noise = noise.report(&cal.residuals);
    cal.loss = opts.loss;
    Ok(cal)
}

/// Refits of the noise estimation (each after a linearised estimation).
const VCE_MAX_REFITS: usize = 4;

/// Variance-component estimation on the fit linearised at `cal`'s solution:
/// residuals `r0 + J δp(σ)` with `δp` the weighted least-squares step under
/// the current σ, iterated until the σ settle.
fn linearized_vce(noise: &mut NoiseModel, cal: &Calibration) {
    // Unweighted Jacobian of the free parameters.
    let mut j = cal.jacobian.clone();
    lm::scale_rows(&mut j, &cal.sigmas);
    let r0 = DVector::from_column_slice(&cal.residuals);
    for _ in 0..VCE_MAX_ROUNDS {
        let s = noise.sigmas();
        let mut jw = j.clone();
        let mut rw = r0.clone();
        lm::unscale_rows(&mut jw, &s);
        for (ri, si) in rw.iter_mut().zip(&s) {
            *ri /= si;
        }
        let (c, _) = lm::covariance(&jw, 1e-12);
        let step = -(&c * (jw.transpose() * &rw));
        let r = &r0 + &j * &step;
        let h = leverages_with(&jw, &c);
        if noise.update(r.as_slice(), &h) < VCE_TOL {
            break;
        }
    }
}

/// Scale a calibration's weighted quantities to new uniform-ratio σ: the
/// solution is unchanged (all weights scale alike), the statistics follow.
fn rescale(cal: &mut Calibration, sigma: &[f64]) {
    let f = sigma
        .first()
        .map_or(1.0, |s| cal.sigmas.first().map_or(1.0, |o| o / s));
    cal.sum_of_squares *= f * f;
    cal.unit_weight_sigma *= f;
    cal.jacobian.scale_mut(f);
    cal.sigmas = sigma.to_vec();
}

/// Reweighting rounds of the robust fit.
const MAX_REWEIGHTS: usize = 20;

/// Residuals below this (mm) are never outliers: on noise-free data the
/// robust scale is round-off and would flag round-off.
pub const OUTLIER_FLOOR_MM: f64 = 1e-6;
/// [`OUTLIER_FLOOR_MM`] for angles (rad).
pub const OUTLIER_FLOOR_RAD: f64 = 1e-8;

/// Robust scale (1.4826 × median |r/σ|) of each group of residuals.
fn group_scales(r: &[f64], sigma: &[f64], keys: &[usize]) -> BTreeMap<usize, f64> {
    let mut scale = BTreeMap::new();
    for &k in keys {
        if scale.contains_key(&k) {
            continue;
        }
        let mut v: Vec<f64> = r
            .iter()
            .zip(sigma)
            .zip(keys)
            .filter(|(_, g)| **g == k)
            .map(|((a, s), _)| (a / s).abs())
            .collect();
        v.sort_by(f64::total_cmp);
        scale.insert(k, 1.4826 * v[v.len() / 2]);
    }
    scale
}

/// `|r/σ| / s_g` with `s_g` the robust scale of the residual's group:
/// lengths and angles are judged each against their own.
fn standardized(r: &[f64], sigma: &[f64], keys: &[usize]) -> Vec<f64> {
    let scale = group_scales(r, sigma, keys);
    r.iter()
        .zip(sigma)
        .zip(keys)
        .map(|((a, s), k)| {
            let g = scale[k];
            if g > 0.0 { (a / s).abs() / g } else { 0.0 }
        })
        .collect()
}

fn find_outliers(
    measurement: &MeasurementModel,
    data: &[Measurement],
    r: &[f64],
    u: &[f64],
    threshold: f64,
) -> Vec<Outlier> {
    let mut offset = 0;
    data.iter()
        .filter_map(|m| {
            let n = measurement.row_len(m);
            let (ri, ui) = (&r[offset..offset + n], &u[offset..offset + n]);
            offset += n;
            let units: Vec<Unit> = (0..n).map(|a| measurement.row_unit(m, a)).collect();
            let floor = |k: usize| match units[k] {
                Unit::Radian => OUTLIER_FLOOR_RAD,
                _ => OUTLIER_FLOOR_MM,
            };
            let worst = (0..n)
                .filter(|&k| ri[k].abs() > floor(k))
                .map(|k| ui[k])
                .fold(0.0, f64::max);
            (worst > threshold && worst.is_finite()).then(|| Outlier {
                origin: m.origin.expect("numbered"),
                residual: ri.to_vec(),
                units,
                standardized: worst,
            })
        })
        .collect()
}

/// One least-squares fit with the residuals weighted by 1/`sigma`, from the
/// mechanism's `start` and the measurement model's `m_given` (default: its
/// nominal values, the frame registered when free).
#[allow(clippy::too_many_arguments)]
fn calibrate_once<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    data: &[Measurement],
    start: &Params,
    m_given: Option<&[f64]>,
    opts: &CalibrationOptions,
    sigma: &[f64],
    exact_free: Option<&[usize]>,
    known: Option<&Identifiability>,
) -> Result<(Calibration, DMatrix<f64>)> {
    let (mech, measurement) = (problem.mech, problem.measurement);
    let spec = mech.spec();
    let nx = measurement.len();
    let np = spec.n_params();
    let mut warnings = vec![];
    let frame_free = *measurement.frame() == Frame::Free;
    if opts.free.is_empty() && !frame_free {
        return Err(Error::InvalidRequest(
            "no parameter is free; free at least one with --free".into(),
        ));
    }
    if let Some(&i) = opts
        .free
        .iter()
        .find(|&&i| i >= np + measurement.n_params())
    {
        return Err(Error::InvalidRequest(format!(
            "free parameter index {i} is out of range: the mechanism has {np} parameters and the measurement model {}",
            measurement.n_params()
        )));
    }
    let n_free_frame = if frame_free {
        measurement.frame_range().len()
    } else {
        0
    };
    let m: usize = data.iter().map(|d| measurement.row_len(d)).sum();
    let n_requested = exact_free.map_or(opts.free.len() + n_free_frame, <[usize]>::len);
    if m <= n_requested {
        return Err(Error::InvalidRequest(format!(
            "{} {} give {m} readings for {n_requested} free parameters{}; measure more poses (at least {}) or identify fewer parameters (--free NAMES, --fix NAMES){}",
            data.len(),
            if data.iter().any(|d| d.partner.is_some()) {
                "rows"
            } else {
                "poses"
            },
            if n_free_frame > 0 {
                " (with the instrument frame's)"
            } else {
                ""
            },
            n_requested / nx + 1,
            if nx < spec.tool_axes.len() {
                format!(
                    "; {} alone cannot see every parameter of the default set: `analyze` names the combinations they cannot separate",
                    measurement.axes().join(", ")
                )
            } else {
                String::new()
            }
        )));
    }
    let m0 = measurement_start(problem, m_given, start, data)?;
    let nf = m0.len();
    let cols = Columns::with_measurement(spec, measurement, &m0);
    let mut requested = opts.free.clone();
    if frame_free {
        requested.extend(measurement.frame_range().map(|i| np + i));
    }
    if let Some(f) = exact_free {
        requested = f.to_vec();
    }
    if sigma.len() != m || sigma.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(Error::InvalidRequest(
            "one positive finite standard deviation per measured coordinate is needed".into(),
        ));
    }
    let weights: Vec<f64> = sigma.iter().map(|v| 1.0 / v).collect();
    let stiff: Vec<usize> = (spec.n_geometric() + spec.n_actuated()..np).collect();
    let unloaded = opts.force.iter().all(|f| *f == 0.0);
    if opts.auto_fix && unloaded && !stiff.is_empty() && stiff.iter().all(|k| requested.contains(k))
    {
        // Only the ratios act without a load: fix exactly one.
        let k = stiff[0];
        requested.retain(|&i| i != k);
        warnings.push(Warning::new(WarningKind::StiffnessRatios {
            fixed: cols.names[k].clone(),
        }));
    }
    let weigh = |mut jac: DMatrix<f64>| -> Result<DMatrix<f64>> {
        lm::scale_rows(&mut jac, &weights);
        if jac.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidRequest(
                "the weighted identification Jacobian is not finite: a standard deviation is too small for the values measured; check the sigma columns and the data".into(),
            ));
        }
        Ok(jac)
    };
    let mut x0: Vec<f64> = start.values.iter().chain(&m0).copied().collect();
    // Identifiability at the start.
    let (_, jac) = problem.residuals_and_jacobian(&x0)?;
    let weighted = weigh(jac)?;
    let mut solver = opts.solver.clone();
    solver.weights = Some(weights.clone());
    // The fit of the requested parameters, computed while identifiability is
    // analysed (on another thread) and kept when the analysis frees them all
    // (as it usually does); stopped, and its evaluations undone, when it
    // fixes one.
    let mut speculative = None;
    let analyze = |jac: &DMatrix<f64>| {
        analyze_identifiability(&cols, jac, &requested, data.len(), opts.auto_fix)
    };
    let (mut identifiability, mut free) = match known {
        // A refit keeps the first fit's analysis (its free set is `exact_free`).
        Some(ident) if !opts.auto_fix => (ident.clone(), requested.clone()),
        // The caller's own cancel flag governs every fit: no speculation.
        _ if opts.solver.cancel.is_some() => analyze(&weighted),
        _ => {
            let saved = problem.saved();
            let cancel = Arc::new(AtomicBool::new(false));
            let mut fit = solver.clone();
            fit.free = Some(mask(np + nf, &requested));
            fit.cancel = Some(cancel.clone());
            let mut analysis = None;
            let report = rayon::in_place_scope(|s| {
                s.spawn(|_| {
                    let a = analyze(&weighted);
                    if a.1 != requested {
                        cancel.store(true, Ordering::Relaxed);
                    }
                    analysis = Some(a);
                });
                lm::minimize(problem, &x0, &fit)
            });
            let (ident, free) = analysis.expect("the scope waits for the analysis");
            if free == requested {
                speculative = Some(report);
            } else {
                problem.restore(saved);
            }
            (ident, free)
        }
    };
    // Stiffness acts only where the actuators fight, which they do not at
    // nominal parameters: judge its identifiability where they do, at the
    // solution without it.
    let idle: Vec<usize> = stiff
        .iter()
        .copied()
        .filter(|k| requested.contains(k) && !free.contains(k))
        .collect();
    if opts.auto_fix && !idle.is_empty() && !free.is_empty() {
        let mut fit = solver.clone();
        fit.free = Some(mask(np + nf, &free));
        x0 = lm::minimize(problem, &x0, &fit).x;
        let (_, jac) = problem.residuals_and_jacobian(&x0)?;
        (identifiability, free) = analyze(&weigh(jac)?);
    }
    // Directions that move the instrument frame with the mechanism are one
    // matter (the gauge), said once.
    let (gauge, other): (Vec<&Unidentifiable>, Vec<&Unidentifiable>) = identifiability
        .unidentifiable
        .iter()
        .partition(|u| frame_free && u.terms.iter().any(|(n, _)| n.starts_with("frame.")));
    if !gauge.is_empty() {
        warnings.push(Warning::new(WarningKind::FrameGauge {
            model: opts.model,
            fixed: gauge.iter().filter_map(|u| u.fixed.clone()).collect(),
            unfixed: gauge.iter().filter(|u| u.fixed.is_none()).count(),
        }));
    }
    for u in other {
        warnings.push(Warning::new(WarningKind::Unidentifiable {
            model: opts.model,
            combination: u.combination.clone(),
            fixed: u.fixed.clone(),
        }));
    }
    solver.free = Some(mask(np + nf, &free));
    let report = match speculative {
        Some(r) => r,
        None => lm::minimize(problem, &x0, &solver),
    };
    if !report.termination.converged() {
        warnings.push(Warning::new(WarningKind::NotConverged {
            reason: report.termination.reason(),
        }));
    }
    let params = Params::new(spec, report.x[..np].to_vec())?;
    let m_values = report.x[np..].to_vec();
    let frame = m_values[measurement.frame_range()].to_vec();
    let dof = m.saturating_sub(free.len()).max(1);
    let s2 = report.sum_of_squares / dof as f64;
    let (cov_unit, rank) = report.covariance(1e-12);
    if rank < free.len() {
        warnings.push(Warning::new(WarningKind::RankDeficient {
            rank,
            free: free.len(),
        }));
    }
    let covariance = &cov_unit * s2;
    let mut parameters = vec![];
    for (i, name) in cols.names.iter().enumerate() {
        let k = free.iter().position(|&f| f == i);
        let note = if k.is_none() && requested.contains(&i) {
            Some("unidentifiable: fixed at its starting value".into())
        } else {
            None
        };
        parameters.push(ParameterResult {
            name: name.clone(),
            unit: cols.units[i],
            kind: cols.kinds[i],
            nominal: cols.nominal[i],
            identified: report.x[i],
            change: report.x[i] - cols.nominal[i],
            std_dev: k.map_or(0.0, |k| covariance[(k, k)].max(0.0).sqrt()),
            free: k.is_some(),
            note,
        });
    }
    let correlations = correlations(&cols, &free, &covariance);
    // The mechanism's part travels with the parameters into predictions
    // (the marginal covariance is the sub-matrix); the instrument's stays in
    // the parameter table.
    let mech_free: Vec<usize> = (0..free.len()).filter(|&a| free[a] < np).collect();
    let parameter_covariance = ParameterCovariance {
        names: mech_free
            .iter()
            .map(|&a| cols.names[free[a]].clone())
            .collect(),
        matrix: mech_free
            .iter()
            .map(|&a| mech_free.iter().map(|&b| covariance[(a, b)]).collect())
            .collect(),
    };
    Ok((
        Calibration {
            parameter_covariance,
            model: opts.model,
            params,
            frame: (!frame.is_empty()).then_some(frame),
            measurement: m_values,
            converged: report.termination.converged(),
            termination_reason: report.termination.reason(),
            termination: report.termination,
            iterations: report.iterations,
            evaluations: report.evaluations,
            poses: data.iter().filter(|d| d.partner.is_none()).count(),
            distances: data.iter().filter(|d| d.partner.is_some()).count(),
            sum_of_squares: report.sum_of_squares,
            unit_weight_sigma: s2.sqrt(),
            noise: vec![],
            parameters,
            identifiability,
            covariance,
            free,
            correlations,
            loss: opts.loss,
            outliers: vec![],
            dropped: vec![],
            residuals: report
                .residuals
                .iter()
                .zip(sigma)
                .map(|(v, s)| v * s)
                .collect(),
            sigmas: sigma.to_vec(),
            jacobian: report.jacobian,
            warnings,
            final_predictions: None,
        },
        cov_unit,
    ))
}

/// The measurement model's parameters to start from: `given`, else its
/// nominal values with a free frame registered onto the readings predicted
/// under `params`.
fn measurement_start<M: Mechanism>(
    problem: &IdentificationProblem<'_, M>,
    given: Option<&[f64]>,
    params: &Params,
    data: &[Measurement],
) -> Result<Vec<f64>> {
    let measurement = problem.measurement();
    if let Some(g) = given {
        return Ok(g.to_vec());
    }
    if *measurement.frame() != Frame::Free {
        return Ok(measurement.nominal().to_vec());
    }
    let (predicted, measured): (Vec<Vec<f64>>, Vec<Vec<f64>>) = problem
        .predict(params)?
        .into_iter()
        .zip(data)
        .filter(|(_, m)| m.partner.is_none())
        .map(|(p, m)| (p, m.measured.clone()))
        .unzip();
    measurement.registered(measurement.nominal(), &predicted, &measured)
}

fn mask(n: usize, free: &[usize]) -> Vec<bool> {
    let mut m = vec![false; n];
    for &i in free {
        m[i] = true;
    }
    m
}

/// Identifiability analysis alone (no fit), at `params` and the measurement
/// model's nominal values (a free frame registered). Rows are weighted by the
/// data's σ where given, otherwise by the default noise ratio of lengths and
/// angles ([`crate::Noise::lengths`]), so that mm and rad do not meet
/// unscaled. `free` indexes the mechanism's parameters then the model's; a
/// free frame's are added. Every unidentifiable direction is listed with the
/// parameter that [`calibrate`] would fix for it.
pub fn analyze<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    model: Model,
    free: &[usize],
    force: &[f64],
) -> Result<Identifiability> {
    let spec = mech.spec();
    let data = numbered(data);
    check_sigma(measurement, &data)?;
    let problem = IdentificationProblem::new(mech, measurement, &data, model, force)?;
    let np = spec.n_params();
    let m0 = measurement_start(&problem, None, params, &data)?;
    let mut free = free.to_vec();
    if *measurement.frame() == Frame::Free {
        free.extend(measurement.frame_range().map(|i| np + i));
    }
    let x: Vec<f64> = params.values.iter().chain(&m0).copied().collect();
    let (_, mut jac) = problem.residuals_and_jacobian(&x)?;
    if jac.iter().any(|v| !v.is_finite()) {
        return Err(Error::InvalidRequest(
            "the identification Jacobian is not finite at these parameters".into(),
        ));
    }
    let default = crate::measurement::data::Noise::lengths(1.0);
    let mut row = 0;
    for m in &data {
        for a in 0..measurement.row_len(m) {
            let s = m
                .sigma_of(a)
                .unwrap_or_else(|| default.for_unit(measurement.row_unit(m, a)));
            jac.row_mut(row).unscale_mut(s);
            row += 1;
        }
    }
    let cols = Columns::with_measurement(spec, measurement, &m0);
    Ok(analyze_identifiability(&cols, &jac, &free, data.len(), true).0)
}

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

/// Before and after statistics of a data set.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Accuracy {
    /// Poses.
    pub poses: usize,
    /// Errors before calibration: measured minus target (or minus the
    /// nominal prediction when no target is known).
    pub before: ErrorStats,
    /// Errors after: measured minus the calibrated prediction.
    pub after: ErrorStats,
    /// Reduction of the largest distance error, percent.
    pub improvement_max_percent: f64,
    /// Reduction of the RMS distance error, percent.
    pub improvement_rms_percent: f64,
    /// Errors of the distances measured between two poses, when the data
    /// hold any (the statistics above are of the other rows).
    pub distances: Option<DistanceAccuracy>,
}

/// Errors of distances measured between two poses (mm): measured minus
/// predicted, before (nominal parameters) and after calibration.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct DistanceAccuracy {
    /// Number of distances.
    pub count: usize,
    /// Root mean square error before (mm).
    pub before_rms: f64,
    /// Largest absolute error before (mm).
    pub before_max: f64,
    /// Root mean square error after (mm).
    pub after_rms: f64,
    /// Largest absolute error after (mm).
    pub after_max: f64,
    /// Each distance's error before, in data order (mm).
    pub before: Vec<f64>,
    /// Each distance's error after (mm).
    pub after: Vec<f64>,
}

/// Error vectors (measured minus reference), one per pose, mm.
pub type ErrorVectors = Vec<Vec<f64>>;

/// Errors of `data` before (nominal) and after (calibrated: the
/// mechanism's `params` and the measurement model's `m`) with `model`.
///
/// Readings of the whole tool are compared in the base frame: after
/// calibration the readings are taken to the base by the identified frame;
/// before, by the frame that best registers them onto the targets (or the
/// nominal predictions), as a metrologist compares an uncalibrated machine.
/// Other readings (target points, bar lengths, a subset of axes) are compared
/// as read; before calibration against the model's nominal values, the frame
/// registered.
pub fn accuracy<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    m: &[f64],
    model: Model,
    force: &[f64],
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    accuracy_cached(mech, measurement, data, params, m, model, force, None, None)
}

/// [`accuracy`] with the poses prepared in `cache`.
#[allow(clippy::too_many_arguments)]
fn accuracy_cached<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    params: &Params,
    m: &[f64],
    model: Model,
    force: &[f64],
    cache: Option<&PoseCache>,
    known: Option<&FinalPredictions>,
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    let spec = mech.spec();
    let nominal = Params::nominal(spec);
    let all = numbered(data);
    let (pairs, data): (Vec<Measurement>, Vec<Measurement>) =
        all.into_iter().partition(|d| d.partner.is_some());
    let distances = if pairs.is_empty() {
        None
    } else {
        let problem =
            IdentificationProblem::with_cache(mech, measurement, &pairs, model, force, cache)?;
        let errors = |p: &Params| -> Result<Vec<f64>> {
            Ok(problem
                .predict_distances(p)?
                .iter()
                .zip(&pairs)
                .map(|(d, m)| m.measured[0] - d.expect("a pair"))
                .collect())
        };
        let (before, after) = (errors(&nominal)?, errors(params)?);
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        let max = |v: &[f64]| v.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        Some(DistanceAccuracy {
            count: pairs.len(),
            before_rms: rms(&before),
            before_max: max(&before),
            after_rms: rms(&after),
            after_max: max(&after),
            before,
            after,
        })
    };
    let data = &data[..];
    let problem = IdentificationProblem::with_cache(mech, measurement, data, model, force, cache)?;
    let nominal_pred = problem.predict(&nominal)?;
    if let Some(k) = known {
        problem.seed(k, params);
    }
    let pred = problem.predict(params)?;
    let reference: Vec<Vec<f64>> = data
        .iter()
        .zip(&nominal_pred)
        .map(|(d, p)| d.target.clone().unwrap_or_else(|| p.clone()))
        .collect();
    let measured: Vec<Vec<f64>> = data.iter().map(|d| d.measured.clone()).collect();
    let m_before = if *measurement.frame() == Frame::Base || data.is_empty() {
        measurement.nominal().to_vec()
    } else {
        measurement.registered(measurement.nominal(), &reference, &measured)?
    };
    let errors = |tools: &[Vec<f64>], mv: &[f64]| -> Vec<Vec<f64>> {
        tools
            .iter()
            .zip(&measured)
            .map(|(x, y)| match measurement.to_base(y, mv) {
                Some(b) => b.iter().zip(x).map(|(p, q)| p - q).collect(),
                None => {
                    let mut h = vec![0.0; measurement.len()];
                    measurement.observe(x, mv, &mut h);
                    y.iter().zip(&h).map(|(p, q)| p - q).collect()
                }
            })
            .collect()
    };
    let before = errors(&reference, &m_before);
    let after = errors(&pred, m);
    let units = measurement.units();
    let b = error_stats(&before, units);
    let a = error_stats(&after, units);
    Ok((
        Accuracy {
            poses: data.len(),
            improvement_max_percent: improvement_percent(b.distance_max, a.distance_max),
            improvement_rms_percent: improvement_percent(b.distance_rms, a.distance_rms),
            before: b,
            after: a,
            distances,
        },
        before,
        after,
    ))
}

/// [`accuracy`] of a calibration: its parameters, model and measurement
/// model's values.
pub fn calibration_accuracy<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    cal: &Calibration,
    force: &[f64],
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    calibration_accuracy_with_cache(mech, measurement, data, cal, force, &PoseCache::default())
}

/// [`calibration_accuracy`] with the poses prepared in `cache` (the one the
/// calibration was given to [`calibrate_with_cache`]: the data's poses are
/// then prepared once for both, and the predictions at the identified
/// parameters, when the fit's last evaluation was there, are the fit's).
pub fn calibration_accuracy_with_cache<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    cal: &Calibration,
    force: &[f64],
    cache: &PoseCache,
) -> Result<(Accuracy, ErrorVectors, ErrorVectors)> {
    crate::on_pool(|| {
        accuracy_cached(
            mech,
            measurement,
            data,
            &cal.params,
            &cal.measurement,
            cal.model,
            force,
            Some(cache),
            cal.final_predictions.as_ref(),
        )
    })
}

/// Split indices into a training and a held-out part (`fraction` held out),
/// shuffled with `seed`.
pub fn holdout_split(n: usize, fraction: f64, seed: u64) -> Result<(Vec<usize>, Vec<usize>)> {
    if !(fraction > 0.0 && fraction < 1.0) {
        return Err(Error::InvalidRequest(format!(
            "the held-out fraction must be between 0 and 1, got {fraction}"
        )));
    }
    let mut idx: Vec<usize> = (0..n).collect();
    idx.shuffle(&mut StdRng::seed_from_u64(seed));
    let k = ((n as f64) * fraction).round().max(1.0) as usize;
    if k >= n {
        return Err(Error::InvalidRequest(format!(
            "holding out {fraction} of {n} poses leaves none to calibrate on"
        )));
    }
    let mut held: Vec<usize> = idx[..k].to_vec();
    let mut train: Vec<usize> = idx[k..].to_vec();
    held.sort_unstable();
    train.sort_unstable();
    Ok((train, held))
}

/// Result of k-fold cross-validation.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct CrossValidation {
    /// Number of folds.
    pub folds: usize,
    /// Held-out RMS distance error of each fold (mm).
    pub fold_rms: Vec<f64>,
    /// Pooled held-out error statistics.
    pub pooled: ErrorStats,
}

/// k-fold cross-validation: calibrate on k−1 folds, predict the held-out one.
pub fn cross_validate<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    folds: usize,
    seed: u64,
) -> Result<CrossValidation> {
    cross_validate_with_progress(mech, measurement, data, start, opts, folds, seed, &|| {})
}

/// [`cross_validate`], calling `progress` after each fold.
#[allow(clippy::too_many_arguments)]
pub fn cross_validate_with_progress<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    data: &[Measurement],
    start: &Params,
    opts: &CalibrationOptions,
    folds: usize,
    seed: u64,
    progress: &dyn Fn(),
) -> Result<CrossValidation> {
    if folds < 2 || folds > data.len() {
        return Err(Error::InvalidRequest(format!(
            "k-fold cross-validation needs 2 ≤ k ≤ {} poses, got k = {folds}",
            data.len()
        )));
    }
    let mut idx: Vec<usize> = (0..data.len()).collect();
    idx.shuffle(&mut StdRng::seed_from_u64(seed));
    let mut fold_rms = vec![];
    let mut pooled = vec![];
    for f in 0..folds {
        let held: Vec<usize> = idx.iter().copied().skip(f).step_by(folds).collect();
        let train: Vec<Measurement> = idx
            .iter()
            .filter(|i| !held.contains(i))
            .map(|&i| data[i].clone())
            .collect();
        let test: Vec<Measurement> = held.iter().map(|&i| data[i].clone()).collect();
        let cal = calibrate(mech, measurement, &train, start, opts)?;
        let (acc, _, after) = calibration_accuracy(mech, measurement, &test, &cal, &opts.force)?;
        fold_rms.push(acc.after.distance_rms);
        pooled.extend(after);
        progress();
    }
    Ok(CrossValidation {
        folds,
        fold_rms,
        pooled: error_stats(&pooled, measurement.units()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::RngExt;

    /// Relative agreement of the singular values found through the QR with
    /// those of the scaled matrix itself (both backward stable: rounding
    /// times the condition number at most).
    const SVD_AGREE: f64 = 1e-12;

    /// [`scaled_svd`] through the QR gives the singular values and right
    /// singular vectors of the scaled matrix: on random tall matrices with
    /// columns of very different sizes, a zero column and two nearly
    /// dependent columns, and on a wide one (the zero-row path).
    #[test]
    fn the_svd_through_the_qr_is_that_of_the_scaled_matrix() {
        let mut rng = StdRng::seed_from_u64(11);
        for (m, n) in [(60, 7), (120, 12), (7, 7), (4, 6)] {
            let mut a = DMatrix::from_fn(m, n, |_, c| {
                rng.random_range(-1.0..1.0) * 10f64.powi(c as i32 % 5 - 2)
            });
            a.column_mut(1).fill(0.0);
            let c3 = a.column(3).into_owned();
            a.column_mut(4).copy_from(&(c3 * 2.0));
            a[(0, 4)] += 1e-6;
            let norms: Vec<f64> = (0..n).map(|k| a.column(k).norm()).collect();
            let (sv, vt, _) = scaled_svd(&a, &norms);
            let mut scaled = a.clone();
            for (k, s) in norms.iter().enumerate() {
                if *s > 0.0 {
                    scaled.column_mut(k).unscale_mut(*s);
                }
            }
            let direct = scaled.clone().svd(false, false).singular_values;
            let mut ours = sv.clone();
            let mut theirs: Vec<f64> = direct.iter().copied().collect();
            ours.sort_by(|a, b| b.total_cmp(a));
            theirs.sort_by(|a, b| b.total_cmp(a));
            for (o, t) in ours.iter().zip(&theirs) {
                assert!(
                    (o - t).abs() <= SVD_AGREE * theirs[0],
                    "{m}x{n}: {o} vs {t}"
                );
            }
            // Each right vector: ‖scaled v‖ is its singular value, v a unit vector.
            for (i, s) in sv.iter().enumerate() {
                let v = vt.row(i).transpose();
                assert!(
                    (v.norm() - 1.0).abs() < SVD_AGREE,
                    "{m}x{n}: |v| = {}",
                    v.norm()
                );
                let image = (&scaled * &v).norm();
                assert!(
                    (image - s).abs() <= SVD_AGREE * theirs[0],
                    "{m}x{n}: {image} vs {s}"
                );
            }
        }
    }
}
