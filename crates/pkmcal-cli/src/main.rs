//! `pkmcal`: the command-line tool. Reads files, validates arguments, calls the
//! library, writes files. No kinematics here.

mod commands;
mod progress;

use pkmcal_io::{Run, calibrate, gcode, output, report, usecal};

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// Kinematic calibration of (redundantly actuated) parallel mechanisms.
#[derive(Parser)]
#[command(name = "pkmcal", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Units of the numbers in data files (read and written), e.g.
    /// `angle=deg,length=m` or `counts_per_rev=4096`: angle rad|deg, length
    /// mm|m|um, counts_per_rev, counts_per_mm (commands in encoder counts).
    /// Overrides the mechanism file's [units]; default mm and rad.
    #[arg(long, global = true, value_name = "KEY=UNIT,…")]
    units: Option<String>,
    /// The largest file read whole, in MiB, for every kind of file (default:
    /// 16 for mechanism, parameter, setup and firmware files and reports,
    /// 256 for data files and G-code; streamed commands and targets have no
    /// size limit, only 1 MiB per line).
    #[arg(long, global = true, value_name = "MB", value_parser = clap::value_parser!(u64).range(1..=1 << 20))]
    max_input_mb: Option<u64>,
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
    /// Actuator commands that bring the tool to targets under calibrated parameters.
    Compensate(CompensateArgs),
    /// Rewrite the G0/G1 moves of a G-code program so that a controller running
    /// the nominal kinematics makes the calibrated machine reach the programmed points.
    Gcode(GcodeArgs),
    /// Choose measurement poses that make the parameters most observable.
    Plan(PlanArgs),
    /// Predict post-calibration accuracy of a measurement plan by simulation.
    Montecarlo(MonteCarloArgs),
    /// Ball-bar readings to tool positions (least squares) with uncertainties.
    Trilaterate(TrilaterateArgs),
    /// Calibrate a linear delta printer from its Klipper printer.cfg (the probe
    /// results DELTA_CALIBRATE saved) and write Klipper's values back.
    Klipper(KlipperArgs),
    /// Calibrate a linear delta printer run by RepRapFirmware from its M665/M666
    /// settings and heights probed with G30 S-1; print (and write) the new
    /// M665/M666 lines.
    Reprap(ReprapArgs),
    /// Run the paper's case study on the built-in reference mechanism.
    Demo(DemoArgs),
}

#[derive(clap::Args)]
pub struct KlipperArgs {
    /// The printer's Klipper configuration (kinematics: delta), with the
    /// [delta_calibrate] probe results (height0, height0_pos, …) that
    /// DELTA_CALIBRATE and SAVE_CONFIG wrote.
    #[arg(long, value_name = "printer.cfg")]
    pub config: PathBuf,
    /// Parameters to identify, comma separated: Klipper's (`default`:
    /// delta_radius, angle_a, angle_b, da, db, dc; the d's are endstop errors)
    /// or more (arm_a, arm_b, arm_c, angle_c, the towers' tilts a.tilt1, …).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Write the configuration with the new values (in its SAVE_CONFIG block,
    /// as Klipper writes them) here; never over --config.
    #[arg(long, value_name = "NEW.cfg")]
    pub out: Option<PathBuf>,
    /// Also write the printer as a pkmcal mechanism (mechanism.toml), the
    /// probe data (probes.csv) and the identified parameters
    /// (calibration.toml) here, for the other commands.
    #[arg(long, value_name = "DIR")]
    pub out_dir: Option<PathBuf>,
    /// How probe heights and DELTA_ANALYZE distances are weighed against
    /// each other: `estimated` (a noise level each, estimated from the
    /// residuals) or `klipper` (Klipper's fixed ratio: heights weigh
    /// n_distances / (0.5 · n_probed) times a distance).
    #[arg(long, default_value = "estimated", value_parser = values::weighting)]
    pub weighting: pkmcal_io::klipper::Weighting,
}

#[derive(clap::Args)]
pub struct ReprapArgs {
    /// The G-code file that sets the delta's geometry: config.g, or
    /// config-override.g (every M665 and M666 line is read, later ones
    /// overriding).
    #[arg(long, value_name = "config.g")]
    pub config: PathBuf,
    /// The probe results: CSV with columns x, y (where the probe touched,
    /// mm) and z (the height at which it triggered, as `G30 S-1` reports it,
    /// mm).
    #[arg(long, value_name = "PROBES.csv")]
    pub probes: PathBuf,
    /// Parameters to identify, comma separated: RepRapFirmware's 6 factors
    /// (`default`: delta_radius, angle_a, angle_b and the endstop errors da,
    /// db, dc) or more (arm_a, arm_b, arm_c for the diagonals; bed.rx, bed.ry
    /// for the bed tilts M666 A B).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Write the new M665 and M666 lines here (never over --config).
    #[arg(long, value_name = "NEW.g")]
    pub out: Option<PathBuf>,
}

