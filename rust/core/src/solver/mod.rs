//! Time stepping of the reduced model: minimisation of the incremental
//! potential E by a Newton-type iteration with positive definite Hessians, a
//! contact model solved inside each iteration, a stick correction for friction
//! and a line search; or the prefactored scheme that keeps the elastic
//! stiffness at rest, `M/h^2 + K(rest) + K_contact`, and factors it again only
//! when the contact terms change (finishing a slow step with Newton, see
//! [`PREFACTORED_BUDGET`]).
//!
//! Where the parts live: the initial guess and the state here; the outer
//! iteration, written for any solver and shared with the body-frame one, in
//! `newton.rs`; the Newton matrix (lagged elastic Hessian with its BFGS correction,
//! incremental contact Hessian) and the search direction in `direction.rs`;
//! the contact model and friction's stick correction in `contact_model.rs`;
//! the line search, usable by any solver, in [`line_search`]; the parameters
//! and reports in `settings.rs`. The iteration on the contact model, the
//! factorisation and the lagged elastic Hessian's drift test and BFGS update
//! are written for any solver and shared with the body-frame one
//! ([`crate::body_frame::solver`]).
//!
//! **Time integrator** ([`crate::integrator`]): the step minimises the system's
//! potential from the anchor that [`ReducedSystem::begin_step`] forms from the
//! state and the state one step back; h' below is its effective step (h for
//! backward Euler). The velocity after the step is `(q - q_a)/h'`.
//!
//! **Initial guess.** `q_t + h qdot_t + h^2 a`, with `a` the acceleration of the
//! previous step (`(qdot_t - qdot_{t-1}) / h`), or gravity alone (`M^-1 f`) on the
//! first step after a new state. A body that rests, slides steadily or sticks is
//! then almost at the solution before the first iteration, with its contact
//! points in the right friction regime.
//!
//! **Line search.** Every trial point is evaluated with its gradient, which
//! becomes the next iteration's gradient when the trial is accepted; energies
//! are taken relative to the inertial target's gravity work, a constant of the
//! step, so that their differences keep their digits.
//!
//! **Convergence** is measured on the (outer) Newton direction `Delta` at the
//! iterate as the velocity `r = sqrt(Delta^T M Delta / m_total) / h'` (m/s),
//! invariant to the choice of basis; when `r < tolerance` the step `Delta` is
//! taken and the solve stops. `iterations` counts these directions (outer
//! iterations); the model's are counted in [`SolverStats`].

pub(crate) mod contact_model;
pub(crate) mod direction;
pub mod line_search;
pub(crate) mod newton;
mod settings;

#[cfg(test)]
mod tests;

pub use contact_model::{INNER_FORCING, STALLED_STEP};
pub use direction::ELASTIC_DRIFT;
pub use line_search::CURVATURE;
pub use settings::{ElasticHessian, SolverKind, SolverSettings, SolverStats, StepReport};

use crate::cholesky::Cholesky;
use crate::error::{check_finite, check_output, check_positive, LicromError, Result};
use crate::reduced::{ContactHessian, ElasticModel, Hessian, ReducedSystem, StepStart, Workspace};
use crate::validity::Validity;
use contact_model::{ContactModelState, ModelOutcome};
use direction::ElasticPart;
use line_search::{line_search, LineStep};
use newton::{newton_step, NewtonSteps};

/// Directions a prefactored step may take before it continues with Newton's.
/// Its matrix keeps the elastic stiffness at rest, so it converges only
/// linearly, and slowly where the body is far from its rest shape or
/// orientation (a world-frame model turned by tens of degrees); a step whose
/// line search finds no decrease falls back at once. Counted in
/// [`SolverStats::fallbacks`].
pub const PREFACTORED_BUDGET: usize = 25;

/// A value that is there or not, like an `Option`, that keeps its buffers
/// while absent: steps fill and clear these without allocating.
#[derive(Debug)]
struct Kept<T> {
    value: T,
    present: bool,
}

