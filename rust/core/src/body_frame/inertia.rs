//! The inertia of the body-frame model from mass moments.
//!
//! With `y_v = Xbar_v + W_v q` and `sum m y = 0` for every q, the inertia of a
//! step `1/(2h^2) sum_v m_v |c + R y_v - xt_v|^2` is, up to a constant of the
//! step, `M/(2h^2) |c - ct|^2 + 1/(2h^2) [q^T Mqq q + 2 b.q - 2 tr(R^T B(q))]`
//! with `B(q) = B0 + sum_k q_k B_k` (see the module documentation of
//! [`crate::body_frame`]). The `q^T Mqq q` part is evaluated by the elastic
//! system (it is its mass term); this module holds the rest.

use crate::second_thread::product_by_rows;
use faer::{Accum, MatMut, MatRef};
use nalgebra::{Matrix3, Vector3};

use super::rotation::axial;
use super::Pose;
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::integrator::Integrator;
use crate::reduced::symmetrized_spd;

/// Mass moments of the body over all its vertices, fixed for a mesh and basis.
#[derive(Debug, Clone)]
pub struct MassMoments {
    /// Total mass M, kg.
    pub(super) total: f64,
    /// `J = sum m Xbar Xbar^T`, kg m^2.
    pub(super) j: Matrix3<f64>,
    /// `P_k = sum m W^k Xbar^T`, n of them.
    pub(super) p: Vec<Matrix3<f64>>,
    /// `Q_lk = sum m W^l W^k^T` laid out for `Y_k`: the nine components
    /// (row-major) of `Q_lk` over l, nine rows of n per k.
    pub(super) q_by_mode: Vec<f64>,
    /// `Mqq_kl = tr Q_kl`, symmetrised (checked positive definite), n x n.
    pub(super) mode_mass: Vec<f64>,
    /// `b_k = tr P_k`.
    pub(super) b: Vec<f64>,
}

/// A row-major 3x3 block of `data` at `at`.
fn block(data: &[f64], at: usize) -> Matrix3<f64> {
    Matrix3::from_row_slice(&data[9 * at..9 * at + 9])
}

impl MassMoments {
    /// Validated moments: `j` 3x3, `p` n x 3 x 3, `q` n x n x 3 x 3 (row-major);
    /// J symmetric positive definite (a body that is not a point or a line) and
    /// `Q_kl = Q_lk^T`, both to a relative 1e-8.
    pub fn new(total_mass: f64, j: &[f64], p: &[f64], q: &[f64]) -> Result<Self> {
        check_positive("total_mass", total_mass)?;
        if j.len() != 9 {
            return Err(LicromError::shape("inertia_moments", "(3, 3)", format!("{} values", j.len())));
        }
        if !p.len().is_multiple_of(9) {
            return Err(LicromError::shape("mode_moments", "(n, 3, 3)", format!("{} values", p.len())));
        }
        let n = p.len() / 9;
        if q.len() != 9 * n * n {
            return Err(LicromError::shape("mode_products", format!("({n}, {n}, 3, 3)"), format!("{} values", q.len())));
        }
        check_finite("inertia_moments", j)?;
        check_finite("mode_moments", p)?;
        check_finite("mode_products", q)?;
        let jm = block(j, 0);
        let scale = jm.amax();
        if (jm - jm.transpose()).amax() > 1e-8 * scale || jm.symmetric_eigen().eigenvalues.min() <= 1e-12 * scale {
            return Err(LicromError::invalid("inertia_moments", "must be symmetric positive definite (a solid, not a point, line or plane)"));
        }
        let qm: Vec<Matrix3<f64>> = (0..n * n).map(|i| block(q, i)).collect();
        let qscale = qm.iter().fold(0.0_f64, |m, b| m.max(b.amax()));
        for k in 0..n {
            for l in 0..n {
                if (qm[k * n + l] - qm[l * n + k].transpose()).amax() > 1e-8 * qscale {
                    return Err(LicromError::invalid("mode_products", format!("must satisfy Q[k, l] = Q[l, k]^T, fails at ({k}, {l})")));
                }
            }
        }
        let traces: Vec<f64> = qm.iter().map(|m| m.trace()).collect();
        let mode_mass = if n == 0 { traces } else { symmetrized_spd(&traces, n)? };
        let pm: Vec<Matrix3<f64>> = (0..n).map(|i| block(p, i)).collect();
        let mut q_by_mode = vec![0.0; 9 * n * n];
        for k in 0..n {
            for l in 0..n {
                for (a, v) in qm[l * n + k].transpose().iter().enumerate() {
                    // Column-major iteration of the transpose: row-major of Q_lk.
                    q_by_mode[(9 * k + a) * n + l] = *v;
                }
            }
        }
        Ok(Self { total: total_mass, j: 0.5 * (jm + jm.transpose()), b: pm.iter().map(|m| m.trace()).collect(), p: pm, q_by_mode, mode_mass })
    }

