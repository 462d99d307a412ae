//! Penalty contact against planes with normal damping and implicit Coulomb
//! friction, per contact point.
//!
//! Each contact point j carries a share `a_j` (m^2) of the boundary area, so the
//! stiffnesses are per unit area and the same scene behaves the same whatever the
//! density of contact points. For one point at `x` (m) against one plane, with
//! `x_prev` the point's position at the start of the step and `h` the time step:
//!
//! - gap `g = n.x + d`; penalty `a k_n/2 min(g, 0)^2`;
//! - lagged normal force `f_n = a k_n max(-g(x_prev), 0)` (N), fixed during the step;
//! - damping, only for points with `f_n > 0` and only while approaching:
//!   `a k_d h/2 min(v_n, 0)^2` with `v_n = n.(x - x_prev)/h`;
//! - friction as a dissipation potential of the tangential slip
//!   `delta = T (x - x_prev)`, `T = I - n n^T`: with `c = a k_f / h` (N/m) and the
//!   Coulomb limit `mu f_n`, `c |delta|^2 / 2` while `c |delta| <= mu f_n` (stick),
//!   else `mu f_n |delta| - (mu f_n)^2 / (2 c)` (slip). It is C^1 and its gradient
//!   is the force of magnitude `min(a k_f s, mu f_n)`, `s = |delta|/h`, opposing
//!   the slip.
//!
//! All three Hessians are PSD; they are returned as at most three weighted
//! rank-one terms so that assembly can stack their square-root factors.
//!
//! This is the friction law, with its stick switch ([`ContactModel::stick_switch`]),
//! the correction of a Newton direction that would carry a slipping point
//! through the stick region. Their sums over the contact points are in
//! `reduced/contact.rs` (world frame) and `body_frame/contact.rs`; the
//! solvers' use of the switch in `solver/contact_model.rs`.

use nalgebra::{Matrix3, Vector3};

use crate::error::{check_non_negative, LicromError, Result};

/// A frictional half-space `n.x + d >= 0` (the solid stays on the positive side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    normal: Vector3<f64>,
    offset: f64,
    friction: f64,
    /// Orthonormal tangents completing `normal` to a right-handed frame.
    tangents: [Vector3<f64>; 2],
}

impl Plane {
    /// Plane with outward `normal` (any non-zero length: it is normalised and the
    /// offset (m) scaled with it, so the half-space is the one given) and
    /// Coulomb coefficient `friction >= 0`.
    pub fn new(normal: Vector3<f64>, offset: f64, friction: f64) -> Result<Self> {
        let length = normal.norm();
        if !(length.is_finite() && length > 1e-12 && offset.is_finite()) {
            return Err(LicromError::invalid(
                "plane",
                format!("needs a finite non-zero normal and a finite offset, got normal {:?}, offset {offset}", normal.as_slice()),
            ));
        }
        check_non_negative("plane friction", friction)?;
        let normal = normal / length;
        // Any vector not parallel to the normal seeds the tangent frame.
        let seed = if normal.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
        let t1 = normal.cross(&seed).normalize();
        let t2 = normal.cross(&t1);
        Ok(Self { normal, offset: offset / length, friction, tangents: [t1, t2] })
    }

    /// Unit outward normal.
    pub fn normal(&self) -> Vector3<f64> {
        self.normal
    }

    /// Offset d (m) of `n.x + d >= 0`.
    pub fn offset(&self) -> f64 {
        self.offset
    }

    /// Coulomb friction coefficient.
    pub fn friction(&self) -> f64 {
        self.friction
    }

    /// Signed distance `n.x + d` (m), negative inside.
    #[inline]
    pub fn gap(&self, x: &Vector3<f64>) -> f64 {
        self.normal.dot(x) + self.offset
    }
}

/// Stiffnesses of the contact model (per unit area) and the time step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactModel {
    /// k_n, N/m^3 (pressure per metre of penetration).
    pub normal_stiffness: f64,
    /// k_d, N s/m^3 (pressure per m/s of approach speed).
    pub normal_damping: f64,
    /// k_f, N s/m^3 (traction per m/s of slip below the Coulomb limit).
    pub friction_stiffness: f64,
    /// Time step h, s.
    pub dt: f64,
}

/// A Hessian `sum_i coef[i] dir[i] dir[i]^T` with orthonormal `dir` and
/// `coef >= 0` (N/m); only the first `len` terms are used.
#[derive(Debug, Clone, Copy, Default)]
pub struct RankOneTerms {
    /// Weights, N/m.
    pub coef: [f64; 3],
    /// Unit directions.
    pub dir: [Vector3<f64>; 3],
    /// Number of terms in use.
    pub len: usize,
}

