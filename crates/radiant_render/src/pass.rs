//! One way to build a pass: a bind-group layout declared once ([`BindLayout`]), from which both
//! the layout and every bind group are made, and [`SimplePass`], kajiya's
//! `SimpleRenderPass` shape: `SimplePass::new(graph, name, &layout).read(a).buffer(&u).draw(..)`
//! declares what the pass reads and writes and binds exactly that.
//!
//! ```no_run
//! # use std::sync::Arc;
//! # use radiant_render::graph::{RenderGraph, TextureDesc};
//! # use radiant_render::pass::{FullscreenEffect, Slot};
//! # fn f(device: &wgpu::Device, source: String) -> Result<(), radiant_render::RenderError> {
//! let float = wgpu::TextureSampleType::Float { filterable: false };
//! let effect = Arc::new(FullscreenEffect::new(
//!     device,
//!     "invert",
//!     source,
//!     &[Slot::Texture(float), Slot::Uniform],
//! ));
//! let mut graph = RenderGraph::new();
//! let desc = TextureDesc::new(64, 64, wgpu::TextureFormat::Rgba8Unorm);
//! let (input, output) = (graph.import("in", desc), graph.import("out", desc));
//! effect
//!     .pass(&mut graph, "invert_pass")
//!     .read(input)
//!     .uniform(&[0u8; 16])
//!     .draw("invert_fs", output)?;
//! # Ok(()) }
//! ```

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use wgpu::util::DeviceExt as _;

use crate::RenderError;
use crate::graph::{
    GraphError, PassBuilder, PassContext, Read, Ref, RenderGraph, TextureHandle, Write,
};
use crate::util::fullscreen_pipeline;

/// What one binding of a bind group holds. Slot `i` of a [`BindLayout`] is `@binding(i)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Slot {
    /// A sampled 2D texture: a graph texture the pass reads, or a view from outside the graph.
    Texture(wgpu::TextureSampleType),
    /// A 2D array texture from outside the graph.
    TextureArray(wgpu::TextureSampleType),
    /// A graph texture a compute pass writes as write-only storage.
    StorageTexture(wgpu::TextureFormat),
    /// A uniform buffer.
    Uniform,
    /// A read-only storage buffer.
    Storage,
    /// A sampler.
    Sampler(wgpu::SamplerBindingType),
    /// No binding at this index (the shader declares it for another entry point).
    Unused,
}

impl Slot {
    fn name(self) -> &'static str {
        match self {
            Slot::Texture(_) | Slot::TextureArray(_) => "a texture",
            Slot::StorageTexture(_) => "a storage texture",
            Slot::Uniform | Slot::Storage => "a buffer",
            Slot::Sampler(_) => "a sampler",
            Slot::Unused => "nothing",
        }
    }

    fn layout_entry(
        self,
        binding: u32,
        stages: wgpu::ShaderStages,
    ) -> Option<wgpu::BindGroupLayoutEntry> {
        let texture = |sample_type, view_dimension| wgpu::BindingType::Texture {
            sample_type,
            view_dimension,
            multisampled: false,
        };
        let buffer = |ty| wgpu::BindingType::Buffer {
            ty,
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let ty = match self {
            Slot::Texture(s) => texture(s, wgpu::TextureViewDimension::D2),
            Slot::TextureArray(s) => texture(s, wgpu::TextureViewDimension::D2Array),
            Slot::StorageTexture(format) => wgpu::BindingType::StorageTexture {
                access: wgpu::StorageTextureAccess::WriteOnly,
                format,
                view_dimension: wgpu::TextureViewDimension::D2,
            },
            Slot::Uniform => buffer(wgpu::BufferBindingType::Uniform),
            Slot::Storage => buffer(wgpu::BufferBindingType::Storage { read_only: true }),
            Slot::Sampler(s) => wgpu::BindingType::Sampler(s),
            Slot::Unused => return None,
        };
        Some(wgpu::BindGroupLayoutEntry {
            binding,
            visibility: stages,
            ty,
            count: None,
        })
    }
}

/// What a pass puts in one slot.
#[derive(Clone, Debug)]
pub enum Bind {
    /// A graph texture the pass reads (declared as a read).
    Read(TextureHandle),
    /// A graph texture a compute pass writes (declared as a write).
    Write(TextureHandle),
    /// A texture view from outside the graph (a light map, a material texture).
    View(wgpu::TextureView),
    /// A buffer.
    Buffer(wgpu::Buffer),
    /// A sampler.
    Sampler(wgpu::Sampler),
}

