//! Arrays in and out: rows of finite numbers from anything array-like (a
//! NumPy array read in place, a pandas DataFrame or a structured array by
//! column name, a pandas Series by label), pandas indexes matched row for
//! row, and results as NumPy arrays or pandas DataFrames.

use crate::errors::{raise, usage, warn};
use numpy::ndarray::{Array2, Array3, ArrayView2, Axis, Ix2};
use numpy::{
    AllowTypeChange, IntoPyArray, PyArray1, PyArrayLikeDyn, PyReadonlyArrayDyn,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::borrow::Cow;

pyo3::create_exception!(
    pkmcal,
    AlignmentWarning,
    crate::errors::PkmcalWarning,
    "pandas objects given together whose rows were in different orders: they were aligned on the first one's index (its rows are the pose numbers)."
);

/// A 2-D array of numbers read from anything array-like (a NumPy array is
/// read in place when it is float64); a 1-D array is one row.
pub struct Rows<'py> {
    arr: PyReadonlyArrayDyn<'py, f64>,
    /// One row given as a 1-D array: results are 1-D too.
    pub single: bool,
}

impl<'py> Rows<'py> {
    pub fn view(&self) -> ArrayView2<'_, f64> {
        let v = self.arr.as_array();
        let v = if self.single {
            v.insert_axis(Axis(0))
        } else {
            v
        };
        v.into_dimensionality::<Ix2>().expect("checked to be 2-D")
    }
    pub fn len(&self) -> usize {
        self.view().nrows()
    }
    pub fn to_vecs(&self) -> Vec<Vec<f64>> {
        self.view().rows().into_iter().map(|r| r.to_vec()).collect()
    }
    /// Every value, row after row: the array itself when it is laid out so
    /// (C order), else a copy.
    pub fn flat(&self) -> Cow<'_, [f64]> {
        let v = self.view();
        match v.to_slice() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(v.iter().copied().collect()),
        }
    }
}

/// Which values besides finite numbers a caller takes.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Missing {
    /// Every value must be finite.
    Refused,
    /// NaN marks a value to estimate (a σ) or a row to skip.
    Nan,
}

/// Rows of `obj` with the columns `columns` (`what` names the argument in
/// errors): a pandas DataFrame or a NumPy structured array by column name
/// (other columns ignored), a pandas Series by label, anything else by
/// position.
pub fn rows<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    columns: &[String],
    missing: Missing,
) -> PyResult<Rows<'py>> {
    let width = columns.len();
    let shape_hint = format!("(n, {width}) with columns {}", columns.join(", "));
    let named = by_name(obj, what, columns)?;
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
            if !(v.is_finite() || (missing == Missing::Nan && v.is_nan())) {
                return Err(raise(
                    format!(
                        "{what}: row {i}, column {} ({}) is {v}; every value must be a finite number{}",
                        k,
                        columns[k],
                        if missing == Missing::Nan {
                            " (or NaN)"
                        } else {
                            ""
                        }
                    ),
                    Some(i),
                ));
            }
        }
    }
    Ok(r)
}

/// Whether `obj` is a pandas object with an index (a DataFrame or a
/// Series).
pub fn has_index(obj: &Bound<'_, PyAny>) -> bool {
    obj.hasattr("index").unwrap_or(false)
        && obj.hasattr("to_numpy").unwrap_or(false)
        && obj.hasattr("iloc").unwrap_or(false)
}

/// Whether `obj` is a pandas Series (an index, no columns).
fn is_series(obj: &Bound<'_, PyAny>) -> bool {
    has_index(obj) && !obj.hasattr("columns").unwrap_or(true)
}

/// Strings of `names` (an iterable), or None when one is not a string.
fn strings(names: Bound<'_, PyAny>) -> Option<Vec<String>> {
    names
        .try_iter()
        .ok()?
        .map(|n| n.ok().and_then(|n| n.extract::<String>().ok()))
        .collect()
}

