//! Stable Neo-Hookean elasticity (Smith, de Goes, Kim 2018) with its analytic
//! Hessian eigensystem (Smith, de Goes, Kim 2019) for PSD projection.
//!
//! Conventions: `vec(F)` is row-major, index `3*i + j` holds `F[i][j]`; stress and
//! Hessians use the same ordering. Energies are densities (J/m^3 = Pa), the first
//! Piola-Kirchhoff stress is in Pa and the Hessian in Pa. The energy has no `log J`
//! term, so everything stays finite for inverted elements (J <= 0).

use nalgebra::{Matrix3, SMatrix, SVector};

use crate::error::{check_finite, check_output, check_positive, LicromError, Result};
use crate::real::{Lanes, Real, LANES};
use crate::simd::{dispatch, Madd, WithMadd};
use crate::svd3::{svd3_of, sym_eigen3_of, M3};

/// A row-major `vec(F)` or stress vector.
pub type Vec9 = SVector<f64, 9>;
/// A 9x9 Hessian in row-major `vec(F)` ordering.
pub type Mat9 = SMatrix<f64, 9, 9>;

/// Row-major `vec` of a 3x3 matrix.
#[inline]
pub fn vec9(m: &Matrix3<f64>) -> Vec9 {
    Vec9::from_fn(|r, _| m[(r / 3, r % 3)])
}

/// 3x3 matrix from 9 row-major values.
#[inline]
pub fn mat3_row_major(v: &[f64]) -> Matrix3<f64> {
    Matrix3::new(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8])
}

/// Cofactor matrix `dJ/dF` (= J F^-T when F is invertible), valid for any F.
#[inline]
pub fn cofactor(f: &Matrix3<f64>) -> Matrix3<f64> {
    let (c0, c1, c2) = (f.column(0), f.column(1), f.column(2));
    Matrix3::from_columns(&[c1.cross(&c2), c2.cross(&c0), c0.cross(&c1)])
}

/// Eigen-decomposition `H = sum_i values[i] vectors[i] vectors[i]^T` of the 9x9
/// energy-density Hessian; vectors are orthonormal in row-major `vec(F)` space.
#[derive(Debug, Clone, Copy)]
pub struct HessianEigensystem {
    /// Eigenvalues, Pa: three scaling modes, then three twists, then three flips.
    pub values: [f64; 9],
    /// Unit eigenvectors, same order as `values`.
    pub vectors: [Vec9; 9],
}

impl HessianEigensystem {
    /// `sum_i max(values[i], 0) v_i v_i^T` when `clamp`, the exact Hessian otherwise.
    pub fn reconstruct(&self, clamp: bool) -> Mat9 {
        let mut h = Mat9::zeros();
        for (&lambda, v) in self.values.iter().zip(&self.vectors) {
            let l = if clamp { lambda.max(0.0) } else { lambda };
            if l != 0.0 {
                h.ger(l, v, v, 1.0);
            }
        }
        h
    }
}

/// Stable Neo-Hookean material
/// `Psi(F) = mu/2 (I_C - 3) + lam/2 (J - alpha)^2 - mu/2 log(I_C + 1) - Psi_0`,
/// `alpha = 1 + 3 mu / (4 lam)`, with `mu`, `lam` the SNH parameters in Pa.
///
/// `Psi_0` is the value of the first three terms at F = I, so that the rest state
/// (and any rotation) has zero energy; a constant shift changes neither stress nor
/// Hessian, and it keeps the incremental potential free of a large constant that
/// would eat into the line search's round-off budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StableNeoHookean {
    mu: f64,
    lam: f64,
    alpha: f64,
    rest_energy: f64,
}

impl StableNeoHookean {
    /// Material with SNH parameters `mu > 0`, `lam > 0` (Pa) whose derived
    /// constants `alpha` and `Psi_0` are finite (`mu / lam` not astronomically large).
    pub fn new(mu: f64, lam: f64) -> Result<Self> {
        check_positive("mu", mu)?;
        check_positive("lam", lam)?;
        let alpha = 1.0 + 0.75 * mu / lam;
        let rest_energy = 0.5 * lam * (1.0 - alpha) * (1.0 - alpha) - 0.5 * mu * 4.0_f64.ln();
        if !(alpha.is_finite() && rest_energy.is_finite()) {
            return Err(LicromError::invalid(
                "mu/lam",
                format!("must keep alpha = 1 + 3 mu / (4 lam) and mu^2 / lam finite in double precision, got mu = {mu:e}, lam = {lam:e}"),
            ));
        }
        Ok(Self { mu, lam, alpha, rest_energy })
    }