/// The mechanism option shared by every subcommand.
#[derive(clap::Args)]
pub struct MechanismArg {
    /// Mechanism file (TOML); the built-in reference mechanism if omitted.
    #[arg(long, value_name = "M.toml")]
    pub mechanism: Option<PathBuf>,
}

/// Which parameters to identify.
#[derive(clap::Args)]
pub struct FreeArgs {
    /// Parameters to identify, comma separated (`all`, `default` allowed); default: the mechanism's default set (the paper's 16 for the reference).
    #[arg(long, value_name = "NAMES")]
    pub free: Option<String>,
    /// Parameters to keep fixed, comma separated (removed from the free set).
    #[arg(long, value_name = "NAMES")]
    pub fix: Option<String>,
}

#[derive(clap::Args)]
pub struct PredictArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Parameter values (flat TOML `name = value`); unnamed parameters stay nominal.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    /// Actuator commands: CSV with one column per actuated joint, named as the
    /// mechanism's joints (q1,q2,q3 for the reference), in rad or mm.
    #[arg(long, value_name = "C.csv")]
    pub commands: PathBuf,
    /// External load applied to the tool, one value per tool coordinate, a wrench: a force in N along each length coordinate, a moment in N·m
    /// about each angle coordinate's axis (phi: the plane's normal; rx, ry,
    /// rz: the base x, y, z axes), e.g. `0,-9.81`.
    #[arg(long, value_name = "F1,F2,…", allow_hyphen_values = true)]
    pub force: Option<String>,
    /// Calibration report (from `calibrate --report`) whose parameter covariance
    /// gives each prediction's standard deviation (columns sigma_<axis>).
    #[arg(long, value_name = "REPORT.json")]
    pub uncertainty: Option<PathBuf>,
    /// Output CSV.
    #[arg(long, value_name = "OUT.csv")]
    pub out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

#[derive(clap::Args)]
pub struct SimulateArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
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
    #[arg(value_parser = values::count, long, value_name = "N")]
    pub grid: Option<usize>,
    /// Standard deviation of the Gaussian noise on each length coordinate
    /// (positions, bar readings, target points), mm.
    #[arg(value_parser = values::length_noise, long, default_value_t = 0.0, value_name = "MM")]
    pub noise: f64,
    /// Standard deviation of the Gaussian noise on each angle coordinate
    /// (orientations such as phi, rx, ry, rz), rad. Default: the length noise
    /// over a 200 mm lever arm (1e-5 rad for --noise 0.002).
    #[arg(value_parser = values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Measure from an instrument standing at this pose in the base frame
    /// (x,y,phi in mm and rad for planar tools; x,y,z,rx,ry,rz for spatial
    /// ones), as a tracker would. Without it the data are in the base frame
    /// and the file says so (`# frame: base`).
    #[arg(long, value_name = "POSE", allow_hyphen_values = true)]
    pub instrument_frame: Option<String>,
    /// Output CSV: targets, commands and measured tool coordinates
    /// (target_x,target_y,q1,q2,q3,x,y for the reference; with --setup: d1..dk
    /// instead of the tool coordinates).
    #[arg(long, value_name = "DATA.csv")]
    pub out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
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

