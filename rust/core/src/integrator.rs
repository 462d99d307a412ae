//! Time integrators, both one minimisation per step: backward Euler and BDF2.
//!
//! Each step minimises, over the end positions x,
//!
//! `1/(2h'^2) |x - xt|_M^2 + E(x) + contact(x) + friction(x - x_a)`
//!
//! with an anchor `x_a`, anchor velocity `v_a`, prediction
//! `xt = x_a + h' v_a + h'^2 g` and effective step h'; friction and damping
//! read the velocity `(x - x_a)/h'`, which is also the velocity after the step.
//!
//! - **Backward Euler**: `x_a = x_n`, `v_a = v_n`, `h' = h`.
//! - **BDF2**: `x_a = (4 x_n - x_{n-1})/3`, `v_a = (4 v_n - v_{n-1})/3`,
//!   `h' = 2h/3`. The minimiser and `v = (x - x_a)/h'` then satisfy
//!   `3 x_{n+1} - 4 x_n + x_{n-1} = 2h v_{n+1}` and
//!   `3 v_{n+1} - 4 v_n + v_{n-1} = 2h M^-1 f(x_{n+1})`: second order, and far
//!   less dissipative than backward Euler at the same step.
//!
//! Both lag the normal force of friction at `x_n`. **BDF2's start**: a new
//! state `(x_0, v_0)` gets the history of a free fall,
//! `x_{-1} = x_0 - h v_0 + h^2 g/2`, `v_{-1} = v_0 - h g`, so that every step
//! is a BDF2 step with the same h' and a free fall is exact from the first step
//! (a history of constant velocity would leave a velocity error of `h g/2` for
//! good: BDF2 keeps what its start values get wrong). The full simulation,
//! `python/licrom/full_sim/`, starts the same way.
//!
//! In positions alone (the body-frame model keeps poses, not velocities),
//! with BDF2's velocity `v_n = (3 x_n - 4 x_{n-1} + x_{n-2})/(2h)`:
//! `xt - h'^2 g = (24 x_n - 22 x_{n-1} + 8 x_{n-2} - x_{n-3})/9`, newest first
//! ([`Integrator::target_weights`]).

use crate::error::{LicromError, Result};

/// The time integrator of a reduced model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Integrator {
    /// First order, dissipative.
    #[default]
    BackwardEuler,
    /// Second-order backward differentiation formula.
    Bdf2,
}

impl std::str::FromStr for Integrator {
    type Err = LicromError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "backward_euler" => Ok(Self::BackwardEuler),
            "bdf2" => Ok(Self::Bdf2),
            other => Err(LicromError::invalid("integrator", format!("must be 'backward_euler' or 'bdf2', got '{other}'"))),
        }
    }
}

impl Integrator {
    /// The effective step h' of a step of length `h`, s.
    pub fn effective_step(self, h: f64) -> f64 {
        match self {
            Self::BackwardEuler => h,
            Self::Bdf2 => 2.0 * h / 3.0,
        }
    }

    /// Weight w of the history in the anchor: `x_a = x_n + w (x_n - x_{n-1})`,
    /// `v_a = v_n + w (v_n - v_{n-1})`.
    pub fn history(self) -> f64 {
        match self {
            Self::BackwardEuler => 0.0,
            Self::Bdf2 => 1.0 / 3.0,
        }
    }

    /// `xt - h'^2 g` as weights of the positions `x_n, x_{n-1}, x_{n-2}, x_{n-3}`
    /// (summing to one): `2 x_n - x_{n-1}` for backward Euler.
    pub fn target_weights(self) -> [f64; 4] {
        match self {
            Self::BackwardEuler => [2.0, -1.0, 0.0, 0.0],
            Self::Bdf2 => [24.0 / 9.0, -22.0 / 9.0, 8.0 / 9.0, -1.0 / 9.0],
        }
    }

    /// The velocity after a step as weights of `x_{n+1}, x_n, x_{n-1}` over h
    /// (`(x - x_a)/h'`): `(1, -1, 0)` for backward Euler, `(3, -4, 1)/2` for BDF2.
    pub fn velocity_weights(self) -> [f64; 3] {
        match self {
            Self::BackwardEuler => [1.0, -1.0, 0.0],
            Self::Bdf2 => [1.5, -2.0, 0.5],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The position form of the target agrees with the anchor form
    /// `x_a + h' v_a` when the velocities are BDF2's own.
    #[test]
    fn target_weights_match_the_anchor_form() {
        let h = 0.01;
        let x = [0.3, -0.7, 1.1, 2.0_f64];
        for integrator in [Integrator::BackwardEuler, Integrator::Bdf2] {
            let [a, b, c] = integrator.velocity_weights();
            let v_n = (a * x[0] + b * x[1] + c * x[2]) / h;
            let v_m = (a * x[1] + b * x[2] + c * x[3]) / h;
            let w = integrator.history();
            let anchor = x[0] + w * (x[0] - x[1]) + integrator.effective_step(h) * (v_n + w * (v_n - v_m));
            let weights = integrator.target_weights();
            let target: f64 = weights.iter().zip(x).map(|(w, x)| w * x).sum();
            assert!((anchor - target).abs() < 1e-12, "{integrator:?}: {anchor} vs {target}");
            assert!((weights.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            // The velocity after the step is (x - x_a)/h'.
            let x_new = 0.9;
            let from_anchor = (x_new - (x[0] + w * (x[0] - x[1]))) / integrator.effective_step(h);
            let from_weights = (a * x_new + b * x[0] + c * x[1]) / h;
            assert!((from_anchor - from_weights).abs() < 1e-9, "{integrator:?}: {from_anchor} vs {from_weights}");
        }
    }

    #[test]
    fn names_parse_and_unknown_ones_say_the_accepted_values() {
        assert_eq!("bdf2".parse::<Integrator>().unwrap(), Integrator::Bdf2);
        assert_eq!("backward_euler".parse::<Integrator>().unwrap(), Integrator::BackwardEuler);
        let err = "rk4".parse::<Integrator>().unwrap_err().to_string();
        assert!(err.contains("'backward_euler' or 'bdf2'"), "{err}");
    }
}
