//! Radiant: diffuse global illumination by finite-element radiosity, baked into light maps, for
//! game prototypes and editors.
//!
//! This facade re-exports the workspace's crates:
//! - [`scene`]: glTF import with validation, the builtin Cornell box;
//! - [`radiosity`]: meshing, form factors, solvers, error metrics, light maps (pure CPU);
//! - [`color`]: sRGB transfer functions and tone-map operators.
//!
//! ```
//! use radiant::radiosity::{Bake, BakeParams};
//! let scene = radiant::scene::builtin("cornell-box").unwrap();
//! let mut params = BakeParams::default();
//! params.mesh.patch_size = 0.3; // coarse, for the example
//! let result = Bake::new(&scene, &params).unwrap().run_to_end(&mut |_| {}).unwrap();
//! assert!(result.report.converged);
//! ```

pub use radiant_color as color;
pub use radiant_radiosity as radiosity;
pub use radiant_scene as scene;
