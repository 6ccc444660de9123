//! Solvers for the radiosity system, each steppable within a time budget so a caller (the CLI's
//! progress bar, an ECS system) can run it in slices: `step(budget) -> Info` (see
//! [`crate::solve`], which adds the stopping rule).
//!
//! - [`Jacobi`]: the lecture's iterative loop, `B ← S + ρ K B`, parallel over elements.
//! - [`GaussSeidel`]: the same sweep using each new value at once.
//! - [`Southwell`]: progressive shooting (Cohen et al. 1988) of the **unshot** radiosity, in
//!   blocks of one input triangle's elements, with Feda & Purgathofer's overshooting and Cohen's
//!   ambient term for display. Receiver `i` of shooter `j` gets `ρ_i F_ij ΔB_j` (gathering
//!   form factors, so no area ratio and no `B_j`: the lecture's pseudo-code is wrong there).
//! - [`Direct`]: dense LU (`faer`) of `(I − diag(ρ) K) B = S`: the small-N reference.
//!
//! All accumulate in `f64`. The residual `r = S + ρKB − B` is reported as the area-weighted
//! L2 norm relative to `B`; the unshot fraction is `‖r‖₁ / ‖S‖₁` (area-weighted, all channels).
//! Southwell reports its unshot radiosity `‖ΔB‖ / ‖B‖` instead, which is the residual of its
//! relaxed iterate (not of the displayed one, which already includes what was received) and
//! costs nothing to keep; it stops on the unshot fraction.

use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::solve::{Info, SolveError};
use crate::system::{Rgb, System};

/// The solvers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SolverKind {
    /// Jacobi iteration.
    Jacobi,
    /// Gauss–Seidel iteration.
    GaussSeidel,
    /// Progressive shooting (Southwell relaxation).
    Southwell,
    /// Dense direct solve.
    Direct,
}

impl SolverKind {
    /// All solvers, in report order.
    pub const ALL: [SolverKind; 4] = [
        Self::Jacobi,
        Self::GaussSeidel,
        Self::Southwell,
        Self::Direct,
    ];

    /// The CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Jacobi => "jacobi",
            Self::GaussSeidel => "gauss-seidel",
            Self::Southwell => "southwell",
            Self::Direct => "direct",
        }
    }

    /// Other names each solver is known by.
    pub const ALIASES: &[(&str, SolverKind)] = &[
        ("progressive", Self::Southwell),
        ("shooting", Self::Southwell),
        ("gs", Self::GaussSeidel),
        ("gauss_seidel", Self::GaussSeidel),
        ("gaussseidel", Self::GaussSeidel),
    ];

    /// Parses a CLI name or an alias.
    pub fn parse(s: &str) -> Option<Self> {
        (Self::ALL.into_iter().find(|k| k.name() == s))
            .or_else(|| Self::ALIASES.iter().find(|(a, _)| *a == s).map(|&(_, k)| k))
    }
}

/// Solver parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolverParams {
    /// Converged when the estimated relative error, the relative residual divided by
    /// `1 − ρ̂` ([`System::contraction`]), falls to this (default: 1e-4). Dividing by `1 − ρ̂`
    /// keeps stiff scenes (reflectance near 1) from stopping early.
    pub tolerance: f64,
    /// Southwell: overshoot by the expected ambient (default: true).
    pub overshoot: bool,
    /// Southwell: add Cohen's ambient term to the displayed radiosity (default: true).
    pub ambient: bool,
    /// Direct: refuse more elements than this (default: 4096; memory is 8 N² bytes).
    pub max_direct: usize,
}

impl Default for SolverParams {
    fn default() -> Self {
        SolverParams {
            tolerance: 1e-4,
            overshoot: true,
            ambient: true,
            max_direct: 4096,
        }
    }
}

