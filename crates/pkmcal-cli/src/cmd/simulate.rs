//! `simulate`: measurements of a mechanism with known parameters: nominal
//! commands for targets, true positions plus noise.

use crate::args;
use anyhow::{Context, Result, bail};
use pkmcal::Mechanism;
use pkmcal_io::Run;
use pkmcal_io::csv::Csv;
use pkmcal_io::description::{Description, read_description};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// True parameter values (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub truth: Option<PathBuf>,
    /// Target tool positions: CSV with one column target_<axis> per tool axis
    /// (target_x,target_y for the reference; mm, rad).
    #[arg(
        long,
        value_name = "T.csv",
        conflicts_with = "grid",
        required_unless_present = "grid"
    )]
    pub targets: Option<PathBuf>,
    /// Instead of a targets file: N targets spread evenly over the usable workspace.
    #[arg(value_parser = args::values::targets, long, value_name = "N")]
    pub grid: Option<usize>,
    /// Standard deviation of the Gaussian noise on each length coordinate
    /// (positions, bar readings, target points), mm.
    #[arg(value_parser = args::values::length_noise, long, default_value_t = 0.0, value_name = "MM")]
    pub noise: f64,
    /// Standard deviation of the Gaussian noise on each angle coordinate
    /// (orientations such as phi, rx, ry, rz), rad. Default: the length noise
    /// over a 200 mm lever arm (1e-5 rad for --noise 0.002).
    #[arg(value_parser = args::values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Measure from an instrument standing at this pose in the base frame
    /// (x,y,phi in mm and rad for planar tools; x,y,z,rx,ry,rz for spatial
    /// ones), as a tracker would. Without it the data are in the base frame
    /// and the file says so (`# frame: base`).
    #[arg(long, value_name = "POSE", allow_hyphen_values = true, value_parser = args::values::numbers)]
    pub instrument_frame: Option<args::Numbers>,
    /// Output CSV: targets, commands and measured tool coordinates
    /// (target_x,target_y,q1,q2,q3,x,y for the reference; with --setup: d1..dk
    /// instead of the tool coordinates).
    #[arg(long, value_name = "DATA.csv")]
    pub out: PathBuf,
    /// Simulate ball-bar readings with this setup (sockets, bar offset); the
    /// noise then applies to each reading.
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Measure the mechanism file's target points ([[target]], columns
    /// t1x,t1y,t1z,…) instead of the tool pose (laser tracker on a spatial
    /// platform); the noise applies to each coordinate.
    #[arg(long, conflicts_with_all = ["setup", "axes"])]
    pub measure_targets: bool,
    /// Measure the tool point's height above a bed plane (column `probe`:
    /// a z-probe or a dial gauge on a surface plate; the plane's height and
    /// tilts bed.z, bed.rx, bed.ry are 0, or as --truth gives them).
    #[arg(long, conflicts_with_all = ["setup", "axes", "measure_targets"])]
    pub probe: bool,
    /// Measure only these tool axes (comma-separated, e.g. `z` for a height
    /// probe); the file then has only their columns.
    #[arg(long, value_name = "AXES", conflicts_with = "setup")]
    pub axes: Option<String>,
    /// Also write distances between pairs of the simulated poses (as
    /// measured with calipers; same length noise) to this file, in the
    /// format `calibrate --distances` reads.
    #[arg(long, value_name = "PAIRS.csv")]
    pub distances_out: Option<PathBuf>,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                self.truth.clone(),
                self.targets.clone(),
                self.setup.clone(),
            ],
            std::iter::once(self.out.clone()).chain(self.distances_out.clone()),
        ))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let units = pkmcal_io::fileunits::of(run, &description);
    let mech = &description.mech;
    let truth = pkmcal_io::params::params_or_nominal(run, a.truth.as_deref(), mech)?;
    let mut noise = pkmcal::Noise::lengths(a.noise);
    if let Some(r) = a.angle_noise {
        noise.angle = r;
    }
    let targets: Vec<Vec<f64>> = match (&a.targets, a.grid) {
        (Some(path), _) => {
            let csv = Csv::read(run, path)?;
            csv.require_rows()?;
            let mut t = csv.named(&pkmcal_io::data::target_names(mech))?;
            pkmcal_io::fileunits::to_internal(
                &mut t,
                &pkmcal_io::fileunits::tool(
                    mech.spec(),
                    &pkmcal_io::fileunits::for_file(run, &units, csv.units.as_ref(), path),
                ),
            );
            for (i, target) in t.iter().enumerate() {
                pkmcal::nominal_commands(mech, target)
                    .with_context(|| format!("{}:{}", path.display(), csv.line(i)))?;
            }
            t
        }
        (None, Some(n)) => {
            if n == 0 {
                return crate::words::usage("--grid needs at least one target");
            }
            pkmcal::spread_targets(mech, n)
                .map_err(anyhow::Error::from)
                .with_context(|| match &a.mech.mechanism {
                    Some(m) => format!("with the [workspace] box of {}", m.display()),
                    None => "with the built-in mechanism's workspace box".into(),
                })?
                .into_iter()
                .map(|p| p.target)
                .collect()
        }
        (None, None) => bail!("give --targets FILE or --grid N"),
    };
    let measurement = simulated_measurement(run, &description, &a)?;
    let bar = run.bar(targets.len() as u64, false, "poses", 0);
    let data = pkmcal::simulate_with_progress(
        mech,
        &measurement,
        &truth,
        &targets,
        noise,
        a.seed,
        &|| bar.inc(1),
    )?;
    bar.finish();
    let distances = match &a.distances_out {
        None => None,
        Some(path) => {
            if path == &a.out {
                return crate::words::usage("--distances-out must differ from --out");
            }
            let pairs = distance_pairs(&targets);
            let rows = pkmcal::simulate_distances(
                mech,
                &measurement,
                &truth,
                &pairs,
                noise.length,
                a.seed.wrapping_add(1),
            )
            .map_err(|e| crate::words::Usage(format!("--distances-out: {e}")))?;
            Some((
                path,
                pkmcal_io::data::distances_csv(mech, &rows, &units),
                rows.len(),
            ))
        }
    };
    let base = *measurement.frame() == pkmcal::Frame::Base;
    run.files.stage(
        &a.out,
        &pkmcal_io::data::with_frame_comment(
            pkmcal_io::data::data_csv(mech, &measurement, &data, &units),
            base,
        ),
    )?;
    let angles = measurement.units().contains(&pkmcal::Unit::Radian);
    crate::note!(
        "simulated {}, {} (noise {} mm on lengths{}, seed {}) -> {}",
        pkmcal::error::count(data.len(), "pose", "poses"),
        measurement.describe(),
        pkmcal::error::shown(noise.length),
        if angles {
            format!(", {} rad on angles", pkmcal::error::shown(noise.angle))
        } else {
            String::new()
        },
        a.seed,
        a.out.display()
    );
    if let Some((path, bytes, n)) = distances {
        run.files.stage(path, &bytes)?;
        crate::note!(
            "simulated {n} distances between pairs of those poses -> {}",
            path.display()
        );
    }
    Ok(())
}

