//! The solve, in the shape of faer's iterative solvers (`Params`, `Info`, `Error`): each step
//! returns what it reached ([`Info`]: iterations, residual, estimated error, progress) or why it
//! cannot go on ([`SolveError`]: stalled, diverged, singular, out of memory). [`Solve`] wraps a
//! [`Solver`] with the one stopping rule ([`Stall`]) that the bake, the clustered bake, the
//! spectral solve, the CLI and the ECS worker all read.

use std::time::Duration;

use crate::solvers::{Solver, SolverKind, SolverParams, new_solver};
use crate::system::{Rgb, System};

/// Where a solve stands after a step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Info {
    /// Sweeps (Jacobi, Gauss–Seidel), shots (Southwell) or 1 (direct).
    pub iterations: u64,
    /// Relative residual (see [`crate::solvers`]).
    pub residual: f64,
    /// Estimated relative error of the solution: the residual divided by `1 − ρ̂`
    /// ([`System::contraction`]), or the clustered bake's `update × q / (1 − q)`.
    pub estimated_error: f64,
    /// Progress toward the tolerance in [0, 1], in log error: 0 at an error of 1, 1 at the
    /// tolerance.
    pub progress: f64,
    /// Unshot energy fraction.
    pub unshot_fraction: f64,
    /// Whether the tolerance is met.
    pub converged: bool,
}

impl Info {
    /// An info from a relative residual: the estimated error is `residual / (1 − contraction)`.
    pub fn from_residual(
        iterations: u64,
        residual: f64,
        unshot_fraction: f64,
        contraction: f64,
        tolerance: f64,
        converged: bool,
    ) -> Info {
        let estimated_error = residual / (1.0 - contraction).clamp(1e-9, 1.0);
        Info {
            iterations,
            residual,
            estimated_error,
            progress: progress(estimated_error, tolerance, converged),
            unshot_fraction,
            converged,
        }
    }

    /// The info of a bake with nothing to solve (no emitters): done at once.
    pub fn nothing_to_solve() -> Info {
        Info {
            iterations: 0,
            residual: 0.0,
            estimated_error: 0.0,
            progress: 1.0,
            unshot_fraction: 0.0,
            converged: true,
        }
    }
}

/// Progress in log error, from an error of 1 (0) down to the tolerance (1).
pub fn progress(estimated_error: f64, tolerance: f64, converged: bool) -> f64 {
    if converged || estimated_error <= 0.0 {
        1.0
    } else if estimated_error.is_finite() && tolerance > 0.0 && tolerance < 1.0 {
        (estimated_error.ln() / tolerance.ln()).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// Seconds until the estimated error reaches `tolerance` at the rate of the last eight steps
/// of `history` (`(seconds, estimated error)` after each step; convergence is log-linear), or
/// `None` while the rate cannot be told (fewer than three steps, or no progress).
pub fn eta_seconds(history: &[(f64, f64)], tolerance: f64) -> Option<f64> {
    let n = history.len();
    if n < 3 {
        return None;
    }
    let (t0, e0) = history[n.saturating_sub(8)];
    let (t1, e1) = history[n - 1];
    if e1 <= tolerance {
        return Some(0.0);
    }
    let rate = (e0.ln() - e1.ln()) / (t1 - t0).max(1e-9);
    let eta = (e1.ln() - tolerance.ln()) / rate;
    (rate > 0.0 && eta.is_finite()).then_some(eta)
}

/// Why a solve cannot go on.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
pub enum SolveError {
    /// The residual has not fallen by [`Stall::GAIN`] over [`Stall::STEPS`] steps: reflectance
    /// 1 in a closed scene, say. The solution so far is finite and can be used.
    #[error(
        "the solver stopped converging (residual {residual:.2e}, no progress in {steps} steps); reflectance 1 in a closed scene?"
    )]
    Stalled {
        /// The residual when it gave up.
        residual: f64,
        /// Steps without progress.
        steps: u32,
    },
    /// The residual became infinite or NaN.
    #[error("the solve diverged (residual {residual} after {iterations} iterations)")]
    Diverged {
        /// The residual.
        residual: f64,
        /// Iterations when it did.
        iterations: u64,
    },
    /// The system has no unique solution (reflectance 1 in a closed scene).
    #[error("the radiosity system is singular (reflectance 1 in a closed scene?)")]
    Singular,
    /// The solver's buffers would exceed what it may allocate.
    #[error(
        "{what}: {} MiB needed, over the limit of {} MiB: use an iterative method or a larger --patch-size",
        needed / (1 << 20),
        limit / (1 << 20)
    )]
    OutOfMemory {
        /// What would not fit.
        what: &'static str,
        /// Bytes it would need.
        needed: u64,
        /// The limit in bytes.
        limit: u64,
    },
}

/// The stopping rule: a solve that has not lowered its best residual by 1 % ([`Stall::GAIN`])
/// for [`Stall::STEPS`] steps has stalled, and a non-finite residual has diverged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stall {
    best: f64,
    since_best: u32,
}

impl Default for Stall {
    fn default() -> Self {
        Stall {
            best: f64::INFINITY,
            since_best: 0,
        }
    }
}

impl Stall {
    /// Steps without progress after which a solve has stalled.
    pub const STEPS: u32 = 200;
    /// A step makes progress when its residual is below this times the best so far.
    pub const GAIN: f64 = 0.99;

