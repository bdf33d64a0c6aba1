//! Errors and warnings in Python's terms: `PkmcalError` (a `ValueError`)
//! for bad input, its `OSError` subclasses for files, the calibration's
//! warnings in their categories, and every refused choice worded with the
//! keyword that sets it.

use pyo3::create_exception;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

create_exception!(
    pkmcal,
    PkmcalError,
    PyValueError,
    "Bad input or an impossible request. `str(e)` says what happened and what to do; \
`e.pose` is the row (from 0) of the arrays where it happened, or None. A file that \
cannot be read or written raises a subclass that is also Python's own `OSError` \
(`FileNotFoundError`, `PermissionError`, …) with `errno` and `filename`."
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
    "The residuals do not match the instrument's stated noise: above it (the model misses something, or the noise is understated) or well below it (the noise is overstated)."
);
create_exception!(
    pkmcal,
    ToleranceWarning,
    PkmcalWarning,
    "An identified value far outside its tolerance, tolerances the data push against, or parameters the data taught little beyond their tolerances."
);

/// The exception classes of files: each Python's own `OSError` class and
/// `PkmcalError` (`PkmcalOSError` for any other system error), made once.
/// Their `str()` is pkmcal's message (what to do included), not
/// `OSError`'s `[Errno 2] …`; `errno`, `strerror` and `filename` are set.
pub const FILE_ERRORS: [(&str, &str); 6] = [
    ("PkmcalOSError", "OSError"),
    ("PkmcalFileNotFoundError", "FileNotFoundError"),
    ("PkmcalPermissionError", "PermissionError"),
    ("PkmcalIsADirectoryError", "IsADirectoryError"),
    ("PkmcalNotADirectoryError", "NotADirectoryError"),
    ("PkmcalFileExistsError", "FileExistsError"),
];

static FILE_CLASSES: PyOnceLock<Vec<Py<PyType>>> = PyOnceLock::new();

/// The classes of [`FILE_ERRORS`], in its order.
pub fn file_classes(py: Python<'_>) -> PyResult<&Vec<Py<PyType>>> {
    FILE_CLASSES.get_or_try_init(py, || {
        let builtins = py.import("builtins")?;
        let base_exception = builtins.getattr("BaseException")?;
        let pkmcal = py.get_type::<PkmcalError>();
        let mut out: Vec<Py<PyType>> = vec![];
        for (name, os) in FILE_ERRORS {
            let os = builtins.getattr(os)?;
            // Every file error is also a PkmcalOSError.
            let bases = match out.first() {
                None => PyTuple::new(py, [os, pkmcal.clone().into_any()])?,
                Some(general) => PyTuple::new(py, [os, general.bind(py).clone().into_any()])?,
            };
            let dict = PyDict::new(py);
            dict.set_item("__module__", "pkmcal")?;
            dict.set_item(
                "__doc__",
                format!(
                    "A file that cannot be read or written: Python's `{}` and `PkmcalError`.",
                    bases.get_item(0)?.getattr("__name__")?
                ),
            )?;
            dict.set_item("__str__", base_exception.getattr("__str__")?)?;
            let class = py
                .get_type::<PyType>()
                .call1((name, bases, dict))?
                .cast_into::<PyType>()?;
            out.push(class.unbind());
        }
        Ok(out)
    })
}

/// A `PkmcalError` with `message`; `pose` the array row it is about.
pub fn raise(message: String, pose: Option<usize>) -> PyErr {
    let err = PkmcalError::new_err(message);
    Python::attach(|py| {
        let _ = err.value(py).setattr("pose", pose);
    });
    err
}

/// Bad input, worded by the caller.
pub fn usage(message: impl Into<String>) -> PyErr {
    raise(message.into(), None)
}

/// A value of the wrong type for keyword `name` (Python's `TypeError`).
pub fn wrong_type(name: &str, expected: &str, got: &Bound<'_, PyAny>) -> PyErr {
    let kind = got
        .get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_default();
    pyo3::exceptions::PyTypeError::new_err(format!("{name}: expected {expected}, got {kind}"))
}

/// A file error as the `OSError` subclass of its system error (`errno`,
/// `strerror`, `filename` set), with `message` as its text.
fn file_error(
    py: Python<'_>,
    message: String,
    cause: &std::io::Error,
    path: &std::path::Path,
) -> PyResult<PyErr> {
    use std::io::ErrorKind as K;
    let classes = file_classes(py)?;
    let k = match cause.kind() {
        K::NotFound => 1,
        K::PermissionDenied => 2,
        K::IsADirectory => 3,
        K::NotADirectory => 4,
        K::AlreadyExists => 5,
        _ => 0,
    };
    let e = classes[k].bind(py).call1((message,))?;
    e.setattr("errno", cause.raw_os_error())?;
    e.setattr("strerror", cause.to_string())?;
    e.setattr("filename", path.to_string_lossy().to_string())?;
    e.setattr("pose", py.None())?;
    Ok(PyErr::from_value(e))
}

