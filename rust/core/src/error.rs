//! Errors of the numerics.
//!
//! Every fallible entry point returns [`Result`]; nothing in this crate panics on
//! bad input. The variants fall in three families that bindings map to their own
//! exception types: shape/finiteness problems of arrays (including finite values
//! so large that a result overflows), out-of-range parameters (including a mass
//! matrix that is not SPD), and solver failures.

use thiserror::Error;

/// What can go wrong in the numerics.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum LicromError {
    /// An array does not have the size the other inputs imply.
    #[error("{name} must have shape {expected}, got {got}")]
    ShapeMismatch {
        /// Name of the offending argument.
        name: String,
        /// Expected shape, human readable (e.g. "(100, 9, 32)").
        expected: String,
        /// Shape (or length) actually given.
        got: String,
    },
    /// An input holds NaN or infinite values.
    #[error("{name} holds NaN or inf values")]
    NonFinite {
        /// Name of the offending argument.
        name: String,
    },
    /// A scalar parameter or a value inside an array is outside its accepted range.
    #[error("{name} {reason}")]
    InvalidParameter {
        /// Name of the offending argument.
        name: String,
        /// What is wrong, completing the sentence "<name> ...".
        reason: String,
    },
    /// The reduced mass matrix is not symmetric positive definite.
    #[error("the reduced mass matrix is not symmetric positive definite ({reason})")]
    SingularMass {
        /// Why: asymmetry or the failing Cholesky pivot.
        reason: String,
    },
    /// The step did not reach the tolerance within the iteration budget.
    #[error("the reduced step did not converge in {iterations} iterations (residual {residual:.3e} m/s)")]
    NotConverged {
        /// Number of search directions computed.
        iterations: usize,
        /// Last convergence measure, m/s.
        residual: f64,
    },
    /// A result is NaN or inf although every input is finite: the inputs are
    /// beyond the range that double precision can evaluate.
    #[error("{what} overflowed to NaN or inf: {input} is too large (or too small) to evaluate in double precision")]
    Overflow {
        /// The quantity computed (e.g. "the energy density").
        what: &'static str,
        /// The input to blame (e.g. "F").
        input: &'static str,
    },
    /// A bug: an internal invariant of the numerics failed (a panic, turned into this error by
    /// [`guarded`] at the boundary).
    #[error(
        "internal error in licrom's core ({message}); this is a bug in licrom, please report it with the call that raised it; \
         the object that raised it may be left in an undefined state: make a new one"
    )]
    Internal {
        /// The panic's message.
        message: String,
    },
    /// NaN or inf appeared during the solve (energy, gradient, Hessian or iterate).
    #[error("the reduced step diverged: non-finite {what} at iteration {iteration}")]
    Diverged {
        /// Iteration (1-based) at which it was detected.
        iteration: usize,
        /// Which quantity went non-finite.
        what: &'static str,
    },
}

/// Result type of the crate.
pub type Result<T> = std::result::Result<T, LicromError>;

impl LicromError {
    /// Shorthand for [`LicromError::ShapeMismatch`].
    pub fn shape(name: &str, expected: impl Into<String>, got: impl Into<String>) -> Self {
        Self::ShapeMismatch { name: name.to_owned(), expected: expected.into(), got: got.into() }
    }

    /// Shorthand for [`LicromError::InvalidParameter`].
    pub fn invalid(name: &str, reason: impl Into<String>) -> Self {
        Self::InvalidParameter { name: name.to_owned(), reason: reason.into() }
    }
}

/// Runs `f`, a panic inside it (its threads' included) turned into [`LicromError::Internal`] with the
/// panic's message: the boundary where a bug becomes an error that a caller can handle, never an
/// abort or a foreign exception. The state `f` mutated may be half updated, which the error says.
pub fn guarded<T>(f: impl FnOnce() -> Result<T>) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)).unwrap_or_else(|payload| {
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".to_owned());
        Err(LicromError::Internal { message })
    })
}

/// Checks that every value of `values` is finite.
pub fn check_finite(name: &str, values: &[f64]) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(LicromError::NonFinite { name: name.to_owned() })
    }
}

/// Checks that every value of `values`, computed from finite inputs, is finite:
/// one pass after the computation, not a test inside its loops.
pub fn check_output(what: &'static str, input: &'static str, values: &[f64]) -> Result<()> {
    if all_finite(values) {
        Ok(())
    } else {
        Err(LicromError::Overflow { what, input })
    }
}

/// Whether every value is finite, in a form that vectorises: `0 x` is 0 for a
/// finite `x` and NaN otherwise, summed in eight independent partial sums.
fn all_finite(values: &[f64]) -> bool {
    let mut acc = [0.0_f64; 8];
    let chunks = values.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for l in 0..8 {
            acc[l] += c[l] * 0.0;
        }
    }
    let tail: f64 = rest.iter().map(|v| v * 0.0).sum();
    acc.iter().sum::<f64>() + tail == 0.0
}

/// Checks that a scalar is finite and strictly positive.
pub fn check_positive(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(LicromError::invalid(name, format!("must be a finite number > 0, got {value}")))
    }
}

/// Checks that a scalar is finite and non-negative.
pub fn check_non_negative(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(LicromError::invalid(name, format!("must be a finite number >= 0, got {value}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_check_finds_any_non_finite_value() {
        for len in [0, 1, 7, 8, 9, 17, 100] {
            let mut v: Vec<f64> = (0..len).map(|i| (i as f64 - 3.0) * 1e300).collect();
            assert!(check_output("x", "y", &v).is_ok());
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                for i in 0..len {
                    let keep = v[i];
                    v[i] = bad;
                    assert!(matches!(check_output("x", "y", &v), Err(LicromError::Overflow { .. })), "{bad} at {i} of {len}");
                    v[i] = keep;
                }
            }
        }
    }

    /// Silences the default hook's report for the panics these tests raise on purpose.
    fn quietly<T>(f: impl FnOnce() -> T) -> T {
        let hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(|_| {}));
        let out = f();
        std::panic::set_hook(hook);
        out
    }

    #[test]
    fn guarded_turns_a_panic_into_an_internal_error_with_its_message() {
        let index = 7;
        let out: Result<f64> = quietly(|| guarded(|| Ok([1.0, 2.0][index % 9])));
        assert!(matches!(&out, Err(LicromError::Internal { message }) if message.contains("index out of bounds")), "{out:?}");
        let out: Result<()> = quietly(|| guarded(|| panic!("static message")));
        assert_eq!(out, Err(LicromError::Internal { message: "static message".to_owned() }));
        let out: Result<()> = quietly(|| {
            guarded(|| -> Result<()> {
                std::thread::scope(|s| {
                    s.spawn(|| panic!("in a worker"));
                });
                Ok(())
            })
        });
        assert!(matches!(&out, Err(LicromError::Internal { message }) if message.contains("thread panicked")), "{out:?}");
        assert!(out.unwrap_err().to_string().contains("this is a bug in licrom"));
    }

    #[test]
    fn guarded_passes_results_and_errors_through() {
        assert_eq!(guarded(|| Ok(3)), Ok(3));
        let err: Result<i32> = guarded(|| Err(LicromError::invalid("x", "must be > 0, got -1")));
        assert_eq!(err, Err(LicromError::invalid("x", "must be > 0, got -1")));
    }
}