#[derive(clap::Args)]
pub struct TrilaterateArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Ball-bar setup: sockets and bar offset.
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Data with the bar readings d1, d2, … (mm).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Standard deviation of one reading (mm), for the positions' uncertainty.
    #[arg(value_parser = values::sigma_mm, long, default_value_t = 0.002, value_name = "MM")]
    pub sigma: f64,
    /// Output CSV: targets and commands if present, x, y, sigma_x, sigma_y.
    #[arg(long, value_name = "OUT.csv")]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Measurements: CSV with the commands (one column per actuated joint) and
    /// the measured tool coordinates (q1,q2,q3 and x,y for the reference), or
    /// ball-bar readings d1..dk (with --setup); optional target_<axis> and
    /// sigma_<axis> columns (any subset; the others are estimated).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model used for identification.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    #[command(flatten)]
    pub params_set: FreeArgs,
    /// Starting (and fixed) parameter values; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub start: Option<PathBuf>,
    /// External load applied to the tool during the measurements, one value per tool coordinate, a wrench: a force in N along each length coordinate, a moment in N·m
    /// about each angle coordinate's axis (phi: the plane's normal; rx, ry,
    /// rz: the base x, y, z axes).
    #[arg(long, value_name = "F1,F2,…", allow_hyphen_values = true)]
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
    #[arg(value_parser = values::fraction, long, value_name = "F")]
    pub holdout: Option<f64>,
    /// Seed of the hold-out split and of the cross-validation folds.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// k-fold cross-validation on the calibration poses.
    #[arg(value_parser = values::folds, long, value_name = "K")]
    pub kfold: Option<usize>,
    /// Write figures (SVG, PNG) and a self-contained report.html here.
    #[arg(long, value_name = "DIR")]
    pub report_dir: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Ball-bar setup (sockets, bar offset) for data with distances d1, d2, …
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Loss on the standardised residuals: squared, huber or cauchy.
    #[arg(long, default_value = "squared", value_parser = ["squared", "huber", "cauchy"])]
    pub loss: String,
    /// Tuning constant of the robust loss, in robust standard deviations
    /// (default: 1.345 for huber, 2.385 for cauchy).
    #[arg(value_parser = values::positive, long, value_name = "K")]
    pub loss_scale: Option<f64>,
    /// Poses beyond this many robust standard deviations are reported as outliers.
    #[arg(value_parser = values::positive, long, default_value_t = 4.0, value_name = "T")]
    pub outlier_threshold: f64,
    /// Drop the outliers and refit.
    #[arg(long)]
    pub drop_outliers: bool,
    /// Where the measuring instrument stands: `free` (a tracker or camera
    /// where it was put: its frame is identified with the rest), `base` (the
    /// data are in the base frame, e.g. trilaterated from ball-bar sockets at
    /// known places), `auto`: base when the data file says `# frame: base`
    /// (simulate and trilaterate write it), otherwise free. Ball-bar
    /// readings carry no frame.
    #[arg(long, default_value = "auto", value_parser = ["auto", "free", "base"])]
    pub frame: String,
    /// Only these tool axes were measured (comma-separated, e.g. `z` for a
    /// height probe); the data file then needs only their columns.
    #[arg(long, value_name = "AXES")]
    pub axes: Option<String>,
    /// Distances measured between pairs of poses (calipers on a printed
    /// object, a gauge), fitted with the data: CSV with the commands of both
    /// poses (`<actuator>_1`, `<actuator>_2` for every actuated joint) and
    /// `distance` in mm (optional `sigma_distance`; otherwise their noise is
    /// estimated apart from the data's).
    #[arg(long, value_name = "PAIRS.csv")]
    pub distances: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct AnalyzeArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Measurements (only the commands are used).
    #[arg(long, value_name = "DATA.csv")]
    pub data: PathBuf,
    /// Forward model.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    #[command(flatten)]
    pub params_set: FreeArgs,
    /// Parameter values at which to analyse; nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// External load applied to the tool, one value per tool coordinate, a
    /// wrench: a force in N along each length coordinate, a moment in N·m
    /// about each angle coordinate's axis (phi: the plane's normal; rx, ry,
    /// rz: the base x, y, z axes).
    #[arg(long, value_name = "F1,F2,…", allow_hyphen_values = true)]
    pub force: Option<String>,
    /// Output: JSON report of the analysis.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// Ball-bar setup for data with distances d1, d2, …
    #[arg(long, value_name = "S.toml")]
    pub setup: Option<PathBuf>,
    /// Where the measuring instrument stands (as for `calibrate`): `free`
    /// adds its frame's parameters to the analysis, `base` leaves them out,
    /// `auto` reads the data file's `# frame: base`.
    #[arg(long, default_value = "auto", value_parser = ["auto", "free", "base"])]
    pub frame: String,
    /// Only these tool axes were measured (comma-separated, e.g. `z` for a
    /// height probe); the data file then needs only their columns.
    #[arg(long, value_name = "AXES")]
    pub axes: Option<String>,
    /// Distances measured between pairs of poses (calipers on a printed
    /// object, a gauge), analysed with the data: CSV with `<actuator>_1`,
    /// `<actuator>_2` and `distance` columns (see calibrate).
    #[arg(long, value_name = "PAIRS.csv")]
    pub distances: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct CompensateArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Calibrated parameters (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    /// Targets: CSV with one column target_<axis> per tool axis.
    #[arg(
        long,
        value_name = "T.csv",
        required_unless_present = "grid",
        conflicts_with = "grid"
    )]
    pub targets: Option<PathBuf>,
    /// A regular grid of corrections instead of a targets file: per tool axis
    /// `start:stop:step` (gridded) or one value (held), e.g.
    /// `x=-100:100:10,y=50:250:10`; axes not named are held at the middle of
    /// the workspace box. Written as CSV, or JSON if --out ends in .json, with
    /// the interpolation error checked at the cell centres.
    #[arg(
        long,
        value_name = "AXIS=START:STOP:STEP,…",
        allow_hyphen_values = true
    )]
    pub grid: Option<String>,
    /// Cartesian pre-distortion for a controller that accepts only tool
    /// targets: write the target to send (command_<axis>) so that the real
    /// machine reaches the wanted one, instead of actuator commands.
    #[arg(long, conflicts_with = "grid")]
    pub cartesian: bool,
    /// The controller's own parameter values (flat TOML) for --cartesian;
    /// nominal if omitted. (Corrections are always against the nominal model.)
    #[arg(long, value_name = "P.toml")]
    pub controller: Option<PathBuf>,
    /// Model to invert: exact (deflections included) or rigid.
    #[arg(long, default_value = "exact", value_parser = ["exact", "rigid"])]
    pub model: String,
    /// External load applied to the tool (e.g. a payload's weight), one value per tool coordinate, a wrench: a force in N along each length coordinate, a moment in N·m
    /// about each angle coordinate's axis (phi: the plane's normal; rx, ry,
    /// rz: the base x, y, z axes).
    #[arg(long, value_name = "F1,F2,…", allow_hyphen_values = true)]
    pub load: Option<String>,
    /// Actuator torques (N·m) whose internal part is held as a preload.
    #[arg(long, value_name = "T1,T2,T3", allow_hyphen_values = true)]
    pub preload: Option<String>,
    /// Report unreachable or singular targets and skip them instead of stopping.
    #[arg(long)]
    pub skip_unreachable: bool,
    /// Output CSV: targets, commands, corrections (delta_<actuator>, to add to
    /// the nominal model's commands) and the actuators' internal torques
    /// (torque_<actuator> in N·m) or forces (force_<actuator> in N).
    #[arg(long, value_name = "COMMANDS.csv")]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct GcodeArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Calibrated parameters (flat TOML): the real machine.
    #[arg(long, value_name = "P.toml")]
    pub params: PathBuf,
    /// The controller's own parameter values (flat TOML); nominal if omitted.
    #[arg(long, value_name = "P.toml")]
    pub controller: Option<PathBuf>,
    /// Model of the real machine: exact (deflections included) or rigid.
    #[arg(long, default_value = "exact", value_parser = ["exact", "rigid"])]
    pub model: String,
    /// External load on the tool while it moves, one value per tool coordinate, a wrench: a force in N along each length coordinate, a moment in N·m
    /// about each angle coordinate's axis (phi: the plane's normal; rx, ry,
    /// rz: the base x, y, z axes).
    #[arg(long, value_name = "F1,F2,…", allow_hyphen_values = true)]
    pub load: Option<String>,
    /// The G-code program to rewrite.
    #[arg(long = "in", value_name = "PROGRAM.gcode")]
    pub input: PathBuf,
    /// Added to the programmed coordinates to give tool coordinates (mm; degrees for angles), one per tool axis.
    #[arg(long, value_name = "X,Y,…", allow_hyphen_values = true)]
    pub offset: Option<String>,
    /// Split moves longer than this (mm) so that the correction follows the path.
    #[arg(long, value_name = "MM")]
    pub max_segment: Option<f64>,
    /// The rewritten program (`-` for standard output).
    #[arg(long, value_name = "OUT.gcode")]
    pub out: PathBuf,
}

