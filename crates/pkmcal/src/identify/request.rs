//! A user's choices, turned into a study's options: the free set by name,
//! tolerances, the instrument's stated noise, validation, folds, the robust
//! loss, the solver's settings. Every rule of what a user may ask is checked
//! here, once, for every front end (the command line, Python, the firmware
//! commands); a refusal is a [`RequestError`] naming the choice as a
//! [`Field`], which each front end words as its own option or keyword.
//!
//! ```
//! use pkmcal::identify::request::Request;
//! use pkmcal::{JeongKim2Dof, MeasurementModel, Mechanism, Model};
//! let mech = JeongKim2Dof::new();
//! let tool = MeasurementModel::tool(mech.spec());
//! let mut request = Request::new(Model::Exact);
//! request.free = Some(vec!["default".into()]);
//! request.fix = vec!["l11".into()];
//! let (priors, free) = request.priors_and_free(mech.spec(), &tool, &[]).unwrap();
//! assert!(priors.is_empty() && free.len() == 15);
//! ```

use super::driver::{CalibrationOptions, DEFAULT_STATED_NOISE_READINGS};
use super::gross::MIN_SIGMA;
use super::loss::Loss;
use super::prior::{Prior, Tolerance, free_with_priors, merged_tolerances, named_priors};
use super::study::{FreeSetError, NameList, StudyOptions, ValidationPlan, resolve_free_set};
use crate::engine::models::Model;
use crate::error::{Field, RequestError, Suggestion};
use crate::measurement::data::{Measurement, Noise};
use crate::measurement::{FrameRequest, FrameRequestError, MeasurementModel, requested_frame};
use crate::mechanism::{Mechanism, Params, Spec};

/// The largest noise or error on a length a user may give (mm).
pub const MAX_LENGTH_MM: f64 = 1000.0;
/// The largest noise or error on an angle a user may give (rad).
pub const MAX_ANGLE_RAD: f64 = 1.0;

/// Where the instrument stands, as a user says it: the library's frame rule
/// ([`requested_frame`]) decides the rest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameChoice {
    /// Free for whole positions and target points unless the data say they
    /// are in the base frame (a data file's `# frame: base`); the base frame
    /// for readings that fix no frame.
    #[default]
    Auto,
    /// An instrument frame identified with the rest.
    Free,
    /// The data are in the base frame.
    Base,
}

impl FrameChoice {
    /// The names a front end takes, in order.
    pub const NAMES: [&str; 3] = ["auto", "free", "base"];

    /// The frame request of this choice for data that do (or do not)
    /// declare themselves in the base frame.
    pub fn request(self, data_in_base: bool) -> FrameRequest {
        match self {
            FrameChoice::Auto => FrameRequest::Auto { data_in_base },
            FrameChoice::Free => FrameRequest::Free,
            FrameChoice::Base => FrameRequest::Base,
        }
    }

    /// `measurement` in the frame this choice gives it (the frame rule of
    /// [`requested_frame`]); a refusal names the frame choice, with the
    /// bed's parameters to free instead for probed heights.
    pub fn apply(
        self,
        measurement: MeasurementModel,
        spec: &Spec,
        data_in_base: bool,
    ) -> Result<MeasurementModel, RequestError> {
        let refused = |e: FrameRequestError| {
            let suggest = match &e {
                FrameRequestError::Probe => Some(Suggestion {
                    field: Field::Free,
                    value: "default,bed.rx,bed.ry".into(),
                }),
                _ => None,
            };
            RequestError::Invalid {
                field: Field::Frame,
                problem: match e {
                    FrameRequestError::BallBar => {
                        "a ball bar's sockets are in the base frame; leave the frame to its default"
                            .into()
                    }
                    e => e.to_string(),
                },
                suggest,
            }
        };
        match requested_frame(&measurement, spec, self.request(data_in_base)) {
            Ok(None) => Ok(measurement),
            Ok(Some(f)) => measurement
                .in_frame(f)
                .map_err(|e| RequestError::invalid(Field::Frame, e.to_string())),
            Err(e) => Err(refused(e)),
        }
    }
}

