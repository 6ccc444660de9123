//! Radiant: diffuse global illumination by finite-element radiosity, baked into light maps, for
//! game prototypes and editors.
//!
//! This facade re-exports the workspace's crates:
//! - [`scene`]: glTF import with validation, the builtin Cornell box;
//! - [`radiosity`]: meshing, form factors, solvers, error metrics, light maps (pure CPU);
//! - [`reference`](mod@reference): a progressive CPU path tracer over the same scene model, the reference the
//!   bake's error is measured against;
//! - [`probes`]: irradiance probes from the solution, for what moves (an irradiance volume);
//! - [`color`]: sRGB transfer functions, CIE colorimetry and tone-map operators;
//! - [`ecs`]: scenes as `bevy_ecs` entities, the background bake and live rebake, a headless app;
//! - [`render`] and [`post`] (feature `render`, on by default): the wgpu render graph, passes,
//!   post-processing and offscreen capture;
//! - [`gather`] (feature `render`): radiosity by direct rendering, a GPU hemicube gather whose
//!   receivers are the light map's texels (`--method gpu-hemicube`).
//!
//! ```
//! use radiant::radiosity::{Bake, BakeParams};
//! let scene = radiant::scene::builtin("cornell-box").unwrap();
//! let mut params = BakeParams::default();
//! params.mesh.patch_size = 0.3; // coarse, for the example
//! let result = Bake::new(&scene, &params).unwrap().run_to_end(&mut |_| {}).unwrap();
//! assert!(result.report.converged);
//! ```

pub use radiant_color as color;
pub use radiant_ecs as ecs;
#[cfg(feature = "render")]
pub use radiant_gather as gather;
#[cfg(feature = "render")]
pub use radiant_post as post;
pub use radiant_probes as probes;
pub use radiant_radiosity as radiosity;
pub use radiant_reference as reference;
#[cfg(feature = "render")]
pub use radiant_render as render;
pub use radiant_scene as scene;

/// Glue from a radiosity bake to the renderer's light map (until the ECS crate owns it).
#[cfg(feature = "render")]
pub mod bridge {
    use radiant_radiosity::BakeResult;
    use radiant_radiosity::lightmap::LightMap;
    use radiant_render::RenderError;
    use radiant_render::scene::RenderScene;
    use radiant_scene::Scene;
    use radiant_scene::atlas::Atlas;

    /// The renderer's scene for `scene`, its light map on the scene's atlas at `texel_density`
    /// texels per unit (`None`: automatic), lit by `bake` (or with an empty light map when there
    /// is no bake: a scene without emitters).
    pub fn render_scene(
        scene: &Scene,
        bake: Option<&BakeResult>,
        texel_density: Option<f64>,
    ) -> Result<RenderScene, RenderError> {
        let mut rs = RenderScene::from_scene(scene, texel_density)?;
        if let Some(bake) = bake {
            // The light map the bake writes (`radiosity::texel_light::compose_lightmap` on the
            // renderer's own atlas: the lights' direct light per texel, the open part of
            // texels at contacts, the smooth field for the rest), so the frame shows what
            // `lightmap.exr`, the export and `bake --points` hold.
            light_with(&mut rs, scene, |atlas| {
                radiant_radiosity::texel_light::compose_lightmap(
                    scene,
                    atlas,
                    &bake.mesh,
                    &bake.system,
                    &bake.radiosity,
                )
            });
        }
        Ok(rs)
    }

    /// Fills `render_scene`'s light map with the one `compose` makes on the renderer's own
    /// atlas (`render_scene.atlas`; e.g. `radiosity::texel_light::compose_gathered`, the final
    /// gather), and leaves the punctual lights out of the frame: a bake's light map holds
    /// their direct light. An untextured surface's `H` is scaled by its reflectance over the
    /// 8-bit base colour the renderer stores, so `albedo × H` is the bake's.
    pub fn light_with(
        render_scene: &mut RenderScene,
        scene: &Scene,
        compose: impl FnOnce(&Atlas) -> LightMap,
    ) {
        if let Some(atlas) = render_scene.atlas.clone() {
            let map = compose(&atlas);
            radiant_ecs::render::set_lightmap(render_scene, scene, &atlas, &map);
        }
        radiant_ecs::render::lit_by_bake(render_scene);
    }

    /// Lights `render_scene`'s dynamic surfaces from `volume` (baked from the same scene's
    /// solution): each probe's whole `H` as order-2 harmonics
    /// ([`radiant_probes::ProbeVolume::h_harmonics`]) on the renderer's grid.
    pub fn light_dynamic(render_scene: &mut RenderScene, volume: &radiant_probes::ProbeVolume) {
        radiant_ecs::render::light_dynamic(render_scene, volume, &volume.h_harmonics());
    }
}
