// Separable Gaussian blur (the lecture's image filter): one 1D pass along `direction` with
// normalised, sampled Gaussian weights; run horizontally then vertically, `passes` times.
// Texels outside the image repeat the edge (clamp to edge).

@group(0) @binding(0) var source: texture_2d<f32>;
@group(0) @binding(1) var<uniform> blur: BlurSettings;

struct BlurSettings {
    // weights[i / 4][i % 4] for tap offsets 0..=radius (symmetric)
    weights: array<vec4<f32>, 16>,
    // radius, direction x, direction y, unused
    params: vec4<i32>,
};

fn weight(i: i32) -> f32 {
    return blur.weights[i / 4][i % 4];
}

@fragment
fn blur_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let size = vec2<i32>(textureDimensions(source));
    let px = vec2<i32>(in.position.xy);
    let dir = blur.params.yz;
    let radius = blur.params.x;
    var sum = textureLoad(source, px, 0) * weight(0);
    for (var i = 1; i <= radius; i++) {
        let a = clamp(px + dir * i, vec2<i32>(0), size - vec2<i32>(1));
        let b = clamp(px - dir * i, vec2<i32>(0), size - vec2<i32>(1));
        sum += (textureLoad(source, a, 0) + textureLoad(source, b, 0)) * weight(i);
    }
    return sum;
}
