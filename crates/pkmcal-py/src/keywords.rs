//! A call's arguments by name. Every function of the package is a Python
//! function (`pkmcal/_api.py`, where its signature and defaults are) that
//! hands the extension its arguments as one dict; they are read here, each
//! with its type, and a value of the wrong type or out of range is refused
//! naming its keyword.

use crate::errors::{usage, wrong_type};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyString};

/// The arguments of one call.
pub struct Kw<'py> {
    args: Bound<'py, PyDict>,
}

impl<'py> Kw<'py> {
    pub fn new(args: Bound<'py, PyDict>) -> Self {
        Kw { args }
    }

    pub fn py(&self) -> Python<'py> {
        self.args.py()
    }

    /// The value of `name`; `None` when it is not given or is None.
    pub fn any(&self, name: &str) -> PyResult<Option<Bound<'py, PyAny>>> {
        Ok(self.args.get_item(name)?.filter(|v| !v.is_none()))
    }

    /// The value of `name`, which the call needs.
    pub fn required(&self, name: &str) -> PyResult<Bound<'py, PyAny>> {
        self.any(name)?.ok_or_else(|| {
            pyo3::exceptions::PyTypeError::new_err(format!("{name}: a value is needed, not None"))
        })
    }

    /// A number (any real: a float, an int, a NumPy scalar).
    pub fn f64(&self, name: &str) -> PyResult<Option<f64>> {
        self.any(name)?
            .map(|v| {
                if v.is_instance_of::<PyBool>() || v.is_instance_of::<PyString>() {
                    return Err(wrong_type(name, "a number", &v));
                }
                v.extract::<f64>()
                    .map_err(|_| wrong_type(name, "a number", &v))
            })
            .transpose()
    }

    /// `True` or `False` (a NumPy bool too).
    pub fn flag(&self, name: &str) -> PyResult<bool> {
        match self.any(name)? {
            None => Ok(false),
            Some(v) => {
                let numpy_bool = v
                    .get_type()
                    .name()
                    .is_ok_and(|n| n == "bool" || n == "bool_");
                if !(v.is_instance_of::<PyBool>() || numpy_bool) {
                    return Err(wrong_type(name, "True or False", &v));
                }
                v.is_truthy()
            }
        }
    }

    /// A string.
    pub fn str(&self, name: &str) -> PyResult<Option<String>> {
        self.any(name)?
            .map(|v| {
                v.extract::<String>()
                    .map_err(|_| wrong_type(name, "a string", &v))
            })
            .transpose()
    }

    /// A whole number ≥ 0 (an int, a NumPy integer): a negative one, or
    /// one beyond what a machine word holds, is refused naming `name`
    /// (`ValueError`).
    pub fn count(&self, name: &str) -> PyResult<Option<usize>> {
        self.any(name)?.map(|v| count_of(&v, name)).transpose()
    }

    /// [`Kw::count`] at most `max`, a bound of the library's: `what` names
    /// the things counted and who bounds them ("targets one request spreads
    /// over the workspace"), as the command line words its options.
    pub fn count_at_most(&self, name: &str, max: usize, what: &str) -> PyResult<Option<usize>> {
        let v = self.count(name)?;
        match v {
            Some(v) if v > max => Err(usage(format!(
                "{name}={v}: more than the {max} {what}; give at most {max}"
            ))),
            _ => Ok(v),
        }
    }

    /// A number of workspace targets ([`pkmcal::MAX_TARGETS`]).
    pub fn targets(&self, name: &str) -> PyResult<Option<usize>> {
        self.count_at_most(
            name,
            pkmcal::MAX_TARGETS,
            "targets one request spreads over the workspace",
        )
    }

    /// Names: a string (one name, or several separated by commas, as on
    /// the command line) or a sequence of strings.
    pub fn names(&self, name: &str) -> PyResult<Option<Vec<String>>> {
        self.any(name)?.map(|v| names_of(&v, name)).transpose()
    }
}

/// `v` as a whole number ≥ 0, refused naming `name`.
pub fn count_of(v: &Bound<'_, PyAny>, name: &str) -> PyResult<usize> {
    if v.is_instance_of::<PyBool>() {
        return Err(wrong_type(name, "a whole number", v));
    }
    let i: i128 = v
        .call_method0("__index__")
        .and_then(|i| i.extract())
        .map_err(|_| wrong_type(name, "a whole number", v))?;
    usize::try_from(i).map_err(|_| {
        usage(if i < 0 {
            format!("{name}={i}: give a whole number ≥ 0")
        } else {
            format!("{name}={i}: more than any machine holds; give a smaller number")
        })
    })
}

/// `v` as names: a string (comma-separated names) or a sequence of strings.
pub fn names_of(v: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<String>> {
    if let Ok(s) = v.extract::<String>() {
        return Ok(pkmcal::Request::names(&s));
    }
    let expected = "a name, names separated by commas, or a sequence of names";
    let items: Vec<Bound<'_, PyAny>> = v
        .try_iter()
        .and_then(|i| i.collect::<PyResult<_>>())
        .map_err(|_| wrong_type(name, expected, v))?;
    let names = items
        .iter()
        .map(|n| {
            n.extract::<String>()
                .map_err(|_| wrong_type(name, expected, n))
        })
        .collect::<PyResult<Vec<String>>>()?;
    if let Some(n) = names.iter().find(|n| n.contains(',')) {
        return Err(usage(format!(
            "{name}: {n:?} holds a comma; give each name apart"
        )));
    }
    Ok(names)
}
