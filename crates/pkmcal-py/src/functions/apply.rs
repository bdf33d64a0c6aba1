//! Using a mechanism and its parameters: predictions, nominal and
//! compensated commands, simulated measurements, positions from ball-bar
//! readings. Each row's work spread over the cores, the GIL released, a
//! long call stopped by Ctrl-C.

use crate::arrays::{Missing, Rows, index_of, out2, out3, row, rows};
use crate::errors::{lib_err, usage};
use crate::keywords::Kw;
use crate::mechanism::{PyMechanism, mechanism_arg};
use crate::request::{
    checked_load, instrument, model, params_arg, seed, simulated_noise, sockets_arg, vector,
};
use crate::results::calibration::{PyCalibration, PySavedCalibration};
use crate::results::tables::{PyCompensation, PyPrediction};
use crate::threads::{QUICK_ROWS, interruptible, run};
use pkmcal::Origin;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use rayon::prelude::*;

/// An error at row `i` of the arrays.
pub fn at(i: usize) -> impl Fn(pkmcal::Error) -> pkmcal::Error {
    move |e| {
        e.at_pose(Origin {
            pose: i,
            line: None,
            distance: false,
        })
    }
}

/// `f` on every row of `rows`, spread over the cores with the GIL released
/// and stopped by Ctrl-C, results in row order; an error names its row.
pub fn per_row<T: Send>(
    py: Python<'_>,
    rows: &Rows<'_>,
    f: impl Fn(&[f64]) -> pkmcal::Result<T> + Sync,
) -> PyResult<Vec<T>> {
    let v = rows.view();
    run(py, v.nrows() > QUICK_ROWS, |cancel| {
        (0..v.nrows())
            .into_par_iter()
            .map(|i| {
                pkmcal::error::check_cancel(Some(&cancel))?;
                f(&row(&v, i)).map_err(at(i))
            })
            .collect::<pkmcal::Result<Vec<T>>>()
    })?
    .map_err(lib_err)
}

/// Which of q, torque and deflection ``outputs`` asks for besides x:
/// ``"all"``, ``"x"`` or a sequence of names.
fn outputs(kw: &Kw<'_>) -> PyResult<[bool; 3]> {
    const NAMES: [&str; 4] = ["x", "q", "torque", "deflection"];
    let Some(names) = kw.names("outputs")? else {
        return Ok([true; 3]);
    };
    if names == ["all"] {
        return Ok([true; 3]);
    }
    let mut want = [false; 3];
    for n in &names {
        match NAMES.iter().position(|k| k == n) {
            Some(0) => {}
            Some(k) => want[k - 1] = true,
            None => {
                return Err(usage(format!(
                    "outputs: unknown `{n}`; give \"all\" or some of {}{}",
                    NAMES.join(", "),
                    pkmcal::error::did_you_mean(n, NAMES)
                        .map(|s| format!(" (did you mean {s:?}?)"))
                        .unwrap_or_default()
                )));
            }
        }
    }
    Ok(want)
}

