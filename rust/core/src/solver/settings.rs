//! Parameters of the reduced solver and what it reports.

use crate::error::{LicromError, Result};

/// How the search direction is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolverKind {
    /// Newton: factor `M/h^2 + K_elastic + K_contact` every iteration (the
    /// elastic part refreshed as [`SolverSettings::elastic_hessian`] says).
    Newton,
    /// Iterate `Delta = -A^-1 grad` with `A = M/h^2 + K(rest) + K_contact`: the
    /// elastic part fixed at rest, factored once, and factored again only when
    /// the contact terms change (points touch, lift off, stick or slip), so that
    /// landings converge like the contact-free motion. A step that needs more
    /// than [`super::PREFACTORED_BUDGET`] directions, or stalls, is finished
    /// with Newton directions.
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

/// Work done by the solver since it was created (or [`super::ReducedSolver::reset_stats`]).
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
    /// Factorizations of the direction's matrix (every direction for Newton;
    /// for the prefactored scheme, one at the start and one per change of the
    /// contact terms).
    pub factorizations: usize,
    /// Prefactored steps finished with Newton directions (see
    /// [`super::PREFACTORED_BUDGET`]).
    pub fallbacks: usize,
    /// Stick-corrected directions solved.
    pub stick_solves: usize,
    /// Stick-corrected steps taken.
    pub stick_steps: usize,
}
