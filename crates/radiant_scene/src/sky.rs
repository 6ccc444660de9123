//! Sky light: radiance arriving from outside the scene along every ray that escapes it.
//!
//! Three kinds, in the bake's emissive units (a surface of reflectance ρ under a uniform sky of
//! radiance `L`, seeing all of it, has radiosity `ρ·L`; its irradiance is `π·L`):
//!
//! - **uniform**: the same radiance in every direction;
//! - **gradient**: `horizon` at and below the horizon, blending linearly in `sin(elevation)` to
//!   `zenith` straight up;
//! - **image**: an equirectangular (latitude–longitude) linear HDR image (`.hdr` or `.exr`),
//!   times a scale.
//!
//! Up is glTF's +Y. A sky comes from the CLI (`--sky`, see [`Sky::parse`]) or from the glTF
//! scene's extras, `{"radiant": {"sky": …}}` with the same string, or an object
//! `{"radiance": [r, g, b]}`, `{"zenith": [..], "horizon": [..]}` or
//! `{"image": "sky.hdr", "scale": 1.0}` (paths relative to the glTF file).

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;

use crate::SceneError;

/// An equirectangular sky image: linear RGB, row 0 at the zenith.
#[derive(Clone, PartialEq)]
pub struct SkyImage {
    /// The file it came from.
    pub path: String,
    /// Width in texels (longitude).
    pub width: u32,
    /// Height in texels (latitude).
    pub height: u32,
    /// `width × height` linear RGB texels, already multiplied by the scale.
    pub texels: Arc<[[f32; 3]]>,
}

impl std::fmt::Debug for SkyImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "SkyImage({:?}, {}×{})",
            self.path, self.width, self.height
        )
    }
}

/// Light from outside the scene.
#[derive(Clone, Debug, PartialEq)]
pub enum Sky {
    /// The same radiance in every direction.
    Uniform {
        /// Linear RGB radiance.
        radiance: [f64; 3],
    },
    /// `horizon` at and below the horizon, linear in `sin(elevation)` up to `zenith`.
    Gradient {
        /// Radiance straight up.
        zenith: [f64; 3],
        /// Radiance at and below the horizon.
        horizon: [f64; 3],
    },
    /// An equirectangular image.
    Image(SkyImage),
}

impl Sky {
    /// Radiance arriving from world direction `dir` (unit, pointing away from the scene).
    pub fn radiance(&self, dir: DVec3) -> [f64; 3] {
        match self {
            Sky::Uniform { radiance } => *radiance,
            Sky::Gradient { zenith, horizon } => {
                let t = dir.y.clamp(0.0, 1.0);
                std::array::from_fn(|c| horizon[c] + (zenith[c] - horizon[c]) * t)
            }
            Sky::Image(img) => {
                let u = 0.5 + dir.x.atan2(-dir.z) / std::f64::consts::TAU;
                let v = dir.y.clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
                if !(u.is_finite() && v.is_finite()) {
                    return [0.0; 3];
                }
                let x = ((u * f64::from(img.width)) as u32).min(img.width - 1);
                let y = ((v * f64::from(img.height)) as u32).min(img.height - 1);
                img.texels[(y * img.width + x) as usize].map(f64::from)
            }
        }
    }

    /// Whether the sky gives no light at all.
    pub fn is_dark(&self) -> bool {
        match self {
            Sky::Uniform { radiance } => radiance.iter().all(|&v| v <= 0.0),
            Sky::Gradient { zenith, horizon } => zenith.iter().chain(horizon).all(|&v| v <= 0.0),
            Sky::Image(img) => img.texels.iter().flatten().all(|&v| v <= 0.0),
        }
    }

