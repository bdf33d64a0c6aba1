//! Results: plain classes that pickle and compare by value, show a table in
//! a notebook (`_repr_html_`) and give pandas DataFrames (`to_pandas`).

use crate::errors::usage;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// What `__reduce__` returns: a callable and its arguments.
pub type Reduced<'py, A> = (Bound<'py, PyAny>, A);

/// A result that pickles and compares by value: its state as a dict of
/// Python values (arrays stay arrays) and back.
pub trait ByValue:
    pyo3::PyClass<Frozen = pyo3::pyclass::boolean_struct::True> + Sync + Sized
{
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>>;
    fn from_dict(d: &Bound<'_, PyDict>) -> PyResult<Self>;
}

/// `ByValue` for a struct of Python-convertible fields.
macro_rules! by_value {
    ($ty:ty { $($f:ident),+ $(,)? }) => {
        impl $crate::results::ByValue for $ty {
            fn to_dict<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::PyResult<pyo3::Bound<'py, pyo3::types::PyDict>> {
                use pyo3::types::PyDictMethods;
                let d = pyo3::types::PyDict::new(py);
                $( d.set_item(stringify!($f), &self.$f)?; )+
                Ok(d)
            }
            fn from_dict(d: &pyo3::Bound<'_, pyo3::types::PyDict>) -> pyo3::PyResult<Self> {
                use pyo3::types::PyAnyMethods;
                Ok(Self {
                    $( $f: $crate::results::state_item(d, stringify!($f))?.extract()?, )+
                })
            }
        }
    };
}

pub fn state_item<'py>(d: &Bound<'py, PyDict>, key: &str) -> PyResult<Bound<'py, PyAny>> {
    d.get_item(key)?
        .ok_or_else(|| usage(format!("a pickled pkmcal result without `{key}`")))
}

/// `ByValue` for a struct that holds library data (each `encoded` field
/// serialised whole, NaN kept) and plain Python-convertible fields.
macro_rules! by_serde {
    ($ty:ty { $($e:ident),+ $(; $($f:ident),+)? }) => {
        impl $crate::results::ByValue for $ty {
            fn to_dict<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::PyResult<pyo3::Bound<'py, pyo3::types::PyDict>> {
                use pyo3::types::PyDictMethods;
                let d = pyo3::types::PyDict::new(py);
                $(
                    let mut bytes = vec![];
                    pkmcal_io::record::encode(&self.$e, &mut bytes)
                        .map_err($crate::errors::io_err)?;
                    d.set_item(stringify!($e), pyo3::types::PyBytes::new(py, &bytes))?;
                )+
                $($( d.set_item(stringify!($f), &self.$f)?; )+)?
                Ok(d)
            }
            fn from_dict(d: &pyo3::Bound<'_, pyo3::types::PyDict>) -> pyo3::PyResult<Self> {
                #[allow(unused_imports)]
                use pyo3::types::{PyAnyMethods, PyBytesMethods};
                Ok(Self {
                    $(
                        $e: pkmcal_io::record::decode(
                            $crate::results::state_item(d, stringify!($e))?
                                .cast::<pyo3::types::PyBytes>()?
                                .as_bytes(),
                        )
                        .map_err($crate::errors::io_err)?,
                    )+
                    $($( $f: $crate::results::state_item(d, stringify!($f))?.extract()?, )+)?
                })
            }
        }
    };
}

pub mod calibration;
pub mod parts;
pub mod pickle;
pub mod tables;

/// What `__reduce__` returns: the class's `_from_state` and the state.
pub fn reduce<'py, T: ByValue>(
    slf: &Bound<'py, T>,
) -> PyResult<Reduced<'py, (Bound<'py, PyDict>,)>> {
    let py = slf.py();
    Ok((
        slf.as_any().get_type().getattr("_from_state")?,
        (slf.get().to_dict(py)?,),
    ))
}

/// Equal values: arrays elementwise with their shapes (NaN equal to NaN),
/// everything else with Python's `==`.
pub fn value_eq(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<bool> {
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
pub fn eq_by_value<T: ByValue>(a: &T, other: &Bound<'_, PyAny>) -> PyResult<bool> {
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

/// Values by name as a dict.
pub fn by_name<'py>(
    py: Python<'py>,
    items: impl Iterator<Item = (String, f64)>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (k, v) in items {
        d.set_item(k, v)?;
    }
    Ok(d)
}

/// Observability indices O1…O5 by name.
pub fn observability<'py>(
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

/// An HTML table for a notebook: a caption, a header and rows of cells
/// (escaped here), at most [`HTML_ROWS`] rows shown (the rest counted).
pub fn html_table(caption: &str, header: &[&str], rows: &[Vec<String>]) -> String {
    use std::fmt::Write;
    let esc = pkmcal_io::report::escape;
    let mut h = format!("<p>{caption}</p><table><tr>");
    for c in header {
        let _ = write!(h, "<th>{}</th>", esc(c));
    }
    h.push_str("</tr>");
    for r in rows.iter().take(HTML_ROWS) {
        h.push_str("<tr>");
        for c in r {
            let _ = write!(h, "<td>{}</td>", esc(c));
        }
        h.push_str("</tr>");
    }
    h.push_str("</table>");
    if rows.len() > HTML_ROWS {
        let _ = write!(
            h,
            "<p>… and {} more rows (<code>to_pandas()</code> has them all)</p>",
            rows.len() - HTML_ROWS
        );
    }
    h
}

/// Rows an HTML table shows.
pub const HTML_ROWS: usize = 40;

/// A number for a table: about four significant digits, `e` notation for
/// the very small and very large, as Python's `{:.4g}` writes it.
pub fn g4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}").replace("inf", "inf");
    }
    let e = v.abs().log10().floor() as i32;
    if (-4..6).contains(&e) {
        let decimals = (3 - e).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        let m = v / 10f64.powi(e);
        let m = format!("{m:.3}");
        let m = m.trim_end_matches('0').trim_end_matches('.');
        format!("{m}e{}{:02}", if e < 0 { "-" } else { "+" }, e.abs())
    }
}

/// A p-value in words: `g4`, or `< 1e-300` where it underflows to 0.
pub fn p_text(p: f64) -> String {
    if p == 0.0 { "< 1e-300".into() } else { g4(p) }
}
