//! The GPU context: instance, adapter, device and queue, headless or for a surface.
//!
//! Adapter choice honours `WGPU_BACKEND` (`vulkan`, `gl`, `metal`, `dx12`, comma-separated) and
//! `WGPU_ADAPTER_NAME` (a case-insensitive substring of the adapter's name), and accepts software
//! adapters such as Mesa's lavapipe. Unlike `wgpu::util::initialize_adapter_from_env`, a name that
//! matches nothing is an error that lists the adapters there are, not a panic.

use std::sync::{Arc, Mutex};

use crate::RenderError;

/// How to install a software Vulkan adapter, for error messages.
pub const SOFTWARE_ADAPTER_HINT: &str = "no GPU adapter found. Install a Vulkan driver; with no GPU, Mesa's software \
     rasteriser lavapipe works (Debian/Ubuntu: `sudo apt-get install mesa-vulkan-drivers libvulkan1`), \
     then run with WGPU_BACKEND=vulkan";

/// Features a pass may need beyond WebGPU's baseline, and the formats it must render to or store.
#[derive(Clone, Debug, Default)]
pub struct Requirements {
    /// Device features the pass uses.
    pub features: wgpu::Features,
    /// Formats the pass writes as storage textures.
    pub storage_formats: Vec<wgpu::TextureFormat>,
    /// Formats the pass renders to, with blending where the flag is set.
    pub render_formats: Vec<(wgpu::TextureFormat, bool)>,
}

/// What an adapter lacks for a pass ([`GpuContext::check`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Missing {
    /// Device features.
    #[error("missing features {0:?}")]
    Features(wgpu::Features),
    /// A format the pass writes as a storage texture.
    #[error("{0:?} is not usable as a storage texture")]
    Storage(wgpu::TextureFormat),
    /// A format the pass renders to.
    #[error("{0:?} is not renderable")]
    Render(wgpu::TextureFormat),
    /// A format the pass blends into.
    #[error("{0:?} is not blendable")]
    Blend(wgpu::TextureFormat),
}

/// An adapter, its device and queue, and what they can do.
pub struct GpuContext {
    /// The instance the adapter came from (needed to create surfaces).
    pub instance: wgpu::Instance,
    /// The chosen adapter.
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Name, backend and driver of the adapter.
    pub info: wgpu::AdapterInfo,
    /// Features enabled on the device (timestamp queries, clip distances and filtered f32 textures
    /// when the adapter has them).
    pub features: wgpu::Features,
    errors: Arc<Mutex<Vec<String>>>,
}

impl GpuContext {
    /// A context with no window, for offscreen rendering and tests.
    ///
    /// Without `WGPU_BACKEND`, the primary backends (Vulkan, Metal, DX12) are tried first and
    /// the GL fallback only when they have no adapter, so machines without GL drivers log no
    /// GL errors.
    pub fn headless() -> Result<Self, RenderError> {
        let from_env = std::env::var_os("WGPU_BACKEND").is_some();
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if !from_env {
            desc.backends = wgpu::Backends::PRIMARY;
        }
        match pollster::block_on(Self::from_instance(wgpu::Instance::new(desc), None)) {
            Err(RenderError::NoAdapter) if !from_env => {
                let instance = wgpu::Instance::new(
                    wgpu::InstanceDescriptor::new_without_display_handle_from_env(),
                );
                pollster::block_on(Self::from_instance(instance, None))
            }
            other => other,
        }
    }

