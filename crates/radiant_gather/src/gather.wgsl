// The GPU hemicube gather (radiant_gather): the scene, coloured by the current radiosity, is
// drawn onto the five faces of a hemicube at every receiver of a batch (one cell of 3R × R
// pixels each: the top face, then the four upper half side faces two by two), and a compute
// pass weights each cell's pixels by their delta form factors and sums them.

enable clip_distances;

struct Receiver {
    // Hemicube centre (scene-local coordinates, lifted off the surface).
    origin: vec4<f32>,
    // Tangent frame: t × b = n, n the surface's front normal.
    t: vec4<f32>,
    b: vec4<f32>,
    n: vec4<f32>,
    // Incident radiance from punctual lights (irradiance / π), added to every gather.
    direct: vec4<f32>,
    // Light-map texel: x, y, page.
    texel: vec4<u32>,
}

struct Params {
    // The hemicube atlas in pixels.
    atlas: vec2<f32>,
    // Hemicube resolution R (even).
    res: u32,
    // Cells per atlas row.
    cols: u32,
    // First receiver of this batch, and how many.
    first: u32,
    count: u32,
    // Near plane (scene-local units).
    near: f32,
    // 1 / the sum of all unnormalised delta form factors: rows sum to exactly 1.
    norm: f32,
    // Sky: 0 none, 1 uniform (a), 2 gradient (a zenith, b horizon).
    sky_kind: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    sky_a: vec4<f32>,
    sky_b: vec4<f32>,
}

struct Material {
    reflectance: vec4<f32>,
    emission: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> receivers: array<Receiver>;
@group(0) @binding(2) var<storage, read> materials: array<Material>;
@group(0) @binding(3) var light_map: texture_2d_array<f32>;
@group(0) @binding(4) var light_sampler: sampler;

struct VsIn {
    @location(0) position: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) page: u32,
    @location(3) material: u32,
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @builtin(clip_distances) clip_distances: array<f32, 4>,
    @location(0) uv: vec2<f32>,
    @location(1) @interpolate(flat) page: u32,
    @location(2) @interpolate(flat) material: u32,
}

// What the fragment stage reads of VsOut (clip distances are the vertex stage's only).
struct FsIn {
    @location(0) uv: vec2<f32>,
    @location(1) @interpolate(flat) page: u32,
    @location(2) @interpolate(flat) material: u32,
}

// Face `face` of a hemicube with frame (t, b, n): forward, right and up, right × up = -forward.
fn face_basis(face: u32, t: vec3<f32>, b: vec3<f32>, n: vec3<f32>) -> array<vec3<f32>, 3> {
    if face == 0u {
        return array<vec3<f32>, 3>(n, b, t);
    }
    var f = t;
    switch face {
        case 2u: { f = -t; }
        case 3u: { f = b; }
        case 4u: { f = -b; }
        default: {}
    }
    return array<vec3<f32>, 3>(f, cross(f, n), n);
}

// The pixel rectangle (x, y, width, height) of face `face` in cell `cell`.
fn face_rect(cell: u32, face: u32) -> vec4<f32> {
    let r = f32(params.res);
    let x0 = f32(cell % params.cols) * 3.0 * r;
    let y0 = f32(cell / params.cols) * r;
    switch face {
        case 0u: { return vec4<f32>(x0, y0, r, r); }
        case 1u: { return vec4<f32>(x0 + r, y0, r, 0.5 * r); }
        case 2u: { return vec4<f32>(x0 + r, y0 + 0.5 * r, r, 0.5 * r); }
        case 3u: { return vec4<f32>(x0 + 2.0 * r, y0, r, 0.5 * r); }
        default: { return vec4<f32>(x0 + 2.0 * r, y0 + 0.5 * r, r, 0.5 * r); }
    }
}

