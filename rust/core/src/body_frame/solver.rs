//! Time stepping of the body-frame model: minimisation of the step's energy
//! over `(c, R, q)` by Newton iterations on `(dc, omega, dq)`, with the
//! world-frame solver's machinery ([`crate::solver`]) wherever the algorithm
//! is the same: its outer iteration (one loop, `solver/newton.rs`), its
//! contact model and stick correction (one driver,
//! [`crate::solver::contact_model`]), its lagged elastic Hessian (one drift
//! test and BFGS update), its incremental contact Hessian (one bookkeeping of
//! the rows put in and taken out) and its line search.
//! What differs is the pose: retraction by the exponential map, directions
//! between poses by its logarithm, and the rotation in the contact Jacobians.
//!
//! **Initial guess.** The previous motion extrapolated with the previous
//! step's acceleration, as in the world-frame solver:
//! `c = c^t + (c^t - c^{t-1}) + (c^t - 2c^{t-1} + c^{t-2})`, likewise q, and
//! `R = exp([2 w_t - w_{t-1}]x) R^t` with `w_t = log(R^t R^{t-1 T})`; after a new
//! state (no pose two steps back) the acceleration is gravity's. A body that
//! rests, slides steadily or spins freely then starts almost at the solution.
//!
//! **Newton matrix.** Positive definite by construction: the inertia by its
//! Gauss-Newton form `J^T M J` over all vertices (the rotation block is the
//! world inertia tensor `R (tr C I - C) R^T`, C = sum m y y^T, from the
//! moments), the contact terms by theirs, the elastic part PSD-projected,
//! factored with [`Cholesky`]. The Gauss-Newton inertia is chosen over the
//! exact one projected to PSD because it is PSD as a whole, cross terms
//! included, with no eigen-decomposition, and differs from the exact one only
//! by terms proportional to the inertial residual `R y_v - a_v`, which are of
//! order h^2 times the accelerations: the iteration stays close to Newton's.
//!
//! The elastic Hessian `K_el` (a pass over the cubature points with an
//! eigen-decomposition each) is lagged as in the world-frame solver: kept
//! across iterations and steps, corrected along every step by BFGS, assembled
//! again after a new state and when its secant error along the last step would
//! make up more than [`BODY_ELASTIC_DRIFT`] of the next direction.
//! The contact part is kept up to date incrementally as `T S T^T`,
//! `T = diag(R, R, I)`, S changing only where a point's terms seen from the
//! body or its lever arm changed ([`super::contact`]).
//!
//! **Contact model and stick correction** (see [`crate::solver::contact_model`]):
//! each Newton direction is replaced by the step to the minimiser of a model
//! of the energy, minimised by the same iteration: inertia, gravity, contact
//! and friction exact in `(c, R, q)`, the elastic energy (a function of q
//! alone, by rotation invariance) by its quadratic expansion in q about the
//! iterate with the lagged `K_el` (`Mqq/h^2` is exactly quadratic already).
//! Where a direction would carry slipping points through the stick region,
//! they are switched to sticking by the low-rank change of the matrix whose
//! rows are `sqrt(c) d^T Jc` in `(dc, omega, dq)`. The outer direction is then
//! the difference `(dc, log(R_m R^T), dq)` to the model's minimiser, which the
//! line search on the energy reaches exactly at alpha = 1.
//!
//! **Line search**: the world-frame solver's ([`crate::solver::line_search`](mod@crate::solver::line_search),
//! one copy, one set of constants) along
//! `alpha -> (c + alpha dc, exp(alpha [omega]x) R, q + alpha dq)`, whose slope
//! is the gradient at the trial point dotted with the direction (the rotations
//! of the line share their axis).
//!
//! **Convergence** as in the world-frame solver: on the outer Newton
//! direction `Delta` at the iterate, `r = sqrt(Delta^T Mg Delta / M)` (m/s)
//! with Mg the Gauss-Newton inertia (with `Mqq`) over h^2: the mass-weighted
//! length of the vertex displacements over h. When `r < tolerance` the step
//! `Delta` is taken and the solve stops. Before forming a new matrix, each
//! iteration first measures the direction on the last factored one: below
//! [`LAST_FACTOR_SHARE`] of the tolerance, that step is taken and the solve
//! stops.
//!
//! **Why**: with only the line search, a lagged elastic block refreshed at
//! most once per step and the whole contact Hessian formed every iteration,
//! the body-frame solver took up to twice the world-frame one's iterations and
//! time on the same block; the contact model, the stick correction, the drift
//! test with its BFGS update and the incremental contact Hessian bring it to
//! the world-frame cost (measured: docs/results.md section 8, "Solver choices, measured").

