//! Extraction to the renderer (feature `render`): effect components on the camera, the baked
//! light as a light map, and a frame rendered every update: offscreen, or by a window into its
//! surface with [`render_to`] (with `RenderSettings::offscreen` off).
//!
//! Effects are components named after the feature, on the [`SceneCamera`] entity: insert
//! [`Bloom`], [`Ssao`], [`Sobel`] or [`GaussianBlur`] to turn one on, remove it to turn it off;
//! with none, their passes are culled and nothing is extracted for them. [`Tonemapping`] and
//! [`DebugView`] fall back to their defaults.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use bevy_tasks::{AsyncComputeTaskPool, Task, TaskPool, futures::check_ready};
use radiant_post::frame::{FrameRenderer, FrameSettings};
use radiant_radiosity::smooth::SmoothField;
use radiant_radiosity::texel_light::TexelBasis;
use radiant_radiosity::{Mesh, Rgb};
use radiant_render::capture::Image;
use radiant_render::scene::{CameraView, RenderScene};
use radiant_render::{GpuContext, RenderError};
use radiant_scene::Scene;

use crate::app::{App, Plugin, PostUpdate};
use crate::bake::{BakeSystems, BakedLighting};
use crate::scene::{SceneCamera, gather_render_scene};

// The effect settings are the components (feature `bevy_ecs` of `radiant_post` and
// `radiant_render`, as Bevy derives `Component` on its own settings): on the camera entity,
// present → the effect's passes run; absent → they are culled. Tone mapping and the debug view
// default to ACES at 0 EV and the lit image when absent.
pub use radiant_post::bloom::Bloom;
pub use radiant_post::blur::GaussianBlur;
pub use radiant_post::sobel::Sobel;
pub use radiant_post::tonemapping::Tonemapping;
pub use radiant_render::lighting::DebugView;
pub use radiant_render::ssao::Ssao;

/// Renderer settings.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Frame size in pixels (default: 512 × 512).
    pub size: (u32, u32),
    /// Light-map texels per scene unit (default `None`: the atlas's automatic density, see
    /// `radiant_scene::atlas::Atlas::auto_density`).
    pub texel_density: Option<f64>,
    /// Light updates whose largest relative change is below this are not uploaded, unless the
    /// bake converged (default: 0.002, under one 8-bit step).
    pub visible_change: f64,
    /// Read every frame back into [`LastFrame`] (default: false; tests and tools turn it on).
    pub capture: bool,
    /// Draw a frame offscreen every update (default: true). A window turns it off and draws
    /// into its surface with [`render_to`]; the renderer is still kept up to date.
    pub offscreen: bool,
    /// Light maps of at most this many texels get their per-texel basis (the lights' direct
    /// light per texel, the open part at contacts: `radiant_radiosity::texel_light`) at once,
    /// in the frame that needs it (the Cornell box's 0.3 M: about 0.07 s); larger ones in the
    /// background, frames meanwhile drawing the elements' light (default: [`BASIS_AT_ONCE`]).
    pub basis_at_once: u64,
}

impl Default for RenderSettings {
    fn default() -> Self {
        Self {
            size: (512, 512),
            texel_density: None,
            visible_change: 0.002,
            capture: false,
            offscreen: true,
            basis_at_once: BASIS_AT_ONCE,
        }
    }
}

/// The GPU, created by [`RenderPlugin::finish`].
#[derive(Resource)]
pub struct Gpu(pub GpuContext);