    /// Number of modes n.
    pub fn n_modes(&self) -> usize {
        self.p.len()
    }

    /// `Mqq_kl = tr Q_kl` (symmetrised, positive definite), n x n row-major.
    pub fn mode_mass(&self) -> &[f64] {
        &self.mode_mass
    }

    /// `sum m y Xbar^T = J + sum_l q_l P_l`.
    pub fn y_xbar(&self, q: &[f64]) -> Matrix3<f64> {
        self.p.iter().zip(q).fold(self.j, |acc, (p, ql)| acc + p * *ql)
    }

    /// The nine components (row-major) of `sum_l q_l Q_lk` for every k, at
    /// each of the V coordinate vectors in the columns of `qs` (n x V), into
    /// the columns of `out` (9n x V, nine rows per k): one matrix product over
    /// the `Q_lk`, `O(9 n^2)` per vector. With `Y_k = P_k^T + that`,
    /// see [`Self::y_of`]. faer's product ran 2x faster than the 8-lane dot
    /// products it replaced (67 against 138 us a vector at n = 256, one core,
    /// AVX-512), whose compiled form shuffled two-lane halves.
    fn mode_products(&self, qs: MatRef<'_, f64>, out: MatMut<'_, f64>) {
        let n = self.n_modes();
        product_by_rows(MatRef::from_row_major_slice(&self.q_by_mode, 9 * n, n), qs, out, Accum::Replace);
    }

    /// `Y_k = sum m y W^k^T = P_k^T + sum_l q_l Q_lk` from the nine values of
    /// its product (see [`Self::mode_products`]).
    fn y_of(&self, k: usize, product: &[f64]) -> Matrix3<f64> {
        self.p[k].transpose() + Matrix3::from_row_slice(product)
    }
}

/// Poses a step's history holds at most (BDF2's four).
const MAX_POSES: usize = 4;

/// What the inertia needs from the start of a step: the predicted centre of
/// mass `ct` and the moments `B0`, `B_k` against `a_v = sum_i w_i R^i y^i_v`
/// over the poses i of the step's history with the integrator's weights w_i
/// (`2 R^t y^t_v - R^{t-1} y^{t-1}_v` for backward Euler).
#[derive(Debug, Clone)]
pub struct InertiaTarget {
    pub(super) ct: Vector3<f64>,
    pub(super) b0: Matrix3<f64>,
    pub(super) bk: Vec<Matrix3<f64>>,
    /// The Gauss-Newton inertia's q-dependent moments at the step's start pose
    /// q^t: `C` and the `a(Y_k)` (see [`Self::add_gauss_newton`]).
    gn_c: Matrix3<f64>,
    gn_axial: Vec<Vector3<f64>>,
    /// The `Y_k` of the poses of the last [`Self::begin`] (pose-major, n each)
    /// with their q, `held` of them: a step's history repeats all but the
    /// newest pose of the one before, whose `Y_k` are taken from here instead
    /// of another pass over the `Q_lk` (half of that pass for backward Euler,
    /// three quarters for BDF2). `next_*`: the buffers being filled.
    held_ys: Vec<Matrix3<f64>>,
    held_q: Vec<f64>,
    held: usize,
    next_ys: Vec<Matrix3<f64>>,
    next_q: Vec<f64>,
    /// Scratch of [`Self::begin`]: the q of the poses not held (n each) and
    /// their products with the `Q_lk` (9n each).
    new_q: Vec<f64>,
    products: Vec<f64>,
}

impl InertiaTarget {
    /// Zeroed target for n modes.
    pub fn new(n: usize) -> Self {
        Self {
            ct: Vector3::zeros(),
            b0: Matrix3::zeros(),
            bk: vec![Matrix3::zeros(); n],
            gn_c: Matrix3::zeros(),
            gn_axial: vec![Vector3::zeros(); n],
            held_ys: vec![Matrix3::zeros(); MAX_POSES * n],
            held_q: vec![0.0; MAX_POSES * n],
            held: 0,
            next_ys: vec![Matrix3::zeros(); MAX_POSES * n],
            next_q: vec![0.0; MAX_POSES * n],
            new_q: vec![0.0; MAX_POSES * n],
            products: vec![0.0; MAX_POSES * 9 * n],
        }
    }

