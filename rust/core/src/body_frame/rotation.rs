//! Small SO(3) helpers: cross-product matrix, the axial vector of a 3x3
//! matrix, and the exponential and logarithm maps.

use nalgebra::{Matrix3, Vector3};

/// The cross-product matrix `[v]x` (`[v]x u = v x u`).
#[inline]
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `a(S) = (S23 - S32, S31 - S13, S12 - S21)` (1-based): the vector with
/// `tr([w]x S) = w . a(S)` for every w. For `S = u v^T` it is `u x v`.
#[inline]
pub fn axial(s: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(s[(1, 2)] - s[(2, 1)], s[(2, 0)] - s[(0, 2)], s[(0, 1)] - s[(1, 0)])
}

/// `exp([w]x)`: the rotation by `|w|` radians about `w` (Rodrigues).
pub fn exp_map(w: &Vector3<f64>) -> Matrix3<f64> {
    let t2 = w.norm_squared();
    let k = skew(w);
    // Series below 1e-4 rad keep full precision where the closed form cancels.
    let (a, b) = if t2 < 1e-8 {
        (1.0 - t2 / 6.0, 0.5 - t2 / 24.0)
    } else {
        let t = t2.sqrt();
        (t.sin() / t, (1.0 - t.cos()) / t2)
    };
    Matrix3::identity() + k * a + k * k * b
}

/// `w` with `exp([w]x) = r` and `|w| <= pi`, for a rotation matrix `r`.
pub fn log_map(r: &Matrix3<f64>) -> Vector3<f64> {
    // vee(R - R^T) = 2 sin(t) u.
    let v = -axial(r);
    let cos = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    let sin = 0.5 * v.norm();
    let t = sin.atan2(cos);
    if t < 1e-4 {
        return v * (0.5 * (1.0 + t * t / 6.0));
    }
    if cos > -0.9 {
        return v * (t / (2.0 * sin));
    }
    // Near pi the sine loses the axis: take it from the symmetric part
    // (R + R^T)/2 = cos(t) I + (1 - cos(t)) u u^T, sign from v.
    let uu = ((r + r.transpose()) * 0.5 - Matrix3::identity() * cos) / (1.0 - cos);
    let i = (0..3).max_by(|&a, &b| uu[(a, a)].total_cmp(&uu[(b, b)])).unwrap_or(0);
    let mut u: Vector3<f64> = uu.column(i) / uu[(i, i)].max(f64::MIN_POSITIVE).sqrt();
    u.normalize_mut();
    if u.dot(&v) < 0.0 {
        u = -u;
    }
    u * t
}

/// Whether `r` is a rotation: `|R^T R - I|_max <= tol` and `det R > 0`.
pub fn is_rotation(r: &Matrix3<f64>, tol: f64) -> bool {
    let e = r.transpose() * r - Matrix3::identity();
    r.iter().all(|v| v.is_finite()) && e.amax() <= tol && r.determinant() > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::Rng;

    #[test]
    fn axial_is_the_trace_pairing_and_the_cross_product() {
        let mut rng = Rng::new(1);
        let s = rng.matrix3(1.0);
        let w = Vector3::new(rng.uniform(), rng.uniform(), rng.uniform());
        assert!(((skew(&w) * s).trace() - w.dot(&axial(&s))).abs() < 1e-14);
        let (u, v) = (Vector3::new(0.3, -1.0, 2.0), Vector3::new(1.5, 0.2, -0.7));
        assert!((axial(&(u * v.transpose())) - u.cross(&v)).norm() < 1e-14);
        assert!((skew(&u) * v - u.cross(&v)).norm() < 1e-15);
    }

    #[test]
    fn exp_and_log_are_inverse_and_match_nalgebra() {
        let mut rng = Rng::new(2);
        for scale in [1e-9, 1e-5, 0.3, 2.0, 3.1] {
            for _ in 0..20 {
                let w = Vector3::new(rng.uniform(), rng.uniform(), rng.uniform()).normalize() * scale * (0.5 + 0.5 * rng.uniform().abs());
                let r = exp_map(&w);
                let reference = nalgebra::Rotation3::from_scaled_axis(w).into_inner();
                assert!((r - reference).amax() < 1e-14, "exp at |w| = {}", w.norm());
                assert!(is_rotation(&r, 1e-13));
                let back = log_map(&r);
                assert!((back - w).norm() < 1e-12 * w.norm().max(1e-3), "log at |w| = {}: {back} vs {w}", w.norm());
            }
        }
        // Exactly pi: either sign of the axis is the same rotation.
        let w = Vector3::new(0.0, 0.6, 0.8) * std::f64::consts::PI;
        assert!((exp_map(&log_map(&exp_map(&w))) - exp_map(&w)).amax() < 1e-12);
        assert!(!is_rotation(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0)), 1e-8));
    }
}
