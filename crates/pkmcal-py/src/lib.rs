//! Python bindings of pkmcal (PyO3): the library's free functions over NumPy
//! arrays. Arrays are in the library's units (mm, rad, N, N·m); pose numbers
//! in results and exceptions are row indices (from 0) of the arrays given.
//! Long computations release the GIL.

use nalgebra::DMatrix;
use numpy::ndarray::{Array2, Array3, ArrayView2, Axis, Ix2};
use numpy::{
    AllowTypeChange, IntoPyArray, PyArray1, PyArrayLikeDyn, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pkmcal::Request;
use pkmcal::identify::{Calibration as LibCalibration, Identifiability};
use pkmcal::{
    AnyMechanism, CalibrationOptions, MeasurementModel, Mechanism as _, Model, Noise, Origin,
    Params,
};
use pkmcal_io::record::{CalibrationState, MechanismSource};
use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyTuple};
use rayon::prelude::*;
use std::borrow::Cow;
use std::sync::Arc;

create_exception!(
    pkmcal,
    PkmcalError,
    PyValueError,
    "Bad input or an impossible request. `str(e)` says what happened and what to do; \
`e.pose` is the row (from 0) of the arrays where it happened, or None."
);

create_exception!(
    pkmcal,
    PkmcalWarning,
    pyo3::exceptions::PyUserWarning,
    "A calibration's warning, emitted once per call with `warnings.warn` (also in \
`Calibration.warnings`). Subclasses: ConvergenceWarning, IdentifiabilityWarning, OutlierWarning, ToleranceWarning, ModelWarning."
);
create_exception!(
    pkmcal,
    ConvergenceWarning,
    PkmcalWarning,
    "The fit stopped before converging (evaluation budget, no progress)."
);
create_exception!(
    pkmcal,
    IdentifiabilityWarning,
    PkmcalWarning,
    "Parameters the data cannot separate were fixed, or the fit is rank deficient."
);
create_exception!(
    pkmcal,
    OutlierWarning,
    PkmcalWarning,
    "Readings far beyond the noise were reported or dropped."
);
create_exception!(
    pkmcal,
    ModelWarning,
    PkmcalWarning,
    "The residuals exceed what the instrument's stated noise explains: the model misses something."
);
create_exception!(
    pkmcal,
    ToleranceWarning,
    PkmcalWarning,
    "An identified value far outside its tolerance, or parameters the data taught little beyond their tolerances."
);

/// Emit a calibration's warnings with `warnings.warn`, each once, in the
/// category of its kind, attributed to the line that called the package's
/// function (the package wraps each function once, `__init__.py`: stack
/// level 2).
fn emit_warnings(py: Python<'_>, warnings: &[pkmcal::identify::Warning]) -> PyResult<()> {
    let mut seen = std::collections::BTreeSet::new();
    for w in warnings {
        let text = format!("{} ({})", w.message, w.hint);
        if !seen.insert(text.clone()) {
            continue;
        }
        let category = match w.kind.category() {
            pkmcal::identify::WarningCategory::Convergence => py.get_type::<ConvergenceWarning>(),
            pkmcal::identify::WarningCategory::Outliers => py.get_type::<OutlierWarning>(),
            pkmcal::identify::WarningCategory::Tolerance => py.get_type::<ToleranceWarning>(),
            pkmcal::identify::WarningCategory::Model => py.get_type::<ModelWarning>(),
            pkmcal::identify::WarningCategory::Identifiability => {
                py.get_type::<IdentifiabilityWarning>()
            }
        };
        let text = std::ffi::CString::new(text.replace('\0', " ")).expect("no NUL left");
        PyErr::warn(py, &category, &text, 2)?;
    }
    Ok(())
}

/// A `DeprecationWarning`: `old` is now `new` (kept for one release).
fn deprecated(py: Python<'_>, old: &str, new: &str) -> PyResult<()> {
    let msg = std::ffi::CString::new(format!(
        "{old} is deprecated and will be removed in the next release; use {new}"
    ))
    .expect("no NUL");
    PyErr::warn(
        py,
        &py.get_type::<pyo3::exceptions::PyDeprecationWarning>(),
        &msg,
        1,
    )
}

// ---------------------------------------------------------------- errors

fn raise(message: String, pose: Option<usize>) -> PyErr {
    let err = PkmcalError::new_err(message);
    Python::attach(|py| {
        let v = err.value(py);
        let _ = v.setattr("pose", pose);
    });
    err
}

fn lib_err(e: pkmcal::Error) -> PyErr {
    let pose = match &e {
        pkmcal::Error::Pose { pose, .. } => Some(*pose),
        _ => None,
    };
    match &e {
        pkmcal::Error::Request(r) => raise(request_words(r), None),
        e => raise(e.to_string(), pose),
    }
}

/// The keyword that sets a choice the library or the file side names.
fn keyword(f: pkmcal::Field) -> &'static str {
    use pkmcal::Field::*;
    match f {
        Mechanism => "mechanism",
        Data => "commands, measured",
        Model => "model",
        Free => "free",
        Fix => "fix",
        Tolerances => "tolerances",
        NoTolerances => "tolerances=False",
        Start => "start",
        Params => "params",
        Load => "load",
        Preload => "preload",
        Loss => "loss",
        LossScale => "loss_scale",
        OutlierThreshold => "outlier_threshold",
        Validation => "validation",
        Holdout => "holdout",
        Kfold => "kfold",
        Seed => "seed",
        Frame => "frame",
        Axes => "axes",
        Setup => "ballbar",
        Distances => "distances",
        StatedNoise => "stated_noise",
        StatedAngleNoise => "stated_angle_noise",
        StatedDistanceNoise => "stated_distance_noise",
        StatedReadings => "stated_readings",
        StatedRelative => "stated_relative",
        Noise => "noise",
        AngleNoise => "angle_noise",
        MaxEvaluations => "max_nfev",
        Ftol => "ftol",
        Xtol => "xtol",
        Gtol => "gtol",
        Bounds => "bounds",
        X0 => "x0",
        Count => "count",
        Candidates => "spacing",
        MaxCandidates => "max_candidates",
        Runs => "runs",
        LengthError => "length_error",
        AngleError => "angle_error",
        ValidationTargets => "validation",
        Samples => "samples",
        Targets => "targets",
        Alpha => "alpha",
        Grid => "grid",
        _ => "the arguments",
    }
}

/// A refused choice in Python's words.
fn request_words(e: &pkmcal::RequestError) -> String {
    use pkmcal::RequestError as R;
    match e {
        R::Invalid {
            field,
            problem,
            suggest,
        } => format!(
            "{}: {problem}{}",
            keyword(*field),
            suggest
                .as_ref()
                .map(|s| format!(" ({}={:?})", keyword(s.field), s.value))
                .unwrap_or_default()
        ),
        R::Exclusive { a, b } => {
            format!("give either {}= or {}=, not both", keyword(*a), keyword(*b))
        }
        R::Needs { field, needs } => format!("{}= needs {}=", keyword(*field), keyword(*needs)),
        R::ToleranceTable(p) => format!("in the mechanism's [tolerances] table: {p}"),
    }
}

/// A file-side error in Python's words.
fn io_words(e: &pkmcal_io::Error) -> String {
    use pkmcal_io::Error as E;
    match e {
        E::MissingAxes {
            path,
            missing,
            present,
        } => format!(
            "{}: missing column{} `{}`; if the instrument measured only {}, say so with axes={:?}",
            path.display(),
            if missing.len() > 1 { "s" } else { "" },
            missing.join("`, `"),
            present.join(", "),
            present
        ),
        E::Request { file, cause } => match file {
            Some(f) => format!("{}: {}", f.display(), request_words(cause)),
            None => request_words(cause),
        },
        E::Library(l) => match l.as_ref() {
            pkmcal::Error::Request(r) => request_words(r),
            l => l.to_string(),
        },
        E::In { context, cause } => format!("{context}: {}", io_words(cause)),
        e => e.to_string(),
    }
}

/// A file-side error as a Python exception, its pose (if any) as `pose`.
fn io_err(e: pkmcal_io::Error) -> PyErr {
    raise(io_words(&e), e.pose().map(|(p, _)| p))
}

fn usage(message: impl Into<String>) -> PyErr {
    raise(message.into(), None)
}

/// Outputs are staged and renamed into place only when complete
/// (`pkmcal_io::Files`): each call that writes is a run of its own, with its
/// own files, so calls from several threads never share a staging area.
fn written(write: impl FnOnce(&pkmcal_io::Run) -> pkmcal_io::Result<()>) -> PyResult<()> {
    let files = pkmcal_io::Files::new();
    let run = pkmcal_io::Run::quiet(&files);
    // A failure drops `files`, which removes what it staged.
    write(&run).and_then(|()| files.commit()).map_err(io_err)
}

/// A run that only reads (no unit override, no progress display).
fn reading<T>(read: impl FnOnce(&pkmcal_io::Run) -> T) -> T {
    read(&pkmcal_io::Run::quiet(&pkmcal_io::Files::new()))
}

/// A path from a `str` or an `os.PathLike`.
fn path_arg(path: &Bound<'_, PyAny>) -> PyResult<String> {
    let p = if path.hasattr("__fspath__")? {
        path.call_method0("__fspath__")?
    } else {
        path.clone()
    };
    p.extract()
        .map_err(|_| usage("expected a path (str or os.PathLike)"))
}

// ---------------------------------------------------------------- threads

/// The package's thread pool, its process and its size (0: one thread per
/// core). A process forked from one that had a pool inherits the pool's
/// handle but not its threads, so work sent to it would wait forever: a
/// process makes its own, and a forked child leaves its parent's alone.
static POOL: std::sync::Mutex<Option<(u32, usize, Arc<rayon::ThreadPool>)>> =
    std::sync::Mutex::new(None);

/// The threads wanted per process ([`set_threads`]; 0 for one per core).
static THREADS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// This process's pool, made or remade as needed. Called with the GIL held,
/// so that no fork (which holds the GIL) can copy the lock while it is held.
fn pool() -> PyResult<Arc<rayon::ThreadPool>> {
    let mut g = POOL.lock().unwrap_or_else(|e| e.into_inner());
    let pid = std::process::id();
    let n = THREADS.load(std::sync::atomic::Ordering::Relaxed);
    if let Some((p, k, pool)) = g.as_ref()
        && *p == pid
        && *k == n
    {
        return Ok(pool.clone());
    }
    let new = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| raise(format!("cannot start pkmcal's threads: {e}"), None))?,
    );
    if let Some((p, _, old)) = g.replace((pid, n, new.clone()))
        && p != pid
    {
        // The parent's pool, copied by a fork: its threads are not here, so
        // dropping it would wait for them forever.
        std::mem::forget(old);
    }
    Ok(new)
}

/// Long computations: the GIL released, on this process's pool.
trait InPool {
    fn in_pool<T: Send, F: FnOnce() -> T + Send>(self, f: F) -> T;
}

impl InPool for Python<'_> {
    fn in_pool<T: Send, F: FnOnce() -> T + Send>(self, f: F) -> T {
        match pool() {
            Ok(p) => self.detach(|| p.install(f)),
            // No threads to be had: on the calling thread.
            Err(_) => self.detach(f),
        }
    }
}

/// How often a long call looks for Ctrl-C while the work runs.
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(20);

/// Run `f` (given a cancel flag the library polls between its steps) on the
/// package's pool, on a thread of its own, while this thread, the caller's,
/// looks for Python's signals every [`SIGNAL_POLL`]: a Ctrl-C sets the flag,
/// waits for the work to stop at its next step (one evaluation, one run, one
/// candidate) and raises Python's KeyboardInterrupt. The GIL is released
/// meanwhile. A panic in the work is an exception, never a crash.
fn interruptible<T: Send>(
    py: Python<'_>,
    f: impl FnOnce(Arc<std::sync::atomic::AtomicBool>) -> T + Send,
) -> PyResult<T> {
    let cancel = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = cancel.clone();
    let pool = pool()?;
    std::thread::scope(|scope| {
        let work = scope.spawn(move || pool.install(|| f(flag)));
        loop {
            let done = py.detach(|| {
                let start = std::time::Instant::now();
                while !work.is_finished() && start.elapsed() < SIGNAL_POLL {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
                work.is_finished()
            });
            if done {
                break;
            }
            if let Err(e) = py.check_signals() {
                cancel.store(true, std::sync::atomic::Ordering::Relaxed);
                let _ = py.detach(|| work.join());
                return Err(e);
            }
        }
        py.detach(|| work.join()).map_err(|_| {
            raise(
                "pkmcal's computation failed unexpectedly (an internal error); please report it"
                    .into(),
                None,
            )
        })
    })
}

/// The number of threads each process computes with: ``n`` (0 for one per
/// core, the default). In a pool of worker processes, 1 per worker keeps
/// the cores from being oversubscribed. Takes effect at the next call.
#[pyfunction]
fn set_threads(n: usize) {
    THREADS.store(n, std::sync::atomic::Ordering::Relaxed);
}

/// An error at row `i` of the arrays.
fn at(i: usize) -> impl Fn(pkmcal::Error) -> pkmcal::Error {
    move |e| {
        e.at_pose(Origin {
            pose: i,
            line: None,
            distance: false,
        })
    }
}

// ---------------------------------------------------------------- arrays

/// A 2-D array of finite numbers read from anything array-like (a NumPy
/// array is read in place when it is float64); a 1-D array is one row.
struct Rows<'py> {
    arr: PyReadonlyArrayDyn<'py, f64>,
    single: bool,
}

