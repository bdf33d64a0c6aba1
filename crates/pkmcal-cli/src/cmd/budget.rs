//! `budget`: how tight the parts must be: the tool error over the workspace
//! that the parameter tolerances give, each tolerance's share, and what a
//! planned calibration would leave.

use crate::args;
use anyhow::Result;
use pkmcal::apply::budget::{BudgetOptions, PlannedCalibration};
use pkmcal::{Field, Mechanism, Request, RequestError};
use pkmcal_io::Run;
use pkmcal_io::data::read_plan_poses;
use pkmcal_io::description::read_description;
use pkmcal_io::text::budget_words;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    #[command(flatten)]
    pub tolerances: args::ToleranceArg,
    /// Machines drawn from the tolerances to check the first-order figures
    /// through the exact model (0: none).
    #[arg(value_parser = args::values::samples, long, default_value_t = 3000, value_name = "N")]
    pub samples: usize,
    /// Random seed of the samples.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Targets spread over the workspace (a plain grid) the error is taken
    /// over.
    #[arg(value_parser = args::values::targets, long, default_value_t = 200, value_name = "N")]
    pub grid: usize,
    /// A planned calibration: CSV with target_<axis> columns (e.g. from
    /// `plan`); the budget then says what calibrating there would leave.
    #[arg(long, value_name = "POSES.csv")]
    pub poses: Option<PathBuf>,
    /// The planned calibration's instrument: its stated noise.
    #[command(flatten)]
    pub weighing: args::WeighingNoiseArgs,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    /// Write the budget as JSON.
    #[arg(long, value_name = "BUDGET.json")]
    pub out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone(), self.poses.clone()],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = &description.mech;
    let spec = mech.spec();
    let given = a.tolerances.tolerances()?;
    pkmcal::apply::budget::resolve_tolerances(spec, &given)
        .map_err(|e| RequestError::invalid(Field::Tolerances, e.to_string()))?;
    let given = pkmcal::apply::budget::merged_tolerances(&description.tolerances, given);
    if given.is_empty() {
        return crate::words::usage(
            "no tolerance: add a [tolerances] table to the mechanism file (name = σ) or give --tolerance NAME=SIGMA",
        );
    }
    let tolerances = pkmcal::apply::budget::resolve_tolerances(spec, &given)?;
    let targets = pkmcal::apply::budget::budget_targets(mech, a.grid)?;
    let mut request = Request::new(a.model);
    a.weighing.apply(&mut request);
    let calibration = match &a.poses {
        Some(p) => Some(PlannedCalibration {
            targets: read_plan_poses(run, p, mech, &units)?,
            noise: request.weighing_noise(true)?,
        }),
        None => None,
    };
    let opts = BudgetOptions {
        model: a.model,
        force: vec![],
        samples: a.samples,
        seed: a.seed,
        calibration,
    };
    let b = pkmcal::apply::budget::budget(mech, &targets, &tolerances, &opts)?;
    say_raw!(
        "{}",
        budget_words(
            &spec.name,
            &b,
            a.poses.as_ref().map(|p| p.display().to_string())
        )
    );
    if let Some(j) = &a.out {
        run.files
            .stage(j, serde_json::to_string_pretty(&b)?.as_bytes())?;
        say!("budget -> {}", j.display());
    }
    Ok(())
}