/// The renderer and what it last drew.
#[derive(Resource, Default)]
pub struct RenderState {
    renderer: Option<FrameRenderer>,
    scene: Option<Arc<Scene>>,
    uploaded_generation: Option<u64>,
    uploaded_light: Option<Arc<Vec<Rgb>>>,
    /// [`crate::probes::BakedProbes::published`] when the scene was last built.
    uploaded_probes: u64,
    /// Light-map atlases made so far (UV charts: a new light, a material or a moved dynamic
    /// mesh keeps the last one).
    pub atlases: u64,
    target: Option<(u32, u32, radiant_render::wgpu::Texture)>,
    /// Light maps uploaded so far.
    pub uploads: u64,
    /// Frames rendered.
    pub frames: u64,
    /// Settings of the last frame.
    pub settings: Option<FrameSettings>,
    /// The last error, if rendering failed.
    pub error: Option<Arc<RenderError>>,
    /// The last measured pass times ([`render_to`] with `timed`).
    pub timings: Option<radiant_render::graph::PassTimings>,
    /// The light map's atlas as last uploaded.
    pub atlas: Option<AtlasReport>,
    /// That atlas and the density it was made at, reused while the geometry stays the same.
    last_atlas: Option<(Option<f64>, radiant_scene::atlas::Atlas)>,
    /// The light map's per-texel basis (the lights' direct light per texel, what contacts
    /// bury: `radiant_radiosity::texel_light`), kept while the mesh, the atlas, the lights and
    /// the alpha modes stay the same, so a material edit recomposes the map without a ray.
    basis: Option<BasisCache>,
    /// A basis being made in the background (light maps over [`BASIS_AT_ONCE`] texels).
    pending_basis: Option<(BasisCache, Task<TexelBasis>)>,
    /// Whether the last light map was composed on its basis.
    drawn_per_texel: bool,
    pending_overlay: Option<Option<Arc<dyn radiant_post::overlay::Overlay>>>,
}

/// The default of [`RenderSettings::basis_at_once`]: 1 M texels (about 0.75 s of rays).
pub const BASIS_AT_ONCE: u64 = 1 << 20;

/// A [`TexelBasis`] and what it was made for.
struct BasisCache {
    mesh: Arc<Mesh>,
    atlas: radiant_scene::atlas::Atlas,
    lights: Vec<radiant_scene::Light>,
    alpha: Vec<radiant_scene::AlphaMode>,
    basis: Option<Arc<TexelBasis>>,
}

impl BasisCache {
    fn new(mesh: &Arc<Mesh>, atlas: &radiant_scene::atlas::Atlas, scene: &Scene) -> BasisCache {
        BasisCache {
            mesh: Arc::clone(mesh),
            atlas: atlas.clone(),
            lights: scene.lights.clone(),
            alpha: scene.surfaces.iter().map(|s| s.alpha).collect(),
            basis: None,
        }
    }

    /// Whether it was made for `mesh`, `atlas` and `scene`.
    fn holds(&self, mesh: &Arc<Mesh>, atlas: &radiant_scene::atlas::Atlas, scene: &Scene) -> bool {
        Arc::ptr_eq(&self.mesh, mesh)
            && self.atlas == *atlas
            && self.lights == scene.lights
            && self
                .alpha
                .iter()
                .eq(scene.surfaces.iter().map(|s| &s.alpha))
    }
}

/// The basis of `scene`'s light map on `atlas` for bakes on `mesh` (rays against the bake's
/// BVH, as `radiant_radiosity::texel_light` casts them).
fn make_basis(scene: &Scene, atlas: &radiant_scene::atlas::Atlas, mesh: &Mesh) -> TexelBasis {
    let masks = radiant_radiosity::input::masks(&radiant_radiosity::input::static_scene(scene));
    let bvh = radiant_radiosity::input::visibility(mesh, masks.as_ref());
    TexelBasis::new(scene, atlas, mesh, bvh)
}

/// The basis for `mesh`, `atlas` and `scene`: the kept one, one made now (small maps), or
/// `None` while one is made in the background.
fn basis_for(
    state: &mut RenderState,
    (scene, atlas, mesh): (&Scene, &radiant_scene::atlas::Atlas, &Arc<Mesh>),
    at_once: u64,
) -> Option<Arc<TexelBasis>> {
    if let Some(c) = state.basis.as_ref().filter(|c| c.holds(mesh, atlas, scene)) {
        return c.basis.clone();
    }
    let texels = u64::from(atlas.width) * u64::from(atlas.height) * u64::from(atlas.pages);
    if texels <= at_once {
        let basis = Arc::new(make_basis(scene, atlas, mesh));
        let mut c = BasisCache::new(mesh, atlas, scene);
        c.basis = Some(Arc::clone(&basis));
        state.basis = Some(c);
        return Some(basis);
    }
    if !state
        .pending_basis
        .as_ref()
        .is_some_and(|(c, _)| c.holds(mesh, atlas, scene))
    {
        let key = BasisCache::new(mesh, atlas, scene);
        let (scene, atlas, mesh) = (scene.clone(), atlas.clone(), Arc::clone(mesh));
        let pool = AsyncComputeTaskPool::get_or_init(TaskPool::new);
        let task = pool.spawn(async move { make_basis(&scene, &atlas, &mesh) });
        state.pending_basis = Some((key, task));
    }
    None
}

