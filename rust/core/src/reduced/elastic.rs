//! The elastic term `sum_k w_k Psi(F_k(q))` (stable Neo-Hookean at the
//! cubature points, `vec(F_k) = vec(I) + G_k q`): energy, gradient, and the
//! square-root rows of its Hessian ([`ElasticTerm`], used by the world-frame
//! system and, by rotation invariance `Psi(R F) = Psi(F)`, as it is by the
//! body-frame one); and the quadratic stand-in for it used by the contact model.
//!
//! **Hessian.** The elastic part is `B^T B`, where B stacks, per cubature
//! point, `sqrt(w_k lambda_i) e_i^T G_k` for the positive eigenpairs of the SNH
//! Hessian (negative ones, with `|lambda_i|`, go into a second stack N, so that
//! the exact elastic Hessian is `B^T B - N^T N`). The rows are written eight at
//! a time (one per lane) into a column-major stack of cache size and multiplied
//! chunk by chunk by faer's blocked symmetric kernels.
//!
//! **Material damping.** With a viscosity eta the term adds, per point, the
//! Kelvin-Voigt dissipation of the Green strain's rate, read with the
//! integrator's formula (as `python/licrom/full/damping.py` does per tet):
//! `w_k eta/(2h') |D_k|^2`, `D_k = (F_k^T F_k - C_k)/2`, with the anchor
//! `C_k = (1 + w) C(q_n) - w C(q_{n-1})` (`C = F^T F`, w the integrator's history
//! weight: `E_a = E_n` for backward Euler, `(4 E_n - E_{n-1})/3` for BDF2;
//! [`StrainAnchor`]). Its stress is `kappa F D` (`kappa = eta/h'`) and
//! its Hessian's Gauss-Newton part `w kappa (dD/dF)^T (dD/dF)` adds six square-root
//! rows per point (`sqrt(w kappa) dD_ii/dF`, `sqrt(2 w kappa) dD_ij/dF`, i < j).
//! Rotation invariant, so the body frame's term is a function of q alone. An
//! evaluation without an anchor is the elastic energy alone.

use crate::validity::{lowest_dets, Validity};
use faer::Accum;

use crate::dense::{mirror_lower, offset_rows_dot, syrk_columns};
use crate::error::{check_finite, check_non_negative, LicromError, Result};
use crate::material::StableNeoHookean;
use crate::real::{Lanes, Real, LANES};
use crate::simd::{dispatch, lane_sum, Madd, WithMadd, F8};

use super::layout::{kept_points, lanes_at, widened_at, CubatureLayout, VertexLayout, VertexStrainInputs};

mod anchor;
pub use anchor::StrainAnchor;

/// Borrowed description of the elastic term; arrays row-major (C order).
#[derive(Debug, Clone, Copy)]
pub struct ElasticInputs<'a> {
    /// `G_k = dvec(F)/dq` at the K cubature points, K x 9 x n.
    pub cubature_jacobians: &'a [f64],
    /// Cubature weights w_k >= 0, K, m^3.
    pub cubature_weights: &'a [f64],
    /// The same Jacobians as the linear-tet gradient of vertex values, where
    /// they are that (the `"mesh"` strain): energy and gradient then go
    /// through the vertices when that is cheaper ([`VertexStrainInputs`]).
    pub vertex_strain: Option<VertexStrainInputs<'a>>,
    /// Material of the solid.
    pub material: StableNeoHookean,
    /// Kelvin-Voigt viscosity eta, Pa s, >= 0 (0: no material damping).
    pub viscosity: f64,
}

/// Validated, owned elastic term over n reduced coordinates.
#[derive(Debug, Clone)]
pub struct ElasticTerm {
    n: usize,
    /// Number of cubature points given (zero weights included).
    n_cubature: usize,
    /// The cubature points of positive weight, packed by lanes.
    cubature: CubatureLayout,
    /// Their vertex form, where given and cheaper than the Jacobians for the
    /// energy and gradient (the Hessian always uses the Jacobians).
    pub(super) vertices: Option<VertexLayout>,
    material: StableNeoHookean,
    /// `eta / h'`, Pa: the damping's weight (0 without damping).
    kappa: f64,
}

