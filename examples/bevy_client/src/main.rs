//! A real engine rendering Radiant's export: Bevy loads the glb that `radiant bake --export`
//! wrote, puts the full-range light map that each primitive names in `extras.lightmap.ktx2`
//! on it as a [`Lightmap`], and captures one frame from the glb's camera, headless (no window,
//! no winit), as a linear EXR of outgoing radiance.
//!
//! ```text
//! radiant_bevy_client SCENE.glb OUT.exr [--size WxH] [--supersample N] [--keep-baked-lights]
//! ```
//!
//! What the export says, and how this client honours it:
//! - a light-map texel holds `H`, incident radiance (irradiance / π): outgoing = base colour ×
//!   `H` + emission. Bevy's lit shader adds `lightmap × lightmap_exposure × diffuse colour`,
//!   so `lightmap_exposure` stays 1 and the camera's exposure is set to 1 (EV100 = log2(1/1.2));
//! - the punctual lights the glb carries are marked `extras.radiant.baked`: their light is in
//!   the light map already. They are left out (their specular highlights alone would differ
//!   from `radiant render`'s diffuse frame), or with `--keep-baked-lights` kept with shadow
//!   maps for their highlights, without lighting the light-mapped diffuse again
//!   (`affects_lightmapped_mesh_diffuse = false`);
//! - ambient light is off (the light map holds the bounces), tone mapping and dithering off,
//!   no MSAA: the frame is rendered `N` times larger and box-filtered, as `radiant render` does
//!   for its comparison, so the two frames can be compared pixel for pixel
//!   (`radiant render --reference-image OUT.exr`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bevy::asset::{AssetPlugin, LoadState, RenderAssetUsages};
use bevy::camera::{Exposure, Hdr, RenderTarget};
use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::gltf::{GltfAssetLabel, GltfExtras};
use bevy::light::GlobalAmbientLight;
use bevy::math::Rect;
use bevy::pbr::Lightmap;
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::RenderPlugin;
use bevy::render::render_resource::{
    Extent3d, PollType, TextureDimension, TextureFormat, TextureUsages,
};
use bevy::render::renderer::RenderDevice;
use bevy::render::view::Msaa;
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::window::{ExitCondition, WindowPlugin};
use bevy::world_serialization::{WorldAsset, WorldAssetRoot};

/// Command-line settings.
struct Args {
    glb: PathBuf,
    out: PathBuf,
    size: (u32, u32),
    supersample: u32,
    keep_baked_lights: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let mut pos = Vec::new();
    let mut size = (256, 256);
    let mut supersample = 4;
    let mut keep_baked_lights = false;
    while let Some(a) = it.next() {
        match a.as_str() {
            "--size" => {
                let v = it.next().ok_or("--size needs WxH")?;
                let (w, h) = v
                    .split_once(['x', 'X'])
                    .ok_or_else(|| format!("--size {v:?} must be WxH"))?;
                let p = |s: &str| {
                    s.trim()
                        .parse::<u32>()
                        .map_err(|e| format!("--size {v:?}: {e}"))
                };
                size = (p(w)?, p(h)?);
            }
            "--supersample" => {
                let v = it.next().ok_or("--supersample needs a number")?;
                supersample = v.parse().map_err(|e| format!("--supersample {v:?}: {e}"))?;
            }
            "--keep-baked-lights" => keep_baked_lights = true,
            "-h" | "--help" => {
                return Err(
                    "usage: radiant_bevy_client SCENE.glb OUT.exr [--size WxH] [--supersample N] [--keep-baked-lights]"
                        .into(),
                );
            }
            _ => pos.push(PathBuf::from(a)),
        }
    }
    let [glb, out] = <[PathBuf; 2]>::try_from(pos).map_err(
        |_| "usage: radiant_bevy_client SCENE.glb OUT.exr [--size WxH] [--supersample N] [--keep-baked-lights]",
    )?;
    let ok = |v: u32| (1..=4096).contains(&v);
    if !ok(size.0) || !ok(size.1) || !(1..=8).contains(&supersample) {
        return Err(format!(
            "--size {}x{} (each side 1 to 4096) or --supersample {supersample} (1 to 8) out of range",
            size.0, size.1
        ));
    }
    if !ok(size.0 * supersample) || !ok(size.1 * supersample) {
        return Err("the supersampled frame must be at most 4096 pixels a side".into());
    }
    Ok(Args {
        glb,
        out,
        size,
        supersample,
        keep_baked_lights,
    })
}