impl RenderState {
    /// Whether the light map drawn last was composed on its per-texel basis (see
    /// [`RenderSettings::basis_at_once`]), not from the elements alone while one is made.
    pub fn light_map_per_texel(&self) -> bool {
        self.drawn_per_texel
    }

    /// The compiled graph's report, once a frame was drawn.
    pub fn graph(&self) -> Option<&radiant_render::graph::GraphReport> {
        self.renderer.as_ref().and_then(|r| r.report())
    }
}

/// The light-map atlas of the uploaded scene, for the inspector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AtlasReport {
    /// Width of a page in texels.
    pub width: u32,
    /// Height of a page in texels.
    pub height: u32,
    /// Pages.
    pub pages: u32,
    /// Charts (0 for an authored TEXCOORD_1).
    pub charts: u32,
    /// Share of texels inside triangles.
    pub utilisation: f64,
    /// Texels per scene unit, area-weighted.
    pub texel_density: f64,
}

/// The last frame read back (with [`RenderSettings::capture`]).
#[derive(Resource, Default)]
pub struct LastFrame {
    /// Tone-mapped, sRGB-encoded.
    pub ldr: Option<Image>,
    /// Linear radiance before tone mapping.
    pub hdr: Option<Image>,
}

/// The render systems.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RenderSystems;

/// Draws the world headless after the bake's systems. Needs a GPU adapter: without one,
/// `finish` logs the install hint and frames are skipped (the bake still runs).
pub struct RenderPlugin;

impl Plugin for RenderPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<RenderSettings>()
            .init_resource::<RenderState>()
            .init_resource::<LastFrame>()
            .init_resource::<RenderChanges>()
            .configure_sets(PostUpdate, RenderSystems.after(BakeSystems))
            .add_systems(
                PostUpdate,
                (detect_render_changes, render_frame)
                    .chain()
                    .in_set(RenderSystems),
            );
    }

    fn finish(&self, app: &mut App) {
        if app.world.contains_resource::<Gpu>() {
            return;
        }
        match GpuContext::headless() {
            Ok(gpu) => {
                app.insert_resource(Gpu(gpu));
            }
            Err(e) => tracing::error!("no frames will be rendered: {e}"),
        }
    }
}

/// Fills a light map made by `RenderScene::from_scene(scene, ..)` with the light map a bake
/// writes (`radiant_radiosity::texel_light`): the whole light of `field` (the bake's smooth
/// field on `mesh`) composed on `basis` (the lights' direct light per texel, the open part of
/// texels at contacts), so the frame shows what `lightmap.exr`, the export and `bake --points`
/// hold; then [`set_lightmap`]. The bake's radiosity already holds the punctual lights' direct
/// light, with shadows: [`lit_by_bake`] removes them from the frame.
pub fn fill_lightmap(
    rs: &mut RenderScene,
    scene: &Scene,
    mesh: &Mesh,
    field: &SmoothField,
    basis: &TexelBasis,
) {
    let Some(atlas) = rs.atlas.clone() else {
        return;
    };
    let map = basis.compose(scene, &atlas, mesh, field);
    set_lightmap(rs, scene, &atlas, &map);
}

