//! Synthetic reduced models of an elastic block on the ground, for benchmarks
//! and tests: the 12 affine modes plus `r` smooth analytic modes
//! `u(X) = d sin(k.X + phi)`, exact mass matrix from a grid of sample points,
//! random interior cubature points with equal weights, and contact points spread
//! over the bottom face (all of them touch the ground when the block rests) or
//! over all six faces. The ground is the plane through the origin, level or
//! inclined about the y axis.

use crate::integrator::Integrator;
use nalgebra::Vector3;

use crate::contact::Plane;
use crate::contact_points::ContactInputs;
use crate::error::Result;
use crate::material::StableNeoHookean;
use crate::reduced::{ElasticInputs, ReducedInputs};

/// Description of the synthetic block scene.
#[derive(Debug, Clone, Copy)]
pub struct BlockScene {
    /// Learned (non-affine) modes r; n = 12 + r.
    pub learned_modes: usize,
    /// Cubature points K.
    pub cubature_points: usize,
    /// Contact points C (on the bottom face).
    pub contact_points: usize,
    /// Edge length of the cube [0, L]^3, m.
    pub size: f64,
    /// Density, kg/m^3.
    pub density: f64,
    /// SNH shear parameter, Pa.
    pub mu: f64,
    /// SNH volume parameter, Pa.
    pub lam: f64,
    /// Kelvin-Voigt viscosity, Pa s (0: no material damping).
    pub viscosity: f64,
    /// Time step, s.
    pub dt: f64,
    /// Time integrator.
    pub integrator: Integrator,
    /// Coulomb coefficient of the ground plane.
    pub friction: f64,
    /// Slope of the ground plane about the y axis, degrees: its normal is
    /// `(sin a, 0, cos a)`, so that it descends towards +x.
    pub incline: f64,
    /// Contact points on all six faces (else on the bottom face only).
    pub contact_on_all_faces: bool,
    /// k_n, N/m^3.
    pub normal_stiffness: f64,
    /// k_d, N s/m^3.
    pub normal_damping: f64,
    /// k_f, N s/m^3.
    pub friction_stiffness: f64,
    /// Seed of the random modes and sample points.
    pub seed: u64,
}

impl BlockScene {
    /// The landing scene of the benches and solver tests: a 20 degree incline,
    /// contact on every face and the cheese scene's stiff contact (k_n = k_f = 1e7).
    pub fn landing(learned_modes: usize, cubature_points: usize, contact_points: usize) -> Self {
        Self {
            learned_modes,
            cubature_points,
            contact_points,
            incline: 20.0,
            contact_on_all_faces: true,
            normal_stiffness: 1e7,
            friction_stiffness: 1e7,
            ..Default::default()
        }
    }
}

impl Default for BlockScene {
    /// A 10 cm block of soft rubber-like material (E = 1e5 Pa, nu = 0.3) on
    /// ground with mu = 0.5, at h = 10 ms.
    fn default() -> Self {
        Self {
            learned_modes: 20,
            cubature_points: 1000,
            contact_points: 1000,
            size: 0.1,
            density: 1000.0,
            mu: 5.13e4,
            lam: 8.97e4,
            viscosity: 0.0,
            dt: 0.01,
            integrator: Integrator::BackwardEuler,
            friction: 0.5,
            incline: 0.0,
            contact_on_all_faces: false,
            normal_stiffness: 2.0e6,
            normal_damping: 0.0,
            friction_stiffness: 1.0e6,
            seed: 1,
        }
    }
}

/// Owned arrays of a synthetic model, borrowed by [`BlockModel::inputs`].
#[derive(Debug, Clone)]
pub struct BlockModel {
    /// The scene it was built from.
    pub scene: BlockScene,
    /// Reduced mass, n x n.
    pub mass: Vec<f64>,
    /// Reduced gravity force, n.
    pub gravity_force: Vec<f64>,
    /// The sampled elastic and contact terms.
    pub terms: SampledTerms,
    /// Total mass, kg.
    pub total_mass: f64,
}

/// The elastic and contact arrays a synthetic block samples, in either
/// model's coordinates (world-frame modes or body-frame modes).
#[derive(Debug, Clone)]
pub struct SampledTerms {
    /// K x 9 x n.
    pub cubature_jacobians: Vec<f64>,
    /// K, equal weights summing to the volume.
    pub cubature_weights: Vec<f64>,
    /// C x 3 x n.
    pub contact_basis: Vec<f64>,
    /// C x 3.
    pub contact_rest: Vec<f64>,
    /// C, equal shares of the faces' area.
    pub contact_areas: Vec<f64>,
    /// The ground plane through the origin.
    pub planes: Vec<Plane>,
    /// Material.
    pub material: StableNeoHookean,
    /// Kelvin-Voigt viscosity, Pa s.
    pub viscosity: f64,
}

