//! The result of a calibration, and a calibration read back from its record.

use crate::arrays::{frame, out2, vec1};
use crate::errors::{io_err, usage};
use crate::files::{path_arg, reading_records, written};
use crate::mechanism::PyMechanism;
use crate::results::parts::{PyErrorStats, PyFigure, PyIdentifiability, PyWarning, warning};
use crate::results::{ByValue, Reduced, by_name, eq_by_value, reduce};
use crate::threads::interruptible;
use pkmcal::identify::Calibration as LibCalibration;
use pkmcal::{AnyMechanism, Mechanism as _};
use pkmcal_io::record::{CalibrationState, MechanismSource};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};
use std::sync::Arc;

/// standard deviations and covariance, identifiability, before/after
/// accuracy, warnings, residuals and figures.
#[pyclass(frozen, module = "pkmcal", name = "Calibration")]
pub struct PyCalibration {
    /// The mechanism calibrated.
    pub mechanism: Py<PyMechanism>,
    /// The whole calibration, as its record keeps it.
    pub state: CalibrationState,
}

/// A summary in Python's words.
pub(crate) const PY_WORDING: pkmcal_io::text::Wording = pkmcal_io::text::Wording {
    frame_base: "identified; frame=\"base\" if the data are in the base frame",
    all_correlations: "Calibration.correlation",
    hint: |w| w.hint.clone(),
    input: |f| format!("{}=", crate::errors::keyword(f)),
};

/// Where the validation poses came from, in Python's words.
fn validation_words(source: pkmcal::identify::ValidationSource) -> String {
    match source {
        pkmcal::identify::ValidationSource::Given => "validation arrays".into(),
        pkmcal::identify::ValidationSource::HeldOut { count, seed } => {
            format!("{count} held-out poses (seed {seed})")
        }
    }
}