impl std::str::FromStr for FrameChoice {
    type Err = RequestError;
    fn from_str(s: &str) -> Result<Self, RequestError> {
        match s {
            "auto" => Ok(FrameChoice::Auto),
            "free" => Ok(FrameChoice::Free),
            "base" => Ok(FrameChoice::Base),
            _ => Err(RequestError::invalid(
                Field::Frame,
                format!("unknown frame `{s}`; one of auto, free, base"),
            )),
        }
    }
}

/// The solver's settings a user may change.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SolverRequest {
    /// The evaluation budget.
    pub max_evaluations: Option<usize>,
    /// Relative reduction of the sum of squares below which the fit stops.
    pub ftol: Option<f64>,
    /// Relative step below which the fit stops.
    pub xtol: Option<f64>,
    /// Gradient cosine below which the fit stops.
    pub gtol: Option<f64>,
    /// Bounds on named parameters: `(name, lower, upper)`, ±∞ for an open
    /// side.
    pub bounds: Vec<(String, f64, f64)>,
}

/// What a user asks of a study, by name and number: the one input of every
/// front end's fit. Fields left at their defaults ([`Request::new`]) ask
/// for nothing.
#[derive(Debug, Clone)]
pub struct Request {
    /// The forward model.
    pub model: Model,
    /// The parameters to identify: names, `all` and `default` (`paper` is
    /// the same); `None`: the default set.
    pub free: Option<Vec<String>>,
    /// Names removed from the free set.
    pub fix: Vec<String>,
    /// The default set where it is not the mechanism's (a firmware's own).
    pub default_free: Option<Vec<String>>,
    /// Tolerances given by the user, replacing the description's for the
    /// same names.
    pub tolerances: Vec<(String, Tolerance)>,
    /// No priors at all (not even the description's).
    pub no_tolerances: bool,
    /// The tool load during the measurements, one value per tool axis
    /// (N, N·m); empty for none.
    pub load: Vec<f64>,
    /// The robust loss by name: `squared`, `huber` or `cauchy`.
    pub loss: String,
    /// Its tuning constant, in robust standard deviations.
    pub loss_scale: Option<f64>,
    /// Poses beyond this many robust standard deviations are outliers.
    pub outlier_threshold: f64,
    /// Drop the outliers and refit.
    pub drop_outliers: bool,
    /// The instrument's stated noise on lengths (mm).
    pub stated_noise: Option<f64>,
    /// And on angles (rad; default: the lengths' over a 200 mm lever arm).
    pub stated_angle_noise: Option<f64>,
    /// The stated noise of the distances between poses (mm).
    pub stated_distance_noise: Option<f64>,
    /// What a stated noise is worth, in readings.
    pub stated_readings: f64,
    /// Only the stated noises' ratios are known.
    pub stated_relative: bool,
    /// Validation poses measured apart.
    pub validation: Option<Vec<Measurement>>,
    /// A fraction of the poses held out for validation.
    pub holdout: Option<f64>,
    /// k-fold cross-validation.
    pub kfold: Option<usize>,
    /// Seed of the hold-out split and of the folds.
    pub seed: u64,
    /// The solver's settings.
    pub solver: SolverRequest,
    /// Accept as many readings as free parameters (a firmware's exact
    /// solve).
    pub exactly_determined: bool,
}

/// The default outlier threshold (robust standard deviations).
pub const DEFAULT_OUTLIER_THRESHOLD: f64 = 4.0;
/// The default noise weighing readings against tolerances (mm).
pub const DEFAULT_WEIGHING_NOISE_MM: f64 = 0.002;
/// The default seed.
pub const DEFAULT_SEED: u64 = 1;

impl Request {
    /// Nothing asked but the model.
    pub fn new(model: Model) -> Self {
        Request {
            model,
            free: None,
            fix: vec![],
            default_free: None,
            tolerances: vec![],
            no_tolerances: false,
            load: vec![],
            loss: "squared".into(),
            loss_scale: None,
            outlier_threshold: DEFAULT_OUTLIER_THRESHOLD,
            drop_outliers: false,
            stated_noise: None,
            stated_angle_noise: None,
            stated_distance_noise: None,
            stated_readings: DEFAULT_STATED_NOISE_READINGS,
            stated_relative: false,
            validation: None,
            holdout: None,
            kfold: None,
            seed: DEFAULT_SEED,
            solver: SolverRequest::default(),
            exactly_determined: false,
        }
    }