    /// Parses a sky description, the CLI's `--sky` and the glTF extras' string form:
    ///
    /// - `L` or `R,G,B`: a uniform sky;
    /// - `gradient:ZR,ZG,ZB/HR,HG,HB` (zenith / horizon; each also one grey value);
    /// - `PATH.hdr` or `PATH.exr`, optionally `PATH.hdr@SCALE`: an equirectangular image,
    ///   relative to `base` when given.
    ///
    /// `none` is the caller's (no sky). Negative or non-finite radiance is an error.
    pub fn parse(spec: &str, base: Option<&Path>) -> Result<Sky, SceneError> {
        let spec = spec.trim();
        let bad = |what: String| SceneError::InvalidSky(what);
        if let Some(rest) = spec.strip_prefix("gradient:") {
            let (z, h) = rest
                .split_once('/')
                .ok_or_else(|| bad(format!("'{spec}': expected gradient:ZENITH/HORIZON")))?;
            let sky = Sky::Gradient {
                zenith: rgb(z).ok_or_else(|| bad(format!("zenith '{z}' is not R,G,B")))?,
                horizon: rgb(h).ok_or_else(|| bad(format!("horizon '{h}' is not R,G,B")))?,
            };
            return sky.checked();
        }
        let (path, scale) = match spec.rsplit_once('@') {
            Some((p, s)) => (p, Some(s)),
            None => (spec, None),
        };
        let lower = path.to_ascii_lowercase();
        if lower.ends_with(".hdr") || lower.ends_with(".exr") {
            let scale = match scale {
                Some(s) => s
                    .parse::<f64>()
                    .map_err(|_| bad(format!("scale '{s}' is not a number")))?,
                None => 1.0,
            };
            return load_image(path, scale, base);
        }
        let radiance = rgb(spec).ok_or_else(|| {
            bad(format!(
                "'{spec}': expected L, R,G,B, gradient:Z/H or an .hdr/.exr image"
            ))
        })?;
        Sky::Uniform { radiance }.checked()
    }

    /// Reads the glTF scene extras' `radiant.sky` value (a string as in [`Sky::parse`] or an
    /// object, see the module docs); `Ok(None)` when it is absent or `"none"`.
    pub fn from_extras(
        value: &serde_json::Value,
        base: Option<&Path>,
    ) -> Result<Option<Sky>, SceneError> {
        let bad = |what: &str| SceneError::InvalidSky(format!("scene extras radiant.sky: {what}"));
        let triple = |v: &serde_json::Value| -> Option<[f64; 3]> {
            let a = v.as_array()?;
            (a.len() == 3).then_some(())?;
            Some([a[0].as_f64()?, a[1].as_f64()?, a[2].as_f64()?])
        };
        match value {
            serde_json::Value::Null => Ok(None),
            serde_json::Value::String(s) if s.trim() == "none" => Ok(None),
            serde_json::Value::String(s) => Sky::parse(s, base).map(Some),
            serde_json::Value::Object(o) => {
                if let Some(r) = o.get("radiance") {
                    let radiance = triple(r).ok_or_else(|| bad("radiance is not [r, g, b]"))?;
                    return Sky::Uniform { radiance }.checked().map(Some);
                }
                if let (Some(z), Some(h)) = (o.get("zenith"), o.get("horizon")) {
                    let sky = Sky::Gradient {
                        zenith: triple(z).ok_or_else(|| bad("zenith is not [r, g, b]"))?,
                        horizon: triple(h).ok_or_else(|| bad("horizon is not [r, g, b]"))?,
                    };
                    return sky.checked().map(Some);
                }
                if let Some(path) = o.get("image").and_then(|p| p.as_str()) {
                    let scale = o.get("scale").map_or(Some(1.0), |s| s.as_f64());
                    let scale = scale.ok_or_else(|| bad("scale is not a number"))?;
                    return load_image(path, scale, base).map(Some);
                }
                Err(bad("expected radiance, zenith and horizon, or image"))
            }
            _ => Err(bad("expected a string or an object")),
        }
    }

    fn checked(self) -> Result<Sky, SceneError> {
        let values: Vec<f64> = match &self {
            Sky::Uniform { radiance } => radiance.to_vec(),
            Sky::Gradient { zenith, horizon } => zenith.iter().chain(horizon).copied().collect(),
            Sky::Image(_) => Vec::new(),
        };
        match values.iter().find(|v| !v.is_finite() || **v < 0.0) {
            Some(v) => Err(SceneError::InvalidSky(format!(
                "radiance {v} is negative or not finite"
            ))),
            None => Ok(self),
        }
    }
}