@vertex
fn hemicube_vs(v: VsIn, @builtin(instance_index) instance: u32) -> VsOut {
    let cell = instance / 5u;
    let face = instance % 5u;
    let rc = receivers[params.first + cell];
    let basis = face_basis(face, rc.t.xyz, rc.b.xyz, rc.n.xyz);
    let d = v.position - rc.origin.xyz;
    let w = dot(d, basis[0]);
    let x = dot(d, basis[1]);
    var y = dot(d, basis[2]);
    if face != 0u {
        // A side face shows only the upper half (up from 0 to 1 on the unit face).
        y = 2.0 * y - w;
    }
    var out: VsOut;
    // The face's own frustum, before it moves into its cell: nothing spills into a neighbour.
    out.clip_distances = array<f32, 4>(w - x, w + x, w - y, w + y);
    let rect = face_rect(cell, face);
    let ax = rect.z / params.atlas.x;
    let bx = (2.0 * rect.x + rect.z) / params.atlas.x - 1.0;
    let ay = rect.w / params.atlas.y;
    let by = 1.0 - (2.0 * rect.y + rect.w) / params.atlas.y;
    // Reversed, infinite depth: z/w = near/w, 1 at the near plane, towards 0 far away.
    out.clip = vec4<f32>(ax * x + bx * w, ay * y + by * w, params.near, w);
    out.uv = v.uv;
    out.page = v.page;
    out.material = v.material;
    return out;
}

// A front face shows its radiosity B = E + ρ H, H from the current light map.
@fragment
fn front_fs(in: FsIn) -> @location(0) vec4<f32> {
    let m = materials[in.material];
    let h = textureSampleLevel(light_map, light_sampler, in.uv, in.page, 0.0).rgb;
    return vec4<f32>(m.emission.rgb + m.reflectance.rgb * h, 1.0);
}

// Surfaces are one-sided: a back face absorbs.
@fragment
fn back_fs() -> @location(0) vec4<f32> {
    return vec4<f32>(0.0, 0.0, 0.0, 1.0);
}

@group(0) @binding(5) var hemicubes: texture_2d<f32>;
@group(0) @binding(6) var<storage, read_write> gathered: array<vec4<f32>>;
@group(0) @binding(7) var next_map: texture_storage_2d_array<rgba16float, write>;

const PI: f32 = 3.14159265358979;
const GROUP: u32 = 256u;
var<workgroup> partial: array<vec3<f32>, GROUP>;

fn sky(dir: vec3<f32>) -> vec3<f32> {
    switch params.sky_kind {
        case 1u: { return params.sky_a.rgb; }
        case 2u: {
            let t = clamp(normalize(dir).y, 0.0, 1.0);
            return params.sky_b.rgb + (params.sky_a.rgb - params.sky_b.rgb) * t;
        }
        default: { return vec3<f32>(0.0); }
    }
}

// One workgroup per receiver: Σ ΔF · L over its cell, then H = direct + Σ into the next map.
@compute @workgroup_size(256)
fn reduce_cs(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let cell = group.x;
    let res = params.res;
    let rc = receivers[params.first + cell];
    let x0 = (cell % params.cols) * 3u * res;
    let y0 = (cell / params.cols) * res;
    let d = 2.0 / f32(res);
    let half = res / 2u;
    var sum = vec3<f32>(0.0);
    for (var k = li; k < 3u * res * res; k += GROUP) {
        let px = k % (3u * res);
        let py = k / (3u * res);
        let column = px / res;
        let x = -1.0 + (f32(px % res) + 0.5) * d;
        var weight: f32;
        var dir: vec3<f32>;
        if column == 0u {
            let y = 1.0 - (f32(py) + 0.5) * d;
            let q = x * x + y * y + 1.0;
            weight = 1.0 / (q * q);
            dir = rc.b.xyz * x + rc.t.xyz * y + rc.n.xyz;
        } else {
            let face = 2u * column - 1u + py / half;
            let z = 1.0 - (f32(py % half) + 0.5) * d;
            let q = x * x + z * z + 1.0;
            weight = z / (q * q);
            let basis = face_basis(face, rc.t.xyz, rc.b.xyz, rc.n.xyz);
            dir = basis[1] * x + basis[2] * z + basis[0];
        }
        let c = textureLoad(hemicubes, vec2<u32>(x0 + px, y0 + py), 0);
        var l = c.rgb;
        if c.a < 0.5 {
            l = sky(dir);
        }
        sum += weight * l;
    }
    partial[li] = sum;
    workgroupBarrier();
    for (var s = GROUP / 2u; s > 0u; s = s / 2u) {
        if li < s {
            partial[li] += partial[li + s];
        }
        workgroupBarrier();
    }
    if li == 0u {
        let h = rc.direct.rgb + partial[0] * (d * d / PI) * params.norm;
        gathered[params.first + cell] = vec4<f32>(h, 0.0);
        textureStore(next_map, rc.texel.xy, rc.texel.z, vec4<f32>(h, 1.0));
    }
}