/// A radiosity solver.
pub trait Solver: Send + Sync {
    /// Which solver.
    fn kind(&self) -> SolverKind;
    /// Works for about `budget` (at least one unit of work), then reports.
    fn step(&mut self, sys: &System, budget: Duration) -> Result<Info, SolveError>;
    /// The current estimate per element, as it should be displayed.
    fn radiosity(&self, sys: &System) -> Vec<Rgb>;
    /// Continues from `b` on a changed system (same links, other materials): iterative
    /// solvers start from `b`; Southwell shoots the residual `S + ρKb − b`, negative energy
    /// included (George, Sillion & Greenberg 1990); the direct solver solves again.
    fn warm_start(&mut self, sys: &System, b: &[Rgb]);
}

/// Creates a solver, starting from `B = S`.
pub fn new_solver(kind: SolverKind, sys: &System, params: SolverParams) -> Box<dyn Solver> {
    match kind {
        SolverKind::Jacobi => Box::new(Jacobi::new(sys, params)),
        SolverKind::GaussSeidel => Box::new(GaussSeidel::new(sys, params)),
        SolverKind::Southwell => Box::new(Southwell::new(sys, params)),
        SolverKind::Direct => Box::new(Direct::new(params)),
    }
}

fn l1(sys: &System, v: &[Rgb]) -> f64 {
    v.iter()
        .zip(&sys.area)
        .map(|(x, a)| a * (x[0].abs() + x[1].abs() + x[2].abs()))
        .sum()
}

/// The residual threshold that meets an error tolerance: `tol × (1 − ρ̂)`.
fn residual_target(sys: &System, tol: f64) -> f64 {
    tol * (1.0 - sys.contraction()).clamp(1e-9, 1.0)
}

fn progress_from_residual(
    sys: &System,
    b: &[Rgb],
    r: &[Rgb],
    iterations: u64,
    tolerance: f64,
) -> Info {
    let tol = residual_target(sys, tolerance);
    let (rn, bn) = (sys.norm(r), sys.norm(b));
    let residual = if bn > 0.0 {
        rn / bn
    } else if rn > 0.0 {
        f64::INFINITY
    } else {
        0.0
    };
    let sp = sys.source_power();
    let unshot_fraction = if sp > 0.0 { l1(sys, r) / sp } else { 0.0 };
    Info::from_residual(
        iterations,
        residual,
        unshot_fraction,
        sys.contraction(),
        tolerance,
        residual <= tol,
    )
}

/// Jacobi iteration.
pub struct Jacobi {
    b: Vec<Rgb>,
    nodes: Vec<Rgb>,
    iterations: u64,
    params: SolverParams,
}

impl Jacobi {
    /// Starts from `B = S`.
    pub fn new(sys: &System, params: SolverParams) -> Self {
        Jacobi {
            b: sys.source.clone(),
            nodes: vec![[0.0; 3]; sys.node_area.len()],
            iterations: 0,
            params,
        }
    }
}

impl Solver for Jacobi {
    fn kind(&self) -> SolverKind {
        SolverKind::Jacobi
    }
    fn step(&mut self, sys: &System, budget: Duration) -> Result<Info, SolveError> {
        let start = Instant::now();
        loop {
            sys.pull(&self.b, &mut self.nodes);
            let nodes = &self.nodes;
            let next: Vec<Rgb> = (0..sys.len())
                .into_par_iter()
                .map(|i| {
                    let g = sys.gather(i, nodes);
                    std::array::from_fn(|c| sys.source[i][c] + sys.rho[i][c] * g[c])
                })
                .collect();
            // The change is exactly the residual of the previous iterate.
            let r: Vec<Rgb> = next
                .iter()
                .zip(&self.b)
                .map(|(n, o)| std::array::from_fn(|c| n[c] - o[c]))
                .collect();
            let p = progress_from_residual(
                sys,
                &self.b,
                &r,
                self.iterations + 1,
                self.params.tolerance,
            );
            self.b = next;
            self.iterations += 1;
            if p.converged || start.elapsed() >= budget || !p.residual.is_finite() {
                return Ok(p);
            }
        }
    }
    fn radiosity(&self, _sys: &System) -> Vec<Rgb> {
        self.b.clone()
    }
    fn warm_start(&mut self, _sys: &System, b: &[Rgb]) {
        self.b = b.to_vec();
    }
}

