//! A call's keywords onto the library's request: the free set, tolerances,
//! the instrument and its stated noise, the load, validation, the solver's
//! settings and the seed, each read once here for every function, the
//! rules left to `pkmcal::Request` (a refusal names the keyword,
//! [`crate::errors::request_words`]). Also the data: commands and readings
//! as the library's measurements.

use crate::arrays::{Missing, aligned, rows, shape_text};
use crate::errors::{io_err, lib_err, request_err, usage, wrong_type};
use crate::files::{path_arg, reading};
use crate::keywords::Kw;
use crate::mechanism::PyMechanism;
use crate::results::calibration::{PyCalibration, PySavedCalibration};
use numpy::{AllowTypeChange, PyArrayLikeDyn};
use pkmcal::{FrameChoice, MeasurementModel, Mechanism as _, Noise, Origin, Params, Request};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};

/// The forward model by name.
pub fn model(kw: &Kw<'_>, default: pkmcal::Model) -> PyResult<pkmcal::Model> {
    match kw.str("model")? {
        None => Ok(default),
        Some(s) => s.parse().map_err(lib_err),
    }
}

/// A request for `model` with the keywords every fit, analysis and plan
/// shares: ``free``, ``fix``, ``tolerances``.
pub fn request(kw: &Kw<'_>, model: pkmcal::Model) -> PyResult<Request> {
    let mut r = Request::new(model);
    r.free = kw.names("free")?;
    r.fix = kw.names("fix")?.unwrap_or_default();
    tolerances_request(&mut r, kw.any("tolerances")?.as_ref())?;
    Ok(r)
}

/// The free set the request resolves (its priors freeing their
/// parameters), for the functions that take no study.
pub fn free_of(
    r: &Request,
    m: &PyMechanism,
    measurement: &MeasurementModel,
) -> PyResult<(Vec<pkmcal::identify::Prior>, Vec<usize>)> {
    r.priors_and_free(m.spec(), measurement, &m.tolerances)
        .map_err(request_err)
}

/// The instrument's stated noise onto the request: ``stated_noise`` (mm)
/// and ``stated_angle_noise`` (rad).
pub fn stated_noise(kw: &Kw<'_>, r: &mut Request) -> PyResult<()> {
    r.stated_noise = kw.f64("stated_noise")?;
    r.stated_angle_noise = kw.f64("stated_angle_noise")?;
    Ok(())
}

/// Simulated noise: ``noise`` (mm) and ``angle_noise`` (rad; by default
/// the length noise over a 200 mm lever arm), bounded as the library
/// bounds every noise a user gives.
pub fn simulated_noise(kw: &Kw<'_>, default: f64) -> PyResult<Noise> {
    use pkmcal::identify::request::{MAX_ANGLE_RAD, MAX_LENGTH_MM, bounded};
    let length = kw.f64("noise")?.unwrap_or(default);
    bounded(pkmcal::Field::Noise, length, MAX_LENGTH_MM, "mm").map_err(request_err)?;
    let mut noise = Noise::lengths(length);
    if let Some(a) = kw.f64("angle_noise")? {
        noise.angle =
            bounded(pkmcal::Field::AngleNoise, a, MAX_ANGLE_RAD, "rad").map_err(request_err)?;
    }
    Ok(noise)
}

