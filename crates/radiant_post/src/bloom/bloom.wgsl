// Bloom.
// Mip chain (Jimenez, "Next Generation Post Processing in Call of Duty: Advanced Warfare",
// SIGGRAPH 2014): a soft-knee threshold, a 13-tap downsample chain (Karis-weighted on the first
// level against fireflies), and a 3x3 tent upsample chain; each level mixes its own downsample
// with the wider levels, so every level keeps the mean of its input.
// Lecture variant: a bright pass, then a separable 9-tap Gaussian, repeated (see blur.wgsl).
// Composite: energy-conserving replaces the thresholded part of the image by its blurred
// version (no energy is added); additive adds the blurred part on top.

@group(0) @binding(0) var tex_a: texture_2d<f32>;
@group(0) @binding(1) var tex_b: texture_2d<f32>;
@group(0) @binding(2) var bilinear: sampler;
@group(0) @binding(3) var<uniform> bloom: BloomSettings;

struct BloomSettings {
    // threshold, knee (fraction of threshold), intensity, scatter
    params: vec4<f32>,
    // composite: 0 energy-conserving, 1 additive; unused x3
    mode: vec4<u32>,
};

fn soft_threshold(c: vec3<f32>) -> vec3<f32> {
    let threshold = bloom.params.x;
    if (threshold <= 0.0) {
        return c;
    }
    let knee = threshold * bloom.params.y;
    let br = max(c.r, max(c.g, c.b));
    var rq = clamp(br - threshold + knee, 0.0, 2.0 * knee);
    rq = rq * rq / (4.0 * knee + 1e-5);
    return c * (max(rq, br - threshold) / max(br, 1e-5));
}

fn tap(uv: vec2<f32>, texel: vec2<f32>, o: vec2<f32>, threshold: bool) -> vec3<f32> {
    let c = textureSampleLevel(tex_a, bilinear, uv + o * texel, 0.0).rgb;
    return select(c, soft_threshold(c), threshold);
}

fn karis(c: vec3<f32>) -> f32 {
    return 1.0 / (1.0 + luminance(c));
}

fn downsample(uv: vec2<f32>, first: bool) -> vec3<f32> {
    let t = 1.0 / vec2<f32>(textureDimensions(tex_a));
    let a = tap(uv, t, vec2<f32>(-2.0, 2.0), first);
    let b = tap(uv, t, vec2<f32>(0.0, 2.0), first);
    let c = tap(uv, t, vec2<f32>(2.0, 2.0), first);
    let d = tap(uv, t, vec2<f32>(-2.0, 0.0), first);
    let e = tap(uv, t, vec2<f32>(0.0, 0.0), first);
    let f = tap(uv, t, vec2<f32>(2.0, 0.0), first);
    let g = tap(uv, t, vec2<f32>(-2.0, -2.0), first);
    let h = tap(uv, t, vec2<f32>(0.0, -2.0), first);
    let i = tap(uv, t, vec2<f32>(2.0, -2.0), first);
    let j = tap(uv, t, vec2<f32>(-1.0, 1.0), first);
    let k = tap(uv, t, vec2<f32>(1.0, 1.0), first);
    let l = tap(uv, t, vec2<f32>(-1.0, -1.0), first);
    let m = tap(uv, t, vec2<f32>(1.0, -1.0), first);
    let g0 = (j + k + l + m) * 0.25;
    let g1 = (a + b + d + e) * 0.25;
    let g2 = (b + c + e + f) * 0.25;
    let g3 = (d + e + g + h) * 0.25;
    let g4 = (e + f + h + i) * 0.25;
    var w = vec4<f32>(0.125);
    var w0 = 0.5;
    if (first) {
        // Karis average: weight each group by 1 / (1 + luma), normalised.
        w0 *= karis(g0);
        w *= vec4<f32>(karis(g1), karis(g2), karis(g3), karis(g4));
    }
    let sum = g0 * w0 + g1 * w.x + g2 * w.y + g3 * w.z + g4 * w.w;
    return sum / (w0 + w.x + w.y + w.z + w.w);
}

@fragment
fn bloom_downsample_first_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    return vec4<f32>(downsample(in.uv, true), 1.0);
}

@fragment
fn bloom_downsample_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    return vec4<f32>(downsample(in.uv, false), 1.0);
}

// tex_a: this level's downsample; tex_b: the next wider level's result.
@fragment
fn bloom_upsample_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let t = 1.0 / vec2<f32>(textureDimensions(tex_b));
    var tent = vec3<f32>(0.0);
    for (var y = -1; y <= 1; y++) {
        for (var x = -1; x <= 1; x++) {
            let w = f32((2 - abs(x)) * (2 - abs(y))) / 16.0;
            tent += w * textureSampleLevel(tex_b, bilinear, in.uv + vec2<f32>(f32(x), f32(y)) * t, 0.0).rgb;
        }
    }
    let own = textureSampleLevel(tex_a, bilinear, in.uv, 0.0).rgb;
    return vec4<f32>(mix(own, tent, bloom.params.w), 1.0);
}

// Lecture bright pass: threshold, 2x2 box downsample (one bilinear tap at the shared corner).
@fragment
fn bloom_bright_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let t = 1.0 / vec2<f32>(textureDimensions(tex_a));
    var c = vec3<f32>(0.0);
    c += soft_threshold(textureSampleLevel(tex_a, bilinear, in.uv + vec2<f32>(-0.5, -0.5) * t, 0.0).rgb);
    c += soft_threshold(textureSampleLevel(tex_a, bilinear, in.uv + vec2<f32>(0.5, -0.5) * t, 0.0).rgb);
    c += soft_threshold(textureSampleLevel(tex_a, bilinear, in.uv + vec2<f32>(-0.5, 0.5) * t, 0.0).rgb);
    c += soft_threshold(textureSampleLevel(tex_a, bilinear, in.uv + vec2<f32>(0.5, 0.5) * t, 0.0).rgb);
    return vec4<f32>(c * 0.25, 1.0);
}

// tex_a: the scene; tex_b: the blurred bright part.
@fragment
fn bloom_composite_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let scene = textureLoad(tex_a, vec2<i32>(in.position.xy), 0).rgb;
    let blurred = textureSampleLevel(tex_b, bilinear, in.uv, 0.0).rgb;
    let k = bloom.params.z;
    var out: vec3<f32>;
    if (bloom.mode.x == 0u) {
        out = scene - k * soft_threshold(scene) + k * blurred;
    } else {
        out = scene + k * blurred;
    }
    return vec4<f32>(max(out, vec3<f32>(0.0)), 1.0);
}
