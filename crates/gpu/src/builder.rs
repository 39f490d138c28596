//! [`Builder`]: what every stage's buffers and kernels are made with — the device, the compiled
//! modules, the terrain's bind group, and a tally of the device memory allocated.

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::sync::Arc;

use wgpu::util::DeviceExt;

use crate::GpuError;
use crate::chunks::Chunking;
use crate::device::Gpu;
use crate::kernel::{self, Binding, Call, Kernel, Module, Parsed, Resources, Traffic};
use crate::shaders::Stage;
use crate::terrain::{SurfaceGpu, TerrainBuffers};

/// Makes buffers and kernel calls for one solver.
pub(crate) struct Builder {
    gpu: Arc<Gpu>,
    /// The limits the solver runs under (the device's, or lower for tests).
    limits: wgpu::Limits,
    chunking: Chunking,
    /// Each stage's module, compiled when a kernel of it is first asked for.
    modules: RefCell<HashMap<Stage, Module>>,
    terrain_layout: wgpu::BindGroupLayout,
    terrain: wgpu::BindGroup,
    /// Storage buffers in the terrain's group.
    terrain_buffers: u32,
    /// Bytes of device memory allocated through the builder.
    bytes: Cell<u64>,
    /// What the calls made here dispatch.
    traffic: Arc<Traffic>,
}

/// Usage of the solver's storage buffers: bound, written by the host, read back.
const STORAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_DST)
    .union(wgpu::BufferUsages::COPY_SRC);