/// Pairs of simulated targets whose distances are measured: each target of
/// the first half with its opposite in the second (long distances, which
/// fix the scale), and neighbours (short ones).
fn distance_pairs(targets: &[Vec<f64>]) -> Vec<(Vec<f64>, Vec<f64>)> {
    let n = targets.len();
    let half = n / 2;
    let long = (0..half).map(|i| (i, i + half));
    let short = (0..n.saturating_sub(1)).step_by(2).map(|i| (i, i + 1));
    long.chain(short)
        .map(|(i, j)| (targets[i].clone(), targets[j].clone()))
        .collect()
}

/// What `simulate` measures: a ball bar (`--setup`), target points
/// (`--measure-targets`), some tool axes (`--axes`) or the whole tool; from
/// an instrument at `--instrument-frame` if given.
fn simulated_measurement(
    run: &Run<'_>,
    description: &Description,
    a: &Args,
) -> Result<pkmcal::MeasurementModel> {
    let spec = description.mech.spec();
    let m = if let Some(p) = &a.setup {
        let setup = pkmcal_io::description::read_setup(run, Some(p), description)?
            .with_context(|| format!("{}: no ball-bar setup", p.display()))?;
        pkmcal::MeasurementModel::ball_bar(spec, &setup)?
    } else if a.probe {
        pkmcal::MeasurementModel::probe(spec)
            .map_err(|e| crate::words::Usage(format!("--probe: {e}")))?
    } else if a.measure_targets {
        let points = &description.targets;
        if points.is_empty() {
            return crate::words::usage(
                "--measure-targets needs target points in the mechanism file: [[target]] at = [x, y, z] (tool frame, mm; [x, y] for a planar tool)",
            );
        }
        pkmcal::MeasurementModel::targets(spec, points)?
    } else if let Some(axes) = &a.axes {
        let names: Vec<&str> = axes.split(',').map(str::trim).collect();
        pkmcal::MeasurementModel::tool_axes(spec, &names)
            .map_err(|e| crate::words::Usage(format!("in --axes: {e}")))?
    } else {
        pkmcal::MeasurementModel::tool(spec)
    };
    match &a.instrument_frame {
        None => Ok(m),
        Some(f) => m
            .in_frame(pkmcal::Frame::Known(f.0.clone()))
            .map_err(|e| crate::words::Usage(format!("in --instrument-frame: {e}")).into()),
    }
}
