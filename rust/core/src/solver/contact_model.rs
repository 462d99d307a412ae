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
//! nonlinearity is left for the next outer iteration. Once the model's
//! minimiser is Newton's own full step, the rest of the time step goes without
//! it ([`ModelOutcome::Settled`]).
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
//!
//! The iteration on the model ([`minimise_contact_model`]) and the stick step
//! are written once for any solver that provides its steps
//! ([`ContactModelSteps`]): the world-frame solver here, the body-frame one in
//! [`crate::body_frame::solver`].

use super::line_search::{sufficient_decrease, LineStep};
use super::{Objective, Point, ReducedSolver, SolverStats};
use crate::error::Result;

/// Inner iterations on the contact model per outer iteration.
const MAX_INNER: usize = 20;
/// The contact model is minimised down to this share of the tolerance, or of
/// the outer Newton direction's residual, whichever is larger.
const INNER_TOLERANCE: f64 = 0.5;
/// Share of the outer residual down to which the contact model is minimised
/// (see `INNER_TOLERANCE`). The outer iteration converges at about 0.1 per
/// iteration where the lagged elastic block leads it, so a model solved
/// further is not followed (measured: docs/results.md section 8, "Solver choices, measured").
pub const INNER_FORCING: f64 = 0.1;
/// A line search on E that ends below this step length along the model's
/// direction made no progress: the model's minimiser lies where E does not
/// decrease (a friction switch that the lagged elastic model misjudges), and
/// the model would lead there again. The next outer iteration then searches
/// along the plain Newton direction ([`ModelSchedule`]); without that rule a
/// step can stall for good (measured: docs/results.md section 8, "Solver choices, measured").
pub const STALLED_STEP: f64 = 1e-4;

/// Whether the outer iterations of one time step solve the contact model: not
/// after a line search on E that stalled along the model's direction
/// ([`STALLED_STEP`]: the next iteration takes the plain Newton direction), and
/// not after the model has settled ([`ModelOutcome::Settled`]) while the line
/// search keeps taking full steps. One schedule per step, shared by the solvers.
#[derive(Debug, Default)]
pub(crate) struct ModelSchedule {
    stalled: bool,
    settled: bool,
}

impl ModelSchedule {
    /// Whether the next outer iteration solves the contact model.
    pub(crate) fn wanted(&self) -> bool {
        !self.stalled && !self.settled
    }

    /// Records what the contact model of this outer iteration did.
    pub(crate) fn solved(&mut self, outcome: ModelOutcome) {
        self.settled = outcome == ModelOutcome::Settled;
    }

    /// Records the step length of this outer iteration's line search on E.
    pub(crate) fn searched(&mut self, alpha: f64) {
        self.stalled = alpha < STALLED_STEP;
        self.settled &= alpha == 1.0;
    }
}

/// What the iteration on the contact model did with the outer Newton direction.
///
/// **Settled.** Where the model's minimiser is the outer direction's full
/// step (taken at once, no stick correction, the model's next direction below
/// its tolerance), contact and friction did not change what Newton's step
/// does; the outer iteration then only removes the elastic nonlinearity, in
/// ever shorter steps. The rest of the time step goes without the model while
/// the line search on E keeps taking full steps (a shorter one means
/// something switched, and the model comes back). Once settled, the model
/// would only spend an evaluation and a factorisation an iteration confirming
/// the Newton step (measured: docs/results.md section 8, "Solver choices, measured").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ModelOutcome {
    /// No step decreased the model: the outer Newton direction stands.
    Stalled,
    /// The model's minimiser is the outer direction's full step (see above).
    Settled,
    /// The iterate moved to the model's minimiser elsewhere.
    Moved,
}

