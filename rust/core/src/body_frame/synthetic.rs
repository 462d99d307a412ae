//! A synthetic body-frame model of the block of [`crate::synthetic`], for
//! tests and benchmarks: the same scene parameters (size, material, counts of
//! learned modes, cubature and contact points, plane), with the 6 symmetric
//! affine modes `S Xbar` and `r` smooth modes `d sin(k.X + phi)`, every one
//! made mass-orthogonal to the rigid modes on a grid of lumped vertex masses.
//! Directions, wave vectors and sample points come from a low-discrepancy
//! sequence, so the model is deterministic.

use nalgebra::{Matrix3, Vector3};

use super::rotation::skew;
use super::BodyFrameInputs;
use crate::error::Result;
use crate::synthetic::{BlockScene, SampledTerms};

/// Owned arrays of a synthetic body-frame block, borrowed by [`BodyBlock::inputs`].
#[derive(Debug, Clone)]
pub struct BodyBlock {
    /// The scene it was built from.
    pub scene: BlockScene,
    /// Modes n (6 affine when requested, plus the learned ones).
    pub n: usize,
    /// Total mass, kg.
    pub total_mass: f64,
    /// `Xbar_v` of the grid vertices, m.
    pub vertices: Vec<Vector3<f64>>,
    /// Their lumped masses, kg.
    pub masses: Vec<f64>,
    /// `W_v`, 3 x n row-major per vertex.
    pub vertex_basis: Vec<f64>,
    /// J, P, Q (row-major).
    pub inertia_moments: Vec<f64>,
    pub mode_moments: Vec<f64>,
    pub mode_products: Vec<f64>,
    /// The sampled elastic and contact terms.
    pub terms: SampledTerms,
}

/// Point i of the additive recurrence with the plastic-number increments
/// (well spread in the unit cube).
fn sequence(i: usize) -> [f64; 3] {
    let g = 1.324_717_957_244_746_f64;
    let a = [1.0 / g, 1.0 / (g * g), 1.0 / (g * g * g)];
    a.map(|a| (0.5 + a * (i + 1) as f64).fract())
}

/// A mode before orthogonalisation: value and gradient at a rest point X.
enum Mode {
    Affine(Matrix3<f64>),
    Wave { dir: Vector3<f64>, k: Vector3<f64>, phase: f64 },
}

impl Mode {
    fn value(&self, xbar: &Vector3<f64>, x: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Mode::Affine(s) => s * xbar,
            Mode::Wave { dir, k, phase } => dir * (k.dot(x) + phase).sin(),
        }
    }

    fn gradient(&self, x: &Vector3<f64>) -> Matrix3<f64> {
        match self {
            Mode::Affine(s) => *s,
            Mode::Wave { dir, k, phase } => dir * k.transpose() * (k.dot(x) + phase).cos(),
        }
    }
}