/// The image the camera renders into.
#[derive(Resource, Clone)]
struct Target(Handle<Image>);

/// The glb's scene, while it loads.
#[derive(Resource)]
struct SceneHandle(Handle<WorldAsset>);

/// The light-map pages loaded so far, by their URI.
#[derive(Resource, Default)]
struct LightmapPages(HashMap<String, Handle<Image>>);

/// What the systems found, for the log and the readiness test.
#[derive(Resource, Default)]
struct Found {
    cameras: usize,
    lightmapped: usize,
    unlit: usize,
    baked_lights: usize,
}

/// `--keep-baked-lights`: see [`unbake_lights`].
#[derive(Resource)]
struct KeepBakedLights(bool);

/// Where the captured frame goes (written by the screenshot's observer).
#[derive(Resource, Clone, Default)]
struct Captured(Arc<Mutex<Option<Image>>>);

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("radiant_bevy_client: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let args = parse_args()?;
    let glb =
        std::fs::canonicalize(&args.glb).map_err(|e| format!("{}: {e}", args.glb.display()))?;
    let dir = glb.parent().unwrap_or(Path::new("/")).to_path_buf();
    let name = glb
        .file_name()
        .and_then(|n| n.to_str())
        .ok_or_else(|| format!("{}: not a UTF-8 file name", glb.display()))?
        .to_string();
    let (w, h) = (
        args.size.0 * args.supersample,
        args.size.1 * args.supersample,
    );
    let started = Instant::now();

    let mut app = App::new();
    app.add_plugins(
        DefaultPlugins
            .set(WindowPlugin {
                primary_window: None,
                exit_condition: ExitCondition::DontExit,
                ..default()
            })
            .set(RenderPlugin {
                synchronous_pipeline_compilation: true,
                ..default()
            })
            .set(AssetPlugin {
                file_path: dir.to_string_lossy().into_owned(),
                ..default()
            }),
    )
    // The light map holds the bounces: no ambient term on top of it.
    .insert_resource(GlobalAmbientLight {
        brightness: 0.0,
        ..default()
    })
    // Where no surface is, nothing: black, as `radiant render` and the path tracer clear.
    .insert_resource(ClearColor(Color::BLACK))
    .insert_resource(KeepBakedLights(args.keep_baked_lights))
    .init_resource::<LightmapPages>()
    .init_resource::<Found>()
    .init_resource::<Captured>()
    .add_systems(Update, (take_camera, attach_lightmaps, unbake_lights));

    let target = {
        let mut image = Image::new_uninit(
            Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
            TextureDimension::D2,
            TextureFormat::Rgba16Float,
            RenderAssetUsages::default(),
        );
        image.texture_descriptor.usage |= TextureUsages::RENDER_ATTACHMENT;
        app.world_mut().resource_mut::<Assets<Image>>().add(image)
    };
    app.insert_resource(Target(target.clone()));
    let scene: Handle<WorldAsset> = app
        .world()
        .resource::<AssetServer>()
        .load(GltfAssetLabel::Scene(0).from_asset(name.clone()));
    app.world_mut().spawn(WorldAssetRoot(scene.clone()));
    app.insert_resource(SceneHandle(scene));
    app.finish();
    app.cleanup();

    // Pump frames until the scene, its camera and every light-map page are in, then a few
    // more (pipelines, uploads), then capture.
    let deadline = started + Duration::from_secs(300);
    let mut ready_frames = 0;
    let mut waited_frames = 0;
    let mut asked = false;
    let captured = app.world().resource::<Captured>().clone();
    loop {
        if Instant::now() > deadline {
            return Err(format!(
                "no frame after {:.0} s (scene, camera or light maps never loaded)",
                started.elapsed().as_secs_f64()
            ));
        }
        app.update();
        app.world()
            .resource::<RenderDevice>()
            .wgpu_device()
            .poll(PollType::Wait {
                submission_index: None,
                timeout: None,
            })
            .map_err(|e| format!("GPU: {e}"))?;
        if let Some(image) = captured.0.lock().map_err(|e| e.to_string())?.take() {
            let found = app.world().resource::<Found>();
            eprintln!(
                "{name}: {} light-mapped primitives, {} without a light map, {} baked lights; \
                 frame {w}x{h} captured after {:.2} s",
                found.lightmapped,
                found.unlit,
                found.baked_lights,
                started.elapsed().as_secs_f64()
            );
            return write_exr(&image, args.supersample, &args.out);
        }
        if asked {
            continue;
        }
        if std::env::var_os("RADIANT_BEVY_DEBUG").is_some() {
            let mut q = app
                .world_mut()
                .query::<(&Camera, &RenderTarget, &GlobalTransform)>();
            for (c, t, g) in q.iter(app.world()) {
                eprintln!(
                    "frame {ready_frames}/{waited_frames}: camera active {} target {:?} size {:?} at {:?}",
                    c.is_active,
                    t,
                    c.computed.target_info.as_ref().map(|i| i.physical_size),
                    g.translation()
                );
            }
        }
        let world = app.world();
        let server = world.resource::<AssetServer>();
        let scene = &world.resource::<SceneHandle>().0;
        if let Some(LoadState::Failed(e)) = server.get_load_state(scene) {
            return Err(format!("{}: {e}", glb.display()));
        }
        for (uri, page) in &world.resource::<LightmapPages>().0 {
            if let Some(LoadState::Failed(e)) = server.get_load_state(page) {
                return Err(format!("light map {uri}: {e}"));
            }
        }
        let found = world.resource::<Found>();
        let pages_in = world
            .resource::<LightmapPages>()
            .0
            .values()
            .all(|p| server.is_loaded_with_dependencies(p));
        let ready = server.is_loaded_with_dependencies(scene)
            && found.cameras > 0
            && found.lightmapped > 0
            && pages_in;
        if ready {
            ready_frames += 1;
        } else if server.is_loaded_with_dependencies(scene) {
            waited_frames += 1;
            if waited_frames > 60 && found.cameras == 0 {
                return Err(format!("{}: the glb has no camera", glb.display()));
            }
            if waited_frames > 60 && found.lightmapped == 0 {
                return Err(format!(
                    "{}: no primitive names a light map (extras.lightmap.ktx2)",
                    glb.display()
                ));
            }
        }
        if ready && ready_frames >= 8 {
            let sink = captured.clone();
            app.world_mut()
                .spawn(Screenshot::image(target.clone()))
                .observe(move |shot: On<ScreenshotCaptured>| {
                    if let Ok(mut slot) = sink.0.lock() {
                        *slot = Some(shot.image.clone());
                    }
                });
            asked = true;
        }
    }
}