#[derive(clap::Args)]
pub struct PlanArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Number of poses to choose.
    #[arg(value_parser = values::count, long, value_name = "N")]
    pub count: usize,
    /// Spacing of the candidate lattice over the usable workspace, mm (an
    /// axis in rad is spaced by it over the mechanism's lever arm).
    #[arg(value_parser = values::positive, long, default_value_t = 6.0, value_name = "SPACING")]
    pub candidates: f64,
    /// Most candidates: a lattice with more usable points is thinned evenly
    /// to this many (a 6-DOF workspace has many at any spacing).
    #[arg(value_parser = values::count, long, default_value_t = 4000, value_name = "N")]
    pub max_candidates: usize,
    /// Hide the progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Observability index to maximise.
    #[arg(long, default_value = "O5", value_parser = ["O1", "O3", "O5"], ignore_case = true)]
    pub criterion: String,
    /// Model whose identification Jacobian is used.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    /// Expected parameters (nominal if omitted).
    #[arg(long, value_name = "P.toml")]
    pub params: Option<PathBuf>,
    #[command(flatten)]
    pub params_set: FreeArgs,
    /// Output CSV: targets and commands (target_x,target_y,q1,q2,q3 for the reference).
    #[arg(long, value_name = "POSES.csv")]
    pub out: PathBuf,
    /// Also write the plain grid of the same size (the baseline), same columns.
    #[arg(long, value_name = "GRID.csv")]
    pub grid_out: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct MonteCarloArgs {
    #[command(flatten)]
    pub mech: MechanismArg,
    /// Measurement plan: CSV with target_<axis> columns (e.g. from `plan`).
    #[arg(long, value_name = "POSES.csv")]
    pub poses: PathBuf,
    /// Number of simulated calibrations (at most 1,000,000).
    #[arg(value_parser = values::runs, long, default_value_t = 200)]
    pub runs: usize,
    /// Measurement noise on each length coordinate, mm.
    #[arg(value_parser = values::length_noise, long, default_value_t = 0.002, value_name = "MM")]
    pub noise: f64,
    /// Measurement noise on each angle coordinate, rad (default: the length
    /// noise over a 200 mm lever arm).
    #[arg(value_parser = values::angle_noise, long, value_name = "RAD")]
    pub angle_noise: Option<f64>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Model used to calibrate.
    #[arg(long, default_value = "exact", value_parser = ["exact", "linear", "rigid"])]
    pub model: String,
    #[command(flatten)]
    pub params_set: FreeArgs,
    /// Standard deviation of the random errors of the free parameters in mm
    /// (lengths, positions, offsets of prismatic actuators).
    #[arg(value_parser = values::length_noise, long, default_value_t = 0.3, value_name = "MM")]
    pub length_error: f64,
    /// Standard deviation of the random errors of the free parameters in rad
    /// (encoder offsets of revolute actuators, axis angles).
    #[arg(
        value_parser = values::angle_noise,
        long,
        default_value_t = 0.001,
        value_name = "RAD",
        alias = "offset-error"
    )]
    pub angle_error: f64,
    /// Unseen poses on which accuracy is judged.
    #[arg(value_parser = values::count, long, default_value_t = 50, value_name = "N")]
    pub validation: usize,
    /// Output CSV with one row per run.
    #[arg(long, value_name = "RUNS.csv")]
    pub out: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
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

