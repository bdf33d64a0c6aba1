//! The file side of pkmcal: mechanism descriptions (TOML), data files (CSV),
//! units of data files, figures and the HTML report. The `pkmcal` binary and
//! the Python package (`crates/pkmcal-py`) are built on it; the mathematics
//! lives in the `pkmcal` library crate, which knows no files.

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
