//! Time stepping of the reduced model: minimisation of the incremental
//! potential E by a Newton-type iteration with positive definite Hessians, a
//! contact model solved inside each iteration, a stick correction for friction
//! and a line search; or the prefactored scheme that reuses one factorisation
//! of `M/h^2 + K(rest)` for every iteration.
//!
//! **Initial guess.** `q_t + h qdot_t + h^2 a`, with `a` the acceleration of the
//! previous step (`(qdot_t - qdot_{t-1}) / h`), or gravity alone (`M^-1 f`) on the
//! first step after a new state. A body that rests, slides steadily or sticks is
//! then almost at the solution before the first iteration, with its contact
//! points in the right friction regime.
//!
//! **Hessian.** `A = M/h^2 + K_el + K_c`. The contact part `K_c` holds the stiff
//! terms (penalty, stick friction) and follows the contact state exactly: it is
//! updated at every iterate by taking out and putting in the rows of the
//! contact points whose terms changed ([`crate::reduced::ContactHessian`]).
//! The elastic part (PSD-projected SNH Hessians at the cubature points) is the
//! expensive one and changes slowly. With [`ElasticHessian::Lagged`] (the
//! default) it is kept from iteration to iteration and from step to step, and
//! improved along every step `s` by a BFGS correction of `M/h^2 + K_el` (so that
//! it reproduces the change of the elastic gradient along `s`); it is assembled
//! again after a new state and when it has drifted: when the secant error
//! `g_el(x + s) - g_el(x) - K_el s`, mapped through the last factored matrix,
//! would make up more than [`ELASTIC_DRIFT`] of the next direction. This makes
//! the outer iteration a quasi-Newton method: every matrix is positive
//! definite, each direction a descent direction, and the fixed point the same
//! minimiser; the convergence measure below is taken on its direction.
//! [`ElasticHessian::EveryIteration`] gives plain Newton; there, where the
//! projection clamped some eigenvalue and the previous iteration took the full
//! step, the exact elastic Hessian is tried first (near rest the clamped twist
//! modes would turn Newton's quadratic convergence into a linear one).
//!
//! **Contact model.** Contact makes E piecewise: a Newton step computed with
//! the contact state of the iterate overshoots or stops short where points
//! touch, lift off, stick or start to slip, and a plain Newton iteration pays
//! a full evaluation for every such switch. So each Newton direction is
//! replaced by the step to the minimiser of a model of E: inertia, gravity and
//! contact exact, the elastic energy by its quadratic expansion at the iterate
//! (with `K_el`). Evaluating the model costs no pass over the cubature points,
//! only over the contact points that touch a plane or carry a lagged normal
//! force. It is minimised by the same iteration (stick correction and line
//! search included) to half the tolerance, or to [`INNER_FORCING`] of the
//! outer residual; E then takes the step to its minimiser as the search
//! direction, and only the elastic nonlinearity is left for the next outer
//! iteration.
//!
//! **Stick correction.** Coulomb friction makes the potential nearly non-smooth:
//! its curvature jumps from `a k_f / h` (stick) to almost nothing (slip) over a
//! slip of `mu f_n h / (a k_f)`, typically a fraction of a micrometre. A Newton
//! step from the slip side sees no curvature along the slip and overshoots, and
//! backtracking then crawls. So, when the direction would carry slipping points
//! through the stick region, the system is solved again with those points
//! modelled as sticking (a low-rank change of the Hessian and the right-hand
//! side), and that step is taken when it decreases the energy enough.
//!
//! **Line search.** Armijo sufficient decrease, plus a curvature test: a full
//! step that overshoots the minimum along the line (the slope at the trial
//! point turned positive beyond [`CURVATURE`] of the initial one), typical where
//! friction switches between stick and slip, is bracketed and the line minimum
//! located by safeguarded secant steps on the slope; otherwise the step is
//! halved until the energy decreases. Near convergence, where the decrease
//! hides in the round-off, a step at the line minimum (small slope) is
//! accepted. Every trial point is evaluated with its gradient, which becomes
//! the next iteration's gradient when the trial is accepted; energies are
//! taken relative to the inertial target's gravity work, a constant of the
//! step, so that their differences keep their digits.
//!
//! **Convergence** is measured on the (outer) Newton direction `Delta` at the
//! iterate as the velocity `r = sqrt(Delta^T M Delta / m_total) / h` (m/s),
//! invariant to the choice of basis; when `r < tolerance` the step `Delta` is
//! taken and the solve stops. `iterations` counts these directions (outer
//! iterations); the model's are counted in [`SolverStats`].

use crate::cholesky::Cholesky;
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::reduced::{ContactHessian, ElasticModel, Hessian, ReducedSystem, StepStart, Workspace};

/// How the search direction is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolverKind {
    /// Newton: factor `M/h^2 + K_elastic + K_contact` every iteration (the
    /// elastic part refreshed as [`SolverSettings::elastic_hessian`] says).
    Newton,
    /// Factor `M/h^2 + K(rest)` once and iterate `Delta = -A^-1 grad`.
    Prefactored,
}

impl std::str::FromStr for SolverKind {
    type Err = LicromError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "newton" => Ok(Self::Newton),
            "prefactored" => Ok(Self::Prefactored),
            other => Err(LicromError::invalid("solver", format!("must be 'newton' or 'prefactored', got '{other}'"))),
        }
    }
}

/// When Newton assembles the elastic part of the Hessian.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ElasticHessian {
    /// At every iterate (plain Newton).
    EveryIteration,
    /// Kept across iterations and steps; assembled again when the iteration
    /// slows down or after a new state (see the module documentation).
    #[default]
    Lagged,
}

impl std::str::FromStr for ElasticHessian {
    type Err = LicromError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "every_iteration" => Ok(Self::EveryIteration),
            "lagged" => Ok(Self::Lagged),
            other => Err(LicromError::invalid("elastic_hessian", format!("must be 'lagged' or 'every_iteration', got '{other}'"))),
        }
    }
}