/// Fills a light map made by `RenderScene::from_scene(scene, ..)` with the bake's incident
/// radiance `H` at each texel's point from the elements alone (what frames draw while a large
/// map's [`TexelBasis`] is made; [`fill_lightmap`] otherwise), from the smooth field (`radiant_radiosity::smooth`:
/// `H` averaged at element vertices and interpolated), so the renderer's `albedo × H + E`
/// reproduces the smooth radiosity `E + ρ H`. On an untextured surface `H` is scaled by
/// `ρ / ρ̃`, `ρ̃` the albedo as the 8-bit G-buffer stores it, so the frame gives the baked value
/// exactly; a textured one multiplies by its texel instead of the element's footprint mean.
/// Dynamic surfaces (not in the bake) get `H = 0`.
///
/// The bake's radiosity already holds the punctual lights' direct light, with shadows, so a
/// frame drawn from this light map must not add the lights again: [`lit_by_bake`] removes them.
pub fn fill_lightmap_from_field(
    rs: &mut RenderScene,
    scene: &Scene,
    mesh: &Mesh,
    field: &SmoothField,
) {
    let to_root = radiant_radiosity::lightmap::static_roots(scene);
    rs.fill_lightmap(|t| {
        let (Some(tri), Some(Some(root))) =
            (scene.triangles.get(t.triangle), to_root.get(t.triangle))
        else {
            return [0.0; 3];
        };
        if *root as usize >= mesh.roots.len() {
            return [0.0; 3];
        }
        let surface = &scene.surfaces[tri.surface as usize];
        let (leaf, w) = mesh.locate_weights(*root, f64::from(t.u), f64::from(t.v));
        let h = field.irradiance_in(leaf, w);
        let rho = field.reflectance(leaf);
        let textured = surface.base_color_texture.is_some();
        [0, 1, 2].map(|c| {
            let scale = match textured {
                true => 1.0,
                false => over_stored(rho[c], surface.reflectance[c]),
            };
            (h[c] * scale).clamp(0.0, 65504.0) as f32
        })
    });
}

/// Copies `map` (a light map on `atlas`, the render scene's own) into the render scene's light
/// map. On an untextured surface `H` is scaled by `ρ / ρ̃`, `ρ̃` the albedo as the 8-bit
/// G-buffer stores it, so the frame gives the baked value exactly; a textured one multiplies
/// by its texel. Texels no chart fills stay 0.
pub fn set_lightmap(
    rs: &mut RenderScene,
    scene: &Scene,
    atlas: &radiant_scene::atlas::Atlas,
    map: &radiant_radiosity::lightmap::LightMap,
) {
    let Some(lm) = rs.lightmap.as_mut() else {
        return;
    };
    if (lm.width, lm.height, lm.pages) != (map.width, map.height, map.pages)
        || map.texels.len() != lm.texels.len()
    {
        return;
    }
    let scale: Vec<[f64; 3]> = scene
        .surfaces
        .iter()
        .map(|s| {
            std::array::from_fn(|c| match s.base_color_texture {
                Some(_) => 1.0,
                None => over_stored(s.reflectance[c], s.reflectance[c]),
            })
        })
        .collect();
    let size = (map.width * map.height) as usize;
    for page in 0..map.pages {
        let base = page as usize * size;
        for (k, o) in atlas.owners(scene, page).iter().enumerate() {
            let Some(t) = scene.triangles.get(o.triangle as usize) else {
                continue;
            };
            let s = scale[t.surface as usize];
            let h = map.texels[base + k];
            lm.texels[base + k] =
                std::array::from_fn(|c| (f64::from(h[c]) * s[c]).clamp(0.0, 65504.0) as f32);
        }
    }
}

/// `rho` over the albedo the 8-bit G-buffer stores for a base colour `factor` (0 where that
/// is 0): what an untextured surface's `H` is scaled by so the frame gives `rho × H`.
fn over_stored(rho: f64, factor: f64) -> f64 {
    let stored = (factor * 255.0).round() / 255.0;
    if stored > 0.0 { rho / stored } else { 0.0 }
}

/// Lights `rs`'s dynamic surfaces from `volume` (baked from the same scene's solution) and its
/// probes' `harmonics` ([`radiant_probes::ProbeVolume::h_harmonics`]): the renderer's probe
/// grid, placed in world units relative to the scene's origin.
pub fn light_dynamic(
    rs: &mut RenderScene,
    volume: &radiant_probes::ProbeVolume,
    harmonics: &[([[f64; 3]; 9], bool)],
) {
    let frame = volume.lighting.frame();
    let origin = frame.to_world(volume.origin) - rs.origin;
    let (sh, valid) = harmonics
        .iter()
        .map(|(c, ok)| (c.map(|k| k.map(|v| v as f32)), *ok))
        .unzip();
    rs.probes = Some(radiant_render::scene::ProbeGrid {
        origin: origin.as_vec3().to_array(),
        step: (volume.step * frame.scale) as f32,
        dims: volume.dims.map(|d| d as u32),
        sh,
        valid,
    });
}