impl Builder {
    /// A builder for per-spring arrays split as `chunking`, with the terrain `packed` uploaded.
    pub fn new(
        gpu: Arc<Gpu>,
        limits: wgpu::Limits,
        chunking: Chunking,
        packed: &TerrainBuffers,
    ) -> Result<Builder, GpuError> {
        let entries = kernel::terrain_entries().map_err(|e| internal(&gpu.name(), e))?;
        let device = &gpu.device;
        let terrain_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("terrain"),
            entries: &entries.iter().map(|(_, e)| *e).collect::<Vec<_>>(),
        });
        let surfaces = at_least(
            bytemuck::cast_slice(packed.surfaces_for_binding()),
            std::mem::size_of::<SurfaceGpu>(),
        );
        let data = at_least(bytemuck::cast_slice(&packed.data), 4);
        let buffer = |label, contents| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: STORAGE,
            })
        };
        let (surfaces_buffer, data_buffer) =
            (buffer("surfaces", &surfaces), buffer("terrain_data", &data));
        let resources = Resources::default()
            .buffer("surfaces", &surfaces_buffer)
            .buffer("terrain_data", &data_buffer);
        let bound = entries
            .iter()
            .map(|(name, entry)| {
                let resource = resources.get(name).ok_or_else(|| {
                    internal(
                        &gpu.name(),
                        format!("terrain.wgsl declares an unknown binding `{name}`"),
                    )
                })?;
                Ok(wgpu::BindGroupEntry {
                    binding: entry.binding,
                    resource: resource.clone(),
                })
            })
            .collect::<Result<Vec<_>, GpuError>>()?;
        let terrain = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("terrain"),
            layout: &terrain_layout,
            entries: &bound,
        });
        Ok(Builder {
            bytes: Cell::new((surfaces.len() + data.len()) as u64),
            traffic: Arc::default(),
            terrain_buffers: entries.len() as u32,
            gpu,
            limits,
            chunking,
            modules: RefCell::new(HashMap::new()),
            terrain_layout,
            terrain,
        })
    }

    /// The context the solver runs on.
    pub fn gpu(&self) -> &Arc<Gpu> {
        &self.gpu
    }

    /// Bytes of device memory allocated through the builder.
    pub fn bytes(&self) -> u64 {
        self.bytes.get()
    }

    /// A buffer of `descriptor`, counted.
    pub fn buffer(&self, descriptor: &wgpu::BufferDescriptor<'_>) -> wgpu::Buffer {
        self.bytes.set(self.bytes.get() + descriptor.size);
        self.gpu.device.create_buffer(descriptor)
    }

    /// A zeroed storage buffer of `count` elements of `element` bytes, at least one (wgpu
    /// refuses to bind an empty buffer, and a shader's array needs a whole element).
    pub fn storage(&self, label: &str, count: u64, element: u64) -> wgpu::Buffer {
        self.buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: count.max(1) * element,
            usage: STORAGE,
            mapped_at_creation: false,
        })
    }

    /// A storage buffer holding `contents` (one zeroed `element` if it is empty).
    pub fn storage_init(&self, label: &str, contents: &[u8], element: usize) -> wgpu::Buffer {
        self.init(label, &at_least(contents, element), STORAGE)
    }

    /// A buffer holding `contents`, of `usage`.
    pub fn init(&self, label: &str, contents: &[u8], usage: wgpu::BufferUsages) -> wgpu::Buffer {
        self.bytes.set(self.bytes.get() + contents.len() as u64);
        self.gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
    }

    /// `stage`'s module, compiled once.
    fn module(&self, stage: Stage) -> Result<std::cell::Ref<'_, Module>, GpuError> {
        if !self.modules.borrow().contains_key(&stage) {
            let module = stage
                .compose(self.chunking)
                .and_then(|composed| Module::new(&self.gpu.device, stage, composed))
                .map_err(|e| internal(&self.gpu.name(), e))?;
            self.modules.borrow_mut().insert(stage, module);
        }
        Ok(std::cell::Ref::map(self.modules.borrow(), |m| &m[&stage]))
    }

    /// Whether the adapter can bind what `entry` of `stage` binds: [`GpuError::Limit`] if not,
    /// found by reflection, before anything is allocated for it.
    pub fn fits(&self, stage: Stage, entry: &'static str) -> Result<(), GpuError> {
        let (bindings, terrain) = self
            .module(stage)?
            .reflect(entry)
            .map_err(|e| internal(&self.gpu.name(), e))?;
        self.check_bindings(stage, entry, &bindings, terrain)
    }

    /// The kernel of `entry` in `stage`'s module (compiled once per stage).
    pub fn kernel(&self, stage: Stage, entry: &'static str) -> Result<Kernel, GpuError> {
        let kernel = Kernel::new(
            &self.gpu.device,
            &*self.module(stage)?,
            entry,
            &self.terrain_layout,
        )
        .map_err(|e| internal(&self.gpu.name(), e))?;
        self.check_bindings(stage, entry, kernel.bindings(), kernel.terrain())?;
        Ok(kernel)
    }

    /// [`check_bindings`] under the builder's limits.
    fn check_bindings(
        &self,
        stage: Stage,
        entry: &'static str,
        bindings: &[Binding],
        terrain: bool,
    ) -> Result<(), GpuError> {
        let storage = kernel::storage_buffers(bindings, terrain, self.terrain_buffers);
        check_bindings(
            &self.limits,
            &self.gpu.name(),
            stage,
            entry,
            bindings,
            storage,
        )
    }

    /// What the calls made here have dispatched.
    pub fn traffic(&self) -> &Arc<Traffic> {
        &self.traffic
    }

    /// A call of `entry` in `stage` with `resources` bound by name.
    pub fn call(
        &self,
        stage: Stage,
        entry: &'static str,
        resources: &Resources<'_>,
    ) -> Result<Call, GpuError> {
        let kernel = self.kernel(stage, entry)?;
        kernel
            .call(&self.gpu.device, resources, &self.terrain, &self.traffic)
            .map_err(|e| internal(&self.gpu.name(), e))
    }

    /// Calls of `entry` in `stage`, one per resource table of `tables` (a per-spring kernel's
    /// chunks), sharing one pipeline.
    pub fn calls<'r>(
        &self,
        stage: Stage,
        entry: &'static str,
        tables: impl IntoIterator<Item = Resources<'r>>,
    ) -> Result<Vec<Call>, GpuError> {
        let kernel = self.kernel(stage, entry)?;
        tables
            .into_iter()
            .map(|resources| {
                kernel
                    .call(&self.gpu.device, &resources, &self.terrain, &self.traffic)
                    .map_err(|e| internal(&self.gpu.name(), e))
            })
            .collect()
    }
}

