//! The reduced incremental potential of one backward-Euler step and its
//! derivatives.
//!
//! With reduced coordinates `q` (n = 12 affine + r learned, treated generically):
//!
//! `E(q) = 1/(2h^2) (q - qt)^T M (q - qt) - f.q + sum_k w_k Psi(F_k(q)) + sum_j,p C_jp(x_j(q))`
//!
//! with `qt = q_t + h qdot_t`, `vec(F_k) = vec(I) + G_k q` (G_k: 9 x n),
//! `x_j = X_j + W_j q` (W_j: 3 x n) and `C_jp` the contact potential of point j
//! against plane p ([`crate::contact`]). Units: q is dimensionless or m depending
//! on the mode; E in J, gradient in J per unit of q.
//!
//! The Hessian is assembled in two PSD parts. The projected Hessian is
//! `M/h^2 + B^T B`, where B stacks, per cubature point, `sqrt(w_k lambda_i) e_i^T G_k`
//! for the positive eigenpairs of the SNH Hessian, and per contact point the
//! square-root factors of its rank-one terms times W_j. The negative eigenpairs
//! go, with `|lambda_i|`, into a second stack N, so that the exact Hessian is
//! `M/h^2 + B^T B - N^T N` at almost no extra cost. Forming the rows is a pass
//! over each G_k while it sits in L1; the products are large symmetric products
//! done by faer's blocked kernels, far faster than K separate 9-row updates of
//! the n x n matrix.

use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};
use nalgebra::{Matrix3, Vector3};

use crate::contact::{ContactModel, Plane};
use crate::dense::{combine_rows, dot, rows_dot};
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::material::{mat3_row_major, vec9, StableNeoHookean};
use crate::real::{Lanes, Real, LANES};
use crate::simd::{dispatch, Madd, WithMadd};

/// Borrowed description of a reduced model; all arrays row-major (C order).
#[derive(Debug, Clone, Copy)]
pub struct ReducedInputs<'a> {
    /// Reduced mass matrix `W^T M W`, n x n, symmetric positive definite, kg.
    pub mass: &'a [f64],
    /// Reduced gravity force `W^T M g`, n, N.
    pub gravity_force: &'a [f64],
    /// `G_k = dvec(F)/dq` at the K cubature points, K x 9 x n.
    pub cubature_jacobians: &'a [f64],
    /// Cubature weights w_k >= 0, K, m^3.
    pub cubature_weights: &'a [f64],
    /// Material of the solid.
    pub material: StableNeoHookean,
    /// Basis rows W_j at the C contact points, C x 3 x n.
    pub contact_basis: &'a [f64],
    /// Rest positions X_j of the contact points, C x 3, m.
    pub contact_rest: &'a [f64],
    /// Boundary area a_j >= 0 carried by each contact point, C, m^2.
    pub contact_areas: &'a [f64],
    /// Contact planes.
    pub planes: &'a [Plane],
    /// k_n, N/m^3.
    pub normal_stiffness: f64,
    /// k_d, N s/m^3.
    pub normal_damping: f64,
    /// k_f, N s/m^3.
    pub friction_stiffness: f64,
    /// Time step h, s.
    pub dt: f64,
}

/// Validated, owned reduced model.
#[derive(Debug, Clone)]
pub struct ReducedSystem {
    n: usize,
    mass: Vec<f64>,
    gravity: Vec<f64>,
    jacobians: Vec<f64>,
    weights: Vec<f64>,
    material: StableNeoHookean,
    contact_basis: Vec<f64>,
    contact_rest: Vec<f64>,
    areas: Vec<f64>,
    planes: Vec<Plane>,
    contact: ContactModel,
}

/// Quantities fixed at the start of a step: the state, the inertial target
/// `qt = q_t + h qdot_t`, contact point positions and lagged normal forces.
#[derive(Debug, Clone)]
pub struct StepStart {
    q: Vec<f64>,
    qtilde: Vec<f64>,
    x_prev: Vec<f64>,
    normal_force: Vec<f64>,
}

