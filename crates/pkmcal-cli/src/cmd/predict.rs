//! `predict`: tool positions, deflections and internal torques for actuator
//! commands, streamed.

use crate::args;
use anyhow::Result;
use pkmcal::{Mechanism, Model, RowSettings};
use pkmcal_io::Run;
use pkmcal_io::description::read_description;
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
    /// Rows whose commands do not assemble the mechanism on its branch
    /// are written with NaN outputs and listed, instead of stopping the run.
    #[arg(long)]
    pub skip_unreachable: bool,
    /// Also write every joint's value (`joint_<name>`, in the readings'
    /// units): the passive joints, and every platform coordinate of a
    /// spatial mechanism, the ones outside its tool axes included (a 3-PRS
    /// head's parasitic x, y, rz).
    #[arg(long)]
    pub joints: bool,
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

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let model: Model = a.model;
    // Streamed in batches (memory flat in the rows, a pipe works), each
    // batch predicted on all cores.
    let mut input = pkmcal_io::csv::CsvStream::open(run, &a.commands)?;
    pkmcal_io::data::commands_belong(&input.path, &input.headers, spec)?;
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
            let r = pkmcal_io::record::read_calibration_record(run, path)?;
            let params = r.checked_params(&mech).map_err(|e| {
                anyhow::anyhow!(
                    "{}: this calibration cannot serve {}: {e}; give the report of a calibration of this mechanism",
                    path.display(),
                    spec.name
                )
            })?;
            Some((r, params))
        }
        None => None,
    };
    // The parameters: --params, else the record's, else nominal.
    let params = match (&a.params, &record) {
        (None, Some((_, p))) => p.clone(),
        _ => pkmcal_io::params::params_or_nominal(run, a.params.as_deref(), &mech)?,
    };
    let force = pkmcal::identify::request::checked_load(
        &a.load.values(),
        &mech,
        &params,
        pkmcal::Field::Load,
    )?;
    let covariance = record.map(|(r, _)| r.covariance);
    let settings = RowSettings {
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
            .map(|(n, u)| crate::cmd::compensate::load_column(n, u)),
    );
    if covariance.is_some() {
        header.extend(spec.tool_axes.iter().map(|a| format!("sigma_{a}")));
    }
    if a.joints {
        header.extend(spec.joints.iter().map(|j| format!("joint_{j}")));
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
        .chain(if covariance.is_some() {
            tf.clone()
        } else {
            vec![]
        })
        .chain(if a.joints {
            pkmcal_io::fileunits::readings(&spec.joint_units, &units)
        } else {
            vec![]
        })
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
    let width = header.len();
    let mut total = 0usize;
    let mut skipped = 0usize;
    let mut line = String::new();
    loop {
        let batch = input.batch(&cols, &names, PREDICT_BATCH_ROWS)?;
        if batch.is_empty() {
            break;
        }
        bar.inc_length(batch.len() as u64);
        let mut commands: Vec<Vec<f64>> = batch.iter().map(|(_, c)| c.clone()).collect();
        pkmcal_io::fileunits::to_internal(&mut commands, &cf_in);
        let preds = pkmcal::predict_rows(&mech, &settings, &commands, &|n| bar.inc(n));
        let nan = vec![f64::NAN; width - names.len()];
        let mut first_failure = None;
        for (((line_no, _), c), r) in batch.iter().zip(&commands).zip(preds) {
            let outputs: Vec<f64> = match r {
                Ok(r) => {
                    let p = &r.prediction;
                    let sigma = r.covariance.as_ref().map_or(vec![], |c| {
                        (0..c.nrows()).map(|a| c[(a, a)].sqrt()).collect()
                    });
                    let joints: &[f64] = if a.joints { &p.q } else { &[] };
                    p.x.iter()
                        .chain(&p.deflection)
                        .chain(&p.torque)
                        .chain(&sigma)
                        .chain(joints)
                        .copied()
                        .collect()
                }
                Err(e) if a.skip_unreachable => {
                    crate::note!(
                        "{}:{line_no}: skipped (NaN outputs): commands {c:?}: {e}",
                        input.path.display()
                    );
                    skipped += 1;
                    nan.clone()
                }
                Err(e) => {
                    first_failure = Some(anyhow::anyhow!(
                        "{}:{line_no}: commands {c:?}: {e} (use --skip-unreachable to go on past such rows)",
                        input.path.display()
                    ));
                    break;
                }
            };
            line.clear();
            for (k, v) in c.iter().chain(&outputs).enumerate() {
                if k > 0 {
                    line.push(',');
                }
                line.push_str(&pkmcal_io::csv::number(pkmcal_io::fileunits::to_file(
                    *v,
                    out_factors[k],
                )));
            }
            writeln!(w, "{line}")?;
        }
        if let Some(e) = first_failure {
            return Err(
                match pkmcal_io::hints::other_units_for(&mech, &commands, &units) {
                    Some((key, value)) => anyhow::anyhow!(
                        "{e:#}\n  hint: the commands assemble the mechanism if read in another unit: give {}",
                        crate::words::units_option(key, value)
                    ),
                    None => e,
                },
            );
        }
        total += batch.len();
    }
    w.flush()?;
    bar.finish();
    crate::note!(
        "predicted {} with the {} model{} -> {}",
        pkmcal::error::count(total - skipped, "pose", "poses"),
        model.name(),
        if skipped > 0 {
            format!(", skipped {skipped} (NaN rows)")
        } else {
            String::new()
        },
        a.out.display()
    );
    Ok(())
}

/// Rows predicted per batch of a streamed `predict`.
const PREDICT_BATCH_ROWS: usize = 1 << 14;
