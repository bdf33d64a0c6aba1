//! The firmware calibrations (`pkmcal klipper`, `reprap`, `marlin` on the
//! command line): a printer's configuration and probe results read as its
//! firmware reads them, its values fitted (or, with ``physical=True``, the
//! printer as built fitted and the firmware's values chosen for the nozzle
//! over the build volume), what the command line prints returned as data,
//! and the files written only where asked (``out=``, ``height_map=``,
//! ``report_dir=``, Klipper's ``out_dir=``), all or nothing, byte for byte
//! as the command line writes them. Marlin's comparison with its own G33
//! is returned as data (``g33``).
//! `pkmcal/_api.py` turns the dict returned into its dataclasses.

use crate::errors::{io_err, keyword, request_err, usage, wrong_type};
use crate::files::{check_outputs, path_arg, reading, written};
use crate::keywords::Kw;
use crate::request::tolerances_arg;
use crate::threads::interruptible;
use pkmcal::{Field, Mechanism, Params, Request};
use pkmcal_io::firmware::choices::{self, Choices};
use pkmcal_io::firmware::g33::{self, G33Ask, RadiusFrom};
use pkmcal_io::firmware::klipper::{DISTANCES_FILE, OUT_DIR_FILES, out_dir_files};
use pkmcal_io::firmware::klipper::{KlipperPrinter, Weighting};
use pkmcal_io::firmware::klipper_rotary::{self, RotaryPrinter};
use pkmcal_io::firmware::marlin::{LetterB, MarlinPrinter};
use pkmcal_io::firmware::physical::{self, ErrorSummary, NoiseNote, ProbeNoise};
use pkmcal_io::firmware::reprap::RrfPrinter;
use pkmcal_io::firmware::{
    self, Firmware, FirmwareValue, FirmwareWarning, PrinterCalibration, Separation, Sigma, Spread,
    TiltPlace, height_map, physical_plan, physical_report,
};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::PathBuf;

/// The firmware command's choices of a call, checked by the library's
/// rules ([`Choices::check`]).
struct Common {
    request: Request,
    physical: bool,
    max_sigma: f64,
    out: Option<PathBuf>,
    height_map: Option<PathBuf>,
    mesh_points: Option<usize>,
    heights: Option<PathBuf>,
    report_dir: Option<PathBuf>,
    out_dir: Option<PathBuf>,
}

impl Common {
    /// Refuse, before any work, an output that is one of the call's
    /// `inputs` (or the heights read) or another output, as the command
    /// line does: `out=` is never written over the configuration.
    fn check_paths(&self, inputs: &[&std::path::Path]) -> PyResult<()> {
        let mut outputs: Vec<PathBuf> = self.out.iter().chain(&self.height_map).cloned().collect();
        let mut dirs = vec![];
        if let Some(d) = &self.report_dir {
            outputs.extend(pkmcal_io::output::in_dir(d, physical_report::FILES).map_err(io_err)?);
            dirs.push(d.clone());
        }
        if let Some(d) = &self.out_dir {
            outputs.extend(pkmcal_io::output::in_dir(d, &OUT_DIR_FILES).map_err(io_err)?);
            outputs.extend(pkmcal_io::output::in_dir(d, &[DISTANCES_FILE]).map_err(io_err)?);
            dirs.push(d.clone());
        }
        let inputs: Vec<&std::path::Path> = inputs
            .iter()
            .copied()
            .chain(self.heights.as_deref())
            .collect();
        let outputs: Vec<&std::path::Path> = outputs.iter().map(PathBuf::as_path).collect();
        check_outputs(&inputs, &outputs, &dirs)
    }
}

fn path_kw(kw: &Kw<'_>, name: &str) -> PyResult<Option<PathBuf>> {
    kw.any(name)?
        .map(|p| {
            path_arg(&p)
                .map(PathBuf::from)
                .map_err(|_| wrong_type(name, "a path (str or os.PathLike)", &p))
        })
        .transpose()
}

