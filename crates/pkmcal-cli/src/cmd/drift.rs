//! `drift`: has the machine changed since its last calibration, or only the
//! noise? Two saved calibrations compared, or one against nominal.

use crate::args;
use anyhow::Result;
use pkmcal::Mechanism;
use pkmcal::identify::Compared;
use pkmcal_io::Run;
use pkmcal_io::description::read_description;
use pkmcal_io::record::read_calibration_record_dof;
use pkmcal_io::text::drift_words;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// The earlier calibration's report (`calibrate --report`); without it,
    /// the nominal values.
    #[arg(long, value_name = "OLD.json")]
    pub old: Option<PathBuf>,
    /// The later calibration's report.
    #[arg(long, value_name = "NEW.json")]
    pub new: PathBuf,
    /// The familywise false-alarm rate (the chance of calling any parameter
    /// drifted when none is).
    #[arg(long, default_value_t = pkmcal::identify::DEFAULT_ALPHA, value_parser = args::values::fraction)]
    pub alpha: f64,
    /// Write the comparison as JSON.
    #[arg(long, value_name = "DRIFT.json")]
    pub out: Option<PathBuf>,
    /// Targets spread over the workspace (a plain grid) where the change at
    /// the tool is judged (0: none).
    #[arg(value_parser = args::values::targets_or_none, long, default_value_t = 100, value_name = "N")]
    pub grid: usize,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.old.clone(),
                Some(self.new.clone()),
            ],
            self.out.clone(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let spec = description.mech.spec();
    let read = |p: &PathBuf| -> Result<Compared> {
        let (r, dof) = read_calibration_record_dof(run, p)?;
        r.checked_params(&description.mech).map_err(|e| {
            anyhow::Error::from(e).context(format!(
                "{}: it cannot be compared on {}",
                p.display(),
                spec.name
            ))
        })?;
        // A record saved before a renaming, in today's names.
        let renamed = r.renamed(spec);
        if !renamed.is_empty() {
            run.note(pkmcal_io::Note::Renamed {
                place: p.display().to_string(),
                renamed,
            });
        }
        Ok(Compared::from_record(&r.in_current_names(spec), dof))
    };
    let new = read(&a.new)?;
    let (old, old_name) = match &a.old {
        Some(p) => (read(p)?, p.display().to_string()),
        None => (Compared::nominal(spec), "the nominal values".to_string()),
    };
    let mut d = pkmcal::identify::drift(&old, &new, a.alpha)?;
    if a.grid > 0 {
        let mech = &description.mech;
        let targets = pkmcal::apply::budget::budget_targets(mech, a.grid)?;
        d.workspace = Some(pkmcal::apply::tooldrift::workspace_drift(
            mech, &old, &new, &targets, a.alpha,
        )?);
    }
    say_raw!(
        "{}",
        drift_words(Some(spec), &d, &old_name, &a.new.display().to_string())
    );
    if let Some(o) = &a.out {
        run.files
            .stage(o, serde_json::to_string_pretty(&d)?.as_bytes())?;
        say!("drift -> {}", o.display());
    }
    Ok(())
}
