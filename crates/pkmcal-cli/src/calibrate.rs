//! `calibrate` and `analyze`: read data, identify, validate, report.

use crate::io::{Csv, Mech, parse_list, read_mechanism, read_params, write_atomic};
use anyhow::{Context, Result, bail};
use pkmcal::BallBar;
use pkmcal::calibration::{CrossValidation, Identifiability};
use pkmcal::{
    Accuracy, Calibration, CalibrationOptions, ErrorStats, Measurement, Mechanism, Model, Params,
    calibrate, calibration_accuracy, holdout_split,
};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Read a measurement file: commands and measured tool coordinates, optional
/// targets and standard deviations.
pub fn read_data<M: Mechanism>(path: &Path, mech: &M) -> Result<Vec<Measurement>> {
    data_from(&Csv::read(path)?, mech)
}

/// [`read_data`] from an already parsed table: every pose carries its σ
/// (`sigma_<axis>` columns, any subset; or `sigma` for all axes of one unit)
/// and its origin (pose number and line in the file).
pub fn data_from<M: Mechanism>(csv: &Csv, mech: &M) -> Result<Vec<Measurement>> {
    let spec = mech.spec();
    csv.require_rows()?;
    let act: Vec<String> = spec
        .actuated_names()
        .iter()
        .map(|s| s.to_string())
        .collect();
    let commands = csv.named(&act)?;
    let measured = csv.named(&spec.tool_axes)?;
    let target_names: Vec<String> = spec
        .tool_axes
        .iter()
        .map(|a| format!("target_{a}"))
        .collect();
    let has_targets = target_names.iter().all(|n| csv.headers.contains(n));
    let targets = if has_targets {
        Some(csv.named(&target_names)?)
    } else {
        None
    };
    let sigma = sigma_from(csv, mech)?;
    Ok(commands
        .into_iter()
        .zip(measured)
        .enumerate()
        .map(|(i, (c, m))| Measurement {
            target: targets.as_ref().map(|t| t[i].clone()),
            commands: c,
            measured: m,
            sigma: sigma.as_ref().map_or(vec![], |s| s[i].clone()),
            origin: Some(pkmcal::Origin {
                pose: i + 1,
                line: Some(csv.line(i)),
            }),
        })
        .collect())
}

