//! Test helpers: a deterministic generator and central finite differences.

use nalgebra::{Matrix3, Vector3};

use crate::synthetic::SampledTerms;
use crate::validity::Validity;

/// SplitMix64: tiny, deterministic, good enough for test data.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(1))
    }

    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [-1, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    pub fn vec(&mut self, len: usize, scale: f64) -> Vec<f64> {
        (0..len).map(|_| scale * self.uniform()).collect()
    }

    pub fn matrix3(&mut self, scale: f64) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| scale * self.uniform())
    }

    /// Identity plus a random perturbation of size `scale`.
    pub fn deformation(&mut self, scale: f64) -> Matrix3<f64> {
        Matrix3::identity() + self.matrix3(scale)
    }
}

/// Shape gradients (T x 4 x 3, row-major: corner 0 first) and rest volumes
/// (T) of the tets `tets` over the points `points`.
pub fn tet_shape_gradients(points: &[Vector3<f64>], tets: &[[usize; 4]]) -> (Vec<f64>, Vec<f64>) {
    let (mut grads, mut volumes) = (Vec::new(), Vec::new());
    for t in tets {
        let dm = Matrix3::from_columns(&[points[t[1]] - points[t[0]], points[t[2]] - points[t[0]], points[t[3]] - points[t[0]]]);
        let inv = dm.try_inverse().expect("a non-degenerate tet");
        let rows: Vec<Vector3<f64>> = (0..3).map(|r| inv.row(r).transpose()).collect();
        grads.extend((-(rows[0] + rows[1] + rows[2])).iter());
        for r in &rows {
            grads.extend(r.iter());
        }
        volumes.push(dm.determinant().abs() / 6.0);
    }
    (grads, volumes)
}

/// Central-difference gradient of `f` at `x` with step `h`.
pub fn fd_gradient(f: impl Fn(&[f64]) -> f64, x: &[f64], h: f64) -> Vec<f64> {
    let mut xp = x.to_vec();
    (0..x.len())
        .map(|i| {
            xp[i] = x[i] + h;
            let fp = f(&xp);
            xp[i] = x[i] - h;
            let fm = f(&xp);
            xp[i] = x[i];
            (fp - fm) / (2.0 * h)
        })
        .collect()
}

/// Central-difference Jacobian (row i = d g / d x_i) of a vector function.
pub fn fd_jacobian(g: impl Fn(&[f64]) -> Vec<f64>, x: &[f64], h: f64) -> Vec<Vec<f64>> {
    let mut xp = x.to_vec();
    (0..x.len())
        .map(|i| {
            xp[i] = x[i] + h;
            let gp = g(&xp);
            xp[i] = x[i] - h;
            let gm = g(&xp);
            xp[i] = x[i];
            gp.iter().zip(&gm).map(|(a, b)| (a - b) / (2.0 * h)).collect()
        })
        .collect()
}

/// Largest absolute difference relative to the largest magnitude (floored at `floor`).
pub fn rel_err(a: &[f64], b: &[f64], floor: f64) -> f64 {
    let scale = a.iter().chain(b).fold(floor, |m, v| m.max(v.abs()));
    a.iter().zip(b).fold(0.0_f64, |m, (x, y)| m.max((x - y).abs())) / scale
}

/// Ten steps of a solid started inside the ground, `step` taking one and
/// returning the reported validity, q and the pose `(c, R)` that carries the
/// points of `terms` to the world (the identity in the world frame): each step reports the smallest `det F`
/// at the cubature points and the deepest penetration of a point, to 1e-6 (it
/// is taken at the accepted iterate, before the step's last correction below
/// the solver tolerance), and the solid is pushed out after the first.
pub fn check_pushed_out(terms: &SampledTerms, mut step: impl FnMut() -> (Validity, Vec<f64>, Vector3<f64>, Matrix3<f64>)) {
    let mut depths = vec![];
    for i in 0..10 {
        let (v, q, center, rotation) = step();
        let n = q.len();
        let dot = |row: &[f64]| row.iter().zip(&q).map(|(a, b)| a * b).sum::<f64>();
        let min_det = terms
            .cubature_jacobians
            .chunks_exact(9 * n)
            .map(|g| {
                let f: Vec<f64> = (0..9).map(|a| dot(&g[a * n..(a + 1) * n]) + if a % 4 == 0 { 1.0 } else { 0.0 }).collect();
                Matrix3::from_row_slice(&f).determinant()
            })
            .fold(f64::INFINITY, f64::min);
        let depth = terms
            .contact_basis
            .chunks_exact(3 * n)
            .zip(terms.contact_rest.chunks_exact(3))
            .map(|(w, x0)| center + rotation * Vector3::new(x0[0] + dot(&w[..n]), x0[1] + dot(&w[n..2 * n]), x0[2] + dot(&w[2 * n..])))
            .map(|x| -terms.planes[0].gap(&x))
            .fold(0.0, f64::max);
        assert!((v.min_det - min_det).abs() < 1e-6, "step {i}: det {} against {min_det}", v.min_det);
        assert!((v.depth - depth).abs() < 1e-6, "step {i}: depth {} against {depth}", v.depth);
        depths.push(v.depth);
    }
    assert!(depths[0] > 2e-3, "deep after the first step: {depths:?}");
    assert!(depths[1] < depths[0] && depths[9] < depths[0], "pushed out: {depths:?}");
}
