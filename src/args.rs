//! Typed values of the command line: the library's own enums as clap `ValueEnum`s (their
//! names are the library's `name()`, their variants its `ALL`, their aliases its `ALIASES`),
//! the bake's method (a solver, or the GPU gather), the link hierarchy and the reference.
//! Nothing here restates a name or a default the library has.

use std::path::PathBuf;
use std::sync::OnceLock;

use clap::ValueEnum;
use clap::builder::PossibleValue;
use radiant::radiosity::{FormFactorKind, SolverKind};

/// A newtype over a library enum with `ALL` and `name()` (and `ALIASES`, when given) that clap
/// parses as a value enum.
macro_rules! library_value {
    ($(#[$doc:meta])* $arg:ident($lib:ty) $(, aliases = $aliases:expr)?) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq)]
        pub(crate) struct $arg(pub(crate) $lib);

        impl ValueEnum for $arg {
            fn value_variants<'a>() -> &'a [Self] {
                static ALL: OnceLock<Vec<$arg>> = OnceLock::new();
                ALL.get_or_init(|| <$lib>::ALL.into_iter().map($arg).collect())
            }

            fn to_possible_value(&self) -> Option<PossibleValue> {
                #[allow(unused_mut, reason = "mutated only when the enum has aliases")]
                let mut v = PossibleValue::new(self.0.name());
                $(for (alias, kind) in $aliases {
                    if *kind == self.0 {
                        v = v.alias(*alias);
                    }
                })?
                Some(v)
            }
        }
    };
}

library_value!(
    /// `--form-factors`: a form-factor method.
    FormFactors(FormFactorKind),
    aliases = FormFactorKind::ALIASES
);

library_value!(
    /// A solver of the per-triangle bake.
    Solver(SolverKind),
    aliases = SolverKind::ALIASES
);

library_value!(
    /// `--builtin`: a builtin scene.
    BuiltinScene(radiant::scene::Builtin),
    aliases = radiant::scene::Builtin::ALIASES
);

#[cfg(feature = "render")]
library_value!(
    /// `--tonemap`: a tone-mapping operator.
    Tonemap(radiant::color::Tonemap),
    aliases = radiant::color::Tonemap::ALIASES
);

#[cfg(feature = "render")]
library_value!(
    /// `--debug`: what the lighting pass shows.
    Debug(radiant::render::lighting::DebugView)
);

/// `--method`, `--methods`: a solver, or the GPU hemicube gather (no form factors).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Method {
    Solver(SolverKind),
    GpuHemicube,
}

impl Method {
    /// The name of the GPU gather.
    pub(crate) const GPU_HEMICUBE: &str = "gpu-hemicube";

    /// The solver, unless this is the GPU gather.
    pub(crate) fn solver(self) -> Option<SolverKind> {
        match self {
            Method::Solver(s) => Some(s),
            Method::GpuHemicube => None,
        }
    }
}

impl ValueEnum for Method {
    fn value_variants<'a>() -> &'a [Self] {
        static ALL: OnceLock<Vec<Method>> = OnceLock::new();
        ALL.get_or_init(|| {
            (SolverKind::ALL.into_iter().map(Method::Solver))
                .chain([Method::GpuHemicube])
                .collect()
        })
    }

    fn to_possible_value(&self) -> Option<PossibleValue> {
        match self {
            Method::Solver(s) => Solver(*s).to_possible_value(),
            Method::GpuHemicube => Some(PossibleValue::new(Self::GPU_HEMICUBE)),
        }
    }
}

/// `--hierarchy`: which link hierarchy bakes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, ValueEnum)]
pub(crate) enum Hierarchy {
    /// Clustered for a level (`radiosity::cluster::is_level`) when no option needs the
    /// per-triangle bake.
    #[default]
    Auto,
    /// Volume clusters above the triangles, links at any level on both ends.
    Clustered,
    /// Every element gathers from a per-triangle hierarchy.
    Triangles,
}

impl From<Hierarchy> for radiant::radiosity::cluster::Hierarchy {
    fn from(h: Hierarchy) -> Self {
        match h {
            Hierarchy::Auto => Self::Auto,
            Hierarchy::Clustered => Self::Clustered,
            Hierarchy::Triangles => Self::Triangles,
        }
    }
}

/// `converge --reference`: what the error is measured against.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Reference {
    /// Path-trace the scene first (total error).
    Path,
    /// The direct solve on the same mesh (solver error only).
    Direct,
    /// A per-surface CSV (total error).
    File(PathBuf),
}

/// Parses `path`, `direct` or a file name.
pub(crate) fn parse_reference(s: &str) -> Result<Reference, String> {
    Ok(match s {
        "path" => Reference::Path,
        "direct" => Reference::Direct,
        "" => return Err("give path, direct or a per-surface CSV file".into()),
        file => Reference::File(PathBuf::from(file)),
    })
}

/// `--texel-density`: a positive, finite number of texels per scene unit.
pub(crate) fn parse_texel_density(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(d) if d.is_finite() && d > 0.0 => Ok(d),
        _ => Err(format!(
            "{s:?} is not a positive number of texels per scene unit"
        )),
    }
}

/// `--probe-spacing`: a positive, finite distance in scene units.
pub(crate) fn parse_spacing(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(d) if d.is_finite() && d > 0.0 => Ok(d),
        _ => Err(format!("{s:?} is not a positive distance in scene units")),
    }
}

/// `4G`, `512M`, `64K` or a number of bytes.
pub(crate) fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (num, mul) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() => {
            let mul: u64 = match c.to_ascii_uppercase() {
                'K' => 1 << 10,
                'M' => 1 << 20,
                'G' => 1 << 30,
                'T' => 1 << 40,
                _ => return Err(format!("'{s}': use a number with K, M, G or T")),
            };
            (&t[..i], mul)
        }
        _ => (t, 1),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a size (e.g. 4G, 512M)"))?;
    let bytes = v * mul as f64;
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!("'{s}' is not a size between 1 byte and 16 EiB"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_are_the_library_s_names_and_aliases() {
        for k in SolverKind::ALL {
            assert_eq!(Method::from_str(k.name(), false), Ok(Method::Solver(k)));
        }
        assert_eq!(
            Method::from_str("progressive", false),
            Ok(Method::Solver(SolverKind::Southwell))
        );
        assert_eq!(
            Method::from_str("gpu-hemicube", false),
            Ok(Method::GpuHemicube)
        );
        assert!(Method::from_str("magic", false).is_err());
        for k in FormFactorKind::ALL {
            assert_eq!(FormFactors::from_str(k.name(), false), Ok(FormFactors(k)));
        }
        assert_eq!(
            FormFactors::from_str("ray-cast", false),
            Ok(FormFactors(FormFactorKind::RayCast))
        );
        assert_eq!(parse_reference("direct"), Ok(Reference::Direct));
        assert_eq!(
            parse_reference("a.csv"),
            Ok(Reference::File(PathBuf::from("a.csv")))
        );
    }
}
