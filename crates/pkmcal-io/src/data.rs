//! Measurement files: what the instrument read (the measurement model, from
//! the columns), the poses with their commands, readings, targets and
//! standard deviations, the distances measured between poses, plans'
//! poses; and data files written as they are read.

use crate::csv::{Csv, csv_bytes};
use crate::description::{Description, Mech};
use crate::error::{Error, Result};
use crate::fileunits as fu;
use crate::refuse;
use pkmcal::{FrameChoice, Measurement, MeasurementModel, Mechanism};
use std::path::Path;

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
    // The file's own units line over `units` (the run's), the run's units
    // over both.
    let units = fu::for_file(run, units, csv.units.as_ref(), &csv.path);
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
    commands_belong(&csv.path, &csv.headers, spec)?;
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
            point: None,
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
/// as a distance ([`pkmcal::Origin::distance`]).
pub fn read_distances<M: Mechanism>(
    run: &crate::Run<'_>,
    path: &Path,
    mech: &M,
    measurement: &MeasurementModel,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Measurement>> {
    let csv = Csv::read(run, path)?;
    let units = &fu::for_file(run, units, csv.units.as_ref(), &csv.path);
    csv.require_rows()?;
    if let Err(e) = measurement.check_distances() {
        refuse!(path, None, "{e}");
    }
    let spec = mech.spec();
    let names = |k: usize| -> Vec<String> {
        spec.actuated_names()
            .iter()
            .map(|s| format!("{s}_{k}"))
            .collect()
    };
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
            Some(s) if s[i][0] <= 0.0 => refuse!(
                path,
                Some(csv.line(i)),
                "sigma_distance must be positive, got {}",
                s[i][0]
            ),
            Some(s) => vec![Some(s[i][0])],
            None => vec![],
        };
        out.push(Measurement {
            point: None,
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

/// A library error located in the measurement file `data`, or in the file
/// of distances between poses where it names one of those.
pub fn located_in(e: pkmcal::Error, data: &Path, distances: Option<&Path>) -> Error {
    match (&e, distances) {
        (pkmcal::Error::Pose { distance: true, .. }, Some(file)) => Error::located(e, file),
        _ => Error::located(e, data),
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
        refuse!(
            csv.path,
            None,
            "column(s) {} name nothing measured ({}); the measured readings are {} (columns sigma_{})",
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
        refuse!(
            csv.path,
            None,
            "give either one `sigma` column or per-axis `sigma_<axis>` columns, not both"
        );
    }
    let rows: Vec<Vec<Option<f64>>> = if common {
        let units = measurement.units();
        if units.iter().any(|u| *u != units[0]) {
            refuse!(
                csv.path,
                None,
                "one `sigma` column cannot hold the noise of {} ({}); give per-axis columns sigma_{} (any subset; the others are estimated)",
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
            refuse!(
                csv.path,
                Some(csv.line(i)),
                "standard deviations must be positive, got {}",
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

/// Refuse a file with command columns the mechanism does not have (e.g.
/// `q7, q8` of an 8-leg platform given to a 6-leg one): data for another
/// mechanism, which would otherwise be read half.
pub fn commands_belong(path: &Path, headers: &[String], spec: &pkmcal::Spec) -> Result<()> {
    let names = spec.actuated_names();
    let prefix = |n: &str| n.trim_end_matches(|c: char| c.is_ascii_digit()).to_string();
    let Some(first) = names.first().map(|n| prefix(n)) else {
        return Ok(());
    };
    if first.is_empty() || names.iter().any(|n| prefix(n) != first || *n == first) {
        return Ok(());
    }
    let foreign: Vec<String> = headers
        .iter()
        .filter(|h| {
            h.len() > first.len()
                && prefix(h) == first
                && !names.contains(&h.as_str())
                && !spec.tool_axes.contains(h)
        })
        .cloned()
        .collect();
    if !foreign.is_empty() {
        return Err(Error::ForeignCommands {
            path: path.to_path_buf(),
            columns: foreign,
            mechanism: spec.name.clone(),
            actuators: names.iter().map(|s| s.to_string()).collect(),
        });
    }
    Ok(())
}

/// The measurement model of a data file, from its columns: the whole tool
/// (`x, y, …`), target points (`t1x …`, from the mechanism file's
/// `[[target]]`s), ball-bar readings (`d1 …`, with `setup` or the mechanism
/// file's `[ballbar]`), probe heights (`probe`), or the tool axes named by
/// `axes` (e.g. only `z`; a file missing a tool column without `axes` is an
/// error, not a subset). The frame: `frame`'s rule
/// ([`FrameChoice::apply`]), the file's `# frame: base` for `auto`.
pub fn measurement_of(
    run: &crate::Run<'_>,
    csv: &Csv,
    description: &Description,
    setup: Option<&Path>,
    frame: FrameChoice,
    axes: Option<&[String]>,
) -> Result<MeasurementModel> {
    let spec = description.mech.spec();
    // Regardless of case, as every column is found.
    let has = |h: &str| csv.has(h);
    let whole = spec.tool_axes.iter().all(|a| has(a));
    let some: Vec<String> = spec.tool_axes.iter().filter(|a| has(a)).cloned().collect();
    let file = csv.path.display();
    let m = if let Some(axes) = axes {
        let names: Vec<&str> = axes.iter().map(|s| s.trim()).collect();
        MeasurementModel::tool_axes(spec, &names)
            .map_err(|e| pkmcal::RequestError::invalid(pkmcal::Field::Axes, e.to_string()))?
    } else if whole {
        MeasurementModel::tool(spec)
    } else if has("probe") {
        MeasurementModel::probe(spec)
            .map_err(|e| Error::from(e).context(format!("probe heights in {file}")))?
    } else if has("t1x") {
        let t = &description.targets;
        if t.is_empty() {
            refuse!(
                csv.path,
                None,
                "it holds target-point positions (t1x…); describe the targets in the mechanism file: [[target]] at = [x, y, z] (tool frame, mm)"
            );
        }
        MeasurementModel::targets(spec, t)
            .map_err(|e| Error::from(e).context(format!("targets for {file}")))?
    } else if has("d1") {
        let Some(setup) = crate::description::read_setup(run, setup, description)? else {
            return Err(Error::NeedsSetup {
                path: csv.path.clone(),
            });
        };
        MeasurementModel::ball_bar(spec, &setup)
            .map_err(|e| Error::from(e).context(format!("ball bar for {file}")))?
    } else if !some.is_empty() {
        return Err(Error::MissingAxes {
            path: csv.path.clone(),
            missing: spec.tool_axes.iter().filter(|a| !has(a)).cloned().collect(),
            present: some,
        });
    } else {
        refuse!(
            csv.path,
            None,
            "no measured columns: give the tool coordinates ({}), some of them, target points (t1x, t1y, …) or ball-bar readings (d1, d2, …)",
            spec.tool_axes.join(", ")
        );
    };
    frame
        .apply(m, spec, csv.base_frame)
        .map_err(|cause| Error::Request {
            file: Some(csv.path.clone()),
            cause,
        })
}

/// What `calibrate` and `analyze` read first: the mechanism, the data file,
/// its measurement model and its poses.
pub struct Measured {
    /// The mechanism description.
    pub description: Description,
    /// What the instrument read.
    pub measurement: MeasurementModel,
    /// The poses.
    pub data: Vec<Measurement>,
    /// The data-file units of the run (the description's and the run's).
    pub units: pkmcal::FileUnits,
}

/// The mechanism, the data file, its measurement model and its poses,
/// checked for plausible units ([`crate::hints::check_data`]).
pub fn read_measured(
    run: &crate::Run<'_>,
    description: Description,
    data: &Path,
    setup: Option<&Path>,
    frame: FrameChoice,
    axes: Option<&[String]>,
) -> Result<Measured> {
    let csv = Csv::read(run, data)?;
    let measurement = measurement_of(run, &csv, &description, setup, frame, axes)?;
    let units = fu::of(run, &description);
    let file_units = fu::for_file(run, &units, csv.units.as_ref(), &csv.path);
    let poses = data_from(&csv, &description.mech, &measurement, &file_units)?;
    crate::hints::check_data(
        &description.mech,
        &measurement,
        &poses,
        &file_units,
        &csv.path,
    )?;
    Ok(Measured {
        description,
        measurement,
        data: poses,
        units,
    })
}

/// A plan's poses (`target_<axis>` columns, e.g. a plan's output) in
/// internal units, each checked reachable by nominal inverse kinematics
/// (an error names the file and line).
pub fn read_plan_poses(
    run: &crate::Run<'_>,
    path: &Path,
    mech: &Mech,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Vec<f64>>> {
    let spec = mech.spec();
    let csv = Csv::read(run, path)?;
    csv.require_rows()?;
    let names = target_names(mech);
    let mut poses = csv.named(&names)?;
    let units = fu::for_file(run, units, csv.units.as_ref(), &csv.path);
    fu::to_internal(&mut poses, &fu::tool(spec, &units));
    for (i, t) in poses.iter().enumerate() {
        if let Err(e) = pkmcal::nominal_commands(mech, t) {
            return Err(Error::from(e).context(format!("{}:{}", path.display(), csv.line(i))));
        }
    }
    Ok(poses)
}

/// Target columns `target_<axis>`.
pub fn target_names(mech: &Mech) -> Vec<String> {
    mech.spec()
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect()
}

/// Distances between pairs of poses as they are read back: `<actuator>_1
/// …, <actuator>_2 …, distance`, in the file's units.
pub fn distances_csv(
    mech: &Mech,
    rows: &[pkmcal::Measurement],
    units: &pkmcal::FileUnits,
) -> Vec<u8> {
    let spec = mech.spec();
    let commands = fu::commands(spec, units);
    let factors: Vec<f64> = commands
        .iter()
        .chain(&commands)
        .copied()
        .chain(fu::readings(&[pkmcal::Unit::Millimetre], units))
        .collect();
    let names = spec.actuated_names();
    let mut header: Vec<String> = names.iter().map(|s| format!("{s}_1")).collect();
    header.extend(names.iter().map(|s| format!("{s}_2")));
    header.push(pkmcal::DISTANCE_AXIS.to_string());
    let rows: Vec<Vec<f64>> = rows
        .iter()
        .map(|m| {
            m.commands
                .iter()
                .chain(m.partner.as_deref().unwrap_or_default())
                .chain(&m.measured)
                .zip(&factors)
                .map(|(v, f)| fu::to_file(*v, *f))
                .collect()
        })
        .collect();
    fu::with_comment(csv_bytes(&header, &rows), units)
}

/// Measurement file: target_*, commands, measured tool coordinates, in the
/// data-file `units` (with a comment line naming them unless internal).
pub fn data_csv(
    mech: &Mech,
    measurement: &pkmcal::MeasurementModel,
    data: &[pkmcal::Measurement],
    units: &pkmcal::FileUnits,
) -> Vec<u8> {
    let spec = mech.spec();
    let factors: Vec<f64> = fu::tool(spec, units)
        .into_iter()
        .chain(fu::commands(spec, units))
        .chain(fu::readings(measurement.units(), units))
        .collect();
    let mut header = target_names(mech);
    header.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    header.extend(measurement.axes().iter().cloned());
    let rows: Vec<Vec<f64>> = data
        .iter()
        .map(|m| {
            let nan = vec![f64::NAN; spec.tool_axes.len()];
            m.target
                .as_ref()
                .unwrap_or(&nan)
                .iter()
                .chain(&m.commands)
                .chain(&m.measured)
                .zip(&factors)
                .map(|(v, f)| fu::to_file(*v, *f))
                .collect()
        })
        .collect();
    fu::with_comment(csv_bytes(&header, &rows), units)
}

/// CSV bytes with the comment that declares them in the base frame.
pub fn with_frame_comment(bytes: Vec<u8>, base: bool) -> Vec<u8> {
    if !base {
        return bytes;
    }
    let mut out = format!("{}\n", crate::csv::BASE_FRAME_COMMENT).into_bytes();
    out.extend(bytes);
    out
}
