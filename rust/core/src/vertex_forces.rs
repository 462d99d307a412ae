//! Elastic forces of the full model at a few vertices, from the positions of
//! the corners of their one-ring tets.
//!
//! For a sample vertex v with one-ring tets t (rest volume `V_t`, shape
//! gradients `g_{t,a}` of its corners a), the force is minus the gradient of
//! the one ring's stable Neo-Hookean energy `sum_t V_t Psi(F_t)`:
//!
//! `F_t = sum_a y_a g_{t,a}^T`, `f_v = -sum_t V_t P(F_t) g_{t,v}`,
//!
//! with `P = dPsi/dF` ([`StableNeoHookean::pk1`]) and `g_{t,v}` the gradient of
//! v's own corner in t. With a material damping
//! ([`VertexForces::damped_forces`]) each ring tet adds the Kelvin-Voigt force
//! `-V_t kappa (F_t D_t) g_{t,v}`, `D_t = (F_t^T F_t - C_t)/2`, `kappa = eta/h'` and
//! the anchor `C_t = (1 + w) C(F_t^n) - w C(F_t^{n-1})` (as in
//! `rust/core/src/reduced/elastic.rs`). The online error estimate of a reduced run
//! (`python/licrom/reduced/error_estimate.py`) takes it every few steps at the
//! reconstructed positions: a few hundred tets, where a sparse product, a
//! batch of stresses and another sparse product from Python cost five times
//! as much, on one step in ten of every run.

use nalgebra::{Matrix3, Vector3};

use crate::error::{check_finite, check_output, LicromError, Result};
use crate::material::StableNeoHookean;

/// Borrowed description of the T one-ring tets of a sample of vertices.
#[derive(Debug, Clone, Copy)]
pub struct RingInputs<'a> {
    /// Corners of each ring tet, T x 4 point indices.
    pub corners: &'a [usize],
    /// Shape gradients of the corners, T x 4 x 3 (row-major), 1/m.
    pub gradients: &'a [f64],
    /// Rest volumes, T, m^3 (> 0).
    pub volumes: &'a [f64],
    /// The sample each tet's force goes to, T.
    pub owners: &'a [usize],
    /// Which corner (0-3) of its tet that sample is, T.
    pub own_corners: &'a [usize],
}

