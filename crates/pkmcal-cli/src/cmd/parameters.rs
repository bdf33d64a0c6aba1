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
    let text = if a.json {
        pkmcal_io::description::summary_json(spec)
    } else {
        table(&pkmcal::summary(spec))
    };
    say_raw!("{text}");
    Ok(())
}

/// The summary as text tables.
fn table(s: &pkmcal::MechanismSummary) -> String {
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
            if p.free_by_default { "yes" } else { "" }
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
