//! `calibrate` and `analyze`: read data, identify, validate, report.

/// `writeln!` into a `String` (which cannot fail).
macro_rules! outln {
    ($o:expr) => {{
        $o.push('\n');
    }};
    ($o:expr, $($t:tt)*) => {{
        use std::fmt::Write as _;
        let _ = writeln!($o, $($t)*);
    }};
}

use crate::io::{Csv, Description, Mech, read_description};
use crate::record::CalibrationState;
use anyhow::{Context, Result, bail};
use pkmcal::identify::{CrossValidation, Identifiability};
use pkmcal::{
    Accuracy, Calibration, CalibrationOptions, ErrorStats, Frame, Measurement, MeasurementModel,
    Mechanism, Model,
};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Read a measurement file: commands and the readings of `measurement`,
/// optional targets and standard deviations.
pub fn read_data<M: Mechanism>(
    run: &crate::Run<'_>,
    path: &Path,
    mech: &M,
    measurement: &MeasurementModel,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Measurement>> {
    let csv = Csv::read(run, path)?;
    // The file's own units line over `units` (the run's), `--units` over both.
    let units = crate::fileunits::for_file(run, units, csv.units.as_ref(), &csv.path);
    data_from(&csv, mech, measurement, &units)
}

/// [`read_data`] from an already parsed table: every pose carries its σ
/// (`sigma_<axis>` columns, any subset; or `sigma` for all readings of one
/// unit) and its origin (pose number and line in the file). Numbers are
/// converted from the file's `units` to mm and rad.
pub fn data_from<M: Mechanism>(
    csv: &Csv,
    mech: &M,
    measurement: &MeasurementModel,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Measurement>> {
    let spec = mech.spec();
    csv.require_rows()?;
    let act: Vec<String> = spec
        .actuated_names()
        .iter()
        .map(|s| s.to_string())
        .collect();
    csv.check_commands_belong(spec)?;
    use crate::fileunits as fu;
    let mut commands = csv.named(&act)?;
    fu::to_internal(&mut commands, &fu::commands(spec, units));
    let reading = fu::readings(measurement.units(), units);
    let mut measured = csv.named(measurement.axes())?;
    fu::to_internal(&mut measured, &reading);
    let target_names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let has_targets = target_names.iter().all(|n| csv.has(n));
    let targets = if has_targets {
        let mut t = csv.named(&target_names)?;
        fu::to_internal(&mut t, &fu::tool(spec, units));
        Some(t)
    } else {
        None
    };
    let mut sigma = sigma_from(csv, measurement)?;
    for row in sigma.iter_mut().flatten() {
        for (v, f) in row.iter_mut().zip(&reading) {
            if let Some(v) = v {
                *v *= f;
            }
        }
    }
    Ok(commands
        .into_iter()
        .zip(measured)
        .enumerate()
        .map(|(i, (c, m))| Measurement {
            target: targets.as_ref().map(|t| t[i].clone()),
            commands: c,
            partner: None,
            measured: m,
            sigma: sigma.as_ref().map_or(vec![], |s| s[i].clone()),
            origin: Some(pkmcal::Origin {
                pose: i + 1,
                line: Some(csv.line(i)),
                distance: false,
            }),
        })
        .collect())
}

/// Distances measured between pairs of poses (calipers on a printed object,
/// a gauge): a CSV with the commands of both poses, `<actuator>_1` and
/// `<actuator>_2` for every actuated joint, the `distance` between the tool
/// points, and optionally `sigma_distance`. Each row is numbered in its file
/// as a distance ([`pkmcal::Origin::distance`], see [`located_in`]).
pub fn read_distances<M: Mechanism>(
    run: &crate::Run<'_>,
    path: &Path,
    mech: &M,
    measurement: &MeasurementModel,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Measurement>> {
    let csv = Csv::read(run, path)?;
    let units = &crate::fileunits::for_file(run, units, csv.units.as_ref(), &csv.path);
    csv.require_rows()?;
    measurement
        .check_distances()
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let spec = mech.spec();
    let names = |k: usize| -> Vec<String> {
        spec.actuated_names()
            .iter()
            .map(|s| format!("{s}_{k}"))
            .collect()
    };
    use crate::fileunits as fu;
    let factors = fu::commands(spec, units);
    let mut a = csv.named(&names(1))?;
    fu::to_internal(&mut a, &factors);
    let mut b = csv.named(&names(2))?;
    fu::to_internal(&mut b, &factors);
    let length = fu::readings(&[pkmcal::Unit::Millimetre], units);
    let mut d = csv.named(&[pkmcal::DISTANCE_AXIS.to_string()])?;
    fu::to_internal(&mut d, &length);
    let sigma_name = format!("sigma_{}", pkmcal::DISTANCE_AXIS);
    let sigma = if csv.has(&sigma_name) {
        let mut s = csv.named(&[sigma_name])?;
        fu::to_internal(&mut s, &length);
        Some(s)
    } else {
        None
    };
    let mut out = vec![];
    for (i, ((a, b), d)) in a.into_iter().zip(b).zip(d).enumerate() {
        let sigma = match &sigma {
            Some(s) if s[i][0] <= 0.0 => bail!(
                "{}:{}: sigma_distance must be positive, got {}",
                path.display(),
                csv.line(i),
                s[i][0]
            ),
            Some(s) => vec![Some(s[i][0])],
            None => vec![],
        };
        out.push(Measurement {
            target: None,
            commands: a,
            partner: Some(b),
            measured: d,
            sigma,
            origin: Some(pkmcal::Origin {
                pose: i + 1,
                line: Some(csv.line(i)),
                distance: true,
            }),
        });
    }
    Ok(out)
}

/// [`located`] for a calibration from a measurement file and a file of
/// distances between poses: an error at a distance names that file.
pub fn located_in(e: pkmcal::Error, data: &Path, distances: Option<&Path>) -> anyhow::Error {
    match (e, distances) {
        (
            pkmcal::Error::Pose {
                pose,
                line: Some(line),
                distance: true,
                source,
            },
            Some(file),
        ) => anyhow::anyhow!("{}:{line}: distance {pose}: {source}", file.display()),
        (e, _) => located(e, data),
    }
}

/// Per-pose standard deviations of the measured coordinates: `sigma_<axis>`
/// columns (any subset; the other axes are estimated from the residuals) or
/// one `sigma` column for every axis when all axes share a unit. `None` when
/// the file has none.
pub fn sigma_from(
    csv: &Csv,
    measurement: &MeasurementModel,
) -> Result<Option<Vec<Vec<Option<f64>>>>> {
    let axes = measurement.axes();
    let nx = axes.len();
    let per_axis: Vec<(usize, String)> = axes
        .iter()
        .enumerate()
        .map(|(k, a)| (k, format!("sigma_{a}")))
        .filter(|(_, n)| csv.has(n))
        .collect();
    let unknown: Vec<&String> = csv
        .headers
        .iter()
        .filter(|h| {
            h.to_ascii_lowercase().starts_with("sigma_")
                && !per_axis.iter().any(|(_, n)| n.eq_ignore_ascii_case(h))
        })
        .collect();
    if !unknown.is_empty() {
        bail!(
            "{}: column(s) {} name nothing measured ({}); the measured readings are {} (columns sigma_{})",
            csv.path.display(),
            unknown
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            measurement.describe(),
            axes.join(", "),
            axes.join(", sigma_")
        );
    }
    let common = csv.has("sigma");
    if common && !per_axis.is_empty() {
        bail!(
            "{}: give either one `sigma` column or per-axis `sigma_<axis>` columns, not both",
            csv.path.display()
        );
    }
    let rows: Vec<Vec<Option<f64>>> = if common {
        let units = measurement.units();
        if units.iter().any(|u| *u != units[0]) {
            bail!(
                "{}: one `sigma` column cannot hold the noise of {} ({}); give per-axis columns sigma_{} (any subset; the others are estimated)",
                csv.path.display(),
                axes.join(", "),
                units
                    .iter()
                    .map(|u| u.symbol())
                    .collect::<Vec<_>>()
                    .join(", "),
                axes.join(", sigma_")
            );
        }
        csv.named(&["sigma".to_string()])?
            .into_iter()
            .map(|r| vec![Some(r[0]); nx])
            .collect()
    } else if per_axis.is_empty() {
        return Ok(None);
    } else {
        let names: Vec<String> = per_axis.iter().map(|(_, n)| n.clone()).collect();
        csv.named(&names)?
            .into_iter()
            .map(|r| {
                let mut row = vec![None; nx];
                for ((k, _), v) in per_axis.iter().zip(r) {
                    row[*k] = Some(v);
                }
                row
            })
            .collect()
    };
    for (i, r) in rows.iter().enumerate() {
        if r.iter().flatten().any(|v| *v <= 0.0) {
            bail!(
                "{}:{}: standard deviations must be positive, got {}",
                csv.path.display(),
                csv.line(i),
                r.iter()
                    .flatten()
                    .map(|v| v.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    Ok(Some(rows))
}

/// A library error, located in `file` when it names a pose that came from it.
pub fn located(e: pkmcal::Error, file: &Path) -> anyhow::Error {
    match e {
        pkmcal::Error::Pose {
            pose,
            line: Some(line),
            distance: false,
            source,
        } => anyhow::anyhow!("{}:{line}: pose {pose}: {source}", file.display()),
        e => anyhow::Error::new(e).context(format!("calibrating from {}", file.display())),
    }
}

/// The free set from `--free` and `--fix` (comma-separated names, `all`,
/// `default`), resolved by the library ([`pkmcal::identify::resolve_free_set`])
/// and worded for the command line: a name it does not know is a usage
/// error naming the option.
/// A parameter with a prior (a tolerance) is free unless `--fix` names it
/// ([`pkmcal::identify::free_with_priors`]).
pub fn free_set<M: Mechanism>(
    mech: &M,
    measurement: &MeasurementModel,
    free: Option<&str>,
    fix: Option<&str>,
    priors: &[pkmcal::identify::Prior],
) -> Result<Vec<usize>> {
    let spec = mech.spec();
    let set = free_set_with_default(spec, measurement, &spec.default_free, free, fix)?;
    let fix: Vec<String> = fix
        .map(|s| s.split(',').map(|t| t.trim().to_string()).collect())
        .unwrap_or_default();
    Ok(pkmcal::identify::free_with_priors(
        spec,
        measurement,
        &set,
        priors,
        &fix,
    ))
}

/// [`free_set`] with another default set (a firmware's own).
pub fn free_set_with_default(
    spec: &pkmcal::Spec,
    measurement: &MeasurementModel,
    default: &[String],
    free: Option<&str>,
    fix: Option<&str>,
) -> Result<Vec<usize>> {
    use pkmcal::identify::{FreeSetError, NameList};
    let names = |s: &str| -> Vec<String> { s.split(',').map(|t| t.trim().to_string()).collect() };
    let flag = |l: NameList| match l {
        NameList::Free => "--free",
        NameList::Fix => "--fix",
    };
    let free = free.map(names);
    let fix = fix.map(names).unwrap_or_default();
    pkmcal::identify::resolve_free_set(spec, measurement, default, free.as_deref(), &fix).map_err(
        |e| {
            crate::output::Usage(match e {
                FreeSetError::Unknown { list, error } => {
                    format!("in {}: {error}", flag(list))
                }
                FreeSetError::FrameParameter { list, name } => format!(
                    "in {}: `{name}` belongs to the instrument frame, which --frame sets (free: identified; base: the data are in the base frame)",
                    flag(list)
                ),
                FreeSetError::Empty => {
                    "no parameter is left free; name some with --free".to_string()
                }
            })
            .into()
        },
    )
}

/// A warning's hint in the command line's terms: the library's hints name
/// no option; where a hint is an option to give, it is named here.
pub fn cli_hint(w: &pkmcal::identify::Warning) -> String {
    use pkmcal::identify::WarningKind as K;
    match &w.kind {
        K::StiffnessRatios { fixed } => format!(
            "give `{fixed}` its measured value (--start P.toml), or calibrate with a known tool load (--load)"
        ),
        K::PlanRankDeficient { .. } => {
            "plan more poses (--count), or identify fewer parameters (--fix); `pkmcal analyze` on the planned poses names the combinations that cannot be identified".into()
        }
        K::FrameGauge { .. } => "to choose which parameters define the base frame, fix them yourself (--fix NAMES), or measure in the base frame (--frame base); the combinations are listed under identifiability".into(),
        K::Outliers {
            robust_loss: true,
            dropping: false,
            ..
        } => "the robust loss already limits their influence; inspect them, or refit without them (--drop-outliers)".into(),
        _ => w.hint.clone(),
    }
}

/// Where the instrument stands, as a user says it (`--frame`): the library's
/// frame rule ([`pkmcal::requested_frame`]) decides the rest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameChoice {
    /// Free for whole positions and target points unless the data file
    /// says `# frame: base`; the base frame otherwise.
    Auto,
    /// An instrument frame identified with the rest.
    Free,
    /// The data are in the base frame.
    Base,
}

impl FrameChoice {
    /// The names a front end takes, in order.
    pub const NAMES: [&str; 3] = ["auto", "free", "base"];
}

impl std::str::FromStr for FrameChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(FrameChoice::Auto),
            "free" => Ok(FrameChoice::Free),
            "base" => Ok(FrameChoice::Base),
            _ => Err(format!("unknown frame `{s}`; one of auto, free, base")),
        }
    }
}

/// Validation results in the report.
#[derive(Serialize, Clone)]
pub struct Validation {
    /// Where the validation poses came from.
    pub source: String,
    /// Before/after on the validation poses.
    pub accuracy: Accuracy,
}

/// The JSON report of `calibrate` (and of Python's `Calibration.save`): a
/// versioned calibration record ([`pkmcal::identify::CalibrationRecord`]
/// reads it back) with everything a reader wants to see, and in `state` the
/// whole calibration ([`crate::record`]).
#[derive(Serialize)]
pub struct Report<'a> {
    /// [`pkmcal::identify::CALIBRATION_FORMAT`].
    pub format: &'static str,
    /// [`pkmcal::identify::CALIBRATION_VERSION`].
    pub version: u32,
    pub pkmcal_version: &'static str,
    pub mechanism: String,
    /// [`pkmcal::identify::mechanism_identity`] of the mechanism.
    pub mechanism_identity: String,
    pub data: String,
    /// What the instrument read.
    pub measurement: pkmcal::MeasurementSummary,
    #[serde(flatten)]
    pub calibration: &'a Calibration,
    pub accuracy: &'a Accuracy,
    pub validation: Option<Validation>,
    pub cross_validation: &'a Option<CrossValidation>,
    /// The whole calibration, to read it back ([`crate::record`]).
    #[serde(serialize_with = "write_state")]
    pub state: &'a CalibrationState,
}

fn write_state<S: serde::Serializer>(
    state: &&CalibrationState,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    crate::record::state_to_json(state)
        .map_err(|e| serde::ser::Error::custom(format!("{e:#}")))?
        .serialize(s)
}

impl<'a> Report<'a> {
    /// The report of the calibration `state` of the mechanism `spec` from
    /// `data` (a file's name, or a description of arrays); `validation`
    /// words where the validation poses came from.
    pub fn new(
        spec: &pkmcal::Spec,
        data: String,
        state: &'a CalibrationState,
        validation: impl Fn(pkmcal::identify::ValidationSource) -> String,
    ) -> Self {
        let study = &state.study;
        Report {
            format: pkmcal::identify::CALIBRATION_FORMAT,
            version: pkmcal::identify::CALIBRATION_VERSION,
            pkmcal_version: env!("CARGO_PKG_VERSION"),
            mechanism: spec.name.clone(),
            mechanism_identity: pkmcal::identify::mechanism_identity(spec),
            data,
            measurement: state.measurement.summary(),
            calibration: &study.calibration,
            accuracy: &study.accuracy,
            validation: study.validation.as_ref().map(|v| Validation {
                source: validation(v.source),
                accuracy: v.accuracy.clone(),
            }),
            cross_validation: &study.cross_validation,
            state,
        }
    }

    /// The report as JSON text (the calibration record's file).
    pub fn to_json(&self) -> Result<String> {
        Ok(serde_json::to_string_pretty(self)?)
    }
}

/// Arguments of `calibrate`, already parsed by clap.
pub struct CalibrateConfig {
    pub mechanism: Option<PathBuf>,
    pub data: PathBuf,
    pub model: Model,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub start: Option<PathBuf>,
    /// The tool load (`--load`), one value per tool axis; empty for none.
    pub load: Vec<f64>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
    pub validate: Option<PathBuf>,
    pub holdout: Option<f64>,
    pub seed: u64,
    pub kfold: Option<usize>,
    pub report_dir: Option<PathBuf>,
    pub setup: Option<PathBuf>,
    pub loss: pkmcal::Loss,
    pub outlier_threshold: f64,
    pub drop_outliers: bool,
    /// Where the instrument stands (`--frame`).
    pub frame: FrameChoice,
    /// `--axes`: the tool axes measured, when not all.
    pub axes: Option<String>,
    /// `--distances`: distances measured between pairs of poses.
    pub distances: Option<PathBuf>,
    /// `--tolerance NAME=SIGMA` items: priors beside the mechanism file's
    /// `[tolerances]` table.
    pub tolerances: Vec<String>,
    /// `--no-tolerances`: fit without priors.
    pub no_tolerances: bool,
    /// `--stated-noise` (and `--stated-angle-noise`): the instrument's
    /// stated noise, a prior of the estimate and the adequacy test's
    /// reference; `--stated-readings`: what it is worth.
    pub stated_noise: Option<pkmcal::Noise>,
    /// `--stated-distance-noise`: the stated noise of `--distances`' readings.
    pub stated_distance_noise: Option<f64>,
    pub stated_readings: f64,
    /// `--stated-relative`: only the stated noises' ratios are known.
    pub stated_relative: bool,
}

/// The measurement model of a data file, from its columns: the whole tool
/// (`x, y, …`), target points (`t1x …`, from the mechanism file's
/// `[[target]]`s), ball-bar readings (`d1 …`, with `setup` or the mechanism
/// file's `[ballbar]`), or the tool axes named by `axes` (e.g. only `z`;
/// a file missing a tool column without `--axes` is an error, not a
/// subset). The frame:
/// `--frame free` (identified), `base`, or `auto` (free for positions unless
/// the file says `# frame: base`; base for readings that do not fix a frame,
/// a subset of axes or bar lengths).
pub fn measurement_of(
    run: &crate::Run<'_>,
    csv: &Csv,
    description: &Description,
    setup: Option<&Path>,
    frame: FrameChoice,
    axes: Option<&str>,
) -> Result<MeasurementModel> {
    let spec = description.mech.spec();
    // Regardless of case, as every column is found.
    let has = |h: &str| csv.has(h);
    let whole = spec.tool_axes.iter().all(|a| has(a));
    let some: Vec<&String> = spec.tool_axes.iter().filter(|a| has(a)).collect();
    let file = csv.path.display();
    let m = if let Some(axes) = axes {
        let names: Vec<&str> = axes.split(',').map(str::trim).collect();
        MeasurementModel::tool_axes(spec, &names)
            .map_err(|e| crate::output::Usage(format!("in --axes: {e}")))?
    } else if whole {
        MeasurementModel::tool(spec)
    } else if has("probe") {
        MeasurementModel::probe(spec).with_context(|| format!("probe heights in {file}"))?
    } else if has("t1x") {
        let t = &description.targets;
        if t.is_empty() {
            bail!(
                "{file} holds target-point positions (t1x…); describe the targets in the mechanism file: [[target]] at = [x, y, z] (tool frame, mm)"
            );
        }
        MeasurementModel::targets(spec, t).with_context(|| format!("targets for {file}"))?
    } else if has("d1") {
        let setup = crate::io::read_setup(run, setup, description)?.with_context(|| {
            format!(
                "{file} holds ball-bar distances (d1…); give the socket positions with --setup S.toml (or a [ballbar] table in the mechanism file)"
            )
        })?;
        MeasurementModel::ball_bar(spec, &setup).with_context(|| format!("ball bar for {file}"))?
    } else if !some.is_empty() {
        let missing: Vec<&String> = spec.tool_axes.iter().filter(|a| !has(a)).collect();
        bail!(
            "{file}: missing column{} `{}`; if the instrument measured only {}, say so with --axes {}",
            if missing.len() > 1 { "s" } else { "" },
            missing
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join("`, `"),
            some.iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            some.iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(",")
        );
    } else {
        bail!(
            "{file} has no measured columns: give the tool coordinates ({}), some of them, target points (t1x, t1y, …) or ball-bar readings (d1, d2, …)",
            spec.tool_axes.join(", ")
        );
    };
    // The frame rule is the library's; the words are the command line's.
    let request = match frame {
        FrameChoice::Free => pkmcal::FrameRequest::Free,
        FrameChoice::Base => pkmcal::FrameRequest::Base,
        FrameChoice::Auto => pkmcal::FrameRequest::Auto {
            data_in_base: csv.base_frame,
        },
    };
    match pkmcal::requested_frame(&m, spec, request) {
        Ok(None) => Ok(m),
        Ok(Some(f)) => Ok(m.in_frame(f)?),
        Err(pkmcal::FrameRequestError::Probe) => crate::output::usage(
            "--frame free: probed heights fix no instrument frame; the bed plane's height and tilts are the parameters bed.z, bed.rx, bed.ry (free them with --free default,bed.rx,bed.ry)",
        ),
        Err(pkmcal::FrameRequestError::PartialAxes { axes }) => crate::output::usage(format!(
            "--frame free needs whole positions to register the instrument frame; {file} reads only {}",
            axes.join(", ")
        )),
        Err(pkmcal::FrameRequestError::BallBar) => crate::output::usage(
            "--frame free: a ball bar's sockets are in the base frame; drop --frame",
        ),
    }
}

/// What `calibrate` and `analyze` read first: the mechanism, the data file,
/// its measurement model and its poses.
struct Measured {
    mech: Mech,
    source: crate::record::MechanismSource,
    measurement: MeasurementModel,
    data: Vec<Measurement>,
    units: pkmcal::FileUnits,
    /// The mechanism file and its `[tolerances]` table.
    path: Option<PathBuf>,
    tolerances: Vec<(String, pkmcal::apply::budget::Tolerance)>,
}

fn read_measured(
    run: &crate::Run<'_>,
    mechanism: Option<&Path>,
    data: &Path,
    setup: Option<&Path>,
    frame: FrameChoice,
    axes: Option<&str>,
) -> Result<Measured> {
    let description = read_description(run, mechanism)?;
    let csv = Csv::read(run, data)?;
    let measurement = measurement_of(run, &csv, &description, setup, frame, axes)?;
    let units = crate::fileunits::of(run, &description);
    let file_units = crate::fileunits::for_file(run, &units, csv.units.as_ref(), &csv.path);
    let mech = description.mech;
    let source = description.source;
    let data = data_from(&csv, &mech, &measurement, &file_units)?;
    crate::hints::check_data(&mech, &measurement, &data, &file_units, &csv.path)?;
    Ok(Measured {
        mech,
        source,
        measurement,
        data,
        units,
        path: description.path,
        tolerances: description.tolerances,
    })
}

pub fn run_calibrate(run: &crate::Run<'_>, c: CalibrateConfig) -> Result<()> {
    let Measured {
        mech,
        source,
        measurement,
        data: all,
        units,
        path,
        tolerances,
    } = read_measured(
        run,
        c.mechanism.as_deref(),
        &c.data,
        c.setup.as_deref(),
        c.frame,
        c.axes.as_deref(),
    )?;
    let spec = mech.spec();
    let mech = &mech;
    let start = crate::io::params_or_nominal(run, c.start.as_deref(), mech)?;
    let pairs = match &c.distances {
        Some(p) => read_distances(run, p, mech, &measurement, &units)?,
        None => vec![],
    };
    let locate = |e: pkmcal::Error| located_in(e, &c.data, c.distances.as_deref());
    let mut opts = CalibrationOptions::new(spec, c.model);
    (opts.priors, opts.free) = crate::budget::priors_and_free(
        mech,
        &measurement,
        &crate::budget::Tolerances {
            table: &tolerances,
            file: path.as_deref(),
            items: &c.tolerances,
            off: c.no_tolerances,
        },
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    opts.stated_noise = c.stated_noise;
    opts.stated_distance_noise = c.stated_distance_noise;
    opts.stated_noise_readings = c.stated_readings;
    opts.stated_noise_relative = c.stated_relative;
    opts.force = crate::io::checked_load(c.load.clone(), mech, &start)?;
    opts.loss = c.loss;
    opts.outlier_threshold = c.outlier_threshold;
    opts.drop_outliers = c.drop_outliers;
    let validation_plan = match (&c.validate, c.holdout) {
        (Some(_), Some(_)) => {
            return crate::output::usage("give either --validate FILE or --holdout F, not both");
        }
        (Some(v), None) => {
            pkmcal::identify::ValidationPlan::Given(read_data(run, v, mech, &measurement, &units)?)
        }
        (None, Some(f)) => pkmcal::identify::ValidationPlan::Holdout(f),
        (None, None) => pkmcal::identify::ValidationPlan::None,
    };
    let study_opts = pkmcal::identify::StudyOptions {
        calibration: opts,
        validation: validation_plan,
        kfold: c.kfold,
        seed: c.seed,
    };
    let bar = run.bar(c.kfold.unwrap_or(0) as u64, c.kfold.is_none(), "folds", 1);
    // Every pose carries its data-file number and line, so errors, outliers
    // and dropped poses name them without translation.
    let study = pkmcal::identify::study(
        mech,
        &measurement,
        &all,
        pairs,
        &start,
        &study_opts,
        &|| bar.inc(1),
    )
    .map_err(|e| {
        use pkmcal::identify::StudyStage;
        match (e.stage, &c.validate) {
            (StudyStage::Fit, _) => locate(e.error),
            (StudyStage::Validation, Some(v)) => located(e.error, v),
            (StudyStage::Validation, None) => located(e.error, &c.data),
            _ => anyhow::Error::from(e.error),
        }
    })?;
    bar.finish();
    let state = CalibrationState {
        mechanism: source,
        measurement,
        study,
    };
    let (measurement, study) = (&state.measurement, &state.study);
    let cal = &study.calibration;
    let header = format!(
        "pkmcal {} calibration ({} model) of {} from {}\nsolver: {}",
        env!("CARGO_PKG_VERSION"),
        c.model.name(),
        spec.name,
        c.data.display(),
        cal.termination_reason
    );
    run.files.stage(
        &c.out,
        crate::io::params_to_string(spec, &cal.params, &header).as_bytes(),
    )?;
    let (before, after, kept) = (&study.before, &study.after, &study.poses);
    let report = Report::new(spec, c.data.display().to_string(), &state, |source| match (
        source,
        &c.validate,
    ) {
        (pkmcal::identify::ValidationSource::Given, Some(p)) => p.display().to_string(),
        (pkmcal::identify::ValidationSource::Given, None) => "validation poses".to_string(),
        (pkmcal::identify::ValidationSource::HeldOut { count, seed }, _) => format!(
            "{count} held-out poses of {} (seed {seed})",
            c.data.display()
        ),
    });
    if let Some(r) = &c.report {
        run.files.stage(r, report.to_json()?.as_bytes())?;
    }
    if let Some(dir) = &c.report_dir {
        crate::report::write_report_dir(
            run,
            dir,
            &crate::report::ReportInputs {
                report: &report,
                mech,
                measurement,
                data: kept,
                before,
                after,
            },
        )?;
    }
    let mut summary = String::new();
    write_summary(&mut summary, &report, measurement, &CLI_WORDING);
    print!("{summary}");
    println!();
    println!("identified parameters -> {}", c.out.display());
    if let Some(r) = &c.report {
        println!("report -> {}", r.display());
    }
    if let Some(d) = &c.report_dir {
        println!("figures and report.html -> {}", d.display());
    }
    Ok(())
}

/// Display factor and symbol of an error column: lengths in mm, angles in
/// mrad (so that micro-radian errors do not print as 0.0000).
pub fn column_unit(u: pkmcal::Unit) -> (f64, &'static str) {
    match u {
        pkmcal::Unit::Radian => (1e3, "mrad"),
        u => (1.0, u.symbol()),
    }
}

/// Width of the one-line table of [`print_stats`] for these axes: beyond
/// [`MAX_TABLE_WIDTH`] (a 6-DOF tool: 250 characters) each row's ranges per
/// axis go on lines of their own under it.
fn table_width(units: &[pkmcal::Unit]) -> usize {
    26 + 22 * units.len()
        + if units.contains(&pkmcal::Unit::Millimetre) {
            44
        } else {
            0
        }
        + if units.contains(&pkmcal::Unit::Radian) {
            22
        } else {
            0
        }
}

/// The widest accuracy table printed on one line per row.
const MAX_TABLE_WIDTH: usize = 140;

pub fn write_stats_header(out: &mut String, axes: &[String], units: &[pkmcal::Unit]) {
    let mut h = format!("  {:<24}", "errors");
    let stacked = table_width(units) > MAX_TABLE_WIDTH;
    for (a, u) in axes.iter().zip(units).filter(|_| !stacked) {
        let a = a.to_uppercase();
        let sym = column_unit(*u).1;
        h.push_str(&format!(
            " {:>10} {:>10}",
            format!("{a}min {sym}"),
            format!("{a}max {sym}")
        ));
    }
    let lengths = units.contains(&pkmcal::Unit::Millimetre);
    if lengths {
        for t in ["dmin", "dmean", "drms", "dmax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mm")));
        }
    }
    if units.contains(&pkmcal::Unit::Radian) {
        for t in ["arms", "amax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mrad")));
        }
    }
    if stacked {
        h.push_str("   (range of each axis below each row)");
    }
    outln!(out, "{h}");
}