mod state;

use crate::validity::Validity;
use nalgebra::Matrix3;

use super::contact::BodyContactHessian;
use super::rotation::{exp_map, log_map};
use super::{BodyFrameSystem, BodyHessian, BodyStart, BodyWorkspace, Pose};
use crate::cholesky::Cholesky;
use crate::error::{check_output, check_positive, LicromError, Result};
use crate::reduced::ElasticModel;
use crate::solver::contact_model::{inner_tolerance, minimise_contact_model, ContactModelSteps, ModelOutcome};
use crate::solver::direction::{elastic_drift, factor_definite, metric_norm, secant_update};
use crate::solver::line_search::{line_search, LineStep};
use crate::solver::newton::{newton_step, NewtonSteps};
use crate::solver::{Objective, SolverStats};

/// Tolerance of the orthonormality of a given rotation.
pub const ROTATION_TOLERANCE: f64 = 1e-8;

/// The lagged elastic Hessian is assembled again when its secant error along
/// the last step makes up more than this share of the next direction (the
/// rule of [`crate::solver::ELASTIC_DRIFT`], looser). Its error only slows the
/// outer iteration, and in the body frame it slows it little, while each
/// assembly is a pass over every cubature point with an eigen-decomposition
/// (measured: docs/results.md section 8, "Solver choices, measured").
pub const BODY_ELASTIC_DRIFT: f64 = 0.4;

/// A step is converged on the last factored Newton matrix, without forming
/// and factoring another, when the direction that matrix gives from the
/// iterate measures below this share of the tolerance. Near the solution the
/// matrix changes little from one iterate to the next (the premise of the
/// lagged elastic Hessian), and the margin covers that change; a check that
/// fails costs two triangular solves. Most steps, and most minimisations of
/// the contact model, end this way: their last direction, formerly a matrix
/// formed and factored only to measure a residual already below the
/// tolerance, reuses the factor of the one before.
/// After a stick step solved by the Woodbury identity the last factored
/// matrix is the switched one (the Newton matrix with the stick rows): its
/// switched points stick at the step's end, and their rows are the curvature
/// of sticking (measured: docs/results.md section 8, "Solver choices, measured").
pub const LAST_FACTOR_SHARE: f64 = 0.5;

/// Solver parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyFrameSettings {
    /// Convergence threshold on r, m/s.
    pub tolerance: f64,
    /// Newton directions allowed per step.
    pub max_iterations: usize,
}

/// Outcome of a converged step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyStepReport {
    /// Newton directions computed.
    pub iterations: usize,
    /// Final convergence measure r, m/s.
    pub residual: f64,
}

/// A point of the iteration and what is kept of its evaluation (the
/// world-frame solver's point, with a pose for its coordinates).
#[derive(Debug)]
struct BodyPoint {
    pose: Pose,
    /// Gradient of the objective evaluated there, 6 + n.
    grad: Vec<f64>,
    /// Elastic part of the q-gradient of the energy, n (not updated by
    /// contact-model evaluations), and the elastic energy, J.
    grad_elastic: Vec<f64>,
    energy_elastic: f64,
    /// Smallest det F and deepest penetration there (E evaluations only).
    validity: Validity,
}

impl BodyPoint {
    fn rest(n: usize) -> Self {
        Self { pose: Pose::rest(n), grad: vec![0.0; 6 + n], grad_elastic: vec![0.0; n], energy_elastic: 0.0, validity: Validity::default() }
    }

    fn assign(&mut self, other: &BodyPoint) {
        self.pose.assign(&other.pose);
        self.grad.copy_from_slice(&other.grad);
        self.grad_elastic.copy_from_slice(&other.grad_elastic);
        self.energy_elastic = other.energy_elastic;
        self.validity = other.validity;
    }
}

