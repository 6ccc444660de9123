//! Finite-element radiosity on the CPU: meshing, form factors, hierarchical links, solvers,
//! error metrics and light maps. No GPU, no ECS.
//!
//! The conventions (see `ARCHITECTURE.md`): `F_ij` is the fraction of the energy leaving element
//! `i` that arrives at element `j` (reciprocity: `A_i F_ij = A_j F_ji`), and `i` gathers `j`'s
//! radiosity with it: `B_i = S_i + ρ_i Σ_j F_ij B_j`, with radiosity in glTF emissive units (a
//! lone emitter of emissive 1 outputs 1).
//!
//! ```
//! use radiant_radiosity::{Bake, BakeParams};
//! let scene = radiant_scene::builtin("cornell-box").unwrap();
//! let mut params = BakeParams::default();
//! params.mesh.patch_size = 0.2; // coarse, for the example
//! let result = Bake::new(&scene, &params).unwrap().run_to_end(&mut |_| {}).unwrap();
//! let floor = result.surfaces.iter().find(|s| s.name == "floor").unwrap();
//! assert!(floor.mean[0] > 0.05 && floor.mean[0] < 0.3);
//! ```

#![expect(
    clippy::needless_range_loop,
    reason = "RGB channel loops index several arrays at once; iterators would hide that"
)]

pub mod bake;
pub mod checkpoint;
pub mod cluster;
pub mod exposure;
pub mod final_gather;
pub mod form_factors;
pub mod hierarchy;
pub mod input;
pub mod lightmap;
pub mod lights;
pub mod links;
pub mod mesh;
pub mod metrics;
pub mod params;
pub mod points;
pub mod report;
pub mod rng;
pub mod scenes;
pub mod smooth;
pub mod solve;
pub mod solvers;
pub mod spectral;
pub mod system;
pub mod texel_light;

pub use bake::{Bake, BakeEvent};
pub use form_factors::{FormFactorKind, FormFactorParams};
pub use links::LinkParams;
pub use mesh::{Mesh, MeshParams};
pub use params::BakeParams;
pub use report::{BakeReport, BakeResult, PhaseTimes, TimelinePoint};
pub use solve::{Info, Solve, SolveError, Stall, eta_seconds};
pub use solvers::{Solver, SolverKind, SolverParams};
pub use system::{Rgb, System};

/// Why a scene cannot be baked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// A triangle names a surface index past the surface list.
    #[error("triangle {triangle} names surface {surface}, but the scene has {surfaces} surfaces")]
    UnknownSurface {
        /// The triangle.
        triangle: usize,
        /// The surface index it names.
        surface: usize,
        /// Surfaces in the scene.
        surfaces: usize,
    },
    /// A triangle with a NaN or infinite vertex.
    #[error("triangle {triangle} has a vertex that is not finite")]
    NonFiniteVertex {
        /// The triangle.
        triangle: usize,
    },
    /// Nothing to bake.
    #[error("the scene has no triangles")]
    NoTriangles,
    /// Every vertex at one point.
    #[error("the scene has zero extent")]
    ZeroExtent,
}

/// What is wrong with a surface's material.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaterialError {
    /// Reflectance outside [0, 1] or not finite.
    #[error("reflectance {0:?} is outside [0, 1]")]
    Reflectance(Rgb),
    /// Emission negative or not finite.
    #[error("emission {0:?} is negative or not finite")]
    Emission(Rgb),
    /// The spectral solve has no spectra for the surface's material.
    #[error("no spectral data for material '{0}'")]
    NoSpectrum(String),
    /// A band of the spectral reflectance outside [0, 1].
    #[error("spectral reflectance {value} outside [0, 1] in band {band}")]
    SpectralReflectance {
        /// The band.
        band: usize,
        /// Its mean reflectance.
        value: f64,
    },
    /// An emitter whose emission spectrum has no luminance to scale to its RGB emission.
    #[error("emission spectrum has no luminance")]
    DarkEmission,
}