impl<T> Kept<T> {
    /// Absent, with `value` as the buffers to fill.
    fn absent(value: T) -> Self {
        Self { value, present: false }
    }

    fn get(&self) -> Option<&T> {
        self.present.then_some(&self.value)
    }

    fn get_mut(&mut self) -> Option<&mut T> {
        self.present.then_some(&mut self.value)
    }

    /// The buffers to overwrite; present afterwards.
    fn fill(&mut self) -> &mut T {
        self.present = true;
        &mut self.value
    }

    /// The value, filled by `fill` first when absent.
    fn get_or_fill(&mut self, fill: impl FnOnce(&mut T)) -> &T {
        if !self.present {
            fill(&mut self.value);
            self.present = true;
        }
        &self.value
    }

    fn clear(&mut self) {
        self.present = false;
    }
}

/// A point of the iteration and what is kept of its evaluation.
#[derive(Debug)]
struct Point {
    /// Reduced coordinates, n.
    q: Vec<f64>,
    /// Gradient of the objective evaluated there, n.
    grad: Vec<f64>,
    /// Elastic part of the gradient of E, n (not updated by contact-model evaluations).
    grad_elastic: Vec<f64>,
    /// Elastic energy, J.
    energy_elastic: f64,
    /// Smallest det F and deepest penetration there (E evaluations only).
    validity: Validity,
}

impl Point {
    fn zeros(n: usize) -> Self {
        Self { q: vec![0.0; n], grad: vec![0.0; n], grad_elastic: vec![0.0; n], energy_elastic: 0.0, validity: Validity::default() }
    }

    fn copy_from(&mut self, other: &Point) {
        self.q.copy_from_slice(&other.q);
        self.grad.copy_from_slice(&other.grad);
        self.grad_elastic.copy_from_slice(&other.grad_elastic);
        self.energy_elastic = other.energy_elastic;
        self.validity = other.validity;
    }
}

/// What a trial point is evaluated on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Objective {
    /// The incremental potential E.
    Energy,
    /// The contact model of the current outer iteration (see `contact_model.rs`).
    ContactModel,
}

/// State `(q, qdot)` of a reduced model and the preallocated machinery to step it.
#[derive(Debug)]
pub struct ReducedSolver {
    system: ReducedSystem,
    settings: SolverSettings,
    q: Vec<f64>,
    qdot: Vec<f64>,
    /// The state one step back `(q, qdot)`: BDF2's history (after a new
    /// state, that of a free fall, [`crate::integrator`]) and, when `guess_from_previous`,
    /// the initial guess's acceleration.
    q_prev: Vec<f64>,
    qdot_prev: Vec<f64>,
    guess_from_previous: bool,
    /// `h^2 M^-1 f`: the gravity part of the initial guess.
    free_fall: Vec<f64>,
    /// Start of the step in progress.
    current: StepStart,
    /// Start of the last accepted step, for contact forces.
    last: Kept<StepStart>,
    /// Start used by the energy/gradient/Hessian probes, and the probed exact Hessian.
    probe: StepStart,
    probe_hessian: Vec<f64>,
    /// Last iterate of the step that just failed to converge.
    failed: Kept<Vec<f64>>,
    ws: Workspace,
    /// Factor of the matrix last factored, and whether it is that of `matrix`
    /// (a stick correction factors another one).
    chol: Cholesky,
    factor_valid: bool,
    /// The scheme of the step in progress: a prefactored step may fall back to Newton.
    mode: SolverKind,
    /// `K(rest)` (n x n) of the prefactored scheme; empty for Newton.
    rest_stiffness: Vec<f64>,
    /// The current iterate and the line search's trial point.
    iterate: Point,
    trial: Point,
    /// The step from the previous iterate to `iterate` (from the second iteration on).
    step_taken: Vec<f64>,
    /// Search direction from `iterate`.
    dir: Vec<f64>,
    /// Stick-corrected direction (and first its right-hand side).
    stick_dir: Vec<f64>,
    /// The contact model of the current outer iteration.
    model: ContactModelState,
    /// Elastic part of the Newton matrix; absent when it must be assembled.
    /// `K(rest)` while the prefactored scheme is in use.
    elastic: Kept<ElasticPart>,
    /// Contact part of the Newton matrix.
    contact: ContactHessian,
    /// The matrix last factored into `chol`, and whether its elastic part was
    /// the exact (not projected) Hessian.
    matrix: Vec<f64>,
    factored_exact: bool,
    mass_over_h2: Vec<f64>,
    /// Scratch of the drift test (`A^-1` of the secant error) and of the BFGS
    /// update (`A s` and `y`), n each.
    secant_error: Vec<f64>,
    bfgs_as: Vec<f64>,
    bfgs_y: Vec<f64>,
    stats: SolverStats,
    /// [`Self::validity`].
    validity: Validity,
}

