//! Time stepping of the reduced model: Newton on the incremental potential with
//! a PSD-projected Hessian and Armijo backtracking, or the prefactored scheme
//! that reuses one factorisation of `M/h^2 + K(rest)` for every iteration.
//!
//! Newton uses the PSD-projected Hessian (elastic eigenvalues clamped at zero)
//! by default. Projection makes the model Hessian wrong wherever it clamps,
//! which near rest (twist modes with eigenvalues about zero) turns Newton's
//! quadratic convergence into a linear one. So once the previous iteration took
//! the full step (the quadratic model is trustworthy there) and some eigenvalue
//! was clamped, the exact Hessian is tried first; it is used when its Cholesky
//! factorisation succeeds, the projected one otherwise. Either way the direction
//! is a descent direction and the line search guards the step.
//!
//! Convergence is measured on the search direction `Delta` as the velocity
//! `r = sqrt(Delta^T M Delta / m_total) / h` (m/s), invariant to the choice of
//! basis; when `r < tolerance` the step `Delta` is taken and the solve stops.

use crate::cholesky::Cholesky;
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::reduced::{Hessian, ReducedSystem, StepStart, Workspace};

/// How the search direction is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolverKind {
    /// Full Newton: assemble and factor the projected Hessian every iteration.
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
}

/// Outcome of a converged step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Search directions computed.
    pub iterations: usize,
    /// Final convergence measure r, m/s.
    pub residual: f64,
}

/// Armijo sufficient-decrease constant.
const ARMIJO: f64 = 1e-4;
/// Backtracking halvings before the line search gives up.
const MAX_HALVINGS: usize = 40;
/// Energy differences below this many ulps of the energy scale are round-off.
const ROUNDOFF_ULPS: f64 = 64.0;

