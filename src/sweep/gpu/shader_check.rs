//! Every stage shader checked against its registry row (`sweep/stages.rs`) with naga: parsed,
//! validated (the subgroup variants with naga's subgroup capability), and its entry point,
//! workgroup size, bindings (group 0, by number, name and kind) and override constants
//! compared with the row. A broken shader or a stale row fails this test with the stage's
//! name. (build.rs did this until issue 30 item 4; a test keeps naga out of the first build's
//! build script.)

use super::pipelines::{SHADERS, SUBGROUP_SHADERS};
use crate::sweep::stages::{BindingKind, StageInfo, STAGES, SUBGROUP_VARIANTS};

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

#[test]
fn every_shader_validates_and_matches_its_registry_row() {
    let stages = STAGES
        .iter()
        .zip(SHADERS)
        .map(|(s, source)| (s, source, naga::valid::Capabilities::default()));
    let variants = SUBGROUP_VARIANTS
        .iter()
        .zip(SUBGROUP_SHADERS)
        .map(|((_, s), source)| (s, source, naga::valid::Capabilities::SUBGROUP));
    let mut failures = Vec::new();
    for (stage, source, capabilities) in stages.chain(variants) {
        let label = format!("camera.wgsl + common.wgsl + shaders/{}.wgsl", stage.name);
        match naga::front::wgsl::parse_str(source) {
            Err(error) => failures.push(error.emit_to_string_with_path(source, &label)),
            Ok(module) => {
                let mut validator =
                    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities);
                if let Err(error) = validator.validate(&module) {
                    failures.push(error.emit_to_string_with_path(source, &label));
                }
                for problem in check_against_registry(stage, &module) {
                    failures.push(format!(
                        "shaders/{}.wgsl disagrees with src/sweep/stages.rs: {problem}",
                        stage.name
                    ));
                }
            }
        }
    }
    assert!(
        failures.is_empty(),
        "shader validation failed:\n{}",
        failures.join("\n")
    );
}
