// Copies the composited frame into the target, texel for texel; the overlay draws on top.
// The composited texture is sRGB, so loads return linear values.
@group(0) @binding(0) var frame: texture_2d<f32>;

// Into an sRGB target: the hardware encodes.
@fragment
fn overlay_copy_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    return textureLoad(frame, vec2<i32>(in.position.xy), 0);
}

fn srgb_encode(c: vec3<f32>) -> vec3<f32> {
    let x = clamp(c, vec3<f32>(0.0), vec3<f32>(1.0));
    return select(1.055 * pow(x, vec3<f32>(1.0 / 2.4)) - 0.055, 12.92 * x, x <= vec3<f32>(0.0031308));
}

// Into a linear-format target (what egui prefers): encode here.
@fragment
fn overlay_copy_encode_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let c = textureLoad(frame, vec2<i32>(in.position.xy), 0);
    return vec4<f32>(srgb_encode(c.rgb), c.a);
}
