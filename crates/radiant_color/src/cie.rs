//! CIE 1931 colorimetry: colour-matching functions, spectra, XYZ ↔ linear sRGB from the
//! primaries and white point, chromaticity, blackbody spectra, Bradford adaptation, CIELAB and
//! ΔE2000, and out-of-gamut handling that reports rather than clamps silently.
//!
//! Tables (in `data/`, written by `tools/make_colour_fixtures.py` from the tables colour-science
//! exports): the CIE 1931 2° x̄ȳz̄ at 1 nm (360–830 nm), the CIE 1931 r̄ḡb̄ derived from them at
//! 5 nm (380–780 nm), and illuminant D65 at 5 nm (300–830 nm).

use std::sync::OnceLock;

/// A 3 × 3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// Errors for spectral data.
#[derive(Debug, Clone, PartialEq)]
pub enum SpectrumError {
    /// Wavelengths and values differ in length, or there are fewer than two samples.
    Shape(String),
    /// Wavelengths not strictly increasing, or a value not finite.
    Invalid(String),
}

impl std::fmt::Display for SpectrumError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Shape(s) | Self::Invalid(s) => write!(f, "spectrum: {s}"),
        }
    }
}

impl std::error::Error for SpectrumError {}

/// A sampled spectrum, linearly interpolated between samples and zero outside them.
#[derive(Clone, Debug, PartialEq)]
pub struct Spectrum {
    wavelengths: Vec<f64>,
    values: Vec<f64>,
}

impl Spectrum {
    /// A spectrum from samples (nm, strictly increasing) and values.
    pub fn new(wavelengths: Vec<f64>, values: Vec<f64>) -> Result<Self, SpectrumError> {
        if wavelengths.len() != values.len() || wavelengths.len() < 2 {
            return Err(SpectrumError::Shape(format!(
                "{} wavelengths, {} values",
                wavelengths.len(),
                values.len()
            )));
        }
        if wavelengths
            .windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
            || wavelengths.iter().any(|w| !w.is_finite())
        {
            return Err(SpectrumError::Invalid(
                "wavelengths must increase strictly".into(),
            ));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(SpectrumError::Invalid("a value is not finite".into()));
        }
        Ok(Spectrum {
            wavelengths,
            values,
        })
    }

    /// A constant spectrum over the visible range (CIE illuminant E when `v` is 1).
    pub fn constant(v: f64) -> Self {
        Spectrum {
            wavelengths: vec![360.0, 830.0],
            values: vec![v, v],
        }
    }

    /// Planck's law at `kelvin`, relative spectral radiance normalised to 1 at 560 nm.
    pub fn blackbody(kelvin: f64) -> Self {
        let planck = |nm: f64| {
            const C2: f64 = 1.438_776_877e-2; // m·K, second radiation constant (CODATA 2018)
            let l = nm * 1e-9;
            1.0 / (l.powi(5) * ((C2 / (l * kelvin)).exp_m1()))
        };
        let norm = planck(560.0);
        let wavelengths: Vec<f64> = (360..=830).map(f64::from).collect();
        let values = wavelengths.iter().map(|&w| planck(w) / norm).collect();
        Spectrum {
            wavelengths,
            values,
        }
    }

    /// The value at `nm`.
    pub fn at(&self, nm: f64) -> f64 {
        let w = &self.wavelengths;
        if nm < w[0] || nm > w[w.len() - 1] {
            return 0.0;
        }
        let k = w.partition_point(|&x| x <= nm).clamp(1, w.len() - 1);
        let t = (nm - w[k - 1]) / (w[k] - w[k - 1]);
        self.values[k - 1] * (1.0 - t) + self.values[k] * t
    }

    /// First and last sampled wavelength.
    pub fn range(&self) -> (f64, f64) {
        (
            self.wavelengths[0],
            self.wavelengths[self.wavelengths.len() - 1],
        )
    }
}

fn parse_table(text: &str) -> Vec<(f64, Vec<f64>)> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .filter_map(|l| {
            let v: Vec<f64> = l.split(',').filter_map(|x| x.trim().parse().ok()).collect();
            (v.len() >= 2).then(|| (v[0], v[1..].to_vec()))
        })
        .collect()
}