    /// Shear parameter, Pa.
    pub fn mu(&self) -> f64 {
        self.mu
    }

    /// Volume parameter, Pa.
    pub fn lam(&self) -> f64 {
        self.lam
    }

    /// Rest-volume shift `1 + 3 mu / (4 lam)` that makes F = I stress free.
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Energy density Psi(F), J/m^3.
    #[inline]
    pub fn energy(&self, f: &Matrix3<f64>) -> f64 {
        let ic = f.norm_squared();
        let dj = f.determinant() - self.alpha;
        0.5 * self.mu * (ic - 3.0) + 0.5 * self.lam * dj * dj - 0.5 * self.mu * (ic + 1.0).ln() - self.rest_energy
    }

    /// First Piola-Kirchhoff stress `P = dPsi/dF`, Pa.
    #[inline]
    pub fn pk1(&self, f: &Matrix3<f64>) -> Matrix3<f64> {
        let ic = f.norm_squared();
        let dj = f.determinant() - self.alpha;
        f * (self.mu * (1.0 - 1.0 / (ic + 1.0))) + cofactor(f) * (self.lam * dj)
    }

    /// Exact Hessian `d^2 Psi / d vec(F)^2` (may be indefinite), Pa.
    ///
    /// Closed form in the invariants, independent of the eigensystem:
    /// `mu (1 - 1/(I_C+1)) I + 2 mu/(I_C+1)^2 f f^T + lam g g^T + lam (J - alpha) H_J`
    /// with `f = vec(F)`, `g = vec(cof F)`, `H_J = d^2 J / dF^2`.
    pub fn hessian(&self, f: &Matrix3<f64>) -> Mat9 {
        let ic = f.norm_squared();
        let dj = f.determinant() - self.alpha;
        let fv = vec9(f);
        let gv = vec9(&cofactor(f));
        let mut h = Mat9::identity() * (self.mu * (1.0 - 1.0 / (ic + 1.0)));
        h.ger(2.0 * self.mu / ((ic + 1.0) * (ic + 1.0)), &fv, &fv, 1.0);
        h.ger(self.lam, &gv, &gv, 1.0);
        // H_J[(i,j),(k,l)] = eps_ikm eps_jln F_mn.
        let s = self.lam * dj;
        for (i, k, m, e1) in LEVI_CIVITA {
            for (j, l, n, e2) in LEVI_CIVITA {
                h[(3 * i + j, 3 * k + l)] += s * e1 * e2 * f[(m, n)];
            }
        }
        h
    }

    /// Analytic eigensystem of the Hessian at `f`, from the rotation-variant SVD
    /// `F = U diag(s) V^T`: three scaling modes `U diag(w) V^T` (w eigenvectors
    /// of the 3x3 Hessian of psi(s0, s1, s2)) and, for each pair (a, b) with third
    /// index k, a twist `(u_a v_b^T - u_b v_a^T)/sqrt 2` with eigenvalue
    /// `2 dPsi/dI_C + dPsi/dJ s_k` and a flip `(u_a v_b^T + u_b v_a^T)/sqrt 2` with
    /// eigenvalue `2 dPsi/dI_C - dPsi/dJ s_k`.
    pub fn eigensystem(&self, f: &Matrix3<f64>) -> HessianEigensystem {
        let m: M3<f64> = std::array::from_fn(|i| std::array::from_fn(|j| f[(i, j)]));
        let mut values = [0.0; 9];
        let mut vectors = [[0.0; 9]; 9];
        self.eigensystem_of(&m, &mut values, &mut vectors);
        HessianEigensystem { values, vectors: vectors.map(Vec9::from) }
    }

