//! Finding an adapter, opening its device, and catching what the device reports later.
//!
//! Backends come from the environment (`WGPU_BACKEND`, e.g. `vulkan` or `gl`; default: every
//! backend compiled in), the power preference from `WGPU_POWER_PREF` (default: high
//! performance). The device gets the adapter's own limits and no optional features.
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

impl Gpu {
    /// Finds an adapter that runs compute shaders and opens its device: a context that many
    /// solvers may share ([`GpuSolver::on`](crate::GpuSolver::on)).
    pub fn open() -> Result<Arc<Gpu>, GpuError> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
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
        let adapter =
            pollster::block_on(
                instance.request_adapter(&wgpu::RequestAdapterOptions {
                    power_preference: wgpu::PowerPreference::from_env()
                        .unwrap_or(wgpu::PowerPreference::HighPerformance),
                    force_fallback_adapter: false,
                    compatible_surface: None,
                    apply_limit_buckets: false,
                }),
            )
            .map_err(|e| GpuError::NoAdapter {
                tried: tried_names.clone(),
                detail: e.to_string(),
            })?;
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