#[pymethods]
impl PyCalibration {
    /// Every mechanism parameter by name, as identified (fixed ones at their
    /// start values): pass it as ``params`` to predict or compensate.
    #[getter]
    fn parameters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let spec = self.mech().spec();
        by_name(
            py,
            spec.param_names()
                .iter()
                .zip(&self.cal().params.values)
                .map(|(n, v)| (n.to_string(), *v)),
        )
    }
    /// Instrument parameters (frame, socket or target positions) by name.
    #[getter]
    fn measurement_parameters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.state
                .measurement
                .param_names()
                .iter()
                .zip(&self.cal().measurement)
                .map(|(n, v)| (n.clone(), *v)),
        )
    }
    /// Names of the identified (free) parameters, mechanism then instrument.
    #[getter]
    fn free(&self) -> Vec<String> {
        let cal = self.cal();
        cal.free
            .iter()
            .map(|&i| cal.parameters[i].name.clone())
            .collect()
    }
    /// Standard deviation of each free parameter by name (its unit in ``units``).
    #[getter]
    fn std_dev<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.cal()
                .parameters
                .iter()
                .filter(|p| p.free)
                .map(|p| (p.name.clone(), p.std_dev)),
        )
    }
    /// Identified minus nominal, by name, for every parameter.
    #[getter]
    fn change<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.cal()
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.change)),
        )
    }
    /// Nominal value by name, for every parameter.
    #[getter]
    fn nominal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.cal()
                .parameters
                .iter()
                .map(|p| (p.name.clone(), p.nominal)),
        )
    }
    /// Unit of every parameter by name.
    #[getter]
    fn units<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for p in &self.cal().parameters {
            d.set_item(&p.name, p.unit.symbol())?;
        }
        Ok(d)
    }
    /// Notes on parameters (e.g. why one was fixed), by name.
    #[getter]
    fn notes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for p in &self.cal().parameters {
            if let Some(n) = &p.note {
                d.set_item(&p.name, n)?;
            }
        }
        Ok(d)
    }
    /// Covariance of every free parameter (their units squared), the
    /// instrument's and the frame's included, in the order of ``free``
    /// (``x_names``). The mechanism's part is what travels into predictions
    /// (``predict(..., uncertainty=True)``).
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let c = &self.cal().covariance;
        let n = c.nrows();
        out2(py, c.transpose().as_slice().to_vec(), n, false)
    }
    /// Row and column names of ``covariance``: ``free``.
    #[getter]
    fn covariance_names(&self) -> Vec<String> {
        self.free()
    }
    /// Correlation matrix of the free parameters (``free`` order): the
    /// covariance scaled by the standard deviations (NaN where one is 0 or
    /// not defined).
    #[getter]
    fn correlation<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let c = &self.cal().covariance;
        let n = c.nrows();
        let mut v = Vec::with_capacity(n * n);
        for i in 0..n {
            for j in 0..n {
                v.push(c[(i, j)] / (c[(i, i)] * c[(j, j)]).sqrt());
            }
        }
        out2(py, v, n, false)
    }
    /// The free parameters' identified values, in ``free`` order (the
    /// mechanism's, then the instrument's): scipy's ``x``.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        let cal = self.cal();
        let v: Vec<f64> = cal
            .free
            .iter()
            .map(|&i| cal.parameters[i].identified)
            .collect();
        vec1(py, &v)
    }
    /// Names of ``x`` (``free``).
    #[getter]
    fn x_names(&self) -> Vec<String> {
        self.free()
    }
    /// Units of ``x`` (mm, rad, N·m/rad…): it mixes lengths and angles.
    #[getter]
    fn x_units(&self) -> Vec<&'static str> {
        let cal = self.cal();
        cal.free
            .iter()
            .map(|&i| cal.parameters[i].unit.symbol())
            .collect()
    }
    /// Residuals at the solution, one per reading (pose-major, then the
    /// distances), predicted minus measured, each in its reading's unit: the
    /// same sign for every reading and distance. scipy's ``fun``.
    #[getter]
    fn fun<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        vec1(py, &self.cal().residuals)
    }
    /// Jacobian of ``fun`` with respect to ``x`` at the solution, shape
    /// (readings, free): each reading's unit per parameter unit.
    #[getter]
    fn jac<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let cal = self.cal();
        let (m, n) = cal.jacobian.shape();
        let mut v = Vec::with_capacity(m * n);
        for i in 0..m {
            let s = cal.sigmas.get(i).copied().unwrap_or(1.0);
            for j in 0..n {
                v.push(cal.jacobian[(i, j)] * s);
            }
        }
        out2(py, v, n, false)
    }
    /// Standard deviation each reading of ``fun`` was weighted with (its
    /// unit): the fit minimises ``sum((fun / sigmas)**2)``, plus with priors
    /// ``sum(((value - centre) / sigma)**2)`` over ``priors``.
    #[getter]
    fn sigmas<'py>(&self, py: Python<'py>) -> Bound<'py, numpy::PyArray1<f64>> {
        vec1(py, &self.cal().sigmas)
    }
    /// The priors the fit used (tolerances, docs/model.md eq. 13), one dict
    /// each: ``name``, ``centre`` (the nominal value, or the instrument's
    /// start) and ``sigma``; empty without.
    #[getter]
    fn priors<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.cal()
            .priors
            .iter()
            .map(|t| {
                let d = PyDict::new(py);
                d.set_item("name", &t.name)?;
                d.set_item("centre", t.centre)?;
                d.set_item("sigma", t.sigma)?;
                Ok(d)
            })
            .collect()
    }
    /// The share of each prior parameter's information that came from the
    /// data, ``1 - sigma_post**2 / sigma_prior**2`` (0: all from its
    /// tolerance, 1: all measured), by name.
    #[getter(from_data)]
    fn information_from_data<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.cal()
                .parameters
                .iter()
                .filter_map(|p| p.from_data.map(|f| (p.name.clone(), f))),
        )
    }
    /// ``0.5 * sum(fun**2)``, in the readings' units squared (mm² for
    /// positions): scipy's ``cost``.
    #[getter]
    fn cost(&self) -> f64 {
        0.5 * self.cal().residuals.iter().map(|r| r * r).sum::<f64>()
    }
    /// Residual evaluations of the final fit.
    #[getter]
    fn nfev(&self) -> usize {
        self.cal().evaluations
    }
    /// Jacobian evaluations of the final fit.
    #[getter]
    fn njev(&self) -> usize {
        self.cal().iterations + 1
    }
    /// Why the solver stopped, as a number: 0 evaluation budget exhausted
    /// (``max_nfev``), 1 ``gtol``, 2 ``ftol``, 3 ``xtol``, 4 ``ftol`` and
    /// ``xtol``, 5 no further progress at machine precision, 6 nothing free;
    /// -1 the model could not be evaluated at the start, -2 cancelled. 1–5
    /// are a success. ``message`` says it in words.
    #[getter]
    fn status(&self) -> i32 {
        use pkmcal::lm::Termination as T;
        match self.cal().termination {
            T::MaxEvaluations => 0,
            T::SmallGradient => 1,
            T::SmallReduction => 2,
            T::SmallStep => 3,
            T::SmallReductionAndStep => 4,
            T::MachinePrecision => 5,
            T::NothingFree => 6,
            T::EvaluationFailed(_) => -1,
            T::Cancelled => -2,
        }
    }
    /// Why the solver stopped, in words.
    #[getter]
    fn message(&self) -> String {
        self.cal().termination_reason.clone()
    }
    /// Whether the fit converged (``converged``).
    #[getter]
    fn success(&self) -> bool {
        self.cal().converged
    }
    /// The summary the command-line tool prints, in Python's words.
    fn summary(&self) -> String {
        let mut out = String::new();
        pkmcal_io::text::write_summary(
            &mut out,
            &self.report(),
            &self.state.measurement,
            &PY_WORDING,
        );
        out
    }
    fn __str__(&self) -> String {
        self.summary()
    }
    /// Rank, singular values and unidentifiable combinations.
    #[getter]
    fn identifiability(&self) -> PyIdentifiability {
        PyIdentifiability {
            id: self.cal().identifiability.clone(),
        }
    }
    /// Error statistics at nominal parameters, on the poses the fit kept.
    #[getter]
    fn before(&self) -> PyErrorStats {
        (&self.study().accuracy.before).into()
    }
    /// Error statistics with the identified parameters.
    #[getter]
    fn after(&self) -> PyErrorStats {
        (&self.study().accuracy.after).into()
    }
    /// Errors of the distances measured between two poses (``distances=``),
    /// mm: a dict with ``count``, ``before_max``, ``before_rms``,
    /// ``after_max``, ``after_rms`` and the arrays ``before``, ``after``
    /// (measured minus predicted); ``None`` without distances.
    #[getter]
    fn distances<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(d) = &self.study().accuracy.distances else {
            return Ok(None);
        };
        let out = PyDict::new(py);
        out.set_item("count", d.count)?;
        out.set_item("before_max", d.before_max)?;
        out.set_item("before_rms", d.before_rms)?;
        out.set_item("after_max", d.after_max)?;
        out.set_item("after_rms", d.after_rms)?;
        out.set_item("before", numpy::PyArray1::from_slice(py, &d.before))?;
        out.set_item("after", numpy::PyArray1::from_slice(py, &d.after))?;
        Ok(Some(out))
    }
    /// Improvement of the largest and the RMS distance error, in percent:
    /// ``(max, rms)``.
    #[getter]
    fn improvement(&self) -> (f64, f64) {
        (
            self.study().accuracy.improvement_max_percent,
            self.study().accuracy.improvement_rms_percent,
        )
    }
    /// Before and after on the validation poses (``validation=`` or
    /// ``holdout=``): ``(before, after)``, or None.
    #[getter]
    fn validation(&self) -> Option<(PyErrorStats, PyErrorStats)> {
        self.study()
            .validation
            .as_ref()
            .map(|v| ((&v.accuracy.before).into(), (&v.accuracy.after).into()))
    }
    /// k-fold cross-validation (``kfold=``): ``{"folds", "fold_rms", "pooled"}``, or None.
    #[getter]
    fn cross_validation<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(cv) = &self.study().cross_validation else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("folds", cv.folds)?;
        d.set_item("fold_rms", vec1(py, &cv.fold_rms))?;
        d.set_item("pooled", Py::new(py, PyErrorStats::from(&cv.pooled))?)?;
        Ok(Some(d))
    }
    /// Warnings: unidentifiable directions fixed, no convergence, outliers…
    #[getter]
    fn warnings(&self) -> Vec<PyWarning> {
        self.cal().warnings.iter().map(warning).collect()
    }
    /// Whether the solver converged.
    #[getter]
    fn converged(&self) -> bool {
        self.cal().converged
    }
    /// Why the solver stopped.
    #[getter]
    fn termination(&self) -> String {
        self.cal().termination_reason.clone()
    }
    /// Solver iterations.
    #[getter]
    fn iterations(&self) -> usize {
        self.cal().iterations
    }
    /// Forward model used: ``rigid``, ``linear`` or ``exact``.
    #[getter]
    fn model(&self) -> &'static str {
        self.cal().model.name()
    }
    /// Weighted sum of squared residuals at the solution.
    #[getter]
    fn sum_of_squares(&self) -> f64 {
        self.cal().sum_of_squares
    }
    /// Noise scale estimated from the residuals (1 when the σ given fit).
    #[getter]
    fn unit_weight_sigma(&self) -> f64 {
        self.cal().unit_weight_sigma
    }
    /// Names of the readings (columns of ``measured`` and ``residuals``).
    #[getter]
    fn axes(&self) -> Vec<String> {
        self.state.measurement.axes().to_vec()
    }
    /// Units of the readings.
    #[getter]
    fn axis_units(&self) -> Vec<&'static str> {
        self.state
            .measurement
            .units()
            .iter()
            .map(|u| u.symbol())
            .collect()
    }
    /// Residuals (predicted minus measured), shape (poses kept, axes).
    #[getter]
    fn residuals<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        out2(
            py,
            self.cal().residuals.clone(),
            self.state.measurement.len(),
            false,
        )
    }
    /// Rows (from 0) of the poses the fit kept.
    #[getter]
    fn poses(&self) -> Vec<usize> {
        self.study()
            .poses
            .iter()
            .filter_map(|m| m.origin.map(|o| o.pose))
            .collect()
    }
    /// Poses beyond the outlier threshold: dicts with ``pose`` (row),
    /// ``residual`` and ``standardized``.
    #[getter]
    fn outliers<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.cal()
            .outliers
            .iter()
            .map(|o| {
                let d = PyDict::new(py);
                d.set_item("pose", o.origin.pose)?;
                d.set_item("residual", vec1(py, &o.residual))?;
                d.set_item("standardized", o.standardized)?;
                Ok(d)
            })
            .collect()
    }
    /// Rows dropped as outliers (``drop_outliers=True``).
    #[getter]
    fn dropped(&self) -> Vec<usize> {
        self.cal().dropped.iter().map(|o| o.pose).collect()
    }
    /// Parameter file text (``name = value`` in mm, rad, N·m/rad), the format
    /// the command-line tool reads with ``--params``.
    fn to_toml(&self) -> String {
        let spec = self.mech().spec();
        let header = format!(
            "pkmcal {} calibration ({} model) of {} from Python\nsolver: {}",
            env!("CARGO_PKG_VERSION"),
            self.cal().model.name(),
            spec.name,
            self.cal().termination_reason
        );
        pkmcal_io::params::params_to_string(spec, &self.cal().params, &header)
    }
    /// The report's figures: errors per pose, parameter changes, workspace
    /// errors and maps, residuals, singular values.
    fn figures(&self, py: Python<'_>) -> PyResult<Vec<PyFigure>> {
        let figs = interruptible(py, |cancel| {
            self.with_inputs(|i| pkmcal_io::report::figures_cancellable(i, Some(&cancel)))
        })?
        .map_err(io_err)?;
        Ok(figs
            .into_iter()
            .map(|f| PyFigure {
                name: f.name.into(),
                title: f.title,
                caption: f.caption,
                svg: f.svg,
                png: PyBytes::new(py, &f.png).unbind(),
            })
            .collect())
    }
    /// Write the calibration record to ``path``: the JSON report
    /// ``pkmcal calibrate --report`` writes (versioned, with the mechanism's
    /// identity and the covariance), which :func:`load_calibration` and
    /// ``pkmcal predict --uncertainty`` read back.
    fn save(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = path_arg(path)?;
        let json = interruptible(py, |cancel| {
            self.report().to_json_cancellable(Some(&cancel))
        })?
        .map_err(io_err)?;
        written(|run| run.files.stage(std::path::Path::new(&p), json.as_bytes()))
    }
    /// Write the report (report.html with every figure as SVG and PNG) into
    /// the directory ``path`` (created if needed).
    fn save_report(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = path_arg(path)?;
        let files = pkmcal_io::Files::new();
        let staged = interruptible(py, |cancel| {
            let run = pkmcal_io::Run::quiet(&files);
            self.with_inputs(|i| {
                pkmcal_io::report::write_report_dir_cancellable(
                    &run,
                    std::path::Path::new(&p),
                    i,
                    Some(&cancel),
                )
            })
        })?;
        // Interrupted or failed: `files` is dropped, and what it staged with it.
        staged.and_then(|()| files.commit()).map_err(io_err)
    }
    /// Read a calibration saved whole (:meth:`save`, or ``pkmcal calibrate
    /// --report`` of this version): the same calibration, to the bit, with
    /// its mechanism (the description saved with it), figures, residuals
    /// and uncertainties. A record written by an older pkmcal holds only
    /// parameters and covariance; read it with :func:`load_calibration`.
    /// ``Calibration.load(path)`` calls it; on a calibration, ``cal.load``
    /// is its tool load.
    #[staticmethod]
    fn _load_file(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let p = path_arg(path)?;
        let text = reading_records(|run| {
            run.files
                .read_to_string(std::path::Path::new(&p), pkmcal_io::output::InputKind::Data)
        })
        .map_err(io_err)?;
        Self::from_record(py, &text, &p)
    }
    /// ``Calibration.load(path)`` reads a calibration saved whole
    /// (:meth:`save`); ``cal.load`` is the tool load during the
    /// measurements (N, N·m; one value per tool axis), or None without one.
    #[classattr]
    fn load() -> LoadAttribute {
        LoadAttribute
    }
    /// The tool load during the measurements (N, N·m; one value per tool
    /// axis), or None without one: ``cal.load``.
    fn _tool_load<'py>(&self, py: Python<'py>) -> Option<Bound<'py, numpy::PyArray1<f64>>> {
        (!self.state.load.is_empty()).then(|| vec1(py, &self.state.load))
    }
    /// The identified parameters as a pandas DataFrame, one row per
    /// parameter (the mechanism's, then the instrument's), indexed by name:
    /// ``value`` (identified; the start where fixed), ``nominal``,
    /// ``change``, ``sd`` (standard deviation; NaN where fixed), ``unit``,
    /// ``free``, ``tolerance`` (the prior's σ; NaN without one),
    /// ``from_data`` (the share of a prior parameter's information that
    /// came from the data; NaN without a tolerance), ``note``. Pass it as ``params`` to predict or compensate.
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let ps = &self.cal().parameters;
        let col = |f: &dyn Fn(&pkmcal::identify::ParameterResult) -> f64| {
            vec1(py, &ps.iter().map(f).collect::<Vec<_>>()).into_any()
        };
        let names: Vec<&str> = ps.iter().map(|p| p.name.as_str()).collect();
        frame(
            py,
            vec![
                ("value".into(), col(&|p| p.identified)),
                ("nominal".into(), col(&|p| p.nominal)),
                ("change".into(), col(&|p| p.change)),
                (
                    "sd".into(),
                    col(&|p| if p.free { p.std_dev } else { f64::NAN }),
                ),
                (
                    "unit".into(),
                    pyo3::types::PyList::new(py, ps.iter().map(|p| p.unit.symbol()))?.into_any(),
                ),
                (
                    "free".into(),
                    numpy::PyArray1::from_iter(py, ps.iter().map(|p| p.free)).into_any(),
                ),
                (
                    "tolerance".into(),
                    col(&|p| p.tolerance.unwrap_or(f64::NAN)),
                ),
                (
                    "from_data".into(),
                    col(&|p| p.from_data.unwrap_or(f64::NAN)),
                ),
                (
                    "note".into(),
                    pyo3::types::PyList::new(py, ps.iter().map(|p| p.note.clone()))?.into_any(),
                ),
            ],
            Some(pyo3::types::PyList::new(py, names)?.into_any()),
            Some("parameter"),
        )
    }
    /// The mechanism calibrated.
    #[getter]
    fn mechanism(&self, py: Python<'_>) -> Py<PyMechanism> {
        self.mechanism.clone_ref(py)
    }
    /// Pickled in binary (:mod:`pickle` of the arrays' bytes, the small
    /// rest in CBOR) with its mechanism, so that a process-pool worker can
    /// return it; read back, it is the same calibration to the bit.
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<Reduced<'py, (Py<PyMechanism>, Bound<'py, PyDict>)>> {
        let py = slf.py();
        let c = slf.get();
        Ok((
            py.get_type::<PyCalibration>().getattr("_from_pickle")?,
            (
                c.mechanism.clone_ref(py),
                crate::results::pickle::pack(py, &c.state)?,
            ),
        ))
    }
    /// A calibration from what :meth:`__reduce__` gave (or, from an older
    /// pkmcal, its record's JSON text).
    #[staticmethod]
    fn _from_pickle(
        py: Python<'_>,
        mechanism: &Bound<'_, PyMechanism>,
        state: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let m = mechanism.get();
        let mechanism = PyMechanism {
            mech: m.mech.clone(),
            targets: m.targets.clone(),
            tolerances: m.tolerances.clone(),
            setup: m.setup.clone(),
            source: m.source.clone(),
            text: m.text.clone(),
        };
        if let Ok(record) = state.extract::<String>() {
            let (r, state) = pkmcal_io::record::record_from_str(&record, "a pickled calibration")
                .map_err(io_err)?;
            let state = state.ok_or_else(|| usage("a pickled calibration without its state"))?;
            return Self::checked(py, mechanism, state, &r, "a pickled calibration");
        }
        let state = crate::results::pickle::unpack(state.cast::<PyDict>()?)?;
        // The calibration's sizes are checked against the mechanism.
        let record =
            pkmcal::identify::CalibrationRecord::new(mechanism.spec(), &state.study.calibration);
        Self::checked(py, mechanism, state, &record, "a pickled calibration")
    }
    /// Equal when everything is: the mechanism, the instrument, the data,
    /// every result (NaN equal to NaN).
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        let Ok(o) = other.cast::<PyCalibration>() else {
            return Ok(false);
        };
        let o = o.get();
        let (a, b) = (self.mechanism.get(), o.mechanism.get());
        if !(a.spec() == b.spec() && a.targets == b.targets && a.setup == b.setup) {
            return Ok(false);
        }
        let bytes = |s: &CalibrationState| pkmcal_io::record::state_bytes(s).map_err(io_err);
        Ok(bytes(&self.state)? == bytes(&o.state)?)
    }
    /// The summary as an HTML table (a notebook shows it).
    fn _repr_html_(&self) -> String {
        use std::fmt::Write;
        let esc = pkmcal_io::report::escape;
        let mut h = format!(
            "<p><b>Calibration of {}</b> ({} model, {} poses, {}): distance error RMS {:.4} → {:.4} mm, max {:.4} → {:.4} mm</p>",
            esc(&self.mech().spec().name),
            self.cal().model.name(),
            self.cal().poses,
            if self.cal().converged {
                "converged"
            } else {
                "<b>not converged</b>"
            },
            self.study().accuracy.before.distance_rms,
            self.study().accuracy.after.distance_rms,
            self.study().accuracy.before.distance_max,
            self.study().accuracy.after.distance_max,
        );
        if let Some(v) = &self.study().validation {
            let _ = write!(
                h,
                "<p>validation on {}: distance error RMS {:.4} → {:.4} mm, max {:.4} → {:.4} mm</p>",
                esc(&validation_words(v.source)),
                v.accuracy.before.distance_rms,
                v.accuracy.after.distance_rms,
                v.accuracy.before.distance_max,
                v.accuracy.after.distance_max,
            );
        }
        if let Some(cv) = &self.study().cross_validation {
            let _ = write!(
                h,
                "<p>{}-fold cross-validation: held-out distance error RMS {:.4} mm pooled, max {:.4} mm; per fold {}</p>",
                cv.folds,
                cv.pooled.distance_rms,
                cv.pooled.distance_max,
                cv.fold_rms
                    .iter()
                    .map(|v| format!("{v:.4}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        h.push_str("<table><tr><th>parameter</th><th>nominal</th><th>identified</th><th>change</th><th>std dev</th><th>unit</th></tr>");
        for p in self.cal().parameters.iter().filter(|p| p.free) {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{:.6}</td><td>{:.6}</td><td>{:+.3e}</td><td>{:.2e}</td><td>{}</td></tr>",
                esc(&p.name),
                p.nominal,
                p.identified,
                p.change,
                p.std_dev,
                esc(p.unit.symbol())
            );
        }
        h.push_str("</table>");
        for w in &self.cal().warnings {
            let _ = write!(h, "<p>⚠ {} ({})</p>", esc(&w.message), esc(&w.hint));
        }
        h
    }
    fn __repr__(&self) -> String {
        format!(
            "<Calibration of {} ({} model, {} poses, {} free, {}): distance rms {:.4} -> {:.4} mm, max {:.4} -> {:.4} mm; {} warning(s)>",
            self.mech().spec().name,
            self.cal().model.name(),
            self.cal().poses,
            self.cal().free.len(),
            if self.cal().converged {
                "converged"
            } else {
                "NOT converged"
            },
            self.study().accuracy.before.distance_rms,
            self.study().accuracy.after.distance_rms,
            self.study().accuracy.before.distance_max,
            self.study().accuracy.after.distance_max,
            self.cal().warnings.len()
        )
    }
}

impl PyCalibration {
    pub fn study(&self) -> &pkmcal::identify::Study {
        &self.state.study
    }
    pub fn cal(&self) -> &LibCalibration {
        &self.state.study.calibration
    }
    pub fn mech(&self) -> &Arc<AnyMechanism> {
        &self.mechanism.get().mech
    }

    /// The JSON report of this calibration (the calibration record).
    pub fn report(&self) -> pkmcal_io::record::Report<'_> {
        pkmcal_io::record::Report::new(
            self.mech().spec(),
            "Python arrays".into(),
            &self.state,
            validation_words,
        )
    }

    /// A calibration from its record's text (``source`` names it), with
    /// the mechanism of its state, checked against the record.
    pub fn from_record(py: Python<'_>, text: &str, source: &str) -> PyResult<Self> {
        let (record, state) = pkmcal_io::record::record_from_str(text, source).map_err(io_err)?;
        let Some(state) = state else {
            return Err(usage(format!(
                "{source}: this calibration record holds only the parameters and their covariance (an older pkmcal wrote it); read it with pkmcal.load_calibration, or calibrate again and save"
            )));
        };
        let mechanism = match &state.mechanism {
            MechanismSource::Reference => PyMechanism::reference(),
            MechanismSource::Description(t) => {
                PyMechanism::from_text(t, format!("the description saved in {source}"))?
            }
        };
        Self::checked(py, mechanism, state, &record, source)
    }

    /// `state` of `mechanism`, checked against its record.
    pub fn checked(
        py: Python<'_>,
        mechanism: PyMechanism,
        state: CalibrationState,
        record: &pkmcal::identify::CalibrationRecord,
        source: &str,
    ) -> PyResult<Self> {
        let spec = mechanism.spec();
        record
            .check(spec)
            .map_err(|e| usage(format!("{source}: {e}")))?;
        let cal = &state.study.calibration;
        if cal.params.values.len() != spec.n_params()
            || state.measurement.param_names().len() != cal.measurement.len()
        {
            return Err(usage(format!(
                "{source}: its state does not fit {} (other parameters or instrument)",
                spec.name
            )));
        }
        Ok(Self {
            mechanism: Py::new(py, mechanism)?,
            state,
        })
    }
    /// `f` with what the HTML report and the figures show.
    pub fn with_inputs<T>(&self, f: impl FnOnce(&pkmcal_io::report::ReportInputs) -> T) -> T {
        let report = self.report();
        f(&pkmcal_io::report::ReportInputs {
            report: &report,
            wording: &PY_WORDING,
            mech: self.mech(),
            measurement: &self.state.measurement,
            data: &self.study().poses,
            before: &self.study().before,
            after: &self.study().after,
        })
    }
}

/// A calibration read back from its record (:meth:`Calibration.save`, or
/// ``pkmcal calibrate --report``): the identified parameters and their
/// covariance, and the identity of the mechanism it is of. Pass it as
/// ``params`` (with ``uncertainty=True`` for standard deviations); it serves
/// only the mechanism it is of.
#[pyclass(frozen, module = "pkmcal", name = "SavedCalibration")]
pub struct PySavedCalibration {
    pub record: pkmcal::identify::CalibrationRecord,
    /// The file it was read from.
    pub source: String,
    /// The degrees of freedom of its estimated noise level, if recorded.
    pub dof: Option<f64>,
}

#[pymethods]
impl PySavedCalibration {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when the records are (NaN equal to NaN) and were read from
    /// the same file.
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The calibrated mechanism's name.
    #[getter]
    fn mechanism(&self) -> String {
        self.record.mechanism.clone()
    }
    /// The mechanism's identity (its joints, parameters and nominal values).
    #[getter]
    fn mechanism_identity(&self) -> String {
        self.record.mechanism_identity.clone()
    }
    /// The record's version (0 for a report written before versions).
    #[getter]
    fn version(&self) -> u32 {
        self.record.version
    }
    /// The model the parameters were identified with.
    #[getter]
    fn model(&self) -> &'static str {
        self.record.model.name()
    }
    /// Every parameter's identified value, by name.
    #[getter]
    fn parameters(&self) -> std::collections::BTreeMap<String, f64> {
        self.record
            .parameters
            .iter()
            .map(|p| (p.name.clone(), p.identified))
            .collect()
    }
    /// Covariance of the identified parameters (``covariance_names`` order).
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let c = &self.record.covariance;
        out2(py, c.matrix.concat(), c.names.len(), false)
    }
    /// Row and column names of ``covariance``.
    #[getter]
    fn covariance_names(&self) -> Vec<String> {
        self.record.covariance.names.clone()
    }
    fn __repr__(&self) -> String {
        format!(
            "<SavedCalibration of {} ({} model, version {}) from {}>",
            self.record.mechanism,
            self.record.model.name(),
            self.record.version,
            self.source
        )
    }
}

