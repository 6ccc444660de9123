//! Tone-map operators on the CPU: linear HDR radiance → display-linear [0, 1].
//!
//! These are the reference versions of the GPU operators in `radiant_post::tonemapping`; a test
//! there renders every operator on the GPU and holds it to these within 1/255 after sRGB
//! encoding. Keep the two in step: the constants below are the same as in `tonemapping.wgsl`.

/// A tone-mapping operator: linear HDR → linear display range [0, 1], before sRGB encoding.
///
/// Exposure is applied by the caller (multiply by `2^ev` first). Every operator maps NaN and
/// negative input to 0 and +∞ to the operator's white.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum Tonemap {
    /// No curve: each channel clamped to [0, 1].
    Clamp,
    /// Reinhard (2002), per channel: `x / (1 + x)`. Never reaches white.
    Reinhard,
    /// Extended Reinhard (2002), per channel: `x (1 + x / w²) / (1 + x)`; `x = w` maps to 1.
    ExtendedReinhard {
        /// The smallest input that maps to white, in exposed linear units; range (0, ∞)
        /// (default: 4).
        white: f64,
    },
    /// ACES filmic curve, Narkowicz's 2015 fit, per channel.
    #[default]
    AcesFitted,
    /// AgX (Sobotka), the minimal fit by Wrensch (2023): inset matrix, log2 encoding over
    /// [-12.47, 4.03] EV, a 6th-order sigmoid, outset matrix, display gamma 2.2 decoded back to
    /// linear.
    AgX,
    /// Khronos PBR Neutral (2024): hue-preserving, identity below 0.76, then a soft
    /// compression of the peak channel with a little desaturation.
    PbrNeutral,
}

impl Tonemap {
    /// Every operator with its default parameters, in the order the UI lists them.
    pub const ALL: [Tonemap; 6] = [
        Tonemap::Clamp,
        Tonemap::Reinhard,
        Tonemap::ExtendedReinhard { white: 4.0 },
        Tonemap::AcesFitted,
        Tonemap::AgX,
        Tonemap::PbrNeutral,
    ];

    /// The operator's short name, as the CLI spells it.
    pub fn name(self) -> &'static str {
        match self {
            Tonemap::Clamp => "clamp",
            Tonemap::Reinhard => "reinhard",
            Tonemap::ExtendedReinhard { .. } => "reinhard-extended",
            Tonemap::AcesFitted => "aces",
            Tonemap::AgX => "agx",
            Tonemap::PbrNeutral => "pbr-neutral",
        }
    }

    /// Parses a CLI name (see [`Tonemap::name`]; `none` is an alias of `clamp`).
    pub fn from_name(name: &str) -> Option<Tonemap> {
        (Self::ALL.into_iter().find(|t| t.name() == name)).or_else(|| {
            Self::ALIASES
                .iter()
                .find(|(a, _)| *a == name)
                .map(|&(_, t)| t)
        })
    }

    /// Other names each operator is known by.
    pub const ALIASES: &[(&str, Tonemap)] = &[("none", Tonemap::Clamp)];

    /// Applies the operator to one exposed linear colour.
    pub fn apply(self, rgb: [f64; 3]) -> [f64; 3] {
        let rgb = rgb.map(|x| {
            if x.is_finite() {
                x.max(0.0)
            } else if x == f64::INFINITY {
                1e30
            } else {
                0.0
            }
        });
        let out = match self {
            Tonemap::Clamp => rgb.map(|x| x.min(1.0)),
            Tonemap::Reinhard => rgb.map(|x| x / (1.0 + x)),
            Tonemap::ExtendedReinhard { white } => {
                let w2 = if white.is_finite() && white > 0.0 {
                    white * white
                } else {
                    1.0
                };
                rgb.map(|x| (x * (1.0 + x / w2) / (1.0 + x)).min(1.0))
            }
            Tonemap::AcesFitted => rgb.map(|x| {
                let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
                let x = x.min(1e6);
                ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0)
            }),
            Tonemap::AgX => agx(rgb),
            Tonemap::PbrNeutral => pbr_neutral(rgb),
        };
        out.map(|x| x.clamp(0.0, 1.0))
    }

    /// Exposes (`2^ev`), tone-maps and encodes one colour to 8-bit sRGB.
    pub fn to_srgb8(self, rgb: [f64; 3], exposure_ev: f64) -> [u8; 3] {
        let k = exposure_ev.exp2();
        self.apply(rgb.map(|x| x * k)).map(crate::linear_to_srgb8)
    }
}