/// The symmetric components `(i, j)` of the damping's six square-root rows, in
/// the order `StrainAnchor` stores `C`.
const SYM: [(usize, usize); 6] = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];

/// Preallocated buffers of the elastic term's evaluations.
#[derive(Debug, Clone)]
pub struct ElasticWorkspace {
    /// The elastic gradient of the last evaluation with gradient, n.
    gradient: Vec<f64>,
    /// Smallest `det F` at the cubature points of the last evaluation with
    /// gradient (+inf without any).
    min_det: f64,
    /// Square-root rows of `chunk` groups of cubature points at a time,
    /// column-major with column stride `row_stride`: positive ones in `rows`,
    /// clamped ones in `clamped_rows`.
    rows: Vec<f64>,
    clamped_rows: Vec<f64>,
    row_stride: usize,
    chunk: usize,
    /// Per-lane partial sums of the gradient: one per varying column of G,
    /// then the nine components of `sum_k w_k P_k` (for the constant ones).
    lane_grad: Vec<F8>,
    /// Vertex displacements `u_v` and vertex forces of the vertex form of the
    /// cubature (3 per used vertex; empty without it).
    vertex_u: Vec<f64>,
    vertex_force: Vec<f64>,
}

impl ElasticWorkspace {
    /// The elastic gradient of the last evaluation with gradient, n.
    pub fn gradient(&self) -> &[f64] {
        &self.gradient
    }

    /// Smallest `det F` at the cubature points of the last evaluation with gradient.
    pub fn min_det(&self) -> f64 {
        self.min_det
    }
}

impl ElasticTerm {
    /// Validates and packs the inputs for n reduced coordinates and a step's
    /// effective length `effective_step` h' (s): consistent sizes, finite values,
    /// non-negative weights and viscosity, a vertex form that reproduces the
    /// Jacobians.
    pub fn new(inp: &ElasticInputs<'_>, n: usize, effective_step: f64) -> Result<Self> {
        check_non_negative("viscosity", inp.viscosity)?;
        let k = inp.cubature_weights.len();
        if inp.cubature_jacobians.len() != k * 9 * n {
            return Err(LicromError::shape("cubature_jacobians", format!("({k}, 9, {n})"), format!("{} values", inp.cubature_jacobians.len())));
        }
        check_finite("cubature_jacobians", inp.cubature_jacobians)?;
        check_finite("cubature_weights", inp.cubature_weights)?;
        if let Some(w) = inp.cubature_weights.iter().find(|w| **w < 0.0) {
            return Err(LicromError::invalid("cubature_weights", format!("must be >= 0, found {w}")));
        }
        let kept = kept_points(inp.cubature_weights);
        let vertices = match &inp.vertex_strain {
            Some(vs) => Some(VertexLayout::new(vs, inp.cubature_jacobians, &kept, k, n)?),
            None => None,
        };
        // Per point the Jacobians cost 9 n multiply-adds each way, the vertex form 3 n per used vertex.
        let vertices = vertices.filter(|v| 3 * v.n_vertices(n) < 9 * kept.len());
        Ok(Self {
            n,
            n_cubature: k,
            cubature: CubatureLayout::new(inp.cubature_jacobians, inp.cubature_weights, &kept, n),
            vertices,
            material: inp.material,
            kappa: inp.viscosity / effective_step,
        })
    }

    /// Whether the term has a material damping (it then needs a [`StrainAnchor`]).
    pub fn damped(&self) -> bool {
        self.kappa > 0.0
    }

    /// Number of cubature points K.
    pub fn n_cubature(&self) -> usize {
        self.n_cubature
    }