/// Option values checked by the parser (a bad value exits 2, naming the
/// option).
mod values {
    /// Largest noise or error on a length that makes sense (mm).
    pub const MAX_LENGTH_MM: f64 = 1000.0;
    /// Largest noise or error on an angle that makes sense (rad).
    pub const MAX_ANGLE_RAD: f64 = 1.0;

    fn number(s: &str) -> Result<f64, String> {
        s.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("`{s}` is not a finite number"))
    }
    pub fn positive(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v > 0.0)
            .then_some(v)
            .ok_or_else(|| format!("{v} must be positive"))
    }
    /// A standard deviation of a length reading, mm: the library's bounds.
    pub fn sigma_mm(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (pkmcal::identify::MIN_SIGMA..=MAX_LENGTH_MM)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| {
                format!(
                    "{v} mm must be between {:e} and {MAX_LENGTH_MM:e} mm",
                    pkmcal::identify::MIN_SIGMA
                )
            })
    }
    pub fn fraction(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (v > 0.0 && v < 1.0)
            .then_some(v)
            .ok_or_else(|| format!("{v} must be between 0 and 1 (exclusive)"))
    }
    pub fn length_noise(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (0.0..=MAX_LENGTH_MM)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| format!("{v} mm must be between 0 and {MAX_LENGTH_MM} mm"))
    }
    pub fn angle_noise(s: &str) -> Result<f64, String> {
        let v = number(s)?;
        (0.0..=MAX_ANGLE_RAD)
            .contains(&v)
            .then_some(v)
            .ok_or_else(|| format!("{v} rad must be between 0 and {MAX_ANGLE_RAD} rad"))
    }
    pub fn count(s: &str) -> Result<usize, String> {
        let v: usize = s
            .trim()
            .parse()
            .map_err(|_| format!("`{s}` is not a whole number"))?;
        (v >= 1)
            .then_some(v)
            .ok_or_else(|| "must be at least 1".to_string())
    }
    pub fn runs(s: &str) -> Result<usize, String> {
        let v = count(s)?;
        (v <= pkmcal::apply::montecarlo::MAX_RUNS)
            .then_some(v)
            .ok_or_else(|| {
                format!(
                    "at most {} runs (each is kept in memory); run several studies with other seeds for more",
                    pkmcal::apply::montecarlo::MAX_RUNS
                )
            })
    }
    pub fn weighting(s: &str) -> Result<pkmcal_io::klipper::Weighting, String> {
        s.parse()
    }
    pub fn folds(s: &str) -> Result<usize, String> {
        let v = count(s)?;
        (v >= 2)
            .then_some(v)
            .ok_or_else(|| "k-fold cross-validation needs at least 2 folds".to_string())
    }
}

