//! An overlay drawn as the last pass of the frame: a GUI (the egui inspector) or anything else
//! that paints over the finished image.
//!
//! The graph has one writer per texture, so with an overlay the frame is composited into a
//! transient sRGB texture first; the overlay pass copies it into the target (encoding it when
//! the target is a linear format, as egui prefers) and draws on top in the same render pass.
//! Without an overlay none of this is in the graph.

use std::sync::Arc;

use radiant_render::graph::{RenderGraph, TextureHandle};
use radiant_render::pass::{FullscreenEffect, Slot, UNFILTERABLE};
use radiant_render::{COMMON_WGSL, RenderError, wgpu};

/// Something that draws over the finished frame. It is called from the graph's last pass, so
/// it must hold its per-frame data behind interior mutability (set it before rendering).
pub trait Overlay: Send + Sync {
    /// Uploads this frame's buffers; called before the overlay's render pass begins.
    fn prepare(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        size: (u32, u32),
    );
    /// Records the draws into the render pass (the frame is already in it).
    fn draw(&self, pass: &mut wgpu::RenderPass<'static>, size: (u32, u32));
}

/// The overlay pass's copy pipeline.
pub struct OverlayPipeline(FullscreenEffect);

impl OverlayPipeline {
    /// Declares the bindings; pipelines are made per target format on first use.
    pub fn new(device: &wgpu::Device) -> Self {
        Self(FullscreenEffect::new(
            device,
            "overlay_copy",
            shader_source(),
            &[Slot::Texture(UNFILTERABLE)],
        ))
    }
}

/// The shader (with the shared prelude).
pub fn shader_source() -> String {
    format!("{COMMON_WGSL}{}", include_str!("overlay.wgsl"))
}

/// Adds the pass that copies `frame` into `target` and then lets `overlay` draw over it;
/// returns `target`.
pub fn overlay_pass(
    graph: &mut RenderGraph,
    frame: TextureHandle,
    target: TextureHandle,
    overlay: Arc<dyn Overlay>,
    pipeline: &OverlayPipeline,
) -> Result<TextureHandle, RenderError> {
    let desc = graph.desc(target);
    // A linear-format target (egui blends correctly only there) gets sRGB-encoded values.
    let entry = if desc.format.is_srgb() {
        "overlay_copy_fs"
    } else {
        "overlay_copy_encode_fs"
    };
    let size = (desc.width, desc.height);
    let record = move |ctx: &mut radiant_render::graph::PassContext<'_>,
                       rp: &wgpu::RenderPipeline,
                       bind: &wgpu::BindGroup,
                       view: &wgpu::TextureView| {
        overlay.prepare(ctx.device, ctx.queue, ctx.encoder, size);
        let mut pass = ctx
            .encoder
            .begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("overlay_pass"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            })
            .forget_lifetime();
        pass.set_pipeline(rp);
        pass.set_bind_group(0, bind, &[]);
        pass.draw(0..3, 0..1);
        overlay.draw(&mut pass, size);
        Ok(())
    };
    pipeline
        .0
        .pass(graph, "overlay_pass")
        .read(frame)
        .raster(entry, target, record)?;
    Ok(target)
}
