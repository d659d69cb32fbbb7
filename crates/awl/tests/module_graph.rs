//! The library's import graph between top-level modules (`crate::X` in `src/X.rs` or `src/X/`),
//! read from the source text: it has no cycle, and `io` reads and writes generic formats only, so
//! it imports none of the product modules. Comment lines (docs) are left out; test modules are
//! kept, since a test's import is an import too.

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// The modules `io` may import: the data types of the generic formats it reads and writes.
const IO_MAY_IMPORT: &[&str] = &["camera", "cloud", "error", "image", "mesh", "scan", "transform"];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).expect("read src") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Every top-level module and the top-level modules its files name as `crate::X`.
fn import_graph() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let modules: BTreeSet<String> = files
        .iter()
        .filter_map(|f| {
            let rel = f.strip_prefix(&src).ok()?;
            let first = rel.components().next()?.as_os_str().to_str()?.trim_end_matches(".rs");
            (first != "lib").then(|| first.to_string())
        })
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = modules.iter().map(|m| (m.clone(), BTreeSet::new())).collect();
    for file in &files {
        let rel = file.strip_prefix(&src).expect("under src");
        let first = rel.components().next().and_then(|c| c.as_os_str().to_str()).expect("name");
        let from = first.trim_end_matches(".rs");
        if from == "lib" {
            continue;
        }
        let text = fs::read_to_string(file).expect("read source");
        for line in text.lines().filter(|l| !l.trim_start().starts_with("//")) {
            for (at, _) in line.match_indices("crate::") {
                let name: String =
                    line[at + 7..].chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect();
                if modules.contains(&name) && name != from {
                    graph.get_mut(from).expect("module").insert(name);
                }
            }
        }
    }
    graph
}

/// A cycle through `start`, if there is one (depth-first search for a path back to it).
fn cycle_through(graph: &BTreeMap<String, BTreeSet<String>>, start: &str) -> Option<Vec<String>> {
    fn walk(
        graph: &BTreeMap<String, BTreeSet<String>>,
        start: &str,
        at: &str,
        path: &mut Vec<String>,
        seen: &mut BTreeSet<String>,
    ) -> bool {
        for next in &graph[at] {
            if next == start {
                return true;
            }
            if seen.insert(next.clone()) {
                path.push(next.clone());
                if walk(graph, start, next, path, seen) {
                    return true;
                }
                path.pop();
            }
        }
        false
    }
    let mut path = vec![start.to_string()];
    let mut seen = BTreeSet::new();
    walk(graph, start, start, &mut path, &mut seen).then(|| {
        path.push(start.to_string());
        path
    })
}

#[test]
fn no_cycle_between_top_level_modules() {
    let graph = import_graph();
    assert!(graph.len() > 20, "found only {} modules: is src/ read?", graph.len());
    assert!(graph["pipeline"].contains("registration"), "the reader misses imports");
    let cycles: Vec<String> = graph.keys().filter_map(|m| cycle_through(&graph, m)).map(|c| c.join(" -> ")).collect();
    assert!(cycles.is_empty(), "module cycles:\n{}", cycles.join("\n"));
}

#[test]
fn io_imports_no_product_module() {
    let graph = import_graph();
    let product: Vec<&String> = graph["io"].iter().filter(|m| !IO_MAY_IMPORT.contains(&m.as_str())).collect();
    assert!(product.is_empty(), "io imports {product:?}; it may import only {IO_MAY_IMPORT:?}");
}
