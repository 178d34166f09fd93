//! Adapter choice and device creation.
//!
//! A real GPU when one is present, else the CPU adapter (Mesa lavapipe). The environment
//! variable `PANO4D_ADAPTER` forces one: `gpu`, `cpu`, `pci:<bus id>` (e.g.
//! `pci:0000:3b:00.0`, as `nvidia-smi --query-gpu=pci.bus_id` prints it: how `pano4d batch`
//! puts each scene on the GPU Ray gave it, since wgpu does not read `CUDA_VISIBLE_DEVICES`),
//! or a substring of the adapter name.

use super::RasterError;

pub const ADAPTER_ENV: &str = "PANO4D_ADAPTER";
/// Set to 0 to leave subgroup operations off (see [`DeviceOptions::from_env`]).
pub const SUBGROUPS_ENV: &str = "PANO4D_SUBGROUPS";
/// Set to 0 to leave native float atomics off (see [`DeviceOptions::from_env`]).
pub const FLOAT_ATOMICS_ENV: &str = "PANO4D_FLOAT_ATOMICS";

const NO_DRIVER_HINT: &str = "no Vulkan/Metal/DX12 adapter found; on Debian/Ubuntu install a \
     Vulkan driver with `apt-get install mesa-vulkan-drivers libvulkan1` (lavapipe runs on the \
     CPU), or use backend=\"torch\"";

/// What `pano4d info` shows about the adapter in use.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdapterSummary {
    pub name: String,
    pub backend: String,
    pub device_type: String,
    pub driver: String,
}

impl From<&wgpu::AdapterInfo> for AdapterSummary {
    fn from(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend).to_lowercase(),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info)
                .trim()
                .to_string(),
        }
    }
}

/// Which optional features the device is created with (each only where the adapter has it),
/// and an optional cap on its buffer limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceOptions {
    /// Subgroup operations (`Features::SUBGROUP`): the backward sums a subgroup's pixels
    /// before one invocation adds them.
    pub subgroups: bool,
    /// Native f32 atomic adds on storage buffers (`Features::SHADER_FLOAT32_ATOMIC`): the
    /// backward adds into each Gaussian's gradient with them instead of a compare-exchange
    /// loop.
    pub float_atomics: bool,
    /// Lowers the storage-binding and buffer-size limits to this many bytes (tests reach
    /// the limits cheaply with a small one).
    pub binding_limit: Option<u64>,
}

impl DeviceOptions {
    /// Every optional feature the adapter has, unless `PANO4D_SUBGROUPS=0` or
    /// `PANO4D_FLOAT_ATOMICS=0` turns it off (to compare the paths, or to step around a
    /// driver that gets one wrong).
    pub fn from_env() -> Self {
        let enabled = |name: &str| std::env::var(name).map_or(true, |v| v.trim() != "0");
        Self {
            subgroups: enabled(SUBGROUPS_ENV),
            float_atomics: enabled(FLOAT_ATOMICS_ENV),
            binding_limit: None,
        }
    }
}

/// A device and queue on the chosen adapter.
pub struct GpuContext {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: AdapterSummary,
}

fn is_gpu(info: &wgpu::AdapterInfo) -> bool {
    matches!(
        info.device_type,
        wgpu::DeviceType::DiscreteGpu
            | wgpu::DeviceType::IntegratedGpu
            | wgpu::DeviceType::VirtualGpu
    )
}

/// Whether two PCI bus ids (`domain:bus:device.function`, hex) name the same slot; the
/// domain's width differs between tools (`0000:` from Vulkan, `00000000:` from nvidia-smi).
fn same_pci_slot(a: &str, b: &str) -> bool {
    fn parse(id: &str) -> Option<(u64, String)> {
        let id = id.trim().to_lowercase();
        let (domain, slot) = match id.matches(':').count() {
            2 => id.split_once(':')?,
            1 => ("0", id.as_str()),
            _ => return None,
        };
        Some((u64::from_str_radix(domain, 16).ok()?, slot.to_string()))
    }
    matches!((parse(a), parse(b)), (Some(x), Some(y)) if x == y)
}