    /// Fills the target of a step from the poses `history`, newest first (the
    /// current one at time t, then t - 1, ...), weighted as `integrator` says,
    /// with its effective step `h` (s).
    ///
    /// # Panics
    /// If `history` holds fewer poses than the integrator reads (2 or 4).
    pub fn begin(&mut self, m: &MassMoments, history: &[&Pose], integrator: Integrator, gravity: &Vector3<f64>, h: f64) {
        let w = integrator.target_weights();
        match integrator {
            Integrator::BackwardEuler => self.begin_with::<2>(m, [history[0], history[1]], [w[0], w[1]], gravity, h),
            Integrator::Bdf2 => self.begin_with::<4>(m, [history[0], history[1], history[2], history[3]], w, gravity, h),
        }
    }

    /// [`Self::begin`]: the `Y_k` of the poses the last call did not see, in
    /// one product over the `Q_lk` (`O(9 n^2)` each), those of the current
    /// pose kept for the Gauss-Newton inertia.
    fn begin_with<const V: usize>(&mut self, m: &MassMoments, poses: [&Pose; V], weights: [f64; V], gravity: &Vector3<f64>, h: f64) {
        let n = m.n_modes();
        let cur = poses[0];
        self.ct = poses.iter().zip(weights).fold(gravity * (h * h), |acc, (p, w)| acc + p.center * w);
        let turns: [Matrix3<f64>; V] = std::array::from_fn(|i| poses[i].rotation * weights[i]);
        self.b0 = poses.iter().zip(&turns).fold(Matrix3::zeros(), |acc, (p, r)| acc + r * m.y_xbar(&p.q));
        self.gn_c = m.j;
        let held: [Option<usize>; V] = std::array::from_fn(|v| (0..self.held).find(|&j| self.held_q[j * n..(j + 1) * n] == poses[v].q[..]));
        let mut missing = 0;
        for (pose, _) in poses.iter().zip(&held).filter(|(_, h)| h.is_none()) {
            self.new_q[missing * n..(missing + 1) * n].copy_from_slice(&pose.q);
            missing += 1;
        }
        if missing > 0 {
            let qs = MatRef::from_column_major_slice(&self.new_q[..missing * n], n, missing);
            m.mode_products(qs, MatMut::from_column_major_slice_mut(&mut self.products[..missing * 9 * n], 9 * n, missing));
        }
        let mut column = 0;
        for (v, held) in held.iter().enumerate() {
            let ys = &mut self.next_ys[v * n..(v + 1) * n];
            match held {
                Some(j) => ys.copy_from_slice(&self.held_ys[j * n..(j + 1) * n]),
                None => {
                    let products = &self.products[column * 9 * n..(column + 1) * 9 * n];
                    for (k, (y, t)) in ys.iter_mut().zip(products.chunks_exact(9)).enumerate() {
                        *y = m.y_of(k, t);
                    }
                    column += 1;
                }
            }
        }
        for (v, pose) in poses.iter().enumerate() {
            self.next_q[v * n..(v + 1) * n].copy_from_slice(&pose.q);
        }
        std::mem::swap(&mut self.held_ys, &mut self.next_ys);
        std::mem::swap(&mut self.held_q, &mut self.next_q);
        self.held = V;
        for (k, (b, a)) in self.bk.iter_mut().zip(self.gn_axial.iter_mut()).enumerate() {
            let ys: [Matrix3<f64>; V] = std::array::from_fn(|v| self.held_ys[v * n + k]);
            *b = turns.iter().zip(&ys).fold(Matrix3::zeros(), |acc, (r, y)| acc + r * y);
            *a = axial(&ys[0]);
            self.gn_c += (m.p[k] + ys[0]).transpose() * cur.q[k];
        }
    }

    /// Takes the `Y_k` held by `other` (the target of the step before, when
    /// the solver alternates two targets), giving it this one's.
    pub(super) fn take_held(&mut self, other: &mut InertiaTarget) {
        std::mem::swap(&mut self.held_ys, &mut other.held_ys);
        std::mem::swap(&mut self.held_q, &mut other.held_q);
        std::mem::swap(&mut self.held, &mut other.held);
    }