/// Gauss–Seidel iteration, in element order, updating node means as it goes.
pub struct GaussSeidel {
    b: Vec<Rgb>,
    nodes: Vec<Rgb>,
    iterations: u64,
    params: SolverParams,
}

impl GaussSeidel {
    /// Starts from `B = S`.
    pub fn new(sys: &System, params: SolverParams) -> Self {
        GaussSeidel {
            b: sys.source.clone(),
            nodes: vec![[0.0; 3]; sys.node_area.len()],
            iterations: 0,
            params,
        }
    }
}

impl Solver for GaussSeidel {
    fn kind(&self) -> SolverKind {
        SolverKind::GaussSeidel
    }
    fn step(&mut self, sys: &System, budget: Duration) -> Result<Info, SolveError> {
        let start = Instant::now();
        loop {
            // Fresh means each sweep, so rounding in the incremental updates cannot drift.
            sys.pull(&self.b, &mut self.nodes);
            for i in 0..sys.len() {
                let g = sys.gather(i, &self.nodes);
                let new: Rgb = std::array::from_fn(|c| sys.source[i][c] + sys.rho[i][c] * g[c]);
                let d: Rgb = std::array::from_fn(|c| new[c] - self.b[i][c]);
                self.b[i] = new;
                let a = sys.weight[i];
                let mut n = sys.leaf_node[i];
                while n != u32::MAX && a > 0.0 {
                    let w = a / sys.node_weight[n as usize];
                    let v = &mut self.nodes[n as usize];
                    for c in 0..3 {
                        v[c] += w * d[c];
                    }
                    n = sys.node_parent[n as usize];
                }
            }
            self.iterations += 1;
            if start.elapsed() >= budget {
                break;
            }
            // Check convergence every few sweeps within a long budget.
            if self.iterations.is_multiple_of(4) {
                let r = sys.residual(&self.b);
                let p = progress_from_residual(
                    sys,
                    &self.b,
                    &r,
                    self.iterations,
                    self.params.tolerance,
                );
                if p.converged || !p.residual.is_finite() {
                    return Ok(p);
                }
            }
        }
        let r = sys.residual(&self.b);
        Ok(progress_from_residual(
            sys,
            &self.b,
            &r,
            self.iterations,
            self.params.tolerance,
        ))
    }
    fn radiosity(&self, _sys: &System) -> Vec<Rgb> {
        self.b.clone()
    }
    fn warm_start(&mut self, _sys: &System, b: &[Rgb]) {
        self.b = b.to_vec();
    }
}

/// Progressive shooting by blocks (one input triangle's elements at a time).
pub struct Southwell {
    b: Vec<Rgb>,
    unshot: Vec<Rgb>,
    /// Per input triangle: area-weighted L1 of unshot.
    power: Vec<f64>,
    /// Column index: links by source node.
    col_ptr: Vec<usize>,
    col_recv: Vec<u32>,
    col_ff: Vec<f32>,
    node_unshot: Vec<Rgb>,
    gathered: Vec<Rgb>,
    touched: Vec<u32>,
    mean_rho: Rgb,
    total_area: f64,
    shots: u64,
    params: SolverParams,
}

