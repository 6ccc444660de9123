//! The window's surface: its format, configuration, resizes, and the texture of each frame
//! (the surface half of wgpu's example framework).

use radiant_render::{GpuContext, RenderError, wgpu};

/// The configured surface.
pub(crate) struct SurfaceState {
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    /// Set when the surface asked to be reconfigured while a frame was held.
    reconfigure: bool,
}

impl SurfaceState {
    /// Picks the format and configures the surface at `(width, height)`.
    ///
    /// egui blends correctly only into a linear-format target and the 3D frame wants sRGB: the
    /// surface is configured in the linear format and viewed as sRGB when the inspector is
    /// hidden, where the adapter can view a surface in another format.
    pub(crate) fn new(
        gpu: &GpuContext,
        surface: wgpu::Surface<'static>,
        (width, height): (u32, u32),
    ) -> Result<Self, RenderError> {
        let caps = surface.get_capabilities(&gpu.adapter);
        let preferred = caps
            .formats
            .first()
            .copied()
            .ok_or(RenderError::NoSurfaceFormat)?;
        let linear = preferred.remove_srgb_suffix();
        let view_formats_ok = gpu
            .adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::SURFACE_VIEW_FORMATS);
        let format = if view_formats_ok && caps.formats.contains(&linear) {
            linear
        } else {
            preferred
        };
        let srgb = format.add_srgb_suffix();
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: width.max(1),
            height: height.max(1),
            present_mode: wgpu::PresentMode::AutoVsync,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps
                .alpha_modes
                .first()
                .copied()
                .unwrap_or(wgpu::CompositeAlphaMode::Auto),
            view_formats: if srgb != format { vec![srgb] } else { vec![] },
            color_space: Default::default(),
        };
        surface.configure(&gpu.device, &config);
        gpu.take_errors()?;
        Ok(Self {
            surface,
            config,
            reconfigure: false,
        })
    }

    /// The configured (linear where possible) format.
    pub(crate) fn format(&self) -> wgpu::TextureFormat {
        self.config.format
    }

    /// Width and height in pixels.
    pub(crate) fn size(&self) -> (u32, u32) {
        (self.config.width, self.config.height)
    }

    /// Reconfigures at a new size (not at zero: a minimised window keeps its surface).
    pub(crate) fn resize(&mut self, gpu: &GpuContext, width: u32, height: u32) {
        if width == 0 || height == 0 {
            return;
        }
        self.config.width = width;
        self.config.height = height;
        self.surface.configure(&gpu.device, &self.config);
    }

    /// This frame's texture, or `None` when there is none to draw into now (timeout, occluded,
    /// outdated or lost: the surface is reconfigured and the next frame tries again).
    pub(crate) fn acquire(
        &mut self,
        gpu: &GpuContext,
    ) -> Result<Option<wgpu::SurfaceTexture>, RenderError> {
        Ok(match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) => Some(t),
            wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
                // Reconfigure after presenting: not while this texture is held.
                self.reconfigure = true;
                Some(t)
            }
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => None,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&gpu.device, &self.config);
                None
            }
            wgpu::CurrentSurfaceTexture::Validation => {
                gpu.take_errors()?;
                None
            }
        })
    }

    /// A view of `frame` and its format: linear under the overlay (which encodes), sRGB
    /// without.
    pub(crate) fn view(
        &self,
        frame: &wgpu::SurfaceTexture,
        overlay: bool,
    ) -> (wgpu::TextureView, wgpu::TextureFormat) {
        let format = if overlay {
            self.config.format
        } else {
            self.config.format.add_srgb_suffix()
        };
        let view = frame.texture.create_view(&wgpu::TextureViewDescriptor {
            format: Some(format),
            ..Default::default()
        });
        (view, format)
    }

    /// Presents `frame`, then reconfigures if the surface asked for it.
    pub(crate) fn present(&mut self, gpu: &GpuContext, frame: wgpu::SurfaceTexture) {
        gpu.queue.present(frame);
        if std::mem::take(&mut self.reconfigure) {
            self.surface.configure(&gpu.device, &self.config);
        }
    }
}