fn common(kw: &Kw<'_>, extra: Choices) -> PyResult<Common> {
    let physical = kw.flag("physical")?;
    let tolerances = tolerances_arg(kw.any("tolerances")?.as_ref())?;
    let height_map = path_kw(kw, "height_map")?;
    let mesh_points = kw.count("mesh_points")?;
    let probe_noise = kw.f64("probe_noise")?;
    let heights = path_kw(kw, "heights")?;
    let report_dir = path_kw(kw, "report_dir")?;
    let out_dir = path_kw(kw, "out_dir")?;
    Choices {
        physical,
        tolerances: !tolerances.is_empty(),
        height_map: height_map.is_some(),
        mesh_points,
        probe_noise,
        heights: heights.is_some(),
        report_dir: report_dir.is_some(),
        out_dir: out_dir.is_some(),
        ..extra
    }
    .check()
    .map_err(request_err)?;
    let max_sigma = match kw.f64("max_sigma")? {
        Some(v) => choices::max_sigma(v).map_err(request_err)?,
        None => firmware::DEFAULT_MAX_SIGMA,
    };
    let mut request = Request::new(pkmcal::Model::Exact);
    request.free = kw.names("free")?;
    request.fix = kw.names("fix")?.unwrap_or_default();
    request.tolerances = tolerances;
    request.stated_noise = probe_noise;
    Ok(Common {
        request,
        physical,
        max_sigma,
        out: path_kw(kw, "out")?,
        height_map,
        mesh_points,
        heights,
        report_dir,
        out_dir,
    })
}

/// ``klipper(config, **options)``.
#[pyfunction]
pub fn klipper<'py>(py: Python<'py>, args: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let kw = Kw::new(args.clone());
    let config = path_kw(&kw, "config")?.ok_or_else(|| usage("config: a value is needed"))?;
    let previous = path_kw(&kw, "previous")?;
    let c = common(
        &kw,
        Choices {
            previous: previous.is_some(),
            ..Choices::default()
        },
    )?;
    c.check_paths(
        &[config.as_path()]
            .into_iter()
            .chain(previous.as_deref())
            .collect::<Vec<_>>(),
    )?;
    let weighting: Weighting = match kw.str("weighting")? {
        Some(w) => w
            .parse()
            .map_err(|e: String| usage(format!("{}: {e}", keyword(Field::Weighting))))?,
        None => Weighting::Klipper,
    };
    let (text, ini) =
        reading(|run| pkmcal_io::firmware::klipper::read_config(run, &config)).map_err(io_err)?;
    if klipper_rotary::is_rotary(&ini) {
        let printer = RotaryPrinter::from_parsed(&config, text, ini, weighting).map_err(io_err)?;
        return result(py, &printer, &config, c, None, Some(weighting), no_g33);
    }
    let before = match &previous {
        Some(p) if c.physical => {
            let before = reading(|run| KlipperPrinter::read(run, p, weighting))
                .map_err(|e| io_err(e.context(format!("previous {}", p.display()))))?;
            let (text, ini) =
                reading(|run| pkmcal_io::firmware::klipper::read_config(run, &config))
                    .map_err(io_err)?;
            Some((
                KlipperPrinter::from_parsed(&config, text, ini, weighting)
                    .map_err(io_err)?
                    .with_readings_of(before),
                p.display().to_string(),
            ))
        }
        _ => None,
    };
    let printer = KlipperPrinter::from_parsed(&config, text, ini, weighting).map_err(io_err)?;
    result(
        py,
        &printer,
        &config,
        c,
        before
            .as_ref()
            .map(|(p, s)| (p as &dyn Firmware, s.clone())),
        Some(weighting),
        no_g33,
    )
}

/// ``reprap(config, probes, **options)``.
#[pyfunction]
pub fn reprap<'py>(py: Python<'py>, args: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let kw = Kw::new(args.clone());
    let config = path_kw(&kw, "config")?.ok_or_else(|| usage("config: a value is needed"))?;
    let probes = path_kw(&kw, "probes")?.ok_or_else(|| usage("probes: a value is needed"))?;
    let c = common(&kw, Choices::default())?;
    c.check_paths(&[&config, &probes])?;
    let printer = reading(|run| RrfPrinter::read(run, &config, &probes, c.request.free.as_deref()))
        .map_err(io_err)?;
    result(py, &printer, &probes, c, None, None, no_g33)
}

