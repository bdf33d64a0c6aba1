//! `demo`: the paper's case study on the built-in reference mechanism.

use crate::args;
use anyhow::{Context, Result};
use pkmcal::{ErrorStats, Mechanism, Model, Params};
use pkmcal_io::Run;
use pkmcal_io::description::Mech;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Directory for the demo's files.
    #[arg(long, default_value = "pkmcal-demo", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Random seed of the measurement noise.
    #[arg(long, default_value_t = 2004)]
    pub seed: u64,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        use pkmcal_io::output::in_dir;
        let mut out = in_dir(&self.out_dir, DEMO_FILES)?;
        out.extend(in_dir(
            &self.out_dir.join("report"),
            pkmcal_io::report::FILES,
        )?);
        Ok(args::Paths::new([], out).with_dirs(vec![self.out_dir.clone()]))
    }
}

/// Validation poses of the demo (unseen: drawn at random from the workspace).
const DEMO_VALIDATION_POSES: usize = 50;

/// Measurement noise of the demo, mm per axis (docs/model.md §10).
const DEMO_NOISE_MM: f64 = 0.002;

/// Every file `demo` writes in its directory (the report in `report/`).
pub const DEMO_FILES: &[&str] = &[
    "measurements.csv",
    "validation.csv",
    "truth.toml",
    "params-rigid.toml",
    "params-linear.toml",
    "params-exact.toml",
    "report-rigid.json",
    "report-linear.json",
    "report-exact.json",
];

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    use pkmcal_io::text::{write_identifiability, write_stats, write_stats_header};
    let print_stats_header = |axes: &[String], units: &[pkmcal::Unit]| {
        let mut o = String::new();
        write_stats_header(&mut o, axes, units);
        say_raw!("{o}");
    };
    let print_stats = |label: &str, s: &ErrorStats| {
        let mut o = String::new();
        write_stats(&mut o, label, s);
        say_raw!("{o}");
    };
    let mech: Mech = pkmcal::JeongKim2Dof::new().into();
    let spec = mech.spec();
    let truth = pkmcal::kinds::reference::demo_truth();
    let dir = &a.out_dir;
    // The demo's own calibrations read its files internally; only what it
    // writes follows --units.
    let units =
        pkmcal_io::fileunits::of(run, &pkmcal_io::description::read_description(run, None)?);
    run.files.create_dir(dir)?;
    let targets: Vec<Vec<f64>> = pkmcal::spread_targets(&mech, 35)?
        .into_iter()
        .map(|p| p.target)
        .collect();
    let tool = pkmcal::MeasurementModel::tool(spec);
    let data = pkmcal::simulate(&mech, &tool, &truth, &targets, DEMO_NOISE_MM, a.seed)?;
    let vtargets = pkmcal::random_targets(&mech, DEMO_VALIDATION_POSES, a.seed + 1)?;
    let vdata = pkmcal::simulate(&mech, &tool, &truth, &vtargets, DEMO_NOISE_MM, a.seed + 2)?;
    run.files.stage(
        &dir.join("measurements.csv"),
        &pkmcal_io::data::with_frame_comment(
            pkmcal_io::data::data_csv(&mech, &tool, &data, &units),
            true,
        ),
    )?;
    run.files.stage(
        &dir.join("validation.csv"),
        &pkmcal_io::data::with_frame_comment(
            pkmcal_io::data::data_csv(&mech, &tool, &vdata, &units),
            true,
        ),
    )?;
    run.files.stage(
        &dir.join("truth.toml"),
        pkmcal_io::params::params_to_string(
            spec,
            &truth,
            "true parameters of the demo (simulated)",
        )
        .as_bytes(),
    )?;
    say!("pkmcal demo: the paper's case study on the {}", spec.name);
    say!(
        "35 calibration poses spread over the workspace and {DEMO_VALIDATION_POSES} unseen validation poses;"
    );
    say!(
        "paper-sized parameter errors (l, B, D, Pt: 0.18-0.47 mm; dq: 0.95-1.42 mrad); {} µm noise per axis (seed {})",
        DEMO_NOISE_MM * 1e3,
        a.seed
    );
    say!();
    let nominal = Params::nominal(spec);
    let mut rows: Vec<(String, ErrorStats, ErrorStats)> = vec![];
    let mut first = true;
    for model in Model::ALL {
        let opts = pkmcal::CalibrationOptions::new(spec, model);
        // The study every front end runs, validated on the unseen poses.
        let study = pkmcal::identify::study(
            &mech,
            &tool,
            &data,
            vec![],
            &nominal,
            &pkmcal::identify::StudyOptions {
                calibration: opts,
                validation: pkmcal::identify::ValidationPlan::Given(vdata.clone()),
                kfold: None,
                seed: a.seed,
                keep_jacobian: true,
            },
            &|| {},
        )
        .map_err(|e| anyhow::Error::from(e.error))?;
        let state = pkmcal_io::record::CalibrationState {
            mechanism: pkmcal_io::record::MechanismSource::Reference,
            measurement: tool.clone(),
            study,
            load: vec![],
        };
        let study = &state.study;
        let cal = &study.calibration;
        let acc = study.accuracy.clone();
        let vacc = study
            .validation
            .as_ref()
            .map(|v| v.accuracy.clone())
            .context("the demo's study validates on its unseen poses")?;
        let report = pkmcal_io::record::Report::new(
            spec,
            "measurements.csv (simulated)".into(),
            &state,
            |_| format!("{DEMO_VALIDATION_POSES} unseen poses"),
        );
        if model == Model::Exact {
            pkmcal_io::report::write_report_dir(
                run,
                &dir.join("report"),
                &pkmcal_io::report::ReportInputs {
                    report: &report,
                    wording: &crate::words::WORDING,
                    mech: &mech,
                    measurement: &tool,
                    data: &study.poses,
                    before: &study.before,
                    after: &study.after,
                },
            )?;
        }
        if first {
            rows.push((
                "before calibration".into(),
                acc.before.clone(),
                vacc.before.clone(),
            ));
            first = false;
        }
        rows.push((
            format!("after, {} model", model.name()),
            acc.after,
            vacc.after,
        ));
        let name = model.name();
        run.files.stage(
            &dir.join(format!("params-{name}.toml")),
            pkmcal_io::params::params_to_string(
                spec,
                &cal.params,
                &format!("demo calibration, {name} model: {}", cal.termination_reason),
            )
            .as_bytes(),
        )?;
        // The calibration record, as `calibrate --report` writes it.
        run.files.stage(
            &dir.join(format!("report-{name}.json")),
            report.to_json()?.as_bytes(),
        )?;
        say!(
            "{name:>6} model: {} ({} iterations), residual σ {:.2} µm",
            cal.termination_reason,
            cal.iterations,
            cal.noise.first().map_or(0.0, |g| g.sigma) * 1e3
        );
        if model == Model::Exact {
            say_raw!("  ");
            let mut o = String::new();
            write_identifiability(
                &mut o,
                &cal.identifiability,
                "fixed",
                crate::words::WORDING.all_correlations,
            );
            say_raw!("{o}");
        }
        for w in &cal.warnings {
            say!("  warning: {}", w.message);
        }
    }
    say!();
    say!("calibration set (35 poses):");
    print_stats_header(&spec.tool_axes, &spec.tool_units);
    for (label, cal, _) in &rows {
        print_stats(label, cal);
    }
    say!();
    say!("validation set ({DEMO_VALIDATION_POSES} unseen poses):");
    print_stats_header(&spec.tool_axes, &spec.tool_units);
    for (label, _, val) in &rows {
        print_stats(label, val);
    }
    let before = rows[0].1.distance_max;
    say!();
    for (label, cal, val) in &rows[1..] {
        say!(
            "  {label:<24} max distance error {:.4} mm ({:.1} % better), validation RMS {:.4} mm",
            cal.distance_max,
            pkmcal::improvement_percent(before, cal.distance_max),
            val.distance_rms
        );
    }
    say!();
    say!(
        "the paper: max distance error 1.416 mm before, 0.243 mm after (-82 %); files in {}",
        dir.display()
    );
    say!(
        "report of the exact-model calibration: {}",
        dir.join("report").join("report.html").display()
    );
    Ok(())
}
