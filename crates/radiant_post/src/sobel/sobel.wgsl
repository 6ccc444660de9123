// Sobel edge detection (Sobel & Feldman 1968; the lecture's edge filter): the 3x3 gradient of a
// signal (colour luminance, linear depth relative to the centre, or the normal), normalised so a
// unit step gives magnitude 1; where it exceeds the threshold the pixel takes the edge colour.

@group(0) @binding(0) var color_in: texture_2d<f32>;
@group(0) @binding(1) var normal_in: texture_2d<f32>;
// Depth as an unfilterable float texture, read with textureLoad: what GLSL (wgpu's GL
// backend) can read; a `texture_depth_2d` cannot be loaded from there.
@group(0) @binding(2) var depth_in: texture_2d<f32>;
@group(0) @binding(3) var<uniform> sobel: SobelSettings;

struct SobelSettings {
    edge_color: vec4<f32>,
    // threshold, near, far, unused
    params: vec4<f32>,
};

fn clamp_px(p: vec2<i32>, size: vec2<i32>) -> vec2<i32> {
    return clamp(p, vec2<i32>(0), size - vec2<i32>(1));
}

fn offsets(k: i32) -> vec2<i32> {
    return vec2<i32>(k % 3 - 1, k / 3 - 1);
}

const GX = array<f32, 9>(-1.0, 0.0, 1.0, -2.0, 0.0, 2.0, -1.0, 0.0, 1.0);
const GY = array<f32, 9>(-1.0, -2.0, -1.0, 0.0, 0.0, 0.0, 1.0, 2.0, 1.0);

fn finish(px: vec2<i32>, magnitude: f32) -> vec4<f32> {
    let c = textureLoad(color_in, px, 0);
    if (magnitude > sobel.params.x) {
        return vec4<f32>(sobel.edge_color.rgb, c.a);
    }
    return c;
}

@fragment
fn sobel_color_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(color_in));
    let px = vec2<i32>(in.position.xy);
    var g = vec2<f32>(0.0);
    for (var k = 0; k < 9; k++) {
        let v = luminance(textureLoad(color_in, clamp_px(px + offsets(k), size), 0).rgb);
        g += vec2<f32>(GX[k], GY[k]) * v;
    }
    return finish(px, length(g) * 0.25);
}

fn linear_depth(d: f32) -> f32 {
    let near = sobel.params.y;
    let far = sobel.params.z;
    return near * far / (far - d * (far - near));
}

@fragment
fn sobel_depth_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(depth_in));
    let px = vec2<i32>(in.position.xy);
    let centre = linear_depth(textureLoad(depth_in, px, 0).r);
    var g = vec2<f32>(0.0);
    for (var k = 0; k < 9; k++) {
        let v = linear_depth(textureLoad(depth_in, clamp_px(px + offsets(k), size), 0).r);
        g += vec2<f32>(GX[k], GY[k]) * v;
    }
    // Relative to the centre's distance, so the threshold does not depend on scene scale.
    return finish(px, length(g) * 0.25 / max(centre, 1e-6));
}

@fragment
fn sobel_normal_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(normal_in));
    let px = vec2<i32>(in.position.xy);
    var gx = vec3<f32>(0.0);
    var gy = vec3<f32>(0.0);
    for (var k = 0; k < 9; k++) {
        let n = oct_decode(textureLoad(normal_in, clamp_px(px + offsets(k), size), 0).xy);
        gx += GX[k] * n;
        gy += GY[k] * n;
    }
    return finish(px, sqrt(dot(gx, gx) + dot(gy, gy)) * 0.25);
}
