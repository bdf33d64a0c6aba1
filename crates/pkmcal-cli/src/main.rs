//! `pkmcal`: the command-line tool. Reads files, validates arguments, calls the
//! library, writes files. No kinematics here.

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