/// What the iteration on the contact model needs from a solver. The solver
/// holds an iterate (with the gradient of the model there), a search
/// direction and a trial point; the last evaluation with gradient is at the
/// iterate whenever a direction or a stick switch is asked for.
pub(crate) trait ContactModelSteps {
    /// Work counters.
    fn stats_mut(&mut self) -> &mut SolverStats;
    /// The model's Newton direction at the iterate (into the direction); its
    /// convergence measure r, m/s. A solver may answer with the direction of
    /// its last factored matrix where that measures well below `tolerance`
    /// (the inner iteration's, m/s), which ends the iteration as surely.
    fn model_direction(&mut self, tolerance: f64) -> Result<f64>;
    /// Moves the iterate by the whole direction.
    fn take_direction(&mut self);
    /// Forms the stick switch of the direction (rows and right-hand side, see
    /// the module documentation); returns its rows (0: no point switches).
    fn switch_rows(&mut self) -> usize;
    /// Solves with the `rows` switch rows added into the stick-corrected
    /// direction; returns its slope (the model's gradient at the iterate along
    /// it), or None when the system cannot be factored.
    fn solve_switched(&mut self, rows: usize) -> Option<f64>;
    /// The model at the iterate moved by the whole stick-corrected direction,
    /// the point left as the trial point.
    fn stick_trial(&mut self) -> f64;
    /// Makes the trial point the iterate.
    fn accept_trial(&mut self);
    /// Line search on the model from the iterate (model value `e0`) along the
    /// direction; moves the iterate and returns the step taken (with the
    /// model's value there), or None when no step decreases it.
    fn model_line_search(&mut self, e0: f64) -> Option<LineStep>;
}

/// Tolerance on r (m/s) of the model of an outer iteration of residual
/// `residual` (m/s) under the solver's `tolerance`: solving the model much
/// closer than the outer iteration can follow (its elastic part is only a
/// model) is wasted work.
pub(crate) fn inner_tolerance(tolerance: f64, residual: f64) -> f64 {
    (INNER_TOLERANCE * tolerance).max(INNER_FORCING * residual)
}