impl<'py> Rows<'py> {
    fn view(&self) -> ArrayView2<'_, f64> {
        let v = self.arr.as_array();
        let v = if self.single {
            v.insert_axis(Axis(0))
        } else {
            v
        };
        v.into_dimensionality::<Ix2>().expect("checked to be 2-D")
    }
    fn len(&self) -> usize {
        self.view().nrows()
    }
    fn to_vecs(&self) -> Vec<Vec<f64>> {
        self.view().rows().into_iter().map(|r| r.to_vec()).collect()
    }
}

/// Row `i` of a view, borrowed when contiguous.
fn row<'a>(v: &'a ArrayView2<'_, f64>, i: usize) -> Cow<'a, [f64]> {
    let r = v.row(i);
    match r.to_slice() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(r.to_vec()),
    }
}

/// `f` on every row of `rows`, spread over the cores with the GIL released,
/// results in row order; an error names its row.
fn per_row<T: Send>(
    py: Python<'_>,
    rows: &Rows<'_>,
    f: impl Fn(&[f64]) -> pkmcal::Result<T> + Sync,
) -> PyResult<Vec<T>> {
    let v = rows.view();
    py.in_pool(|| {
        (0..v.nrows())
            .into_par_iter()
            .map(|i| f(&row(&v, i)).map_err(at(i)))
            .collect::<pkmcal::Result<Vec<T>>>()
    })
    .map_err(lib_err)
}

/// Square matrices as a NumPy array (n, d, d), or (d, d) for one row in.
fn stacked<'py>(
    py: Python<'py>,
    mats: &[&DMatrix<f64>],
    d: usize,
    single: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let a = Array3::from_shape_fn((mats.len(), d, d), |(i, j, k)| mats[i][(j, k)]);
    let a = a.into_pyarray(py).into_any();
    if single { a.get_item(0) } else { Ok(a) }
}

fn rows<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    columns: &[String],
    allow_nan: bool,
) -> PyResult<Rows<'py>> {
    let width = columns.len();
    let shape_hint = format!("(n, {width}) with columns {}", columns.join(", "));
    // Named columns (a pandas DataFrame, a NumPy structured array) are taken
    // by name, in the mechanism's order, as a CSV file's are.
    let named = columns_by_name(obj, what, columns)?;
    let obj = named.as_ref().unwrap_or(obj);
    let arr: PyArrayLikeDyn<'py, f64, AllowTypeChange> = obj.extract().map_err(|_| {
        usage(format!(
            "{what}: expected an array of numbers of shape {shape_hint}"
        ))
    })?;
    let arr: PyReadonlyArrayDyn<'py, f64> = (*arr).clone();
    let shape = arr.shape().to_vec();
    let single = match shape.as_slice() {
        [w] if *w == width => true,
        [_, w] if *w == width => false,
        _ => {
            return Err(usage(format!(
                "{what}: expected shape {shape_hint}, got {}",
                shape_text(&shape)
            )));
        }
    };
    let r = Rows { arr, single };
    if r.len() == 0 {
        return Err(usage(format!("{what}: no rows; give at least one")));
    }
    for (i, rw) in r.view().rows().into_iter().enumerate() {
        for (k, v) in rw.iter().enumerate() {
            if !(v.is_finite() || (allow_nan && v.is_nan())) {
                return Err(raise(
                    format!(
                        "{what}: row {i}, column {} ({}) is {v}; every value must be a finite number",
                        k, columns[k]
                    ),
                    Some(i),
                ));
            }
        }
    }
    Ok(r)
}

/// The columns `columns` of `obj` in that order when `obj` names its
/// columns (a DataFrame's `columns`, a structured array's field names),
/// matched as a CSV file's headers are (regardless of case when
/// unambiguous, [`pkmcal_io::csv::column_index`]): a missing column is an
/// error naming it and the names found; other columns are ignored. `None`
/// for an array without names (its columns are taken in order).
fn columns_by_name<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    columns: &[String],
) -> PyResult<Option<Bound<'py, PyAny>>> {
    let py = obj.py();
    let names_of = |o: Bound<'py, PyAny>| -> Option<Vec<String>> {
        o.try_iter()
            .ok()?
            .map(|n| n.ok().and_then(|n| n.extract::<String>().ok()))
            .collect()
    };
    let frame = obj
        .hasattr("columns")?
        .then(|| obj.getattr("columns").ok())
        .flatten()
        .filter(|_| obj.hasattr("to_numpy").unwrap_or(false));
    let structured = obj
        .getattr("dtype")
        .ok()
        .and_then(|d| d.getattr("names").ok())
        .filter(|n| !n.is_none());
    let (names, is_frame) = match (frame, structured) {
        (Some(c), _) => match names_of(c) {
            Some(n) => (n, true),
            None => return Ok(None),
        },
        (None, Some(n)) => match names_of(n) {
            Some(n) => (n, false),
            None => return Ok(None),
        },
        (None, None) => return Ok(None),
    };
    let picked: Vec<String> = columns
        .iter()
        .map(|c| {
            pkmcal_io::csv::column_index(std::path::Path::new(what), &names, c, b',')
                .map(|i| names[i].clone())
                .map_err(|e| usage(format!("{e:#}")))
        })
        .collect::<PyResult<_>>()?;
    let list = pyo3::types::PyList::new(py, &picked)?;
    let sub = obj.get_item(list)?;
    Ok(Some(if is_frame {
        sub.call_method0("to_numpy")?
    } else {
        py.import("numpy.lib.recfunctions")?
            .call_method1("structured_to_unstructured", (sub,))?
    }))
}

/// A shape as Python prints it: `(35, 1)`, `(3,)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        s => format!(
            "({})",
            s.iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `n × w` values as a NumPy array, 1-D when the input was one row.
fn out2<'py>(py: Python<'py>, flat: Vec<f64>, w: usize, single: bool) -> Bound<'py, PyAny> {
    let n = flat.len().checked_div(w).unwrap_or(0);
    let a = Array2::from_shape_vec((n, w), flat).expect("sizes agree");
    if single {
        a.row(0).to_owned().into_pyarray(py).into_any()
    } else {
        a.into_pyarray(py).into_any()
    }
}

fn vec1<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

fn finite_list(v: &[f64], what: &str, n: usize) -> PyResult<Vec<f64>> {
    if v.len() != n {
        return Err(usage(format!(
            "{what}: expected {n} values, got {}",
            v.len()
        )));
    }
    if let Some(x) = v.iter().find(|x| !x.is_finite()) {
        return Err(usage(format!("{what}: {x} is not a finite number")));
    }
    Ok(v.to_vec())
}

fn parse_model(s: &str) -> PyResult<Model> {
    s.parse().map_err(lib_err)
}

