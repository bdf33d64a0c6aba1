//! A scanner of a crate's imports, for the architecture tests of the
//! library (`crates/pkmcal/tests/all/architecture.rs`) and of the file side
//! (`crates/pkmcal-io/tests/all/imports.rs`), which include it with `#[path]`:
//! the edges between a crate's top-level modules (for a crate of flat
//! files, between its files), their cycles, and the layers they break.
//!
//! Written here rather than with a parser crate: the check needs only paths
//! (`crate::x`, `super::x`, `use crate::{x, y}`), which a small scanner over
//! the source without comments and literals finds. Non-test code counts
//! (doc comments and `#[cfg(test)]` items do not); a name taken through the
//! crate root's re-exports counts as an import of the module that defines
//! it.
#![allow(dead_code)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The edges between top-level modules: (from, to) -> an example file.
pub type Edges = BTreeMap<(String, String), String>;

/// The source with comments, string and character literals blanked out.
pub fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    let blank = |out: &mut Vec<u8>, s: &[u8]| {
        out.extend(s.iter().map(|&c| if c == b'\n' { b'\n' } else { b' ' }));
    };
    while i < b.len() {
        let rest = &b[i..];
        let end = if rest.starts_with(b"//") {
            i + rest.iter().position(|&c| c == b'\n').unwrap_or(rest.len())
        } else if rest.starts_with(b"/*") {
            i + 2
                + rest[2..]
                    .windows(2)
                    .position(|w| w == b"*/")
                    .map_or(rest.len() - 2, |p| p + 2)
        } else if rest.starts_with(b"r#\"") || rest.starts_with(b"r\"") {
            let hashes = rest[1..].iter().take_while(|&&c| c == b'#').count();
            let mut close = vec![b'"'];
            close.extend(std::iter::repeat_n(b'#', hashes));
            let start = 2 + hashes;
            i + start
                + rest[start..]
                    .windows(close.len())
                    .position(|w| w == close.as_slice())
                    .map_or(rest.len() - start, |p| p + close.len())
        } else if rest[0] == b'"' {
            let mut j = 1;
            while j < rest.len() && rest[j] != b'"' {
                j += if rest[j] == b'\\' { 2 } else { 1 };
            }
            i + j + 1
        } else if rest[0] == b'\'' && rest.len() > 2 && (rest[1] == b'\\' || rest[2] == b'\'') {
            let j = 2 + rest[2..].iter().position(|&c| c == b'\'').unwrap_or(0);
            i + j + 1
        } else {
            out.push(b[i]);
            i += 1;
            continue;
        };
        let end = end.min(b.len());
        blank(&mut out, &b[i..end]);
        i = end;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// `code` without its `#[cfg(test)]` items (a module, a function, a use).
pub fn without_tests(code: &str) -> String {
    let mut out = code.to_string();
    while let Some(start) = out.find("#[cfg(test)]") {
        let b = out.as_bytes();
        let mut i = start + "#[cfg(test)]".len();
        let mut depth = 0usize;
        let mut end = b.len();
        while i < b.len() {
            match b[i] {
                b';' if depth == 0 => {
                    end = i + 1;
                    break;
                }
                b'{' => depth += 1,
                b'}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = i + 1;
                        break;
                    }
                }
                _ => {}
            }
            i += 1;
        }
        out.replace_range(start..end, "");
    }
    out
}

fn ident_at(s: &str) -> &str {
    let n = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..n]
}

/// The top-level names a file's code reaches through `prefix` (`crate::`,
/// or `super::` in a file directly under the root): `prefix name` and
/// `prefix {a::…, b, …}`.
pub fn reached(code: &str, prefix: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(p) = rest.find(prefix) {
        let before = rest[..p].chars().last();
        rest = &rest[p + prefix.len()..];
        if before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':') {
            continue;
        }
        if let Some(group) = rest.strip_prefix('{') {
            // Top-level segments of the group.
            let mut depth = 0;
            let mut segment_start = true;
            for (k, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' if depth == 0 => break,
                    '}' => depth -= 1,
                    ',' if depth == 0 => segment_start = true,
                    c if c.is_whitespace() => {}
                    _ if segment_start && depth == 0 => {
                        out.insert(ident_at(&group[k..]).to_string());
                        segment_start = false;
                    }
                    _ => {}
                }
            }
        } else {
            let name = ident_at(rest);
            if !name.is_empty() {
                out.insert(name.to_string());
            }
        }
    }
    out
}