    /// The parameters this request names by a name they had before (in
    /// its free and fix lists and its tolerances): still read, each meaning
    /// its new name; for a front end's note.
    pub fn renamed(&self, spec: &Spec) -> Vec<crate::mechanism::Renamed> {
        spec.renamed_among(
            self.free
                .iter()
                .flatten()
                .chain(&self.fix)
                .map(String::as_str)
                .chain(self.tolerances.iter().map(|(n, _)| n.as_str())),
        )
    }

    /// Names from a comma-separated list (`"l11, l12"`), as every front
    /// end's name lists are written.
    pub fn names(text: &str) -> Vec<String> {
        text.split(',').map(|t| t.trim().to_string()).collect()
    }

    /// The priors of a fit (docs/model.md eq. 13): the description's
    /// `[tolerances]` (`table`) with the user's replacing its entries for
    /// the same names, resolved against the mechanism and the instrument;
    /// none when [`Request::no_tolerances`].
    pub fn priors(
        &self,
        spec: &Spec,
        measurement: &MeasurementModel,
        table: &[(String, Tolerance)],
    ) -> Result<Vec<Prior>, RequestError> {
        if self.no_tolerances {
            if !self.tolerances.is_empty() {
                return Err(RequestError::Exclusive {
                    a: Field::Tolerances,
                    b: Field::NoTolerances,
                });
            }
            return Ok(vec![]);
        }
        if let Some(dup) = self
            .tolerances
            .iter()
            .enumerate()
            .find(|(k, (n, _))| self.tolerances[..*k].iter().any(|(m, _)| m == n))
        {
            return Err(RequestError::invalid(
                Field::Tolerances,
                format!("`{}` has two tolerances; give one", dup.1.0),
            ));
        }
        named_priors(spec, measurement, &self.tolerances)
            .map_err(|e| RequestError::invalid(Field::Tolerances, e.to_string()))?;
        let merged = merged_tolerances(table, self.tolerances.clone());
        named_priors(spec, measurement, &merged)
            .map_err(|e| RequestError::ToleranceTable(e.to_string()))
    }

    /// The free set (indices of the identification vector), from the names
    /// given, with the parameters `priors` hold freed unless fixed by name
    /// ([`free_with_priors`]).
    pub fn free_set(
        &self,
        spec: &Spec,
        measurement: &MeasurementModel,
        priors: &[Prior],
    ) -> Result<Vec<usize>, RequestError> {
        let default = self.default_free.as_ref().unwrap_or(&spec.default_free);
        let set = resolve_free_set(spec, measurement, default, self.free.as_deref(), &self.fix)
            .map_err(free_set_error)?;
        Ok(free_with_priors(spec, measurement, &set, priors, &self.fix))
    }

    /// The parameters a tolerance frees beyond the free set named (the
    /// documented rule: a tolerance frees its parameter unless it is fixed
    /// by name), by name in the identification vector's order.
    pub fn freed_by_tolerances(
        &self,
        spec: &Spec,
        measurement: &MeasurementModel,
        table: &[(String, Tolerance)],
    ) -> Result<Vec<String>, RequestError> {
        let priors = self.priors(spec, measurement, table)?;
        let default = self.default_free.as_ref().unwrap_or(&spec.default_free);
        let set = resolve_free_set(spec, measurement, default, self.free.as_deref(), &self.fix)
            .map_err(free_set_error)?;
        let all = measurement.all_names(spec);
        Ok(
            free_with_priors(spec, measurement, &set, &priors, &self.fix)
                .into_iter()
                .filter(|i| !set.contains(i))
                .map(|i| all[i].clone())
                .collect(),
        )
    }

