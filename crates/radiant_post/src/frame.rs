//! The standard frame: G-buffer → \[SSAO\] → lighting → \[bloom\] → tone mapping → \[blur\] → \[Sobel\].
//!
//! Bracketed effects are `Option`s in [`FrameSettings`]: `None` means their passes are never
//! added, so the compiled graph has neither their passes nor their textures. The graph is
//! rebuilt only when the size, the target format, the settings or the scene change; otherwise
//! a frame reuses the compiled graph and its pooled textures and allocates nothing.

use std::sync::Arc;

use radiant_render::capture::{Image, read_texture};
use radiant_render::gbuffer::{GBufferPipeline, gbuffer_pass};
use radiant_render::graph::{
    CompiledGraph, GraphReport, PassTimings, RenderGraph, TextureDesc, TextureHandle, TexturePool,
};
use radiant_render::lighting::{DebugView, LightingPipeline, lighting_pass};
use radiant_render::material::TextureCache;
use radiant_render::scene::{CameraView, GpuScene, RenderScene};
use radiant_render::ssao::{AO_FORMAT, Ssao, SsaoPipeline, ssao_pass};
use radiant_render::{GpuContext, RenderError, Requirements};

use crate::bloom::{BLOOM_FORMAT, Bloom, BloomPipeline, bloom_pass};
use crate::blur::{BlurPipeline, GaussianBlur, blur_pass};
use crate::overlay::{Overlay, OverlayPipeline, overlay_pass};
use crate::sobel::{Sobel, SobelInputs, SobelPipeline, sobel_pass};
use crate::tonemapping::{Tonemapping, TonemappingPipeline, tonemapping_pass};

/// Every setting of the frame. An effect that is `None` is left out entirely.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameSettings {
    /// Exposure and tone-map operator.
    pub tonemapping: Tonemapping,
    /// Bloom, if on (default: on).
    pub bloom: Option<Bloom>,
    /// SSAO, if on (default: on).
    pub ssao: Option<Ssao>,
    /// Sobel edge overlay, if on (default: off).
    pub sobel: Option<Sobel>,
    /// Gaussian blur of the final image, if on (default: off).
    pub blur: Option<GaussianBlur>,
    /// What the lighting pass outputs (default: the lit image).
    pub debug_view: DebugView,
}

impl Default for FrameSettings {
    fn default() -> Self {
        Self {
            tonemapping: Tonemapping::default(),
            bloom: Some(Bloom::default()),
            ssao: Some(Ssao::default()),
            sobel: None,
            blur: None,
            debug_view: DebugView::Lit,
        }
    }
}

impl FrameSettings {
    /// Only what every frame needs: G-buffer, lighting, tone mapping.
    pub const MINIMAL: FrameSettings = FrameSettings {
        tonemapping: Tonemapping {
            operator: radiant_color::Tonemap::AcesFitted,
            exposure: 0.0,
        },
        bloom: None,
        ssao: None,
        sobel: None,
        blur: None,
        debug_view: DebugView::Lit,
    };

    /// Checks every enabled effect's fields.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.tonemapping.validate()?;
        if let Some(b) = &self.bloom {
            b.validate()?;
        }
        if let Some(s) = &self.ssao {
            s.validate()?;
        }
        if let Some(s) = &self.sobel {
            s.validate()?;
        }
        if let Some(b) = &self.blur {
            b.validate()?;
        }
        Ok(())
    }
}

/// The pipelines of every pass, compiled once per device.
#[derive(Clone)]
pub struct FramePipelines {
    gbuffer: Arc<GBufferPipeline>,
    lighting: Arc<LightingPipeline>,
    ssao: Arc<SsaoPipeline>,
    tonemapping: Arc<TonemappingPipeline>,
    bloom: Arc<BloomPipeline>,
    blur: Arc<BlurPipeline>,
    sobel: Arc<SobelPipeline>,
    overlay: Arc<OverlayPipeline>,
}

