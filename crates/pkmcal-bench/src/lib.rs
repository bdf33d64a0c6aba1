//! The criterion benchmarks of pkmcal, in `benches/` (`cargo bench -p
//! pkmcal-bench`, or `--bench <name>` for one). This library is empty: the
//! crate exists so that criterion stays out of `cargo test --workspace`'s
//! build (Cargo.toml).