/// `L` or `R,G,B`.
fn rgb(s: &str) -> Option<[f64; 3]> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .ok()?;
    match v[..] {
        [l] => Some([l; 3]),
        [r, g, b] => Some([r, g, b]),
        _ => None,
    }
}

/// The most texels a sky image may have (16384 × 8192): its linear RGB takes 1.5 GiB.
pub const SKY_MAX_TEXELS: u64 = 16384 * 8192;

/// The most bytes a sky image file may have: an uncompressed float EXR of
/// [`SKY_MAX_TEXELS`] RGBA texels, with room for its headers.
const SKY_MAX_FILE: u64 = SKY_MAX_TEXELS * 16 + (1 << 20);

fn load_image(path: &str, scale: f64, base: Option<&Path>) -> Result<Sky, SceneError> {
    let full = match base {
        Some(dir) if Path::new(path).is_relative() => dir.join(path),
        _ => Path::new(path).to_path_buf(),
    };
    let name = full.display().to_string();
    let bytes =
        crate::read_regular_file(&full, SKY_MAX_FILE).map_err(|what| SceneError::Texture {
            image: name.clone(),
            what,
        })?;
    Sky::from_image_bytes(&name, &bytes, scale)
}

impl Sky {
    /// Decodes an equirectangular sky image (Radiance `.hdr` or OpenEXR, recognised by its
    /// bytes) held in memory, times `scale`; `name` labels it in errors and in
    /// [`SkyImage::path`]. Sizes are checked from the header before any texel is decoded.
    ///
    /// # Errors
    /// [`SceneError::Texture`] when the bytes are not an image or cannot be decoded,
    /// [`SceneError::InvalidSky`] for a negative or non-finite scale or texel, an empty image, or
    /// one over [`SKY_MAX_TEXELS`].
    pub fn from_image_bytes(name: &str, bytes: &[u8], scale: f64) -> Result<Sky, SceneError> {
        Self::from_image_bytes_within(name, bytes, scale, SKY_MAX_TEXELS)
    }