    /// [`Self::eigensystem`] for any [`Real`]: eigenvalues and row-major unit
    /// eigenvectors, in the same order. Written with plain loops (no closures
    /// through `array::from_fn`) so that all of it inlines into vectorised callers.
    #[inline(always)]
    pub fn eigensystem_of<T: Real>(&self, f: &M3<T>, values: &mut [T; 9], vectors: &mut [[T; 9]; 9]) {
        let (u, s, v) = svd3_of(f);
        let ic = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
        let j = s[0] * s[1] * s[2];
        let (one, mu, lam) = (T::splat(1.0), T::splat(self.mu), T::splat(self.lam));
        let ic1 = ic + one;
        let two_psi_i = mu * (one - one / ic1);
        let four_psi_ii = T::splat(2.0) * mu / (ic1 * ic1);
        let psi_j = lam * (j - T::splat(self.alpha));
        // Hessian of psi w.r.t. the signed singular values.
        let c = [s[1] * s[2], s[0] * s[2], s[0] * s[1]];
        let mut a = [[T::splat(0.0); 3]; 3];
        for r in 0..3 {
            for k in 0..3 {
                let coupling = if r == k { two_psi_i } else { psi_j * s[3 - r - k] };
                a[r][k] = four_psi_ii * s[r] * s[k] + lam * c[r] * c[k] + coupling;
            }
        }
        let (scaling, w) = sym_eigen3_of(&a);

        for m in 0..3 {
            values[m] = scaling[m];
            // U diag(w_m) V^T, row-major.
            for r in 0..9 {
                let (i, j) = (r / 3, r % 3);
                vectors[m][r] = u[i][0] * v[j][0] * w[0][m] + u[i][1] * v[j][1] * w[1][m] + u[i][2] * v[j][2] * w[2][m];
            }
        }
        let inv_sqrt2 = T::splat(std::f64::consts::FRAC_1_SQRT_2);
        for (m, (a, b, k)) in [(1, 2, 0), (0, 2, 1), (0, 1, 2)].into_iter().enumerate() {
            values[3 + m] = two_psi_i + psi_j * s[k];
            values[6 + m] = two_psi_i - psi_j * s[k];
            // (u_a v_b^T -+ u_b v_a^T) / sqrt 2, row-major.
            for r in 0..9 {
                let (i, j) = (r / 3, r % 3);
                let (ab, ba) = (u[i][a] * v[j][b], u[i][b] * v[j][a]);
                vectors[3 + m][r] = (ab - ba) * inv_sqrt2;
                vectors[6 + m][r] = (ab + ba) * inv_sqrt2;
            }
        }
    }

    /// Energy densities (J/m^3, when `with_energy`; zeros otherwise) and first
    /// Piola-Kirchhoff stresses (Pa, row-major components `[a][lane]`) of
    /// [`LANES`] deformation gradients given as row-major components `f[a][lane]`.
    /// Plain per-lane loops, so that every operation is one vector instruction
    /// in the vectorised callers.
    #[inline(always)]
    pub(crate) fn energy_stress_lanes<M: Madd>(&self, f: &[[f64; LANES]; 9], with_energy: bool) -> ([f64; LANES], [[f64; LANES]; 9]) {
        let mut cof = [[0.0; LANES]; 9];
        let mut ic = [0.0; LANES];
        let mut dj = [0.0; LANES];
        for l in 0..LANES {
            let m = |a: usize| f[a][l];
            cof[0][l] = m(4) * m(8) - m(5) * m(7);
            cof[1][l] = m(5) * m(6) - m(3) * m(8);
            cof[2][l] = m(3) * m(7) - m(4) * m(6);
            cof[3][l] = m(2) * m(7) - m(1) * m(8);
            cof[4][l] = m(0) * m(8) - m(2) * m(6);
            cof[5][l] = m(1) * m(6) - m(0) * m(7);
            cof[6][l] = m(1) * m(5) - m(2) * m(4);
            cof[7][l] = m(2) * m(3) - m(0) * m(5);
            cof[8][l] = m(0) * m(4) - m(1) * m(3);
            let mut s = 0.0;
            for a in 0..9 {
                s = M::madd(m(a), m(a), s);
            }
            ic[l] = s;
            dj[l] = M::madd(m(0), cof[0][l], M::madd(m(1), cof[1][l], m(2) * cof[2][l])) - self.alpha;
        }
        let mut p = [[0.0; LANES]; 9];
        let mut psi = [0.0; LANES];
        for l in 0..LANES {
            let a = self.mu * (1.0 - 1.0 / (ic[l] + 1.0));
            let b = self.lam * dj[l];
            for c in 0..9 {
                p[c][l] = M::madd(a, f[c][l], b * cof[c][l]);
            }
        }
        if with_energy {
            for l in 0..LANES {
                // The logarithm has no vector instruction; it is the one scalar call per lane.
                psi[l] = 0.5 * self.mu * (ic[l] - 3.0) + 0.5 * self.lam * dj[l] * dj[l] - 0.5 * self.mu * (ic[l] + 1.0).ln() - self.rest_energy;
            }
        }
        (psi, p)
    }

