//! Build script: prepends `shaders/common.wgsl` to every stage shader, validates each with naga
//! (so a broken shader fails `cargo build` with its name and line), and writes the combined
//! sources to OUT_DIR for `include_str!`.

use std::{env, fs, path::PathBuf};

const STAGES: &[&str] = &[
    "cost",
    "box_h",
    "box_v",
    "aggregate",
    "finalize",
    "median",
    "splat",
    "visibility",
    "sgm",
    "sgm_select",
];

fn main() {
    let out_dir = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    println!("cargo:rerun-if-changed=shaders");
    let common =
        fs::read_to_string("shaders/common.wgsl").expect("shaders/common.wgsl is readable");
    let mut failures = Vec::new();
    for stage in STAGES {
        let path = format!("shaders/{stage}.wgsl");
        println!("cargo:rerun-if-changed={path}");
        let body = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let source = format!("{common}\n// ---- {path} ----\n{body}");
        let label = format!("common.wgsl + {path}");
        match naga::front::wgsl::parse_str(&source) {
            Err(error) => failures.push(error.emit_to_string_with_path(&source, &label)),
            Ok(module) => {
                let mut validator = naga::valid::Validator::new(
                    naga::valid::ValidationFlags::all(),
                    naga::valid::Capabilities::default(),
                );
                if let Err(error) = validator.validate(&module) {
                    failures.push(error.emit_to_string_with_path(&source, &label));
                }
            }
        }
        fs::write(out_dir.join(format!("{stage}.wgsl")), source).expect("OUT_DIR is writable");
    }
    // The stage list for the engine, generated from the one list above.
    let names: Vec<String> = STAGES.iter().map(|s| format!("{s:?}")).collect();
    let sources: Vec<String> = STAGES
        .iter()
        .map(|s| format!("include_str!(concat!(env!(\"OUT_DIR\"), \"/{s}.wgsl\"))"))
        .collect();
    let generated = format!(
        "/// Stage names in pipeline order (also the shader file names).\npub const STAGES: [&str; {n}] = [{}];\n/// The validated sources of the stages, `common.wgsl` prepended.\nconst SHADERS: [&str; {n}] = [{}];\n",
        names.join(", "),
        sources.join(", "),
        n = STAGES.len()
    );
    fs::write(out_dir.join("stages.rs"), generated).expect("OUT_DIR is writable");
    if !failures.is_empty() {
        panic!("shader validation failed:\n{}", failures.join("\n"));
    }
}
