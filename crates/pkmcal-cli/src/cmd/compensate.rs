//! `compensate`: the actuator commands (or Cartesian targets) that bring the
//! tool to targets under calibrated parameters.

use crate::args;
use anyhow::{Result, bail};
use pkmcal::{CompensationOptions, Mechanism, Params, compensate};
use pkmcal_io::Run;
use pkmcal_io::description::read_description;
use pkmcal_io::params::params_or_nominal;
use rayon::prelude::*;
use std::io::Write;
use std::path::PathBuf;

/// Rows compensated per parallel batch (bounded memory for any file size).
const BATCH_ROWS: usize = 1 << 16;

/// The name of an actuator's internal load column: `torque_<a>` (N·m) for a
/// revolute actuator, `force_<a>` (N) for a prismatic one.
pub fn load_column(name: &str, unit: pkmcal::Unit) -> String {
    match unit {
        pkmcal::Unit::Radian => format!("torque_{name}"),
        _ => format!("force_{name}"),
    }
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Calibrated parameters (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Targets: CSV with one column target_<axis> per tool axis.
    #[arg(
        long,
        value_name = "T.csv",
        required_unless_present = "table",
        conflicts_with = "table"
    )]
    pub targets: Option<PathBuf>,
    /// A correction table on a regular grid instead of a targets file: per
    /// tool axis `start:stop:step` (gridded) or one value (held), e.g.
    /// `x=-100:100:10,y=50:250:10`; axes not named are held at the middle of
    /// the workspace box. Written as CSV, or JSON if --out ends in .json, with
    /// the interpolation error checked at the cell centres. (`--grid` is its
    /// old spelling.)
    #[arg(
        long,
        alias = "grid",
        value_name = "AXIS=START:STOP:STEP,…",
        allow_hyphen_values = true
    )]
    pub table: Option<String>,
    /// Cartesian pre-distortion for a controller that accepts only tool
    /// targets: write the target to send (command_<axis>) so that the real
    /// machine reaches the wanted one, instead of actuator commands.
    #[arg(long, conflicts_with = "table")]
    pub cartesian: bool,
    /// The controller's own parameter values (flat TOML) for --cartesian;
    /// nominal if omitted. (Corrections are always against the nominal model.)
    #[arg(long, value_name = "P.toml")]
    pub controller: Option<PathBuf>,
    /// Model to invert: exact (deflections included) or rigid.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::INVERTIBLE_MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Actuator torques (N·m) whose internal part is held as a preload.
    #[arg(long, value_name = "T1,T2,T3", allow_hyphen_values = true, value_parser = args::values::load)]
    pub preload: Option<args::Wrench>,
    /// Report unreachable or singular targets and skip them instead of stopping.
    #[arg(long)]
    pub skip_unreachable: bool,
    /// Output CSV: targets, commands, corrections (delta_<actuator>, to add to
    /// the nominal model's commands) and the actuators' internal torques
    /// (torque_<actuator> in N·m) or forces (force_<actuator> in N).
    #[arg(long, value_name = "COMMANDS.csv")]
    pub out: PathBuf,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.params.clone(),
                self.targets.clone(),
                self.controller.clone(),
            ],
            [self.out.clone()],
        ))
    }
}

