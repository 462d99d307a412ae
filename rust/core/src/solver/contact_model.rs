//! The contact model solved inside each Newton iteration, and friction's stick
//! correction of its directions.
//!
//! **Contact model.** Contact makes E piecewise: a Newton step computed with
//! the contact state of the iterate overshoots or stops short where points
//! touch, lift off, stick or start to slip, and a plain Newton iteration pays
//! a full evaluation for every such switch. So each Newton direction is
//! replaced by the step to the minimiser of a model of E: inertia, gravity and
//! contact exact, the elastic energy by its quadratic expansion at the iterate
//! (with `K_el`; [`crate::reduced::ReducedSystem::evaluate_model`]). Evaluating
//! the model costs no pass over the cubature points, only over the contact
//! points that touch a plane or carry a lagged normal force. It is minimised by
//! the same iteration (stick correction and line search included) to half the
//! tolerance, or to [`INNER_FORCING`] of the outer residual; E then takes the
//! step to its minimiser as the search direction, and only the elastic
//! nonlinearity is left for the next outer iteration.
//!
//! **Stick correction.** Coulomb friction makes the potential nearly non-smooth:
//! its curvature jumps from `a k_f / h` (stick) to almost nothing (slip) over a
//! slip of `mu f_n h / (a k_f)`, typically a fraction of a micrometre. A Newton
//! step from the slip side sees no curvature along the slip and overshoots, and
//! backtracking then crawls. So, when the direction would carry slipping points
//! through the stick region, the system is solved again with those points
//! modelled as sticking (a low-rank change of the Hessian and the right-hand
//! side, [`crate::reduced::ReducedSystem::stick_switch`]), and that step is
//! taken when it decreases the energy enough.

use super::line_search::sufficient_decrease;
use super::{Objective, Point, ReducedSolver};

/// Inner iterations on the contact model per outer iteration.
const MAX_INNER: usize = 20;
/// The contact model is minimised down to this share of the tolerance, or of
/// the outer Newton direction's residual, whichever is larger.
const INNER_TOLERANCE: f64 = 0.5;
/// Share of the outer residual down to which the contact model is minimised
/// (see `INNER_TOLERANCE`).
pub const INNER_FORCING: f64 = 0.01;

/// The contact model of one outer iteration.
#[derive(Debug)]
pub(super) struct ContactModelState {
    /// The outer iterate, the expansion point of the elastic model: its
    /// elastic energy and gradient are the model's, and it is restored with its
    /// gradient once the model is solved.
    pub(super) outer: Point,
    /// The outer Newton direction, the fallback when the model makes no progress.
    outer_dir: Vec<f64>,
    /// The model's elastic Hessian, n x n.
    pub(super) hessian: Vec<f64>,
}

impl ContactModelState {
    pub(super) fn new(n: usize) -> Self {
        Self { outer: Point::zeros(n), outer_dir: vec![0.0; n], hessian: vec![0.0; n * n] }
    }
}

impl ReducedSolver {
    /// Replaces the Newton direction `self.dir` from `self.iterate` by the step
    /// to the minimiser of the contact model (see the module documentation).
    /// Falls back to the Newton direction when the model makes no progress.
    pub(super) fn solve_contact_model(&mut self, energy: f64, residual: f64) {
        let n = self.system.n_dofs();
        let Some(elastic) = self.elastic.get() else {
            return;
        };
        self.model.outer.copy_from(&self.iterate);
        self.model.outer_dir.copy_from_slice(&self.dir);
        let factored_exact = self.factored_exact;
        // The model takes the elastic Hessian of the Newton direction, the exact
        // one only where M/h^2 + K_el is positive definite by itself (the model
        // stays convex when contact terms vanish); with the projected one the
        // model's minimiser would miss the clamped curvature and the outer
        // iteration would converge only linearly.
        let mut exact = factored_exact;
        for ((m, e), c) in self.model.hessian.iter_mut().zip(&elastic.projected).zip(&elastic.clamped) {
            *m = e - if exact { *c } else { 0.0 };
        }
        if exact {
            self.factor_valid = false;
        }
        if exact && self.chol.factor_shifted(&self.mass_over_h2, 1.0, &self.model.hessian).is_err() {
            exact = false;
            self.model.hessian.copy_from_slice(&elastic.projected);
        }
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
                        for (x, d) in self.iterate.q.iter_mut().zip(&self.dir) {
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
            match self.search_line(e, Objective::ContactModel) {
                Some(step) => {
                    e = step.energy;
                    moved = true;
                }
                None => break,
            }
        }
        self.factored_exact = factored_exact;
        for i in 0..n {
            self.dir[i] = if moved { self.iterate.q[i] - self.model.outer.q[i] } else { self.model.outer_dir[i] };
        }
        std::mem::swap(&mut self.iterate, &mut self.model.outer);
    }

    /// The stick correction of `self.dir` (see the module documentation): when
    /// some slipping contact points would be carried through the stick region,
    /// solves again with them sticking and takes that full step if it decreases
    /// the model enough. Returns the new energy when the step was taken.
    fn stick_step(&mut self, energy: f64) -> Option<f64> {
        self.stick_dir.copy_from_slice(&self.iterate.grad);
        // The last evaluation was at `self.iterate` (see `solve_contact_model`).
        let rows = self.system.stick_switch(&self.current, &self.dir, &mut self.ws, &mut self.stick_dir);
        if rows == 0 {
            return None;
        }
        self.stats.stick_solves += 1;
        // `matrix` and `chol` now hold the corrected system; the next direction factors anew.
        self.factor_valid = false;
        self.system.add_switch_rows(&self.ws, rows, &mut self.matrix);
        if self.chol.factor_shifted(&self.matrix, 0.0, &self.mass_over_h2).is_err() {
            return None;
        }
        for a in self.stick_dir.iter_mut() {
            *a = -*a;
        }
        self.chol.solve_in_place(&mut self.stick_dir);
        let slope: f64 = self.iterate.grad.iter().zip(&self.stick_dir).map(|(g, d)| g * d).sum();
        if !(slope.is_finite() && slope < 0.0) {
            return None;
        }
        for ((t, x), d) in self.trial.q.iter_mut().zip(&self.iterate.q).zip(&self.stick_dir) {
            *t = x + d;
        }
        let e = self.evaluate_trial(Objective::ContactModel);
        if sufficient_decrease(energy, slope, 1.0, e) {
            self.stats.stick_steps += 1;
            self.accept_trial();
            Some(e)
        } else {
            None
        }
    }
}
