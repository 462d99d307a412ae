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
//! **Layout.** The cubature Jacobians of the points with `w_k > 0` (points of
//! zero weight are dropped) are stored in groups of [`LANES`] points, each group
//! as `[i][a][lane]` (column i of `G_k`, component a of `vec(F)`). One pass over
//! a group forms the eight deformation gradients with vertical multiply-adds
//! (`F[a][lane] += G[i][a][lane] q_i`, no horizontal sums), the stress and energy
//! run eight points per instruction, and the gradient `G_k^T P_k` accumulates
//! per lane until one final reduction. Columns of G that are the same at every
//! point (the affine modes: a linear map of X has the same gradient
//! everywhere) are factored out: they add a constant to every F, and their
//! gradient is one product with the summed stress. Contact points are packed
//! the same way (`W_j` as `[i][c][lane]`, plus their normal rows `n_p^T W_j`):
//! the gaps of eight points cost one pass over the normal rows, and only groups
//! with a point that touches a plane or carries a lagged normal force go on to
//! positions, contact terms and gradient. Measured on one core (AVX-512), the
//! elastic gradient costs about 30-40 ns per cubature point at n = 32 whether
//! K is 100 or 5000, so it is compute bound: storing G in f32 would save
//! bandwidth that is not the limit, and would perturb the model at 1e-7.
//!
//! **Hessian.** It is assembled in parts, so that the solver can refresh them
//! at different rates: the elastic part `B^T B`, where B stacks, per cubature
//! point, `sqrt(w_k lambda_i) e_i^T G_k` for the positive eigenpairs of the SNH
//! Hessian (negative ones, with `|lambda_i|`, go into a second stack N, so that
//! the exact elastic Hessian is `B^T B - N^T N`), and the contact part, the same
//! product over the square-root factors of the contact points' rank-one terms
//! times `W_j`, formed only for points that touch a plane or carry a lagged
//! normal force, and kept up to date incrementally ([`ContactHessian`]). The
//! elastic rows are written eight at a time (one per lane) into a column-major
//! stack of cache size and multiplied chunk by chunk by faer's blocked
//! symmetric kernels.
//!
//! **Contact model.** [`ReducedSystem::evaluate_model`] is E with the elastic
//! energy replaced by a quadratic ([`ElasticModel`]): the solver minimises it
//! inside each Newton iteration (see [`crate::solver`]).

use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};
use nalgebra::Vector3;

use crate::contact::{ContactModel, Plane, RankOneTerms};
use crate::dense::{combine_rows, dot, rows_dot};
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::material::StableNeoHookean;
use crate::real::{Lanes, Real, LANES};
use crate::simd::{dispatch, Madd, WithMadd, F8};

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
    /// Number of cubature points given (zero weights included).
    n_cubature: usize,
    /// Columns of G that differ between cubature points, and the columns that
    /// are the same non-zero 9-vector at every point (the affine modes: a linear
    /// map of X has the same gradient everywhere) with that vector. Columns that
    /// are zero everywhere (translations) appear in neither.
    var_cols: Vec<usize>,
    const_cols: Vec<(usize, [f64; 9])>,
    /// The varying columns of the Jacobians of the points with w > 0, in groups
    /// of LANES (see the module documentation); the last group is padded with
    /// G = 0, w = 0.
    packed: Vec<f64>,
    /// Weights of the packed points, `LANES` per group.
    packed_weights: Vec<f64>,
    material: StableNeoHookean,
    contact_basis: Vec<f64>,
    contact_rest: Vec<f64>,
    areas: Vec<f64>,
    /// Contact points with a non-zero area (the others carry no force).
    contact_points: Vec<usize>,
    /// Basis rows `W_j` of those points in groups of LANES, group g at
    /// `g n 3 LANES` as `[i][c][lane]`, and their rest positions `[g][c][lane]`.
    contact_packed: Vec<f64>,
    contact_rest_packed: Vec<f64>,
    /// Normal rows `n_p^T W_j` of those points in groups of LANES: group g and
    /// plane p at `(g P + p) n LANES`, as `[i][lane]`.
    normal_rows: Vec<f64>,
    /// `n_p . X_j + d_p` at `(g P + p) LANES + lane` (+inf in padding lanes), so
    /// that `gap = offset + row . q`.
    normal_offsets: Vec<f64>,
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
    /// `-f . qt`: the part of E that does not depend on q, left out of
    /// [`ReducedSystem::evaluate`] so that energy differences keep their digits.
    offset: f64,
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
    /// Contact part of the Hessian (scratch of [`ReducedSystem::assemble`]).
    contact_hess: Vec<f64>,
    /// Elastic square-root rows of `chunk` groups of cubature points at a time,
    /// column-major with column stride `row_stride`:
    /// positive ones in `rows`, clamped ones in `clamped_rows`.
    rows: Vec<f64>,
    clamped_rows: Vec<f64>,
    row_stride: usize,
    chunk: usize,
    /// Contact square-root rows, row-major, up to 3 per point and plane (and
    /// the rows taken out by an incremental update).
    contact_rows: Vec<f64>,
    contact_rows_out: Vec<f64>,
    contact_coef: Vec<[f64; 3]>,
    contact_coef_out: Vec<[f64; 3]>,
    /// Hessian terms of every contact point with area and plane, and the
    /// displacement `x - x_prev` of every evaluated one, from the last
    /// [`ReducedSystem::evaluate`] with gradient.
    contact_terms: Vec<RankOneTerms>,
    contact_dx: Vec<[f64; 3]>,
    /// Per-lane partial sums of the contact gradient, n.
    contact_lane_grad: Vec<[f64; LANES]>,
    /// Per-lane partial sums of the elastic gradient: one per varying column
    /// of G, then the nine components of `sum_k w_k P_k` (for the constant ones).
    lane_grad: Vec<[f64; LANES]>,
    /// The columns of G split as in the system (for `elastic_gradient`).
    var_cols: Vec<usize>,
    const_cols: Vec<(usize, [f64; 9])>,
    /// Elastic energy of the last evaluation, J.
    pub elastic_energy: f64,
}

impl Workspace {
    /// The elastic part of the gradient of the last [`ReducedSystem::evaluate`]
    /// with gradient into `out` (n).
    pub fn elastic_gradient(&self, out: &mut [f64]) {
        out.fill(0.0);
        reduce_lane_gradient(&self.lane_grad, &self.var_cols, &self.const_cols, out);
    }

    /// The exact Hessian `hess - hess_clamped` into `out` (n x n).
    pub fn exact_hessian(&self, out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(&self.hess).zip(&self.hess_clamped) {
            *o = a - b;
        }
    }
}

/// `dst (lower triangle) = op(B^T B)` for the `count` rows of the row-major `rows` (width n).
fn syrk_rows(dst: &mut [f64], n: usize, rows: &[f64], count: usize, accum: Accum) {
    syrk_lower(dst, n, (count > 0).then(|| MatRef::from_row_major_slice(&rows[..count * n], count, n)), accum, 1.0);
}