/// Minimises the contact model from the solver's iterate (model value
/// `energy` there, the outer Newton direction as its first direction) until
/// its direction's r is below `tolerance`.
pub(crate) fn minimise_contact_model(s: &mut impl ContactModelSteps, energy: f64, tolerance: f64) -> ModelOutcome {
    let mut e = energy;
    let mut outcome = ModelOutcome::Stalled;
    // Whether every step so far is the outer direction's full step.
    let mut newton_step = true;
    for inner in 0..MAX_INNER {
        if inner > 0 {
            s.stats_mut().model_iterations += 1;
            match s.model_direction(tolerance) {
                Ok(r) if r < tolerance => {
                    s.take_direction();
                    if newton_step && inner == 1 {
                        outcome = ModelOutcome::Settled;
                    }
                    break;
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
        if let Some(e1) = stick_step(s, e) {
            e = e1;
            outcome = ModelOutcome::Moved;
            newton_step = false;
            continue;
        }
        match s.model_line_search(e) {
            Some(step) => {
                e = step.energy;
                outcome = ModelOutcome::Moved;
                newton_step &= step.alpha == 1.0;
            }
            None => break,
        }
    }
    outcome
}

/// The stick correction of the direction (see the module documentation):
/// when some slipping contact points would be carried through the stick
/// region, solves again with them sticking and takes that full step if it
/// decreases the model enough. Returns the new model value when the step was
/// taken.
fn stick_step(s: &mut impl ContactModelSteps, energy: f64) -> Option<f64> {
    let rows = s.switch_rows();
    if rows == 0 {
        return None;
    }
    s.stats_mut().stick_solves += 1;
    let slope = s.solve_switched(rows)?;
    if !(slope.is_finite() && slope < 0.0) {
        return None;
    }
    let e = s.stick_trial();
    if sufficient_decrease(energy, slope, 1.0, e) {
        s.stats_mut().stick_steps += 1;
        s.accept_trial();
        Some(e)
    } else {
        None
    }
}

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
    /// Whether that is the exact elastic Hessian (else the projected one).
    exact: bool,
}

impl ContactModelState {
    pub(super) fn new(n: usize) -> Self {
        Self { outer: Point::zeros(n), outer_dir: vec![0.0; n], hessian: vec![0.0; n * n], exact: false }
    }
}

impl ReducedSolver {
    /// Replaces the Newton direction `self.dir` from `self.iterate` by the step
    /// to the minimiser of the contact model (see the module documentation).
    /// Falls back to the Newton direction when the model makes no progress.
    pub(super) fn solve_contact_model(&mut self, energy: f64, residual: f64) -> ModelOutcome {
        let n = self.system.n_dofs();
        let Some(elastic) = self.elastic.get() else {
            return ModelOutcome::Stalled;
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
        self.model.exact = exact;
        let outcome = minimise_contact_model(self, energy, inner_tolerance(self.settings.tolerance, residual));
        let moved = outcome != ModelOutcome::Stalled;
        self.factored_exact = factored_exact;
        for i in 0..n {
            self.dir[i] = if moved { self.iterate.q[i] - self.model.outer.q[i] } else { self.model.outer_dir[i] };
        }
        std::mem::swap(&mut self.iterate, &mut self.model.outer);
        outcome
    }
}

impl ContactModelSteps for ReducedSolver {
    fn stats_mut(&mut self) -> &mut SolverStats {
        &mut self.stats
    }

    fn model_direction(&mut self, _tolerance: f64) -> Result<f64> {
        self.direction(0, self.model.exact)
    }

    fn take_direction(&mut self) {
        for (x, d) in self.iterate.q.iter_mut().zip(&self.dir) {
            *x += d;
        }
    }

    fn switch_rows(&mut self) -> usize {
        // The last evaluation was at `self.iterate` (see `ContactModelSteps`).
        self.stick_dir.copy_from_slice(&self.iterate.grad);
        self.system.stick_switch(&self.current, &self.dir, &mut self.ws, &mut self.stick_dir)
    }

    /// Few rows are solved on the factor of `matrix` by the Woodbury identity
    /// ([`crate::cholesky::Cholesky::solve_with_rows`]), more by adding them and
    /// factoring again; the next direction factors anew either way.
    fn solve_switched(&mut self, rows: usize) -> Option<f64> {
        for a in self.stick_dir.iter_mut() {
            *a = -*a;
        }
        let on_factor = self.factor_valid && self.chol.rows_worth_update(rows);
        self.factor_valid = false;
        if on_factor {
            self.chol.solve_with_rows(self.system.switch_rows(&self.ws, rows), rows, &mut self.stick_dir).ok()?;
        } else {
            self.system.add_switch_rows(&self.ws, rows, &mut self.matrix);
            self.chol.factor_shifted(&self.matrix, 0.0, &self.mass_over_h2).ok()?;
            self.chol.solve_in_place(&mut self.stick_dir);
        }
        Some(self.iterate.grad.iter().zip(&self.stick_dir).map(|(g, d)| g * d).sum())
    }

    fn stick_trial(&mut self) -> f64 {
        for ((t, x), d) in self.trial.q.iter_mut().zip(&self.iterate.q).zip(&self.stick_dir) {
            *t = x + d;
        }
        self.evaluate_trial(Objective::ContactModel)
    }

    fn accept_trial(&mut self) {
        ReducedSolver::accept_trial(self);
    }

    fn model_line_search(&mut self, e0: f64) -> Option<LineStep> {
        self.search_line(e0, Objective::ContactModel)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::line_search::line_search;

    /// A one-dimensional solver for the driver: the model is `phi` (value and
    /// slope), every direction's matrix the number `curvature`, no stick switch.
    struct Line {
        phi: fn(f64) -> (f64, f64),
        curvature: f64,
        x: f64,
        dir: f64,
        stats: SolverStats,
    }

    impl Line {
        /// At `x`, with the Newton direction there as the outer direction.
        fn at(phi: fn(f64) -> (f64, f64), curvature: f64, x: f64) -> Self {
            Self { phi, curvature, x, dir: -phi(x).1 / curvature, stats: SolverStats::default() }
        }
    }

    impl ContactModelSteps for Line {
        fn stats_mut(&mut self) -> &mut SolverStats {
            &mut self.stats
        }
        fn model_direction(&mut self, _tolerance: f64) -> Result<f64> {
            self.dir = -(self.phi)(self.x).1 / self.curvature;
            Ok(self.dir.abs())
        }
        fn take_direction(&mut self) {
            self.x += self.dir;
        }
        fn switch_rows(&mut self) -> usize {
            0
        }
        fn solve_switched(&mut self, _rows: usize) -> Option<f64> {
            None
        }
        fn stick_trial(&mut self) -> f64 {
            f64::NAN
        }
        fn accept_trial(&mut self) {}
        fn model_line_search(&mut self, e0: f64) -> Option<LineStep> {
            let (x, dir, phi) = (self.x, self.dir, self.phi);
            let step = line_search(e0, phi(x).1 * dir, |alpha| {
                let (e, slope) = phi(x + alpha * dir);
                (e, slope * dir)
            })?;
            self.x = x + step.alpha * dir;
            Some(step)
        }
    }

    fn quadratic(x: f64) -> (f64, f64) {
        (0.5 * x * x, x)
    }

    fn steep_quadratic(x: f64) -> (f64, f64) {
        (2.0 * x * x, 4.0 * x)
    }

    fn quartic(x: f64) -> (f64, f64) {
        (0.5 * x * x + 0.25 * x.powi(4), x + x.powi(3))
    }

    #[test]
    fn the_schedule_leaves_the_model_out_after_it_settled_or_stalled_until_a_step_is_shortened() {
        let mut schedule = ModelSchedule::default();
        assert!(schedule.wanted());
        schedule.solved(ModelOutcome::Moved);
        schedule.searched(1.0);
        assert!(schedule.wanted(), "{schedule:?}");
        schedule.solved(ModelOutcome::Settled);
        schedule.searched(1.0);
        assert!(!schedule.wanted(), "{schedule:?}");
        schedule.searched(1.0);
        assert!(!schedule.wanted(), "settled while the steps are full: {schedule:?}");
        schedule.searched(0.5);
        assert!(schedule.wanted(), "a shortened step brings the model back: {schedule:?}");
        schedule.searched(0.1 * STALLED_STEP);
        assert!(!schedule.wanted(), "a stalled step leaves it out: {schedule:?}");
        schedule.searched(0.5);
        assert!(schedule.wanted(), "for one iteration only: {schedule:?}");
    }

    fn minimise(line: &mut Line) -> ModelOutcome {
        let e0 = (line.phi)(line.x).0;
        minimise_contact_model(line, e0, 1e-6)
    }

    #[test]
    fn a_model_whose_minimiser_is_the_full_newton_step_has_settled() {
        let mut line = Line::at(quadratic, 1.0, 0.3);
        assert_eq!(minimise(&mut line), ModelOutcome::Settled);
        assert!(line.x.abs() < 1e-12 && line.stats.model_iterations == 1, "x = {}, {:?}", line.x, line.stats);
    }

    #[test]
    fn a_shortened_step_or_a_further_direction_is_not_settled() {
        // The matrix misses 3/4 of the curvature: the full step overshoots and the line search shortens it.
        let mut overshoot = Line::at(steep_quadratic, 1.0, 0.3);
        assert_eq!(minimise(&mut overshoot), ModelOutcome::Moved);
        assert!(overshoot.x.abs() < 1e-6, "x = {}", overshoot.x);
        // The full step is taken, but the model's minimiser lies beyond it: more directions follow.
        let mut curved = Line::at(quartic, 1.0, 0.5);
        assert_eq!(minimise(&mut curved), ModelOutcome::Moved);
        assert!(curved.x.abs() < 1e-6 && curved.stats.model_iterations > 1, "x = {}, {:?}", curved.x, curved.stats);
    }
}
