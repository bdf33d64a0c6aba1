//! The file side's integration tests, in one binary: each file of this
//! folder is a module, so the library's generic code is compiled and linked
//! once for all of them rather than once a file (BENCHMARKS.md, issue 52).
//!
//! To add tests: put them in a new file `tests/all/<topic>.rs` (its `//!`
//! comment saying what it covers) and add `mod <topic>;` below. Run one
//! file's tests with `cargo test -p pkmcal-io --test all <topic>::`.

mod choices;
mod csv;
mod firmware_shared;
mod fuzz_grammar;
mod fuzz_readers;
mod gcode;
mod height_map;
mod imports;
mod klipper_rotary;
mod marlin;
mod output;
mod physical;
mod physical_acceptance;
mod physical_drift;
mod physical_heights;
mod physical_plan;
mod physical_report;
mod record;
mod renamed;
mod reprap_script;
