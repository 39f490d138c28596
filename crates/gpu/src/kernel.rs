//! Kernels by reflection: the one helper every stage uses to make its pipelines, bind its
//! buffers and dispatch.
//!
//! A stage names an entry point of its module ([`Stage`]); [`Kernel::new`] reads from the
//! composed WGSL, with naga, which `@group(0)` bindings that entry point uses (directly or
//! through the functions it calls), their names, numbers and access (uniform, read-only or
//! read-write storage), and whether it reads the terrain at `@group(1)`. The kernel's bind group
//! layout holds exactly those bindings, so the host never writes a binding number and cannot
//! disagree with the shader: it binds buffers by the names the shader gives them
//! ([`Resources`]), and a name the kernel needs but the host does not provide is an error when
//! the solver is built, not a wrong number at run time.
//!
//! A [`Call`] is a kernel with its bind groups: what a stage keeps and dispatches each step.
//! Every dispatch is counted in the solver's [`Traffic`], with the bytes the design makes it
//! move.

use std::borrow::Cow;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use naga::valid::{Capabilities, ModuleInfo, ValidationFlags, Validator};

use crate::WORKGROUP_SIZE;
use crate::chunks::Chunking;
use crate::compose::Composed;
use crate::grid::Grid;
use crate::shaders::{DYNAMIC_UNIFORMS, Stage};

/// A stage's composed module as naga reads it: the IR and its validation info, from which
/// each entry point's interface is reflected.
pub(crate) struct Parsed {
    stage: Stage,
    naga: naga::Module,
    info: ModuleInfo,
}

impl Parsed {
    /// Parses and validates `module`, the composed module of `stage`. A failure is a defect of
    /// the shaders: its message names the line of the file at fault.
    pub fn new(stage: Stage, module: &Composed) -> Result<Parsed, String> {
        let source = &module.source;
        let at = |location: Option<naga::SourceLocation>, message: String| match location
            .and_then(|l| module.locate(l.line_number as usize))
        {
            Some((file, line)) => format!("{file}:{line}: {message}"),
            None => message,
        };
        let naga = naga::front::wgsl::parse_str(source).map_err(|e| {
            at(
                e.location(source),
                e.emit_to_string_with_path(source, stage.file()),
            )
        })?;
        let info = Validator::new(ValidationFlags::all(), Capabilities::default())
            .validate(&naga)
            .map_err(|e| at(e.location(source), e.emit_to_string(source)))?;
        Ok(Parsed { stage, naga, info })
    }

    /// The entry points' names.
    #[cfg(test)]
    pub fn entry_points(&self) -> impl Iterator<Item = &str> {
        self.naga.entry_points.iter().map(|e| e.name.as_str())
    }
}

/// A stage's module: parsed (for reflection) and compiled (shared by its pipelines).
pub(crate) struct Module {
    parsed: Parsed,
    shader: wgpu::ShaderModule,
}

impl Module {
    /// Parses, validates and compiles `module`, the composed module of `stage`.
    pub fn new(device: &wgpu::Device, stage: Stage, module: Composed) -> Result<Module, String> {
        let parsed = Parsed::new(stage, &module)?;
        let shader = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(stage.file()),
            source: wgpu::ShaderSource::Wgsl(Cow::Owned(module.source)),
        });
        Ok(Module { parsed, shader })
    }

    /// The `@group(0)` bindings `entry` uses and whether it reads the terrain ([`reflect`]).
    pub fn reflect(&self, entry: &str) -> Result<(Vec<Binding>, bool), String> {
        reflect(&self.parsed, entry)
    }
}

/// Storage buffers a kernel with `bindings` binds, the terrain's (`terrain_buffers` of them)
/// included if it reads the terrain.
pub(crate) fn storage_buffers(bindings: &[Binding], terrain: bool, terrain_buffers: u32) -> u32 {
    let own = bindings
        .iter()
        .filter(|b| b.access != Access::Uniform)
        .count() as u32;
    own + if terrain { terrain_buffers } else { 0 }
}

