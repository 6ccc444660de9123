// Shared WGSL: the camera block, a fullscreen triangle, octahedral normals (Cigolle et al.,
// "A Survey of Efficient Representations for Independent Unit Vectors", JCGT 2014) and position
// reconstruction from depth. Prepended to every shader of radiant_render and radiant_post.

struct Camera {
    view_proj: mat4x4<f32>,
    inv_view_proj: mat4x4<f32>,
    view: mat4x4<f32>,
    proj: mat4x4<f32>,
    inv_proj: mat4x4<f32>,
    position: vec4<f32>,
    viewport: vec4<f32>,
    params: vec4<f32>,
};

struct FullscreenOut {
    @builtin(position) position: vec4<f32>,
    @location(0) uv: vec2<f32>,
};

// One triangle covering the screen; uv (0,0) is the top-left texel.
@vertex
fn fullscreen_vs(@builtin(vertex_index) i: u32) -> FullscreenOut {
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var out: FullscreenOut;
    out.position = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 0.0, 1.0);
    out.uv = uv;
    return out;
}

fn oct_wrap(v: vec2<f32>) -> vec2<f32> {
    return (1.0 - abs(v.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), v >= vec2<f32>(0.0));
}

fn oct_encode(n: vec3<f32>) -> vec2<f32> {
    let l1 = abs(n.x) + abs(n.y) + abs(n.z);
    if (l1 < 1e-20) {
        // A zero normal (degenerate input) encodes +z rather than NaN.
        return vec2<f32>(0.0);
    }
    var p = n.xy / l1;
    if (n.z < 0.0) {
        p = oct_wrap(p);
    }
    return p;
}

fn oct_decode(e: vec2<f32>) -> vec3<f32> {
    var n = vec3<f32>(e, 1.0 - abs(e.x) - abs(e.y));
    let t = max(-n.z, 0.0);
    n.x += select(t, -t, n.x >= 0.0);
    n.y += select(t, -t, n.y >= 0.0);
    return normalize(n);
}

// View-space position of the texel centre `uv` (0..1, top-left origin) at NDC depth `depth`.
fn view_position(inv_proj: mat4x4<f32>, uv: vec2<f32>, depth: f32) -> vec3<f32> {
    let v = inv_proj * vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, depth, 1.0);
    return v.xyz / v.w;
}

fn luminance(c: vec3<f32>) -> f32 {
    return dot(c, vec3<f32>(0.2126, 0.7152, 0.0722));
}
