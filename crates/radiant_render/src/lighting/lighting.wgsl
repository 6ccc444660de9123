// Tiled deferred lighting (Andersson, "DirectX 11 Rendering in Battlefield 3", GDC 2011): each
// 16x16 tile finds its depth bounds, culls the punctual lights against the tile's view-space box,
// then shades its pixels with the survivors. Output radiance, linear HDR:
//   direct (Lambertian, KHR_lights_punctual units) + albedo * light-map H * AO + emission.
// Range falloff is KHR_lights_punctual's recommended window; punctual lights cast no shadows.
// Where no geometry is, the sky's radiance in the pixel's direction (radiant_scene::Sky's
// mapping: +Y up, the gradient linear in sin(elevation), the image equirectangular, nearest).

@group(0) @binding(0) var<uniform> camera: Camera;
@group(0) @binding(1) var<storage, read> lights: array<Light>;
@group(0) @binding(2) var g_albedo: texture_2d<f32>;
@group(0) @binding(3) var g_normal: texture_2d<f32>;
@group(0) @binding(4) var g_material: texture_2d<f32>;
@group(0) @binding(5) var g_irradiance: texture_2d<f32>;
@group(0) @binding(6) var g_emissive: texture_2d<f32>;
// Depth as an unfilterable float texture, read with textureLoad: what GLSL (wgpu's GL
// backend) can read; a `texture_depth_2d` cannot be loaded from there.
@group(0) @binding(7) var g_depth: texture_2d<f32>;
@group(0) @binding(8) var ao_texture: texture_2d<f32>;
@group(0) @binding(9) var out_radiance: texture_storage_2d<rgba16float, write>;
@group(0) @binding(10) var<uniform> settings: LightingSettings;
@group(0) @binding(11) var<uniform> sky: Sky;
@group(0) @binding(12) var sky_image: texture_2d<f32>;

struct Sky {
    // 0 none, 1 uniform, 2 gradient, 3 image.
    kind: u32,
    width: u32,
    height: u32,
    _pad: u32,
    a: vec4<f32>,
    b: vec4<f32>,
};

fn sky_radiance(dir: vec3<f32>) -> vec3<f32> {
    switch sky.kind {
        case 1u: { return sky.a.rgb; }
        case 2u: { return mix(sky.b.rgb, sky.a.rgb, clamp(dir.y, 0.0, 1.0)); }
        case 3u: {
            let u = 0.5 + atan2(dir.x, -dir.z) / (2.0 * PI);
            let v = acos(clamp(dir.y, -1.0, 1.0)) / PI;
            let size = vec2<u32>(sky.width, sky.height);
            let xy = min(vec2<u32>(max(vec2<f32>(u, v) * vec2<f32>(size), vec2<f32>(0.0))), size - vec2<u32>(1u));
            return textureLoad(sky_image, vec2<i32>(xy), 0).rgb;
        }
        default: { return vec3<f32>(0.0); }
    }
}

struct Light {
    position_range: vec4<f32>,
    direction_kind: vec4<f32>,
    color: vec4<f32>,
    spot: vec4<f32>,
};

struct LightingSettings {
    // 0 lit, 1 albedo, 2 normal, 3 material, 4 light map (albedo * H), 5 emissive,
    // 6 depth (linear, / far), 7 AO, 8 direct light only.
    debug_view: u32,
    // 1 when an AO texture is bound.
    use_ao: u32,
    _pad0: u32,
    _pad1: u32,
};

const TILE: u32 = 16u;
const MAX_TILE_LIGHTS: u32 = 256u;
const PI: f32 = 3.14159265358979;

var<workgroup> tile_min: atomic<u32>;
var<workgroup> tile_max: atomic<u32>;
var<workgroup> tile_count: atomic<u32>;
var<workgroup> tile_lights: array<u32, 256>;

// KHR_lights_punctual's recommended cutoff, clamp(1 - (d / range)^4, 0, 1), as the bake uses;
// range 0 here means none (lights with a non-positive range are not uploaded).
fn range_window(d: f32, range: f32) -> f32 {
    if (range <= 0.0) {
        return 1.0;
    }
    let r = d / range;
    return clamp(1.0 - r * r * r * r, 0.0, 1.0);
}

fn light_irradiance(l: Light, p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let kind = u32(l.direction_kind.w);
    if (kind == 0u) {
        let wi = -l.direction_kind.xyz;
        return l.color.rgb * max(dot(n, wi), 0.0);
    }
    let to_light = l.position_range.xyz - p;
    let d2 = max(dot(to_light, to_light), 1e-8);
    let d = sqrt(d2);
    let wi = to_light / d;
    var e = l.color.rgb * max(dot(n, wi), 0.0) * range_window(d, l.position_range.w) / d2;
    if (kind == 2u) {
        let cd = dot(l.direction_kind.xyz, -wi);
        let t = clamp((cd - l.spot.x) * l.spot.y, 0.0, 1.0);
        e *= t * t;
    }
    return e;
}