    /// [`Request::priors`] and [`Request::free_set`]: what every command
    /// that fits, analyses or plans resolves first.
    pub fn priors_and_free(
        &self,
        spec: &Spec,
        measurement: &MeasurementModel,
        table: &[(String, Tolerance)],
    ) -> Result<(Vec<Prior>, Vec<usize>), RequestError> {
        let priors = self.priors(spec, measurement, table)?;
        let free = self.free_set(spec, measurement, &priors)?;
        Ok((priors, free))
    }

    /// The free parameters' names in the order given (the default set's
    /// where `default` stands, every free one's for `all`), each once: how
    /// a firmware command lists what it fits.
    pub fn free_names(
        &self,
        spec: &Spec,
        measurement: &MeasurementModel,
        free: &[usize],
    ) -> Vec<String> {
        let default = self.default_free.as_ref().unwrap_or(&spec.default_free);
        let all = measurement.all_names(spec);
        let given = self.free.clone().unwrap_or_else(|| vec!["default".into()]);
        let mut names: Vec<String> = vec![];
        for n in given.iter().map(|n| n.trim()) {
            match n {
                "default" | "paper" => names.extend(default.iter().cloned()),
                "all" => names.extend(free.iter().map(|&i| all[i].clone())),
                "" => {}
                _ => names.push(n.to_string()),
            }
        }
        let mut seen = std::collections::BTreeSet::new();
        names.retain(|n| seen.insert(n.clone()));
        names.retain(|n| {
            measurement
                .index_of(spec, n)
                .is_ok_and(|i| free.contains(&i))
        });
        // A parameter a tolerance freed, after the names given.
        for &i in free {
            if !names.contains(&all[i]) {
                names.push(all[i].clone());
            }
        }
        names
    }

    /// The stated noise of the readings, checked.
    fn stated(&self) -> Result<Option<Noise>, RequestError> {
        if let Some(a) = self.stated_angle_noise {
            if self.stated_noise.is_none() {
                return Err(RequestError::Needs {
                    field: Field::StatedAngleNoise,
                    needs: Field::StatedNoise,
                });
            }
            positive(Field::StatedAngleNoise, a, MAX_ANGLE_RAD, "rad")?;
        }
        if let Some(l) = self.stated_noise {
            sigma_mm(Field::StatedNoise, l)?;
        }
        if let Some(d) = self.stated_distance_noise {
            sigma_mm(Field::StatedDistanceNoise, d)?;
        }
        if self.stated_readings.is_nan() || self.stated_readings < 0.0 {
            return Err(RequestError::invalid(
                Field::StatedReadings,
                format!(
                    "a stated noise is worth a non-negative number of readings, not {}",
                    self.stated_readings
                ),
            ));
        }
        if self.stated_relative
            && self.stated_noise.is_none()
            && self.stated_distance_noise.is_none()
        {
            return Err(RequestError::Needs {
                field: Field::StatedRelative,
                needs: Field::StatedNoise,
            });
        }
        Ok(self.stated_noise.map(|l| {
            let mut n = Noise::lengths(l);
            if let Some(a) = self.stated_angle_noise {
                n.angle = a;
            }
            n
        }))
    }

    /// The instrument's stated noise where no fit estimates it: what
    /// weighs readings against tolerances in identifiability and planning
    /// ([`Request::stated_noise`], [`DEFAULT_WEIGHING_NOISE_MM`] where not
    /// given), checked: with priors it must be positive (a noise of 0 would
    /// make the readings infinitely more certain than any tolerance).
    pub fn weighing_noise(&self, priors: bool) -> Result<Noise, RequestError> {
        let length = self.stated_noise.unwrap_or(DEFAULT_WEIGHING_NOISE_MM);
        bounded(Field::StatedNoise, length, MAX_LENGTH_MM, "mm")?;
        let mut noise = Noise::lengths(length);
        if let Some(a) = self.stated_angle_noise {
            bounded(Field::StatedAngleNoise, a, MAX_ANGLE_RAD, "rad")?;
            noise.angle = a;
        }
        if priors && !(noise.length >= MIN_SIGMA && noise.angle > 0.0) {
            return Err(RequestError::invalid(
                Field::StatedNoise,
                format!(
                    "with tolerances, the readings' noise weighs them against the tolerances and must be at least {MIN_SIGMA:e} mm (and the angles' above 0); give the instrument's σ"
                ),
            ));
        }
        Ok(noise)
    }