impl StepStart {
    /// Reduced coordinates at the start of the step.
    pub fn q(&self) -> &[f64] {
        &self.q
    }
}

/// What [`ReducedSystem::assemble`] computes besides the gradient.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hessian {
    /// Gradient only.
    None,
    /// The projected Hessian (`Workspace::hess`).
    Projected,
    /// The projected Hessian and its clamped part (`Workspace::hess_clamped`),
    /// from which the exact Hessian follows.
    Split,
}

/// Preallocated buffers of the evaluation, sized once per system.
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Gradient, n.
    pub grad: Vec<f64>,
    /// Projected Hessian (elastic negative eigenvalues clamped to zero): n x n,
    /// symmetric positive definite.
    pub hess: Vec<f64>,
    /// What the clamping removed, PSD: the exact Hessian is `hess - hess_clamped`
    /// (filled by [`Hessian::Split`] only).
    pub hess_clamped: Vec<f64>,
    /// Whether some elastic eigenvalue was clamped (set by [`Hessian::Split`]).
    pub has_clamped: bool,
    /// Square-root rows: positive ones from the front, clamped ones from the back.
    rows: Vec<f64>,
    contact_coef: Vec<[f64; 3]>,
}

impl Workspace {
    /// The exact Hessian `hess - hess_clamped` into `out` (n x n).
    pub fn exact_hessian(&self, out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(&self.hess).zip(&self.hess_clamped) {
            *o = a - b;
        }
    }
}

/// `dst (lower triangle) = op(B^T B)` for the `count` rows of `rows` (row-major, width n).
fn syrk_lower(dst: &mut [f64], n: usize, rows: &[f64], count: usize, accum: Accum) {
    if count == 0 {
        if accum == Accum::Replace {
            dst.fill(0.0);
        }
        return;
    }
    let b = MatRef::from_row_major_slice(&rows[..count * n], count, n);
    let a = MatMut::from_column_major_slice_mut(dst, n, n);
    triangular_matmul(
        a,
        BlockStructure::TriangularLower,
        accum,
        b.transpose(),
        BlockStructure::Rectangular,
        b,
        BlockStructure::Rectangular,
        1.0,
        Par::Seq,
    );
}

/// Copies the lower triangle of the n x n column-major `a` to its upper triangle.
fn mirror_lower(a: &mut [f64], n: usize) {
    for c in 0..n {
        for r in c + 1..n {
            a[r * n + c] = a[c * n + r];
        }
    }
}

fn check_len(name: &str, data: &[f64], expected: usize, shape: impl FnOnce() -> String) -> Result<()> {
    if data.len() == expected {
        Ok(())
    } else {
        Err(LicromError::shape(name, shape(), format!("{} values", data.len())))
    }
}

