// G-buffer pass of a deferred renderer (Saito & Takahashi 1990; Deering et al. 1988): one
// geometry pass writes albedo, an octahedral normal, material, the baked light-map irradiance
// (sampled on the second UV set) and emission; depth goes to Depth32Float and positions are
// reconstructed from it later. Geometry is two-sided: back faces flip their normal, except for
// double-sided materials, whose back is a separate twin (their back faces are discarded).
// Group 1 is the material: the base-colour texture (sRGB, mipmapped, anisotropic; 1×1 white
// without one) multiplies the vertex albedo, and alpha below the cut-off is discarded.
// Dynamic surfaces (light-map page PROBE_LIT) have no chart: their irradiance comes from the
// probe grid at the fragment (trilinear over the cell's valid probes, each probe's order-2
// harmonics evaluated for the normal).

@group(0) @binding(0) var<uniform> camera: Camera;
@group(0) @binding(1) var lightmap: texture_2d_array<f32>;
@group(0) @binding(2) var lightmap_sampler: sampler;
// Copies' own light-map coordinates and pages, in their prototype's vertex order.
struct InstanceUv {
    uv: vec2<f32>,
    page: u32,
    _pad: u32,
};
@group(0) @binding(3) var<storage, read> instance_uvs: array<InstanceUv>;
struct ProbeGrid {
    // The first probe (relative to the scene origin, like positions) and the step.
    origin_step: vec4<f32>,
    // Probes along x, y, z; w 0 when there is no grid.
    dims: vec4<u32>,
};
@group(0) @binding(4) var<uniform> probe_grid: ProbeGrid;
// Per probe nine RGB coefficients; the first one's w is the probe's validity (1 or 0).
@group(0) @binding(5) var<storage, read> probes: array<vec4<f32>>;

const PROBE_LIT: u32 = 0xffffffffu;

// H for unit normal n from probe k: Σ c_j Y_j(n), real SH of order 2 in
// radiant_radiosity::cluster::sh::basis's order.
fn probe_h(k: u32, n: vec3<f32>) -> vec3<f32> {
    let b = k * 9u;
    var h = probes[b].rgb * 0.2820948;
    h += probes[b + 1u].rgb * (0.4886025 * n.y);
    h += probes[b + 2u].rgb * (0.4886025 * n.z);
    h += probes[b + 3u].rgb * (0.4886025 * n.x);
    h += probes[b + 4u].rgb * (1.0925484 * n.x * n.y);
    h += probes[b + 5u].rgb * (1.0925484 * n.y * n.z);
    h += probes[b + 6u].rgb * (0.3153916 * (3.0 * n.z * n.z - 1.0));
    h += probes[b + 7u].rgb * (1.0925484 * n.x * n.z);
    h += probes[b + 8u].rgb * (0.5462742 * (n.x * n.x - n.y * n.y));
    return h;
}

fn probe_index(c: vec3<u32>) -> u32 {
    let d = probe_grid.dims;
    return (c.z * d.y + c.y) * d.x + c.x;
}

// The grid's H at p (relative to the origin) for unit normal n; 0 without a grid.
fn probe_irradiance(p: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let d = probe_grid.dims;
    if (d.w == 0u) {
        return vec3<f32>(0.0);
    }
    let g = (p - probe_grid.origin_step.xyz) / probe_grid.origin_step.w;
    let hi = vec3<i32>(max(vec3<i32>(d.xyz) - vec3<i32>(2), vec3<i32>(0)));
    let base = clamp(vec3<i32>(floor(g)), vec3<i32>(0), hi);
    let f = clamp(g - vec3<f32>(base), vec3<f32>(0.0), vec3<f32>(1.0));
    var sum = vec3<f32>(0.0);
    var total = 0.0;
    var nearest = 0xffffffffu;
    var nearest_d = 1e30;
    for (var corner = 0u; corner < 8u; corner++) {
        let bit = vec3<u32>(corner & 1u, (corner >> 1u) & 1u, (corner >> 2u) & 1u);
        let c = min(vec3<u32>(base) + bit, d.xyz - vec3<u32>(1u));
        let k = probe_index(c);
        if (probes[k * 9u].w <= 0.0) {
            continue;
        }
        let t3 = select(vec3<f32>(1.0) - f, f, bit == vec3<u32>(1u));
        let t = t3.x * t3.y * t3.z;
        let dist = dot(g - vec3<f32>(c), g - vec3<f32>(c));
        if (dist < nearest_d) {
            nearest_d = dist;
            nearest = k;
        }
        if (t > 0.0) {
            sum += t * probe_h(k, n);
            total += t;
        }
    }
    if (total > 0.0) {
        return max(sum / total, vec3<f32>(0.0));
    }
    if (nearest != 0xffffffffu) {
        return max(probe_h(nearest, n), vec3<f32>(0.0));
    }
    return vec3<f32>(0.0);
}
@group(1) @binding(0) var base_color: texture_2d<f32>;
@group(1) @binding(1) var base_color_sampler: sampler;
@group(1) @binding(2) var<uniform> material: Material;

