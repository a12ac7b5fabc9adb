//! Build script: prepends `shaders/camera.wgsl`, `shaders/common.wgsl` and the stage's `prelude`
//! files to every stage shader of the stage registry
//! (`src/sweep/stages.rs`) and writes the combined sources to OUT_DIR for `include_str!`.
//! Standard library only, so the first release build compiles no shader compiler for it: the
//! check of each shader against its registry row (naga: parse, validate, entry point,
//! workgroup size, bindings, override constants) is a test, `src/sweep/gpu/shader_check.rs`
//! (issue 30 item 4: naga built a second time at opt-level 0 for this script, and the script
//! itself, were ~10 s of the first build's CPU time).

use std::{env, fs, path::PathBuf};

#[allow(dead_code)]
mod registry {
    include!("src/sweep/stages.rs");
}

use registry::{STAGES, SUBGROUP_VARIANTS};

fn main() {
    let out_dir = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    println!("cargo:rerun-if-changed=shaders");
    println!("cargo:rerun-if-changed=src/sweep/stages.rs");
    let camera =
        fs::read_to_string("shaders/camera.wgsl").expect("shaders/camera.wgsl is readable");
    let common =
        fs::read_to_string("shaders/common.wgsl").expect("shaders/common.wgsl is readable");
    let common = format!("{camera}\n{common}");
    let variants = SUBGROUP_VARIANTS.iter().map(|(_, info)| info);
    for stage in STAGES.iter().chain(variants) {
        let path = format!("shaders/{}.wgsl", stage.name);
        println!("cargo:rerun-if-changed={path}");
        let body = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let mut source = common.clone();
        for prelude in stage.prelude {
            let path = format!("shaders/{prelude}.wgsl");
            println!("cargo:rerun-if-changed={path}");
            let text = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
            source.push_str(&format!("\n// ---- {path} ----\n{text}"));
        }
        source.push_str(&format!("\n// ---- {path} ----\n{body}"));
        fs::write(out_dir.join(format!("{}.wgsl", stage.name)), source)
            .expect("OUT_DIR is writable");
    }
    // The combined sources, in registry order, then the subgroup variants'.
    let include =
        |name: &str| format!("include_str!(concat!(env!(\"OUT_DIR\"), \"/{name}.wgsl\"))");
    let sources: Vec<String> = STAGES.iter().map(|s| include(s.name)).collect();
    let variants: Vec<String> = SUBGROUP_VARIANTS
        .iter()
        .map(|(_, s)| include(s.name))
        .collect();
    let generated = format!(
        "/// The sources of the stages (registry order), `camera.wgsl` and `common.wgsl` prepended.\npub const SHADERS: [&str; {n}] = [{}];\n/// The same of `SUBGROUP_VARIANTS`.\npub const SUBGROUP_SHADERS: [&str; {m}] = [{}];\n",
        sources.join(", "),
        variants.join(", "),
        n = STAGES.len(),
        m = SUBGROUP_VARIANTS.len(),
    );
    fs::write(out_dir.join("shaders.rs"), generated).expect("OUT_DIR is writable");
}
