//! Dense Cholesky (LL^T) factorisation with preallocated memory, on faer.
//!
//! **Recursion threshold 32** instead of faer's 64: below the threshold faer
//! factors column by column, above it recursively in blocks. The solvers
//! factor matrices of n = 26-170 (6 + r body coordinates, or the world-frame
//! modes) ten or more times per step, and at these sizes the smaller
//! threshold is as fast or faster at every n tried (measured: docs/results.md section 8, "Solver choices, measured").
//!
//! **Rows added to a factored matrix** ([`Cholesky::solve_with_rows`]): friction's
//! stick correction solves `(A + B^T B) x = b` with A just factored and B a
//! few rows (k, one or two per switched contact point). By the Woodbury
//! identity, with `A = L L^T`, `Z = L^-1 B^T` (n x k) and `S = I + Z^T Z`
//! (k x k, eigenvalues >= 1, so well conditioned whatever A's):
//! `x = L^-T (w - Z S^-1 Z^T w)`, `w = L^-1 b`. That costs `k n^2 + k^2 n +
//! k^3/3` flops against `k n^2 + n^3/3` to add the rows and factor again: the cheaper for k up to
//! about half of n, measured ([`WOODBURY_MAX_SHARE`]), and A's factor is kept.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt::factor::{cholesky_in_place, cholesky_in_place_scratch, LltParams, LltRegularization};
use faer::linalg::cholesky::llt::solve::solve_in_place;
use faer::linalg::triangular_solve::{solve_lower_triangular_in_place, solve_upper_triangular_in_place};
use faer::{Accum, Auto, MatMut, MatRef, Par, Spec};

use crate::dense::syrk_columns;

/// [`Cholesky::solve_with_rows`] takes rows up to this share of n; above it
/// adding them to the matrix and factoring it again costs less (see the module
/// documentation; measured: docs/results.md section 8, "Solver choices, measured").
pub const WOODBURY_MAX_SHARE: f64 = 0.4;

/// faer's factorisation parameters with the recursion threshold of the module documentation.
fn params() -> Spec<LltParams, f64> {
    Spec::new(LltParams { recursion_threshold: 32, ..<LltParams as Auto<f64>>::auto() })
}

/// Reusable LL^T factorisation of an n x n symmetric positive definite matrix.
pub struct Cholesky {
    n: usize,
    factor: Vec<f64>,
    mem: MemBuffer,
    /// Scratch of [`Self::solve_with_rows`]: Z (n x k), the factor of S
    /// (k x k) and `Z^T w` (k), allocated for k up to n.
    z: Vec<f64>,
    s: Vec<f64>,
    u: Vec<f64>,
    /// Rows of the last [`Self::solve_with_rows`] on the current factor (0: none).
    kept_rows: usize,
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
        Self { n, factor: vec![0.0; n * n], mem: MemBuffer::new(req), z: vec![0.0; n * n], s: vec![0.0; n * n], u: vec![0.0; n], kept_rows: 0 }
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
        self.kept_rows = 0;
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

    /// Whether [`Self::solve_with_rows`] is the cheaper way to solve with
    /// `count` rows added ([`WOODBURY_MAX_SHARE`]).
    pub fn rows_worth_update(&self, count: usize) -> bool {
        count as f64 <= WOODBURY_MAX_SHARE * self.n as f64
    }

