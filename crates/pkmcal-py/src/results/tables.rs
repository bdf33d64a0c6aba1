//! Results that are tables: predictions, compensations, plans, Monte Carlo
//! studies, tolerance budgets and drift tests. Each pickles and compares by
//! value, shows its table in a notebook and gives it as a pandas DataFrame.

use crate::arrays::{frame, named_columns, out2, vec1};
use crate::errors::{DIRECT, deprecated};
use crate::results::{
    ByValue, HTML_ROWS, Reduced, by_name, eq_by_value, g4, html_table, p_text, reduce,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

/// The rows of a 2-D NumPy array as text for a table, at most
/// [`HTML_ROWS`].
fn text_rows(a: &Bound<'_, PyAny>) -> PyResult<Vec<Vec<String>>> {
    let a = if a.getattr("ndim")?.extract::<usize>()? == 1 {
        a.call_method1("reshape", (1, -1))?
    } else {
        a.clone()
    };
    let n: usize = a.len()?;
    (0..n.min(HTML_ROWS + 1))
        .map(|i| {
            let row: Vec<f64> = a.get_item(i)?.extract()?;
            Ok(row.into_iter().map(g4).collect())
        })
        .collect()
}

/// Predicted tool positions and what the model computed with them.
#[pyclass(frozen, module = "pkmcal", name = "Prediction")]
pub struct PyPrediction {
    /// Tool coordinates, shape (n, axes).
    #[pyo3(get)]
    pub x: Py<PyAny>,
    /// Joint configurations, shape (n, joints); None unless asked for
    /// (``outputs``).
    #[pyo3(get)]
    pub q: Option<Py<PyAny>>,
    /// Internal actuator loads, shape (n, actuators): N·m for revolute, N for
    /// prismatic actuators; None unless asked for.
    #[pyo3(get)]
    pub torque: Option<Py<PyAny>>,
    /// Deflections of the actuated joints (rad or mm), shape (n, actuators);
    /// None unless asked for.
    #[pyo3(get)]
    pub deflection: Option<Py<PyAny>>,
    /// Covariance of ``x`` (n, axes, axes) from a calibration's parameter
    /// covariance, when asked for with ``uncertainty=True``; else None.
    #[pyo3(get)]
    pub covariance: Option<Py<PyAny>>,
    /// Rows whose commands did not assemble the mechanism on its branch
    /// (``skip_unreachable=True``; their outputs are NaN), from 0.
    #[pyo3(get)]
    pub skipped: Vec<usize>,
    /// Names of the tool axes, joints and actuators (the columns).
    pub names: (Vec<String>, Vec<String>, Vec<String>),
    /// The commands' pandas index, if they had one.
    pub index: Option<Py<PyAny>>,
}

#[pymethods]
impl PyPrediction {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is (arrays elementwise, NaN equal to NaN).
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The predictions as a pandas DataFrame, one row per row of commands
    /// (their index when they had one): the tool axes, then what else was
    /// computed (joints ``q_<joint>``, ``torque_<actuator>``,
    /// ``deflection_<actuator>``).
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let (axes, joints, actuators) = &self.names;
        let mut cols = named_columns(self.x.bind(py), axes, "")?;
        for (a, names, prefix) in [
            (&self.q, joints, "q_"),
            (&self.torque, actuators, "torque_"),
            (&self.deflection, actuators, "deflection_"),
        ] {
            if let Some(a) = a {
                let prefixed: Vec<String> = names.iter().map(|n| format!("{prefix}{n}")).collect();
                cols.extend(named_columns(a.bind(py), &prefixed, "")?);
            }
        }
        frame(
            py,
            cols,
            self.index.as_ref().map(|i| i.bind(py).clone()),
            None,
        )
    }
    /// The tool positions as a table (a notebook shows it).
    fn _repr_html_(&self, py: Python<'_>) -> PyResult<String> {
        let x = self.x.bind(py);
        let n: usize = if x.getattr("ndim")?.extract::<usize>()? == 1 {
            1
        } else {
            x.len()?
        };
        let axes: Vec<&str> = self.names.0.iter().map(String::as_str).collect();
        let mut rows = text_rows(x)?;
        if n > rows.len() {
            rows.resize(n.min(HTML_ROWS + 1), vec![]);
        }
        Ok(html_table(
            &format!(
                "<b>Prediction</b> of {n} tool pose(s){}",
                if self.skipped.is_empty() {
                    String::new()
                } else {
                    format!(", {} skipped (NaN)", self.skipped.len())
                }
            ),
            &axes,
            &rows,
        ))
    }
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!("<Prediction x={}>", self.x.bind(py).repr()?))
    }
}

