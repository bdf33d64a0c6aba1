//! `compensate`, `plan` and `montecarlo`: using a calibration.

use crate::io::{Csv, csv_bytes, read_description};
use anyhow::{Context, Result, bail};
use pkmcal::{
    CalibrationOptions, CompensationOptions, Mechanism, Model, MonteCarloOptions, Params,
    PlanCriterion, compensate, monte_carlo,
};
use rayon::prelude::*;
use std::io::Write;
use std::path::PathBuf;

/// Rows compensated per parallel batch (bounded memory for any file size).
const BATCH_ROWS: usize = 1 << 16;

pub struct CompensateConfig {
    pub mechanism: Option<PathBuf>,
    pub params: Option<PathBuf>,
    pub targets: Option<PathBuf>,
    pub grid: Option<String>,
    pub cartesian: bool,
    pub controller: Option<PathBuf>,
    pub model: Model,
    /// The tool load (`--load`), one value per tool axis; empty for none.
    pub load: Vec<f64>,
    pub preload: Option<String>,
    pub skip_unreachable: bool,
    pub out: PathBuf,
}

/// The name of an actuator's internal load column: `torque_<a>` (N·m) for a
/// revolute actuator, `force_<a>` (N) for a prismatic one.
pub fn load_column(name: &str, unit: pkmcal::Unit) -> String {
    match unit {
        pkmcal::Unit::Radian => format!("torque_{name}"),
        _ => format!("force_{name}"),
    }
}