/// The glb's first camera renders into the target: linear radiance, exposure 1, no tone
/// mapping, dithering or MSAA.
fn take_camera(
    mut commands: Commands,
    mut cameras: Query<(Entity, &Camera, &mut Projection), Added<Camera3d>>,
    target: Res<Target>,
    mut found: ResMut<Found>,
) {
    for (entity, camera, mut projection) in &mut cameras {
        if !camera.is_active {
            continue;
        }
        // Bevy sizes a camera's view from its target when the camera is added or its
        // projection changes, not when its target does.
        projection.set_changed();
        commands.entity(entity).insert((
            RenderTarget::Image(target.0.clone().into()),
            Hdr,
            Tonemapping::None,
            DebandDither::Disabled,
            Msaa::Off,
            Exposure {
                ev100: (1.0f32 / 1.2).log2(),
            },
        ));
        found.cameras += 1;
    }
}

/// Each primitive whose `extras.lightmap.ktx2` names a page gets it as its [`Lightmap`]
/// (TEXCOORD_1 is already on the page: the whole page is the rectangle).
fn attach_lightmaps(
    mut commands: Commands,
    prims: Query<(Entity, &GltfExtras), (With<Mesh3d>, Without<Lightmap>)>,
    server: Res<AssetServer>,
    mut pages: ResMut<LightmapPages>,
    mut found: ResMut<Found>,
) {
    for (entity, extras) in &prims {
        let uri = serde_json::from_str::<serde_json::Value>(&extras.value)
            .ok()
            .and_then(|v| v["lightmap"]["ktx2"].as_str().map(str::to_owned));
        let Some(uri) = uri else {
            found.unlit += 1;
            continue;
        };
        let image = pages
            .0
            .entry(uri.clone())
            .or_insert_with(|| server.load(uri))
            .clone();
        commands.entity(entity).insert(Lightmap {
            image,
            uv_rect: Rect::new(0.0, 0.0, 1.0, 1.0),
            bicubic_sampling: false,
        });
        found.lightmapped += 1;
    }
}