/// Builds the body-frame block of `scene`, with the 6 symmetric affine modes
/// when `affine` (else only the scene's learned modes; none gives a rigid body).
pub fn body_block(scene: &BlockScene, affine: bool) -> Result<BodyBlock> {
    let l = scene.size;
    let com = Vector3::repeat(l / 2.0);
    let mut modes = Vec::new();
    if affine {
        for (a, b) in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)] {
            let mut s = Matrix3::zeros();
            s[(a, b)] = if a == b { 1.0 } else { 0.5 };
            s[(b, a)] = s[(a, b)];
            modes.push(Mode::Affine(s));
        }
    }
    let mut counter = 1000 * scene.seed as usize;
    let mut next = || {
        counter += 1;
        Vector3::from(sequence(counter)) - Vector3::repeat(0.5)
    };
    for _ in 0..scene.learned_modes {
        let dir = next().normalize();
        // Wavelengths between 2L/3 and 2L, as in the world-frame block.
        let k = next().normalize() * (std::f64::consts::PI / l * (1.0 + 2.0 * (next().x + 0.5)));
        let phase = 2.0 * std::f64::consts::PI * (next().x + 0.5);
        modes.push(Mode::Wave { dir, k, phase });
    }
    let n = modes.len();

    // Lumped masses on a grid of cell centres.
    let grid = 10;
    let total_mass = scene.density * l * l * l;
    let m_v = total_mass / (grid * grid * grid) as f64;
    let mut vertices = Vec::new();
    for a in 0..grid {
        for b in 0..grid {
            for c in 0..grid {
                let x = Vector3::new(a as f64, b as f64, c as f64).map(|i| l * (i + 0.5) / grid as f64);
                vertices.push(x - com);
            }
        }
    }
    let masses = vec![m_v; vertices.len()];
    let j: Matrix3<f64> = vertices.iter().map(|x| x * x.transpose() * m_v).sum();
    let tensor_inv = (Matrix3::identity() * j.trace() - j).try_inverse().expect("a cube has an invertible inertia tensor");
    // Per mode, the translation and infinitesimal rotation removed from it.
    let rigid: Vec<(Vector3<f64>, Vector3<f64>)> = modes
        .iter()
        .map(|mode| {
            let (mut mean, mut moment) = (Vector3::zeros(), Vector3::zeros());
            for xb in &vertices {
                let w = mode.value(xb, &(xb + com));
                mean += w * m_v;
                moment += xb.cross(&w) * m_v;
            }
            (mean / total_mass, tensor_inv * moment)
        })
        .collect();
    let value = |xb: &Vector3<f64>, k: usize| {
        let (t, w) = &rigid[k];
        modes[k].value(xb, &(xb + com)) - t - w.cross(xb)
    };
    let gradient = |xb: &Vector3<f64>, k: usize| modes[k].gradient(&(xb + com)) - skew(&rigid[k].1);
    let rows = |xb: &Vector3<f64>, out: &mut [f64]| {
        for k in 0..n {
            let w = value(xb, k);
            for c in 0..3 {
                out[c * n + k] = w[c];
            }
        }
    };

    let mut vertex_basis = vec![0.0; vertices.len() * 3 * n];
    for (v, xb) in vertices.iter().enumerate() {
        rows(xb, &mut vertex_basis[3 * n * v..3 * n * (v + 1)]);
    }
    let column = |v: usize, k: usize| {
        let w = &vertex_basis[3 * n * v..3 * n * (v + 1)];
        Vector3::new(w[k], w[n + k], w[2 * n + k])
    };
    let mut mode_moments = vec![0.0; 9 * n];
    let mut mode_products = vec![0.0; 9 * n * n];
    for (v, xb) in vertices.iter().enumerate() {
        for k in 0..n {
            let wk = column(v, k);
            let p = wk * xb.transpose() * m_v;
            for (a, b) in mode_moments[9 * k..9 * k + 9].iter_mut().zip(p.transpose().iter()) {
                *a += b;
            }
            for l2 in 0..n {
                let q = wk * column(v, l2).transpose() * m_v;
                for (a, b) in mode_products[9 * (k * n + l2)..9 * (k * n + l2) + 9].iter_mut().zip(q.transpose().iter()) {
                    *a += b;
                }
            }
        }
    }

    let k_count = scene.cubature_points;
    let mut cubature_jacobians = vec![0.0; k_count * 9 * n];
    for i in 0..k_count {
        let g = &mut cubature_jacobians[9 * n * i..9 * n * (i + 1)];
        let xb = Vector3::from(sequence(7919 + i)) * l - com;
        for k in 0..n {
            let d = gradient(&xb, k);
            for a in 0..3 {
                for b in 0..3 {
                    g[(3 * a + b) * n + k] = d[(a, b)];
                }
            }
        }
    }

    let c_count = scene.contact_points;
    let mut contact_basis = vec![0.0; c_count * 3 * n];
    let mut contact_rest = vec![0.0; c_count * 3];
    for jp in 0..c_count {
        let s = sequence(104_729 + jp);
        let xb = Vector3::from(scene.contact_point(jp, l * s[0], l * s[1])) - com;
        rows(&xb, &mut contact_basis[3 * n * jp..3 * n * (jp + 1)]);
        contact_rest[3 * jp..3 * jp + 3].copy_from_slice(xb.as_slice());
    }
    Ok(BodyBlock {
        scene: *scene,
        n,
        total_mass,
        vertices,
        masses,
        vertex_basis,
        inertia_moments: j.transpose().as_slice().to_vec(),
        mode_moments,
        mode_products,
        terms: SampledTerms::new(scene, cubature_jacobians, contact_basis, contact_rest)?,
    })
}

impl BodyBlock {
    /// The arrays as body-frame inputs (gravity 9.81 m/s^2 along -z).
    pub fn inputs(&self) -> BodyFrameInputs<'_> {
        let s = &self.scene;
        BodyFrameInputs {
            total_mass: self.total_mass,
            inertia_moments: &self.inertia_moments,
            mode_moments: &self.mode_moments,
            mode_products: &self.mode_products,
            gravity: [0.0, 0.0, -9.81],
            elastic: self.terms.elastic(),
            contact: self.terms.contact(s),
            dt: s.dt,
            integrator: s.integrator,
        }
    }

    /// The block lying on the plane (turned about y by the incline), sunk to
    /// the depth where the penalty carries its weight, undeformed: (c, R).
    pub fn resting_pose(&self) -> (Vector3<f64>, Matrix3<f64>) {
        let s = &self.scene;
        let (sin, cos) = s.incline.to_radians().sin_cos();
        let r = Matrix3::new(cos, 0.0, sin, 0.0, 1.0, 0.0, -sin, 0.0, cos);
        let depth = self.total_mass * 9.81 * cos / (s.size * s.size * s.normal_stiffness);
        (self.terms.planes[0].normal() * (s.size / 2.0 - depth), r)
    }
}
