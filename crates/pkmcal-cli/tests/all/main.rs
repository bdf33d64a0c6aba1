//! The command line's integration tests, in one binary: each file of this
//! folder is a module, and they are compiled and linked once rather than
//! once a file (a fresh clone's `cargo test --workspace` linked some thirty
//! binaries; BENCHMARKS.md, issue 52).
//!
//! To add tests: put them in a new file `tests/all/<topic>.rs` (its `//!`
//! comment saying what it covers), add `mod <topic>;` below, and take the
//! shared helpers with `use crate::common::{ok, fails, …};` (they run the
//! `pkmcal` binary, `tests/common/mod.rs`). Run one file's tests with
//! `cargo test -p pkmcal-cli --test all <topic>::`.

// Where it was before the merge, so that a test file still written as its
// own binary (`tests/<topic>.rs` with `mod common;`) keeps compiling.
mod budget;
mod calibrate;
mod cli;
#[path = "../common/mod.rs"]
mod common;
mod controllers;
mod drift;
mod examples;
mod firmware_checks;
mod gcode;
mod height_map;
mod input;
mod instruments;
mod klipper;
mod klipper_rotary;
mod marlin;
mod measurements;
mod noise;
mod physical;
mod physical_report;
mod readme;
mod reliability;
mod renamed;
mod report;
mod reprap;
mod scaling;
mod use_calibration;
mod vocabulary;
