//! Full-space positions from reduced coordinates: `x_v = X_v + W_v q`.

use faer::{Accum, MatMut, MatRef};

use crate::error::{check_finite, check_output, LicromError, Result};
use crate::second_thread::product_by_rows;

/// Basis rows `W_v` (3 x n each) and rest positions `X_v` of N points.
#[derive(Debug, Clone)]
pub struct Reconstruction {
    n: usize,
    basis: Vec<f64>,
    rest: Vec<f64>,
}

impl Reconstruction {
    /// From `basis` (N x 3 x n, row-major) and `rest` (N x 3, m); `n >= 1`.
    pub fn new(basis: Vec<f64>, rest: Vec<f64>, n: usize) -> Result<Self> {
        let points = rest.len() / 3;
        if n == 0 || !rest.len().is_multiple_of(3) || basis.len() != points * 3 * n {
            return Err(LicromError::shape("basis", format!("({points}, 3, n) with n >= 1"), format!("{} values", basis.len())));
        }
        check_finite("basis", &basis)?;
        check_finite("rest", &rest)?;
        Ok(Self { n, basis, rest })
    }

    /// Number of reduced coordinates n.
    pub fn n_dofs(&self) -> usize {
        self.n
    }

    /// Number of points N.
    pub fn n_points(&self) -> usize {
        self.rest.len() / 3
    }

    /// Positions `X + W q` (N x 3, m) into `out`; [`LicromError::Overflow`] where
    /// `q` is so large that a position is not finite.
    pub fn positions(&self, q: &[f64], out: &mut [f64]) -> Result<()> {
        if q.len() != self.n {
            return Err(LicromError::shape("q", format!("({},)", self.n), format!("{} values", q.len())));
        }
        if out.len() != self.rest.len() {
            return Err(LicromError::shape("out", format!("({}, 3)", self.n_points()), format!("{} values", out.len())));
        }
        check_finite("q", q)?;
        out.copy_from_slice(&self.rest);
        let rows = self.rest.len();
        if rows > 0 {
            product_by_rows(
                MatRef::from_row_major_slice(&self.basis, rows, self.n),
                MatRef::from_column_major_slice(q, self.n, 1),
                MatMut::from_column_major_slice_mut(out, rows, 1),
                Accum::Add,
            );
        }
        check_output("the positions", "q", out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Rng;

    #[test]
    fn positions_are_rest_plus_basis_times_q() {
        let mut rng = Rng::new(21);
        let (points, n) = (17, 5);
        let basis = rng.vec(points * 3 * n, 1.0);
        let rest = rng.vec(points * 3, 1.0);
        let q = rng.vec(n, 1.0);
        let r = Reconstruction::new(basis.clone(), rest.clone(), n).unwrap();
        let mut out = vec![0.0; points * 3];
        r.positions(&q, &mut out).unwrap();
        for row in 0..points * 3 {
            let e = rest[row] + (0..n).map(|c| basis[row * n + c] * q[c]).sum::<f64>();
            assert!((out[row] - e).abs() < 1e-12);
        }
        assert!(r.positions(&q[..3], &mut out).is_err());
        assert!(Reconstruction::new(basis, rest, 4).is_err());
        let empty = Reconstruction::new(vec![], vec![], n).unwrap();
        empty.positions(&q, &mut []).unwrap();
        let r = Reconstruction::new(vec![1.0; 3 * n], vec![0.0; 3], n).unwrap();
        assert!(matches!(r.positions(&[1e308; 5], &mut [0.0; 3]), Err(LicromError::Overflow { .. })));
    }
}