impl SampledTerms {
    /// The terms of `scene` with the given Jacobians and contact rows (weights, areas, plane and material from the scene).
    pub fn new(scene: &BlockScene, cubature_jacobians: Vec<f64>, contact_basis: Vec<f64>, contact_rest: Vec<f64>) -> Result<Self> {
        let (l, k, c) = (scene.size, scene.cubature_points, scene.contact_points);
        let faces = if scene.contact_on_all_faces { 6.0 } else { 1.0 };
        let slope = scene.incline.to_radians();
        Ok(Self {
            cubature_jacobians,
            cubature_weights: vec![l * l * l / k.max(1) as f64; k],
            contact_basis,
            contact_rest,
            contact_areas: vec![faces * l * l / c.max(1) as f64; c],
            planes: vec![Plane::new(Vector3::new(slope.sin(), 0.0, slope.cos()), 0.0, scene.friction)?],
            material: StableNeoHookean::new(scene.mu, scene.lam)?,
            viscosity: scene.viscosity,
        })
    }

    /// The elastic term's inputs.
    pub fn elastic(&self) -> ElasticInputs<'_> {
        ElasticInputs {
            cubature_jacobians: &self.cubature_jacobians,
            cubature_weights: &self.cubature_weights,
            vertex_strain: None,
            material: self.material,
            viscosity: self.viscosity,
        }
    }

    /// The contact points' inputs, with the stiffnesses of `scene`.
    pub fn contact(&self, scene: &BlockScene) -> ContactInputs<'_> {
        ContactInputs {
            basis: &self.contact_basis,
            rest: &self.contact_rest,
            areas: &self.contact_areas,
            planes: &self.planes,
            normal_stiffness: scene.normal_stiffness,
            normal_damping: scene.normal_damping,
            friction_stiffness: scene.friction_stiffness,
        }
    }
}

impl BlockScene {
    /// Rest position (in the cube [0, L]^3) of contact point j from the face
    /// coordinates `(u, v)` in [0, L): on the bottom face, or with contact on
    /// all faces on face j mod 6.
    pub fn contact_point(&self, j: usize, u: f64, v: f64) -> [f64; 3] {
        if self.contact_on_all_faces {
            // Face j mod 6: the axis it is normal to and which side.
            let (axis, side) = (j % 3, if (j / 3).is_multiple_of(2) { 0.0 } else { self.size });
            let mut x = [u, v, 0.0];
            x.swap(2, axis);
            x[axis] = side;
            x
        } else {
            [u, v, 0.0]
        }
    }
}

/// SplitMix64 stream of uniforms in [0, 1).
struct Uniform(u64);

impl Uniform {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn point(&mut self, size: f64) -> [f64; 3] {
        [size * self.next(), size * self.next(), size * self.next()]
    }
}

/// One learned mode `u(X) = dir sin(k.X + phase)`.
struct Wave {
    dir: Vector3<f64>,
    k: Vector3<f64>,
    phase: f64,
}

struct Basis {
    waves: Vec<Wave>,
}

impl Basis {
    fn n(&self) -> usize {
        12 + self.waves.len()
    }

    /// W(X), 3 x n row-major, into `out`.
    fn values(&self, x: [f64; 3], out: &mut [f64]) {
        let n = self.n();
        out.fill(0.0);
        for i in 0..3 {
            for (j, xj) in x.iter().enumerate() {
                out[i * n + 3 * j + i] = *xj;
            }
            out[i * n + 9 + i] = 1.0;
        }
        let xv = Vector3::from(x);
        for (r, w) in self.waves.iter().enumerate() {
            let s = (w.k.dot(&xv) + w.phase).sin();
            for i in 0..3 {
                out[i * n + 12 + r] = w.dir[i] * s;
            }
        }
    }

    /// G(X) = dvec(F)/dq, 9 x n row-major, into `out`.
    fn jacobian(&self, x: [f64; 3], out: &mut [f64]) {
        let n = self.n();
        out.fill(0.0);
        for i in 0..3 {
            for j in 0..3 {
                out[(3 * i + j) * n + 3 * j + i] = 1.0;
            }
        }
        let xv = Vector3::from(x);
        for (r, w) in self.waves.iter().enumerate() {
            let c = (w.k.dot(&xv) + w.phase).cos();
            for i in 0..3 {
                for j in 0..3 {
                    out[(3 * i + j) * n + 12 + r] = w.dir[i] * w.k[j] * c;
                }
            }
        }
    }
}

