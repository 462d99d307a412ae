//! Small dense decompositions of 3x3 matrices: symmetric eigen-decomposition by
//! cyclic Jacobi and the rotation-variant SVD built on it.
//!
//! Jacobi is used instead of a closed-form cubic because it stays accurate for
//! (nearly) repeated eigenvalues, which are the norm at rest (F = I) and under
//! uniform scaling. The SVD follows McAdams et al. 2011: eigenvectors of F^T F
//! give V, and a Givens QR of F V gives U and the signed singular values. Givens
//! rotations are proper, so U and V are rotations and a reflection in F shows up
//! as a negative last singular value, which is what the analytic eigensystems
//! of isotropic energies need.

use nalgebra::{Matrix3, Vector3};

/// Symmetric 3x3 eigen-decomposition `A = V diag(values) V^T`.
#[derive(Debug, Clone, Copy)]
pub struct SymEigen3 {
    /// Eigenvalues in descending order.
    pub values: Vector3<f64>,
    /// Orthonormal eigenvectors as columns, with det = +1.
    pub vectors: Matrix3<f64>,
}

/// Rotation-variant SVD `F = U diag(s) V^T` with U, V rotations (det = +1).
#[derive(Debug, Clone, Copy)]
pub struct Svd3 {
    /// Left rotation.
    pub u: Matrix3<f64>,
    /// Signed singular values, |s0| >= |s1| >= |s2| up to round-off; only s2 may
    /// be negative (when det F < 0).
    pub s: Vector3<f64>,
    /// Right rotation.
    pub v: Matrix3<f64>,
}

const MAX_SWEEPS: usize = 32;

/// Eigen-decomposition of the symmetric part of `a` by cyclic Jacobi sweeps.
pub fn sym_eigen3(a: &Matrix3<f64>) -> SymEigen3 {
    let mut m = [[a[(0, 0)], 0.5 * (a[(0, 1)] + a[(1, 0)]), 0.5 * (a[(0, 2)] + a[(2, 0)])], [0.0; 3], [0.0; 3]];
    m[1] = [m[0][1], a[(1, 1)], 0.5 * (a[(1, 2)] + a[(2, 1)])];
    m[2] = [m[0][2], m[1][2], a[(2, 2)]];
    let mut v = Matrix3::identity();
    let scale = m.iter().flatten().map(|x| x * x).sum::<f64>();
    // Off-diagonal mass below eps^2 of the whole: the diagonal is exact to round-off.
    let threshold = scale * (f64::EPSILON * f64::EPSILON);
    for _ in 0..MAX_SWEEPS {
        let off = m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
        if off <= threshold {
            break;
        }
        for (p, q, r) in [(0, 1, 2), (0, 2, 1), (1, 2, 0)] {
            let apq = m[p][q];
            if apq == 0.0 {
                continue;
            }
            // Classic Jacobi rotation (Golub & Van Loan, sym.schur2), smaller angle.
            let theta = (m[q][q] - m[p][p]) / (2.0 * apq);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            m[p][p] -= t * apq;
            m[q][q] += t * apq;
            m[p][q] = 0.0;
            m[q][p] = 0.0;
            let (arp, arq) = (m[r][p], m[r][q]);
            m[r][p] = c * arp - s * arq;
            m[p][r] = m[r][p];
            m[r][q] = s * arp + c * arq;
            m[q][r] = m[r][q];
            for i in 0..3 {
                let (vp, vq) = (v[(i, p)], v[(i, q)]);
                v[(i, p)] = c * vp - s * vq;
                v[(i, q)] = s * vp + c * vq;
            }
        }
    }
    let mut values = Vector3::new(m[0][0], m[1][1], m[2][2]);
    // Sort descending with a 3-element network, permuting eigenvector columns along.
    for (i, j) in [(0, 1), (1, 2), (0, 1)] {
        if values[i] < values[j] {
            values.swap_rows(i, j);
            v.swap_columns(i, j);
        }
    }
    if v.determinant() < 0.0 {
        v.column_mut(2).neg_mut();
    }
    SymEigen3 { values, vectors: v }
}

