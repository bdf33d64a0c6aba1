//! The subcommands: each reads its inputs, calls the library, writes outputs.

use crate::{DemoArgs, PredictArgs, SimulateArgs};
use anyhow::{Context, Result, bail};
use pkmcal::{ErrorStats, Mechanism, Model, Params, Prediction, predict_pose, prepare_pose};
use pkmcal_io::Run;
use pkmcal_io::io::{Csv, Mech, csv_bytes, read_mechanism, read_params};
use rayon::prelude::*;
use std::path::Path;

/// Rows per sequential chunk (each chunk warm-starts from its previous row).
const CHUNK_ROWS: usize = 512;

/// A prediction and the standard deviation of each tool coordinate (empty
/// without a covariance).
type Row = (Prediction, Vec<f64>);

/// What to predict for every row.
pub struct PredictSettings<'a> {
    pub params: &'a Params,
    pub model: Model,
    pub force: &'a [f64],
    pub covariance: Option<&'a pkmcal::ParameterCovariance>,
}

/// Predict every row, in parallel over chunks; the error names the row's line.
pub fn predict_rows(
    mech: &Mech,
    settings: &PredictSettings,
    commands: &[Vec<f64>],
    where_: &(dyn Fn(usize) -> String + Sync),
    bar: &dyn pkmcal_io::Progress,
) -> Result<Vec<Row>> {
    let PredictSettings {
        params,
        model,
        force,
        covariance,
    } = *settings;
    let chunks: Vec<Result<Vec<Row>>> = commands
        .par_chunks(CHUNK_ROWS)
        .enumerate()
        .map(|(ci, chunk)| {
            let mut start: Option<Vec<f64>> = None;
            let mut out = Vec::with_capacity(chunk.len());
            for (k, c) in chunk.iter().enumerate() {
                let row = ci * CHUNK_ROWS + k;
                let pose = match start.as_deref().map(|s| prepare_pose(mech, c, Some(s))) {
                    Some(Ok(p)) => p,
                    _ => prepare_pose(mech, c, None)
                        .with_context(|| format!("{}: commands {c:?}", where_(row)))?,
                };
                let row_result = match covariance {
                    None => predict_pose(mech, &pose, params, model, force).map(|p| (p, vec![])),
                    Some(cov) => pkmcal::tool_covariance(mech, &pose, params, model, force, cov)
                        .map(|(p, c)| {
                            let s = (0..c.nrows()).map(|a| c[(a, a)].max(0.0).sqrt()).collect();
                            (p, s)
                        }),
                };
                let p = row_result.with_context(|| format!("{}: commands {c:?}", where_(row)))?;
                start = Some(pose.nominal_q);
                out.push(p);
            }
            bar.inc(chunk.len() as u64);
            Ok(out)
        })
        .collect();
    let mut all = Vec::with_capacity(commands.len());
    for c in chunks {
        all.extend(c?);
    }
    Ok(all)
}

fn load_params<M: Mechanism>(run: &Run<'_>, path: Option<&Path>, mech: &M) -> Result<Params> {
    match path {
        Some(p) => read_params(run, p, mech),
        None => Ok(Params::nominal(mech.spec())),
    }
}

