//! The render graph: passes declare the virtual textures they read and write, and compiling the
//! graph culls, orders and allocates.
//!
//! A pass is a function over typed handles that returns its outputs (the kajiya/rend3 shape).
//! Declaring a read or a write on a [`PassBuilder`] returns the [`Ref`] the pass binds when it
//! runs, so a pass reaches exactly the textures it declared (kajiya's `pass_builder.rs`):
//!
//! ```
//! use radiant_render::graph::{RenderGraph, TextureDesc, TextureHandle};
//!
//! fn blur_pass(graph: &mut RenderGraph, input: TextureHandle) -> TextureHandle {
//!     let desc = graph.desc(input);
//!     let out = graph.create("blur_out", desc);
//!     let mut pass = graph.add_pass("blur_pass");
//!     let (input, output) = (pass.read(input), pass.write(out));
//!     pass.render(move |ctx| {
//!         let (_src, _dst) = (ctx.view(input)?, ctx.view(output)?); // encode commands
//!         Ok(())
//!     });
//!     out
//! }
//!
//! let mut graph = RenderGraph::new();
//! let desc = TextureDesc::new(64, 64, wgpu::TextureFormat::Rgba16Float);
//! let target = graph.import("target", desc);
//! let hdr = graph.create("hdr", desc);
//! let mut draw = graph.add_pass("draw");
//! draw.write(hdr);
//! draw.render(|_ctx| Ok(()));
//! let unused = blur_pass(&mut graph, hdr); // nobody reads this: culled
//! let mut present = graph.add_pass("present");
//! present.read(hdr);
//! present.write(target);
//! present.render(|_ctx| Ok(()));
//! let plan = graph.compile().unwrap();
//! assert_eq!(plan.report().passes, vec!["draw", "present"]);
//! assert_eq!(plan.report().culled, vec!["blur_pass"]);
//! # let _ = unused;
//! ```
//!
//! Each texture is written by exactly one pass (single assignment), so the graph is a DAG over
//! textures and culling is a backward walk from the roots: the imported textures some pass writes
//! (the frame's target) and the textures [`RenderGraph::export`] marks. Compiling is pure CPU
//! ([`RenderGraph::compile`] → [`GraphPlan`]); [`GraphPlan::realize`] then takes GPU textures
//! from a [`TexturePool`] that lives across frames, so a frame allocates nothing and textures
//! whose lifetimes do not overlap share one allocation.

use std::collections::HashMap;
use std::marker::PhantomData;

use crate::{GpuContext, RenderError};

/// The size, format and usage of a texture in the graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TextureDesc {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// Texel format.
    pub format: wgpu::TextureFormat,
    /// How passes use it.
    pub usage: wgpu::TextureUsages,
}

impl TextureDesc {
    /// A texture that passes can render to, sample, and copy from.
    pub fn new(width: u32, height: u32, format: wgpu::TextureFormat) -> Self {
        Self {
            width,
            height,
            format,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                | wgpu::TextureUsages::TEXTURE_BINDING
                | wgpu::TextureUsages::COPY_SRC,
        }
    }

    /// The same, also writable as a storage texture from compute passes.
    pub fn storage(width: u32, height: u32, format: wgpu::TextureFormat) -> Self {
        let mut d = Self::new(width, height, format);
        d.usage |= wgpu::TextureUsages::STORAGE_BINDING;
        d
    }

    /// Bytes of GPU memory the texture takes (texel size × texels, no padding).
    pub fn bytes(&self) -> u64 {
        let texel = self
            .format
            .block_copy_size(None)
            .or_else(|| {
                self.format
                    .block_copy_size(Some(wgpu::TextureAspect::DepthOnly))
            })
            .unwrap_or(4);
        u64::from(texel) * u64::from(self.width) * u64::from(self.height)
    }
}

/// A virtual texture in one graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TextureHandle(u32);

impl TextureHandle {
    fn index(self) -> usize {
        self.0 as usize
    }
}

/// Access marker of a [`Ref`] to a texture a pass reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Read;

/// Access marker of a [`Ref`] to a texture a pass writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Write;