/// State of a body-frame model (current and previous pose) and the
/// preallocated machinery to step it.
#[derive(Debug)]
pub struct BodyFrameSolver {
    system: BodyFrameSystem,
    settings: BodyFrameSettings,
    pose: Pose,
    prev: Pose,
    /// The poses two and three steps back: BDF2's history (after a new
    /// state, see [`Self::set_state`]) and, when `has_prev2`, the
    /// initial guess's acceleration.
    prev2: Pose,
    prev3: Pose,
    has_prev2: bool,
    current: BodyStart,
    /// Start of the last accepted step, for contact forces (valid if `has_last`).
    last: BodyStart,
    has_last: bool,
    /// Whether `iterate` holds the last iterate of a step that just failed.
    has_failed: bool,
    /// [`Self::validity`].
    validity: Validity,
    probe: BodyStart,
    ws: BodyWorkspace,
    /// The current iterate and the line search's trial point.
    iterate: BodyPoint,
    trial: BodyPoint,
    /// The outer iterate while the contact model is minimised (its expansion
    /// point), and the outer Newton direction (the fallback when the model
    /// makes no progress).
    outer: BodyPoint,
    outer_dir: Vec<f64>,
    /// Search direction from `iterate`, and the stick-corrected one (first its
    /// right-hand side).
    dir: Vec<f64>,
    stick_dir: Vec<f64>,
    /// The matrix last factored into `chol`, and the convergence metric.
    hess: Vec<f64>,
    metric: Vec<f64>,
    chol: Cholesky,
    /// Whether `chol` holds the factor of a Newton matrix (not a stick-switched
    /// one) with `metric` its metric, for [`LAST_FACTOR_SHARE`]; where it does
    /// not, the switched matrix is used when `chol` kept its stick rows.
    newton_factor: bool,
    /// The lagged elastic Hessian `K_el` with its BFGS corrections (valid if
    /// `elastic_valid`), and `Mqq/h^2`, n x n.
    stiffness: Vec<f64>,
    elastic_valid: bool,
    mass_over_h2: Vec<f64>,
    /// The step from the previous iterate to `iterate` (from the second
    /// iteration on), 6 + n.
    step_taken: Vec<f64>,
    /// Scratch of the drift test (6 + n) and of the BFGS update (n each).
    secant_error: Vec<f64>,
    bfgs_as: Vec<f64>,
    bfgs_y: Vec<f64>,
    /// Contact part of the Newton matrix.
    contact: BodyContactHessian,
    stats: SolverStats,
}

/// `r` made orthonormal (two Björck iterations `R <- R (3I - R^T R)/2`, which
/// converge quadratically from a rotation perturbed by round-off).
fn reorthonormalize(r: &Matrix3<f64>) -> Matrix3<f64> {
    let mut m = *r;
    for _ in 0..2 {
        m = m * (Matrix3::identity() * 3.0 - m.transpose() * m) * 0.5;
    }
    m
}

impl BodyFrameSolver {
    /// Solver at rest at the origin.
    pub fn new(system: BodyFrameSystem, settings: BodyFrameSettings) -> Result<Self> {
        check_positive("tolerance", settings.tolerance)?;
        if settings.max_iterations == 0 {
            return Err(LicromError::invalid("max_iterations", "must be >= 1, got 0"));
        }
        let n = system.n_modes();
        let big = 6 + n;
        Ok(Self {
            settings,
            pose: Pose::rest(n),
            prev: Pose::rest(n),
            prev2: Pose::rest(n),
            prev3: Pose::rest(n),
            has_prev2: false,
            validity: Validity::default(),
            current: system.step_start(),
            last: system.step_start(),
            has_last: false,
            has_failed: false,
            probe: system.step_start(),
            ws: system.workspace(),
            iterate: BodyPoint::rest(n),
            trial: BodyPoint::rest(n),
            outer: BodyPoint::rest(n),
            outer_dir: vec![0.0; big],
            dir: vec![0.0; big],
            stick_dir: vec![0.0; big],
            hess: vec![0.0; big * big],
            metric: vec![0.0; big * big],
            chol: Cholesky::new(big),
            newton_factor: false,
            stiffness: vec![0.0; n * n],
            elastic_valid: false,
            mass_over_h2: system.mode_mass().iter().map(|m| m / (system.effective_step() * system.effective_step())).collect(),
            step_taken: vec![0.0; big],
            secant_error: vec![0.0; big],
            bfgs_as: vec![0.0; n],
            bfgs_y: vec![0.0; n],
            contact: system.contact_hessian_state(),
            stats: SolverStats::default(),
            system,
        })
    }