impl Bind {
    fn fits(&self, slot: Slot) -> bool {
        matches!(
            (self, slot),
            (Bind::Read(_) | Bind::View(_), Slot::Texture(_))
                | (Bind::View(_), Slot::TextureArray(_))
                | (Bind::Write(_), Slot::StorageTexture(_))
                | (Bind::Buffer(_), Slot::Uniform | Slot::Storage)
                | (Bind::Sampler(_), Slot::Sampler(_))
        )
    }
}

/// A bind-group layout declared once as a list of slots.
#[derive(Debug)]
pub struct BindLayout {
    label: &'static str,
    slots: Vec<Slot>,
    layout: wgpu::BindGroupLayout,
}

impl BindLayout {
    /// The layout of `slots` (slot `i` at `@binding(i)`), visible to `stages`.
    pub fn new(
        device: &wgpu::Device,
        label: &'static str,
        stages: wgpu::ShaderStages,
        slots: &[Slot],
    ) -> Self {
        let entries: Vec<_> = (0u32..)
            .zip(slots)
            .filter_map(|(b, s)| s.layout_entry(b, stages))
            .collect();
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some(label),
            entries: &entries,
        });
        Self {
            label,
            slots: slots.to_vec(),
            layout,
        }
    }

    /// The wgpu layout, for a pipeline layout.
    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// Checks `binds` against the slots (one per slot that is not [`Slot::Unused`], in order)
    /// and declares the graph textures among them on `pass`.
    pub fn bind(
        self: &Arc<Self>,
        pass: &mut PassBuilder<'_>,
        binds: Vec<Bind>,
    ) -> Result<Bindings, GraphError> {
        let used: Vec<(u32, Slot)> = (0u32..)
            .zip(self.slots.iter().copied())
            .filter(|(_, s)| *s != Slot::Unused)
            .collect();
        if used.len() != binds.len() {
            return Err(GraphError::BindCount {
                pass: pass.name(),
                layout: self.label,
                expected: used.len(),
                given: binds.len(),
            });
        }
        let mut bound = Vec::with_capacity(binds.len());
        for (&(binding, slot), bind) in used.iter().zip(binds) {
            if !bind.fits(slot) {
                return Err(GraphError::BindKind {
                    pass: pass.name(),
                    layout: self.label,
                    binding,
                    expected: slot.name(),
                });
            }
            bound.push((
                binding,
                match bind {
                    Bind::Read(h) => Bound::Read(pass.read(h)),
                    Bind::Write(h) => Bound::Write(pass.write(h)),
                    Bind::View(v) => Bound::View(v),
                    Bind::Buffer(b) => Bound::Buffer(b),
                    Bind::Sampler(s) => Bound::Sampler(s),
                },
            ));
        }
        Ok(Bindings {
            layout: self.clone(),
            bound,
        })
    }
}

#[derive(Debug)]
enum Bound {
    Read(Ref<Read>),
    Write(Ref<Write>),
    View(wgpu::TextureView),
    Buffer(wgpu::Buffer),
    Sampler(wgpu::Sampler),
}

/// A pass's resources for one [`BindLayout`], checked and declared; made into a bind group
/// when the pass runs.
#[derive(Debug)]
pub struct Bindings {
    layout: Arc<BindLayout>,
    bound: Vec<(u32, Bound)>,
}

impl Bindings {
    /// The bind group, with the graph textures resolved to this frame's views.
    pub fn create(&self, ctx: &PassContext<'_>) -> Result<wgpu::BindGroup, GraphError> {
        let mut entries = Vec::with_capacity(self.bound.len());
        for (binding, b) in &self.bound {
            let resource = match b {
                Bound::Read(r) => wgpu::BindingResource::TextureView(ctx.view(*r)?),
                Bound::Write(w) => wgpu::BindingResource::TextureView(ctx.view(*w)?),
                Bound::View(v) => wgpu::BindingResource::TextureView(v),
                Bound::Buffer(b) => b.as_entire_binding(),
                Bound::Sampler(s) => wgpu::BindingResource::Sampler(s),
            };
            entries.push(wgpu::BindGroupEntry {
                binding: *binding,
                resource,
            });
        }
        Ok(ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(self.layout.label),
            layout: &self.layout.layout,
            entries: &entries,
        }))
    }
}

