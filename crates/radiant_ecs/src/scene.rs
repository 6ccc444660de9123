//! Scenes as entities: one entity per surface under a scene root, with transforms, materials,
//! lights and the camera; and the gathering of the static ones back into a radiosity [`Scene`].

use bevy_ecs::prelude::*;
use glam::{DAffine3, DQuat, DVec3, Vec2, Vec3};
use radiant_scene::{AlphaMode, Camera, Image, Light, Scene, Sky, Surface, TextureRef, Triangle};

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
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Geometry {
    /// Counter-clockwise triangles (the front face is the normal's side).
    pub triangles: Vec<[DVec3; 3]>,
    /// Per triangle: shading normals (local space) and texture coordinates; empty for flat,
    /// untextured geometry.
    pub attributes: Vec<TriangleAttributes>,
}

/// A triangle's shading normals and its two UV sets (see [`radiant_scene::Triangle`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TriangleAttributes {
    /// Unit normals at the vertices, local space.
    pub normals: [Vec3; 3],
    /// TEXCOORD_0 and TEXCOORD_1 at the vertices.
    pub uv: [[Vec2; 3]; 2],
}

/// A surface's textures and alpha mode, beside its [`Material`] (whose colours the textures
/// modulate). Absent on untextured, opaque surfaces.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct MaterialTextures {
    /// The base-colour texture (an index into [`SceneImages`]).
    pub base_color: Option<TextureRef>,
    /// The base colour factor's alpha.
    pub base_color_alpha: f64,
    /// The emissive texture.
    pub emissive: Option<TextureRef>,
    /// Opaque, masked or blended.
    pub alpha: AlphaMode,
    /// Whether the surface's triangles include back-facing twins.
    pub double_sided: bool,
    /// TEXCOORD sets the surface has.
    pub tex_coords: u8,
}

/// The images the scene's textures read.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct SceneImages(pub Vec<Image>);

