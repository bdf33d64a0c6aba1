//! `pkmcal`: the command-line tool. Reads files, validates arguments, calls the
//! library, writes files. No kinematics here.

/// `eprintln!` for messages: a standard error that cannot be written (closed,
/// full, a broken pipe) loses the message, never the run (`eprintln!` would
/// panic and the run's outputs be discarded).
#[macro_export]
macro_rules! note {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr(), $($t)*);
    }};
}

/// `println!` for a command's summary on standard output: a standard output
/// that cannot be written (`| head` gone, a full disk) loses the rest of
/// the summary, not the run's files; the run ends with the error once its
/// files are in place ([`stdout_failure`]).
#[macro_export]
macro_rules! say {
    () => {
        $crate::say_fmt(format_args!("\n"))
    };
    ($($t:tt)*) => {
        $crate::say_fmt(format_args!("{}\n", format_args!($($t)*)))
    };
}

/// `print!` for a command's summary, as [`say!`].
#[macro_export]
macro_rules! say_raw {
    ($($t:tt)*) => {
        $crate::say_fmt(format_args!($($t)*))
    };
}

/// The first failure to write standard output, if any.
static STDOUT_FAILURE: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// Write `args` to standard output, unless a write failed before; a failure
/// is kept for the end of the run.
pub fn say_fmt(args: std::fmt::Arguments<'_>) {
    use std::io::Write as _;
    let mut failed = STDOUT_FAILURE.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_none()
        && let Err(e) = std::io::stdout().lock().write_fmt(args)
    {
        *failed = Some(e.to_string());
    }
}

/// Why standard output could not be written, if it could not.
fn stdout_failure() -> Option<String> {
    use std::io::Write as _;
    let mut failed = STDOUT_FAILURE.lock().unwrap_or_else(|e| e.into_inner());
    if failed.is_none()
        && let Err(e) = std::io::stdout().lock().flush()
    {
        *failed = Some(e.to_string());
    }
    failed.clone()
}

mod args;
mod cmd;
mod progress;
mod words;

use pkmcal_io::Run;

use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
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
    #[arg(long, global = true, value_name = "KEY=UNIT,…", display_order = GLOBAL_ORDER)]
    units: Option<String>,
    /// The largest file read whole, in MiB, for every kind of file (default:
    /// 16 for mechanism, parameter, setup and firmware files and reports,
    /// 256 for data files and G-code; streamed commands and targets have no
    /// size limit, only 1 MiB per line).
    #[arg(long, global = true, value_name = "MB", value_parser = clap::value_parser!(u64).range(1..=1 << 20), display_order = GLOBAL_ORDER + 1)]
    max_input_mb: Option<u64>,
    /// No progress bar (every command takes it).
    #[arg(long, global = true, display_order = GLOBAL_ORDER + 2)]
    quiet: bool,
}

/// Where the global options stand in every command's help: after the
/// command's own.
const GLOBAL_ORDER: usize = 10_000;