/// ``predict(mechanism, commands, params=None, *, model=None, load=None,
/// force=None, uncertainty=False, skip_unreachable=False, outputs="all")``.
#[pyfunction]
pub fn predict(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyPrediction> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m: &PyMechanism = mechanism.get();
    let spec = m.spec();
    let params = kw.any("params")?;
    let cal = params.as_ref().and_then(|p| p.cast::<PyCalibration>().ok());
    let saved = params
        .as_ref()
        .and_then(|p| p.cast::<PySavedCalibration>().ok());
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
    let model = model(&kw, cal_model.unwrap_or(pkmcal::Model::Exact))?;
    let uncertainty = kw.flag("uncertainty")?;
    if uncertainty && cal_covariance.is_none() {
        return Err(usage(
            "uncertainty=True needs params=<a Calibration or SavedCalibration>: the covariance comes from its parameters",
        ));
    }
    let skip = kw.flag("skip_unreachable")?;
    let [want_q, want_torque, want_deflection] = outputs(&kw)?;
    let p = params_arg(m, params.as_ref(), "params")?;
    let force = checked_load(&kw, m, &p)?;
    let commands = kw.required("commands")?;
    let missing = if skip { Missing::Nan } else { Missing::Refused };
    let r = rows(&commands, "commands", &m.actuators(), missing)?;
    let mech = &*m.mech;
    let settings = pkmcal::RowSettings {
        params: &p,
        model,
        force: &force,
        covariance: cal_covariance.as_ref().filter(|_| uncertainty),
    };
    let (n, nx, nq, na) = (
        r.len(),
        spec.tool_axes.len(),
        spec.joints.len(),
        spec.n_actuated(),
    );
    // Only the outputs asked for are kept: the memory is theirs.
    let buffer = |want: bool, w: usize| want.then(|| vec![0.0; n * w]);
    let mut x = vec![0.0; n * nx];
    let mut q = buffer(want_q, nq);
    let mut torque = buffer(want_torque, na);
    let mut deflection = buffer(want_deflection, na);
    let mut covariance = buffer(uncertainty, nx * nx);
    let flat = r.flat();
    let failed = run(py, n > QUICK_ROWS, |cancel| {
        pkmcal::predict_rows_into(
            mech,
            &settings,
            &flat,
            pkmcal::RowBuffers {
                x: Some(&mut x),
                q: q.as_deref_mut(),
                torque: torque.as_deref_mut(),
                deflection: deflection.as_deref_mut(),
                covariance: covariance.as_deref_mut(),
            },
            Some(&cancel),
        )
    })?;
    let skipped: Vec<usize> = failed.iter().map(|(i, _)| *i).collect();
    if !skip && let Some((i, e)) = failed.into_iter().next() {
        return Err(lib_err(at(i)(e)));
    }
    let single = r.single;
    drop(flat);
    Ok(PyPrediction {
        x: out2(py, x, nx, single).unbind(),
        q: q.map(|v| out2(py, v, nq, single).unbind()),
        torque: torque.map(|v| out2(py, v, na, single).unbind()),
        deflection: deflection.map(|v| out2(py, v, na, single).unbind()),
        covariance: covariance
            .map(|v| out3(py, v, nx, single).map(|a| a.unbind()))
            .transpose()?,
        skipped,
        names: (spec.tool_axes.clone(), spec.joints.clone(), m.actuators()),
        index: index_of(&commands).map(|i| i.unbind()),
    })
}

/// ``nominal_commands(mechanism, targets)``.
#[pyfunction]
pub fn nominal_commands<'py>(
    py: Python<'py>,
    args: &Bound<'py, PyDict>,
) -> PyResult<Bound<'py, PyAny>> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let r = rows(
        &kw.required("targets")?,
        "targets",
        &m.spec().tool_axes,
        Missing::Refused,
    )?;
    let mech = &*m.mech;
    let out = per_row(py, &r, |t| pkmcal::nominal_commands(mech, t))?;
    Ok(out2(py, out.concat(), m.spec().n_actuated(), r.single))
}