by_value!(PyPrediction {
    x,
    q,
    torque,
    deflection,
    covariance,
    skipped,
    names,
    index
});

/// Commands that bring the tool to its targets.
#[pyclass(frozen, module = "pkmcal", name = "Compensation")]
pub struct PyCompensation {
    /// Commands to send, shape (n, actuators).
    #[pyo3(get)]
    pub commands: Py<PyAny>,
    /// Commands of the nominal model for the same targets.
    #[pyo3(get)]
    pub nominal: Py<PyAny>,
    /// ``commands - nominal``.
    #[pyo3(get)]
    pub correction: Py<PyAny>,
    /// Internal actuator loads at the compensated pose (N·m or N).
    #[pyo3(get)]
    pub torque: Py<PyAny>,
    /// Joint configurations, shape (n, joints).
    #[pyo3(get)]
    pub q: Py<PyAny>,
    /// Rows whose target could not be reached (``skip_unreachable=True``;
    /// their values are NaN).
    #[pyo3(get)]
    pub skipped: Vec<usize>,
    /// Names of the actuators (the columns).
    pub actuators: Vec<String>,
    /// The targets' pandas index, if they had one.
    pub index: Option<Py<PyAny>>,
}

#[pymethods]
impl PyCompensation {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is (arrays elementwise, NaN equal to NaN).
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The commands as a pandas DataFrame, one row per target (their
    /// index when they had one): each actuator's command, then
    /// ``correction_<actuator>`` and ``torque_<actuator>``.
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let mut cols = named_columns(self.commands.bind(py), &self.actuators, "")?;
        cols.extend(
            named_columns(self.correction.bind(py), &self.actuators, "")?
                .into_iter()
                .map(|(n, c)| (format!("correction_{n}"), c)),
        );
        cols.extend(
            named_columns(self.torque.bind(py), &self.actuators, "")?
                .into_iter()
                .map(|(n, c)| (format!("torque_{n}"), c)),
        );
        frame(
            py,
            cols,
            self.index.as_ref().map(|i| i.bind(py).clone()),
            None,
        )
    }
    /// The commands as a table (a notebook shows it).
    fn _repr_html_(&self, py: Python<'_>) -> PyResult<String> {
        let names: Vec<&str> = self.actuators.iter().map(String::as_str).collect();
        Ok(html_table(
            &format!(
                "<b>Compensated commands</b>{}",
                if self.skipped.is_empty() {
                    String::new()
                } else {
                    format!(", {} target(s) unreachable (NaN)", self.skipped.len())
                }
            ),
            &names,
            &text_rows(self.commands.bind(py))?,
        ))
    }
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "<Compensation commands={}>",
            self.commands.bind(py).repr()?
        ))
    }
}

by_value!(PyCompensation {
    commands,
    nominal,
    correction,
    torque,
    q,
    skipped,
    actuators,
    index
});

/// A measurement plan.
#[pyclass(frozen, module = "pkmcal", name = "Plan", get_all)]
pub struct PyPlan {
    /// Chosen tool positions, shape (count, axes).
    pub targets: Py<PyAny>,
    /// Their nominal commands, shape (count, actuators).
    pub commands: Py<PyAny>,
    /// Observability indices O1…O5 of the plan.
    pub observability: Py<PyDict>,
    /// Condition number of the plan's scaled identification Jacobian.
    pub condition: f64,
    /// A plain grid of the same size (the baseline), shape (count, axes).
    pub grid_targets: Py<PyAny>,
    /// Observability of the grid.
    pub grid_observability: Py<PyDict>,
    /// Condition number of the grid.
    pub grid_condition: f64,
    /// Candidate lattice spacing used (mm).
    pub spacing: f64,
    /// Candidates scored.
    pub candidates: usize,
    /// Parameter directions the chosen poses determine (below the number of
    /// free parameters: some are left unidentified; an
    /// ``IdentifiabilityWarning`` says so).
    pub rank: usize,
    /// Number of free parameters.
    pub free: usize,
    /// Names of the tool axes and of the actuators (the columns).
    pub columns: (Vec<String>, Vec<String>),
}