/// Solver parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSettings {
    /// Total mass of the solid, kg (normalises the convergence measure).
    pub total_mass: f64,
    /// Convergence threshold on r, m/s.
    pub tolerance: f64,
    /// Search directions allowed per step.
    pub max_iterations: usize,
    /// Direction scheme.
    pub kind: SolverKind,
    /// Refresh rule of the elastic Hessian (Newton only).
    pub elastic_hessian: ElasticHessian,
}

impl SolverSettings {
    /// Settings with the default elastic Hessian rule.
    pub fn new(total_mass: f64, tolerance: f64, max_iterations: usize, kind: SolverKind) -> Self {
        Self { total_mass, tolerance, max_iterations, kind, elastic_hessian: ElasticHessian::default() }
    }
}

/// Outcome of a converged step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Search directions computed.
    pub iterations: usize,
    /// Final convergence measure r, m/s.
    pub residual: f64,
}

/// Work done by the solver since it was created (or [`ReducedSolver::reset_stats`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SolverStats {
    /// Steps attempted.
    pub steps: usize,
    /// Search directions computed.
    pub iterations: usize,
    /// Energy and gradient evaluations (initial guesses and line-search trials).
    pub evaluations: usize,
    /// Directions computed on the contact model (inner iterations).
    pub model_iterations: usize,
    /// Evaluations of the contact model (no pass over the cubature points).
    pub model_evaluations: usize,
    /// Assemblies of the elastic Hessian.
    pub elastic_hessians: usize,
    /// Stick-corrected directions solved.
    pub stick_solves: usize,
    /// Stick-corrected steps taken.
    pub stick_steps: usize,
}

/// Armijo sufficient-decrease constant.
const ARMIJO: f64 = 1e-4;
/// `|phi'(alpha)| <= CURVATURE |phi'(0)|` accepts a step at the line minimum.
pub const CURVATURE: f64 = 0.5;
/// Secant steps locating an overshot line minimum.
const MAX_SECANT: usize = 8;
/// Backtracking halvings before the line search gives up.
const MAX_HALVINGS: usize = 40;
/// Energy differences below this many ulps of the energy scale are round-off.
const ROUNDOFF_ULPS: f64 = 64.0;
/// Relative energy increase still taken as round-off when the slope shows
/// that the trial point is at the line minimum. The energy sums terms much
/// larger than its changes near convergence (the inertia `d^T M d / h^2` of a
/// basis whose affine and learned modes overlap is computed from coordinates
/// that cancel), so its round-off can reach 1e-9 of its value, while the slope
/// (a gradient, linear in those coordinates) stays accurate.
const NOISE: f64 = 1e-8;
/// Inner iterations on the contact model per outer iteration.
const MAX_INNER: usize = 20;
/// The contact model is minimised down to this share of the tolerance, or of
/// the outer Newton direction's residual, whichever is larger.
const INNER_TOLERANCE: f64 = 0.5;
pub const INNER_FORCING: f64 = 0.01;
/// The lagged elastic Hessian is assembled again when its error along the last
/// step makes up more than this share of the next direction (see
/// the module documentation).
pub const ELASTIC_DRIFT: f64 = 0.1;

/// State `(q, qdot)` of a reduced model and the preallocated machinery to step it.
#[derive(Debug)]
pub struct ReducedSolver {
    system: ReducedSystem,
    settings: SolverSettings,
    q: Vec<f64>,
    qdot: Vec<f64>,
    /// Velocity before the last step (valid if `has_prev`), for the initial guess.
    qdot_prev: Vec<f64>,
    has_prev: bool,
    /// `h^2 M^-1 f`: the gravity part of the initial guess.
    free_fall: Vec<f64>,
    /// Start of the step in progress.
    current: StepStart,
    /// Start of the last accepted step, for contact forces (valid if `has_last`).
    last: StepStart,
    has_last: bool,
    /// Start used by the energy/gradient/Hessian probes.
    probe: StepStart,
    /// Last iterate of the step that just failed to converge (valid if `has_failed`).
    failed: Vec<f64>,
    has_failed: bool,
    ws: Workspace,
    chol: Cholesky,
    /// Factor of `M/h^2 + K(rest)` for the prefactored scheme.
    prefactor: Option<Cholesky>,
    iterate: Vec<f64>,
    /// Gradient at `iterate`, and its elastic part.
    grad: Vec<f64>,
    grad_elastic: Vec<f64>,
    trial: Vec<f64>,
    trial_grad: Vec<f64>,
    trial_grad_elastic: Vec<f64>,
    /// The step from the previous iterate (valid from the second iteration).
    step_taken: Vec<f64>,
    /// Elastic energy at `iterate` and at `trial`.
    energy_elastic: f64,
    trial_energy_elastic: f64,
    /// The contact model (see [`Self::solve_contact_model`]): its expansion
    /// point, elastic energy and gradient there; `model_mode` routes the
    /// evaluations to it.
    model_origin: Vec<f64>,
    model_energy: f64,
    model_grad: Vec<f64>,
    model_hessian: Vec<f64>,
    model_mode: bool,
    /// The outer gradient and Newton direction, kept while the model is solved.
    outer_grad: Vec<f64>,
    outer_dir: Vec<f64>,
    dir: Vec<f64>,
    /// Stick-corrected direction and its right-hand side.
    alt: Vec<f64>,
    /// Elastic Hessian, projected and clamped parts (valid if `elastic_valid`).
    elastic: Vec<f64>,
    elastic_clamped: Vec<f64>,
    has_clamped: bool,
    elastic_valid: bool,
    /// Whether the last direction used the exact elastic Hessian.
    used_exact: bool,
    contact: ContactHessian,
    /// The matrix last factored into `chol`.
    hess: Vec<f64>,
    mass_over_h2: Vec<f64>,
    stats: SolverStats,
}

