//! Post-processing on Radiant's render graph, one folder per effect, and the assembled frame.
//!
//! - [`bloom`]: Jimenez 2014 mip chain or the lecture's bright pass + Gaussian;
//! - [`tonemapping`]: exposure and six operators (CPU twins in `radiant_color::Tonemap`);
//! - [`sobel`]: edge overlay on colour, depth or normals;
//! - [`blur`]: separable Gaussian;
//! - [`overlay`]: a GUI drawn as the frame's last pass;
//! - [`frame`]: the standard frame, with every optional effect an `Option`.
//!
//! ```no_run
//! use radiant_post::frame::{FrameRenderer, FrameSettings};
//! use radiant_render::{GpuContext, scene::RenderScene};
//!
//! let gpu = GpuContext::headless()?;
//! let scene = radiant_scene::builtin("cornell-box").expect("builtin scene");
//! let mut render_scene = RenderScene::from_scene(&scene, None)?;
//! render_scene.fill_synthetic_lightmap(0.02);
//! let mut frame = FrameRenderer::new(&gpu, &render_scene)?;
//! let capture = frame.capture(&gpu, 256, 256, &FrameSettings::default())?;
//! radiant_render::capture::write_png("frame.png".as_ref(), &capture.ldr)?;
//! # Ok::<(), radiant_render::RenderError>(())
//! ```

pub mod bloom;
pub mod blur;
pub mod frame;
pub mod overlay;
pub mod sobel;
pub mod tonemapping;

/// Every shader of this crate, as (name, full source), for validation.
pub fn shaders() -> Vec<(&'static str, String)> {
    vec![
        ("bloom", bloom::shader_source()),
        ("blur", blur::shader_source()),
        ("overlay", overlay::shader_source()),
        ("sobel", sobel::shader_source()),
        ("tonemapping", tonemapping::shader_source()),
    ]
}
