//! The file side's shape: no import circle between its files (its
//! top-level modules), with the library's scanner
//! (`crates/pkmcal/tests/support/imports.rs`).

#[path = "../../../pkmcal/tests/support/imports.rs"]
mod scanner;

use std::path::Path;

/// Before issue 48 `calibrate`, `report`, `budget` and `usecal` imported
/// each other in a circle, and so did `io` and `fileunits`.
#[test]
fn no_import_circle_between_files() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let (modules, edges) = scanner::module_graph(&src);
    assert!(modules.contains("output"), "{modules:?}");
    if let Some(cycle) = scanner::find_cycle(&modules, &edges) {
        panic!(
            "import circle between the files of pkmcal-io:\n  {}",
            scanner::cycle_words(&cycle, &edges)
        );
    }
}