    /// Solves `(A + B^T B) x = rhs` in place, A the last successful
    /// factorisation and B the first `count` rows of the row-major `rows`
    /// (width n, `count <= n`), by the Woodbury identity of the module
    /// documentation; the factor of A is kept. On failure (only where B or rhs
    /// is not finite) returns the index of S's first non-positive pivot and
    /// leaves `rhs` undefined.
    pub fn solve_with_rows(&mut self, rows: &[f64], count: usize, rhs: &mut [f64]) -> Result<(), usize> {
        let n = self.n;
        self.kept_rows = 0;
        if count == 0 {
            self.solve_in_place(rhs);
            return Ok(());
        }
        assert!(count <= n && rows.len() >= count * n && rhs.len() == n, "solve_with_rows: {count} rows of width {n}");
        let l = MatRef::from_column_major_slice(&self.factor, n, n);
        // Row i of B is column i of B^T, column-major n x count.
        let z = &mut self.z[..count * n];
        z.copy_from_slice(&rows[..count * n]);
        solve_lower_triangular_in_place(l, MatMut::from_column_major_slice_mut(z, n, count), Par::Seq);
        let s = &mut self.s[..count * count];
        syrk_columns(s, count, z, n, n, Accum::Replace);
        for i in 0..count {
            s[i * count + i] += 1.0;
        }
        let stack = MemStack::new(&mut self.mem);
        cholesky_in_place(MatMut::from_column_major_slice_mut(s, count, count), LltRegularization::default(), Par::Seq, stack, params())
            .map_err(|faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index }| index)?;
        self.kept_rows = count;
        self.solve_with_kept_rows(rhs);
        Ok(())
    }

    /// Solves with the rows of the last [`Self::solve_with_rows`] on the current
    /// factor again (Z and the factor of S kept); false where there are none.
    pub fn solve_with_kept_rows(&mut self, rhs: &mut [f64]) -> bool {
        let (n, count) = (self.n, self.kept_rows);
        if count == 0 {
            return false;
        }
        let l = MatRef::from_column_major_slice(&self.factor, n, n);
        let (z, s) = (&self.z[..count * n], &self.s[..count * count]);
        solve_lower_triangular_in_place(l, MatMut::from_column_major_slice_mut(rhs, n, 1), Par::Seq);
        let u = &mut self.u[..count];
        for (ui, zi) in u.iter_mut().zip(z.chunks_exact(n)) {
            *ui = zi.iter().zip(rhs.iter()).map(|(a, b)| a * b).sum();
        }
        solve_in_place(
            MatRef::from_column_major_slice(s, count, count),
            MatMut::from_column_major_slice_mut(u, count, 1),
            Par::Seq,
            MemStack::new(&mut self.mem),
        );
        for (ui, zi) in u.iter().zip(z.chunks_exact(n)) {
            for (x, a) in rhs.iter_mut().zip(zi) {
                *x -= ui * a;
            }
        }
        solve_upper_triangular_in_place(l.transpose(), MatMut::from_column_major_slice_mut(rhs, n, 1), Par::Seq);
        true
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

    #[test]
    fn solves_with_rows_added_as_a_factorisation_of_the_sum_does() {
        let mut rng = Rng::new(4);
        let n = 17;
        let c = rng.vec(n * n, 1.0);
        let a: Vec<f64> =
            (0..n * n).map(|i| (0..n).map(|k| c[k * n + i / n] * c[k * n + i % n]).sum::<f64>() + if i / n == i % n { 0.1 } else { 0.0 }).collect();
        for count in [0, 1, 3, n] {
            let rows = rng.vec(count * n, 2.0);
            let rhs = rng.vec(n, 1.0);
            let mut sum = a.clone();
            crate::dense::add_gram(&mut sum, n, &rows, count);
            let mut expected = rhs.clone();
            Cholesky::factor(&sum, n).unwrap().solve_in_place(&mut expected);
            let mut chol = Cholesky::factor(&a, n).unwrap();
            let mut x = rhs.clone();
            chol.solve_with_rows(&rows, count, &mut x).unwrap();
            let scale = expected.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(x.iter().zip(&expected).all(|(u, v)| (u - v).abs() < 1e-9 * scale), "{count} rows");
            // So are Z and S, for the same system.
            let mut again = rhs.clone();
            assert_eq!(chol.solve_with_kept_rows(&mut again), count > 0);
            if count > 0 {
                assert_eq!(again, x);
            }
            // A's factor is kept.
            let mut y = rhs.clone();
            chol.solve_in_place(&mut y);
            let mut plain = rhs.clone();
            Cholesky::factor(&a, n).unwrap().solve_in_place(&mut plain);
            assert_eq!(y, plain);
        }
        // A new factorisation drops the rows.
        let mut chol = Cholesky::factor(&a, n).unwrap();
        chol.solve_with_rows(&rng.vec(2 * n, 1.0), 2, &mut rng.vec(n, 1.0)).unwrap();
        chol.factor_shifted(&a, 0.0, &a).unwrap();
        assert!(!chol.solve_with_kept_rows(&mut rng.vec(n, 1.0)));
        let mut rows = rng.vec(2 * n, 1.0);
        rows[3] = f64::NAN;
        assert!(chol.solve_with_rows(&rows, 2, &mut rng.vec(n, 1.0)).is_err());
    }
}