impl BlockScene {
    /// Builds the model's arrays.
    pub fn build(&self) -> Result<BlockModel> {
        let mut rng = Uniform(self.seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x5851_F42D_4C95_7F2D);
        let l = self.size;
        let waves = (0..self.learned_modes)
            .map(|_| {
                let dir = Vector3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5).normalize();
                let k = Vector3::new(rng.next() - 0.5, rng.next() - 0.5, rng.next() - 0.5).normalize()
                    * (std::f64::consts::PI / l * (1.0 + 2.0 * rng.next()));
                Wave { dir, k, phase: 2.0 * std::f64::consts::PI * rng.next() }
            })
            .collect();
        let basis = Basis { waves };
        let n = basis.n();
        let g = [0.0, 0.0, -9.81];

        // Lumped masses on a grid fine enough to resolve every mode.
        let grid = 10;
        let total_mass = self.density * l * l * l;
        let m_v = total_mass / (grid * grid * grid) as f64;
        let mut mass = vec![0.0; n * n];
        let mut gravity_force = vec![0.0; n];
        let mut w = vec![0.0; 3 * n];
        for a in 0..grid {
            for b in 0..grid {
                for c in 0..grid {
                    let x = [a, b, c].map(|i| l * (i as f64 + 0.5) / grid as f64);
                    basis.values(x, &mut w);
                    for i in 0..3 {
                        let row = &w[i * n..(i + 1) * n];
                        for (p, wp) in row.iter().enumerate() {
                            gravity_force[p] += m_v * wp * g[i];
                            for (q, wq) in row.iter().enumerate() {
                                mass[p * n + q] += m_v * wp * wq;
                            }
                        }
                    }
                }
            }
        }

        let k = self.cubature_points;
        let mut cubature_jacobians = vec![0.0; k * 9 * n];
        for chunk in cubature_jacobians.chunks_exact_mut(9 * n) {
            basis.jacobian(rng.point(l), chunk);
        }

        let c = self.contact_points;
        let mut contact_basis = vec![0.0; c * 3 * n];
        let mut contact_rest = vec![0.0; c * 3];
        for (j, (chunk, rest)) in contact_basis.chunks_exact_mut(3 * n).zip(contact_rest.chunks_exact_mut(3)).enumerate() {
            let x = self.contact_point(j, l * rng.next(), l * rng.next());
            basis.values(x, chunk);
            rest.copy_from_slice(&x);
        }
        Ok(BlockModel {
            scene: *self,
            mass,
            gravity_force,
            terms: SampledTerms::new(self, cubature_jacobians, contact_basis, contact_rest)?,
            total_mass,
        })
    }
}

impl BlockModel {
    /// Number of reduced coordinates.
    pub fn n_dofs(&self) -> usize {
        self.gravity_force.len()
    }

    /// The arrays as reduced-system inputs.
    pub fn inputs(&self) -> ReducedInputs<'_> {
        ReducedInputs {
            mass: &self.mass,
            gravity_force: &self.gravity_force,
            elastic: self.terms.elastic(),
            contact: self.terms.contact(&self.scene),
            dt: self.scene.dt,
            integrator: self.scene.integrator,
        }
    }

    /// The block at rest, turned about the y axis by `tilt` degrees (turning
    /// it by the plane's incline lays its bottom face flat on the plane), with
    /// its lowest corner `height` (m) above the plane: `(q, qdot)`.
    pub fn dropped_state(&self, tilt: f64, height: f64) -> (Vec<f64>, Vec<f64>) {
        let s = &self.scene;
        let n = self.n_dofs();
        let (sin, cos) = tilt.to_radians().sin_cos();
        let r = nalgebra::Matrix3::new(cos, 0.0, sin, 0.0, 1.0, 0.0, -sin, 0.0, cos);
        let normal = self.terms.planes[0].normal();
        let lowest = (0..8)
            .map(|c| {
                let corner = Vector3::new((c & 1) as f64, ((c >> 1) & 1) as f64, ((c >> 2) & 1) as f64) * s.size;
                normal.dot(&(r * corner))
            })
            .fold(f64::INFINITY, f64::min);
        let lift = (height - lowest - self.terms.planes[0].offset()) / normal.z;
        let mut q = vec![0.0; n];
        for i in 0..3 {
            for j in 0..3 {
                q[3 * j + i] = r[(i, j)] - if i == j { 1.0 } else { 0.0 };
            }
        }
        q[11] = lift;
        (q, vec![0.0; n])
    }

    /// State of the block sunk to the depth where the penalty carries its weight,
    /// moving at `speed` (m/s) along x: `(q, qdot)` (level ground).
    pub fn resting_state(&self, speed: f64) -> (Vec<f64>, Vec<f64>) {
        let s = &self.scene;
        let n = self.n_dofs();
        let pressure = self.total_mass * 9.81 / (s.size * s.size);
        let mut q = vec![0.0; n];
        q[11] = -pressure / s.normal_stiffness;
        let mut qdot = vec![0.0; n];
        qdot[9] = speed;
        (q, qdot)
    }
}
