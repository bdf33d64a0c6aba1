//! `pkmcal`: the command-line tool. Reads files, validates arguments, calls the
//! library, writes files. No kinematics here.

mod calibrate;
mod commands;
mod io;

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// Kinematic calibration of (redundantly actuated) parallel mechanisms.
#[derive(Parser)]
#[command(name = "pkmcal", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Predict tool positions, deflections and internal torques for actuator commands.
    Predict(PredictArgs),
    /// Simulate measurements: nominal commands for targets, true positions plus noise.
    Simulate(SimulateArgs),
    /// Identify parameter errors and encoder offsets from measured positions (eq. 12).
    Calibrate(CalibrateArgs),
    /// Identifiability of the parameters from a data set, without fitting.
    Analyze(AnalyzeArgs),
    /// Run the paper's case study on the built-in reference mechanism.
    Demo(DemoArgs),
}

#[derive(clap::Args)]
pub struct PredictArgs {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
    /// Parameter values (flat TOML `name = value`); unnamed parameters stay nominal.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    /// Actuator commands: CSV with one column per actuated joint (q1,q2,q3; rad).
    #[arg(long, value_name = "C.csv")]
    pub commands: PathBuf,
    /// External force applied to the tool, N, one value per tool axis (e.g. `0,-9.81`).
    #[arg(long, value_name = "FX,FY", allow_hyphen_values = true)]
    pub force: Option<String>,
    /// Calibration report (from `calibrate --report`) whose parameter covariance
    /// gives each prediction's standard deviation (columns sigma_x, sigma_y).
    #[arg(long, value_name = "REPORT.json")]
    pub uncertainty: Option<PathBuf>,
    /// Output CSV.
    #[arg(long, value_name = "OUT.csv")]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct SimulateArgs {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
    /// True parameter values (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub truth: Option<PathBuf>,
    /// Target tool positions: CSV with columns target_x,target_y (mm).
    #[arg(
        long,
        value_name = "T.csv",
        conflicts_with = "grid",
        required_unless_present = "grid"
    )]
    pub targets: Option<PathBuf>,
    /// Instead of a targets file: N targets spread evenly over the usable workspace.
    #[arg(long, value_name = "N")]
    pub grid: Option<usize>,
    /// Standard deviation of the Gaussian measurement noise per axis, mm.
    #[arg(long, default_value_t = 0.0, value_name = "SIGMA_MM")]
    pub noise: f64,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output CSV: target_x,target_y,q1,q2,q3,x,y.
    #[arg(long, value_name = "DATA.csv")]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
    /// Measurements: CSV with q1,q2,q3 (rad) and x,y (mm); optional target_x,target_y.
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model used for identification.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    /// Parameters to identify, comma separated (`all`, `default` allowed); default: the paper's 16.
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed, comma separated (removed from the free set).
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
    /// Starting (and fixed) parameter values; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub start: Option<PathBuf>,
    /// External force applied to the tool during the measurements, N.
    #[arg(long, value_name = "FX,FY", allow_hyphen_values = true)]
    pub force: Option<String>,
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
    #[arg(long, value_name = "F")]
    pub holdout: Option<f64>,
    /// Seed of the hold-out split and of the cross-validation folds.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// k-fold cross-validation on the calibration poses.
    #[arg(long, value_name = "K")]
    pub kfold: Option<usize>,
}

#[derive(clap::Args)]
pub struct AnalyzeArgs {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
    /// Measurements (only the commands are used).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    /// Parameters to analyse (as for calibrate).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed.
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
    /// Parameter values at which to analyse; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// External force applied to the tool, N.
    #[arg(long, value_name = "FX,FY", allow_hyphen_values = true)]
    pub force: Option<String>,
    /// Output: JSON report of the analysis.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Directory for the demo's files.
    #[arg(long, default_value = "pkmcal-demo", value_name = "DIR")]
    pub out_dir: PathBuf,
    /// Random seed of the measurement noise.
    #[arg(long, default_value_t = 2004)]
    pub seed: u64,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Predict(a) => commands::predict(a),
        Command::Simulate(a) => commands::simulate(a),
        Command::Calibrate(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            calibrate::run_calibrate(calibrate::CalibrateConfig {
                mechanism: a.mechanism,
                data: a.data,
                model,
                free: a.free,
                fix: a.fix,
                start: a.start,
                force: a.force,
                out: a.out,
                report: a.report,
                validate: a.validate,
                holdout: a.holdout,
                seed: a.seed,
                kfold: a.kfold,
            })
        }),
        Command::Analyze(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            calibrate::run_analyze(calibrate::AnalyzeConfig {
                mechanism: a.mechanism,
                data: a.data,
                model,
                free: a.free,
                fix: a.fix,
                params: a.params,
                force: a.force,
                report: a.report,
            })
        }),
        Command::Demo(a) => commands::demo(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(1)
        }
    }
}