/// Rows of `wavelength, a, b, c`; rows with fewer numbers are skipped.
fn triples(text: &str) -> Vec<(f64, [f64; 3])> {
    parse_table(text)
        .into_iter()
        .filter(|(_, v)| v.len() >= 3)
        .map(|(w, v)| (w, [v[0], v[1], v[2]]))
        .collect()
}

/// The CIE 1931 2° colour-matching functions x̄ȳz̄, 360–830 nm at 1 nm.
pub fn cmf_xyz() -> &'static [(f64, [f64; 3])] {
    static T: OnceLock<Vec<(f64, [f64; 3])>> = OnceLock::new();
    T.get_or_init(|| triples(include_str!("../data/cie1931_xyz_cmf_1nm.csv")))
}

/// The CIE 1931 RGB colour-matching functions r̄ḡb̄ (primaries 700, 546.1, 435.8 nm), 380–780 nm
/// at 5 nm, derived from x̄ȳz̄. r̄ is negative between about 440 and 545 nm: matching those
/// wavelengths needs red light added to the test side.
pub fn cmf_rgb() -> &'static [(f64, [f64; 3])] {
    static T: OnceLock<Vec<(f64, [f64; 3])>> = OnceLock::new();
    T.get_or_init(|| triples(include_str!("../data/cie1931_rgb_cmf_5nm.csv")))
}

/// CIE standard illuminant D65 (relative spectral power, 300–830 nm at 5 nm).
pub fn d65() -> &'static Spectrum {
    static S: OnceLock<Spectrum> = OnceLock::new();
    S.get_or_init(|| {
        let t = parse_table(include_str!("../data/cie_d65_5nm.csv"));
        Spectrum {
            wavelengths: t.iter().map(|r| r.0).collect(),
            values: t.iter().map(|r| r.1[0]).collect(),
        }
    })
}

/// XYZ of a reflectance under an illuminant, normalised so that a perfect reflector has Y = 1.
/// Integrated at 1 nm over the wavelengths where the reflectance is sampled. Also returns the
/// white (perfect reflector) XYZ over the same range.
pub fn reflectance_to_xyz(reflectance: &Spectrum, illuminant: &Spectrum) -> ([f64; 3], [f64; 3]) {
    let (lo, hi) = reflectance.range();
    let (mut xyz, mut white) = ([0.0; 3], [0.0; 3]);
    for &(w, c) in cmf_xyz().iter().filter(|(w, _)| *w >= lo && *w <= hi) {
        let s = illuminant.at(w);
        let r = reflectance.at(w);
        for k in 0..3 {
            xyz[k] += r * s * c[k];
            white[k] += s * c[k];
        }
    }
    let n = white[1];
    if n > 0.0 {
        (xyz.map(|v| v / n), white.map(|v| v / n))
    } else {
        ([0.0; 3], [0.0; 3])
    }
}

/// xy chromaticity of an XYZ colour; the D65 white for black.
pub fn xy(xyz: [f64; 3]) -> [f64; 2] {
    let s = xyz[0] + xyz[1] + xyz[2];
    if s > 0.0 {
        [xyz[0] / s, xyz[1] / s]
    } else {
        SRGB_WHITE_XY
    }
}

/// The spectral locus: xy of each monochromatic wavelength, 360–830 nm at 1 nm.
pub fn spectral_locus() -> Vec<(f64, [f64; 2])> {
    cmf_xyz().iter().map(|&(w, c)| (w, xy(c))).collect()
}

/// sRGB (Rec. 709) primaries, xy (IEC 61966-2-1).
pub const SRGB_PRIMARIES_XY: [[f64; 2]; 3] = [[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]];
/// The sRGB white point, D65, xy as IEC 61966-2-1 rounds it.
pub const SRGB_WHITE_XY: [f64; 2] = [0.3127, 0.3290];

fn xy_to_xyz(c: [f64; 2]) -> [f64; 3] {
    [c[0] / c[1], 1.0, (1.0 - c[0] - c[1]) / c[1]]
}

