//! One module per command: its arguments (clap), the files it declares, and
//! its run.

pub mod analyze;
pub mod budget;
pub mod calibrate;
pub mod compensate;
pub mod demo;
pub mod drift;
pub mod gcode;
pub mod klipper;
pub mod montecarlo;
pub mod parameters;
pub mod plan;
pub mod predict;
pub mod reprap;
pub mod simulate;
pub mod trilaterate;
