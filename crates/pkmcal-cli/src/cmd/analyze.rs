//! `analyze`: the identifiability of the parameters from a data set, without
//! fitting.

use crate::args;
use anyhow::Result;
use pkmcal::error::count;
use pkmcal::{Frame, Measurement, Mechanism, Request};
use pkmcal_io::Run;
use pkmcal_io::data::{Measured, located_in, read_distances, read_measured};
use pkmcal_io::description::read_description;
use pkmcal_io::params::params_or_nominal;
use pkmcal_io::text::write_identifiability;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Measurements (only the commands are used).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    #[command(flatten)]
    pub weighing: args::WeighingNoiseArgs,
    /// Parameter values at which to analyse; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Output: JSON report of the analysis.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    #[command(flatten)]
    pub instrument: args::InstrumentArgs,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                Some(self.data.clone()),
                self.params.clone(),
                self.instrument.setup.clone(),
                self.instrument.distances.clone(),
            ],
            self.report.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let axes = a.instrument.axes();
    let Measured {
        description,
        measurement,
        data,
        units,
    } = read_measured(
        run,
        description,
        &a.data,
        a.instrument.setup.as_deref(),
        a.instrument.frame,
        axes.as_deref(),
    )?;
    let mech = &description.mech;
    let spec = mech.spec();
    let params = params_or_nominal(run, a.params.as_deref(), mech)?;
    let mut request = Request::new(a.model);
    a.params_set.apply(&mut request);
    a.priors.apply(&mut request)?;
    a.weighing.apply(&mut request);
    request.load = a.load.values();
    crate::cmd::note_renamed(run, spec, &request);
    let (priors, free) = request
        .priors_and_free(spec, &measurement, &description.tolerances)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    let force = request.checked_load(mech, &params)?;
    let noise = request.weighing_noise(!priors.is_empty())?;
    let n_data = data.len();
    let distances = a.instrument.distances.as_deref();
    let data: Vec<Measurement> = match distances {
        Some(p) => {
            let pairs = read_distances(run, p, mech, &measurement, &units)?;
            data.into_iter().chain(pairs).collect()
        }
        None => data,
    };
    let id = if priors.is_empty() {
        pkmcal::analyze(mech, &measurement, &data, &params, a.model, &free, &force)
    } else {
        pkmcal::identify::analyze_with_priors(
            mech,
            &measurement,
            &data,
            &params,
            a.model,
            &free,
            &force,
            &priors,
            noise,
        )
    }
    .map_err(|e| located_in(e, &a.data, distances))?;
    if let Some(r) = &a.report {
        run.files
            .stage(r, serde_json::to_string_pretty(&id)?.as_bytes())?;
    }
    say!(
        "identifiability of {} free parameters from {} poses of {}{} ({} model)",
        free.len(),
        n_data,
        a.data.display(),
        match distances {
            Some(p) => format!(" and {} distances of {}", data.len() - n_data, p.display()),
            None => String::new(),
        },
        a.model.name()
    );
    say!(
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
    let mut o = String::new();
    write_identifiability(
        &mut o,
        &id,
        "calibrate fixes",
        crate::words::WORDING.all_correlations,
    );
    say_raw!("{o}");
    say!(
        "  singular values (column-scaled): {}",
        id.singular_values
            .iter()
            .map(|s| format!("{s:.3e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    if !id.held.is_empty() {
        say!(
            "{} the data alone cannot see, held by the tolerances ({} given, readings weighed with {} mm of noise):",
            count(id.held.len(), "direction", "directions"),
            priors.len(),
            noise.length
        );
        for u in &id.held {
            say!("  {}", u.combination);
        }
    }
    if id.unidentifiable.is_empty() {
        say!(
            "all {} free parameters are identifiable{}",
            free.len(),
            if id.held.is_empty() {
                ""
            } else {
                ", with the tolerances"
            }
        );
    } else {
        say!(
            "{} cannot be identified; calibrate fixes one parameter per direction (or use --fix)",
            count(id.unidentifiable.len(), "direction", "directions")
        );
    }
    Ok(())
}