// ---------------------------------------------------------------- mechanism

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
struct PyMechanism {
    mech: Arc<AnyMechanism>,
    targets: Vec<Vec<f64>>,
    setup: Option<pkmcal::Setup>,
    source: String,
    /// The description's text (None for the built-in reference), for pickling.
    text: Option<String>,
    /// Its `[tolerances]` table.
    tolerances: Vec<(String, pkmcal::apply::budget::Tolerance)>,
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
    fn from_text(text: &str, source: String) -> PyResult<Self> {
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
        let text = std::fs::read_to_string(path).map_err(|e| {
            usage(format!(
                "cannot read mechanism file {path}: {e}; give a path to a .toml description, TOML text or a dict"
            ))
        })?;
        Self::from_text(&text, path.to_string())
    }
    fn spec(&self) -> &pkmcal::Spec {
        self.mech.spec()
    }
    fn actuators(&self) -> Vec<String> {
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
    fn reference() -> Self {
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
    fn kind(&self) -> &'static str {
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
        deprecated(py, "Mechanism.parameters", "Mechanism.parameter_names")?;
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
        deprecated(py, "Mechanism.targets", "Mechanism.target_points")?;
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

fn mech_ref<'a, 'py>(m: &'a Bound<'py, PyMechanism>) -> &'a PyMechanism {
    m.get()
}

/// Parameters from None (nominal), a dict (name → value; the others
/// nominal), a Calibration (its identified values) or a path to a parameter
/// file written by the command-line tool.
fn params_arg(m: &PyMechanism, p: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<Params> {
    let spec = m.spec();
    let Some(p) = p.filter(|p| !p.is_none()) else {
        return Ok(Params::nominal(spec));
    };
    if let Ok(s) = p.cast::<PySavedCalibration>() {
        let s = s.get();
        return s.record.checked_params(m.mech.as_ref()).map_err(|e| {
            usage(format!(
                "{what}: {}: this calibration cannot serve {}: {e}",
                s.source, spec.name
            ))
        });
    }
    if let Ok(c) = p.cast::<PyCalibration>() {
        let c = c.get();
        // The same rule as for a calibration read back: the same
        // mechanism identity (joints, parameters, nominal values).
        if pkmcal::identify::mechanism_identity(c.mech().spec())
            != pkmcal::identify::mechanism_identity(spec)
        {
            return Err(usage(format!(
                "{what}: this calibration is of another mechanism ({})",
                c.mech().spec().name
            )));
        }
        return Ok(c.cal().params.clone());
    }
    // Any mapping of names to values (a dict, a pandas Series, …): its
    // `items()`.
    let items = if p.cast::<PyDict>().is_ok() || p.hasattr("items")? && !p.hasattr("__fspath__")? {
        p.call_method0("items").ok()
    } else {
        None
    };
    let params = if let Some(items) = items {
        let mut params = Params::nominal(spec);
        for kv in items.try_iter()? {
            let (k, v): (Bound<'_, PyAny>, Bound<'_, PyAny>) = kv?
                .extract()
                .map_err(|_| usage(format!("{what}: expected name → value pairs")))?;
            let name: String = k
                .extract()
                .map_err(|_| usage(format!("{what}: keys must be parameter names")))?;
            let value: f64 = v
                .extract()
                .map_err(|_| usage(format!("{what}: `{name}` must be a number")))?;
            params
                .set(spec, &name, value)
                .map_err(|e| usage(format!("{what}: {e}")))?;
        }
        params
    } else if let Ok(path) = path_arg(p) {
        return reading(|run| {
            pkmcal_io::params::read_params(run, std::path::Path::new(&path), &*m.mech)
        })
        .map_err(io_err);
    } else {
        return Err(usage(format!(
            "{what}: expected parameter values by name (a dict or any mapping, e.g. a pandas Series), a Calibration, a SavedCalibration or a parameter file path (str or os.PathLike); got {}",
            p.get_type().name()?
        )));
    };
    pkmcal::check_params(&*m.mech, &params).map_err(|e| {
        usage(format!(
            "{what}: the values cannot describe this mechanism: {e}"
        ))
    })?;
    Ok(params)
}

fn names_arg(v: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<Option<String>> {
    let Some(v) = v.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    if let Ok(s) = v.extract::<String>() {
        return Ok(Some(s));
    }
    let names: Vec<String> = v
        .extract()
        .map_err(|_| usage(format!("{what}: expected a list of parameter names")))?;
    if names.iter().any(|n| n.contains(',')) {
        return Err(usage(format!("{what}: a name cannot contain a comma")));
    }
    Ok(Some(names.join(",")))
}

/// ``free`` and ``fix`` (a string of comma-separated names, or a sequence
/// of names) onto the request.
fn names_request(
    r: &mut Request,
    free: Option<&Bound<'_, PyAny>>,
    fix: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    r.free = names_arg(free, "free")?.map(|s| Request::names(&s));
    r.fix = names_arg(fix, "fix")?
        .map(|s| Request::names(&s))
        .unwrap_or_default();
    Ok(())
}

/// The free set the request resolves (its priors freeing their
/// parameters), for the functions that take no study.
fn free_of(
    r: &Request,
    m: &PyMechanism,
    measurement: &MeasurementModel,
) -> PyResult<(Vec<pkmcal::identify::Prior>, Vec<usize>)> {
    r.priors_and_free(m.spec(), measurement, &m.tolerances)
        .map_err(|e| lib_err(e.into()))
}

/// ``tolerances``: a mapping name → σ (a number in the parameter's unit) or a
/// percentage of its nominal value (``"20%"``), in the order given.
fn tolerances_arg(
    t: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<(String, pkmcal::apply::budget::Tolerance)>> {
    use pkmcal::apply::budget::Tolerance;
    let mut given: Vec<(String, Tolerance)> = vec![];
    let Some(t) = t.filter(|t| !t.is_none()) else {
        return Ok(given);
    };
    let items = t
        .call_method0("items")
        .map_err(|_| usage("tolerances: expected a dict name → σ or \"20%\""))?;
    for kv in items.try_iter()? {
        let (name, v): (String, Bound<'_, PyAny>) = kv?.extract()?;
        let text = if let Ok(s) = v.extract::<String>() {
            s
        } else {
            v.extract::<f64>()
                .map_err(|_| {
                    usage(format!(
                        "tolerances: `{name}` must be σ (a number) or a percentage (\"20%\")"
                    ))
                })?
                .to_string()
        };
        let tol =
            Tolerance::parse(&text).map_err(|e| usage(format!("tolerances: `{name}`: {e}")))?;
        given.push((name, tol));
    }
    Ok(given)
}

/// ``tolerances`` onto the request: a dict replacing the mechanism's
/// ``[tolerances]`` entries; ``False``: no priors at all.
fn tolerances_request(r: &mut Request, tolerances: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    let flag = tolerances
        .filter(|t| t.is_instance_of::<pyo3::types::PyBool>())
        .map(|t| t.is_truthy())
        .transpose()?;
    r.no_tolerances = flag == Some(false);
    r.tolerances =
        tolerances_arg(tolerances.filter(|t| !t.is_instance_of::<pyo3::types::PyBool>()))?;
    Ok(())
}

/// ``bounds``: a mapping name → ``(lower, upper)``.
fn bounds_arg(b: &Bound<'_, PyAny>) -> PyResult<Vec<(String, f64, f64)>> {
    let items = b
        .call_method0("items")
        .map_err(|_| usage("bounds: expected a dict name → (lower, upper)"))?;
    let mut out = vec![];
    for kv in items.try_iter()? {
        let (name, pair): (String, Bound<'_, PyAny>) = kv?
            .extract()
            .map_err(|_| usage("bounds: expected a dict name → (lower, upper)"))?;
        let (lo, hi): (f64, f64) = pair.extract().map_err(|_| {
            usage(format!(
                "bounds: `{name}` must map to (lower, upper), two numbers (±inf for an open side)"
            ))
        })?;
        out.push((name, lo, hi));
    }
    Ok(out)
}

/// ``x0``: a mapping (as ``start``) or one value per free mechanism
/// parameter, in column order.
fn x0_arg(m: &PyMechanism, free: &[usize], x0: &Bound<'_, PyAny>) -> PyResult<Params> {
    if x0.hasattr("items")?
        || x0.hasattr("__fspath__")?
        || x0.is_instance_of::<pyo3::types::PyString>()
    {
        return params_arg(m, Some(x0), "x0");
    }
    let spec = m.spec();
    let names = spec.param_names();
    let mech_free: Vec<usize> = free.iter().copied().filter(|&i| i < names.len()).collect();
    let v: Vec<f64> = x0.extract().map_err(|_| {
        usage("x0: expected a dict name → value, or a 1-D array of the free mechanism parameters' starting values")
    })?;
    if v.len() != mech_free.len() {
        return Err(usage(format!(
            "x0 has {} values; give one per free mechanism parameter, in this order: {}",
            v.len(),
            mech_free
                .iter()
                .map(|&i| names[i])
                .collect::<Vec<_>>()
                .join(", ")
        )));
    }
    let mut p = Params::nominal(spec);
    for (&i, x) in mech_free.iter().zip(&v) {
        if !x.is_finite() {
            return Err(usage(format!(
                "x0: `{}` is {x}; every value must be a finite number",
                names[i]
            )));
        }
        p.values[i] = *x;
    }
    Ok(p)
}

/// ``mechanism``: a :class:`Mechanism`, or what ``Mechanism(...)`` takes (a
/// path, TOML text, a dict).
fn mechanism_arg<'py>(obj: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyMechanism>> {
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

/// ``seed``: a non-negative integer (the same numbers every time), None
/// (fresh numbers from the operating system's entropy) or a NumPy
/// ``Generator`` or ``RandomState`` (one draw from it, so a user's stream
/// decides).
fn seed_arg(seed: SeedArg) -> PyResult<u64> {
    let obj = match seed {
        SeedArg::Default(n) => return Ok(n),
        SeedArg::Given(obj) => obj,
    };
    Python::attach(|py| seed_of(obj.as_ref().map(|o| o.bind(py))))
}

/// A ``seed`` as given: the function's default, or an object.
enum SeedArg {
    Default(u64),
    Given(Option<Py<PyAny>>),
}

impl<'a, 'py> FromPyObject<'a, 'py> for SeedArg {
    type Error = PyErr;
    fn extract(obj: pyo3::Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        Ok(SeedArg::Given(Some(obj.to_owned().unbind())))
    }
}

fn seed_of(seed: Option<&Bound<'_, PyAny>>) -> PyResult<u64> {
    let Some(s) = seed.filter(|s| !s.is_none()) else {
        let mut b = [0u8; 8];
        getrandom(&mut b)?;
        return Ok(u64::from_le_bytes(b));
    };
    let drawn = if s.hasattr("integers")? {
        Some(s.call_method1("integers", (0u64, 1u64 << 63))?)
    } else if s.hasattr("randint")? && !s.is_instance_of::<pyo3::types::PyInt>() {
        Some(s.call_method1("randint", (0u64, 1u64 << 62))?)
    } else {
        None
    };
    let value = drawn.as_ref().unwrap_or(s);
    if value.is_instance_of::<pyo3::types::PyBool>() {
        return Err(usage(
            "seed: expected an integer ≥ 0, None or a NumPy Generator, got a bool",
        ));
    }
    let i: i128 = value
        .call_method0("__index__")
        .and_then(|v| v.extract())
        .map_err(|_| {
            usage(format!(
                "seed: expected an integer ≥ 0, None or a NumPy Generator, got {}",
                s.get_type()
                    .name()
                    .map(|n| n.to_string())
                    .unwrap_or_default()
            ))
        })?;
    u64::try_from(i).map_err(|_| {
        usage(format!(
            "seed: {i} is out of range; give an integer from 0 to 2^64 - 1, None or a NumPy Generator"
        ))
    })
}

/// Bytes of the operating system's entropy, through Python's `os.urandom`.
fn getrandom(out: &mut [u8]) -> PyResult<()> {
    Python::attach(|py| {
        let b = py.import("os")?.call_method1("urandom", (out.len(),))?;
        out.copy_from_slice(b.cast::<PyBytes>()?.as_bytes());
        Ok(())
    })
}

/// A vector argument (``load``, ``preload``…): one value per item, a list or
/// a 1-D array; a 2-D array is refused by name (one value per row is not
/// taken).
fn vector_arg(v: Option<&Bound<'_, PyAny>>, what: &str, per: &str) -> PyResult<Option<Vec<f64>>> {
    let Some(v) = v.filter(|v| !v.is_none()) else {
        return Ok(None);
    };
    if let Ok(shape) = v.getattr("shape").and_then(|s| s.extract::<Vec<usize>>())
        && shape.len() != 1
    {
        return Err(usage(format!(
            "{what}: one value per {per} (a list or a 1-D array), not an array of shape {}; it is the same for every row",
            shape_text(&shape)
        )));
    }
    v.extract::<Vec<f64>>().map(Some).map_err(|_| {
        usage(format!(
            "{what}: expected one number per {per} (a list or a 1-D array), got {}",
            v.get_type()
                .name()
                .map(|n| n.to_string())
                .unwrap_or_default()
        ))
    })
}

fn wrench(m: &PyMechanism, f: Option<Vec<f64>>, what: &str) -> PyResult<Vec<f64>> {
    match f {
        None => Ok(vec![]),
        Some(v) => finite_list(&v, what, m.spec().tool_axes.len()),
    }
}

/// The tool load: ``load=`` (the CLI's ``--load``), or ``force=``, its old
/// name, still read; not both.
fn load_arg(
    m: &PyMechanism,
    load: Option<&Bound<'_, PyAny>>,
    force: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<f64>> {
    let load = vector_arg(load, "load", "tool axis")?;
    let force = vector_arg(force, "force", "tool axis")?;
    match (load, force) {
        (Some(_), Some(_)) => Err(usage(
            "give the tool load once: load= (force= is its old name)",
        )),
        (l, f) => wrench(m, l.or(f), "load"),
    }
}

/// The instrument: the whole tool, some tool axes, heights probed on a bed
/// plane (`axes=["probe"]`), target points on the tool or a ball bar; in the
/// base frame or with a free (identified) frame.
fn measurement_arg(
    m: &PyMechanism,
    axes: Option<Vec<String>>,
    points: Option<&Bound<'_, PyAny>>,
    ballbar: Option<&Bound<'_, PyAny>>,
    frame: &str,
) -> PyResult<MeasurementModel> {
    let spec = m.spec();
    let given = [axes.is_some(), points.is_some(), ballbar.is_some()];
    if given.iter().filter(|g| **g).count() > 1 {
        return Err(usage(
            "give at most one of axes=, points= and ballbar= (what the instrument reads)",
        ));
    }
    let mm = if axes.as_deref().is_some_and(|a| a == ["probe"]) {
        // Heights probed on a bed plane (bed.z, bed.rx, bed.ry).
        MeasurementModel::probe(spec).map_err(|e| usage(format!("axes: {e}")))?
    } else if let Some(a) = &axes {
        MeasurementModel::tool_axes(spec, a).map_err(|e| usage(format!("axes: {e}")))?
    } else if let Some(p) = points {
        let pts: Vec<Vec<f64>> = if let Ok(s) = p.extract::<String>() {
            if s != "mechanism" {
                return Err(usage(
                    "points: give an array of target points (k, axes) or \"mechanism\" for the description's [[target]]s",
                ));
            }
            if m.targets.is_empty() {
                return Err(usage(
                    "points=\"mechanism\": the description has no [[target]] tables",
                ));
            }
            m.targets.clone()
        } else {
            let dim = if spec.tool_layout.frame_size() == 3 {
                2
            } else {
                3
            };
            let cols: Vec<String> = ["x", "y", "z"][..dim]
                .iter()
                .map(|s| s.to_string())
                .collect();
            rows(p, "points", &cols, false)?.to_vecs()
        };
        MeasurementModel::targets(spec, &pts).map_err(|e| usage(format!("points: {e}")))?
    } else if let Some(b) = ballbar {
        let setup = if let Ok(s) = b.extract::<String>() {
            if s != "mechanism" {
                return Err(usage(
                    "ballbar: give a dict {\"sockets\": array, \"bar_offset\": mm} or \"mechanism\" for the description's [ballbar]",
                ));
            }
            m.setup.clone().ok_or_else(|| {
                usage("ballbar=\"mechanism\": the description has no [ballbar] table")
            })?
        } else {
            let d = b.cast::<PyDict>().map_err(|_| {
                usage(
                    "ballbar: expected a dict {\"sockets\": array (k, 2 or 3), \"bar_offset\": mm}",
                )
            })?;
            // A misspelled key is refused, not ignored.
            for k in d.keys() {
                let k: String = k.extract().unwrap_or_default();
                if k != "sockets" && k != "bar_offset" {
                    return Err(usage(format!(
                        "ballbar: unknown key {k:?}; the keys are \"sockets\" and \"bar_offset\"{}",
                        pkmcal::error::did_you_mean(&k, ["sockets", "bar_offset"])
                            .map(|s| format!(" (did you mean {s:?}?)"))
                            .unwrap_or_default()
                    )));
                }
            }
            let sockets = d
                .get_item("sockets")?
                .ok_or_else(|| usage("ballbar: the dict needs \"sockets\""))?;
            let sockets = sockets_arg(&sockets, "ballbar: \"sockets\"")?;
            let bar_offset: f64 = match d.get_item("bar_offset")? {
                Some(v) => v
                    .extract()
                    .map_err(|_| usage("ballbar: \"bar_offset\" must be a number (mm)"))?,
                None => 0.0,
            };
            pkmcal::Setup {
                sockets,
                bar_offset,
            }
        };
        MeasurementModel::ball_bar(spec, &setup).map_err(|e| usage(format!("ballbar: {e}")))?
    } else {
        MeasurementModel::tool(spec)
    };
    // The frame rule is the library's; the words are Python's. Arrays
    // declare no frame: `auto` takes a free frame for whole positions and
    // target points, the base frame otherwise.
    let choice: pkmcal::FrameChoice = frame.parse().map_err(|_| {
        usage(format!(
            "frame: unknown `{frame}`; use \"auto\" (the default: free for whole positions and target points, base otherwise), \"base\" (readings in the base frame) or \"free\" (an instrument frame identified with the rest)"
        ))
    })?;
    choice
        .apply(mm, spec, false)
        .map_err(|e| usage(request_words(&e)))
}

/// Ball-bar socket centres: an array (k, 2) or (k, 3) of finite numbers.
fn sockets_arg(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Vec<f64>>> {
    let arr: PyArrayLikeDyn<'_, f64, AllowTypeChange> = obj
        .extract()
        .map_err(|_| usage(format!("{what}: expected an array of numbers (k, 2 or 3)")))?;
    let a = arr.as_array();
    if a.ndim() != 2 || !(2..=3).contains(&a.shape()[1]) || a.shape()[0] == 0 {
        return Err(usage(format!(
            "{what}: expected shape (k, 2) or (k, 3), one row per socket, got {}",
            shape_text(a.shape())
        )));
    }
    Ok(a.rows().into_iter().map(|r| r.to_vec()).collect())
}

/// Per-pose σ: None; a scalar (when every reading has one unit); one value
/// per axis; or an array (n, axes) with NaN where the σ is to be estimated.
fn sigma_arg(
    s: Option<&Bound<'_, PyAny>>,
    mm: &MeasurementModel,
    n: usize,
) -> PyResult<Vec<Vec<Option<f64>>>> {
    let Some(s) = s.filter(|s| !s.is_none()) else {
        return Ok(vec![vec![]; n]);
    };
    let nx = mm.len();
    let check = |v: f64| -> PyResult<Option<f64>> {
        if v.is_nan() {
            Ok(None)
        } else if v.is_finite() && v > 0.0 {
            Ok(Some(v))
        } else {
            Err(usage(format!(
                "sigma: {v} is not a standard deviation; give positive numbers (NaN where it is to be estimated)"
            )))
        }
    };
    if let Ok(v) = s.extract::<f64>() {
        let units = mm.units();
        if units.iter().any(|u| *u != units[0]) {
            return Err(usage(format!(
                "sigma: one number cannot be the σ of readings in {}; give one per axis ({})",
                units
                    .iter()
                    .map(|u| u.symbol())
                    .collect::<Vec<_>>()
                    .join(", "),
                mm.axes().join(", ")
            )));
        }
        let v = check(v)?;
        return Ok(vec![vec![v; nx]; n]);
    }
    let r = rows(s, "sigma", mm.axes(), true)?;
    let all = r.to_vecs();
    let per: Vec<Vec<Option<f64>>> = all
        .iter()
        .map(|row| row.iter().map(|&v| check(v)).collect::<PyResult<_>>())
        .collect::<PyResult<_>>()?;
    if r.single {
        return Ok(vec![per[0].clone(); n]);
    }
    if per.len() != n {
        return Err(usage(format!(
            "sigma: {} rows for {n} poses; give one row per pose or one per axis",
            per.len()
        )));
    }
    Ok(per)
}

/// Commands and readings as the library's measurements, rows numbered from 0.
/// Distances measured between pairs of poses: a tuple ``(commands_1,
/// commands_2, distance)`` or ``(commands_1, commands_2, distance, sigma)``,
/// each commands array of shape ``(n, actuators)``, distances ``(n,)`` in mm.
fn distances_arg(
    m: &PyMechanism,
    mm: &MeasurementModel,
    obj: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<pkmcal::Measurement>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(vec![]);
    };
    let expected = "distances: expected a tuple (commands_1, commands_2, distance) or (commands_1, commands_2, distance, sigma)";
    let t = obj.cast::<PyTuple>().map_err(|_| usage(expected))?;
    if !(3..=4).contains(&t.len()) {
        return Err(usage(expected));
    }
    mm.check_distances().map_err(lib_err)?;
    let a = rows(
        &t.get_item(0)?,
        "distances commands_1",
        &m.actuators(),
        false,
    )?
    .to_vecs();
    let b = rows(
        &t.get_item(1)?,
        "distances commands_2",
        &m.actuators(),
        false,
    )?
    .to_vecs();
    let one = |i: usize, what: &str| -> PyResult<Vec<f64>> {
        let item = t.get_item(i)?;
        let v: Vec<f64> = match item.extract::<Vec<f64>>() {
            Ok(v) => v,
            Err(_) => rows(&item, what, &[pkmcal::DISTANCE_AXIS.to_string()], false)?
                .to_vecs()
                .into_iter()
                .map(|v| v[0])
                .collect(),
        };
        if let Some(x) = v.iter().find(|x| !x.is_finite()) {
            return Err(usage(format!("{what}: {x} is not a finite number (mm)")));
        }
        Ok(v)
    };
    let d = one(2, "distances distance")?;
    let s = if t.len() == 4 {
        Some(one(3, "distances sigma")?)
    } else {
        None
    };
    if a.len() != b.len() || a.len() != d.len() || s.as_ref().is_some_and(|s| s.len() != d.len()) {
        return Err(usage(format!(
            "distances: commands_1 has {} rows, commands_2 {}, distance {}; give one of each per pair",
            a.len(),
            b.len(),
            d.len()
        )));
    }
    if let Some(v) = s.iter().flatten().find(|v| !(v.is_finite() && **v > 0.0)) {
        return Err(usage(format!("distances sigma must be positive, got {v}")));
    }
    Ok(a.into_iter()
        .zip(b)
        .zip(d)
        .enumerate()
        .map(|(i, ((a, b), d))| pkmcal::Measurement {
            target: None,
            commands: a,
            partner: Some(b),
            measured: vec![d],
            sigma: s.as_ref().map_or(vec![], |s| vec![Some(s[i])]),
            // Numbered as the rows of the arrays, from 0, as the poses are.
            origin: Some(Origin {
                pose: i,
                line: None,
                distance: true,
            }),
        })
        .collect())
}

fn measurements(
    m: &PyMechanism,
    mm: &MeasurementModel,
    commands: &Bound<'_, PyAny>,
    measured: &Bound<'_, PyAny>,
    sigma: Option<&Bound<'_, PyAny>>,
    targets: Option<&Bound<'_, PyAny>>,
    what: &str,
) -> PyResult<Vec<pkmcal::Measurement>> {
    let spec = m.spec();
    let c = rows(commands, &format!("{what}commands"), &m.actuators(), false)?.to_vecs();
    let y = rows(measured, &format!("{what}measured"), mm.axes(), false)?.to_vecs();
    if c.len() != y.len() {
        return Err(usage(format!(
            "{what}commands has {} rows and {what}measured {}; give one row of each per pose",
            c.len(),
            y.len()
        )));
    }
    let t = match targets.filter(|t| !t.is_none()) {
        Some(t) => {
            let t = rows(t, &format!("{what}targets"), &spec.tool_axes, false)?.to_vecs();
            if t.len() != c.len() {
                return Err(usage(format!(
                    "{what}targets has {} rows for {} poses",
                    t.len(),
                    c.len()
                )));
            }
            Some(t)
        }
        None => None,
    };
    let s = sigma_arg(sigma, mm, c.len())?;
    Ok(c.into_iter()
        .zip(y)
        .zip(s)
        .enumerate()
        .map(|(i, ((commands, measured), sigma))| pkmcal::Measurement {
            target: t.as_ref().map(|t| t[i].clone()),
            commands,
            partner: None,
            measured,
            sigma,
            origin: Some(Origin {
                pose: i,
                line: None,
                distance: false,
            }),
        })
        .collect())
}

fn noise_arg(length: f64, angle: Option<f64>) -> PyResult<Noise> {
    if !(length.is_finite() && length >= 0.0) {
        return Err(usage(format!(
            "noise must be a non-negative length in mm, got {length}"
        )));
    }
    if let Some(a) = angle
        && !(a.is_finite() && a >= 0.0)
    {
        return Err(usage(format!(
            "angle_noise must be a non-negative angle in rad, got {a}"
        )));
    }
    let mut noise = Noise::lengths(length);
    if let Some(a) = angle {
        noise.angle = a;
    }
    Ok(noise)
}

// ---------------------------------------------------------------- results

/// What `__reduce__` returns: a callable and its arguments.
type Reduced<'py, A> = (Bound<'py, PyAny>, A);

/// A result that pickles and compares by value: its state as a dict of
/// Python values (arrays stay arrays) and back.
trait ByValue: pyo3::PyClass<Frozen = pyo3::pyclass::boolean_struct::True> + Sync + Sized {
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>>;
    fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self>;
}

/// `ByValue` for a struct of Python-convertible fields.
macro_rules! by_value {
    ($ty:ty { $($f:ident),+ $(,)? }) => {
        impl ByValue for $ty {
            fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                let d = PyDict::new(py);
                $( d.set_item(stringify!($f), &self.$f)?; )+
                Ok(d)
            }
            fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self> {
                Ok(Self {
                    $( $f: state_item(d, stringify!($f))?.extract()?, )+
                })
            }
        }
    };
}

fn state_item<'py>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?
        .ok_or_else(|| usage(format!("a pickled pkmcal result without `{key}`")))
}

/// `ByValue` for a struct that holds library data (each `encoded` field
/// serialised whole, NaN kept) and plain Python-convertible fields.
macro_rules! by_serde {
    ($ty:ty { $($e:ident),+ $(; $($f:ident),+)? }) => {
        impl ByValue for $ty {
            fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
                let d = PyDict::new(py);
                $(
                    let mut bytes = vec![];
                    pkmcal_io::record::encode(&self.$e, &mut bytes).map_err(io_err)?;
                    d.set_item(stringify!($e), PyBytes::new(py, &bytes))?;
                )+
                $($( d.set_item(stringify!($f), &self.$f)?; )+)?
                Ok(d)
            }
            fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self> {
                Ok(Self {
                    $(
                        $e: pkmcal_io::record::decode(
                            state_item(d, stringify!($e))?.cast::<PyBytes>()?.as_bytes(),
                        )
                        .map_err(io_err)?,
                    )+
                    $($( $f: state_item(d, stringify!($f))?.extract()?, )+)?
                })
            }
        }
    };
}

/// What `__reduce__` returns: the class's `_from_state` and the state.
fn reduce<'py, T: ByValue>(slf: &Bound<'py, T>) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
    let py = slf.py();
    Ok((
        slf.as_any().get_type().getattr("_from_state")?,
        (slf.get().to_dict(py)?,),
    ))
}

/// Equal values: arrays elementwise with their shapes (NaN equal to NaN),
/// everything else with Python's `==`.
fn value_eq(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<bool> {
    let py = a.py();
    let np = py.import("numpy")?;
    let ndarray = np.getattr("ndarray")?;
    if a.is_instance(&ndarray)? || b.is_instance(&ndarray)? {
        let kw = PyDict::new(py);
        kw.set_item(
            "equal_nan",
            a.is_instance(&ndarray)?
                && a.getattr("dtype")?.getattr("kind")?.extract::<String>()? == "f",
        )?;
        return np
            .getattr("array_equal")?
            .call((a, b), Some(&kw))?
            .is_truthy();
    }
    a.eq(b)
}

/// `==` of two results of one class: every part of their state.
fn eq_by_value<T: ByValue>(a: &T, other: &Bound<'_, PyAny>) -> PyResult<bool> {
    let py = other.py();
    let Ok(o) = other.cast::<T>() else {
        return Ok(false);
    };
    let (x, y) = (a.to_dict(py)?, o.get().to_dict(py)?);
    for (k, v) in x.iter() {
        match y.get_item(&k)? {
            Some(w) if value_eq(&v, &w)? => {}
            _ => return Ok(false),
        }
    }
    Ok(x.len() == y.len())
}

/// Error statistics of a set of poses: per axis and over the position
/// distance (mm); angles apart (rad).
#[pyclass(frozen, module = "pkmcal", name = "ErrorStats", get_all)]
struct PyErrorStats {
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
struct PyWarning {
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

fn warning(w: &pkmcal::identify::Warning) -> PyWarning {
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
struct PyIdentifiability {
    id: Identifiability,
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

fn observability<'py>(
    py: Python<'py>,
    o: &pkmcal::identify::Observability,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in [
        ("O1", o.o1),
        ("O2", o.o2),
        ("O3", o.o3),
        ("O4", o.o4),
        ("O5", o.o5),
    ] {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// A rendered figure: ``svg`` (text), ``png`` (bytes), a title and a caption.
/// A notebook shows it inline.
#[pyclass(frozen, module = "pkmcal", name = "Figure", get_all)]
struct PyFigure {
    /// Short name (``errors``, ``parameters``, ``workspace``, ``maps``,
    /// ``residuals``, ``singular-values``).
    name: String,
    /// Title.
    title: String,
    /// What is shown and how to read it.
    caption: String,
    /// SVG text.
    svg: String,
    /// PNG image.
    png: Py<PyBytes>,
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

/// The result of :func:`calibrate`: identified parameters with their
/// standard deviations and covariance, identifiability, before/after
/// accuracy, warnings, residuals and figures.
#[pyclass(frozen, module = "pkmcal", name = "Calibration")]
struct PyCalibration {
    /// The mechanism calibrated.
    mechanism: Py<PyMechanism>,
    /// The whole calibration, as its record keeps it.
    state: CalibrationState,
}

/// A summary in Python's words.
const PY_WORDING: pkmcal_io::text::Wording = pkmcal_io::text::Wording {
    frame_base: "identified; frame=\"base\" if the data are in the base frame",
    all_correlations: "Calibration.correlation",
    hint: |w| w.hint.clone(),
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

fn by_name<'py>(
    py: Python<'py>,
    items: impl Iterator<Item = (String, f64)>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in items {
        d.set_item(k, v)?;
    }
    Ok(d)
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
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
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
    fn fun<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
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
    fn sigmas<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
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
        out.set_item("before", PyArray1::from_slice(py, &d.before))?;
        out.set_item("after", PyArray1::from_slice(py, &d.after))?;
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
        let figs = py
            .in_pool(|| self.with_inputs(pkmcal_io::report::figures))
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
        py.in_pool(|| {
            let json = self.report().to_json().map_err(io_err)?;
            written(|run| run.files.stage(std::path::Path::new(&p), json.as_bytes()))
        })
    }
    /// Write the report (report.html with every figure as SVG and PNG) into
    /// the directory ``path`` (created if needed).
    fn save_report(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = path_arg(path)?;
        py.in_pool(|| {
            written(|run| {
                self.with_inputs(|i| {
                    pkmcal_io::report::write_report_dir(run, std::path::Path::new(&p), i)
                })
            })
        })
    }
    /// Read a calibration saved whole (:meth:`save`, or ``pkmcal calibrate
    /// --report`` of this version): the same calibration, to the bit, with
    /// its mechanism (the description saved with it), figures, residuals
    /// and uncertainties. A record written by an older pkmcal holds only
    /// parameters and covariance; read it with :func:`load_calibration`.
    #[staticmethod]
    fn load(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let p = path_arg(path)?;
        let text = reading(|run| {
            run.files.read_to_string(
                std::path::Path::new(&p),
                pkmcal_io::output::InputKind::Description,
            )
        })
        .map_err(|e| usage(format!("cannot read calibration {p}: {e:#}")))?;
        Self::from_record(py, &text, &p)
    }
    /// The mechanism calibrated.
    #[getter]
    fn mechanism(&self, py: Python<'_>) -> Py<PyMechanism> {
        self.mechanism.clone_ref(py)
    }
    /// Pickled as its record (what :meth:`save` writes) with its mechanism,
    /// so that a process-pool worker can return it.
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<Reduced<'py, (Py<PyMechanism>, String)>> {
        let py = slf.py();
        let c = slf.get();
        let text = c.report().to_json().map_err(io_err)?;
        Ok((
            py.get_type::<PyCalibration>().getattr("_from_pickle")?,
            (c.mechanism.clone_ref(py), text),
        ))
    }
    #[staticmethod]
    fn _from_pickle(
        py: Python<'_>,
        mechanism: &Bound<'_, PyMechanism>,
        record: &str,
    ) -> PyResult<Self> {
        let (r, state) =
            pkmcal_io::record::record_from_str(record, "a pickled calibration").map_err(io_err)?;
        let state = state.ok_or_else(|| usage("a pickled calibration without its state"))?;
        let m = mechanism.get();
        let mechanism = PyMechanism {
            mech: m.mech.clone(),
            targets: m.targets.clone(),
            tolerances: m.tolerances.clone(),
            setup: m.setup.clone(),
            source: m.source.clone(),
            text: m.text.clone(),
        };
        Self::checked(py, mechanism, state, &r, "a pickled calibration")
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
    fn study(&self) -> &pkmcal::identify::Study {
        &self.state.study
    }
    fn cal(&self) -> &LibCalibration {
        &self.state.study.calibration
    }
    fn mech(&self) -> &Arc<AnyMechanism> {
        &self.mechanism.get().mech
    }

    /// The JSON report of this calibration (the calibration record).
    fn report(&self) -> pkmcal_io::record::Report<'_> {
        pkmcal_io::record::Report::new(
            self.mech().spec(),
            "Python arrays".into(),
            &self.state,
            validation_words,
        )
    }

    /// A calibration from its record's text (``source`` names it), with
    /// the mechanism of its state, checked against the record.
    fn from_record(py: Python<'_>, text: &str, source: &str) -> PyResult<Self> {
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
    fn checked(
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
    fn with_inputs<T>(&self, f: impl FnOnce(&pkmcal_io::report::ReportInputs) -> T) -> T {
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
struct PySavedCalibration {
    record: pkmcal::identify::CalibrationRecord,
    /// The file it was read from.
    source: String,
    /// The degrees of freedom of its estimated noise level, if recorded.
    dof: Option<f64>,
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
/// --report``).
#[pyfunction]
fn load_calibration(path: &Bound<'_, PyAny>) -> PyResult<PySavedCalibration> {
    let p = path_arg(path)?;
    let record = reading(|run| {
        pkmcal_io::record::read_calibration_record_dof(run, std::path::Path::new(&p))
    })
    .map_err(io_err)?;
    let (record, dof) = record;
    Ok(PySavedCalibration {
        record,
        source: p,
        dof,
    })
}

/// Predicted tool positions and what the model computed with them.
#[pyclass(frozen, module = "pkmcal", name = "Prediction", get_all)]
struct PyPrediction {
    /// Tool coordinates, shape (n, axes).
    x: Py<PyAny>,
    /// Joint configurations, shape (n, joints).
    q: Py<PyAny>,
    /// Internal actuator loads, shape (n, actuators): N·m for revolute, N for
    /// prismatic actuators.
    torque: Py<PyAny>,
    /// Deflections of the actuated joints (rad or mm), shape (n, actuators).
    deflection: Py<PyAny>,
    /// Covariance of ``x`` (n, axes, axes) from a calibration's parameter
    /// covariance, when asked for with ``uncertainty=True``; else None.
    covariance: Option<Py<PyAny>>,
    /// Rows whose commands did not assemble the mechanism on its branch
    /// (``skip_unreachable=True``; their outputs are NaN), from 0.
    skipped: Vec<usize>,
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
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!("<Prediction x={}>", self.x.bind(py).repr()?))
    }
}

/// Commands that bring the tool to its targets.
#[pyclass(frozen, module = "pkmcal", name = "Compensation", get_all)]
struct PyCompensation {
    /// Commands to send, shape (n, actuators).
    commands: Py<PyAny>,
    /// Commands of the nominal model for the same targets.
    nominal: Py<PyAny>,
    /// ``commands - nominal``.
    correction: Py<PyAny>,
    /// Internal actuator loads at the compensated pose (N·m or N).
    torque: Py<PyAny>,
    /// Joint configurations, shape (n, joints).
    q: Py<PyAny>,
    /// Rows whose target could not be reached (``skip_unreachable=True``;
    /// their values are NaN).
    skipped: Vec<usize>,
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
    fn __repr__(&self, py: Python<'_>) -> PyResult<String> {
        Ok(format!(
            "<Compensation commands={}>",
            self.commands.bind(py).repr()?
        ))
    }
}

/// A measurement plan.
#[pyclass(frozen, module = "pkmcal", name = "Plan", get_all)]
struct PyPlan {
    /// Chosen tool positions, shape (count, axes).
    targets: Py<PyAny>,
    /// Their nominal commands, shape (count, actuators).
    commands: Py<PyAny>,
    /// Observability indices O1…O5 of the plan.
    observability: Py<PyDict>,
    /// Condition number of the plan's scaled identification Jacobian.
    condition: f64,
    /// A plain grid of the same size (the baseline), shape (count, axes).
    grid_targets: Py<PyAny>,
    /// Observability of the grid.
    grid_observability: Py<PyDict>,
    /// Condition number of the grid.
    grid_condition: f64,
    /// Candidate lattice spacing used (mm).
    spacing: f64,
    /// Candidates scored.
    candidates: usize,
    /// Parameter directions the chosen poses determine (below the number of
    /// free parameters: some are left unidentified; an
    /// ``IdentifiabilityWarning`` says so).
    rank: usize,
    /// Number of free parameters.
    free: usize,
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
    fn __repr__(&self) -> String {
        format!(
            "<Plan: {} candidates, condition {:.2} (plain grid {:.2})>",
            self.candidates, self.condition, self.grid_condition
        )
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
by_value!(PyPrediction {
    x,
    q,
    torque,
    deflection,
    covariance,
    skipped
});
by_value!(PyCompensation {
    commands,
    nominal,
    correction,
    torque,
    q,
    skipped
});
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
    free
});

by_serde!(PySavedCalibration { record; source, dof });

// ---------------------------------------------------------------- functions

/// Predict the tool position reached at each row of ``commands``.
///
/// ``params``: None (nominal), a dict name → value (others nominal), a
/// :class:`Calibration`, a :class:`SavedCalibration` or a parameter file
/// path. ``model``: ``"exact"``, ``"linear"`` or ``"rigid"``; by default the
/// calibration's model when ``params`` is one, else ``"exact"``. ``load``: a
/// constant wrench on the tool (N along lengths, N·m about angles;
/// ``force=`` is its old name). ``uncertainty=True`` (with a calibration)
/// adds the covariance of each position. A row whose commands do not
/// assemble the mechanism on its branch raises, naming the row; with
/// ``skip_unreachable=True`` its outputs are NaN and it is listed in
/// ``skipped``.
#[pyfunction]
#[pyo3(signature = (mechanism, commands, params = None, *, model = None, load = None, force = None, uncertainty = false, skip_unreachable = false))]
#[allow(clippy::too_many_arguments)]
fn predict<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    commands: &Bound<'py, PyAny>,
    params: Option<&Bound<'py, PyAny>>,
    model: Option<&str>,
    load: Option<&Bound<'py, PyAny>>,
    force: Option<&Bound<'py, PyAny>>,
    uncertainty: bool,
    skip_unreachable: bool,
) -> PyResult<PyPrediction> {
    let mechanism = &mechanism_arg(mechanism)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let cal = params.and_then(|p| p.cast::<PyCalibration>().ok());
    let saved = params.and_then(|p| p.cast::<PySavedCalibration>().ok());
    // The model and covariance of a calibration, or of one read back.
    let (cal_model, cal_covariance) = match (&cal, &saved) {
        (Some(c), _) => (
            Some(c.get().cal().model),
            Some(c.get().cal().parameter_covariance.clone()),
        ),
        (None, Some(s)) => (
            Some(s.get().record.model),
            Some(s.get().record.covariance.clone()),
        ),
        (None, None) => (None, None),
    };
    let model = match (model, cal_model) {
        (Some(s), _) => parse_model(s)?,
        (None, Some(m)) => m,
        (None, None) => Model::Exact,
    };
    if uncertainty && cal_covariance.is_none() {
        return Err(usage(
            "uncertainty=True needs params=<a Calibration or SavedCalibration>: the covariance comes from its parameters",
        ));
    }
    let p = params_arg(m, params, "params")?;
    let force = load_arg(m, load, force)?;
    pkmcal::engine::load::check_load(&*m.mech, &p, &force)
        .map_err(|e| usage(format!("load: {e}")))?;
    let r = rows(commands, "commands", &m.actuators(), false)?;
    let mech = &*m.mech;
    let settings = pkmcal::RowSettings {
        params: &p,
        model,
        force: &force,
        covariance: cal_covariance.as_ref().filter(|_| uncertainty),
    };
    let v = r.view();
    let all: Vec<Vec<f64>> = (0..v.nrows()).map(|i| row(&v, i).into_owned()).collect();
    let results = py.in_pool(|| pkmcal::predict_rows(mech, &settings, &all, &|_| {}));
    let mut out: Vec<Option<pkmcal::RowPrediction>> = Vec::with_capacity(results.len());
    for (i, res) in results.into_iter().enumerate() {
        match res {
            Ok(p) => out.push(Some(p)),
            Err(_) if skip_unreachable => out.push(None),
            Err(e) => return Err(lib_err(at(i)(e))),
        }
    }
    let skipped: Vec<usize> = (0..out.len()).filter(|&i| out[i].is_none()).collect();
    let nx = spec.tool_axes.len();
    let na = spec.n_actuated();
    let nj = spec.joints.len();
    let flat = |f: &dyn Fn(&pkmcal::Prediction) -> &Vec<f64>, w: usize| -> Vec<f64> {
        out.iter()
            .flat_map(|p| match p {
                Some(p) => f(&p.prediction).clone(),
                None => vec![f64::NAN; w],
            })
            .collect()
    };
    let covariance = if uncertainty {
        let nan = DMatrix::from_element(nx, nx, f64::NAN);
        let mats: Vec<&DMatrix<f64>> = out
            .iter()
            .map(|p| {
                p.as_ref()
                    .and_then(|p| p.covariance.as_ref())
                    .unwrap_or(&nan)
            })
            .collect();
        Some(stacked(py, &mats, nx, r.single)?.unbind())
    } else {
        None
    };
    Ok(PyPrediction {
        x: out2(py, flat(&|p| &p.x, nx), nx, r.single).unbind(),
        q: out2(py, flat(&|p| &p.q, nj), nj, r.single).unbind(),
        torque: out2(py, flat(&|p| &p.torque, na), na, r.single).unbind(),
        deflection: out2(py, flat(&|p| &p.deflection, na), na, r.single).unbind(),
        covariance,
        skipped,
    })
}

/// Nominal commands (inverse kinematics with nominal parameters) of tool
/// positions, shape (n, actuators).
#[pyfunction]
fn nominal_commands<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let mechanism = &mechanism_arg(mechanism)?;
    let m = mech_ref(mechanism);
    let r = rows(targets, "targets", &m.spec().tool_axes, false)?;
    let mech = &*m.mech;
    let out = per_row(py, &r, |t| pkmcal::nominal_commands(mech, t))?;
    Ok(out2(py, out.concat(), m.spec().n_actuated(), r.single))
}

/// Simulate measurements at tool positions ``targets`` for a mechanism whose
/// true parameters are ``truth`` (None: nominal; a dict; a Calibration).
///
/// Returns ``(commands, measured)``: the nominal commands of each target and
/// what the instrument reads when they are sent, with Gaussian noise
/// (``noise`` mm on lengths, ``angle_noise`` rad on angles; default the
/// length noise over a 200 mm lever arm), seeded by ``seed``. The instrument
/// is the whole tool unless ``axes``, ``points`` or ``ballbar`` say otherwise
/// (as in :func:`calibrate`).
#[pyfunction]
#[pyo3(signature = (mechanism, targets, truth = None, *, noise = 0.0, angle_noise = None, seed = SeedArg::Given(None), axes = None, points = None, ballbar = None))]
#[allow(clippy::too_many_arguments)]
fn simulate<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyAny>,
    truth: Option<&Bound<'py, PyAny>>,
    noise: f64,
    angle_noise: Option<f64>,
    seed: SeedArg,
    axes: Option<Vec<String>>,
    points: Option<&Bound<'py, PyAny>>,
    ballbar: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let mechanism = &mechanism_arg(mechanism)?;
    let seed = seed_arg(seed)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let truth = params_arg(m, truth, "truth")?;
    let noise = noise_arg(noise, angle_noise)?;
    let mm = measurement_arg(m, axes, points, ballbar, "base")?;
    let r = rows(targets, "targets", &spec.tool_axes, false)?;
    let t = r.to_vecs();
    let mech = &*m.mech;
    let data = py
        .in_pool(|| pkmcal::simulate(mech, &mm, &truth, &t, noise, seed))
        .map_err(lib_err)?;
    let c: Vec<f64> = data.iter().flat_map(|d| d.commands.clone()).collect();
    let y: Vec<f64> = data.iter().flat_map(|d| d.measured.clone()).collect();
    Ok((
        out2(py, c, spec.n_actuated(), r.single),
        out2(py, y, mm.len(), r.single),
    ))
}

/// Identify parameter errors and encoder offsets from measurements (the
/// method of docs/model.md, eq. 12).
///
/// ``commands``: (n, actuators); ``measured``: (n, readings) — the tool
/// coordinates (``mechanism.tool_axes``), or with ``axes=[...]`` only those
/// (``axes=["probe"]``: heights probed on a bed plane whose height and tilts
/// are the parameters ``bed.z``, ``bed.rx``, ``bed.ry``, fixed unless freed),
/// with ``points=`` target points on the tool (``t1x, t1y, …``), with
/// ``ballbar=`` bar lengths (``d1, d2, …``). ``sigma``: the standard
/// deviation of the readings (a number when they share a unit, one per
/// reading, or (n, readings) with NaN where it is to be estimated).
/// ``frame``: ``"auto"`` (the default, as on the command line: an
/// instrument frame identified with the rest for whole positions and target
/// points, as a laser tracker reads them; the base frame for readings that
/// fix no frame), ``"base"`` (readings in the base frame) or ``"free"``.
/// ``targets``: (n, tool axes), the poses the commands were meant to reach
/// (for the "before" statistics; optional). ``ballbar``: a dict
/// ``{"sockets": (k, 2 or 3) mm, "bar_offset": mm}`` or ``"mechanism"`` for
/// the description's ``[ballbar]``.
/// ``free``/``fix``: parameter names (``"all"``, ``"default"``); ``start``:
/// starting parameters. ``load``: the wrench on the tool during the
/// measurements (N, N·m; ``force=`` is its old name). ``loss``:
/// ``"squared"``, ``"huber"`` or ``"cauchy"``, with ``loss_scale`` (robust
/// standard deviations; default 1.345 for huber, 2.385 for cauchy);
/// ``outlier_threshold`` (robust standard deviations, default 4) flags
/// outliers and ``drop_outliers=True`` refits without them.
/// Validation: ``validation=(commands, measured)``, or ``holdout=0.2``
/// (a fraction held out, drawn with ``seed``), and/or ``kfold=5`` (folds
/// drawn with ``seed``).
/// ``distances=(commands_1, commands_2, distance[, sigma])``: distances
/// measured between pairs of poses (calipers on a printed object, mm),
/// fitted with the readings (their noise estimated apart); their errors are
/// in ``Calibration.distances``.
/// Solver controls, as scipy's ``least_squares`` names them: ``max_nfev``
/// (evaluation budget, default 200), ``ftol``, ``xtol`` (default 1e-12),
/// ``gtol`` (default 0), ``bounds`` (a dict name → ``(lower, upper)``, ±inf
/// for an open side; mechanism or instrument parameters) and ``x0`` (the
/// start: a dict name → value like ``start``, or an array with one value per
/// free mechanism parameter in the order :func:`analyze`'s ``free`` lists
/// them).
/// ``stated_noise`` (mm) and ``stated_angle_noise`` (rad): the instrument's
/// stated noise, a prior of the noise estimates worth ``stated_readings``
/// readings, and what the model-adequacy test holds the residuals against
/// (a ``ModelWarning`` names the parameters whose freeing would explain
/// them). ``stated_distance_noise`` (mm): the same for ``distances``
/// (another instrument). ``stated_relative=True``: only the stated noises'
/// ratios are known; their scale is estimated and not tested.
/// ``tolerances``: priors (docs/model.md eq. 13), a dict name → σ or
/// ``"20%"`` beside the mechanism's ``[tolerances]`` table (replacing its
/// entries of the same names); ``False`` fits without priors. A parameter
/// with a tolerance is identified (unless ``fix`` names it) and held by it
/// where the data are weak: the fit is then the maximum a posteriori
/// estimate, ``Calibration.priors`` lists the priors and
/// ``Calibration.parameters`` each one's tolerance and share of information
/// from the data.
#[pyfunction]
#[pyo3(signature = (mechanism, commands, measured, *, sigma = None, targets = None, model = "exact", free = None, fix = None, start = None, loss = "squared", loss_scale = None, outlier_threshold = 4.0, drop_outliers = false, load = None, force = None, axes = None, points = None, ballbar = None, frame = "auto", validation = None, holdout = None, kfold = None, seed = SeedArg::Default(1), distances = None, max_nfev = None, ftol = None, xtol = None, gtol = None, bounds = None, x0 = None, tolerances = None, stated_noise = None, stated_angle_noise = None, stated_readings = pkmcal::identify::DEFAULT_STATED_NOISE_READINGS, stated_distance_noise = None, stated_relative = false))]
#[allow(clippy::too_many_arguments)]
fn calibrate<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    commands: &Bound<'py, PyAny>,
    measured: &Bound<'py, PyAny>,
    sigma: Option<&Bound<'py, PyAny>>,
    targets: Option<&Bound<'py, PyAny>>,
    model: &str,
    free: Option<&Bound<'py, PyAny>>,
    fix: Option<&Bound<'py, PyAny>>,
    start: Option<&Bound<'py, PyAny>>,
    loss: &str,
    loss_scale: Option<f64>,
    outlier_threshold: f64,
    drop_outliers: bool,
    load: Option<&Bound<'py, PyAny>>,
    force: Option<&Bound<'py, PyAny>>,
    axes: Option<Vec<String>>,
    points: Option<&Bound<'py, PyAny>>,
    ballbar: Option<&Bound<'py, PyAny>>,
    frame: &str,
    validation: Option<&Bound<'py, PyAny>>,
    holdout: Option<f64>,
    kfold: Option<usize>,
    seed: SeedArg,
    distances: Option<&Bound<'py, PyAny>>,
    max_nfev: Option<usize>,
    ftol: Option<f64>,
    xtol: Option<f64>,
    gtol: Option<f64>,
    bounds: Option<&Bound<'py, PyAny>>,
    x0: Option<&Bound<'py, PyAny>>,
    tolerances: Option<&Bound<'py, PyAny>>,
    stated_noise: Option<f64>,
    stated_angle_noise: Option<f64>,
    stated_readings: f64,
    stated_distance_noise: Option<f64>,
    stated_relative: bool,
) -> PyResult<PyCalibration> {
    let mechanism = &mechanism_arg(mechanism)?;
    let seed = seed_arg(seed)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let mm = measurement_arg(m, axes, points, ballbar, frame)?;
    let all = measurements(m, &mm, commands, measured, sigma, targets, "")?;
    let pairs = distances_arg(m, &mm, distances)?;
    let mut request = Request::new(parse_model(model)?);
    names_request(&mut request, free, fix)?;
    tolerances_request(&mut request, tolerances)?;
    request.stated_noise = stated_noise;
    request.stated_angle_noise = stated_angle_noise;
    request.stated_readings = stated_readings;
    request.stated_distance_noise = stated_distance_noise;
    request.stated_relative = stated_relative;
    request.load = load_arg(m, load, force)?;
    request.loss = loss.to_string();
    request.loss_scale = loss_scale;
    request.outlier_threshold = outlier_threshold;
    request.drop_outliers = drop_outliers;
    request.solver = pkmcal::identify::SolverRequest {
        max_evaluations: max_nfev,
        ftol,
        xtol,
        gtol,
        bounds: match bounds.filter(|b| !b.is_none()) {
            Some(b) => bounds_arg(b)?,
            None => vec![],
        },
    };
    let start = match (start.filter(|s| !s.is_none()), x0.filter(|s| !s.is_none())) {
        (Some(_), Some(_)) => return Err(usage("give either start= or x0=, not both")),
        (None, Some(x)) => {
            let (_, free) = request
                .priors_and_free(spec, &mm, &m.tolerances)
                .map_err(|e| lib_err(e.into()))?;
            x0_arg(m, &free, x)?
        }
        (s, None) => params_arg(m, s, "start")?,
    };
    request.validation = match validation.filter(|v| !v.is_none()) {
        None => None,
        Some(v) => {
            // A tuple or a list (any sequence that is not itself an array).
            let t = PyTuple::new(
                py,
                v.try_iter()
                    .and_then(|i| i.collect::<PyResult<Vec<_>>>())
                    .ok()
                    .filter(|_| !v.hasattr("shape").unwrap_or(false))
                    .ok_or_else(|| {
                        usage("validation: expected a tuple (commands, measured) or (commands, measured, sigma)")
                    })?,
            )?;
            if !(2..=3).contains(&t.len()) {
                return Err(usage(
                    "validation: expected a tuple (commands, measured) or (commands, measured, sigma)",
                ));
            }
            let s = if t.len() == 3 {
                Some(t.get_item(2)?)
            } else {
                None
            };
            Some(measurements(
                m,
                &mm,
                &t.get_item(0)?,
                &t.get_item(1)?,
                s.as_ref(),
                None,
                "validation ",
            )?)
        }
    };
    request.holdout = holdout;
    request.kfold = kfold;
    request.seed = seed;
    let mech = &*m.mech;
    let study_opts = request
        .study_options(mech, &mm, &m.tolerances, &start)
        .map_err(|e| lib_err(e.into()))?;
    let result = interruptible(py, |cancel| {
        let mut study_opts = study_opts;
        study_opts.calibration.solver.cancel = Some(cancel);
        pkmcal::identify::study(mech, &mm, &all, pairs, &start, &study_opts, &|| {})
    })?;
    let study = result.map_err(|e| lib_err(e.error))?;
    emit_warnings(py, &study.calibration.warnings)?;
    Ok(PyCalibration {
        mechanism: mechanism.clone().unbind(),
        state: CalibrationState {
            mechanism: match &m.text {
                Some(t) => MechanismSource::Description(t.clone()),
                None => MechanismSource::Reference,
            },
            measurement: mm,
            study,
        },
    })
}

/// Identifiability of the free parameters from poses and readings at
/// ``params`` (nominal by default), without fitting: rank, singular values
/// and the combinations the data cannot see. Arguments as :func:`calibrate`;
/// with tolerances (the mechanism's table, or ``tolerances``) their
/// information counts, readings without a given σ weighed with ``noise``
/// (mm) and ``angle_noise`` (rad), and ``Identifiability.held`` lists what
/// they hold.
#[pyfunction]
#[pyo3(signature = (mechanism, commands, measured, *, params = None, sigma = None, model = "exact", free = None, fix = None, load = None, force = None, axes = None, points = None, ballbar = None, frame = "auto", tolerances = None, noise = 0.002, angle_noise = None))]
#[allow(clippy::too_many_arguments)]
fn analyze<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    commands: &Bound<'py, PyAny>,
    measured: &Bound<'py, PyAny>,
    params: Option<&Bound<'py, PyAny>>,
    sigma: Option<&Bound<'py, PyAny>>,
    model: &str,
    free: Option<&Bound<'py, PyAny>>,
    fix: Option<&Bound<'py, PyAny>>,
    load: Option<&Bound<'py, PyAny>>,
    force: Option<&Bound<'py, PyAny>>,
    axes: Option<Vec<String>>,
    points: Option<&Bound<'py, PyAny>>,
    ballbar: Option<&Bound<'py, PyAny>>,
    frame: &str,
    tolerances: Option<&Bound<'py, PyAny>>,
    noise: f64,
    angle_noise: Option<f64>,
) -> PyResult<PyIdentifiability> {
    let mechanism = &mechanism_arg(mechanism)?;
    let m = mech_ref(mechanism);
    let mm = measurement_arg(m, axes, points, ballbar, frame)?;
    let data = measurements(m, &mm, commands, measured, sigma, None, "")?;
    let params = params_arg(m, params, "params")?;
    let model = parse_model(model)?;
    let mut request = Request::new(model);
    names_request(&mut request, free, fix)?;
    tolerances_request(&mut request, tolerances)?;
    request.load = load_arg(m, load, force)?;
    request.stated_noise = Some(noise);
    request.stated_angle_noise = angle_noise;
    let (priors, free) = free_of(&request, m, &mm)?;
    let force = request
        .checked_load(&*m.mech, &params)
        .map_err(|e| lib_err(e.into()))?;
    let noise = request
        .weighing_noise(!priors.is_empty())
        .map_err(|e| lib_err(e.into()))?;
    let mech = &*m.mech;
    let id = py
        .in_pool(|| {
            if priors.is_empty() {
                pkmcal::analyze(mech, &mm, &data, &params, model, &free, &force)
            } else {
                pkmcal::identify::analyze_with_priors(
                    mech, &mm, &data, &params, model, &free, &force, &priors, noise,
                )
            }
        })
        .map_err(lib_err)?;
    Ok(PyIdentifiability { id })
}

/// Commands that bring the tool to each row of ``targets`` under ``params``
/// (a Calibration, a dict or None), deflections included (``model="exact"``)
/// or not (``"rigid"``); ``load``: a wrench on the tool; ``preload``:
/// actuator loads whose internal part is held. An unreachable or singular
/// target raises, naming its row; with ``skip_unreachable=True`` its row is
/// NaN and listed in ``skipped``.
#[pyfunction]
#[pyo3(signature = (mechanism, targets, params = None, *, model = "exact", load = None, force = None, preload = None, skip_unreachable = false))]
#[allow(clippy::too_many_arguments)]
fn compensate<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyAny>,
    params: Option<&Bound<'py, PyAny>>,
    model: &str,
    load: Option<&Bound<'py, PyAny>>,
    force: Option<&Bound<'py, PyAny>>,
    preload: Option<&Bound<'py, PyAny>>,
    skip_unreachable: bool,
) -> PyResult<PyCompensation> {
    let mechanism = &mechanism_arg(mechanism)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let p = params_arg(m, params, "params")?;
    let model = parse_model(model)?;
    let force = load_arg(m, load, force)?;
    pkmcal::engine::load::check_load(&*m.mech, &p, &force)
        .map_err(|e| usage(format!("load: {e}")))?;
    let opts = pkmcal::CompensationOptions {
        force,
        preload: match vector_arg(preload, "preload", "actuator")? {
            None => vec![],
            Some(v) => finite_list(&v, "preload", spec.n_actuated())?,
        },
    };
    let r = rows(targets, "targets", &spec.tool_axes, false)?;
    let mech = &*m.mech;
    let out: Vec<Option<pkmcal::Compensation>> = per_row(py, &r, |t| {
        match pkmcal::compensate(mech, &p, t, model, &opts) {
            Ok(c) => Ok(Some(c)),
            Err(_) if skip_unreachable => Ok(None),
            Err(e) => Err(e),
        }
    })?;
    let na = spec.n_actuated();
    let nj = spec.joints.len();
    let flat = |f: &dyn Fn(&pkmcal::Compensation) -> &Vec<f64>, w: usize| -> Vec<f64> {
        out.iter()
            .flat_map(|c| match c {
                Some(c) => f(c).clone(),
                None => vec![f64::NAN; w],
            })
            .collect()
    };
    let skipped: Vec<usize> = (0..out.len()).filter(|&i| out[i].is_none()).collect();
    Ok(PyCompensation {
        commands: out2(py, flat(&|c| &c.commands, na), na, r.single).unbind(),
        nominal: out2(py, flat(&|c| &c.nominal, na), na, r.single).unbind(),
        correction: out2(py, flat(&|c| &c.correction, na), na, r.single).unbind(),
        torque: out2(py, flat(&|c| &c.torque, na), na, r.single).unbind(),
        q: out2(py, flat(&|c| &c.q, nj), nj, r.single).unbind(),
        skipped,
    })
}

/// Choose ``count`` poses that make the free parameters most observable
/// (greedy selection then exchanges, over a lattice of the usable
/// workspace). ``criterion``: ``"O1"`` (D-optimal), ``"O3"`` or ``"O5"``
/// (default); ``spacing``: lattice spacing in mm; ``max_candidates``: most
/// lattice points scored. ``tolerances`` (as :func:`calibrate` takes them;
/// the mechanism's table by default, ``False`` for none): the plan is
/// optimal given what they already tell, its poses measured with ``noise``
/// (mm) and ``angle_noise`` (rad).
#[pyfunction]
#[pyo3(signature = (mechanism, count, params = None, *, criterion = "O5", model = "exact", free = None, fix = None, spacing = 6.0, max_candidates = 4000, tolerances = None, noise = 0.002, angle_noise = None))]
#[allow(clippy::too_many_arguments)]
fn plan<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    count: usize,
    params: Option<&Bound<'py, PyAny>>,
    criterion: &str,
    model: &str,
    free: Option<&Bound<'py, PyAny>>,
    fix: Option<&Bound<'py, PyAny>>,
    spacing: f64,
    max_candidates: usize,
    tolerances: Option<&Bound<'py, PyAny>>,
    noise: f64,
    angle_noise: Option<f64>,
) -> PyResult<PyPlan> {
    let mechanism = &mechanism_arg(mechanism)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let params = params_arg(m, params, "params")?;
    let tool = MeasurementModel::tool(spec);
    let mut request = Request::new(parse_model(model)?);
    names_request(&mut request, free, fix)?;
    tolerances_request(&mut request, tolerances)?;
    request.stated_noise = Some(noise);
    request.stated_angle_noise = angle_noise;
    let (priors, free) = free_of(&request, m, &tool)?;
    let noise = request
        .weighing_noise(!priors.is_empty())
        .map_err(|e| lib_err(e.into()))?;
    let opts = pkmcal::PlanOptions {
        count,
        criterion: criterion.parse().map_err(lib_err)?,
        model: request.model,
        free,
        spacing,
        max_candidates,
        cancel: None,
        priors,
        noise,
    };
    let mech = &*m.mech;
    let p = interruptible(py, |cancel| {
        let opts = pkmcal::PlanOptions {
            cancel: Some(cancel),
            ..opts
        };
        pkmcal::plan(mech, &params, &opts, &|| {})
    })?
    .map_err(lib_err)?;
    emit_warnings(py, &p.warnings)?;
    let nx = spec.tool_axes.len();
    let targets = |s: &[pkmcal::WorkspacePoint]| -> Vec<f64> {
        s.iter().flat_map(|w| w.target.iter().copied()).collect()
    };
    let commands: Vec<f64> = p
        .poses
        .iter()
        .flat_map(|w| spec.actuated.iter().map(|&j| w.q[j]).collect::<Vec<_>>())
        .collect();
    Ok(PyPlan {
        targets: out2(py, targets(&p.poses), nx, false).unbind(),
        commands: out2(py, commands, spec.n_actuated(), false).unbind(),
        observability: observability(py, &p.observability)?.unbind(),
        condition: p.condition,
        grid_targets: out2(py, targets(&p.grid), nx, false).unbind(),
        grid_observability: observability(py, &p.grid_observability)?.unbind(),
        grid_condition: p.grid_condition,
        spacing: p.spacing,
        candidates: p.candidates,
        rank: p.rank,
        free: p.free,
    })
}

/// A tolerance budget (:func:`budget`): the tool error the tolerances give
/// over the workspace, each tolerance's share, and what a planned
/// calibration would leave.
#[pyclass(frozen, module = "pkmcal", name = "Budget")]
struct PyBudget {
    b: pkmcal::apply::budget::Budget,
    /// The mechanism's name, for the summary.
    mechanism: String,
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

/// The tool error a mechanism's parameter tolerances give over its
/// workspace, before any machine exists: to first order through the exact
/// model's Jacobian at ``grid`` targets spread over the workspace, checked by
/// ``samples`` machines drawn from the tolerances (0: none); each
/// tolerance's share; and, with ``poses`` (targets a calibration would
/// measure the tool at, with ``noise`` mm and ``angle_noise`` rad), what
/// that calibration would leave. ``tolerances``: a dict name → σ (in the
/// parameter's unit) or ``"20%"`` (of its nominal value); by default the
/// description's ``[tolerances]`` table (given ones replace its entries).
#[pyfunction]
#[pyo3(signature = (mechanism, tolerances = None, *, grid = 200, samples = 3000, seed = SeedArg::Default(1), model = "exact", poses = None, noise = 0.002, angle_noise = None))]
#[allow(clippy::too_many_arguments)]
fn budget<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    tolerances: Option<&Bound<'py, PyAny>>,
    grid: usize,
    samples: usize,
    seed: SeedArg,
    model: &str,
    poses: Option<&Bound<'py, PyAny>>,
    noise: f64,
    angle_noise: Option<f64>,
) -> PyResult<PyBudget> {
    let mechanism = &mechanism_arg(mechanism)?;
    let seed = seed_arg(seed)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    let given = tolerances_arg(tolerances)?;
    let given = pkmcal::apply::budget::merged_tolerances(&m.tolerances, given);
    if given.is_empty() {
        return Err(usage(
            "no tolerance: give tolerances={name: σ} or describe the mechanism with a [tolerances] table",
        ));
    }
    let resolved = pkmcal::apply::budget::resolve_tolerances(spec, &given)
        .map_err(|e| usage(format!("tolerances: {e}")))?;
    let calibration = match poses.filter(|p| !p.is_none()) {
        Some(p) => Some(pkmcal::apply::budget::PlannedCalibration {
            targets: rows(p, "poses", &spec.tool_axes, false)?.to_vecs(),
            noise: noise_arg(noise, angle_noise)?,
        }),
        None => None,
    };
    let opts = pkmcal::apply::budget::BudgetOptions {
        model: parse_model(model)?,
        force: vec![],
        samples,
        seed,
        calibration,
    };
    let mech = &*m.mech;
    let b = py
        .in_pool(|| -> pkmcal::Result<_> {
            let targets = pkmcal::apply::budget::budget_targets(mech, grid)?;
            pkmcal::apply::budget::budget(mech, &targets, &resolved, &opts)
        })
        .map_err(lib_err)?;
    Ok(PyBudget {
        b,
        mechanism: spec.name.clone(),
    })
}

/// What :func:`drift` found: each parameter's change against what both
/// calibrations' covariances allow, and the joint test.
#[pyclass(frozen, module = "pkmcal", name = "Drift")]
struct PyDrift {
    d: pkmcal::identify::Drift,
    /// The summary's text.
    text: String,
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
    fn __repr__(&self) -> String {
        format!(
            "<Drift: {} of {} parameters drifted; joint p {:.3e}>",
            self.drifted().len(),
            self.d.parameters.len(),
            self.d.p_joint
        )
    }
}

by_serde!(PyDrift { d; text });

/// A calibration for the drift test: its values, covariance, the identity
/// of its mechanism, and the mechanism when it has one.
fn compared_arg(
    c: &Bound<'_, PyAny>,
    what: &str,
) -> PyResult<(
    pkmcal::identify::Compared,
    String,
    Option<Arc<AnyMechanism>>,
)> {
    if let Ok(cal) = c.cast::<PyCalibration>() {
        let cal = cal.get();
        return Ok((
            pkmcal::identify::Compared::from_calibration(cal.cal()),
            pkmcal::identify::mechanism_identity(cal.mech().spec()),
            Some(cal.mech().clone()),
        ));
    }
    let (record, dof) = if let Ok(s) = c.cast::<PySavedCalibration>() {
        (s.get().record.clone(), s.get().dof)
    } else if c.is_instance_of::<pyo3::types::PyString>() || c.hasattr("__fspath__")? {
        let p = path_arg(c)?;
        reading(|run| pkmcal_io::record::read_calibration_record_dof(run, std::path::Path::new(&p)))
            .map_err(io_err)?
    } else {
        return Err(usage(format!(
            "{what}: expected a Calibration, a SavedCalibration or a calibration record's path"
        )));
    };
    Ok((
        pkmcal::identify::Compared::from_record(&record, dof),
        record.mechanism_identity.clone(),
        None,
    ))
}

/// Has the machine changed, or only the noise? Compare the calibration
/// ``new`` with ``old`` (an earlier calibration of the same machine) or,
/// without ``old``, with the mechanism's nominal values: each parameter
/// identified in both, its change against ``√(σ_old² + σ_new²)``, sorted by
/// significance; Holm–Bonferroni keeps the chance of any false alarm at
/// ``alpha``; a joint χ² test includes the correlations. Each is a
/// :class:`Calibration`, a :class:`SavedCalibration` or a record's path;
/// ``mechanism`` is needed for the nominal values when ``new`` is not a
/// :class:`Calibration`. With the mechanism at hand, the change at the tool
/// over ``grid`` workspace targets too (``Drift.workspace``; 0: none).
#[pyfunction]
#[pyo3(signature = (new, old = None, *, mechanism = None, alpha = 0.05, grid = 100))]
fn drift<'py>(
    new: &Bound<'py, PyAny>,
    old: Option<&Bound<'py, PyAny>>,
    mechanism: Option<&Bound<'py, PyAny>>,
    alpha: f64,
    grid: usize,
) -> PyResult<PyDrift> {
    let (b, b_id, b_mech) = compared_arg(new, "new")?;
    let given = mechanism
        .filter(|m| !m.is_none())
        .map(|m| mechanism_arg(m).map(|m| m.get().mech.clone()))
        .transpose()?;
    let mech = given.or(b_mech);
    let (a, old_name) = match old.filter(|o| !o.is_none()) {
        Some(o) => {
            let (a, a_id, _) = compared_arg(o, "old")?;
            if !a_id.is_empty() && !b_id.is_empty() && a_id != b_id {
                return Err(usage(
                    "old and new are calibrations of different mechanisms (other joints, parameters or nominal values); compare calibrations of one machine",
                ));
            }
            (a, "old".to_string())
        }
        None => {
            let m = mech.as_ref().ok_or_else(|| {
                usage("drift against the nominal values needs the mechanism: give mechanism=")
            })?;
            (
                pkmcal::identify::Compared::nominal(m.spec()),
                "the nominal values".to_string(),
            )
        }
    };
    let mut d = pkmcal::identify::drift(&a, &b, alpha).map_err(lib_err)?;
    if let (Some(m), true) = (mech.as_deref(), grid > 0) {
        let targets = pkmcal::apply::budget::budget_targets(m, grid).map_err(lib_err)?;
        d.workspace = Some(
            pkmcal::apply::tooldrift::workspace_drift(m, &a, &b, &targets, alpha)
                .map_err(lib_err)?,
        );
    }
    let text = pkmcal_io::text::drift_words(mech.as_ref().map(|m| m.spec()), &d, &old_name, "new");
    Ok(PyDrift { d, text })
}

/// What :func:`montecarlo` found: the summary over the runs and each run's
/// figures.
#[pyclass(frozen, module = "pkmcal", name = "MonteCarlo", get_all)]
struct PyMonteCarlo {
    /// Runs made.
    runs: usize,
    /// Runs that converged.
    converged: usize,
    /// Median over the runs of the validation RMS distance error (mm).
    validation_rms_median: f64,
    /// 95th percentile of the validation RMS distance error (mm).
    validation_rms_p95: f64,
    /// Median of the validation maximum distance error (mm).
    validation_max_median: f64,
    /// Free parameter names (columns of ``parameter_errors``).
    parameters: Vec<String>,
    /// RMS over the runs of each free parameter's error (its unit).
    parameter_rms_error: Py<PyAny>,
    /// Whether each run converged, shape (runs,).
    run_converged: Py<PyAny>,
    /// Each run's validation RMS distance error (mm), shape (runs,).
    validation_rms: Py<PyAny>,
    /// Each run's validation maximum distance error (mm), shape (runs,).
    validation_max: Py<PyAny>,
    /// Identified minus true value of each free parameter, shape (runs, free).
    parameter_errors: Py<PyAny>,
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
        )?;
        slf.getattr(key)
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

/// Monte Carlo study of a measurement plan: ``runs`` simulated calibrations
/// from the poses ``targets``, each with random parameter errors
/// (``length_error`` mm, ``angle_error`` rad on the free parameters) and
/// measurement noise, judged on ``validation`` random unseen poses.
/// ``tolerances`` (as :func:`calibrate` takes them; the mechanism's table by
/// default, ``False`` for none): each run's parameters with a tolerance are
/// drawn from it, and the fits use them as priors.
///
/// Returns a :class:`MonteCarlo`: the medians and per-parameter RMS errors,
/// and each run's figures.
#[pyfunction]
#[pyo3(signature = (mechanism, targets, *, runs = 200, noise = 0.002, angle_noise = None, seed = SeedArg::Default(1), model = "exact", free = None, fix = None, length_error = 0.3, angle_error = 0.001, validation = 50, tolerances = None))]
#[allow(clippy::too_many_arguments)]
fn montecarlo<'py>(
    py: Python<'py>,
    mechanism: &Bound<'py, PyAny>,
    targets: &Bound<'py, PyAny>,
    runs: usize,
    noise: f64,
    angle_noise: Option<f64>,
    seed: SeedArg,
    model: &str,
    free: Option<&Bound<'py, PyAny>>,
    fix: Option<&Bound<'py, PyAny>>,
    length_error: f64,
    angle_error: f64,
    validation: usize,
    tolerances: Option<&Bound<'py, PyAny>>,
) -> PyResult<PyMonteCarlo> {
    let mechanism = &mechanism_arg(mechanism)?;
    let seed = seed_arg(seed)?;
    let m = mech_ref(mechanism);
    let spec = m.spec();
    if runs == 0 || validation == 0 {
        return Err(usage("runs and validation must be at least 1"));
    }
    for (v, name) in [(length_error, "length_error"), (angle_error, "angle_error")] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(usage(format!(
                "{name} must be a non-negative number, got {v}"
            )));
        }
    }
    let poses = rows(targets, "targets", &spec.tool_axes, false)?.to_vecs();
    let mut cal = CalibrationOptions::new(spec, parse_model(model)?);
    let tool = MeasurementModel::tool(spec);
    let mut request = Request::new(cal.model);
    names_request(&mut request, free, fix)?;
    tolerances_request(&mut request, tolerances)?;
    (cal.priors, cal.free) = free_of(&request, m, &tool)?;
    let opts = pkmcal::MonteCarloOptions {
        runs,
        noise: noise_arg(noise, angle_noise)?,
        seed,
        length_error,
        angle_error,
        calibration: cal,
    };
    let mech = &*m.mech;
    let (each, s) = interruptible(py, |cancel| -> pkmcal::Result<_> {
        let mut opts = opts;
        opts.calibration.solver.cancel = Some(cancel);
        for (i, t) in poses.iter().enumerate() {
            pkmcal::nominal_commands(mech, t).map_err(at(i))?;
        }
        let val = pkmcal::validation_targets(mech, validation, seed)?;
        pkmcal::monte_carlo(mech, &poses, &val, &opts, &|| {})
    })?
    .map_err(lib_err)?;
    let n = s.parameters.len();
    Ok(PyMonteCarlo {
        runs: s.runs,
        converged: s.converged,
        validation_rms_median: s.validation_rms_median,
        validation_rms_p95: s.validation_rms_p95,
        validation_max_median: s.validation_max_median,
        parameter_rms_error: vec1(py, &s.parameter_rms_error).into_any().unbind(),
        run_converged: PyArray1::from_iter(py, each.iter().map(|r| r.converged))
            .into_any()
            .unbind(),
        validation_rms: PyArray1::from_iter(py, each.iter().map(|r| r.validation.distance_rms))
            .into_any()
            .unbind(),
        validation_max: PyArray1::from_iter(py, each.iter().map(|r| r.validation.distance_max))
            .into_any()
            .unbind(),
        parameter_errors: out2(
            py,
            each.iter()
                .flat_map(|r| r.parameter_errors.iter().copied())
                .collect(),
            n,
            false,
        )
        .unbind(),
        parameters: s.parameters,
    })
}

