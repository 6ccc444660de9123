// 4x4 box blur of the raw SSAO: it averages exactly one period of the 4x4 rotation pattern, so
// the pattern's noise cancels (Chapman / LearnOpenGL).

@group(0) @binding(0) var raw_ao: texture_2d<f32>;

@fragment
fn ssao_blur_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(raw_ao));
    let px = vec2<i32>(in.position.xy);
    var sum = 0.0;
    for (var y = -2; y < 2; y++) {
        for (var x = -2; x < 2; x++) {
            let q = clamp(px + vec2<i32>(x, y), vec2<i32>(0), size - vec2<i32>(1));
            sum += textureLoad(raw_ao, q, 0).r;
        }
    }
    return vec4<f32>(sum / 16.0);
}