    /// The model.
    pub fn system(&self) -> &BodyFrameSystem {
        &self.system
    }

    /// Work counters (as the world-frame solver's).
    pub fn stats(&self) -> SolverStats {
        self.stats
    }

    /// Zeroes the work counters.
    pub fn reset_stats(&mut self) {
        self.stats = SolverStats::default();
    }

    /// Current pose.
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// Advances one time step. On error the state is left unchanged; after
    /// [`LicromError::NotConverged`] the last iterate can be taken with
    /// [`Self::accept_last_iterate`].
    pub fn step(&mut self) -> Result<BodyStepReport> {
        self.has_failed = false;
        self.stats.steps += 1;
        let h = self.system.dt();
        self.system.begin_step(&[&self.pose, &self.prev, &self.prev2, &self.prev3], &mut self.current);
        let (cur, prev, prev2) = (&self.pose, &self.prev, &self.prev2);
        let turn = self.angular_velocity() * h;
        let guess = &mut self.trial.pose;
        if self.has_prev2 {
            guess.center = 3.0 * (cur.center - prev.center) + prev2.center;
            let previous_turn = log_map(&(prev.rotation * prev2.rotation.transpose()));
            guess.rotation = exp_map(&(2.0 * turn - previous_turn)) * cur.rotation;
            for (((x, q), p), p2) in guess.q.iter_mut().zip(&cur.q).zip(&prev.q).zip(&prev2.q) {
                *x = 3.0 * (q - p) + p2;
            }
        } else {
            guess.center = 2.0 * cur.center - prev.center + self.system.gravity() * (h * h);
            guess.rotation = exp_map(&turn) * cur.rotation;
            for ((x, q), p) in guess.q.iter_mut().zip(&cur.q).zip(&prev.q) {
                *x = 2.0 * q - p;
            }
        }
        let energy = self.evaluate_trial(Objective::Energy);
        std::mem::swap(&mut self.iterate, &mut self.trial);
        if !energy.is_finite() {
            return Err(LicromError::Diverged { iteration: 0, what: "energy at the initial guess" });
        }
        let report = newton_step(self, energy, self.settings.tolerance, self.settings.max_iterations)?;
        Ok(BodyStepReport { iterations: report.iterations, residual: report.residual })
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        self.has_failed = true;
        LicromError::NotConverged { iterations, residual }
    }

    /// Smallest det F at the cubature points and deepest penetration of a
    /// contact point at the accepted iterate of the last step (before its
    /// final correction, below the tolerance): [`crate::validity`].
    pub fn validity(&self) -> Validity {
        self.validity
    }

    /// Takes the last iterate of the step that just failed to converge as the
    /// new pose, as if the step had converged.
    pub fn accept_last_iterate(&mut self) -> Result<()> {
        if !self.has_failed {
            return Err(LicromError::invalid("accept_last_iterate", "needs a step that did not converge just before"));
        }
        self.finish_step();
        self.has_failed = false;
        Ok(())
    }

    /// Keeps, corrects or assembles the lagged elastic Hessian at the start of
    /// an outer iteration, as the world-frame solver does
    /// (with [`BODY_ELASTIC_DRIFT`]): assembled after a new state and when
    /// its drift along the last step exceeds that share, corrected along the
    /// step by BFGS otherwise.
    fn update_elastic(&mut self, iteration: usize) {
        if self.elastic_valid && iteration > 1 {
            // After `accept_trial`, `trial` holds the previous iterate.
            let gradients = (&self.iterate.grad_elastic[..], &self.trial.grad_elastic[..]);
            let drift = elastic_drift(&mut self.chol, &self.metric, (&self.stiffness, None), &self.step_taken, gradients, &mut self.secant_error);
            if drift > BODY_ELASTIC_DRIFT {
                self.elastic_valid = false;
            } else {
                secant_update(&mut self.stiffness, &self.mass_over_h2, &self.step_taken, gradients, (&mut self.bfgs_as, &mut self.bfgs_y));
            }
        }
        if !self.elastic_valid {
            self.stats.elastic_hessians += 1;
            self.system.elastic_stiffness(&self.iterate.pose.q, &mut self.ws, &mut self.stiffness);
            self.elastic_valid = true;
        }
    }

