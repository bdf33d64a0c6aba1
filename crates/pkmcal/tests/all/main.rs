//! The library's integration tests, in one binary: the generic library is
//! monomorphised and linked once for all of them, not once per file (this
//! halves the test suite's build).

mod common;

mod adequacy;
mod architecture;
mod atlas;
mod budget;
mod calibration;
mod cancel;
mod coverage;
mod curvature;
mod drift;
mod engine;
mod extreme_weights;
mod frame;
mod fuzz;
mod identifiability;
mod lattice;
mod linalg_kkt;
mod linalg_lu;
mod linalg_products;
mod linalg_small;
mod linalg_solve;
mod lm;
mod load;
mod measurement_models;
mod measurements;
mod models;
mod montecarlo;
mod newton;
mod nist_strd;
mod noise;
mod planar;
mod planning;
mod priors;
mod record;
mod renamed;
mod round_trip;
mod screening;
mod sensitivity;
mod spatial;
mod study;
mod typed_numbers;
mod units;
mod use_calibration;