/// Stream the targets file in batches, compensate each batch in parallel,
/// write to a temporary file renamed over `out` only when all succeeded.
/// With `grid`, a correction table instead; with `cartesian`, the targets to
/// send to a closed controller.
pub fn run_compensate(run: &crate::Run<'_>, c: CompensateConfig) -> Result<()> {
    let description = read_description(run, c.mechanism.as_deref())?;
    let units = crate::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let params = crate::io::params_or_nominal(run, c.params.as_deref(), &mech)?;
    let controller = crate::io::params_or_nominal(run, c.controller.as_deref(), &mech)?;
    let opts = CompensationOptions {
        force: crate::io::checked_load(c.load.clone(), &mech, &params)?,
        preload: match &c.preload {
            Some(s) => {
                let t = crate::io::parse_load(s, "--preload")?;
                if t.len() != spec.n_actuated() {
                    return crate::output::usage(format!(
                        "--preload needs {} torques (one per actuator), got {}",
                        spec.n_actuated(),
                        t.len()
                    ));
                }
                t
            }
            None => vec![],
        },
    };
    if c.cartesian && !opts.preload.is_empty() {
        return crate::output::usage(
            "--preload needs actuator commands; a closed controller given tool targets cannot hold one (drop --cartesian or --preload)",
        );
    }
    if let Some(g) = &c.grid {
        return run_grid(run, &mech, &params, g, &c, &opts, &units);
    }
    let Some(targets) = &c.targets else {
        return crate::output::usage("give --targets T.csv or --grid AXIS=START:STOP:STEP,…");
    };
    // Read once, in batches (a pipe works; memory flat in the rows); its
    // targets in its own units (its units line, else the run's).
    let mut input = crate::io::CsvStream::open(run, targets)?;
    let (cf, tf) = (
        crate::fileunits::commands(spec, &units),
        crate::fileunits::tool(spec, &units),
    );
    let tf_in = crate::fileunits::tool(
        spec,
        &crate::fileunits::for_file(run, &units, input.units.as_ref(), &input.path),
    );
    let names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let cols = input.columns(&names)?;
    let act = spec.actuated_names();
    let cmd_units = spec.command_units();
    let mut w = run.files.writer(&c.out)?;
    let result = (|| -> Result<(usize, usize)> {
        let mut header: Vec<String> = names.clone();
        // Output factors, column by column.
        let mut factors: Vec<f64> = tf.clone();
        if c.cartesian {
            header.extend(spec.tool_axes.iter().map(|a| format!("command_{a}")));
            header.extend(spec.tool_axes.iter().map(|a| format!("delta_{a}")));
            header.extend(act.iter().map(|s| s.to_string()));
            factors.extend(tf.iter().chain(&tf).chain(&cf));
        } else {
            header.extend(act.iter().map(|s| s.to_string()));
            header.extend(act.iter().map(|s| format!("delta_{s}")));
            header.extend(act.iter().zip(&cmd_units).map(|(s, u)| load_column(s, *u)));
            factors.extend(cf.iter().chain(&cf));
            factors.extend(std::iter::repeat_n(1.0, act.len()));
        }
        if let Some(u) = crate::fileunits::comment(&units) {
            writeln!(w, "{u}")?;
        }
        writeln!(w, "{}", header.join(","))?;
        let (mut done, mut skipped) = (0usize, 0usize);
        loop {
            let mut batch = input.batch(&cols, &names, BATCH_ROWS)?;
            if batch.is_empty() {
                break;
            }
            for (_, t) in batch.iter_mut() {
                for (v, f) in t.iter_mut().zip(&tf_in) {
                    *v *= f;
                }
            }
            let results: Vec<Result<Vec<f64>, pkmcal::Error>> = batch
                .par_iter()
                .map(|(_, t)| {
                    if c.cartesian {
                        pkmcal::predistort(&mech, &controller, &params, t, c.model, &opts).map(
                            |p| {
                                let delta: Vec<f64> =
                                    p.command_target.iter().zip(t).map(|(a, b)| a - b).collect();
                                p.command_target
                                    .iter()
                                    .chain(&delta)
                                    .chain(&p.commands)
                                    .copied()
                                    .collect()
                            },
                        )
                    } else {
                        compensate(&mech, &params, t, c.model, &opts).map(|comp| {
                            comp.commands
                                .iter()
                                .chain(&comp.correction)
                                .chain(&comp.torque)
                                .copied()
                                .collect()
                        })
                    }
                })
                .collect();
            for ((line, t), r) in batch.iter().zip(results) {
                match r {
                    Ok(vals) => {
                        let vals: Vec<String> = t
                            .iter()
                            .chain(&vals)
                            .zip(&factors)
                            .map(|(v, f)| crate::io::number(crate::fileunits::to_file(*v, *f)))
                            .collect();
                        writeln!(w, "{}", vals.join(","))?;
                        done += 1;
                    }
                    Err(e) if c.skip_unreachable => {
                        crate::note!("{}:{line}: skipped: {e}", targets.display());
                        skipped += 1;
                    }
                    Err(e) => bail!(
                        "{}:{line}: {e} (use --skip-unreachable to skip such rows)",
                        targets.display()
                    ),
                }
            }
        }
        w.flush()?;
        Ok((done, skipped))
    })();
    let (done, skipped) = result?;
    crate::note!(
        "{} {done} targets{} ({} model) -> {}",
        if c.cartesian {
            "pre-distorted"
        } else {
            "compensated"
        },
        if skipped > 0 {
            format!(", skipped {skipped}")
        } else {
            String::new()
        },
        c.model.name(),
        c.out.display()
    );
    Ok(())
}