    /// Adds the Gauss-Newton inertia `J^T M J` of the vertex positions,
    /// `Jv = [I, -[R y_v]x, R W_v]`, scaled by `scale`, to `hess` (N x N) without
    /// its `Mqq` block (which the elastic system holds): `M I` for c,
    /// `R (tr C I - C) R^T` (C = sum m y y^T: the inertia tensor) for omega and
    /// `R a(Y_k)` between omega and q_k, with `C = J + sum_k q_k (P_k + Y_k)^T`
    /// (as `Q_kl = Q_lk^T`). R is the rotation of `pose`, but `y_v` and the
    /// moments are those of the step's start pose q^t, found by [`Self::begin`]
    /// in its pass over the `Q_lk`: `O(n)` for each matrix the solver factors
    /// instead of another `O(9 n^2)` pass (a sixth of a contact step's
    /// instructions at r = 120). It is still the Gram matrix of a Jacobian
    /// (at `(R, q^t)`), positive semi-definite with `Mqq`, and differs from the
    /// exact Hessian by terms of order h^2 times the accelerations and of
    /// order `q - q^t` in the omega rows: it shapes the directions only, the
    /// line search and the residual take the exact energy and gradient.
    pub fn add_gauss_newton(&self, m: &MassMoments, pose: &Pose, scale: f64, hess: &mut [f64]) {
        let r = &pose.rotation;
        let ww = r * (Matrix3::identity() * self.gn_c.trace() - self.gn_c) * r.transpose() * scale;
        add_blocks(hess, 6 + m.n_modes(), m.total * scale, &ww, |k| r * self.gn_axial[k] * scale);
    }

    /// `B(q) = B0 + sum_k q_k B_k`.
    pub fn b_of(&self, q: &[f64]) -> Matrix3<f64> {
        self.bk.iter().zip(q).fold(self.b0, |acc, (b, qk)| acc + b * *qk)
    }

    /// Inertia energy (J) without its `q^T Mqq q / (2h^2)` part and without the
    /// constant of the step; adds its gradient in `(c, omega, q)` to `grad`
    /// (length 6 + n) when given.
    pub fn energy(&self, m: &MassMoments, pose: &Pose, h: f64, grad: Option<&mut [f64]>) -> f64 {
        let inv_h2 = 1.0 / (h * h);
        let (r, q) = (&pose.rotation, &pose.q);
        let dc = pose.center - self.ct;
        let b = self.b_of(q);
        let bq: f64 = m.b.iter().zip(q).map(|(b, q)| b * q).sum();
        let e = 0.5 * m.total * dc.norm_squared() * inv_h2 + (bq - r.dot(&b)) * inv_h2;
        if let Some(g) = grad {
            let gc = dc * (m.total * inv_h2);
            let gw = axial(&(b * r.transpose())) * inv_h2;
            g[..3].iter_mut().zip(gc.iter()).for_each(|(a, v)| *a += v);
            g[3..6].iter_mut().zip(gw.iter()).for_each(|(a, v)| *a += v);
            for (k, gk) in g[6..].iter_mut().enumerate() {
                *gk += (m.b[k] - r.dot(&self.bk[k])) * inv_h2;
            }
        }
        e
    }

    /// Adds the exact Hessian of [`Self::energy`] at `pose` (for the pulled-back
    /// function `omega -> E(exp([omega]x) R)` at omega = 0) to the full symmetric
    /// `hess` (N x N, N = 6 + n): `M/h^2 I` for c, `(tr S I - sym S)/h^2`,
    /// `S = B(q) R^T`, for omega, and `a(B_k R^T)/h^2` between omega and q_k.
    pub fn add_exact_hessian(&self, m: &MassMoments, pose: &Pose, h: f64, hess: &mut [f64]) {
        let inv_h2 = 1.0 / (h * h);
        let big = 6 + m.n_modes();
        let rt = pose.rotation.transpose();
        let s = self.b_of(&pose.q) * rt;
        let ww = (Matrix3::identity() * s.trace() - 0.5 * (s + s.transpose())) * inv_h2;
        let cross = |k: usize| axial(&(self.bk[k] * rt)) * inv_h2;
        add_blocks(hess, big, m.total * inv_h2, &ww, cross);
    }
}

/// Adds `cc I` to the centre block, `ww` to the rotation block and
/// `cross(k)` between omega and q_k (both ways) of the N x N `hess`.
fn add_blocks(hess: &mut [f64], big: usize, cc: f64, ww: &Matrix3<f64>, cross: impl Fn(usize) -> Vector3<f64>) {
    add_rigid(hess, big, cc, ww);
    for k in 0..big - 6 {
        add_cross(hess, big, k, &cross(k));
    }
}

/// Adds `cc I` to the centre block and `ww` to the rotation block of the N x N `hess`.
fn add_rigid(hess: &mut [f64], big: usize, cc: f64, ww: &Matrix3<f64>) {
    for i in 0..3 {
        hess[i * big + i] += cc;
        for j in 0..3 {
            hess[(3 + i) * big + 3 + j] += ww[(i, j)];
        }
    }
}

/// Adds `v` between omega and q_k (both ways) of the N x N `hess`.
#[inline]
fn add_cross(hess: &mut [f64], big: usize, k: usize, v: &Vector3<f64>) {
    for i in 0..3 {
        hess[(3 + i) * big + 6 + k] += v[i];
        hess[(6 + k) * big + 3 + i] += v[i];
    }
}
