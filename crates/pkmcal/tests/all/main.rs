//! The library's integration tests, in one binary: the generic library is
//! monomorphised and linked once for all of them, not once per file (this
//! halves the test suite's build).

mod common;

mod adequacy;
mod architecture;
mod budget;
mod calibration;
mod cancel;
mod coverage;
mod drift;
mod engine;
mod extreme_weights;
mod frame;
mod fuzz;
mod lattice;
mod measurement_models;
mod measurements;
mod nist_strd;
mod noise;
mod planar;
mod priors;
mod record;
mod renamed;
mod round_trip;
mod spatial;
mod typed_numbers;
mod use_calibration;
