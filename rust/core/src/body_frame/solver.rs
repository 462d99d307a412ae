//! Time stepping of the body-frame model: minimisation of the step's energy
//! over `(c, R, q)` by Newton iterations on `(dc, omega, dq)`.
//!
//! **Initial guess.** The previous motion extrapolated with the previous
//! step's acceleration, as in the world-frame solver:
//! `c = c^t + (c^t - c^{t-1}) + (c^t - 2c^{t-1} + c^{t-2})`, likewise q, and
//! `R = exp([2 w_t - w_{t-1}]x) R^t` with `w_t = log(R^t R^{t-1 T})`; after a new
//! state (no pose two steps back) the acceleration is gravity's. A body that
//! rests, slides steadily or spins freely then starts almost at the solution.
//!
//! **Hessian.** Positive definite by construction: the inertia by its
//! Gauss-Newton form `J^T M J` over all vertices (the rotation block is the
//! world inertia tensor `R (tr C I - C) R^T`, C = sum m y y^T, from the
//! moments), the contact terms by theirs, the elastic part PSD-projected,
//! factored with [`Cholesky`]. The Gauss-Newton inertia is chosen over the
//! exact one projected to PSD because it is PSD as a whole, cross terms
//! included, with no eigen-decomposition, and differs from the exact one only
//! by terms proportional to the inertial residual `R y_v - a_v`, which are of
//! order h^2 times the accelerations: the iteration stays close to Newton's.
//!
//! The elastic block `Mqq/h^2 + K_el` is the expensive part (a pass over the
//! cubature points with an eigen-decomposition each); it is kept across
//! iterations and steps and assembled again after a new state and, at most
//! once per step, when an iteration reduced the residual by less than
//! [`ELASTIC_REFRESH`]: a
//! quasi-Newton iteration with the same minimiser, whose directions are
//! descent directions because every matrix is positive definite.
//!
//! **Line search**: the world-frame solver's ([`crate::solver::line_search`](mod@crate::solver::line_search),
//! one copy, one set of constants) along
//! `alpha -> (c + alpha dc, exp(alpha [omega]x) R, q + alpha dq)`, whose slope
//! is the gradient at the trial point dotted with the direction (the rotations
//! of the line share their axis).
//!
//! **Convergence** as in the world-frame solver: on the Newton direction
//! `Delta` at the iterate, `r = sqrt(Delta^T Mg Delta / M) / h` (m/s) with Mg the
//! Gauss-Newton inertia times h^2: the mass-weighted length of the vertex
//! displacements over h. When `r < tolerance` the step `Delta` is taken and the
//! solve stops.

use nalgebra::{Matrix3, Vector3};

use super::rotation::{exp_map, is_rotation, log_map};
use super::{BodyFrameSystem, BodyHessian, BodyStart, BodyWorkspace, Pose};
use crate::cholesky::Cholesky;
use crate::error::{check_finite, check_output, check_positive, LicromError, Result};
use crate::solver::line_search::line_search;

/// The elastic block is assembled again when an iteration's residual is above
/// this share of the previous one.
pub const ELASTIC_REFRESH: f64 = 0.25;
/// Tolerance of the orthonormality of a given rotation.
pub const ROTATION_TOLERANCE: f64 = 1e-8;

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

