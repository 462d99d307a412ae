//! The search direction: Newton's matrix `A = M/h^2 + K_el + K_c`, its
//! factorisation, and the upkeep of its elastic part.
//!
//! The contact part `K_c` holds the stiff terms (penalty, stick friction) and
//! follows the contact state exactly: it is updated at every iterate by taking
//! out and putting in the rows of the contact points whose terms changed
//! ([`crate::reduced::ContactHessian`]). The elastic part (PSD-projected SNH
//! Hessians at the cubature points) is the expensive one and changes slowly.
//! With [`ElasticHessian::Lagged`] (the default) it is kept from iteration to
//! iteration and from step to step, and improved along every step `s` by a BFGS
//! correction of `M/h^2 + K_el` (so that it reproduces the change of the
//! elastic gradient along `s`); it is assembled again after a new state and
//! when it has drifted: when the secant error `g_el(x + s) - g_el(x) - K_el s`,
//! mapped through the last factored matrix, would make up more than
//! [`ELASTIC_DRIFT`] of the next direction. This makes the outer iteration a
//! quasi-Newton method: every matrix is positive definite, each direction a
//! descent direction, and the fixed point the same minimiser; the convergence
//! measure is taken on its direction. [`ElasticHessian::EveryIteration`] gives
//! plain Newton; there, where the projection clamped some eigenvalue and the
//! previous iteration took the full step, the exact elastic Hessian is tried
//! first (near rest the clamped twist modes would turn Newton's quadratic
//! convergence into a linear one).

use crate::error::{LicromError, Result};
use crate::reduced::{ReducedSystem, Workspace};

use super::{ElasticHessian, ReducedSolver, SolverKind};

/// The lagged elastic Hessian is assembled again when its error along the last
/// step makes up more than this share of the next direction (see the module
/// documentation).
pub const ELASTIC_DRIFT: f64 = 0.1;

/// The elastic part of the Newton matrix.
#[derive(Debug)]
pub(super) struct ElasticPart {
    /// Projected elastic Hessian (with the BFGS corrections when lagged), n x n.
    pub(super) projected: Vec<f64>,
    /// What the projection clamped, n x n (assembled for plain Newton only).
    pub(super) clamped: Vec<f64>,
    /// Whether `clamped` is non-zero.
    any_clamped: bool,
}

impl ElasticPart {
    pub(super) fn zeros(n: usize) -> Self {
        Self { projected: vec![0.0; n * n], clamped: vec![0.0; n * n], any_clamped: false }
    }

    /// A fixed projected Hessian (n x n) that clamps nothing.
    pub(super) fn set(&mut self, projected: &[f64]) {
        self.projected.copy_from_slice(projected);
        self.any_clamped = false;
    }

    /// Assembles the projected Hessian at `q`, and its clamped part when
    /// `with_clamped`.
    pub(super) fn assemble(&mut self, system: &ReducedSystem, q: &[f64], ws: &mut Workspace, with_clamped: bool) {
        let clamped = with_clamped.then_some(&mut self.clamped[..]);
        self.any_clamped = system.elastic_hessian(q, ws, &mut self.projected, clamped);
    }
}

impl ReducedSolver {
    /// Keeps or drops the elastic Hessian at the start of an outer iteration:
    /// plain Newton assembles it at every iterate; lagged, it is dropped when it
    /// has drifted and corrected along the last step otherwise.
    pub(super) fn update_elastic(&mut self, iteration: usize) {
        match self.settings.elastic_hessian {
            ElasticHessian::EveryIteration => self.elastic.clear(),
            ElasticHessian::Lagged if iteration > 1 => {
                if self.elastic_drift() > ELASTIC_DRIFT {
                    self.elastic.clear();
                } else {
                    self.secant_update();
                }
            }
            ElasticHessian::Lagged => {}
        }
    }

    /// Computes the search direction at `self.iterate` into `self.dir` from its
    /// gradient and returns its convergence measure r. `try_exact`: the
    /// previous step was taken in full (see the module documentation).
    ///
    /// Newton factors its matrix at every call. The prefactored scheme keeps the
    /// factor while the contact terms stay as they were when it was formed, and
    /// factors again (counted in [`super::SolverStats::factorizations`]) when
    /// they change: where points touch, lift off, stick or slip.
    pub(super) fn direction(&mut self, iteration: usize, try_exact: bool) -> Result<f64> {
        for (d, g) in self.dir.iter_mut().zip(&self.iterate.grad) {
            *d = -g;
        }
        // The contact terms are those of the evaluation at `self.iterate`.
        let changed = self.system.update_contact_hessian(&mut self.ws, &mut self.contact);
        let reuse = self.mode == SolverKind::Prefactored && self.factor_valid && changed == 0;
        if !reuse {
            self.factor(iteration, try_exact)?;
        }
        self.chol.solve_in_place(&mut self.dir);
        let r = self.velocity_norm(&self.dir);
        if !r.is_finite() {
            return Err(LicromError::Diverged { iteration, what: "search direction" });
        }
        Ok(r)
    }