impl FramePipelines {
    /// Compiles them.
    pub fn new(gpu: &GpuContext) -> Self {
        let blur = Arc::new(BlurPipeline::new(&gpu.device));
        Self {
            gbuffer: Arc::new(GBufferPipeline::new(&gpu.device)),
            lighting: Arc::new(LightingPipeline::new(&gpu.device, &gpu.queue)),
            ssao: Arc::new(SsaoPipeline::new(&gpu.device)),
            tonemapping: Arc::new(TonemappingPipeline::new(&gpu.device)),
            bloom: Arc::new(BloomPipeline::new(&gpu.device, blur.clone())),
            blur,
            sobel: Arc::new(SobelPipeline::new(&gpu.device)),
            overlay: Arc::new(OverlayPipeline::new(&gpu.device)),
        }
    }
}

/// Which optional effects this adapter can run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct EffectSupport {
    /// SSAO renders to R8Unorm.
    pub ssao: bool,
    /// Bloom renders to Rgba16Float.
    pub bloom: bool,
}

struct Compiled {
    key: FrameKey,
    graph: CompiledGraph,
    hdr: TextureHandle,
}

#[derive(Clone, PartialEq)]
struct FrameKey {
    width: u32,
    height: u32,
    format: wgpu::TextureFormat,
    settings: FrameSettings,
    scene_generation: u64,
    overlay_generation: u64,
}

/// One frame's outputs read back to the CPU.
pub struct Capture {
    /// The tone-mapped image as stored (sRGB-encoded values in [0, 1]).
    pub ldr: Image,
    /// Linear HDR radiance before tone mapping (after bloom, when on).
    pub hdr: Image,
}

/// Draws [`RenderScene`]s through the standard frame into any target.
pub struct FrameRenderer {
    pipelines: FramePipelines,
    support: EffectSupport,
    scene: Arc<GpuScene>,
    camera: CameraView,
    scene_generation: u64,
    overlay: Option<Arc<dyn Overlay>>,
    overlay_generation: u64,
    pool: TexturePool,
    textures: TextureCache,
    compiled: Option<Compiled>,
    compiles: u64,
}

impl FrameRenderer {
    /// Compiles the pipelines, checks what the adapter supports, and uploads `scene`.
    pub fn new(gpu: &GpuContext, scene: &RenderScene) -> Result<Self, RenderError> {
        gpu.check(&radiant_render::lighting::requirements())
            .map_err(|reason| RenderError::Unsupported {
                pass: "lighting_pass",
                reason,
            })?;
        let mut support = EffectSupport {
            ssao: true,
            bloom: true,
        };
        if let Err(reason) = gpu.check(&Requirements {
            render_formats: vec![(AO_FORMAT, false)],
            ..Default::default()
        }) {
            tracing::warn!("SSAO disabled on this adapter: {reason}");
            support.ssao = false;
        }
        if let Err(reason) = gpu.check(&Requirements {
            render_formats: vec![(BLOOM_FORMAT, false)],
            ..Default::default()
        }) {
            tracing::warn!("bloom disabled on this adapter: {reason}");
            support.bloom = false;
        }
        let pipelines = FramePipelines::new(gpu);
        let mut textures = TextureCache::new();
        let gpu_scene = GpuScene::upload_cached(gpu, scene, &mut textures)?;
        gpu.take_errors()?;
        Ok(Self {
            pipelines,
            support,
            scene: Arc::new(gpu_scene),
            camera: scene.camera,
            scene_generation: 0,
            overlay: None,
            overlay_generation: 0,
            pool: TexturePool::new(),
            textures,
            compiled: None,
            compiles: 0,
        })
    }

    /// Replaces the scene (the graph recompiles on the next frame). Textures whose pixels the
    /// previous scene shared are not uploaded again.
    pub fn set_scene(&mut self, gpu: &GpuContext, scene: &RenderScene) -> Result<(), RenderError> {
        self.scene = Arc::new(GpuScene::upload_cached(gpu, scene, &mut self.textures)?);
        self.camera = scene.camera;
        self.scene_generation += 1;
        Ok(())
    }