/// ``marlin(config, probes, **options)``.
#[pyfunction]
pub fn marlin<'py>(py: Python<'py>, args: &Bound<'py, PyDict>) -> PyResult<Bound<'py, PyDict>> {
    let kw = Kw::new(args.clone());
    let config = path_kw(&kw, "config")?.ok_or_else(|| usage("config: a value is needed"))?;
    let probes = path_kw(&kw, "probes")?.ok_or_else(|| usage("probes: a value is needed"))?;
    // (The wrapper always passes G33's default points.)
    let g33 = choices::g33_given(
        kw.count("g33_points")?
            .unwrap_or(usize::from(g33::DEFAULT_POINTS)),
        kw.flag("g33_fixed_angles")?,
    );
    let c = common(
        &kw,
        Choices {
            g33,
            ..Choices::default()
        },
    )?;
    c.check_paths(&[&config, &probes])?;
    let letter_b: Option<LetterB> = kw
        .str("m665_b")?
        .map(|s| {
            s.parse()
                .map_err(|e: String| usage(format!("{}: {e}", keyword(Field::FirmwareLetters))))
        })
        .transpose()?;
    let probe_offset: Option<[f64; 2]> = kw
        .any("probe_offset")?
        .map(|v| {
            v.extract::<(f64, f64)>()
                .map(|(x, y)| [x, y])
                .map_err(|_| wrong_type("probe_offset", "two numbers (x, y)", &v))
        })
        .transpose()?;
    let g33_radius = kw
        .f64("g33_radius")?
        .map(choices::g33_radius)
        .transpose()
        .map_err(request_err)?;
    let ask = G33Ask {
        points: match kw.count("g33_points")? {
            None => g33::DEFAULT_POINTS,
            Some(p) => choices::g33_points(p).map_err(|e| match e {
                pkmcal::RequestError::Invalid { field, problem, .. } => {
                    usage(format!("{}={p}: {problem}", keyword(field)))
                }
                e => request_err(e),
            })?,
        },
        towers: !kw.flag("g33_fixed_angles")?,
        radius: g33_radius,
    };
    let printer = reading(|run| {
        MarlinPrinter::read(
            run,
            &config,
            &probes,
            letter_b,
            probe_offset,
            g33_radius,
            c.request.free.as_deref(),
        )
    })
    .map_err(io_err)?;
    result(py, &printer, &probes, c, None, None, |py, calibrated| {
        g33_comparison(py, &printer, calibrated, &ask).map(|d| d.into_any())
    })
}

/// No comparison with a firmware's own calibration (Klipper's,
/// RepRapFirmware's).
fn no_g33<'py>(py: Python<'py>, _: &PrinterCalibration) -> PyResult<Bound<'py, PyAny>> {
    Ok(py.None().into_bound(py))
}

/// Marlin's own G33, as its G33.cpp runs it, on the printer the fit found,
/// against pkmcal's values ([`g33::compare`]): what the command line
/// prints after the values (`pkmcal marlin`), as data. Where G33 cannot
/// run, `not_run` says why.
fn g33_comparison<'py>(
    py: Python<'py>,
    printer: &MarlinPrinter,
    calibrated: &PrinterCalibration,
    ask: &G33Ask,
) -> PyResult<Bound<'py, PyDict>> {
    let c = g33::compare(printer, calibrated, ask).map_err(io_err)?;
    let d = PyDict::new(py);
    d.set_item("points", c.options.points)?;
    d.set_item("towers", c.options.towers)?;
    d.set_item("factors", c.factors.0)?;
    d.set_item("adjusts", c.factors.1)?;
    d.set_item("radius", c.options.radius)?;
    d.set_item(
        "radius_from",
        match c.radius_from {
            RadiusFrom::Given => "given",
            RadiusFrom::Log => "log",
            RadiusFrom::M665B => "M665 B",
            RadiusFrom::FarthestProbe => "farthest probed point",
        },
    )?;
    match &c.outcome {
        Ok(x) => {
            let g = &x.run;
            let r = PyDict::new(py);
            r.set_item("std_devs", g.std_devs.clone())?;
            r.set_item("rolled_back", g.rolled_back)?;
            r.set_item("probes", g.probes)?;
            r.set_item("settings", g.settings.gcode())?;
            r.set_item("with_g33", figures(py, x.with_g33)?)?;
            r.set_item("with_pkmcal", figures(py, x.with_calibration)?)?;
            d.set_item("run", r)?;
            d.set_item("not_run", py.None())?;
        }
        Err(e) => {
            d.set_item("run", py.None())?;
            d.set_item("not_run", crate::errors::io_words(e))?;
        }
    }
    Ok(d)
}