/// A texture as one pass declared it: the only way that pass's closure reaches its view.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ref<A> {
    pass: u32,
    texture: TextureHandle,
    access: PhantomData<A>,
}

/// What a pass gets when it runs: the device, an encoder and the views of its textures.
pub struct PassContext<'a> {
    /// The device, to create bind groups.
    pub device: &'a wgpu::Device,
    /// The queue, to upload small per-frame data.
    pub queue: &'a wgpu::Queue,
    /// The frame's command encoder.
    pub encoder: &'a mut wgpu::CommandEncoder,
    pass: u32,
    name: &'static str,
    views: &'a [Option<&'a wgpu::TextureView>],
}

impl<'a> PassContext<'a> {
    /// The view of a texture this pass declared. A [`Ref`] another pass declared is an error.
    pub fn view<A>(&self, r: Ref<A>) -> Result<&'a wgpu::TextureView, GraphError> {
        // Compilation keeps every texture a live pass declares, so a ref of this pass resolves.
        let view = (r.pass == self.pass)
            .then(|| self.views.get(r.texture.index()).copied().flatten())
            .flatten();
        view.ok_or(GraphError::Undeclared { pass: self.name })
    }
}

type PassFn = Box<dyn Fn(&mut PassContext<'_>) -> Result<(), GraphError> + Send + Sync>;

struct VirtualTexture {
    name: &'static str,
    desc: TextureDesc,
    /// Index among the imports, for imported textures.
    import: Option<usize>,
    exported: bool,
}

struct PassNode {
    name: &'static str,
    reads: Vec<TextureHandle>,
    writes: Vec<TextureHandle>,
    run: PassFn,
}

/// A frame's passes and textures before compilation.
#[derive(Default)]
pub struct RenderGraph {
    textures: Vec<VirtualTexture>,
    passes: Vec<PassNode>,
    imports: usize,
}

/// Why a graph does not compile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GraphError {
    /// A pass reads a transient texture that no pass writes.
    #[error("pass `{pass}` reads `{texture}`, which no pass writes")]
    ReadOfUnwritten {
        /// The reading pass.
        pass: &'static str,
        /// The texture.
        texture: &'static str,
    },
    /// Two passes write one texture (each texture has one writer).
    #[error("`{texture}` is written by both `{first}` and `{second}`")]
    WrittenTwice {
        /// The texture.
        texture: &'static str,
        /// The first writer.
        first: &'static str,
        /// The second writer.
        second: &'static str,
    },
    /// Nothing reaches an imported target or an exported texture.
    #[error("the graph has no output: no pass writes an imported or exported texture")]
    NoOutput,
    /// The passes depend on each other in a cycle.
    #[error("the passes form a cycle through `{pass}`")]
    Cycle {
        /// A pass on the cycle.
        pass: &'static str,
    },
    /// A handle from another graph.
    #[error("a texture handle does not belong to this graph")]
    ForeignHandle,
    /// A pass used a texture reference another pass declared.
    #[error("pass `{pass}` used a texture it did not declare")]
    Undeclared {
        /// The pass.
        pass: &'static str,
    },
    /// A pass bound a different number of resources than its layout has slots.
    #[error("pass `{pass}` binds {given} resources to `{layout}`, which has {expected} slots")]
    BindCount {
        /// The pass.
        pass: &'static str,
        /// The bind-group layout.
        layout: &'static str,
        /// Slots of the layout.
        expected: usize,
        /// Resources given.
        given: usize,
    },
    /// A pass bound the wrong kind of resource to a slot.
    #[error(
        "pass `{pass}` binds the wrong kind of resource at `{layout}` binding {binding}: it takes {expected}"
    )]
    BindKind {
        /// The pass.
        pass: &'static str,
        /// The bind-group layout.
        layout: &'static str,
        /// The binding index.
        binding: u32,
        /// What the slot takes.
        expected: &'static str,
    },
    /// `execute` got a different number of imported views than the graph imports.
    #[error("the graph imports {expected} textures, {given} given")]
    Imports {
        /// Imports of the graph.
        expected: usize,
        /// Views given.
        given: usize,
    },
}

