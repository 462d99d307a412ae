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
//!
//! The algorithms are written once against [`Real`] and branch-free, so that
//! they also run on eight matrices at once ([`crate::real::Lanes`]).

use nalgebra::{Matrix3, Vector3};

use crate::real::Real;

/// A 3x3 matrix as rows: `m[i][j]`.
pub type M3<T> = [[T; 3]; 3];

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

const MAX_SWEEPS: usize = 16;

#[inline(always)]
fn det3<T: Real>(m: &M3<T>) -> T {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// Eigenvalues (descending) and eigenvectors (columns of a rotation) of the
/// symmetric part of `a`, by cyclic Jacobi sweeps.
#[inline(always)]
pub fn sym_eigen3_of<T: Real>(a: &M3<T>) -> ([T; 3], M3<T>) {
    let zero = T::splat(0.0);
    let one = T::splat(1.0);
    let half = T::splat(0.5);
    let mut m = [[zero; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = half * (a[i][j] + a[j][i]);
        }
    }
    let mut v = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    let mut scale = zero;
    for row in &m {
        for x in row {
            scale = scale + *x * *x;
        }
    }
    // An off-diagonal entry below eps of the matrix norm is round-off: rotating it
    // away changes nothing. Relative accuracy of tiny eigenvalues is not needed
    // here (the SVD recovers singular values from F V, not from these).
    let tiny = scale * T::splat(0.25 * f64::EPSILON * f64::EPSILON);
    for _ in 0..MAX_SWEEPS {
        let off = |m: &M3<T>| m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
        let pending = T::lt(tiny, off(&m));
        if !T::any(pending) {
            break;
        }
        for (p, q, r) in [(0, 1, 2), (0, 2, 1), (1, 2, 0)] {
            let apq = m[p][q];
            let skip = T::le(apq * apq, tiny);
            // Classic Jacobi rotation (Golub & Van Loan, sym.schur2), smaller angle;
            // identity where the entry is already negligible.
            let theta = (m[q][q] - m[p][p]) / (T::splat(2.0) * apq);
            let t = T::select(skip, zero, theta.signum() / (theta.abs() + (theta * theta + one).sqrt()));
            let c = one / (t * t + one).sqrt();
            let s = t * c;
            m[p][p] = m[p][p] - t * apq;
            m[q][q] = m[q][q] + t * apq;
            let kept = T::select(skip, apq, zero);
            m[p][q] = kept;
            m[q][p] = kept;
            let (arp, arq) = (m[r][p], m[r][q]);
            m[r][p] = c * arp - s * arq;
            m[p][r] = m[r][p];
            m[r][q] = s * arp + c * arq;
            m[q][r] = m[r][q];
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut values = [m[0][0], m[1][1], m[2][2]];
    // Sort descending with a 3-element network, moving eigenvector columns along.
    for (i, j) in [(0, 1), (1, 2), (0, 1)] {
        let swap = T::lt(values[i], values[j]);
        let (vi, vj) = (values[i], values[j]);
        values[i] = T::select(swap, vj, vi);
        values[j] = T::select(swap, vi, vj);
        for row in v.iter_mut() {
            let (a, b) = (row[i], row[j]);
            row[i] = T::select(swap, b, a);
            row[j] = T::select(swap, a, b);
        }
    }
    let flip = T::lt(det3(&v), zero);
    for row in v.iter_mut() {
        row[2] = T::select(flip, -row[2], row[2]);
    }
    (values, v)
}

/// Givens rotation acting on rows `i < j` of `b` that zeroes `b[j][k]`, keeping
/// `b[i][k] >= 0`; the transposed rotation is accumulated into the columns of `u`.
#[inline(always)]
fn givens_zero<T: Real>(b: &mut M3<T>, u: &mut M3<T>, i: usize, j: usize, k: usize) {
    let (zero, one) = (T::splat(0.0), T::splat(1.0));
    let (x, y) = (b[i][k], b[j][k]);
    // Entries are O(|F|): no overflow risk that would call for hypot.
    let r = (x * x + y * y).sqrt();
    let skip = T::or(T::le(r, zero), T::and(T::le(y.abs(), zero), T::le(zero, x)));
    let rs = T::select(skip, one, r);
    let c = T::select(skip, one, x / rs);
    let s = T::select(skip, zero, y / rs);
    for col in 0..3 {
        let (bi, bj) = (b[i][col], b[j][col]);
        b[i][col] = c * bi + s * bj;
        b[j][col] = c * bj - s * bi;
    }
    for row in u.iter_mut() {
        let (ui, uj) = (row[i], row[j]);
        row[i] = c * ui + s * uj;
        row[j] = c * uj - s * ui;
    }
}

/// Rotation-variant SVD `(U, s, V)` of `f`; exact to round-off also for
/// rank-deficient and inverted matrices.
#[inline(always)]
pub fn svd3_of<T: Real>(f: &M3<T>) -> (M3<T>, [T; 3], M3<T>) {
    let zero = T::splat(0.0);
    let mut ftf = [[zero; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            ftf[i][j] = f[0][i] * f[0][j] + f[1][i] * f[1][j] + f[2][i] * f[2][j];
        }
    }
    let (_, v) = sym_eigen3_of(&ftf);
    let mut b = [[zero; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            b[i][j] = f[i][0] * v[0][j] + f[i][1] * v[1][j] + f[i][2] * v[2][j];
        }
    }
    let one = T::splat(1.0);
    let mut u = [[one, zero, zero], [zero, one, zero], [zero, zero, one]];
    givens_zero(&mut b, &mut u, 0, 1, 0);
    givens_zero(&mut b, &mut u, 0, 2, 0);
    givens_zero(&mut b, &mut u, 1, 2, 1);
    (u, [b[0][0], b[1][1], b[2][2]], v)
}

fn to_m3(m: &Matrix3<f64>) -> M3<f64> {
    [[m[(0, 0)], m[(0, 1)], m[(0, 2)]], [m[(1, 0)], m[(1, 1)], m[(1, 2)]], [m[(2, 0)], m[(2, 1)], m[(2, 2)]]]
}

fn from_m3(m: &M3<f64>) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| m[i][j])
}

/// Eigen-decomposition of the symmetric part of `a`.
pub fn sym_eigen3(a: &Matrix3<f64>) -> SymEigen3 {
    let (values, vectors) = sym_eigen3_of(&to_m3(a));
    SymEigen3 { values: Vector3::from(values), vectors: from_m3(&vectors) }
}

/// Rotation-variant SVD of `f`.
pub fn svd3(f: &Matrix3<f64>) -> Svd3 {
    let (u, s, v) = svd3_of(&to_m3(f));
    Svd3 { u: from_m3(&u), s: Vector3::from(s), v: from_m3(&v) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::real::{Lanes, LANES};
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

    #[test]
    fn lanes_give_the_scalar_results() {
        let mut rng = Rng::new(12);
        let mut fs: Vec<Matrix3<f64>> = (0..LANES - 2).map(|_| rng.matrix3(1.0)).collect();
        fs.push(Matrix3::identity());
        fs.push(Matrix3::from_diagonal(&Vector3::new(2.0, 2.0, -0.5)));
        let lanes: M3<Lanes> = std::array::from_fn(|i| std::array::from_fn(|j| Lanes(std::array::from_fn(|l| fs[l][(i, j)]))));
        let (u, s, v) = svd3_of(&lanes);
        for (l, f) in fs.iter().enumerate() {
            let d = svd3(f);
            for i in 0..3 {
                assert_eq!(s[i].0[l], d.s[i]);
                for j in 0..3 {
                    assert_eq!(u[i][j].0[l], d.u[(i, j)]);
                    assert_eq!(v[i][j].0[l], d.v[(i, j)]);
                }
            }
        }
    }
}
