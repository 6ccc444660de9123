// Tone mapping with exposure: linear HDR radiance -> display-linear [0, 1]; the sRGB target
// encodes. Operators (the CPU references are radiant_color::Tonemap, kept in step):
//   0 clamp; 1 Reinhard 2002; 2 extended Reinhard (white point); 3 ACES fitted (Narkowicz 2015);
//   4 AgX (Sobotka; minimal fit by Wrensch 2023); 5 Khronos PBR Neutral (2024).

@group(0) @binding(0) var hdr: texture_2d<f32>;
@group(0) @binding(1) var<uniform> tm: TonemapSettings;

struct TonemapSettings {
    op: u32,
    exposure: f32,   // linear scale, 2^EV
    white: f32,      // extended Reinhard white point
    _pad: f32,
};

// NaN -> 0, +inf -> 1e30, negatives -> 0, without relying on NaN comparisons.
fn sanitize(x: f32) -> f32 {
    let bits = bitcast<u32>(x) & 0x7fffffffu;
    if (bits > 0x7f800000u) {
        return 0.0;
    }
    if (bits == 0x7f800000u) {
        return select(1e30, 0.0, x < 0.0);
    }
    return max(x, 0.0);
}

fn agx_curve(x: f32) -> f32 {
    let x2 = x * x;
    let x4 = x2 * x2;
    return 15.5 * x4 * x2 - 40.14 * x4 * x + 31.96 * x4 - 6.868 * x2 * x + 0.4298 * x2 + 0.1191 * x - 0.00232;
}

fn agx(c: vec3<f32>) -> vec3<f32> {
    let inset = mat3x3<f32>(
        0.842479062253094, 0.0423282422610123, 0.0423756549057051,
        0.0784335999999992, 0.878468636469772, 0.0784336,
        0.0792237451477643, 0.0791661274605434, 0.879142973793104);
    let outset = mat3x3<f32>(
        1.19687900512017, -0.0528968517574562, -0.0529716355144438,
        -0.0980208811401368, 1.15190312990417, -0.0980434501171241,
        -0.0990297440797205, -0.0989611768448433, 1.15107367264116);
    let min_ev = -12.47393118833241;
    let max_ev = 4.026068811667588;
    var v = inset * c;
    v = clamp(log2(max(v, vec3<f32>(1e-10))), vec3<f32>(min_ev), vec3<f32>(max_ev));
    v = (v - min_ev) / (max_ev - min_ev);
    v = vec3<f32>(agx_curve(v.x), agx_curve(v.y), agx_curve(v.z));
    v = outset * v;
    return pow(max(v, vec3<f32>(0.0)), vec3<f32>(2.2));
}

fn pbr_neutral(color: vec3<f32>) -> vec3<f32> {
    let start = 0.8 - 0.04;
    let desaturation = 0.15;
    let x = min(color.r, min(color.g, color.b));
    let offset = select(0.04, x - 6.25 * x * x, x < 0.08);
    var c = color - offset;
    let peak = max(c.r, max(c.g, c.b));
    if (peak < start) {
        return c;
    }
    let d = 1.0 - start;
    let new_peak = 1.0 - d * d / (peak + d - start);
    c *= new_peak / peak;
    let g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0);
    return mix(c, vec3<f32>(new_peak), g);
}

fn tonemap(c_in: vec3<f32>) -> vec3<f32> {
    let c = vec3<f32>(sanitize(c_in.r), sanitize(c_in.g), sanitize(c_in.b));
    var out: vec3<f32>;
    switch tm.op {
        case 0u: { out = min(c, vec3<f32>(1.0)); }
        case 1u: { out = c / (1.0 + c); }
        case 2u: {
            let w2 = tm.white * tm.white;
            out = min(c * (1.0 + c / w2) / (1.0 + c), vec3<f32>(1.0));
        }
        case 3u: {
            let x = min(c, vec3<f32>(1e6));
            out = (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14);
        }
        case 4u: { out = agx(c); }
        default: { out = pbr_neutral(c); }
    }
    return clamp(out, vec3<f32>(0.0), vec3<f32>(1.0));
}

@fragment
fn tonemapping_fs(in: FullscreenOut) -> @location(0) vec4<f32> {
    let c = textureLoad(hdr, vec2<i32>(in.position.xy), 0).rgb;
    return vec4<f32>(tonemap(c * tm.exposure), 1.0);
}