/// Parse `x=-100:100:10,y=50,…` into gridded axes and held values (file
/// units, converted with the tool factors `tf`); unnamed axes are held at
/// the middle of the workspace box.
pub fn parse_grid(
    spec: &pkmcal::Spec,
    text: &str,
    tf: &[f64],
) -> Result<(Vec<pkmcal::GridAxis>, Vec<f64>)> {
    let mut fixed: Vec<f64> = spec
        .workspace_box
        .iter()
        .map(|b| 0.5 * (b[0] + b[1]))
        .collect();
    let mut axes = vec![];
    let mut seen = vec![];
    for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let bad = |why: &str| {
            crate::output::Usage(format!(
                "--grid: `{item}`: {why}; write AXIS=START:STOP:STEP or AXIS=VALUE, e.g. x=-100:100:10"
            ))
        };
        let (name, value) = item.split_once('=').ok_or_else(|| bad("no `=`"))?;
        let name = name.trim();
        let k = spec
            .tool_axes
            .iter()
            .position(|a| a == name)
            .ok_or_else(|| {
                bad(&format!(
                    "`{name}` is not a tool axis ({})",
                    spec.tool_axes.join(", ")
                ))
            })?;
        if seen.contains(&k) {
            return Err(bad("axis given twice").into());
        }
        seen.push(k);
        let nums: Vec<f64> = value
            .split(':')
            .map(|v| v.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad("not numbers"))?;
        if nums.iter().any(|v| !v.is_finite()) {
            return Err(bad("not finite").into());
        }
        match nums[..] {
            [v] => fixed[k] = v * tf[k],
            [a, b, step] => {
                if step <= 0.0 || b < a {
                    return Err(bad("needs START ≤ STOP and a positive STEP").into());
                }
                // Counted in floating point first: a tiny step must not wrap
                // the count around.
                let steps = ((b - a) / step + 1e-9).floor();
                if steps.is_nan() || steps >= pkmcal::apply::compensation::MAX_GRID_NODES as f64 {
                    return Err(bad("too many nodes; use a larger step").into());
                }
                let count = steps as usize + 1;
                if count > pkmcal::apply::compensation::MAX_GRID_NODES {
                    return Err(bad("too many nodes; use a larger step").into());
                }
                axes.push((
                    k,
                    pkmcal::GridAxis {
                        name: name.to_string(),
                        unit: spec.tool_units[k],
                        start: a * tf[k],
                        step: step * tf[k],
                        count,
                    },
                ));
            }
            _ => return Err(bad("give one value or START:STOP:STEP").into()),
        }
    }
    if axes.is_empty() {
        return Err(crate::output::Usage(
            "--grid needs at least one gridded axis, AXIS=START:STOP:STEP".into(),
        )
        .into());
    }
    axes.sort_by_key(|(k, _)| *k);
    Ok((axes.into_iter().map(|(_, a)| a).collect(), fixed))
}

/// The correction table of `compensate --grid`, as JSON.
#[derive(serde::Serialize)]
struct GridFile<'a> {
    mechanism: &'a str,
    model: &'a str,
    /// How a controller uses the table.
    usage: &'static str,
    units: pkmcal::FileUnits,
    /// Gridded axes (values in the file's units).
    axes: Vec<pkmcal::GridAxis>,
    /// Value of every tool axis not gridded.
    held: std::collections::BTreeMap<String, f64>,
    actuators: Vec<GridActuator>,
    /// Corrections per node, row-major (the last axis fastest); `null` where
    /// the node is unreachable or singular.
    corrections: Vec<Option<Vec<f64>>>,
    interpolation_error: pkmcal::InterpolationError,
}

#[derive(serde::Serialize)]
struct GridActuator {
    name: String,
    unit: &'static str,
}

