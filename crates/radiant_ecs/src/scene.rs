//! Scenes as entities: one entity per surface under a scene root, with transforms, materials,
//! lights and the camera; and the gathering of the static ones back into a radiosity [`Scene`].

use bevy_ecs::prelude::*;
use glam::{DAffine3, DQuat, DVec3};
use radiant_scene::{Camera, Light, Scene, Surface, Triangle};

use crate::app::{App, Plugin, PostUpdate};

/// Local placement relative to the parent (f64: scenes far from the origin keep precision).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[require(GlobalTransform)]
pub struct Transform {
    /// Translation, scene units.
    pub translation: DVec3,
    /// Rotation.
    pub rotation: DQuat,
    /// Scale per axis.
    pub scale: DVec3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// No translation, rotation or scale.
    pub const IDENTITY: Transform = Transform {
        translation: DVec3::ZERO,
        rotation: DQuat::IDENTITY,
        scale: DVec3::ONE,
    };

    /// A pure translation.
    pub fn from_translation(translation: DVec3) -> Self {
        Self {
            translation,
            ..Self::IDENTITY
        }
    }

    /// As an affine map.
    pub fn to_affine(&self) -> DAffine3 {
        DAffine3::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

/// World placement, computed from the [`Transform`] hierarchy by [`propagate_transforms`].
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct GlobalTransform(pub DAffine3);

impl Default for GlobalTransform {
    fn default() -> Self {
        Self(DAffine3::IDENTITY)
    }
}

/// Triangles in the entity's local space.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct Geometry {
    /// Counter-clockwise triangles (the front face is the normal's side).
    pub triangles: Vec<[DVec3; 3]>,
}

/// A Lambertian material.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Material {
    /// Linear diffuse reflectance per channel, in [0, 1].
    pub reflectance: [f64; 3],
    /// Emitted radiance per channel, ≥ 0 (glTF emissive units).
    pub emission: [f64; 3],
}

/// Geometry that takes part in the bake. Spawned scenes mark every surface static; remove the
/// component to make one dynamic (it is then neither a receiver nor an occluder).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Static;

/// A punctual light, its position and direction in the entity's local space.
#[derive(Component, Clone, Debug, PartialEq)]
#[require(Transform)]
pub struct PunctualLight(pub Light);

/// The camera the renderer uses (the Cornell box's published one for the builtin scene).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct SceneCamera(pub Camera);

/// Keeps surface order stable (the order they were spawned in), so bakes are reproducible.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub struct SurfaceOrder(pub u32);

/// The root of a spawned scene.
#[derive(Component, Clone, Copy, Debug, Default)]
#[require(Transform)]
pub struct SceneRoot;

/// Transform propagation.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TransformSystems;

/// Adds transform propagation (in `PostUpdate`, before the bake).
pub struct ScenePlugin;

impl Plugin for ScenePlugin {
    fn build(&self, app: &mut App) {
        app.add_systems(PostUpdate, propagate_transforms.in_set(TransformSystems));
    }
}

/// Spawns `scene` as a root entity with one child per surface (its triangles in the root's
/// space, [`Static`] unless the surface is dynamic), one per light and the camera. Returns the
/// root.
pub fn spawn_scene(world: &mut World, scene: &Scene) -> Entity {
    let root = world
        .spawn((SceneRoot, Transform::IDENTITY, Name::new("scene")))
        .id();
    let mut tris: Vec<Vec<[DVec3; 3]>> = vec![Vec::new(); scene.surfaces.len()];
    for t in &scene.triangles {
        if let Some(v) = tris.get_mut(t.surface as usize) {
            v.push(t.vertices);
        }
    }
    for (i, (s, triangles)) in scene.surfaces.iter().zip(tris).enumerate() {
        let mut e = world.spawn((
            Name::new(s.name.clone()),
            Transform::IDENTITY,
            Geometry { triangles },
            Material {
                reflectance: s.reflectance,
                emission: s.emission,
            },
            SurfaceOrder(i as u32),
            ChildOf(root),
        ));
        // glTF nodes are static unless their extras say dynamic.
        if !s.dynamic {
            e.insert(Static);
        }
    }
    for l in &scene.lights {
        world.spawn((
            Name::new(l.name.clone()),
            PunctualLight(l.clone()),
            ChildOf(root),
        ));
    }
    if let Some(c) = scene.camera {
        world.spawn((
            Name::new("camera"),
            SceneCamera(c),
            Transform::IDENTITY,
            ChildOf(root),
        ));
    }
    root
}