pub fn write_stats(out: &mut String, label: &str, s: &ErrorStats) {
    write_stats_of(out, label, s, None);
}

/// [`print_stats`] with the axes' names (for the ranges printed under a
/// row of a wide table); `None` names them X, Y, … by position.
pub fn write_stats_of(out: &mut String, label: &str, s: &ErrorStats, axes: Option<&[String]>) {
    let stacked = table_width(&s.axis_units) > MAX_TABLE_WIDTH;
    let mut row = format!("  {label:<24}");
    if !stacked {
        for ((a, b), u) in s.axis_min.iter().zip(&s.axis_max).zip(&s.axis_units) {
            let f = column_unit(*u).0;
            row.push_str(&format!(" {:>10.4} {:>10.4}", a * f, b * f));
        }
    }
    if s.axis_units.contains(&pkmcal::Unit::Millimetre) {
        for v in [
            s.distance_min,
            s.distance_mean,
            s.distance_rms,
            s.distance_max,
        ] {
            row.push_str(&format!(" {v:>10.4}"));
        }
    }
    if let (Some(r), Some(m)) = (s.angle_rms, s.angle_max) {
        row.push_str(&format!(" {:>10.4} {:>10.4}", r * 1e3, m * 1e3));
    }
    outln!(out, "{row}");
    if stacked {
        // One line per unit: the lengths, then the angles.
        for unit in [pkmcal::Unit::Millimetre, pkmcal::Unit::Radian] {
            let (f, sym) = column_unit(unit);
            let parts: Vec<String> = (0..s.axis_units.len())
                .filter(|&k| s.axis_units[k] == unit)
                .map(|k| {
                    let name = axes
                        .and_then(|a| a.get(k))
                        .map_or_else(|| format!("axis {}", k + 1), |a| a.to_uppercase());
                    format!("{name} {:.4} … {:.4}", s.axis_min[k] * f, s.axis_max[k] * f)
                })
                .collect();
            // At most three axes a line (a tracker's three target points
            // give nine length axes).
            let lines = parts.len().div_ceil(3);
            for (k, chunk) in parts.chunks(3).enumerate() {
                let end = if k + 1 == lines {
                    format!(" {sym}")
                } else {
                    String::new()
                };
                outln!(out, "    {}{end}", chunk.join("   "));
            }
        }
    }
}

