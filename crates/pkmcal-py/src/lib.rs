//! Python bindings of pkmcal (PyO3): the library's free functions over NumPy
//! arrays and pandas tables. Arrays are in the library's units (mm, rad, N,
//! N·m); pose numbers in results and exceptions are row indices (from 0) of
//! the arrays given. Long computations release the GIL, run on a thread
//! pool of their own and stop on Ctrl-C.
//!
//! By job: [`errors`] (exceptions, warnings, the keywords' words),
//! [`threads`] (pools, Ctrl-C), [`keywords`] (a call's arguments by name),
//! [`arrays`] (rows in, arrays and DataFrames out), [`files`],
//! [`mechanism`], [`request`] (keywords onto `pkmcal::Request` and the
//! data), [`results`] and [`functions`]. The package's Python side
//! (`python/pkmcal/_api.py`) holds each function's signature and
//! documentation and hands the extension its arguments as one dict.

mod arrays;
mod errors;
mod files;
mod functions;
mod keywords;
mod mechanism;
mod request;
mod results;
mod threads;

use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The library's defaults the Python signatures show (`_api.py` reads them
/// from here, so that each is written once).
fn defaults(py: Python<'_>) -> PyResult<Bound<'_, PyDict>> {
    use pkmcal::identify::request as r;
    let d = PyDict::new(py);
    d.set_item("outlier_threshold", r::DEFAULT_OUTLIER_THRESHOLD)?;
    d.set_item("seed", r::DEFAULT_SEED)?;
    d.set_item("stated_noise", r::DEFAULT_WEIGHING_NOISE_MM)?;
    d.set_item(
        "stated_readings",
        pkmcal::identify::DEFAULT_STATED_NOISE_READINGS,
    )?;
    d.set_item("alpha", pkmcal::identify::DEFAULT_ALPHA)?;
    d.set_item("max_sigma", pkmcal_io::firmware::DEFAULT_MAX_SIGMA)?;
    Ok(d)
}

/// Kinematic calibration of (redundantly actuated) parallel mechanisms.
#[pymodule]
fn _pkmcal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    // NumPy's C API is fetched here, at import, rather than by the first
    // call that makes an array: a Ctrl-C landing during that fetch became a
    // panic (`PanicException`, which `except Exception` does not catch).
    // Here NumPy is imported first (an interruption is then Python's own
    // KeyboardInterrupt, failing the import), and the capsule is fetched
    // from the module already loaded.
    py.import("numpy")?;
    let _ = numpy::PyArray1::<f64>::zeros(py, [0], false);
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DEFAULTS", defaults(py)?)?;
    errors::register(m)?;
    m.add(
        "AlignmentWarning",
        py.get_type::<arrays::AlignmentWarning>(),
    )?;
    m.add_class::<mechanism::PyMechanism>()?;
    m.add_class::<results::calibration::PyCalibration>()?;
    m.add_class::<results::calibration::PySavedCalibration>()?;
    m.add_class::<results::calibration::LoadAttribute>()?;
    m.add_class::<results::parts::PyIdentifiability>()?;
    m.add_class::<results::parts::PyErrorStats>()?;
    m.add_class::<results::parts::PyWarning>()?;
    m.add_class::<results::parts::PyFigure>()?;
    m.add_class::<results::tables::PyMonteCarlo>()?;
    m.add_class::<results::tables::PyBudget>()?;
    m.add_class::<results::tables::PyDrift>()?;
    m.add_class::<results::tables::PyPrediction>()?;
    m.add_class::<results::tables::PyCompensation>()?;
    m.add_class::<results::tables::PyPlan>()?;
    m.add_function(wrap_pyfunction!(results::calibration::load_calibration, m)?)?;
    m.add_function(wrap_pyfunction!(functions::design::set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(functions::apply::predict, m)?)?;
    m.add_function(wrap_pyfunction!(functions::apply::nominal_commands, m)?)?;
    m.add_function(wrap_pyfunction!(functions::apply::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(functions::apply::compensate, m)?)?;
    m.add_function(wrap_pyfunction!(functions::apply::trilaterate, m)?)?;
    m.add_function(wrap_pyfunction!(functions::fit::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(functions::fit::analyze, m)?)?;
    m.add_function(wrap_pyfunction!(functions::design::plan, m)?)?;
    m.add_function(wrap_pyfunction!(functions::design::montecarlo, m)?)?;
    m.add_function(wrap_pyfunction!(functions::design::budget, m)?)?;
    m.add_function(wrap_pyfunction!(functions::design::drift, m)?)?;
    m.add_function(wrap_pyfunction!(functions::firmware::klipper, m)?)?;
    m.add_function(wrap_pyfunction!(functions::firmware::reprap, m)?)?;
    m.add_function(wrap_pyfunction!(functions::firmware::marlin, m)?)?;
    Ok(())
}