    /// Buffers for the evaluations.
    pub fn workspace(&self) -> ElasticWorkspace {
        let n = self.n;
        // Chunks of rows of about 256 KiB: they stay in cache between being
        // written and being multiplied. Per point: nine eigenmodes, and the damping's six rows.
        let per_point = if self.damped() { 15 } else { 9 };
        let chunk = (256 * 1024 / (per_point * LANES * 8 * n)).clamp(1, self.cubature.groups().max(1));
        let row_stride = per_point * LANES * chunk;
        let vertices = self.vertices.as_ref().map_or(0, |v| 3 * v.n_vertices(n));
        ElasticWorkspace {
            gradient: vec![0.0; n],
            min_det: f64::INFINITY,
            rows: vec![0.0; row_stride * n],
            clamped_rows: vec![0.0; row_stride * n],
            row_stride,
            chunk,
            lane_grad: vec![[0.0; LANES]; self.cubature.var_cols.len() + 9],
            vertex_u: vec![0.0; vertices],
            vertex_force: vec![0.0; vertices],
        }
    }

    /// The elastic energy at `q` (J), plus the damping's against `anchor`
    /// where given, and, with `ws`, its gradient and the smallest `det F` into `ws`.
    pub fn evaluate(&self, q: &[f64], anchor: Option<&StrainAnchor>, ws: Option<&mut ElasticWorkspace>) -> f64 {
        dispatch(ElasticKernel { term: self, q, anchor, ws })
    }

    /// The anchor's six components of group `g`, where the term is damped and `anchor` given.
    #[inline(always)]
    fn anchor_of<'a>(&self, anchor: Option<&'a StrainAnchor>, g: usize) -> Option<&'a [F8]> {
        anchor.filter(|_| self.damped()).map(|a| a.group(g))
    }

    /// Adds the damping's energy density and stress (both per unit weight) at
    /// the lanes' `f` against their anchor `c` to `psi` and `p`.
    #[inline(always)]
    fn add_damping(&self, f: &[F8; 9], c: &[F8], psi: &mut F8, p: &mut [F8; 9]) {
        let k = self.kappa;
        for l in 0..LANES {
            let mut d = [[0.0; 3]; 3];
            for (&(i, j), cij) in SYM.iter().zip(c) {
                let v = 0.5 * (f[i][l] * f[j][l] + f[3 + i][l] * f[3 + j][l] + f[6 + i][l] * f[6 + j][l] - cij[l]);
                d[i][j] = v;
                d[j][i] = v;
            }
            let dd: f64 = d.iter().flatten().map(|v| v * v).sum();
            psi[l] += 0.5 * k * dd;
            for a in 0..3 {
                for b in 0..3 {
                    p[3 * a + b][l] += k * (f[3 * a][l] * d[0][b] + f[3 * a + 1][l] * d[1][b] + f[3 * a + 2][l] * d[2][b]);
                }
            }
        }
    }

    /// The damping's six square-root rows' coefficients (in vec F, row-major) at
    /// the lanes' `f` with weights `weights`, into `coef[..6]`.
    #[inline(always)]
    fn damping_rows(&self, f: &[F8; 9], weights: &[f64], coef: &mut [[F8; 9]; 9]) {
        for (row, &(i, j)) in coef.iter_mut().zip(&SYM) {
            for l in 0..LANES {
                let s = (if i == j { 1.0 } else { 2.0 } * weights[l] * self.kappa).sqrt();
                // dD_ij/dF_ab = (delta_bi F_aj + F_ai delta_bj)/2.
                for a in 0..3 {
                    for b in 0..3 {
                        let mut v = 0.0;
                        if b == i {
                            v += f[3 * a + j][l];
                        }
                        if b == j {
                            v += f[3 * a + i][l];
                        }
                        row[3 * a + b][l] = 0.5 * s * v;
                    }
                }
            }
        }
    }
}

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

impl ElasticModel<'_> {
    /// The model's energy at `q`, and its gradient added to `grad` when given.
    #[inline(always)]
    pub(crate) fn evaluate<M: Madd>(&self, q: &[f64], mut grad: Option<&mut [f64]>) -> f64 {
        let mut em = self.energy;
        offset_rows_dot::<M>(self.hessian, q, self.origin, |i, kd| {
            em = M::madd(q[i] - self.origin[i], self.gradient[i] + 0.5 * kd, em);
            if let Some(g) = grad.as_deref_mut() {
                g[i] += self.gradient[i] + kd;
            }
        });
        em
    }
}