/// Relative change of a contact curvature below which a lagged contact Hessian
/// keeps the old term (see [`RankOneTerms::close_to`]).
pub const CURVATURE_SLACK: f64 = 1.1;
/// Cosine of the turn of a curvature direction above which a lagged contact
/// Hessian keeps the old term (about 6 degrees).
pub const DIRECTION_COS: f64 = 0.995;

impl RankOneTerms {
    #[inline]
    fn push(&mut self, coef: f64, dir: Vector3<f64>) {
        if coef > 0.0 {
            self.coef[self.len] = coef;
            self.dir[self.len] = dir;
            self.len += 1;
        }
    }

    /// The dense 3x3 matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        (0..self.len).map(|i| self.dir[i] * self.dir[i].transpose() * self.coef[i]).sum()
    }

    /// Whether these terms may stand in for `other`: as many terms, curvatures
    /// within a ratio `slack` and directions with cosine at least `cos` (1, 1
    /// for equality).
    #[inline]
    pub fn close_to(&self, other: &RankOneTerms, slack: f64, cos: f64) -> bool {
        self.len == other.len
            && (0..self.len).all(|t| {
                let (ca, cb) = (self.coef[t], other.coef[t]);
                ca <= slack * cb && cb <= slack * ca && self.dir[t].dot(&other.dir[t]) >= cos
            })
    }

    /// The same terms with every direction mapped by `m` (a rotation).
    #[inline]
    pub fn rotated(&self, m: &Matrix3<f64>) -> RankOneTerms {
        let mut out = *self;
        for t in 0..self.len {
            out.dir[t] = m * self.dir[t];
        }
        out
    }

    /// Writes the square-root factors `sqrt(coef_t) dir_t` into `out` from
    /// index `at` on; returns the index after them.
    #[inline(always)]
    pub fn write_factors(&self, out: &mut [[f64; 3]], at: usize) -> usize {
        for t in 0..self.len {
            let d = self.dir[t] * self.coef[t].sqrt();
            out[at + t] = [d.x, d.y, d.z];
        }
        at + self.len
    }
}

/// Friction's stick switch of one slipping point against one plane
/// ([`ContactModel::stick_switch`]).
#[derive(Debug, Clone, Copy)]
pub struct StickSwitch {
    /// Square-root factors of the Hessian change from slip to stick (N/m when squared).
    pub factors: [Vector3<f64>; 2],
    /// Stick force minus slip force (as gradients), N.
    pub force: Vector3<f64>,
}

/// Energy (J), gradient (N, = minus the force) and PSD Hessian of one point
/// against one plane.
#[derive(Debug, Clone, Copy, Default)]
pub struct ContactEval {
    /// Penalty + damping + friction potential, J.
    pub energy: f64,
    /// Gradient w.r.t. the point position, N.
    pub gradient: Vector3<f64>,
    /// Hessian w.r.t. the point position, N/m.
    pub hessian: RankOneTerms,
}

impl ContactModel {
    /// Validated model: all stiffnesses >= 0, `dt > 0`.
    pub fn new(normal_stiffness: f64, normal_damping: f64, friction_stiffness: f64, dt: f64) -> Result<Self> {
        check_non_negative("normal_stiffness", normal_stiffness)?;
        check_non_negative("normal_damping", normal_damping)?;
        check_non_negative("friction_stiffness", friction_stiffness)?;
        crate::error::check_positive("dt", dt)?;
        Ok(Self { normal_stiffness, normal_damping, friction_stiffness, dt })
    }

    /// Lagged normal force `a k_n max(-g(x_prev), 0)`, N.
    #[inline]
    pub fn lagged_normal_force(&self, plane: &Plane, area: f64, x_prev: &Vector3<f64>) -> f64 {
        area * self.normal_stiffness * (-plane.gap(x_prev)).max(0.0)
    }