/// The bind group layout entries of the terrain's `@group(1)` declarations in `terrain.wgsl`
/// (read from the terrain probe's module: every terrain-reading module imports the same
/// piece, so this is one layout for all of them).
pub(crate) fn terrain_entries() -> Result<Vec<(String, wgpu::BindGroupLayoutEntry)>, String> {
    let module = Parsed::new(
        Stage::TerrainProbe,
        &Stage::TerrainProbe.compose(Chunking::ONE)?,
    )?
    .naga;
    Ok(module
        .global_variables
        .iter()
        .filter_map(|(_, var)| {
            let binding = var.binding.as_ref().filter(|b| b.group == 1)?;
            let entry = layout_entry(binding.binding, access_of(var.space)?, false);
            Some((var.name.clone().unwrap_or_default(), entry))
        })
        .collect())
}

/// How a kernel uses a buffer binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// `var<uniform>`.
    Uniform,
    /// `var<storage, read>`.
    Read,
    /// `var<storage, read_write>`.
    ReadWrite,
}

fn access_of(space: naga::AddressSpace) -> Option<Access> {
    match space {
        naga::AddressSpace::Uniform => Some(Access::Uniform),
        naga::AddressSpace::Storage { access } if access.contains(naga::StorageAccess::STORE) => {
            Some(Access::ReadWrite)
        }
        naga::AddressSpace::Storage { .. } => Some(Access::Read),
        _ => None,
    }
}

fn layout_entry(binding: u32, access: Access, dynamic: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: match access {
                Access::Uniform => wgpu::BufferBindingType::Uniform,
                Access::Read => wgpu::BufferBindingType::Storage { read_only: true },
                Access::ReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
            },
            has_dynamic_offset: dynamic,
            min_binding_size: None,
        },
        count: None,
    }
}

/// One `@group(0)` binding an entry point uses, as the shader declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Binding {
    /// The variable's name in the WGSL.
    pub name: String,
    /// Its `@binding` number.
    pub binding: u32,
    /// Its address space and access.
    pub access: Access,
    /// Bound at a dynamic offset ([`DYNAMIC_UNIFORMS`]).
    pub dynamic: bool,
}

/// The `@group(0)` bindings entry point `entry` of `module` uses, in binding order, and whether
/// it uses the terrain (`@group(1)`).
pub(crate) fn reflect(module: &Parsed, entry: &str) -> Result<(Vec<Binding>, bool), String> {
    let file = module.stage.file();
    let index = module
        .naga
        .entry_points
        .iter()
        .position(|e| e.name == entry)
        .ok_or_else(|| format!("{file} has no entry point {entry}"))?;
    let workgroup = module.naga.entry_points[index].workgroup_size;
    if workgroup != [WORKGROUP_SIZE as u32, 1, 1] {
        return Err(format!(
            "{file}: {entry} has workgroup size {workgroup:?}; the host dispatches [{WORKGROUP_SIZE}, 1, 1]"
        ));
    }
    let uses = module.info.get_entry_point(index);
    let mut bindings = Vec::new();
    let mut terrain = false;
    for (handle, var) in module.naga.global_variables.iter() {
        let Some(binding) = &var.binding else {
            continue;
        };
        if uses[handle].is_empty() {
            continue;
        }
        let name = var.name.clone().unwrap_or_default();
        match binding.group {
            0 => bindings.push(Binding {
                access: access_of(var.space)
                    .ok_or_else(|| format!("{file}: {name} is not a buffer"))?,
                dynamic: DYNAMIC_UNIFORMS.contains(&name.as_str()),
                binding: binding.binding,
                name,
            }),
            1 => terrain = true,
            group => return Err(format!("{file}: {name} is in group {group}")),
        }
    }
    bindings.sort_by_key(|b| b.binding);
    Ok((bindings, terrain))
}

