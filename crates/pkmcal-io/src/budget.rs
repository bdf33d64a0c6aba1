//! `budget`: the tool error a mechanism's parameter tolerances give over its
//! workspace, each tolerance's share, and what a planned calibration would
//! leave ([`pkmcal::apply::budget`]), from the mechanism file's
//! `[tolerances]` table and `--tolerance` options.

use crate::io::read_description;
use anyhow::Result;
use pkmcal::apply::budget::{Budget, BudgetOptions, PlannedCalibration, Tolerance};
use pkmcal::{Mechanism, Model};
use std::path::PathBuf;

/// Arguments of `budget`, already parsed by clap.
pub struct BudgetConfig {
    pub mechanism: Option<PathBuf>,
    /// `NAME=SIGMA` items (`--tolerance`), each σ a number or a percentage.
    pub tolerances: Vec<String>,
    pub samples: usize,
    pub seed: u64,
    /// Workspace targets to take the error over.
    pub targets: usize,
    /// A planned calibration's poses.
    pub poses: Option<PathBuf>,
    pub noise: f64,
    pub angle_noise: Option<f64>,
    pub model: Model,
    pub json: Option<PathBuf>,
}

/// The `--tolerance` items (`NAME=SIGMA`, comma-separated or repeated),
/// each checked against the mechanism: a usage error (exit 2) names the item.
pub fn option_tolerances(
    spec: &pkmcal::Spec,
    items: &[String],
) -> Result<Vec<(String, Tolerance)>> {
    let out = tolerance_items(items)?;
    if let Err(e) = pkmcal::apply::budget::resolve_tolerances(spec, &out) {
        return crate::output::usage(format!("--tolerance: {e}"));
    }
    Ok(out)
}

/// The `--tolerance` items parsed (a later one replaces an earlier one of
/// the same name), not yet resolved: a usage error (exit 2) names the item.
pub fn tolerance_items(items: &[String]) -> Result<Vec<(String, Tolerance)>> {
    let mut out: Vec<(String, Tolerance)> = vec![];
    for item in items.iter().flat_map(|s| s.split(',')).map(str::trim) {
        if item.is_empty() {
            continue;
        }
        let Some((name, value)) = item.split_once('=') else {
            return crate::output::usage(format!(
                "--tolerance {item}: give NAME=SIGMA (e.g. l11=0.05 or k1=20%)"
            ));
        };
        let tol = match Tolerance::parse(value) {
            Ok(t) => t,
            Err(e) => return crate::output::usage(format!("--tolerance {item}: {e}")),
        };
        let name = name.trim().to_string();
        out.retain(|(n, _)| *n != name);
        out.push((name, tol));
    }
    Ok(out)
}

/// What a command knows of the parameters before the data: the mechanism
/// file's `[tolerances]` table (and the file, for messages) and the
/// `--tolerance` items, or none (`--no-tolerances`).
pub struct Tolerances<'a> {
    pub table: &'a [(String, Tolerance)],
    pub file: Option<&'a std::path::Path>,
    pub items: &'a [String],
    pub off: bool,
}

/// The priors of a fit (docs/model.md eq. 13): the mechanism file's
/// `[tolerances]` table with the `--tolerance` items replacing its entries,
/// resolved against the mechanism and the instrument (`off`: none, as
/// `--no-tolerances` asks). An item naming an unknown parameter is a usage
/// error; a table entry's is the file's error.
pub fn fit_priors(
    spec: &pkmcal::Spec,
    measurement: &pkmcal::MeasurementModel,
    t: &Tolerances<'_>,
) -> Result<Vec<pkmcal::identify::Prior>> {
    let given = tolerance_items(t.items)?;
    if t.off {
        if !given.is_empty() {
            return crate::output::usage("give either --tolerance or --no-tolerances, not both");
        }
        return Ok(vec![]);
    }
    if let Err(e) = pkmcal::identify::named_priors(spec, measurement, &given) {
        return crate::output::usage(format!("--tolerance: {e}"));
    }
    let merged = pkmcal::apply::budget::merged_tolerances(t.table, given);
    pkmcal::identify::named_priors(spec, measurement, &merged).map_err(|e| {
        let file = t
            .file
            .map_or_else(|| "the mechanism".to_string(), |p| p.display().to_string());
        anyhow::anyhow!("in the [tolerances] table of {file}: {e}")
    })
}

/// The priors ([`fit_priors`]) and the free set they join
/// ([`crate::calibrate::free_set`]): what every command that fits, analyses
/// or plans resolves first.
pub fn priors_and_free<M: pkmcal::Mechanism>(
    mech: &M,
    measurement: &pkmcal::MeasurementModel,
    t: &Tolerances<'_>,
    free: Option<&str>,
    fix: Option<&str>,
) -> Result<(Vec<pkmcal::identify::Prior>, Vec<usize>)> {
    let priors = fit_priors(mech.spec(), measurement, t)?;
    let free = crate::calibrate::free_set(mech, measurement, free, fix, &priors)?;
    Ok((priors, free))
}