/// `dst (lower triangle) = op(B^T B)` for the first `count` rows of the
/// column-major `rows` with column stride `stride`.
fn syrk_columns(dst: &mut [f64], n: usize, rows: &[f64], stride: usize, count: usize, accum: Accum) {
    syrk_lower(dst, n, (count > 0).then(|| MatRef::from_column_major_slice_with_stride(rows, count, n, stride)), accum, 1.0);
}

/// `dst (lower triangle) = op(alpha B^T B)` (nothing, or zeros for `Replace`, without B).
fn syrk_lower(dst: &mut [f64], n: usize, b: Option<MatRef<'_, f64>>, accum: Accum, alpha: f64) {
    let Some(b) = b else {
        if accum == Accum::Replace {
            dst.fill(0.0);
        }
        return;
    };
    let a = MatMut::from_column_major_slice_mut(dst, n, n);
    triangular_matmul(
        a,
        BlockStructure::TriangularLower,
        accum,
        b.transpose(),
        BlockStructure::Rectangular,
        b,
        BlockStructure::Rectangular,
        alpha,
        Par::Seq,
    );
}

/// Copies the lower triangle of the n x n column-major `a` to its upper triangle.
pub(crate) fn mirror_lower(a: &mut [f64], n: usize) {
    for c in 0..n {
        for r in c + 1..n {
            a[r * n + c] = a[c * n + r];
        }
    }
}

/// Adds `B^T B` for the `count` row-major rows (width n) to the full symmetric `dst`.
pub(crate) fn add_gram(dst: &mut [f64], n: usize, rows: &[f64], count: usize) {
    if count == 0 {
        return;
    }
    syrk_rows(dst, n, rows, count, Accum::Add);
    mirror_lower(dst, n);
}

/// A contact point whose gap, from its normal row, is above this (m) is
/// skipped unless it carries a lagged normal force; its exact gap (from its
/// position) decides everything else. The margin covers the round-off between
/// the two ways of computing the gap.
const CULL_MARGIN: f64 = 1e-9;

/// A quadratic stand-in for the elastic energy about `origin`:
/// `energy + gradient . d + d^T hessian d / 2`, `d = q - origin`.
#[derive(Debug, Clone, Copy)]
pub struct ElasticModel<'a> {
    /// Expansion point, n.
    pub origin: &'a [f64],
    /// Elastic energy there, J.
    pub energy: f64,
    /// Elastic gradient there, n.
    pub gradient: &'a [f64],
    /// Symmetric n x n matrix.
    pub hessian: &'a [f64],
}

/// Relative change of a contact curvature (and `1 - cos` of its direction)
/// below which an incremental update keeps the old term.
const CURVATURE_SLACK: f64 = 1.1;
const DIRECTION_COS: f64 = 0.995;

/// The contact part of the Hessian, kept up to date incrementally by
/// [`ReducedSystem::update_contact_hessian`].
#[derive(Debug, Clone)]
pub struct ContactHessian {
    /// The terms in `hess`, per contact point with area and plane.
    used: Vec<RankOneTerms>,
    /// n x n, full symmetric.
    hess: Vec<f64>,
    /// Rows in `hess`, and rows taken out since it was last formed from scratch.
    rows: usize,
    removed: usize,
    valid: bool,
    /// Keep terms that changed by less than [`CURVATURE_SLACK`] (else only equal ones).
    lagged: bool,
}

impl ContactHessian {
    /// The matrix (n x n, full symmetric, PSD up to round-off).
    pub fn matrix(&self) -> &[f64] {
        &self.hess
    }

    /// Forms the matrix from scratch at the next update.
    pub fn invalidate(&mut self) {
        self.valid = false;
    }
}

/// Whether the curvature terms `a` may stand in for `b` (`slack`: allowed ratio of
/// the curvatures, `cos`: of the directions; 1, 1 for equality).
fn close_terms(a: &RankOneTerms, b: &RankOneTerms, slack: f64, cos: f64) -> bool {
    a.len == b.len
        && (0..a.len).all(|t| {
            let (ca, cb) = (a.coef[t], b.coef[t]);
            ca <= slack * cb && cb <= slack * ca && a.dir[t].dot(&b.dir[t]) >= cos
        })
}

fn check_len(name: &str, data: &[f64], expected: usize, shape: impl FnOnce() -> String) -> Result<()> {
    if data.len() == expected {
        Ok(())
    } else {
        Err(LicromError::shape(name, shape(), format!("{} values", data.len())))
    }
}

/// The eight values of `s` from `at`.
#[inline(always)]
fn lanes_at(s: &[f64], at: usize) -> &F8 {
    s[at..at + LANES].try_into().expect("eight lanes")
}

/// Writes the combinations `sum_a coef[b][a] gs[a]` (for the first `count`
/// modes b of each coefficient set, eight lanes each) into column `at` of the
/// positive and clamped row stacks, from row `base` on. All nine combinations
/// are formed at once: nine independent multiply-add chains reuse each lane
/// block of G.
#[inline(always)]
fn write_rows<M: Madd>(at: usize, gs: &[[f64; LANES]; 9], coefs: [&[[[f64; LANES]; 9]; 9]; 2], counts: [(usize, usize); 2], outs: [&mut Vec<f64>; 2]) {
    for ((coef, (count, base)), out) in coefs.into_iter().zip(counts).zip(outs) {
        if count == 0 {
            continue;
        }
        let mut v = [[0.0; LANES]; 9];
        for a in 0..9 {
            for b in 0..9 {
                v[b] = M::madd8(&coef[b][a], &gs[a], v[b]);
            }
        }
        let at = at + base;
        out[at..at + count * LANES].copy_from_slice(v[..count].as_flattened());
    }
}

/// Adds the elastic gradient held per lane in `lane_grad` (varying columns,
/// then the nine components of the summed stress) to `out` (n).
fn reduce_lane_gradient(lane_grad: &[[f64; LANES]], var_cols: &[usize], const_cols: &[(usize, [f64; 9])], out: &mut [f64]) {
    let sum = |a: &[f64; LANES]| ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7]));
    for (a, &c) in lane_grad.iter().zip(var_cols) {
        out[c] += sum(a);
    }
    let nv = var_cols.len();
    let stress: [f64; 9] = std::array::from_fn(|a| sum(&lane_grad[nv + a]));
    for (c, v) in const_cols {
        out[*c] += (0..9).map(|a| v[a] * stress[a]).sum::<f64>();
    }
}