    /// A context on `instance` whose adapter can present to `surface`, if one is given.
    pub async fn from_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Self, RenderError> {
        let adapter = choose_adapter(&instance, surface).await?;
        let info = adapter.get_info();
        // Clip distances and filtered f32 textures: the GPU hemicube gather (`radiant_gather`)
        // clips each face to its cell and samples an f32 light map.
        let wanted = wgpu::Features::TIMESTAMP_QUERY
            | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS
            | wgpu::Features::TIMESTAMP_QUERY_INSIDE_PASSES
            | wgpu::Features::CLIP_DISTANCES
            | wgpu::Features::FLOAT32_FILTERABLE;
        let features = adapter.features() & wanted;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("radiant_device"),
                required_features: features,
                required_limits: adapter.limits(),
                ..Default::default()
            })
            .await
            .map_err(RenderError::RequestDevice)?;
        // wgpu's default handler panics on a validation error; record it and fail the frame.
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            tracing::error!("wgpu: {e}");
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        tracing::info!(
            "GPU adapter: {} ({:?}, {})",
            info.name,
            info.backend,
            info.driver
        );
        Ok(Self {
            instance,
            adapter,
            device,
            queue,
            info,
            features,
            errors,
        })
    }

    /// Whether GPU timestamps can be written between passes.
    pub fn has_timestamps(&self) -> bool {
        self.features.contains(
            wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TIMESTAMP_QUERY_INSIDE_ENCODERS,
        )
    }

    /// Checks that the adapter can run a pass; `Err` says what is missing.
    pub fn check(&self, req: &Requirements) -> Result<(), Missing> {
        let missing = req.features - self.adapter.features();
        if !missing.is_empty() {
            return Err(Missing::Features(missing));
        }
        for &f in &req.storage_formats {
            let ff = self.adapter.get_texture_format_features(f);
            if !ff
                .allowed_usages
                .contains(wgpu::TextureUsages::STORAGE_BINDING)
            {
                return Err(Missing::Storage(f));
            }
        }
        for &(f, blend) in &req.render_formats {
            let ff = self.adapter.get_texture_format_features(f);
            if !ff
                .allowed_usages
                .contains(wgpu::TextureUsages::RENDER_ATTACHMENT)
            {
                return Err(Missing::Render(f));
            }
            if blend
                && !ff
                    .flags
                    .contains(wgpu::TextureFormatFeatureFlags::BLENDABLE)
            {
                return Err(Missing::Blend(f));
            }
        }
        Ok(())
    }

    /// The validation errors recorded so far, without waiting for the GPU (errors of work still
    /// in flight show up in a later call).
    pub fn poll_errors(&self) -> Result<(), RenderError> {
        let errors = match self.errors.lock() {
            Ok(mut v) => std::mem::take(&mut *v),
            Err(_) => vec!["error log poisoned".into()],
        };
        if errors.is_empty() {
            Ok(())
        } else {
            Err(RenderError::Gpu(errors.join("; ")))
        }
    }

    /// Waits for the GPU and returns the validation errors raised since the last call.
    pub fn take_errors(&self) -> Result<(), RenderError> {
        let _ = self.device.poll(wgpu::PollType::wait_indefinitely());
        self.poll_errors()
    }
}

async fn choose_adapter(
    instance: &wgpu::Instance,
    surface: Option<&wgpu::Surface<'_>>,
) -> Result<wgpu::Adapter, RenderError> {
    let adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
    let usable: Vec<wgpu::Adapter> = adapters
        .into_iter()
        .filter(|a| surface.is_none_or(|s| a.is_surface_supported(s)))
        .collect();
    if let Ok(name) = std::env::var("WGPU_ADAPTER_NAME") {
        let want = name.to_lowercase();
        let names: Vec<String> = usable.iter().map(|a| a.get_info().name).collect();
        return usable
            .into_iter()
            .find(|a| a.get_info().name.to_lowercase().contains(&want))
            .ok_or(RenderError::AdapterNotFound {
                name,
                available: names,
            });
    }
    let power = wgpu::PowerPreference::from_env().unwrap_or_default();
    match instance
        .request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: power,
            compatible_surface: surface,
            force_fallback_adapter: false,
            apply_limit_buckets: false,
        })
        .await
    {
        Ok(a) => Ok(a),
        // request_adapter may refuse a CPU adapter; take any usable one then.
        Err(_) => usable.into_iter().next().ok_or(RenderError::NoAdapter),
    }
}