/// Declares what one pass reads and writes, then takes the closure that records it
/// ([`RenderGraph::add_pass`]). A pass that is never given its closure does not exist.
pub struct PassBuilder<'g> {
    graph: &'g mut RenderGraph,
    name: &'static str,
    reads: Vec<TextureHandle>,
    writes: Vec<TextureHandle>,
}

impl PassBuilder<'_> {
    /// The pass's name.
    pub fn name(&self) -> &'static str {
        self.name
    }

    fn reference<A>(&self, texture: TextureHandle) -> Ref<A> {
        Ref {
            pass: self.graph.passes.len() as u32,
            texture,
            access: PhantomData,
        }
    }

    /// Declares a read of `texture`; the returned ref binds it.
    pub fn read(&mut self, texture: TextureHandle) -> Ref<Read> {
        if !self.reads.contains(&texture) {
            self.reads.push(texture);
        }
        self.reference(texture)
    }

    /// Declares a write of `texture`; the returned ref binds it.
    pub fn write(&mut self, texture: TextureHandle) -> Ref<Write> {
        if !self.writes.contains(&texture) {
            self.writes.push(texture);
        }
        self.reference(texture)
    }

    /// The description of a texture of the graph.
    pub fn desc(&self, texture: TextureHandle) -> TextureDesc {
        self.graph.desc(texture)
    }

    /// Adds the pass, recorded by `run` each frame.
    pub fn render(
        self,
        run: impl Fn(&mut PassContext<'_>) -> Result<(), GraphError> + Send + Sync + 'static,
    ) {
        self.graph.passes.push(PassNode {
            name: self.name,
            reads: self.reads,
            writes: self.writes,
            run: Box::new(run),
        });
    }
}