#[pymethods]
impl PyPlan {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is (arrays elementwise, NaN equal to NaN).
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The plan as a pandas DataFrame, one row per pose (in the order
    /// chosen): the target's tool axes, then each actuator's nominal
    /// command.
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let (axes, actuators) = &self.columns;
        let mut cols = named_columns(self.targets.bind(py), axes, "")?;
        cols.extend(named_columns(self.commands.bind(py), actuators, "")?);
        frame(py, cols, None, Some("pose"))
    }
    /// The poses as a table (a notebook shows it).
    fn _repr_html_(&self, py: Python<'_>) -> PyResult<String> {
        let (axes, actuators) = &self.columns;
        let header: Vec<&str> = axes.iter().chain(actuators).map(String::as_str).collect();
        let targets = text_rows(self.targets.bind(py))?;
        let commands = text_rows(self.commands.bind(py))?;
        let rows: Vec<Vec<String>> = targets
            .into_iter()
            .zip(commands)
            .map(|(mut t, c)| {
                t.extend(c);
                t
            })
            .collect();
        let n: usize = self.targets.bind(py).len()?;
        Ok(html_table(
            &format!(
                "<b>Plan</b> of {n} poses: condition {} (plain grid {}), rank {} of {} free, {} candidates",
                g4(self.condition),
                g4(self.grid_condition),
                self.rank,
                self.free,
                self.candidates
            ),
            &header,
            &rows,
        ))
    }
    fn __repr__(&self) -> String {
        format!(
            "<Plan: {} candidates, condition {:.2} (plain grid {:.2})>",
            self.candidates, self.condition, self.grid_condition
        )
    }
}

by_value!(PyPlan {
    targets,
    commands,
    observability,
    condition,
    grid_targets,
    grid_observability,
    grid_condition,
    spacing,
    candidates,
    rank,
    free,
    columns
});

/// A tolerance budget (:func:`budget`): the tool error the tolerances give
/// over the workspace, each tolerance's share, and what a planned
/// calibration would leave.
#[pyclass(frozen, module = "pkmcal", name = "Budget")]
pub struct PyBudget {
    pub b: pkmcal::apply::budget::Budget,
    /// The mechanism's name, for the summary.
    pub mechanism: String,
}

fn spread_dict<'py>(
    py: Python<'py>,
    s: &pkmcal::apply::budget::ErrorSpread,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("position_rms", s.position_rms)?;
    d.set_item("position_worst", s.position_worst)?;
    d.set_item("axis_rms", vec1(py, &s.axis_rms))?;
    Ok(d)
}