fn run_grid(
    run: &crate::Run<'_>,
    mech: &crate::io::Mech,
    params: &Params,
    text: &str,
    c: &CompensateConfig,
    opts: &CompensationOptions,
    units: &pkmcal::FileUnits,
) -> Result<()> {
    let spec = mech.spec();
    let (cf, tf) = (
        crate::fileunits::commands(spec, units),
        crate::fileunits::tool(spec, units),
    );
    let (axes, fixed) = parse_grid(spec, text, &tf)?;
    let grid = pkmcal::correction_grid(mech, params, &axes, &fixed, c.model, opts)?;
    let reachable = grid.nodes.iter().filter(|n| n.is_some()).count();
    if reachable == 0 {
        bail!(
            "no node of the grid {text} is reachable; choose ranges inside the workspace (box: {})",
            spec.tool_axes
                .iter()
                .zip(&spec.workspace_box)
                .zip(&tf)
                .map(|((a, b), f)| format!("{a} {}..{}", b[0] / f, b[1] / f))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let err = pkmcal::interpolation_error(mech, params, &grid, c.model, opts)?;
    let act = spec.actuated_names();
    let cmd_units = spec.command_units();
    let file_axes: Vec<pkmcal::GridAxis> = grid
        .axes
        .iter()
        .zip(&grid.axis_index)
        .map(|(a, &k)| pkmcal::GridAxis {
            start: a.start / tf[k],
            step: a.step / tf[k],
            ..a.clone()
        })
        .collect();
    let held: std::collections::BTreeMap<String, f64> = (0..spec.tool_axes.len())
        .filter(|k| !grid.axis_index.contains(k))
        .map(|k| (spec.tool_axes[k].clone(), fixed[k] / tf[k]))
        .collect();
    let describe = format!(
        "{}{}",
        file_axes
            .iter()
            .map(|a| format!(
                "{} = {}:{}:{} ({} nodes)",
                a.name,
                a.start,
                a.node(a.count - 1),
                a.step,
                a.count
            ))
            .collect::<Vec<_>>()
            .join(", "),
        if held.is_empty() {
            String::new()
        } else {
            format!(
                "; held: {}",
                held.iter()
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        }
    );
    let usage = "command = nominal model's command + correction interpolated multilinearly in the grid cell";
    let json = c
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let bytes = if json {
        let f = GridFile {
            mechanism: &spec.name,
            model: c.model.name(),
            usage,
            units: *units,
            axes: file_axes.clone(),
            held: held.clone(),
            actuators: act
                .iter()
                .zip(&cmd_units)
                .map(|(n, u)| GridActuator {
                    name: n.to_string(),
                    unit: units.symbol(*u, pkmcal::Role::Command),
                })
                .collect(),
            corrections: grid
                .nodes
                .iter()
                .map(|n| {
                    n.as_ref()
                        .map(|comp| crate::fileunits::row_to_file(&comp.correction, &cf))
                })
                .collect(),
            interpolation_error: pkmcal::InterpolationError {
                command_max: crate::fileunits::row_to_file(&err.command_max, &cf),
                ..err.clone()
            },
        };
        let mut b = serde_json::to_vec_pretty(&f)?;
        b.push(b'\n');
        b
    } else {
        let mut out = String::new();
        if let Some(u) = crate::fileunits::comment(units) {
            out.push_str(&format!("{u}\n"));
        }
        out.push_str(&format!("# correction grid: {describe}\n# {usage}; empty fields: node unreachable or outside the usable workspace\n"));
        out.push_str(&format!(
            "# interpolation error at {} cell centres: {}\n",
            err.points,
            interpolation_summary(&err)
        ));
        let mut header: Vec<String> = spec
            .tool_axes
            .iter()
            .map(|a| format!("target_{a}"))
            .collect();
        header.extend(act.iter().map(|s| s.to_string()));
        header.extend(act.iter().map(|s| format!("delta_{s}")));
        header.extend(act.iter().zip(&cmd_units).map(|(s, u)| load_column(s, *u)));
        out.push_str(&header.join(","));
        out.push('\n');
        for (n, node) in grid.nodes.iter().enumerate() {
            let t = grid.target(n);
            let mut fields: Vec<String> = t
                .iter()
                .zip(&tf)
                .map(|(v, f)| crate::io::number(crate::fileunits::to_file(*v, *f)))
                .collect();
            match node {
                Some(comp) => fields.extend(
                    comp.commands
                        .iter()
                        .zip(&cf)
                        .chain(comp.correction.iter().zip(&cf))
                        .map(|(v, f)| crate::io::number(crate::fileunits::to_file(*v, *f)))
                        .chain(comp.torque.iter().map(|v| crate::io::number(*v))),
                ),
                None => fields.extend(std::iter::repeat_n(String::new(), 3 * act.len())),
            }
            out.push_str(&fields.join(","));
            out.push('\n');
        }
        out.into_bytes()
    };
    run.files.stage(&c.out, &bytes)?;
    crate::note!(
        "correction grid {describe}: {reachable} of {} nodes reachable and usable ({} model) -> {}",
        grid.len(),
        c.model.name(),
        c.out.display()
    );
    crate::note!(
        "interpolation error at {} cell centres: {}",
        err.points,
        interpolation_summary(&err)
    );
    Ok(())
}

/// `position max 0.41 µm, RMS 0.12 µm` (and angles when the tool has them).
fn interpolation_summary(e: &pkmcal::InterpolationError) -> String {
    let (f, u) = pkmcal::Unit::Millimetre.readable(e.position_max);
    let mut s = format!(
        "position max {:.3} {u} (at {:?}), RMS {:.3} {u}",
        e.position_max * f,
        e.worst_target,
        e.position_rms * f
    );
    if e.angle_max > 0.0 {
        let (fa, ua) = pkmcal::Unit::Radian.readable(e.angle_max);
        s.push_str(&format!(", angle max {:.3} {ua}", e.angle_max * fa));
    }
    s
}

pub struct PlanConfig {
    pub mechanism: Option<PathBuf>,
    pub count: usize,
    pub candidates: f64,
    pub max_candidates: usize,
    pub criterion: PlanCriterion,
    pub model: Model,
    pub params: Option<PathBuf>,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub out: PathBuf,
    pub grid_out: Option<PathBuf>,
    /// Priors (`--tolerance`, the file's table unless `--no-tolerances`) and
    /// the instrument's noise the poses are weighed with against them.
    pub tolerances: Vec<String>,
    pub no_tolerances: bool,
    pub noise: f64,
    pub angle_noise: Option<f64>,
}

pub fn run_plan(run: &crate::Run<'_>, c: PlanConfig) -> Result<()> {
    let description = read_description(run, c.mechanism.as_deref())?;
    let units = crate::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let params = crate::io::params_or_nominal(run, c.params.as_deref(), &mech)?;
    let tool = pkmcal::MeasurementModel::tool(spec);
    let (priors, free) = crate::budget::priors_and_free(
        &mech,
        &tool,
        &crate::budget::Tolerances {
            table: &description.tolerances,
            file: description.path.as_deref(),
            items: &c.tolerances,
            off: c.no_tolerances,
        },
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    let n_priors = priors.len();
    let noise = crate::io::noise_arg(c.noise, c.angle_noise);
    if !(c.candidates.is_finite() && c.candidates > 0.0) {
        return crate::output::usage("--candidates must be a positive spacing in mm");
    }
    // Too few poses for the free set is the command line's (--count, --free).
    if let Err(e) = pkmcal::apply::planning::check_count(c.count, spec.tool_axes.len(), free.len())
    {
        return crate::output::usage(format!("--count: {e}"));
    }
    let bar = run.bar(0, false, "planning steps", 0);
    let plan = pkmcal::apply::planning::plan(
        &mech,
        &params,
        &pkmcal::apply::planning::PlanOptions {
            count: c.count,
            criterion: c.criterion,
            model: c.model,
            free: free.clone(),
            spacing: c.candidates,
            max_candidates: c.max_candidates,
            cancel: None,
            priors,
            noise,
        },
        &|| {
            bar.inc_length(1);
            bar.inc(1);
        },
    )?;
    bar.finish();
    let (spacing, lattice_points, n_candidates) =
        (plan.spacing, plan.lattice_points, plan.candidates);
    let mut header: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    header.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    let factors: Vec<f64> = crate::fileunits::tool(spec, &units)
        .into_iter()
        .chain(crate::fileunits::commands(spec, &units))
        .collect();
    let rows = |set: &[pkmcal::WorkspacePoint]| -> Vec<Vec<f64>> {
        set.iter()
            .map(|p| {
                let row: Vec<f64> = p
                    .target
                    .iter()
                    .copied()
                    .chain(spec.actuated.iter().map(|&j| p.q[j]))
                    .collect();
                crate::fileunits::row_to_file(&row, &factors)
            })
            .collect()
    };
    let file = |set: &[pkmcal::WorkspacePoint]| {
        crate::fileunits::with_comment(csv_bytes(&header, &rows(set)), &units)
    };
    run.files.stage(&c.out, &file(&plan.poses))?;
    if let Some(g) = &c.grid_out {
        run.files.stage(g, &file(&plan.grid))?;
    }
    println!(
        "planned {} poses of {} candidates (spacing {:.4} mm{}) maximising {:?} for {} free parameters ({} model){}",
        c.count,
        n_candidates,
        spacing,
        {
            let mut notes = String::new();
            if spacing > c.candidates {
                notes.push_str(&format!(
                    ", coarsened from {} mm to stay within {} lattice points",
                    c.candidates,
                    pkmcal::apply::planning::MAX_CANDIDATE_LATTICE
                        .min(c.max_candidates.saturating_mul(4))
                ));
            }
            if lattice_points > n_candidates {
                notes.push_str(&format!(
                    ", {lattice_points} usable lattice points thinned evenly to --max-candidates"
                ));
            }
            notes
        },
        c.criterion,
        free.len(),
        c.model.name(),
        if n_priors > 0 {
            format!(
                ", given {} (poses measured with {} mm of noise)",
                pkmcal::error::count(n_priors, "tolerance", "tolerances"),
                noise.length
            )
        } else {
            String::new()
        }
    );
    println!(
        "  {:<14} {:>11} {:>11} {:>11} {:>11} {:>11} {:>10}",
        "", "O1", "O2", "O3", "O4", "O5", "cond"
    );
    for (label, o, cond) in [
        ("planned", &plan.observability, plan.condition),
        ("plain grid", &plan.grid_observability, plan.grid_condition),
    ] {
        println!(
            "  {label:<14} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>10.2}",
            o.o1, o.o2, o.o3, o.o4, o.o5, cond
        );
    }
    for w in &plan.warnings {
        println!(
            "warning: {}\n  hint: {}",
            w.message,
            crate::calibrate::cli_hint(w)
        );
    }
    println!("poses -> {}", c.out.display());
    if let Some(g) = &c.grid_out {
        println!("plain grid -> {}", g.display());
    }
    Ok(())
}

pub struct MonteCarloConfig {
    pub mechanism: Option<PathBuf>,
    pub poses: PathBuf,
    pub runs: usize,
    pub noise: f64,
    pub seed: u64,
    pub model: Model,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub length_error: f64,
    pub angle_error: f64,
    pub angle_noise: Option<f64>,
    pub validation: usize,
    pub out: Option<PathBuf>,
    /// `--tolerance` items and `--no-tolerances`: priors, and the truth of
    /// each run drawn from them.
    pub tolerances: Vec<String>,
    pub no_tolerances: bool,
}

/// A plan's poses (`target_<axis>` columns, e.g. `plan`'s output) in
/// internal units, each checked reachable by nominal inverse kinematics
/// (an error names the file and line).
pub fn read_plan_poses(
    run: &crate::Run<'_>,
    path: &std::path::Path,
    mech: &crate::io::Mech,
    units: &pkmcal::FileUnits,
) -> Result<Vec<Vec<f64>>> {
    let spec = mech.spec();
    let csv = Csv::read(run, path)?;
    csv.require_rows()?;
    let names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let mut poses = csv.named(&names)?;
    let units = crate::fileunits::for_file(run, units, csv.units.as_ref(), &csv.path);
    crate::fileunits::to_internal(&mut poses, &crate::fileunits::tool(spec, &units));
    for (i, t) in poses.iter().enumerate() {
        pkmcal::nominal_commands(mech, t)
            .with_context(|| format!("{}:{}", path.display(), csv.line(i)))?;
    }
    Ok(poses)
}

pub fn run_montecarlo(run: &crate::Run<'_>, c: MonteCarloConfig) -> Result<()> {
    let description = read_description(run, c.mechanism.as_deref())?;
    let units = crate::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    if c.runs == 0 {
        return crate::output::usage("--runs must be at least 1");
    }
    let noise = crate::io::noise_arg(c.noise, c.angle_noise);
    for (v, name) in [
        (c.length_error, "--length-error"),
        (c.angle_error, "--angle-error"),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            bail!("{name} must be a non-negative number");
        }
    }
    let poses = read_plan_poses(run, &c.poses, &mech, &units)?;
    let mut cal = CalibrationOptions::new(spec, c.model);
    let tool = pkmcal::MeasurementModel::tool(spec);
    (cal.priors, cal.free) = crate::budget::priors_and_free(
        &mech,
        &tool,
        &crate::budget::Tolerances {
            table: &description.tolerances,
            file: description.path.as_deref(),
            items: &c.tolerances,
            off: c.no_tolerances,
        },
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    let validation = pkmcal::validation_targets(&mech, c.validation, c.seed)?;
    let bar = run.bar(c.runs as u64, false, "calibrations", 1);
    let opts = MonteCarloOptions {
        runs: c.runs,
        noise,
        seed: c.seed,
        length_error: c.length_error,
        angle_error: c.angle_error,
        calibration: cal,
    };
    let start = std::time::Instant::now();
    let (runs, summary) = monte_carlo(&mech, &poses, &validation, &opts, &|| bar.inc(1))?;
    bar.finish();
    let secs = start.elapsed().as_secs_f64();
    println!(
        "{} simulated calibrations ({} model) from {} poses of {}: {} converged ({:.0} calibrations/s)",
        summary.runs,
        c.model.name(),
        poses.len(),
        c.poses.display(),
        summary.converged,
        summary.runs as f64 / secs
    );
    let n_priors = opts.calibration.priors.len();
    println!(
        "random errors: {}σ {} mm on free parameters in mm, σ {} rad on free parameters in rad{}; noise σ {} mm on lengths{}",
        if n_priors > 0 {
            format!(
                "drawn from {} (also the fits' priors), ",
                pkmcal::error::count(n_priors, "tolerance", "tolerances")
            )
        } else {
            String::new()
        },
        c.length_error,
        c.angle_error,
        if n_priors > 0 { " otherwise" } else { "" },
        noise.length,
        if spec.tool_units.contains(&pkmcal::Unit::Radian) {
            format!(", {} rad on angles", noise.angle)
        } else {
            String::new()
        }
    );
    println!(
        "accuracy on {} unseen poses after calibration: RMS median {:.4} mm, 95th percentile {:.4} mm; max error median {:.4} mm",
        c.validation,
        summary.validation_rms_median,
        summary.validation_rms_p95,
        summary.validation_max_median
    );
    println!("parameter errors (RMS over runs):");
    for (n, e) in summary.parameters.iter().zip(&summary.parameter_rms_error) {
        let i = spec.param_index(n)?;
        println!("  {n:<6} {e:>12.4e} {}", spec.param_unit(i));
    }
    if let Some(out) = &c.out {
        let mut header = vec![
            "run".to_string(),
            "converged".into(),
            "validation_rms".into(),
            "validation_max".into(),
        ];
        header.extend(summary.parameters.iter().map(|n| format!("error_{n}")));
        let rows: Vec<Vec<f64>> = runs
            .iter()
            .enumerate()
            .map(|(i, r)| {
                [
                    i as f64,
                    f64::from(u8::from(r.converged)),
                    r.validation.distance_rms,
                    r.validation.distance_max,
                ]
                .into_iter()
                .chain(r.parameter_errors.iter().copied())
                .collect()
            })
            .collect();
        run.files.stage(out, &csv_bytes(&header, &rows))?;
        println!("runs -> {}", out.display());
    }
    Ok(())
}