    /// Forms `M/h^2 + K_el + K_c` in `self.matrix` and factors it into `self.chol`.
    fn factor(&mut self, iteration: usize, try_exact: bool) -> Result<()> {
        self.stats.factorizations += 1;
        self.factor_valid = false;
        // Lagged, the clamped part is not worth its cost (the BFGS correction
        // does better); plain Newton uses it for its quadratic convergence
        // near rest. The prefactored scheme keeps K(rest), which clamps nothing.
        let with_clamped = self.settings.elastic_hessian == ElasticHessian::EveryIteration;
        let (system, ws, q, stats) = (&self.system, &mut self.ws, &self.iterate.q, &mut self.stats);
        let elastic = self.elastic.get_or_fill(|part| {
            stats.elastic_hessians += 1;
            part.assemble(system, q, ws, with_clamped);
        });
        let exact = try_exact && elastic.any_clamped;
        self.factored_exact = exact;
        let contact = self.contact.matrix();
        for i in 0..self.matrix.len() {
            let clamped = if exact { elastic.clamped[i] } else { 0.0 };
            self.matrix[i] = self.mass_over_h2[i] + (elastic.projected[i] - clamped) + contact[i];
        }
        if !self.matrix.iter().all(|v| v.is_finite()) {
            return Err(LicromError::Diverged { iteration, what: "Hessian" });
        }
        let mut factored = self.chol.factor_shifted(&self.matrix, 0.0, &self.mass_over_h2).is_ok();
        if !factored && exact {
            self.factored_exact = false;
            for (h, c) in self.matrix.iter_mut().zip(&elastic.clamped) {
                *h += c;
            }
            factored = self.chol.factor_shifted(&self.matrix, 0.0, &self.mass_over_h2).is_ok();
        }
        // The projected Hessian is M/h^2 plus PSD terms, so this only fails
        // through round-off; a growing share of M/h^2 restores definiteness.
        let mut shift = 1e-8;
        while !factored {
            factored = self.chol.factor_shifted(&self.matrix, shift, &self.mass_over_h2).is_ok();
            if factored {
                for (h, m) in self.matrix.iter_mut().zip(&self.mass_over_h2) {
                    *h += shift * m;
                }
            }
            shift *= 10.0;
            if shift > 1e9 {
                return Err(LicromError::Diverged { iteration, what: "Hessian factorisation" });
            }
        }
        self.factor_valid = true;
        Ok(())
    }

    /// `sqrt(d^T M d / m_total) / h`, m/s.
    pub(super) fn velocity_norm(&self, d: &[f64]) -> f64 {
        let n = self.system.n_dofs();
        let mass = self.system.mass();
        let mut norm2 = 0.0;
        for i in 0..n {
            let row: f64 = (0..n).map(|j| mass[i * n + j] * d[j]).sum();
            norm2 += d[i] * row;
        }
        (norm2.max(0.0) / self.settings.total_mass).sqrt() / self.system.dt()
    }

    /// How far the lagged elastic Hessian is off along the last step `s`: the
    /// secant error `e = g_el(x + s) - g_el(x) - K_el s` measured as the part of
    /// the next direction it causes, `|A^-1 e|_M / |s|_M`, with `A` the last
    /// matrix factored. Zero where no step was taken yet or no Hessian is kept.
    fn elastic_drift(&mut self) -> f64 {
        let n = self.system.n_dofs();
        let den = self.velocity_norm(&self.step_taken);
        if den <= 0.0 || !den.is_finite() {
            return 0.0;
        }
        let Some(elastic) = self.elastic.get() else {
            return 0.0;
        };
        for i in 0..n {
            let mut ks = 0.0;
            for j in 0..n {
                let k = elastic.projected[i * n + j] - if self.factored_exact { elastic.clamped[i * n + j] } else { 0.0 };
                ks += k * self.step_taken[j];
            }
            // After `accept_trial`, `trial` holds the previous iterate.
            self.secant_error[i] = self.iterate.grad_elastic[i] - self.trial.grad_elastic[i] - ks;
        }
        self.chol.solve_in_place(&mut self.secant_error);
        self.velocity_norm(&self.secant_error) / den
    }

    /// BFGS update of the lagged elastic Hessian along the last step `s`: with
    /// `A = M/h^2 + K_el` and `y = M s / h^2 + g_el(x + s) - g_el(x)` (the change
    /// of the smooth part of the gradient), `A + y y^T / y.s - A s (A s)^T / s.A s`
    /// reproduces `y` along `s` and stays positive definite when `y.s > 0`
    /// (skipped otherwise). The update goes into `K_el`.
    fn secant_update(&mut self) {
        let n = self.system.n_dofs();
        let Some(elastic) = self.elastic.get_mut() else {
            return;
        };
        let (mut sas, mut ys) = (0.0, 0.0);
        for i in 0..n {
            let (mut a_s, mut m_s) = (0.0, 0.0);
            for j in 0..n {
                let sj = self.step_taken[j];
                a_s += (self.mass_over_h2[i * n + j] + elastic.projected[i * n + j]) * sj;
                m_s += self.mass_over_h2[i * n + j] * sj;
            }
            self.bfgs_as[i] = a_s;
            self.bfgs_y[i] = m_s + self.iterate.grad_elastic[i] - self.trial.grad_elastic[i];
            sas += self.step_taken[i] * a_s;
            ys += self.step_taken[i] * self.bfgs_y[i];
        }
        if !(sas > 0.0 && ys > 1e-8 * sas && sas.is_finite() && ys.is_finite()) {
            return;
        }
        for i in 0..n {
            for j in 0..n {
                elastic.projected[i * n + j] += self.bfgs_y[i] * self.bfgs_y[j] / ys - self.bfgs_as[i] * self.bfgs_as[j] / sas;
            }
        }
    }
}