impl Southwell {
    /// Builds the column index and starts from `B = ΔB = S`.
    pub fn new(sys: &System, params: SolverParams) -> Self {
        let nn = sys.node_area.len();
        let mut col_ptr = vec![0usize; nn + 1];
        for &s in &sys.links.src {
            col_ptr[s as usize + 1] += 1;
        }
        for k in 0..nn {
            col_ptr[k + 1] += col_ptr[k];
        }
        let mut fill = col_ptr.clone();
        let mut col_recv = vec![0u32; sys.links.len()];
        let mut col_ff = vec![0f32; sys.links.len()];
        for i in 0..sys.len() {
            for k in sys.links.row[i]..sys.links.row[i + 1] {
                let s = sys.links.src[k] as usize;
                col_recv[fill[s]] = i as u32;
                col_ff[fill[s]] = sys.links.ff[k];
                fill[s] += 1;
            }
        }
        let total_area: f64 = sys.area.iter().sum();
        let mut mean_rho = [0.0; 3];
        for (r, a) in sys.rho.iter().zip(&sys.area) {
            for c in 0..3 {
                mean_rho[c] += r[c] * a / total_area;
            }
        }
        let mut power = vec![0.0; sys.root_nodes.len()];
        for i in 0..sys.len() {
            let s = &sys.source[i];
            power[sys.leaf_root[i] as usize] +=
                sys.weight[i] * (s[0].abs() + s[1].abs() + s[2].abs());
        }
        Southwell {
            b: sys.source.clone(),
            unshot: sys.source.clone(),
            power,
            col_ptr,
            col_recv,
            col_ff,
            node_unshot: vec![[0.0; 3]; nn],
            gathered: vec![[0.0; 3]; sys.len()],
            touched: Vec::new(),
            mean_rho,
            total_area,
            shots: 0,
            params,
        }
    }

    /// Cohen et al.'s ambient: the unshot energy, spread evenly and reflected `1/(1−ρ̄)` times.
    fn ambient(&self, sys: &System) -> Rgb {
        let mut a = [0.0; 3];
        for (u, ar) in self.unshot.iter().zip(&sys.weight) {
            for c in 0..3 {
                a[c] += u[c] * ar;
            }
        }
        std::array::from_fn(|c| a[c] / self.total_area / (1.0 - self.mean_rho[c].min(0.999_999)))
    }

    fn recount_power(&mut self, sys: &System) {
        self.power.iter_mut().for_each(|p| *p = 0.0);
        for (i, u) in self.unshot.iter().enumerate() {
            self.power[sys.leaf_root[i] as usize] +=
                sys.weight[i] * (u[0].abs() + u[1].abs() + u[2].abs());
        }
    }

    fn shoot(&mut self, sys: &System, root: usize) {
        let (lo, hi) = sys.root_nodes[root];
        let (llo, lhi) = (
            sys.node_leaf_lo[lo as usize] as usize,
            sys.node_leaf_hi[lo as usize] as usize,
        );
        // What each element shoots: its unshot radiosity, plus the overshoot.
        let amb = if self.params.overshoot {
            self.ambient(sys)
        } else {
            [0.0; 3]
        };
        let mut shot = vec![[0.0; 3]; lhi - llo];
        for (k, i) in (llo..lhi).enumerate() {
            // Overshoot (Feda & Purgathofer 1992) only what is positive and seen by others: a
            // negative residual is shot as it is, or it would be overshot back to where it was.
            let over: Rgb = std::array::from_fn(|c| {
                if self.unshot[i][c] > 0.0 && sys.weight[i] > 0.0 {
                    sys.rho[i][c] * amb[c].max(0.0)
                } else {
                    0.0
                }
            });
            shot[k] = std::array::from_fn(|c| self.unshot[i][c] + over[c]);
            // Relaxing by more than the residual leaves a negative residual; the displayed
            // estimate (relaxed plus unshot) does not change.
            for c in 0..3 {
                self.unshot[i][c] = -over[c];
            }
        }
        // Node means of what is shot, over this tree only.
        let mut full = std::mem::take(&mut self.gathered);
        for (k, i) in (llo..lhi).enumerate() {
            full[i] = shot[k];
        }
        sys.pull_range(&full, &mut self.node_unshot, lo, hi);
        for i in llo..lhi {
            full[i] = [0.0; 3];
        }
        self.gathered = full;
        for s in lo..hi {
            let d = self.node_unshot[s as usize];
            if d == [0.0; 3] {
                continue;
            }
            for k in self.col_ptr[s as usize]..self.col_ptr[s as usize + 1] {
                let i = self.col_recv[k] as usize;
                let f = f64::from(self.col_ff[k]);
                let g = &mut self.gathered[i];
                if *g == [0.0; 3] {
                    self.touched.push(i as u32);
                }
                for c in 0..3 {
                    g[c] += f * d[c];
                }
            }
        }
        let mut pw_root = 0.0;
        for i in llo..lhi {
            let u = &self.unshot[i];
            pw_root += sys.weight[i] * (u[0].abs() + u[1].abs() + u[2].abs());
        }
        self.power[root] = pw_root;
        for &i in &self.touched {
            let i = i as usize;
            let g = std::mem::replace(&mut self.gathered[i], [0.0; 3]);
            let a = sys.weight[i];
            let old = self.unshot[i];
            for c in 0..3 {
                let d = sys.rho[i][c] * g[c];
                self.b[i][c] += d;
                self.unshot[i][c] += d;
            }
            let new = self.unshot[i];
            let r = sys.leaf_root[i] as usize;
            self.power[r] += a
                * ((new[0].abs() + new[1].abs() + new[2].abs())
                    - (old[0].abs() + old[1].abs() + old[2].abs()));
        }
        self.touched.clear();
        self.shots += 1;
    }
}

