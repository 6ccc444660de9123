// The GPU hemicube gather (radiant_gather): the scene is drawn onto the five faces of a
// hemicube at every receiver of a batch (one cell of 3R × R pixels each: the top face, then the
// four upper half side faces two by two), each pixel holding what it sees: the light-map
// coordinates and page there. A compute pass colours each pixel by the current radiosity there,
// sampled from the radiosity map as a fragment would, weights it by its delta form factor and
// sums each cell into the receiver's H; it writes the receiver's B = E + ρ H into the next
// radiosity map. The ids do not change between sweeps, so a kept batch is drawn once and only
// reduced afterwards.

enable clip_distances;

struct Receiver {
    // Hemicube centre (scene-local coordinates, lifted off the surface).
    origin: vec4<f32>,
    // Tangent frame: t × b = n, n the surface's front normal.
    t: vec4<f32>,
    b: vec4<f32>,
    n: vec4<f32>,
    // Incident radiance from punctual lights (irradiance / π) and, when they are lit in closed
    // form, from the emitters: added to every gather.
    direct: vec4<f32>,
    // Light-map texel: x, y, page.
    texel: vec4<u32>,
    // Its surface's mean reflectance, and the emission it shows in the hemicubes.
    reflectance: vec4<f32>,
    emission: vec4<f32>,
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
    // Sky: 0 none, 1 uniform (a), 2 gradient (a zenith, b horizon).
    sky_kind: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    pad3: u32,
    sky_a: vec4<f32>,
    sky_b: vec4<f32>,
}

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> receivers: array<Receiver>;
struct VsIn {
    @location(0) position: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) page: u32,
    @location(3) tex: vec2<f32>,
    @location(4) mask: u32,
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @builtin(clip_distances) clip_distances: array<f32, 4>,
    @location(0) uv: vec2<f32>,
    @location(1) @interpolate(flat) page: u32,
    @location(2) tex: vec2<f32>,
    @location(3) @interpolate(flat) mask: u32,
}

// What the fragment stage reads of VsOut (clip distances are the vertex stage's only).
struct FsIn {
    @location(0) uv: vec2<f32>,
    @location(1) @interpolate(flat) page: u32,
    @location(2) tex: vec2<f32>,
    @location(3) @interpolate(flat) mask: u32,
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
    out.tex = v.tex;
    out.mask = v.mask;
    return out;
}

// What a pixel sees: x the light-map coordinates (two unorm16), y the page + 1. A pixel that
// sees nothing stays 0 (the sky); a back face is BACK (black).
const BACK: u32 = 0xffffffffu;

// Alpha masks: a masked triangle's fragments below its cutoff are not there (as the CPU bake's
// rays pass them). The masks' images are their alpha bytes, four to a word, sampled as the
// glTF sampler says (radiant_scene's `taps`).
const NO_MASK: u32 = 0xffffffffu;

struct MaskInfo {
    image: u32,
    // Wrap along U in bits 0-1, along V in 2-3 (0 repeat, 1 mirrored, 2 clamp); bit 4 nearest.
    sampler: u32,
    cutoff: f32,
    factor: f32,
}

struct ImageInfo {
    offset: u32,
    width: u32,
    height: u32,
    pad: u32,
}

@group(0) @binding(11) var<storage, read> mask_infos: array<MaskInfo>;
@group(0) @binding(12) var<storage, read> mask_images: array<ImageInfo>;
@group(0) @binding(13) var<storage, read> mask_alpha: array<u32>;

fn fold(i: i32, n: i32, wrap: u32) -> i32 {
    switch wrap {
        case 1u: {
            let p = 2 * n;
            let m = ((i % p) + p) % p;
            return select(m, p - 1 - m, m >= n);
        }
        case 2u: { return clamp(i, 0, n - 1); }
        default: { return ((i % n) + n) % n; }
    }
}

fn alpha_texel(img: ImageInfo, x: i32, y: i32) -> f32 {
    let k = img.offset + u32(y) * img.width + u32(x);
    let word = mask_alpha[k >> 2u];
    return f32((word >> ((k & 3u) * 8u)) & 0xffu) / 255.0;
}

fn mask_alpha_at(m: MaskInfo, uv: vec2<f32>) -> f32 {
    let img = mask_images[m.image];
    let w = i32(img.width);
    let h = i32(img.height);
    let ws = m.sampler & 3u;
    let wt = (m.sampler >> 2u) & 3u;
    let x = uv.x * f32(w) - 0.5;
    let y = uv.y * f32(h) - 0.5;
    if (m.sampler & 16u) != 0u {
        return alpha_texel(img, fold(i32(floor(x + 0.5)), w, ws), fold(i32(floor(y + 0.5)), h, wt));
    }
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let i0 = fold(i32(x0), w, ws);
    let i1 = fold(i32(x0) + 1, w, ws);
    let j0 = fold(i32(y0), h, wt);
    let j1 = fold(i32(y0) + 1, h, wt);
    return alpha_texel(img, i0, j0) * (1.0 - fx) * (1.0 - fy)
        + alpha_texel(img, i1, j0) * fx * (1.0 - fy)
        + alpha_texel(img, i0, j1) * (1.0 - fx) * fy
        + alpha_texel(img, i1, j1) * fx * fy;
}

struct IdOut {
    @location(0) id: vec2<u32>,
    @builtin(frag_depth) depth: f32,
}

