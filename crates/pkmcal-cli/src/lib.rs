//! The file side of pkmcal: mechanism descriptions (TOML), data files (CSV),
//! units of data files, figures and the HTML report. The `pkmcal` binary and
//! the Python package (`crates/pkmcal-py`) are built on it; the mathematics
//! lives in the `pkmcal` library crate, which knows no files.

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

pub mod calibrate;
pub mod figures;
pub mod fileunits;
pub mod gcode;
pub mod hints;
pub mod io;
pub mod klipper;
pub mod output;
pub mod report;
pub mod reprap;
pub mod usecal;
