//! Finding an adapter, opening its device, and catching what the device reports later.
//!
//! Backends come from the environment (`WGPU_BACKEND`, e.g. `vulkan` or `gl`; default: every
//! backend compiled in), the adapter from [`choose`]: a name asked for with `SOFTBODY_ADAPTER`
//! (`--adapter`), else a discrete GPU before an integrated, virtual or software one
//! (`WGPU_POWER_PREF=low` puts an integrated GPU first). The device gets the adapter's own
//! limits and no optional features.
//!
//! wgpu's default handler for errors outside an error scope panics; [`Gpu::open`] installs one
//! that records the first such error (and a device loss), and every solver on the device turns
//! the record into [`StepError::Device`](softbody_scene::StepError) at its next synchronisation
//! point.

use std::sync::{Arc, Mutex};

use crate::GpuError;

/// The first asynchronous device error (validation outside a scope, device loss), if any.
#[derive(Debug, Clone, Default)]
pub struct ErrorSink(Arc<Mutex<Option<String>>>);

impl ErrorSink {
    fn record(&self, message: String) {
        let mut slot = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if slot.is_none() {
            *slot = Some(message);
        }
    }

    /// The recorded error, if any (it stays recorded).
    pub fn get(&self) -> Option<String> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }
}

/// An open device.
#[derive(Debug)]
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// What the adapter says about itself.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was opened with (the adapter's own).
    pub limits: wgpu::Limits,
    /// What the adapter can do below WebGPU's baseline (e.g. indirect dispatch on old GL).
    pub downlevel: wgpu::DownlevelFlags,
    /// Errors reported outside error scopes.
    pub errors: ErrorSink,
}

/// A backend's name as people write it.
pub fn backend_name(backend: wgpu::Backend) -> &'static str {
    match backend {
        wgpu::Backend::Vulkan => "Vulkan",
        wgpu::Backend::Metal => "Metal",
        wgpu::Backend::Dx12 => "DX12",
        wgpu::Backend::Gl => "GL",
        wgpu::Backend::BrowserWebGpu => "WebGPU",
        wgpu::Backend::Noop => "no-op",
    }
}

/// The names of a set of backends, e.g. "Vulkan, GL".
pub fn backends_list(backends: wgpu::Backends) -> String {
    let all = [
        (wgpu::Backends::VULKAN, wgpu::Backend::Vulkan),
        (wgpu::Backends::METAL, wgpu::Backend::Metal),
        (wgpu::Backends::DX12, wgpu::Backend::Dx12),
        (wgpu::Backends::GL, wgpu::Backend::Gl),
        (wgpu::Backends::BROWSER_WEBGPU, wgpu::Backend::BrowserWebGpu),
        (wgpu::Backends::NOOP, wgpu::Backend::Noop),
    ];
    let names: Vec<&str> = all
        .iter()
        .filter(|(flag, _)| backends.contains(*flag))
        .map(|&(_, b)| backend_name(b))
        .collect();
    if names.is_empty() {
        "none".to_owned()
    } else {
        names.join(", ")
    }
}

/// The environment variable that picks an adapter by (part of) its name, case-insensitive
/// (`softbody --adapter NAME` sets it).
pub const ADAPTER_VARIABLE: &str = "SOFTBODY_ADAPTER";

/// Which of `adapters` to run on: those whose name contains `wanted` (case-insensitive) when
/// it is given, then by kind: a discrete GPU first, then an integrated one (the other way round
/// with `WGPU_POWER_PREF=low`), a virtual one, another, and a software adapter (llvmpipe,
/// lavapipe, WARP) last; between equals, by backend (Vulkan, Metal, DX12, GL) and then the order
/// wgpu lists them in, so that the choice is the same every time.
pub fn choose(
    adapters: &[wgpu::AdapterInfo],
    wanted: Option<&str>,
    preference: Option<wgpu::PowerPreference>,
) -> Result<usize, String> {
    use wgpu::{Backend, DeviceType};
    let kind = |t: DeviceType| match (t, preference) {
        (DeviceType::IntegratedGpu, Some(wgpu::PowerPreference::LowPower)) => 0,
        (DeviceType::DiscreteGpu, _) => 1,
        (DeviceType::IntegratedGpu, _) => 2,
        (DeviceType::VirtualGpu, _) => 3,
        (DeviceType::Other, _) => 4,
        (DeviceType::Cpu, _) => 5,
    };
    let backend = |b: Backend| match b {
        Backend::Vulkan => 0,
        Backend::Metal => 1,
        Backend::Dx12 => 2,
        Backend::Gl => 3,
        _ => 4,
    };
    let wanted_lower = wanted.map(str::to_lowercase);
    adapters
        .iter()
        .enumerate()
        .filter(|(_, a)| {
            wanted_lower
                .as_ref()
                .is_none_or(|w| a.name.to_lowercase().contains(w.as_str()))
        })
        .min_by_key(|&(k, a)| (kind(a.device_type), backend(a.backend), k))
        .map(|(k, _)| k)
        .ok_or_else(|| match wanted {
            Some(w) => format!(
                "no adapter's name contains `{w}` ({ADAPTER_VARIABLE}, --adapter); found: {}",
                if adapters.is_empty() {
                    "none".to_owned()
                } else {
                    adapters.iter().map(describe).collect::<Vec<_>>().join("; ")
                }
            ),
            None => "wgpu found no adapter".to_owned(),
        })
}