// Surfaces are one-sided: a back face absorbs. Front and back faces are drawn in one pass; a
// back face sits a little farther than it is (depth is reversed: nearer is greater), so a
// double-sided surface's twin, at the same depth and facing this way, wins whichever comes
// first.
fn id_of(in: FsIn, position: vec4<f32>, front: bool) -> IdOut {
    var out: IdOut;
    if front {
        out.id = vec2<u32>(pack2x16unorm(in.uv), in.page + 1u);
        out.depth = position.z;
    } else {
        out.id = vec2<u32>(0u, BACK);
        out.depth = position.z * (1.0 - 1e-5);
    }
    return out;
}

// A scene without alpha masks: no fragment is discarded (which keeps a CPU rasteriser on its
// fast path).
@fragment
fn id_fs(in: FsIn, @builtin(position) position: vec4<f32>, @builtin(front_facing) front: bool) -> IdOut {
    return id_of(in, position, front);
}

// A scene with alpha masks: a masked fragment below its cutoff is not there.
@fragment
fn id_masked_fs(in: FsIn, @builtin(position) position: vec4<f32>, @builtin(front_facing) front: bool) -> IdOut {
    if in.mask != NO_MASK {
        let m = mask_infos[in.mask];
        if m.factor * mask_alpha_at(m, in.tex) < m.cutoff {
            discard;
        }
    }
    return id_of(in, position, front);
}

@group(0) @binding(3) var light_map: texture_2d_array<f32>;
@group(0) @binding(4) var light_sampler: sampler;
@group(0) @binding(5) var hemicubes: texture_2d<u32>;
@group(0) @binding(6) var<storage, read_write> gathered: array<vec4<f32>>;
@group(0) @binding(7) var next_map: texture_storage_2d_array<rgba16float, write>;
// Each pixel's delta form factor, normalised so that a cell's sum to 1 (3R × R, as a cell).
@group(0) @binding(8) var<storage, read> multipliers: array<f32>;
// H two sweeps back, and this sweep's step weight: H_new = ω J + (1 − ω) H_older (ω = 1: Jacobi).
@group(0) @binding(9) var<storage, read_write> older: array<vec4<f32>>;
struct Sweep {
    omega: f32,
    pad0: f32,
    pad1: f32,
    pad2: f32,
}
@group(0) @binding(10) var<uniform> sweep: Sweep;

// Invocations per receiver (`gpu.rs` sets 64 on a GPU: on a CPU rasteriser such as lavapipe,
// eight, one SIMD row without a barrier's cost, reduce 1.5× faster than 64 and 3× than 256).
const GROUP: u32 = 8u;
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

// The direction (scene frame) through pixel (px, py) of a cell of the hemicube `rc`.
fn pixel_direction(px: u32, py: u32, rc: Receiver) -> vec3<f32> {
    let res = params.res;
    let d = 2.0 / f32(res);
    let column = px / res;
    let x = -1.0 + (f32(px % res) + 0.5) * d;
    if column == 0u {
        let y = 1.0 - (f32(py) + 0.5) * d;
        return rc.b.xyz * x + rc.t.xyz * y + rc.n.xyz;
    }
    let half = res / 2u;
    let face = 2u * column - 1u + py / half;
    let z = 1.0 - (f32(py % half) + 0.5) * d;
    let basis = face_basis(face, rc.t.xyz, rc.b.xyz, rc.n.xyz);
    return basis[1] * x + basis[2] * z + basis[0];
}

// Before the first sweep: every receiver's texel shows its emission (B = E, H = 0).
@compute @workgroup_size(64)
fn seed_cs(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x < params.count {
        let rc = receivers[params.first + id.x];
        textureStore(next_map, rc.texel.xy, rc.texel.z, vec4<f32>(rc.emission.rgb, 1.0));
    }
}

// One workgroup per receiver: Σ ΔF · L over its cell (ΔF from the multiplier buffer, laid out
// as a cell); H = direct + Σ (stepped with ω) into `gathered`, B = E + ρ H into the next map.
@compute @workgroup_size(8)
fn reduce_cs(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let cell = group.x;
    let res = params.res;
    let rc = receivers[params.first + cell];
    let w = 3u * res;
    let x0 = (cell % params.cols) * w;
    let y0 = (cell / params.cols) * res;
    var sum = vec3<f32>(0.0);
    let layers = textureNumLayers(light_map);
    // Flat over the cell's pixels, so every invocation has work whatever R.
    for (var k = li; k < w * res; k += GROUP) {
        let px = k % w;
        let py = k / w;
        let id = textureLoad(hemicubes, vec2<u32>(x0 + px, y0 + py), 0).xy;
        // Branch-free but for the sky: B where a surface is seen; the sky's and a back face's
        // ids sample some page (clamped into range) and show black.
        let page = min(id.y - 1u, layers - 1u);
        let b = textureSampleLevel(light_map, light_sampler, unpack2x16unorm(id.x), page, 0.0).rgb;
        var l = select(vec3<f32>(0.0), b, id.y != 0u && id.y != BACK);
        if params.sky_kind != 0u && id.y == 0u {
            l = sky(pixel_direction(px, py, rc));
        }
        sum += multipliers[k] * l;
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
        let i = params.first + cell;
        let j = rc.direct.rgb + partial[0];
        let h = j * sweep.omega + older[i].rgb * (1.0 - sweep.omega);
        older[i] = gathered[i];
        gathered[i] = vec4<f32>(h, 0.0);
        textureStore(next_map, rc.texel.xy, rc.texel.z, vec4<f32>(rc.emission.rgb + rc.reflectance.rgb * h, 1.0));
    }
}