    /// Newton direction at the iterate into `dir`, from the lagged elastic
    /// Hessian and the contact terms of the last evaluation (at the iterate);
    /// returns its residual r.
    fn direction(&mut self, iteration: usize) -> Result<f64> {
        self.system.update_contact_hessian(&mut self.ws, &mut self.contact);
        self.system.newton_matrix(&self.current, &self.iterate.pose, &self.stiffness, &self.contact, &mut self.hess, &mut self.metric);
        if !self.hess.iter().all(|v| v.is_finite()) {
            return Err(LicromError::Diverged { iteration, what: "Hessian" });
        }
        self.stats.factorizations += 1;
        self.newton_factor = factor_definite(&mut self.chol, &mut self.hess, &self.metric);
        if !self.newton_factor {
            return Err(LicromError::Diverged { iteration, what: "Hessian factorisation" });
        }
        for (d, g) in self.dir.iter_mut().zip(&self.iterate.grad) {
            *d = -g;
        }
        self.chol.solve_in_place(&mut self.dir);
        let residual = self.direction_residual();
        if !residual.is_finite() {
            return Err(LicromError::Diverged { iteration, what: "direction" });
        }
        Ok(residual)
    }

    /// The direction from the iterate on the last factored Newton matrix into
    /// `dir`, and its residual, when that is below [`LAST_FACTOR_SHARE`] of
    /// `tolerance` (m/s): the outer iteration's, or the contact model's.
    fn converged_on_last_factor(&mut self, tolerance: f64) -> Option<f64> {
        for (d, g) in self.dir.iter_mut().zip(&self.iterate.grad) {
            *d = -g;
        }
        if self.newton_factor {
            self.chol.solve_in_place(&mut self.dir);
        } else if !self.chol.solve_with_kept_rows(&mut self.dir) {
            return None;
        }
        let residual = self.direction_residual();
        (residual < LAST_FACTOR_SHARE * tolerance).then_some(residual)
    }

    /// Replaces the Newton direction `dir` from the iterate by the step to the
    /// minimiser of the contact model ([`crate::solver`]'s, with the elastic
    /// energy expanded in q about the iterate with the lagged `K_el`); falls
    /// back to the Newton direction when the model makes no progress.
    fn solve_contact_model(&mut self, energy: f64, residual: f64) -> ModelOutcome {
        self.outer.assign(&self.iterate);
        self.outer_dir.copy_from_slice(&self.dir);
        let outcome = minimise_contact_model(self, energy, inner_tolerance(self.settings.tolerance, residual));
        if outcome != ModelOutcome::Stalled {
            self.iterate.pose.difference(&self.outer.pose, &mut self.dir);
        } else {
            self.dir.copy_from_slice(&self.outer_dir);
        }
        std::mem::swap(&mut self.iterate, &mut self.outer);
        outcome
    }

    /// Energy (or contact model) and gradient at `self.trial.pose`, kept in `self.trial`.
    fn evaluate_trial(&mut self, objective: Objective) -> f64 {
        let e = match objective {
            Objective::Energy => {
                self.stats.evaluations += 1;
                let e = self.system.evaluate(&self.current, &self.trial.pose, true, &mut self.ws);
                self.ws.elastic_gradient(&mut self.trial.grad_elastic);
                self.trial.energy_elastic = self.ws.elastic_energy();
                self.trial.validity = self.ws.validity;
                e
            }
            Objective::ContactModel => {
                self.stats.model_evaluations += 1;
                let outer = &self.outer;
                let model =
                    ElasticModel { origin: &outer.pose.q, energy: outer.energy_elastic, gradient: &outer.grad_elastic, hessian: &self.stiffness };
                self.system.evaluate_model(&self.current, &self.trial.pose, &model, true, &mut self.ws)
            }
        };
        self.trial.grad.copy_from_slice(&self.ws.grad);
        e
    }