impl ReducedSolver {
    /// Solver at rest (`q = qdot = 0`). Factors `M/h^2 + K(rest)` when the
    /// prefactored scheme is chosen.
    pub fn new(system: ReducedSystem, settings: SolverSettings) -> Result<Self> {
        check_positive("total_mass", settings.total_mass)?;
        check_positive("tolerance", settings.tolerance)?;
        if settings.max_iterations == 0 {
            return Err(LicromError::invalid("max_iterations", "must be >= 1, got 0"));
        }
        let n = system.n_dofs();
        let h = system.dt();
        let mass_over_h2: Vec<f64> = system.mass().iter().map(|m| m / (h * h)).collect();
        let mut chol = Cholesky::new(n);
        chol.factor_shifted(system.mass(), 0.0, system.mass())
            .map_err(|index| LicromError::SingularMass { reason: format!("Cholesky pivot {index} is not positive") })?;
        let mut free_fall: Vec<f64> = system.gravity().iter().map(|f| f * h * h).collect();
        chol.solve_in_place(&mut free_fall);
        let mut ws = system.workspace();
        let prefactor = match settings.kind {
            SolverKind::Newton => None,
            SolverKind::Prefactored => {
                system.rest_stiffness(&mut ws);
                let mut a = Cholesky::new(n);
                a.factor_shifted(&mass_over_h2, 1.0, &ws.hess)
                    .map_err(|index| LicromError::invalid("prefactored system", format!("M/h^2 + K(rest) is not positive definite (pivot {index})")))?;
                Some(a)
            }
        };
        let zeros = vec![0.0; n];
        let square = vec![0.0; n * n];
        Ok(Self {
            current: system.step_start(),
            probe: system.step_start(),
            last: system.step_start(),
            has_last: false,
            failed: zeros.clone(),
            has_failed: false,
            settings,
            q: zeros.clone(),
            qdot: zeros.clone(),
            qdot_prev: zeros.clone(),
            has_prev: false,
            free_fall,
            ws,
            chol,
            prefactor,
            iterate: zeros.clone(),
            grad: zeros.clone(),
            grad_elastic: zeros.clone(),
            trial: zeros.clone(),
            trial_grad: zeros.clone(),
            trial_grad_elastic: zeros.clone(),
            step_taken: zeros.clone(),
            energy_elastic: 0.0,
            trial_energy_elastic: 0.0,
            model_origin: zeros.clone(),
            model_energy: 0.0,
            model_grad: zeros.clone(),
            model_hessian: square.clone(),
            model_mode: false,
            outer_grad: zeros.clone(),
            outer_dir: zeros.clone(),
            dir: zeros.clone(),
            alt: zeros,
            elastic: square.clone(),
            elastic_clamped: square.clone(),
            has_clamped: false,
            elastic_valid: false,
            used_exact: false,
            contact: system.contact_hessian_state(settings.elastic_hessian == ElasticHessian::Lagged),
            hess: square,
            mass_over_h2,
            stats: SolverStats::default(),
            system,
        })
    }

    /// The reduced model.
    pub fn system(&self) -> &ReducedSystem {
        &self.system
    }

    /// Solver parameters.
    pub fn settings(&self) -> &SolverSettings {
        &self.settings
    }

    /// Reduced coordinates.
    pub fn q(&self) -> &[f64] {
        &self.q
    }

    /// Reduced velocities (per second).
    pub fn qdot(&self) -> &[f64] {
        &self.qdot
    }

    /// Work counters.
    pub fn stats(&self) -> SolverStats {
        self.stats
    }

    /// Zeroes the work counters.
    pub fn reset_stats(&mut self) {
        self.stats = SolverStats::default();
    }

    fn check_state(&self, name: &str, v: &[f64]) -> Result<()> {
        let n = self.system.n_dofs();
        if v.len() != n {
            return Err(LicromError::shape(name, format!("({n},)"), format!("{} values", v.len())));
        }
        check_finite(name, v)
    }

    /// Replaces the state. Contact forces read zero until the next step; the
    /// next step starts from the free-fall guess and a fresh elastic Hessian.
    pub fn set_state(&mut self, q: &[f64], qdot: &[f64]) -> Result<()> {
        self.check_state("q", q)?;
        self.check_state("qdot", qdot)?;
        self.q.copy_from_slice(q);
        self.qdot.copy_from_slice(qdot);
        self.has_last = false;
        self.has_failed = false;
        self.has_prev = false;
        self.elastic_valid = false;
        Ok(())
    }

    /// Advances one time step. On error the state is left unchanged; after
    /// [`LicromError::NotConverged`] the last iterate can be taken with
    /// [`Self::accept_last_iterate`].
    pub fn step(&mut self) -> Result<StepReport> {
        self.has_failed = false;
        self.stats.steps += 1;
        let n = self.system.n_dofs();
        let h = self.system.dt();
        self.system.begin_step(&self.q, &self.qdot, &mut self.current);
        for i in 0..n {
            let accel = if self.has_prev { h * (self.qdot[i] - self.qdot_prev[i]) } else { self.free_fall[i] };
            self.iterate[i] = self.q[i] + h * self.qdot[i] + accel;
        }
        let mut energy = self.system.evaluate(&self.current, &self.iterate, true, &mut self.ws);
        self.grad.copy_from_slice(&self.ws.grad);
        self.ws.elastic_gradient(&mut self.grad_elastic);
        self.energy_elastic = self.ws.elastic_energy;
        self.stats.evaluations += 1;
        if !energy.is_finite() {
            return Err(LicromError::Diverged { iteration: 0, what: "energy at the initial guess" });
        }
        let mut residual = f64::INFINITY;
        let mut full_step = false;
        for iteration in 1..=self.settings.max_iterations {
            self.stats.iterations += 1;
            if !self.grad.iter().all(|g| g.is_finite()) {
                return Err(LicromError::Diverged { iteration, what: "gradient" });
            }
            if self.prefactor.is_none() {
                let refresh = match self.settings.elastic_hessian {
                    ElasticHessian::EveryIteration => true,
                    ElasticHessian::Lagged => !self.elastic_valid || (iteration > 1 && self.elastic_drift() > ELASTIC_DRIFT),
                };
                if refresh {
                    self.refresh_elastic();
                } else if iteration > 1 {
                    self.secant_update();
                }
            }
            residual = self.direction(iteration, full_step)?;
            if residual < self.settings.tolerance {
                for (x, d) in self.iterate.iter_mut().zip(&self.dir) {
                    *x += d;
                }
                self.finish_step();
                return Ok(StepReport { iterations: iteration, residual });
            }
            if self.prefactor.is_none() && self.system.has_contact() {
                self.solve_contact_model(energy, residual);
            }
            match self.line_search(energy) {
                Some((e, alpha)) => {
                    energy = e;
                    full_step = alpha == 1.0;
                }
                None => return Err(self.fail(iteration, residual)),
            }
        }
        Err(self.fail(self.settings.max_iterations, residual))
    }