/// True when a light's `extras` say Radiant baked it.
fn baked(extras: &GltfExtras) -> bool {
    serde_json::from_str::<serde_json::Value>(&extras.value)
        .ok()
        .and_then(|v| v["radiant"]["baked"].as_bool())
        .unwrap_or(false)
}

/// Punctual lights already in the light map (`extras.radiant.baked`). By default they go: the
/// light map holds their diffuse light, and their specular highlights alone, which `radiant
/// render` does not draw, would differ from its frame. With `--keep-baked-lights` they stay for
/// their highlights, with shadow maps, and do not light the light-mapped meshes' diffuse again
/// (`affects_lightmapped_mesh_diffuse = false`), as a game would keep them.
fn unbake_lights(
    mut commands: Commands,
    mut points: Query<(Entity, &mut PointLight, &GltfExtras), Added<PointLight>>,
    mut spots: Query<(Entity, &mut SpotLight, &GltfExtras), Added<SpotLight>>,
    mut suns: Query<(Entity, &mut DirectionalLight, &GltfExtras), Added<DirectionalLight>>,
    keep: Res<KeepBakedLights>,
    mut found: ResMut<Found>,
) {
    // The three kinds share the fields this touches, not a trait.
    macro_rules! unbake {
        ($query:ident, $kind:ty) => {
            for (entity, mut l, e) in &mut $query {
                if baked(e) {
                    found.baked_lights += 1;
                    if keep.0 {
                        l.affects_lightmapped_mesh_diffuse = false;
                        l.shadow_maps_enabled = true;
                    } else {
                        commands.entity(entity).remove::<$kind>();
                    }
                }
            }
        };
    }
    unbake!(points, PointLight);
    unbake!(spots, SpotLight);
    unbake!(suns, DirectionalLight);
}

/// Box-filters the captured frame by `ss` and writes it as a linear RGBA float EXR.
fn write_exr(image: &Image, ss: u32, out: &Path) -> Result<(), String> {
    let format = image.texture_descriptor.format;
    if format != TextureFormat::Rgba16Float {
        return Err(format!("captured a {format:?} frame, expected Rgba16Float"));
    }
    let (w, h) = (image.width(), image.height());
    let data = image
        .data
        .as_ref()
        .ok_or("the captured frame has no data")?;
    if data.len() != (w * h * 8) as usize {
        return Err(format!("captured {} bytes for {w}x{h}", data.len()));
    }
    let texel = |x: u32, y: u32, c: u32| {
        let i = ((y * w + x) * 4 + c) as usize * 2;
        f64::from(half::f16::from_le_bytes([data[i], data[i + 1]]).to_f32())
    };
    let (ow, oh) = (w / ss, h / ss);
    let norm = 1.0 / f64::from(ss * ss);
    let mut out_px = Vec::with_capacity((ow * oh * 4) as usize);
    for y in 0..oh {
        for x in 0..ow {
            for c in 0..4 {
                let mut acc = 0.0;
                for j in 0..ss {
                    for i in 0..ss {
                        acc += texel(x * ss + i, y * ss + j, c);
                    }
                }
                out_px.push((acc * norm) as f32);
            }
        }
    }
    if let Some(bad) = out_px.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "the frame has a non-finite value at pixel {}",
            bad / 4
        ));
    }
    if out_px.iter().all(|&v| v == 0.0) {
        return Err("the frame is black: nothing was drawn into it".into());
    }
    let buf = image::Rgba32FImage::from_raw(ow, oh, out_px).ok_or("frame size")?;
    image::DynamicImage::ImageRgba32F(buf)
        .save_with_format(out, image::ImageFormat::OpenExr)
        .map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!(
        "wrote {} ({ow}x{oh}, {ss}x{ss} supersampled)",
        out.display()
    );
    Ok(())
}