impl ReducedSystem {
    /// Validates and copies the inputs: consistent sizes, finite values,
    /// non-negative weights and areas, symmetric positive definite mass.
    pub fn new(inp: &ReducedInputs<'_>) -> Result<Self> {
        let n = inp.gravity_force.len();
        if n == 0 {
            return Err(LicromError::shape("gravity_force", "(n,) with n >= 1", "0 values"));
        }
        let k = inp.cubature_weights.len();
        let c = inp.contact_areas.len();
        check_len("mass", inp.mass, n * n, || format!("({n}, {n})"))?;
        check_len("cubature_jacobians", inp.cubature_jacobians, k * 9 * n, || format!("({k}, 9, {n})"))?;
        check_len("contact_basis", inp.contact_basis, c * 3 * n, || format!("({c}, 3, {n})"))?;
        check_len("contact_rest", inp.contact_rest, c * 3, || format!("({c}, 3)"))?;
        for (name, data) in [
            ("mass", inp.mass),
            ("gravity_force", inp.gravity_force),
            ("cubature_jacobians", inp.cubature_jacobians),
            ("cubature_weights", inp.cubature_weights),
            ("contact_basis", inp.contact_basis),
            ("contact_rest", inp.contact_rest),
            ("contact_areas", inp.contact_areas),
        ] {
            check_finite(name, data)?;
        }
        if let Some(w) = inp.cubature_weights.iter().find(|w| **w < 0.0) {
            return Err(LicromError::invalid("cubature_weights", format!("must be >= 0, found {w}")));
        }
        if let Some(a) = inp.contact_areas.iter().find(|a| **a < 0.0) {
            return Err(LicromError::invalid("contact_areas", format!("must be >= 0, found {a}")));
        }
        let contact = ContactModel::new(inp.normal_stiffness, inp.normal_damping, inp.friction_stiffness, inp.dt)?;
        let mass = symmetrized_spd(inp.mass, n)?;
        Ok(Self {
            n,
            mass,
            gravity: inp.gravity_force.to_vec(),
            jacobians: inp.cubature_jacobians.to_vec(),
            weights: inp.cubature_weights.to_vec(),
            material: inp.material,
            contact_basis: inp.contact_basis.to_vec(),
            contact_rest: inp.contact_rest.to_vec(),
            areas: inp.contact_areas.to_vec(),
            planes: inp.planes.to_vec(),
            contact,
        })
    }

    /// Number of reduced coordinates n.
    pub fn n_dofs(&self) -> usize {
        self.n
    }

    /// Number of cubature points K.
    pub fn n_cubature(&self) -> usize {
        self.weights.len()
    }

    /// Number of contact points C.
    pub fn n_contacts(&self) -> usize {
        self.areas.len()
    }

    /// Time step h, s.
    pub fn dt(&self) -> f64 {
        self.contact.dt
    }

    /// Reduced mass matrix (symmetrised), n x n, kg.
    pub fn mass(&self) -> &[f64] {
        &self.mass
    }

    /// Reduced gravity force, n, N.
    pub fn gravity(&self) -> &[f64] {
        &self.gravity
    }

    /// Zeroed start-of-step buffers for this system.
    pub fn step_start(&self) -> StepStart {
        let c = self.n_contacts();
        StepStart {
            q: vec![0.0; self.n],
            qtilde: vec![0.0; self.n],
            x_prev: vec![0.0; 3 * c],
            normal_force: vec![0.0; c * self.planes.len()],
        }
    }

    /// Buffers for [`Self::assemble`].
    pub fn workspace(&self) -> Workspace {
        let n = self.n;
        let max_rows = 9 * self.n_cubature() + 3 * self.n_contacts() * self.planes.len();
        Workspace {
            grad: vec![0.0; n],
            hess: vec![0.0; n * n],
            hess_clamped: vec![0.0; n * n],
            has_clamped: false,
            rows: vec![0.0; max_rows * n],
            contact_coef: vec![[0.0; 3]; 3 * self.planes.len()],
        }
    }

    /// Fills `start` for a step from state `(q, qdot)`: inertial target, contact
    /// positions and lagged normal forces. Lengths must be n.
    pub fn begin_step(&self, q: &[f64], qdot: &[f64], start: &mut StepStart) {
        let h = self.dt();
        start.q.copy_from_slice(q);
        for ((t, qi), vi) in start.qtilde.iter_mut().zip(q).zip(qdot) {
            *t = qi + h * vi;
        }
        let n_planes = self.planes.len();
        for j in 0..self.n_contacts() {
            let x = self.contact_position::<crate::simd::Separate>(j, q);
            start.x_prev[3 * j..3 * j + 3].copy_from_slice(x.as_slice());
            for (p, plane) in self.planes.iter().enumerate() {
                start.normal_force[j * n_planes + p] = self.contact.lagged_normal_force(plane, self.areas[j], &x);
            }
        }
    }

    #[inline(always)]
    fn contact_position<M: Madd>(&self, j: usize, q: &[f64]) -> Vector3<f64> {
        let n = self.n;
        let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
        let x0 = &self.contact_rest[3 * j..3 * j + 3];
        let wq = rows_dot::<M, 3>(w, q);
        Vector3::new(x0[0] + wq[0], x0[1] + wq[1], x0[2] + wq[2])
    }