    /// The tool load, checked against the mechanism: one value per tool
    /// axis, a working load at `params`.
    pub fn checked_load<M: Mechanism>(
        &self,
        mech: &M,
        params: &Params,
    ) -> Result<Vec<f64>, RequestError> {
        checked_load(&self.load, mech, params, Field::Load)
    }

    /// The fit's options for `mech` read by `measurement`, starting at
    /// `start`; `table` is the description's `[tolerances]`.
    pub fn calibration_options<M: Mechanism>(
        &self,
        mech: &M,
        measurement: &MeasurementModel,
        table: &[(String, Tolerance)],
        start: &Params,
    ) -> Result<CalibrationOptions, RequestError> {
        let spec = mech.spec();
        let mut opts = CalibrationOptions::new(spec, self.model);
        (opts.priors, opts.free) = self.priors_and_free(spec, measurement, table)?;
        opts.stated_noise = self.stated()?;
        opts.stated_distance_noise = self.stated_distance_noise;
        opts.stated_noise_readings = self.stated_readings;
        opts.stated_noise_relative = self.stated_relative;
        opts.force = self.checked_load(mech, start)?;
        if let Some(k) = self.loss_scale
            && !(k.is_finite() && k > 0.0)
        {
            return Err(RequestError::invalid(
                Field::LossScale,
                format!(
                    "the loss scale must be a positive number of robust standard deviations, got {k}"
                ),
            ));
        }
        opts.loss = Loss::named(&self.loss, self.loss_scale)
            .map_err(|e| RequestError::invalid(Field::Loss, e.to_string()))?;
        if !(self.outlier_threshold.is_finite() && self.outlier_threshold > 0.0) {
            return Err(RequestError::invalid(
                Field::OutlierThreshold,
                format!(
                    "give a positive number of robust standard deviations, got {}",
                    self.outlier_threshold
                ),
            ));
        }
        opts.outlier_threshold = self.outlier_threshold;
        opts.drop_outliers = self.drop_outliers;
        opts.exactly_determined = self.exactly_determined;
        let s = &self.solver;
        if let Some(n) = s.max_evaluations {
            if n == 0 {
                return Err(RequestError::invalid(
                    Field::MaxEvaluations,
                    "the solver's evaluation budget is 0; allow at least 1 evaluation",
                ));
            }
            opts.solver.max_evaluations = n;
        }
        for (v, field, slot) in [
            (s.ftol, Field::Ftol, &mut opts.solver.ftol),
            (s.xtol, Field::Xtol, &mut opts.solver.xtol),
            (s.gtol, Field::Gtol, &mut opts.solver.gtol),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(RequestError::invalid(
                        field,
                        format!("the solver's tolerance is {v}; give a finite number ≥ 0"),
                    ));
                }
                *slot = v;
            }
        }
        if !s.bounds.is_empty() {
            let (lower, upper) = super::study::named_bounds(spec, measurement, &s.bounds)
                .map_err(|e| RequestError::invalid(Field::Bounds, e.to_string()))?;
            opts.solver.lower = Some(lower);
            opts.solver.upper = Some(upper);
        }
        Ok(opts)
    }

    /// The study's options: the fit's ([`Request::calibration_options`]),
    /// validation (poses given apart or held out, not both) and
    /// cross-validation.
    pub fn study_options<M: Mechanism>(
        self,
        mech: &M,
        measurement: &MeasurementModel,
        table: &[(String, Tolerance)],
        start: &Params,
    ) -> Result<StudyOptions, RequestError> {
        let calibration = self.calibration_options(mech, measurement, table, start)?;
        let validation = match (self.validation, self.holdout) {
            (Some(_), Some(_)) => {
                return Err(RequestError::Exclusive {
                    a: Field::Validation,
                    b: Field::Holdout,
                });
            }
            (Some(v), None) => ValidationPlan::Given(v),
            (None, Some(f)) => {
                if !(f > 0.0 && f < 1.0) {
                    return Err(RequestError::invalid(
                        Field::Holdout,
                        format!("hold out a fraction between 0 and 1 (exclusive), not {f}"),
                    ));
                }
                ValidationPlan::Holdout(f)
            }
            (None, None) => ValidationPlan::None,
        };
        if let Some(k) = self.kfold
            && k < 2
        {
            return Err(RequestError::invalid(
                Field::Kfold,
                format!("k-fold cross-validation needs at least 2 folds, got {k}"),
            ));
        }
        Ok(StudyOptions {
            calibration,
            validation,
            kfold: self.kfold,
            seed: self.seed,
            keep_jacobian: true,
        })
    }
}