    /// Moves the camera; nothing is uploaded but the camera uniform of the next frame. A new
    /// near or far plane recompiles the graph (the depth-edge pass bakes them in).
    pub fn set_camera(&mut self, camera: CameraView) {
        if (camera.near, camera.far) != (self.camera.near, self.camera.far) {
            self.scene_generation += 1;
        }
        self.camera = camera;
    }

    /// The camera the next frame is drawn from.
    pub fn camera(&self) -> CameraView {
        self.camera
    }

    /// Draws `overlay` over every frame as the graph's last pass (`None`: no overlay pass and
    /// no extra texture). The graph recompiles on the next frame.
    pub fn set_overlay(&mut self, overlay: Option<Arc<dyn Overlay>>) {
        self.overlay = overlay;
        self.overlay_generation += 1;
    }

    /// What the adapter can run.
    pub fn support(&self) -> EffectSupport {
        self.support
    }

    /// How many times the graph has been compiled.
    pub fn compiles(&self) -> u64 {
        self.compiles
    }

    /// Vertices in the uploaded scene's vertex buffer, and draws (instanced copies share
    /// their prototype's vertices).
    pub fn scene_size(&self) -> (u32, usize) {
        (self.scene.vertex_count, self.scene.materials.len())
    }

    /// How many material textures were uploaded so far (cached ones count once).
    pub fn material_texture_uploads(&self) -> usize {
        self.textures.uploads()
    }

    /// How many GPU textures the pool has ever created.
    pub fn textures_created(&self) -> usize {
        self.pool.created()
    }

    /// The current compiled graph's passes, textures and bytes.
    pub fn report(&self) -> Option<&GraphReport> {
        self.compiled.as_ref().map(|c| c.graph.report())
    }

    /// Builds the frame's graph (not compiled). `target` is the imported output.
    pub fn build_graph(
        &self,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
        settings: &FrameSettings,
    ) -> Result<(RenderGraph, TextureHandle), RenderError> {
        let p = &self.pipelines;
        let mut g = RenderGraph::new();
        let target = g.import(
            "frame_target",
            TextureDesc {
                width,
                height,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            },
        );
        // With an overlay, the frame is composited first and the overlay pass writes the target.
        let final_target = target;
        let target = match &self.overlay {
            Some(_) => g.create(
                "composited",
                TextureDesc::new(width, height, format.add_srgb_suffix()),
            ),
            None => target,
        };
        let scene = &self.scene;
        let gb = gbuffer_pass(&mut g, (width, height), scene, &p.gbuffer)?;
        let ao = match settings.ssao {
            Some(s) if self.support.ssao => Some(ssao_pass(&mut g, &gb, scene, &s, &p.ssao)?),
            Some(_) => {
                tracing::warn!("SSAO requested but unsupported here: skipped");
                None
            }
            None => None,
        };
        let lit = lighting_pass(&mut g, (&gb, ao), scene, settings.debug_view, &p.lighting)?;
        let hdr = match settings.bloom {
            Some(b) if self.support.bloom => bloom_pass(&mut g, lit, &b, &p.bloom)?,
            Some(_) => {
                tracing::warn!("bloom requested but unsupported here: skipped");
                lit
            }
            None => lit,
        };
        g.export(hdr);
        if settings.blur.is_none() && settings.sobel.is_none() {
            tonemapping_pass(&mut g, hdr, target, &settings.tonemapping, &p.tonemapping)?;
            self.overlay_pass(&mut g, target, final_target)?;
            return Ok((g, hdr));
        }
        let ldr = g.create(
            "ldr",
            TextureDesc::new(width, height, wgpu::TextureFormat::Rgba8UnormSrgb),
        );
        let mut current =
            tonemapping_pass(&mut g, hdr, ldr, &settings.tonemapping, &p.tonemapping)?;
        if let Some(b) = &settings.blur {
            let out = settings.sobel.is_none().then_some(target);
            current = blur_pass(&mut g, current, b, out, &p.blur)?;
        }
        if let Some(s) = &settings.sobel {
            let inputs = SobelInputs {
                color: current,
                depth: Some(gb.depth),
                normal: Some(gb.normal),
                near_far: [self.camera.near, self.camera.far],
            };
            sobel_pass(&mut g, inputs, s, Some(target), &p.sobel)?;
        }
        self.overlay_pass(&mut g, target, final_target)?;
        Ok((g, hdr))
    }

