//! `trilaterate`: ball-bar readings to tool positions (least squares) with
//! their uncertainties.

use crate::args;
use anyhow::{Context, Result};
use pkmcal::Mechanism;
use pkmcal_io::Run;
use pkmcal_io::csv::{Csv, csv_bytes};
use pkmcal_io::description::read_description;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Ball-bar setup: sockets and bar offset.
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Data with the bar readings d1, d2, … (mm).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Standard deviation of one reading (mm), for the positions' uncertainty.
    #[arg(value_parser = args::values::sigma_mm, long, alias = "sigma", default_value_t = 0.002, value_name = "MM")]
    pub stated_noise: f64,
    /// Output CSV: targets and commands if present, x, y, sigma_x, sigma_y.
    #[arg(long, value_name = "OUT.csv")]
    pub out: PathBuf,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.setup.clone(),
                Some(self.data.clone()),
            ],
            [self.out.clone()],
        ))
    }
}

/// `trilaterate`: bar readings to positions with their standard deviations.
pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = &description.mech;
    let spec = mech.spec();
    let setup = pkmcal_io::description::read_setup(run, a.setup.as_deref(), &description)?
        .context("give the socket positions with --setup S.toml (or a [ballbar] table in the mechanism file)")?;
    // Checks the setup against the tool point.
    pkmcal::MeasurementModel::ball_bar(spec, &setup)?;
    let csv = Csv::read(run, &a.data)?;
    csv.require_rows()?;
    // In the data file's own units (its units line, else the run's), read
    // and written: the targets and commands pass through unchanged.
    let units = pkmcal_io::fileunits::for_file(run, &units, csv.units.as_ref(), &a.data);
    let dnames: Vec<String> = (1..=setup.sockets.len()).map(|j| format!("d{j}")).collect();
    let mut readings = csv.named(&dnames)?;
    let d_factor = units.factor(pkmcal::Unit::Millimetre, pkmcal::Role::Reading);
    pkmcal_io::fileunits::to_internal(&mut readings, &vec![d_factor; dnames.len()]);
    let tf = pkmcal_io::fileunits::tool(spec, &units);
    // Pass through targets and commands when present (in the file's units).
    let mut keep: Vec<String> = pkmcal_io::data::target_names(mech);
    keep.extend(spec.actuated_names().iter().map(|s| s.to_string()));
    keep.retain(|n| csv.headers.contains(n));
    let kept = csv.named(&keep)?;
    let mut rows = Vec::with_capacity(readings.len());
    for (i, d) in readings.iter().enumerate() {
        let (x, cov) = pkmcal::trilaterate(&setup, d, a.stated_noise, None)
            .with_context(|| format!("{}:{}: readings {d:?}", a.data.display(), csv.line(i)))?;
        let sig = (0..x.len()).map(|k| cov[(k, k)].max(0.0).sqrt() / tf[k]);
        rows.push(
            kept[i]
                .iter()
                .copied()
                .chain(x.iter().zip(&tf).map(|(v, f)| v / f))
                .chain(sig)
                .collect::<Vec<f64>>(),
        );
    }
    let mut header = keep;
    header.extend(spec.tool_axes.iter().cloned());
    header.extend(spec.tool_axes.iter().map(|a| format!("sigma_{a}")));
    // Sockets are placed in the base frame, so are the positions.
    run.files.stage(
        &a.out,
        &pkmcal_io::data::with_frame_comment(
            pkmcal_io::fileunits::with_comment(csv_bytes(&header, &rows), &units),
            true,
        ),
    )?;
    crate::note!(
        "trilaterated {} from {} sockets -> {}",
        pkmcal::error::count(rows.len(), "pose", "poses"),
        setup.sockets.len(),
        a.out.display()
    );
    Ok(())
}