/// The instance's settings from the environment (`WGPU_BACKEND`, `WGPU_VALIDATION_INDIRECT_CALL`,
/// …), with wgpu's validation of indirect dispatches off by default where no D3D12 adapter can be
/// chosen.
///
/// That validation runs a compute pass of wgpu's own before every indirect dispatch, in release
/// builds too, and implicit Euler's CG (the only indirect dispatches here) issues four per
/// iteration. It is safe without: the arguments are only ever zero or the particle and spring
/// grids the host wrote into `CgScalars` when it built the solver (`cg.wgsl`, `set_slot`), grids it
/// also dispatches directly, which wgpu validates against `max_compute_workgroups_per_dimension`.
/// D3D12 keeps it: without it `@builtin(num_workgroups)`, from which every kernel computes its
/// thread index, reads 0 in an indirect dispatch there.
fn instance_descriptor() -> wgpu::InstanceDescriptor {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    if !desc.backends.with_env().contains(wgpu::Backends::DX12) {
        desc.flags
            .remove(wgpu::InstanceFlags::VALIDATION_INDIRECT_CALL);
    }
    desc.with_env()
}

impl Gpu {
    /// Finds an adapter that runs compute shaders ([`choose`]) and opens its device: a context
    /// that many solvers may share ([`GpuSolver::on`](crate::GpuSolver::on)).
    pub fn open() -> Result<Arc<Gpu>, GpuError> {
        let desc = instance_descriptor();
        let tried = desc.backends & wgpu::Instance::enabled_backend_features();
        let tried_names = backends_list(tried);
        if tried.is_empty() {
            return Err(GpuError::NoAdapter {
                tried: tried_names,
                detail: format!(
                    "WGPU_BACKEND selects no backend this build has (it has {})",
                    backends_list(wgpu::Instance::enabled_backend_features())
                ),
            });
        }
        let instance = wgpu::Instance::new(desc);
        let adapters = pollster::block_on(instance.enumerate_adapters(tried));
        let infos: Vec<wgpu::AdapterInfo> = adapters.iter().map(|a| a.get_info()).collect();
        let wanted = std::env::var(ADAPTER_VARIABLE)
            .ok()
            .filter(|w| !w.is_empty());
        let preference = wgpu::PowerPreference::from_env();
        let adapter = match choose(&infos, wanted.as_deref(), preference) {
            Ok(k) => adapters.into_iter().nth(k).expect("an index of the list"),
            Err(detail) => {
                return Err(GpuError::NoAdapter {
                    tried: tried_names,
                    detail,
                });
            }
        };
        let info = adapter.get_info();
        let name = describe(&info);
        let downlevel = adapter.get_downlevel_capabilities().flags;
        if !downlevel.contains(wgpu::DownlevelFlags::COMPUTE_SHADERS) {
            return Err(GpuError::NoAdapter {
                tried: tried_names,
                detail: format!("the adapter found, {name}, cannot run compute shaders"),
            });
        }
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("softbody"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::default(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::Device {
            adapter: name.clone(),
            message: format!("cannot open the device: {e}"),
        })?;
        let errors = ErrorSink::default();
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| sink.record(e.to_string())));
        let sink = errors.clone();
        device.set_device_lost_callback(move |reason, message| {
            // Dropping the solver destroys the device on purpose.
            if reason != wgpu::DeviceLostReason::Destroyed {
                sink.record(format!("the device was lost: {message}"));
            }
        });
        Ok(Arc::new(Gpu {
            device,
            queue,
            info,
            limits,
            downlevel,
            errors,
        }))
    }

    /// The adapter, e.g. "llvmpipe (LLVM 15.0.6, 256 bits) via Vulkan".
    pub fn name(&self) -> String {
        describe(&self.info)
    }
}

fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} via {}", info.name, backend_name(info.backend))
}

#[cfg(test)]
mod tests {
    use super::choose;
    use wgpu::{AdapterInfo, Backend, DeviceType, PowerPreference};

    fn adapter(name: &str, device_type: DeviceType, backend: Backend) -> AdapterInfo {
        AdapterInfo {
            name: name.to_owned(),
            vendor: 0,
            device: 0,
            device_type,
            device_pci_bus_id: String::new(),
            driver: String::new(),
            driver_info: String::new(),
            backend,
            subgroup_min_size: 4,
            subgroup_max_size: 128,
            transient_saves_memory: None,
            limit_bucket: None,
        }
    }

    /// A machine with a software adapter listed first (as Mesa lists llvmpipe), an integrated
    /// and a discrete GPU, the discrete one on two backends.
    #[test]
    fn a_discrete_gpu_is_chosen_before_integrated_and_software_ones() {
        let adapters = [
            adapter(
                "llvmpipe (LLVM 15.0.6, 256 bits)",
                DeviceType::Cpu,
                Backend::Vulkan,
            ),
            adapter(
                "Intel(R) UHD Graphics 770",
                DeviceType::IntegratedGpu,
                Backend::Vulkan,
            ),
            adapter(
                "NVIDIA H100 80GB HBM3",
                DeviceType::DiscreteGpu,
                Backend::Gl,
            ),
            adapter(
                "NVIDIA H100 80GB HBM3",
                DeviceType::DiscreteGpu,
                Backend::Vulkan,
            ),
        ];
        assert_eq!(choose(&adapters, None, None), Ok(3));
        assert_eq!(
            choose(&adapters, None, Some(PowerPreference::LowPower)),
            Ok(1)
        );
        assert_eq!(choose(&adapters, Some("LLVMPIPE"), None), Ok(0));
        assert_eq!(choose(&adapters[..1], None, None), Ok(0));
        let e = choose(&adapters, Some("radeon"), None).unwrap_err();
        assert!(
            e.starts_with(
                "no adapter's name contains `radeon` (SOFTBODY_ADAPTER, --adapter); found: llvmpipe"
            ),
            "{e}"
        );
        assert_eq!(
            choose(&[], None, None),
            Err("wgpu found no adapter".to_owned())
        );
    }
}