impl RenderGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// A transient texture, allocated from the pool only if a live pass uses it.
    pub fn create(&mut self, name: &'static str, desc: TextureDesc) -> TextureHandle {
        self.textures.push(VirtualTexture {
            name,
            desc,
            import: None,
            exported: false,
        });
        TextureHandle(self.textures.len() as u32 - 1)
    }

    /// A texture owned outside the graph (a swapchain image, a capture target). Its view is
    /// passed to [`CompiledGraph::execute`], in import order.
    pub fn import(&mut self, name: &'static str, desc: TextureDesc) -> TextureHandle {
        let h = self.create(name, desc);
        self.textures[h.index()].import = Some(self.imports);
        self.imports += 1;
        h
    }

    /// Keeps a transient texture alive to the end of the frame, for reading back afterwards.
    pub fn export(&mut self, handle: TextureHandle) {
        if let Some(t) = self.textures.get_mut(handle.index()) {
            t.exported = true;
        }
    }

    /// The description of a texture in this graph.
    ///
    /// # Panics
    /// Never for a handle this graph returned; a foreign handle gives a 1×1 placeholder.
    pub fn desc(&self, handle: TextureHandle) -> TextureDesc {
        self.textures
            .get(handle.index())
            .map(|t| t.desc)
            .unwrap_or(TextureDesc::new(1, 1, wgpu::TextureFormat::Rgba8Unorm))
    }

    /// Starts a pass: declare its reads and writes on the builder, then give it its closure.
    pub fn add_pass(&mut self, name: &'static str) -> PassBuilder<'_> {
        PassBuilder {
            graph: self,
            name,
            reads: Vec::new(),
            writes: Vec::new(),
        }
    }

    /// Culls, orders and plans the allocation of the graph. Pure CPU.
    pub fn compile(self) -> Result<GraphPlan, GraphError> {
        let writer = self.writers()?;
        let live = self.live_passes(&writer)?;
        let order = self.order(&writer, &live)?;
        let (slots, physical) = self.alias(&order);
        let culled = (0..self.passes.len())
            .filter(|&p| !live[p])
            .map(|p| self.passes[p].name)
            .collect();
        Ok(GraphPlan {
            textures: self.textures,
            passes: self.passes,
            imports: self.imports,
            order,
            culled,
            slots,
            physical,
        })
    }

    /// The pass that writes each texture; refuses two writers, foreign handles and reads of
    /// transient textures nobody writes.
    fn writers(&self) -> Result<Vec<Option<usize>>, GraphError> {
        let mut writer: Vec<Option<usize>> = vec![None; self.textures.len()];
        for (p, pass) in self.passes.iter().enumerate() {
            for &w in &pass.writes {
                let slot = writer.get_mut(w.index()).ok_or(GraphError::ForeignHandle)?;
                if let Some(first) = *slot {
                    return Err(GraphError::WrittenTwice {
                        texture: self.textures[w.index()].name,
                        first: self.passes[first].name,
                        second: pass.name,
                    });
                }
                *slot = Some(p);
            }
        }
        for pass in &self.passes {
            for &r in &pass.reads {
                let t = self
                    .textures
                    .get(r.index())
                    .ok_or(GraphError::ForeignHandle)?;
                if t.import.is_none() && writer[r.index()].is_none() {
                    return Err(GraphError::ReadOfUnwritten {
                        pass: pass.name,
                        texture: t.name,
                    });
                }
            }
        }
        Ok(writer)
    }

    /// The passes the roots (written imports and exports) depend on, walking back from them.
    fn live_passes(&self, writer: &[Option<usize>]) -> Result<Vec<bool>, GraphError> {
        let n_tex = self.textures.len();
        let mut needed = vec![false; n_tex];
        let mut live = vec![false; self.passes.len()];
        let mut stack: Vec<usize> = (0..n_tex)
            .filter(|&t| {
                (self.textures[t].import.is_some() || self.textures[t].exported)
                    && writer[t].is_some()
            })
            .collect();
        if stack.is_empty() {
            return Err(GraphError::NoOutput);
        }
        while let Some(t) = stack.pop() {
            if needed[t] {
                continue;
            }
            needed[t] = true;
            if let Some(p) = writer[t]
                && !live[p]
            {
                live[p] = true;
                stack.extend(self.passes[p].reads.iter().map(|h| h.index()));
                // A live pass writes all its outputs, so they exist too.
                stack.extend(self.passes[p].writes.iter().map(|h| h.index()));
            }
        }
        Ok(live)
    }

    /// Kahn's algorithm over the live passes, lowest declaration index first.
    fn order(&self, writer: &[Option<usize>], live: &[bool]) -> Result<Vec<usize>, GraphError> {
        let n = self.passes.len();
        let mut indegree = vec![0usize; n];
        let mut users: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (p, pass) in self.passes.iter().enumerate().filter(|&(p, _)| live[p]) {
            for r in &pass.reads {
                if let Some(w) = writer[r.index()] {
                    indegree[p] += 1;
                    users[w].push(p);
                }
            }
        }
        let mut ready: std::collections::BTreeSet<usize> =
            (0..n).filter(|&p| live[p] && indegree[p] == 0).collect();
        let mut order = Vec::new();
        while let Some(p) = ready.pop_first() {
            order.push(p);
            for &u in &users[p] {
                indegree[u] -= 1;
                if indegree[u] == 0 {
                    ready.insert(u);
                }
            }
        }
        let n_live = live.iter().filter(|&&l| l).count();
        if order.len() != n_live {
            let stuck = (0..n)
                .find(|&p| live[p] && !order.contains(&p))
                .map_or("?", |p| self.passes[p].name);
            return Err(GraphError::Cycle { pass: stuck });
        }
        Ok(order)
    }

    /// Lifetimes in execution steps, then greedy aliasing of identical descriptions: the slot
    /// of each live transient texture and the physical textures (description, first user).
    fn alias(&self, order: &[usize]) -> (Vec<Option<usize>>, Vec<(TextureDesc, &'static str)>) {
        let n_tex = self.textures.len();
        let mut first = vec![usize::MAX; n_tex];
        let mut last = vec![0usize; n_tex];
        for (step, &p) in order.iter().enumerate() {
            let pass = &self.passes[p];
            for h in pass.reads.iter().chain(&pass.writes) {
                let t = h.index();
                first[t] = first[t].min(step);
                last[t] = last[t].max(step);
            }
        }
        for (t, tex) in self.textures.iter().enumerate() {
            if tex.exported && first[t] != usize::MAX {
                last[t] = usize::MAX;
            }
        }
        // Only live passes are in the order, so a texture with a first step is a live one.
        let mut by_first: Vec<usize> = (0..n_tex)
            .filter(|&t| first[t] != usize::MAX && self.textures[t].import.is_none())
            .collect();
        by_first.sort_by_key(|&t| (first[t], t));
        let mut slots: Vec<Option<usize>> = vec![None; n_tex];
        let mut physical: Vec<(TextureDesc, usize, &'static str)> = Vec::new(); // desc, busy until, name
        for t in by_first {
            let desc = self.textures[t].desc;
            let reuse = physical
                .iter()
                .position(|(d, until, _)| *d == desc && *until < first[t]);
            let s = match reuse {
                Some(s) => s,
                None => {
                    physical.push((desc, 0, self.textures[t].name));
                    physical.len() - 1
                }
            };
            physical[s].1 = last[t];
            slots[t] = Some(s);
        }
        let physical = physical.into_iter().map(|(d, _, n)| (d, n)).collect();
        (slots, physical)
    }
}

/// What a compiled graph runs and allocates.
#[derive(Clone, Debug, PartialEq)]
pub struct GraphReport {
    /// Live passes, in execution order.
    pub passes: Vec<&'static str>,
    /// Passes removed because nothing reaches the output through them.
    pub culled: Vec<&'static str>,
    /// Transient textures the live passes use.
    pub virtual_textures: usize,
    /// GPU textures allocated for them after aliasing: (first user's name, description).
    pub physical_textures: Vec<(&'static str, TextureDesc)>,
    /// Bytes of those GPU textures.
    pub bytes: u64,
}

impl std::fmt::Display for GraphReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} passes ({} culled), {} transient textures in {} allocations, {:.2} MiB",
            self.passes.len(),
            self.culled.len(),
            self.virtual_textures,
            self.physical_textures.len(),
            self.bytes as f64 / (1024.0 * 1024.0)
        )?;
        writeln!(f, "  passes: {}", self.passes.join(" → "))?;
        for (name, d) in &self.physical_textures {
            writeln!(
                f,
                "  {name:<24} {}×{} {:?} {:.2} MiB",
                d.width,
                d.height,
                d.format,
                d.bytes() as f64 / (1024.0 * 1024.0)
            )?;
        }
        Ok(())
    }
}