/// Drops the punctual lights from a scene lit by a bake's light map: their direct light (with
/// shadows) is in the map already, and drawing them too would count it twice.
pub fn lit_by_bake(rs: &mut RenderScene) {
    rs.lights.clear();
}

fn max_rel_change(a: &[Rgb], b: &[Rgb]) -> f64 {
    if a.len() != b.len() {
        return f64::INFINITY;
    }
    let peak = b
        .iter()
        .flatten()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(1e-12);
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .map(|(x, y)| (x - y).abs() / peak)
        .fold(0.0, f64::max)
}

/// The frame settings the camera's components ask for. Absent effects are `None`.
pub fn extract_settings(world: &mut World) -> FrameSettings {
    let mut q = world.query_filtered::<(
        Option<&Bloom>,
        Option<&Ssao>,
        Option<&Sobel>,
        Option<&GaussianBlur>,
        Option<&Tonemapping>,
        Option<&DebugView>,
    ), With<SceneCamera>>();
    let Some((bloom, ssao, sobel, blur, tm, view)) = q.iter(world).next() else {
        return FrameSettings::MINIMAL;
    };
    FrameSettings {
        tonemapping: tm.copied().unwrap_or_default(),
        bloom: bloom.copied(),
        ssao: ssao.copied(),
        sobel: sobel.copied(),
        blur: blur.copied(),
        debug_view: view.copied().unwrap_or_default(),
    }
}

/// Whether `a` and `b` hold the same triangles but for where their dynamic ones are: a moved
/// dynamic mesh keeps the atlas (its charts are never read: it is lit by probes).
fn same_static_triangles(a: &Scene, b: &Scene) -> bool {
    let dynamic = |s: &Scene, t: &radiant_scene::Triangle| {
        s.surfaces
            .get(t.surface as usize)
            .is_some_and(|s| s.dynamic)
    };
    a.triangles.len() == b.triangles.len()
        && a.triangles
            .iter()
            .zip(&b.triangles)
            .all(|(x, y)| x == y || (x.surface == y.surface && dynamic(a, x) && dynamic(b, y)))
}

/// The render scene with the baked light, or `None` for a world with nothing to draw yet.
fn build_scene(
    world: &mut World,
    settings: &RenderSettings,
) -> Result<Option<RenderScene>, RenderError> {
    let scene = gather_render_scene(world);
    if scene.triangles.is_empty() {
        return Ok(None);
    }
    let lit = world.resource::<BakedLighting>().clone();
    // A new light (or a material) on the same triangles keeps the atlas: its UV charts are the
    // expensive part of the render scene on a level.
    let state = world.resource::<RenderState>();
    let reuse = match (&state.last_atlas, &state.scene) {
        (Some((density, atlas)), Some(old))
            if *density == settings.texel_density
                && same_static_triangles(old, &scene)
                && old.surfaces.len() == scene.surfaces.len()
                && old
                    .surfaces
                    .iter()
                    .zip(&scene.surfaces)
                    .all(|(a, b)| a.tex_coords == b.tex_coords) =>
        {
            Some(atlas.clone())
        }
        _ => None,
    };
    let mut rs = match reuse {
        Some(atlas) => RenderScene::with_atlas(&scene, atlas)?,
        None => {
            world.resource_mut::<RenderState>().atlases += 1;
            RenderScene::from_scene(&scene, settings.texel_density)?
        }
    };
    if let (Some(mesh), Some(field)) = (&lit.mesh, &lit.field)
        && !lit.radiosity.is_empty()
    {
        let basis = match rs.atlas.clone() {
            Some(atlas) => basis_for(
                &mut world.resource_mut::<RenderState>(),
                (&scene, &atlas, mesh),
                settings.basis_at_once,
            ),
            None => None,
        };
        world.resource_mut::<RenderState>().drawn_per_texel = basis.is_some();
        match basis {
            Some(basis) => fill_lightmap(&mut rs, &scene, mesh, field, &basis),
            None => fill_lightmap_from_field(&mut rs, &scene, mesh, field),
        }
        lit_by_bake(&mut rs);
    }
    // Dynamic surfaces: the latest probes, when the world bakes them.
    let probes = world
        .get_resource::<crate::probes::BakedProbes>()
        .map(|p| (p.published, p.volume.clone(), p.harmonics.clone()));
    if let Some((published, volume, harmonics)) = probes {
        if let (Some(v), Some(h)) = (volume, harmonics) {
            light_dynamic(&mut rs, &v, &h);
        }
        world.resource_mut::<RenderState>().uploaded_probes = published;
    }
    let atlas = rs.atlas.as_ref().map(|a| AtlasReport {
        width: a.width,
        height: a.height,
        pages: a.pages,
        charts: a.charts,
        utilisation: a.utilisation(),
        texel_density: a.texel_density(&scene),
    });
    let mut state = world.resource_mut::<RenderState>();
    state.scene = Some(Arc::new(scene));
    state.atlas = atlas;
    state.last_atlas = rs.atlas.clone().map(|a| (settings.texel_density, a));
    Ok(Some(rs))
}