/// Read a calibration record (:meth:`Calibration.save`, ``pkmcal calibrate
/// --report``): ``load_calibration(path)``.
#[pyfunction]
pub fn load_calibration(args: &Bound<'_, PyDict>) -> PyResult<PySavedCalibration> {
    let kw = crate::keywords::Kw::new(args.clone());
    let p = path_arg(&kw.required("path")?)?;
    let (record, dof) = reading_records(|run| {
        pkmcal_io::record::read_calibration_record_dof(run, std::path::Path::new(&p))
    })
    .map_err(io_err)?;
    Ok(PySavedCalibration {
        record,
        source: p,
        dof,
    })
}

/// ``Calibration.load``: on the class, the reader of a saved calibration
/// (``Calibration.load(path)``); on a calibration, its tool load
/// (``cal.load``), which the reader would otherwise hide.
#[pyclass(frozen, module = "pkmcal", name = "_LoadAttribute")]
pub struct LoadAttribute;

#[pymethods]
impl LoadAttribute {
    fn __get__<'py>(
        &self,
        instance: Option<&Bound<'py, PyAny>>,
        owner: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        match instance.filter(|i| !i.is_none()) {
            Some(i) => i.call_method0("_tool_load"),
            None => {
                let owner = owner.ok_or_else(|| usage("Calibration.load: no class"))?;
                owner.getattr("_load_file")
            }
        }
    }
}

by_serde!(PySavedCalibration { record; source, dof });