/// The inverse of a 3 × 3 matrix (`None` if singular).
pub fn invert(m: &Mat3) -> Option<Mat3> {
    let c = |r: usize, k: usize| {
        m[(r + 1) % 3][(k + 1) % 3] * m[(r + 2) % 3][(k + 2) % 3]
            - m[(r + 1) % 3][(k + 2) % 3] * m[(r + 2) % 3][(k + 1) % 3]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    Some(std::array::from_fn(|i| {
        std::array::from_fn(|j| c(j, i) / det)
    }))
}

/// `m · v`.
pub fn mul(m: &Mat3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

fn matmul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// The linear RGB → XYZ matrix of a colour space from its primaries and white point (xy): the
/// columns are the primaries' XYZ, scaled so that RGB (1, 1, 1) is the white with Y = 1.
pub fn rgb_to_xyz_matrix(primaries: [[f64; 2]; 3], white: [f64; 2]) -> Option<Mat3> {
    let p: Mat3 = std::array::from_fn(|i| std::array::from_fn(|j| xy_to_xyz(primaries[j])[i]));
    let s = mul(&invert(&p)?, xy_to_xyz(white));
    Some(std::array::from_fn(|i| {
        std::array::from_fn(|j| p[i][j] * s[j])
    }))
}

/// The sRGB matrices, derived from the primaries and D65: (RGB → XYZ, XYZ → RGB).
pub fn srgb_matrices() -> &'static (Mat3, Mat3) {
    static M: OnceLock<(Mat3, Mat3)> = OnceLock::new();
    M.get_or_init(|| {
        let to_xyz = rgb_to_xyz_matrix(SRGB_PRIMARIES_XY, SRGB_WHITE_XY).unwrap_or([[0.0; 3]; 3]);
        (to_xyz, invert(&to_xyz).unwrap_or([[0.0; 3]; 3]))
    })
}

/// Bradford chromatic adaptation from one white (XYZ) to another.
pub fn bradford(from_white: [f64; 3], to_white: [f64; 3]) -> Option<Mat3> {
    const M: Mat3 = [
        [0.8951, 0.2664, -0.1614],
        [-0.7502, 1.7135, 0.0367],
        [0.0389, -0.0685, 1.0296],
    ];
    let (s, d) = (mul(&M, from_white), mul(&M, to_white));
    if s.contains(&0.0) {
        return None;
    }
    let scale: Mat3 =
        std::array::from_fn(|i| std::array::from_fn(|j| if i == j { d[i] / s[i] } else { 0.0 }));
    Some(matmul(&invert(&M)?, &matmul(&scale, &M)))
}

/// How to bring an out-of-gamut colour into [0, 1]³.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GamutMapping {
    /// Clamp each channel (hue may shift).
    Clip,
    /// Mix with the grey of the same luminance until no channel is negative, then scale down
    /// if one exceeds 1 (keeps hue, loses saturation).
    Desaturate,
}

/// Linear sRGB from XYZ, with whether it was out of gamut (a channel < 0 or > 1).
pub fn xyz_to_srgb_linear(xyz: [f64; 3]) -> ([f64; 3], bool) {
    let rgb = mul(&srgb_matrices().1, xyz);
    let out = rgb.iter().any(|&c| !(0.0..=1.0).contains(&c));
    (rgb, out)
}

/// Maps a linear sRGB colour into the gamut by the stated method.
pub fn map_to_gamut(rgb: [f64; 3], method: GamutMapping) -> [f64; 3] {
    match method {
        GamutMapping::Clip => rgb.map(|c| c.clamp(0.0, 1.0)),
        GamutMapping::Desaturate => {
            let y = crate::luminance(rgb).clamp(0.0, 1.0);
            let lowest = rgb.iter().copied().fold(f64::INFINITY, f64::min);
            let t = if lowest < 0.0 && y - lowest > 0.0 {
                y / (y - lowest)
            } else {
                1.0
            };
            let mixed = rgb.map(|c| y + (c - y) * t);
            let peak = mixed.iter().copied().fold(0.0, f64::max);
            let out = if peak > 1.0 {
                mixed.map(|c| c / peak)
            } else {
                mixed
            };
            out.map(|c| c.clamp(0.0, 1.0))
        }
    }
}