pub fn predict(run: &Run<'_>, a: PredictArgs) -> Result<()> {
    let mech = read_mechanism(run, a.mech.mechanism.as_deref())?;
    let spec = mech.spec();
    let params = load_params(run, a.params.as_deref(), &mech)?;
    let model: Model = a.model.parse()?;
    let force = match &a.force {
        Some(s) => {
            let f = pkmcal_io::io::parse_load(s, "--force")?;
            if f.len() != spec.tool_axes.len() {
                return pkmcal_io::output::usage(format!(
                    "--force needs {} values ({}), got {}",
                    spec.tool_axes.len(),
                    spec.tool_axes.join(","),
                    f.len()
                ));
            }
            f
        }
        None => vec![],
    };
    // Streamed in batches (memory flat in the rows, a pipe works), each
    // batch predicted on all cores.
    let mut input = pkmcal_io::io::CsvStream::open(run, &a.commands)?;
    pkmcal_io::io::commands_belong(&input.path, &input.headers, spec)?;
    let names: Vec<String> = spec
        .actuated_names()
        .iter()
        .map(|s| s.to_string())
        .collect();
    let cols = input.columns(&names)?;
    let covariance = match &a.uncertainty {
        Some(path) => {
            let c = read_covariance(run, path)?;
            // Checked against this mechanism here, so that a report of
            // another mechanism, or a malformed matrix, is blamed on the
            // report and not on a row of the commands.
            c.resolve(spec).with_context(|| {
                format!(
                    "{}: its `covariance` cannot serve {} (give the report of a calibration of this mechanism)",
                    path.display(),
                    spec.name
                )
            })?;
            Some(c)
        }
        None => None,
    };
    let settings = PredictSettings {
        params: &params,
        model,
        force: &force,
        covariance: covariance.as_ref(),
    };
    let mut header = names.clone();
    header.extend(spec.tool_axes.iter().cloned());
    header.extend(names.iter().map(|n| format!("deflection_{n}")));
    header.extend(
        names
            .iter()
            .zip(spec.command_units())
            .map(|(n, u)| pkmcal_io::usecal::load_column(n, u)),
    );
    if covariance.is_some() {
        header.extend(spec.tool_axes.iter().map(|a| format!("sigma_{a}")));
    }
    let units = pkmcal_io::fileunits::of(run, a.mech.mechanism.as_deref())?;
    let (cf, tf) = (
        pkmcal_io::fileunits::commands(spec, &units),
        pkmcal_io::fileunits::tool(spec, &units),
    );
    // Output factors, column by column: commands, tool, deflections (in the
    // commands' unit), torques (N·m or N), σ (tool).
    let out_factors: Vec<f64> = cf
        .iter()
        .chain(&tf)
        .chain(&cf)
        .copied()
        .chain(std::iter::repeat_n(1.0, names.len()))
        .chain(tf.iter().copied())
        .collect();
    let bar = run.bar(0, a.quiet, "poses", 0);
    let mut w = run.files.writer(&a.out)?;
    use std::io::Write;
    if let Some(c) = pkmcal_io::fileunits::comment(&units) {
        writeln!(w, "{c}")?;
    }
    writeln!(w, "{}", header.join(","))?;
    let mut total = 0usize;
    let mut line = String::new();
    loop {
        let batch = input.batch(&cols, &names, PREDICT_BATCH_ROWS)?;
        if batch.is_empty() {
            break;
        }
        bar.inc_length(batch.len() as u64);
        let mut commands: Vec<Vec<f64>> = batch.iter().map(|(_, c)| c.clone()).collect();
        pkmcal_io::fileunits::to_internal(&mut commands, &cf);
        let path = input.path.clone();
        let preds = predict_rows(
            &mech,
            &settings,
            &commands,
            &|r| format!("{}:{}", path.display(), batch[r].0),
            &*bar,
        )
        .map_err(|e| pkmcal_io::hints::explain_failure(e, &mech, &commands, &units))?;
        for (c, (p, sigma)) in commands.iter().zip(&preds) {
            line.clear();
            for (k, v) in c
                .iter()
                .chain(&p.x)
                .chain(&p.deflection)
                .chain(&p.torque)
                .chain(sigma)
                .enumerate()
            {
                if k > 0 {
                    line.push(',');
                }
                line.push_str(&format!(
                    "{}",
                    pkmcal_io::fileunits::to_file(*v, out_factors[k])
                ));
            }
            writeln!(w, "{line}")?;
        }
        total += batch.len();
    }
    w.flush()?;
    bar.finish();
    pkmcal_io::note!(
        "predicted {total} poses with the {} model -> {}",
        model.name(),
        a.out.display()
    );
    Ok(())
}

/// Rows predicted per batch of a streamed `predict`.
const PREDICT_BATCH_ROWS: usize = 1 << 14;