/// The files a command reads and writes, checked before any work
/// ([`output::check`]).
fn check_paths(run: &Run, command: &Command) -> anyhow::Result<()> {
    use std::path::Path;
    let m = |a: &MechanismArg| a.mechanism.clone();
    let mut dirs: Vec<PathBuf> = vec![];
    let (inputs, outputs): (Vec<Option<PathBuf>>, Vec<PathBuf>) = match command {
        Command::Predict(a) => (
            vec![
                m(&a.mech),
                a.params.clone(),
                Some(a.commands.clone()),
                a.uncertainty.clone(),
            ],
            vec![a.out.clone()],
        ),
        Command::Simulate(a) => (
            vec![
                m(&a.mech),
                a.truth.clone(),
                a.targets.clone(),
                a.setup.clone(),
            ],
            std::iter::once(a.out.clone())
                .chain(a.distances_out.clone())
                .collect(),
        ),
        Command::Trilaterate(a) => (
            vec![m(&a.mech), a.setup.clone(), Some(a.data.clone())],
            vec![a.out.clone()],
        ),
        Command::Calibrate(a) => {
            if output::is_stdout(&a.out) || a.report.as_deref().is_some_and(output::is_stdout) {
                return output::usage(
                    "calibrate prints its summary on standard output: write the parameters (--out) and the report (--report) to files",
                );
            }
            let mut out = vec![a.out.clone()];
            out.extend(a.report.clone());
            if let Some(d) = &a.report_dir {
                out.extend(output::in_dir(d, report::FILES)?);
                dirs.push(d.clone());
            }
            (
                vec![
                    m(&a.mech),
                    Some(a.data.clone()),
                    a.start.clone(),
                    a.validate.clone(),
                    a.setup.clone(),
                    a.distances.clone(),
                ],
                out,
            )
        }
        Command::Analyze(a) => (
            vec![
                m(&a.mech),
                Some(a.data.clone()),
                a.params.clone(),
                a.setup.clone(),
                a.distances.clone(),
            ],
            a.report.iter().cloned().collect(),
        ),
        Command::Compensate(a) => (
            vec![
                m(&a.mech),
                a.params.clone(),
                a.targets.clone(),
                a.controller.clone(),
            ],
            vec![a.out.clone()],
        ),
        Command::Gcode(a) => (
            vec![
                m(&a.mech),
                Some(a.params.clone()),
                a.controller.clone(),
                Some(a.input.clone()),
            ],
            vec![a.out.clone()],
        ),
        Command::Plan(a) => {
            let mut out = vec![a.out.clone()];
            out.extend(a.grid_out.clone());
            (vec![m(&a.mech), a.params.clone()], out)
        }
        Command::Montecarlo(a) => (
            vec![m(&a.mech), Some(a.poses.clone())],
            a.out.iter().cloned().collect(),
        ),
        Command::Klipper(a) => {
            let mut out: Vec<PathBuf> = a.out.iter().cloned().collect();
            if let Some(d) = &a.out_dir {
                out.extend(output::in_dir(d, &pkmcal_io::klipper::OUT_DIR_FILES)?);
                out.extend(output::in_dir(d, &[pkmcal_io::klipper::DISTANCES_FILE])?);
                dirs.push(d.clone());
            }
            (vec![Some(a.config.clone())], out)
        }
        Command::Reprap(a) => (
            vec![Some(a.config.clone()), Some(a.probes.clone())],
            a.out.iter().cloned().collect(),
        ),
        Command::Demo(a) => {
            let mut out = output::in_dir(&a.out_dir, commands::DEMO_FILES)?;
            out.extend(output::in_dir(&a.out_dir.join("report"), report::FILES)?);
            dirs.push(a.out_dir.clone());
            (vec![], out)
        }
    };
    let inputs: Vec<PathBuf> = inputs.into_iter().flatten().collect();
    let inputs: Vec<&Path> = inputs.iter().map(PathBuf::as_path).collect();
    let outputs: Vec<&Path> = outputs.iter().map(PathBuf::as_path).collect();
    run.files.check(&inputs, &outputs, &dirs)
}