/// A fit check ([`fits`], [`Builder::fits`]) as an answer: `false` for [`GpuError::Limit`],
/// any other error passed on.
pub(crate) fn answer(check: Result<(), GpuError>) -> Result<bool, GpuError> {
    match check {
        Ok(()) => Ok(true),
        Err(GpuError::Limit { .. }) => Ok(false),
        Err(e) => Err(e),
    }
}

/// Whether an adapter with `limits` can bind what each of `entries` of `stage` binds (its
/// per-spring arrays split as `chunking`): [`GpuError::Limit`] naming the first that cannot.
/// [`Builder::fits`] without a builder: found by reflection on the composed module alone, before
/// anything is allocated or compiled (a run's route is decided with it).
pub(crate) fn fits(
    limits: &wgpu::Limits,
    adapter: &str,
    stage: Stage,
    entries: &[&'static str],
    chunking: Chunking,
) -> Result<(), GpuError> {
    let parsed = stage
        .compose(chunking)
        .and_then(|composed| Parsed::new(stage, &composed))
        .map_err(|e| internal(adapter, e))?;
    let terrain_buffers = kernel::terrain_entries()
        .map_err(|e| internal(adapter, e))?
        .len() as u32;
    for &entry in entries {
        let (bindings, terrain) =
            kernel::reflect(&parsed, entry).map_err(|e| internal(adapter, e))?;
        let storage = kernel::storage_buffers(&bindings, terrain, terrain_buffers);
        check_bindings(limits, adapter, stage, entry, &bindings, storage)?;
    }
    Ok(())
}

/// [`GpuError::Limit`] if an adapter with `limits` cannot bind `bindings` (`storage` storage
/// buffers with the terrain's) for `entry` of `stage`.
fn check_bindings(
    limits: &wgpu::Limits,
    adapter: &str,
    stage: Stage,
    entry: &'static str,
    bindings: &[Binding],
    storage: u32,
) -> Result<(), GpuError> {
    let allowed = limits.max_storage_buffers_per_shader_stage;
    if storage > allowed {
        return Err(GpuError::Limit {
            adapter: adapter.to_owned(),
            limit: "max_storage_buffers_per_shader_stage",
            what: format!("the kernel {entry} ({})", stage.file()),
            needed: format!("{storage} storage buffers"),
            available: format!("{allowed}"),
        });
    }
    if let Some(b) = bindings.last()
        && b.binding >= limits.max_bindings_per_bind_group
    {
        return Err(GpuError::Limit {
            adapter: adapter.to_owned(),
            limit: "max_bindings_per_bind_group",
            what: format!("the kernel {entry} ({})", stage.file()),
            needed: format!("binding numbers up to {}", b.binding),
            available: format!("{}", limits.max_bindings_per_bind_group),
        });
    }
    Ok(())
}

/// `bytes`, or one zeroed element of `element` bytes if empty: wgpu refuses to bind an empty
/// buffer.
fn at_least(bytes: &[u8], element: usize) -> Vec<u8> {
    if bytes.is_empty() {
        vec![0; element]
    } else {
        bytes.to_vec()
    }
}

/// A defect of the shaders or of the host's wiring, reported rather than panicking.
fn internal(adapter: &str, message: String) -> GpuError {
    GpuError::Device {
        adapter: adapter.to_owned(),
        message: format!("internal error in the GPU solver's kernels: {message}"),
    }
}