/// AgX inset matrix, rows (applied as `M · rgb`).
const AGX_INSET: [[f64; 3]; 3] = [
    [
        0.842_479_062_253_094,
        0.078_433_599_999_999_2,
        0.079_223_745_147_764_3,
    ],
    [
        0.042_328_242_261_012_3,
        0.878_468_636_469_772,
        0.079_166_127_460_543_4,
    ],
    [0.042_375_654_905_705_1, 0.078_433_6, 0.879_142_973_793_104],
];
/// AgX outset matrix, rows.
const AGX_OUTSET: [[f64; 3]; 3] = [
    [
        1.196_879_005_120_17,
        -0.098_020_881_140_136_8,
        -0.099_029_744_079_720_5,
    ],
    [
        -0.052_896_851_757_456_2,
        1.151_903_129_904_17,
        -0.098_961_176_844_843_3,
    ],
    [
        -0.052_971_635_514_443_8,
        -0.098_043_450_117_124_1,
        1.151_073_672_641_16,
    ],
];
const AGX_MIN_EV: f64 = -12.473_931_188_332_41;
const AGX_MAX_EV: f64 = 4.026_068_811_667_588;

fn mat_mul(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

fn agx(rgb: [f64; 3]) -> [f64; 3] {
    let v = mat_mul(&AGX_INSET, rgb).map(|x| {
        let ev = x.max(1e-10).log2().clamp(AGX_MIN_EV, AGX_MAX_EV);
        let t = (ev - AGX_MIN_EV) / (AGX_MAX_EV - AGX_MIN_EV);
        let t2 = t * t;
        let t4 = t2 * t2;
        15.5 * t4 * t2 - 40.14 * t4 * t + 31.96 * t4 - 6.868 * t2 * t + 0.4298 * t2 + 0.1191 * t
            - 0.00232
    });
    mat_mul(&AGX_OUTSET, v).map(|x| x.max(0.0).powf(2.2))
}

fn pbr_neutral(mut c: [f64; 3]) -> [f64; 3] {
    const START: f64 = 0.8 - 0.04;
    const DESATURATION: f64 = 0.15;
    let x = c[0].min(c[1]).min(c[2]);
    let offset = if x < 0.08 { x - 6.25 * x * x } else { 0.04 };
    c = c.map(|v| v - offset);
    let peak = c[0].max(c[1]).max(c[2]);
    if peak < START {
        return c;
    }
    let d = 1.0 - START;
    let new_peak = 1.0 - d * d / (peak + d - START);
    c = c.map(|v| v * new_peak / peak);
    let g = 1.0 - 1.0 / (DESATURATION * (peak - new_peak) + 1.0);
    c.map(|v| v + (new_peak - v) * g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_operator_is_monotone_bounded_and_nan_free() {
        for op in Tonemap::ALL {
            let mut last = -1.0;
            for i in 0..=400 {
                let x = (f64::from(i) / 20.0 - 10.0).exp2();
                let y = op.apply([x, x, x]);
                assert!(
                    y.iter().all(|v| (0.0..=1.0).contains(v)),
                    "{op:?} at {x}: {y:?}"
                );
                assert!(y[0] >= last - 1e-9, "{op:?} not monotone at {x}");
                last = y[0];
            }
            for bad in [f64::NAN, f64::NEG_INFINITY, -1.0, f64::INFINITY] {
                let y = op.apply([bad, 0.5, bad]);
                assert!(y.iter().all(|v| v.is_finite()), "{op:?} on {bad}: {y:?}");
            }
            assert_eq!(Tonemap::from_name(op.name()), Some(op));
        }
    }

    #[test]
    fn published_anchor_values() {
        // Extended Reinhard maps the white point to exactly 1.
        let y = Tonemap::ExtendedReinhard { white: 4.0 }.apply([4.0; 3]);
        assert!((y[0] - 1.0).abs() < 1e-12);
        // PBR Neutral is the identity (up to the toe offset of 0.04) below 0.76.
        let y = Tonemap::PbrNeutral.apply([0.5, 0.3, 0.2]);
        assert!((y[0] - 0.46).abs() < 1e-12 && (y[2] - 0.16).abs() < 1e-12);
        // ACES fitted at 1.0 is 0.8038 (Narkowicz).
        let y = Tonemap::AcesFitted.apply([1.0; 3]);
        assert!((y[0] - 0.803_797).abs() < 1e-5, "{y:?}");
        // AgX maps 18 % grey to about 0.18-0.2 display-linear (its mid-grey anchor).
        let y = Tonemap::AgX.apply([0.18; 3]);
        assert!((0.12..0.25).contains(&y[0]), "{y:?}");
    }
}