    /// Energy and slope at `alpha` along the direction (trial point in `trial`).
    fn line_trial(&mut self, alpha: f64, objective: Objective) -> (f64, f64) {
        self.trial.pose.retract(&self.iterate.pose, &self.dir, alpha);
        let e = self.evaluate_trial(objective);
        let d = self.trial.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        (e, d)
    }

    /// Line search from the iterate (value `e0`, [`crate::solver::line_search`](mod@crate::solver::line_search))
    /// on the objective; the accepted point becomes the iterate.
    fn search_line(&mut self, e0: f64, objective: Objective) -> Option<LineStep> {
        let d0: f64 = self.iterate.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        let step = line_search(e0, d0, |alpha| self.line_trial(alpha, objective))?;
        self.accept_trial();
        Some(step)
    }

    /// Makes the trial point the iterate.
    fn accept_trial(&mut self) {
        self.trial.pose.difference(&self.iterate.pose, &mut self.step_taken);
        std::mem::swap(&mut self.iterate, &mut self.trial);
    }

    fn finish_step(&mut self) {
        let pose = &mut self.iterate.pose;
        pose.rotation = reorthonormalize(&pose.rotation);
        std::mem::swap(&mut self.prev3, &mut self.prev2);
        std::mem::swap(&mut self.prev2, &mut self.prev);
        std::mem::swap(&mut self.prev, &mut self.pose);
        self.pose.assign(pose);
        self.validity = self.iterate.validity;
        self.has_prev2 = true;
        std::mem::swap(&mut self.last, &mut self.current);
        // The next step's history repeats this one's poses, whose products the last start holds.
        self.current.take_kept(&mut self.last);
        self.has_last = true;
    }

    /// Contact forces (C x 3, N) at the current pose over the last step; zeros
    /// before any step.
    pub fn contact_forces(&self, out: &mut [f64]) -> Result<()> {
        let c = self.system.n_contacts();
        if out.len() != 3 * c {
            return Err(LicromError::shape("out", format!("({c}, 3)"), format!("{} values", out.len())));
        }
        if self.has_last {
            self.system.contact_forces(&self.last, &self.pose, out);
        } else {
            out.fill(0.0);
        }
        check_output("the contact forces", "the state", out)
    }

    /// Energy (J, without the step's constant) at `pose` of a step from the current state.
    ///
    /// The probes fail with [`LicromError::Overflow`] where the pose (or the
    /// state) is so large that the result is not finite.
    pub fn energy(&mut self, pose: &Pose) -> Result<f64> {
        self.system.begin_step(&[&self.pose, &self.prev, &self.prev2, &self.prev3], &mut self.probe);
        let e = self.system.evaluate(&self.probe, pose, false, &mut self.ws);
        check_output("the energy", "the pose", &[e])?;
        Ok(e)
    }

    /// Gradient (6 + n) at `pose` of a step from the current state.
    pub fn gradient(&mut self, pose: &Pose) -> Result<&[f64]> {
        self.system.begin_step(&[&self.pose, &self.prev, &self.prev2, &self.prev3], &mut self.probe);
        self.system.evaluate(&self.probe, pose, true, &mut self.ws);
        check_output("the gradient", "the pose", &self.ws.grad)?;
        Ok(&self.ws.grad)
    }

    /// Hessian ((6 + n)^2, full symmetric) at `pose` of a step from the current
    /// state: exact, or the solver's positive definite one.
    pub fn hessian(&mut self, pose: &Pose, exact: bool) -> Result<&[f64]> {
        self.system.begin_step(&[&self.pose, &self.prev, &self.prev2, &self.prev3], &mut self.probe);
        // An energy out of range is where the projection's eigensystem breaks down.
        let e = self.system.evaluate(&self.probe, pose, false, &mut self.ws);
        check_output("the Hessian", "the pose", &[e])?;
        let kind = if exact { BodyHessian::Exact } else { BodyHessian::GaussNewton };
        self.system.hessian(&self.probe, pose, kind, &mut self.ws, &mut self.hess);
        check_output("the Hessian", "the pose", &self.hess)?;
        Ok(&self.hess)
    }
}

