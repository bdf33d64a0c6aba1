//! The subcommands: each reads its inputs, calls the library, writes outputs.

use crate::io::{Csv, Mech, csv_bytes, parse_list, read_mechanism, read_params, write_atomic};
use crate::{DemoArgs, PredictArgs, SimulateArgs};
use anyhow::{Context, Result, bail};
use pkmcal::{
    ErrorStats, Mechanism, Model, Params, Prediction, error_stats, predict_pose, prepare_pose,
};
use rayon::prelude::*;
use std::path::Path;

/// Rows per sequential chunk (each chunk warm-starts from its previous row).
const CHUNK_ROWS: usize = 512;

/// Predict every row, in parallel over chunks; the error names the row's line.
pub fn predict_rows(
    mech: &Mech,
    params: &Params,
    commands: &[Vec<f64>],
    model: Model,
    force: &[f64],
    where_: &(dyn Fn(usize) -> String + Sync),
) -> Result<Vec<Prediction>> {
    let chunks: Vec<Result<Vec<Prediction>>> = commands
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
                let p = predict_pose(mech, &pose, params, model, force)
                    .with_context(|| format!("{}: commands {c:?}", where_(row)))?;
                start = Some(pose.nominal_q);
                out.push(p);
            }
            Ok(out)
        })
        .collect();
    let mut all = Vec::with_capacity(commands.len());
    for c in chunks {
        all.extend(c?);
    }
    Ok(all)
}

fn load_params(path: Option<&Path>, mech: &Mech) -> Result<Params> {
    match path {
        Some(p) => read_params(p, mech.spec()),
        None => Ok(Params::nominal(mech.spec())),
    }
}

pub fn predict(a: PredictArgs) -> Result<()> {
    let mech = read_mechanism(a.mechanism.as_deref())?;
    let spec = mech.spec();
    let params = load_params(a.params.as_deref(), &mech)?;
    let model: Model = a.model.parse()?;
    let force = match &a.force {
        Some(s) => {
            let f = parse_list(s, "--force")?;
            if f.len() != spec.tool_axes.len() {
                bail!(
                    "--force needs {} values ({}), got {}",
                    spec.tool_axes.len(),
                    spec.tool_axes.join(","),
                    f.len()
                );
            }
            f
        }
        None => vec![],
    };
    let csv = Csv::read(&a.commands)?;
    csv.require_rows()?;
    let names: Vec<String> = spec
        .actuated_names()
        .iter()
        .map(|s| s.to_string())
        .collect();
    let commands = csv.named(&names)?;
    let preds = predict_rows(&mech, &params, &commands, model, &force, &|r| {
        format!("{}:{}", csv.path.display(), csv.line(r))
    })?;
    let mut header = names.clone();
    header.extend(spec.tool_axes.iter().cloned());
    header.extend(names.iter().map(|n| format!("deflection_{n}")));
    header.extend(names.iter().map(|n| format!("torque_{n}")));
    let rows: Vec<Vec<f64>> = commands
        .iter()
        .zip(&preds)
        .map(|(c, p)| {
            c.iter()
                .chain(&p.x)
                .chain(&p.deflection)
                .chain(&p.torque)
                .copied()
                .collect()
        })
        .collect();
    write_atomic(&a.out, &csv_bytes(&header, &rows))?;
    eprintln!(
        "predicted {} poses with the {} model -> {}",
        rows.len(),
        model.name(),
        a.out.display()
    );
    Ok(())
}

/// Target columns `target_<axis>`.
fn target_names(mech: &Mech) -> Vec<String> {
    mech.spec()
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect()
}

pub fn simulate(a: SimulateArgs) -> Result<()> {
    let mech = read_mechanism(a.mechanism.as_deref())?;
    let truth = load_params(a.truth.as_deref(), &mech)?;
    if !(a.noise >= 0.0 && a.noise.is_finite()) {
        bail!(
            "--noise must be a non-negative number of mm, got {}",
            a.noise
        );
    }
    let targets: Vec<Vec<f64>> = match (&a.targets, a.grid) {
        (Some(path), _) => {
            let csv = Csv::read(path)?;
            csv.require_rows()?;
            let t = csv.named(&target_names(&mech))?;
            for (i, target) in t.iter().enumerate() {
                pkmcal::nominal_commands(&mech, target).with_context(|| {
                    format!("{}:{}: target {target:?}", path.display(), csv.line(i))
                })?;
            }
            t
        }
        (None, Some(n)) => {
            if n == 0 {
                bail!("--grid needs at least one target");
            }
            pkmcal::spread_targets(&mech, n)?
                .into_iter()
                .map(|p| p.target)
                .collect()
        }
        (None, None) => bail!("give --targets FILE or --grid N"),
    };
    let data = pkmcal::simulate(&mech, &truth, &targets, a.noise, a.seed)?;
    write_atomic(&a.out, &data_csv(&mech, &data))?;
    eprintln!(
        "simulated {} poses (noise {} mm, seed {}) -> {}",
        data.len(),
        a.noise,
        a.seed,
        a.out.display()
    );
    Ok(())
}

/// Measurement file: target_*, commands, measured tool coordinates.
pub fn data_csv(mech: &Mech, data: &[pkmcal::Measurement]) -> Vec<u8> {
    let spec = mech.spec();
    let mut header = target_names(mech);
    header.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    header.extend(spec.tool_axes.iter().cloned());
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
                .copied()
                .collect()
        })
        .collect();
    csv_bytes(&header, &rows)
}

fn print_stats(label: &str, s: &ErrorStats) {
    println!(
        "{label:<28} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.4} {:>8.4} {:>8.4} {:>8.4}",
        s.axis_min[0],
        s.axis_max[0],
        s.axis_min[1],
        s.axis_max[1],
        s.distance_min,
        s.distance_mean,
        s.distance_rms,
        s.distance_max
    );
}

pub fn demo(a: DemoArgs) -> Result<()> {
    let mech = Mech::new();
    let spec = mech.spec();
    let truth = pkmcal::reference::demo_truth();
    std::fs::create_dir_all(&a.out_dir)
        .with_context(|| format!("cannot create {}", a.out_dir.display()))?;
    let targets: Vec<Vec<f64>> = pkmcal::spread_targets(&mech, 35)?
        .into_iter()
        .map(|p| p.target)
        .collect();
    let data = pkmcal::simulate(&mech, &truth, &targets, 0.002, a.seed)?;
    let data_path = a.out_dir.join("measurements.csv");
    write_atomic(&data_path, &data_csv(&mech, &data))?;
    let truth_path = a.out_dir.join("truth.toml");
    write_atomic(
        &truth_path,
        crate::io::params_to_string(spec, &truth, "true parameters of the demo (simulated)")
            .as_bytes(),
    )?;
    println!("pkmcal demo: {}", spec.name);
    println!(
        "35 poses over the workspace, paper-sized parameter errors, 2 µm measurement noise (seed {})",
        a.seed
    );
    println!("files: {}, {}", data_path.display(), truth_path.display());
    println!();
    println!(
        "{:<28} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "errors (mm)", "Xmin", "Xmax", "Ymin", "Ymax", "dmin", "dmean", "drms", "dmax"
    );
    let before: Vec<Vec<f64>> = data
        .iter()
        .map(|m| {
            let t = m.target.as_ref().expect("simulated data have targets");
            m.measured.iter().zip(t).map(|(a, b)| a - b).collect()
        })
        .collect();
    print_stats("before calibration", &error_stats(&before));
    Ok(())
}
