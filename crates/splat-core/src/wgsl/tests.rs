//! Every struct shared by the host and the kernels has one layout: each kernel module
//! (every variant) parsed by naga, each struct in it that Rust declares with
//! `gpu_struct!` compared field by field, and every struct a kernel binds declared in
//! Rust.

use super::{GpuStruct, KernelModule, StructLayout};
use crate::raster::params::{Projected, RenderParams};
use crate::raster::sort::{DispatchPlan, SortPass};
use crate::spacetime::evaluate::TimeParams;
use crate::train::adam::AdamParams;
use crate::train::losses::LossParams;

/// The Rust side of every shared struct.
fn rust_structs() -> Vec<StructLayout> {
    vec![
        RenderParams::LAYOUT,
        Projected::LAYOUT,
        DispatchPlan::LAYOUT,
        SortPass::LAYOUT,
        AdamParams::LAYOUT,
        LossParams::LAYOUT,
        TimeParams::LAYOUT,
    ]
}

fn kernel_modules() -> Vec<KernelModule> {
    let mut modules = crate::raster::kernel_modules();
    modules.extend(crate::train::kernel_modules());
    modules.extend(crate::spacetime::kernel_modules());
    modules
}

/// How the WGSL declaration `members` (of byte size `span`) in `module` differs from
/// `rust`: one line per difference, naming struct and field.
fn differences(
    rust: &StructLayout,
    members: &[naga::StructMember],
    span: u32,
    module: &str,
) -> Vec<String> {
    let name = rust.name;
    let wgsl: Vec<(&str, usize)> = members
        .iter()
        .map(|m| (m.name.as_deref().unwrap_or("?"), m.offset as usize))
        .collect();
    let mut out = Vec::new();
    for &(field, offset) in rust.fields {
        match wgsl.iter().find(|(w, _)| *w == field) {
            None => out.push(format!(
                "{name}.{field} (Rust, byte {offset}) is missing from the WGSL of `{module}`"
            )),
            Some(&(_, at)) if at != offset => out.push(format!(
                "{name}.{field} is at byte {offset} in Rust but {at} in the WGSL of `{module}`"
            )),
            Some(_) => {}
        }
    }
    for &(field, at) in &wgsl {
        if !rust.fields.iter().any(|(r, _)| *r == field) {
            out.push(format!(
                "{name}.{field} (WGSL of `{module}`, byte {at}) is missing from the Rust struct"
            ));
        }
    }
    if out.is_empty() && span as usize != rust.size {
        out.push(format!(
            "{name} is {} bytes in Rust but {span} in the WGSL of `{module}`",
            rust.size
        ));
    }
    out
}

/// The struct a global of type `ty` holds (itself, or its array's elements), if any.
fn bound_struct(module: &naga::Module, ty: naga::Handle<naga::Type>) -> Option<&str> {
    let ty = &module.types[ty];
    match ty.inner {
        naga::TypeInner::Struct { .. } => ty.name.as_deref(),
        naga::TypeInner::Array { base, .. } => bound_struct(module, base),
        _ => None,
    }
}

#[test]
fn every_gpu_struct_matches_its_wgsl_declaration() {
    let rust = rust_structs();
    let mut found = Vec::new();
    let mut failures = Vec::new();
    for kernel in kernel_modules() {
        let source = kernel.source();
        let module = naga::front::wgsl::parse_str(&source).unwrap_or_else(|e| {
            panic!(
                "kernel module `{}` does not parse:\n{}",
                kernel.label,
                e.emit_to_string(&source)
            )
        });
        for (_, ty) in module.types.iter() {
            let (Some(name), naga::TypeInner::Struct { members, span }) = (&ty.name, &ty.inner)
            else {
                continue;
            };
            if let Some(layout) = rust.iter().find(|l| l.name == name) {
                found.push(layout.name);
                failures.extend(differences(layout, members, *span, kernel.label));
            }
        }
        for (_, global) in module.global_variables.iter() {
            let shared = matches!(
                global.space,
                naga::AddressSpace::Uniform | naga::AddressSpace::Storage { .. }
            );
            if let Some(name) = bound_struct(&module, global.ty).filter(|_| shared) {
                if !rust.iter().any(|l| l.name == name) {
                    failures.push(format!(
                        "`{}` binds a {name}, which no gpu_struct! declares in Rust",
                        kernel.label
                    ));
                }
            }
        }
        for part in &kernel.parts {
            for global in part.reads {
                let declared = module
                    .global_variables
                    .iter()
                    .any(|(_, g)| g.name.as_deref() == Some(global));
                if !declared {
                    failures.push(format!(
                        "{} reads `{global}`, which `{}` does not declare",
                        part.file, kernel.label
                    ));
                }
            }
        }
    }
    for layout in &rust {
        if !found.contains(&layout.name) {
            failures.push(format!("{} is declared in no kernel module", layout.name));
        }
    }
    failures.sort();
    failures.dedup();
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_part_without_a_part_it_needs_is_refused() {
    let module = KernelModule {
        label: "project without common",
        parts: vec![
            &crate::raster::GAUSSIAN_LAYOUT_WGSL,
            &crate::raster::GAUSSIAN_WGSL,
        ],
    };
    let error = std::panic::catch_unwind(|| module.source()).expect_err("refused");
    let message = error.downcast_ref::<String>().expect("a formatted message");
    assert!(
        message.contains("gaussian.wgsl needs common.wgsl"),
        "{message}"
    );
}
