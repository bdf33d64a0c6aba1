//! `calibrate`: identify parameter errors and encoder offsets from measured
//! positions (eq. 12), validate, report.

use crate::args;
use anyhow::Result;
use pkmcal_io::Run;
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
    #[arg(long, value_name = "FILE")]
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
        use pkmcal_io::output::{in_dir, is_stdout, usage};
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
    let loss = pkmcal::Loss::named(&a.loss, a.loss_scale)?;
    pkmcal_io::calibrate::run_calibrate(
        run,
        pkmcal_io::calibrate::CalibrateConfig {
            loss,
            outlier_threshold: a.outlier_threshold,
            drop_outliers: a.drop_outliers,
            frame: a.instrument.frame,
            axes: a.instrument.axes,
            mechanism: a.mech.mechanism,
            data: a.data,
            model: a.model,
            free: a.params_set.free,
            fix: a.params_set.fix,
            start: a.start,
            load: a.load.values(),
            out: a.out,
            report: a.report,
            validate: a.validate,
            holdout: a.holdout,
            seed: a.seed,
            kfold: a.kfold,
            report_dir: a.report_dir,
            setup: a.instrument.setup,
            distances: a.instrument.distances,
            tolerances: a.priors.tolerance,
            no_tolerances: a.priors.no_tolerances,
            stated_noise: a
                .stated_noise
                .map(|l| pkmcal_io::io::noise_arg(l, a.stated_angle_noise)),
            stated_distance_noise: a.stated_distance_noise,
            stated_readings: a.stated_readings,
            stated_relative: a.stated_relative,
        },
    )
}