/// Picks an adapter by the `PANO4D_ADAPTER` preference (None: GPU first, then CPU).
fn choose(
    adapters: Vec<wgpu::Adapter>,
    preference: Option<&str>,
) -> Result<wgpu::Adapter, RasterError> {
    let names: Vec<String> = adapters
        .iter()
        .map(|a| {
            let info = a.get_info();
            match info.device_pci_bus_id.as_str() {
                "" => info.name,
                bus => format!("{} (pci:{bus})", info.name),
            }
        })
        .collect();
    let rank = |info: &wgpu::AdapterInfo| match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    let mut candidates: Vec<wgpu::Adapter> = match preference.map(str::to_lowercase).as_deref() {
        None | Some("") => adapters,
        Some("gpu") => adapters
            .into_iter()
            .filter(|a| is_gpu(&a.get_info()))
            .collect(),
        Some("cpu") => adapters
            .into_iter()
            .filter(|a| a.get_info().device_type == wgpu::DeviceType::Cpu)
            .collect(),
        Some(pci) if pci.starts_with("pci:") => adapters
            .into_iter()
            .filter(|a| same_pci_slot(&a.get_info().device_pci_bus_id, &pci[4..]))
            .collect(),
        Some(name) => adapters
            .into_iter()
            .filter(|a| a.get_info().name.to_lowercase().contains(name))
            .collect(),
    };
    candidates.sort_by_key(|a| rank(&a.get_info()));
    candidates
        .into_iter()
        .next()
        .ok_or_else(|| match preference {
            Some(p) if !p.is_empty() => RasterError::NoAdapter(format!(
                "{ADAPTER_ENV}={p:?} matches no adapter (available: {names:?}); {NO_DRIVER_HINT}"
            )),
            _ => RasterError::NoAdapter(NO_DRIVER_HINT.to_string()),
        })
}

impl GpuContext {
    /// Creates a device on the adapter chosen by `PANO4D_ADAPTER` (see the module docs)
    /// with [`DeviceOptions::from_env`].
    pub fn new() -> Result<Self, RasterError> {
        Self::with_options(DeviceOptions::from_env())
    }

    /// Creates a device on the adapter chosen by `PANO4D_ADAPTER` with `options` (tests
    /// compare the paths of one adapter this way).
    pub fn with_options(options: DeviceOptions) -> Result<Self, RasterError> {
        let preference = std::env::var(ADAPTER_ENV).ok();
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
        let adapter = choose(adapters, preference.as_deref())?;
        let info = adapter.get_info();
        let mut wanted = wgpu::Features::empty();
        if options.subgroups {
            wanted |= wgpu::Features::SUBGROUP;
        }
        if options.float_atomics {
            wanted |= wgpu::Features::SHADER_FLOAT32_ATOMIC;
        }
        // The adapter's own limits: large scenes need storage buffers beyond the defaults.
        let mut limits = adapter.limits();
        if let Some(cap) = options.binding_limit {
            limits.max_storage_buffer_binding_size =
                limits.max_storage_buffer_binding_size.min(cap);
            limits.max_buffer_size = limits.max_buffer_size.min(cap);
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("pano4d rasteriser"),
            required_features: adapter.features() & wanted,
            required_limits: limits,
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| RasterError::Device(e.to_string()))?;
        // Validation errors are collected by error scopes; never panic on them.
        device.on_uncaptured_error(std::sync::Arc::new(|e: wgpu::Error| {
            eprintln!("pano4d: uncaptured wgpu error: {e}");
        }));
        Ok(Self {
            device,
            queue,
            adapter: AdapterSummary::from(&info),
        })
    }

    /// Whether the backward sums each subgroup's pixels first (`Features::SUBGROUP`).
    pub fn has_subgroups(&self) -> bool {
        self.device.features().contains(wgpu::Features::SUBGROUP)
    }

    /// Whether the backward adds with native f32 atomics (else by compare-exchange).
    pub fn has_float_atomics(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::SHADER_FLOAT32_ATOMIC)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pci_slots_match_across_domain_widths_and_case() {
        assert!(same_pci_slot("0000:3b:00.0", "00000000:3B:00.0"));
        assert!(same_pci_slot("0000:3b:00.0", "3b:00.0"));
        assert!(!same_pci_slot("0000:3b:00.0", "0000:3c:00.0"));
        assert!(!same_pci_slot("0000:3b:00.0", "0001:3b:00.0"));
        assert!(!same_pci_slot("0000:3b:00.0", "0000:3b:00.1"));
        // Adapters without PCI information (lavapipe) report an empty id: never a match.
        assert!(!same_pci_slot("", "0000:3b:00.0"));
        assert!(!same_pci_slot("", ""));
    }

    #[test]
    fn a_pci_preference_without_that_slot_names_what_there_is() {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
        let error = choose(adapters, Some("pci:00ff:ff:1f.7")).err().unwrap();
        let text = error.to_string();
        assert!(
            text.contains("pci:00ff:ff:1f.7") && text.contains("available"),
            "{text}"
        );
    }
}