/// A pass over one bind group, built by declaring its resources in slot order, then drawn as
/// a fullscreen triangle, dispatched as compute, or recorded by a closure.
pub struct SimplePass<'g> {
    graph: &'g mut RenderGraph,
    name: &'static str,
    layout: Arc<BindLayout>,
    device: wgpu::Device,
    binds: Vec<Bind>,
}

impl<'g> SimplePass<'g> {
    /// A pass named `name` whose bind group 0 has `layout`.
    pub fn new(
        graph: &'g mut RenderGraph,
        name: &'static str,
        layout: &Arc<BindLayout>,
        device: &wgpu::Device,
    ) -> Self {
        Self {
            graph,
            name,
            layout: layout.clone(),
            device: device.clone(),
            binds: Vec::new(),
        }
    }

    /// The next slot reads a graph texture.
    pub fn read(mut self, h: TextureHandle) -> Self {
        self.binds.push(Bind::Read(h));
        self
    }

    /// The next slot writes a graph texture as storage (compute).
    pub fn write(mut self, h: TextureHandle) -> Self {
        self.binds.push(Bind::Write(h));
        self
    }

    /// The next slot holds a texture view from outside the graph.
    pub fn view(mut self, v: &wgpu::TextureView) -> Self {
        self.binds.push(Bind::View(v.clone()));
        self
    }

    /// The next slot holds `buffer`.
    pub fn buffer(mut self, buffer: &wgpu::Buffer) -> Self {
        self.binds.push(Bind::Buffer(buffer.clone()));
        self
    }

    /// The next slot holds a new uniform buffer with `bytes`.
    pub fn uniform(mut self, bytes: &[u8]) -> Self {
        let buffer = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(self.name),
                contents: bytes,
                usage: wgpu::BufferUsages::UNIFORM,
            });
        self.binds.push(Bind::Buffer(buffer));
        self
    }

    /// The next slot holds `sampler`.
    pub fn sampler(mut self, sampler: &wgpu::Sampler) -> Self {
        self.binds.push(Bind::Sampler(sampler.clone()));
        self
    }

    /// Draws a fullscreen triangle with `pipeline` into `target` (cleared first).
    pub fn draw(
        self,
        pipeline: Arc<wgpu::RenderPipeline>,
        target: TextureHandle,
    ) -> Result<(), RenderError> {
        let name = self.name;
        self.raster(target, move |ctx, bind, view| {
            crate::util::draw_fullscreen(ctx.encoder, name, view, &pipeline, bind);
            Ok(())
        })
    }

    /// Records a pass that renders into `target` with the bound group: `record` gets the
    /// context, the bind group and the target's view.
    pub fn raster(
        self,
        target: TextureHandle,
        record: impl Fn(
            &mut PassContext<'_>,
            &wgpu::BindGroup,
            &wgpu::TextureView,
        ) -> Result<(), GraphError>
        + Send
        + Sync
        + 'static,
    ) -> Result<(), RenderError> {
        let mut pass = self.graph.add_pass(self.name);
        let bindings = self.layout.bind(&mut pass, self.binds)?;
        let target = pass.write(target);
        pass.render(move |ctx| {
            let bind = bindings.create(ctx)?;
            let view = ctx.view(target)?;
            record(ctx, &bind, view)
        });
        Ok(())
    }

    /// Dispatches `groups` workgroups of `pipeline`.
    pub fn dispatch(
        self,
        pipeline: wgpu::ComputePipeline,
        groups: [u32; 3],
    ) -> Result<(), RenderError> {
        let name = self.name;
        let mut pass = self.graph.add_pass(name);
        let bindings = self.layout.bind(&mut pass, self.binds)?;
        pass.render(move |ctx| {
            let bind = bindings.create(ctx)?;
            let mut cp = ctx
                .encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some(name),
                    timestamp_writes: None,
                });
            cp.set_pipeline(&pipeline);
            cp.set_bind_group(0, &bind, &[]);
            cp.dispatch_workgroups(groups[0], groups[1], groups[2]);
            Ok(())
        });
        Ok(())
    }
}