#[pymethods]
impl PyBudget {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is.
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The error to first order: ``position_rms`` and ``position_worst``
    /// (mm), ``axis_rms`` (each axis's unit).
    #[getter]
    fn first_order<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        spread_dict(py, &self.b.first_order)
    }
    /// The same from machines drawn from the tolerances through the exact
    /// model (``samples`` of them), or None.
    #[getter]
    fn monte_carlo<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.b
            .monte_carlo
            .as_ref()
            .map(|s| spread_dict(py, s))
            .transpose()
    }
    /// What the planned calibration (``poses=``) would leave, or None.
    #[getter]
    fn after_calibration<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.b
            .after_calibration
            .as_ref()
            .map(|s| spread_dict(py, s))
            .transpose()
    }
    /// Each tolerance's share of the position error variance, by name
    /// (largest first; they add up to 1).
    #[getter]
    fn shares<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.b.tolerances.iter().map(|t| (t.name.clone(), t.share)),
        )
    }
    /// Each tolerance (one σ, its unit), by name.
    #[getter]
    fn tolerances<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        by_name(
            py,
            self.b.tolerances.iter().map(|t| (t.name.clone(), t.sigma)),
        )
    }
    /// Each parameter's σ after the planned calibration, by name, or None.
    #[getter]
    fn sigma_after<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        if self.b.after_calibration.is_none() {
            return Ok(None);
        }
        by_name(
            py,
            self.b
                .tolerances
                .iter()
                .map(|t| (t.name.clone(), t.sigma_after.unwrap_or(f64::NAN))),
        )
        .map(Some)
    }
    /// Tool axes (columns of ``axis_rms``).
    #[getter]
    fn axes(&self) -> Vec<String> {
        self.b.axes.clone()
    }
    /// Workspace targets the error is taken over.
    #[getter]
    fn targets(&self) -> usize {
        self.b.targets
    }
    /// Monte Carlo samples drawn.
    #[getter]
    fn samples(&self) -> usize {
        self.b.samples
    }
    /// The budget in words, as ``pkmcal budget`` prints it.
    fn summary(&self) -> String {
        pkmcal_io::text::budget_words(
            &self.mechanism,
            &self.b,
            self.b
                .after_calibration
                .as_ref()
                .map(|_| "poses".to_string()),
        )
    }
    fn __str__(&self) -> String {
        self.summary()
    }
    /// The tolerances as a pandas DataFrame, largest share first, indexed
    /// by parameter: ``sigma`` (the tolerance, its ``unit``), ``share`` of
    /// the position error variance, ``sigma_after`` (after the planned
    /// calibration; NaN without one).
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let t = &self.b.tolerances;
        let col = |f: &dyn Fn(&pkmcal::apply::budget::ToleranceShare) -> f64| {
            vec1(py, &t.iter().map(f).collect::<Vec<_>>()).into_any()
        };
        frame(
            py,
            vec![
                ("sigma".into(), col(&|t| t.sigma)),
                (
                    "unit".into(),
                    PyList::new(py, t.iter().map(|t| t.unit.symbol()))?.into_any(),
                ),
                ("share".into(), col(&|t| t.share)),
                (
                    "sigma_after".into(),
                    col(&|t| t.sigma_after.unwrap_or(f64::NAN)),
                ),
            ],
            Some(PyList::new(py, t.iter().map(|t| t.name.as_str()))?.into_any()),
            Some("parameter"),
        )
    }
    /// The budget as a table (a notebook shows it).
    fn _repr_html_(&self) -> String {
        let b = &self.b;
        let after = b
            .after_calibration
            .as_ref()
            .map(|a| format!("; after the planned calibration {} mm", g4(a.position_rms)));
        let mc = b
            .monte_carlo
            .as_ref()
            .map(|m| format!(" ({} machines drawn: {} mm)", b.samples, g4(m.position_rms)));
        let with_after = b.after_calibration.is_some();
        let mut header = vec!["parameter", "tolerance", "unit", "share"];
        if with_after {
            header.push("σ after");
        }
        html_table(
            &format!(
                "<b>Tolerance budget of {}</b>: position error RMS {} mm over {} targets, worst {} mm{}{}",
                pkmcal_io::report::escape(&self.mechanism),
                g4(b.first_order.position_rms),
                b.targets,
                g4(b.first_order.position_worst),
                mc.unwrap_or_default(),
                after.unwrap_or_default()
            ),
            &header,
            &b.tolerances
                .iter()
                .map(|t| {
                    let mut r = vec![
                        t.name.clone(),
                        g4(t.sigma),
                        t.unit.symbol().to_string(),
                        format!("{:.1} %", 100.0 * t.share),
                    ];
                    if with_after {
                        r.push(t.sigma_after.map(g4).unwrap_or_default());
                    }
                    r
                })
                .collect::<Vec<_>>(),
        )
    }
    fn __repr__(&self) -> String {
        format!(
            "<Budget of {}: position error RMS {:.4} mm over {} targets, {} tolerances>",
            self.mechanism,
            self.b.first_order.position_rms,
            self.b.targets,
            self.b.tolerances.len()
        )
    }
}

by_serde!(PyBudget { b; mechanism });

/// What :func:`drift` found: each parameter's change against what both
/// calibrations' covariances allow, and the joint test.
#[pyclass(frozen, module = "pkmcal", name = "Drift")]
pub struct PyDrift {
    pub d: pkmcal::identify::Drift,
    /// The summary's text.
    pub text: String,
}