struct Material {
    // Discard below this alpha (-1: never).
    alpha_cutoff: f32,
    alpha_factor: f32,
    cull_back: u32,
    _pad: u32,
};

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) albedo: vec3<f32>,
    @location(3) emissive: vec3<f32>,
    @location(4) lightmap_uv: vec2<f32>,
    @location(5) uv: vec2<f32>,
    @location(13) lightmap_page: u32,
};

// Per instance: rows of the model matrix, rows of the normal matrix, and where its light-map
// coordinates are: x base in `instance_uvs`, y the draw's first vertex, z 1 if its own.
struct InstanceIn {
    @location(6) m0: vec4<f32>,
    @location(7) m1: vec4<f32>,
    @location(8) m2: vec4<f32>,
    @location(9) n0: vec4<f32>,
    @location(10) n1: vec4<f32>,
    @location(11) n2: vec4<f32>,
    @location(12) lightmap: vec4<u32>,
};

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    @location(1) albedo: vec3<f32>,
    @location(2) emissive: vec3<f32>,
    @location(3) lightmap_uv: vec2<f32>,
    @location(4) uv: vec2<f32>,
    @location(5) @interpolate(flat) lightmap_page: u32,
    // Relative to the scene origin (for the probe grid).
    @location(6) position: vec3<f32>,
};

@vertex
fn gbuffer_vs(v: VertexIn, inst: InstanceIn, @builtin(vertex_index) index: u32) -> VertexOut {
    var out: VertexOut;
    let p = vec4<f32>(v.position, 1.0);
    let world = vec3<f32>(dot(inst.m0, p), dot(inst.m1, p), dot(inst.m2, p));
    out.clip = camera.view_proj * vec4<f32>(world, 1.0);
    out.position = world;
    out.normal = vec3<f32>(dot(inst.n0.xyz, v.normal), dot(inst.n1.xyz, v.normal), dot(inst.n2.xyz, v.normal));
    out.albedo = v.albedo;
    out.emissive = v.emissive;
    out.lightmap_uv = v.lightmap_uv;
    out.lightmap_page = v.lightmap_page;
    if (inst.lightmap.z != 0u) {
        let own = instance_uvs[inst.lightmap.x + index - inst.lightmap.y];
        out.lightmap_uv = own.uv;
        out.lightmap_page = own.page;
    }
    out.uv = v.uv;
    return out;
}

struct GBufferOut {
    @location(0) albedo: vec4<f32>,
    @location(1) normal: vec2<f32>,
    @location(2) material: vec2<f32>,
    @location(3) irradiance: vec4<f32>,
    @location(4) emissive: vec4<f32>,
};

@fragment
fn gbuffer_fs(in: VertexOut, @builtin(front_facing) front: bool) -> GBufferOut {
    // Sampled before any discard: implicit derivatives need uniform control flow.
    let texel = textureSample(base_color, base_color_sampler, in.uv);
    if (!front && material.cull_back != 0u) {
        discard;
    }
    if (material.alpha_factor * texel.a < material.alpha_cutoff) {
        discard;
    }
    let len = length(in.normal);
    var n = select(vec3<f32>(0.0, 0.0, 1.0), in.normal / len, len > 1e-20);
    if (!front) {
        n = -n;
    }
    var out: GBufferOut;
    out.albedo = vec4<f32>(in.albedo * texel.rgb, 1.0);
    out.normal = oct_encode(n);
    // r: roughness (Lambertian: 1), g: light-map coverage (every surface has a chart: 1).
    out.material = vec2<f32>(1.0, 1.0);
    if (in.lightmap_page == PROBE_LIT) {
        out.irradiance = vec4<f32>(probe_irradiance(in.position, n), 1.0);
    } else {
        out.irradiance = vec4<f32>(textureSampleLevel(lightmap, lightmap_sampler, in.lightmap_uv, in.lightmap_page, 0.0).rgb, 1.0);
    }
    out.emissive = vec4<f32>(in.emissive, 1.0);
    return out;
}