/// Computes every [`GlobalTransform`] from the hierarchy, writing only those that changed.
pub fn propagate_transforms(
    roots: Query<Entity, (With<Transform>, Without<ChildOf>)>,
    children: Query<&Children>,
    transforms: Query<&Transform>,
    mut globals: Query<&mut GlobalTransform>,
) {
    let mut stack: Vec<(Entity, DAffine3)> =
        roots.iter().map(|e| (e, DAffine3::IDENTITY)).collect();
    while let Some((e, parent)) = stack.pop() {
        let local = transforms
            .get(e)
            .map_or(DAffine3::IDENTITY, Transform::to_affine);
        let global = parent * local;
        if let Ok(mut g) = globals.get_mut(e) {
            g.set_if_neq(GlobalTransform(global));
        }
        if let Ok(c) = children.get(e) {
            stack.extend(c.iter().map(|child| (child, global)));
        }
    }
}

/// The static surfaces, lights and camera as a radiosity scene, in world space: what the
/// bake sees.
pub fn gather_scene(world: &mut World) -> Scene {
    gather(world, false)
}

/// Every surface, static or not (dynamic ones marked `dynamic`), with the lights and camera:
/// what the renderer draws.
pub fn gather_render_scene(world: &mut World) -> Scene {
    gather(world, true)
}

fn gather(world: &mut World, with_dynamic: bool) -> Scene {
    let mut q = world.query::<(
        &SurfaceOrder,
        Option<&Name>,
        &Geometry,
        &Material,
        Option<&GlobalTransform>,
        Has<Static>,
    )>();
    let mut rows: Vec<_> = q.iter(world).filter(|r| r.5 || with_dynamic).collect();
    rows.sort_by_key(|r| *r.0);
    let mut scene = Scene::default();
    for (order, name, geometry, material, global, is_static) in rows {
        let m = global.map_or(DAffine3::IDENTITY, |g| g.0);
        let surface = scene.surfaces.len() as u32;
        let name = name.map_or_else(|| format!("surface{}", order.0), |n| n.as_str().to_string());
        scene.surfaces.push(Surface {
            material: name.clone(),
            name,
            reflectance: material.reflectance,
            emission: material.emission,
            dynamic: !is_static,
        });
        for t in &geometry.triangles {
            scene.triangles.push(Triangle {
                vertices: t.map(|p| m.transform_point3(p)),
                surface,
            });
        }
    }
    let mut lights = world.query::<(&PunctualLight, Option<&GlobalTransform>)>();
    for (l, g) in lights.iter(world) {
        let m = g.map_or(DAffine3::IDENTITY, |g| g.0);
        let mut light = l.0.clone();
        light.position = m.transform_point3(light.position);
        light.direction = m
            .transform_vector3(light.direction)
            .normalize_or(light.direction);
        scene.lights.push(light);
    }
    let mut cams = world.query::<(&SceneCamera, Option<&GlobalTransform>)>();
    scene.camera = cams.iter(world).next().map(|(c, g)| {
        let m = g.map_or(DAffine3::IDENTITY, |g| g.0);
        let mut cam = c.0;
        cam.position = m.transform_point3(cam.position);
        cam.forward = m.transform_vector3(cam.forward).normalize_or(cam.forward);
        cam.up = m.transform_vector3(cam.up).normalize_or(cam.up);
        cam
    });
    scene
}
