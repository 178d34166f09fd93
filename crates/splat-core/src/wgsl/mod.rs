//! How the kernels' WGSL is put together, and the structs the host and the kernels share.
//!
//! - A kernel module is a list of [`WgslPart`]s, each a file beside the Rust that uses it,
//!   joined in order by [`KernelModule::source`]: the shared parts first (each says which
//!   parts it needs in its module and which of the kernel's globals it reads), the kernel's
//!   own file last (WGSL declarations may come in any order within a module). The joined
//!   source names every part in a header, so a WGSL error points at a file.
//! - A struct the host writes and a kernel reads is declared once in Rust with
//!   [`gpu_struct!`], which records its field names and byte offsets; the test in
//!   `tests.rs` parses every kernel module with naga and fails, naming struct and field,
//!   where the WGSL declaration of the same name differs.

#[cfg(test)]
mod tests;

/// One WGSL file of a kernel module.
#[derive(Debug)]
pub(crate) struct WgslPart {
    /// The file's name beside the Rust that includes it (for headers and errors).
    pub file: &'static str,
    pub source: &'static str,
    /// Parts that must be in the same module (this one uses their declarations).
    pub needs: &'static [&'static str],
    /// Globals the part reads but the including kernel declares (its own bindings, under
    /// these names).
    pub reads: &'static [&'static str],
}

/// The parts of one shader module, in order, and its label.
#[derive(Debug)]
pub(crate) struct KernelModule {
    pub label: &'static str,
    pub parts: Vec<&'static WgslPart>,
}

impl KernelModule {
    /// The module's WGSL: each part after a header line naming it. Panics if a part's
    /// module lacks a part it needs (a mistake in the part list, caught by every test that
    /// compiles the kernel).
    pub(crate) fn source(&self) -> String {
        let files: Vec<&str> = self.parts.iter().map(|p| p.file).collect();
        let mut source = format!(
            "// Kernel module `{}`: {} (joined by splat-core's wgsl::KernelModule).\n",
            self.label,
            files.join(", ")
        );
        for part in &self.parts {
            for needed in part.needs {
                assert!(
                    files.contains(needed),
                    "kernel module `{}`: {} needs {needed}",
                    self.label,
                    part.file
                );
            }
            source.push_str(&format!("\n// ---- {} ----\n", part.file));
            if !part.reads.is_empty() {
                source.push_str(&format!(
                    "// (reads the kernel's {})\n",
                    part.reads.join(", ")
                ));
            }
            source.push_str(part.source);
        }
        source
    }
}

/// A struct's layout as the host writes it: name, size, and each field's name and byte
/// offset, in declaration order (for the tests, which compare it with the WGSL's).
#[cfg(test)]
#[derive(Clone, Copy, Debug)]
pub(crate) struct StructLayout {
    pub name: &'static str,
    pub size: usize,
    pub fields: &'static [(&'static str, usize)],
}

/// A `#[repr(C)]` struct shared with WGSL (see [`gpu_struct!`]).
#[cfg(test)]
pub(crate) trait GpuStruct: bytemuck::Pod {
    const LAYOUT: StructLayout;
}

/// Declares a `#[repr(C)]`, `Pod` struct that WGSL declares under the same name with the
/// same fields, and records its layout (`GpuStruct::LAYOUT`, in test builds) from this one
/// declaration for the test that compares it with the WGSL side.
macro_rules! gpu_struct {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $($(#[$field_meta:meta])* $field_vis:vis $field:ident : $ty:ty),* $(,)?
        }
    ) => {
        $(#[$meta])*
        #[repr(C)]
        #[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
        $vis struct $name {
            $($(#[$field_meta])* $field_vis $field: $ty),*
        }

        #[cfg(test)]
        impl $crate::wgsl::GpuStruct for $name {
            const LAYOUT: $crate::wgsl::StructLayout = $crate::wgsl::StructLayout {
                name: stringify!($name),
                size: std::mem::size_of::<$name>(),
                fields: &[$((stringify!($field), std::mem::offset_of!($name, $field))),*],
            };
        }
    };
}
pub(crate) use gpu_struct;
