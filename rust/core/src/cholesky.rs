//! Dense Cholesky (LL^T) factorisation with preallocated memory, on faer.
//!
//! **Recursion threshold 32** instead of faer's 64: below the threshold faer
//! factors column by column, above it recursively in blocks. The solvers
//! factor matrices of n = 26-170 (6 + r body coordinates, or the world-frame
//! modes) ten or more times per step, and at these sizes the smaller
//! threshold is as fast or faster at every n tried (measured: docs/results.md section 8, "Solver choices, measured").

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch, LltParams, LltRegularization};
use faer::linalg::cholesky::llt::solve::solve_in_place;
use faer::{Auto, MatMut, MatRef, Par, Spec};

/// faer's factorisation parameters with the recursion threshold of the module documentation.
fn params() -> Spec<LltParams, f64> {
    Spec::new(LltParams { recursion_threshold: 32, ..<LltParams as Auto<f64>>::auto() })
}

/// Reusable LL^T factorisation of an n x n symmetric positive definite matrix.
pub struct Cholesky {
    n: usize,
    factor: Vec<f64>,
    mem: MemBuffer,
}

impl std::fmt::Debug for Cholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cholesky").field("n", &self.n).finish_non_exhaustive()
    }
}

impl Cholesky {
    /// Buffers for matrices of size n (no factorisation yet).
    pub fn new(n: usize) -> Self {
        let req = cholesky_in_place_scratch::<f64>(n, Par::Seq, params());
        Self { n, factor: vec![0.0; n * n], mem: MemBuffer::new(req) }
    }

    /// Factorises `a` (n x n, symmetric; only its lower triangle is read), allocating.
    /// On failure returns the index of the first non-positive pivot.
    pub fn factor(a: &[f64], n: usize) -> Result<Self, usize> {
        let mut chol = Self::new(n);
        chol.factor_shifted(a, 0.0, a)?;
        Ok(chol)
    }

    /// Factorises `a + shift * b` without allocating (`a`, `b` symmetric n x n).
    /// On failure returns the index of the first non-positive pivot.
    pub fn factor_shifted(&mut self, a: &[f64], shift: f64, b: &[f64]) -> Result<(), usize> {
        if shift == 0.0 {
            self.factor.copy_from_slice(a);
        } else {
            for ((f, x), y) in self.factor.iter_mut().zip(a).zip(b) {
                *f = x + shift * y;
            }
        }
        let mat = MatMut::from_column_major_slice_mut(&mut self.factor, self.n, self.n);
        let stack = MemStack::new(&mut self.mem);
        cholesky_in_place(mat, LltRegularization::default(), Par::Seq, stack, params()).map(|_| ()).map_err(|e| match e {
            faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index } => index,
        })
    }

    /// Solves `A x = rhs` in place with the last successful factorisation.
    pub fn solve_in_place(&mut self, rhs: &mut [f64]) {
        let l = MatRef::from_column_major_slice(&self.factor, self.n, self.n);
        let x = MatMut::from_column_major_slice_mut(rhs, self.n, 1);
        solve_in_place(l, x, Par::Seq, MemStack::new(&mut self.mem));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Rng;

    #[test]
    fn solves_spd_systems_and_rejects_indefinite_ones() {
        let mut rng = Rng::new(9);
        let n = 13;
        let b = rng.vec(n * n, 1.0);
        // A = B^T B + I, full symmetric.
        let mut a = vec![0.0; n * n];
        for r in 0..n {
            for c in 0..n {
                a[r * n + c] = (0..n).map(|k| b[k * n + r] * b[k * n + c]).sum::<f64>() + if r == c { 1.0 } else { 0.0 };
            }
        }
        let x = rng.vec(n, 1.0);
        let mut rhs: Vec<f64> = (0..n).map(|r| (0..n).map(|c| a[r * n + c] * x[c]).sum()).collect();
        let mut chol = Cholesky::factor(&a, n).unwrap();
        chol.solve_in_place(&mut rhs);
        assert!(rhs.iter().zip(&x).all(|(u, v)| (u - v).abs() < 1e-10));
        let mut neg = a.clone();
        neg[5 * n + 5] = -1e3;
        assert!(Cholesky::factor(&neg, n).is_err());
        // The shift repairs it.
        assert!(chol.factor_shifted(&neg, 1e4, &a).is_ok());
    }
}