/// ``compensate(mechanism, targets, params=None, *, model="exact",
/// load=None, force=None, preload=None, skip_unreachable=False)``.
#[pyfunction]
pub fn compensate(py: Python<'_>, args: &Bound<'_, PyDict>) -> PyResult<PyCompensation> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let spec = m.spec();
    let p = params_arg(m, kw.any("params")?.as_ref(), "params")?;
    let model = model(&kw, pkmcal::Model::Exact)?;
    let opts = pkmcal::CompensationOptions {
        force: checked_load(&kw, m, &p)?,
        preload: vector(&kw, "preload", "actuator")?.unwrap_or_default(),
    };
    let skip = kw.flag("skip_unreachable")?;
    let targets = kw.required("targets")?;
    let missing = if skip { Missing::Nan } else { Missing::Refused };
    let r = rows(&targets, "targets", &spec.tool_axes, missing)?;
    let mech = &*m.mech;
    let flat = r.flat();
    let results = run(py, r.len() > QUICK_ROWS, |cancel| {
        pkmcal::compensate_rows(mech, &p, &flat, model, &opts, Some(&cancel))
    })?;
    let mut out: Vec<Option<pkmcal::Compensation>> = Vec::with_capacity(results.len());
    for (i, c) in results.into_iter().enumerate() {
        match c {
            Ok(c) => out.push(Some(c)),
            Err(_) if skip => out.push(None),
            Err(e) => return Err(lib_err(at(i)(e))),
        }
    }
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
        actuators: m.actuators(),
        index: index_of(&targets).map(|i| i.unbind()),
    })
}

/// ``simulate(mechanism, targets, truth=None, *, noise=0.0,
/// angle_noise=None, seed=None, axes=None, points=None, ballbar=None)``:
/// ``(commands, measured)``.
#[pyfunction]
pub fn simulate<'py>(
    py: Python<'py>,
    args: &Bound<'py, PyDict>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let kw = Kw::new(args.clone());
    let mechanism = mechanism_arg(&kw.required("mechanism")?)?;
    let m = mechanism.get();
    let spec = m.spec();
    let seed = seed(&kw)?;
    let truth = params_arg(m, kw.any("truth")?.as_ref(), "truth")?;
    let noise = simulated_noise(&kw, 0.0)?;
    // Simulated readings are in the base frame.
    let mm = instrument(&kw, m, Some(pkmcal::FrameChoice::Base))?;
    let r = rows(
        &kw.required("targets")?,
        "targets",
        &spec.tool_axes,
        Missing::Refused,
    )?;
    let t = r.to_vecs();
    let mech = &*m.mech;
    let data = interruptible(py, |cancel| {
        pkmcal::simulate_cancellable(mech, &mm, &truth, &t, noise, seed, Some(&cancel))
    })?
    .map_err(lib_err)?;
    let c: Vec<f64> = data.iter().flat_map(|d| d.commands.clone()).collect();
    let y: Vec<f64> = data.iter().flat_map(|d| d.measured.clone()).collect();
    Ok((
        out2(py, c, spec.n_actuated(), r.single),
        out2(py, y, mm.len(), r.single),
    ))
}

/// ``trilaterate(sockets, readings, *, bar_offset=0.0, sigma=0.002)``:
/// ``(positions, covariances)``.
#[pyfunction]
pub fn trilaterate<'py>(
    py: Python<'py>,
    args: &Bound<'py, PyDict>,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let kw = Kw::new(args.clone());
    let sigma = kw.f64("sigma")?.unwrap_or(0.002);
    let setup = pkmcal::Setup {
        sockets: sockets_arg(&kw.required("sockets")?, "sockets")?,
        bar_offset: kw.f64("bar_offset")?.unwrap_or(0.0),
    };
    let dim = setup.sockets[0].len();
    setup.validate(dim).map_err(lib_err)?;
    let cols: Vec<String> = (1..=setup.sockets.len()).map(|k| format!("d{k}")).collect();
    let r = rows(
        &kw.required("readings")?,
        "readings",
        &cols,
        Missing::Refused,
    )?;
    let out = per_row(py, &r, |d| pkmcal::trilaterate(&setup, d, sigma, None))?;
    let x: Vec<f64> = out.iter().flat_map(|(x, _)| x.iter().copied()).collect();
    let cov: Vec<f64> = out
        .iter()
        .flat_map(|(_, c)| (0..dim).flat_map(move |j| (0..dim).map(move |k| c[(j, k)])))
        .collect();
    Ok((out2(py, x, dim, r.single), out3(py, cov, dim, r.single)?))
}