/// The root's re-exports: name -> the top-level module that defines it.
pub fn reexports(lib: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let code = code_only(lib);
    for stmt in code.split(';') {
        let Some(body) = stmt.trim().strip_prefix("pub use ") else {
            continue;
        };
        let module = ident_at(body).to_string();
        let names: Vec<&str> = match body.find('{') {
            Some(open) => body[open + 1..]
                .trim_end()
                .trim_end_matches('}')
                .split(',')
                .collect(),
            None => vec![body.rsplit("::").next().unwrap_or("")],
        };
        for n in names {
            let n = n.trim();
            if !n.is_empty() {
                out.insert(n.to_string(), module.clone());
            }
        }
    }
    out
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The edges between top-level modules: (from, to) -> an example file.
pub fn module_graph(src: &Path) -> (BTreeSet<String>, Edges) {
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    let roots = reexports(&lib);
    let mut files = vec![];
    rust_files(src, &mut files);
    let top = |p: &Path| -> Option<String> {
        let rel = p.strip_prefix(src).unwrap();
        let first = rel.components().next()?.as_os_str().to_string_lossy();
        (first != "lib.rs").then(|| first.trim_end_matches(".rs").to_string())
    };
    let modules: BTreeSet<String> = files.iter().filter_map(|p| top(p)).collect();
    let mut edges = BTreeMap::new();
    for f in &files {
        let Some(from) = top(f) else { continue };
        let code = without_tests(&code_only(&std::fs::read_to_string(f).unwrap()));
        let mut names = reached(&code, "crate::");
        if f.parent() == Some(src) {
            names.extend(reached(&code, "super::"));
        }
        for n in names {
            let to = if modules.contains(&n) {
                Some(n)
            } else {
                roots.get(&n).cloned()
            };
            if let Some(to) = to.filter(|t| *t != from) {
                edges
                    .entry((from.clone(), to))
                    .or_insert_with(|| f.strip_prefix(src).unwrap().display().to_string());
            }
        }
    }
    (modules, edges)
}

/// A cycle of the graph, if any, as its modules in order.
pub fn find_cycle(modules: &BTreeSet<String>, edges: &Edges) -> Option<Vec<String>> {
    fn visit(
        m: &str,
        edges: &Edges,
        state: &mut BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(m.to_string(), 1);
        path.push(m.to_string());
        for ((a, b), _) in edges.iter().filter(|((a, _), _)| a == m) {
            let _ = a;
            match state.get(b.as_str()).copied().unwrap_or(0) {
                1 => {
                    let k = path.iter().position(|x| x == b).unwrap();
                    let mut c = path[k..].to_vec();
                    c.push(b.clone());
                    return Some(c);
                }
                0 => {
                    if let Some(c) = visit(b, edges, state, path) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        path.pop();
        state.insert(m.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for m in modules {
        if state.get(m.as_str()).copied().unwrap_or(0) == 0
            && let Some(c) = visit(m, edges, &mut state, &mut vec![])
        {
            return Some(c);
        }
    }
    None
}

/// A cycle as the message of a failing test: each edge with a file that
/// makes it.
pub fn cycle_words(cycle: &[String], edges: &Edges) -> String {
    cycle
        .windows(2)
        .map(|w| {
            format!(
                "{} -> {} (e.g. in {})",
                w[0],
                w[1],
                edges[&(w[0].clone(), w[1].clone())]
            )
        })
        .collect::<Vec<_>>()
        .join("\n  ")
}

/// One layer of a crate: its modules, and whether they stand apart (none
/// imports another of the layer).
pub struct Layer<'a> {
    pub modules: &'a [&'a str],
    pub apart: bool,
}

/// The edges that break the layer order `layers` (bottom first): a module
/// may import only from a lower layer, or from its own unless the layer
/// stands apart. A module in no layer is reported as `module -> ?`.
pub fn layer_violations(
    modules: &BTreeSet<String>,
    edges: &Edges,
    layers: &[Layer],
) -> Vec<String> {
    let level = |m: &str| layers.iter().position(|l| l.modules.contains(&m));
    let mut out: Vec<String> = modules
        .iter()
        .filter(|m| level(m).is_none())
        .map(|m| format!("{m} -> ? (a module in no layer: place it)"))
        .collect();
    for ((a, b), file) in edges {
        let (Some(la), Some(lb)) = (level(a), level(b)) else {
            continue;
        };
        if lb > la || (lb == la && layers[la].apart) {
            out.push(format!("{a} -> {b} (e.g. in {file})"));
        }
    }
    out
}