/// Positions from ball-bar readings: for each row of ``readings`` (bar
/// lengths to each socket, mm), the point whose distances to ``sockets``
/// (k, 2 or 3; base frame, mm) best match them, and its covariance for
/// readings of standard deviation ``sigma`` (mm). Returns
/// ``(positions (n, dim), covariances (n, dim, dim))``.
#[pyfunction]
#[pyo3(signature = (sockets, readings, *, bar_offset = 0.0, sigma = 0.002))]
fn trilaterate<'py>(
    py: Python<'py>,
    sockets: &Bound<'py, PyAny>,
    readings: &Bound<'py, PyAny>,
    bar_offset: f64,
    sigma: f64,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    if !(sigma.is_finite() && sigma > 0.0) {
        return Err(usage(format!(
            "sigma must be a positive length in mm, got {sigma}"
        )));
    }
    let setup = pkmcal::Setup {
        sockets: sockets_arg(sockets, "sockets")?,
        bar_offset,
    };
    let dim = setup.sockets[0].len();
    setup.validate(dim).map_err(lib_err)?;
    let cols: Vec<String> = (1..=setup.sockets.len()).map(|k| format!("d{k}")).collect();
    let r = rows(readings, "readings", &cols, false)?;
    let out = per_row(py, &r, |d| pkmcal::trilaterate(&setup, d, sigma, None))?;
    let x: Vec<f64> = out.iter().flat_map(|(x, _)| x.iter().copied()).collect();
    let mats: Vec<&DMatrix<f64>> = out.iter().map(|(_, c)| c).collect();
    let cov = stacked(py, &mats, dim, r.single)?;
    Ok((out2(py, x, dim, r.single), cov))
}