/// Light from outside the scene: `None` for none. The bake and the renderer read it; the
/// inspector edits it.
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct SceneSky(pub Option<Sky>);

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
    let mut geometry: Vec<Geometry> = vec![Geometry::default(); scene.surfaces.len()];
    for t in &scene.triangles {
        if let Some(g) = geometry.get_mut(t.surface as usize) {
            g.triangles.push(t.vertices);
            g.attributes.push(TriangleAttributes {
                normals: t.normals,
                uv: t.uv,
            });
        }
    }
    world.insert_resource(SceneImages(scene.images.clone()));
    world.insert_resource(SceneSky(scene.sky.clone()));
    for (i, (s, geometry)) in scene.surfaces.iter().zip(geometry).enumerate() {
        let mut e = world.spawn((
            Name::new(s.name.clone()),
            Transform::IDENTITY,
            geometry,
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
        if s.base_color_texture.is_some()
            || s.emissive_texture.is_some()
            || s.alpha != AlphaMode::Opaque
            || s.double_sided
            || s.tex_coords > 0
        {
            e.insert(MaterialTextures {
                base_color: s.base_color_texture,
                base_color_alpha: s.base_color_alpha,
                emissive: s.emissive_texture,
                alpha: s.alpha,
                double_sided: s.double_sided,
                tex_coords: s.tex_coords,
            });
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

/// Moves every dynamic mesh (a surface without [`Static`]) by `delta`, scene units, as a game
/// moves what it owns: the bake does not see it, the renderer draws it again lit by the probes.
/// Returns how many moved.
pub fn move_dynamic(world: &mut World, delta: DVec3) -> usize {
    if !delta.is_finite() || delta == DVec3::ZERO {
        return 0;
    }
    let mut q = world.query_filtered::<&mut Transform, (With<Geometry>, Without<Static>)>();
    let mut moved = 0;
    for mut t in q.iter_mut(world) {
        t.translation += delta;
        moved += 1;
    }
    moved
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
        Option<&MaterialTextures>,
        Option<&GlobalTransform>,
        Has<Static>,
    )>();
    let mut rows: Vec<_> = q.iter(world).filter(|r| r.6 || with_dynamic).collect();
    rows.sort_by_key(|r| *r.0);
    let mut scene = Scene::default();
    for (order, name, geometry, material, textures, global, is_static) in rows {
        let m = global.map_or(DAffine3::IDENTITY, |g| g.0);
        // Normals follow the inverse transpose; a mirroring transform flips the winding.
        let normal_matrix = m.matrix3.inverse().transpose();
        let flip = m.matrix3.determinant() < 0.0;
        let surface = scene.surfaces.len() as u32;
        let name = name.map_or_else(|| format!("surface{}", order.0), |n| n.as_str().to_string());
        let mut s = Surface {
            material: name.clone(),
            name,
            reflectance: material.reflectance,
            emission: material.emission,
            dynamic: !is_static,
            ..Surface::default()
        };
        if let Some(t) = textures {
            s.base_color_texture = t.base_color;
            s.base_color_alpha = t.base_color_alpha;
            s.emissive_texture = t.emissive;
            s.alpha = t.alpha;
            s.double_sided = t.double_sided;
            s.tex_coords = t.tex_coords;
        }
        scene.surfaces.push(s);
        for (k, t) in geometry.triangles.iter().enumerate() {
            let mut tri = Triangle::new(t.map(|p| m.transform_point3(p)), surface);
            if let Some(a) = geometry.attributes.get(k) {
                tri.normals = a
                    .normals
                    .map(|n| (normal_matrix * n.as_dvec3()).normalize_or_zero().as_vec3());
                tri.uv = a.uv;
            }
            if flip {
                tri = tri.rewound();
            }
            scene.triangles.push(tri);
        }
    }
    scene.images = world
        .get_resource::<SceneImages>()
        .map(|i| i.0.clone())
        .unwrap_or_default();
    scene.sky = world.get_resource::<SceneSky>().and_then(|s| s.0.clone());
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The scene gathered back from the world is the one spawned, in order; a mirrored surface
    /// comes back rewound (its faces still in front of its shading normals), the others as
    /// they were.
    #[test]
    fn the_gathered_scene_is_the_spawned_one_and_a_mirror_rewinds() {
        let scene = radiant_scene::builtin("cornell-box").expect("builtin");
        let mut app = App::new();
        app.add_plugins(ScenePlugin);
        spawn_scene(&mut app.world, &scene);
        app.update();
        let back = gather_scene(&mut app.world);
        assert_eq!(back.surfaces.len(), scene.surfaces.len());
        assert_eq!(back.triangles.len(), scene.triangles.len());
        for (a, b) in back.triangles.iter().zip(&scene.triangles) {
            assert_eq!((a.vertices, a.surface, a.uv), (b.vertices, b.surface, b.uv));
            for k in 0..3 {
                assert!(a.normals[k].distance(b.normals[k]) < 1e-6);
            }
        }
        let mirrored = (scene.surfaces.iter())
            .position(|s| s.name.starts_with("short_block"))
            .expect("a block") as u32;
        let mut q = app.world.query::<(&SurfaceOrder, &mut Transform)>();
        for (order, mut t) in q.iter_mut(&mut app.world) {
            if order.0 == mirrored {
                t.scale.x = -1.0;
            }
        }
        app.update();
        let back = gather_scene(&mut app.world);
        assert_eq!(back.triangles.len(), scene.triangles.len());
        let mut seen = 0;
        for (a, b) in back.triangles.iter().zip(&scene.triangles) {
            if a.surface != mirrored {
                assert_eq!(a.vertices, b.vertices);
                continue;
            }
            seen += 1;
            let v = a.vertices;
            let face = (v[1] - v[0]).cross(v[2] - v[0]);
            for n in a.normals {
                assert!(face.dot(n.as_dvec3()) > 0.0, "a mirrored face turned away");
            }
            let mirror = |p: DVec3| DVec3::new(-p.x, p.y, p.z);
            let mut want: Vec<[i64; 3]> = (b.vertices.iter())
                .map(|&p| (mirror(p) * 1e9).round().as_i64vec3().to_array())
                .collect();
            let mut got: Vec<[i64; 3]> = (v.iter())
                .map(|&p| (p * 1e9).round().as_i64vec3().to_array())
                .collect();
            want.sort();
            got.sort();
            assert_eq!(got, want);
        }
        assert!(seen > 0);
    }
}