/// A culled, ordered graph with its allocation plan, before any GPU memory exists.
pub struct GraphPlan {
    textures: Vec<VirtualTexture>,
    passes: Vec<PassNode>,
    imports: usize,
    order: Vec<usize>,
    culled: Vec<&'static str>,
    slots: Vec<Option<usize>>,
    physical: Vec<(TextureDesc, &'static str)>,
}

impl GraphPlan {
    /// Passes, textures and bytes.
    pub fn report(&self) -> GraphReport {
        GraphReport {
            passes: self.order.iter().map(|&p| self.passes[p].name).collect(),
            culled: self.culled.clone(),
            virtual_textures: self.slots.iter().filter(|s| s.is_some()).count(),
            physical_textures: self.physical.iter().map(|&(d, n)| (n, d)).collect(),
            bytes: self.physical.iter().map(|(d, _)| d.bytes()).sum(),
        }
    }

    /// The GPU allocation a texture shares, if it is live and transient.
    pub fn slot(&self, handle: TextureHandle) -> Option<usize> {
        self.slots.get(handle.index()).copied().flatten()
    }

    /// Allocates the plan's textures from `pool` (reusing what it holds).
    pub fn realize(self, device: &wgpu::Device, pool: &mut TexturePool) -> CompiledGraph {
        let textures: Vec<wgpu::Texture> = self
            .physical
            .iter()
            .map(|&(d, name)| pool.acquire(device, d, name))
            .collect();
        let views = textures
            .iter()
            .map(|t| t.create_view(&wgpu::TextureViewDescriptor::default()))
            .collect();
        let report = self.report();
        CompiledGraph {
            plan: self,
            textures,
            views,
            report,
        }
    }
}

/// GPU textures kept across frames and recompiles, keyed by description.
#[derive(Default)]
pub struct TexturePool {
    free: HashMap<TextureDesc, Vec<wgpu::Texture>>,
    created: usize,
}

impl TexturePool {
    /// An empty pool.
    pub fn new() -> Self {
        Self::default()
    }