/// `{"max": …, "rms": …}` of errors.
fn figures<'py>(py: Python<'py>, s: Spread) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("max", s.max)?;
    d.set_item("rms", s.rms)?;
    Ok(d)
}

fn value_dicts<'py>(py: Python<'py>, values: &[FirmwareValue]) -> PyResult<Bound<'py, PyList>> {
    let l = PyList::empty(py);
    for v in values {
        let d = PyDict::new(py);
        d.set_item("name", &v.name)?;
        d.set_item("before", v.before)?;
        d.set_item("after", v.after)?;
        // As the command line shows it ([`FirmwareValue::sigma_shown`]):
        // unknown NaN, fixed None.
        d.set_item(
            "sigma",
            match v.sigma_shown() {
                Sigma::Known(s) => Some(s),
                Sigma::Unknown => Some(f64::NAN),
                Sigma::Fixed => None,
            },
        )?;
        d.set_item("unit", v.unit)?;
        l.append(d)?;
    }
    Ok(l)
}

fn summary_dict<'py>(py: Python<'py>, e: &ErrorSummary) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("xy_rms", e.xy_rms)?;
    d.set_item("xy_max", e.xy_max)?;
    d.set_item("z_rms", e.z_rms)?;
    d.set_item("z_max", e.z_max)?;
    Ok(d)
}

fn note<'py>(
    py: Python<'py>,
    kind: &str,
    message: String,
    hint: String,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("kind", kind)?;
    d.set_item("message", message)?;
    d.set_item("hint", hint)?;
    Ok(d)
}

/// A firmware check: what it found (the library's words) and what to do,
/// naming the package's keywords.
fn firmware_warning<'py>(py: Python<'py>, w: &FirmwareWarning) -> PyResult<Bound<'py, PyDict>> {
    let (kind, hint) = match w {
        FirmwareWarning::Correlated {
            distances,
            separation,
            fix,
            ..
        } => {
            let separate = match (separation, distances) {
                (Separation::Distances, 0) => {
                    "add DELTA_ANALYZE distances (measured on a calibration object)"
                }
                (Separation::Distances, _) => "add more DELTA_ANALYZE distances",
                (Separation::FurtherOut, _) => "probe points further out towards the bed's edge",
            };
            (
                "correlated",
                format!("{separate}, or keep `{fix}` fixed at a measured value (fix=\"{fix}\")"),
            )
        }
        FirmwareWarning::Uncertain { limit, nozzle, .. } => (
            "uncertain",
            match firmware::uncertain_cause(*limit, *nozzle) {
                firmware::UncertainCause::Together => "each value's σ is of it alone; a print shows the nozzle's. To pin each value down, measure what the probe cannot see (the next measurements); max_sigma= sets the limit".into(),
                firmware::UncertainCause::Nozzle => "the readings leave the nozzle itself uncertain: take the next measurements, or state tighter tolerances of the parts you know (tolerances=); max_sigma= sets the limit".into(),
                firmware::UncertainCause::Readings => "probe more points over the whole bed, or keep fixed what the readings cannot determine (fix=); max_sigma= sets the limit".into(),
            },
        ),
        FirmwareWarning::TiltAbsorbed { place, .. } => {
            let hint = match place {
                TiltPlace::Values { values, free } => format!(
                    "free {} to write the tilt as {values} (free=\"default,{}\"), or level the bed",
                    free.join(" and "),
                    free.join(",")
                ),
                TiltPlace::BedMesh => "level the bed and probe again (a tilt is the bed's, not the delta's: Klipper's bed_mesh can take it when printing)".into(),
                TiltPlace::Levelling => "level the bed and probe again (a tilt is the bed's, not the delta's: Marlin's bed levelling, G29, can take it when printing)".into(),
            };
            ("tilt_absorbed", hint)
        }
    };
    note(py, kind, w.message(), hint)
}

/// A calibration's warning, as the package's other results give it.
fn calibration_warning<'py>(
    py: Python<'py>,
    w: &pkmcal::identify::Warning,
) -> PyResult<Bound<'py, PyDict>> {
    note(py, w.kind.name(), w.message.clone(), w.hint.clone())
}

