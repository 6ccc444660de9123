//! What a bake can be told, and the checks that refuse bad settings before anything is spent.

use std::time::Duration;

use crate::form_factors::{FormFactorKind, FormFactorParams};
use crate::links::LinkParams;
use crate::mesh::MeshParams;
use crate::solvers::{SolverKind, SolverParams};
use crate::{BakeError, ParameterError};

/// Everything a bake can be told. `Default` gives the settings the accuracy tests hold to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BakeParams {
    /// Meshing (patch size, element levels).
    pub mesh: MeshParams,
    /// The form-factor method (default: analytic).
    pub form_factors: FormFactorKind,
    /// Form-factor parameters (hemicube resolution, ray counts, seed).
    pub ff: FormFactorParams,
    /// Link refinement.
    pub links: LinkParams,
    /// The solver (default: Gauss–Seidel).
    pub solver: SolverKind,
    /// Solver parameters (tolerance etc.).
    pub solver_params: SolverParams,
    /// Stop solving after this long (solve phase only), converged or not (default: none).
    pub time_limit: Option<Duration>,
    /// Length of one solver step between progress reports (default: 25 ms).
    pub step_budget: Duration,
}

impl Default for BakeParams {
    fn default() -> Self {
        BakeParams {
            mesh: MeshParams::default(),
            form_factors: FormFactorKind::Analytic,
            ff: FormFactorParams::default(),
            links: LinkParams::default(),
            solver: SolverKind::GaussSeidel,
            solver_params: SolverParams::default(),
            time_limit: None,
            step_budget: Duration::from_millis(25),
        }
    }
}

impl BakeParams {
    /// Refuses settings no bake can use (a non-positive tolerance or refinement, a negative
    /// far field), naming the setting.
    pub fn check(&self) -> Result<(), BakeError> {
        let tolerance = self.solver_params.tolerance;
        if !(tolerance.is_finite() && tolerance > 0.0) {
            return Err(ParameterError::out_of_range("tolerance", tolerance, "(0, inf)").into());
        }
        if !(self.links.far_field.is_finite() && self.links.far_field >= 0.0) {
            let far = self.links.far_field;
            return Err(ParameterError::out_of_range("far field", far, "[0, inf)").into());
        }
        if !(self.links.refinement.is_finite() && self.links.refinement > 0.0) {
            let refinement = self.links.refinement;
            return Err(ParameterError::out_of_range("refinement", refinement, "(0, inf)").into());
        }
        Ok(())
    }
}