impl Solver for Southwell {
    fn kind(&self) -> SolverKind {
        SolverKind::Southwell
    }
    fn step(&mut self, sys: &System, budget: Duration) -> Result<Info, SolveError> {
        let start = Instant::now();
        let sp = sys.source_power();
        let tol = residual_target(sys, self.params.tolerance);
        // At least one shot per step, however small the budget.
        let mut shot = false;
        loop {
            let mut total: f64 = self.power.iter().sum();
            let mut done = total <= tol * sp;
            if done {
                // The per-root powers are updated incrementally; before stopping, recount them
                // exactly so that rounding cannot fake convergence.
                self.recount_power(sys);
                total = self.power.iter().sum();
                done = total <= tol * sp;
            }
            let unshot_fraction = if sp > 0.0 { total / sp } else { 0.0 };
            if done || (shot && start.elapsed() >= budget) {
                let rn = sys.norm(&self.unshot);
                let bn = sys.norm(&self.b);
                let residual = if bn > 0.0 { rn / bn } else { 0.0 };
                return Ok(Info::from_residual(
                    self.shots,
                    residual,
                    unshot_fraction,
                    sys.contraction(),
                    self.params.tolerance,
                    done,
                ));
            }
            let mut best = 0;
            for (k, &p) in self.power.iter().enumerate() {
                if p > self.power[best] {
                    best = k;
                }
            }
            self.shoot(sys, best);
            shot = true;
        }
    }
    fn warm_start(&mut self, sys: &System, b: &[Rgb]) {
        // The invariant of shooting: B already holds the unshot radiosity. With the residual
        // r = S + ρKb − b (what each element lacks, given its neighbours), B = b + r and r is
        // unshot, exactly as a cold start has B = S and S unshot.
        let mut r = sys.residual(b);
        for (ri, &w) in r.iter_mut().zip(&sys.weight) {
            if w <= 0.0 {
                // Dead elements (inside closed geometry) see nothing and shoot nothing.
                *ri = [0.0; 3];
            }
        }
        self.b = b
            .iter()
            .zip(&r)
            .map(|(bi, ri)| std::array::from_fn(|c| bi[c] + ri[c]))
            .collect();
        self.unshot = r;
        self.recount_power(sys);
    }
    fn radiosity(&self, sys: &System) -> Vec<Rgb> {
        if !self.params.ambient {
            return self.b.clone();
        }
        // Overshooting can make the unshot sum negative; the display never subtracts.
        let amb = self.ambient(sys).map(|a| a.max(0.0));
        // Elements inside closed geometry see nothing, ambient included.
        self.b
            .iter()
            .zip(&sys.rho)
            .zip(&sys.weight)
            .map(|((b, r), &w)| {
                if w > 0.0 {
                    std::array::from_fn(|c| b[c] + r[c] * amb[c])
                } else {
                    *b
                }
            })
            .collect()
    }
}

