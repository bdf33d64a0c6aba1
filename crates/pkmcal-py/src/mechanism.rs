//! The mechanism: the built-in reference, or one described in TOML (a
//! path, text or a dict), as the command-line tool reads it.

use crate::arrays::out2;
use crate::errors::{DIRECT, deprecated, io_err, usage};
use crate::files::path_arg;
use pkmcal::{AnyMechanism, Mechanism as _};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use std::sync::Arc;

/// A parallel mechanism: the built-in reference, or one described in TOML.
///
/// ``Mechanism()`` is the built-in reference (Jeong & Kim's planar 2-DOF
/// mechanism with three actuators). ``Mechanism(source)`` reads a
/// description: a path (``str`` ending in ``.toml`` or ``os.PathLike``), TOML
/// text, or a ``dict`` with the same tables and keys as the file. The formats
/// are those of the command-line tool (docs/mechanisms.md).
///
/// Arrays passed to and returned by pkmcal are in mm, rad, N and N·m; a
/// description's ``[units]`` table applies to the command-line tool's files
/// only.
#[pyclass(frozen, module = "pkmcal", name = "Mechanism")]
pub struct PyMechanism {
    pub mech: Arc<AnyMechanism>,
    pub targets: Vec<Vec<f64>>,
    pub setup: Option<pkmcal::Setup>,
    pub source: String,
    /// The description's text (None for the built-in reference), for pickling.
    pub text: Option<String>,
    /// Its `[tolerances]` table.
    pub tolerances: Vec<(String, pkmcal::apply::budget::Tolerance)>,
}

fn toml_value(v: &Bound<'_, PyAny>, path: &str) -> PyResult<toml::Value> {
    use pyo3::types::{PyBool, PyFloat, PyInt, PyString};
    if v.is_instance_of::<PyBool>() {
        return Ok(toml::Value::Boolean(v.extract()?));
    }
    if v.is_instance_of::<PyInt>() {
        return Ok(toml::Value::Integer(v.extract()?));
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(toml::Value::Float(v.extract()?));
    }
    if v.is_instance_of::<PyString>() {
        return Ok(toml::Value::String(v.extract()?));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut t = toml::Table::new();
        for (k, x) in d.iter() {
            let k: String = k.extract().map_err(|_| {
                usage(format!(
                    "mechanism dict: keys must be strings (at `{path}`)"
                ))
            })?;
            let p = if path.is_empty() {
                k.clone()
            } else {
                format!("{path}.{k}")
            };
            t.insert(k, toml_value(&x, &p)?);
        }
        return Ok(toml::Value::Table(t));
    }
    if v.hasattr("tolist")? && !v.is_instance_of::<PyList>() {
        return toml_value(&v.call_method0("tolist")?, path);
    }
    if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
        let items: Vec<Bound<'_, PyAny>> = v.try_iter()?.collect::<PyResult<_>>()?;
        let mut a = vec![];
        for (i, x) in items.iter().enumerate() {
            a.push(toml_value(x, &format!("{path}[{i}]"))?);
        }
        return Ok(toml::Value::Array(a));
    }
    // NumPy scalars and other numbers.
    if let Ok(f) = v.extract::<f64>() {
        return Ok(toml::Value::Float(f));
    }
    Err(usage(format!(
        "mechanism dict: `{path}` holds a {}, which a description cannot hold (numbers, strings, booleans, lists and dicts)",
        v.get_type().name()?
    )))
}

impl PyMechanism {
    pub fn from_text(text: &str, source: String) -> PyResult<Self> {
        // Every part of the description, read once as the CLI reads it.
        let parts = pkmcal_io::description::description_from_str(text)
            .map_err(|e| io_err(e.context(format!("in mechanism description {source}"))))?;
        Ok(Self {
            mech: Arc::new(parts.mech),
            targets: parts.targets,
            setup: parts.ballbar,
            tolerances: parts.tolerances,
            source,
            text: Some(text.to_string()),
        })
    }
    fn from_path(path: &str) -> PyResult<Self> {
        let text = crate::files::reading(|run| {
            run.files.read_to_string(
                std::path::Path::new(path),
                pkmcal_io::output::InputKind::Description,
            )
        })
        .map_err(|e| match e.io_error() {
            Some(cause) => crate::errors::os_err(
                format!(
                    "cannot read mechanism file {path}: {cause}; give a path to a .toml description, TOML text or a dict"
                ),
                cause,
                std::path::Path::new(path),
            ),
            None => io_err(e),
        })?;
        Self::from_text(&text, path.to_string())
    }
    pub fn spec(&self) -> &pkmcal::Spec {
        self.mech.spec()
    }
    pub fn actuators(&self) -> Vec<String> {
        self.spec()
            .actuated_names()
            .iter()
            .map(|s| s.to_string())
            .collect()
    }
}