/// A free-set refusal as a request error naming the list.
fn free_set_error(e: FreeSetError) -> RequestError {
    let field = |l: NameList| match l {
        NameList::Free => Field::Free,
        NameList::Fix => Field::Fix,
    };
    match e {
        FreeSetError::Unknown { list, error } => {
            RequestError::invalid(field(list), error.to_string())
        }
        FreeSetError::FrameParameter { list, name } => RequestError::invalid(
            field(list),
            format!(
                "`{name}` belongs to the instrument frame, which the frame choice sets (free: identified; base: the data are in the base frame)"
            ),
        ),
        FreeSetError::Empty => {
            RequestError::invalid(Field::Free, "no parameter is left free; name some")
        }
    }
}

/// A tool load checked against `mech` at `params`: one value per tool axis
/// (an empty load is none), finite, and a working load
/// ([`crate::engine::load::check_load`]); a refusal names `field`.
pub fn checked_load<M: Mechanism>(
    load: &[f64],
    mech: &M,
    params: &Params,
    field: Field,
) -> Result<Vec<f64>, RequestError> {
    if load.is_empty() {
        return Ok(vec![]);
    }
    let spec = mech.spec();
    let n = spec.tool_axes.len();
    if load.len() != n {
        return Err(RequestError::invalid(
            field,
            format!(
                "needs {n} values ({}), got {}",
                spec.tool_axes.join(","),
                load.len()
            ),
        ));
    }
    if let Some(x) = load
        .iter()
        .find(|x| !(x.is_finite() && x.abs() <= crate::units::MAX_LOAD))
    {
        return Err(RequestError::invalid(
            field,
            format!(
                "{x:?} is beyond ±{:e} (N, N·m); no machine bears that",
                crate::units::MAX_LOAD
            ),
        ));
    }
    crate::engine::load::check_load(mech, params, load)
        .map_err(|e| RequestError::invalid(field, e.to_string()))?;
    Ok(load.to_vec())
}

/// `v` within `[0, max]` (a noise or an error a user gives).
pub fn bounded(field: Field, v: f64, max: f64, unit: &str) -> Result<f64, RequestError> {
    if (0.0..=max).contains(&v) {
        Ok(v)
    } else {
        Err(RequestError::invalid(
            field,
            format!("{v:?} {unit} must be between 0 and {max} {unit}"),
        ))
    }
}

/// `v` within `(0, max]`.
pub fn positive(field: Field, v: f64, max: f64, unit: &str) -> Result<f64, RequestError> {
    if v > 0.0 && v <= max {
        Ok(v)
    } else {
        Err(RequestError::invalid(
            field,
            format!("{v:?} {unit} must be positive and at most {max} {unit}"),
        ))
    }
}

/// A standard deviation of a length reading (mm): within
/// [`MIN_SIGMA`]..=[`MAX_LENGTH_MM`].
pub fn sigma_mm(field: Field, v: f64) -> Result<f64, RequestError> {
    if (MIN_SIGMA..=MAX_LENGTH_MM).contains(&v) {
        Ok(v)
    } else {
        Err(RequestError::invalid(
            field,
            format!("{v:?} mm must be between {MIN_SIGMA:e} and {MAX_LENGTH_MM:e} mm"),
        ))
    }
}