impl ReducedSolver {
    /// Solver at rest (`q = qdot = 0`). Assembles `K(rest)` and factors
    /// `M/h^2 + K(rest)` when the prefactored scheme is chosen.
    pub fn new(system: ReducedSystem, settings: SolverSettings) -> Result<Self> {
        check_positive("total_mass", settings.total_mass)?;
        check_positive("tolerance", settings.tolerance)?;
        if settings.max_iterations == 0 {
            return Err(LicromError::invalid("max_iterations", "must be >= 1, got 0"));
        }
        let n = system.n_dofs();
        let h = system.dt();
        let mass_over_h2: Vec<f64> = system.mass().iter().map(|m| m / (h * h)).collect();
        let step = system.time_step();
        let mut chol = Cholesky::new(n);
        chol.factor_shifted(system.mass(), 0.0, system.mass())
            .map_err(|index| LicromError::SingularMass { reason: format!("Cholesky pivot {index} is not positive") })?;
        let mut free_fall: Vec<f64> = system.gravity().iter().map(|f| f * step * step).collect();
        chol.solve_in_place(&mut free_fall);
        let mut ws = system.workspace();
        let zeros = vec![0.0; n];
        let square = vec![0.0; n * n];
        let mut elastic = Kept::absent(ElasticPart::zeros(n));
        let mut matrix = square.clone();
        let mut factor_valid = false;
        let mut stats = SolverStats::default();
        let mut rest_stiffness = Vec::new();
        if settings.kind == SolverKind::Prefactored {
            let rest = elastic.fill();
            rest.assemble(&system, &zeros, &mut ws, false);
            rest_stiffness = rest.projected.clone();
            for ((a, m), k) in matrix.iter_mut().zip(&mass_over_h2).zip(&rest.projected) {
                *a = m + k;
            }
            chol.factor_shifted(&matrix, 0.0, &mass_over_h2)
                .map_err(|index| LicromError::invalid("prefactored system", format!("M/h^2 + K(rest) is not positive definite (pivot {index})")))?;
            // Contact terms enter (and the matrix is factored again) when they appear.
            factor_valid = true;
            stats.elastic_hessians = 1;
            stats.factorizations = 1;
        }
        Ok(Self {
            validity: Validity::default(),
            current: system.step_start(),
            probe: system.step_start(),
            probe_hessian: square.clone(),
            last: Kept::absent(system.step_start()),
            failed: Kept::absent(zeros.clone()),
            settings,
            q: zeros.clone(),
            qdot: zeros.clone(),
            q_prev: zeros.clone(),
            qdot_prev: zeros.clone(),
            guess_from_previous: false,
            free_fall,
            ws,
            chol,
            factor_valid,
            mode: settings.kind,
            rest_stiffness,
            iterate: Point::zeros(n),
            trial: Point::zeros(n),
            step_taken: zeros.clone(),
            dir: zeros.clone(),
            stick_dir: zeros.clone(),
            model: ContactModelState::new(n),
            elastic,
            contact: system.contact_hessian_state(settings.elastic_hessian == ElasticHessian::Lagged),
            matrix,
            factored_exact: false,
            mass_over_h2,
            secant_error: zeros.clone(),
            bfgs_as: zeros.clone(),
            bfgs_y: zeros,
            stats,
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
    /// next step starts from the free-fall guess and fresh elastic and contact
    /// Hessians (the prefactored scheme: `K(rest)`), so that the steps from here
    /// depend on the state alone (the same as a new solver's, bit for bit).
    pub fn set_state(&mut self, q: &[f64], qdot: &[f64]) -> Result<()> {
        self.check_state("q", q)?;
        self.check_state("qdot", qdot)?;
        self.q.copy_from_slice(q);
        self.qdot.copy_from_slice(qdot);
        // `free_fall` is `h^2 M^-1 f`: gravity's acceleration times h^2.
        let h = self.system.time_step();
        for ((((p, v), q), qdot), fall) in self.q_prev.iter_mut().zip(self.qdot_prev.iter_mut()).zip(q).zip(qdot).zip(&self.free_fall) {
            *p = q - h * qdot + 0.5 * fall;
            *v = qdot - fall / h;
        }
        self.guess_from_previous = false;
        self.last.clear();
        self.failed.clear();
        self.contact.invalidate();
        match self.settings.kind {
            SolverKind::Newton => self.elastic.clear(),
            SolverKind::Prefactored => {
                self.elastic.fill().set(&self.rest_stiffness);
                self.mode = SolverKind::Prefactored;
                self.factor_valid = false;
            }
        }
        Ok(())
    }

    /// Advances one time step. On error the state is left unchanged; after
    /// [`LicromError::NotConverged`] the last iterate can be taken with
    /// [`Self::accept_last_iterate`].
    pub fn step(&mut self) -> Result<StepReport> {
        self.failed.clear();
        self.stats.steps += 1;
        let n = self.system.n_dofs();
        let h = self.system.time_step();
        self.system.begin_step(&self.q, &self.qdot, Some((&self.q_prev, &self.qdot_prev)), &mut self.current);
        for i in 0..n {
            let accel = if self.guess_from_previous { h * (self.qdot[i] - self.qdot_prev[i]) } else { self.free_fall[i] };
            self.iterate.q[i] = self.q[i] + h * self.qdot[i] + accel;
        }
        let energy = self.system.evaluate(&self.current, &self.iterate.q, true, &mut self.ws);
        self.iterate.grad.copy_from_slice(&self.ws.grad);
        self.ws.elastic_gradient(&mut self.iterate.grad_elastic);
        self.iterate.energy_elastic = self.ws.elastic_energy;
        self.iterate.validity = self.ws.validity;
        self.stats.evaluations += 1;
        if !energy.is_finite() {
            return Err(LicromError::Diverged { iteration: 0, what: "energy at the initial guess" });
        }
        if self.settings.kind == SolverKind::Prefactored && self.mode == SolverKind::Newton {
            // The last step fell back to Newton: back to K(rest).
            self.elastic.fill().set(&self.rest_stiffness);
            self.factor_valid = false;
            self.mode = SolverKind::Prefactored;
        }
        newton_step(self, energy, self.settings.tolerance, self.settings.max_iterations)
    }

    /// Continues the prefactored step with Newton directions from the current
    /// iterate (see [`PREFACTORED_BUDGET`]).
    fn fall_back(&mut self) {
        self.stats.fallbacks += 1;
        self.mode = SolverKind::Newton;
        self.elastic.clear();
        self.factor_valid = false;
    }

    /// Energy and gradient at `self.trial.q` (gradient into `self.trial`), of
    /// E or of the contact model.
    fn evaluate_trial(&mut self, objective: Objective) -> f64 {
        let e = match objective {
            Objective::ContactModel => {
                self.stats.model_evaluations += 1;
                let outer = &self.model.outer;
                let model =
                    ElasticModel { origin: &outer.q, energy: outer.energy_elastic, gradient: &outer.grad_elastic, hessian: &self.model.hessian };
                self.system.evaluate_model(&self.current, &self.trial.q, &model, true, &mut self.ws)
            }
            Objective::Energy => {
                self.stats.evaluations += 1;
                let e = self.system.evaluate(&self.current, &self.trial.q, true, &mut self.ws);
                self.ws.elastic_gradient(&mut self.trial.grad_elastic);
                self.trial.validity = self.ws.validity;
                e
            }
        };
        self.trial.grad.copy_from_slice(&self.ws.grad);
        self.trial.energy_elastic = self.ws.elastic_energy;
        e
    }

    /// Makes the trial point the iterate.
    fn accept_trial(&mut self) {
        for ((s, t), x) in self.step_taken.iter_mut().zip(&self.trial.q).zip(&self.iterate.q) {
            *s = t - x;
        }
        std::mem::swap(&mut self.iterate, &mut self.trial);
    }

    /// `phi(alpha)` and `phi'(alpha)` of the objective at `x + alpha d`, the point left in `self.trial`.
    fn line_trial(&mut self, alpha: f64, objective: Objective) -> (f64, f64) {
        for ((t, x), d) in self.trial.q.iter_mut().zip(&self.iterate.q).zip(&self.dir) {
            *t = x + alpha * d;
        }
        let e = self.evaluate_trial(objective);
        let slope = self.trial.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        (e, slope)
    }

    /// [`line_search`] from `self.iterate` (energy `e0`) along `self.dir`; moves
    /// the iterate to the step taken.
    fn search_line(&mut self, e0: f64, objective: Objective) -> Option<LineStep> {
        let d0: f64 = self.iterate.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        let step = line_search(e0, d0, |alpha| self.line_trial(alpha, objective))?;
        self.accept_trial();
        Some(step)
    }

    /// The iterate becomes the state, with the velocity `(q - q_a)/h'` from the step's anchor.
    fn finish_step(&mut self) {
        let h = self.system.dt();
        std::mem::swap(&mut self.qdot_prev, &mut self.qdot);
        std::mem::swap(&mut self.q_prev, &mut self.q);
        for ((v, x), a) in self.qdot.iter_mut().zip(&self.iterate.q).zip(self.current.q()) {
            *v = (x - a) / h;
        }
        self.q.copy_from_slice(&self.iterate.q);
        self.guess_from_previous = true;
        self.validity = self.iterate.validity;
        std::mem::swap(self.last.fill(), &mut self.current);
        self.current.keep_strain(&self.last.value);
    }

    /// Smallest det F at the cubature points and deepest penetration of a
    /// contact point at the accepted iterate of the last step (before its
    /// final correction, below the tolerance): [`crate::validity`].
    pub fn validity(&self) -> Validity {
        self.validity
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        self.failed.fill().copy_from_slice(&self.iterate.q);
        LicromError::NotConverged { iterations, residual }
    }

    /// Takes the last iterate of the step that just failed to converge as the
    /// new state (velocity from the difference), as if the step had converged.
    pub fn accept_last_iterate(&mut self) -> Result<()> {
        let Some(failed) = self.failed.get() else {
            return Err(LicromError::invalid("accept_last_iterate", "needs a step that did not converge just before"));
        };
        self.iterate.q.copy_from_slice(failed);
        self.finish_step();
        self.failed.clear();
        Ok(())
    }

    /// Contact forces (C x 3, N) at the current state relative to the start of
    /// the last step; zeros before any step.
    pub fn contact_forces(&self, out: &mut [f64]) -> Result<()> {
        let c = self.system.n_contacts();
        if out.len() != 3 * c {
            return Err(LicromError::shape("out", format!("({c}, 3)"), format!("{} values", out.len())));
        }
        match self.last.get() {
            Some(last) => self.system.contact_forces(last, &self.q, out),
            None => out.fill(0.0),
        }
        check_output("the contact forces", "the state", out)
    }

    fn prepare_probe(&mut self, q: &[f64]) -> Result<()> {
        self.check_state("q", q)?;
        self.system.begin_step(&self.q, &self.qdot, Some((&self.q_prev, &self.qdot_prev)), &mut self.probe);
        Ok(())
    }

    /// Incremental potential E(q) (J) of a step starting from the current state.
    ///
    /// The probes fail with [`LicromError::Overflow`] where `q` (or the state) is
    /// so large that the result is not finite.
    pub fn energy(&mut self, q: &[f64]) -> Result<f64> {
        self.prepare_probe(q)?;
        let e = self.system.energy(&self.probe, q);
        check_output("the energy", "q", &[e])?;
        Ok(e)
    }

    /// Gradient of E at `q` for a step starting from the current state.
    pub fn gradient(&mut self, q: &[f64]) -> Result<&[f64]> {
        self.prepare_probe(q)?;
        self.system.assemble(&self.probe, q, Hessian::None, &mut self.ws);
        check_output("the gradient", "q", &self.ws.grad)?;
        Ok(&self.ws.grad)
    }

    /// Hessian of E at `q` (n x n, symmetric) for a step starting from the
    /// current state; elastic parts PSD-projected when `project`.
    pub fn hessian(&mut self, q: &[f64], project: bool) -> Result<&[f64]> {
        self.prepare_probe(q)?;
        // An elastic energy out of range is where the projection's eigensystem breaks down.
        let e = self.system.energy(&self.probe, q);
        check_output("the Hessian", "q", &[e])?;
        self.system.assemble(&self.probe, q, if project { Hessian::Projected } else { Hessian::Split }, &mut self.ws);
        if project {
            check_output("the Hessian", "q", &self.ws.hess)?;
            return Ok(&self.ws.hess);
        }
        self.ws.exact_hessian(&mut self.probe_hessian);
        check_output("the Hessian", "q", &self.probe_hessian)?;
        Ok(&self.probe_hessian)
    }
}

impl NewtonSteps for ReducedSolver {
    fn iterate_gradient(&self) -> &[f64] {
        &self.iterate.grad
    }

    fn converged_early(&mut self, _tolerance: f64) -> Option<f64> {
        None
    }

    fn newton_direction(&mut self, iteration: usize, full_step: bool) -> Result<f64> {
        if self.mode == SolverKind::Newton {
            self.update_elastic(iteration);
        }
        self.direction(iteration, full_step)
    }

    fn has_contact(&self) -> bool {
        self.system.has_contact()
    }

    fn solve_contact_model(&mut self, energy: f64, residual: f64) -> ModelOutcome {
        ReducedSolver::solve_contact_model(self, energy, residual)
    }

    fn energy_line_search(&mut self, energy: f64) -> Option<LineStep> {
        self.search_line(energy, Objective::Energy)
    }

    fn direction_residual(&self) -> f64 {
        self.velocity_norm(&self.dir)
    }

    /// A prefactored step falls back to Newton's directions.
    fn recover(&mut self) -> bool {
        if self.mode != SolverKind::Prefactored {
            return false;
        }
        self.fall_back();
        true
    }

    /// A prefactored step falls back to Newton's directions after [`PREFACTORED_BUDGET`] iterations.
    fn iterated(&mut self, iteration: usize) {
        if self.mode == SolverKind::Prefactored && iteration >= PREFACTORED_BUDGET {
            self.fall_back();
        }
    }

    fn finish_step(&mut self) {
        ReducedSolver::finish_step(self);
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        ReducedSolver::fail(self, iterations, residual)
    }
}