    /// [`Sky::from_image_bytes`] with at most `max_texels` texels (and decoder allocations
    /// in proportion), as a tighter memory budget asks.
    pub fn from_image_bytes_within(
        name: &str,
        bytes: &[u8],
        scale: f64,
        max_texels: u64,
    ) -> Result<Sky, SceneError> {
        if !scale.is_finite() || scale < 0.0 {
            return Err(SceneError::InvalidSky(format!(
                "scale {scale} is negative or not finite"
            )));
        }
        let undecodable = |e: image::ImageError| SceneError::Texture {
            image: name.to_string(),
            what: format!("cannot decode it: {e}"),
        };
        let reader = || -> Result<_, SceneError> {
            let mut r = image::ImageReader::new(std::io::Cursor::new(bytes))
                .with_guessed_format()
                .map_err(|e| undecodable(image::ImageError::IoError(e)))?;
            let mut limits = image::Limits::default();
            limits.max_alloc = Some(max_texels * 32 + (64 << 20));
            r.limits(limits);
            Ok(r)
        };
        crate::exr_fits(bytes, max_texels)
            .map_err(|what| SceneError::InvalidSky(format!("{name}: {what}")))?;
        let (width, height) = reader()?.into_dimensions().map_err(undecodable)?;
        if width == 0 || height == 0 {
            return Err(SceneError::InvalidSky(format!("{name}: empty image")));
        }
        if u64::from(width) * u64::from(height) > max_texels {
            return Err(SceneError::InvalidSky(format!(
                "{name}: {width}×{height} texels is more than a sky image may have ({max_texels})"
            )));
        }
        let img = reader()?.decode().map_err(undecodable)?;
        let rgb = img.to_rgb32f();
        let (width, height) = rgb.dimensions();
        let texels: Vec<[f32; 3]> = rgb
            .pixels()
            .map(|p| p.0.map(|v| v * scale as f32))
            .collect();
        if let Some(v) = texels
            .iter()
            .flatten()
            .find(|v| !v.is_finite() || **v < 0.0)
        {
            return Err(SceneError::InvalidSky(format!(
                "{name}: texel value {v} is negative or not finite"
            )));
        }
        if width == 0 || height == 0 {
            return Err(SceneError::InvalidSky(format!("{name}: empty image")));
        }
        Ok(Sky::Image(SkyImage {
            path: name.to_string(),
            width,
            height,
            texels: texels.into(),
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat (not run-length) Radiance RGBE image, every texel `(m, m, m)` × 2^(e − 136).
    fn rgbe(width: u32, height: u32, m: u8, e: u8) -> Vec<u8> {
        let mut b =
            format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {height} +X {width}\n").into_bytes();
        for _ in 0..width * height {
            b.extend_from_slice(&[m, m, m, e]);
        }
        b
    }

    #[test]
    fn sky_images_decode_from_bytes_within_their_limit() {
        let bytes = rgbe(8, 4, 128, 129);
        let Sky::Image(img) = Sky::from_image_bytes("flat.hdr", &bytes, 2.0).expect("decodes")
        else {
            panic!("not an image sky");
        };
        assert_eq!((img.width, img.height), (8, 4));
        // 128 × 2^(129 − 136) = 1, times the scale.
        assert!(img.texels.iter().flatten().all(|&v| (v - 2.0).abs() < 1e-6));
        let e = Sky::from_image_bytes_within("flat.hdr", &bytes, 1.0, 31).expect_err("32 > 31");
        assert!(
            matches!(e, SceneError::InvalidSky(ref w) if w.contains("8×4")),
            "{e}"
        );
        for scale in [-1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                Sky::from_image_bytes("flat.hdr", &bytes, scale),
                Err(SceneError::InvalidSky(_))
            ));
        }
        assert!(matches!(
            Sky::from_image_bytes("junk.hdr", b"not an image", 1.0),
            Err(SceneError::Texture { .. })
        ));
        // A header that promises more texels than the bytes hold.
        assert!(Sky::from_image_bytes("short.hdr", &bytes[..bytes.len() - 9], 1.0).is_err());
    }

    #[test]
    fn a_sky_file_that_is_a_device_is_refused_unread() {
        let dir = std::env::temp_dir().join(format!("radiant-sky-dev-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let link = dir.join("sky.hdr");
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink("/dev/zero", &link).expect("symlink");
        let e = Sky::parse(&link.display().to_string(), None).expect_err("a device");
        assert!(
            matches!(e, SceneError::Texture { ref what, .. } if what.contains("not a regular file")),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn parses_the_cli_forms() {
        assert_eq!(
            Sky::parse("2", None).expect("grey"),
            Sky::Uniform { radiance: [2.0; 3] }
        );
        assert_eq!(
            Sky::parse("0.1, 0.2,0.3", None).expect("rgb"),
            Sky::Uniform {
                radiance: [0.1, 0.2, 0.3]
            }
        );
        assert_eq!(
            Sky::parse("gradient:1,2,3/0.5", None).expect("gradient"),
            Sky::Gradient {
                zenith: [1.0, 2.0, 3.0],
                horizon: [0.5; 3]
            }
        );
        for bad in ["-1", "nan", "1,2", "gradient:1", "blue", "missing.hdr"] {
            assert!(Sky::parse(bad, None).is_err(), "{bad}");
        }
    }

    #[test]
    fn gradient_blends_in_elevation() {
        let sky = Sky::Gradient {
            zenith: [1.0; 3],
            horizon: [0.0; 3],
        };
        assert_eq!(sky.radiance(DVec3::Y), [1.0; 3]);
        assert_eq!(sky.radiance(DVec3::NEG_Y), [0.0; 3]);
        assert!((sky.radiance(DVec3::new(0.0, 0.5, 0.75f64.sqrt()))[0] - 0.5).abs() < 1e-12);
    }

    #[test]
    fn extras_read_objects_and_strings() {
        let v = serde_json::json!({"zenith": [1, 1, 1], "horizon": [0, 0, 0]});
        assert!(matches!(
            Sky::from_extras(&v, None),
            Ok(Some(Sky::Gradient { .. }))
        ));
        let v = serde_json::json!("none");
        assert!(matches!(Sky::from_extras(&v, None), Ok(None)));
        let v = serde_json::json!({"radiance": [1, -1, 1]});
        assert!(Sky::from_extras(&v, None).is_err());
        let v = serde_json::json!(3);
        assert!(Sky::from_extras(&v, None).is_err());
    }
}