/// What the physical fit's residuals say of the readings' noise, worded
/// with the package's keywords: stated (``probe_noise=``) or assumed.
fn noise_note<'py>(py: Python<'py>, n: &NoiseNote) -> PyResult<Bound<'py, PyDict>> {
    let message = n.message();
    let model = if n.suspects.is_empty() {
        "the printer moves in a way the physical model does not describe (backlash, a loose joint, thermal drift between the probes)"
    } else {
        "free the parameters named (free=) and calibrate again"
    };
    let hint = match (n.is_warning(), n.more, n.heights, n.noise) {
        (false, ..) => String::new(),
        (true, false, _, s) => format!(
            "the σ stated is larger than the heights show: check probe_noise={} against the probe's repeatability (the standard deviation of repeated probes at one point, as PROBE_ACCURACY reports it), or leave probe_noise out to assume a typical probe's {}",
            s.mm(),
            physical::PROBE_NOISE_MM
        ),
        (true, true, true, ProbeNoise::Assumed(_)) => format!(
            "the probe's σ was assumed, not stated: measure its repeatability (the standard deviation of repeated probes at one point, as PROBE_ACCURACY reports it) and state it with probe_noise=; if it is as small as assumed, {model}"
        ),
        (true, true, true, ProbeNoise::Stated(s)) => format!(
            "check probe_noise={s} against the probe's repeatability measured as the heights were (speed, temperature); if it is right, {model}"
        ),
        (true, true, false, _) => format!(
            "check the distances measured on the calibration object for a misread value; if they are right, {model}"
        ),
    };
    let d = note(py, "noise", message, hint)?;
    d.set_item("heights", n.heights)?;
    d.set_item("stated", !n.noise.assumed())?;
    d.set_item("noise", n.noise.mm())?;
    d.set_item("found", n.found)?;
    d.set_item("p", n.p)?;
    d.set_item("more", n.more)?;
    d.set_item("suspects", n.suspects.clone())?;
    Ok(d)
}

/// Run the calibration as the call asks and return what it found.
fn result<'py>(
    py: Python<'py>,
    printer: &(dyn Firmware + Sync),
    source: &std::path::Path,
    c: Common,
    previous: Option<(&dyn Firmware, String)>,
    weighting: Option<Weighting>,
    compare: impl FnOnce(Python<'py>, &PrinterCalibration) -> PyResult<Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("firmware", printer.name())?;
    d.set_item("source", source.display().to_string())?;
    if c.physical {
        d.set_item("g33", py.None())?;
        d.set_item("out_dir", py.None())?;
        return physical_result(py, d, printer, source, c, previous);
    }
    let request = c.request.clone();
    let calibrated =
        interruptible(py, |_cancel| firmware::calibrate(printer, request))?.map_err(io_err)?;
    let spec = calibrated.mech.spec();
    let cal = calibrated.calibration();
    let readings = &calibrated.readings;
    let measurement = &readings.measurement;
    let (before, after) = if weighting.is_some() {
        let nominal = Params::nominal(spec);
        (
            firmware::probe_errors(
                &calibrated.mech,
                measurement,
                &nominal,
                measurement.nominal(),
                &readings.poses,
            )
            .map_err(io_err)?,
            firmware::probe_errors(
                &calibrated.mech,
                measurement,
                &cal.params,
                &cal.measurement,
                &readings.poses,
            )
            .map_err(io_err)?,
        )
    } else {
        let first = |e: &[Vec<f64>]| e.iter().map(|r| r[0]).collect::<Vec<f64>>();
        (
            first(&calibrated.study.before),
            first(&calibrated.study.after),
        )
    };
    d.set_item("free", calibrated.free_names.clone())?;
    d.set_item("termination", cal.termination.reason())?;
    d.set_item("heights", readings.poses.len())?;
    d.set_item("distances", readings.distances.len())?;
    let h = PyDict::new(py);
    h.set_item("before", figures(py, Spread::of(&before))?)?;
    h.set_item("after", figures(py, Spread::of(&after))?)?;
    d.set_item("height_errors", h)?;
    match (
        &calibrated.study.accuracy.distances,
        readings.distances.is_empty(),
    ) {
        (Some(x), false) => {
            let e = PyDict::new(py);
            let f = |max, rms| figures(py, Spread { max, rms });
            e.set_item("before", f(x.before_max, x.before_rms)?)?;
            e.set_item("after", f(x.after_max, x.after_rms)?)?;
            d.set_item("distance_errors", e)?;
        }
        _ => d.set_item("distance_errors", py.None())?,
    }
    let values = firmware::written(printer, &calibrated).map_err(io_err)?;
    d.set_item("values", value_dicts(py, &values.values)?)?;
    let warnings = PyList::empty(py);
    for w in &cal.warnings {
        warnings.append(calibration_warning(py, w)?)?;
    }
    for w in firmware::checks(printer, &calibrated, &values, c.max_sigma).map_err(io_err)? {
        warnings.append(firmware_warning(py, &w)?)?;
    }
    d.set_item("warnings", warnings)?;
    d.set_item("physical", py.None())?;
    d.set_item("report_dir", py.None())?;
    d.set_item("g33", compare(py, &calibrated)?)?;
    let text = printer
        .updated(spec, &cal.params, &cal.measurement)
        .map_err(io_err)?;
    d.set_item("updated", &text)?;
    // Every file asked for is written together, or none (all or nothing).
    let mut outputs: Vec<(PathBuf, Vec<u8>)> = vec![];
    if let Some(out) = &c.out {
        let text = firmware::out_file(
            printer,
            &text,
            &source.display().to_string(),
            calibrated.study.accuracy.poses,
            false,
        );
        outputs.push((out.clone(), text.into_bytes()));
    }
    if let Some(dir) = &c.out_dir {
        outputs.extend(out_dir_files(printer, &calibrated, source, dir));
    }
    written(|run| {
        // (Checked before any work: check_paths.)
        if let Some(dir) = &c.out_dir {
            run.files.create_dir(dir)?;
        }
        outputs
            .iter()
            .try_for_each(|(path, bytes)| run.files.stage(path, bytes))
    })?;
    d.set_item("out", c.out.as_ref().map(|p| p.display().to_string()))?;
    d.set_item(
        "out_dir",
        c.out_dir.as_ref().map(|p| p.display().to_string()),
    )?;
    Ok(d)
}