/// The damping's `kappa` (Pa) and the points' positions at the step's start
/// and, with the history weight w, the step before.
type Damping<'a> = (f64, &'a [f64], Option<(&'a [f64], f64)>);

/// The one-ring tets of a sample of vertices, in the numbering of the points
/// whose positions [`VertexForces::forces`] takes.
#[derive(Debug, Clone)]
pub struct VertexForces {
    n_points: usize,
    n_samples: usize,
    corners: Vec<[usize; 4]>,
    gradients: Vec<[Vector3<f64>; 4]>,
    volumes: Vec<f64>,
    /// The sample each tet's force goes to and which of its corners that is.
    owner: Vec<(usize, usize)>,
    material: StableNeoHookean,
}

impl VertexForces {
    /// From the `rings` (corners below `n_points`, owners below `n_samples`)
    /// and the material, after checking shapes, indices and values.
    pub fn new(n_points: usize, n_samples: usize, rings: &RingInputs<'_>, material: StableNeoHookean) -> Result<Self> {
        let RingInputs { corners, gradients, volumes, owners, own_corners } = *rings;
        let t = volumes.len();
        for (name, len, shape) in [("corners", corners.len(), 4 * t), ("gradients", gradients.len(), 12 * t)] {
            if len != shape {
                return Err(LicromError::shape(name, format!("({t}, {})", shape / t.max(1)), format!("{len} values")));
            }
        }
        for (name, len) in [("owners", owners.len()), ("own_corners", own_corners.len())] {
            if len != t {
                return Err(LicromError::shape(name, format!("({t},)"), format!("{len} values")));
            }
        }
        check_finite("gradients", gradients)?;
        if let Some(v) = volumes.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
            return Err(LicromError::invalid("volumes", format!("must be finite and > 0, found {v}")));
        }
        let bad = |name: &str, values: &[usize], bound: usize| -> Result<()> {
            match values.iter().find(|&&v| v >= bound) {
                Some(v) => Err(LicromError::invalid(name, format!("must be below {bound}, found {v}"))),
                None => Ok(()),
            }
        };
        bad("corners", corners, n_points)?;
        bad("owners", owners, n_samples)?;
        bad("own_corners", own_corners, 4)?;
        Ok(Self {
            n_points,
            n_samples,
            corners: corners.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(),
            gradients: gradients.chunks_exact(12).map(|g| std::array::from_fn(|a| Vector3::from_row_slice(&g[3 * a..3 * a + 3]))).collect(),
            volumes: volumes.to_vec(),
            owner: owners.iter().copied().zip(own_corners.iter().copied()).collect(),
            material,
        })
    }

    /// Number of points whose positions [`Self::forces`] takes.
    pub fn n_points(&self) -> usize {
        self.n_points
    }

    /// Number of sample vertices.
    pub fn n_samples(&self) -> usize {
        self.n_samples
    }

    /// The force on each sample (n_samples x 3, N) into `out`, from the
    /// positions of the points (n_points x 3, m).
    pub fn forces(&self, positions: &[f64], out: &mut [f64]) -> Result<()> {
        self.accumulate(positions, None, out)
    }

    /// [`Self::forces`] plus the material damping's, `kappa = eta/h'` (Pa), its
    /// anchor from the points' positions at the step's start `now` and, with the
    /// integrator's history weight w, the step before (all n_points x 3, m).
    pub fn damped_forces(&self, positions: &[f64], kappa: f64, now: &[f64], previous: Option<(&[f64], f64)>, out: &mut [f64]) -> Result<()> {
        for (name, values) in std::iter::once(("anchor positions", now)).chain(previous.map(|(p, _)| ("previous positions", p))) {
            self.check_positions(name, values)?;
        }
        self.accumulate(positions, Some((kappa, now, previous)), out)
    }

    fn check_positions(&self, name: &str, positions: &[f64]) -> Result<()> {
        if positions.len() != 3 * self.n_points {
            return Err(LicromError::shape(name, format!("({}, 3)", self.n_points), format!("{} values", positions.len())));
        }
        check_finite(name, positions)
    }

    fn accumulate(&self, positions: &[f64], damping: Option<Damping<'_>>, out: &mut [f64]) -> Result<()> {
        self.check_positions("positions", positions)?;
        if out.len() != 3 * self.n_samples {
            return Err(LicromError::shape("out", format!("({}, 3)", self.n_samples), format!("{} values", out.len())));
        }
        out.fill(0.0);
        let at = |x: &[f64], p: usize| Vector3::new(x[3 * p], x[3 * p + 1], x[3 * p + 2]);
        for (((corners, g), &volume), &(sample, own)) in self.corners.iter().zip(&self.gradients).zip(&self.volumes).zip(&self.owner) {
            let deformation = |x: &[f64]| -> Matrix3<f64> { (0..4).map(|a| at(x, corners[a]) * g[a].transpose()).sum() };
            let f = deformation(positions);
            let mut stress = self.material.pk1(&f);
            if let Some((kappa, now, previous)) = damping {
                let cauchy_green = |x: &[f64]| {
                    let fa = deformation(x);
                    fa.transpose() * fa
                };
                let anchor = match previous {
                    Some((prev, w)) => (1.0 + w) * cauchy_green(now) - w * cauchy_green(prev),
                    None => cauchy_green(now),
                };
                stress += kappa * f * (0.5 * (f.transpose() * f - anchor));
            }
            let force = stress * g[own] * -volume;
            for i in 0..3 {
                out[3 * sample + i] += force[i];
            }
        }
        check_output("the vertex forces", "positions", out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{fd_gradient, rel_err, tet_shape_gradients, Rng};

    /// Five points, two tets sharing the face (1, 2, 3) (corners flat, T x 4),
    /// their shape gradients and volumes.
    fn two_tets() -> (Vec<f64>, Vec<usize>, Vec<f64>, Vec<f64>) {
        let points = [Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z(), Vector3::new(1.0, 1.0, 1.0)];
        let tets = [[0, 1, 2, 3], [4, 3, 2, 1]];
        let (grads, volumes) = tet_shape_gradients(&points, &tets);
        (points.iter().flat_map(|p| p.iter().copied()).collect(), tets.concat(), grads, volumes)
    }

    /// `F` of tet t (corners `tets[4t..4t + 4]`, shape gradients `grads`) at the points `y`.
    fn deformation(tets: &[usize], grads: &[f64], y: &[f64], t: usize) -> Matrix3<f64> {
        (0..4)
            .map(|a| {
                let p = tets[4 * t + a];
                Vector3::from_column_slice(&y[3 * p..3 * p + 3]) * Vector3::from_column_slice(&grads[12 * t + 3 * a..12 * t + 3 * a + 3]).transpose()
            })
            .sum()
    }

    fn ring_energy(material: &StableNeoHookean, tets: &[usize], grads: &[f64], vols: &[f64], y: &[f64]) -> f64 {
        (0..vols.len()).map(|t| vols[t] * material.energy(&deformation(tets, grads, y, t))).sum()
    }

    #[test]
    fn forces_are_minus_the_ring_energy_gradient_by_finite_differences() {
        let (rest, tets, grads, vols) = two_tets();
        let material = StableNeoHookean::new(3.0e4, 5.0e4).unwrap();
        // Samples: the shared vertex 1 (a corner of both tets) and vertex 4 (of the second only).
        let (owners, own) = (vec![0, 0, 1], vec![1, 3, 0]);
        let ring_tets = [0usize, 1, 1];
        let corners: Vec<usize> = ring_tets.iter().flat_map(|&t| tets[4 * t..4 * t + 4].to_vec()).collect();
        let ring_grads: Vec<f64> = ring_tets.iter().flat_map(|&t| grads[12 * t..12 * t + 12].to_vec()).collect();
        let ring_vols: Vec<f64> = ring_tets.iter().map(|&t| vols[t]).collect();
        let rings = RingInputs { corners: &corners, gradients: &ring_grads, volumes: &ring_vols, owners: &owners, own_corners: &own };
        let forces = VertexForces::new(5, 2, &rings, material).unwrap();
        let mut rng = Rng::new(5);
        let y: Vec<f64> = rest.iter().zip(rng.vec(15, 0.1)).map(|(x, d)| x + d).collect();
        let mut out = vec![0.0; 6];
        forces.forces(&y, &mut out).unwrap();
        let fd = fd_gradient(|x| ring_energy(&material, &tets, &grads, &vols, x), &y, 1e-6);
        let expected: Vec<f64> = [1usize, 4].iter().flat_map(|&v| fd[3 * v..3 * v + 3].iter().map(|g| -g)).collect();
        assert!(expected.iter().any(|f| f.abs() > 1e2), "the deformed tets push back: {expected:?}");
        assert!(rel_err(&out, &expected, 1.0) < 1e-6, "{out:?} vs {expected:?}");
    }

    /// With a material damping the force is minus the gradient of the ring's elastic energy plus
    /// `V kappa/2 |D|^2` per tet, against the anchor of two earlier states (BDF2's weight 1/3).
    #[test]
    fn damped_forces_add_minus_the_damping_gradient_by_finite_differences() {
        let (rest, tets, grads, vols) = two_tets();
        let material = StableNeoHookean::new(3.0e4, 5.0e4).unwrap();
        let rings = RingInputs { corners: &tets, gradients: &grads, volumes: &vols, owners: &[0, 0], own_corners: &[1, 3] };
        let forces = VertexForces::new(5, 1, &rings, material).unwrap();
        let mut rng = Rng::new(6);
        let mut near = |scale: f64| -> Vec<f64> { rest.iter().zip(rng.vec(15, scale)).map(|(x, d)| x + d).collect() };
        let (y, now, previous) = (near(0.1), near(0.05), near(0.05));
        let (kappa, w) = (4.0e4, 1.0 / 3.0);
        let cg = |x: &[f64], t: usize| {
            let f = deformation(&tets, &grads, x, t);
            f.transpose() * f
        };
        let damping = |x: &[f64]| -> f64 {
            (0..2)
                .map(|t| {
                    let d = 0.5 * (cg(x, t) - ((1.0 + w) * cg(&now, t) - w * cg(&previous, t)));
                    vols[t] * 0.5 * kappa * d.norm_squared()
                })
                .sum()
        };
        let (mut plain, mut damped) = (vec![0.0; 3], vec![0.0; 3]);
        forces.forces(&y, &mut plain).unwrap();
        forces.damped_forces(&y, kappa, &now, Some((&previous, w)), &mut damped).unwrap();
        let fd = fd_gradient(damping, &y, 1e-7);
        let expected: Vec<f64> = plain.iter().zip(&fd[3..6]).map(|(f, g)| f - g).collect();
        assert!(fd[3..6].iter().any(|g| g.abs() > 1e2), "the damping pushes back: {fd:?}");
        assert!(rel_err(&damped, &expected, 1.0) < 1e-6, "{damped:?} vs {expected:?}");
        let err = forces.damped_forces(&y, kappa, &now[..6], None, &mut damped).unwrap_err().to_string();
        assert!(err.contains("anchor positions"), "{err}");
    }

    #[test]
    fn rest_positions_give_no_force() {
        let (rest, tets, grads, vols) = two_tets();
        let material = StableNeoHookean::new(3.0e4, 5.0e4).unwrap();
        let rings = RingInputs { corners: &tets, gradients: &grads, volumes: &vols, owners: &[0, 0], own_corners: &[1, 3] };
        let forces = VertexForces::new(5, 1, &rings, material).unwrap();
        let mut out = vec![1.0; 3];
        forces.forces(&rest, &mut out).unwrap();
        assert!(out.iter().all(|f| f.abs() < 1e-9), "{out:?}");
    }

    #[test]
    fn bad_input_is_an_error() {
        let (rest, tets, grads, vols) = two_tets();
        let material = StableNeoHookean::new(3.0e4, 5.0e4).unwrap();
        let make = |corners: &[usize], volumes: &[f64], owners: &[usize], own_corners: &[usize]| {
            VertexForces::new(5, 1, &RingInputs { corners, gradients: &grads, volumes, owners, own_corners }, material)
        };
        assert!(make(&tets[..7], &vols, &[0, 0], &[1, 3]).is_err());
        assert!(make(&[0, 1, 2, 3, 4, 3, 2, 5], &vols, &[0, 0], &[1, 3]).is_err());
        assert!(make(&tets, &[vols[0], 0.0], &[0, 0], &[1, 3]).is_err());
        assert!(make(&tets, &vols, &[0, 1], &[1, 3]).is_err());
        assert!(make(&tets, &vols, &[0, 0], &[1, 4]).is_err());
        let forces = make(&tets, &vols, &[0, 0], &[1, 3]).unwrap();
        let mut out = vec![0.0; 3];
        assert!(forces.forces(&rest[..12], &mut out).is_err());
        let mut nan = rest.clone();
        nan[4] = f64::NAN;
        assert!(forces.forces(&nan, &mut out).is_err());
    }
}
