//! The house rules of ARCHITECTURE.md, read from the sources: every folder and top-level file
//! of `src/` has its place in one of the layers below and imports only from layers under its
//! own (so there is no import cycle either); the named rules on top (`pipeline/` never imports
//! `node/` or `bag/`, the engine, fusion and geometry know nothing of ROS, ...); `anyhow` only
//! at the command line; no source file of more than 800 lines outside its tests, and no
//! function of more than 150.
//!
//! A module's imports are the `crate::<module>` paths of its production code (and `super::`
//! paths that climb to the crate root, and `crate::{a, b}` groups): every line of every file
//! but its comments, the contents of its string and character literals, and the items under
//! `#[cfg(test)]` (inline test modules wherever they are in the file, and files declared
//! `#[cfg(test)] mod x;`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layers of `src/`, lowest first. A module imports only modules of the layers below its
/// own: none of its own layer, none above. A new folder or top-level file needs a place here
/// (`every_folder_and_file_has_a_place`).
const LAYERS: &[(&str, &[&str])] = &[
    (
        "leaves, importing nothing of the crate",
        &[
            "geometry",
            "image",
            "msgs",
            "msgdefs",
            "handoff",
            "gpu_context",
            "logging",
            "process_env",
            "simd",
        ],
    ),
    (
        "on the leaves: the engines, fusion, synthetic scenes, rig files, ROS plumbing",
        &["sweep", "fusion", "synthetic", "rig_file", "ros"],
    ),
    (
        "the engine behind one API, image files, parameters",
        &["engine", "io", "params"],
    ),
    (
        "the DDS-free pipeline, dataset loaders",
        &["pipeline", "datasets"],
    ),
    ("the live view, evaluation", &["viewer", "eval"]),
    ("front ends: the node, bags", &["node", "bag"]),
    (
        "the subcommands that only print: the demo, the benchmark",
        &["cli"],
    ),
];

/// The crate roots: `lib.rs` declares the modules, `main.rs` is the binary.
const ROOTS: &[&str] = &["lib", "main"];

/// Imports that no layer order may allow: ARCHITECTURE.md's house rules by name, and the parts
/// that stay free of ROS messages although `msgs` is a leaf.
const NEVER: &[(&str, &[&str])] = &[
    ("pipeline", &["node", "bag"]),
    ("bag", &["node"]),
    // The live view serves what node and bag give it; it knows neither.
    ("viewer", &["node", "bag"]),
    ("params", &["node", "bag", "pipeline"]),
    ("ros", &["node", "bag", "pipeline", "params"]),
    (
        "sweep",
        &[
            "ros", "node", "bag", "pipeline", "params", "msgs", "msgdefs",
        ],
    ),
    (
        "engine",
        &[
            "ros", "node", "bag", "pipeline", "params", "msgs", "msgdefs",
        ],
    ),
    ("fusion", &["ros", "pipeline", "sweep", "msgs", "msgdefs"]),
    ("geometry", &["ros", "msgs", "msgdefs"]),
];

/// The only files whose production code may use `anyhow` (errors printed at the command line):
/// the binary and the files under these folders.
const ANYHOW_FILES: &[&str] = &["main.rs"];
const ANYHOW_FOLDERS: &[&str] = &["cli/"];

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

fn is_ident(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_'
}

