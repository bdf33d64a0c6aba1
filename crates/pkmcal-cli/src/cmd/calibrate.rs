//! `calibrate`: identify parameter errors and encoder offsets from measured
//! positions (eq. 12), validate, report.

use crate::args;
use anyhow::Result;
use pkmcal::identify::ValidationSource;
use pkmcal::{Mechanism, Request};
use pkmcal_io::Run;
use pkmcal_io::data::{Measured, located_in, read_data, read_distances, read_measured};
use pkmcal_io::description::read_description;
use pkmcal_io::params::{params_or_nominal, params_to_string};
use pkmcal_io::record::{CalibrationState, Report};
use pkmcal_io::text::write_summary;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("stated").multiple(true).args(["stated_noise", "stated_distance_noise"])))]
pub struct Args {
    #[command(flatten)]
    pub mech: args::MechanismArg,
    /// Measurements: CSV with the commands (one column per actuated joint) and
    /// the measured tool coordinates (q1,q2,q3 and x,y for the reference), or
    /// ball-bar readings d1..dk (with --setup); optional target_<axis> and
    /// sigma_<axis> columns (any subset; the others are estimated).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model used for identification.
    #[arg(long, default_value = "exact", value_parser = args::model(&args::MODELS))]
    pub model: pkmcal::Model,
    #[command(flatten)]
    pub params_set: args::FreeArgs,
    #[command(flatten)]
    pub priors: args::PriorArgs,
    /// The instrument's stated noise on each length reading, mm (a
    /// datasheet's, a probe's repeatability): a prior of the noise estimate,
    /// and what the model-adequacy test holds the residuals against.
    #[arg(value_parser = args::values::sigma_mm, long, value_name = "MM")]
    pub stated_noise: Option<f64>,
    /// The stated noise on each angle reading, rad (default: the stated
    /// length noise over a 200 mm lever arm).
    #[arg(value_parser = args::values::positive, long, value_name = "RAD", requires = "stated_noise")]
    pub stated_angle_noise: Option<f64>,
    /// The stated noise of the distances given with `--distances`, mm
    /// (calipers on a printed part, a gauge: another instrument than the
    /// data's).
    #[arg(value_parser = args::values::sigma_mm, long, value_name = "MM", requires = "distances")]
    pub stated_distance_noise: Option<f64>,
    /// How many readings each stated noise is worth against the residuals.
    #[arg(value_parser = args::values::non_negative, long, default_value_t = pkmcal::identify::DEFAULT_STATED_NOISE_READINGS, value_name = "N")]
    pub stated_readings: f64,
    /// Only the ratios of the stated noises are known (e.g. calipers five
    /// times the probe's), not their scale: the scale is estimated from the
    /// residuals, and no adequacy test is made.
    #[arg(long, requires = "stated")]
    pub stated_relative: bool,
    /// Starting (and fixed) parameter values; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub start: Option<PathBuf>,
    #[command(flatten)]
    pub load: args::LoadArg,
    /// Output: identified parameters (flat TOML, readable by --params).
    #[arg(long, value_name = "PARAMS.toml")]
    pub out: PathBuf,
    /// Output: JSON report.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// Validate on a separate measurement file.
    #[arg(long, value_name = "FILE", conflicts_with = "holdout")]
    pub validate: Option<PathBuf>,
    /// Hold out this fraction of the poses for validation.
    #[arg(value_parser = args::values::fraction, long, value_name = "F")]
    pub holdout: Option<f64>,
    /// Seed of the hold-out split and of the cross-validation folds.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// k-fold cross-validation on the calibration poses.
    #[arg(value_parser = args::values::folds, long, value_name = "K")]
    pub kfold: Option<usize>,
    /// Write figures (SVG, PNG) and a self-contained report.html here.
    #[arg(long, value_name = "DIR")]
    pub report_dir: Option<PathBuf>,
    /// Loss on the standardised residuals: squared, huber or cauchy.
    #[arg(long, default_value = "squared", value_parser = ["squared", "huber", "cauchy"])]
    pub loss: String,
    /// Tuning constant of the robust loss, in robust standard deviations
    /// (default: 1.345 for huber, 2.385 for cauchy).
    #[arg(value_parser = args::values::positive, long, value_name = "K")]
    pub loss_scale: Option<f64>,
    /// Poses beyond this many robust standard deviations are reported as outliers.
    #[arg(value_parser = args::values::positive, long, default_value_t = 4.0, value_name = "T")]
    pub outlier_threshold: f64,
    /// Drop the outliers and refit.
    #[arg(long)]
    pub drop_outliers: bool,
    #[command(flatten)]
    pub instrument: args::InstrumentArgs,
}

impl Args {
    pub fn paths(&self) -> Result<args::Paths> {
        use crate::words::usage;
        use pkmcal_io::output::{in_dir, is_stdout};
        if is_stdout(&self.out) || self.report.as_deref().is_some_and(is_stdout) {
            return usage(
                "calibrate prints its summary on standard output: write the parameters (--out) and the report (--report) to files",
            );
        }
        let mut out = vec![self.out.clone()];
        out.extend(self.report.clone());
        let mut dirs = vec![];
        if let Some(d) = &self.report_dir {
            out.extend(in_dir(d, pkmcal_io::report::FILES)?);
            dirs.push(d.clone());
        }
        Ok(args::Paths::new(
            [
                self.mech.mechanism.clone(),
                Some(self.data.clone()),
                self.start.clone(),
                self.validate.clone(),
                self.instrument.setup.clone(),
                self.instrument.distances.clone(),
            ],
            out,
        )
        .with_dirs(dirs))
    }
}