impl ContactModelSteps for BodyFrameSolver {
    fn stats_mut(&mut self) -> &mut SolverStats {
        &mut self.stats
    }

    fn model_direction(&mut self, tolerance: f64) -> Result<f64> {
        match self.converged_on_last_factor(tolerance) {
            Some(residual) => Ok(residual),
            None => self.direction(0),
        }
    }

    fn take_direction(&mut self) {
        self.trial.pose.retract(&self.iterate.pose, &self.dir, 1.0);
        std::mem::swap(&mut self.iterate, &mut self.trial);
        // The new iterate is not evaluated: it keeps the validity of the point the
        // correction was taken from, not the stale one of the trial buffer.
        self.iterate.validity = self.trial.validity;
    }

    fn switch_rows(&mut self) -> usize {
        self.stick_dir.copy_from_slice(&self.iterate.grad);
        self.system.stick_switch(&self.current, &self.iterate.pose, &self.dir, &mut self.ws, &mut self.stick_dir)
    }

    /// The switched direction was solved on the factor of `hess` (a Newton
    /// matrix, `newton_factor`): few rows are solved on that factor by the
    /// Woodbury identity ([`Cholesky::solve_with_rows`]), more by adding them
    /// and factoring again.
    fn solve_switched(&mut self, rows: usize) -> Option<f64> {
        for a in self.stick_dir.iter_mut() {
            *a = -*a;
        }
        if self.newton_factor && self.chol.rows_worth_update(rows) {
            // The last factor is now that of the switched matrix (the factor
            // kept with the rows), not the Newton matrix's alone, which misjudges
            // the switched points.
            self.chol.solve_with_rows(self.system.switch_rows(&self.ws, rows), rows, &mut self.stick_dir).ok()?;
            self.newton_factor = false;
        } else {
            self.system.add_switch_rows(&self.ws, rows, &mut self.hess);
            self.newton_factor = false;
            self.stats.factorizations += 1;
            self.chol.factor_shifted(&self.hess, 0.0, &self.metric).ok()?;
            self.chol.solve_in_place(&mut self.stick_dir);
        }
        Some(self.iterate.grad.iter().zip(&self.stick_dir).map(|(g, d)| g * d).sum())
    }

    fn stick_trial(&mut self) -> f64 {
        self.trial.pose.retract(&self.iterate.pose, &self.stick_dir, 1.0);
        self.evaluate_trial(Objective::ContactModel)
    }

    fn accept_trial(&mut self) {
        BodyFrameSolver::accept_trial(self);
    }

    fn model_line_search(&mut self, e0: f64) -> Option<LineStep> {
        self.search_line(e0, Objective::ContactModel)
    }
}

impl NewtonSteps for BodyFrameSolver {
    fn iterate_gradient(&self) -> &[f64] {
        &self.iterate.grad
    }

    /// The step ends on the last factored matrix ([`LAST_FACTOR_SHARE`]).
    fn converged_early(&mut self, tolerance: f64) -> Option<f64> {
        self.converged_on_last_factor(tolerance)
    }

    fn newton_direction(&mut self, iteration: usize, _full_step: bool) -> Result<f64> {
        self.update_elastic(iteration);
        self.direction(iteration)
    }

    fn has_contact(&self) -> bool {
        self.system.has_contact()
    }

    fn solve_contact_model(&mut self, energy: f64, residual: f64) -> ModelOutcome {
        BodyFrameSolver::solve_contact_model(self, energy, residual)
    }

    fn energy_line_search(&mut self, energy: f64) -> Option<LineStep> {
        self.search_line(energy, Objective::Energy)
    }

    /// `sqrt(dir^T metric dir / m_total)`, m/s: the metric is the inertia over h^2.
    fn direction_residual(&self) -> f64 {
        metric_norm(&self.metric, &self.dir) / self.system.total_mass().sqrt()
    }

    fn recover(&mut self) -> bool {
        false
    }

    fn iterated(&mut self, _iteration: usize) {}

    fn finish_step(&mut self) {
        BodyFrameSolver::finish_step(self);
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        BodyFrameSolver::fail(self, iterations, residual)
    }
}