/// `text` with its comments and the contents of its string and character literals blanked
/// (newlines kept, so that offsets and line numbers stay those of the file).
fn blank_comments_and_literals(text: &str) -> Vec<u8> {
    let src = text.as_bytes();
    let mut out = src.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for b in &mut out[from..to.min(src.len())] {
            if *b != b'\n' {
                *b = b' ';
            }
        }
    };
    let mut i = 0;
    while i < src.len() {
        let rest = &src[i..];
        let after_ident = i > 0 && is_ident(src[i - 1]);
        if rest.starts_with(b"//") {
            let end = rest
                .iter()
                .position(|&b| b == b'\n')
                .map_or(src.len(), |p| i + p);
            blank(&mut out, i, end);
            i = end;
        } else if rest.starts_with(b"/*") {
            let (mut depth, mut j) = (0, i);
            while j < src.len() {
                if src[j..].starts_with(b"/*") {
                    depth += 1;
                    j += 2;
                } else if src[j..].starts_with(b"*/") {
                    depth -= 1;
                    j += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if src[i] == b'r'
            && (!after_ident || (src[i - 1] == b'b' && (i < 2 || !is_ident(src[i - 2]))))
            && rest[1..]
                .iter()
                .position(|&b| b != b'#')
                .is_some_and(|h| rest[1 + h] == b'"')
        {
            // A raw string: r"..", r#".."#, br"..".
            let hashes = rest[1..].iter().take_while(|&&b| b == b'#').count();
            let open = i + 2 + hashes;
            let mut close = b"\"".to_vec();
            close.extend(std::iter::repeat_n(b'#', hashes));
            let end = src[open..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(src.len(), |p| open + p);
            blank(&mut out, open, end);
            i = end + close.len();
        } else if src[i] == b'"' {
            let mut j = i + 1;
            while j < src.len() && src[j] != b'"' {
                j += if src[j] == b'\\' { 2 } else { 1 };
            }
            blank(&mut out, i + 1, j);
            i = j + 1;
        } else if src[i] == b'\'' {
            // A character literal ('x', '\n', '\u{7b}', 'é') or a lifetime or label ('a).
            let width = match src.get(i + 1) {
                Some(b'\\') => src
                    .get(i + 3..)
                    .and_then(|rest| rest.iter().position(|&b| b == b'\''))
                    .map(|p| p + 2),
                Some(&b) => {
                    let n = match b {
                        0xf0.. => 4,
                        0xe0.. => 3,
                        0xc0.. => 2,
                        _ => 1,
                    };
                    (src.get(i + 1 + n) == Some(&b'\'')).then_some(n)
                }
                None => None,
            };
            match width {
                Some(n) => {
                    blank(&mut out, i + 1, i + 1 + n);
                    i += n + 2;
                }
                None => i += 1,
            }
        } else {
            i += 1;
        }
    }
    out
}

fn find(haystack: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    haystack
        .get(from..)?
        .windows(needle.len())
        .position(|w| w == needle)
        .map(|p| from + p)
}

/// The end of the item that starts at `from` in `code`: after its closing brace, or after its
/// semicolon at the outer level (`mod x;`, `use ...;`).
fn item_end(code: &[u8], from: usize) -> usize {
    let mut depth = 0i32;
    for (j, &b) in code.iter().enumerate().skip(from) {
        match b {
            b'{' | b'(' | b'[' => depth += 1,
            b'}' | b')' | b']' => {
                depth -= 1;
                if depth <= 0 && b == b'}' {
                    return j + 1;
                }
            }
            b';' if depth == 0 => return j + 1,
            _ => {}
        }
    }
    code.len()
}

/// Byte ranges of the items under `#[cfg(test)]` (the attribute, any further attributes and the
/// item through its closing brace or semicolon), wherever they are in the file.
fn test_items(code: &[u8]) -> Vec<(usize, usize)> {
    const ATTR: &[u8] = b"#[cfg(test)]";
    let mut items = Vec::new();
    let mut at = 0;
    while let Some(start) = find(code, ATTR, at) {
        let end = item_end(code, start + ATTR.len());
        items.push((start, end));
        at = end;
    }
    items
}

/// The identifier at `at` (after any whitespace), if one starts there.
fn ident_at(code: &[u8], at: usize) -> Option<(String, usize)> {
    let start = at
        + code
            .get(at..)?
            .iter()
            .take_while(|b| b.is_ascii_whitespace())
            .count();
    let len = code
        .get(start..)?
        .iter()
        .take_while(|&&b| is_ident(b))
        .count();
    (len > 0).then(|| {
        (
            String::from_utf8_lossy(&code[start..start + len]).into_owned(),
            start + len,
        )
    })
}

/// The first segments of the path at `at`: `name` of `name::...`, or each name of a group
/// `{a::x, b, c::{..}}`. A macro (`name!`) is no module.
fn first_segments(code: &[u8], at: usize) -> Vec<String> {
    let start = at
        + code[at..]
            .iter()
            .take_while(|b| b.is_ascii_whitespace())
            .count();
    if code.get(start) != Some(&b'{') {
        return match ident_at(code, start) {
            Some((name, end)) if code.get(end) != Some(&b'!') => vec![name],
            _ => Vec::new(),
        };
    }
    let mut names = Vec::new();
    let (mut depth, mut expect_name, mut j) = (0, true, start);
    while j < code.len() {
        match code[j] {
            b'{' => {
                depth += 1;
                expect_name = depth == 1;
            }
            b'}' => {
                depth -= 1;
                if depth == 0 {
                    break;
                }
            }
            b',' if depth == 1 => expect_name = true,
            b if is_ident(b) && depth == 1 && expect_name => {
                let (name, end) = ident_at(code, j).expect("an identifier starts here");
                if name != "self" {
                    names.push(name);
                }
                expect_name = false;
                j = end;
                continue;
            }
            _ => {}
        }
        j += 1;
    }
    names
}

/// One source file of `src/`, read as the rules see it.
struct Source {
    /// Relative to `src/`: `node/dds.rs`.
    name: String,
    /// The top-level module: `node` for `src/node/dds.rs`, `lib` for `src/lib.rs`.
    module: String,
    /// The production code: the file with its comments, literal contents and test items
    /// blanked.
    code: Vec<u8>,
    /// Lines outside the test items.
    production_lines: usize,
    /// Sibling files that this one declares `#[cfg(test)] mod x;` (relative to `src/`, without
    /// `.rs`: `ros/sync/test_support`).
    test_files: Vec<String>,
}

impl Source {
    fn read(path: &Path) -> Source {
        let text = std::fs::read_to_string(path).expect("a readable source file");
        let name = path
            .strip_prefix(src())
            .expect("a file under src/")
            .to_string_lossy()
            .into_owned();
        Source::parse(name, &text)
    }

    fn parse(name: String, text: &str) -> Source {
        let module = name
            .split('/')
            .next()
            .expect("a path")
            .trim_end_matches(".rs")
            .to_string();
        let mut code = blank_comments_and_literals(text);
        // This file's own folder for the modules it declares.
        let stem = name.trim_end_matches(".rs");
        let folder = match stem.rsplit_once('/') {
            Some((dir, "mod")) => Some(dir.to_string()),
            Some(_) => Some(stem.to_string()),
            None if ROOTS.contains(&stem) => None,
            None => Some(stem.to_string()),
        };
        let mut test_files = Vec::new();
        let mut in_test = vec![false; text.len()];
        for (start, end) in test_items(&code) {
            let item = &code[start..end];
            if let Some(at) = find(item, b"mod ", 0) {
                if let Some((m, after)) = ident_at(item, at + 4) {
                    if item[after..].iter().find(|b| !b.is_ascii_whitespace()) == Some(&b';') {
                        test_files.push(match &folder {
                            Some(dir) => format!("{dir}/{m}"),
                            None => m,
                        });
                    }
                }
            }
            in_test[start..end].iter_mut().for_each(|t| *t = true);
        }
        let mut production_lines = 0;
        let mut offset = 0;
        for line in text.split_inclusive('\n') {
            let range = offset..offset + line.len();
            // Inside a test item from its start (blank lines too), or its first line.
            let test_line = in_test[range.start]
                || range
                    .clone()
                    .any(|i| in_test[i] && !text.as_bytes()[i].is_ascii_whitespace());
            if !test_line {
                production_lines += 1;
            }
            offset = range.end;
        }
        for (b, t) in code.iter_mut().zip(&in_test) {
            if *t && *b != b'\n' {
                *b = b' ';
            }
        }
        Source {
            name,
            module,
            code,
            production_lines,
            test_files,
        }
    }

    fn line_of(&self, at: usize) -> usize {
        1 + self.code[..at].iter().filter(|&&b| b == b'\n').count()
    }

    /// How deep the module at `at` is below the crate root: `node/events.rs` 2, `node/mod.rs`
    /// 1, plus one per inline `mod x { .. }` around `at`.
    fn depth_at(&self, at: usize) -> usize {
        let stem = self.name.trim_end_matches(".rs");
        let parts: Vec<&str> = stem.split('/').collect();
        let mut depth = match parts.last() {
            _ if ROOTS.contains(&stem) => 0,
            Some(&"mod") => parts.len() - 1,
            _ => parts.len(),
        };
        let mut from = 0;
        while let Some(m) = find(&self.code, b"mod ", from) {
            from = m + 4;
            if m > 0 && is_ident(self.code[m - 1]) {
                continue;
            }
            let Some((_, after)) = ident_at(&self.code, m + 4) else {
                continue;
            };
            let open = after
                + self.code[after..]
                    .iter()
                    .take_while(|b| b.is_ascii_whitespace())
                    .count();
            if self.code.get(open) == Some(&b'{') && open < at && at < item_end(&self.code, open) {
                depth += 1;
            }
        }
        depth
    }

    /// The top-level modules its production code names, each with the line that names it:
    /// `crate::m`, `crate::{m, n}`, and `super::...::m` chains that climb to the crate root.
    fn imports(&self) -> Vec<(String, usize)> {
        let code = &self.code;
        let mut found = Vec::new();
        let mut from = 0;
        while let Some(at) = find(code, b"crate::", from) {
            from = at + 7;
            if at > 0 && is_ident(code[at - 1]) {
                continue;
            }
            for m in first_segments(code, at + 7) {
                found.push((m, self.line_of(at)));
            }
        }
        let mut from = 0;
        while let Some(at) = find(code, b"super::", from) {
            from = at + 7;
            if (at > 0 && is_ident(code[at - 1])) || (at >= 2 && &code[at - 2..at] == b"::") {
                continue;
            }
            let mut end = at;
            let mut climbs = 0;
            while code[end..].starts_with(b"super::") {
                climbs += 1;
                end += 7;
            }
            from = end;
            if climbs >= self.depth_at(at) {
                for m in first_segments(code, end) {
                    found.push((m, self.line_of(at)));
                }
            }
        }
        found
    }

    /// Its module below the crate root: `[node, diag]` for `node/diag.rs`, `[node]` for
    /// `node/mod.rs`, none for the crate roots.
    fn module_path(&self) -> Vec<String> {
        let stem = self.name.trim_end_matches(".rs");
        if ROOTS.contains(&stem) {
            return Vec::new();
        }
        let mut parts: Vec<String> = stem.split('/').map(String::from).collect();
        if parts.last().is_some_and(|p| p == "mod") {
            parts.pop();
        }
        parts
    }

    /// The crate paths its production code names, each from the crate root and with the line
    /// that names it: `crate::a::b::C`, `super::` chains (climbing from this file's module
    /// through any inline modules around the path) and `self::` paths, groups expanded
    /// (`super::{a::X, b}` gives `[.., a, X]` and `[.., b]`). Paths that stay inside the file
    /// (`super::` out of an inline module only, `self::` in one) are left out.
    fn full_paths(&self) -> Vec<(Vec<String>, usize)> {
        let code = &self.code;
        let own = self.module_path();
        let mut found = Vec::new();
        for prefix in [&b"crate::"[..], b"super::", b"self::"] {
            let mut from = 0;
            while let Some(at) = find(code, prefix, from) {
                from = at + prefix.len();
                if (at > 0 && is_ident(code[at - 1])) || (at >= 2 && &code[at - 2..at] == b"::") {
                    continue;
                }
                let inline = self.depth_at(at) - own.len();
                let base = match prefix {
                    b"crate::" => Vec::new(),
                    b"self::" if inline == 0 => own.clone(),
                    b"self::" => continue,
                    _ => {
                        let mut climbs = 1;
                        while code[from..].starts_with(b"super::") {
                            climbs += 1;
                            from += prefix.len();
                        }
                        if climbs <= inline || climbs - inline > own.len() {
                            continue;
                        }
                        own[..own.len() - (climbs - inline)].to_vec()
                    }
                };
                for path in paths_at(code, from) {
                    let mut full = base.clone();
                    full.extend(path);
                    found.push((full, self.line_of(at)));
                }
            }
        }
        found
    }
}

/// The paths that start at `at`, each as its segments: `a::b::C` gives `[a, b, C]`, a group
/// `{a::x, b::{c, self}, d::*}` gives `[a, x]`, `[b, c]`, `[b]` and `[d]`. A path ends at
/// anything but `::` and a name (a call's parenthesis, `::<` generics, `as`); a macro
/// (`name!`) is no path.
fn paths_at(code: &[u8], at: usize) -> Vec<Vec<String>> {
    fn skip_space(code: &[u8], mut j: usize) -> usize {
        while code.get(j).is_some_and(|b| b.is_ascii_whitespace()) {
            j += 1;
        }
        j
    }
    /// Reads one path (or group) after `prefix`, from `j`; returns where it ends.
    fn read(code: &[u8], j: usize, prefix: &[String], out: &mut Vec<Vec<String>>) -> usize {
        let j = skip_space(code, j);
        match code.get(j) {
            Some(b'{') => {
                let mut k = j + 1;
                loop {
                    k = skip_space(code, k);
                    match code.get(k) {
                        None => return k,
                        Some(b'}') => return k + 1,
                        Some(b',') => k += 1,
                        Some(_) => {
                            let end = read(code, k, prefix, out);
                            // Past anything the reader does not know (`as name`).
                            k = end.max(k + 1);
                            while code.get(k).is_some_and(|&b| !matches!(b, b',' | b'}')) {
                                k += 1;
                            }
                        }
                    }
                }
            }
            Some(b'*') => {
                out.push(prefix.to_vec());
                j + 1
            }
            _ => match ident_at(code, j) {
                Some((_, end)) if code.get(end) == Some(&b'!') => end,
                Some((name, end)) => {
                    let mut path = prefix.to_vec();
                    if name != "self" {
                        path.push(name);
                    }
                    let after = skip_space(code, end);
                    if code[after..].starts_with(b"::") && code.get(after + 2) != Some(&b'<') {
                        read(code, after + 2, &path, out)
                    } else {
                        out.push(path);
                        end
                    }
                }
                None => j,
            },
        }
    }
    let mut out = Vec::new();
    read(code, at, &[], &mut out);
    out
}

/// Every source file of `src/` but those declared `#[cfg(test)] mod x;` (and their folders).
fn sources() -> Vec<Source> {
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let all: Vec<Source> = files.iter().map(|f| Source::read(f)).collect();
    let test_only: Vec<String> = all.iter().flat_map(|s| s.test_files.clone()).collect();
    all.into_iter()
        .filter(|s| {
            let stem = s.name.trim_end_matches(".rs");
            !test_only
                .iter()
                .any(|t| stem == t || stem.starts_with(&format!("{t}/")))
        })
        .collect()
}

/// Module -> the modules it imports -> where (`node/events.rs:14`).
type Graph = BTreeMap<String, BTreeMap<String, Vec<String>>>;

fn graph_of(sources: &[Source]) -> Graph {
    let mut graph = Graph::new();
    for s in sources {
        let deps = graph.entry(s.module.clone()).or_default();
        for (dep, line) in s.imports() {
            if dep != s.module {
                deps.entry(dep)
                    .or_default()
                    .push(format!("src/{}:{line}", s.name));
            }
        }
    }
    graph
}

fn graph() -> Graph {
    graph_of(&sources())
}

/// File -> the files it imports -> where, each file named `src/node/diag.rs`: a path names the
/// file of its longest leading part that is a module of the crate (`super::why::NoDepth` in
/// `node/diag.rs` names `src/node/why.rs`, `super::NodeError` names `src/node/mod.rs`, also
/// where `node/mod.rs` only re-exports the item). A file's paths into itself and into the
/// modules it declares (a folder's `mod.rs` using its own files) are no edges: a parent holds
/// its children by declaring them, and the cycles that count are among siblings and cousins.
fn file_graph_of(sources: &[Source]) -> Graph {
    let files: BTreeMap<Vec<String>, String> = sources
        .iter()
        .filter(|s| s.name != "main.rs")
        .map(|s| (s.module_path(), format!("src/{}", s.name)))
        .collect();
    let mut graph = Graph::new();
    for s in sources {
        let own = s.module_path();
        let deps = graph.entry(format!("src/{}", s.name)).or_default();
        for (path, line) in s.full_paths() {
            let Some(n) = (0..=path.len())
                .rev()
                .find(|&n| files.contains_key(&path[..n]))
            else {
                continue;
            };
            if path[..n].starts_with(&own) {
                continue;
            }
            deps.entry(files[&path[..n]].clone())
                .or_default()
                .push(format!("src/{}:{line}", s.name));
        }
    }
    graph
}

/// The cycles a depth-first search of `graph` closes, each as `a -> b (a:12) -> a (b:3)`: one
/// cycle per edge back onto the search's stack, so every knot of the graph shows at least once.
fn cycles_of(graph: &Graph) -> Vec<String> {
    fn visit(
        m: &str,
        graph: &Graph,
        stack: &mut Vec<String>,
        done: &mut BTreeSet<String>,
        found: &mut Vec<String>,
    ) {
        if done.contains(m) {
            return;
        }
        if let Some(at) = stack.iter().position(|s| s == m) {
            let mut cycle = stack[at..].to_vec();
            cycle.push(m.to_string());
            let mut text = cycle[0].clone();
            for pair in cycle.windows(2) {
                let place = &graph[&pair[0]][&pair[1]][0];
                text.push_str(&format!(" -> {} ({place})", pair[1]));
            }
            found.push(text);
            return;
        }
        stack.push(m.to_string());
        for d in graph.get(m).into_iter().flat_map(|deps| deps.keys()) {
            visit(d, graph, stack, done, found);
        }
        stack.pop();
        done.insert(m.to_string());
    }
    let (mut done, mut found) = (BTreeSet::new(), Vec::new());
    for m in graph.keys() {
        visit(m, graph, &mut Vec::new(), &mut done, &mut found);
    }
    found
}

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, ms)| ms.contains(&module))
}