#[pymethods]
impl PyMechanism {
    #[new]
    #[pyo3(signature = (source = None))]
    fn new(source: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let Some(s) = source else {
            return Ok(Self::reference());
        };
        if s.is_none() {
            return Ok(Self::reference());
        }
        if let Ok(d) = s.cast::<PyDict>() {
            return Self::from_dict(d);
        }
        if let Ok(text) = s.extract::<String>() {
            let t = text.trim();
            let looks_like_path = !t.contains('\n') && !t.contains('=');
            if looks_like_path {
                return Self::from_path(t);
            }
            return Self::from_toml(&text);
        }
        if s.hasattr("__fspath__")? {
            return Self::from_path(&path_arg(s)?);
        }
        Err(usage(format!(
            "Mechanism(source): expected None, a path, TOML text or a dict, got {}",
            s.get_type().name()?
        )))
    }

    /// The built-in reference mechanism (Jeong & Kim's planar 2-DOF, three
    /// actuators).
    #[staticmethod]
    pub fn reference() -> Self {
        Self {
            mech: Arc::new(pkmcal::JeongKim2Dof::new().into()),
            targets: vec![],
            setup: None,
            tolerances: vec![],
            source: "the built-in reference".into(),
            text: None,
        }
    }

    /// A mechanism from a TOML description file.
    #[staticmethod]
    fn from_file(path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let p = path_arg(path)?;
        Self::from_path(&p)
    }

    /// A mechanism from TOML text.
    #[staticmethod]
    fn from_toml(text: &str) -> PyResult<Self> {
        Self::from_text(text, "(TOML text)".into())
    }

    /// A mechanism from a dict with the tables and keys of a description file.
    #[staticmethod]
    fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self> {
        let toml::Value::Table(t) = toml_value(d.as_any(), "")? else {
            unreachable!("a dict is a table")
        };
        let text = toml::to_string(&t).map_err(|e| usage(format!("mechanism dict: {e}")))?;
        Self::from_text(&text, "(dict)".into())
    }