#[derive(Subcommand)]
enum Command {
    /// Predict tool positions, deflections and internal torques for actuator commands.
    Predict(cmd::predict::Args),
    /// Simulate measurements: nominal commands for targets, true positions plus noise.
    Simulate(cmd::simulate::Args),
    /// Identify parameter errors and encoder offsets from measured positions (eq. 12).
    Calibrate(cmd::calibrate::Args),
    /// Identifiability of the parameters from a data set, without fitting.
    Analyze(cmd::analyze::Args),
    /// Actuator commands that bring the tool to targets under calibrated parameters.
    Compensate(cmd::compensate::Args),
    /// Rewrite the G0/G1 moves of a G-code program so that a controller running
    /// the nominal kinematics makes the calibrated machine reach the programmed points.
    Gcode(cmd::gcode::Args),
    /// Choose measurement poses that make the parameters most observable.
    Plan(cmd::plan::Args),
    /// Predict post-calibration accuracy of a measurement plan by simulation.
    Montecarlo(cmd::montecarlo::Args),
    /// The tool error a mechanism's parameter tolerances give over its
    /// workspace (first order, checked by Monte Carlo), each tolerance's
    /// share, and what a planned calibration would leave.
    Budget(cmd::budget::Args),
    /// Compare two saved calibrations of one machine (or one with the
    /// nominal values): which parameters changed beyond what both
    /// covariances allow.
    Drift(cmd::drift::Args),
    /// Ball-bar readings to tool positions (least squares) with uncertainties.
    Trilaterate(cmd::trilaterate::Args),
    /// List a mechanism's parameters (name, kind, unit, nominal value, free by
    /// default), joints, actuators and tool axes with the workspace box.
    Parameters(cmd::parameters::Args),
    /// Calibrate a delta printer (linear or rotary) from its Klipper printer.cfg (the probe
    /// results DELTA_CALIBRATE saved) and write Klipper's values back.
    Klipper(cmd::klipper::Args),
    /// Calibrate a linear delta printer run by RepRapFirmware from its M665/M666
    /// settings and heights probed with G30 S-1; print (and write) the new
    /// M665/M666 lines.
    Reprap(cmd::reprap::Args),
    /// Calibrate a linear delta printer run by Marlin from its M503 settings
    /// and a console log of probes (G30, or G33's heights); print (and
    /// write) the new M665/M666 lines beside what G33 would set.
    Marlin(cmd::marlin::Args),
    /// Run the paper's case study on the built-in reference mechanism.
    Demo(cmd::demo::Args),
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
            bars: &progress::TerminalBars { quiet: cli.quiet },
            notes: &progress::TerminalNotes,
        };
        let p = cli.command.paths()?;
        let inputs: Vec<&Path> = p.inputs.iter().map(PathBuf::as_path).collect();
        let outputs: Vec<&Path> = p.outputs.iter().map(PathBuf::as_path).collect();
        files.check(&inputs, &outputs, &p.dirs)?;
        let written: Vec<String> = p
            .outputs
            .iter()
            .filter(|o| o.as_os_str() != "-")
            .map(|o| o.display().to_string())
            .collect();
        in_pool(&run, cli.command)?;
        files.commit()?;
        Ok(written)
    });
    match result {
        // The files are in place; the summary was cut short.
        Ok(written) => match stdout_failure() {
            Some(cause) => {
                note!(
                    "error: cannot write to standard output: {cause}{}",
                    if written.is_empty() {
                        String::new()
                    } else {
                        format!(
                            " (the summary is cut short; {} written)",
                            written.join(", ")
                        )
                    }
                );
                ExitCode::from(1)
            }
            None => ExitCode::SUCCESS,
        },
        Err(e) => {
            files.discard();
            let (message, usage) = words::message(&e);
            note!("error: {message}");
            ExitCode::from(if usage { 2 } else { 1 })
        }
    }
}

/// The `--units` option, read (a usage error names it).
fn units_option(text: Option<&str>) -> anyhow::Result<pkmcal::PartialUnits> {
    Ok(match text {
        Some(t) => {
            pkmcal::PartialUnits::parse(t).map_err(|e| words::Usage(format!("--units: {e}")))?
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
            note!(
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
            note!("error: cannot write to standard output: {cause}");
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

impl Command {
    /// The files the command reads and writes, declared before any work.
    fn paths(&self) -> anyhow::Result<args::Paths> {
        match self {
            Command::Predict(a) => a.paths(),
            Command::Simulate(a) => a.paths(),
            Command::Calibrate(a) => a.paths(),
            Command::Analyze(a) => a.paths(),
            Command::Compensate(a) => a.paths(),
            Command::Gcode(a) => a.paths(),
            Command::Plan(a) => a.paths(),
            Command::Montecarlo(a) => a.paths(),
            Command::Budget(a) => a.paths(),
            Command::Drift(a) => a.paths(),
            Command::Trilaterate(a) => a.paths(),
            Command::Parameters(a) => a.paths(),
            Command::Klipper(a) => a.paths(),
            Command::Reprap(a) => a.paths(),
            Command::Marlin(a) => a.paths(),
            Command::Demo(a) => a.paths(),
        }
    }
}

fn run_command(run: &Run, command: Command) -> anyhow::Result<()> {
    match command {
        Command::Predict(a) => cmd::predict::run(run, a),
        Command::Simulate(a) => cmd::simulate::run(run, a),
        Command::Calibrate(a) => cmd::calibrate::run(run, a),
        Command::Analyze(a) => cmd::analyze::run(run, a),
        Command::Compensate(a) => cmd::compensate::run(run, a),
        Command::Gcode(a) => cmd::gcode::run(run, a),
        Command::Plan(a) => cmd::plan::run(run, a),
        Command::Montecarlo(a) => cmd::montecarlo::run(run, a),
        Command::Budget(a) => cmd::budget::run(run, a),
        Command::Drift(a) => cmd::drift::run(run, a),
        Command::Trilaterate(a) => cmd::trilaterate::run(run, a),
        Command::Parameters(a) => cmd::parameters::run(run, a),
        Command::Klipper(a) => cmd::klipper::run(run, a),
        Command::Reprap(a) => cmd::reprap::run(run, a),
        Command::Marlin(a) => cmd::marlin::run(run, a),
        Command::Demo(a) => cmd::demo::run(run, a),
    }
}