    /// The overlay's pass from the composited frame into the target, when there is an overlay.
    fn overlay_pass(
        &self,
        g: &mut RenderGraph,
        composited: TextureHandle,
        target: TextureHandle,
    ) -> Result<(), RenderError> {
        if let Some(overlay) = &self.overlay {
            overlay_pass(
                g,
                composited,
                target,
                overlay.clone(),
                &self.pipelines.overlay,
            )?;
        }
        Ok(())
    }

    fn prepare(
        &mut self,
        gpu: &GpuContext,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
        settings: &FrameSettings,
    ) -> Result<&Compiled, RenderError> {
        let max = gpu.device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(RenderError::InvalidSize { width, height, max });
        }
        settings.validate()?;
        let key = FrameKey {
            width,
            height,
            format,
            settings: *settings,
            scene_generation: self.scene_generation,
            overlay_generation: self.overlay_generation,
        };
        if let Some(old) = self.compiled.take() {
            if old.key == key {
                return Ok(self.compiled.insert(old));
            }
            self.pool.release(old.graph);
        }
        let (graph, hdr) = self.build_graph(width, height, format, settings)?;
        let graph = graph.compile()?.realize(&gpu.device, &mut self.pool);
        // Textures the new graph did not take back are freed now, not kept.
        self.pool.trim();
        self.compiles += 1;
        tracing::debug!("frame graph compiled: {}", graph.report());
        Ok(self.compiled.insert(Compiled { key, graph, hdr }))
    }

    /// Renders one frame into `target` (a view of a `width × height` texture of `format`).
    /// Does not wait for the GPU.
    pub fn render(
        &mut self,
        gpu: &GpuContext,
        target: &wgpu::TextureView,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
        settings: &FrameSettings,
    ) -> Result<(), RenderError> {
        self.scene
            .write_camera(&gpu.queue, &self.camera, width, height);
        let c = self.prepare(gpu, width, height, format, settings)?;
        c.graph.execute(gpu, &[target])
    }

    /// Renders one frame and measures each pass (GPU timestamps where available).
    pub fn render_timed(
        &mut self,
        gpu: &GpuContext,
        target: &wgpu::TextureView,
        width: u32,
        height: u32,
        format: wgpu::TextureFormat,
        settings: &FrameSettings,
    ) -> Result<PassTimings, RenderError> {
        self.scene
            .write_camera(&gpu.queue, &self.camera, width, height);
        let c = self.prepare(gpu, width, height, format, settings)?;
        let t = c.graph.execute_timed(gpu, &[target])?;
        gpu.take_errors()?;
        Ok(t)
    }

    /// The linear HDR image of the last frame (before tone mapping).
    pub fn hdr_texture(&self) -> Option<&wgpu::Texture> {
        self.compiled.as_ref().and_then(|c| c.graph.texture(c.hdr))
    }

    /// Renders offscreen at `width × height` and reads back the tone-mapped and HDR images.
    pub fn capture(
        &mut self,
        gpu: &GpuContext,
        width: u32,
        height: u32,
        settings: &FrameSettings,
    ) -> Result<Capture, RenderError> {
        let format = wgpu::TextureFormat::Rgba8UnormSrgb;
        let max = gpu.device.limits().max_texture_dimension_2d;
        if width == 0 || height == 0 || width > max || height > max {
            return Err(RenderError::InvalidSize { width, height, max });
        }
        let target = radiant_render::util::target_texture(
            &gpu.device,
            "capture_target",
            width,
            height,
            format,
        );
        let view = target.create_view(&Default::default());
        self.render(gpu, &view, width, height, format, settings)?;
        gpu.take_errors()?;
        let ldr = read_texture(gpu, &target)?;
        let hdr_tex = self.hdr_texture().ok_or(RenderError::NoFrame)?;
        let hdr = read_texture(gpu, hdr_tex)?;
        Ok(Capture { ldr, hdr })
    }
}