    /// The mechanism's name.
    #[getter]
    fn name(&self) -> String {
        self.spec().name.clone()
    }
    /// Its kind: ``jeong-kim-2dof``, ``planar``, ``gough-stewart`` or ``spatial``.
    #[getter]
    pub fn kind(&self) -> &'static str {
        match &*self.mech {
            AnyMechanism::JeongKim(_) => "jeong-kim-2dof",
            AnyMechanism::Planar(_) => "planar",
            AnyMechanism::GoughStewart(_) => "gough-stewart",
            AnyMechanism::Spatial(_) => "spatial",
        }
    }
    /// Degrees of freedom.
    #[getter]
    fn dof(&self) -> usize {
        self.spec().dof()
    }
    /// Joint names, in the order of a configuration ``q``.
    #[getter]
    fn joints(&self) -> Vec<String> {
        self.spec().joints.clone()
    }
    /// Actuated joint names: the columns of a commands array.
    #[getter(actuators)]
    fn py_actuators(&self) -> Vec<String> {
        self.actuators()
    }
    /// Units of the commands (``mm`` or ``rad``), per actuator.
    #[getter]
    fn command_units(&self) -> Vec<&'static str> {
        self.spec()
            .command_units()
            .iter()
            .map(|u| u.symbol())
            .collect()
    }
    /// Tool coordinate names: the columns of a positions array.
    #[getter]
    fn tool_axes(&self) -> Vec<String> {
        self.spec().tool_axes.clone()
    }
    /// Units of the tool coordinates (``mm`` or ``rad``), per axis.
    #[getter]
    fn tool_units(&self) -> Vec<&'static str> {
        self.spec().tool_units.iter().map(|u| u.symbol()).collect()
    }
    /// What the mechanism is made of, as a dict: ``name``, ``dof``,
    /// ``joints`` (name, unit, actuated, independent), ``actuators`` (the
    /// commands' columns), ``tool_axes`` (name, unit, workspace) and
    /// ``parameters`` (name, kind, unit, nominal, free_by_default): what
    /// ``pkmcal parameters --json`` prints.
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        py.import("json")?.call_method1(
            "loads",
            (pkmcal_io::description::summary_json(self.spec()),),
        )
    }
    /// Every parameter name: geometry, then encoder offsets, then stiffness.
    #[getter]
    fn parameter_names(&self) -> Vec<String> {
        self.spec()
            .param_names()
            .iter()
            .map(|s| s.to_string())
            .collect()
    }
    /// Deprecated name of ``parameter_names`` (``Calibration.parameters``
    /// are values by name).
    #[getter]
    fn parameters(&self, py: Python<'_>) -> PyResult<Vec<String>> {
        deprecated(
            py,
            "Mechanism.parameters",
            "Mechanism.parameter_names",
            DIRECT,
        )?;
        Ok(self.parameter_names())
    }
    /// Nominal parameter values by name.
    #[getter]
    fn nominal<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let spec = self.spec();
        for (n, v) in spec.param_names().iter().zip(&spec.nominal) {
            d.set_item(n, v)?;
        }
        Ok(d)
    }
    /// Unit of each parameter by name (``mm``, ``rad``, ``N·m/rad``, ``N/mm``).
    #[getter]
    fn parameter_units<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let spec = self.spec();
        for (i, n) in spec.param_names().iter().enumerate() {
            d.set_item(n, spec.param_unit(i).symbol())?;
        }
        Ok(d)
    }
    /// Kind of each parameter by name (``geometry``, ``offset``, ``stiffness``).
    #[getter]
    fn parameter_kinds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        let spec = self.spec();
        for (i, n) in spec.param_names().iter().enumerate() {
            d.set_item(n, spec.param_kind(i).name())?;
        }
        Ok(d)
    }
    /// The parameters a calibration identifies unless told otherwise.
    #[getter]
    fn default_free(&self) -> Vec<String> {
        self.spec().default_free.clone()
    }
    /// The workspace box, one ``[min, max]`` row per tool axis.
    #[getter]
    fn workspace<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let b = &self.spec().workspace_box;
        out2(py, b.iter().flat_map(|r| [r[0], r[1]]).collect(), 2, false)
    }
    /// Target points of the description's ``[[target]]`` tables (tool frame,
    /// mm), shape (k, axes); None when it has none.
    #[getter]
    fn target_points<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyAny>> {
        let w = self.targets.first()?.len();
        Some(out2(py, self.targets.concat(), w, false))
    }
    /// Deprecated name of ``target_points`` (``Plan.targets`` are poses).
    #[getter]
    fn targets<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        deprecated(py, "Mechanism.targets", "Mechanism.target_points", DIRECT)?;
        Ok(self.target_points(py))
    }
    /// Pickled as its description, so that it crosses process boundaries
    /// (multiprocessing, joblib).
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyTuple>)> {
        let py = slf.py();
        let cls = py.get_type::<PyMechanism>();
        Ok(match &slf.get().text {
            Some(t) => (cls.getattr("from_toml")?, PyTuple::new(py, [t])?),
            None => (cls.getattr("reference")?, PyTuple::empty(py)),
        })
    }
    /// Equal when the descriptions are: the same mechanism (names, nominal
    /// values, workspace, assembly), target points and ball-bar setup,
    /// wherever they were read from.
    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other.cast::<PyMechanism>().is_ok_and(|o| {
            let o = o.get();
            self.mech.spec() == o.mech.spec()
                && self.kind() == o.kind()
                && self.targets == o.targets
                && self.setup == o.setup
        })
    }
    /// Consistent with ``==``: from the mechanism's identity and name.
    fn __hash__(&self) -> u64 {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        (
            pkmcal::identify::mechanism_identity(self.spec()),
            &self.spec().name,
        )
            .hash(&mut h);
        h.finish()
    }
    fn __repr__(&self) -> String {
        let s = self.spec();
        format!(
            "<pkmcal.Mechanism {:?} ({}): {} DOF, actuators {}, tool axes {}, {} parameters; from {}>",
            s.name,
            self.kind(),
            s.dof(),
            self.actuators().join(", "),
            s.tool_axes.join(", "),
            s.n_params(),
            self.source
        )
    }
}

/// ``mechanism``: a :class:`Mechanism`, or what ``Mechanism(...)`` takes (a
/// path, TOML text, a dict).
pub fn mechanism_arg<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyMechanism>> {
    if let Ok(m) = obj.cast::<PyMechanism>() {
        return Ok(m.clone());
    }
    let is_source = obj.is_instance_of::<pyo3::types::PyString>()
        || obj.hasattr("__fspath__")?
        || obj.cast::<PyDict>().is_ok();
    if !is_source {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "mechanism: expected a pkmcal.Mechanism (or a path, TOML text or dict describing one), got {}",
            obj.get_type().name()?
        )));
    }
    Bound::new(obj.py(), PyMechanism::new(Some(obj))?)
}
