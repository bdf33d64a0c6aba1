//! The file side of pkmcal: mechanism descriptions (TOML), data files (CSV),
//! parameter files, units of data files, calibration records, reports and
//! figures, firmware configurations as data (read, edit, write), G-code
//! programs, and outputs written all or nothing. The `pkmcal` command
//! (`crates/pkmcal-cli`) and the Python package (`crates/pkmcal-py`) are
//! both built on it; the mathematics lives in the `pkmcal` library crate,
//! which knows no files.
//!
//! It knows no front end either: it prints nothing (what it has to tell a
//! user is a [`Note`] handed to the front end, which shows it), names no
//! command-line option (a user's choice is a [`pkmcal::Field`], which each
//! front end words), and its errors are typed ([`Error`]), carrying the
//! file, line, row or pose they are about as data. A front end hands it a
//! [`Run`]: the files of one run, the data-file units given over those of
//! the mechanism file, how to show progress and notes.

pub mod csv;
pub mod data;
pub mod description;
pub mod error;
pub mod figures;
pub mod fileunits;
pub mod firmware;
pub mod gcode;
pub mod hints;
pub mod output;
pub mod params;
pub mod record;
pub mod report;
pub mod text;

pub use error::{Error, Result};
pub use output::Files;

use std::path::PathBuf;

/// What one run of a front end brings to the file side: its files (inputs
/// read, outputs staged), the data-file units it was given over those of
/// the mechanism file, its progress display and where its notes go.
pub struct Run<'a> {
    /// The run's inputs and outputs.
    pub files: &'a Files,
    /// Data-file units given to this run.
    pub units: pkmcal::PartialUnits,
    /// Progress displays.
    pub bars: &'a dyn Bars,
    /// Where notes go.
    pub notes: &'a dyn Notes,
}

impl<'a> Run<'a> {
    /// A run with no unit override, no progress display, notes dropped.
    pub fn quiet(files: &'a Files) -> Self {
        Run {
            files,
            units: pkmcal::PartialUnits::default(),
            bars: &NoBars,
            notes: &NoNotes,
        }
    }

    /// A progress display of `len` items (`what`), hidden when `quiet` or
    /// when there are fewer than `min_items` (0: the front end's default).
    pub fn bar(&self, len: u64, quiet: bool, what: &str, min_items: u64) -> Box<dyn Progress> {
        self.bars.bar(len, quiet, what, min_items)
    }

    /// Hand a note to the front end.
    pub fn note(&self, note: Note) {
        self.notes.note(note);
    }
}

/// Something the file side has to tell a user that is no error: the front
/// end shows it (the command line on standard error, Python as a warning).
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Note {
    /// A data file's own units line disagrees with the units given to the
    /// run, which win.
    UnitsDiffer {
        /// The data file.
        path: PathBuf,
        /// What differs (`"lengths in m (given: mm)"`).
        differ: Vec<String>,
    },
    /// Parameters given by a name they had before (still read, meaning
    /// their new one), where a user gave them.
    Renamed {
        /// Where the old names stand (a file, or a choice's words).
        place: String,
        /// The old names and the new.
        renamed: Vec<pkmcal::Renamed>,
    },
}

impl std::fmt::Display for Note {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Note::UnitsDiffer { path, differ } => write!(
                f,
                "{} says {}; the units given to this run win",
                path.display(),
                differ.join(", ")
            ),
            Note::Renamed { place, renamed } => write!(
                f,
                "{place} names {} by {}: read as {}",
                if renamed.len() == 1 {
                    "a parameter"
                } else {
                    "parameters"
                },
                if renamed.len() == 1 {
                    "its old name"
                } else {
                    "their old names"
                },
                renamed
                    .iter()
                    .map(|r| format!("`{}` → `{}`", r.old, r.new))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }
}

/// Where a front end's notes go.
pub trait Notes: Sync {
    /// Show (or keep) one note.
    fn note(&self, note: Note);
}

/// Notes dropped.
pub struct NoNotes;

impl Notes for NoNotes {
    fn note(&self, _: Note) {}
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