#[test]
fn every_folder_and_file_has_a_place() {
    let mut unplaced = Vec::new();
    let mut present = BTreeSet::new();
    for entry in std::fs::read_dir(src()).expect("src/ is readable") {
        let path = entry.expect("a directory entry").path();
        let name = path
            .file_name()
            .expect("a name")
            .to_string_lossy()
            .into_owned();
        let module = if path.is_dir() {
            name.clone()
        } else if let Some(stem) = name.strip_suffix(".rs") {
            stem.to_string()
        } else {
            unplaced.push(format!("src/{name} (not a Rust file)"));
            continue;
        };
        present.insert(module.clone());
        let places = LAYERS
            .iter()
            .filter(|(_, ms)| ms.contains(&module.as_str()))
            .count()
            + usize::from(ROOTS.contains(&module.as_str()));
        if places != 1 {
            unplaced.push(format!("src/{name} ({places} places)"));
        }
    }
    assert!(
        unplaced.is_empty(),
        "every folder and top-level file of src/ needs exactly one place in LAYERS (or ROOTS) of \
         tests/house/architecture.rs: {unplaced:?}"
    );
    let stale: Vec<&str> = LAYERS
        .iter()
        .flat_map(|(_, ms)| ms.iter().copied())
        .chain(ROOTS.iter().copied())
        .filter(|m| !present.contains(*m))
        .collect();
    assert!(
        stale.is_empty(),
        "LAYERS names modules that src/ no longer has: {stale:?}"
    );
}

