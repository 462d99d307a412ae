//! Test helpers: a deterministic generator and central finite differences.

use nalgebra::Matrix3;

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
