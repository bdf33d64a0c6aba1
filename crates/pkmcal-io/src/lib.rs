//! The file side of pkmcal: mechanism descriptions (TOML), data files (CSV),
//! units of data files, reports and figures, firmware configurations
//! (Klipper, RepRapFirmware, G-code), and outputs written all or nothing.
//! The `pkmcal` command (`crates/pkmcal-cli`) and the Python package
//! (`crates/pkmcal-py`) are both built on it; the mathematics lives in the
//! `pkmcal` library crate, which knows no files. It knows no command line
//! either: a front end hands it a [`Run`] (the files of one run, the
//! `--units` given, how to show progress).

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

pub mod budget;
pub mod calibrate;
pub mod drift;
pub mod figures;
pub mod fileunits;
pub mod gcode;
pub mod hints;
pub mod io;
pub mod klipper;
pub mod output;
pub mod record;
pub mod report;
pub mod reprap;
pub mod usecal;

#[cfg(test)]
mod fuzz_readers;

pub use output::Files;

/// What one run of a front end brings to the file side: its files (inputs
/// read, outputs staged), the data-file units it was given over those of
/// the mechanism file (`--units`), and its progress display.
pub struct Run<'a> {
    pub files: &'a Files,
    pub units: pkmcal::PartialUnits,
    pub bars: &'a dyn Bars,
}

impl<'a> Run<'a> {
    /// A run with no unit override and no progress display.
    pub fn quiet(files: &'a Files) -> Self {
        Run {
            files,
            units: pkmcal::PartialUnits::default(),
            bars: &NoBars,
        }
    }

    /// A progress display of `len` items (`what`), hidden when `quiet` or
    /// when there are fewer than `min_items` (0: the front end's default).
    pub fn bar(&self, len: u64, quiet: bool, what: &str, min_items: u64) -> Box<dyn Progress> {
        self.bars.bar(len, quiet, what, min_items)
    }
}

/// One progress display: items done out of a length that may grow.
pub trait Progress: Sync {
    /// `n` more items done.
    fn inc(&self, n: u64);
    /// `n` more items to do.
    fn inc_length(&self, n: u64);
    /// Done: the display goes away.
    fn finish(&self);
}

/// How a front end shows progress (the CLI: a bar on a terminal; Python:
/// nothing).
pub trait Bars: Sync {
    /// A display of `len` items (`what`), hidden when `quiet` or when there
    /// are fewer than `min_items` (0: the front end's default).
    fn bar(&self, len: u64, quiet: bool, what: &str, min_items: u64) -> Box<dyn Progress>;
}

/// No progress shown.
pub struct NoBars;

struct NoBar;

impl Progress for NoBar {
    fn inc(&self, _: u64) {}
    fn inc_length(&self, _: u64) {}
    fn finish(&self) {}
}

impl Bars for NoBars {
    fn bar(&self, _: u64, _: bool, _: &str, _: u64) -> Box<dyn Progress> {
        Box::new(NoBar)
    }
}