pub fn run(run: &Run<'_>, a: Args) -> Result<()> {
    let description = read_description(run, a.mech.mechanism.as_deref())?;
    let axes = a.instrument.axes();
    let Measured {
        description,
        measurement,
        data: all,
        units,
    } = read_measured(
        run,
        description,
        &a.data,
        a.instrument.setup.as_deref(),
        a.instrument.frame,
        axes.as_deref(),
    )?;
    let mech = &description.mech;
    let spec = mech.spec();
    let start = params_or_nominal(run, a.start.as_deref(), mech)?;
    let distances = a.instrument.distances.as_deref();
    let pairs = match distances {
        Some(p) => read_distances(run, p, mech, &measurement, &units)?,
        None => vec![],
    };
    let mut request = Request::new(a.model);
    a.params_set.apply(&mut request);
    a.priors.apply(&mut request)?;
    request.stated_noise = a.stated_noise;
    request.stated_angle_noise = a.stated_angle_noise;
    request.stated_distance_noise = a.stated_distance_noise;
    request.stated_readings = a.stated_readings;
    request.stated_relative = a.stated_relative;
    request.load = a.load.values();
    request.loss = a.loss.clone();
    request.loss_scale = a.loss_scale;
    request.outlier_threshold = a.outlier_threshold;
    request.drop_outliers = a.drop_outliers;
    request.validation = match &a.validate {
        Some(v) => Some(read_data(run, v, mech, &measurement, &units)?),
        None => None,
    };
    request.holdout = a.holdout;
    request.kfold = a.kfold;
    request.seed = a.seed;
    crate::cmd::note_renamed(run, spec, &request);
    let freed = request
        .freed_by_tolerances(spec, &measurement, &description.tolerances)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    let mut study_opts = request
        .study_options(mech, &measurement, &description.tolerances, &start)
        .map_err(|e| crate::cmd::in_mechanism(e, &description))?;
    // The fit's Jacobian is read by nothing but the report's record of the
    // whole calibration: without a report it goes once the fit is done.
    study_opts.keep_jacobian = a.report.is_some() || a.report_dir.is_some();
    let bar = run.bar(a.kfold.unwrap_or(0) as u64, a.kfold.is_none(), "folds", 1);
    // Every pose carries its data-file number and line, so errors, outliers
    // and dropped poses name them without translation.
    let study = pkmcal::identify::study(
        mech,
        &measurement,
        &all,
        pairs,
        &start,
        &study_opts,
        &|| bar.inc(1),
    )
    .map_err(|e| {
        use pkmcal::identify::StudyStage;
        match (e.stage, &a.validate) {
            (StudyStage::Fit, _) => located_in(e.error, &a.data, distances),
            (StudyStage::Validation, Some(v)) => pkmcal_io::Error::located(e.error, v),
            (StudyStage::Validation, None) => pkmcal_io::Error::located(e.error, &a.data),
            _ => pkmcal_io::Error::from(e.error),
        }
    })?;
    bar.finish();
    let state = CalibrationState {
        mechanism: description.source.clone(),
        measurement,
        study,
        load: study_opts.calibration.force.clone(),
    };
    let (measurement, study) = (&state.measurement, &state.study);
    let cal = &study.calibration;
    let header = format!(
        "pkmcal {} calibration ({} model) of {} from {}\nsolver: {}",
        env!("CARGO_PKG_VERSION"),
        a.model.name(),
        spec.name,
        a.data.display(),
        cal.termination_reason
    );
    run.files.stage(
        &a.out,
        params_to_string(spec, &cal.params, &header).as_bytes(),
    )?;
    let (before, after, kept) = (&study.before, &study.after, &study.poses);
    let report = Report::new(spec, a.data.display().to_string(), &state, |source| match (
        source,
        &a.validate,
    ) {
        (ValidationSource::Given, Some(p)) => p.display().to_string(),
        (ValidationSource::Given, None) => "validation poses".to_string(),
        (ValidationSource::HeldOut { count, seed }, _) => format!(
            "{count} held-out poses of {} (seed {seed})",
            a.data.display()
        ),
    });
    if let Some(r) = &a.report {
        run.files.stage(r, report.to_json()?.as_bytes())?;
    }
    if let Some(dir) = &a.report_dir {
        pkmcal_io::report::write_report_dir(
            run,
            dir,
            &pkmcal_io::report::ReportInputs {
                report: &report,
                wording: &crate::words::WORDING,
                mech,
                measurement,
                data: kept,
                before,
                after,
            },
        )?;
    }
    let mut summary = String::new();
    write_summary(&mut summary, &report, measurement, &crate::words::WORDING);
    if !freed.is_empty() {
        say!(
            "free by their tolerances (a tolerance frees its parameter; --fix keeps one fixed): {}",
            freed.join(" ")
        );
    }
    say_raw!("{summary}");
    say!();
    say!("identified parameters -> {}", a.out.display());
    if let Some(r) = &a.report {
        say!("report -> {}", r.display());
    }
    if let Some(d) = &a.report_dir {
        say!("figures and report.html -> {}", d.display());
    }
    Ok(())
}