/// Givens rotation acting on rows `i < j` of `b` that zeroes `b[(j, k)]`, keeping
/// `b[(i, k)] >= 0`; the transposed rotation is accumulated into the columns of `q`.
#[inline]
fn givens_zero(b: &mut Matrix3<f64>, q: &mut Matrix3<f64>, i: usize, j: usize, k: usize) {
    let (x, y) = (b[(i, k)], b[(j, k)]);
    let r = x.hypot(y);
    if r == 0.0 || y == 0.0 && x >= 0.0 {
        return;
    }
    let (c, s) = (x / r, y / r);
    for col in 0..3 {
        let (bi, bj) = (b[(i, col)], b[(j, col)]);
        b[(i, col)] = c * bi + s * bj;
        b[(j, col)] = -s * bi + c * bj;
    }
    for row in 0..3 {
        let (qi, qj) = (q[(row, i)], q[(row, j)]);
        q[(row, i)] = c * qi + s * qj;
        q[(row, j)] = -s * qi + c * qj;
    }
}

/// Rotation-variant SVD of `f`; exact to round-off also for rank-deficient and
/// inverted matrices.
pub fn svd3(f: &Matrix3<f64>) -> Svd3 {
    let eig = sym_eigen3(&f.tr_mul(f));
    let v = eig.vectors;
    let mut b = f * v;
    let mut u = Matrix3::identity();
    givens_zero(&mut b, &mut u, 0, 1, 0);
    givens_zero(&mut b, &mut u, 0, 2, 0);
    givens_zero(&mut b, &mut u, 1, 2, 1);
    Svd3 { u, s: Vector3::new(b[(0, 0)], b[(1, 1)], b[(2, 2)]), v }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Rng;

    fn check(f: &Matrix3<f64>) {
        let d = svd3(f);
        let recon = d.u * Matrix3::from_diagonal(&d.s) * d.v.transpose();
        let tol = 1e-12 * f.norm().max(1.0);
        assert!((recon - f).norm() < tol, "reconstruction error {}", (recon - f).norm());
        assert!((d.u.determinant() - 1.0).abs() < 1e-12);
        assert!((d.v.determinant() - 1.0).abs() < 1e-12);
        assert!((d.u.tr_mul(&d.u) - Matrix3::identity()).norm() < 1e-12);
        assert!((d.v.tr_mul(&d.v) - Matrix3::identity()).norm() < 1e-12);
        assert!(d.s[0] >= 0.0 && d.s[1] >= 0.0);
        assert!(d.s[0] >= d.s[1] - tol && d.s[1] >= d.s[2].abs() - tol);
    }

    #[test]
    fn svd_reconstructs_random_inverted_and_degenerate_matrices() {
        let mut rng = Rng::new(7);
        for _ in 0..2000 {
            check(&rng.matrix3(1.0));
        }
        check(&Matrix3::identity());
        check(&Matrix3::zeros());
        check(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)));
        check(&Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, 0.0)));
        check(&Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 1.0, 1.0, 1.0));
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -1.2, 2.0).into_inner();
        check(&(r * 1.7));
        check(&(r * Matrix3::from_diagonal(&Vector3::new(1.0, 1e-9, -1e-9))));
    }

    #[test]
    fn sym_eigen_diagonalizes() {
        let mut rng = Rng::new(3);
        for _ in 0..500 {
            let m = rng.matrix3(1.0);
            let a = m + m.transpose();
            let e = sym_eigen3(&a);
            let recon = e.vectors * Matrix3::from_diagonal(&e.values) * e.vectors.transpose();
            assert!((recon - a).norm() < 1e-12 * a.norm().max(1.0));
            assert!(e.values[0] >= e.values[1] && e.values[1] >= e.values[2]);
        }
    }
}