/// A fullscreen fragment effect: its bind-group layout made from the declared slots, and its
/// pipelines compiled once per (entry point, target format) on first use.
pub struct FullscreenEffect {
    device: wgpu::Device,
    label: &'static str,
    source: String,
    layout: Arc<BindLayout>,
    pipelines: Mutex<HashMap<(&'static str, wgpu::TextureFormat), Arc<wgpu::RenderPipeline>>>,
}

impl FullscreenEffect {
    /// An effect of the WGSL `source` (with the shared prelude) whose bind group 0 has `slots`.
    pub fn new(device: &wgpu::Device, label: &'static str, source: String, slots: &[Slot]) -> Self {
        Self {
            device: device.clone(),
            label,
            source,
            layout: Arc::new(BindLayout::new(
                device,
                label,
                wgpu::ShaderStages::FRAGMENT,
                slots,
            )),
            pipelines: Mutex::new(HashMap::new()),
        }
    }

    /// The pipeline of fragment entry point `entry` writing `format`, compiled the first time.
    pub fn pipeline(
        &self,
        entry: &'static str,
        format: wgpu::TextureFormat,
    ) -> Arc<wgpu::RenderPipeline> {
        let mut map = match self.pipelines.lock() {
            Ok(m) => m,
            Err(poisoned) => poisoned.into_inner(),
        };
        map.entry((entry, format))
            .or_insert_with(|| {
                Arc::new(fullscreen_pipeline(
                    &self.device,
                    self.label,
                    &self.source,
                    entry,
                    self.layout.layout(),
                    format,
                    None,
                ))
            })
            .clone()
    }

    /// The device the effect was made on.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// Starts a pass of this effect; declare its slots in order, then [`EffectPass::draw`].
    pub fn pass<'g>(&self, graph: &'g mut RenderGraph, name: &'static str) -> EffectPass<'g, '_> {
        EffectPass {
            pass: SimplePass::new(graph, name, &self.layout, &self.device),
            effect: self,
        }
    }
}

/// A [`SimplePass`] of a [`FullscreenEffect`].
pub struct EffectPass<'g, 'e> {
    pass: SimplePass<'g>,
    effect: &'e FullscreenEffect,
}

impl EffectPass<'_, '_> {
    /// The next slot reads a graph texture.
    pub fn read(mut self, h: TextureHandle) -> Self {
        self.pass = self.pass.read(h);
        self
    }

    /// The next slot holds a texture view from outside the graph.
    pub fn view(mut self, v: &wgpu::TextureView) -> Self {
        self.pass = self.pass.view(v);
        self
    }

    /// The next slot holds `buffer`.
    pub fn buffer(mut self, buffer: &wgpu::Buffer) -> Self {
        self.pass = self.pass.buffer(buffer);
        self
    }

    /// The next slot holds a new uniform buffer with `bytes`.
    pub fn uniform(mut self, bytes: &[u8]) -> Self {
        self.pass = self.pass.uniform(bytes);
        self
    }

    /// The next slot holds `sampler`.
    pub fn sampler(mut self, sampler: &wgpu::Sampler) -> Self {
        self.pass = self.pass.sampler(sampler);
        self
    }

    /// Draws entry point `entry` into `target`.
    pub fn draw(self, entry: &'static str, target: TextureHandle) -> Result<(), RenderError> {
        let format = self.pass.graph.desc(target).format;
        self.pass.draw(self.effect.pipeline(entry, format), target)
    }

    /// Records a custom pass into `target` with the pipeline of `entry` (see
    /// [`SimplePass::raster`]).
    pub fn raster(
        self,
        entry: &'static str,
        target: TextureHandle,
        record: impl Fn(
            &mut PassContext<'_>,
            &wgpu::RenderPipeline,
            &wgpu::BindGroup,
            &wgpu::TextureView,
        ) -> Result<(), GraphError>
        + Send
        + Sync
        + 'static,
    ) -> Result<(), RenderError> {
        let format = self.pass.graph.desc(target).format;
        let pipeline = self.effect.pipeline(entry, format);
        self.pass.raster(target, move |ctx, bind, view| {
            record(ctx, &pipeline, bind, view)
        })
    }
}

/// A float texture read with `textureLoad` (no filtering).
pub const UNFILTERABLE: wgpu::TextureSampleType =
    wgpu::TextureSampleType::Float { filterable: false };