/// Values with their units, each in a readable scale (µm, µrad…).
pub fn with_units(values: &[f64], units: &[pkmcal::Unit]) -> String {
    values
        .iter()
        .zip(units)
        .map(|(v, u)| {
            let (f, sym) = u.readable(*v);
            format!("{:.3} {sym}", v * f)
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The instrument frame in words, when the data were measured from one.
pub fn frame_text(
    cal: &Calibration,
    measurement: &MeasurementModel,
    wording: &Wording,
) -> Option<String> {
    cal.frame.as_ref()?;
    let names = &measurement.param_names()[measurement.frame_range()];
    let rows: Vec<String> = cal
        .parameters
        .iter()
        .filter(|p| p.kind == pkmcal::ParamKind::Instrument && names.contains(&p.name))
        .map(|p| {
            let (f, sym) = match p.unit {
                pkmcal::Unit::Radian => (1e3, "mrad"),
                u => (1.0, u.symbol()),
            };
            if p.free {
                format!(
                    "{} {:.4} ± {:.2e} {sym}",
                    p.name,
                    p.identified * f,
                    p.std_dev * f
                )
            } else {
                format!("{} {:.4} {sym} (fixed)", p.name, p.identified * f)
            }
        })
        .collect();
    Some(format!(
        "instrument frame in the base frame ({}): {}",
        if *measurement.frame() == Frame::Free {
            wording.frame_base
        } else {
            "given"
        },
        rows.join(", ")
    ))
}

/// A noise group in words: its σ (estimated or given) and residual RMS.
pub fn noise_text(g: &pkmcal::NoiseGroup) -> String {
    let (f, sym) = g.unit.readable(g.sigma);
    format!(
        "noise of {} ({}, {} coordinates): σ {:.3} {sym} {}; residual RMS {:.3} {sym}",
        g.unit.group_name(),
        g.axes.join(", "),
        g.count,
        g.sigma * f,
        match (g.estimated, g.stated, g.stated_readings) {
            (true, Some(s0), Some(nu)) if g.stated_relative => format!(
                "estimated from the residuals and its stated share {:.3} {sym} of their common scale (worth {nu} readings)",
                s0 * f
            ),
            (true, Some(s0), Some(nu)) => format!(
                "estimated from the residuals and the stated {:.3} {sym} (worth {nu} readings)",
                s0 * f
            ),
            (true, ..) => "estimated from the residuals".to_string(),
            _ => "given in the data".to_string(),
        },
        g.residual_rms * f
    )
}

/// One line per noise group.
pub fn write_noise(out: &mut String, groups: &[pkmcal::NoiseGroup]) {
    for g in groups {
        outln!(out, "  {}", noise_text(g));
    }
}

/// The condition number in words: with unidentifiable directions, that of
/// the identifiable ones (the full one is infinite).
pub fn condition_text(id: &Identifiability) -> String {
    let n = id.singular_values.len();
    if id.rank == 0 || id.rank >= n {
        return format!("condition number {:.3e}", id.condition_number);
    }
    let c = id.singular_values[0] / id.singular_values[id.rank - 1];
    format!(
        "condition number {c:.3e} over the {} ({} unidentifiable)",
        crate::io::count(id.rank, "identifiable direction", "identifiable directions"),
        n - id.rank
    )
}

/// The identifiability summary; `fixed` says what happened to the parameter
/// named for each unidentifiable direction ("fixed", "calibrate fixes").
pub fn write_identifiability(out: &mut String, id: &Identifiability, fixed: &str, all_in: &str) {
    outln!(
        out,
        "identifiability: rank {} of {} free, {}",
        id.rank,
        id.singular_values.len(),
        condition_text(id)
    );
    let o = &id.observability;
    outln!(
        out,
        "  observability O1 {:.4e}  O2 {:.4e}  O3 {:.4e}  O4 {:.4e}  O5 {:.4e}",
        o.o1,
        o.o2,
        o.o3,
        o.o4,
        o.o5
    );
    for u in &id.unidentifiable {
        match &u.fixed {
            Some(f) => outln!(out, "  unidentifiable: {}  -> {fixed} {f}", u.combination),
            None => outln!(out, "  unidentifiable: {}", u.combination),
        }
    }
    write_correlations(out, &id.correlations, "correlated", all_in);
}

/// Pairs of correlated parameters printed before the rest are only counted
/// (a hexapod with every joint centre free has over a hundred).
const PRINTED_CORRELATIONS: usize = 10;

/// The strongest correlations (largest |r| first), at most
/// [`PRINTED_CORRELATIONS`], and how many more the reports hold.
fn write_correlations(
    out: &mut String,
    all: &[pkmcal::identify::Correlation],
    label: &str,
    all_in: &str,
) {
    let mut sorted: Vec<&pkmcal::identify::Correlation> = all.iter().collect();
    sorted.sort_by(|a, b| b.r.abs().total_cmp(&a.r.abs()));
    for c in sorted.iter().take(PRINTED_CORRELATIONS) {
        outln!(out, "  {label}: {} and {} (r = {:+.3})", c.a, c.b, c.r);
    }
    if sorted.len() > PRINTED_CORRELATIONS {
        outln!(
            out,
            "  {label}: {} more pairs with |r| > {} (all of them in {all_in})",
            sorted.len() - PRINTED_CORRELATIONS,
            pkmcal::identify::CORRELATION_REPORT
        );
    }
}

/// The summary of a calibration as text, in `wording`'s words.
pub fn write_summary(
    out: &mut String,
    r: &Report,
    measurement: &MeasurementModel,
    wording: &Wording,
) {
    let (axes, units) = (measurement.axes(), measurement.units());
    let cal = r.calibration;
    outln!(
        out,
        "calibration of {} from {} ({} poses{}, {} model)",
        r.mechanism,
        r.data,
        cal.poses,
        if cal.distances > 0 {
            format!(" and {} distances between poses", cal.distances)
        } else {
            String::new()
        },
        cal.model.name()
    );
    outln!(
        out,
        "{} after {} iterations ({} evaluations); σ of unit weight {:.3}",
        cal.termination_reason,
        cal.iterations,
        cal.evaluations,
        cal.unit_weight_sigma
    );
    write_noise(out, &cal.noise);
    outln!(out);
    let width = cal
        .parameters
        .iter()
        .filter(|p| p.free || p.note.is_some())
        .map(|p| p.name.chars().count())
        .fold(6, usize::max);
    // With priors: each one's tolerance and the share of the information
    // that came from the data.
    let priors = !cal.priors.is_empty();
    outln!(
        out,
        "  {:<width$} {:>14} {:>16} {:>14} {:>12} {:<8}{}",
        "param",
        "nominal",
        "identified",
        "change",
        "±σ",
        "unit",
        if priors {
            format!(" {:>10} {:>9}", "tolerance", "from data")
        } else {
            String::new()
        }
    );
    for p in &cal.parameters {
        if p.free || p.note.is_some() {
            let prior = match (priors, p.tolerance) {
                (false, _) => String::new(),
                (true, None) => format!(" {:>10} {:>9}", "", ""),
                (true, Some(t)) => format!(
                    " {:>10.3e} {:>9}",
                    t,
                    p.from_data
                        .map_or_else(String::new, |f| format!("{:.0} %", 100.0 * f))
                ),
            };
            outln!(
                out,
                "  {:<width$} {:>14.6} {:>16.8} {:>+14.6e} {:>12.3e} {:<8}{}{}",
                p.name,
                p.nominal,
                p.identified,
                p.change,
                p.std_dev,
                p.unit,
                prior,
                p.note
                    .as_deref()
                    .map(|n| format!(" ({n})"))
                    .unwrap_or_default()
            );
        }
    }
    let fixed: Vec<&str> = cal
        .parameters
        .iter()
        .filter(|p| !p.free && p.note.is_none())
        .map(|p| p.name.as_str())
        .collect();
    outln!(out, "  fixed: {}", fixed.join(" "));
    if let Some(text) = frame_text(cal, measurement, wording) {
        outln!(out, "  {text}");
    }
    outln!(out);
    write_identifiability(out, &cal.identifiability, "fixed", wording.all_correlations);
    write_correlations(
        out,
        &cal.correlations,
        "correlated at the solution",
        wording.all_correlations,
    );
    outln!(out);
    write_stats_header(out, axes, units);
    write_stats_of(out, "calibration, before", &r.accuracy.before, Some(axes));
    write_stats_of(out, "calibration, after", &r.accuracy.after, Some(axes));
    outln!(
        out,
        "  improvement: max {:.1} %, RMS {:.1} %",
        r.accuracy.improvement_max_percent,
        r.accuracy.improvement_rms_percent
    );
    if let Some(d) = &r.accuracy.distances {
        write_distances(out, d);
    }
    if let Some(v) = &r.validation {
        outln!(out, "  validation: {}", v.source);
        write_stats_of(out, "validation, before", &v.accuracy.before, Some(axes));
        write_stats_of(out, "validation, after", &v.accuracy.after, Some(axes));
        outln!(
            out,
            "  improvement: max {:.1} %, RMS {:.1} %",
            v.accuracy.improvement_max_percent,
            v.accuracy.improvement_rms_percent
        );
    }
    if let Some(cv) = &r.cross_validation {
        outln!(
            out,
            "  {}-fold cross-validation: held-out RMS per fold {}",
            cv.folds,
            cv.fold_rms
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        write_stats_of(out, "cross-validation pooled", &cv.pooled, Some(axes));
    }
    if cal.loss != pkmcal::Loss::Squared {
        outln!(out, "  loss {:?}", cal.loss);
    }
    for o in &cal.outliers {
        outln!(
            out,
            "  outlier: {} residual {} ({:.1} robust σ){}",
            o.origin,
            with_units(&o.residual, &o.units),
            o.standardized,
            if cal.dropped.contains(&o.origin) {
                ", dropped"
            } else {
                ""
            }
        );
    }
    for w in &cal.warnings {
        outln!(out, "warning: {}\n  hint: {}", w.message, (wording.hint)(w));
    }
}

/// Errors of the distances between poses, before and after.
pub fn write_distances(out: &mut String, d: &pkmcal::DistanceAccuracy) {
    outln!(
        out,
        "  {} distances between poses: error max {:.4} mm, RMS {:.4} mm before; max {:.4} mm, RMS {:.4} mm after",
        d.count,
        d.before_max,
        d.before_rms,
        d.after_max,
        d.after_rms
    );
}

/// How a front end words a summary: where it keeps what the text leaves
/// out, and its hints.
pub struct Wording {
    /// After an identified instrument frame: how to say the data are in the
    /// base frame.
    pub frame_base: &'static str,
    /// Where every correlated pair is listed.
    pub all_correlations: &'static str,
    /// A warning's hint.
    pub hint: fn(&pkmcal::identify::Warning) -> String,
}

/// The command line's words.
pub const CLI_WORDING: Wording = Wording {
    frame_base: "identified; --frame base if the data are in the base frame",
    all_correlations: "--report's JSON",
    hint: cli_hint,
};

/// Print what [`write_stats_header`] writes.
pub fn print_stats_header(axes: &[String], units: &[pkmcal::Unit]) {
    let mut o = String::new();
    write_stats_header(&mut o, axes, units);
    print!("{o}");
}

/// Print what [`write_stats`] writes.
pub fn print_stats(label: &str, s: &ErrorStats) {
    let mut o = String::new();
    write_stats(&mut o, label, s);
    print!("{o}");
}

/// Print what [`write_noise`] writes.
pub fn print_noise(groups: &[pkmcal::NoiseGroup]) {
    let mut o = String::new();
    write_noise(&mut o, groups);
    print!("{o}");
}

/// Print what [`write_identifiability`] writes, in the command line's words.
pub fn print_identifiability(id: &Identifiability, fixed: &str) {
    let mut o = String::new();
    write_identifiability(&mut o, id, fixed, CLI_WORDING.all_correlations);
    print!("{o}");
}

/// Print what [`write_distances`] writes.
pub fn print_distances(d: &pkmcal::DistanceAccuracy) {
    let mut o = String::new();
    write_distances(&mut o, d);
    print!("{o}");
}

pub struct AnalyzeConfig {
    pub mechanism: Option<PathBuf>,
    pub data: PathBuf,
    pub model: Model,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub params: Option<PathBuf>,
    /// The tool load (`--load`), one value per tool axis; empty for none.
    pub load: Vec<f64>,
    pub report: Option<PathBuf>,
    pub setup: Option<PathBuf>,
    /// Where the instrument stands (`--frame`).
    pub frame: FrameChoice,
    /// `--axes`: the tool axes measured, when not all.
    pub axes: Option<String>,
    /// `--distances`: distances measured between pairs of poses.
    pub distances: Option<PathBuf>,
    /// Priors (`--tolerance`, the file's table unless `--no-tolerances`) and
    /// the instrument's noise the readings are weighed with against them.
    pub tolerances: Vec<String>,
    pub no_tolerances: bool,
    pub noise: f64,
    pub angle_noise: Option<f64>,
}

pub fn run_analyze(run: &crate::Run<'_>, c: AnalyzeConfig) -> Result<()> {
    let Measured {
        mech,
        measurement,
        data,
        units,
        path,
        tolerances,
        ..
    } = read_measured(
        run,
        c.mechanism.as_deref(),
        &c.data,
        c.setup.as_deref(),
        c.frame,
        c.axes.as_deref(),
    )?;
    let mech = &mech;
    let spec = mech.spec();
    let params = crate::io::params_or_nominal(run, c.params.as_deref(), mech)?;
    let (priors, free) = crate::budget::priors_and_free(
        mech,
        &measurement,
        &crate::budget::Tolerances {
            table: &tolerances,
            file: path.as_deref(),
            items: &c.tolerances,
            off: c.no_tolerances,
        },
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    let force = crate::io::checked_load(c.load.clone(), mech, &params)?;
    let n_data = data.len();
    let data: Vec<Measurement> = match &c.distances {
        Some(p) => {
            let pairs = read_distances(run, p, mech, &measurement, &units)?;
            data.into_iter().chain(pairs).collect()
        }
        None => data,
    };
    let id = if priors.is_empty() {
        pkmcal::analyze(mech, &measurement, &data, &params, c.model, &free, &force)
    } else {
        pkmcal::identify::analyze_with_priors(
            mech,
            &measurement,
            &data,
            &params,
            c.model,
            &free,
            &force,
            &priors,
            crate::io::noise_arg(c.noise, c.angle_noise),
        )
    }
    .map_err(|e| located_in(e, &c.data, c.distances.as_deref()))?;
    if let Some(r) = &c.report {
        run.files
            .stage(r, serde_json::to_string_pretty(&id)?.as_bytes())?;
    }
    println!(
        "identifiability of {} free parameters from {} poses of {}{} ({} model)",
        free.len(),
        n_data,
        c.data.display(),
        match &c.distances {
            Some(p) => format!(" and {} distances of {}", data.len() - n_data, p.display()),
            None => String::new(),
        },
        c.model.name()
    );
    println!(
        "  free: {}{}",
        free.iter()
            .map(|&i| measurement.all_names(spec)[i].clone())
            .collect::<Vec<_>>()
            .join(" "),
        if *measurement.frame() == Frame::Free {
            format!(
                ", and the instrument frame's {} (--frame base if the data are in the base frame)",
                measurement.param_names()[measurement.frame_range()].join(" ")
            )
        } else {
            String::new()
        }
    );
    print_identifiability(&id, "calibrate fixes");
    println!(
        "  singular values (column-scaled): {}",
        id.singular_values
            .iter()
            .map(|s| format!("{s:.3e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    if !id.held.is_empty() {
        println!(
            "{} the data alone cannot see, held by the tolerances ({} given, readings weighed with {} mm of noise):",
            crate::io::count(id.held.len(), "direction", "directions"),
            priors.len(),
            c.noise
        );
        for u in &id.held {
            println!("  {}", u.combination);
        }
    }
    if id.unidentifiable.is_empty() {
        println!(
            "all {} free parameters are identifiable{}",
            free.len(),
            if id.held.is_empty() {
                ""
            } else {
                ", with the tolerances"
            }
        );
    } else {
        println!(
            "{} cannot be identified; calibrate fixes one parameter per direction (or use --fix)",
            crate::io::count(id.unidentifiable.len(), "direction", "directions")
        );
    }
    Ok(())
}
