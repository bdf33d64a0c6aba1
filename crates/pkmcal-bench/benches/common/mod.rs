//! What the benchmarks share: the shipped examples' mechanism descriptions.

#[path = "../../../pkmcal/tests/support/examples.rs"]
mod examples;
pub use examples::example_table;