    /// Records a step's residual.
    pub fn observe(&mut self, residual: f64, iterations: u64) -> Result<(), SolveError> {
        if !residual.is_finite() {
            return Err(SolveError::Diverged {
                residual,
                iterations,
            });
        }
        if residual < Self::GAIN * self.best {
            (self.best, self.since_best) = (residual, 0);
        } else {
            self.since_best += 1;
        }
        if self.since_best >= Self::STEPS {
            return Err(SolveError::Stalled {
                residual,
                steps: self.since_best,
            });
        }
        Ok(())
    }
}

/// A solver with the stopping rule: what [`crate::Bake`] and the spectral solve step.
pub struct Solve {
    solver: Box<dyn Solver>,
    params: SolverParams,
    stall: Stall,
    last: Option<Info>,
    solving: Duration,
}

impl Solve {
    /// Starts `kind` on `sys` from `B = S`.
    pub fn new(kind: SolverKind, sys: &System, params: SolverParams) -> Solve {
        Solve {
            solver: new_solver(kind, sys, params),
            params,
            stall: Stall::default(),
            last: None,
            solving: Duration::ZERO,
        }
    }

    /// Works for about `budget` (at least one unit of work). A step that stalls or diverges is
    /// an error; the solution is left as it was, and [`Solve::radiosity`] still reads it.
    pub fn step(&mut self, sys: &System, budget: Duration) -> Result<Info, SolveError> {
        let t = std::time::Instant::now();
        let info = self.solver.step(sys, budget);
        self.solving += t.elapsed();
        let info = info?;
        self.last = Some(info);
        if !info.converged {
            self.stall.observe(info.residual, info.iterations)?;
        } else if !info.residual.is_finite() {
            return Err(SolveError::Diverged {
                residual: info.residual,
                iterations: info.iterations,
            });
        }
        Ok(info)
    }

    /// Continues from `b` on a changed system (see [`Solver::warm_start`]); the stopping rule
    /// starts over.
    pub fn warm_start(&mut self, sys: &System, b: &[Rgb]) {
        self.solver.warm_start(sys, b);
        self.stall = Stall::default();
        self.last = None;
    }

    /// Starts the same solver afresh on another system (other links: a geometry edit) from
    /// `b`; the time spent so far is kept.
    pub fn restart(&mut self, sys: &System, b: &[Rgb]) {
        self.solver = new_solver(self.solver.kind(), sys, self.params);
        self.warm_start(sys, b);
    }

    /// The current estimate per element.
    pub fn radiosity(&self, sys: &System) -> Vec<Rgb> {
        self.solver.radiosity(sys)
    }

    /// The latest step's info (none since the start or a warm start).
    pub fn last(&self) -> Option<Info> {
        self.last
    }

    /// Time spent in steps.
    pub fn solving(&self) -> Duration {
        self.solving
    }

    /// Which solver.
    pub fn kind(&self) -> SolverKind {
        self.solver.kind()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_residual_that_stops_falling_stalls_after_the_rule_s_steps() {
        let mut s = Stall::default();
        assert!(s.observe(1.0, 1).is_ok());
        for k in 0..Stall::STEPS - 1 {
            assert!(s.observe(0.995, u64::from(k) + 2).is_ok(), "step {k}");
        }
        assert_eq!(
            s.observe(0.995, 1000),
            Err(SolveError::Stalled {
                residual: 0.995,
                steps: Stall::STEPS
            })
        );
        // Progress of more than 1 % resets the count.
        let mut s = Stall::default();
        for k in 0..10 * Stall::STEPS {
            assert!(s.observe(0.98f64.powi(k as i32), 1).is_ok());
        }
        assert!(matches!(
            s.observe(f64::NAN, 7),
            Err(SolveError::Diverged { iterations: 7, .. })
        ));
    }

    #[test]
    fn progress_runs_in_log_error_from_one_to_the_tolerance() {
        assert_eq!(progress(1.0, 1e-4, false), 0.0);
        assert!((progress(1e-2, 1e-4, false) - 0.5).abs() < 1e-12);
        assert_eq!(progress(1e-5, 1e-4, false), 1.0);
        assert_eq!(progress(f64::INFINITY, 1e-4, false), 0.0);
        assert_eq!(progress(0.5, 1e-4, true), 1.0);
        let i = Info::from_residual(3, 1e-3, 0.0, 0.9, 1e-4, false);
        assert!((i.estimated_error - 1e-2).abs() < 1e-12);
    }

    #[test]
    fn the_eta_follows_the_log_linear_rate() {
        // The error falls tenfold a second: from 1e-2 at t = 4 s, 1e-4 is 2 s away.
        let h: Vec<(f64, f64)> = (0..5).map(|k| (f64::from(k), 10f64.powi(2 - k))).collect();
        let eta = eta_seconds(&h, 1e-4).expect("a rate");
        assert!((eta - 2.0).abs() < 1e-9, "{eta}");
        assert_eq!(eta_seconds(&h[..2], 1e-4), None);
        assert_eq!(eta_seconds(&h, 1.0), Some(0.0));
        let flat = [(0.0, 0.5), (1.0, 0.5), (2.0, 0.5)];
        assert_eq!(eta_seconds(&flat, 1e-4), None);
    }
}