/// The eight deformation gradients of a packed group, `F[a][lane]`: `f0`
/// (identity plus the constant columns' part) plus the varying columns.
#[inline(always)]
fn group_deformation<M: Madd>(group: &[f64], q: &[f64], var_cols: &[usize], f0: &[f64; 9]) -> [[f64; LANES]; 9] {
    let mut f = [[0.0; LANES]; 9];
    for a in 0..9 {
        f[a] = [f0[a]; LANES];
    }
    for (g, &c) in group.chunks_exact(9 * LANES).zip(var_cols) {
        let qc = q[c];
        for a in 0..9 {
            f[a] = M::madd8_splat(qc, lanes_at(g, a * LANES), f[a]);
        }
    }
    f
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
        let kept: Vec<usize> = (0..k).filter(|&i| inp.cubature_weights[i] > 0.0).collect();
        let column = |point: usize, c: usize| -> [f64; 9] { std::array::from_fn(|a| inp.cubature_jacobians[9 * n * point + a * n + c]) };
        let (mut var_cols, mut const_cols) = (Vec::new(), Vec::new());
        for c in 0..n {
            let first = kept.first().map(|&p| column(p, c)).unwrap_or([0.0; 9]);
            if kept.iter().any(|&p| column(p, c) != first) {
                var_cols.push(c);
            } else if first.iter().any(|v| *v != 0.0) {
                const_cols.push((c, first));
            }
        }
        let nv = var_cols.len();
        let groups = kept.len().div_ceil(LANES);
        let mut packed = vec![0.0; groups * nv * 9 * LANES];
        let mut packed_weights = vec![0.0; groups * LANES];
        for (slot, &point) in kept.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            packed_weights[slot] = inp.cubature_weights[point];
            let src = &inp.cubature_jacobians[9 * n * point..9 * n * (point + 1)];
            let dst = &mut packed[g * nv * 9 * LANES..(g + 1) * nv * 9 * LANES];
            for (iv, &c) in var_cols.iter().enumerate() {
                for a in 0..9 {
                    dst[(iv * 9 + a) * LANES + l] = src[a * n + c];
                }
            }
        }
        let contact_points: Vec<usize> = (0..c).filter(|&j| inp.contact_areas[j] > 0.0).collect();
        let n_planes = inp.planes.len();
        let contact_groups = contact_points.len().div_ceil(LANES);
        let mut normal_rows = vec![0.0; contact_groups * n_planes * n * LANES];
        let mut normal_offsets = vec![f64::INFINITY; contact_groups * n_planes * LANES];
        for (slot, &j) in contact_points.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            let w = &inp.contact_basis[3 * n * j..3 * n * (j + 1)];
            for (p, plane) in inp.planes.iter().enumerate() {
                let at = g * n_planes + p;
                let nrm = plane.normal();
                let x0 = Vector3::from_column_slice(&inp.contact_rest[3 * j..3 * j + 3]);
                normal_offsets[at * LANES + l] = plane.gap(&x0);
                for i in 0..n {
                    normal_rows[(at * n + i) * LANES + l] = nrm.x * w[i] + nrm.y * w[n + i] + nrm.z * w[2 * n + i];
                }
            }
        }
        let mut contact_packed = vec![0.0; contact_groups * n * 3 * LANES];
        let mut contact_rest_packed = vec![0.0; contact_groups * 3 * LANES];
        for (slot, &j) in contact_points.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            for c in 0..3 {
                contact_rest_packed[(g * 3 + c) * LANES + l] = inp.contact_rest[3 * j + c];
                for i in 0..n {
                    contact_packed[((g * n + i) * 3 + c) * LANES + l] = inp.contact_basis[3 * n * j + c * n + i];
                }
            }
        }
        Ok(Self {
            n,
            mass,
            gravity: inp.gravity_force.to_vec(),
            n_cubature: k,
            var_cols,
            const_cols,
            packed,
            packed_weights,
            material: inp.material,
            contact_basis: inp.contact_basis.to_vec(),
            contact_rest: inp.contact_rest.to_vec(),
            contact_points,
            contact_packed,
            contact_rest_packed,
            normal_rows,
            normal_offsets,
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
        self.n_cubature
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

    /// Whether the model has contact points with area and planes (friction and
    /// contact terms can be non-zero).
    pub fn has_contact(&self) -> bool {
        !self.contact_points.is_empty() && !self.planes.is_empty()
    }

    fn groups(&self) -> usize {
        self.packed_weights.len() / LANES
    }

    /// Zeroed start-of-step buffers for this system.
    pub fn step_start(&self) -> StepStart {
        let c = self.n_contacts();
        StepStart {
            q: vec![0.0; self.n],
            qtilde: vec![0.0; self.n],
            x_prev: vec![0.0; 3 * c],
            normal_force: vec![0.0; c * self.planes.len()],
            offset: 0.0,
        }
    }

    /// Buffers for [`Self::assemble`] and the other evaluations.
    pub fn workspace(&self) -> Workspace {
        let n = self.n;
        // Chunks of rows of about 256 KiB: they stay in cache between being
        // written and being multiplied.
        let chunk = (256 * 1024 / (9 * LANES * 8 * n)).clamp(1, self.groups().max(1));
        let row_stride = 9 * LANES * chunk;
        let contact_rows = 3 * self.contact_points.len() * self.planes.len();
        Workspace {
            grad: vec![0.0; n],
            hess: vec![0.0; n * n],
            hess_clamped: vec![0.0; n * n],
            has_clamped: false,
            contact_hess: vec![0.0; n * n],
            rows: vec![0.0; row_stride * n],
            clamped_rows: vec![0.0; row_stride * n],
            row_stride,
            chunk,
            contact_rows: vec![0.0; contact_rows * n],
            contact_rows_out: vec![0.0; contact_rows * n],
            contact_coef: vec![[0.0; 3]; 3 * self.planes.len()],
            contact_coef_out: vec![[0.0; 3]; 3 * self.planes.len()],
            contact_terms: vec![RankOneTerms::default(); self.contact_points.len() * self.planes.len()],
            contact_dx: vec![[0.0; 3]; self.contact_points.len()],
            contact_lane_grad: vec![[0.0; LANES]; n],
            lane_grad: vec![[0.0; LANES]; self.var_cols.len() + 9],
            var_cols: self.var_cols.clone(),
            const_cols: self.const_cols.clone(),
            elastic_energy: 0.0,
        }
    }

    /// Fills `start` for a step from state `(q, qdot)`: inertial target, contact
    /// positions and lagged normal forces. Lengths must be n.
    pub fn begin_step(&self, q: &[f64], qdot: &[f64], start: &mut StepStart) {
        dispatch(BeginKernel { sys: self, q, qdot, start })
    }

    #[inline(always)]
    fn begin_impl<M: Madd>(&self, q: &[f64], qdot: &[f64], start: &mut StepStart) {
        let h = self.dt();
        start.q.copy_from_slice(q);
        for ((t, qi), vi) in start.qtilde.iter_mut().zip(q).zip(qdot) {
            *t = qi + h * vi;
        }
        start.offset = -dot::<M>(&self.gravity, &start.qtilde);
        let n_planes = self.planes.len();
        start.normal_force.fill(0.0);
        let k = self.contact.normal_stiffness;
        for (g, slots) in self.contact_points.chunks(LANES).enumerate() {
            let mut engaged = 0u32;
            for p in 0..n_planes {
                let gap = self.group_gap::<M>(g * n_planes + p, q);
                for (l, &j) in slots.iter().enumerate() {
                    // As `ContactModel::lagged_normal_force`.
                    let f = self.areas[j] * k * (-gap[l]).max(0.0);
                    start.normal_force[j * n_planes + p] = f;
                    if f > 0.0 {
                        engaged |= 1 << l;
                    }
                }
            }
            // Only points with a lagged normal force use their start position.
            for (l, &j) in slots.iter().enumerate() {
                if engaged & (1 << l) != 0 {
                    let x = self.contact_position::<M>(j, q);
                    start.x_prev[3 * j..3 * j + 3].copy_from_slice(x.as_slice());
                }
            }
        }
    }

    /// Gaps of the eight contact points of group `at / P` to plane `at % P` at `q`.
    #[inline(always)]
    fn group_gap<M: Madd>(&self, at: usize, q: &[f64]) -> F8 {
        let n = self.n;
        let rows = &self.normal_rows[at * n * LANES..(at + 1) * n * LANES];
        let mut gap = *lanes_at(&self.normal_offsets, at * LANES);
        for (i, &qi) in q.iter().enumerate() {
            gap = M::madd8_splat(qi, lanes_at(rows, i * LANES), gap);
        }
        gap
    }

    #[inline(always)]
    fn contact_position<M: Madd>(&self, j: usize, q: &[f64]) -> Vector3<f64> {
        let n = self.n;
        let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
        let x0 = &self.contact_rest[3 * j..3 * j + 3];
        let wq = rows_dot::<M, 3>(w, q);
        Vector3::new(x0[0] + wq[0], x0[1] + wq[1], x0[2] + wq[2])
    }

    #[cfg(test)]
    fn deformation_gradient<M: Madd>(g: &[f64], q: &[f64]) -> nalgebra::Matrix3<f64> {
        let mut f = rows_dot::<M, 9>(g, q);
        for a in [0, 4, 8] {
            f[a] += 1.0;
        }
        crate::material::mat3_row_major(&f)
    }

    /// Incremental potential E(q), J.
    pub fn energy(&self, start: &StepStart, q: &[f64]) -> f64 {
        dispatch(EvaluateKernel { sys: self, start, q, model: None, ws: None }).0 + start.offset
    }

    /// `E(q) - E0` (J) with the constant `E0 = -f . qt` of the step left out, so
    /// that differences of nearby values keep their digits; with `with_gradient`
    /// also the gradient (into `ws.grad`) and the contact points' Hessian terms
    /// (for [`Self::update_contact_hessian`]).
    /// The elastic energy goes to `ws.elastic_energy`.
    pub fn evaluate(&self, start: &StepStart, q: &[f64], with_gradient: bool, ws: &mut Workspace) -> f64 {
        self.evaluate_with(start, q, None, with_gradient, ws)
    }

    /// [`Self::evaluate`] with the elastic energy replaced by a quadratic `model`
    /// (inertia, gravity and contact exact): a minimisation of it costs no pass
    /// over the cubature points. `ws.elastic_gradient` is then not set.
    pub fn evaluate_model(&self, start: &StepStart, q: &[f64], model: &ElasticModel<'_>, with_gradient: bool, ws: &mut Workspace) -> f64 {
        self.evaluate_with(start, q, Some(model), with_gradient, ws)
    }

    fn evaluate_with(&self, start: &StepStart, q: &[f64], model: Option<&ElasticModel<'_>>, with_gradient: bool, ws: &mut Workspace) -> f64 {
        let (e, elastic) = dispatch(EvaluateKernel { sys: self, start, q, model, ws: with_gradient.then_some(&mut *ws) });
        ws.elastic_energy = elastic;
        e
    }

    /// Energy (shifted as in [`Self::evaluate`]) and, when `grad` is not empty,
    /// the gradient; `lane_grad` (n, or empty) is scratch.
    #[inline(always)]
    fn evaluate_impl<M: Madd>(&self, start: &StepStart, q: &[f64], model: Option<&ElasticModel<'_>>, mut ws: Option<&mut Workspace>) -> (f64, f64) {
        let n = self.n;
        let inv_h2 = 1.0 / (self.dt() * self.dt());
        // Inertia and gravity, relative to the inertial target.
        let mut inertia = 0.0;
        let mut work = 0.0;
        for i in 0..n {
            let mut md = 0.0;
            for j in 0..n {
                md = M::madd(self.mass[i * n + j], q[j] - start.qtilde[j], md);
            }
            let d = q[i] - start.qtilde[i];
            inertia = M::madd(d, md, inertia);
            work = M::madd(self.gravity[i], d, work);
            if let Some(ws) = ws.as_deref_mut() {
                ws.grad[i] = md * inv_h2 - self.gravity[i];
            }
        }
        let mut e = 0.5 * inertia * inv_h2 - work;

        let elastic_energy = if let Some(m) = model {
            let mut em = m.energy;
            for i in 0..n {
                let mut kd = 0.0;
                for j in 0..n {
                    kd = M::madd(m.hessian[i * n + j], q[j] - m.origin[j], kd);
                }
                em = M::madd(q[i] - m.origin[i], m.gradient[i] + 0.5 * kd, em);
                if let Some(ws) = ws.as_deref_mut() {
                    ws.grad[i] += m.gradient[i] + kd;
                }
            }
            em
        } else {
            match ws.as_deref_mut() {
                Some(ws) => self.elastic_impl::<M>(q, &mut ws.lane_grad, &mut ws.grad),
                None => self.elastic_impl::<M>(q, &mut [], &mut []),
            }
        };
        e += elastic_energy;
        (e + self.contact_energy_impl::<M>(start, q, ws), elastic_energy)
    }

    /// Contact energy and, with `ws`, its gradient (added to `ws.grad`), the
    /// Hessian terms and displacements of the points (into `ws`). Points that
    /// touch no plane and carry no lagged normal force contribute nothing: eight
    /// gaps at a time find them from the normal rows alone; the positions and
    /// the gradient of the others are formed eight points at a time too.
    #[inline(always)]
    fn contact_energy_impl<M: Madd>(&self, start: &StepStart, q: &[f64], mut ws: Option<&mut Workspace>) -> f64 {
        let n = self.n;
        let n_planes = self.planes.len();
        let mut e = 0.0;
        if n_planes == 0 {
            return e;
        }
        if let Some(ws) = ws.as_deref_mut() {
            ws.contact_lane_grad.fill([0.0; LANES]);
        }
        let mut any_force = false;
        for (g, slots) in self.contact_points.chunks(LANES).enumerate() {
            let mut active = 0u32;
            for p in 0..n_planes {
                let gap = self.group_gap::<M>(g * n_planes + p, q);
                for (l, &j) in slots.iter().enumerate() {
                    if gap[l] < CULL_MARGIN || start.normal_force[j * n_planes + p] > 0.0 {
                        active |= 1 << l;
                    }
                }
            }
            if active == 0 {
                if let Some(ws) = ws.as_deref_mut() {
                    for t in &mut ws.contact_terms[g * LANES * n_planes..(g * LANES + slots.len()) * n_planes] {
                        t.len = 0;
                    }
                }
                continue;
            }
            let x = self.group_positions::<M>(g, q);
            let mut force = [[0.0; LANES]; 3];
            let mut group_force = false;
            for (l, &j) in slots.iter().enumerate() {
                let slot = g * LANES + l;
                if active & (1 << l) == 0 {
                    if let Some(ws) = ws.as_deref_mut() {
                        for t in &mut ws.contact_terms[slot * n_planes..(slot + 1) * n_planes] {
                            t.len = 0;
                        }
                    }
                    continue;
                }
                let xj = Vector3::new(x[0][l], x[1][l], x[2][l]);
                let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
                let mut g3 = Vector3::zeros();
                for (p, plane) in self.planes.iter().enumerate() {
                    let c = self.contact.evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &xj, &xp);
                    e += c.energy;
                    g3 += c.gradient;
                    if let Some(ws) = ws.as_deref_mut() {
                        ws.contact_terms[slot * n_planes + p] = c.hessian;
                    }
                }
                if let Some(ws) = ws.as_deref_mut() {
                    let dx = xj - xp;
                    ws.contact_dx[slot] = [dx.x, dx.y, dx.z];
                }
                if g3 != Vector3::zeros() {
                    for c in 0..3 {
                        force[c][l] = g3[c];
                    }
                    group_force = true;
                }
            }
            if let (Some(ws), true) = (ws.as_deref_mut(), group_force) {
                any_force = true;
                let w = &self.contact_packed[g * n * 3 * LANES..(g + 1) * n * 3 * LANES];
                for (wi, acc) in w.chunks_exact(3 * LANES).zip(ws.contact_lane_grad.iter_mut()) {
                    let mut v = *acc;
                    for c in 0..3 {
                        v = M::madd8(lanes_at(wi, c * LANES), &force[c], v);
                    }
                    *acc = v;
                }
            }
        }
        if let (Some(ws), true) = (ws, any_force) {
            for (g, a) in ws.grad.iter_mut().zip(&ws.contact_lane_grad) {
                *g += ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7]));
            }
        }
        e
    }

    /// Positions `x[c][lane]` of the eight contact points of group `g` at `q`.
    #[inline(always)]
    fn group_positions<M: Madd>(&self, g: usize, q: &[f64]) -> [F8; 3] {
        let n = self.n;
        let w = &self.contact_packed[g * n * 3 * LANES..(g + 1) * n * 3 * LANES];
        let mut x = [[0.0; LANES]; 3];
        for c in 0..3 {
            x[c] = *lanes_at(&self.contact_rest_packed, (g * 3 + c) * LANES);
        }
        for (wi, &qi) in w.chunks_exact(3 * LANES).zip(q) {
            for c in 0..3 {
                x[c] = M::madd8_splat(qi, lanes_at(wi, c * LANES), x[c]);
            }
        }
        x
    }

    /// Elastic energy and, when `grad` is not
    /// empty, its gradient added to `grad`, eight points at a time.
    #[inline(always)]
    fn elastic_impl<M: Madd>(&self, q: &[f64], lane_grad: &mut [[f64; LANES]], grad: &mut [f64]) -> f64 {
        let nv = self.var_cols.len();
        let with_gradient = !grad.is_empty();
        if with_gradient {
            lane_grad.fill([0.0; LANES]);
        }
        let f0 = self.constant_deformation(q);
        let mut elastic = [0.0; LANES];
        let group_len = nv * 9 * LANES;
        for (g, weights) in self.packed_weights.chunks_exact(LANES).enumerate() {
            let group = &self.packed[g * group_len..(g + 1) * group_len];
            let f = group_deformation::<M>(group, q, &self.var_cols, &f0);
            let (psi, mut p) = self.material.energy_stress_lanes::<M>(&f, true);
            for l in 0..LANES {
                elastic[l] = M::madd(weights[l], psi[l], elastic[l]);
            }
            if with_gradient {
                for row in p.iter_mut() {
                    for l in 0..LANES {
                        row[l] *= weights[l];
                    }
                }
                let (var_acc, stress_acc) = lane_grad.split_at_mut(nv);
                for (g, acc) in group.chunks_exact(9 * LANES).zip(var_acc.iter_mut()) {
                    let mut v = *acc;
                    for a in 0..9 {
                        v = M::madd8(lanes_at(g, a * LANES), &p[a], v);
                    }
                    *acc = v;
                }
                for (acc, pa) in stress_acc.iter_mut().zip(&p) {
                    for l in 0..LANES {
                        acc[l] += pa[l];
                    }
                }
            }
        }
        let e = ((elastic[0] + elastic[4]) + (elastic[1] + elastic[5])) + ((elastic[2] + elastic[6]) + (elastic[3] + elastic[7]));
        if with_gradient {
            reduce_lane_gradient(lane_grad, &self.var_cols, &self.const_cols, grad);
        }
        e
    }

    /// `vec(I) + sum_c v_c q_c` over the constant columns of G.
    #[inline(always)]
    fn constant_deformation(&self, q: &[f64]) -> [f64; 9] {
        let mut f0 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        for (c, v) in &self.const_cols {
            for a in 0..9 {
                f0[a] += v[a] * q[*c];
            }
        }
        f0
    }

    /// Gradient (into `ws.grad`) and the requested Hessian parts (into `ws.hess`,
    /// `ws.hess_clamped`, full symmetric) of E at `q`.
    pub fn assemble(&self, start: &StepStart, q: &[f64], hessian: Hessian, ws: &mut Workspace) {
        self.evaluate(start, q, true, ws);
        if hessian == Hessian::None {
            return;
        }
        let split = hessian == Hessian::Split;
        let mut hess = std::mem::take(&mut ws.hess);
        let mut clamped = std::mem::take(&mut ws.hess_clamped);
        let mut contact = std::mem::take(&mut ws.contact_hess);
        let has_clamped = self.elastic_hessian(q, ws, &mut hess, split.then_some(&mut clamped[..]));
        self.contact_hessian(start, q, ws, &mut contact);
        let inv_h2 = 1.0 / (self.dt() * self.dt());
        for ((h, m), c) in hess.iter_mut().zip(&self.mass).zip(&contact) {
            *h += m * inv_h2 + c;
        }
        ws.hess = hess;
        ws.hess_clamped = clamped;
        ws.contact_hess = contact;
        if split {
            ws.has_clamped = has_clamped;
        }
    }

    /// Elastic part of the Hessian at `q`: the PSD projection (negative
    /// eigenvalues of every point's SNH Hessian clamped to zero) into
    /// `projected`, and what the clamping removed (PSD) into `clamped` when
    /// given, both n x n full symmetric. Returns whether anything was clamped.
    pub fn elastic_hessian(&self, q: &[f64], ws: &mut Workspace, projected: &mut [f64], mut clamped: Option<&mut [f64]>) -> bool {
        let n = self.n;
        let split = clamped.is_some();
        projected.fill(0.0);
        if let Some(c) = clamped.as_deref_mut() {
            c.fill(0.0);
        }
        let mut any_clamped = false;
        let groups = self.groups();
        for first in (0..groups).step_by(ws.chunk) {
            let range = first..groups.min(first + ws.chunk);
            let (positive, negative) = dispatch(ElasticRowsKernel { sys: self, q, split, range, ws: &mut *ws });
            syrk_columns(projected, n, &ws.rows, ws.row_stride, positive, Accum::Add);
            if let Some(c) = clamped.as_deref_mut() {
                syrk_columns(c, n, &ws.clamped_rows, ws.row_stride, negative, Accum::Add);
            }
            any_clamped |= negative > 0;
        }
        mirror_lower(projected, n);
        if let Some(c) = clamped {
            mirror_lower(c, n);
        }
        any_clamped
    }

    /// Square-root rows of the elastic Hessian for the groups in `range`, eight
    /// (one per lane) per group and eigenmode, skipping modes that no lane of the
    /// group needs; returns the numbers of positive and clamped rows written.
    #[inline(always)]
    fn elastic_rows_impl<M: Madd>(&self, q: &[f64], split: bool, range: std::ops::Range<usize>, ws: &mut Workspace) -> (usize, usize) {
        let nv = self.var_cols.len();
        let stride = ws.row_stride;
        let group_len = nv * 9 * LANES;
        let f0 = self.constant_deformation(q);
        let (mut positive, mut negative) = (0, 0);
        let mut values = [Lanes::splat(0.0); 9];
        let mut vectors = [[Lanes::splat(0.0); 9]; 9];
        let mut pos_coef = [[[0.0; LANES]; 9]; 9];
        let mut neg_coef = [[[0.0; LANES]; 9]; 9];
        let packed = &self.packed[range.start * group_len..range.end * group_len];
        let packed_weights = &self.packed_weights[range.start * LANES..range.end * LANES];
        for (g, weights) in packed_weights.chunks_exact(LANES).enumerate() {
            let group = &packed[g * group_len..(g + 1) * group_len];
            let f = group_deformation::<M>(group, q, &self.var_cols, &f0);
            let mut lanes = [[Lanes::splat(0.0); 3]; 3];
            for a in 0..9 {
                lanes[a / 3][a % 3] = Lanes(f[a]);
            }
            self.material.eigensystem_of(&lanes, &mut values, &mut vectors);
            let (mut n_pos, mut n_neg) = (0, 0);
            for (lambda, v) in values.iter().zip(&vectors) {
                let mut sp = [0.0; LANES];
                let mut sn = [0.0; LANES];
                let (mut any_pos, mut any_neg) = (false, false);
                for l in 0..LANES {
                    let s = (weights[l] * lambda.0[l].abs()).sqrt();
                    if lambda.0[l] > 0.0 {
                        sp[l] = s;
                        any_pos |= s > 0.0;
                    } else {
                        sn[l] = s;
                        any_neg |= s > 0.0;
                    }
                }
                if any_pos {
                    for a in 0..9 {
                        for l in 0..LANES {
                            pos_coef[n_pos][a][l] = sp[l] * v[a].0[l];
                        }
                    }
                    n_pos += 1;
                }
                if split && any_neg {
                    for a in 0..9 {
                        for l in 0..LANES {
                            neg_coef[n_neg][a][l] = sn[l] * v[a].0[l];
                        }
                    }
                    n_neg += 1;
                }
            }
            // All nine combinations at once: nine independent multiply-add
            // chains reuse each loaded block of G; only the needed ones are stored.
            let counts = [(n_pos, positive), (n_neg, negative)];
            for (g, &c) in group.chunks_exact(9 * LANES).zip(&self.var_cols) {
                let mut gs = [[0.0; LANES]; 9];
                for a in 0..9 {
                    gs[a] = *lanes_at(g, a * LANES);
                }
                write_rows::<M>(c * stride, &gs, [&pos_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
            }
            for (c, v) in &self.const_cols {
                write_rows::<M>(*c * stride, &v.map(|x| [x; LANES]), [&pos_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
            }
            positive += n_pos * LANES;
            negative += n_neg * LANES;
        }
        (positive, negative)
    }

    /// Contact part of the Hessian at `q` (PSD, n x n full symmetric) into `out`,
    /// from the points that touch a plane or carry a lagged normal force.
    pub fn contact_hessian(&self, start: &StepStart, q: &[f64], ws: &mut Workspace, out: &mut [f64]) {
        let count = dispatch(ContactRowsKernel { sys: self, start, q, ws: &mut *ws });
        syrk_rows(out, self.n, &ws.contact_rows, count, Accum::Replace);
        mirror_lower(out, self.n);
    }

    #[inline(always)]
    fn contact_rows_impl<M: Madd>(&self, start: &StepStart, q: &[f64], ws: &mut Workspace) -> usize {
        let n = self.n;
        let n_planes = self.planes.len();
        let mut rows = 0;
        if n_planes == 0 {
            return 0;
        }
        for &j in &self.contact_points {
            let x = self.contact_position::<M>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let mut count = 0;
            for (p, plane) in self.planes.iter().enumerate() {
                let e = self.contact.evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp);
                for t in 0..e.hessian.len {
                    let d = e.hessian.dir[t] * e.hessian.coef[t].sqrt();
                    ws.contact_coef[count] = [d.x, d.y, d.z];
                    count += 1;
                }
            }
            if count > 0 {
                let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
                combine_rows::<M, 3>(w, &ws.contact_coef[..count], &mut ws.contact_rows[rows * n..], &[0.0; 3], &mut []);
                rows += count;
            }
        }
        rows
    }

    /// An empty incremental contact Hessian for this system; `lagged` keeps
    /// curvatures that changed by less than 10% (and directions that turned by
    /// less than about 6 degrees), else only unchanged ones.
    pub fn contact_hessian_state(&self, lagged: bool) -> ContactHessian {
        ContactHessian {
            used: vec![RankOneTerms::default(); self.contact_points.len() * self.planes.len()],
            hess: vec![0.0; self.n * self.n],
            rows: 0,
            removed: 0,
            valid: false,
            lagged,
        }
    }

    /// Brings `state` to the contact terms of the last [`Self::evaluate`] with
    /// gradient: the rows of the points whose terms changed are taken out of the
    /// matrix and their new rows put in, so that a contact state that does not
    /// change (sticking, resting) costs nothing. The matrix is formed from scratch
    /// when invalid or once the rows taken out outnumber four times those in it,
    /// which bounds the round-off of the updates. Returns the rows changed.
    pub fn update_contact_hessian(&self, ws: &mut Workspace, state: &mut ContactHessian) -> usize {
        let n = self.n;
        let rebuild = !state.valid || state.removed > 4 * state.rows.max(64);
        let (plus, minus, rows) = dispatch(ContactUpdateKernel { sys: self, ws: &mut *ws, state: &mut *state, rebuild });
        if rebuild {
            syrk_rows(&mut state.hess, n, &ws.contact_rows, plus, Accum::Replace);
            state.removed = 0;
        } else {
            if plus > 0 {
                syrk_rows(&mut state.hess, n, &ws.contact_rows, plus, Accum::Add);
            }
            if minus > 0 {
                let b = MatRef::from_row_major_slice(&ws.contact_rows_out[..minus * n], minus, n);
                syrk_lower(&mut state.hess, n, Some(b), Accum::Add, -1.0);
            }
            state.removed += minus;
        }
        mirror_lower(&mut state.hess, n);
        state.rows = rows;
        state.valid = true;
        plus + minus
    }

    /// Rows in and out of an incremental update; returns their counts and the
    /// rows in the matrix afterwards.
    #[inline(always)]
    fn update_contact_impl<M: Madd>(&self, ws: &mut Workspace, state: &mut ContactHessian, rebuild: bool) -> (usize, usize, usize) {
        let n = self.n;
        let n_planes = self.planes.len();
        let (slack, cos) = if state.lagged { (CURVATURE_SLACK, DIRECTION_COS) } else { (1.0, 1.0) };
        let (mut plus, mut minus, mut rows) = (0, 0, 0);
        for (slot, &j) in self.contact_points.iter().enumerate() {
            let (mut count_in, mut count_out) = (0, 0);
            for p in 0..n_planes {
                let k = slot * n_planes + p;
                let (new, old) = (ws.contact_terms[k], state.used[k]);
                if !rebuild && (new.len == 0 && old.len == 0 || close_terms(&new, &old, slack, cos)) {
                    rows += old.len;
                    continue;
                }
                if !rebuild {
                    for t in 0..old.len {
                        let d = old.dir[t] * old.coef[t].sqrt();
                        ws.contact_coef_out[count_out] = [d.x, d.y, d.z];
                        count_out += 1;
                    }
                }
                for t in 0..new.len {
                    let d = new.dir[t] * new.coef[t].sqrt();
                    ws.contact_coef[count_in] = [d.x, d.y, d.z];
                    count_in += 1;
                }
                state.used[k] = new;
                rows += new.len;
            }
            let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
            if count_in > 0 {
                combine_rows::<M, 3>(w, &ws.contact_coef[..count_in], &mut ws.contact_rows[plus * n..], &[0.0; 3], &mut []);
                plus += count_in;
            }
            if count_out > 0 {
                combine_rows::<M, 3>(w, &ws.contact_coef_out[..count_out], &mut ws.contact_rows_out[minus * n..], &[0.0; 3], &mut []);
                minus += count_out;
            }
        }
        (plus, minus, rows)
    }

    /// Stick correction of a Newton direction `dir` taken from the point of the
    /// last [`Self::evaluate`] with gradient (whose contact displacements it
    /// uses): the slipping
    /// contact points whose slip the step would reverse or bring into the stick
    /// region (where the friction force falls below the Coulomb limit) are modelled
    /// as sticking. For each, the square-root rows of the Hessian change
    /// `c T - (mu f_n / s)(T - t t^T)` (PSD: `c > mu f_n / s` while slipping) go to the
    /// switch rows, and `W_j^T t (c s - mu f_n)` (stick force minus slip force) is
    /// added to `rhs`. Returns the number of rows; [`Self::add_switch_rows`] adds
    /// their product to a Hessian.
    pub fn stick_switch(&self, start: &StepStart, dir: &[f64], ws: &mut Workspace, rhs: &mut [f64]) -> usize {
        dispatch(StickKernel { sys: self, start, dir, ws, rhs })
    }

    /// Adds the product of the first `count` switch rows of [`Self::stick_switch`]
    /// to the full symmetric `hess`.
    pub fn add_switch_rows(&self, ws: &Workspace, count: usize, hess: &mut [f64]) {
        add_gram(hess, self.n, &ws.contact_rows, count);
    }

    #[inline(always)]
    fn stick_impl<M: Madd>(&self, start: &StepStart, dir: &[f64], ws: &mut Workspace, rhs: &mut [f64]) -> usize {
        let n = self.n;
        let n_planes = self.planes.len();
        let h = self.dt();
        let mut rows = 0;
        for (g, slots) in self.contact_points.chunks(LANES).enumerate() {
            // Slipping points (all carry a lagged normal force, so they were
            // evaluated and their displacement kept).
            let mut slipping = 0u32;
            for (l, &j) in slots.iter().enumerate() {
                let c = self.areas[j] * self.contact.friction_stiffness / h;
                let dx = Vector3::from(ws.contact_dx[g * LANES + l]);
                for (p, plane) in self.planes.iter().enumerate() {
                    let cap = plane.friction() * start.normal_force[j * n_planes + p];
                    if cap > 0.0 && c > 0.0 {
                        let nrm = plane.normal();
                        if c * (dx - nrm * nrm.dot(&dx)).norm() > cap {
                            slipping |= 1 << l;
                        }
                    }
                }
            }
            if slipping == 0 {
                continue;
            }
            // Their motion along the direction, eight at a time.
            let w = &self.contact_packed[g * n * 3 * LANES..(g + 1) * n * 3 * LANES];
            let mut wd = [[0.0; LANES]; 3];
            for (wi, &di) in w.chunks_exact(3 * LANES).zip(dir) {
                for c in 0..3 {
                    wd[c] = M::madd8_splat(di, lanes_at(wi, c * LANES), wd[c]);
                }
            }
            for (l, &j) in slots.iter().enumerate() {
                if slipping & (1 << l) == 0 {
                    continue;
                }
                let c = self.areas[j] * self.contact.friction_stiffness / h;
                let dx = Vector3::from(ws.contact_dx[g * LANES + l]);
                let wd = Vector3::new(wd[0][l], wd[1][l], wd[2][l]);
                let mut count = 0;
                let mut force = Vector3::zeros();
                for (p, plane) in self.planes.iter().enumerate() {
                    let cap = plane.friction() * start.normal_force[j * n_planes + p];
                    if cap <= 0.0 {
                        continue;
                    }
                    let nrm = plane.normal();
                    let delta = dx - nrm * nrm.dot(&dx);
                    let slip = delta.norm();
                    if c * slip <= cap {
                        continue;
                    }
                    let t = delta / slip;
                    let moved = delta + wd - nrm * nrm.dot(&wd);
                    if t.dot(&moved) >= cap / c {
                        continue;
                    }
                    let b = nrm.cross(&t);
                    let (st, sb) = (c.sqrt(), (c - cap / slip).max(0.0).sqrt());
                    ws.contact_coef[count] = [st * t.x, st * t.y, st * t.z];
                    ws.contact_coef[count + 1] = [sb * b.x, sb * b.y, sb * b.z];
                    count += 2;
                    force += t * (c * slip - cap);
                }
                if count > 0 {
                    let f: &[f64; 3] = force.as_slice().try_into().expect("3 components");
                    let wj = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
                    combine_rows::<M, 3>(wj, &ws.contact_coef[..count], &mut ws.contact_rows[rows * n..], f, rhs);
                    rows += count;
                }
            }
        }
        rows
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
        let rest = vec![0.0; self.n];
        let mut hess = std::mem::take(&mut ws.hess);
        self.elastic_hessian(&rest, ws, &mut hess, None);
        ws.hess = hess;
    }
}

struct EvaluateKernel<'a> {
    sys: &'a ReducedSystem,
    start: &'a StepStart,
    q: &'a [f64],
    model: Option<&'a ElasticModel<'a>>,
    ws: Option<&'a mut Workspace>,
}

impl WithMadd for EvaluateKernel<'_> {
    type Output = (f64, f64);
    #[inline(always)]
    fn run<M: Madd>(self) -> (f64, f64) {
        self.sys.evaluate_impl::<M>(self.start, self.q, self.model, self.ws)
    }
}