    #[inline(always)]
    fn deformation_gradient<M: Madd>(g: &[f64], q: &[f64]) -> Matrix3<f64> {
        let mut f = rows_dot::<M, 9>(g, q);
        for a in [0, 4, 8] {
            f[a] += 1.0;
        }
        mat3_row_major(&f)
    }

    /// Incremental potential E(q), J.
    pub fn energy(&self, start: &StepStart, q: &[f64]) -> f64 {
        dispatch(EnergyKernel { sys: self, start, q })
    }

    #[inline(always)]
    fn energy_impl<M: Madd>(&self, start: &StepStart, q: &[f64]) -> f64 {
        let n = self.n;
        let h = self.dt();
        let mut inertia = 0.0;
        for i in 0..n {
            let mut md = 0.0;
            for j in 0..n {
                md = M::madd(self.mass[i * n + j], q[j] - start.qtilde[j], md);
            }
            inertia = M::madd(q[i] - start.qtilde[i], md, inertia);
        }
        let mut e = 0.5 * inertia / (h * h) - dot::<M>(&self.gravity, q);
        let mut elastic = 0.0;
        for (g, &w) in self.jacobians.chunks_exact(9 * n).zip(&self.weights) {
            let f = Self::deformation_gradient::<M>(g, q);
            elastic = M::madd(w, self.material.energy(&f), elastic);
        }
        e += elastic;
        let n_planes = self.planes.len();
        for j in 0..self.n_contacts() {
            let x = self.contact_position::<M>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            for (p, plane) in self.planes.iter().enumerate() {
                e += self.contact.evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp).energy;
            }
        }
        e
    }

    /// Gradient (into `ws.grad`) and the requested Hessian parts (into `ws.hess`,
    /// `ws.hess_clamped`, full symmetric) of E at `q`.
    pub fn assemble(&self, start: &StepStart, q: &[f64], hessian: Hessian, ws: &mut Workspace) {
        let (positive, clamped) = dispatch(AssembleKernel { sys: self, start, q, hessian, ws: &mut *ws });
        if hessian == Hessian::None {
            return;
        }
        let n = self.n;
        let total = ws.rows.len() / n;
        syrk_lower(&mut ws.hess, n, &ws.rows, positive, Accum::Replace);
        if hessian == Hessian::Split {
            syrk_lower(&mut ws.hess_clamped, n, &ws.rows[(total - clamped) * n..], clamped, Accum::Replace);
            mirror_lower(&mut ws.hess_clamped, n);
            ws.has_clamped = clamped > 0;
        }
        let inv_h2 = 1.0 / (self.dt() * self.dt());
        for (h, m) in ws.hess.iter_mut().zip(&self.mass) {
            *h += m * inv_h2;
        }
        mirror_lower(&mut ws.hess, n);
    }

    /// Per-point work of [`Self::assemble`]: gradient and the stacked square-root
    /// rows; returns how many positive and clamped rows were written.
    #[inline(always)]
    fn assemble_impl<M: Madd>(&self, start: &StepStart, q: &[f64], hessian: Hessian, ws: &mut Workspace) -> (usize, usize) {
        let with_hessian = hessian != Hessian::None;
        let n = self.n;
        let inv_h2 = 1.0 / (self.dt() * self.dt());
        for i in 0..n {
            let mut md = 0.0;
            for j in 0..n {
                md = M::madd(self.mass[i * n + j], q[j] - start.qtilde[j], md);
            }
            ws.grad[i] = md * inv_h2 - self.gravity[i];
        }
        // Positive rows fill `ws.rows` from the front, clamped ones from the back;
        // together they never exceed its 9 K + 3 C P rows.
        let (mut positive, mut clamped) = (0, 0);
        let total = ws.rows.len() / n;
        // Cubature points go in groups of LANES through the eigensystem, which is
        // latency-bound per point but vectorises across points.
        let k_total = self.n_cubature();
        let mut values = [Lanes::splat(0.0); 9];
        let mut vectors = [[Lanes::splat(0.0); 9]; 9];
        for k0 in (0..k_total).step_by(LANES) {
            let group = LANES.min(k_total - k0);
            let mut fs = [Matrix3::identity(); LANES];
            // Lanes past the last point hold F = I, which is harmless.
            let mut lanes = [[Lanes::splat(0.0); 3]; 3];
            for (i, row) in lanes.iter_mut().enumerate() {
                row[i] = Lanes::splat(1.0);
            }
            for (l, f) in fs.iter_mut().enumerate().take(group) {
                let k = k0 + l;
                *f = Self::deformation_gradient::<M>(&self.jacobians[9 * n * k..9 * n * (k + 1)], q);
                for i in 0..3 {
                    for j in 0..3 {
                        lanes[i][j].0[l] = f[(i, j)];
                    }
                }
            }
            if with_hessian {
                self.material.eigensystem_of(&lanes, &mut values, &mut vectors);
            }
            for (l, f) in fs.iter().enumerate().take(group) {
                let k = k0 + l;
                let w = self.weights[k];
                if w == 0.0 {
                    continue;
                }
                let g = &self.jacobians[9 * n * k..9 * n * (k + 1)];
                let p = vec9(&self.material.pk1(f)) * w;
                let p: &[f64; 9] = p.as_slice().try_into().expect("9 stress components");
                let mut pos = [[0.0; 9]; 9];
                let mut neg = [[0.0; 9]; 9];
                let (mut n_pos, mut n_neg) = (0, 0);
                if with_hessian {
                    for (lambda, v) in values.iter().zip(&vectors) {
                        let lambda = lambda.0[l];
                        let (coef, count) = if lambda > 0.0 { (&mut pos, &mut n_pos) } else { (&mut neg, &mut n_neg) };
                        if lambda != 0.0 {
                            let s = (w * lambda.abs()).sqrt();
                            for (c, e) in coef[*count].iter_mut().zip(v) {
                                *c = s * e.0[l];
                            }
                            *count += 1;
                        }
                    }
                }
                combine_rows::<M, 9>(g, &pos[..n_pos], &mut ws.rows[positive * n..], p, &mut ws.grad);
                positive += n_pos;
                if n_neg > 0 && hessian == Hessian::Split {
                    clamped += n_neg;
                    combine_rows::<M, 9>(g, &neg[..n_neg], &mut ws.rows[(total - clamped) * n..], p, &mut []);
                }
            }
        }
        let n_planes = self.planes.len();
        for j in 0..self.n_contacts() {
            let x = self.contact_position::<M>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let mut grad = Vector3::zeros();
            let mut count = 0;
            for (p, plane) in self.planes.iter().enumerate() {
                let e = self.contact.evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp);
                grad += e.gradient;
                if with_hessian {
                    for t in 0..e.hessian.len {
                        let d = e.hessian.dir[t] * e.hessian.coef[t].sqrt();
                        ws.contact_coef[count] = [d.x, d.y, d.z];
                        count += 1;
                    }
                }
            }
            let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
            let grad: &[f64; 3] = grad.as_slice().try_into().expect("3 components");
            combine_rows::<M, 3>(w, &ws.contact_coef[..count], &mut ws.rows[positive * n..], grad, &mut ws.grad);
            positive += count;
        }
        (positive, clamped)
    }

    /// Contact force (N, world frame) on each contact point at `q`: minus the
    /// gradient of penalty + damping + friction w.r.t. its position. `out`: C x 3.
    pub fn contact_forces(&self, start: &StepStart, q: &[f64], out: &mut [f64]) {
        let n_planes = self.planes.len();
        for j in 0..self.n_contacts() {
            let x = self.contact_position::<crate::simd::Separate>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let mut f = Vector3::zeros();
            for (p, plane) in self.planes.iter().enumerate() {
                f -= self.contact.evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp).gradient;
            }
            out[3 * j..3 * j + 3].copy_from_slice(f.as_slice());
        }
    }

    /// Elastic stiffness at the rest configuration `K = sum_k w_k G_k^T H(I) G_k`
    /// (into `ws.hess`, full symmetric), Pa m^3 per unit of q squared.
    pub fn rest_stiffness(&self, ws: &mut Workspace) {
        let n = self.n;
        // H(I) is the same for every point: factor it once.
        let eig = self.material.eigensystem(&Matrix3::identity());
        let mut modes = [[0.0; 9]; 9];
        let mut count = 0;
        for (lambda, v) in eig.values.iter().zip(&eig.vectors) {
            if *lambda > 0.0 {
                for (c, e) in modes[count].iter_mut().zip(v.iter()) {
                    *c = lambda.sqrt() * e;
                }
                count += 1;
            }
        }
        let mut rows = 0;
        for (g, &w) in self.jacobians.chunks_exact(9 * n).zip(&self.weights) {
            let mut coef = modes;
            for row in coef.iter_mut().take(count) {
                row.iter_mut().for_each(|c| *c *= w.sqrt());
            }
            combine_rows::<crate::simd::Separate, 9>(g, &coef[..count], &mut ws.rows[rows * n..], &[0.0; 9], &mut []);
            rows += count;
        }
        syrk_lower(&mut ws.hess, n, &ws.rows, rows, Accum::Replace);
        mirror_lower(&mut ws.hess, n);
    }
}