/// Adds the elastic gradient held per lane in `lane_grad` (varying columns,
/// then the nine components of the summed stress) to `out` (n).
pub(super) fn reduce_lane_gradient(lane_grad: &[F8], var_cols: &[usize], const_cols: &[(usize, [f64; 9])], out: &mut [f64]) {
    for (a, &c) in lane_grad.iter().zip(var_cols) {
        out[c] += lane_sum(a);
    }
    let nv = var_cols.len();
    let stress: [f64; 9] = std::array::from_fn(|a| lane_sum(&lane_grad[nv + a]));
    for (c, v) in const_cols {
        out[*c] += (0..9).map(|a| v[a] * stress[a]).sum::<f64>();
    }
}

/// Writes the combinations `sum_a coef[b][a] gs[a]` (for the first `count`
/// modes b of each coefficient set, eight lanes each) into column `at` of the
/// positive and clamped row stacks, from row `base` on. All nine combinations
/// are formed at once: nine independent multiply-add chains reuse each lane
/// block of G.
#[inline(always)]
fn write_rows<M: Madd>(at: usize, gs: &[F8; 9], coefs: [&[[F8; 9]; 9]; 2], counts: [(usize, usize); 2], outs: [&mut Vec<f64>; 2]) {
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

/// `u_v` of used vertex v from displacements stored three per vertex.
#[inline(always)]
pub(super) fn stored_displacement(u: &[f64], v: usize) -> [f64; 3] {
    [u[3 * v], u[3 * v + 1], u[3 * v + 2]]
}

impl ElasticTerm {
    /// Elastic energy and, with `ws`, its gradient and smallest `det F` into
    /// `ws`: through the vertices where the term has their form, else through
    /// the Jacobians.
    #[inline(always)]
    pub(crate) fn evaluate_impl<M: Madd>(&self, q: &[f64], anchor: Option<&StrainAnchor>, ws: Option<&mut ElasticWorkspace>) -> f64 {
        match &self.vertices {
            Some(vertices) => self.elastic_vertices::<M>(vertices, q, anchor, ws),
            None => self.elastic_points::<M>(q, anchor, ws),
        }
    }

    /// [`Self::evaluate_impl`] through the Jacobians, eight points at a time;
    /// the gradient into `ws.gradient`.
    #[inline(always)]
    fn elastic_points<M: Madd>(&self, q: &[f64], anchor: Option<&StrainAnchor>, ws: Option<&mut ElasticWorkspace>) -> f64 {
        let (lane_grad, grad, min_det): (&mut [F8], &mut [f64], _) = match ws {
            Some(ws) => (&mut ws.lane_grad[..], &mut ws.gradient[..], Some(&mut ws.min_det)),
            None => (&mut [][..], &mut [][..], None),
        };
        let mut low = [f64::INFINITY; LANES];
        let cub = &self.cubature;
        let nv = cub.var_cols.len();
        let with_gradient = !grad.is_empty();
        if with_gradient {
            lane_grad.fill([0.0; LANES]);
        }
        let f0 = cub.constant_deformation(q);
        let mut elastic = [0.0; LANES];
        let group_len = cub.group_len();
        for (g, weights) in cub.weights.chunks_exact(LANES).enumerate() {
            let group = &cub.packed[g * group_len..(g + 1) * group_len];
            let f = cub.group_deformation::<M>(group, q, &f0);
            if with_gradient {
                lowest_dets(&f, weights, &mut low);
            }
            let (mut psi, mut p) = self.material.energy_stress_lanes::<M>(&f, true);
            if let Some(c) = self.anchor_of(anchor, g) {
                self.add_damping(&f, c, &mut psi, &mut p);
            }
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
                        v = M::madd8(&widened_at(g, a * LANES), &p[a], v);
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
        if let Some(min_det) = min_det {
            *min_det = lowest(&low);
        }
        if with_gradient {
            grad.fill(0.0);
            reduce_lane_gradient(lane_grad, &cub.var_cols, &cub.const_cols, grad);
        }
        lane_sum(&elastic)
    }

    /// [`Self::evaluate_impl`] through the vertices ([`VertexLayout`]): `u_v =
    /// W_v q` of the used vertices, each point's F from its tet's four, and the
    /// gradient `sum_v W_v^T f_v` from the vertex forces `f_v` of the points'
    /// stresses (into `ws.gradient`). Without `ws` the `u_v` are formed per
    /// point, by the same products, so the energy is the same to the last bit.
    #[inline(always)]
    fn elastic_vertices<M: Madd>(
        &self,
        vertices: &VertexLayout,
        q: &[f64],
        anchor: Option<&StrainAnchor>,
        mut ws: Option<&mut ElasticWorkspace>,
    ) -> f64 {
        let n = self.n;
        // Without a workspace (energy probes) the displacements go to a buffer of their own, formed by the same
        // product, so the energy is the same to the last bit.
        let mut own_u = Vec::new();
        let u = match ws.as_deref_mut() {
            Some(ws) => {
                vertices.displacements(q, n, &mut ws.vertex_u);
                ws.vertex_force.fill(0.0);
                None
            }
            None => {
                own_u.resize(3 * vertices.n_vertices(n), 0.0);
                vertices.displacements(q, n, &mut own_u);
                Some(&own_u[..])
            }
        };
        let track = ws.is_some();
        let mut low = [f64::INFINITY; LANES];
        let mut elastic = [0.0; LANES];
        for (g, weights) in self.cubature.weights.chunks_exact(LANES).enumerate() {
            let tets = &vertices.tets[g * 4 * LANES..(g + 1) * 4 * LANES];
            let grads = &vertices.grads[g * 12 * LANES..(g + 1) * 12 * LANES];
            let u = u.unwrap_or_else(|| &ws.as_deref().expect("a workspace where no own displacements").vertex_u);
            let f = vertices.group_deformation::<M>(g, |v| stored_displacement(u, v));
            if track {
                lowest_dets(&f, weights, &mut low);
            }
            let (mut psi, mut p) = self.material.energy_stress_lanes::<M>(&f, true);
            if let Some(c) = self.anchor_of(anchor, g) {
                self.add_damping(&f, c, &mut psi, &mut p);
            }
            for l in 0..LANES {
                elastic[l] = M::madd(weights[l], psi[l], elastic[l]);
            }
            let Some(ws) = ws.as_deref_mut() else { continue };
            for row in p.iter_mut() {
                for l in 0..LANES {
                    row[l] *= weights[l];
                }
            }
            for (t, vs) in tets.chunks_exact(LANES).enumerate() {
                for i in 0..3 {
                    let mut fi = [0.0; LANES];
                    for j in 0..3 {
                        fi = M::madd8(&p[3 * i + j], lanes_at(grads, (3 * t + j) * LANES), fi);
                    }
                    for (l, &v) in vs.iter().enumerate() {
                        ws.vertex_force[3 * v as usize + i] += fi[l];
                    }
                }
            }
        }
        if let Some(ws) = ws {
            ws.min_det = lowest(&low);
            vertices.pull_back(&ws.vertex_force, n, &mut ws.gradient);
        }
        lane_sum(&elastic)
    }

    /// Elastic part of the Hessian at `q`: the PSD projection (negative
    /// eigenvalues of every point's SNH Hessian clamped to zero), plus the
    /// damping's Gauss-Newton part where the term is damped, into `projected`, and what the clamping removed (PSD) into `clamped` when
    /// given, both n x n full symmetric. Returns whether anything was clamped.
    pub fn hessian(&self, q: &[f64], ws: &mut ElasticWorkspace, projected: &mut [f64], mut clamped: Option<&mut [f64]>) -> bool {
        let n = self.n;
        let split = clamped.is_some();
        projected.fill(0.0);
        if let Some(c) = clamped.as_deref_mut() {
            c.fill(0.0);
        }
        let mut any_clamped = false;
        let groups = self.cubature.groups();
        for first in (0..groups).step_by(ws.chunk) {
            let range = first..groups.min(first + ws.chunk);
            let (positive, negative) = dispatch(ElasticRowsKernel { term: self, q, split, range, ws: &mut *ws });
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
    fn elastic_rows_impl<M: Madd>(&self, q: &[f64], split: bool, range: std::ops::Range<usize>, ws: &mut ElasticWorkspace) -> (usize, usize) {
        let cub = &self.cubature;
        let stride = ws.row_stride;
        let group_len = cub.group_len();
        let f0 = cub.constant_deformation(q);
        let (mut positive, mut negative) = (0, 0);
        let mut values = [Lanes::splat(0.0); 9];
        let mut vectors = [[Lanes::splat(0.0); 9]; 9];
        let mut pos_coef = [[[0.0; LANES]; 9]; 9];
        let mut neg_coef = [[[0.0; LANES]; 9]; 9];
        let mut damp_coef = [[[0.0; LANES]; 9]; 9];
        let packed = &cub.packed[range.start * group_len..range.end * group_len];
        let packed_weights = &cub.weights[range.start * LANES..range.end * LANES];
        for (g, weights) in packed_weights.chunks_exact(LANES).enumerate() {
            let group = &packed[g * group_len..(g + 1) * group_len];
            let f = cub.group_deformation::<M>(group, q, &f0);
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
            for (g, &c) in group.chunks_exact(9 * LANES).zip(&cub.var_cols) {
                let mut gs = [[0.0; LANES]; 9];
                for a in 0..9 {
                    gs[a] = widened_at(g, a * LANES);
                }
                write_rows::<M>(c * stride, &gs, [&pos_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
            }
            for (c, v) in &cub.const_cols {
                write_rows::<M>(*c * stride, &v.map(|x| [x; LANES]), [&pos_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
            }
            positive += n_pos * LANES;
            negative += n_neg * LANES;
            if self.damped() {
                self.damping_rows(&f, weights, &mut damp_coef);
                let counts = [(6, positive), (0, 0)];
                for (g, &c) in group.chunks_exact(9 * LANES).zip(&cub.var_cols) {
                    let gs = std::array::from_fn(|a| widened_at(g, a * LANES));
                    write_rows::<M>(c * stride, &gs, [&damp_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
                }
                for (c, v) in &cub.const_cols {
                    write_rows::<M>(*c * stride, &v.map(|x| [x; LANES]), [&damp_coef, &neg_coef], counts, [&mut ws.rows, &mut ws.clamped_rows]);
                }
                positive += 6 * LANES;
            }
        }
        (positive, negative)
    }
}

/// The smallest `det F` of [`lowest_dets`]' lanes (+inf where none was lowered).
fn lowest(low: &F8) -> f64 {
    let mut v = Validity::default();
    v.take_lanes(low);
    v.min_det
}

struct ElasticRowsKernel<'a> {
    term: &'a ElasticTerm,
    q: &'a [f64],
    split: bool,
    range: std::ops::Range<usize>,
    ws: &'a mut ElasticWorkspace,
}

impl WithMadd for ElasticRowsKernel<'_> {
    type Output = (usize, usize);
    #[inline(always)]
    fn run<M: Madd>(self) -> (usize, usize) {
        self.term.elastic_rows_impl::<M>(self.q, self.split, self.range, self.ws)
    }
}

struct ElasticKernel<'a> {
    term: &'a ElasticTerm,
    q: &'a [f64],
    anchor: Option<&'a StrainAnchor>,
    ws: Option<&'a mut ElasticWorkspace>,
}

impl WithMadd for ElasticKernel<'_> {
    type Output = f64;
    #[inline(always)]
    fn run<M: Madd>(self) -> f64 {
        self.term.evaluate_impl::<M>(self.q, self.anchor, self.ws)
    }
}