/// State of a body-frame model (current and previous pose) and the
/// preallocated machinery to step it.
#[derive(Debug)]
pub struct BodyFrameSolver {
    system: BodyFrameSystem,
    settings: BodyFrameSettings,
    pose: Pose,
    prev: Pose,
    /// The pose two steps back (valid if `has_prev2`), for the initial guess.
    prev2: Pose,
    has_prev2: bool,
    current: BodyStart,
    /// Start of the last accepted step, for contact forces (valid if `has_last`).
    last: BodyStart,
    has_last: bool,
    /// Whether `iterate` holds the last iterate of a step that just failed.
    has_failed: bool,
    probe: BodyStart,
    ws: BodyWorkspace,
    iterate: Pose,
    trial: Pose,
    grad: Vec<f64>,
    dir: Vec<f64>,
    hess: Vec<f64>,
    metric: Vec<f64>,
    chol: Cholesky,
    /// The lagged elastic block (valid if `elastic_valid`), and the residuals of
    /// the step's last two directions (infinite at its start).
    elastic: Vec<f64>,
    elastic_valid: bool,
    /// Whether the block was assembled during this step (a stall from contact
    /// switches is not cured by assembling it again).
    elastic_fresh: bool,
    last_residual: f64,
    previous_residual: f64,
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
            has_prev2: false,
            current: system.step_start(),
            last: system.step_start(),
            has_last: false,
            has_failed: false,
            probe: system.step_start(),
            ws: system.workspace(),
            iterate: Pose::rest(n),
            trial: Pose::rest(n),
            grad: vec![0.0; big],
            dir: vec![0.0; big],
            hess: vec![0.0; big * big],
            metric: vec![0.0; big * big],
            chol: Cholesky::new(big),
            elastic: vec![0.0; n * n],
            elastic_valid: false,
            elastic_fresh: false,
            last_residual: f64::INFINITY,
            previous_residual: f64::INFINITY,
            system,
        })
    }

    /// The model.
    pub fn system(&self) -> &BodyFrameSystem {
        &self.system
    }

    /// Current pose.
    pub fn pose(&self) -> &Pose {
        &self.pose
    }

    /// Velocity of the centre of mass, m/s.
    pub fn velocity(&self) -> Vector3<f64> {
        (self.pose.center - self.prev.center) / self.system.dt()
    }

    /// Angular velocity in the world frame, rad/s: `log(R R'^T) / h`.
    pub fn angular_velocity(&self) -> Vector3<f64> {
        log_map(&(self.pose.rotation * self.prev.rotation.transpose())) / self.system.dt()
    }

    /// Modal velocities into `out` (n), per second.
    pub fn qdot(&self, out: &mut [f64]) {
        let h = self.system.dt();
        for ((o, q), p) in out.iter_mut().zip(&self.pose.q).zip(&self.prev.q) {
            *o = (q - p) / h;
        }
    }

    fn check_vector(&self, name: &str, v: &[f64], len: usize) -> Result<()> {
        if v.len() != len {
            return Err(LicromError::shape(name, format!("({len},)"), format!("{} values", v.len())));
        }
        check_finite(name, v)
    }

    /// Checks the parts of a pose (`rotation` row-major 3 x 3, a rotation to
    /// [`ROTATION_TOLERANCE`]); returns the rotation made exactly orthonormal.
    fn check_pose(&self, center: &[f64], rotation: &[f64], q: &[f64]) -> Result<Matrix3<f64>> {
        self.check_vector("center", center, 3)?;
        self.check_vector("rotation", rotation, 9)?;
        self.check_vector("q", q, self.system.n_modes())?;
        let r = Matrix3::from_row_slice(rotation);
        if !is_rotation(&r, ROTATION_TOLERANCE) {
            return Err(LicromError::invalid("rotation", format!("must be orthonormal with determinant +1 (to {ROTATION_TOLERANCE})")));
        }
        Ok(reorthonormalize(&r))
    }

    /// A validated pose from its parts (see [`Self::set_state`]).
    pub fn make_pose(&self, center: &[f64], rotation: &[f64], q: &[f64]) -> Result<Pose> {
        let r = self.check_pose(center, rotation, q)?;
        Ok(Pose { center: Vector3::from_column_slice(center), rotation: r, q: q.to_vec() })
    }

    /// Replaces the state: pose and velocities (m/s, world angular velocity in
    /// rad/s, modal per second). The previous pose becomes
    /// `(c - h v, exp(-h [w]x) R, q - h qdot)`. Contact forces read zero until
    /// the next step.
    pub fn set_state(&mut self, pose: &Pose, velocity: &[f64], angular_velocity: &[f64], qdot: &[f64]) -> Result<()> {
        let n = self.system.n_modes();
        let rotation = self.check_pose(pose.center.as_slice(), pose.rotation.transpose().as_slice(), &pose.q)?;
        self.check_vector("velocity", velocity, 3)?;
        self.check_vector("angular_velocity", angular_velocity, 3)?;
        self.check_vector("qdot", qdot, n)?;
        let h = self.system.dt();
        let prev_center = pose.center - Vector3::from_column_slice(velocity) * h;
        let prev_rotation = exp_map(&(Vector3::from_column_slice(angular_velocity) * -h)) * rotation;
        let prev_q_finite = pose.q.iter().zip(qdot).all(|(q, v)| (q - h * v).is_finite());
        if !(prev_q_finite && prev_center.iter().chain(prev_rotation.iter()).all(|v| v.is_finite())) {
            return Err(LicromError::Overflow { what: "the previous pose (pose - dt x velocity)", input: "the velocities" });
        }
        self.pose.assign(pose);
        self.pose.rotation = rotation;
        self.prev.center = prev_center;
        self.prev.rotation = prev_rotation;
        for ((p, q), v) in self.prev.q.iter_mut().zip(&pose.q).zip(qdot) {
            *p = q - h * v;
        }
        self.has_last = false;
        self.has_failed = false;
        self.has_prev2 = false;
        self.elastic_valid = false;
        Ok(())
    }

    /// Advances one time step. On error the state is left unchanged; after
    /// [`LicromError::NotConverged`] the last iterate can be taken with
    /// [`Self::accept_last_iterate`].
    pub fn step(&mut self) -> Result<BodyStepReport> {
        self.has_failed = false;
        let h = self.system.dt();
        self.system.begin_step(&self.pose, &self.prev, &mut self.current);
        let (cur, prev, prev2) = (&self.pose, &self.prev, &self.prev2);
        let turn = self.angular_velocity() * h;
        if self.has_prev2 {
            self.iterate.center = 3.0 * (cur.center - prev.center) + prev2.center;
            let previous_turn = log_map(&(prev.rotation * prev2.rotation.transpose()));
            self.iterate.rotation = exp_map(&(2.0 * turn - previous_turn)) * cur.rotation;
            for (((x, q), p), p2) in self.iterate.q.iter_mut().zip(&cur.q).zip(&prev.q).zip(&prev2.q) {
                *x = 3.0 * (q - p) + p2;
            }
        } else {
            self.iterate.center = 2.0 * cur.center - prev.center + self.system.gravity() * (h * h);
            self.iterate.rotation = exp_map(&turn) * cur.rotation;
            for ((x, q), p) in self.iterate.q.iter_mut().zip(&cur.q).zip(&prev.q) {
                *x = 2.0 * q - p;
            }
        }
        let mut energy = self.system.evaluate(&self.current, &self.iterate, true, &mut self.ws);
        self.grad.copy_from_slice(&self.ws.grad);
        if !energy.is_finite() {
            return Err(LicromError::Diverged { iteration: 0, what: "energy at the initial guess" });
        }
        let mut residual = f64::INFINITY;
        self.last_residual = f64::INFINITY;
        self.previous_residual = f64::INFINITY;
        self.elastic_fresh = false;
        for iteration in 1..=self.settings.max_iterations {
            if !self.grad.iter().all(|g| g.is_finite()) {
                return Err(LicromError::Diverged { iteration, what: "gradient" });
            }
            residual = self.direction(iteration)?;
            if residual < self.settings.tolerance {
                self.trial.retract(&self.iterate, &self.dir, 1.0);
                std::mem::swap(&mut self.iterate, &mut self.trial);
                self.finish_step();
                return Ok(BodyStepReport { iterations: iteration, residual });
            }
            match self.line_search(energy) {
                Some(e) => energy = e,
                None => return Err(self.fail(iteration, residual)),
            }
        }
        Err(self.fail(self.settings.max_iterations, residual))
    }

    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError {
        self.has_failed = true;
        LicromError::NotConverged { iterations, residual }
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

    /// Newton direction at the iterate into `dir`; returns its residual r.
    fn direction(&mut self, iteration: usize) -> Result<f64> {
        let big = self.dir.len();
        if !self.elastic_valid || (self.stalled() && !self.elastic_fresh) {
            self.system.elastic_block(&self.iterate.q, false, &mut self.ws, &mut self.elastic);
            self.elastic_valid = true;
            self.elastic_fresh = true;
        }
        self.system.hessian(
            &self.current,
            &self.iterate,
            BodyHessian::GaussNewton,
            Some(&self.elastic),
            &mut self.ws,
            &mut self.hess,
            Some(&mut self.metric),
        );
        if !self.hess.iter().all(|v| v.is_finite()) {
            return Err(LicromError::Diverged { iteration, what: "Hessian" });
        }
        self.chol
            .factor_shifted(&self.hess, 0.0, &self.hess)
            .map_err(|_| LicromError::Diverged { iteration, what: "Hessian (not positive definite)" })?;
        for (d, g) in self.dir.iter_mut().zip(&self.grad) {
            *d = -g;
        }
        self.chol.solve_in_place(&mut self.dir);
        let mut dmd = 0.0;
        for r in 0..big {
            let row: f64 = (0..big).map(|c| self.metric[r * big + c] * self.dir[c]).sum();
            dmd += self.dir[r] * row;
        }
        let residual = (dmd.max(0.0) / self.system.total_mass()).sqrt() / self.system.dt();
        if !residual.is_finite() {
            return Err(LicromError::Diverged { iteration, what: "direction" });
        }
        self.previous_residual = self.last_residual;
        self.last_residual = residual;
        Ok(residual)
    }

    /// Whether the step's last direction reduced the residual by less than
    /// [`ELASTIC_REFRESH`] of the one before it.
    fn stalled(&self) -> bool {
        self.previous_residual.is_finite() && self.last_residual > ELASTIC_REFRESH * self.previous_residual
    }

    /// Energy and slope at `alpha` along the direction (trial point in `trial`,
    /// its gradient in `ws.grad`).
    fn line_trial(&mut self, alpha: f64) -> (f64, f64) {
        self.trial.retract(&self.iterate, &self.dir, alpha);
        let e = self.system.evaluate(&self.current, &self.trial, true, &mut self.ws);
        let d = self.ws.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        (e, d)
    }

    fn accept_trial(&mut self) {
        std::mem::swap(&mut self.iterate, &mut self.trial);
        self.grad.copy_from_slice(&self.ws.grad);
    }

    /// Line search from the iterate (energy `e0`, [`crate::solver::line_search`](mod@crate::solver::line_search));
    /// the accepted point becomes the iterate. Returns its energy, or None when
    /// no acceptable step is found.
    fn line_search(&mut self, e0: f64) -> Option<f64> {
        let d0: f64 = self.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        let step = line_search(e0, d0, |alpha| self.line_trial(alpha))?;
        self.accept_trial();
        Some(step.energy)
    }

    fn finish_step(&mut self) {
        self.iterate.rotation = reorthonormalize(&self.iterate.rotation);
        std::mem::swap(&mut self.prev2, &mut self.prev);
        std::mem::swap(&mut self.prev, &mut self.pose);
        self.pose.assign(&self.iterate);
        self.has_prev2 = true;
        std::mem::swap(&mut self.last, &mut self.current);
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
        self.system.begin_step(&self.pose, &self.prev, &mut self.probe);
        let e = self.system.evaluate(&self.probe, pose, false, &mut self.ws);
        check_output("the energy", "the pose", &[e])?;
        Ok(e)
    }

    /// Gradient (6 + n) at `pose` of a step from the current state.
    pub fn gradient(&mut self, pose: &Pose) -> Result<&[f64]> {
        self.system.begin_step(&self.pose, &self.prev, &mut self.probe);
        self.system.evaluate(&self.probe, pose, true, &mut self.ws);
        check_output("the gradient", "the pose", &self.ws.grad)?;
        Ok(&self.ws.grad)
    }

    /// Hessian ((6 + n)^2, full symmetric) at `pose` of a step from the current
    /// state: exact, or the solver's positive definite one.
    pub fn hessian(&mut self, pose: &Pose, exact: bool) -> Result<&[f64]> {
        self.system.begin_step(&self.pose, &self.prev, &mut self.probe);
        // An energy out of range is where the projection's eigensystem breaks down.
        let e = self.system.evaluate(&self.probe, pose, false, &mut self.ws);
        check_output("the Hessian", "the pose", &[e])?;
        let kind = if exact { BodyHessian::Exact } else { BodyHessian::GaussNewton };
        self.system.hessian(&self.probe, pose, kind, None, &mut self.ws, &mut self.hess, None);
        check_output("the Hessian", "the pose", &self.hess)?;
        Ok(&self.hess)
    }
}
