//! The library's shape: no import cycle between its top-level modules, and
//! the layers of its data flow, bottom first:
//!
//! ```text
//! error, units, linalg, lm -> mechanism -> engine -> {kinds | measurement} -> identify -> apply
//! ```
//!
//! A module imports only from its own layer or below; `kinds` and
//! `measurement` stand apart (neither imports the other). The scanner is
//! `tests/support/imports.rs`, shared with the file side's test.

#[path = "../support/imports.rs"]
mod imports;

use imports::{
    Edges, Layer, code_only, cycle_words, find_cycle, layer_violations, module_graph, reached,
    reexports, without_tests,
};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The library's layers, bottom first.
const LAYERS: [Layer; 6] = [
    Layer {
        modules: &["error", "units", "linalg", "lm"],
        apart: false,
    },
    Layer {
        modules: &["mechanism"],
        apart: false,
    },
    Layer {
        modules: &["engine"],
        apart: false,
    },
    Layer {
        modules: &["kinds", "measurement"],
        apart: true,
    },
    Layer {
        modules: &["identify"],
        apart: false,
    },
    Layer {
        modules: &["apply"],
        apart: false,
    },
];

fn graph() -> (BTreeSet<String>, Edges) {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let (modules, edges) = module_graph(&src);
    // `PKMCAL_PRINT_GRAPH=1 cargo test -p pkmcal --test all architecture -- --nocapture`
    // prints the graph.
    if std::env::var_os("PKMCAL_PRINT_GRAPH").is_some() {
        for ((a, b), f) in &edges {
            eprintln!("{a} -> {b} (e.g. {f})");
        }
    }
    for expected in [
        "engine",
        "error",
        "identify",
        "kinds",
        "linalg",
        "mechanism",
    ] {
        assert!(modules.contains(expected), "{modules:?}");
    }
    (modules, edges)
}

#[test]
fn no_import_cycle_between_top_level_modules() {
    let (modules, edges) = graph();
    if let Some(cycle) = find_cycle(&modules, &edges) {
        panic!(
            "import cycle between top-level modules:\n  {}",
            cycle_words(&cycle, &edges)
        );
    }
}

#[test]
fn top_level_modules_import_only_from_their_layer_or_below() {
    let (modules, edges) = graph();
    let wrong = layer_violations(&modules, &edges, &LAYERS);
    assert!(
        wrong.is_empty(),
        "imports against the layer order (error, units, linalg, lm -> mechanism -> engine -> {{kinds | measurement}} -> identify -> apply):\n  {}",
        wrong.join("\n  ")
    );
}

/// The checker finds what it must: paths through `crate::`, groups, the
/// root's re-exports, `super::` at the top level; it skips comments,
/// strings and test modules; and it reports a cycle.
#[test]
fn the_cycle_check_sees_imports_and_cycles() {
    let code = code_only(
        "use crate::{a::X, b, c::{D, E}};\n// crate::commented\nlet s = \"crate::quoted\";\nfn f() { crate::Name::new(); super::g(); }\n#[cfg(test)]\nmod tests { use crate::tested; }\n",
    );
    let code = without_tests(&code);
    let found = reached(&code, "crate::");
    assert_eq!(
        found,
        ["Name", "a", "b", "c"]
            .map(String::from)
            .into_iter()
            .collect()
    );
    assert!(reached(&code, "super::").contains("g"));
    let roots = reexports("pub use engine::models::{Model, predict};\npub use error::Error;\n");
    assert_eq!(roots["predict"], "engine");
    assert_eq!(roots["Error"], "error");
    let modules: BTreeSet<String> = ["a", "b", "c"].map(String::from).into();
    let mut edges = BTreeMap::new();
    edges.insert(("a".to_string(), "b".to_string()), String::new());
    edges.insert(("b".to_string(), "c".to_string()), String::new());
    assert_eq!(find_cycle(&modules, &edges), None);
    edges.insert(("c".to_string(), "a".to_string()), String::new());
    assert!(find_cycle(&modules, &edges).is_some());
}

/// The layer check refuses an import from a higher layer, and between the
/// modules of a layer that stands apart, and names a module in no layer.
#[test]
fn the_layer_check_sees_upward_and_sideways_imports() {
    let layers = [
        Layer {
            modules: &["low"],
            apart: false,
        },
        Layer {
            modules: &["left", "right"],
            apart: true,
        },
    ];
    let modules: BTreeSet<String> = ["low", "left", "right"].map(String::from).into();
    let edge = |a: &str, b: &str| ((a.to_string(), b.to_string()), "f.rs".to_string());
    let fine: Edges = [edge("left", "low"), edge("right", "low")].into();
    assert!(layer_violations(&modules, &fine, &layers).is_empty());
    let wrong: Edges = [edge("low", "left"), edge("left", "right")].into();
    assert_eq!(
        layer_violations(&modules, &wrong, &layers),
        ["left -> right (e.g. in f.rs)", "low -> left (e.g. in f.rs)"]
    );
    let more: BTreeSet<String> = ["low", "new"].map(String::from).into();
    assert_eq!(
        layer_violations(&more, &BTreeMap::new(), &layers),
        ["new -> ? (a module in no layer: place it)"]
    );
}
