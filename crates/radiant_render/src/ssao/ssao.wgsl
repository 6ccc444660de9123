// Screen-space ambient occlusion, normal-oriented hemisphere variant (Mittring, "Finding next gen:
// CryEngine 2", SIGGRAPH 2007; hemisphere kernel as in Chapman/LearnOpenGL): N kernel samples
// in the tangent-space hemisphere, rotated per pixel by a 4x4 interleaved pattern, compared with
// the depth buffer, with a range check so distant occluders do not count.

@group(0) @binding(0) var<uniform> camera: Camera;
// Depth as an unfilterable float texture (see lighting.wgsl: GLSL cannot load a depth texture).
@group(0) @binding(1) var g_depth: texture_2d<f32>;
@group(0) @binding(2) var g_normal: texture_2d<f32>;
@group(0) @binding(3) var<uniform> ssao: SsaoSettings;

struct SsaoSettings {
    kernel: array<vec4<f32>, 64>,
    // radius (view-space metres), bias (metres), intensity (exponent), sample count
    params: vec4<f32>,
};

@fragment
fn ssao_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(camera.viewport.xy);
    let px = vec2<i32>(in.position.xy);
    let depth = textureLoad(g_depth, px, 0).r;
    if (depth >= 1.0) {
        return vec4<f32>(1.0);
    }
    let uv = (vec2<f32>(px) + 0.5) * camera.viewport.zw;
    let p = view_position(camera.inv_proj, uv, depth);
    let n_world = oct_decode(textureLoad(g_normal, px, 0).xy);
    let n = normalize((camera.view * vec4<f32>(n_world, 0.0)).xyz);

    // 16 rotations from the pixel's place in a 4x4 tile.
    let k = f32((px.x & 3) + 4 * (px.y & 3));
    let angle = fract(k * 0.618034) * 6.2831853;
    var r = vec3<f32>(cos(angle), sin(angle), 0.0);
    var t = r - n * dot(r, n);
    if (dot(t, t) < 1e-6) {
        r = vec3<f32>(0.0, sin(angle), cos(angle));
        t = r - n * dot(r, n);
    }
    t = normalize(t);
    let b = cross(n, t);

    let radius = ssao.params.x;
    let bias = ssao.params.y;
    let count = u32(ssao.params.w);
    var occlusion = 0.0;
    for (var i = 0u; i < count; i++) {
        let k = ssao.kernel[i].xyz;
        let s = p + (t * k.x + b * k.y + n * k.z) * radius;
        let clip = camera.proj * vec4<f32>(s, 1.0);
        if (clip.w <= 0.0) {
            continue;
        }
        let ndc = clip.xy / clip.w;
        let suv = vec2<f32>(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5);
        if (any(suv < vec2<f32>(0.0)) || any(suv >= vec2<f32>(1.0))) {
            continue;
        }
        let spx = vec2<i32>(suv * camera.viewport.xy);
        let sd = textureLoad(g_depth, spx, 0).r;
        if (sd >= 1.0) {
            continue;
        }
        let scene_z = view_position(camera.inv_proj, (vec2<f32>(spx) + 0.5) * camera.viewport.zw, sd).z;
        let range = smoothstep(0.0, 1.0, radius / max(abs(p.z - scene_z), 1e-6));
        occlusion += select(0.0, 1.0, scene_z >= s.z + bias) * range;
    }
    let ao = 1.0 - occlusion / f32(max(count, 1u));
    return vec4<f32>(pow(clamp(ao, 0.0, 1.0), ssao.params.z));
}