/// What changed since the renderer last looked (Bevy change detection, no gathering).
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderChanges {
    /// Geometry, materials, transforms, lights or the sky: the scene is gathered and uploaded
    /// again (its textures stay cached).
    pub scene: bool,
    /// Only the camera moved: one uniform is written.
    pub camera: bool,
}

impl Default for RenderChanges {
    fn default() -> Self {
        // The first frame gathers the scene.
        Self {
            scene: true,
            camera: true,
        }
    }
}

/// Notes what the renderer must upload: any drawn surface or light changed, appeared or went,
/// or only the camera moved.
#[expect(
    clippy::type_complexity,
    clippy::too_many_arguments,
    reason = "change-detection filters, one system parameter per kind of change"
)]
pub fn detect_render_changes(
    surfaces: Query<
        (),
        (
            With<crate::scene::Geometry>,
            Or<(
                Changed<crate::scene::Geometry>,
                Changed<crate::scene::Material>,
                Changed<crate::scene::GlobalTransform>,
                Added<crate::scene::Static>,
            )>,
        ),
    >,
    lights: Query<
        (),
        (
            With<crate::scene::PunctualLight>,
            Or<(
                Changed<crate::scene::PunctualLight>,
                Changed<crate::scene::GlobalTransform>,
            )>,
        ),
    >,
    cameras: Query<
        (),
        (
            With<SceneCamera>,
            Or<(Changed<SceneCamera>, Changed<crate::scene::GlobalTransform>)>,
        ),
    >,
    mut removed_geometry: RemovedComponents<crate::scene::Geometry>,
    mut removed_static: RemovedComponents<crate::scene::Static>,
    mut removed_lights: RemovedComponents<crate::scene::PunctualLight>,
    sky: Option<Res<crate::scene::SceneSky>>,
    mut changes: ResMut<RenderChanges>,
) {
    let removed = removed_geometry.read().count()
        + removed_static.read().count()
        + removed_lights.read().count();
    let sky_changed = sky.is_some_and(|s| s.is_changed());
    if !surfaces.is_empty() || !lights.is_empty() || removed > 0 || sky_changed {
        changes.scene = true;
    }
    if !cameras.is_empty() {
        changes.camera = true;
    }
}

/// The scene camera as the renderer sees it, with the clip planes of `fallback` (they come
/// from the scene's bounds when it was uploaded).
fn camera_view(world: &mut World, fallback: CameraView) -> CameraView {
    let mut q = world.query::<(&SceneCamera, Option<&crate::scene::GlobalTransform>)>();
    let Some((c, g)) = q.iter(world).next() else {
        return fallback;
    };
    let m = g.map_or(glam::DAffine3::IDENTITY, |g| g.0);
    CameraView {
        position: m.transform_point3(c.0.position),
        forward: m
            .transform_vector3(c.0.forward)
            .normalize_or(c.0.forward)
            .as_vec3(),
        up: m.transform_vector3(c.0.up).normalize_or(c.0.up).as_vec3(),
        yfov: c.0.yfov as f32,
        ..fallback
    }
}