#[test]
fn layers_import_only_downwards() {
    let mut wrong = Vec::new();
    for (module, deps) in graph() {
        if ROOTS.contains(&module.as_str()) {
            continue;
        }
        let Some(own) = layer_of(&module) else {
            continue; // every_folder_and_file_has_a_place names it
        };
        for (dep, at) in deps {
            match layer_of(&dep) {
                Some(layer) if layer < own => {}
                Some(layer) => wrong.push(format!(
                    "src/{module} (layer {own}, {}) imports crate::{dep} (layer {layer}, {}) \
                     at {at:?}",
                    LAYERS[own].0, LAYERS[layer].0
                )),
                None => wrong.push(format!(
                    "src/{module} imports crate::{dep}, which is no module of a layer, at {at:?}"
                )),
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the layers:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn no_module_imports_what_the_house_rules_forbid() {
    let graph = graph();
    let mut wrong = Vec::new();
    for (module, forbidden) in NEVER {
        let deps = graph.get(*module).cloned().unwrap_or_default();
        for f in *forbidden {
            if let Some(at) = deps.get(*f) {
                wrong.push(format!("src/{module} imports crate::{f} at {at:?}"));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the house rules:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn no_import_cycle_between_modules() {
    let graph = graph();
    assert!(graph.contains_key("pipeline") && graph.contains_key("node"));
    // Depth-first search; a module met again while on the stack closes a cycle.
    fn visit(m: &str, graph: &Graph, stack: &mut Vec<String>, done: &mut BTreeSet<String>) {
        if done.contains(m) {
            return;
        }
        if let Some(at) = stack.iter().position(|s| s == m) {
            panic!("import cycle: {} -> {m}", stack[at..].join(" -> "));
        }
        stack.push(m.to_string());
        for d in graph.get(m).into_iter().flat_map(|deps| deps.keys()) {
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

/// Issue 55: the files of one folder import each other one way too (a shared item lives in the
/// file lower in the order, or in a small file of its own), so that each can be read after the
/// ones it uses.
#[test]
fn no_import_cycle_inside_a_folder() {
    let graph = file_graph_of(&sources());
    // The reader sees `use super::x` between siblings and paths from the crate root.
    let dds = &graph["src/node/dds.rs"];
    assert!(dds.contains_key("src/node/events.rs") && dds.contains_key("src/node/mod.rs"));
    let cycles = cycles_of(&graph);
    assert!(
        cycles.is_empty(),
        "import cycles between source files:\n{}",
        cycles.join("\n")
    );
}

#[test]
fn anyhow_only_at_the_command_line() {
    let users: Vec<String> = sources()
        .iter()
        .filter(|s| {
            find(&s.code, b"anyhow", 0).is_some()
                && !ANYHOW_FILES.contains(&s.name.as_str())
                && !ANYHOW_FOLDERS.iter().any(|f| s.name.starts_with(f))
        })
        .map(|s| format!("src/{}", s.name))
        .collect();
    assert!(
        users.is_empty(),
        "anyhow outside {ANYHOW_FILES:?} and {ANYHOW_FOLDERS:?} (library code returns typed errors): {users:?}"
    );
}

#[test]
fn no_source_file_is_over_the_limit_outside_its_tests() {
    let mut over = Vec::new();
    for s in sources() {
        let name = format!("src/{}", s.name);
        if s.production_lines > MAX_LINES && !OVERSIZED_FOR_NOW.contains(&name.as_str()) {
            over.push(format!("{name}: {} lines", s.production_lines));
        }
    }
    assert!(
        over.is_empty(),
        "files over {MAX_LINES} lines (tests excepted): {over:?}"
    );
}

/// The longest a function of production code may be, in lines from `fn` to its closing brace
/// (issue 55: a function people edit should fit on a screen or two).
const MAX_FUNCTION_LINES: usize = 150;

/// Each function of `code` (production code, test items blanked): its name, first line and
/// length in lines, from `fn` through its closing brace (declarations without a body skipped).
fn functions(code: &[u8]) -> Vec<(String, usize, usize)> {
    let mut found = Vec::new();
    let mut at = 0;
    while let Some(start) = find(code, b"fn ", at) {
        at = start + 3;
        if start > 0 && is_ident(code[start - 1]) {
            continue;
        }
        let Some((name, after)) = ident_at(code, start + 3) else {
            continue;
        };
        let end = item_end(code, after);
        if code[..end].last() != Some(&b'}') {
            continue;
        }
        let line = code[..start].iter().filter(|&&b| b == b'\n').count() + 1;
        let lines = code[start..end].iter().filter(|&&b| b == b'\n').count() + 1;
        found.push((name, line, lines));
    }
    found
}

#[test]
fn no_function_is_over_the_limit_outside_tests() {
    let mut over = Vec::new();
    let mut longest = (String::new(), 0);
    for s in sources() {
        for (name, line, lines) in functions(&s.code) {
            if lines > longest.1 {
                longest = (format!("src/{}:{line} {name}", s.name), lines);
            }
            if lines > MAX_FUNCTION_LINES {
                over.push(format!("src/{}:{line} {name}: {lines} lines", s.name));
            }
        }
    }
    assert!(
        over.is_empty(),
        "functions over {MAX_FUNCTION_LINES} lines (tests excepted): {over:?}"
    );
    // The reader finds the long ones: the longest is close to the limit, not a one-liner.
    assert!(longest.1 > 100, "the longest function found: {longest:?}");
}

/// The function reader counts a body from `fn` to its brace, and skips declarations and names
/// that merely end in `fn`.
#[test]
fn the_function_reader_measures_bodies() {
    let code = blank_comments_and_literals(
        "fn one() {\n    let x = 1;\n}\ntrait T {\n    fn decl(&self);\n}\nfn two(a: fn(u8) -> u8) -> u8 {\n    a(1)\n}\nmacro_rules! myfn { () => {} }\n",
    );
    let found = functions(&code);
    assert_eq!(
        found,
        vec![("one".to_string(), 1, 3), ("two".to_string(), 7, 3)]
    );
}

/// The reader itself: production code after a test module, groups, `super::` chains, and
/// names in comments, strings and test code that are no imports.
#[test]
fn the_reader_sees_every_production_line_and_only_those() {
    let text = r####"
//! Mentions crate::node in a comment.
use crate::geometry::Rig;
use crate::{image::Rgba8Image, msgs::{Image, Time}};
/* crate::bag in a block comment /* nested */ crate::bag */
const S: &str = "crate::bag";
const R: &str = r#"crate::bag " still"#;
const C: char = '{';
const Q: char = '\'';
fn f<'a>(x: &'a str) -> &'a str { x }

#[cfg(test)]
mod tests {
    use crate::node::Shared;
    const OPEN: char = '}';

    #[test]
    fn t() { let _ = "}"; }
}

#[cfg(test)]
mod test_support;

use super::super::pipeline::Job;
use super::sibling::Thing;
fn g() { crate::sweep::run(); crate::vectorised_fn!(); }
mod inner {
    use super::super::super::ros::Tf;
    use super::super::Sibling;
}
"####;
    let s = Source::parse("node/events.rs".to_string(), text);
    let names: Vec<(String, usize)> = s.imports();
    let mut found: Vec<(&str, usize)> = names.iter().map(|(m, l)| (m.as_str(), *l)).collect();
    found.sort();
    assert_eq!(
        found,
        [
            ("geometry", 3),
            ("image", 4),
            ("msgs", 4),
            ("pipeline", 24),
            ("ros", 28),
            ("sweep", 26),
        ]
    );
    assert_eq!(s.test_files, ["node/events/test_support"]);
    // 30 lines of text, 10 of them in test items (a blank line among them).
    assert_eq!(s.production_lines, 30 - 10);
}

/// The file-level reader: full paths from `crate::`, `super::` chains (out of inline modules
/// too) and `self::`, groups expanded, macros and paths inside the file left out; and a cycle
/// among sibling files is found and named, while a folder's `mod.rs` using its own files is not.
#[test]
fn the_file_reader_follows_full_paths() {
    let text = r####"
use super::why::{NoDepth, Reason as Why};
use super::{log::{lock, RateLimited}, NodeConfig};
use crate::params::{self, engine::apply};
use self::inner::Hidden;
fn f() { super::fusion::values(); crate::vectorised_fn!(); super::worker::Pool::<u8>::new(); }
mod inner {
    use super::super::topics::ros_err;
    use super::Local;
}
"####;
    let s = Source::parse("node/diag.rs".to_string(), text);
    let mut found: Vec<(String, usize)> = s
        .full_paths()
        .into_iter()
        .map(|(p, l)| (p.join("::"), l))
        .collect();
    found.sort();
    let expected = [
        ("node::diag::inner::Hidden", 5),
        ("node::fusion::values", 6),
        ("node::log::RateLimited", 3),
        ("node::log::lock", 3),
        ("node::topics::ros_err", 8),
        ("node::why::NoDepth", 2),
        ("node::why::Reason", 2),
        ("node::worker::Pool", 6),
        ("node::NodeConfig", 3),
        ("params", 4),
        ("params::engine::apply", 4),
    ];
    let expected: Vec<(String, usize)> =
        expected.iter().map(|(p, l)| (p.to_string(), *l)).collect();
    let mut expected = expected;
    expected.sort();
    assert_eq!(found, expected);

    let files = [
        ("node/mod.rs", "use self::a::X;\nuse self::b::Y;\n"),
        ("node/a.rs", "use super::b::Y;\nuse super::NodeError;\n"),
        ("node/b.rs", "fn g() { crate::node::a::f(); }\n"),
    ];
    let sources: Vec<Source> = files
        .iter()
        .map(|(name, text)| Source::parse(name.to_string(), text))
        .collect();
    let graph = file_graph_of(&sources);
    assert!(graph["src/node/mod.rs"].is_empty());
    assert_eq!(
        cycles_of(&graph),
        ["src/node/a.rs -> src/node/b.rs (src/node/a.rs:1) -> src/node/a.rs (src/node/b.rs:1)"]
    );
}