    fn acquire(&mut self, device: &wgpu::Device, desc: TextureDesc, name: &str) -> wgpu::Texture {
        if let Some(t) = self.free.get_mut(&desc).and_then(Vec::pop) {
            return t;
        }
        self.created += 1;
        device.create_texture(&wgpu::TextureDescriptor {
            label: Some(name),
            size: wgpu::Extent3d {
                width: desc.width.max(1),
                height: desc.height.max(1),
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: desc.format,
            usage: desc.usage,
            view_formats: &[],
        })
    }

    /// Returns a compiled graph's textures for reuse.
    pub fn release(&mut self, graph: CompiledGraph) {
        for (t, (d, _)) in graph.textures.into_iter().zip(&graph.plan.physical) {
            self.free.entry(*d).or_default().push(t);
        }
    }

    /// Frees the textures no compiled graph took back (after a recompile that needs less).
    pub fn trim(&mut self) {
        self.free.clear();
    }

    /// How many GPU textures the pool has created in its life.
    pub fn created(&self) -> usize {
        self.created
    }
}

/// GPU time of each pass of one frame.
#[derive(Clone, Debug, Default)]
pub struct PassTimings {
    /// (pass, milliseconds), in execution order.
    pub passes: Vec<(&'static str, f64)>,
    /// True when the times are GPU timestamps; false when they are CPU wall times of each pass
    /// submitted and waited for on its own.
    pub gpu: bool,
}

/// A graph with its GPU textures, ready to run every frame.
pub struct CompiledGraph {
    plan: GraphPlan,
    textures: Vec<wgpu::Texture>,
    views: Vec<wgpu::TextureView>,
    report: GraphReport,
}

impl CompiledGraph {
    /// Passes, textures and bytes.
    pub fn report(&self) -> &GraphReport {
        &self.report
    }

    /// The GPU texture behind a live transient (or exported) texture.
    pub fn texture(&self, handle: TextureHandle) -> Option<&wgpu::Texture> {
        self.plan.slot(handle).map(|s| &self.textures[s])
    }

    /// Encodes live pass `p`.
    fn run_pass(
        &self,
        p: usize,
        gpu: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        views: &[Option<&wgpu::TextureView>],
    ) -> Result<(), GraphError> {
        let node = &self.plan.passes[p];
        let mut ctx = PassContext {
            device: &gpu.device,
            queue: &gpu.queue,
            encoder,
            pass: p as u32,
            name: node.name,
            views,
        };
        (node.run)(&mut ctx)
    }

    fn resolve<'a>(
        &'a self,
        imports: &[&'a wgpu::TextureView],
    ) -> Result<Vec<Option<&'a wgpu::TextureView>>, GraphError> {
        if imports.len() != self.plan.imports {
            return Err(GraphError::Imports {
                expected: self.plan.imports,
                given: imports.len(),
            });
        }
        Ok(self
            .plan
            .textures
            .iter()
            .enumerate()
            .map(|(t, vt)| match (vt.import, self.plan.slots[t]) {
                (Some(i), _) => Some(imports[i]),
                (None, Some(s)) => Some(&self.views[s]),
                // Dead texture: no live pass names it.
                (None, None) => None,
            })
            .collect())
    }