/// Per-pose standard deviations of the measured coordinates: `sigma_<axis>`
/// columns (any subset; the other axes are estimated from the residuals) or
/// one `sigma` column for every axis when all axes share a unit. `None` when
/// the file has none.
pub fn sigma_from<M: Mechanism>(csv: &Csv, mech: &M) -> Result<Option<Vec<Vec<Option<f64>>>>> {
    let spec = mech.spec();
    let nx = spec.tool_axes.len();
    let per_axis: Vec<(usize, String)> = spec
        .tool_axes
        .iter()
        .enumerate()
        .map(|(k, a)| (k, format!("sigma_{a}")))
        .filter(|(_, n)| csv.headers.contains(n))
        .collect();
    let unknown: Vec<&String> = csv
        .headers
        .iter()
        .filter(|h| h.starts_with("sigma_") && !per_axis.iter().any(|(_, n)| n == *h))
        .collect();
    if !unknown.is_empty() {
        bail!(
            "{}: column(s) {} name no measured axis of {}; the measured axes are {} (columns sigma_{})",
            csv.path.display(),
            unknown
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", "),
            spec.name,
            spec.tool_axes.join(", "),
            spec.tool_axes.join(", sigma_")
        );
    }
    let common = csv.headers.iter().any(|h| h == "sigma");
    if common && !per_axis.is_empty() {
        bail!(
            "{}: give either one `sigma` column or per-axis `sigma_<axis>` columns, not both",
            csv.path.display()
        );
    }
    let rows: Vec<Vec<Option<f64>>> = if common {
        let units = &spec.tool_units;
        if units.iter().any(|u| *u != units[0]) {
            bail!(
                "{}: one `sigma` column cannot hold the noise of {} ({}); give per-axis columns sigma_{} (any subset; the others are estimated)",
                csv.path.display(),
                spec.tool_axes.join(", "),
                units
                    .iter()
                    .map(|u| u.symbol())
                    .collect::<Vec<_>>()
                    .join(", "),
                spec.tool_axes.join(", sigma_")
            );
        }
        csv.named(&["sigma".to_string()])?
            .into_iter()
            .map(|r| vec![Some(r[0]); nx])
            .collect()
    } else if per_axis.is_empty() {
        return Ok(None);
    } else {
        let names: Vec<String> = per_axis.iter().map(|(_, n)| n.clone()).collect();
        csv.named(&names)?
            .into_iter()
            .map(|r| {
                let mut row = vec![None; nx];
                for ((k, _), v) in per_axis.iter().zip(r) {
                    row[*k] = Some(v);
                }
                row
            })
            .collect()
    };
    for (i, r) in rows.iter().enumerate() {
        if r.iter().flatten().any(|v| *v <= 0.0) {
            bail!(
                "{}:{}: standard deviations must be positive, got {}",
                csv.path.display(),
                csv.line(i),
                r.iter()
                    .flatten()
                    .map(|v| v.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    Ok(Some(rows))
}

/// A library error, located in `file` when it names a pose that came from it.
pub fn located(e: pkmcal::Error, file: &Path) -> anyhow::Error {
    match e {
        pkmcal::Error::Pose {
            pose,
            line: Some(line),
            source,
        } => anyhow::anyhow!("{}:{line}: pose {pose}: {source}", file.display()),
        e => anyhow::Error::new(e).context(format!("calibrating from {}", file.display())),
    }
}

/// Resolve `--free` / `--fix` lists into parameter indices.
pub fn free_set<M: Mechanism>(
    mech: &M,
    free: Option<&str>,
    fix: Option<&str>,
) -> Result<Vec<usize>> {
    let spec = mech.spec();
    let names = |s: &str| -> Vec<String> {
        s.split(',')
            .map(|t| t.trim().to_string())
            .filter(|t| !t.is_empty())
            .collect()
    };
    let mut set: Vec<usize> = match free {
        None => spec
            .default_free
            .iter()
            .map(|n| spec.param_index(n))
            .collect::<pkmcal::Result<_>>()?,
        Some(list) => {
            let mut out = vec![];
            for n in names(list) {
                match n.as_str() {
                    "all" => out.extend(0..spec.n_params()),
                    "default" | "paper" => {
                        for d in &spec.default_free {
                            out.push(spec.param_index(d)?);
                        }
                    }
                    _ => out.push(spec.param_index(&n).context("in --free")?),
                }
            }
            out
        }
    };
    if let Some(list) = fix {
        for n in names(list) {
            let i = spec.param_index(&n).context("in --fix")?;
            set.retain(|&k| k != i);
        }
    }
    set.sort_unstable();
    set.dedup();
    if set.is_empty() {
        bail!("no parameter is left free; name some with --free");
    }
    Ok(set)
}

/// Validation results in the report.
#[derive(Serialize)]
pub struct Validation {
    /// Where the validation poses came from.
    pub source: String,
    /// Before/after on the validation poses.
    pub accuracy: Accuracy,
}

/// The JSON report of `calibrate`.
#[derive(Serialize)]
pub struct Report<'a> {
    pub pkmcal_version: &'static str,
    pub mechanism: String,
    pub data: String,
    #[serde(flatten)]
    pub calibration: &'a Calibration,
    pub accuracy: Accuracy,
    pub validation: Option<Validation>,
    pub cross_validation: Option<CrossValidation>,
}

/// Arguments of `calibrate`, already parsed by clap.
pub struct CalibrateConfig {
    pub mechanism: Option<PathBuf>,
    pub data: PathBuf,
    pub model: Model,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub start: Option<PathBuf>,
    pub force: Option<String>,
    pub out: PathBuf,
    pub report: Option<PathBuf>,
    pub validate: Option<PathBuf>,
    pub holdout: Option<f64>,
    pub seed: u64,
    pub kfold: Option<usize>,
    pub report_dir: Option<PathBuf>,
    pub quiet: bool,
    pub setup: Option<PathBuf>,
    pub loss: pkmcal::Loss,
    pub outlier_threshold: f64,
    pub drop_outliers: bool,
    /// `auto`, `free` or `base`.
    pub frame: String,
}

fn force_arg<M: Mechanism>(mech: &M, s: Option<&str>) -> Result<Vec<f64>> {
    let Some(s) = s else { return Ok(vec![]) };
    let f = parse_list(s, "--force")?;
    if f.len() != mech.spec().tool_axes.len() {
        bail!(
            "--force needs {} values, got {}",
            mech.spec().tool_axes.len(),
            f.len()
        );
    }
    Ok(f)
}

/// The ball-bar setup when `csv` holds bar readings (`d1…`) instead of tool
/// coordinates; an error naming the file when no setup is given for them.
fn ballbar_setup(
    csv: &Csv,
    mech: &Mech,
    setup: Option<&Path>,
    mechanism: Option<&Path>,
) -> Result<Option<pkmcal::Setup>> {
    let distances = csv.headers.iter().any(|h| h == "d1");
    let positions = mech
        .spec()
        .tool_axes
        .iter()
        .all(|a| csv.headers.contains(a));
    if !distances || positions {
        return Ok(None);
    }
    crate::io::read_setup(setup, mechanism)?
        .with_context(|| {
            format!(
                "{} holds ball-bar distances (d1…); give the socket positions with --setup S.toml (or a [ballbar] table in the mechanism file)",
                csv.path.display()
            )
        })
        .map(Some)
}

/// The target points when `csv` holds their positions (`t1x…`) instead of the
/// tool pose; an error naming the file when the mechanism file has none.
pub fn point_targets(
    csv: &Csv,
    mech: &Mech,
    mechanism: Option<&Path>,
) -> Result<Option<Vec<[f64; 3]>>> {
    let targets = csv.headers.iter().any(|h| h == "t1x");
    let positions = mech
        .spec()
        .tool_axes
        .iter()
        .all(|a| csv.headers.contains(a));
    if !targets || positions {
        return Ok(None);
    }
    let t = crate::io::read_targets(mechanism)?;
    if t.is_empty() {
        bail!(
            "{} holds target-point positions (t1x…); describe the targets in the mechanism file: [[target]] at = [x, y, z] (platform frame, mm)",
            csv.path.display()
        );
    }
    Ok(Some(t))
}

/// `p` of a wrapper whose extra geometric parameters follow the plain
/// mechanism's, reduced to the plain mechanism's parameters.
fn plain_params(plain: &Mech, wrapped_geometric: usize) -> impl Fn(&Params) -> Params + use<> {
    let ng = plain.spec().n_geometric();
    let spec = plain.spec().clone();
    move |p: &Params| -> Params {
        let mut v = p.values[..ng].to_vec();
        v.extend(&p.values[wrapped_geometric..]);
        Params::new(&spec, v).expect("same layout")
    }
}

pub fn run_calibrate(c: CalibrateConfig) -> Result<()> {
    let mech = read_mechanism(c.mechanism.as_deref())?;
    let csv = Csv::read(&c.data)?;
    if let Some(t) = point_targets(&csv, &mech, c.mechanism.as_deref())? {
        if c.report_dir.is_some() {
            bail!("--report-dir needs tool positions; drop it for target-point data");
        }
        let pt = pkmcal::PointTargets::new(mech.clone(), &t)?;
        let to_plain = plain_params(&mech, pt.spec().n_geometric());
        return calibrate_on(&pt, &c, &csv, &mech, &to_plain, None);
    }
    if let Some(setup) = ballbar_setup(&csv, &mech, c.setup.as_deref(), c.mechanism.as_deref())? {
        if c.report_dir.is_some() {
            bail!(
                "--report-dir needs positions; trilaterate the distances first (pkmcal trilaterate) or drop --report-dir"
            );
        }
        let bb = BallBar::new(mech.clone(), &setup)?;
        let to_plain = plain_params(&mech, bb.spec().n_geometric());
        return calibrate_on(&bb, &c, &csv, &mech, &to_plain, None);
    }
    calibrate_on(&mech, &c, &csv, &mech, &|p: &Params| p.clone(), Some(&mech))
}

/// Calibrate `mech` (the mechanism itself, or it measured by a ball bar) and
/// write the plain mechanism's parameters.
fn calibrate_on<M: Mechanism>(
    mech: &M,
    c: &CalibrateConfig,
    csv: &Csv,
    plain: &Mech,
    to_plain: &dyn Fn(&Params) -> Params,
    figures_for: Option<&Mech>,
) -> Result<()> {
    let spec = mech.spec();
    let all = data_from(csv, mech)?;
    let start = match &c.start {
        Some(p) => read_params(p, spec)?,
        None => Params::nominal(spec),
    };
    let mut opts = CalibrationOptions::new(spec, c.model);
    opts.free = free_set(mech, c.free.as_deref(), c.fix.as_deref())?;
    opts.force = force_arg(mech, c.force.as_deref())?;
    opts.loss = c.loss;
    opts.outlier_threshold = c.outlier_threshold;
    opts.drop_outliers = c.drop_outliers;
    opts.frame = frame_choice(&c.frame, spec, csv);
    // Validation data: a description, the file it came from, the poses.
    type Held = Option<(String, PathBuf, Vec<Measurement>)>;
    let (train, held): (Vec<Measurement>, Held) = match (&c.validate, c.holdout) {
        (Some(_), Some(_)) => bail!("give either --validate FILE or --holdout F, not both"),
        (Some(v), None) => (
            all.clone(),
            Some((v.display().to_string(), v.clone(), read_data(v, mech)?)),
        ),
        (None, Some(f)) => {
            let (tr, he) = holdout_split(all.len(), f, c.seed)?;
            (
                tr.iter().map(|&i| all[i].clone()).collect(),
                Some((
                    format!(
                        "{} held-out poses of {} (seed {})",
                        he.len(),
                        c.data.display(),
                        c.seed
                    ),
                    c.data.clone(),
                    he.iter().map(|&i| all[i].clone()).collect(),
                )),
            )
        }
        (None, None) => (all.clone(), None),
    };
    // Every pose carries its data-file number and line, so errors, outliers
    // and dropped poses name them without translation.
    let cal = calibrate(mech, &train, &start, &opts).map_err(|e| located(e, &c.data))?;
    let (acc, before, after) =
        calibration_accuracy(mech, &train, &cal, &opts.force).map_err(|e| located(e, &c.data))?;
    let validation = match &held {
        Some((source, path, data)) => Some(Validation {
            source: source.clone(),
            accuracy: calibration_accuracy(mech, data, &cal, &opts.force)
                .map_err(|e| located(e, path))?
                .0,
        }),
        None => None,
    };
    let cross_validation = match c.kfold {
        Some(k) => {
            let bar = crate::io::progress(k as u64, c.quiet, "folds", 1);
            let cv = pkmcal::cross_validate_with_progress(
                mech,
                &train,
                &start,
                &opts,
                k,
                c.seed,
                &|| bar.inc(1),
            )?;
            bar.finish_and_clear();
            Some(cv)
        }
        None => None,
    };
    let header = format!(
        "pkmcal {} calibration ({} model) of {} from {}\nsolver: {}",
        env!("CARGO_PKG_VERSION"),
        c.model.name(),
        spec.name,
        c.data.display(),
        cal.termination_reason
    );
    let params_text = crate::io::params_to_string(plain.spec(), &to_plain(&cal.params), &header);
    let report = Report {
        pkmcal_version: env!("CARGO_PKG_VERSION"),
        mechanism: spec.name.clone(),
        data: c.data.display().to_string(),
        calibration: &cal,
        accuracy: acc,
        validation,
        cross_validation,
    };
    let json = serde_json::to_string_pretty(&report)?;
    // Write everything only after every computation succeeded.
    write_atomic(&c.out, params_text.as_bytes())?;
    if let Some(r) = &c.report {
        write_atomic(r, json.as_bytes())?;
    }
    if let (Some(dir), Some(fig_mech)) = (&c.report_dir, figures_for) {
        crate::report::write_report_dir(
            dir,
            &crate::report::ReportInputs {
                mech: fig_mech,
                data_name: &c.data.display().to_string(),
                cal: &cal,
                data: &train,
                before: &before,
                after: &after,
                accuracy: &report.accuracy,
                validation: report.validation.as_ref(),
                cross_validation: report.cross_validation.as_ref(),
            },
        )?;
    }
    print_summary(&report, &spec.tool_axes, &spec.tool_units);
    println!();
    println!("identified parameters -> {}", c.out.display());
    if let Some(r) = &c.report {
        println!("report -> {}", r.display());
    }
    if let Some(d) = &c.report_dir {
        println!("figures and report.html -> {}", d.display());
    }
    Ok(())
}

/// Display factor and symbol of an error column: lengths in mm, angles in
/// mrad (so that micro-radian errors do not print as 0.0000).
fn column_unit(u: pkmcal::Unit) -> (f64, &'static str) {
    match u {
        pkmcal::Unit::Radian => (1e3, "mrad"),
        u => (1.0, u.symbol()),
    }
}

pub fn print_stats_header(axes: &[String], units: &[pkmcal::Unit]) {
    let mut h = format!("  {:<24}", "errors");
    for (a, u) in axes.iter().zip(units) {
        let a = a.to_uppercase();
        let sym = column_unit(*u).1;
        h.push_str(&format!(
            " {:>10} {:>10}",
            format!("{a}min {sym}"),
            format!("{a}max {sym}")
        ));
    }
    let lengths = units.contains(&pkmcal::Unit::Millimetre);
    if lengths {
        for t in ["dmin", "dmean", "drms", "dmax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mm")));
        }
    }
    if units.contains(&pkmcal::Unit::Radian) {
        for t in ["arms", "amax"] {
            h.push_str(&format!(" {:>10}", format!("{t} mrad")));
        }
    }
    println!("{h}");
}