/// One entry point's pipeline and the interface read from its WGSL.
pub(crate) struct Kernel {
    entry: &'static str,
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    bindings: Vec<Binding>,
    terrain: bool,
}

impl Kernel {
    /// The pipeline of `entry` in `module`, with a layout of the bindings it uses (and the
    /// terrain's group, laid out as `terrain_layout`, if it reads the terrain).
    pub fn new(
        device: &wgpu::Device,
        module: &Module,
        entry: &'static str,
        terrain_layout: &wgpu::BindGroupLayout,
    ) -> Result<Kernel, String> {
        let (bindings, terrain) = reflect(&module.parsed, entry)?;
        let entries: Vec<_> = bindings
            .iter()
            .map(|b| layout_entry(b.binding, b.access, b.dynamic))
            .collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(entry),
            entries: &entries,
        });
        let mut layouts = vec![Some(&layout)];
        if terrain {
            layouts.push(Some(terrain_layout));
        }
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some(entry),
            bind_group_layouts: &layouts,
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: Some(&pipeline_layout),
            module: &module.shader,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        Ok(Kernel {
            entry,
            pipeline,
            layout,
            bindings,
            terrain,
        })
    }

    /// The bindings it uses.
    pub fn bindings(&self) -> &[Binding] {
        &self.bindings
    }

    /// Whether it reads the terrain.
    pub fn terrain(&self) -> bool {
        self.terrain
    }

    /// A call of the kernel with the buffers of `resources` bound by name (and the terrain
    /// group if it reads the terrain). Names it does not use are ignored; one it uses and
    /// `resources` lacks is an error naming it.
    pub fn call(
        &self,
        device: &wgpu::Device,
        resources: &Resources<'_>,
        terrain: &wgpu::BindGroup,
        traffic: &Arc<Traffic>,
    ) -> Result<Call, String> {
        let entries = self
            .bindings
            .iter()
            .map(|b| {
                let resource = resources.get(&b.name).ok_or_else(|| {
                    format!(
                        "{} binds `{}` (binding {}), which the host does not provide",
                        self.entry, b.name, b.binding
                    )
                })?;
                Ok(wgpu::BindGroupEntry {
                    binding: b.binding,
                    resource: resource.clone(),
                })
            })
            .collect::<Result<Vec<_>, String>>()?;
        let bytes = self
            .bindings
            .iter()
            .zip(&entries)
            .map(|(b, e)| {
                let size = match &e.resource {
                    wgpu::BindingResource::Buffer(binding) => binding
                        .size
                        .map_or(binding.buffer.size() - binding.offset, |s| s.get()),
                    _ => 0,
                };
                match b.access {
                    Access::Uniform => 0,
                    Access::Read => size,
                    Access::ReadWrite => 2 * size,
                }
            })
            .sum();
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.entry),
            layout: &self.layout,
            entries: &entries,
        });
        Ok(Call {
            pipeline: self.pipeline.clone(),
            group,
            terrain: self.terrain.then(|| terrain.clone()),
            bytes,
            traffic: Arc::clone(traffic),
        })
    }
}

/// Buffers (and buffer slices) by the names the shaders give their bindings. A later entry of
/// a name replaces an earlier one, so a stage can start from the solver's table and rebind
/// `x` and `v` to a stage state.
#[derive(Clone, Default)]
pub(crate) struct Resources<'a> {
    entries: Vec<(Cow<'static, str>, wgpu::BindingResource<'a>)>,
}

impl<'a> Resources<'a> {
    /// `name` bound to all of `buffer`.
    pub fn buffer(self, name: impl Into<Cow<'static, str>>, buffer: &'a wgpu::Buffer) -> Self {
        self.resource(name, buffer.as_entire_binding())
    }

