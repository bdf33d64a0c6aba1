//! The parts of results: error statistics, warnings, identifiability and
//! figures.

use crate::arrays::vec1;
use crate::errors::usage;
use crate::files::{path_arg, written};
use crate::results::{ByValue, Reduced, eq_by_value, g4, html_table, observability, reduce};
use numpy::PyArray1;
use pkmcal::identify::Identifiability;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

/// Error statistics of a set of poses: per axis and over the position
/// distance (mm); angles apart (rad).
#[pyclass(frozen, module = "pkmcal", name = "ErrorStats", get_all)]
pub struct PyErrorStats {
    /// Poses.
    count: usize,
    /// Unit of each axis.
    axis_units: Vec<String>,
    /// Smallest error per axis.
    axis_min: Vec<f64>,
    /// Largest error per axis.
    axis_max: Vec<f64>,
    /// RMS error per axis.
    axis_rms: Vec<f64>,
    /// Position error distance, smallest (mm).
    distance_min: f64,
    /// Mean (mm).
    distance_mean: f64,
    /// RMS (mm).
    distance_rms: f64,
    /// Largest (mm).
    distance_max: f64,
    /// RMS angle error (rad), when the readings have angles.
    angle_rms: Option<f64>,
    /// Largest angle error (rad).
    angle_max: Option<f64>,
}

impl From<&pkmcal::ErrorStats> for PyErrorStats {
    fn from(s: &pkmcal::ErrorStats) -> Self {
        Self {
            count: s.count,
            axis_units: s
                .axis_units
                .iter()
                .map(|u| u.symbol().to_string())
                .collect(),
            axis_min: s.axis_min.clone(),
            axis_max: s.axis_max.clone(),
            axis_rms: s.axis_rms.clone(),
            distance_min: s.distance_min,
            distance_mean: s.distance_mean,
            distance_rms: s.distance_rms,
            distance_max: s.distance_max,
            angle_rms: s.angle_rms,
            angle_max: s.angle_max,
        }
    }
}

#[pymethods]
impl PyErrorStats {
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
    /// The statistics as a table (a notebook shows it).
    fn _repr_html_(&self) -> String {
        let mut rows: Vec<Vec<String>> = (0..self.axis_rms.len())
            .map(|k| {
                vec![
                    format!("axis {}", k + 1),
                    self.axis_units[k].clone(),
                    g4(self.axis_min[k]),
                    g4(self.axis_max[k]),
                    g4(self.axis_rms[k]),
                ]
            })
            .collect();
        rows.push(vec![
            "distance".into(),
            "mm".into(),
            g4(self.distance_min),
            g4(self.distance_max),
            g4(self.distance_rms),
        ]);
        if let (Some(r), Some(m)) = (self.angle_rms, self.angle_max) {
            rows.push(vec![
                "angle".into(),
                "rad".into(),
                String::new(),
                g4(m),
                g4(r),
            ]);
        }
        html_table(
            &format!(
                "<b>Errors of {} poses</b> (distance mean {} mm)",
                self.count,
                g4(self.distance_mean)
            ),
            &["error", "unit", "min", "max", "rms"],
            &rows,
        )
    }
    fn __repr__(&self) -> String {
        let angles = match (self.angle_rms, self.angle_max) {
            (Some(r), Some(m)) => format!(", angle rms {r:.3e} rad, max {m:.3e} rad"),
            _ => String::new(),
        };
        format!(
            "<ErrorStats {} poses: distance rms {:.4} mm, max {:.4} mm{angles}>",
            self.count, self.distance_rms, self.distance_max
        )
    }
}

/// A warning of a calibration: ``kind`` (e.g. ``unidentifiable``,
/// ``not_converged``), what happened and what to do.
#[pyclass(frozen, eq, hash, module = "pkmcal", name = "Warning", get_all)]
#[derive(PartialEq, Eq, Hash)]
pub struct PyWarning {
    /// What it is about: stiffness_ratios, unidentifiable, frame_gauge,
    /// not_converged, rank_deficient, outliers, dropped.
    kind: String,
    /// What happened.
    message: String,
    /// What to do.
    hint: String,
}

#[pymethods]
impl PyWarning {
    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
        reduce(slf)
    }
    #[staticmethod]
    fn _from_state(state: &Bound<'_, PyDict>) -> PyResult<Self> {
        Self::from_dict(state)
    }
    fn __repr__(&self) -> String {
        format!("<Warning {}: {}>", self.kind, self.message)
    }
    fn __str__(&self) -> String {
        format!("{} ({})", self.message, self.hint)
    }
}

pub fn warning(w: &pkmcal::identify::Warning) -> PyWarning {
    PyWarning {
        kind: w.kind.name().into(),
        message: w.message.clone(),
        hint: w.hint.clone(),
    }
}

/// What the data can and cannot identify: rank, singular values of the
/// scaled identification Jacobian, the unidentifiable combinations and the
/// strong correlations.
#[pyclass(frozen, module = "pkmcal", name = "Identifiability")]
pub struct PyIdentifiability {
    pub id: Identifiability,
}