    /// Replaces the Newton direction `self.dir` from `self.iterate` by the step
    /// to the minimiser of the contact model: E with the elastic energy replaced
    /// by its quadratic expansion at the iterate (the projected elastic Hessian),
    /// inertia, gravity and contact exact. Contact makes E piecewise: a Newton
    /// step computed with the contact state of the iterate overshoots or stops
    /// short where points touch, lift off, stick or start to slip. On the model
    /// those switches cost no pass over the cubature points, so it is minimised
    /// by the same Newton iteration (stick correction and line search
    /// included) down to half the tolerance; the true E then takes its minimiser
    /// as the search direction, and only the elastic nonlinearity is left for
    /// the next outer iteration. Falls back to the Newton direction when the
    /// model makes no progress.
    fn solve_contact_model(&mut self, energy: f64, residual: f64) {
        let n = self.system.n_dofs();
        self.model_origin.copy_from_slice(&self.iterate);
        self.model_grad.copy_from_slice(&self.grad_elastic);
        self.model_energy = self.energy_elastic;
        self.outer_grad.copy_from_slice(&self.grad);
        self.outer_dir.copy_from_slice(&self.dir);
        let used_exact = self.used_exact;
        // The model takes the elastic Hessian of the Newton direction, the exact
        // one only where M/h^2 + K_el is positive definite by itself (the model
        // stays convex when contact terms vanish); with the projected one the
        // model's minimiser would miss the clamped curvature and the outer
        // iteration would converge only linearly.
        let mut exact = used_exact;
        for ((m, e), c) in self.model_hessian.iter_mut().zip(&self.elastic).zip(&self.elastic_clamped) {
            *m = e - if exact { *c } else { 0.0 };
        }
        if exact && self.chol.factor_shifted(&self.mass_over_h2, 1.0, &self.model_hessian).is_err() {
            exact = false;
            self.model_hessian.copy_from_slice(&self.elastic);
        }
        self.model_mode = true;
        // Solving the model much closer than the outer iteration can follow
        // (its elastic part is only a model) is wasted work.
        let tolerance = (INNER_TOLERANCE * self.settings.tolerance).max(INNER_FORCING * residual);
        let mut e = energy;
        let mut moved = false;
        for inner in 0..MAX_INNER {
            if inner > 0 {
                self.stats.model_iterations += 1;
                match self.direction(0, exact) {
                    Ok(r) if r < tolerance => {
                        for (x, d) in self.iterate.iter_mut().zip(&self.dir) {
                            *x += d;
                        }
                        break;
                    }
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
            if let Some(e1) = self.stick_step(e) {
                e = e1;
                moved = true;
                continue;
            }
            match self.line_search(e) {
                Some((e1, _)) => {
                    e = e1;
                    moved = true;
                }
                None => break,
            }
        }
        self.model_mode = false;
        self.used_exact = used_exact;
        for i in 0..n {
            self.dir[i] = if moved { self.iterate[i] - self.model_origin[i] } else { self.outer_dir[i] };
            self.iterate[i] = self.model_origin[i];
        }
        self.grad.copy_from_slice(&self.outer_grad);
        self.grad_elastic.copy_from_slice(&self.model_grad);
        self.energy_elastic = self.model_energy;
    }

    fn refresh_elastic(&mut self) {
        // Lagged, the clamped part is not worth its cost (the BFGS correction does
        // better); plain Newton uses it for its quadratic convergence near rest.
        let clamped = (self.settings.elastic_hessian == ElasticHessian::EveryIteration).then_some(&mut self.elastic_clamped[..]);
        self.has_clamped = self.system.elastic_hessian(&self.iterate, &mut self.ws, &mut self.elastic, clamped);
        self.elastic_valid = true;
        self.stats.elastic_hessians += 1;
    }

    /// Computes the search direction at `self.iterate` into `self.dir` from the
    /// gradient `self.grad` and returns its convergence measure r. `try_exact`:
    /// the previous step was taken in full (see the module documentation).
    fn direction(&mut self, iteration: usize, try_exact: bool) -> Result<f64> {
        for (d, g) in self.dir.iter_mut().zip(&self.grad) {
            *d = -g;
        }
        match &mut self.prefactor {
            Some(a) => a.solve_in_place(&mut self.dir),
            None => {
                // The contact terms are those of the evaluation at `self.iterate`.
                self.system.update_contact_hessian(&mut self.ws, &mut self.contact);
                let exact = try_exact && self.has_clamped;
                self.used_exact = exact;
                let contact = self.contact.matrix();
                for i in 0..self.hess.len() {
                    let clamped = if exact { self.elastic_clamped[i] } else { 0.0 };
                    self.hess[i] = self.mass_over_h2[i] + (self.elastic[i] - clamped) + contact[i];
                }
                if !self.hess.iter().all(|v| v.is_finite()) {
                    return Err(LicromError::Diverged { iteration, what: "Hessian" });
                }
                let mut factored = self.chol.factor_shifted(&self.hess, 0.0, &self.mass_over_h2).is_ok();
                if !factored && exact {
                    self.used_exact = false;
                    for (h, c) in self.hess.iter_mut().zip(&self.elastic_clamped) {
                        *h += c;
                    }
                    factored = self.chol.factor_shifted(&self.hess, 0.0, &self.mass_over_h2).is_ok();
                }
                // The projected Hessian is M/h^2 plus PSD terms, so this only fails
                // through round-off; a growing share of M/h^2 restores definiteness.
                let mut shift = 1e-8;
                while !factored {
                    factored = self.chol.factor_shifted(&self.hess, shift, &self.mass_over_h2).is_ok();
                    if factored {
                        for (h, m) in self.hess.iter_mut().zip(&self.mass_over_h2) {
                            *h += shift * m;
                        }
                    }
                    shift *= 10.0;
                    if shift > 1e9 {
                        return Err(LicromError::Diverged { iteration, what: "Hessian factorisation" });
                    }
                }
                self.chol.solve_in_place(&mut self.dir);
            }
        }
        let r = self.velocity_norm(&self.dir);
        if !r.is_finite() {
            return Err(LicromError::Diverged { iteration, what: "search direction" });
        }
        Ok(r)
    }

    /// `sqrt(d^T M d / m_total) / h`, m/s.
    fn velocity_norm(&self, d: &[f64]) -> f64 {
        let n = self.system.n_dofs();
        let mass = self.system.mass();
        let mut norm2 = 0.0;
        for i in 0..n {
            let row: f64 = (0..n).map(|j| mass[i * n + j] * d[j]).sum();
            norm2 += d[i] * row;
        }
        (norm2.max(0.0) / self.settings.total_mass).sqrt() / self.system.dt()
    }

    /// The stick correction of `self.dir` (see the module documentation): when
    /// some slipping contact points would be carried through the stick region,
    /// solves again with them sticking and takes that full step if it decreases
    /// E enough. Returns the new energy when the step was taken.
    fn stick_step(&mut self, energy: f64) -> Option<f64> {
        self.alt.copy_from_slice(&self.grad);
        // The last evaluation was at `self.iterate` (see `solve_contact_model`).
        let rows = self.system.stick_switch(&self.current, &self.dir, &mut self.ws, &mut self.alt);
        if rows == 0 {
            return None;
        }
        self.stats.stick_solves += 1;
        self.system.add_switch_rows(&self.ws, rows, &mut self.hess);
        if self.chol.factor_shifted(&self.hess, 0.0, &self.mass_over_h2).is_err() {
            return None;
        }
        for a in self.alt.iter_mut() {
            *a = -*a;
        }
        self.chol.solve_in_place(&mut self.alt);
        let slope: f64 = self.grad.iter().zip(&self.alt).map(|(g, d)| g * d).sum();
        if !(slope.is_finite() && slope < 0.0) {
            return None;
        }
        for ((t, x), d) in self.trial.iter_mut().zip(&self.iterate).zip(&self.alt) {
            *t = x + d;
        }
        let e = self.evaluate_trial();
        let slack = ROUNDOFF_ULPS * f64::EPSILON * energy.abs().max(e.abs());
        if e.is_finite() && e <= energy + ARMIJO * slope + slack {
            self.stats.stick_steps += 1;
            self.accept_trial();
            Some(e)
        } else {
            None
        }
    }

    /// Energy and gradient at `self.trial` (gradient into `self.trial_grad`), of
    /// E or of the contact model.
    fn evaluate_trial(&mut self) -> f64 {
        let e = if self.model_mode {
            self.stats.model_evaluations += 1;
            let model = ElasticModel { origin: &self.model_origin, energy: self.model_energy, gradient: &self.model_grad, hessian: &self.model_hessian };
            self.system.evaluate_model(&self.current, &self.trial, &model, true, &mut self.ws)
        } else {
            self.stats.evaluations += 1;
            let e = self.system.evaluate(&self.current, &self.trial, true, &mut self.ws);
            self.ws.elastic_gradient(&mut self.trial_grad_elastic);
            e
        };
        self.trial_grad.copy_from_slice(&self.ws.grad);
        self.trial_energy_elastic = self.ws.elastic_energy;
        e
    }

    fn accept_trial(&mut self) {
        for ((s, t), x) in self.step_taken.iter_mut().zip(&self.trial).zip(&self.iterate) {
            *s = t - x;
        }
        std::mem::swap(&mut self.iterate, &mut self.trial);
        std::mem::swap(&mut self.grad, &mut self.trial_grad);
        std::mem::swap(&mut self.grad_elastic, &mut self.trial_grad_elastic);
        std::mem::swap(&mut self.energy_elastic, &mut self.trial_energy_elastic);
    }

    /// How far the lagged elastic Hessian is off along the last step `s`: the
    /// secant error `e = g_el(x + s) - g_el(x) - K_el s` measured as the part of
    /// the next direction it causes, `|A^-1 e|_M / |s|_M`, with `A` the last
    /// matrix factored. Zero where no step was taken yet.
    fn elastic_drift(&mut self) -> f64 {
        let n = self.system.n_dofs();
        let den = self.velocity_norm(&self.step_taken);
        if den <= 0.0 || !den.is_finite() {
            return 0.0;
        }
        for i in 0..n {
            let mut ks = 0.0;
            for j in 0..n {
                let k = self.elastic[i * n + j] - if self.used_exact { self.elastic_clamped[i * n + j] } else { 0.0 };
                ks += k * self.step_taken[j];
            }
            self.alt[i] = self.grad_elastic[i] - self.trial_grad_elastic[i] - ks;
        }
        // After `accept_trial`, `trial_grad_elastic` holds the previous iterate's.
        self.chol.solve_in_place(&mut self.alt);
        self.velocity_norm(&self.alt) / den
    }

    /// BFGS update of the lagged elastic Hessian along the last step `s`: with
    /// `A = M/h^2 + K_el` and `y = M s / h^2 + g_el(x + s) - g_el(x)` (the change
    /// of the smooth part of the gradient), `A + y y^T / y.s - A s (A s)^T / s.A s`
    /// reproduces `y` along `s` and stays positive definite when `y.s > 0`
    /// (skipped otherwise). The update goes into `K_el`.
    fn secant_update(&mut self) {
        let n = self.system.n_dofs();
        let mass = self.system.mass();
        let (mut sas, mut ys) = (0.0, 0.0);
        for i in 0..n {
            let (mut a_s, mut m_s) = (0.0, 0.0);
            for j in 0..n {
                let sj = self.step_taken[j];
                a_s += (self.mass_over_h2[i * n + j] + self.elastic[i * n + j]) * sj;
                m_s += self.mass_over_h2[i * n + j] * sj;
            }
            let _ = mass;
            self.alt[i] = a_s;
            self.outer_dir[i] = m_s + self.grad_elastic[i] - self.trial_grad_elastic[i];
            sas += self.step_taken[i] * a_s;
            ys += self.step_taken[i] * self.outer_dir[i];
        }
        if !(sas > 0.0 && ys > 1e-8 * sas && sas.is_finite() && ys.is_finite()) {
            return;
        }
        for i in 0..n {
            for j in 0..n {
                self.elastic[i * n + j] += self.outer_dir[i] * self.outer_dir[j] / ys - self.alt[i] * self.alt[j] / sas;
            }
        }
    }

    /// `phi(alpha) = E(x + alpha d)` and `phi'(alpha)` at `x + alpha d`, the point left in `self.trial`.
    fn line_trial(&mut self, alpha: f64) -> (f64, f64) {
        for ((t, x), d) in self.trial.iter_mut().zip(&self.iterate).zip(&self.dir) {
            *t = x + alpha * d;
        }
        let e = self.evaluate_trial();
        let slope = self.trial_grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        (e, slope)
    }

    /// Line search from `self.iterate` along `self.dir` (see the module
    /// documentation); moves the iterate and returns the new energy and the step
    /// length taken, or `None` when no step decreases E beyond round-off.
    fn line_search(&mut self, e0: f64) -> Option<(f64, f64)> {
        let d0: f64 = self.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        let ok = |a: f64, e: f64, d: f64| {
            if !e.is_finite() {
                return false;
            }
            let scale = e0.abs().max(e.abs());
            if e <= e0 + ARMIJO * a * d0 + ROUNDOFF_ULPS * f64::EPSILON * scale {
                return true;
            }
            // Near convergence the decrease hides in the round-off of E; there a
            // step at the line minimum (small slope) is taken.
            e <= e0 + NOISE * scale && d.is_finite() && d.abs() <= CURVATURE * d0.abs()
        };
        let (e1, d1) = self.line_trial(1.0);
        let good1 = ok(1.0, e1, d1);
        if good1 && d1 <= CURVATURE * d0.abs() {
            self.accept_trial();
            return Some((e1, 1.0));
        }
        let mut hi = 1.0;
        if d1.is_finite() && d1 > 0.0 {
            // Overshoot: the line minimum lies in (0, 1); bracket it by secant steps.
            let mut best = good1.then_some((1.0, e1));
            let (mut lo, mut dlo, mut dhi) = (0.0, d0, d1);
            let mut last = 1.0;
            for _ in 0..MAX_SECANT {
                let width = hi - lo;
                let a = (lo - dlo * width / (dhi - dlo)).clamp(lo + 0.05 * width, hi - 0.05 * width);
                let (e, d) = self.line_trial(a);
                last = a;
                let good = ok(a, e, d);
                if good && best.is_none_or(|(_, eb)| e < eb) {
                    best = Some((a, e));
                }
                if good && d.abs() <= CURVATURE * d0.abs() {
                    self.accept_trial();
                    return Some((e, a));
                }
                if good && d < 0.0 {
                    (lo, dlo) = (a, d);
                } else if d.is_finite() && d > 0.0 {
                    (hi, dhi) = (a, d);
                } else {
                    break;
                }
            }
            if let Some((a, e)) = best {
                if a != last {
                    self.line_trial(a);
                }
                self.accept_trial();
                return Some((e, a));
            }
        } else if good1 {
            self.accept_trial();
            return Some((e1, 1.0));
        }
        let mut alpha = 0.5 * hi;
        for _ in 0..MAX_HALVINGS {
            let (e, d) = self.line_trial(alpha);
            if ok(alpha, e, d) {
                self.accept_trial();
                return Some((e, alpha));
            }
            alpha *= 0.5;
        }
        None
    }

    fn finish_step(&mut self) {
        let h = self.system.dt();
        std::mem::swap(&mut self.qdot_prev, &mut self.qdot);
        for ((v, x), q) in self.qdot.iter_mut().zip(&self.iterate).zip(&self.q) {
            *v = (x - q) / h;
        }
        self.has_prev = true;
        self.q.copy_from_slice(&self.iterate);
        std::mem::swap(&mut self.last, &mut self.current);
        self.has_last = true;
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        self.failed.copy_from_slice(&self.iterate);
        self.has_failed = true;
        LicromError::NotConverged { iterations, residual }
    }

    /// Takes the last iterate of the step that just failed to converge as the
    /// new state (velocity from the difference), as if the step had converged.
    pub fn accept_last_iterate(&mut self) -> Result<()> {
        if !self.has_failed {
            return Err(LicromError::invalid("accept_last_iterate", "needs a step that did not converge just before"));
        }
        self.iterate.copy_from_slice(&self.failed);
        self.finish_step();
        self.has_failed = false;
        Ok(())
    }

    /// Contact forces (C x 3, N) at the current state relative to the start of
    /// the last step; zeros before any step.
    pub fn contact_forces(&self, out: &mut [f64]) -> Result<()> {
        let c = self.system.n_contacts();
        if out.len() != 3 * c {
            return Err(LicromError::shape("out", format!("({c}, 3)"), format!("{} values", out.len())));
        }
        if self.has_last {
            self.system.contact_forces(&self.last, &self.q, out);
        } else {
            out.fill(0.0);
        }
        Ok(())
    }

    fn prepare_probe(&mut self, q: &[f64]) -> Result<()> {
        self.check_state("q", q)?;
        self.system.begin_step(&self.q, &self.qdot, &mut self.probe);
        Ok(())
    }

    /// Incremental potential E(q) (J) of a step starting from the current state.
    pub fn energy(&mut self, q: &[f64]) -> Result<f64> {
        self.prepare_probe(q)?;
        Ok(self.system.energy(&self.probe, q))
    }

    /// Gradient of E at `q` for a step starting from the current state.
    pub fn gradient(&mut self, q: &[f64]) -> Result<&[f64]> {
        self.prepare_probe(q)?;
        self.system.assemble(&self.probe, q, Hessian::None, &mut self.ws);
        Ok(&self.ws.grad)
    }

    /// Hessian of E at `q` (n x n, symmetric) for a step starting from the
    /// current state; elastic parts PSD-projected when `project`.
    pub fn hessian(&mut self, q: &[f64], project: bool) -> Result<&[f64]> {
        self.prepare_probe(q)?;
        self.system.assemble(&self.probe, q, if project { Hessian::Projected } else { Hessian::Split }, &mut self.ws);
        if project {
            return Ok(&self.ws.hess);
        }
        // The probe result goes through the clamped buffer, which is free here.
        for (c, h) in self.ws.hess_clamped.iter_mut().zip(&self.ws.hess) {
            *c = h - *c;
        }
        Ok(&self.ws.hess_clamped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{BlockModel, BlockScene};

    fn solver(model: &BlockModel, kind: SolverKind, tolerance: f64, max_iterations: usize) -> ReducedSolver {
        let system = ReducedSystem::new(&model.inputs()).unwrap();
        let settings = SolverSettings::new(model.total_mass, tolerance, max_iterations, kind);
        ReducedSolver::new(system, settings).unwrap()
    }

    fn block(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
        BlockScene { learned_modes, cubature_points, contact_points, normal_damping: 2.0e3, seed: 5, ..Default::default() }
            .build()
            .unwrap()
    }

    /// |grad| relative to the size of the inertial and gravity terms.
    fn relative_gradient(s: &mut ReducedSolver) -> f64 {
        let q = s.q.clone();
        s.system.assemble(&s.last, &q, Hessian::None, &mut s.ws);
        let g: f64 = s.ws.grad.iter().map(|g| g * g).sum::<f64>().sqrt();
        let f: f64 = s.system.gravity().iter().map(|g| g * g).sum::<f64>().sqrt();
        g / f
    }

    #[test]
    fn newton_converges_to_a_stationary_point_while_sliding() {
        let model = block(8, 60, 50);
        let mut s = solver(&model, SolverKind::Newton, 1e-9, 50);
        let (q, qdot) = model.resting_state(0.5);
        s.set_state(&q, &qdot).unwrap();
        for _ in 0..20 {
            let report = s.step().unwrap();
            // The step in which the block comes to rest (slip to stick) is the hardest.
            assert!(report.residual < 1e-9 && report.iterations <= 20, "{report:?}");
            assert!(relative_gradient(&mut s) < 1e-6, "gradient at the solution: {}", relative_gradient(&mut s));
        }
        // Friction decelerates the block: mu g = 4.9 m/s^2 for 0.2 s takes 0.98 m/s,
        // more than it had, so it has stopped sliding (up to the stick creep).
        assert!(s.qdot()[9].abs() < 0.05, "still sliding at {} m/s", s.qdot()[9]);
        let mut forces = vec![0.0; 3 * 50];
        s.contact_forces(&mut forces).unwrap();
        let total_z: f64 = forces.chunks_exact(3).map(|f| f[2]).sum();
        assert!((total_z - model.total_mass * 9.81).abs() < 0.05 * model.total_mass * 9.81, "ground carries {total_z} N");
    }

    #[test]
    fn lagged_and_plain_newton_reach_the_same_solution() {
        let model = block(8, 60, 50);
        let (q, qdot) = model.resting_state(0.5);
        let mut lagged = solver(&model, SolverKind::Newton, 1e-10, 50);
        let system = ReducedSystem::new(&model.inputs()).unwrap();
        let settings = SolverSettings { elastic_hessian: ElasticHessian::EveryIteration, ..SolverSettings::new(model.total_mass, 1e-10, 50, SolverKind::Newton) };
        let mut plain = ReducedSolver::new(system, settings).unwrap();
        lagged.set_state(&q, &qdot).unwrap();
        plain.set_state(&q, &qdot).unwrap();
        let n = model.n_dofs();
        for _ in 0..15 {
            lagged.step().unwrap();
            plain.step().unwrap();
            let d: Vec<f64> = lagged.q().iter().zip(plain.q()).map(|(x, y)| x - y).collect();
            let dmd: f64 = (0..n).map(|i| d[i] * (0..n).map(|j| model.mass[i * n + j] * d[j]).sum::<f64>()).sum();
            let gap = (dmd / model.total_mass).sqrt() / model.scene.dt;
            assert!(gap < 1e-8, "solutions differ by {gap} m/s");
        }
        assert!(lagged.stats().elastic_hessians < plain.stats().elastic_hessians / 2, "{:?} vs {:?}", lagged.stats(), plain.stats());
    }

    #[test]
    fn a_block_dropped_on_an_incline_lands_and_comes_to_rest() {
        // Turned 30 degrees about y above a 20 degree incline: it lands on an edge,
        // rocks and stops (tan 20 < mu = 0.5); stiff contact as in the cheese scene.
        let model = BlockScene {
            learned_modes: 6,
            cubature_points: 80,
            contact_points: 120,
            incline: 20.0,
            contact_on_all_faces: true,
            normal_stiffness: 1e7,
            friction_stiffness: 1e7,
            seed: 7,
            ..Default::default()
        }
        .build()
        .unwrap();
        let mut s = solver(&model, SolverKind::Newton, 1e-6, 50);
        let (q, qdot) = model.dropped_state(30.0, 0.01);
        s.set_state(&q, &qdot).unwrap();
        let mut iterations = 0;
        for _ in 0..150 {
            let report = s.step().unwrap();
            assert!(report.iterations <= 15, "{report:?}");
            iterations += report.iterations;
        }
        assert!(iterations < 3 * 150, "{iterations} iterations in 150 steps");
        // At rest on the plane (up to the stick creep and a last rocking).
        let speed = (s.qdot()[9].powi(2) + s.qdot()[10].powi(2) + s.qdot()[11].powi(2)).sqrt();
        assert!(speed < 1e-3, "still moving at {speed} m/s");
    }

    #[test]
    fn prefactored_reaches_the_newton_solution() {
        let model = block(6, 40, 30);
        let (q, qdot) = model.resting_state(0.3);
        let mut newton = solver(&model, SolverKind::Newton, 1e-10, 50);
        // Its preconditioner lacks the contact stiffness: linear convergence, and a
        // floor where energy differences drop below round-off (about 4e-8 m/s here).
        let mut pre = solver(&model, SolverKind::Prefactored, 1e-7, 500);
        newton.set_state(&q, &qdot).unwrap();
        pre.set_state(&q, &qdot).unwrap();
        let a = newton.step().unwrap();
        let b = pre.step().unwrap();
        assert!(b.iterations > a.iterations);
        // Distance between the solutions as a velocity, like the convergence measure.
        let n = model.n_dofs();
        let d: Vec<f64> = newton.q().iter().zip(pre.q()).map(|(x, y)| x - y).collect();
        let dmd: f64 = (0..n).map(|i| d[i] * (0..n).map(|j| model.mass[i * n + j] * d[j]).sum::<f64>()).sum();
        let gap = (dmd / model.total_mass).sqrt() / model.scene.dt;
        assert!(gap < 1e-5, "prefactored solution differs by {gap} m/s");
    }

    #[test]
    fn affine_free_fall_matches_backward_euler_point_mass() {
        // A single cubature point, no contact: the affine modes carry a rigid
        // translation exactly, so the block must follow the discrete BE trajectory.
        let model = BlockScene { learned_modes: 0, cubature_points: 1, contact_points: 0, ..Default::default() }.build().unwrap();
        let mut s = solver(&model, SolverKind::Newton, 1e-12, 20);
        let h = model.scene.dt;
        let mut q = vec![0.0; 12];
        q[9..12].copy_from_slice(&[0.1, -0.2, 1.0]);
        let mut v = [0.3, 0.0, 1.5];
        let mut qdot = vec![0.0; 12];
        qdot[9..12].copy_from_slice(&v);
        s.set_state(&q, &qdot).unwrap();
        let mut x = [0.1, -0.2, 1.0];
        for _ in 0..25 {
            s.step().unwrap();
            v[2] -= 9.81 * h;
            for i in 0..3 {
                x[i] += h * v[i];
            }
            for i in 0..3 {
                assert!((s.q()[9 + i] - x[i]).abs() < 1e-12, "position {i}: {} vs {}", s.q()[9 + i], x[i]);
                assert!((s.qdot()[9 + i] - v[i]).abs() < 1e-10, "velocity {i}");
            }
            assert!(s.q()[..9].iter().all(|a| a.abs() < 1e-12), "the block deformed");
        }
    }

    #[test]
    fn empty_cubature_contacts_and_planes_work() {
        let mut model = BlockScene { learned_modes: 2, cubature_points: 0, contact_points: 0, ..Default::default() }.build().unwrap();
        model.planes.clear();
        let mut s = solver(&model, SolverKind::Newton, 1e-9, 10);
        let report = s.step().unwrap();
        assert!(report.iterations >= 1);
        let mut forces = [];
        s.contact_forces(&mut forces).unwrap();
        let mut p = solver(&model, SolverKind::Prefactored, 1e-9, 10);
        p.step().unwrap();
        assert!(s.q().iter().zip(p.q()).all(|(a, b)| (a - b).abs() < 1e-12));
    }

    #[test]
    fn non_convergence_leaves_the_state_and_can_be_accepted() {
        let model = block(4, 20, 20);
        let mut s = solver(&model, SolverKind::Newton, 1e-14, 1);
        let (q, qdot) = model.resting_state(0.5);
        s.set_state(&q, &qdot).unwrap();
        match s.step() {
            Err(LicromError::NotConverged { iterations: 1, residual }) => assert!(residual > 1e-14),
            other => panic!("expected non-convergence, got {other:?}"),
        }
        assert_eq!(s.q(), q.as_slice());
        assert_eq!(s.qdot(), qdot.as_slice());
        s.accept_last_iterate().unwrap();
        assert_ne!(s.q(), q.as_slice());
        assert!(s.accept_last_iterate().is_err());
    }

    #[test]
    fn probes_and_state_are_validated() {
        let model = block(1, 5, 4);
        let mut s = solver(&model, SolverKind::Newton, 1e-8, 10);
        assert!(matches!(s.set_state(&[0.0; 3], &[0.0; 13]), Err(LicromError::ShapeMismatch { .. })));
        let mut bad = vec![0.0; 13];
        bad[2] = f64::INFINITY;
        assert!(matches!(s.set_state(&bad, &[0.0; 13]), Err(LicromError::NonFinite { .. })));
        assert!(s.energy(&[0.0; 13]).unwrap().is_finite());
        assert_eq!(s.gradient(&[0.0; 13]).unwrap().len(), 13);
        assert_eq!(s.hessian(&[0.0; 13], false).unwrap().len(), 169);
        assert!("gauss-seidel".parse::<SolverKind>().is_err());
        let system = ReducedSystem::new(&model.inputs()).unwrap();
        let settings = SolverSettings::new(1.0, 1e-6, 0, SolverKind::Newton);
        assert!(ReducedSolver::new(system, settings).is_err());
    }
}