fn main() -> ExitCode {
    keep_freed_memory();
    let cli = Cli::parse();
    // One run per process: its files live as long as the process, and the
    // Ctrl-C handler and the panic hook clean them up.
    let files: &'static pkmcal_io::Files = Box::leak(Box::new(
        pkmcal_io::Files::new()
            .tracking_inputs()
            .with_max_input_mb(cli.max_input_mb),
    ));
    install_cleanup(files);
    let result = units_option(cli.units.as_deref()).and_then(|units| {
        let run = Run {
            files,
            units,
            bars: &progress::TerminalBars,
        };
        check_paths(&run, &cli.command)?;
        in_pool(&run, cli.command)?;
        files.commit()
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            files.discard();
            pkmcal_io::note!("error: {e:#}");
            if e.downcast_ref::<output::Usage>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

/// The `--units` option, read (a usage error names it).
fn units_option(text: Option<&str>) -> anyhow::Result<pkmcal::PartialUnits> {
    Ok(match text {
        Some(t) => {
            pkmcal::PartialUnits::parse(t).map_err(|e| output::Usage(format!("--units: {e}")))?
        }
        None => pkmcal::PartialUnits::default(),
    })
}

/// Remove the run's temporaries on Ctrl-C, SIGTERM and panics.
fn install_cleanup(files: &'static pkmcal_io::Files) {
    let _ = ctrlc::set_handler(move || {
        // The files stay held until the exit: the run cannot stage or
        // commit anything after the temporaries are removed.
        files.interrupt(|committed| {
            // (Not `eprintln!`: with standard error closed it would panic,
            // and the panic hook wait for the state held here.)
            pkmcal_io::note!(
                "{}",
                if committed {
                    "interrupted after the outputs were written (they are complete)"
                } else {
                    "interrupted: no output was written"
                }
            );
            std::process::exit(130);
        });
    });
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        files.discard();
        // `println!` panics when standard output is closed (`| head`) or
        // full: a one-line error and exit 1, not a panic report.
        let message = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if let Some(cause) = message.strip_prefix("failed printing to stdout: ") {
            pkmcal_io::note!("error: cannot write to standard output: {cause}");
            std::process::exit(1);
        }
        default(info);
    }));
}