/// ``tolerances``: a mapping name → σ (a number in the parameter's unit) or a
/// percentage of its nominal value (``"20%"``), in the order given.
pub fn tolerances_arg(
    t: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<(String, pkmcal::apply::budget::Tolerance)>> {
    use pkmcal::apply::budget::Tolerance;
    let mut given: Vec<(String, Tolerance)> = vec![];
    let Some(t) = t.filter(|t| !t.is_none()) else {
        return Ok(given);
    };
    let items = t
        .call_method0("items")
        .map_err(|_| wrong_type("tolerances", "a dict name → σ or \"20%\"", t))?;
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

/// The solver's settings, as scipy's ``least_squares`` names them.
pub fn solver(kw: &Kw<'_>) -> PyResult<pkmcal::identify::SolverRequest> {
    Ok(pkmcal::identify::SolverRequest {
        max_evaluations: kw.count("max_nfev")?,
        ftol: kw.f64("ftol")?,
        xtol: kw.f64("xtol")?,
        gtol: kw.f64("gtol")?,
        bounds: match kw.any("bounds")? {
            Some(b) => bounds_arg(&b)?,
            None => vec![],
        },
    })
}

/// ``bounds``: a mapping name → ``(lower, upper)``.
fn bounds_arg(b: &Bound<'_, PyAny>) -> PyResult<Vec<(String, f64, f64)>> {
    let items = b
        .call_method0("items")
        .map_err(|_| wrong_type("bounds", "a dict name → (lower, upper)", b))?;
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

/// The start of a fit: ``start`` (parameters, as ``params`` takes them) or
/// ``x0`` (the same, or one value per free mechanism parameter in column
/// order), not both.
pub fn start(kw: &Kw<'_>, m: &PyMechanism, r: &Request, mm: &MeasurementModel) -> PyResult<Params> {
    match (kw.any("start")?, kw.any("x0")?) {
        (Some(_), Some(_)) => Err(request_err(pkmcal::RequestError::Exclusive {
            a: pkmcal::Field::Start,
            b: pkmcal::Field::X0,
        })),
        (None, Some(x)) => {
            let (_, free) = free_of(r, m, mm)?;
            x0_arg(m, &free, &x)
        }
        (s, None) => params_arg(m, s.as_ref(), "start"),
    }
}

/// Parameters from None (nominal), a dict (name → value; the others
/// nominal), a Calibration (its identified values) or a path to a parameter
/// file written by the command-line tool.
pub fn params_arg(m: &PyMechanism, p: Option<&Bound<'_, PyAny>>, what: &str) -> PyResult<Params> {
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
    // A table of parameters (`Calibration.to_pandas()`): its values.
    if crate::arrays::has_index(p)
        && p.hasattr("columns")?
        && p.getattr("columns")?.contains("value")?
    {
        return params_arg(m, Some(&p.get_item("value")?), what);
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
        return params_file(m, &path);
    } else {
        return Err(wrong_type(
            what,
            "parameter values by name (a dict or any mapping, e.g. a pandas Series), a Calibration, a SavedCalibration or a parameter file path (str or os.PathLike)",
            p,
        ));
    };
    pkmcal::check_params(&*m.mech, &params).map_err(|e| {
        usage(format!(
            "{what}: the values cannot describe this mechanism: {e}"
        ))
    })?;
    Ok(params)
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

/// ``seed``: a whole number ≥ 0 (the same numbers every time), None (fresh
/// numbers from the operating system's entropy) or a NumPy ``Generator``
/// or ``RandomState`` (one draw from it, so that a user's stream decides).
pub fn seed(kw: &Kw<'_>) -> PyResult<u64> {
    let Some(s) = kw.any("seed")? else {
        let mut b = [0u8; 8];
        let bytes = kw.py().import("os")?.call_method1("urandom", (b.len(),))?;
        b.copy_from_slice(bytes.cast::<PyBytes>()?.as_bytes());
        return Ok(u64::from_le_bytes(b));
    };
    let drawn = if s.hasattr("integers")? {
        Some(s.call_method1("integers", (0u64, 1u64 << 63))?)
    } else if s.hasattr("randint")? && !s.is_instance_of::<pyo3::types::PyInt>() {
        Some(s.call_method1("randint", (0u64, 1u64 << 62))?)
    } else {
        None
    };
    let value = drawn.as_ref().unwrap_or(&s);
    let expected = "a whole number ≥ 0, None or a NumPy Generator";
    if value.is_instance_of::<pyo3::types::PyBool>() {
        return Err(wrong_type("seed", expected, value));
    }
    let i: i128 = value
        .call_method0("__index__")
        .and_then(|v| v.extract())
        .map_err(|_| wrong_type("seed", expected, &s))?;
    u64::try_from(i).map_err(|_| {
        usage(format!(
            "seed={i}: out of range; give a whole number from 0 to 2^64 - 1, None or a NumPy Generator"
        ))
    })
}

/// A vector argument (``load``, ``preload``…): one value per item, a list or
/// a 1-D array; a 2-D array is refused by name (one value per row is not
/// taken).
pub fn vector(kw: &Kw<'_>, what: &str, per: &str) -> PyResult<Option<Vec<f64>>> {
    let Some(v) = kw.any(what)? else {
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
        wrong_type(
            what,
            &format!("one number per {per} (a list or a 1-D array)"),
            &v,
        )
    })
}

/// The tool load: ``load=`` (the CLI's ``--load``), or ``force=``, its old
/// name, still read; not both. Empty for none; the library checks it
/// against the mechanism ([`pkmcal::identify::request::checked_load`]).
pub fn load(kw: &Kw<'_>) -> PyResult<Vec<f64>> {
    let load = vector(kw, "load", "tool axis")?;
    let force = vector(kw, "force", "tool axis")?;
    match (load, force) {
        (Some(_), Some(_)) => Err(usage(
            "give the tool load once: load= (force= is its old name)",
        )),
        (l, f) => Ok(l.or(f).unwrap_or_default()),
    }
}

/// The tool load checked against the mechanism at `params`.
pub fn checked_load(kw: &Kw<'_>, m: &PyMechanism, params: &Params) -> PyResult<Vec<f64>> {
    pkmcal::identify::request::checked_load(&load(kw)?, &*m.mech, params, pkmcal::Field::Load)
        .map_err(request_err)
}

/// The instrument: the whole tool, some tool axes, heights probed on a bed
/// plane (`axes=["probe"]`), target points on the tool or a ball bar (at
/// most one of ``axes``, ``points``, ``ballbar``); in the frame ``frame``
/// says (``auto`` where not given), or in `frame` where the function has
/// no such keyword.
pub fn instrument(
    kw: &Kw<'_>,
    m: &PyMechanism,
    frame: Option<FrameChoice>,
) -> PyResult<MeasurementModel> {
    let spec = m.spec();
    let axes = kw.names("axes")?;
    let points = kw.any("points")?;
    let ballbar = kw.any("ballbar")?;
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
            rows(&p, "points", &cols, Missing::Refused)?.to_vecs()
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
                wrong_type(
                    "ballbar",
                    "a dict {\"sockets\": array (k, 2 or 3), \"bar_offset\": mm}",
                    &b,
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
    let choice: FrameChoice = match frame {
        Some(f) => f,
        None => {
            let frame = kw.str("frame")?.unwrap_or_else(|| "auto".into());
            frame.parse().map_err(|_| {
                usage(format!(
                    "frame: unknown `{frame}`; use \"auto\" (the default: free for whole positions and target points, base otherwise), \"base\" (readings in the base frame) or \"free\" (an instrument frame identified with the rest)"
                ))
            })?
        }
    };
    choice.apply(mm, spec, false).map_err(request_err)
}

/// Ball-bar socket centres: an array (k, 2) or (k, 3) of finite numbers.
pub fn sockets_arg(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<Vec<f64>>> {
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
    // NaN: to be estimated; the library bounds the others.
    let check = |v: f64| -> PyResult<Option<f64>> { Ok((!v.is_nan()).then_some(v)) };
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
    let r = rows(s, "sigma", mm.axes(), Missing::Nan)?;
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

/// Distances measured between pairs of poses: a tuple ``(commands_1,
/// commands_2, distance)`` or ``(commands_1, commands_2, distance, sigma)``,
/// each commands array of shape ``(n, actuators)``, distances ``(n,)`` in mm
/// (pandas objects matched on their index).
pub fn distances(
    kw: &Kw<'_>,
    m: &PyMechanism,
    mm: &MeasurementModel,
) -> PyResult<Vec<pkmcal::Measurement>> {
    let Some(obj) = kw.any("distances")? else {
        return Ok(vec![]);
    };
    let expected =
        "a tuple (commands_1, commands_2, distance) or (commands_1, commands_2, distance, sigma)";
    let t = obj
        .cast::<PyTuple>()
        .map_err(|_| wrong_type("distances", expected, &obj))?;
    if !(3..=4).contains(&t.len()) {
        return Err(usage(format!("distances: expected {expected}")));
    }
    mm.check_distances().map_err(lib_err)?;
    let names = ["commands_1", "commands_2", "distance", "sigma"];
    let items = aligned(
        (0..t.len())
            .map(|i| Ok((names[i], Some(t.get_item(i)?))))
            .collect::<PyResult<Vec<_>>>()?,
    )?;
    let item = |i: usize| items[i].clone().expect("given");
    let a = rows(
        &item(0),
        "distances commands_1",
        &m.actuators(),
        Missing::Refused,
    )?
    .to_vecs();
    let b = rows(
        &item(1),
        "distances commands_2",
        &m.actuators(),
        Missing::Refused,
    )?
    .to_vecs();
    let one = |i: usize, what: &str| -> PyResult<Vec<f64>> {
        let item = item(i);
        let v: Vec<f64> = match item.extract::<Vec<f64>>() {
            Ok(v) => v,
            Err(_) => rows(
                &item,
                what,
                &[pkmcal::DISTANCE_AXIS.to_string()],
                Missing::Refused,
            )?
            .to_vecs()
            .into_iter()
            .map(|v| v[0])
            .collect(),
        };
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
    Ok(a.into_iter()
        .zip(b)
        .zip(d)
        .enumerate()
        .map(|(i, ((a, b), d))| pkmcal::Measurement {
            point: None,
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

/// The poses of ``commands`` and ``measured`` (with ``sigma`` and
/// ``targets`` when given) as the library's measurements, numbered by row
/// from 0; pandas objects matched on their index. `what` prefixes the names
/// in errors (``validation``).
pub fn measurements(
    m: &PyMechanism,
    mm: &MeasurementModel,
    given: [Option<Bound<'_, PyAny>>; 4],
    what: &str,
) -> PyResult<Vec<pkmcal::Measurement>> {
    let spec = m.spec();
    let name = |n: &str| format!("{what}{n}");
    let [commands, measured, sigma, targets] = given;
    let (cn, mn, sn, tn) = (
        name("commands"),
        name("measured"),
        name("sigma"),
        name("targets"),
    );
    // A σ per pose is a table (a row per pose); a Series or a 1-D array
    // is one σ per axis, with no rows to match.
    let sigma_rows = sigma
        .clone()
        .filter(|s| s.hasattr("columns").unwrap_or(false));
    let items = aligned(vec![
        (cn.as_str(), commands),
        (mn.as_str(), measured),
        (sn.as_str(), sigma_rows.clone()),
        (tn.as_str(), targets),
    ])?;
    let [commands, measured, aligned_sigma, targets] =
        <[Option<Bound<'_, PyAny>>; 4]>::try_from(items).expect("four");
    let sigma = if sigma_rows.is_some() {
        aligned_sigma
    } else {
        sigma
    };
    let (commands, measured) = (
        commands.ok_or_else(|| usage(format!("{cn}: give the commands")))?,
        measured.ok_or_else(|| usage(format!("{mn}: give the readings")))?,
    );
    let c = rows(&commands, &cn, &m.actuators(), Missing::Refused)?.to_vecs();
    let y = rows(&measured, &mn, mm.axes(), Missing::Refused)?.to_vecs();
    if c.len() != y.len() {
        return Err(usage(format!(
            "{cn} has {} rows and {mn} {}; give one row of each per pose",
            c.len(),
            y.len()
        )));
    }
    let t = match targets {
        Some(t) => {
            let t = rows(&t, &tn, &spec.tool_axes, Missing::Refused)?.to_vecs();
            if t.len() != c.len() {
                return Err(usage(format!(
                    "{tn} has {} rows for {} poses",
                    t.len(),
                    c.len()
                )));
            }
            Some(t)
        }
        None => None,
    };
    let s = sigma_arg(sigma.as_ref(), mm, c.len())?;
    Ok(c.into_iter()
        .zip(y)
        .zip(s)
        .enumerate()
        .map(|(i, ((commands, measured), sigma))| pkmcal::Measurement {
            point: None,
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

/// ``validation``: a tuple (or list) ``(commands, measured)`` or
/// ``(commands, measured, sigma)``.
pub fn validation(
    kw: &Kw<'_>,
    m: &PyMechanism,
    mm: &MeasurementModel,
) -> PyResult<Option<Vec<pkmcal::Measurement>>> {
    let Some(v) = kw.any("validation")? else {
        return Ok(None);
    };
    let expected = "a tuple (commands, measured) or (commands, measured, sigma)";
    // A tuple or a list (any sequence that is not itself an array).
    let items: Vec<Bound<'_, PyAny>> = v
        .try_iter()
        .and_then(|i| i.collect::<PyResult<Vec<_>>>())
        .ok()
        .filter(|_| !v.hasattr("shape").unwrap_or(false) && !crate::arrays::has_index(&v))
        .ok_or_else(|| wrong_type("validation", expected, &v))?;
    if !(2..=3).contains(&items.len()) {
        return Err(usage(format!("validation: expected {expected}")));
    }
    let mut it = items.into_iter();
    let (c, y, s) = (it.next(), it.next(), it.next());
    measurements(m, mm, [c, y, s, None], "validation ").map(Some)
}

/// Parameters read from a file written by the command-line tool.
fn params_file(m: &PyMechanism, path: &str) -> PyResult<Params> {
    reading(|run| pkmcal_io::params::read_params(run, std::path::Path::new(path), &*m.mech))
        .map_err(io_err)
}