/// A system error reading or writing `path` (outside `pkmcal_io`).
pub fn os_err(message: String, cause: &std::io::Error, path: &std::path::Path) -> PyErr {
    Python::attach(|py| file_error(py, message, cause, path).unwrap_or_else(|e| e))
}

/// A library error as a Python exception.
pub fn lib_err(e: pkmcal::Error) -> PyErr {
    let pose = match &e {
        pkmcal::Error::Pose { pose, .. } => Some(*pose),
        _ => None,
    };
    match &e {
        pkmcal::Error::Request(r) => raise(request_words(r), None),
        e => raise(e.to_string(), pose),
    }
}

/// A refused request as a Python exception.
pub fn request_err(e: pkmcal::RequestError) -> PyErr {
    raise(request_words(&e), None)
}

/// The keyword that sets a choice the library or the file side names.
pub fn keyword(f: pkmcal::Field) -> &'static str {
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
        Out => "out",
        Weighting => "weighting",
        FirmwareLetters => "m665_b",
        ProbeOffset => "probe_offset",
        G33Radius => "g33_radius",
        G33Points => "g33_points",
        Physical => "physical",
        HeightMap => "height_map",
        MeshPoints => "mesh_points",
        ReportDir => "report_dir",
        OutDir => "out_dir",
        Previous => "previous",
        ProbeNoise => "probe_noise",
        Heights => "heights",
        Probes => "probes",
        MaxSigma => "max_sigma",
        _ => "the arguments",
    }
}

/// The keyword with what it takes, where a message shows how to give it.
fn keyword_with_value(f: pkmcal::Field) -> String {
    match f {
        pkmcal::Field::Physical => "physical=True".into(),
        f => format!("{}=...", keyword(f)),
    }
}

/// A refused choice in Python's words.
pub fn request_words(e: &pkmcal::RequestError) -> String {
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
        R::Belongs { field, needs, why } => {
            format!(
                "{}= {why}: add {}",
                keyword(*field),
                keyword_with_value(*needs)
            )
        }
        R::Excluded { field, with, why } => format!(
            "{}= {why}; leave it out with {}",
            keyword(*field),
            keyword_with_value(*with)
        ),
    }
}

/// A file-side error in Python's words.
pub fn io_words(e: &pkmcal_io::Error) -> String {
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

/// A file-side error as a Python exception: a file that cannot be read or
/// written is an `OSError` subclass ([`FILE_ERRORS`]); its pose (if any) is
/// `pose`.
pub fn io_err(e: pkmcal_io::Error) -> PyErr {
    if let pkmcal_io::Error::Io { path, cause, .. } = e.innermost() {
        return os_err(io_words(&e), cause, path);
    }
    raise(io_words(&e), e.pose().map(|(p, _)| p))
}

/// Emit a calibration's warnings with `warnings.warn`, each once, in the
/// category of its kind, attributed to the line that called the package's
/// function (each is a Python function calling the extension: stack level
/// 2).
pub fn emit_warnings(py: Python<'_>, warnings: &[pkmcal::identify::Warning]) -> PyResult<()> {
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
        warn(py, &category, &text)?;
    }
    Ok(())
}

/// Where a warning points: the line that called the package's function
/// (each a Python function calling the extension).
pub const CALLER: i32 = 2;
/// The line that read an attribute or called a method (the extension's
/// own, called directly).
pub const DIRECT: i32 = 1;

/// `warnings.warn(text, category)` at the caller of the package's function.
pub fn warn(py: Python<'_>, category: &Bound<'_, PyType>, text: &str) -> PyResult<()> {
    warn_at(py, category, text, CALLER)
}

fn warn_at(py: Python<'_>, category: &Bound<'_, PyType>, text: &str, level: i32) -> PyResult<()> {
    let text = std::ffi::CString::new(text.replace('\0', " ")).expect("no NUL left");
    PyErr::warn(py, category, &text, level)
}

/// A `DeprecationWarning`: `old` is now `new` (kept for one release),
/// pointing `level` frames up ([`CALLER`], [`DIRECT`]).
pub fn deprecated(py: Python<'_>, old: &str, new: &str, level: i32) -> PyResult<()> {
    warn_at(
        py,
        &py.get_type::<pyo3::exceptions::PyDeprecationWarning>(),
        &format!("{old} is deprecated and will be removed in the next release; use {new}"),
        level,
    )
}

/// The exceptions and warnings, added to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("PkmcalError", py.get_type::<PkmcalError>())?;
    m.add("PkmcalWarning", py.get_type::<PkmcalWarning>())?;
    m.add("ConvergenceWarning", py.get_type::<ConvergenceWarning>())?;
    m.add(
        "IdentifiabilityWarning",
        py.get_type::<IdentifiabilityWarning>(),
    )?;
    m.add("OutlierWarning", py.get_type::<OutlierWarning>())?;
    m.add("ToleranceWarning", py.get_type::<ToleranceWarning>())?;
    m.add("ModelWarning", py.get_type::<ModelWarning>())?;
    for ((name, _), class) in FILE_ERRORS.iter().zip(file_classes(py)?) {
        m.add(*name, class.bind(py))?;
    }
    Ok(())
}