/// glibc gives the free memory at the top of a thread's heap back to the
/// system as soon as it exceeds 128 KB, and takes it back page by page (a
/// system call and page faults) at the next allocation: a calibration frees
/// and allocates its Jacobians (hundreds of KB) at every evaluation, on the
/// pool's threads, and paid about 460 `mprotect` calls and 400 page faults
/// for it on gough-stewart-8. Freed memory is kept up to 64 MB instead (the
/// peak is unchanged). Measured in BENCHMARKS.md (issue 12).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn keep_freed_memory() {
    // SAFETY: `mallopt` only sets parameters of the allocator; called
    // first thing in `main`, before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_TRIM_THRESHOLD, 64 << 20);
        libc::mallopt(libc::M_TOP_PAD, 16 << 20);
        libc::mallopt(libc::M_MMAP_THRESHOLD, 4 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn keep_freed_memory() {}

/// Runs the command on a thread of rayon's pool (with the main thread's
/// stack size): the library's parallel sections (the poses of each
/// evaluation of a calibration, a hundred or so per fit) then start on a
/// worker, which takes its share at once, instead of on the main thread,
/// which hands the whole section to the pool and sleeps until it is done
/// (measured in BENCHMARKS.md, issue 12).
fn in_pool(run: &Run, command: Command) -> anyhow::Result<()> {
    // Only fails when a pool exists already, which it does not this early.
    let _ = rayon::ThreadPoolBuilder::new()
        .stack_size(MAIN_STACK)
        .build_global();
    rayon::scope(move |_| run_command(run, command))
}

/// Stack of the pool's threads: what the main thread has on Linux, so that
/// deeply nested input (a TOML file) is read as it was on the main thread.
const MAIN_STACK: usize = 8 << 20;

fn run_command(run: &Run, command: Command) -> anyhow::Result<()> {
    match command {
        Command::Predict(a) => commands::predict(run, a),
        Command::Simulate(a) => commands::simulate(run, a),
        Command::Calibrate(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            let loss = pkmcal::Loss::named(&a.loss, a.loss_scale)?;
            calibrate::run_calibrate(
                run,
                calibrate::CalibrateConfig {
                    loss,
                    outlier_threshold: a.outlier_threshold,
                    drop_outliers: a.drop_outliers,
                    frame: a.frame,
                    axes: a.axes,
                    mechanism: a.mech.mechanism,
                    data: a.data,
                    model,
                    free: a.params_set.free,
                    fix: a.params_set.fix,
                    start: a.start,
                    force: a.force,
                    out: a.out,
                    report: a.report,
                    validate: a.validate,
                    holdout: a.holdout,
                    seed: a.seed,
                    kfold: a.kfold,
                    report_dir: a.report_dir,
                    quiet: a.quiet,
                    setup: a.setup,
                    distances: a.distances,
                },
            )
        }),
        Command::Analyze(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            calibrate::run_analyze(
                run,
                calibrate::AnalyzeConfig {
                    mechanism: a.mech.mechanism,
                    data: a.data,
                    model,
                    free: a.params_set.free,
                    fix: a.params_set.fix,
                    params: a.params,
                    force: a.force,
                    report: a.report,
                    setup: a.setup,
                    frame: a.frame,
                    axes: a.axes,
                    distances: a.distances,
                },
            )
        }),
        Command::Compensate(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            usecal::run_compensate(
                run,
                usecal::CompensateConfig {
                    mechanism: a.mech.mechanism,
                    params: a.params,
                    targets: a.targets,
                    grid: a.grid,
                    cartesian: a.cartesian,
                    controller: a.controller,
                    model,
                    load: a.load,
                    preload: a.preload,
                    skip_unreachable: a.skip_unreachable,
                    out: a.out,
                },
            )
        }),
        Command::Plan(a) => (|| {
            usecal::run_plan(
                run,
                usecal::PlanConfig {
                    mechanism: a.mech.mechanism,
                    count: a.count,
                    candidates: a.candidates,
                    max_candidates: a.max_candidates,
                    quiet: a.quiet,
                    criterion: a.criterion.parse()?,
                    model: a.model.parse()?,
                    params: a.params,
                    free: a.params_set.free,
                    fix: a.params_set.fix,
                    out: a.out,
                    grid_out: a.grid_out,
                },
            )
        })(),
        Command::Montecarlo(a) => (|| {
            usecal::run_montecarlo(
                run,
                usecal::MonteCarloConfig {
                    mechanism: a.mech.mechanism,
                    poses: a.poses,
                    runs: a.runs,
                    noise: a.noise,
                    seed: a.seed,
                    model: a.model.parse()?,
                    free: a.params_set.free,
                    fix: a.params_set.fix,
                    length_error: a.length_error,
                    angle_error: a.angle_error,
                    angle_noise: a.angle_noise,
                    validation: a.validation,
                    out: a.out,
                    quiet: a.quiet,
                },
            )
        })(),
        Command::Trilaterate(a) => commands::trilaterate(run, a),
        Command::Gcode(a) => a.model.parse().map_err(Into::into).and_then(|model| {
            gcode::run_gcode(
                run,
                gcode::GcodeConfig {
                    mechanism: a.mech.mechanism,
                    params: a.params,
                    controller: a.controller,
                    model,
                    load: a.load,
                    input: a.input,
                    offset: a.offset,
                    max_segment: a.max_segment,
                    out: a.out,
                },
            )
        }),
        Command::Klipper(a) => pkmcal_io::klipper::run_klipper(
            run,
            pkmcal_io::klipper::KlipperConfig {
                config: a.config,
                free: a.free,
                out: a.out,
                out_dir: a.out_dir,
                weighting: a.weighting,
            },
        ),
        Command::Reprap(a) => pkmcal_io::reprap::run_reprap(
            run,
            pkmcal_io::reprap::ReprapConfig {
                config: a.config,
                probes: a.probes,
                free: a.free,
                out: a.out,
            },
        ),
        Command::Demo(a) => commands::demo(run, a),
    }
}
