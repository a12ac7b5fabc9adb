//! Build script: prepends `shaders/common.wgsl` to every stage shader of the stage registry
//! (`src/sweep/stages.rs`), validates each with naga and checks it against its registry row
//! (entry point, workgroup size, bindings by number, name and kind, override constants), so a
//! broken shader or a stale row fails `cargo build` with the stage's name; writes the combined
//! sources to OUT_DIR for `include_str!`.

use std::{env, fs, path::PathBuf};

#[allow(dead_code)]
mod registry {
    include!("src/sweep/stages.rs");
}

use registry::{BindingKind, StageInfo, STAGES, SUBGROUP_VARIANTS};

/// Where `module` disagrees with the registry row `stage`.
fn check_against_registry(stage: &StageInfo, module: &naga::Module) -> Vec<String> {
    let mut problems = Vec::new();
    match module
        .entry_points
        .iter()
        .find(|e| e.name == stage.entry_point)
    {
        None => problems.push(format!("no entry point `{}`", stage.entry_point)),
        Some(entry) => {
            let overridden = entry
                .workgroup_size_overrides
                .is_some_and(|o| o.iter().any(Option::is_some));
            match stage.workgroup_size {
                Some(size) if overridden || entry.workgroup_size != size => problems.push(format!(
                    "workgroup size {:?} (an override: {overridden}), the registry says {size:?}",
                    entry.workgroup_size
                )),
                None if !overridden => problems.push(format!(
                    "workgroup size {:?} is fixed, the registry says an override sets it",
                    entry.workgroup_size
                )),
                _ => {}
            }
        }
    }
    let mut declared = Vec::new();
    for (_, var) in module.global_variables.iter() {
        let Some(binding) = &var.binding else {
            continue;
        };
        let name = var.name.clone().unwrap_or_default();
        let kind = match var.space {
            naga::AddressSpace::Uniform => Some(BindingKind::Uniform),
            naga::AddressSpace::Storage { access } => {
                if access.contains(naga::StorageAccess::STORE) {
                    Some(BindingKind::ReadWrite)
                } else {
                    Some(BindingKind::Read)
                }
            }
            _ => None,
        };
        declared.push((binding.group, binding.binding, name, kind));
    }
    for (group, number, name, kind) in &declared {
        let row = stage.bindings.get(*number as usize);
        let expected = row.map(|b| {
            let kind = match b.kind {
                BindingKind::DynamicUniform => BindingKind::Uniform,
                other => other,
            };
            (b.name, kind)
        });
        if *group != 0 || expected != Some((name.as_str(), kind.unwrap_or(BindingKind::Uniform))) {
            problems.push(format!(
                "@group({group}) @binding({number}) `{name}` ({kind:?}), the registry says {row:?}"
            ));
        }
    }
    for (number, binding) in stage.bindings.iter().enumerate() {
        if !declared.iter().any(|(_, n, _, _)| *n as usize == number) {
            problems.push(format!(
                "binding {number} (`{}`) is in the registry, not in the shader",
                binding.name
            ));
        }
    }
    for name in stage.overrides {
        if !module
            .overrides
            .iter()
            .any(|(_, o)| o.name.as_deref() == Some(*name))
        {
            problems.push(format!("no override constant `{name}`"));
        }
    }
    problems
}

fn main() {
    let out_dir = PathBuf::from(env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    println!("cargo:rerun-if-changed=shaders");
    println!("cargo:rerun-if-changed=src/sweep/stages.rs");
    let common =
        fs::read_to_string("shaders/common.wgsl").expect("shaders/common.wgsl is readable");
    let mut failures = Vec::new();
    let subgroup_stages = SUBGROUP_VARIANTS.iter().map(|(_, info)| info);
    for (stage, capabilities) in STAGES
        .iter()
        .map(|s| (s, naga::valid::Capabilities::default()))
        .chain(subgroup_stages.map(|s| (s, naga::valid::Capabilities::SUBGROUP)))
    {
        let path = format!("shaders/{}.wgsl", stage.name);
        println!("cargo:rerun-if-changed={path}");
        let body = fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let source = format!("{common}\n// ---- {path} ----\n{body}");
        let label = format!("common.wgsl + {path}");
        match naga::front::wgsl::parse_str(&source) {
            Err(error) => failures.push(error.emit_to_string_with_path(&source, &label)),
            Ok(module) => {
                let mut validator =
                    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities);
                if let Err(error) = validator.validate(&module) {
                    failures.push(error.emit_to_string_with_path(&source, &label));
                }
                for problem in check_against_registry(stage, &module) {
                    failures.push(format!(
                        "{path} disagrees with src/sweep/stages.rs: {problem}"
                    ));
                }
            }
        }
        fs::write(out_dir.join(format!("{}.wgsl", stage.name)), source)
            .expect("OUT_DIR is writable");
    }
    // The validated sources, in registry order, then the subgroup variants'.
    let include =
        |name: &str| format!("include_str!(concat!(env!(\"OUT_DIR\"), \"/{name}.wgsl\"))");
    let sources: Vec<String> = STAGES.iter().map(|s| include(s.name)).collect();
    let variants: Vec<String> = SUBGROUP_VARIANTS
        .iter()
        .map(|(_, s)| include(s.name))
        .collect();
    let generated = format!(
        "/// The validated sources of the stages (registry order), `common.wgsl` prepended.\npub const SHADERS: [&str; {n}] = [{}];\n/// The same of `SUBGROUP_VARIANTS`.\npub const SUBGROUP_SHADERS: [&str; {m}] = [{}];\n",
        sources.join(", "),
        variants.join(", "),
        n = STAGES.len(),
        m = SUBGROUP_VARIANTS.len(),
    );
    fs::write(out_dir.join("shaders.rs"), generated).expect("OUT_DIR is writable");
    if !failures.is_empty() {
        panic!("shader validation failed:\n{}", failures.join("\n"));
    }
}