/// A bake parameter no bake can use.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParameterError {
    /// A number outside its range.
    #[error("{name} = {value} is outside its range {range}")]
    OutOfRange {
        /// The parameter, as the CLI names it.
        name: &'static str,
        /// The value given.
        value: f64,
        /// The valid range.
        range: &'static str,
    },
    /// A light with a non-finite or negative value.
    #[error("light '{light}' has a non-finite or negative value")]
    BadLight {
        /// The light's name.
        light: String,
    },
    /// An edit that changes the number of surfaces.
    #[error("an edit must keep the {expected} surfaces ({given} given)")]
    SurfaceCount {
        /// Surfaces of the bake.
        expected: usize,
        /// Surfaces of the edit.
        given: usize,
    },
    /// A form-factor method the hierarchy does not compute.
    #[error(
        "the clustered hierarchy computes form factors analytic or ray-cast, not {method}: use --hierarchy triangles for it"
    )]
    FormFactors {
        /// The method asked for.
        method: &'static str,
    },
}

impl ParameterError {
    /// `name = value` outside `range`.
    pub fn out_of_range(name: &'static str, value: f64, range: &'static str) -> Self {
        Self::OutOfRange { name, value, range }
    }
}

/// Errors from baking. Each says what to change.
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    /// The scene cannot be baked as given.
    #[error("invalid scene: {0}")]
    InvalidScene(#[from] SceneError),
    /// A material value is out of range.
    #[error("surface '{surface}': {what}")]
    InvalidMaterial {
        /// The surface name.
        surface: String,
        /// What is wrong.
        what: MaterialError,
    },
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(#[from] ParameterError),
    /// The patch size would create too many elements.
    #[error("{elements} elements exceed the limit of {limit}: use a larger --patch-size")]
    TooManyElements {
        /// Elements the patch size would create.
        elements: usize,
        /// The limit.
        limit: usize,
    },
    /// The direct solver's dense matrix would be too large.
    #[error(
        "the direct solver is limited to {limit} elements ({elements} here): use an iterative method or a larger --patch-size"
    )]
    TooLargeForDirect {
        /// Elements in the system.
        elements: usize,
        /// The limit.
        limit: usize,
    },
    /// The solve could not go on: singular, diverged, stalled, or out of memory
    /// ([`SolveError`]).
    #[error(transparent)]
    Solve(#[from] SolveError),
    /// An edit needs links the bake does not have (it had no emitters): bake again.
    #[error("the edit adds emitters to a bake that had none: bake again")]
    NeedsRebuild,
    /// A reference file could not be used.
    #[error("reference: {0}")]
    Reference(#[from] metrics::ReferenceFileError),
    /// The bake would need more memory than its budget (`--memory-limit`), even at the
    /// coarsest thresholds it may use. Nothing of that size was allocated.
    #[error(
        "{what} need {} MiB, over the memory limit of {} MiB: raise --memory-limit, or use a larger --patch-size or --refinement",
        needed / (1 << 20),
        limit / (1 << 20)
    )]
    OutOfMemory {
        /// What would not fit.
        what: &'static str,
        /// Bytes it would need (at least).
        needed: u64,
        /// The budget in bytes (0: the allocator itself refused).
        limit: u64,
    },
    /// A checkpoint could not be written, read, or does not fit this scene.
    #[error("checkpoint: {0}")]
    Checkpoint(#[from] checkpoint::CheckpointError),
    /// A checkpoint of the other hierarchy (a per-triangle bake's, version 1 or 2, read by a
    /// clustered bake, or the reverse): nothing is wrong with the file, but this bake cannot
    /// use it. Bake again (the new bake writes its own).
    #[error(
        "checkpoint {path}: written by the {found} hierarchy (version {version}), this bake uses the {needed} one: rebake"
    )]
    CheckpointHierarchy {
        /// The file.
        path: String,
        /// The file's format version.
        version: u8,
        /// The hierarchy that wrote it.
        found: &'static str,
        /// The hierarchy of this bake.
        needed: &'static str,
    },
    /// The caller stopped the bake (a clustered bake's [`cluster::Watch::stop`]).
    #[error("the bake was stopped before it finished")]
    Stopped,
}

#[cfg(test)]
pub(crate) mod testing {
    use glam::DVec3;

    /// The unit cube's 12 triangles, facing inward.
    pub fn unit_cube_inward() -> Vec<[DVec3; 3]> {
        crate::scenes::box_triangles(DVec3::ZERO, DVec3::ONE, true)
    }
}
