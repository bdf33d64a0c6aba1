//! `compensate`, `plan` and `montecarlo`: using a calibration.

use crate::calibrate::free_set;
use crate::io::{Csv, csv_bytes, read_mechanism, read_params};
use anyhow::{Context, Result, bail};
use pkmcal::{
    CalibrationOptions, CompensationOptions, Mechanism, Model, MonteCarloOptions, Params,
    PlanCriterion, candidate_jacobians, compensate, grid_targets, monte_carlo, plan_observability,
    plan_poses, random_targets, sample_workspace,
};
use rayon::prelude::*;
use std::io::Write;
use std::path::PathBuf;

/// Rows compensated per parallel batch (bounded memory for any file size).
const BATCH_ROWS: usize = 1 << 16;

pub struct CompensateConfig {
    pub mechanism: Option<PathBuf>,
    pub params: Option<PathBuf>,
    pub targets: PathBuf,
    pub model: Model,
    pub load: Option<String>,
    pub preload: Option<String>,
    pub skip_unreachable: bool,
    pub out: PathBuf,
}

/// Stream the targets file in batches, compensate each batch in parallel,
/// write to a temporary file renamed over `out` only when all succeeded.
pub fn run_compensate(c: CompensateConfig) -> Result<()> {
    let mech = read_mechanism(c.mechanism.as_deref())?;
    let spec = mech.spec();
    let params = match &c.params {
        Some(p) => read_params(p, &mech)?,
        None => Params::nominal(spec),
    };
    let nx = spec.tool_axes.len();
    let opts = CompensationOptions {
        force: match &c.load {
            Some(s) => {
                let f = crate::io::parse_load(s, "--load")?;
                if f.len() != nx {
                    return crate::output::usage(format!(
                        "--load needs {nx} values, got {}",
                        f.len()
                    ));
                }
                f
            }
            None => vec![],
        },
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
    if c.model == Model::Linear {
        bail!("compensation inverts the exact model (or the rigid one); use --model exact");
    }
    // Read once, in batches (a pipe works; memory flat in the rows).
    let mut input = crate::io::CsvStream::open(&c.targets)?;
    let names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let cols = input.columns(&names)?;
    let mut w = crate::output::writer(&c.out)?;
    let result = (|| -> Result<(usize, usize)> {
        let mut header: Vec<String> = names.clone();
        header.extend(spec.actuated_names().iter().map(|s| s.to_string()));
        header.extend(spec.actuated_names().iter().map(|s| format!("torque_{s}")));
        writeln!(w, "{}", header.join(","))?;
        let (mut done, mut skipped) = (0usize, 0usize);
        loop {
            let batch = input.batch(&cols, &names, BATCH_ROWS)?;
            if batch.is_empty() {
                break;
            }
            let results: Vec<_> = batch
                .par_iter()
                .map(|(_, t)| compensate(&mech, &params, t, c.model, &opts))
                .collect();
            for ((line, t), r) in batch.iter().zip(results) {
                match r {
                    Ok(comp) => {
                        let vals: Vec<String> = t
                            .iter()
                            .chain(&comp.commands)
                            .chain(&comp.torque)
                            .map(|v| format!("{v}"))
                            .collect();
                        writeln!(w, "{}", vals.join(","))?;
                        done += 1;
                    }
                    Err(e) if c.skip_unreachable => {
                        eprintln!("{}:{line}: skipped: {e}", c.targets.display());
                        skipped += 1;
                    }
                    Err(e) => bail!(
                        "{}:{line}: {e} (use --skip-unreachable to skip such rows)",
                        c.targets.display()
                    ),
                }
            }
        }
        w.flush()?;
        Ok((done, skipped))
    })();
    let (done, skipped) = result?;
    eprintln!(
        "compensated {done} targets{} ({} model) -> {}",
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

pub struct PlanConfig {
    pub mechanism: Option<PathBuf>,
    pub count: usize,
    pub candidates: f64,
    pub criterion: PlanCriterion,
    pub model: Model,
    pub params: Option<PathBuf>,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub out: PathBuf,
    pub grid_out: Option<PathBuf>,
}

pub fn run_plan(c: PlanConfig) -> Result<()> {
    let mech = read_mechanism(c.mechanism.as_deref())?;
    let spec = mech.spec();
    let params = match &c.params {
        Some(p) => read_params(p, &mech)?,
        None => Params::nominal(spec),
    };
    let free = free_set(
        &mech,
        &pkmcal::MeasurementModel::tool(spec),
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    if !(c.candidates.is_finite() && c.candidates > 0.0) {
        return crate::output::usage("--candidates must be a positive spacing in mm");
    }
    if c.count * spec.tool_axes.len() <= free.len() {
        bail!(
            "{} poses give too few coordinates for {} free parameters; plan at least {}",
            c.count,
            free.len(),
            free.len() / spec.tool_axes.len() + 1
        );
    }
    let spacing = pkmcal::workspace::lattice_spacing(
        spec,
        c.candidates,
        pkmcal::planning::MAX_CANDIDATE_LATTICE,
    );
    let mut points = sample_workspace(&mech, spacing);
    let n_candidates = points.len();
    // The plain grid of the same size, judged with the same column scaling.
    let grid = grid_targets(&mech, c.count)?;
    points.extend(grid);
    let cands = candidate_jacobians(&mech, points, &params, c.model, &free)?;
    let pool: Vec<usize> = (0..n_candidates).collect();
    let sub = pkmcal::planning::Candidates {
        points: pool.iter().map(|&i| cands.points[i].clone()).collect(),
        rows: pool.iter().map(|&i| cands.rows[i].clone()).collect(),
    };
    let chosen = plan_poses(&sub, c.count, c.criterion)?;
    let (planned, pcond) = plan_observability(&cands, &chosen);
    let grid_idx: Vec<usize> = (n_candidates..n_candidates + c.count).collect();
    let (grid_o, gcond) = plan_observability(&cands, &grid_idx);
    let mut header: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    header.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    let rows = |set: &[usize]| -> Vec<Vec<f64>> {
        set.iter()
            .map(|&i| {
                let p = &cands.points[i];
                p.target
                    .iter()
                    .copied()
                    .chain(spec.actuated.iter().map(|&j| p.q[j]))
                    .collect()
            })
            .collect()
    };
    crate::output::stage(&c.out, &csv_bytes(&header, &rows(&chosen)))?;
    if let Some(g) = &c.grid_out {
        crate::output::stage(g, &csv_bytes(&header, &rows(&grid_idx)))?;
    }
    println!(
        "planned {} poses of {} candidates (spacing {:.4} mm{}) maximising {:?} for {} free parameters ({} model)",
        c.count,
        n_candidates,
        spacing,
        if spacing > c.candidates {
            format!(
                ", coarsened from {} mm to stay within {} lattice points",
                c.candidates,
                pkmcal::planning::MAX_CANDIDATE_LATTICE
            )
        } else {
            String::new()
        },
        c.criterion,
        free.len(),
        c.model.name()
    );
    println!(
        "  {:<14} {:>11} {:>11} {:>11} {:>11} {:>11} {:>10}",
        "", "O1", "O2", "O3", "O4", "O5", "cond"
    );
    for (label, o, cond) in [("planned", &planned, pcond), ("plain grid", &grid_o, gcond)] {
        println!(
            "  {label:<14} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>10.2}",
            o.o1, o.o2, o.o3, o.o4, o.o5, cond
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
    pub quiet: bool,
}

pub fn run_montecarlo(c: MonteCarloConfig) -> Result<()> {
    let mech = read_mechanism(c.mechanism.as_deref())?;
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
    let csv = Csv::read(&c.poses)?;
    csv.require_rows()?;
    let names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let poses = csv.named(&names)?;
    for (i, t) in poses.iter().enumerate() {
        pkmcal::nominal_commands(&mech, t)
            .with_context(|| format!("{}:{}", c.poses.display(), csv.line(i)))?;
    }
    let mut cal = CalibrationOptions::new(spec, c.model);
    cal.free = free_set(
        &mech,
        &pkmcal::MeasurementModel::tool(spec),
        c.free.as_deref(),
        c.fix.as_deref(),
    )?;
    let validation = random_targets(&mech, c.validation, c.seed ^ 0x5eed)?;
    let bar = crate::io::progress(c.runs as u64, c.quiet, "calibrations", 1);
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
    bar.finish_and_clear();
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
    println!(
        "random errors: σ {} mm on free parameters in mm, σ {} rad on free parameters in rad; noise σ {} mm on lengths{}",
        c.length_error,
        c.angle_error,
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
        crate::output::stage(out, &csv_bytes(&header, &rows))?;
        println!("runs -> {}", out.display());
    }
    Ok(())
}
