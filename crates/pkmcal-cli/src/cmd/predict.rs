//! `predict`: tool positions, deflections and internal torques for actuator
//! commands, streamed.

use crate::args;
use anyhow::{Context, Result};
use pkmcal::{Mechanism, Model, Params, Prediction, predict_pose, prepare_pose};
use pkmcal_io::Run;
use pkmcal_io::io::{Mech, read_description};
use rayon::prelude::*;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Parameter values (flat TOML `name = value`); unnamed parameters stay nominal.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    /// Actuator commands: CSV with one column per actuated joint, named as the
    /// mechanism's joints (q1,q2,q3 for the reference), in rad or mm.
    #[arg(long, value_name = "C.csv")]
    pub commands: PathBuf,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Calibration report (from `calibrate --report`, or Python's
    /// Calibration.save) whose parameter covariance gives each prediction's
    /// standard deviation (columns sigma_<axis>); its parameters are used
    /// unless --params gives others. It must be of this mechanism.
    #[arg(long, value_name = "REPORT.json")]
    pub uncertainty: Option<PathBuf>,
    /// Output CSV.
    #[arg(long, value_name = "OUT.csv")]
    pub out: PathBuf,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.params.clone(),
                Some(self.commands.clone()),
                self.uncertainty.clone(),
            ],
            [self.out.clone()],
        ))
    }
}

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

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let model: Model = a.model;
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
    // The calibration record is read and checked against this mechanism
    // first, so that a report of another mechanism, or a malformed one, is
    // blamed on the report and not on a row of the commands.
    let record = match &a.uncertainty {
        Some(path) => {
            let r = pkmcal_io::io::read_calibration_record(run, path)?;
            r.check(spec).map_err(|e| {
                anyhow::anyhow!(
                    "{}: this calibration cannot serve {}: {e}; give the report of a calibration of this mechanism",
                    path.display(),
                    spec.name
                )
            })?;
            Some(r)
        }
        None => None,
    };
    // The parameters: --params, else the record's, else nominal.
    let params = match (&a.params, &record, &a.uncertainty) {
        (None, Some(r), Some(path)) => r
            .params(spec)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?,
        _ => pkmcal_io::io::params_or_nominal(run, a.params.as_deref(), &mech)?,
    };
    let force = pkmcal_io::io::checked_load(a.load.values(), &mech, &params)?;
    let covariance = record.map(|r| r.covariance);
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
    // The commands in their file's own units (its units line, else the
    // run's); the output in the run's, as its units line says.
    let cf_in = pkmcal_io::fileunits::commands(
        spec,
        &pkmcal_io::fileunits::for_file(run, &units, input.units.as_ref(), &input.path),
    );
    let bar = run.bar(0, false, "poses", 0);
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
        pkmcal_io::fileunits::to_internal(&mut commands, &cf_in);
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
                line.push_str(&pkmcal_io::io::number(pkmcal_io::fileunits::to_file(
                    *v,
                    out_factors[k],
                )));
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