    /// Hessian with negative eigenvalues clamped to zero (PSD), Pa.
    pub fn projected_hessian(&self, f: &Matrix3<f64>) -> Mat9 {
        self.eigensystem(f).reconstruct(true)
    }

    /// Energy densities of a batch: `fs` holds `p` row-major 3x3 matrices.
    ///
    /// The batch functions fail with [`LicromError::Overflow`] where an F is so
    /// large that a result is not finite.
    pub fn energy_batch(&self, fs: &[f64], out: &mut [f64]) -> Result<()> {
        check_batch(fs, out.len(), 1)?;
        for (f, o) in fs.chunks_exact(9).zip(out.iter_mut()) {
            *o = self.energy(&mat3_row_major(f));
        }
        check_output("the energy density", "F", out)
    }

    /// First Piola-Kirchhoff stresses of a batch, row-major 3x3 each.
    pub fn pk1_batch(&self, fs: &[f64], out: &mut [f64]) -> Result<()> {
        check_batch(fs, out.len(), 9)?;
        for (f, o) in fs.chunks_exact(9).zip(out.chunks_exact_mut(9)) {
            o.copy_from_slice(vec9(&self.pk1(&mat3_row_major(f))).as_slice());
        }
        check_output("the stress", "F", out)
    }

    /// Hessians of a batch, row-major 9x9 each; PSD-projected when `project`.
    /// The projected ones go through the eigensystem eight points at a time,
    /// as in the reduced assembly.
    pub fn hessian_batch(&self, fs: &[f64], project: bool, out: &mut [f64]) -> Result<()> {
        check_batch(fs, out.len(), 81)?;
        if project {
            // Checked inside, on the vectors, where it costs little.
            if !dispatch(ProjectedBatch { material: self, fs, out }) {
                return Err(LicromError::Overflow { what: "the Hessian", input: "F" });
            }
            return Ok(());
        }
        for (f, o) in fs.chunks_exact(9).zip(out.chunks_exact_mut(81)) {
            // The Hessian is symmetric, so nalgebra's column-major storage is row-major too.
            o.copy_from_slice(self.hessian(&mat3_row_major(f)).as_slice());
        }
        check_output("the Hessian", "F", out)
    }
}

/// Projected Hessians of a batch of row-major F (9 values each) into `out` (81
/// each); returns whether all of them are finite.
struct ProjectedBatch<'a> {
    material: &'a StableNeoHookean,
    fs: &'a [f64],
    out: &'a mut [f64],
}

impl WithMadd for ProjectedBatch<'_> {
    type Output = bool;
    #[inline(always)]
    fn run<M: Madd>(self) -> bool {
        let mut values = [Lanes::splat(0.0); 9];
        let mut vectors = [[Lanes::splat(0.0); 9]; 9];
        // Sum of `0 x` over the entries: 0 while all are finite, NaN after an overflow.
        let mut finite = Lanes::splat(0.0);
        for (fs, out) in self.fs.chunks(9 * LANES).zip(self.out.chunks_mut(81 * LANES)) {
            // Missing lanes of the last group hold F = I.
            let mut lanes = [[Lanes::splat(0.0); 3]; 3];
            for (i, row) in lanes.iter_mut().enumerate() {
                row[i] = Lanes::splat(1.0);
            }
            for (l, f) in fs.chunks_exact(9).enumerate() {
                for r in 0..9 {
                    lanes[r / 3][r % 3].0[l] = f[r];
                }
            }
            self.material.eigensystem_of(&lanes, &mut values, &mut vectors);
            // Sum of clamped modes, formed for the eight points at once. Only negative
            // eigenvalues are clamped: a NaN one (an overflow inside the eigensystem)
            // stays and fails the finiteness check.
            let zero = Lanes::splat(0.0);
            let clamped = values.map(|v| Lanes::select(Lanes::lt(v, zero), zero, v));
            let mut h = [[zero; 9]; 9];
            for a in 0..9 {
                for b in a..9 {
                    let mut acc = zero;
                    for m in 0..9 {
                        acc = acc + clamped[m] * vectors[m][a] * vectors[m][b];
                    }
                    h[a][b] = acc;
                    h[b][a] = acc;
                    finite = finite + acc * zero;
                }
            }
            for (l, o) in out.chunks_exact_mut(81).enumerate() {
                for r in 0..81 {
                    o[r] = h[r / 9][r % 9].0[l];
                }
            }
        }
        finite.0.iter().all(|v| *v == 0.0)
    }
}

