//! The parameter table as documentation: the parameter section of docs/node.md is
//! [`markdown_table`]'s output (a test keeps them equal).

use super::spec::ParamRange;
use super::table::param_table;

/// The parameter table as a Markdown table (name, type, default, range, description) for
/// docs/node.md.
pub fn markdown_table() -> String {
    fn cell(s: &str) -> String {
        s.replace('|', "\\|").replace('\n', " ")
    }
    let mut out = String::from(
        "| Parameter | Type | Default | Range | Description |\n|---|---|---|---|---|\n",
    );
    for p in param_table() {
        let default = if p.required {
            "(required)".to_string()
        } else {
            format!("`{}`", p.default)
        };
        let range = match &p.range {
            // Already escaped.
            ParamRange::OneOf(values) => values
                .iter()
                .map(|v| format!("`{v}`"))
                .collect::<Vec<_>>()
                .join(" \\| "),
            other => cell(&other.describe()),
        };
        let mut description = cell(p.description);
        if p.read_only {
            description.push_str(" *(read-only)*");
        }
        out.push_str(&format!(
            "| `{}` | `{}` | {} | {} | {} |\n",
            p.name,
            p.kind,
            cell(&default),
            range,
            description
        ));
    }
    out
}
