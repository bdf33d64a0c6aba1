//! Identification: the calibration study, and the identifiability analysis
//! without a fit.

use crate::errors::{emit_warnings, lib_err, request_err};
use crate::keywords::Kw;
use crate::mechanism::mechanism_arg;
use crate::request::{
    distances, free_of, instrument, load, measurements, model, params_arg, request, seed, solver,
    start, stated_noise, validation,
};
use crate::results::calibration::PyCalibration;
use crate::results::parts::PyIdentifiability;
use crate::threads::interruptible;
use pkmcal_io::record::{CalibrationState, MechanismSource};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// ``calibrate(mechanism, commands, measured, **options)``: the keywords of
/// `pkmcal/_api.py`'s `calibrate`, its groups (``Instrument``, ``Solver``,
/// ``Validation``) given there as keywords.
#[pyfunction]
pub fn calibrate(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyCalibration> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let seed = seed(&kw)?;
    let mm = instrument(&kw, m, None)?;
    let all = measurements(
        m,
        &mm,
        [
            kw.any("commands")?,
            kw.any("measured")?,
            kw.any("sigma")?,
            kw.any("targets")?,
        ],
        "",
    )?;
    let pairs = distances(&kw, m, &mm)?;
    let mut request = request(&kw, model(&kw, pkmcal::Model::Exact)?)?;
    stated_noise(&kw, &mut request)?;
    if let Some(r) = kw.f64("stated_readings")? {
        request.stated_readings = r;
    }
    request.stated_distance_noise = kw.f64("stated_distance_noise")?;
    request.stated_relative = kw.flag("stated_relative")?;
    request.load = load(&kw)?;
    if let Some(l) = kw.str("loss")? {
        request.loss = l;
    }
    request.loss_scale = kw.f64("loss_scale")?;
    if let Some(t) = kw.f64("outlier_threshold")? {
        request.outlier_threshold = t;
    }
    request.drop_outliers = kw.flag("drop_outliers")?;
    request.solver = solver(&kw)?;
    let start = start(&kw, m, &request, &mm)?;
    request.validation = validation(&kw, m, &mm)?;
    request.holdout = kw.f64("holdout")?;
    request.kfold = kw.count("kfold")?;
    request.seed = seed;
    let mech = &*m.mech;
    let study_opts = request
        .study_options(mech, &mm, &m.tolerances, &start)
        .map_err(request_err)?;
    let load = study_opts.calibration.force.clone();
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
            load,
        },
    })
}

/// ``analyze(mechanism, commands, measured, **options)``.
#[pyfunction]
pub fn analyze(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyIdentifiability> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let mm = instrument(&kw, m, None)?;
    let data = measurements(
        m,
        &mm,
        [
            kw.any("commands")?,
            kw.any("measured")?,
            kw.any("sigma")?,
            None,
        ],
        "",
    )?;
    let params = params_arg(m, kw.any("params")?.as_ref(), "params")?;
    let model = model(&kw, pkmcal::Model::Exact)?;
    let mut request = request(&kw, model)?;
    request.load = load(&kw)?;
    stated_noise(&kw, &mut request)?;
    let (priors, free) = free_of(&request, m, &mm)?;
    let force = request
        .checked_load(&*m.mech, &params)
        .map_err(request_err)?;
    let noise = request
        .weighing_noise(!priors.is_empty())
        .map_err(request_err)?;
    // Without priors, the readings are weighed as `pkmcal::analyze` weighs
    // them (the stated noise then scales nothing that is reported).
    let noise = if priors.is_empty() {
        pkmcal::Noise::lengths(1.0)
    } else {
        noise
    };
    let mech = &*m.mech;
    let id = interruptible(py, |cancel| {
        let opts = pkmcal::identify::AnalysisOptions {
            model,
            free,
            force,
            priors,
            noise,
            cancel: Some(cancel),
        };
        pkmcal::identify::analyze_cancellable(mech, &mm, &data, &params, &opts)
    })?
    .map_err(lib_err)?;
    Ok(PyIdentifiability { id })
}