/// Brings the renderer up to date: uploads the scene when it changed (found by change
/// detection, not by gathering), a new light map when the bake published a visibly different
/// one, and otherwise at most the camera. `Ok(false)`: nothing to draw yet (no GPU, or an empty
/// world).
pub fn prepare_frame(world: &mut World) -> Result<bool, RenderError> {
    if !world.contains_resource::<Gpu>() {
        return Ok(false);
    }
    let settings = *world.resource::<RenderSettings>();
    // A basis made in the background: keep it and draw the light map again with it.
    let ready = {
        let mut state = world.resource_mut::<RenderState>();
        match state.pending_basis.as_mut().map(|(_, t)| check_ready(t)) {
            Some(Some(basis)) => state.pending_basis.take().map(|(mut key, _)| {
                key.basis = Some(Arc::new(basis));
                key
            }),
            _ => None,
        }
    };
    if let Some(c) = ready {
        world.resource_mut::<RenderState>().basis = Some(c);
        world.resource_mut::<RenderChanges>().scene = true;
    }
    let changes = std::mem::replace(
        &mut *world.resource_mut::<RenderChanges>(),
        RenderChanges {
            scene: false,
            camera: false,
        },
    );
    let (generation, light, converged) = {
        let lit = world.resource::<BakedLighting>();
        let converged =
            world.resource::<crate::bake::BakeStatus>().phase == crate::bake::BakePhase::Converged;
        (lit.generation, lit.radiosity.clone(), converged)
    };
    let result = world.resource_scope(|world, gpu: Mut<Gpu>| -> Result<bool, RenderError> {
        let state = world.resource::<RenderState>();
        let light_changed = state.uploaded_generation != Some(generation)
            && (converged
                || state
                    .uploaded_light
                    .as_ref()
                    .is_none_or(|old| max_rel_change(&light, old) >= settings.visible_change));
        // New probes for the dynamic surfaces (built into the scene with the light map).
        let probes_changed = world
            .get_resource::<crate::probes::BakedProbes>()
            .is_some_and(|p| p.published != state.uploaded_probes);
        if state.renderer.is_none() || changes.scene || light_changed || probes_changed {
            let Some(rs) = build_scene(world, &settings)? else {
                // Nothing to draw: keep looking until something is spawned.
                world.resource_mut::<RenderChanges>().scene = true;
                return Ok(false);
            };
            let mut state = world.resource_mut::<RenderState>();
            match state.renderer.as_mut() {
                Some(r) => r.set_scene(&gpu.0, &rs)?,
                None => state.renderer = Some(FrameRenderer::new(&gpu.0, &rs)?),
            }
            state.uploaded_generation = Some(generation);
            state.uploaded_light = Some(light.clone());
            state.uploads += 1;
        } else if changes.camera {
            let Some(old) = world
                .resource::<RenderState>()
                .renderer
                .as_ref()
                .map(|r| r.camera())
            else {
                return Ok(false);
            };
            let camera = camera_view(world, old);
            if let Some(r) = world.resource_mut::<RenderState>().renderer.as_mut() {
                r.set_camera(camera);
            }
        }
        Ok(world.resource::<RenderState>().renderer.is_some())
    });
    if result.is_err() {
        // Try again next frame: a failed upload must not be forgotten.
        let mut c = world.resource_mut::<RenderChanges>();
        c.scene |= changes.scene;
        c.camera |= changes.camera;
    }
    result
}

