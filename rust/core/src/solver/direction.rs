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

use crate::cholesky::Cholesky;
use crate::dense::{mat_vec_add, quadratic_form};
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

/// Factors `matrix`, inertia `inertia` (positive definite) plus positive
/// semi-definite parts, into `chol`. That fails only through round-off; then a
/// growing share of `inertia` is added (to `matrix` too) until it factors.
/// Returns false when no share up to 1e9 does.
pub(crate) fn factor_definite(chol: &mut Cholesky, matrix: &mut [f64], inertia: &[f64]) -> bool {
    if chol.factor_shifted(matrix, 0.0, inertia).is_ok() {
        return true;
    }
    let mut shift = 1e-8;
    while shift <= 1e9 {
        if chol.factor_shifted(matrix, shift, inertia).is_ok() {
            for (h, m) in matrix.iter_mut().zip(inertia) {
                *h += shift * m;
            }
            return true;
        }
        shift *= 10.0;
    }
    false
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
        if !(exact && self.chol.factor_shifted(&self.matrix, 0.0, &self.mass_over_h2).is_ok()) {
            if exact {
                self.factored_exact = false;
                for (h, c) in self.matrix.iter_mut().zip(&elastic.clamped) {
                    *h += c;
                }
            }
            if !factor_definite(&mut self.chol, &mut self.matrix, &self.mass_over_h2) {
                return Err(LicromError::Diverged { iteration, what: "Hessian factorisation" });
            }
        }
        self.factor_valid = true;
        Ok(())
    }

    /// `sqrt(d^T M d / m_total) / h`, m/s.
    pub(super) fn velocity_norm(&self, d: &[f64]) -> f64 {
        metric_norm(self.system.mass(), d) / self.settings.total_mass.sqrt() / self.system.dt()
    }

    /// How far the lagged elastic Hessian is off along the last step
    /// ([`elastic_drift`]). Zero where no Hessian is kept.
    fn elastic_drift(&mut self) -> f64 {
        let Some(elastic) = self.elastic.get() else {
            return 0.0;
        };
        let clamped = self.factored_exact.then_some(&elastic.clamped[..]);
        // After `accept_trial`, `trial` holds the previous iterate.
        let gradients = (&self.iterate.grad_elastic[..], &self.trial.grad_elastic[..]);
        elastic_drift(&mut self.chol, self.system.mass(), (&elastic.projected, clamped), &self.step_taken, gradients, &mut self.secant_error)
    }

    /// BFGS update of the lagged elastic Hessian along the last step ([`secant_update`]).
    fn secant_update(&mut self) {
        if let Some(elastic) = self.elastic.get_mut() {
            let gradients = (&self.iterate.grad_elastic[..], &self.trial.grad_elastic[..]);
            secant_update(&mut elastic.projected, &self.mass_over_h2, &self.step_taken, gradients, (&mut self.bfgs_as, &mut self.bfgs_y));
        }
    }
}

/// `sqrt(v^T m v)` for the positive definite m (N x N); NaN where the form is
/// (`f64::max` would turn it into 0, a direction that overflowed into a
/// converged one).
pub(crate) fn metric_norm(m: &[f64], v: &[f64]) -> f64 {
    let form = quadratic_form(m, v);
    if form < 0.0 {
        0.0
    } else {
        form.sqrt()
    }
}

