//! `plan`: choose measurement poses that make the parameters most observable.

use crate::args;
use anyhow::Result;
use pkmcal::{Mechanism, PlanCriterion, Request};
use pkmcal_io::Run;
use pkmcal_io::csv::csv_bytes;
use pkmcal_io::description::read_description;
use pkmcal_io::params::params_or_nominal;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Number of poses to choose.
    #[arg(value_parser = args::values::targets, long, value_name = "N")]
    pub count: usize,
    /// Spacing of the candidate lattice over the usable workspace, mm (an
    /// axis in rad is spaced by it over the mechanism's lever arm;
    /// `--candidates` is its old spelling).
    #[arg(value_parser = args::values::spacing, long, alias = "candidates", default_value_t = 6.0, value_name = "MM")]
    pub candidate_spacing: f64,
    /// Most candidates: a lattice with more usable points is thinned evenly
    /// to this many (a 6-DOF workspace has many at any spacing).
    #[arg(value_parser = args::values::count, long, default_value_t = 4000, value_name = "N")]
    pub max_candidates: usize,
    /// Observability index to maximise.
    #[arg(long, default_value = "O5", value_parser = ["O1", "O3", "O5"], ignore_case = true)]
    pub criterion: String,
    /// Model whose identification Jacobian is used.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    /// Expected parameters (nominal if omitted).
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    #[command(flatten)]
    pub weighing: args::WeighingNoiseArgs,
    /// Output CSV: targets and commands (target_x,target_y,q1,q2,q3 for the reference).
    #[arg(long, value_name = "POSES.csv")]
    pub out: PathBuf,
    /// Also write the plain grid of the same size (the baseline), same columns.
    #[arg(long, value_name = "GRID.csv")]
    pub grid_out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone(), self.params.clone()],
            std::iter::once(self.out.clone()).chain(self.grid_out.clone()),
        ))
    }
}

pub fn run(run: &Run<'_>, c: Args) -> Result<()> {
    let description = read_description(run, c.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = &description.mech;
    let spec = mech.spec();
    let params = params_or_nominal(run, c.params.as_deref(), mech)?;
    let tool = pkmcal::MeasurementModel::tool(spec);
    let mut request = Request::new(c.model);
    c.params_set.apply(&mut request);
    c.priors.apply(&mut request)?;
    c.weighing.apply(&mut request);
    crate::cmd::note_renamed(run, spec, &request);
    let (priors, free) = request
        .priors_and_free(spec, &tool, &description.tolerances)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    let n_priors = priors.len();
    let noise = request.weighing_noise(n_priors > 0)?;
    // Too few poses for the free set is the command line's (--count, --free).
    if let Err(e) = pkmcal::apply::planning::check_count(c.count, spec.tool_axes.len(), free.len())
    {
        return crate::words::usage(format!("--count: {e}"));
    }
    let criterion: PlanCriterion = c.criterion.parse()?;
    // The steps foreseen grow as exchange passes improve the plan: the bar
    // follows (shown on a terminal whatever the count: a 48-leg platform
    // takes minutes).
    let foreseen = (c.count as u64).saturating_mul(2);
    let bar = run.bar(
        foreseen,
        false,
        "planning steps (greedy, then up to 20 exchange passes)",
        1,
    );
    let shown = (AtomicU64::new(0), AtomicU64::new(foreseen));
    let plan = pkmcal::apply::planning::plan(
        mech,
        &params,
        &pkmcal::apply::planning::PlanOptions {
            count: c.count,
            criterion,
            model: c.model,
            free: free.clone(),
            spacing: c.candidate_spacing,
            max_candidates: c.max_candidates,
            cancel: None,
            priors,
            noise,
        },
        &|done, total| {
            let (done, total) = (done as u64, total as u64);
            let more = total.saturating_sub(shown.1.swap(total, Ordering::Relaxed));
            if more > 0 {
                bar.inc_length(more);
            }
            bar.inc(done.saturating_sub(shown.0.swap(done, Ordering::Relaxed)));
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
    let factors: Vec<f64> = pkmcal_io::fileunits::tool(spec, &units)
        .into_iter()
        .chain(pkmcal_io::fileunits::commands(spec, &units))
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
                pkmcal_io::fileunits::row_to_file(&row, &factors)
            })
            .collect()
    };
    let file = |set: &[pkmcal::WorkspacePoint]| {
        pkmcal_io::fileunits::with_comment(csv_bytes(&header, &rows(set)), &units)
    };
    run.files.stage(&c.out, &file(&plan.poses))?;
    if let Some(g) = &c.grid_out {
        run.files.stage(g, &file(&plan.grid))?;
    }
    say!(
        "planned {} poses of {} candidates (spacing {:.4} mm{}) maximising {:?} for {} free parameters ({} model){}",
        c.count,
        n_candidates,
        spacing,
        {
            let mut notes = String::new();
            if spacing > c.candidate_spacing {
                notes.push_str(&format!(
                    ", coarsened from {} mm to stay within {} lattice points",
                    c.candidate_spacing,
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
        criterion,
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
    say!(
        "  {:<14} {:>11} {:>11} {:>11} {:>11} {:>11} {:>10}",
        "",
        "O1",
        "O2",
        "O3",
        "O4",
        "O5",
        "cond"
    );
    for (label, o, cond) in [
        ("planned", &plan.observability, plan.condition),
        ("plain grid", &plan.grid_observability, plan.grid_condition),
    ] {
        say!(
            "  {label:<14} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>11.4e} {:>10.2}",
            o.o1,
            o.o2,
            o.o3,
            o.o4,
            o.o5,
            cond
        );
    }
    for w in &plan.warnings {
        say!("warning: {}\n  hint: {}", w.message, crate::words::hint(w));
    }
    say!("poses -> {}", c.out.display());
    if let Some(g) = &c.grid_out {
        say!("plain grid -> {}", g.display());
    }
    Ok(())
}