/// The parameter covariance stored in a calibration report (`covariance`).
fn read_covariance(run: &Run<'_>, path: &Path) -> Result<pkmcal::ParameterCovariance> {
    let text = run
        .files
        .read_to_string(path, pkmcal_io::output::InputKind::Description)
        .with_context(|| format!("cannot read calibration report {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{}: not a JSON calibration report", path.display()))?;
    let c = v.get("covariance").with_context(|| {
        format!(
            "{}: no `covariance` entry; pass the report written by `pkmcal calibrate --report`",
            path.display()
        )
    })?;
    serde_json::from_value(c.clone())
        .with_context(|| format!("{}: malformed `covariance` entry", path.display()))
}

/// Target columns `target_<axis>`.
fn target_names(mech: &Mech) -> Vec<String> {
    mech.spec()
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect()
}

pub fn simulate(run: &Run<'_>, a: SimulateArgs) -> Result<()> {
    let mech = read_mechanism(run, a.mech.mechanism.as_deref())?;
    let truth = load_params(run, a.truth.as_deref(), &mech)?;
    let noise = pkmcal_io::io::noise_arg(a.noise, a.angle_noise);
    let targets: Vec<Vec<f64>> = match (&a.targets, a.grid) {
        (Some(path), _) => {
            let csv = Csv::read(run, path)?;
            csv.require_rows()?;
            let mut t = csv.named(&target_names(&mech))?;
            pkmcal_io::fileunits::to_internal(
                &mut t,
                &pkmcal_io::fileunits::tool(
                    mech.spec(),
                    &pkmcal_io::fileunits::of(run, a.mech.mechanism.as_deref())?,
                ),
            );
            for (i, target) in t.iter().enumerate() {
                pkmcal::nominal_commands(&mech, target)
                    .with_context(|| format!("{}:{}", path.display(), csv.line(i)))?;
            }
            t
        }
        (None, Some(n)) => {
            if n == 0 {
                return pkmcal_io::output::usage("--grid needs at least one target");
            }
            pkmcal::spread_targets(&mech, n)
                .map_err(anyhow::Error::from)
                .with_context(|| match &a.mech.mechanism {
                    Some(m) => format!("with the [workspace] box of {}", m.display()),
                    None => "with the built-in mechanism's workspace box".into(),
                })?
                .into_iter()
                .map(|p| p.target)
                .collect()
        }
        (None, None) => bail!("give --targets FILE or --grid N"),
    };
    let measurement = simulated_measurement(run, &mech, &a)?;
    let bar = run.bar(targets.len() as u64, a.quiet, "poses", 0);
    let data = pkmcal::simulate_with_progress(
        &mech,
        &measurement,
        &truth,
        &targets,
        noise,
        a.seed,
        &|| bar.inc(1),
    )?;
    bar.finish();
    let units = pkmcal_io::fileunits::of(run, a.mech.mechanism.as_deref())?;
    let distances = match &a.distances_out {
        None => None,
        Some(path) => {
            if path == &a.out {
                return pkmcal_io::output::usage("--distances-out must differ from --out");
            }
            let pairs = distance_pairs(&targets);
            let rows = pkmcal::simulate_distances(
                &mech,
                &measurement,
                &truth,
                &pairs,
                noise.length,
                a.seed.wrapping_add(1),
            )
            .map_err(|e| pkmcal_io::output::Usage(format!("--distances-out: {e}")))?;
            Some((path, distances_csv(&mech, &rows, &units), rows.len()))
        }
    };
    let base = *measurement.frame() == pkmcal::Frame::Base;
    run.files.stage(
        &a.out,
        &with_frame_comment(data_csv(&mech, &measurement, &data, &units), base),
    )?;
    let angles = measurement.units().contains(&pkmcal::Unit::Radian);
    pkmcal_io::note!(
        "simulated {} poses, {} (noise {} mm on lengths{}, seed {}) -> {}",
        data.len(),
        measurement.describe(),
        noise.length,
        if angles {
            format!(", {} rad on angles", noise.angle)
        } else {
            String::new()
        },
        a.seed,
        a.out.display()
    );
    if let Some((path, bytes, n)) = distances {
        run.files.stage(path, &bytes)?;
        pkmcal_io::note!(
            "simulated {n} distances between pairs of those poses -> {}",
            path.display()
        );
    }
    Ok(())
}

