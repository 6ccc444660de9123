//! Punctual lights (point, spot, directional with a shadow), sky light, base-colour textures and
//! alpha masks, through the whole pipeline: glTF JSON with embedded data-URI buffers → import →
//! bake (and the reference path tracer) → per-element radiosity against closed forms.
//!
//! Every scene is a floor, which cannot see itself, plus at most a black occluder, so there is no
//! indirect light: each element's radiosity is exactly the direct term `ρ E / π` at its centroid.

use std::f64::consts::PI;
use std::io::Cursor;

use radiant::color::srgb_to_linear;
use radiant::radiosity::{Bake, BakeParams, BakeResult};
use radiant::scene::{Scene, SceneError, load_gltf_slice};

// ---------------------------------------------------------------------------------------------
// A tiny glTF writer.

/// Standard base64 with padding (RFC 4648).
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> (18 - 6 * k)) as usize & 63]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[test]
fn base64_matches_rfc4648_vectors() {
    for (input, want) in [
        ("", ""),
        ("f", "Zg=="),
        ("fo", "Zm8="),
        ("foo", "Zm9v"),
        ("foob", "Zm9vYg=="),
        ("fooba", "Zm9vYmE="),
        ("foobar", "Zm9vYmFy"),
    ] {
        assert_eq!(base64(input.as_bytes()), want, "{input:?}");
    }
    assert_eq!(base64(&[0xfb, 0xff, 0xbf]), "+/+/");
}

/// A glTF document under construction: one binary buffer, one node per mesh or light.
#[derive(Default)]
struct Doc {
    bin: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
    meshes: Vec<String>,
    nodes: Vec<String>,
    materials: Vec<String>,
    lights: Vec<String>,
    /// Further top-level members, as `"key": value`.
    extra: Vec<String>,
}

