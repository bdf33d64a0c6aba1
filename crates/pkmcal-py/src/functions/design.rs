//! Design and monitoring: measurement plans, Monte Carlo studies of them,
//! tolerance budgets, and the drift test between calibrations.

use crate::arrays::{Missing, out2, rows, vec1};
use crate::errors::{emit_warnings, lib_err, request_err, usage, wrong_type};
use crate::files::{path_arg, reading_records};
use crate::functions::apply::at;
use crate::keywords::{Kw, count_of};
use crate::mechanism::mechanism_arg;
use crate::request::{
    free_of, model, params_arg, request, seed, simulated_noise, stated_noise, tolerances_arg,
};
use crate::results::calibration::{PyCalibration, PySavedCalibration};
use crate::results::observability;
use crate::results::tables::{PyBudget, PyDrift, PyMonteCarlo, PyPlan};
use crate::threads::interruptible;
use pkmcal::{AnyMechanism, CalibrationOptions, MeasurementModel, Mechanism as _};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

/// A keyword the function's Python signature always gives.
fn needed(name: &str) -> PyErr {
    pyo3::exceptions::PyTypeError::new_err(format!("{name}: a value is needed, not None"))
}

/// ``plan(mechanism, count, params=None, **options)``.
#[pyfunction]
pub fn plan(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyPlan> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let spec = m.spec();
    let count = count_of(&kw.required("count")?, "count")?;
    if count > pkmcal::MAX_TARGETS {
        return Err(usage(format!(
            "count={count}: more than the {} targets one request spreads over the workspace; give at most {}",
            pkmcal::MAX_TARGETS,
            pkmcal::MAX_TARGETS
        )));
    }
    let params = params_arg(m, kw.any("params")?.as_ref(), "params")?;
    let tool = MeasurementModel::tool(spec);
    let mut request = request(&kw, model(&kw, pkmcal::Model::Exact)?)?;
    stated_noise(&kw, &mut request)?;
    let (priors, free) = free_of(&request, m, &tool)?;
    let noise = request
        .weighing_noise(!priors.is_empty())
        .map_err(request_err)?;
    let opts = pkmcal::PlanOptions {
        count,
        criterion: kw
            .str("criterion")?
            .unwrap_or_else(|| "O5".into())
            .parse()
            .map_err(lib_err)?,
        model: request.model,
        free,
        spacing: kw.f64("spacing")?.ok_or_else(|| needed("spacing"))?,
        max_candidates: kw
            .count("max_candidates")?
            .ok_or_else(|| needed("max_candidates"))?,
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
        pkmcal::plan(mech, &params, &opts, &|_, _| {})
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
        columns: (spec.tool_axes.clone(), m.actuators()),
    })
}

/// ``montecarlo(mechanism, targets, **options)``.
#[pyfunction]
pub fn montecarlo(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyMonteCarlo> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let spec = m.spec();
    let seed = seed(&kw)?;
    let poses = rows(
        &kw.required("targets")?,
        "targets",
        &spec.tool_axes,
        Missing::Refused,
    )?
    .to_vecs();
    let mut cal = CalibrationOptions::new(spec, model(&kw, pkmcal::Model::Exact)?);
    let tool = MeasurementModel::tool(spec);
    let request = request(&kw, cal.model)?;
    (cal.priors, cal.free) = free_of(&request, m, &tool)?;
    let validation = kw
        .targets("validation")?
        .ok_or_else(|| needed("validation"))?;
    let opts = pkmcal::MonteCarloOptions {
        runs: kw
            .count_at_most(
                "runs",
                pkmcal::apply::montecarlo::MAX_RUNS,
                "simulated calibrations a study runs",
            )?
            .ok_or_else(|| needed("runs"))?,
        noise: simulated_noise(&kw, pkmcal::identify::request::DEFAULT_WEIGHING_NOISE_MM)?,
        seed,
        length_error: kw
            .f64("length_error")?
            .ok_or_else(|| needed("length_error"))?,
        angle_error: kw
            .f64("angle_error")?
            .ok_or_else(|| needed("angle_error"))?,
        calibration: cal,
    };
    opts.check().map_err(request_err)?;
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
        run_converged: numpy::PyArray1::from_iter(py, each.iter().map(|r| r.converged))
            .into_any()
            .unbind(),
        validation_rms: numpy::PyArray1::from_iter(
            py,
            each.iter().map(|r| r.validation.distance_rms),
        )
        .into_any()
        .unbind(),
        validation_max: numpy::PyArray1::from_iter(
            py,
            each.iter().map(|r| r.validation.distance_max),
        )
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

/// ``budget(mechanism, tolerances=None, **options)``.
#[pyfunction]
pub fn budget(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyBudget> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let spec = m.spec();
    let seed = seed(&kw)?;
    let given = tolerances_arg(kw.any("tolerances")?.as_ref())?;
    let given = pkmcal::apply::budget::merged_tolerances(&m.tolerances, given);
    let resolved = pkmcal::apply::budget::resolve_tolerances(spec, &given)
        .map_err(|e| usage(format!("tolerances: {e}")))?;
    let model = model(&kw, pkmcal::Model::Exact)?;
    // The planned calibration's instrument: its stated noise.
    let mut stated = pkmcal::Request::new(model);
    stated_noise(&kw, &mut stated)?;
    let calibration = match kw.any("poses")? {
        Some(p) => Some(pkmcal::apply::budget::PlannedCalibration {
            targets: rows(&p, "poses", &spec.tool_axes, Missing::Refused)?.to_vecs(),
            noise: stated.weighing_noise(false).map_err(request_err)?,
        }),
        None => None,
    };
    let grid = kw.targets("grid")?.ok_or_else(|| needed("grid"))?;
    let opts = pkmcal::apply::budget::BudgetOptions {
        model,
        force: vec![],
        samples: kw
            .count_at_most(
                "samples",
                pkmcal::apply::budget::MAX_SAMPLES,
                "machines a budget draws",
            )?
            .ok_or_else(|| needed("samples"))?,
        seed,
        calibration,
    };
    let mech = &*m.mech;
    let b = interruptible(py, |cancel| -> pkmcal::Result<_> {
        let targets = pkmcal::apply::budget::budget_targets_cancellable(mech, grid, Some(&cancel))?;
        pkmcal::apply::budget::budget_cancellable(mech, &targets, &resolved, &opts, Some(&cancel))
    })?
    .map_err(lib_err)?;
    Ok(PyBudget {
        b,
        mechanism: spec.name.clone(),
    })
}

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
        reading_records(|run| {
            pkmcal_io::record::read_calibration_record_dof(run, std::path::Path::new(&p))
        })
        .map_err(crate::errors::io_err)?
    } else {
        return Err(wrong_type(
            what,
            "a Calibration, a SavedCalibration or a calibration record's path",
            c,
        ));
    };
    Ok((
        pkmcal::identify::Compared::from_record(&record, dof),
        record.mechanism_identity.clone(),
        None,
    ))
}

