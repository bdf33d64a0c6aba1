//! The shipped examples' mechanism descriptions, for tests and benchmarks
//! (one file, included by the library's integration tests and its
//! benchmarks).

/// The mechanism file of `examples/<name>` as a table (without `type`, the
/// targets and the tables other readers use: `[units]`, `[ballbar]`,
/// `[tolerances]`), for a description's `try_into`.
pub fn example_table(name: &str) -> toml::Table {
    let path = format!(
        "{}/../../examples/{name}/mechanism.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let mut t: toml::Table = std::fs::read_to_string(path).unwrap().parse().unwrap();
    for key in ["type", "target", "units", "ballbar", "tolerances"] {
        t.remove(key);
    }
    t
}