/// Non-zero entries (i, k, m, sign) of the Levi-Civita symbol.
const LEVI_CIVITA: [(usize, usize, usize, f64); 6] =
    [(0, 1, 2, 1.0), (1, 2, 0, 1.0), (2, 0, 1, 1.0), (0, 2, 1, -1.0), (2, 1, 0, -1.0), (1, 0, 2, -1.0)];

fn check_batch(fs: &[f64], out_len: usize, per_point: usize) -> Result<()> {
    if !fs.len().is_multiple_of(9) {
        return Err(LicromError::shape("F", "(p, 3, 3)", format!("{} values", fs.len())));
    }
    let p = fs.len() / 9;
    if out_len != p * per_point {
        return Err(LicromError::shape("output", format!("{} values", p * per_point), format!("{out_len} values")));
    }
    check_finite("F", fs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{fd_gradient, fd_jacobian, rel_err, Rng};
    use nalgebra::Vector3;

    fn material() -> StableNeoHookean {
        StableNeoHookean::new(3.0e5, 1.2e6).unwrap()
    }

    fn samples() -> Vec<Matrix3<f64>> {
        let mut rng = Rng::new(11);
        let mut fs: Vec<_> = (0..60).map(|_| rng.deformation(0.4)).collect();
        // Inverted and strongly compressed/stretched states.
        for _ in 0..20 {
            let mut f = rng.deformation(0.3);
            f.row_mut(2).neg_mut();
            fs.push(f);
        }
        fs.push(Matrix3::from_diagonal(&Vector3::new(0.3, 0.5, 2.0)));
        fs.push(Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -0.5)));
        fs.push(Matrix3::identity() * 0.5);
        fs
    }

    #[test]
    fn energy_gradient_matches_finite_differences() {
        let mat = material();
        for f in samples() {
            let fd = fd_gradient(|x| mat.energy(&mat3_row_major(x)), vec9(&f).as_slice(), 1e-6);
            let p = vec9(&mat.pk1(&f));
            assert!(rel_err(p.as_slice(), &fd, 1.0) < 1e-6, "P vs FD: {}", rel_err(p.as_slice(), &fd, 1.0));
        }
    }

    #[test]
    fn hessian_matches_finite_differences_of_stress() {
        let mat = material();
        for f in samples() {
            let fd = fd_jacobian(|x| vec9(&mat.pk1(&mat3_row_major(x))).as_slice().to_vec(), vec9(&f).as_slice(), 1e-6);
            let h = mat.hessian(&f);
            let fd: Vec<f64> = fd.into_iter().flatten().collect();
            // Row r of fd is dP/dvec(F)_r, i.e. column r of H (H is symmetric anyway).
            assert!(rel_err(h.as_slice(), &fd, 1.0) < 1e-6, "H vs FD: {}", rel_err(h.as_slice(), &fd, 1.0));
            assert!((h - h.transpose()).norm() <= 1e-9 * h.norm());
        }
    }

    #[test]
    fn eigensystem_reconstructs_exact_hessian() {
        let mat = material();
        for f in samples() {
            let e = mat.eigensystem(&f);
            let exact = mat.hessian(&f);
            let recon = e.reconstruct(false);
            assert!((recon - exact).norm() <= 1e-9 * exact.norm(), "eigensystem error {}", (recon - exact).norm());
            let gram = Mat9::from_fn(|a, b| e.vectors[a].dot(&e.vectors[b]));
            assert!((gram - Mat9::identity()).norm() < 1e-10);
        }
    }

    #[test]
    fn projection_is_exact_when_psd_and_psd_always() {
        let mat = material();
        let mut psd_cases = 0;
        for f in samples() {
            let exact = mat.hessian(&f);
            let proj = mat.projected_hessian(&f);
            let min_exact = exact.symmetric_eigen().eigenvalues.min();
            let min_proj = proj.symmetric_eigen().eigenvalues.min();
            assert!(min_proj >= -1e-9 * exact.norm(), "projected Hessian has eigenvalue {min_proj}");
            if min_exact >= 0.0 {
                psd_cases += 1;
                assert!((proj - exact).norm() <= 1e-9 * exact.norm());
            } else {
                // Projection removes exactly the negative part: the difference is PSD.
                let diff_min = (proj - exact).symmetric_eigen().eigenvalues.min();
                assert!(diff_min >= -1e-9 * exact.norm());
            }
        }
        assert!(psd_cases > 0);
    }

    #[test]
    fn rest_state_is_stress_free_and_hessian_psd() {
        let mat = material();
        let i = Matrix3::identity();
        assert!(mat.pk1(&i).norm() < 1e-9 * mat.mu());
        let e = mat.eigensystem(&i);
        assert!(e.values.iter().all(|&l| l >= -1e-9 * mat.mu()));
    }

    #[test]
    fn rigid_rotation_has_zero_energy_and_stress() {
        let mat = material();
        let mut rng = Rng::new(5);
        for _ in 0..20 {
            let r = nalgebra::Rotation3::from_scaled_axis(Vector3::new(rng.uniform(), rng.uniform(), rng.uniform()) * 3.0).into_inner();
            assert!(mat.energy(&r).abs() < 1e-9 * mat.mu());
            assert!(mat.pk1(&r).norm() < 1e-9 * mat.mu());
        }
    }

    #[test]
    fn batch_helpers_check_sizes_and_finiteness() {
        let mat = material();
        let fs = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        let mut out = [0.0; 2];
        assert!(matches!(mat.energy_batch(&fs, &mut out), Err(LicromError::ShapeMismatch { .. })));
        let mut bad = fs;
        bad[4] = f64::NAN;
        assert!(matches!(mat.energy_batch(&bad, &mut out[..1]), Err(LicromError::NonFinite { .. })));
        let mut h = [0.0; 81];
        mat.hessian_batch(&fs, true, &mut h).unwrap();
        // The batched projection agrees with the per-point one (13 points: a partial group).
        let mut rng = Rng::new(17);
        let many: Vec<f64> = (0..13).flat_map(|_| vec9(&rng.deformation(0.5)).as_slice().to_vec()).collect();
        let mut batch = vec![0.0; 13 * 81];
        mat.hessian_batch(&many, true, &mut batch).unwrap();
        for (f, h) in many.chunks_exact(9).zip(batch.chunks_exact(81)) {
            let single = mat.projected_hessian(&mat3_row_major(f));
            assert!(rel_err(h, single.as_slice(), 1.0) < 1e-12);
        }
        assert!(StableNeoHookean::new(-1.0, 1.0).is_err());
        assert!(StableNeoHookean::new(1.0, 0.0).is_err());
    }

    #[test]
    fn results_out_of_double_range_are_errors_not_inf_or_nan() {
        let mat = material();
        // A subnormal lam makes alpha = 1 + 3 mu / (4 lam) infinite.
        assert!(matches!(StableNeoHookean::new(5e4, 1e-320), Err(LicromError::InvalidParameter { .. })));
        assert!(matches!(StableNeoHookean::new(1e300, 1e-10), Err(LicromError::InvalidParameter { .. })));
        for scale in [1e80, 1e100, 1e200] {
            let huge = vec9(&(Matrix3::identity() * scale)).as_slice().to_vec();
            let overflow = |r: Result<()>| matches!(r, Err(LicromError::Overflow { input: "F", .. }));
            assert!(overflow(mat.energy_batch(&huge, &mut [0.0])), "energy at {scale}");
            assert!(overflow(mat.pk1_batch(&huge, &mut [0.0; 9])), "stress at {scale}");
            assert!(overflow(mat.hessian_batch(&huge, true, &mut [0.0; 81])), "projected Hessian at {scale}");
            assert!(overflow(mat.hessian_batch(&huge, false, &mut [0.0; 81])), "Hessian at {scale}");
        }
        // Large but representable: finite results.
        let big = vec9(&(Matrix3::identity() * 1e40)).as_slice().to_vec();
        let mut e = [0.0];
        mat.energy_batch(&big, &mut e).unwrap();
        assert!(e[0].is_finite() && e[0] > 0.0);
    }
}
