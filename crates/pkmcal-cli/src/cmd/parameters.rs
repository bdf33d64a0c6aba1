//! `parameters`: what a mechanism is made of, for writing parameter files,
//! data files and free sets: every parameter (name, kind, unit, nominal
//! value, free by default), the joints, the actuators and the tool axes with
//! the workspace box.

use crate::args;
use anyhow::Result;
use pkmcal::Mechanism;
use pkmcal_io::Run;
use pkmcal_io::description::read_description;
use std::fmt::Write as _;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// JSON on standard output instead of the text tables.
    #[arg(long)]
    pub json: bool,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [self.mech.mechanism.clone()],
            Vec::<std::path::PathBuf>::new(),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let spec = description.mech.spec();
    // The mechanism file's tolerances free their parameters (the rule every
    // fit follows); those naming an instrument's parameters wait for one.
    let names = spec.param_names();
    let table_of_mech: Vec<_> = description
        .tolerances
        .iter()
        .filter(|(n, _)| names.iter().any(|m| m == n))
        .cloned()
        .collect();
    let freed = pkmcal::Request::new(pkmcal::Model::Exact)
        .freed_by_tolerances(spec, &pkmcal::MeasurementModel::tool(spec), &table_of_mech)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    let text = if a.json {
        pkmcal_io::description::summary_json(spec)
    } else {
        table(&pkmcal::summary(spec), &freed)
    };
    say_raw!("{text}");
    Ok(())
}

/// The summary as text tables; `freed` are free by their tolerances.
fn table(s: &pkmcal::MechanismSummary, freed: &[String]) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{}: {} degrees of freedom, {} joints, {} actuators\n",
        s.name,
        s.dof,
        s.joints.len(),
        s.actuators.len()
    );
    let _ = writeln!(
        t,
        "{:<16} {:<15} {:<8} {:>16}  free by default",
        "parameter", "kind", "unit", "nominal"
    );
    for p in &s.parameters {
        let _ = writeln!(
            t,
            "{:<16} {:<15} {:<8} {:>16}  {}",
            p.name,
            p.kind.name(),
            p.unit.symbol(),
            pkmcal_io::csv::number(p.nominal),
            if p.free_by_default {
                "yes"
            } else if freed.contains(&p.name) {
                "yes, by its tolerance ([tolerances])"
            } else {
                ""
            }
        );
    }
    let _ = writeln!(t, "\n{:<16} {:<8} role", "joint", "unit");
    for j in &s.joints {
        let role = match (j.actuated, j.independent) {
            (true, true) => "actuated, independent (drives the rigid model)",
            (true, false) => "actuated",
            (false, _) => "passive",
        };
        let _ = writeln!(t, "{:<16} {:<8} {role}", j.name, j.unit.symbol());
    }
    let _ = writeln!(
        t,
        "\ncommands' columns (actuators): {}",
        s.actuators.join(", ")
    );
    let _ = writeln!(t, "\n{:<16} {:<8} workspace box", "tool axis", "unit");
    for x in &s.tool_axes {
        let _ = writeln!(
            t,
            "{:<16} {:<8} [{}, {}]",
            x.name,
            x.unit.symbol(),
            pkmcal_io::csv::number(x.workspace[0]),
            pkmcal_io::csv::number(x.workspace[1])
        );
    }
    t
}
