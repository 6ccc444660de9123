//! Radiant's renderer on wgpu: the GPU context, the render graph, the G-buffer, tiled deferred
//! lighting, SSAO and offscreen capture. Post-processing (bloom, tone mapping, Sobel, blur) and
//! the assembled frame live in `radiant_post`.
//!
//! The renderer consumes light maps; it never runs the radiosity solver.
//!
//! ```no_run
//! use radiant_render::{GpuContext, graph::{RenderGraph, TexturePool}};
//! let gpu = GpuContext::headless()?; // honours WGPU_BACKEND and WGPU_ADAPTER_NAME
//! println!("{}", gpu.info.name);
//! # Ok::<(), radiant_render::RenderError>(())
//! ```

pub mod capture;
pub mod context;
pub mod gbuffer;
pub mod graph;
pub mod instancing;
pub mod lighting;
pub mod material;
pub mod pass;
pub mod scene;
pub mod ssao;
pub mod util;

pub use context::{GpuContext, Requirements};
pub use wgpu;

/// The WGSL prelude every shader of the renderer starts with: the camera block, the fullscreen
/// triangle, octahedral normals and depth reconstruction.
pub const COMMON_WGSL: &str = include_str!("common.wgsl");

/// Every shader of this crate, as (name, full source), for validation.
pub fn shaders() -> Vec<(&'static str, String)> {
    vec![
        ("gbuffer", gbuffer::shader_source()),
        ("lighting", lighting::shader_source()),
        ("ssao", ssao::shader_source()),
        ("ssao_blur", ssao::blur_shader_source()),
    ]
}

/// Why rendering failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No adapter at all.
    #[error("{}", context::SOFTWARE_ADAPTER_HINT)]
    NoAdapter,
    /// `WGPU_ADAPTER_NAME` matched none of the adapters.
    #[error("WGPU_ADAPTER_NAME={name:?} matches no adapter; available: {available:?}")]
    AdapterNotFound {
        /// The requested name.
        name: String,
        /// The adapters there are.
        available: Vec<String>,
    },
    /// The adapter refused to create a device.
    #[error("could not create a GPU device: {0}")]
    RequestDevice(wgpu::RequestDeviceError),
    /// A pass needs something the adapter lacks (essential passes only; optional ones are
    /// skipped with a warning).
    #[error("pass `{pass}` cannot run on this adapter: {reason}")]
    Unsupported {
        /// The pass.
        pass: &'static str,
        /// What is missing.
        reason: context::Missing,
    },
    /// A pass needs an input its caller did not give.
    #[error("pass `{pass}` needs the {input} texture")]
    MissingInput {
        /// The pass.
        pass: &'static str,
        /// The input it needs.
        input: &'static str,
    },
    /// A wgpu validation or out-of-memory error.
    #[error("GPU error: {0}")]
    Gpu(String),
    /// A render graph that does not compile or run.
    #[error("render graph: {0}")]
    Graph(#[from] graph::GraphError),
    /// A frame's texture was asked for before any frame was rendered.
    #[error("no frame has been rendered yet")]
    NoFrame,
    /// Reading a texture back failed.
    #[error("readback failed: {0}")]
    Readback(#[from] capture::ReadbackError),
    /// The target size is zero or above the adapter's limit.
    #[error("size {width}×{height} is outside 1..={max} per side")]
    InvalidSize {
        /// Width asked for.
        width: u32,
        /// Height asked for.
        height: u32,
        /// The adapter's largest 2D texture.
        max: u32,
    },
    /// A setting outside its documented range.
    #[error("{field} = {value} is outside its range {range}")]
    InvalidSetting {
        /// The field, as `effect.field`.
        field: &'static str,
        /// The value given.
        value: f64,
        /// The valid range.
        range: &'static str,
    },
    /// The scene is inconsistent (a triangle naming a missing surface, say).
    #[error("invalid scene: {0}")]
    InvalidScene(#[from] scene::SceneError),
    /// The scene has no triangles.
    #[error("the scene has no triangles to draw")]
    EmptyScene,
    /// The scene's light-map atlas could not be made.
    #[error("light-map atlas: {0}")]
    Atlas(#[from] radiant_scene::atlas::AtlasError),
    /// An index past the vertex buffer.
    #[error("index {index} is past the {vertices} vertices")]
    IndexOutOfRange {
        /// The index.
        index: u32,
        /// Vertex count.
        vertices: usize,
    },
    /// NaN or infinity in scene data.
    #[error("non-finite values in the {0}")]
    NonFinite(&'static str),
    /// A probe grid whose probes do not fill its dimensions.
    #[error("a probe grid of {dims:?} probes holds {probes}")]
    ProbeLayout {
        /// Probes along x, y and z.
        dims: [u32; 3],
        /// Probes given.
        probes: usize,
    },
    /// Encoding an image failed.
    #[error("image encoding: {0}")]
    Image(#[from] image::ImageError),
    /// An image whose texels do not fill its size.
    #[error("an image of {width}×{height} with {texels} texels")]
    ImageSize {
        /// Width.
        width: u32,
        /// Height.
        height: u32,
        /// Texels given.
        texels: usize,
    },
    /// A window surface could not be created.
    #[error("cannot create a surface: {0}")]
    Surface(#[from] wgpu::CreateSurfaceError),
    /// The window surface offers no format to render to.
    #[error("the surface supports no format")]
    NoSurfaceFormat,
    /// A file could not be written.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}