/// State `(q, qdot)` of a reduced model and the preallocated machinery to step it.
#[derive(Debug)]
pub struct ReducedSolver {
    system: ReducedSystem,
    settings: SolverSettings,
    q: Vec<f64>,
    qdot: Vec<f64>,
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
    trial: Vec<f64>,
    dir: Vec<f64>,
    mass_over_h2: Vec<f64>,
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
        Ok(Self {
            current: system.step_start(),
            probe: system.step_start(),
            last: system.step_start(),
            has_last: false,
            failed: vec![0.0; n],
            has_failed: false,
            settings,
            q: vec![0.0; n],
            qdot: vec![0.0; n],
            free_fall,
            ws,
            chol,
            prefactor,
            iterate: vec![0.0; n],
            trial: vec![0.0; n],
            dir: vec![0.0; n],
            mass_over_h2,
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

    fn check_state(&self, name: &str, v: &[f64]) -> Result<()> {
        let n = self.system.n_dofs();
        if v.len() != n {
            return Err(LicromError::shape(name, format!("({n},)"), format!("{} values", v.len())));
        }
        check_finite(name, v)
    }

    /// Replaces the state. Contact forces read zero until the next step.
    pub fn set_state(&mut self, q: &[f64], qdot: &[f64]) -> Result<()> {
        self.check_state("q", q)?;
        self.check_state("qdot", qdot)?;
        self.q.copy_from_slice(q);
        self.qdot.copy_from_slice(qdot);
        self.has_last = false;
        self.has_failed = false;
        Ok(())
    }

    /// Advances one time step. On error the state is left unchanged; after
    /// [`LicromError::NotConverged`] the last iterate can be taken with
    /// [`Self::accept_last_iterate`].
    pub fn step(&mut self) -> Result<StepReport> {
        self.has_failed = false;
        let n = self.system.n_dofs();
        let h = self.system.dt();
        self.system.begin_step(&self.q, &self.qdot, &mut self.current);
        for i in 0..n {
            self.iterate[i] = self.q[i] + h * self.qdot[i] + self.free_fall[i];
        }
        let mut energy = self.system.energy(&self.current, &self.iterate);
        if !energy.is_finite() {
            return Err(LicromError::Diverged { iteration: 0, what: "energy at the initial guess" });
        }
        let mut residual = f64::INFINITY;
        let mut full_step = false;
        for iteration in 1..=self.settings.max_iterations {
            residual = self.direction(iteration, full_step)?;
            if residual < self.settings.tolerance {
                for (x, d) in self.iterate.iter_mut().zip(&self.dir) {
                    *x += d;
                }
                self.finish_step();
                return Ok(StepReport { iterations: iteration, residual });
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

    /// Computes the search direction at `self.iterate` into `self.dir` (gradient
    /// left in `self.ws.grad`) and returns its convergence measure r. `try_exact`:
    /// the previous step was taken in full (see the module documentation).
    fn direction(&mut self, iteration: usize, try_exact: bool) -> Result<f64> {
        let hessian = match (&self.prefactor, try_exact) {
            (Some(_), _) => Hessian::None,
            (None, false) => Hessian::Projected,
            (None, true) => Hessian::Split,
        };
        self.system.assemble(&self.current, &self.iterate, hessian, &mut self.ws);
        if !self.ws.grad.iter().all(|g| g.is_finite()) {
            return Err(LicromError::Diverged { iteration, what: "gradient" });
        }
        for (d, g) in self.dir.iter_mut().zip(&self.ws.grad) {
            *d = -g;
        }
        match &mut self.prefactor {
            Some(a) => a.solve_in_place(&mut self.dir),
            None => {
                if !self.ws.hess.iter().chain(&self.ws.hess_clamped).all(|v| v.is_finite()) {
                    return Err(LicromError::Diverged { iteration, what: "Hessian" });
                }
                let exact = hessian == Hessian::Split && self.ws.has_clamped && self.chol.factor_shifted(&self.ws.hess, -1.0, &self.ws.hess_clamped).is_ok();
                // The projected Hessian is M/h^2 plus PSD terms, so this only fails
                // through round-off; a growing share of M/h^2 restores definiteness.
                let mut shift = 0.0;
                while !exact && self.chol.factor_shifted(&self.ws.hess, shift, &self.mass_over_h2).is_err() {
                    shift = if shift == 0.0 { 1e-8 } else { shift * 10.0 };
                    if shift > 1e8 {
                        return Err(LicromError::Diverged { iteration, what: "Hessian factorisation" });
                    }
                }
                self.chol.solve_in_place(&mut self.dir);
            }
        }
        let h = self.system.dt();
        let n = self.system.n_dofs();
        let mass = self.system.mass();
        let mut norm2 = 0.0;
        for i in 0..n {
            let row: f64 = (0..n).map(|j| mass[i * n + j] * self.dir[j]).sum();
            norm2 += self.dir[i] * row;
        }
        let r = (norm2.max(0.0) / self.settings.total_mass).sqrt() / h;
        if !r.is_finite() {
            return Err(LicromError::Diverged { iteration, what: "search direction" });
        }
        Ok(r)
    }

    /// Armijo backtracking from `self.iterate` along `self.dir`; moves the
    /// iterate and returns the new energy and the step length taken, or `None`
    /// when no step decreases E beyond round-off.
    fn line_search(&mut self, energy: f64) -> Option<(f64, f64)> {
        let slope: f64 = self.ws.grad.iter().zip(&self.dir).map(|(g, d)| g * d).sum();
        let mut alpha = 1.0;
        for _ in 0..MAX_HALVINGS {
            for ((t, x), d) in self.trial.iter_mut().zip(&self.iterate).zip(&self.dir) {
                *t = x + alpha * d;
            }
            let e = self.system.energy(&self.current, &self.trial);
            let slack = ROUNDOFF_ULPS * f64::EPSILON * energy.abs().max(e.abs());
            if e.is_finite() && e <= energy + ARMIJO * alpha * slope + slack {
                std::mem::swap(&mut self.iterate, &mut self.trial);
                return Some((e, alpha));
            }
            alpha *= 0.5;
        }
        None
    }

    fn finish_step(&mut self) {
        let h = self.system.dt();
        for ((v, x), q) in self.qdot.iter_mut().zip(&self.iterate).zip(&self.q) {
            *v = (x - q) / h;
        }
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
        let settings = SolverSettings { total_mass: model.total_mass, tolerance, max_iterations, kind };
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
        let settings = SolverSettings { total_mass: 1.0, tolerance: 1e-6, max_iterations: 0, kind: SolverKind::Newton };
        assert!(ReducedSolver::new(system, settings).is_err());
    }
}