/// How far a lagged elastic Hessian `K_el` is off along the last step `s`
/// (N, of which the elastic coordinates are the last n): the secant error
/// `e = g_el(x + s) - g_el(x) - K_el s` (`gradients`: the elastic gradients
/// at `x + s` and x, n each) measured as the part of the next direction it
/// causes, `|A^-1 e|_M / |s|_M`, with A the last matrix factored (`chol`) and
/// M any positive definite inertia `metric` (N x N). `stiffness`: `K_el` (n x
/// n) and what to subtract from it (the clamped part where the exact Hessian
/// was factored). Zero where no step was taken. `scratch`: N.
pub(crate) fn elastic_drift(
    chol: &mut Cholesky,
    metric: &[f64],
    stiffness: (&[f64], Option<&[f64]>),
    s: &[f64],
    gradients: (&[f64], &[f64]),
    scratch: &mut [f64],
) -> f64 {
    let (g1, g0) = gradients;
    let (big, n) = (s.len(), g1.len());
    let offset = big - n;
    let den = metric_norm(metric, s);
    if den <= 0.0 || !den.is_finite() {
        return 0.0;
    }
    let (k, clamped) = stiffness;
    scratch[..offset].fill(0.0);
    let (e, s_el) = (&mut scratch[offset..], &s[offset..]);
    for ((e, a), b) in e.iter_mut().zip(g1).zip(g0) {
        *e = a - b;
    }
    mat_vec_add(k, s_el, -1.0, e);
    if let Some(c) = clamped {
        mat_vec_add(c, s_el, 1.0, e);
    }
    chol.solve_in_place(scratch);
    metric_norm(metric, scratch) / den
}

/// BFGS update of a lagged elastic Hessian `stiffness` (`K_el`, n x n) along
/// the last step `s` (N, of which the elastic coordinates are the last n):
/// with `A = M/h^2 + K_el` (`mass_over_h2`: `M/h^2`, n x n) and
/// `y = M s / h^2 + g_el(x + s) - g_el(x)` (the change of the smooth part of
/// the gradient; `gradients` as in [`elastic_drift`]),
/// `A + y y^T / y.s - A s (A s)^T / s.A s` reproduces `y` along `s` and stays
/// positive definite when `y.s > 0` (skipped otherwise). The update goes into
/// `K_el`. `scratch`: `A s` and y, n each.
pub(crate) fn secant_update(stiffness: &mut [f64], mass_over_h2: &[f64], s: &[f64], gradients: (&[f64], &[f64]), scratch: (&mut [f64], &mut [f64])) {
    let (g1, g0) = gradients;
    let (a_s, y) = scratch;
    let n = g1.len();
    let s = &s[s.len() - n..];
    let (a_s, y) = (&mut a_s[..n], &mut y[..n]);
    y.fill(0.0);
    mat_vec_add(mass_over_h2, s, 1.0, y);
    a_s.copy_from_slice(y);
    mat_vec_add(stiffness, s, 1.0, a_s);
    for ((y, a), b) in y.iter_mut().zip(g1).zip(g0) {
        *y += a - b;
    }
    let sas: f64 = s.iter().zip(a_s.iter()).map(|(s, a)| s * a).sum();
    let ys: f64 = s.iter().zip(y.iter()).map(|(s, y)| s * y).sum();
    if !(sas > 0.0 && ys > 1e-8 * sas && sas.is_finite() && ys.is_finite()) {
        return;
    }
    // The rank-two update as `u y^T - v (A s)^T`, the divisions taken out of the n^2 loop.
    let (y_scale, as_scale) = (1.0 / ys, 1.0 / sas);
    for (row, (yi, ai)) in stiffness.chunks_exact_mut(n).zip(y.iter().zip(a_s.iter())) {
        let (u, v) = (yi * y_scale, ai * as_scale);
        for ((k, yj), aj) in row.iter_mut().zip(y.iter()).zip(a_s.iter()) {
            *k += u * yj - v * aj;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::metric_norm;

    #[test]
    fn metric_norm_keeps_nan_and_clamps_round_off_below_zero() {
        let m = [2.0, 0.0, 0.0, 3.0];
        assert_eq!(metric_norm(&m, &[1.0, 1.0]), 5.0f64.sqrt());
        // A direction that overflowed must not measure as converged.
        assert!(metric_norm(&m, &[f64::NAN, 1.0]).is_nan());
        let infinite = metric_norm(&m, &[f64::INFINITY, 0.0]);
        assert!(infinite.is_nan() || infinite == f64::INFINITY, "an infinite direction measures {infinite}");
        assert!(metric_norm(&[f64::INFINITY, 0.0, 0.0, -f64::INFINITY], &[1.0, 1.0]).is_nan());
        // A form below zero by round-off measures zero.
        assert_eq!(metric_norm(&[-1e-300, 0.0, 0.0, 0.0], &[1.0, 0.0]), 0.0);
    }
}