pub fn print_stats(label: &str, s: &ErrorStats) {
    let mut row = format!("  {label:<24}");
    for ((a, b), u) in s.axis_min.iter().zip(&s.axis_max).zip(&s.axis_units) {
        let f = column_unit(*u).0;
        row.push_str(&format!(" {:>10.4} {:>10.4}", a * f, b * f));
    }
    if s.axis_units.contains(&pkmcal::Unit::Millimetre) {
        for v in [
            s.distance_min,
            s.distance_mean,
            s.distance_rms,
            s.distance_max,
        ] {
            row.push_str(&format!(" {v:>10.4}"));
        }
    }
    if let (Some(r), Some(m)) = (s.angle_rms, s.angle_max) {
        row.push_str(&format!(" {:>10.4} {:>10.4}", r * 1e3, m * 1e3));
    }
    println!("{row}");
}

/// Values with their units, each in a readable scale (µm, µrad…).
pub fn with_units(values: &[f64], units: &[pkmcal::Unit]) -> String {
    values
        .iter()
        .zip(units)
        .map(|(v, u)| {
            let (f, sym) = u.readable(*v);
            format!("{:.3} {sym}", v * f)
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// The instrument frame in words, when the data were measured from one.
pub fn frame_text(cal: &Calibration) -> Option<String> {
    cal.frame.as_ref()?;
    let rows: Vec<String> = cal
        .parameters
        .iter()
        .filter(|p| p.kind == pkmcal::ParamKind::Instrument)
        .map(|p| {
            let (f, sym) = match p.unit {
                pkmcal::Unit::Radian => (1e3, "mrad"),
                u => (1.0, u.symbol()),
            };
            if p.free {
                format!(
                    "{} {:.4} ± {:.2e} {sym}",
                    p.name,
                    p.identified * f,
                    p.std_dev * f
                )
            } else {
                format!("{} {:.4} {sym} (fixed)", p.name, p.identified * f)
            }
        })
        .collect();
    Some(format!(
        "instrument frame in the base frame (identified; --frame base if the data are in the base frame): {}",
        rows.join(", ")
    ))
}

/// A noise group in words: its σ (estimated or given) and residual RMS.
pub fn noise_text(g: &pkmcal::NoiseGroup) -> String {
    let (f, sym) = g.unit.readable(g.sigma);
    format!(
        "noise of {} ({}, {} coordinates): σ {:.3} {sym} {}; residual RMS {:.3} {sym}",
        g.unit.group_name(),
        g.axes.join(", "),
        g.count,
        g.sigma * f,
        if g.estimated {
            "estimated from the residuals"
        } else {
            "given in the data"
        },
        g.residual_rms * f
    )
}

/// One line per noise group.
pub fn print_noise(groups: &[pkmcal::NoiseGroup]) {
    for g in groups {
        println!("  {}", noise_text(g));
    }
}

/// The identifiability summary; `fixed` says what happened to the parameter
/// named for each unidentifiable direction ("fixed", "calibrate fixes").
pub fn print_identifiability(id: &Identifiability, fixed: &str) {
    println!(
        "identifiability: rank {} of {} free, condition number {:.3e}",
        id.rank,
        id.singular_values.len(),
        id.condition_number
    );
    let o = &id.observability;
    println!(
        "  observability O1 {:.4e}  O2 {:.4e}  O3 {:.4e}  O4 {:.4e}  O5 {:.4e}",
        o.o1, o.o2, o.o3, o.o4, o.o5
    );
    for u in &id.unidentifiable {
        match &u.fixed {
            Some(f) => println!("  unidentifiable: {}  -> {fixed} {f}", u.combination),
            None => println!("  unidentifiable: {}", u.combination),
        }
    }
    for c in &id.correlations {
        println!("  correlated: {} and {} (r = {:+.3})", c.a, c.b, c.r);
    }
}

fn print_summary(r: &Report, axes: &[String], units: &[pkmcal::Unit]) {
    let cal = r.calibration;
    println!(
        "calibration of {} from {} ({} poses, {} model)",
        r.mechanism,
        r.data,
        cal.poses,
        cal.model.name()
    );
    println!(
        "{} after {} iterations ({} evaluations); σ of unit weight {:.3}",
        cal.termination_reason, cal.iterations, cal.evaluations, cal.unit_weight_sigma
    );
    print_noise(&cal.noise);
    println!();
    println!(
        "  {:<6} {:>14} {:>16} {:>14} {:>12} {:<8}",
        "param", "nominal", "identified", "change", "±σ", "unit"
    );
    for p in &cal.parameters {
        if p.free || p.note.is_some() {
            println!(
                "  {:<6} {:>14.6} {:>16.8} {:>+14.6e} {:>12.3e} {:<8}{}",
                p.name,
                p.nominal,
                p.identified,
                p.change,
                p.std_dev,
                p.unit,
                p.note
                    .as_deref()
                    .map(|n| format!(" ({n})"))
                    .unwrap_or_default()
            );
        }
    }
    let fixed: Vec<&str> = cal
        .parameters
        .iter()
        .filter(|p| !p.free && p.note.is_none())
        .map(|p| p.name.as_str())
        .collect();
    println!("  fixed: {}", fixed.join(" "));
    if let Some(text) = frame_text(cal) {
        println!("  {text}");
    }
    println!();
    print_identifiability(&cal.identifiability, "fixed");
    for c in &cal.correlations {
        println!(
            "  correlated at the solution: {} and {} (r = {:+.3})",
            c.a, c.b, c.r
        );
    }
    println!();
    print_stats_header(axes, units);
    print_stats("calibration, before", &r.accuracy.before);
    print_stats("calibration, after", &r.accuracy.after);
    println!(
        "  improvement: max {:.1} %, RMS {:.1} %",
        r.accuracy.improvement_max_percent, r.accuracy.improvement_rms_percent
    );
    if let Some(v) = &r.validation {
        println!("  validation: {}", v.source);
        print_stats("validation, before", &v.accuracy.before);
        print_stats("validation, after", &v.accuracy.after);
        println!(
            "  improvement: max {:.1} %, RMS {:.1} %",
            v.accuracy.improvement_max_percent, v.accuracy.improvement_rms_percent
        );
    }
    if let Some(cv) = &r.cross_validation {
        println!(
            "  {}-fold cross-validation: held-out RMS per fold {}",
            cv.folds,
            cv.fold_rms
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        print_stats("cross-validation pooled", &cv.pooled);
    }
    if cal.loss != pkmcal::Loss::Squared {
        println!("  loss {:?}", cal.loss);
    }
    for o in &cal.outliers {
        println!(
            "  outlier: pose {}{} residual {} ({:.1} robust σ){}",
            o.origin.pose,
            o.origin
                .line
                .map(|l| format!(" (line {l})"))
                .unwrap_or_default(),
            with_units(&o.residual, &o.units),
            o.standardized,
            if cal.dropped.contains(&o.origin) {
                ", dropped"
            } else {
                ""
            }
        );
    }
    for w in &cal.warnings {
        println!("warning: {}\n  hint: {}", w.message, w.hint);
    }
}

pub struct AnalyzeConfig {
    pub mechanism: Option<PathBuf>,
    pub data: PathBuf,
    pub model: Model,
    pub free: Option<String>,
    pub fix: Option<String>,
    pub params: Option<PathBuf>,
    pub force: Option<String>,
    pub report: Option<PathBuf>,
    pub setup: Option<PathBuf>,
    /// `auto`, `free` or `base`.
    pub frame: String,
}

/// The instrument frame of `--frame` for data `csv` of a mechanism.
fn frame_choice(choice: &str, spec: &pkmcal::Spec, csv: &Csv) -> pkmcal::Frame {
    match choice {
        _ if spec.tool_layout.frame_size() == 0 => pkmcal::Frame::Base,
        "base" => pkmcal::Frame::Base,
        "auto" if csv.base_frame => pkmcal::Frame::Base,
        _ => pkmcal::Frame::Free,
    }
}

pub fn run_analyze(c: AnalyzeConfig) -> Result<()> {
    let mech = read_mechanism(c.mechanism.as_deref())?;
    let csv = Csv::read(&c.data)?;
    if let Some(setup) = ballbar_setup(&csv, &mech, c.setup.as_deref(), c.mechanism.as_deref())? {
        return analyze_on(&BallBar::new(mech, &setup)?, &c, &csv);
    }
    if let Some(t) = point_targets(&csv, &mech, c.mechanism.as_deref())? {
        return analyze_on(&pkmcal::PointTargets::new(mech, &t)?, &c, &csv);
    }
    analyze_on(&mech, &c, &csv)
}

fn analyze_on<M: Mechanism>(mech: &M, c: &AnalyzeConfig, csv: &Csv) -> Result<()> {
    let spec = mech.spec();
    let data = data_from(csv, mech)?;
    let params = match &c.params {
        Some(p) => read_params(p, spec)?,
        None => Params::nominal(spec),
    };
    let free = free_set(mech, c.free.as_deref(), c.fix.as_deref())?;
    let force = force_arg(mech, c.force.as_deref())?;
    let frame = frame_choice(&c.frame, spec, csv);
    let id = pkmcal::analyze_in_frame(mech, &data, &params, c.model, &free, &force, &frame)
        .with_context(|| format!("analysing {}", c.data.display()))?;
    if let Some(r) = &c.report {
        write_atomic(r, serde_json::to_string_pretty(&id)?.as_bytes())?;
    }
    println!(
        "identifiability of {} free parameters from {} poses of {} ({} model)",
        free.len(),
        data.len(),
        c.data.display(),
        c.model.name()
    );
    println!(
        "  free: {}{}",
        free.iter()
            .map(|&i| spec.param_names()[i])
            .collect::<Vec<_>>()
            .join(" "),
        if frame == pkmcal::Frame::Free {
            format!(
                ", and the instrument frame's {} (--frame base if the data are in the base frame)",
                spec.tool_layout.frame_names().join(" ")
            )
        } else {
            String::new()
        }
    );
    print_identifiability(&id, "calibrate fixes");
    println!(
        "  singular values (column-scaled): {}",
        id.singular_values
            .iter()
            .map(|s| format!("{s:.3e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    if id.unidentifiable.is_empty() {
        println!("all {} free parameters are identifiable", free.len());
    } else {
        println!(
            "{} direction(s) cannot be identified; calibrate fixes one parameter per direction (or use --fix)",
            id.unidentifiable.len()
        );
    }
    Ok(())
}