    /// Records and submits every live pass in order.
    pub fn execute(
        &self,
        gpu: &GpuContext,
        imports: &[&wgpu::TextureView],
    ) -> Result<(), RenderError> {
        let views = self.resolve(imports)?;
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("render_graph"),
            });
        for &p in &self.plan.order {
            self.run_pass(p, gpu, &mut encoder, &views)?;
        }
        gpu.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// Runs the frame once and measures each pass: GPU timestamps when the device has them,
    /// else the CPU wall time of each pass submitted and waited for alone.
    pub fn execute_timed(
        &self,
        gpu: &GpuContext,
        imports: &[&wgpu::TextureView],
    ) -> Result<PassTimings, RenderError> {
        let views = self.resolve(imports)?;
        let n = self.plan.order.len() as u32;
        if gpu.has_timestamps() && n > 0 {
            let qs = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass_timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: n + 1,
            });
            let bytes = u64::from(n + 1) * 8;
            let resolve = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp_resolve"),
                size: bytes,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let readback = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp_readback"),
                size: bytes,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("render_graph_timed"),
                });
            encoder.write_timestamp(&qs, 0);
            for (i, &p) in self.plan.order.iter().enumerate() {
                self.run_pass(p, gpu, &mut encoder, &views)?;
                encoder.write_timestamp(&qs, i as u32 + 1);
            }
            encoder.resolve_query_set(&qs, 0..n + 1, &resolve, 0);
            encoder.copy_buffer_to_buffer(&resolve, 0, &readback, 0, bytes);
            gpu.queue.submit([encoder.finish()]);
            let raw = crate::capture::read_buffer(gpu, &readback)?;
            let ticks: Vec<u64> = raw
                .chunks_exact(8)
                .map(|c| u64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
                .collect();
            let period = f64::from(gpu.queue.get_timestamp_period());
            let passes = self
                .plan
                .order
                .iter()
                .enumerate()
                .map(|(i, &p)| {
                    let dt = ticks[i + 1].saturating_sub(ticks[i]) as f64 * period * 1e-6;
                    (self.plan.passes[p].name, dt)
                })
                .collect();
            return Ok(PassTimings { passes, gpu: true });
        }
        let mut passes = Vec::new();
        for &p in &self.plan.order {
            let t0 = std::time::Instant::now();
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("render_graph_pass"),
                });
            self.run_pass(p, gpu, &mut encoder, &views)?;
            gpu.queue.submit([encoder.finish()]);
            let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
            passes.push((self.plan.passes[p].name, t0.elapsed().as_secs_f64() * 1e3));
        }
        Ok(PassTimings { passes, gpu: false })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const F: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

    fn desc() -> TextureDesc {
        TextureDesc::new(64, 32, F)
    }

    /// A pass that declares `reads` and `writes` and records nothing.
    fn pass(
        g: &mut RenderGraph,
        name: &'static str,
        reads: &[TextureHandle],
        writes: &[TextureHandle],
    ) {
        let mut p = g.add_pass(name);
        for &r in reads {
            p.read(r);
        }
        for &w in writes {
            p.write(w);
        }
        p.render(|_| Ok(()));
    }

    #[test]
    fn culls_passes_that_do_not_reach_the_target_and_allocates_nothing_for_them() {
        let mut g = RenderGraph::new();
        let target = g.import("target", desc());
        let a = g.create("a", desc());
        let unused = g.create("unused", TextureDesc::new(512, 512, F));
        let unused2 = g.create("unused2", desc());
        pass(&mut g, "draw", &[], &[a]);
        pass(&mut g, "side", &[a], &[unused]);
        pass(&mut g, "side2", &[unused], &[unused2]);
        pass(&mut g, "present", &[a], &[target]);
        let plan = g.compile().expect("compiles");
        let r = plan.report();
        assert_eq!(r.passes, vec!["draw", "present"]);
        assert_eq!(r.culled, vec!["side", "side2"]);
        assert_eq!(r.virtual_textures, 1);
        assert_eq!(r.bytes, desc().bytes());
        assert_eq!(plan.slot(unused), None);
    }

    #[test]
    fn orders_by_dependency_not_declaration() {
        let mut g = RenderGraph::new();
        let target = g.import("target", desc());
        let a = g.create("a", desc());
        let b = g.create("b", desc());
        pass(&mut g, "present", &[b], &[target]);
        pass(&mut g, "second", &[a], &[b]);
        pass(&mut g, "first", &[], &[a]);
        let r = g.compile().expect("compiles").report();
        assert_eq!(r.passes, vec!["first", "second", "present"]);
    }

    #[test]
    fn aliases_textures_whose_lifetimes_do_not_overlap() {
        // a -> b -> c -> d -> target: a and c (and b and d) can share memory.
        let mut g = RenderGraph::new();
        let target = g.import("target", desc());
        let t: Vec<TextureHandle> = ["a", "b", "c", "d"]
            .iter()
            .map(|n| g.create(n, desc()))
            .collect();
        pass(&mut g, "p0", &[], &[t[0]]);
        pass(&mut g, "p1", &[t[0]], &[t[1]]);
        pass(&mut g, "p2", &[t[1]], &[t[2]]);
        pass(&mut g, "p3", &[t[2]], &[t[3]]);
        pass(&mut g, "p4", &[t[3]], &[target]);
        let plan = g.compile().expect("compiles");
        let r = plan.report();
        assert_eq!(r.virtual_textures, 4);
        assert_eq!(r.physical_textures.len(), 2);
        assert_eq!(r.bytes, 2 * desc().bytes());
        assert_eq!(plan.slot(t[0]), plan.slot(t[2]));
        assert_eq!(plan.slot(t[1]), plan.slot(t[3]));
        assert_ne!(plan.slot(t[0]), plan.slot(t[1]));
    }

    #[test]
    fn different_descriptions_never_alias_and_exports_live_to_the_end() {
        let mut g = RenderGraph::new();
        let target = g.import("target", desc());
        let hdr = g.create("hdr", desc());
        let small = g.create("small", TextureDesc::new(32, 16, F));
        let late = g.create("late", desc());
        pass(&mut g, "p0", &[], &[hdr]);
        pass(&mut g, "p1", &[hdr], &[small]);
        pass(&mut g, "p2", &[small], &[late]);
        pass(&mut g, "p3", &[late], &[target]);
        g.export(hdr);
        let plan = g.compile().expect("compiles");
        // Without the export, `late` could reuse `hdr`'s memory.
        assert_ne!(plan.slot(hdr), plan.slot(late));
        assert_ne!(plan.slot(hdr), plan.slot(small));
        assert_eq!(plan.report().physical_textures.len(), 3);
    }

    #[test]
    fn export_alone_is_an_output() {
        let mut g = RenderGraph::new();
        let a = g.create("a", desc());
        pass(&mut g, "p", &[], &[a]);
        g.export(a);
        assert_eq!(g.compile().expect("compiles").report().passes, vec!["p"]);
    }

    #[test]
    fn malformed_graphs_are_typed_errors() {
        let mut g = RenderGraph::new();
        let t = g.import("t", desc());
        let a = g.create("a", desc());
        pass(&mut g, "w1", &[], &[a]);
        pass(&mut g, "w2", &[], &[a]);
        pass(&mut g, "p", &[a], &[t]);
        assert!(matches!(
            g.compile(),
            Err(GraphError::WrittenTwice { texture: "a", .. })
        ));

        let mut g = RenderGraph::new();
        let t = g.import("t", desc());
        let a = g.create("a", desc());
        pass(&mut g, "p", &[a], &[t]);
        assert!(matches!(
            g.compile(),
            Err(GraphError::ReadOfUnwritten { pass: "p", .. })
        ));

        let mut g = RenderGraph::new();
        let a = g.create("a", desc());
        pass(&mut g, "p", &[], &[a]);
        assert!(matches!(g.compile(), Err(GraphError::NoOutput)));

        let mut g = RenderGraph::new();
        let t = g.import("t", desc());
        let a = g.create("a", desc());
        let b = g.create("b", desc());
        pass(&mut g, "x", &[b], &[a]);
        pass(&mut g, "y", &[a], &[b, t]);
        assert!(matches!(g.compile(), Err(GraphError::Cycle { .. })));
    }

    #[test]
    fn bytes_follow_the_format() {
        assert_eq!(TextureDesc::new(4, 4, F).bytes(), 128);
        assert_eq!(
            TextureDesc::new(4, 4, wgpu::TextureFormat::Depth32Float).bytes(),
            64
        );
        assert_eq!(
            TextureDesc::new(4, 4, wgpu::TextureFormat::R8Unorm).bytes(),
            16
        );
    }
}
