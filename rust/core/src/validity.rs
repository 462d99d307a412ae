//! What the valid range of the physics needs from each step (see the Python
//! `licrom.validity` for the policy): the smallest `det F` over the elements
//! and the deepest penetration of a contact point into a plane.
//!
//! The reduced solvers keep both from the evaluation at the accepted iterate of
//! every step, where the elastic kernel forms each cubature point's F and the
//! contact term each engaged point's gap anyway: checking every step then costs
//! a determinant per point and a comparison per gap, not a pass of its own. The
//! step's final Newton correction (below the tolerance) is not re-evaluated.

use crate::real::LANES;
use crate::simd::F8;

/// Smallest `det F` and deepest penetration of one evaluation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validity {
    /// Smallest `det F` over the cubature points with weight > 0; +inf without any.
    pub min_det: f64,
    /// Deepest penetration of a contact point into a plane, m, >= 0 (the
    /// negated smallest gap); points the contact culls (gap bounded above
    /// zero) count as outside.
    pub depth: f64,
}

impl Default for Validity {
    fn default() -> Self {
        Self { min_det: f64::INFINITY, depth: 0.0 }
    }
}

impl Validity {
    /// Takes in the lanes of [`lowest_dets`].
    #[inline(always)]
    pub fn take_lanes(&mut self, low: &F8) {
        for &d in low {
            if d < self.min_det {
                self.min_det = d;
            }
        }
    }

    /// Takes in a contact point's gap to a plane, m.
    #[inline(always)]
    pub fn take_gap(&mut self, gap: f64) {
        self.depth = self.depth.max(-gap);
    }
}

/// Lowers each lane of `low` to the `det F` of that lane's point, for eight
/// points' row-major F (nine lanes) with `weight > 0`: kept in registers over
/// the kernel's pass and taken in once at its end ([`Validity::take_lanes`]).
#[inline(always)]
pub fn lowest_dets(f: &[F8; 9], weights: &[f64], low: &mut F8) {
    let w = &weights[..LANES];
    for l in 0..LANES {
        let det = f[0][l] * (f[4][l] * f[8][l] - f[5][l] * f[7][l]) - f[1][l] * (f[3][l] * f[8][l] - f[5][l] * f[6][l])
            + f[2][l] * (f[3][l] * f[7][l] - f[4][l] * f[6][l]);
        if w[l] > 0.0 && det < low[l] {
            low[l] = det;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn determinants_of_weighted_lanes_only() {
        let mut f = [[0.0; 8]; 9];
        for l in 0..8 {
            let s = 1.0 + l as f64;
            f[0][l] = s;
            f[4][l] = 2.0;
            f[8][l] = if l == 3 { -0.5 } else { 1.0 };
            f[1][l] = 7.0; // an upper-triangular F: det = product of the diagonal
        }
        let mut v = Validity::default();
        let mut weights = [1.0; 8];
        weights[3] = 0.0;
        let mut low = [f64::INFINITY; 8];
        lowest_dets(&f, &weights, &mut low);
        v.take_lanes(&low);
        assert_eq!(v.min_det, 2.0);
        weights[3] = 1.0;
        lowest_dets(&f, &weights, &mut low);
        v.take_lanes(&low);
        assert_eq!(v.min_det, -4.0);
    }

    #[test]
    fn depth_is_the_deepest_negative_gap() {
        let mut v = Validity::default();
        v.take_gap(0.3);
        assert_eq!(v.depth, 0.0);
        v.take_gap(-0.2);
        v.take_gap(-0.1);
        assert_eq!(v.depth, 0.2);
    }
}
