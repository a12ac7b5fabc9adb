//! The documents' links hold: every relative link in the project's Markdown (README,
//! ARCHITECTURE, CHANGELOG, docs/ and its notes, the folders' READMEs) names a file that exists
//! and, with a `#fragment` into a Markdown file, one of its headings (GitHub's anchors: lower
//! case, punctuation dropped, spaces as hyphens, `-1`, `-2` for repeats). Pages split or
//! headings renamed leave links behind otherwise (the history moved to docs/notes/ did). And the
//! user pages in docs/ stay within their length.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The project's own Markdown files (not the vendored crates', not build output).
fn markdown_files() -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut folders = vec![root()];
    while let Some(folder) = folders.pop() {
        let entries = std::fs::read_dir(&folder).expect("a readable folder");
        for entry in entries.flatten() {
            let path = entry.path();
            let name = entry.file_name().to_string_lossy().into_owned();
            if path.is_dir() {
                let skipped = ["target", "vendor", "fuzz", "node_modules"];
                if !name.starts_with('.') && !skipped.contains(&name.as_str()) {
                    folders.push(path);
                }
            } else if name.ends_with(".md") {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// GitHub's anchor of a heading's text.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a Markdown file's headings (outside code blocks).
fn anchors(text: &str) -> HashSet<String> {
    let mut seen = std::collections::HashMap::<String, usize>::new();
    let mut out = HashSet::new();
    let mut in_code = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if in_code || hashes == 0 || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = anchor(&line[hashes..]);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        });
        *n += 1;
    }
    out
}

/// The `](target)` links of a line.
fn links(line: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = line;
    while let Some(at) = rest.find("](") {
        let after = &rest[at + 2..];
        let end = after.find(')').unwrap_or(after.len());
        out.push(&after[..end]);
        rest = &after[end..];
    }
    out
}

#[test]
fn every_relative_link_names_a_file_and_a_heading_that_exist() {
    let files = markdown_files();
    assert!(
        files.iter().any(|f| f.ends_with("docs/speed.md")),
        "the docs were found"
    );
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        let text = std::fs::read_to_string(file).expect("readable");
        let mut in_code = false;
        for (number, line) in text.lines().enumerate() {
            if line.trim_start().starts_with("```") {
                in_code = !in_code;
            }
            if in_code {
                continue;
            }
            for link in links(line) {
                if link.contains("://") || link.starts_with("mailto:") || link.contains(' ') {
                    continue;
                }
                let (path, fragment) = link.split_once('#').unwrap_or((link, ""));
                let target = if path.is_empty() {
                    file.clone()
                } else {
                    file.parent().unwrap_or(Path::new(".")).join(path)
                };
                let place = format!(
                    "{}:{}: {link}",
                    file.strip_prefix(root()).unwrap_or(file).display(),
                    number + 1
                );
                checked += 1;
                if !target.exists() {
                    broken.push(format!("{place} (no such file)"));
                } else if !fragment.is_empty() && path_is_markdown(&target) {
                    let text = std::fs::read_to_string(&target).expect("readable");
                    if !anchors(&text).contains(fragment) {
                        broken.push(format!("{place} (no such heading)"));
                    }
                }
            }
        }
    }
    assert!(checked > 100, "{checked} links checked");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

fn path_is_markdown(path: &Path) -> bool {
    path.extension().is_some_and(|e| e == "md")
}

/// The anchors as GitHub makes them, on headings of this project's kind.
#[test]
fn anchors_are_githubs() {
    let text = "# Quality\n## Two cameras (2026-11-30)\n### `bag`: rosbag2, step 1.5\n\
                ```\n# not a heading\n```\n## Quality\n";
    let got = anchors(text);
    for want in [
        "quality",
        "two-cameras-2026-11-30",
        "bag-rosbag2-step-15",
        "quality-1",
    ] {
        assert!(got.contains(want), "{want} in {got:?}");
    }
    assert!(!got.contains("not-a-heading"));
}

/// The user pages stay pages (ARCHITECTURE.md's rule for `docs/`): at most 300 lines each, so
/// that a new figure replaces today's and the one it replaces moves to `docs/notes/`, the
/// developers' history, instead of the page growing into a lab notebook.
#[test]
fn the_user_pages_stay_within_300_lines() {
    const MOST: usize = 300;
    let docs = root().join("docs");
    let mut pages = 0;
    let mut long = Vec::new();
    for entry in std::fs::read_dir(&docs).expect("docs/").flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "md") {
            pages += 1;
            let text = std::fs::read_to_string(&path).expect("a readable page");
            let lines = text.lines().count();
            if lines > MOST {
                long.push(format!("{} ({lines} lines)", path.display()));
            }
        }
    }
    assert!(pages >= 5, "only {pages} pages found in {}", docs.display());
    assert!(
        long.is_empty(),
        "over {MOST} lines: {long:?}; move the older figures to docs/notes/"
    );
}