/// ``drift(new, old=None, *, mechanism=None, alpha=0.05, grid=100)``.
#[pyfunction]
pub fn drift(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyDrift> {
    let kw = Kw::new(args.clone());
    let (b, b_id, b_mech) = compared_arg(&kw.required("new")?, "new")?;
    let given = kw
        .any("mechanism")?
        .map(|m| mechanism_arg(&m).map(|m| m.get().mech.clone()))
        .transpose()?;
    let old = kw.any("old")?;
    let old = old.as_ref().map(|o| compared_arg(o, "old")).transpose()?;
    // Every calibration compared must be of the mechanism given (by the
    // identity its record keeps: joints, parameters, nominal values).
    if let Some(g) = &given {
        let id = pkmcal::identify::mechanism_identity(g.spec());
        for (what, other) in [("new", Some(&b_id)), ("old", old.as_ref().map(|o| &o.1))] {
            if let Some(other) = other
                && !other.is_empty()
                && *other != id
            {
                return Err(usage(format!(
                    "mechanism: {what} is a calibration of another mechanism than {} (other joints, parameters or nominal values); give the mechanism it calibrated",
                    g.spec().name
                )));
            }
        }
    }
    let mech = given.or(b_mech);
    let (a, old_name) = match old {
        Some((a, a_id, _)) => {
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
    let alpha = kw.f64("alpha")?.ok_or_else(|| needed("alpha"))?;
    let grid = kw.targets("grid")?.ok_or_else(|| needed("grid"))?;
    let d = interruptible(py, |cancel| -> pkmcal::Result<_> {
        let mut d = pkmcal::identify::drift(&a, &b, alpha)?;
        if let (Some(m), true) = (mech.as_deref(), grid > 0) {
            let targets =
                pkmcal::apply::budget::budget_targets_cancellable(m, grid, Some(&cancel))?;
            d.workspace = Some(pkmcal::apply::tooldrift::workspace_drift_cancellable(
                m,
                &a,
                &b,
                &targets,
                alpha,
                Some(&cancel),
            )?);
        }
        Ok(d)
    })?
    .map_err(lib_err)?;
    let text = pkmcal_io::text::drift_words(mech.as_ref().map(|m| m.spec()), &d, &old_name, "new");
    Ok(PyDrift { d, text })
}

/// ``set_threads(n)``: the threads each call computes with (0: one per
/// core).
#[pyfunction]
pub fn set_threads(args: &Bound<'_, PyDict>) -> PyResult<()> {
    let kw = Kw::new(args.clone());
    let n = count_of(&kw.required("n")?, "n")?;
    if n > crate::threads::MAX_THREADS {
        return Err(usage(format!(
            "n={n}: more threads than any machine has cores; give at most {} (0: one per core)",
            crate::threads::MAX_THREADS
        )));
    }
    crate::threads::set_threads(n);
    Ok(())
}