/// The colour of a black body at `kelvin` (the Planckian locus): its xy chromaticity and a
/// linear sRGB colour of that chromaticity with the largest channel 1 (desaturated into the
/// gamut where the locus leaves it, below about 1 900 K). `None` for a temperature that is not
/// finite and positive.
pub fn blackbody_color(kelvin: f64) -> Option<([f64; 2], [f64; 3])> {
    if !(kelvin.is_finite() && kelvin > 0.0) {
        return None;
    }
    let (xyz, _) = reflectance_to_xyz(&Spectrum::blackbody(kelvin), &Spectrum::constant(1.0));
    let c = xy(xyz);
    if c[1] <= 0.0 {
        return None;
    }
    let xyz = [c[0] / c[1], 1.0, (1.0 - c[0] - c[1]) / c[1]];
    let (rgb, _) = xyz_to_srgb_linear(xyz);
    let rgb = if rgb.iter().any(|&v| v < 0.0) {
        map_to_gamut(rgb, GamutMapping::Desaturate)
    } else {
        rgb
    };
    let peak = rgb.iter().copied().fold(0.0, f64::max);
    (peak > 0.0).then(|| (c, rgb.map(|v| v / peak)))
}

/// CIELAB of an XYZ colour relative to a white.
pub fn xyz_to_lab(xyz: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    let f = |t: f64| {
        if t > (6.0f64 / 29.0).powi(3) {
            t.cbrt()
        } else {
            t / (3.0 * (6.0f64 / 29.0).powi(2)) + 4.0 / 29.0
        }
    };
    let (fx, fy, fz) = (
        f(xyz[0] / white[0]),
        f(xyz[1] / white[1]),
        f(xyz[2] / white[2]),
    );
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIEDE2000 colour difference (Sharma, Wu & Dalal 2005), kL = kC = kH = 1.
pub fn delta_e_2000(a: [f64; 3], b: [f64; 3]) -> f64 {
    use std::f64::consts::PI;
    let deg = PI / 180.0;
    let (c1, c2) = (a[1].hypot(a[2]), b[1].hypot(b[2]));
    let cm = (c1 + c2) / 2.0;
    let g = 0.5 * (1.0 - (cm.powi(7) / (cm.powi(7) + 25f64.powi(7))).sqrt());
    let (a1, a2) = ((1.0 + g) * a[1], (1.0 + g) * b[1]);
    let (c1, c2) = (a1.hypot(a[2]), a2.hypot(b[2]));
    let hue = |y: f64, x: f64| {
        if x == 0.0 && y == 0.0 {
            0.0
        } else {
            y.atan2(x).rem_euclid(2.0 * PI)
        }
    };
    let (h1, h2) = (hue(a[2], a1), hue(b[2], a2));
    let dl = b[0] - a[0];
    let dc = c2 - c1;
    let mut dh = h2 - h1;
    if c1 * c2 != 0.0 {
        if dh > PI {
            dh -= 2.0 * PI;
        } else if dh < -PI {
            dh += 2.0 * PI;
        }
    } else {
        dh = 0.0;
    }
    let dhh = 2.0 * (c1 * c2).sqrt() * (dh / 2.0).sin();
    let lm = (a[0] + b[0]) / 2.0;
    let cm = (c1 + c2) / 2.0;
    let hm = if c1 * c2 == 0.0 {
        h1 + h2
    } else if (h1 - h2).abs() <= PI {
        (h1 + h2) / 2.0
    } else if h1 + h2 < 2.0 * PI {
        (h1 + h2 + 2.0 * PI) / 2.0
    } else {
        (h1 + h2 - 2.0 * PI) / 2.0
    };
    let t = 1.0 - 0.17 * (hm - 30.0 * deg).cos()
        + 0.24 * (2.0 * hm).cos()
        + 0.32 * (3.0 * hm + 6.0 * deg).cos()
        - 0.20 * (4.0 * hm - 63.0 * deg).cos();
    let dtheta = 30.0 * deg * (-((hm / deg - 275.0) / 25.0).powi(2)).exp();
    let rc = 2.0 * (cm.powi(7) / (cm.powi(7) + 25f64.powi(7))).sqrt();
    let sl = 1.0 + 0.015 * (lm - 50.0).powi(2) / (20.0 + (lm - 50.0).powi(2)).sqrt();
    let sc = 1.0 + 0.045 * cm;
    let sh = 1.0 + 0.015 * cm * t;
    let rt = -(2.0 * dtheta).sin() * rc;
    ((dl / sl).powi(2) + (dc / sc).powi(2) + (dhh / sh).powi(2) + rt * (dc / sc) * (dhh / sh))
        .sqrt()
}