struct EnergyKernel<'a> {
    sys: &'a ReducedSystem,
    start: &'a StepStart,
    q: &'a [f64],
}

impl WithMadd for EnergyKernel<'_> {
    type Output = f64;
    #[inline(always)]
    fn run<M: Madd>(self) -> f64 {
        self.sys.energy_impl::<M>(self.start, self.q)
    }
}

struct AssembleKernel<'a> {
    sys: &'a ReducedSystem,
    start: &'a StepStart,
    q: &'a [f64],
    hessian: Hessian,
    ws: &'a mut Workspace,
}

impl WithMadd for AssembleKernel<'_> {
    type Output = (usize, usize);
    #[inline(always)]
    fn run<M: Madd>(self) -> (usize, usize) {
        self.sys.assemble_impl::<M>(self.start, self.q, self.hessian, self.ws)
    }
}

/// The symmetrised mass matrix, after checking symmetry (to a relative 1e-8, the
/// round-off of `W^T M W` computed in any order) and positive definiteness.
fn symmetrized_spd(mass: &[f64], n: usize) -> Result<Vec<f64>> {
    let scale = mass.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut sym = vec![0.0; n * n];
    for r in 0..n {
        for c in 0..n {
            let (a, b) = (mass[r * n + c], mass[c * n + r]);
            if (a - b).abs() > 1e-8 * scale {
                return Err(LicromError::SingularMass {
                    reason: format!("entries ({r}, {c}) and ({c}, {r}) differ: {a} vs {b}"),
                });
            }
            sym[r * n + c] = 0.5 * (a + b);
        }
    }
    check_positive("mass scale", scale).map_err(|_| LicromError::SingularMass { reason: "it is zero".into() })?;
    crate::cholesky::Cholesky::factor(&sym, n).map_err(|index| LicromError::SingularMass {
        reason: format!("Cholesky pivot {index} is not positive"),
    })?;
    Ok(sym)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::{BlockModel, BlockScene};
    use crate::testing::{fd_gradient, fd_jacobian, rel_err, Rng};

    fn small_block(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
        BlockScene { learned_modes, cubature_points, contact_points, normal_damping: 5.0e3, seed: 3, ..Default::default() }
            .build()
            .unwrap()
    }

    /// Start of a step of a block that rests sunk in the ground, slides along x
    /// and is slightly deformed.
    fn sliding_start(model: &BlockModel, sys: &ReducedSystem) -> (StepStart, Vec<f64>, Vec<f64>) {
        let (mut q, qdot) = model.resting_state(0.2);
        let mut rng = Rng::new(4);
        for qi in q.iter_mut().skip(12) {
            *qi += 2e-3 * rng.uniform();
        }
        for qi in q.iter_mut().take(9) {
            *qi += 1e-2 * rng.uniform();
        }
        let mut start = sys.step_start();
        sys.begin_step(&q, &qdot, &mut start);
        (start, q, qdot)
    }

    /// Friction regime of every contact point at q: (sticking, slipping) counts.
    fn regimes(model: &BlockModel, sys: &ReducedSystem, start: &StepStart, q: &[f64]) -> (usize, usize) {
        let s = &model.scene;
        let (mut stick, mut slip) = (0, 0);
        for j in 0..sys.n_contacts() {
            let fn_lag = start.normal_force[j];
            if fn_lag == 0.0 {
                continue;
            }
            let x = sys.contact_position::<crate::simd::Separate>(j, q);
            let dx = x - Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let c = model.contact_areas[j] * s.friction_stiffness / s.dt;
            if c * (dx.x * dx.x + dx.y * dx.y).sqrt() <= s.friction * fn_lag {
                stick += 1;
            } else {
                slip += 1;
            }
        }
        (stick, slip)
    }

    #[test]
    fn gradient_and_exact_hessian_match_finite_differences() {
        let model = small_block(3, 7, 9);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let (start, q0, qdot) = sliding_start(&model, &sys);
        let mut ws = sys.workspace();
        let n = sys.n_dofs();
        let mut rng = Rng::new(8);
        // Slipping everywhere: near the inertial target, sunk a bit deeper (damping on).
        let mut slipping: Vec<f64> = (0..n).map(|i| q0[i] + model.scene.dt * qdot[i] + 1e-5 * rng.uniform()).collect();
        slipping[11] -= 1e-5;
        // Sticking everywhere: nearly at the start, approaching the ground (damping
        // on, and clear of its kink at zero normal speed).
        let mut sticking: Vec<f64> = (0..n).map(|i| q0[i] + 1e-9 * rng.uniform()).collect();
        sticking[11] -= 1e-7;
        assert_eq!(regimes(&model, &sys, &start, &slipping).0, 0);
        assert_eq!(regimes(&model, &sys, &start, &sticking).1, 0);
        assert!(regimes(&model, &sys, &start, &sticking).0 > 0);
        for q in [slipping, sticking] {
            sys.assemble(&start, &q, Hessian::Split, &mut ws);
            let fd = fd_gradient(|x| sys.energy(&start, x), &q, 1e-8);
            assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
            let mut hess = vec![0.0; n * n];
            ws.exact_hessian(&mut hess);
            let fd_h: Vec<f64> = fd_jacobian(
                |x| {
                    let mut w = sys.workspace();
                    sys.assemble(&start, x, Hessian::None, &mut w);
                    w.grad
                },
                &q,
                1e-9,
            )
            .into_iter()
            .flatten()
            .collect();
            assert!(rel_err(&hess, &fd_h, 1e-6) < 1e-5, "Hessian vs FD: {}", rel_err(&hess, &fd_h, 1e-6));
        }
    }

    #[test]
    fn projected_assembly_matches_naive_sum() {
        let model = small_block(5, 11, 13);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let (start, q0, qdot) = sliding_start(&model, &sys);
        let n = sys.n_dofs();
        let h = model.scene.dt;
        let q: Vec<f64> = (0..n).map(|i| q0[i] + h * qdot[i] + if i >= 12 { 0.02 } else { 0.0 }).collect();
        let mut ws = sys.workspace();
        sys.assemble(&start, &q, Hessian::Split, &mut ws);

        let mut naive: Vec<f64> = model.mass.iter().map(|m| m / (h * h)).collect();
        for (g, w) in model.cubature_jacobians.chunks_exact(9 * n).zip(&model.cubature_weights) {
            let f = ReducedSystem::deformation_gradient::<crate::simd::Separate>(g, &q);
            let hp = model.material.projected_hessian(&f);
            for r in 0..n {
                for c in 0..n {
                    let mut s = 0.0;
                    for a in 0..9 {
                        for b in 0..9 {
                            s += g[a * n + r] * hp[(a, b)] * g[b * n + c];
                        }
                    }
                    naive[r * n + c] += w * s;
                }
            }
        }
        for j in 0..sys.n_contacts() {
            let x = sys.contact_position::<crate::simd::Separate>(j, &q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let hc = sys.contact.evaluate(&sys.planes[0], sys.areas[j], start.normal_force[j], &x, &xp).hessian.matrix();
            let wj = &model.contact_basis[3 * n * j..3 * n * (j + 1)];
            for r in 0..n {
                for c in 0..n {
                    naive[r * n + c] += (0..3).flat_map(|a| (0..3).map(move |b| (a, b))).map(|(a, b)| wj[a * n + r] * hc[(a, b)] * wj[b * n + c]).sum::<f64>();
                }
            }
        }
        assert!(rel_err(&ws.hess, &naive, 1e-9) < 1e-11, "assembly error {}", rel_err(&ws.hess, &naive, 1e-9));
    }

    #[test]
    fn rigid_rotation_has_zero_elastic_energy_and_force() {
        let model = small_block(2, 20, 0);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let n = sys.n_dofs();
        let r = nalgebra::Rotation3::from_euler_angles(0.7, -0.4, 1.9).into_inner();
        let mut q = vec![0.0; n];
        for i in 0..3 {
            for j in 0..3 {
                q[3 * j + i] = r[(i, j)] - if i == j { 1.0 } else { 0.0 };
            }
        }
        q[9..12].copy_from_slice(&[0.3, -0.1, 0.5]);
        let mut start = sys.step_start();
        sys.begin_step(&q, &vec![0.0; n], &mut start);
        // With q = qtilde the inertia vanishes: what is left is -f.q + elastic.
        let gravity_work: f64 = model.gravity_force.iter().zip(&q).map(|(f, x)| f * x).sum();
        let elastic = sys.energy(&start, &q) + gravity_work;
        assert!(elastic.abs() < 1e-12 * model.material.mu() * model.scene.size.powi(3), "elastic energy {elastic}");
        let mut ws = sys.workspace();
        sys.assemble(&start, &q, Hessian::None, &mut ws);
        let force_scale = model.material.mu() * model.scene.size.powi(3) * 100.0;
        for (g, f) in ws.grad.iter().zip(&model.gravity_force) {
            assert!((g + f).abs() < 1e-10 * force_scale, "elastic force {}", g + f);
        }
    }

    #[test]
    fn invalid_inputs_are_rejected() {
        let model = small_block(1, 3, 2);
        let mut inp = model.inputs();
        let short = &model.mass[..model.mass.len() - 1];
        inp.mass = short;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::ShapeMismatch { .. })));

        let n = model.n_dofs();
        let mut asym = model.mass.clone();
        asym[1] += 1.0;
        let mut inp = model.inputs();
        inp.mass = &asym;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::SingularMass { .. })));

        let mut indefinite = model.mass.clone();
        indefinite[n + 1] = -1.0;
        let mut inp = model.inputs();
        inp.mass = &indefinite;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::SingularMass { .. })));

        let mut weights = model.cubature_weights.clone();
        weights[0] = -1.0;
        let mut inp = model.inputs();
        inp.cubature_weights = &weights;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::InvalidParameter { .. })));

        let mut nan = model.contact_rest.clone();
        nan[2] = f64::NAN;
        let mut inp = model.inputs();
        inp.contact_rest = &nan;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::NonFinite { .. })));

        let mut inp = model.inputs();
        inp.dt = 0.0;
        assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::InvalidParameter { .. })));
    }
}