#[pymethods]
impl PyDrift {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is.
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// Names of the parameters that drifted (Holm–Bonferroni at ``alpha``).
    #[getter]
    fn drifted(&self) -> Vec<String> {
        self.d
            .parameters
            .iter()
            .filter(|p| p.drifted)
            .map(|p| p.name.clone())
            .collect()
    }
    /// Every compared parameter, smallest p-value first: dicts with
    /// ``name``, ``before``, ``after``, ``change``, ``sigma``, ``z``,
    /// ``p_value``, ``drifted``.
    #[getter]
    fn parameters<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.d
            .parameters
            .iter()
            .map(|p| {
                let d = PyDict::new(py);
                d.set_item("name", &p.name)?;
                d.set_item("before", p.before)?;
                d.set_item("after", p.after)?;
                d.set_item("change", p.change)?;
                d.set_item("sigma", p.sigma)?;
                d.set_item("z", p.z)?;
                d.set_item("p_value", p.p_value)?;
                d.set_item("drifted", p.drifted)?;
                Ok(d)
            })
            .collect()
    }
    /// The familywise false-alarm rate.
    #[getter]
    fn alpha(&self) -> f64 {
        self.d.alpha
    }
    /// The joint statistic, its degrees of freedom and p-value.
    #[getter]
    fn chi2(&self) -> (f64, usize, f64) {
        (self.d.chi2, self.d.dof, self.d.p_joint)
    }
    /// Whether the joint test calls the machine changed.
    #[getter]
    fn joint_drift(&self) -> bool {
        self.d.joint_drift
    }
    /// Parameters identified in one calibration only (not compared).
    #[getter]
    fn untested(&self) -> Vec<String> {
        self.d.untested.clone()
    }
    /// The change at the tool over the workspace (when the mechanism was at
    /// hand): a dict with ``targets`` (n, axes), ``change`` (n, axes),
    /// ``distance`` (n, mm), ``p_value`` (n), ``largest`` (the row where
    /// the position moved most), ``beyond`` (how many targets exceed what
    /// both covariances allow at ``alpha``, each judged alone); None without.
    #[getter]
    fn workspace<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(w) = &self.d.workspace else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        let nx = w.targets.first().map_or(0, |t| t.target.len());
        let flat = |f: &dyn Fn(&pkmcal::identify::drift::TargetDrift) -> &Vec<f64>| -> Vec<f64> {
            w.targets
                .iter()
                .flat_map(|t| f(t).iter().copied())
                .collect()
        };
        d.set_item("targets", out2(py, flat(&|t| &t.target), nx, false))?;
        d.set_item("change", out2(py, flat(&|t| &t.change), nx, false))?;
        let col = |f: &dyn Fn(&pkmcal::identify::drift::TargetDrift) -> f64| -> Vec<f64> {
            w.targets.iter().map(f).collect()
        };
        d.set_item("distance", vec1(py, &col(&|t| t.distance)))?;
        d.set_item("p_value", vec1(py, &col(&|t| t.p_value)))?;
        d.set_item("largest", w.largest)?;
        d.set_item("beyond", w.beyond)?;
        Ok(Some(d))
    }
    /// The comparison in words, as ``pkmcal drift`` prints it.
    fn summary(&self) -> String {
        self.text.clone()
    }
    fn __str__(&self) -> String {
        self.text.clone()
    }
    /// The compared parameters as a pandas DataFrame, smallest p-value
    /// first, indexed by name: ``before``, ``after``, ``change``, ``sigma``
    /// (what both covariances allow), ``z``, ``p_value``, ``drifted``.
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let ps = &self.d.parameters;
        let col = |f: &dyn Fn(&pkmcal::identify::ParameterDrift) -> f64| {
            vec1(py, &ps.iter().map(f).collect::<Vec<_>>()).into_any()
        };
        frame(
            py,
            vec![
                ("before".into(), col(&|p| p.before)),
                ("after".into(), col(&|p| p.after)),
                ("change".into(), col(&|p| p.change)),
                ("sigma".into(), col(&|p| p.sigma)),
                ("z".into(), col(&|p| p.z)),
                ("p_value".into(), col(&|p| p.p_value)),
                (
                    "drifted".into(),
                    numpy::PyArray1::from_iter(py, ps.iter().map(|p| p.drifted)).into_any(),
                ),
            ],
            Some(PyList::new(py, ps.iter().map(|p| p.name.as_str()))?.into_any()),
            Some("parameter"),
        )
    }
    /// The test as a table (a notebook shows it).
    fn _repr_html_(&self) -> String {
        let d = &self.d;
        html_table(
            &format!(
                "<b>Drift</b>: {} of {} parameters drifted (Holm–Bonferroni at α = {}); joint χ² = {} with {} degrees of freedom, p {}{}",
                self.drifted().len(),
                d.parameters.len(),
                g4(d.alpha),
                g4(d.chi2),
                d.dof,
                p_text(d.p_joint),
                if d.joint_drift {
                    ": the machine changed"
                } else {
                    ""
                }
            ),
            &[
                "parameter",
                "before",
                "after",
                "change",
                "σ",
                "z",
                "p",
                "drifted",
            ],
            &d.parameters
                .iter()
                .map(|p| {
                    vec![
                        p.name.clone(),
                        g4(p.before),
                        g4(p.after),
                        g4(p.change),
                        g4(p.sigma),
                        g4(p.z),
                        p_text(p.p_value),
                        if p.drifted { "yes" } else { "" }.to_string(),
                    ]
                })
                .collect::<Vec<_>>(),
        )
    }
    fn __repr__(&self) -> String {
        format!(
            "<Drift: {} of {} parameters drifted; joint p {}>",
            self.drifted().len(),
            self.d.parameters.len(),
            p_text(self.d.p_joint)
        )
    }
}