    /// Potential, gradient and Hessian at `x` of a point of area `area` (m^2)
    /// that started the step at `x_prev` with lagged normal force `normal_force`.
    #[inline(always)]
    pub fn evaluate(&self, plane: &Plane, area: f64, normal_force: f64, x: &Vector3<f64>, x_prev: &Vector3<f64>) -> ContactEval {
        let mut out = ContactEval::default();
        let n = plane.normal;
        let h = self.dt;

        // Penalty and damping both act along n; their curvatures add up.
        let mut normal_curvature = 0.0;
        let g = plane.gap(x);
        if g < 0.0 {
            let k = area * self.normal_stiffness;
            out.energy += 0.5 * k * g * g;
            out.gradient += n * (k * g);
            normal_curvature += k;
        }
        let dx = x - x_prev;
        if normal_force > 0.0 {
            let vn = n.dot(&dx) / h;
            if vn < 0.0 {
                let kd = area * self.normal_damping;
                out.energy += 0.5 * kd * h * vn * vn;
                out.gradient += n * (kd * vn);
                normal_curvature += kd / h;
            }
        }
        out.hessian.push(normal_curvature, n);

        let limit = plane.friction * normal_force;
        let c = area * self.friction_stiffness / h;
        if limit > 0.0 && c > 0.0 {
            let delta = dx - n * n.dot(&dx);
            let slip = delta.norm();
            if c * slip <= limit {
                out.energy += 0.5 * c * slip * slip;
                out.gradient += delta * c;
                out.hessian.push(c, plane.tangents[0]);
                out.hessian.push(c, plane.tangents[1]);
            } else {
                let t = delta / slip;
                out.energy += limit * slip - limit * limit / (2.0 * c);
                out.gradient += t * limit;
                // limit (T - t t^T)/|delta|: curvature only across the slip direction.
                out.hessian.push(limit / slip, n.cross(&t));
            }
        }
        out
    }

    /// Whether a point that moved by `dx` (m) since the start of the step
    /// slips against `plane` (its friction force at the Coulomb limit).
    #[inline]
    pub fn slips(&self, plane: &Plane, area: f64, normal_force: f64, dx: &Vector3<f64>) -> bool {
        let limit = plane.friction * normal_force;
        let c = area * self.friction_stiffness / self.dt;
        limit > 0.0 && c > 0.0 && c * (dx - plane.normal * plane.normal.dot(dx)).norm() > limit
    }