/// Draws the world into `target` (a view of a `width × height` texture of `format`), e.g. a
/// window's surface texture, after [`prepare_frame`]. With `timed`, every pass is measured
/// (GPU timestamps where the adapter has them) and the times kept in
/// [`RenderState::timings`]; that waits for the GPU, so do it now and then, not every frame.
pub fn render_to(
    world: &mut World,
    target: &radiant_render::wgpu::TextureView,
    (width, height): (u32, u32),
    format: radiant_render::wgpu::TextureFormat,
    timed: bool,
) -> Result<(), RenderError> {
    let frame_settings = extract_settings(world);
    world.resource_scope(|world, gpu: Mut<Gpu>| {
        let mut state = world.resource_mut::<RenderState>();
        let Some(renderer) = state.renderer.as_mut() else {
            return Ok(());
        };
        if timed {
            let t =
                renderer.render_timed(&gpu.0, target, width, height, format, &frame_settings)?;
            state.timings = Some(t);
        } else {
            renderer.render(&gpu.0, target, width, height, format, &frame_settings)?;
        }
        state.frames += 1;
        state.settings = Some(frame_settings);
        state.error = None;
        Ok(())
    })
}

/// Installs (or with `None` removes) an overlay drawn over every frame as the graph's last
/// pass; the viewer's egui inspector is one.
pub fn set_overlay(world: &mut World, overlay: Option<Arc<dyn radiant_post::overlay::Overlay>>) {
    let mut state = world.resource_mut::<RenderState>();
    if let Some(r) = state.renderer.as_mut() {
        r.set_overlay(overlay);
    } else {
        state.pending_overlay = Some(overlay);
    }
}

/// Brings the renderer up to date ([`prepare_frame`]) and renders one frame offscreen (read
/// back into [`LastFrame`] with [`RenderSettings::capture`]).
pub fn render_frame(world: &mut World) {
    let result = render_offscreen(world);
    if let Err(e) = result {
        tracing::error!("frame not rendered: {e}");
        world.resource_mut::<RenderState>().error = Some(Arc::new(e));
    }
}

fn render_offscreen(world: &mut World) -> Result<(), RenderError> {
    if !prepare_frame(world)? {
        return Ok(());
    }
    apply_pending_overlay(world);
    let settings = *world.resource::<RenderSettings>();
    if !settings.offscreen {
        return Ok(());
    }
    let frame_settings = extract_settings(world);
    world.resource_scope(|world, gpu: Mut<Gpu>| -> Result<(), RenderError> {
        let (w, h) = settings.size;
        let mut state = world.resource_mut::<RenderState>();
        if settings.capture {
            let Some(renderer) = state.renderer.as_mut() else {
                return Ok(());
            };
            let capture = renderer.capture(&gpu.0, w, h, &frame_settings)?;
            let mut last = world.resource_mut::<LastFrame>();
            last.ldr = Some(capture.ldr);
            last.hdr = Some(capture.hdr);
        } else {
            use radiant_render::wgpu;
            let format = wgpu::TextureFormat::Rgba8UnormSrgb;
            if state.target.as_ref().is_none_or(|t| (t.0, t.1) != (w, h)) {
                let max = gpu.0.device.limits().max_texture_dimension_2d;
                if w == 0 || h == 0 || w > max || h > max {
                    return Err(RenderError::InvalidSize {
                        width: w,
                        height: h,
                        max,
                    });
                }
                let tex = radiant_render::util::target_texture(
                    &gpu.0.device,
                    "ecs_frame_target",
                    w,
                    h,
                    format,
                );
                state.target = Some((w, h, tex));
            }
            let state = &mut *state;
            let (Some(renderer), Some((_, _, tex))) =
                (state.renderer.as_mut(), state.target.as_ref())
            else {
                return Ok(());
            };
            let view = tex.create_view(&Default::default());
            renderer.render(&gpu.0, &view, w, h, format, &frame_settings)?;
        }
        let mut state = world.resource_mut::<RenderState>();
        state.frames += 1;
        state.settings = Some(frame_settings);
        state.error = None;
        Ok(())
    })
}

/// Hands an overlay set before the renderer existed to the renderer.
pub fn apply_pending_overlay(world: &mut World) {
    let mut state = world.resource_mut::<RenderState>();
    if state.renderer.is_some()
        && let Some(overlay) = state.pending_overlay.take()
        && let Some(r) = state.renderer.as_mut()
    {
        r.set_overlay(overlay);
    }
}