by_serde!(PyDrift { d; text });

/// What :func:`montecarlo` found: the summary over the runs and each run's
/// figures.
#[pyclass(frozen, module = "pkmcal", name = "MonteCarlo", get_all)]
pub struct PyMonteCarlo {
    /// Runs made.
    pub runs: usize,
    /// Runs that converged.
    pub converged: usize,
    /// Median over the runs of the validation RMS distance error (mm).
    pub validation_rms_median: f64,
    /// 95th percentile of the validation RMS distance error (mm).
    pub validation_rms_p95: f64,
    /// Median of the validation maximum distance error (mm).
    pub validation_max_median: f64,
    /// Free parameter names (columns of ``parameter_errors``).
    pub parameters: Vec<String>,
    /// RMS over the runs of each free parameter's error (its unit).
    pub parameter_rms_error: Py<PyAny>,
    /// Whether each run converged, shape (runs,).
    pub run_converged: Py<PyAny>,
    /// Each run's validation RMS distance error (mm), shape (runs,).
    pub validation_rms: Py<PyAny>,
    /// Each run's validation maximum distance error (mm), shape (runs,).
    pub validation_max: Py<PyAny>,
    /// Identified minus true value of each free parameter, shape (runs, free).
    pub parameter_errors: Py<PyAny>,
}

#[pymethods]
impl PyMonteCarlo {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    /// Equal when every part is (arrays elementwise, NaN equal to NaN).
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> PyResult<bool> {
        eq_by_value(self, other)
    }
    /// The dict :func:`montecarlo` returned before (``mc["runs"]``):
    /// deprecated, use the attributes.
    fn __getitem__<'py>(slf: &Bound<'py, Self>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        let py = slf.py();
        const KEYS: [&str; 6] = [
            "runs",
            "converged",
            "validation_rms_median",
            "validation_max_median",
            "parameters",
            "parameter_rms_error",
        ];
        if !KEYS.contains(&key) {
            return Err(pyo3::exceptions::PyKeyError::new_err(key.to_string()));
        }
        deprecated(
            py,
            &format!("montecarlo(...)[\"{key}\"]"),
            &format!("montecarlo(...).{key}"),
            DIRECT,
        )?;
        slf.getattr(key)
    }
    /// The runs as a pandas DataFrame, one row per run: ``converged``,
    /// ``validation_rms``, ``validation_max`` (mm), then each free
    /// parameter's error (identified minus true, its unit).
    fn to_pandas<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let mut cols = vec![
            ("converged".to_string(), self.run_converged.bind(py).clone()),
            (
                "validation_rms".to_string(),
                self.validation_rms.bind(py).clone(),
            ),
            (
                "validation_max".to_string(),
                self.validation_max.bind(py).clone(),
            ),
        ];
        cols.extend(named_columns(
            self.parameter_errors.bind(py),
            &self.parameters,
            "",
        )?);
        frame(py, cols, None, Some("run"))
    }
    /// The study as a table (a notebook shows it): each free parameter's
    /// RMS error over the runs.
    fn _repr_html_(&self, py: Python<'_>) -> PyResult<String> {
        let rms: Vec<f64> = self.parameter_rms_error.bind(py).extract()?;
        Ok(html_table(
            &format!(
                "<b>Monte Carlo</b>: {} runs, {} converged; validation RMS distance error median {} mm (95th percentile {} mm), max median {} mm",
                self.runs,
                self.converged,
                g4(self.validation_rms_median),
                g4(self.validation_rms_p95),
                g4(self.validation_max_median)
            ),
            &["parameter", "RMS error"],
            &self
                .parameters
                .iter()
                .zip(rms)
                .map(|(n, r)| vec![n.clone(), g4(r)])
                .collect::<Vec<_>>(),
        ))
    }
    fn __repr__(&self) -> String {
        format!(
            "<MonteCarlo {} runs ({} converged): validation RMS median {:.4} mm, p95 {:.4} mm>",
            self.runs, self.converged, self.validation_rms_median, self.validation_rms_p95
        )
    }
}

by_value!(PyMonteCarlo {
    runs,
    converged,
    validation_rms_median,
    validation_rms_p95,
    validation_max_median,
    parameters,
    parameter_rms_error,
    run_converged,
    validation_rms,
    validation_max,
    parameter_errors,
});