#[pymethods]
impl PyIdentifiability {
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
    /// Free parameter names, in column order.
    #[getter]
    fn free(&self) -> Vec<String> {
        self.id.free.clone()
    }
    /// Numerical rank.
    #[getter]
    fn rank(&self) -> usize {
        self.id.rank
    }
    /// Singular values of the column-scaled, σ-weighted Jacobian, largest first.
    #[getter]
    fn singular_values<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, &self.id.singular_values)
    }
    /// Condition number of the identifiable directions.
    #[getter]
    fn condition_number(&self) -> f64 {
        self.id.condition_number
    }
    /// Observability indices O1…O5 by name.
    #[getter]
    fn observability<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        observability(py, &self.id.observability)
    }
    /// Unidentifiable directions: dicts with ``combination`` (text),
    /// ``terms`` (name → coefficient) and ``fixed`` (the parameter fixed to
    /// remove it, or None).
    #[getter]
    fn unidentifiable<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        self.id
            .unidentifiable
            .iter()
            .map(|u| {
                let d = PyDict::new(py);
                d.set_item("combination", &u.combination)?;
                let t = PyDict::new(py);
                for (n, c) in &u.terms {
                    t.set_item(n, c)?;
                }
                d.set_item("terms", t)?;
                d.set_item("fixed", &u.fixed)?;
                Ok(d)
            })
            .collect()
    }
    /// Directions the data alone cannot see, held by the tolerances
    /// (priors): their combinations.
    #[getter]
    fn held(&self) -> Vec<String> {
        self.id.held.iter().map(|u| u.combination.clone()).collect()
    }
    /// Pairs of free parameters correlated beyond 0.9: ``(a, b, r)``.
    #[getter]
    fn correlations(&self) -> Vec<(String, String, f64)> {
        self.id
            .correlations
            .iter()
            .map(|c| (c.a.clone(), c.b.clone(), c.r))
            .collect()
    }
    /// The analysis as tables (a notebook shows it): each free parameter's
    /// singular value (largest first), the unidentifiable combinations and
    /// the strong correlations.
    fn _repr_html_(&self) -> String {
        let id = &self.id;
        let esc = pkmcal_io::report::escape;
        let mut h = html_table(
            &format!(
                "<b>Identifiability</b>: rank {} of {} free, condition number {}",
                id.rank,
                id.free.len(),
                g4(id.condition_number)
            ),
            &["#", "singular value"],
            &id.singular_values
                .iter()
                .enumerate()
                .map(|(k, v)| vec![(k + 1).to_string(), g4(*v)])
                .collect::<Vec<_>>(),
        );
        for u in &id.unidentifiable {
            h.push_str(&format!(
                "<p>unidentifiable: {}{}</p>",
                esc(&u.combination),
                u.fixed
                    .as_ref()
                    .map(|f| format!(" (fixed {})", esc(f)))
                    .unwrap_or_default()
            ));
        }
        if !id.correlations.is_empty() {
            h.push_str(&html_table(
                "strong correlations",
                &["a", "b", "r"],
                &id.correlations
                    .iter()
                    .map(|c| vec![c.a.clone(), c.b.clone(), g4(c.r)])
                    .collect::<Vec<_>>(),
            ));
        }
        h
    }
    fn __repr__(&self) -> String {
        format!(
            "<Identifiability rank {} of {} free, condition {:.3e}, {} unidentifiable direction(s)>",
            self.id.rank,
            self.id.free.len(),
            self.id.condition_number,
            self.id.unidentifiable.len()
        )
    }
}
/// A rendered figure: ``svg`` (text), ``png`` (bytes), a title and a caption.
/// A notebook shows it inline.
#[pyclass(frozen, module = "pkmcal", name = "Figure", get_all)]
pub struct PyFigure {
    /// Short name (``errors``, ``parameters``, ``workspace``, ``maps``,
    /// ``residuals``, ``singular-values``).
    pub name: String,
    /// Title.
    pub title: String,
    /// What is shown and how to read it.
    pub caption: String,
    /// SVG text.
    pub svg: String,
    /// PNG image.
    pub png: Py<PyBytes>,
}

#[pymethods]
impl PyFigure {
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
    fn _repr_svg_(&self) -> String {
        self.svg.clone()
    }
    /// Write the figure to ``path``: SVG, or PNG when the name ends in ``.png``.
    fn save(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = path_arg(path)?;
        let lower = p.to_ascii_lowercase();
        let bytes: Vec<u8> = if lower.ends_with(".png") {
            self.png.bind(py).as_bytes().to_vec()
        } else if lower.ends_with(".svg") {
            self.svg.as_bytes().to_vec()
        } else {
            return Err(usage(format!(
                "save: {p}: a figure is written as SVG or PNG; name the file .svg or .png"
            )));
        };
        written(|run| run.files.stage(std::path::Path::new(&p), &bytes))
    }
    fn __repr__(&self) -> String {
        format!("<Figure {}: {}>", self.name, self.title)
    }
}

by_value!(PyErrorStats {
    count,
    axis_units,
    axis_min,
    axis_max,
    axis_rms,
    distance_min,
    distance_mean,
    distance_rms,
    distance_max,
    angle_rms,
    angle_max,
});
by_value!(PyWarning {
    kind,
    message,
    hint
});
by_serde!(PyIdentifiability { id });
by_value!(PyFigure {
    name,
    title,
    caption,
    svg,
    png
});