/// Stream the targets file in batches, compensate each batch in parallel,
/// write to a temporary file renamed over `out` only when all succeeded.
/// With `table`, a correction table instead; with `cartesian`, the targets to
/// send to a closed controller.
pub fn run(run: &Run<'_>, c: Args) -> Result<()> {
    let description = read_description(run, c.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let params = params_or_nominal(run, c.params.as_deref(), &mech)?;
    let controller = params_or_nominal(run, c.controller.as_deref(), &mech)?;
    let opts = CompensationOptions {
        force: pkmcal::identify::request::checked_load(
            &c.load.values(),
            &mech,
            &params,
            pkmcal::Field::Load,
        )?,
        preload: match &c.preload {
            Some(t) => {
                let t = t.0.clone();
                if t.len() != spec.n_actuated() {
                    return crate::words::usage(format!(
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
        return crate::words::usage(
            "--preload needs actuator commands; a closed controller given tool targets cannot hold one (drop --cartesian or --preload)",
        );
    }
    if let Some(g) = &c.table {
        return run_grid(run, &mech, &params, g, &c, &opts, &units);
    }
    let Some(targets) = &c.targets else {
        return crate::words::usage("give --targets T.csv or --table AXIS=START:STOP:STEP,…");
    };
    // Read once, in batches (a pipe works; memory flat in the rows); its
    // targets in its own units (its units line, else the run's).
    let mut input = pkmcal_io::csv::CsvStream::open(run, targets)?;
    let (cf, tf) = (
        pkmcal_io::fileunits::commands(spec, &units),
        pkmcal_io::fileunits::tool(spec, &units),
    );
    let tf_in = pkmcal_io::fileunits::tool(
        spec,
        &pkmcal_io::fileunits::for_file(run, &units, input.units.as_ref(), &input.path),
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
        if let Some(u) = pkmcal_io::fileunits::comment(&units) {
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
                            .map(|(v, f)| {
                                pkmcal_io::csv::number(pkmcal_io::fileunits::to_file(*v, *f))
                            })
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
        "{} {}{} ({} model) -> {}",
        if c.cartesian {
            "pre-distorted"
        } else {
            "compensated"
        },
        pkmcal::error::count(done, "target", "targets"),
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
            crate::words::Usage(format!(
                "--table: `{item}`: {why}; write AXIS=START:STOP:STEP or AXIS=VALUE, e.g. x=-100:100:10"
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
        return Err(crate::words::Usage(
            "--table needs at least one gridded axis, AXIS=START:STOP:STEP".into(),
        )
        .into());
    }
    // The whole grid's nodes, bounded before any work.
    let total = axes
        .iter()
        .fold(1usize, |t, (_, a)| t.saturating_mul(a.count));
    let max = pkmcal::apply::compensation::MAX_GRID_NODES;
    if total > max {
        return Err(crate::words::Usage(format!(
            "--table: `{text}` makes {total} nodes, more than the {max} a table may have; use larger steps"
        ))
        .into());
    }
    axes.sort_by_key(|(k, _)| *k);
    Ok((axes.into_iter().map(|(_, a)| a).collect(), fixed))
}

/// The correction table of `compensate --table`, as JSON.
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
    run: &Run<'_>,
    mech: &pkmcal_io::description::Mech,
    params: &Params,
    text: &str,
    c: &Args,
    opts: &CompensationOptions,
    units: &pkmcal::FileUnits,
) -> Result<()> {
    let spec = mech.spec();
    let (cf, tf) = (
        pkmcal_io::fileunits::commands(spec, units),
        pkmcal_io::fileunits::tool(spec, units),
    );
    let (axes, fixed) = parse_grid(spec, text, &tf)?;
    // The nodes' count is bounded where it is read (MAX_GRID_NODES); the
    // work is shown.
    let total: usize = axes.iter().map(|a| a.count).product();
    let bar = run.bar(total as u64, false, "grid nodes", 0);
    let grid =
        pkmcal::correction_grid_with_progress(mech, params, &axes, &fixed, c.model, opts, &|| {
            bar.inc(1)
        });
    bar.finish();
    let grid = grid?;
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
                        .map(|comp| pkmcal_io::fileunits::row_to_file(&comp.correction, &cf))
                })
                .collect(),
            interpolation_error: pkmcal::InterpolationError {
                command_max: pkmcal_io::fileunits::row_to_file(&err.command_max, &cf),
                ..err.clone()
            },
        };
        let mut b = serde_json::to_vec_pretty(&f)?;
        b.push(b'\n');
        b
    } else {
        let mut out = String::new();
        if let Some(u) = pkmcal_io::fileunits::comment(units) {
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
                .map(|(v, f)| pkmcal_io::csv::number(pkmcal_io::fileunits::to_file(*v, *f)))
                .collect();
            match node {
                Some(comp) => fields.extend(
                    comp.commands
                        .iter()
                        .zip(&cf)
                        .chain(comp.correction.iter().zip(&cf))
                        .map(|(v, f)| pkmcal_io::csv::number(pkmcal_io::fileunits::to_file(*v, *f)))
                        .chain(comp.torque.iter().map(|v| pkmcal_io::csv::number(*v))),
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