/// The columns `columns` of `obj` in that order when `obj` names them (a
/// DataFrame's columns, a structured array's fields, a Series' labels when
/// they are strings), matched as a CSV file's headers are (regardless of
/// case when unambiguous, [`pkmcal_io::csv::column_index`]): a missing one
/// is an error naming it and the names found; others are ignored. `None`
/// for an array without names (its columns are taken in order).
fn by_name<'py>(
    obj: &Bound<'py, PyAny>,
    what: &str,
    columns: &[String],
) -> PyResult<Option<Bound<'py, PyAny>>> {
    let py = obj.py();
    enum Kind {
        Frame,
        Series,
        Structured,
    }
    let (names, kind) = if has_index(obj) && obj.hasattr("columns")? {
        match strings(obj.getattr("columns")?) {
            Some(n) => (n, Kind::Frame),
            None => return Ok(None),
        }
    } else if is_series(obj) {
        // Labelled by strings: a row of a DataFrame (`df.iloc[0]`), read
        // by its labels; numbered (a default index): by position.
        match strings(obj.getattr("index")?) {
            Some(n) => (n, Kind::Series),
            None => return Ok(Some(obj.call_method0("to_numpy")?)),
        }
    } else {
        let structured = obj
            .getattr("dtype")
            .ok()
            .and_then(|d| d.getattr("names").ok())
            .filter(|n| !n.is_none());
        match structured.and_then(strings) {
            Some(n) => (n, Kind::Structured),
            None => return Ok(None),
        }
    };
    let picked: Vec<String> = columns
        .iter()
        .map(|c| {
            pkmcal_io::csv::column_index(std::path::Path::new(what), &names, c, b',')
                .map(|i| names[i].clone())
                .map_err(|e| usage(format!("{e:#}")))
        })
        .collect::<PyResult<_>>()?;
    let list = PyList::new(py, &picked)?;
    Ok(Some(match kind {
        Kind::Frame => obj.get_item(list)?.call_method0("to_numpy")?,
        Kind::Series => obj
            .getattr("loc")?
            .get_item(list)?
            .call_method0("to_numpy")?,
        Kind::Structured => py
            .import("numpy.lib.recfunctions")?
            .call_method1("structured_to_unstructured", (obj.get_item(list)?,))?,
    }))
}

/// Arrays given together, their rows matched: of those with an index
/// (pandas DataFrames and Series), each must have the first one's labels
/// row for row; one with the same labels in another order is reordered to
/// the first's (an [`AlignmentWarning`] says so), other labels are refused
/// naming both. Arrays without an index are taken as they are.
pub fn aligned<'py>(
    items: Vec<(&str, Option<Bound<'py, PyAny>>)>,
) -> PyResult<Vec<Option<Bound<'py, PyAny>>>> {
    let mut reference: Option<(&str, Bound<'py, PyAny>)> = None;
    let mut out = Vec::with_capacity(items.len());
    for (name, obj) in items {
        let Some(o) = obj.clone().filter(has_index) else {
            out.push(obj);
            continue;
        };
        let Some((first, reference_obj)) = &reference else {
            reference = Some((name, o.clone()));
            out.push(Some(o));
            continue;
        };
        let (a, b) = (reference_obj.getattr("index")?, o.getattr("index")?);
        if a.call_method1("equals", (&b,))?.is_truthy()? {
            out.push(Some(o));
            continue;
        }
        let unique = |i: &Bound<'_, PyAny>| i.getattr("is_unique").and_then(|u| u.is_truthy());
        let py = o.py();
        let set = |i: &Bound<'py, PyAny>| py.import("builtins")?.getattr("set")?.call1((i,));
        let (sa, sb) = (set(&a)?, set(&b)?);
        if unique(&a)? && unique(&b)? && a.len()? == b.len()? && sa.eq(&sb)? {
            warn(
                py,
                &py.get_type::<AlignmentWarning>(),
                &format!(
                    "{name} has the rows of {first} in another order; they were aligned on the index of {first} (pose numbers are its rows)"
                ),
            )?;
            out.push(Some(o.getattr("loc")?.get_item(&a)?));
            continue;
        }
        let only = |x: &Bound<'py, PyAny>, y: &Bound<'py, PyAny>| -> PyResult<Option<String>> {
            let d = x.call_method1("difference", (y,))?;
            Ok(if d.len()? > 0 {
                Some(d.get_item(0)?.repr()?.to_string())
            } else {
                None
            })
        };
        let why = match (only(&a, &b)?, only(&b, &a)?) {
            (Some(l), _) => format!("label {l} is in {first} but not in {name}"),
            (None, Some(l)) => format!("label {l} is in {name} but not in {first}"),
            (None, None) => "a label is repeated".to_string(),
        };
        return Err(usage(format!(
            "{first} and {name} have different rows ({why}); give rows that match (or drop the indexes with reset_index(drop=True))"
        )));
    }
    Ok(out)
}