/// Pairs of simulated targets whose distances are measured: each target of
/// the first half with its opposite in the second (long distances, which
/// fix the scale), and neighbours (short ones).
fn distance_pairs(targets: &[Vec<f64>]) -> Vec<(Vec<f64>, Vec<f64>)> {
    let n = targets.len();
    let half = n / 2;
    let long = (0..half).map(|i| (i, i + half));
    let short = (0..n.saturating_sub(1)).step_by(2).map(|i| (i, i + 1));
    long.chain(short)
        .map(|(i, j)| (targets[i].clone(), targets[j].clone()))
        .collect()
}

/// Distances between pairs of poses as `calibrate --distances` reads them:
/// `<actuator>_1 …, <actuator>_2 …, distance`, in the file's units.
pub fn distances_csv(
    mech: &Mech,
    rows: &[pkmcal::Measurement],
    units: &pkmcal::FileUnits,
) -> Vec<u8> {
    let spec = mech.spec();
    use pkmcal_io::fileunits as fu;
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

/// What `simulate` measures: a ball bar (`--setup`), target points
/// (`--measure-targets`), some tool axes (`--axes`) or the whole tool; from
/// an instrument at `--instrument-frame` if given.
fn simulated_measurement(
    run: &Run<'_>,
    mech: &Mech,
    a: &SimulateArgs,
) -> Result<pkmcal::MeasurementModel> {
    let spec = mech.spec();
    let m = if let Some(p) = &a.setup {
        let setup = pkmcal_io::io::read_setup(run, Some(p), None)?
            .with_context(|| format!("{}: no ball-bar setup", p.display()))?;
        pkmcal::MeasurementModel::ball_bar(spec, &setup)?
    } else if a.probe {
        pkmcal::MeasurementModel::probe(spec)
            .map_err(|e| pkmcal_io::output::Usage(format!("--probe: {e}")))?
    } else if a.measure_targets {
        let points = pkmcal_io::io::read_targets(run, a.mech.mechanism.as_deref())?;
        if points.is_empty() {
            return pkmcal_io::output::usage(
                "--measure-targets needs target points in the mechanism file: [[target]] at = [x, y, z] (tool frame, mm; [x, y] for a planar tool)",
            );
        }
        pkmcal::MeasurementModel::targets(spec, &points)?
    } else if let Some(axes) = &a.axes {
        let names: Vec<&str> = axes.split(',').map(str::trim).collect();
        pkmcal::MeasurementModel::tool_axes(spec, &names)
            .map_err(|e| pkmcal_io::output::Usage(format!("in --axes: {e}")))?
    } else {
        pkmcal::MeasurementModel::tool(spec)
    };
    match &a.instrument_frame {
        None => Ok(m),
        Some(s) => {
            let f = pkmcal_io::io::parse_list(s, "--instrument-frame")?;
            m.in_frame(pkmcal::Frame::Known(f))
                .map_err(|e| pkmcal_io::output::Usage(format!("in --instrument-frame: {e}")).into())
        }
    }
}

/// `trilaterate`: bar readings to positions with their standard deviations.
pub fn trilaterate(run: &Run<'_>, a: crate::TrilaterateArgs) -> Result<()> {
    let mech = read_mechanism(run, a.mech.mechanism.as_deref())?;
    let spec = mech.spec();
    let setup = pkmcal_io::io::read_setup(run, a.setup.as_deref(), a.mech.mechanism.as_deref())?
        .context("give the socket positions with --setup S.toml (or a [ballbar] table in the mechanism file)")?;
    // Checks the setup against the tool point.
    pkmcal::MeasurementModel::ball_bar(spec, &setup)?;
    if !(a.sigma.is_finite() && a.sigma >= 0.0) {
        return pkmcal_io::output::usage("--sigma must be a non-negative number of mm");
    }
    let csv = Csv::read(run, &a.data)?;
    csv.require_rows()?;
    let dnames: Vec<String> = (1..=setup.sockets.len()).map(|j| format!("d{j}")).collect();
    let units = pkmcal_io::fileunits::of(run, a.mech.mechanism.as_deref())?;
    let mut readings = csv.named(&dnames)?;
    let d_factor = units.factor(pkmcal::Unit::Millimetre, pkmcal::Role::Reading);
    pkmcal_io::fileunits::to_internal(&mut readings, &vec![d_factor; dnames.len()]);
    let tf = pkmcal_io::fileunits::tool(spec, &units);
    // Pass through targets and commands when present (in the file's units).
    let mut keep: Vec<String> = target_names(&mech);
    keep.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    keep.retain(|n| csv.headers.contains(n));
    let kept = csv.named(&keep)?;
    let mut rows = Vec::with_capacity(readings.len());
    for (i, d) in readings.iter().enumerate() {
        let (x, cov) = pkmcal::trilaterate(&setup, d, a.sigma, None)
            .with_context(|| format!("{}:{}: readings {d:?}", a.data.display(), csv.line(i)))?;
        let sig = (0..x.len()).map(|k| cov[(k, k)].max(0.0).sqrt() / tf[k]);
        rows.push(
            kept[i]
                .iter()
                .copied()
                .chain(x.iter().zip(&tf).map(|(v, f)| v / f))
                .chain(sig)
                .collect::<Vec<f64>>(),
        );
    }
    let mut header = keep;
    header.extend(spec.tool_axes.iter().cloned());
    header.extend(spec.tool_axes.iter().map(|a| format!("sigma_{a}")));
    // Sockets are placed in the base frame, so are the positions.
    run.files.stage(
        &a.out,
        &with_frame_comment(
            pkmcal_io::fileunits::with_comment(csv_bytes(&header, &rows), &units),
            true,
        ),
    )?;
    pkmcal_io::note!(
        "trilaterated {} poses from {} sockets -> {}",
        rows.len(),
        setup.sockets.len(),
        a.out.display()
    );
    Ok(())
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
    use pkmcal_io::fileunits as fu;
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

/// Validation poses of the demo (unseen: drawn at random from the workspace).
const DEMO_VALIDATION_POSES: usize = 50;
/// Measurement noise of the demo, mm per axis (docs/model.md §10).
const DEMO_NOISE_MM: f64 = 0.002;

/// Every file `demo` writes in its directory (the report in `report/`).
pub const DEMO_FILES: &[&str] = &[
    "measurements.csv",
    "validation.csv",
    "truth.toml",
    "params-rigid.toml",
    "params-linear.toml",
    "params-exact.toml",
    "report-rigid.json",
    "report-linear.json",
    "report-exact.json",
];

pub fn demo(run: &Run<'_>, a: DemoArgs) -> Result<()> {
    use pkmcal_io::calibrate::{print_identifiability, print_stats, print_stats_header};
    let mech: Mech = pkmcal::JeongKim2Dof::new().into();
    let spec = mech.spec();
    let truth = pkmcal::kinds::reference::demo_truth();
    let dir = &a.out_dir;
    // The demo's own calibrations read its files internally; only what it
    // writes follows --units.
    let units = pkmcal_io::fileunits::of(run, None)?;
    run.files.create_dir(dir)?;
    let targets: Vec<Vec<f64>> = pkmcal::spread_targets(&mech, 35)?
        .into_iter()
        .map(|p| p.target)
        .collect();
    let tool = pkmcal::MeasurementModel::tool(spec);
    let data = pkmcal::simulate(&mech, &tool, &truth, &targets, DEMO_NOISE_MM, a.seed)?;
    let vtargets = pkmcal::random_targets(&mech, DEMO_VALIDATION_POSES, a.seed + 1)?;
    let vdata = pkmcal::simulate(&mech, &tool, &truth, &vtargets, DEMO_NOISE_MM, a.seed + 2)?;
    run.files.stage(
        &dir.join("measurements.csv"),
        &with_frame_comment(data_csv(&mech, &tool, &data, &units), true),
    )?;
    run.files.stage(
        &dir.join("validation.csv"),
        &with_frame_comment(data_csv(&mech, &tool, &vdata, &units), true),
    )?;
    run.files.stage(
        &dir.join("truth.toml"),
        pkmcal_io::io::params_to_string(spec, &truth, "true parameters of the demo (simulated)")
            .as_bytes(),
    )?;
    println!("pkmcal demo: the paper's case study on the {}", spec.name);
    println!(
        "35 calibration poses spread over the workspace and {DEMO_VALIDATION_POSES} unseen validation poses;"
    );
    println!(
        "paper-sized parameter errors (l, B, D, Pt: 0.18-0.47 mm; dq: 0.95-1.42 mrad); {} µm noise per axis (seed {})",
        DEMO_NOISE_MM * 1e3,
        a.seed
    );
    println!();
    let nominal = Params::nominal(spec);
    let mut rows: Vec<(String, ErrorStats, ErrorStats)> = vec![];
    let mut first = true;
    for model in Model::ALL {
        let opts = pkmcal::CalibrationOptions::new(spec, model);
        let cal = pkmcal::calibrate(&mech, &tool, &data, &nominal, &opts)?;
        let (acc, before, after) = pkmcal::calibration_accuracy(&mech, &tool, &data, &cal, &[])?;
        let (vacc, _, _) = pkmcal::calibration_accuracy(&mech, &tool, &vdata, &cal, &[])?;
        if model == Model::Exact {
            let validation = pkmcal_io::calibrate::Validation {
                source: format!("{DEMO_VALIDATION_POSES} unseen poses"),
                accuracy: vacc.clone(),
            };
            pkmcal_io::report::write_report_dir(
                run,
                &dir.join("report"),
                &pkmcal_io::report::ReportInputs {
                    mech: &mech,
                    measurement: &tool,
                    data_name: "measurements.csv (simulated)",
                    cal: &cal,
                    data: &data,
                    before: &before,
                    after: &after,
                    accuracy: &acc,
                    validation: Some(&validation),
                    cross_validation: None,
                },
            )?;
        }
        if first {
            rows.push((
                "before calibration".into(),
                acc.before.clone(),
                vacc.before.clone(),
            ));
            first = false;
        }
        rows.push((
            format!("after, {} model", model.name()),
            acc.after,
            vacc.after,
        ));
        let name = model.name();
        run.files.stage(
            &dir.join(format!("params-{name}.toml")),
            pkmcal_io::io::params_to_string(
                spec,
                &cal.params,
                &format!("demo calibration, {name} model: {}", cal.termination_reason),
            )
            .as_bytes(),
        )?;
        run.files.stage(
            &dir.join(format!("report-{name}.json")),
            serde_json::to_string_pretty(&cal)?.as_bytes(),
        )?;
        println!(
            "{name:>6} model: {} ({} iterations), residual σ {:.2} µm",
            cal.termination_reason,
            cal.iterations,
            cal.noise.first().map_or(0.0, |g| g.sigma) * 1e3
        );
        if model == Model::Exact {
            print!("  ");
            print_identifiability(&cal.identifiability, "fixed");
        }
        for w in &cal.warnings {
            println!("  warning: {}", w.message);
        }
    }
    println!();
    println!("calibration set (35 poses):");
    print_stats_header(&spec.tool_axes, &spec.tool_units);
    for (label, cal, _) in &rows {
        print_stats(label, cal);
    }
    println!();
    println!("validation set ({DEMO_VALIDATION_POSES} unseen poses):");
    print_stats_header(&spec.tool_axes, &spec.tool_units);
    for (label, _, val) in &rows {
        print_stats(label, val);
    }
    let before = rows[0].1.distance_max;
    println!();
    for (label, cal, val) in &rows[1..] {
        println!(
            "  {label:<24} max distance error {:.4} mm ({:.1} % better), validation RMS {:.4} mm",
            cal.distance_max,
            pkmcal::improvement_percent(before, cal.distance_max),
            val.distance_rms
        );
    }
    println!();
    println!(
        "the paper: max distance error 1.416 mm before, 0.243 mm after (-82 %); files in {}",
        dir.display()
    );
    println!(
        "report of the exact-model calibration: {}",
        dir.join("report").join("report.html").display()
    );
    Ok(())
}

/// CSV bytes with the comment that declares them in the base frame.
pub fn with_frame_comment(bytes: Vec<u8>, base: bool) -> Vec<u8> {
    if !base {
        return bytes;
    }
    let mut out = format!("{}\n", pkmcal_io::io::BASE_FRAME_COMMENT).into_bytes();
    out.extend(bytes);
    out
}