/// Kinematic calibration of (redundantly actuated) parallel mechanisms.
#[pymodule]
fn _pkmcal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    // NumPy's C API is fetched here, at import, rather than by the first
    // call that makes an array: a Ctrl-C landing during that fetch became a
    // panic (`PanicException`, which `except Exception` does not catch).
    // Here NumPy is imported first (an interruption is then Python's own
    // KeyboardInterrupt, failing the import), and the capsule is fetched
    // from the module already loaded.
    m.py().import("numpy")?;
    let _ = PyArray1::<f64>::zeros(m.py(), [0], false);
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("PkmcalError", m.py().get_type::<PkmcalError>())?;
    m.add("PkmcalWarning", m.py().get_type::<PkmcalWarning>())?;
    m.add(
        "ConvergenceWarning",
        m.py().get_type::<ConvergenceWarning>(),
    )?;
    m.add(
        "IdentifiabilityWarning",
        m.py().get_type::<IdentifiabilityWarning>(),
    )?;
    m.add("OutlierWarning", m.py().get_type::<OutlierWarning>())?;
    m.add("ToleranceWarning", m.py().get_type::<ToleranceWarning>())?;
    m.add("ModelWarning", m.py().get_type::<ModelWarning>())?;
    m.add_class::<PyMechanism>()?;
    m.add_class::<PyCalibration>()?;
    m.add_class::<PyMonteCarlo>()?;
    m.add_class::<PyBudget>()?;
    m.add_class::<PyDrift>()?;
    m.add_class::<PyIdentifiability>()?;
    m.add_class::<PyErrorStats>()?;
    m.add_class::<PyWarning>()?;
    m.add_class::<PyFigure>()?;
    m.add_class::<PyPrediction>()?;
    m.add_class::<PyCompensation>()?;
    m.add_class::<PyPlan>()?;
    m.add_class::<PySavedCalibration>()?;
    m.add_function(wrap_pyfunction!(load_calibration, m)?)?;
    m.add_function(wrap_pyfunction!(set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(predict, m)?)?;
    m.add_function(wrap_pyfunction!(nominal_commands, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(analyze, m)?)?;
    m.add_function(wrap_pyfunction!(compensate, m)?)?;
    m.add_function(wrap_pyfunction!(plan, m)?)?;
    m.add_function(wrap_pyfunction!(montecarlo, m)?)?;
    m.add_function(wrap_pyfunction!(budget, m)?)?;
    m.add_function(wrap_pyfunction!(drift, m)?)?;
    m.add_function(wrap_pyfunction!(trilaterate, m)?)?;
    Ok(())
}
