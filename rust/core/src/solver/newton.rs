//! The outer Newton iteration of a time step, written once for any solver
//! that provides its steps ([`NewtonSteps`]): the world-frame solver
//! ([`super::ReducedSolver`]) and the body-frame one
//! ([`crate::body_frame::solver`]).
//!
//! Each iteration checks the gradient at the iterate, computes the Newton
//! direction and its convergence measure r (m/s; the solver may first answer
//! from its last factored matrix, see [`NewtonSteps::converged_early`]), takes
//! the whole direction and stops when r is below the tolerance, else replaces
//! the direction by the step to the contact model's minimiser (where the
//! [`ModelSchedule`] wants it, [`super::contact_model`]) and searches the line
//! on E ([`super::line_search`](mod@super::line_search)).
//!
//! A step also ends on the contact model's step when that step's r is below
//! the tolerance. The model is E but for the elastic energy's terms beyond
//! second order, so a short step to its minimiser is as good a measure of the
//! distance to E's as the Newton direction; better where friction sits at the
//! stick/slip boundary: the Newton matrix takes one regime's curvature there,
//! and its direction's r stayed above the tolerance for dozens of full steps
//! that each moved the iterate by a few percent of it (a box hitting the
//! ground at 50 m/s: 100 iterations without converging at 1e-4 m/s; 36 with
//! this rule). A solver may recover from a line search that finds
//! no decrease ([`NewtonSteps::recover`]) and change its scheme after an
//! iteration ([`NewtonSteps::iterated`]).

use super::contact_model::{ContactModelSteps, ModelOutcome, ModelSchedule};
use super::line_search::LineStep;
use super::StepReport;
use crate::error::{LicromError, Result};

/// What the outer iteration needs from a solver beyond the contact model's
/// steps: the solver holds the iterate with its energy's gradient, the search
/// direction, and the state the step ends in.
pub(crate) trait NewtonSteps: ContactModelSteps {
    /// The gradient of E at the iterate.
    fn iterate_gradient(&self) -> &[f64];
    /// The direction from the iterate (into the direction) and its r where
    /// the solver can tell, without forming a new matrix, that the step ends
    /// with it under `tolerance` (m/s); None otherwise.
    fn converged_early(&mut self, tolerance: f64) -> Option<f64>;
    /// The Newton direction at the iterate of outer iteration `iteration`
    /// (from 1) into the direction; its r, m/s. `full_step`: whether the last
    /// line search took the whole direction.
    fn newton_direction(&mut self, iteration: usize, full_step: bool) -> Result<f64>;
    /// Whether the model has contact terms (else the contact model is E's own
    /// Newton model and is not solved).
    fn has_contact(&self) -> bool;
    /// Replaces the direction by the step to the contact model's minimiser
    /// (from the iterate, of energy `energy`; the outer direction's r `residual`).
    fn solve_contact_model(&mut self, energy: f64, residual: f64) -> ModelOutcome;
    /// The r of the direction (m/s), as the Newton direction's is measured.
    fn direction_residual(&self) -> f64;
    /// Line search on E from the iterate (energy `energy`) along the
    /// direction; moves the iterate and returns the step, or None when no step
    /// decreases E.
    fn energy_line_search(&mut self, energy: f64) -> Option<LineStep>;
    /// After a line search that found no decrease: whether the solver changed
    /// its scheme so that the iteration goes on from the same iterate (else
    /// the step fails).
    fn recover(&mut self) -> bool;
    /// After outer iteration `iteration` moved the iterate.
    fn iterated(&mut self, iteration: usize);
    /// The iterate, moved by the last direction, becomes the state.
    fn finish_step(&mut self);
    /// Keeps the iterate of a step that did not converge; the error to report.
    fn fail(&mut self, iterations: usize, residual: f64) -> LicromError;
}

/// Minimises the step's energy from the solver's iterate (energy `energy`
/// there) by at most `max_iterations` outer iterations, down to r below
/// `tolerance` (m/s).
pub(crate) fn newton_step(s: &mut impl NewtonSteps, mut energy: f64, tolerance: f64, max_iterations: usize) -> Result<StepReport> {
    let mut residual = f64::INFINITY;
    let mut full_step = false;
    let mut schedule = ModelSchedule::default();
    for iteration in 1..=max_iterations {
        s.stats_mut().iterations += 1;
        if !s.iterate_gradient().iter().all(|g| g.is_finite()) {
            return Err(LicromError::Diverged { iteration, what: "gradient" });
        }
        if let Some(residual) = s.converged_early(tolerance) {
            s.take_direction();
            s.finish_step();
            return Ok(StepReport { iterations: iteration, residual });
        }
        residual = s.newton_direction(iteration, full_step)?;
        if residual < tolerance {
            s.take_direction();
            s.finish_step();
            return Ok(StepReport { iterations: iteration, residual });
        }
        if s.has_contact() && schedule.wanted() {
            let outcome = s.solve_contact_model(energy, residual);
            schedule.solved(outcome);
            if outcome != ModelOutcome::Stalled {
                let step = s.direction_residual();
                if step < tolerance {
                    s.take_direction();
                    s.finish_step();
                    return Ok(StepReport { iterations: iteration, residual: step });
                }
            }
        }
        match s.energy_line_search(energy) {
            Some(step) => {
                energy = step.energy;
                full_step = step.alpha == 1.0;
                schedule.searched(step.alpha);
            }
            None if s.recover() => {
                full_step = false;
                continue;
            }
            None => return Err(s.fail(iteration, residual)),
        }
        s.iterated(iteration);
    }
    Err(s.fail(max_iterations, residual))
}