pub fn run_budget(run: &crate::Run<'_>, c: BudgetConfig) -> Result<()> {
    let description = read_description(run, c.mechanism.as_deref())?;
    let units = crate::fileunits::of(run, &description);
    let mech = description.mech;
    let spec = mech.spec();
    let given = pkmcal::apply::budget::merged_tolerances(
        &description.tolerances,
        option_tolerances(spec, &c.tolerances)?,
    );
    if given.is_empty() {
        return crate::output::usage(
            "no tolerance: add a [tolerances] table to the mechanism file (name = σ) or give --tolerance NAME=SIGMA",
        );
    }
    let tolerances = pkmcal::apply::budget::resolve_tolerances(spec, &given)?;
    let targets = pkmcal::apply::budget::budget_targets(&mech, c.targets)?;
    let calibration = match &c.poses {
        Some(p) => Some(PlannedCalibration {
            targets: crate::usecal::read_plan_poses(run, p, &mech, &units)?,
            noise: crate::io::noise_arg(c.noise, c.angle_noise),
        }),
        None => None,
    };
    let opts = BudgetOptions {
        model: c.model,
        force: vec![],
        samples: c.samples,
        seed: c.seed,
        calibration,
    };
    let b = pkmcal::apply::budget::budget(&mech, &targets, &tolerances, &opts)?;
    print!(
        "{}",
        budget_words(
            &spec.name,
            &b,
            c.poses.as_ref().map(|p| p.display().to_string())
        )
    );
    if let Some(j) = &c.json {
        run.files
            .stage(j, serde_json::to_string_pretty(&b)?.as_bytes())?;
        println!("budget -> {}", j.display());
    }
    Ok(())
}

/// A value in a readable unit (µm, mrad…), to four significant digits.
fn readable(v: f64, unit: pkmcal::Unit) -> String {
    let (f, sym) = unit.readable(v);
    let x = v * f;
    let digits = if x == 0.0 || !x.is_finite() {
        0
    } else {
        (3 - x.abs().log10().floor() as i32).clamp(0, 6) as usize
    };
    format!("{x:.digits$} {sym}")
}

/// The budget in words: the error over the workspace, the tolerances by
/// share, and what the planned calibration (`plan`, its poses' source)
/// would leave.
pub fn budget_words(mechanism: &str, b: &Budget, plan: Option<String>) -> String {
    use std::fmt::Write;
    let mut o = String::new();
    let mm = pkmcal::Unit::Millimetre;
    let _ = writeln!(
        o,
        "tolerance budget of {mechanism} over {} workspace targets",
        b.targets
    );
    let axes = |s: &pkmcal::apply::budget::ErrorSpread| {
        b.axes
            .iter()
            .zip(&b.units)
            .zip(&s.axis_rms)
            .map(|((a, u), v)| format!("{a} {}", readable(*v, *u)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(
        o,
        "  first order: position error RMS {}, worst target {}; per axis {}",
        readable(b.first_order.position_rms, mm),
        readable(b.first_order.position_worst, mm),
        axes(&b.first_order)
    );
    if let Some(mc) = &b.monte_carlo {
        let _ = writeln!(
            o,
            "  {} machines drawn from the tolerances (exact model): position error RMS {} ({:+.1} % from first order); per axis {}",
            b.samples,
            readable(mc.position_rms, mm),
            100.0 * (mc.position_rms / b.first_order.position_rms - 1.0),
            axes(mc)
        );
    }
    let width = b
        .tolerances
        .iter()
        .map(|t| t.name.len())
        .fold(9, usize::max);
    let _ = writeln!(
        o,
        "\n  {:<width$} {:>18} {:>8}{}",
        "parameter",
        "tolerance σ",
        "share",
        if plan.is_some() {
            format!(" {:>16}", "σ after")
        } else {
            String::new()
        }
    );
    for t in &b.tolerances {
        let _ = writeln!(
            o,
            "  {:<width$} {:>18} {:>7.1}%{}",
            t.name,
            readable(t.sigma, t.unit),
            100.0 * t.share,
            t.sigma_after
                .map(|s| format!(" {:>16}", readable(s, t.unit)))
                .unwrap_or_default()
        );
    }
    let _ = writeln!(
        o,
        "  (share: of the position error variance over the workspace; stiffness tolerances have none to first order at nominal, where the actuators do not fight)"
    );
    if let (Some(a), Some(p)) = (&b.after_calibration, plan) {
        let _ = writeln!(
            o,
            "\nafter a calibration measuring the tool at the poses of {p}: position error RMS {}, worst target {}; per axis {}",
            readable(a.position_rms, mm),
            readable(a.position_worst, mm),
            axes(a)
        );
    }
    o
}