impl Doc {
    /// Appends bytes as a buffer view (4-byte aligned); returns the view index.
    fn view(&mut self, bytes: &[u8]) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        self.views.push(format!(
            r#"{{"buffer":0,"byteOffset":{},"byteLength":{}}}"#,
            self.bin.len(),
            bytes.len()
        ));
        self.bin.extend_from_slice(bytes);
        self.views.len() - 1
    }

    /// Adds a material given as a JSON object; returns its index.
    fn material(&mut self, json: String) -> usize {
        self.materials.push(json);
        self.materials.len() - 1
    }

    /// Adds a node with a one-primitive triangle mesh.
    fn mesh(&mut self, name: &str, positions: &[[f32; 3]], indices: &[u16], material: usize) {
        self.mesh_uv(name, positions, None, indices, material);
    }

    /// Adds a node with a one-primitive triangle mesh, with TEXCOORD_0 where given.
    fn mesh_uv(
        &mut self,
        name: &str,
        positions: &[[f32; 3]],
        uv: Option<&[[f32; 2]]>,
        indices: &[u16],
        material: usize,
    ) {
        let uv_member = uv.map_or(String::new(), |uv| {
            let bytes: Vec<u8> = uv.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
            let view = self.view(&bytes);
            self.accessors.push(format!(
                r#"{{"bufferView":{view},"componentType":5126,"count":{},"type":"VEC2"}}"#,
                uv.len()
            ));
            format!(r#","TEXCOORD_0":{}"#, self.accessors.len() - 1)
        });
        let pos_bytes: Vec<u8> = positions
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let idx_bytes: Vec<u8> = indices.iter().flat_map(|i| i.to_le_bytes()).collect();
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in positions {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        let pv = self.view(&pos_bytes);
        let iv = self.view(&idx_bytes);
        self.accessors.push(format!(
            r#"{{"bufferView":{pv},"componentType":5126,"count":{},"type":"VEC3","min":[{},{},{}],"max":[{},{},{}]}}"#,
            positions.len(),
            lo[0],
            lo[1],
            lo[2],
            hi[0],
            hi[1],
            hi[2]
        ));
        self.accessors.push(format!(
            r#"{{"bufferView":{iv},"componentType":5123,"count":{},"type":"SCALAR"}}"#,
            indices.len()
        ));
        let (pa, ia) = (self.accessors.len() - 2, self.accessors.len() - 1);
        self.meshes.push(format!(
            r#"{{"name":"{name}","primitives":[{{"attributes":{{"POSITION":{pa}{uv_member}}},"indices":{ia},"material":{material}}}]}}"#
        ));
        self.nodes.push(format!(
            r#"{{"name":"{name}","mesh":{}}}"#,
            self.meshes.len() - 1
        ));
    }

    /// Adds a KHR_lights_punctual light (JSON object) on a node with the given extra members
    /// (`"translation": [...]`, `"rotation": [...]`, or empty).
    fn light(&mut self, light: String, node_members: &str) {
        self.lights.push(light);
        let sep = if node_members.is_empty() { "" } else { "," };
        self.nodes.push(format!(
            r#"{{"name":"light node {}"{sep}{node_members},"extensions":{{"KHR_lights_punctual":{{"light":{}}}}}}}"#,
            self.lights.len() - 1,
            self.lights.len() - 1
        ));
    }

    /// The document as glTF JSON.
    fn json(&self) -> String {
        let list = |v: &[String]| format!("[{}]", v.join(","));
        let mut members = vec![
            r#""asset":{"version":"2.0"}"#.to_string(),
            r#""scene":0"#.to_string(),
            format!(
                r#""scenes":[{{"nodes":[{}]}}]"#,
                (0..self.nodes.len())
                    .map(|i| i.to_string())
                    .collect::<Vec<_>>()
                    .join(",")
            ),
            format!(r#""nodes":{}"#, list(&self.nodes)),
        ];
        if !self.meshes.is_empty() {
            members.push(format!(r#""meshes":{}"#, list(&self.meshes)));
            members.push(format!(r#""accessors":{}"#, list(&self.accessors)));
            members.push(format!(r#""bufferViews":{}"#, list(&self.views)));
            members.push(format!(
                r#""buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{}"}}]"#,
                self.bin.len(),
                base64(&self.bin)
            ));
        }
        if !self.materials.is_empty() {
            members.push(format!(r#""materials":{}"#, list(&self.materials)));
        }
        if !self.lights.is_empty() {
            members.push(r#""extensionsUsed":["KHR_lights_punctual"]"#.to_string());
            members.push(format!(
                r#""extensions":{{"KHR_lights_punctual":{{"lights":{}}}}}"#,
                list(&self.lights)
            ));
        }
        members.extend(self.extra.iter().cloned());
        format!("{{{}}}", members.join(","))
    }

    /// Imports the document.
    fn load(&self) -> Result<Scene, SceneError> {
        load_gltf_slice(self.json().as_bytes())
    }
}

/// A diffuse material with linear base colour `rho`.
fn diffuse(name: &str, rho: [f64; 3], double_sided: bool) -> String {
    format!(
        r#"{{"name":"{name}","doubleSided":{double_sided},"pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},1],"metallicFactor":0}}}}"#,
        rho[0], rho[1], rho[2]
    )
}

/// A rectangle `[x0, x1] × [z0, z1]` in the plane `y`, facing `+y`.
fn rect_up(x0: f32, x1: f32, z0: f32, z1: f32, y: f32) -> ([[f32; 3]; 4], [u16; 6]) {
    (
        [[x0, y, z1], [x1, y, z1], [x1, y, z0], [x0, y, z0]],
        [0, 1, 2, 0, 2, 3],
    )
}

/// Texture coordinates of a rectangle's corners: `(x, z)` itself (the test rectangles are
/// inside the unit square or tile it).
fn uv_of(p: &[[f32; 3]]) -> Vec<[f32; 2]> {
    p.iter().map(|v| [v[0], v[2]]).collect()
}

/// A PNG data URI of `w × h` RGBA texels.
fn png_uri(w: u32, h: u32, rgba: Vec<u8>) -> String {
    let img = image::RgbaImage::from_raw(w, h, rgba).expect("size matches");
    let mut png = Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .expect("PNG encodes");
    format!("data:image/png;base64,{}", base64(png.get_ref()))
}

/// Adds the document's one texture: a sampler (JSON members), texture 0 reading image 0 from
/// `uri`.
fn add_texture(doc: &mut Doc, sampler: &str, uri: &str) {
    doc.extra.push(format!(r#""samplers":[{{{sampler}}}]"#));
    doc.extra
        .push(r#""textures":[{"sampler":0,"source":0}]"#.into());
    doc.extra.push(format!(r#""images":[{{"uri":"{uri}"}}]"#));
}

/// Rotation by -90° about x as a glTF quaternion (x, y, z, w): the node's -z axis points to -y.
const POINT_DOWN: &str = r#""rotation":[-0.7071068,0,0,0.7071068]"#;

/// Floor reflectance, different per channel so the channels are checked separately. glTF
/// stores it as `f32` (0.4 becomes 0.400000006), so the expected values use the `f32` value.
const RHO: [f32; 3] = [0.5, 0.4, 0.25];

/// The floor's reflectance in channel `c`, as imported.
fn rho(c: usize) -> f64 {
    f64::from(RHO[c])
}
/// Half the floor's side (m): the floor is 10 m × 10 m, centred on the origin at y = 0.
const HALF: f32 = 5.0;

/// A document with the floor.
fn floor_doc() -> Doc {
    let mut doc = Doc::default();
    let m = doc.material(diffuse("floor", RHO.map(f64::from), false));
    let (p, i) = rect_up(-HALF, HALF, -HALF, HALF, 0.0);
    doc.mesh("floor", &p, &i, m);
    doc
}

fn params() -> BakeParams {
    let mut p = BakeParams::default();
    p.mesh.patch_size = 1.0;
    p.mesh.element_levels = 2;
    p
}

fn bake(scene: &Scene) -> BakeResult {
    Bake::new(scene, &params())
        .expect("bake prepares")
        .run_to_end(&mut |_| {})
        .expect("bake runs")
}

/// One element: its world centroid and corners, unit normal, surface index and radiosity.
struct Element {
    centroid: [f64; 3],
    corners: [[f64; 3]; 3],
    normal: [f64; 3],
    surface: u32,
    b: [f64; 3],
}

fn elements(r: &BakeResult) -> Vec<Element> {
    (0..r.mesh.element_count())
        .map(|i| {
            let node = r.mesh.leaf_node(i as u32);
            let c = r.mesh.frame.to_world(node.centroid);
            Element {
                centroid: [c.x, c.y, c.z],
                corners: node.v.map(|v| r.mesh.frame.to_world(v).to_array()),
                normal: [node.normal.x, node.normal.y, node.normal.z],
                surface: r.mesh.root_surface[node.root as usize],
                b: r.radiosity[i],
            }
        })
        .collect()
}

fn surface_index(scene: &Scene, name: &str) -> u32 {
    scene
        .surfaces
        .iter()
        .position(|s| s.name == name)
        .unwrap_or_else(|| panic!("surface {name}")) as u32
}

/// Radiosity `ρ I cos θ / (π d²)` at `x` (normal `n`) from `I` candela at `light`.
fn point_radiosity(rho: f64, intensity: f64, light: [f64; 3], x: [f64; 3], n: [f64; 3]) -> f64 {
    let d = [light[0] - x[0], light[1] - x[1], light[2] - x[2]];
    let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let cos = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / d2.sqrt();
    rho * intensity * cos.max(0.0) / d2 / PI
}

/// Horizontal distance from `x` to the vertical axis through the origin.
fn radial(x: [f64; 3]) -> f64 {
    x[0].hypot(x[2])
}

fn rel(got: f64, want: f64) -> f64 {
    (got - want).abs() / want.abs()
}

/// The mean of `f` over the element's triangle (a 24 × 24 grid of its sub-triangles'
/// centroids): what a light's direct part per element estimates (the mean of nine points, one
/// at random in each ninth, `radiosity::lights`).
fn element_mean(e: &Element, f: impl Fn([f64; 3]) -> f64) -> f64 {
    const N: usize = 24;
    let [a, b, c] = e.corners;
    let at = |u: f64, v: f64| std::array::from_fn(|k| a[k] + (b[k] - a[k]) * u + (c[k] - a[k]) * v);
    let mut sum = 0.0;
    for i in 0..N {
        for j in 0..N - i {
            let (u, v) = (i as f64, j as f64);
            sum += f(at((u + 1.0 / 3.0) / N as f64, (v + 1.0 / 3.0) / N as f64));
            if i + j + 1 < N {
                sum += f(at((u + 2.0 / 3.0) / N as f64, (v + 2.0 / 3.0) / N as f64));
            }
        }
    }
    sum / (N * N) as f64
}

/// Whether all of the element's corners (`all`) or any of them satisfy `inside`.
fn corners_in(e: &Element, all: bool, inside: impl Fn([f64; 3]) -> bool) -> bool {
    match all {
        true => e.corners.iter().all(|&c| inside(c)),
        false => e.corners.iter().any(|&c| inside(c)),
    }
}

// ---------------------------------------------------------------------------------------------
// The tests.

#[test]
fn point_light_irradiance_matches_inverse_square() {
    let (intensity, h) = (100.0, 2.0);
    let mut doc = floor_doc();
    doc.light(
        format!(r#"{{"name":"bulb","type":"point","color":[1,1,1],"intensity":{intensity}}}"#),
        &format!(r#""translation":[0,{h},0]"#),
    );
    let scene = doc.load().expect("scene loads");
    assert_eq!(scene.lights.len(), 1);
    let floor = surface_index(&scene, "floor");
    let r = bake(&scene);
    let light = [0.0, h, 0.0];
    let (mut checked, mut worst, mut signed) = (0, 0.0f64, 0.0);
    for e in elements(&r).iter().filter(|e| e.surface == floor) {
        assert!(e.normal[1] > 0.999_999, "floor faces up");
        if radial(e.centroid) > 1.5 {
            continue;
        }
        for c in 0..3 {
            // The element's mean, which its nine points estimate: within a percent or so
            // each, and without bias (below).
            let want = element_mean(e, |x| {
                point_radiosity(rho(c), intensity, light, x, e.normal)
            });
            let dev = rel(e.b[c], want);
            signed += (e.b[c] - want) / want;
            assert!(
                dev < 1.5e-2,
                "element at {:?}, channel {c}: B = {} vs {want}",
                e.centroid,
                e.b[c]
            );
            worst = worst.max(dev);
        }
        checked += 1;
    }
    assert!(checked > 100, "only {checked} elements near the light");
    let bias = signed / (3 * checked) as f64;
    println!(
        "point light: {checked} elements, worst relative deviation {worst:.3e}, mean {bias:+.2e}"
    );
    assert!(bias.abs() < 1e-3, "the elements' mean deviation {bias}");
}

#[test]
fn spot_light_cone() {
    let (intensity, h, inner, outer) = (100.0, 2.0, 0.4, 0.6);
    let mut doc = floor_doc();
    doc.light(
        format!(
            r#"{{"name":"spot","type":"spot","intensity":{intensity},"spot":{{"innerConeAngle":{inner},"outerConeAngle":{outer}}}}}"#
        ),
        &format!(r#""translation":[0,{h},0],{POINT_DOWN}"#),
    );
    let scene = doc.load().expect("scene loads");
    let l = &scene.lights[0];
    assert!(
        (l.direction.y + 1.0).abs() < 1e-6,
        "spot points down: {}",
        l.direction
    );
    let floor = surface_index(&scene, "floor");
    let r = bake(&scene);
    let light = [0.0, h, 0.0];
    let (mut inside, mut outside, mut between, mut worst) = (0, 0, 0, 0.0f64);
    for e in elements(&r).iter().filter(|e| e.surface == floor) {
        // Angle from the spot's axis (straight down), at the centroid and the corners.
        let angle_at = |x: [f64; 3]| radial(x).atan2(h - x[1]);
        let corners = e.corners.map(angle_at);
        let (near, far) = (
            corners.iter().copied().fold(f64::MAX, f64::min),
            corners.iter().copied().fold(f64::MIN, f64::max),
        );
        for c in 0..3 {
            let point = element_mean(e, |x| {
                point_radiosity(rho(c), intensity, light, x, e.normal)
            });
            if far < inner {
                let dev = rel(e.b[c], point);
                assert!(
                    dev < 1.5e-2,
                    "inside the inner cone at {:?}: B = {} vs {point}",
                    e.centroid,
                    e.b[c]
                );
                worst = worst.max(dev);
            } else if near > outer {
                assert_eq!(e.b[c], 0.0, "outside the outer cone at {:?}", e.centroid);
            } else if near > inner && far < outer {
                // The falloff: some light, less than the full point-light value.
                assert!(
                    e.b[c] > 0.0 && e.b[c] < point,
                    "in the falloff at {:?}: B = {} vs {point}",
                    e.centroid,
                    e.b[c]
                );
            }
        }
        if far < inner {
            inside += 1;
        } else if near > outer {
            outside += 1;
        } else if near > inner && far < outer {
            between += 1;
        }
    }
    assert!(
        inside > 50 && outside > 1000 && between > 20,
        "{inside} / {between} / {outside}"
    );
    println!(
        "spot light: {inside} elements inside (worst relative deviation {worst:.3e}), \
         {between} in the falloff, {outside} outside (all exactly 0)"
    );
}

#[test]
fn directional_light_and_shadow() {
    let illuminance = 3.0;
    // The occluder's footprint, off the element grid's centroids.
    let (x0, x1, z0, z1, y) = (-1.05f32, 0.95f32, -0.95f32, 1.55f32, 1.0f32);
    let mut doc = floor_doc();
    let black = doc.material(diffuse("black", [0.0; 3], true));
    let (p, i) = rect_up(x0, x1, z0, z1, y);
    doc.mesh("occluder", &p, &i, black);
    doc.light(
        format!(r#"{{"name":"sun","type":"directional","intensity":{illuminance}}}"#),
        POINT_DOWN,
    );
    let scene = doc.load().expect("scene loads");
    let floor = surface_index(&scene, "floor");
    let occluder = surface_index(&scene, "occluder");
    // Double-sided: each of the two triangles is also imported facing down.
    assert_eq!(
        scene
            .triangles
            .iter()
            .filter(|t| t.surface == occluder)
            .count(),
        4
    );
    let r = bake(&scene);
    let under = |x: [f64; 3]| {
        (f64::from(x0)..=f64::from(x1)).contains(&x[0])
            && (f64::from(z0)..=f64::from(z1)).contains(&x[2])
    };
    // Wholly under the footprint: dark; wholly beside it (bounding boxes apart): the open
    // sun exactly; across its edge: the share of the element's nine points in the sun.
    let apart = |e: &Element| {
        let xs = e.corners.map(|c| c[0]);
        let zs = e.corners.map(|c| c[2]);
        xs.iter().all(|&x| x <= f64::from(x0))
            || xs.iter().all(|&x| x >= f64::from(x1))
            || zs.iter().all(|&z| z <= f64::from(z0))
            || zs.iter().all(|&z| z >= f64::from(z1))
    };
    let (mut lit, mut shadowed, mut worst) = (0, 0, 0.0f64);
    let (mut area, mut sunlit) = (0.0, 0.0);
    for e in elements(&r) {
        if e.surface == occluder {
            assert_eq!(e.b, [0.0; 3], "the occluder is black");
            continue;
        }
        assert_eq!(e.surface, floor);
        let full = |c: usize| rho(c) * illuminance / PI;
        let [a, b, c] = e.corners.map(glam::DVec3::from);
        let da = 0.5 * (b - a).cross(c - a).length();
        area += da;
        sunlit += da * e.b[0] / full(0);
        if corners_in(&e, true, under) {
            assert_eq!(e.b, [0.0; 3], "shadowed element at {:?}", e.centroid);
            shadowed += 1;
        } else if apart(&e) {
            for c in 0..3 {
                let dev = rel(e.b[c], full(c));
                assert!(
                    dev < 1e-6,
                    "lit element at {:?}: B = {} vs {}",
                    e.centroid,
                    e.b[c],
                    full(c)
                );
                worst = worst.max(dev);
            }
            lit += 1;
        } else {
            for c in 0..3 {
                assert!(
                    (0.0..=full(c) * (1.0 + 1e-9)).contains(&e.b[c]),
                    "across the edge at {:?}: B = {}",
                    e.centroid,
                    e.b[c]
                );
            }
        }
    }
    // The footprint is 2 m × 2.5 m of the 100 m² floor: the floor's mean is 95 % of the sun.
    let share = sunlit / area;
    assert!(
        (share - 0.95).abs() < 2e-3,
        "the floor holds {share} of the open sun, 0.95 expected"
    );
    assert!(shadowed > 0 && lit > 0);
    println!(
        "directional light: {lit} lit elements (worst relative deviation {worst:.3e}), \
         {shadowed} shadowed (all exactly 0)"
    );
}

#[test]
fn base_color_texture_mean_scales_reflectance() {
    let texels: [[u8; 3]; 4] = [[255, 0, 128], [64, 200, 32], [10, 20, 30], [128, 128, 128]];
    let img = image::RgbImage::from_raw(2, 2, texels.concat()).expect("2 × 2 RGB");
    let mut png = Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png)
        .expect("PNG encodes");
    // Exact in `f32`, so the expected product needs no rounding.
    let factor = [1.0, 0.5, 0.75];

    let mut doc = Doc::default();
    let m = doc.material(format!(
        r#"{{"name":"textured","pbrMetallicRoughness":{{"baseColorFactor":[{},{},{},1],"baseColorTexture":{{"index":0}}}}}}"#,
        factor[0], factor[1], factor[2]
    ));
    let (p, i) = rect_up(0.0, 1.0, 0.0, 1.0, 0.0);
    doc.mesh_uv("tile", &p, Some(&uv_of(&p)), &i, m);
    add_texture(
        &mut doc,
        r#""magFilter":9729,"minFilter":9729"#,
        &format!("data:image/png;base64,{}", base64(png.get_ref())),
    );
    let scene = doc.load().expect("scene with a data-URI texture loads");
    let s = &scene.surfaces[surface_index(&scene, "tile") as usize];
    // The mean of the decoded (linear) texels, per channel.
    let mean: [f64; 3] = std::array::from_fn(|c| {
        texels
            .iter()
            .map(|t| srgb_to_linear(f64::from(t[c]) / 255.0))
            .sum::<f64>()
            / 4.0
    });
    for c in 0..3 {
        let want = factor[c] * mean[c];
        let dev = (s.reflectance[c] - want).abs();
        assert!(
            dev < 1e-12,
            "channel {c}: reflectance {} vs {want}",
            s.reflectance[c]
        );
        println!(
            "texture: channel {c} reflectance {} (want {want}, deviation {dev:.1e})",
            s.reflectance[c]
        );
    }
}

#[test]
fn lights_with_bad_parameters_are_typed_errors() {
    let cases = [
        (
            "equal cones",
            r#"{"name":"bad","type":"spot","intensity":1,"spot":{"innerConeAngle":0.5,"outerConeAngle":0.5}}"#,
        ),
        (
            "inner above outer",
            r#"{"name":"bad","type":"spot","intensity":1,"spot":{"innerConeAngle":0.6,"outerConeAngle":0.4}}"#,
        ),
        (
            "range 0",
            r#"{"name":"bad","type":"point","intensity":1,"range":0}"#,
        ),
    ];
    for (what, light) in cases {
        // With and without geometry: the light is checked either way.
        for with_floor in [false, true] {
            let mut doc = if with_floor {
                floor_doc()
            } else {
                Doc::default()
            };
            doc.light(light.to_string(), r#""translation":[0,2,0]"#);
            match doc.load() {
                Err(SceneError::InvalidLight {
                    light: name,
                    what: msg,
                }) => {
                    assert_eq!(name, "bad", "{what}: {msg}");
                }
                other => panic!("{what}: expected InvalidLight, got {other:?}"),
            }
        }
    }
}

/// Slice import has no directory: an image that is neither a data URI nor a buffer view is a
/// typed error, and nothing is read from the working directory.
#[test]
fn external_image_in_slice_import_is_a_typed_error() {
    let mut doc = Doc::default();
    let m = doc.material(
        r#"{"name":"textured","pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}"#.into(),
    );
    let (p, i) = rect_up(0.0, 1.0, 0.0, 1.0, 0.0);
    doc.mesh("tile", &p, &i, m);
    doc.extra.push(r#""textures":[{"source":0}]"#.into());
    doc.extra
        .push(r#""images":[{"uri":"Cargo.toml","mimeType":"image/png"}]"#.into());
    match doc.load() {
        Err(SceneError::Texture { image, what }) => {
            assert_eq!(image, "Cargo.toml");
            assert!(what.contains("external"), "{what}");
        }
        other => panic!("expected Texture, got {other:?}"),
    }
}

/// A one-tile scene whose material (factor 0.5, 0.25, 0.125) reads one base-colour texture from
/// `uri`, and the imported tile.
fn textured_tile(uri: &str) -> (Scene, radiant::scene::Surface) {
    let mut doc = Doc::default();
    let m = doc.material(
        r#"{"name":"textured","pbrMetallicRoughness":{"baseColorFactor":[0.5,0.25,0.125,1],"baseColorTexture":{"index":0}}}"#
            .into(),
    );
    let (p, i) = rect_up(0.0, 1.0, 0.0, 1.0, 0.0);
    doc.mesh_uv("tile", &p, Some(&uv_of(&p)), &i, m);
    add_texture(&mut doc, r#""magFilter":9729"#, uri);
    let scene = doc
        .load()
        .expect("a texture fault is a warning, not an error");
    let tile = scene.surfaces[surface_index(&scene, "tile") as usize].clone();
    (scene, tile)
}

/// An image whose declared MIME type is not what its bytes are is decoded by its bytes, with one
/// warning that says so (a PNG labelled `image/jpeg`, and a JPEG labelled `image/png`).
#[test]
fn an_image_is_decoded_by_its_bytes_whatever_its_mime_type_says() {
    let grey = vec![128u8; 4 * 4 * 4];
    let png = png_uri(4, 4, grey.clone()).replace("data:image/png", "data:image/jpeg");
    let mut jpeg = Cursor::new(Vec::new());
    image::RgbImage::from_raw(4, 4, vec![128u8; 4 * 4 * 3])
        .expect("4 × 4 RGB")
        .write_to(&mut jpeg, image::ImageFormat::Jpeg)
        .expect("JPEG encodes");
    let jpeg = format!("data:image/png;base64,{}", base64(jpeg.get_ref()));
    for (uri, is) in [(png, "image/png"), (jpeg, "image/jpeg")] {
        let (scene, tile) = textured_tile(&uri);
        assert!(
            tile.base_color_texture.is_some(),
            "{is}: the texture is kept"
        );
        let warnings = scene.warnings();
        assert_eq!(warnings.len(), 1, "{is}: {warnings:?}");
        assert!(
            warnings[0].contains(&format!("its bytes are {is}")),
            "{warnings:?}"
        );
        // Grey 128 is 0.2158 linear; JPEG may round a level either way.
        let want = 0.5 * srgb_to_linear(128.0 / 255.0);
        assert!(
            (tile.reflectance[0] - want).abs() < 0.01 * want,
            "{is}: {:?}",
            tile.reflectance
        );
    }
}

/// A texture that cannot be decoded, or whose header claims more texels than the import takes,
/// is one warning naming the image and the material that reads it; the material keeps its
/// colour factor and the scene loads (as an engine would still draw the level).
#[test]
fn an_undecodable_or_oversized_texture_warns_and_keeps_the_factor() {
    /// CRC-32 (ISO 3309, as PNG chunks carry it), bit by bit.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
    fn chunk(kind: &[u8], data: &[u8]) -> Vec<u8> {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        c.extend(kind);
        c.extend(data);
        c.extend(crc32(&c[4..]).to_be_bytes());
        c
    }
    // The header of a 16384 × 16384 RGBA PNG and no texels: refused from the header, before any
    // allocation of its 1 GiB.
    let mut huge = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = 16384u32.to_be_bytes().to_vec();
    ihdr.extend(16384u32.to_be_bytes());
    ihdr.extend([8, 6, 0, 0, 0]);
    huge.extend(chunk(b"IHDR", &ihdr));
    huge.extend(chunk(b"IDAT", &[]));
    huge.extend(chunk(b"IEND", &[]));
    let huge = format!("data:image/png;base64,{}", base64(&huge));
    let garbage = format!("data:image/png;base64,{}", base64(b"not an image at all"));
    let truncated = png_uri(8, 8, vec![200u8; 8 * 8 * 4]);
    let truncated = truncated[..truncated.len() - 24].to_string();
    for (uri, what) in [
        (huge, "16384×16384"),
        (garbage, "neither PNG nor JPEG"),
        (truncated, "cannot decode"),
    ] {
        let (scene, tile) = textured_tile(&uri);
        assert!(tile.base_color_texture.is_none(), "{what}");
        assert_eq!(tile.reflectance, [0.5, 0.25, 0.125], "{what}");
        let warnings = scene.warnings();
        assert_eq!(warnings.len(), 1, "{what}: {warnings:?}");
        let w = &warnings[0];
        assert!(w.contains(what) && w.contains("material 'textured'"), "{w}");
        assert!(w.contains("node 'tile'") && !w.contains('\n'), "{w}");
    }
}

#[test]
fn degenerate_triangles_are_skipped_and_reported() {
    // The floor plus a mesh whose two triangles are a good one and a collinear one.
    let mut doc = floor_doc();
    doc.light(
        r#"{"name":"bulb","type":"point","color":[1,1,1],"intensity":10}"#.to_string(),
        r#""translation":[0,2,0]"#,
    );
    let m = doc.material(diffuse("card", [0.5; 3], false));
    let positions = [
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 1.0, 1.0],
        [2.0, 1.0, 2.0],
        [3.0, 1.0, 3.0],
    ];
    doc.mesh("card", &positions, &[0, 2, 1, 0, 3, 4], m);
    let scene = doc.load().expect("scene loads");
    assert_eq!(scene.stats.degenerate_triangles, 1);
    let r = bake(&scene);
    assert!(
        r.report
            .warnings
            .iter()
            .any(|w| w.contains("skipped 1 degenerate")),
        "warnings: {:?}",
        r.report.warnings
    );
    assert!(r.radiosity.iter().flatten().all(|v| v.is_finite()));
}

// ---------------------------------------------------------------------------------------------
// Textures over element footprints, alpha masks and sky light.

/// Bakes with both hierarchies: the per-triangle one and the clustered one.
fn bake_both(scene: &Scene, p: &BakeParams) -> [BakeResult; 2] {
    let triangles = Bake::new(scene, p)
        .expect("bake prepares")
        .run_to_end(&mut |_| {})
        .expect("bake runs");
    let clustered = radiant::radiosity::cluster::bake(
        scene,
        p,
        &radiant::radiosity::cluster::ClusterParams::default(),
        &|_, _, _| {},
    )
    .expect("clustered bake runs");
    [triangles, clustered]
}

/// The unit-square floor under a uniform sky of radiance 1 (in the scene's extras), textured
/// with a 4 × 4 checkerboard of two greys (nearest filtering).
fn checker_floor() -> (Scene, [f64; 2]) {
    let (light, dark) = (230u8, 40u8);
    let mut rgba = Vec::new();
    for y in 0..4 {
        for x in 0..4 {
            let v = if (x + y) % 2 == 0 { light } else { dark };
            rgba.extend([v, v, v, 255]);
        }
    }
    let mut doc = Doc::default();
    let m = doc.material(
        r#"{"name":"checker","pbrMetallicRoughness":{"baseColorTexture":{"index":0},"metallicFactor":0}}"#
            .into(),
    );
    let (p, i) = rect_up(0.0, 1.0, 0.0, 1.0, 0.0);
    doc.mesh_uv("floor", &p, Some(&uv_of(&p)), &i, m);
    add_texture(
        &mut doc,
        r#""magFilter":9728,"minFilter":9728"#,
        &png_uri(4, 4, rgba),
    );
    let json = doc.json().replacen(
        r#""scenes":[{"#,
        r#""scenes":[{"extras":{"radiant":{"sky":"1"}},"#,
        1,
    );
    let scene = load_gltf_slice(json.as_bytes()).expect("checker floor loads");
    let lin = |v: u8| srgb_to_linear(f64::from(v) / 255.0);
    (scene, [lin(light), lin(dark)])
}

#[test]
fn texture_footprints_give_each_element_its_own_reflectance() {
    let (scene, [light, dark]) = checker_floor();
    assert!(matches!(
        scene.sky,
        Some(radiant::scene::Sky::Uniform { .. })
    ));
    let s = &scene.surfaces[0];
    assert!((s.reflectance[0] - 0.5 * (light + dark)).abs() < 1e-9);
    let mut p = BakeParams::default();
    // Elements with legs of 1/8: each lies inside one checker square of 1/4.
    p.mesh.patch_size = 1.0;
    p.mesh.element_levels = 2;
    for (which, r) in ["per-triangle", "clustered"]
        .iter()
        .zip(bake_both(&scene, &p))
    {
        let mut worst: f64 = 0.0;
        let (mut lights, mut darks) = (0, 0);
        for e in elements(&r) {
            let (cx, cz) = (e.centroid[0], e.centroid[2]);
            let cell = ((cx * 4.0).floor() as i64 + (cz * 4.0).floor() as i64) % 2 == 0;
            let want = if cell { light } else { dark };
            if cell {
                lights += 1;
            } else {
                darks += 1;
            }
            for c in 0..3 {
                worst = worst.max(rel(e.b[c], want));
            }
        }
        println!(
            "{which}: {} elements ({lights} light, {darks} dark): worst deviation from ρ·L of \
             their own footprint {worst:.2e} (texture mean {:.3}, squares {light:.3} / {dark:.3})",
            lights + darks,
            0.5 * (light + dark)
        );
        assert!(lights > 0 && darks > 0);
        assert!(worst < 0.01, "{which}: worst {worst}");
    }
}

/// The view factor from a point at height 0 to the rectangle `[x0, x1] × [z0, z1]` at height
/// `h` above it, parallel and facing it (corner superposition).
fn view_factor_to_rect(p: [f64; 2], x: [f64; 2], z: [f64; 2], h: f64) -> f64 {
    let f = |a: f64, b: f64| {
        let (ra, rb) = ((h * h + a * a).sqrt(), (h * h + b * b).sqrt());
        (a / ra * (b / ra).atan() + b / rb * (a / rb).atan()) / (2.0 * PI)
    };
    let (x0, x1, z0, z1) = (x[0] - p[0], x[1] - p[0], z[0] - p[1], z[1] - p[1]);
    f(x1, z1) - f(x0, z1) - f(x1, z0) + f(x0, z0)
}

#[test]
fn sky_lights_an_open_floor_exactly_and_an_occluded_one_by_its_visible_sky() {
    // Open: every ray escapes, so B = ρ·L exactly. A gradient sky: E = π (h + 2 (z − h) / 3).
    let mut scene = floor_doc().load().expect("floor");
    let (zen, hor) = (2.0, 0.5);
    for (sky, l) in [
        (radiant::scene::Sky::Uniform { radiance: [1.5; 3] }, 1.5),
        (
            radiant::scene::Sky::Gradient {
                zenith: [zen; 3],
                horizon: [hor; 3],
            },
            hor + 2.0 * (zen - hor) / 3.0,
        ),
    ] {
        scene.sky = Some(sky.clone());
        let mut p = params();
        p.ff.sky_rays = 1024;
        let r = Bake::new(&scene, &p)
            .expect("prepares")
            .run_to_end(&mut |_| {})
            .expect("runs");
        let mut worst: f64 = 0.0;
        for e in elements(&r) {
            for c in 0..3 {
                worst = worst.max(rel(e.b[c], rho(c) * l));
            }
        }
        println!("open floor under {sky:?}: worst deviation {worst:.2e}");
        let tol = if matches!(sky, radiant::scene::Sky::Uniform { .. }) {
            1e-9
        } else {
            // Stratified cosine sampling of a linear-in-cos integrand.
            5e-3
        };
        assert!(worst < tol, "{sky:?}: {worst}");
    }
    // With a black square roof 2 m × 2 m at 1 m: each element sees the sky minus the roof.
    let mut doc = floor_doc();
    let black = doc.material(diffuse("roof", [0.0; 3], true));
    let (pr, ir) = rect_up(-1.0, 1.0, -1.0, 1.0, 1.0);
    doc.mesh("roof", &pr, &ir, black);
    let mut scene = doc.load().expect("floor and roof");
    let l = 1.0;
    scene.sky = Some(radiant::scene::Sky::Uniform { radiance: [l; 3] });
    let mut p = params();
    p.ff.sky_rays = 1024;
    let r = Bake::new(&scene, &p)
        .expect("prepares")
        .run_to_end(&mut |_| {})
        .expect("runs");
    let floor = surface_index(&scene, "floor");
    let (mut worst, mut count, mut sum_dev): (f64, usize, f64) = (0.0, 0, 0.0);
    for e in elements(&r).iter().filter(|e| e.surface == floor) {
        let f = view_factor_to_rect(
            [e.centroid[0], e.centroid[2]],
            [-1.0, 1.0],
            [-1.0, 1.0],
            1.0,
        );
        let want = rho(0) * l * (1.0 - f);
        let dev = (e.b[0] - want) / (rho(0) * l);
        worst = worst.max(dev.abs());
        sum_dev += dev;
        count += 1;
    }
    println!(
        "floor under a roof: {count} elements, worst |B − ρL(1 − F)| / ρL {worst:.2e}, mean {:.2e}",
        sum_dev / count as f64
    );
    // 1024 stratified rays per element: about 1 % per element, unbiased on average.
    assert!(worst < 0.02, "worst {worst}");
    assert!((sum_dev / count as f64).abs() < 2e-3);

    // The reference tracer sees the same sky: the floor's mean radiosity.
    let tracer = radiant::reference::Tracer::new(&scene).expect("tracer");
    let params = radiant::reference::Params {
        samples: Some(200_000),
        target_error: None,
        ..Default::default()
    };
    let (est, _) = tracer.surfaces(&params, &|_| {}).expect("trace");
    let baked = r.surfaces[floor as usize].mean[0];
    let traced = &est[floor as usize].estimate;
    println!(
        "floor mean: bake {baked:.5}, tracer {:.5} ± {:.5}",
        traced.mean[0], traced.se[0]
    );
    assert!((baked - traced.mean[0]).abs() < 4.0 * traced.se[0] + 2e-3 * baked);
}

/// A sun straight down, a black plane at 1 m whose texture is transparent on its left half
/// (u < 0.5) and opaque on its right, and the floor below.
fn masked_scene() -> Scene {
    let mut doc = floor_doc();
    let mut rgba = Vec::new();
    for x in 0..2u8 {
        rgba.extend([0, 0, 0, if x == 0 { 0 } else { 255 }]);
    }
    let m = doc.material(
        r#"{"name":"leaves","alphaMode":"MASK","alphaCutoff":0.5,"pbrMetallicRoughness":{"baseColorTexture":{"index":0},"baseColorFactor":[0,0,0,1],"metallicFactor":0}}"#
            .into(),
    );
    // The plane covers [-2, 2] × [-2, 2]; UVs map it to [0, 1]².
    let (p, i) = rect_up(-2.0, 2.0, -2.0, 2.0, 1.0);
    let uv: Vec<[f32; 2]> = p
        .iter()
        .map(|v| [(v[0] + 2.0) / 4.0, (v[2] + 2.0) / 4.0])
        .collect();
    doc.mesh_uv("leaves", &p, Some(&uv), &i, m);
    add_texture(
        &mut doc,
        r#""magFilter":9728,"minFilter":9728,"wrapS":33071,"wrapT":33071"#,
        &png_uri(2, 1, rgba),
    );
    doc.light(
        r#"{"name":"sun","type":"directional","color":[1,1,1],"intensity":1000}"#.into(),
        POINT_DOWN,
    );
    doc.load().expect("masked scene loads")
}

#[test]
fn alpha_masks_let_light_through_where_they_cut() {
    let scene = masked_scene();
    assert!(matches!(
        scene.surfaces[surface_index(&scene, "leaves") as usize].alpha,
        radiant::scene::AlphaMode::Mask { .. }
    ));
    let floor = surface_index(&scene, "floor");
    let open = rho(0) * 1000.0 / PI;
    for (which, r) in ["per-triangle", "clustered"]
        .iter()
        .zip(bake_both(&scene, &params()))
    {
        // Wholly under the plane: lit where x < 0 (the cut half), dark where x > 0. The mask's
        // edge lies on element edges, so each element is wholly one or the other.
        let (mut lit, mut dark, mut wrong) = (0, 0, Vec::new());
        let mut flux = 0.0;
        let mut area = 0.0;
        for e in elements(&r).iter().filter(|e| e.surface == floor) {
            let [x, _, z] = e.centroid;
            if !corners_in(e, true, |c| c[0].abs() <= 2.0 && c[2].abs() <= 2.0) {
                continue;
            }
            let want = if x < 0.0 { open } else { 0.0 };
            if x < 0.0 {
                lit += 1;
            } else {
                dark += 1;
            }
            if (e.b[0] - want).abs() > 1e-9 * open {
                wrong.push(format!("({x:.3}, {z:.3}): {} want {want}", e.b[0]));
            }
            flux += e.b[0];
            area += 1.0;
        }
        println!(
            "{which}: under the masked plane {lit} lit and {dark} shadowed elements; fraction of \
             the open sun's light {:.4} (closed form 0.5)",
            flux / area / open
        );
        assert!(wrong.is_empty(), "{which}: {}", wrong.join("; "));
        assert_eq!(lit, dark);
    }
    // The tracer, by sampling: the floor under the plane gets half the sun, within 4 se.
    let tracer = radiant::reference::Tracer::new(&scene).expect("tracer");
    let points: Vec<radiant::reference::Point> = [(-1.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
        .iter()
        .map(|&(x, z, _)| radiant::reference::Point {
            name: format!("{x}"),
            position: glam::DVec3::new(x, 0.0, z),
            normal: glam::DVec3::Y,
        })
        .collect();
    let params = radiant::reference::Params {
        samples: Some(4096),
        target_error: None,
        ..Default::default()
    };
    let (est, _) = tracer.points(&points, &params, &|_| {}).expect("trace");
    println!(
        "tracer: under the cut half {:.3} (open {open:.3}), under the opaque half {:.3}",
        est[0].mean[0], est[1].mean[0]
    );
    assert!((est[0].mean[0] - open).abs() < 1e-9 * open + 4.0 * est[0].se[0]);
    assert!(est[1].mean[0].abs() < 1e-12);
}

/// An image URI that names a device (`/dev/zero`, `/dev/urandom`: read without end) is not
/// read: one warning that says it is not a regular file, and the scene loads with the
/// material's factor.
#[test]
fn an_image_that_is_a_device_is_not_read() {
    let dir = std::env::temp_dir().join(format!("radiant-device-image-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    for device in ["/dev/zero", "/dev/urandom"] {
        let mut doc = Doc::default();
        let m = doc.material(
            r#"{"name":"textured","pbrMetallicRoughness":{"baseColorFactor":[0.5,0.25,0.125,1],"baseColorTexture":{"index":0}}}"#
                .into(),
        );
        let (p, i) = rect_up(0.0, 1.0, 0.0, 1.0, 0.0);
        doc.mesh_uv("tile", &p, Some(&uv_of(&p)), &i, m);
        add_texture(&mut doc, r#""magFilter":9729"#, device);
        let path = dir.join("device.gltf");
        std::fs::write(&path, doc.json()).expect("write");
        let t = std::time::Instant::now();
        let scene = radiant::scene::load_gltf(&path).expect("a warning, not an error");
        assert!(t.elapsed().as_secs_f64() < 10.0, "{device} was read");
        let tile = &scene.surfaces[surface_index(&scene, "tile") as usize];
        assert!(tile.base_color_texture.is_none() && tile.reflectance == [0.5, 0.25, 0.125]);
        let warnings = scene.warnings();
        assert!(
            warnings.len() == 1 && warnings[0].contains("not a regular file"),
            "{device}: {warnings:?}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
