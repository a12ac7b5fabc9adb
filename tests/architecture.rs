//! The house rules of ARCHITECTURE.md, read from the sources: no import cycle between the
//! top-level modules, the layering (`pipeline/` never imports `node/` or `bag/`, `bag/` never
//! `node/`, `sweep/` nothing of ROS), and no source file of more than 800 lines outside its
//! tests. A module's imports are its code's `crate::<module>` paths (comments and the test
//! module at the end of a file left out).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Files still above the limit, each being split by other work in progress (remove the entry
/// when its split lands).
const OVERSIZED_FOR_NOW: &[&str] = &[];
const MAX_LINES: usize = 800;

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("src/ is readable") {
        let path = entry.expect("a directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The file's code: its lines up to the test module, without comment lines.
fn code_lines(text: &str) -> Vec<&str> {
    text.lines()
        .take_while(|l| l.trim() != "#[cfg(test)]")
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect()
}

/// The top-level module a file belongs to (`src/node/dds.rs` -> `node`); None for the crate
/// root and the binary.
fn module_of(path: &Path) -> Option<String> {
    let relative = path.strip_prefix(src()).ok()?;
    let first = relative.components().next()?.as_os_str().to_str()?;
    let name = first.trim_end_matches(".rs");
    (name != "lib" && name != "main").then(|| name.to_string())
}

/// `crate::<module>` paths in `code`.
fn imports(code: &[&str]) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for line in code {
        for (at, _) in line.match_indices("crate::") {
            let rest = &line[at + "crate::".len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                found.insert(name);
            }
        }
    }
    found
}

/// Module -> the modules it imports.
fn graph() -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(&file) else {
            continue;
        };
        let text = std::fs::read_to_string(&file).expect("a readable source file");
        let deps = graph.entry(module.clone()).or_default();
        deps.extend(
            imports(&code_lines(&text))
                .into_iter()
                .filter(|d| *d != module),
        );
    }
    graph
}

#[test]
fn no_import_cycle_between_modules() {
    let graph = graph();
    assert!(graph.contains_key("pipeline") && graph.contains_key("node"));
    // Depth-first search; a module met again while on the stack closes a cycle.
    fn visit(
        m: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        stack: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) {
        if done.contains(m) {
            return;
        }
        if let Some(at) = stack.iter().position(|s| s == m) {
            panic!("import cycle: {} -> {m}", stack[at..].join(" -> "));
        }
        stack.push(m.to_string());
        for d in graph.get(m).into_iter().flatten() {
            visit(d, graph, stack, done);
        }
        stack.pop();
        done.insert(m.to_string());
    }
    let mut done = BTreeSet::new();
    for m in graph.keys() {
        visit(m, &graph, &mut Vec::new(), &mut done);
    }
}

#[test]
fn layers_import_only_downwards() {
    let graph = graph();
    for (module, forbidden) in [
        ("pipeline", &["node", "bag"][..]),
        ("bag", &["node"]),
        // The live view serves what node and bag give it; it knows neither.
        ("viewer", &["node", "bag"]),
        ("params", &["node", "bag", "pipeline"]),
        ("ros", &["node", "bag", "pipeline", "params"]),
        (
            "sweep",
            &["ros", "node", "bag", "pipeline", "params", "msgs"],
        ),
    ] {
        let deps = graph.get(module).cloned().unwrap_or_default();
        for f in forbidden {
            assert!(
                !deps.contains(*f),
                "src/{module} imports crate::{f} (it imports {deps:?})"
            );
        }
    }
}

#[test]
fn no_source_file_is_over_the_limit_outside_its_tests() {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut over = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).expect("a readable source file");
        let lines = text
            .lines()
            .take_while(|l| l.trim() != "#[cfg(test)]")
            .count();
        let name = file
            .strip_prefix(root)
            .unwrap_or(&file)
            .display()
            .to_string();
        if lines > MAX_LINES && !OVERSIZED_FOR_NOW.contains(&name.as_str()) {
            over.push(format!("{name}: {lines} lines"));
        }
    }
    assert!(
        over.is_empty(),
        "files over {MAX_LINES} lines (tests excepted): {over:?}"
    );
}