    /// Friction's correction of a step for a point that moved by `dx` (m) and
    /// slips: when the step, which moves the point by `motion` (m), would
    /// reverse its slip or bring it into the stick region, the point is
    /// modelled as sticking. The Hessian change `c T - (mu f_n / s)(T - t t^T)`
    /// (slip direction t, slip s, PSD since `c > mu f_n / s` while slipping)
    /// comes as the square-root factors `sqrt(c) t` and
    /// `sqrt(c - mu f_n / s) (n x t)`, with the change of the gradient
    /// `t (c s - mu f_n)`. None where the point does not slip or the step
    /// carries it on slipping.
    #[inline]
    pub fn stick_switch(&self, plane: &Plane, area: f64, normal_force: f64, dx: &Vector3<f64>, motion: &Vector3<f64>) -> Option<StickSwitch> {
        let limit = plane.friction * normal_force;
        let c = area * self.friction_stiffness / self.dt;
        if limit <= 0.0 {
            return None;
        }
        let n = plane.normal;
        let delta = dx - n * n.dot(dx);
        let slip = delta.norm();
        if c * slip <= limit {
            return None;
        }
        let t = delta / slip;
        let moved = delta + motion - n * n.dot(motion);
        if t.dot(&moved) >= limit / c {
            return None;
        }
        let (st, sb) = (c.sqrt(), (c - limit / slip).max(0.0).sqrt());
        Some(StickSwitch { factors: [t * st, n.cross(&t) * sb], force: t * (c * slip - limit) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{fd_gradient, fd_jacobian, rel_err, Rng};

    fn model() -> ContactModel {
        ContactModel::new(2.0e6, 3.0e3, 1.0e6, 1e-3).unwrap()
    }

    fn v3(x: &[f64]) -> Vector3<f64> {
        Vector3::new(x[0], x[1], x[2])
    }

    /// Checks gradient and Hessian against central differences at `x`.
    fn check(plane: &Plane, area: f64, fn_lag: f64, x: Vector3<f64>, x_prev: Vector3<f64>) -> ContactEval {
        let m = model();
        let e = m.evaluate(plane, area, fn_lag, &x, &x_prev);
        let h = 1e-9;
        let fd_g = fd_gradient(|y| m.evaluate(plane, area, fn_lag, &v3(y), &x_prev).energy, x.as_slice(), h);
        assert!(rel_err(e.gradient.as_slice(), &fd_g, 1e-9) < 1e-5, "grad {:?} vs {:?}", e.gradient, fd_g);
        let fd_h: Vec<f64> = fd_jacobian(|y| m.evaluate(plane, area, fn_lag, &v3(y), &x_prev).gradient.as_slice().to_vec(), x.as_slice(), h)
            .into_iter()
            .flatten()
            .collect();
        let hm = e.hessian.matrix();
        assert!(rel_err(hm.as_slice(), &fd_h, 1e-6) < 1e-5, "hess {hm} vs {fd_h:?}");
        assert!(hm.symmetric_eigen().eigenvalues.min() >= -1e-9 * hm.norm());
        e
    }

    fn tilted() -> Plane {
        Plane::new(Vector3::new(0.3, -0.2, 1.0), 0.05, 0.4).unwrap()
    }

    #[test]
    fn penalty_and_damping_derivatives() {
        let p = tilted();
        let area = 1e-3;
        let x_prev = Vector3::new(0.1, 0.2, -0.06);
        let fn_lag = model().lagged_normal_force(&p, area, &x_prev);
        assert!(fn_lag > 0.0);
        // Penetrating further while approaching: penalty + damping active.
        let x = x_prev - p.normal() * 2e-4 + Vector3::new(1e-5, 0.0, 0.0);
        let e = check(&p, area, fn_lag, x, x_prev);
        assert!(e.gradient.dot(&p.normal()) < 0.0, "contact must push outward");
        // Separating: no damping, penalty only.
        check(&p, area, fn_lag, x_prev + p.normal() * 1e-5, x_prev);
        // Outside the plane and not in contact at the start: nothing at all.
        let out = check(&p, area, 0.0, Vector3::new(0.0, 0.0, 1.0), Vector3::new(0.0, 0.0, 1.01));
        assert_eq!(out.energy, 0.0);
        assert_eq!(out.hessian.len, 0);
    }

    #[test]
    fn friction_stick_and_slip_derivatives() {
        let p = tilted();
        let m = model();
        let area = 1e-3;
        let x_prev = Vector3::new(0.1, 0.2, -0.06);
        let fn_lag = m.lagged_normal_force(&p, area, &x_prev);
        let c = area * m.friction_stiffness / m.dt;
        let threshold = p.friction() * fn_lag / c;
        let mut rng = Rng::new(2);
        for scale in [0.3, 3.0] {
            for _ in 0..10 {
                let dir = Vector3::new(rng.uniform(), rng.uniform(), rng.uniform());
                let tangential = (dir - p.normal() * p.normal().dot(&dir)).normalize();
                let x = x_prev + tangential * (threshold * scale) - p.normal() * 1e-6 * rng.uniform();
                let e = check(&p, area, fn_lag, x, x_prev);
                let ft = -(e.gradient - p.normal() * p.normal().dot(&e.gradient));
                let expected = (c * threshold * scale).min(p.friction() * fn_lag);
                assert!((ft.norm() - expected).abs() < 1e-9 * expected, "friction magnitude");
                assert!(ft.dot(&tangential) < 0.0, "friction opposes slip");
            }
        }
    }

    #[test]
    fn friction_is_continuous_at_the_coulomb_limit_and_clean_at_zero() {
        let p = Plane::new(Vector3::z(), 0.0, 0.5).unwrap();
        let m = model();
        let (area, fn_lag) = (1e-3, 10.0);
        let c = area * m.friction_stiffness / m.dt;
        let threshold = p.friction() * fn_lag / c;
        let at = |s: f64| m.evaluate(&p, area, fn_lag, &Vector3::new(s, 0.0, 0.0), &Vector3::zeros());
        let (below, above) = (at(threshold * (1.0 - 1e-12)), at(threshold * (1.0 + 1e-12)));
        assert!((below.energy - above.energy).abs() < 1e-9 * below.energy);
        assert!((below.gradient - above.gradient).norm() < 1e-9 * below.gradient.norm());
        let zero = at(0.0);
        assert_eq!(zero.energy, 0.0);
        assert_eq!(zero.gradient, Vector3::zeros());
        assert!(zero.hessian.len == 2 && zero.hessian.coef.iter().all(|c| c.is_finite()));
        // No normal force: no friction, no damping.
        let free = m.evaluate(&p, area, 0.0, &Vector3::new(1.0, 0.0, 0.1), &Vector3::zeros());
        assert_eq!(free.energy, 0.0);
        assert_eq!(free.hessian.len, 0);
    }

    #[test]
    fn plane_is_normalised_and_validated() {
        let p = Plane::new(Vector3::new(0.0, 0.0, 2.0), 1.0, 0.3).unwrap();
        assert!((p.normal() - Vector3::z()).norm() < 1e-15);
        assert_eq!(p.offset(), 0.5);
        let [t1, t2] = p.tangents;
        assert!(t1.dot(&p.normal()).abs() < 1e-15 && t2.dot(&t1).abs() < 1e-15 && (t2.norm() - 1.0).abs() < 1e-15);
        assert!(Plane::new(Vector3::zeros(), 0.0, 0.3).is_err());
        assert!(Plane::new(Vector3::z(), 0.0, -0.1).is_err());
        assert!(ContactModel::new(1.0, 0.0, 1.0, 0.0).is_err());
    }
}