    /// `name` bound to `resource`.
    pub fn resource(
        mut self,
        name: impl Into<Cow<'static, str>>,
        resource: wgpu::BindingResource<'a>,
    ) -> Self {
        self.entries.push((name.into(), resource));
        self
    }

    /// A chunked per-spring array as the gathers read it: chunk 0 as `first`, chunk c ≥ 1 as
    /// `{rest}_{c}` (the names [`crate::shaders`] generates).
    pub fn chunks(mut self, first: &'static str, rest: &str, buffers: &'a [wgpu::Buffer]) -> Self {
        for (c, buffer) in buffers.iter().enumerate() {
            let name: Cow<'static, str> = if c == 0 {
                first.into()
            } else {
                format!("{rest}_{c}").into()
            };
            self = self.buffer(name, buffer);
        }
        self
    }

    /// The resource bound to `name` last.
    pub fn get(&self, name: &str) -> Option<&wgpu::BindingResource<'a>> {
        self.entries
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|(_, r)| r)
    }
}

/// What a solver's dispatches add up to: how many were encoded, and the bytes of device memory
/// their bindings make them move.
///
/// The bytes are the design's compulsory traffic, not a measurement: each dispatch reads every
/// storage buffer it binds once and writes every read-write one once (a read-write binding
/// counts twice its size). Gathers that read a value more than once are assumed to hit in
/// cache, uniforms and the terrain's tables (a few kilobytes) are left out, and an indirect
/// dispatch counts in full even when its grid is empty; a buffer copy counts what it reads and
/// writes, but is no dispatch. It is the figure to compare designs by (per-spring buffers
/// against a fused gather, say), on any adapter, a software one included.
#[derive(Debug, Default)]
pub(crate) struct Traffic {
    dispatches: AtomicU64,
    bytes: AtomicU64,
}

impl Traffic {
    /// Counts a buffer copy that moves `bytes` (read and written).
    pub fn copied(&self, bytes: u64) {
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    /// (dispatches, bytes) so far.
    pub fn totals(&self) -> (u64, u64) {
        (
            self.dispatches.load(Ordering::Relaxed),
            self.bytes.load(Ordering::Relaxed),
        )
    }
}

/// A kernel with its bind groups, ready to dispatch.
#[derive(Debug, Clone)]
pub(crate) struct Call {
    pipeline: wgpu::ComputePipeline,
    group: wgpu::BindGroup,
    terrain: Option<wgpu::BindGroup>,
    /// Bytes one dispatch moves ([`Traffic`]).
    bytes: u64,
    traffic: Arc<Traffic>,
}

impl Call {
    fn bind(&self, pass: &mut wgpu::ComputePass<'_>, offsets: &[u32]) {
        self.traffic.dispatches.fetch_add(1, Ordering::Relaxed);
        self.traffic.bytes.fetch_add(self.bytes, Ordering::Relaxed);
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.group, offsets);
        if let Some(terrain) = &self.terrain {
            pass.set_bind_group(1, terrain, &[]);
        }
    }

    /// Dispatches `grid` (nothing for an empty grid).
    pub fn run(&self, pass: &mut wgpu::ComputePass<'_>, grid: Grid) {
        self.run_at(pass, grid, &[]);
    }

    /// Dispatches `grid` with the dynamic offsets of its dynamic uniforms.
    pub fn run_at(&self, pass: &mut wgpu::ComputePass<'_>, grid: Grid, offsets: &[u32]) {
        if grid.groups() == 0 {
            return;
        }
        self.bind(pass, offsets);
        pass.dispatch_workgroups(grid.x, grid.y, 1);
    }

    /// Dispatches the grid written at byte `offset` of `arguments`.
    pub fn run_indirect(
        &self,
        pass: &mut wgpu::ComputePass<'_>,
        arguments: &wgpu::Buffer,
        offset: u64,
    ) {
        self.bind(pass, &[]);
        pass.dispatch_workgroups_indirect(arguments, offset);
    }
}