struct ElasticRowsKernel<'a> {
    sys: &'a ReducedSystem,
    q: &'a [f64],
    split: bool,
    range: std::ops::Range<usize>,
    ws: &'a mut Workspace,
}

impl WithMadd for ElasticRowsKernel<'_> {
    type Output = (usize, usize);
    #[inline(always)]
    fn run<M: Madd>(self) -> (usize, usize) {
        self.sys.elastic_rows_impl::<M>(self.q, self.split, self.range, self.ws)
    }
}

struct ContactRowsKernel<'a> {
    sys: &'a ReducedSystem,
    start: &'a StepStart,
    q: &'a [f64],
    ws: &'a mut Workspace,
}

impl WithMadd for ContactRowsKernel<'_> {
    type Output = usize;
    #[inline(always)]
    fn run<M: Madd>(self) -> usize {
        self.sys.contact_rows_impl::<M>(self.start, self.q, self.ws)
    }
}

struct ContactUpdateKernel<'a> {
    sys: &'a ReducedSystem,
    ws: &'a mut Workspace,
    state: &'a mut ContactHessian,
    rebuild: bool,
}

impl WithMadd for ContactUpdateKernel<'_> {
    type Output = (usize, usize, usize);
    #[inline(always)]
    fn run<M: Madd>(self) -> (usize, usize, usize) {
        self.sys.update_contact_impl::<M>(self.ws, self.state, self.rebuild)
    }
}