fn physical_result<'py>(
    py: Python<'py>,
    d: Bound<'py, PyDict>,
    printer: &(dyn Firmware + Sync),
    source: &std::path::Path,
    c: Common,
    previous: Option<(&dyn Firmware, String)>,
) -> PyResult<Bound<'py, PyDict>> {
    let request = c.request.clone();
    let touches = match &c.heights {
        Some(path) => Some(
            reading(|run| pkmcal_io::firmware::physical_heights::read(run, path))
                .map_err(io_err)?,
        ),
        None => None,
    };
    // A mesh count the printer's mesh cannot take is refused before the
    // fit, as the command line does (the report lists the map's nodes).
    if c.height_map.is_some() || c.report_dir.is_some() {
        physical::mesh_layout(printer, c.mesh_points).map_err(io_err)?;
    }
    let assessed = interruptible(py, |_cancel| {
        physical::assess(printer, request, touches.as_ref())
    })?
        .map_err(io_err)?
        .ok_or_else(|| {
            usage(format!(
                "physical=True models linear deltas (towers with carriages); this {} printer is a rotary delta, whose arms and their errors it has no model of: calibrate its firmware values with physical=False",
                printer.name()
            ))
        })?;
    let fit = &assessed.fit;
    let cal = &fit.study.calibration;
    let choice = &assessed.choice;
    let proj = &choice.written;
    d.set_item("free", fit.free_names.clone())?;
    d.set_item("termination", cal.termination.reason())?;
    // The probe's heights; the touches measured by hand are not among them.
    d.set_item("heights", fit.readings.poses.len() - fit.touches.0)?;
    d.set_item("distances", fit.readings.distances.len())?;
    let h = PyDict::new(py);
    h.set_item("before", figures(py, Spread::of(&assessed.heights[0]))?)?;
    h.set_item("after", figures(py, Spread::of(&assessed.heights[1]))?)?;
    d.set_item("height_errors", h)?;
    d.set_item("distance_errors", py.None())?;
    d.set_item("values", value_dicts(py, &assessed.values)?)?;
    let warnings = PyList::empty(py);
    let mut noise = py.None().into_bound(py);
    use pkmcal::identify::WarningKind;
    for w in cal.warnings.iter().filter(|w| {
        !matches!(
            w.kind,
            WarningKind::HeldByTolerance { .. } | WarningKind::PriorDominated { .. }
        )
    }) {
        match NoiseNote::of(fit, w) {
            Some(n) => {
                let n = noise_note(py, &n)?;
                noise = n.clone().into_any();
                // A typical probe scattering less than assumed is news, not
                // a fault: no warning.
                if !n
                    .get_item("hint")?
                    .is_some_and(|h| h.to_string().is_empty())
                {
                    warnings.append(n)?;
                }
            }
            None => warnings.append(calibration_warning(py, w)?)?,
        }
    }
    if let Some(w) = physical::uncertain(&assessed, c.max_sigma).map_err(io_err)? {
        warnings.append(firmware_warning(py, &w)?)?;
    }
    d.set_item("warnings", warnings)?;
    let p = PyDict::new(py);
    p.set_item("probe_noise", fit.probe_noise.mm())?;
    p.set_item("probe_noise_stated", !fit.probe_noise.assumed())?;
    p.set_item("noise_note", noise)?;
    p.set_item("projection_written", choice.projection_written)?;
    p.set_item("gain", choice.gain.to_vec())?;
    p.set_item("z_gain", choice.z_gain.to_vec())?;
    p.set_item("z_weight", choice.z_weight)?;
    p.set_item("grid_points", proj.targets.len())?;
    p.set_item("print_radius", assessed.delta.print_radius())?;
    let e = PyDict::new(py);
    e.set_item("current", summary_dict(py, &assessed.before)?)?;
    e.set_item("own", summary_dict(py, &choice.own.summary)?)?;
    e.set_item("projected", summary_dict(py, &choice.projected.summary)?)?;
    p.set_item("nozzle_errors", e)?;
    let cubes = PyList::empty(py);
    for c in &assessed.cubes {
        let x = PyDict::new(py);
        x.set_item("centre", c.centre.to_vec())?;
        x.set_item("size", c.size.to_vec())?;
        x.set_item("size_sd", c.size_sd.to_vec())?;
        x.set_item("flatness", c.flatness)?;
        x.set_item("flatness_sd", c.flatness_sd)?;
        cubes.append(x)?;
    }
    p.set_item("cubes", cubes)?;
    let unseen = PyList::empty(py);
    for u in physical_report::unseen(fit) {
        let x = PyDict::new(py);
        x.set_item("part", u.part)?;
        x.set_item("blind", u.blind)?;
        x.set_item("of", u.of)?;
        x.set_item("meaning", u.meaning)?;
        unseen.append(x)?;
    }
    p.set_item("unseen", unseen)?;
    let fw_bed = assessed.fw_bed();
    let klipper = printer.flavour().reads_object_distances();
    let next = PyList::empty(py);
    // As the command line does: where the candidates cannot be scored, the
    // values are written all the same, with no suggestion.
    let suggestions = physical_plan::suggest(fit, &assessed.fw_mech, &proj.params, fw_bed, klipper)
        .unwrap_or_default();
    for s in &suggestions {
        let x = PyDict::new(py);
        x.set_item(
            "what",
            physical_report::measurement_words(
                &s.extra,
                printer.flavour(),
                fit.delta.probe_offset,
                &crate::results::calibration::PY_WORDING,
            ),
        )?;
        let (before, after) = s.largest();
        x.set_item("largest_before", before)?;
        x.set_item("largest_after", after)?;
        x.set_item("variance_removed", s.variance_removed())?;
        next.append(x)?;
    }
    p.set_item("next_measurements", next)?;
    let drift = match previous {
        Some((prev, from)) => {
            let dr =
                pkmcal_io::firmware::physical_drift::since(prev, &assessed.own).map_err(io_err)?;
            let x = PyDict::new(py);
            x.set_item("previous", &from)?;
            x.set_item("changed", dr.joint_drift)?;
            x.set_item("chi2", dr.chi2)?;
            x.set_item("dof", dr.dof)?;
            x.set_item("p", dr.p_joint)?;
            let params = PyList::empty(py);
            for q in &dr.parameters {
                let y = PyDict::new(py);
                y.set_item("name", &q.name)?;
                y.set_item("change", q.change)?;
                y.set_item("sigma", q.sigma)?;
                y.set_item("p", q.p_value)?;
                y.set_item("changed", q.drifted)?;
                params.append(y)?;
            }
            x.set_item("parameters", params)?;
            x.set_item("untested", dr.untested.clone())?;
            p.set_item("drift", x)?;
            Some((from, dr))
        }
        None => {
            p.set_item("drift", py.None())?;
            None
        }
    };
    let src = source.display().to_string();
    // Every file asked for is written together, or none (all or nothing).
    let mut outputs: Vec<(PathBuf, Vec<u8>)> = vec![];
    match &c.height_map {
        Some(path) => {
            let Some(map) = height_map::for_printer(
                printer,
                fit,
                &assessed.fw_mech,
                &proj.params,
                fw_bed,
                &src,
                c.mesh_points,
            )
            .map_err(io_err)?
            else {
                return Err(usage(format!(
                    "{} keeps no height map pkmcal can write: leave height_map out",
                    printer.name()
                )));
            };
            outputs.push((path.clone(), map.text.clone().into_bytes()));
            let v = map.map.values();
            let x = PyDict::new(py);
            x.set_item("path", path.display().to_string())?;
            x.set_item("counts", map.layout.counts().to_vec())?;
            x.set_item("spacings", map.layout.spacings().to_vec())?;
            x.set_item("rectangular", map.layout.rect.is_some())?;
            x.set_item("radius", map.layout.radius)?;
            x.set_item("nodes", v.len())?;
            x.set_item("min", v.iter().copied().fold(f64::INFINITY, f64::min))?;
            x.set_item("max", v.iter().copied().fold(f64::NEG_INFINITY, f64::max))?;
            x.set_item("largest_sd", map.map.largest_sd())?;
            x.set_item(
                "uncertain",
                matches!(
                    physical_report::map_advice(&map.map),
                    physical_report::MapAdvice::Uncertain { .. }
                ),
            )?;
            p.set_item("height_map", x)?;
        }
        None => p.set_item("height_map", py.None())?,
    }
    d.set_item("physical", p)?;
    let fw_spec = assessed.fw_mech.spec();
    let text = printer
        .updated(fw_spec, &proj.params, &proj.bed)
        .map_err(io_err)?;
    d.set_item("updated", &text)?;
    if let Some(out) = &c.out {
        let text = firmware::out_file(
            printer,
            &text,
            &src,
            assessed.own.readings.poses.len(),
            // The header says the physical model's values only where they
            // are written (else the firmware's own fit is).
            choice.projection_written,
        );
        outputs.push((out.clone(), text.into_bytes()));
    }
    // The report for the printer's owner, as `--report-dir` writes it: its
    // page built from what is above (the command line lists as many next
    // measurements).
    let report = match &c.report_dir {
        Some(dir) => {
            let (own, fw_mech, values) = (&assessed.own, &assessed.fw_mech, &assessed.values);
            let (before, cubes) = (assessed.before, &assessed.cubes);
            let (suggestions, height_map) = (&suggestions, c.height_map.as_deref());
            let page = interruptible(py, |_cancel| {
                physical_report::Page::build(&physical_report::Inputs {
                    printer,
                    source: &src,
                    own,
                    fit,
                    fw_mech,
                    projection: proj,
                    values,
                    projected: (choice.projected.summary, choice.projection_written),
                    before: [before, choice.own.summary],
                    cubes,
                    suggestions,
                    shown: physical_plan::SHOWN,
                    drift,
                    mesh_points: c.mesh_points,
                    height_map,
                    wording: &crate::results::calibration::PY_WORDING,
                })
            })?
            .map_err(io_err)?;
            Some((dir.clone(), page))
        }
        None => None,
    };
    written(|run| {
        if let Some((dir, page)) = &report {
            physical_report::write_report_dir(run, dir, page)?;
        }
        outputs
            .iter()
            .try_for_each(|(path, bytes)| run.files.stage(path, bytes))
    })?;
    d.set_item("out", c.out.as_ref().map(|p| p.display().to_string()))?;
    d.set_item(
        "report_dir",
        c.report_dir.as_ref().map(|p| p.display().to_string()),
    )?;
    Ok(d)
}