/// Dense LU of the element system; one factorisation per distinct reflectance channel.
pub struct Direct {
    b: Option<Vec<Rgb>>,
    params: SolverParams,
}

impl Direct {
    /// A direct solver; the work happens in the first step.
    pub fn new(params: SolverParams) -> Self {
        Direct { b: None, params }
    }

    /// The dense gathering matrix `K` (row-major, `n × n`): `K_ij = Σ_links F_is w_j / w_s`.
    pub fn dense_k(sys: &System) -> Vec<f64> {
        let n = sys.len();
        let mut k = vec![0.0; n * n];
        for i in 0..n {
            for l in sys.links.row[i]..sys.links.row[i + 1] {
                let s = sys.links.src[l] as usize;
                if sys.node_weight[s] <= 0.0 {
                    continue;
                }
                let f = f64::from(sys.links.ff[l]) / sys.node_weight[s];
                for j in sys.node_leaf_lo[s]..sys.node_leaf_hi[s] {
                    k[i * n + j as usize] += f * sys.weight[j as usize];
                }
            }
        }
        k
    }

    fn solve(&self, sys: &System) -> Result<Vec<Rgb>, SolveError> {
        use faer::prelude::*;
        let n = sys.len();
        if n > self.params.max_direct {
            let bytes = |n: usize| (n as u64).pow(2) * 8;
            return Err(SolveError::OutOfMemory {
                what: "the direct solver's dense matrix",
                needed: bytes(n),
                limit: bytes(self.params.max_direct),
            });
        }
        let k = Self::dense_k(sys);
        let mut out = vec![[0.0; 3]; n];
        let mut done = [false; 3];
        // With all inputs non-negative the exact solution is non-negative, (I − ρK)⁻¹ being the
        // Neumann series Σ (ρK)ⁿ. A solution with clearly negative values or a large residual
        // means the matrix is singular to working precision (reflectance 1 in a closed scene).
        for c in 0..3 {
            if done[c] {
                continue;
            }
            // Channels with the same reflectance everywhere share one factorisation.
            let same: Vec<usize> = (c..3)
                .filter(|&d| !done[d] && sys.rho.iter().all(|r| r[d] == r[c]))
                .collect();
            let a = Mat::<f64>::from_fn(n, n, |i, j| {
                f64::from(u8::from(i == j)) - sys.rho[i][c] * k[i * n + j]
            });
            let rhs = Mat::<f64>::from_fn(n, same.len(), |i, j| sys.source[i][same[j]]);
            let x = a.partial_piv_lu().solve(&rhs);
            for (j, &d) in same.iter().enumerate() {
                for i in 0..n {
                    let v = x[(i, j)];
                    if !v.is_finite() {
                        return Err(SolveError::Singular);
                    }
                    out[i][d] = v;
                }
                done[d] = true;
            }
        }
        let peak = out.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        if out.iter().flatten().any(|&v| v < -1e-9 * peak) {
            return Err(SolveError::Singular);
        }
        let residual = sys.relative_residual(&out);
        if residual.is_nan() || residual > 1e-6 {
            return Err(SolveError::Singular);
        }
        Ok(out)
    }
}

impl Solver for Direct {
    fn kind(&self) -> SolverKind {
        SolverKind::Direct
    }
    fn step(&mut self, sys: &System, _budget: Duration) -> Result<Info, SolveError> {
        if self.b.is_none() {
            self.b = Some(self.solve(sys)?);
        }
        let b = self.b.as_deref().unwrap_or_default();
        let r = sys.residual(b);
        let p = progress_from_residual(sys, b, &r, 1, self.params.tolerance);
        // A direct solve is done whatever its rounding; the residual says how well.
        Ok(Info {
            converged: p.residual.is_finite(),
            progress: 1.0,
            ..p
        })
    }
    fn warm_start(&mut self, _sys: &System, _b: &[Rgb]) {
        self.b = None;
    }
    fn radiosity(&self, sys: &System) -> Vec<Rgb> {
        self.b.clone().unwrap_or_else(|| vec![[0.0; 3]; sys.len()])
    }
}