struct BeginKernel<'a> {
    sys: &'a ReducedSystem,
    q: &'a [f64],
    qdot: &'a [f64],
    start: &'a mut StepStart,
}

impl WithMadd for BeginKernel<'_> {
    type Output = ();
    #[inline(always)]
    fn run<M: Madd>(self) {
        self.sys.begin_impl::<M>(self.q, self.qdot, self.start)
    }
}

struct StickKernel<'a> {
    sys: &'a ReducedSystem,
    start: &'a StepStart,
    dir: &'a [f64],
    ws: &'a mut Workspace,
    rhs: &'a mut [f64],
}

impl WithMadd for StickKernel<'_> {
    type Output = usize;
    #[inline(always)]
    fn run<M: Madd>(self) -> usize {
        self.sys.stick_impl::<M>(self.start, self.dir, self.ws, self.rhs)
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
    fn incremental_contact_hessian_matches_a_fresh_one() {
        let model = small_block(4, 9, 40);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let (start, q0, qdot) = sliding_start(&model, &sys);
        let n = sys.n_dofs();
        let h = model.scene.dt;
        let mut ws = sys.workspace();
        let mut exact = sys.contact_hessian_state(false);
        let mut fresh = vec![0.0; n * n];
        let mut rng = Rng::new(21);
        // A walk through slipping, sticking, lifted and sunk states.
        for step in 0..30 {
            let s = [1.0, 0.0, 1e-3, 0.5][step % 4];
            let mut q: Vec<f64> = (0..n).map(|i| q0[i] + s * h * qdot[i] + 1e-6 * rng.uniform()).collect();
            q[11] += [0.0, -2e-5, 3e-4, 1e-5][step % 4];
            sys.evaluate(&start, &q, true, &mut ws);
            sys.update_contact_hessian(&mut ws, &mut exact);
            sys.contact_hessian(&start, &q, &mut ws, &mut fresh);
            assert!(rel_err(exact.matrix(), &fresh, 1e-9) < 1e-10, "step {step}: {}", rel_err(exact.matrix(), &fresh, 1e-9));
        }
    }

    #[test]
    fn contact_model_matches_the_energy_to_second_order() {
        let model = small_block(3, 11, 9);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let (start, q0, qdot) = sliding_start(&model, &sys);
        let n = sys.n_dofs();
        let q: Vec<f64> = (0..n).map(|i| q0[i] + model.scene.dt * qdot[i]).collect();
        let mut ws = sys.workspace();
        let e = sys.evaluate(&start, &q, true, &mut ws);
        let mut g_el = vec![0.0; n];
        ws.elastic_gradient(&mut g_el);
        let grad = ws.grad.clone();
        let e_el = ws.elastic_energy;
        let mut k_el = vec![0.0; n * n];
        let mut clamped = vec![0.0; n * n];
        sys.elastic_hessian(&q, &mut ws, &mut k_el, Some(&mut clamped));
        for (k, c) in k_el.iter_mut().zip(&clamped) {
            *k -= c;
        }
        let m = ElasticModel { origin: &q, energy: e_el, gradient: &g_el, hessian: &k_el };
        // Same value and gradient at the expansion point.
        assert!((sys.evaluate_model(&start, &q, &m, true, &mut ws) - e).abs() < 1e-14 * e.abs().max(1.0));
        assert!(rel_err(&ws.grad, &grad, 1e-9) < 1e-12);
        // Its gradient is that of its energy, and it follows E to second order.
        let mut rng = Rng::new(5);
        let dir: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
        let at = |t: f64| -> Vec<f64> { q.iter().zip(&dir).map(|(x, d)| x + t * 1e-4 * d).collect() };
        let p = at(1.0);
        sys.evaluate_model(&start, &p, &m, true, &mut ws);
        let fd = fd_gradient(|x| sys.evaluate_model(&start, x, &m, false, &mut sys.workspace()), &p, 1e-8);
        assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "model gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
        let mut gap = |t: f64| {
            let x = at(t);
            (sys.evaluate(&start, &x, false, &mut ws) - sys.evaluate_model(&start, &x, &m, false, &mut ws)).abs()
        };
        // Third order: halving the step divides the gap by about 8.
        let (g1, g2) = (gap(1.0), gap(0.5));
        assert!(g2 < g1 / 5.0 || g1 < 1e-15, "model gap {g1} -> {g2}");
    }

    #[test]
    fn stick_switch_flags_points_carried_through_the_stick_region() {
        let model = small_block(2, 5, 16);
        let sys = ReducedSystem::new(&model.inputs()).unwrap();
        let (start, q0, qdot) = sliding_start(&model, &sys);
        let n = sys.n_dofs();
        let h = model.scene.dt;
        // Slipping along +x; a step that reverses the slip switches every
        // slipping point, one that carries it on switches none.
        let q: Vec<f64> = (0..n).map(|i| q0[i] + h * qdot[i]).collect();
        assert!(regimes(&model, &sys, &start, &q).1 > 0);
        let mut ws = sys.workspace();
        let mut rhs = vec![0.0; n];
        let mut back = vec![0.0; n];
        back[9] = -2.0 * h * qdot[9];
        sys.evaluate(&start, &q, true, &mut ws);
        let rows = sys.stick_switch(&start, &back, &mut ws, &mut rhs);
        assert_eq!(rows, 2 * regimes(&model, &sys, &start, &q).1);
        assert!(rhs[9] > 0.0, "stick force minus slip force opposes the slip");
        let mut on = vec![0.0; n];
        on[9] = 0.5 * h * qdot[9];
        let mut rhs = vec![0.0; n];
        assert_eq!(sys.stick_switch(&start, &on, &mut ws, &mut rhs), 0);
        assert!(rhs.iter().all(|r| *r == 0.0));
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