@compute @workgroup_size(16, 16, 1)
fn lighting_main(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let size = vec2<u32>(camera.viewport.xy);
    let inside = gid.x < size.x && gid.y < size.y;
    let coord = vec2<i32>(min(gid.xy, size - vec2<u32>(1u)));
    let depth = textureLoad(g_depth, coord, 0).r;

    if (lid == 0u) {
        atomicStore(&tile_min, 0x7f7fffffu);
        atomicStore(&tile_max, 0u);
        atomicStore(&tile_count, 0u);
    }
    workgroupBarrier();
    if (inside && depth < 1.0) {
        // Non-negative floats order like their bit patterns.
        atomicMin(&tile_min, bitcast<u32>(depth));
        atomicMax(&tile_max, bitcast<u32>(depth));
    }
    workgroupBarrier();
    let dmin = bitcast<f32>(atomicLoad(&tile_min));
    let dmax = bitcast<f32>(atomicLoad(&tile_max));
    let any_geometry = dmax >= dmin;

    // The tile's view-space bounding box from its 8 corners.
    let light_count = u32(camera.params.z);
    if (any_geometry) {
        let lo_px = vec2<f32>(wid.xy * TILE);
        let hi_px = min(lo_px + vec2<f32>(f32(TILE)), camera.viewport.xy);
        var bmin = vec3<f32>(1e30);
        var bmax = vec3<f32>(-1e30);
        for (var c = 0u; c < 8u; c++) {
            let px = vec2<f32>(select(lo_px.x, hi_px.x, (c & 1u) != 0u), select(lo_px.y, hi_px.y, (c & 2u) != 0u));
            let dz = select(dmin, dmax, (c & 4u) != 0u);
            let v = view_position(camera.inv_proj, px * camera.viewport.zw, dz);
            bmin = min(bmin, v);
            bmax = max(bmax, v);
        }
        for (var i = lid; i < light_count; i += TILE * TILE) {
            let l = lights[i];
            var keep = true;
            let range = l.position_range.w;
            if (u32(l.direction_kind.w) != 0u && range > 0.0) {
                let c = (camera.view * vec4<f32>(l.position_range.xyz, 1.0)).xyz;
                let q = clamp(c, bmin, bmax);
                keep = dot(q - c, q - c) <= range * range;
            }
            if (keep) {
                let slot = atomicAdd(&tile_count, 1u);
                if (slot < MAX_TILE_LIGHTS) {
                    tile_lights[slot] = i;
                }
            }
        }
    }
    workgroupBarrier();
    if (!inside) {
        return;
    }
    if (depth >= 1.0) {
        let uv = (vec2<f32>(coord) + 0.5) * camera.viewport.zw;
        let far = camera.inv_view_proj * vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 1.0, 1.0);
        let dir = normalize(far.xyz / far.w - camera.position.xyz);
        var background = sky_radiance(dir);
        // Debug views show their input, which the sky has none of.
        if (settings.debug_view != 0u) {
            background = vec3<f32>(0.0);
        }
        textureStore(out_radiance, coord, vec4<f32>(background, 1.0));
        return;
    }

    let uv = (vec2<f32>(coord) + 0.5) * camera.viewport.zw;
    let vp = view_position(camera.inv_proj, uv, depth);
    let wp4 = camera.inv_view_proj * vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, depth, 1.0);
    let p = wp4.xyz / wp4.w;
    let albedo = textureLoad(g_albedo, coord, 0).rgb;
    let n = oct_decode(textureLoad(g_normal, coord, 0).xy);
    let material = textureLoad(g_material, coord, 0).xy;
    let h = textureLoad(g_irradiance, coord, 0).rgb;
    let emissive = textureLoad(g_emissive, coord, 0).rgb;
    var ao = 1.0;
    if (settings.use_ao != 0u) {
        ao = textureLoad(ao_texture, coord, 0).r;
    }

    var direct_e = vec3<f32>(0.0);
    let n_tile = min(atomicLoad(&tile_count), MAX_TILE_LIGHTS);
    for (var k = 0u; k < n_tile; k++) {
        direct_e += light_irradiance(lights[tile_lights[k]], p, n);
    }
    let direct = albedo / PI * direct_e;
    let indirect = albedo * h * ao;

    var out = direct + indirect + emissive;
    switch settings.debug_view {
        case 1u: { out = albedo; }
        case 2u: { out = n * 0.5 + 0.5; }
        case 3u: { out = vec3<f32>(material, 0.0); }
        case 4u: { out = albedo * h; }
        case 5u: { out = emissive; }
        case 6u: { out = vec3<f32>(-vp.z / camera.params.y); }
        case 7u: { out = vec3<f32>(ao); }
        case 8u: { out = direct; }
        default: {}
    }
    textureStore(out_radiance, coord, vec4<f32>(out, 1.0));
}