/// The index of a pandas object, to give back with its results.
pub fn index_of<'py>(obj: &Bound<'py, PyAny>) -> Option<Bound<'py, PyAny>> {
    has_index(obj).then(|| obj.getattr("index").ok()).flatten()
}

/// A shape as Python prints it: `(35, 1)`, `(3,)`.
pub fn shape_text(shape: &[usize]) -> String {
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

/// `n × w` values as a NumPy array (taking the vector, no copy), 1-D when
/// the input was one row.
pub fn out2<'py>(py: Python<'py>, flat: Vec<f64>, w: usize, single: bool) -> Bound<'py, PyAny> {
    let n = flat.len().checked_div(w).unwrap_or(0);
    let a = Array2::from_shape_vec((n, w), flat).expect("sizes agree");
    if single {
        a.row(0).to_owned().into_pyarray(py).into_any()
    } else {
        a.into_pyarray(py).into_any()
    }
}

/// `n × d × d` values (row-major) as a NumPy array, `(d, d)` for one row in.
pub fn out3<'py>(
    py: Python<'py>,
    flat: Vec<f64>,
    d: usize,
    single: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let n = flat.len().checked_div(d * d).unwrap_or(0);
    let a = Array3::from_shape_vec((n, d, d), flat)
        .expect("sizes agree")
        .into_pyarray(py)
        .into_any();
    if single { a.get_item(0) } else { Ok(a) }
}

pub fn vec1<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// Row `i` of a view, borrowed when contiguous.
pub fn row<'a>(v: &'a ArrayView2<'_, f64>, i: usize) -> Cow<'a, [f64]> {
    let r = v.row(i);
    match r.to_slice() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(r.to_vec()),
    }
}

/// pandas, or an ImportError that says how to get it.
pub fn pandas(py: Python<'_>) -> PyResult<Bound<'_, PyModule>> {
    py.import("pandas").map_err(|_| {
        pyo3::exceptions::PyImportError::new_err(
            "to_pandas needs pandas (pip install pandas); the arrays are the attributes",
        )
    })
}

/// A pandas DataFrame of `columns` (name, values), in that order, on
/// `index` (None: 0, 1, …), its index named `index_name`.
pub fn frame<'py>(
    py: Python<'py>,
    columns: Vec<(String, Bound<'py, PyAny>)>,
    index: Option<Bound<'py, PyAny>>,
    index_name: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    let pd = pandas(py)?;
    let data = PyDict::new(py);
    for (k, v) in columns {
        data.set_item(k, v)?;
    }
    let kw = PyDict::new(py);
    if let Some(i) = index {
        kw.set_item("index", i)?;
    }
    let df = pd.getattr("DataFrame")?.call((data,), Some(&kw))?;
    if let Some(n) = index_name {
        df.getattr("index")?.setattr("name", n)?;
    }
    Ok(df)
}

/// The columns of a 2-D array named `names`: `(name, column)` each.
pub fn named_columns<'py>(
    array: &Bound<'py, PyAny>,
    names: &[String],
    suffix: &str,
) -> PyResult<Vec<(String, Bound<'py, PyAny>)>> {
    let a = if array.getattr("ndim")?.extract::<usize>()? == 1 {
        array.call_method1("reshape", (1, -1))?
    } else {
        array.clone()
    };
    names
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let col = a.get_item((pyo3::types::PySlice::full(a.py()), k))?;
            Ok((format!("{n}{suffix}"), col))
        })
        .collect()
}
