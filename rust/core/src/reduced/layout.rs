//! Packing of the per-point data in groups of [`LANES`] points.
//!
//! The cubature Jacobians of the points with `w_k > 0` (points of zero weight
//! are dropped) are stored in groups of [`LANES`] points, each group as
//! `[i][a][lane]` (column i of `G_k`, component a of `vec(F)`). One pass over a
//! group forms the eight deformation gradients with vertical multiply-adds
//! (`F[a][lane] += G[i][a][lane] q_i`, no horizontal sums), the stress and energy
//! run eight points per instruction, and the gradient `G_k^T P_k` accumulates
//! per lane until one final reduction. Columns of G that are the same at every
//! point (the affine modes: a linear map of X has the same gradient
//! everywhere) are factored out: they add a constant to every F, and their
//! gradient is one product with the summed stress. Contact points are packed
//! the same way (`W_j` as `[i][c][lane]`, plus their normal rows `n_p^T W_j`):
//! the gaps of eight points cost one pass over the normal rows, and only groups
//! with a point that touches a plane or carries a lagged normal force go on to
//! positions, contact terms and gradient.
//!
//! **G in f32.** The varying columns of G are stored in single precision and
//! widened as they are loaded. At n = 32 the pass is compute bound (30-40 ns
//! per point whether K is 100 or 5000), but at n = 66 and K = 1000 the f64
//! Jacobians take 4.3 MB, twice the 2 MB L2 of one core, and the pass waits on
//! L3; f32 storage halves that (measured: docs/results.md section 8, "Solver choices, measured"). The rounding
//! (relative 6e-8, far below the discretisation error) is the model: energy,
//! gradient and Hessian all use the same rounded G (the constant columns are
//! rounded alike), so they stay consistent and Newton converges as before.

use nalgebra::Vector3;

use crate::contact::Plane;
use crate::error::{check_finite, LicromError, Result};
use crate::real::LANES;
use crate::second_thread::product_by_rows;
use crate::simd::{Madd, F8};
use faer::{Accum, MatMut, MatRef};

/// The eight values of `s` from `at`.
#[inline(always)]
pub(super) fn lanes_at(s: &[f64], at: usize) -> &F8 {
    s[at..at + LANES].try_into().expect("eight lanes")
}

/// The eight values of `s` from `at`, widened to f64.
#[inline(always)]
pub(super) fn widened_at(s: &[f32], at: usize) -> F8 {
    let v: &[f32; LANES] = s[at..at + LANES].try_into().expect("eight lanes");
    v.map(f64::from)
}

/// The points of positive weight, in packing order.
pub(super) fn kept_points(weights: &[f64]) -> Vec<usize> {
    (0..weights.len()).filter(|&i| weights[i] > 0.0).collect()
}

/// The cubature Jacobians `G_k` of the points with `w_k > 0`, packed by lanes.
#[derive(Debug, Clone)]
pub(super) struct CubatureLayout {
    /// Columns of G that differ between cubature points, and the columns that
    /// are the same non-zero 9-vector at every point (the affine modes: a linear
    /// map of X has the same gradient everywhere) with that vector. Columns that
    /// are zero everywhere (translations) appear in neither.
    pub(super) var_cols: Vec<usize>,
    pub(super) const_cols: Vec<(usize, [f64; 9])>,
    /// The varying columns of the Jacobians, in groups of LANES points, group g
    /// at `g group_len()` as `[i][a][lane]`; the last group is padded with
    /// G = 0, w = 0.
    pub(super) packed: Vec<f32>,
    /// Weights of the packed points, `LANES` per group, m^3.
    pub(super) weights: Vec<f64>,
}

impl CubatureLayout {
    /// Packs the K x 9 x n Jacobians (row-major) of the points of positive
    /// weight (`kept`, from [`kept_points`]).
    pub(super) fn new(jacobians: &[f64], weights: &[f64], kept: &[usize], n: usize) -> Self {
        let column = |point: usize, c: usize| -> [f64; 9] { std::array::from_fn(|a| f64::from(jacobians[9 * n * point + a * n + c] as f32)) };
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
        let mut packed = vec![0.0f32; groups * nv * 9 * LANES];
        let mut packed_weights = vec![0.0; groups * LANES];
        for (slot, &point) in kept.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            packed_weights[slot] = weights[point];
            let src = &jacobians[9 * n * point..9 * n * (point + 1)];
            let dst = &mut packed[g * nv * 9 * LANES..(g + 1) * nv * 9 * LANES];
            for (iv, &c) in var_cols.iter().enumerate() {
                for a in 0..9 {
                    dst[(iv * 9 + a) * LANES + l] = src[a * n + c] as f32;
                }
            }
        }
        Self { var_cols, const_cols, packed, weights: packed_weights }
    }

    /// Number of groups of LANES points.
    pub(super) fn groups(&self) -> usize {
        self.weights.len() / LANES
    }

    /// Values per packed group.
    pub(super) fn group_len(&self) -> usize {
        self.var_cols.len() * 9 * LANES
    }

    /// `vec(I) + sum_c v_c q_c` over the constant columns of G.
    #[inline(always)]
    pub(super) fn constant_deformation(&self, q: &[f64]) -> [f64; 9] {
        let mut f0 = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        for (c, v) in &self.const_cols {
            for a in 0..9 {
                f0[a] += v[a] * q[*c];
            }
        }
        f0
    }

    /// The eight deformation gradients of a packed group, `F[a][lane]`: `f0`
    /// (identity plus the constant columns' part) plus the varying columns.
    #[inline(always)]
    pub(super) fn group_deformation<M: Madd>(&self, group: &[f32], q: &[f64], f0: &[f64; 9]) -> [F8; 9] {
        let mut f = [[0.0; LANES]; 9];
        for a in 0..9 {
            f[a] = [f0[a]; LANES];
        }
        for (g, &c) in group.chunks_exact(9 * LANES).zip(&self.var_cols) {
            let qc = q[c];
            for a in 0..9 {
                f[a] = M::madd8_splat(qc, &widened_at(g, a * LANES), f[a]);
            }
        }
        f
    }
}

/// The contact points with a non-zero area, packed by lanes.
#[derive(Debug, Clone)]
pub(super) struct ContactLayout {
    n: usize,
    n_planes: usize,
    /// Basis rows `W_j` of those points in groups of LANES, group g at
    /// `g n 3 LANES` as `[i][c][lane]`, and their rest positions `[g][c][lane]`.
    basis: Vec<f64>,
    rest: Vec<f64>,
    /// Normal rows `n_p^T W_j` of those points in groups of LANES: group g and
    /// plane p at `(g P + p) n LANES`, as `[i][lane]`.
    normal_rows: Vec<f64>,
    /// `n_p . X_j + d_p` at `(g P + p) LANES + lane` (+inf in padding lanes), so
    /// that `gap = offset + row . q`.
    normal_offsets: Vec<f64>,
}

impl ContactLayout {
    /// Packs the C x 3 x n basis rows and C x 3 rest positions (row-major) of
    /// the points `points` (those with a non-zero area, the others carry no
    /// force), in that order.
    pub(super) fn new(basis: &[f64], rest: &[f64], points: &[usize], planes: &[Plane], n: usize) -> Self {
        let n_planes = planes.len();
        let groups = points.len().div_ceil(LANES);
        let mut normal_rows = vec![0.0; groups * n_planes * n * LANES];
        let mut normal_offsets = vec![f64::INFINITY; groups * n_planes * LANES];
        for (slot, &j) in points.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            let w = &basis[3 * n * j..3 * n * (j + 1)];
            for (p, plane) in planes.iter().enumerate() {
                let at = g * n_planes + p;
                let nrm = plane.normal();
                let x0 = Vector3::from_column_slice(&rest[3 * j..3 * j + 3]);
                normal_offsets[at * LANES + l] = plane.gap(&x0);
                for i in 0..n {
                    normal_rows[(at * n + i) * LANES + l] = nrm.x * w[i] + nrm.y * w[n + i] + nrm.z * w[2 * n + i];
                }
            }
        }
        let mut packed = vec![0.0; groups * n * 3 * LANES];
        let mut rest_packed = vec![0.0; groups * 3 * LANES];
        for (slot, &j) in points.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            for c in 0..3 {
                rest_packed[(g * 3 + c) * LANES + l] = rest[3 * j + c];
                for i in 0..n {
                    packed[((g * n + i) * 3 + c) * LANES + l] = basis[3 * n * j + c * n + i];
                }
            }
        }
        Self { n, n_planes, basis: packed, rest: rest_packed, normal_rows, normal_offsets }
    }

    /// The packed basis rows of group `g`, `[i][c][lane]`.
    #[inline(always)]
    pub(super) fn group_basis(&self, g: usize) -> &[f64] {
        let n = self.n;
        &self.basis[g * n * 3 * LANES..(g + 1) * n * 3 * LANES]
    }

    /// Gaps of the eight contact points of group `g` to plane `p` at `q`.
    #[inline(always)]
    pub(super) fn group_gap<M: Madd>(&self, g: usize, p: usize, q: &[f64]) -> F8 {
        let n = self.n;
        let at = g * self.n_planes + p;
        let rows = &self.normal_rows[at * n * LANES..(at + 1) * n * LANES];
        let mut gap = *lanes_at(&self.normal_offsets, at * LANES);
        for (i, &qi) in q.iter().enumerate() {
            gap = M::madd8_splat(qi, lanes_at(rows, i * LANES), gap);
        }
        gap
    }

    /// Positions `x[c][lane]` of the eight contact points of group `g` at `q`.
    #[inline(always)]
    pub(super) fn group_positions<M: Madd>(&self, g: usize, q: &[f64]) -> [F8; 3] {
        let rest = std::array::from_fn(|c| *lanes_at(&self.rest, (g * 3 + c) * LANES));
        self.group_combination::<M>(g, q, rest)
    }

    /// Motion `W_j d` of the eight contact points of group `g` along `d`, `[c][lane]`.
    #[inline(always)]
    pub(super) fn group_motion<M: Madd>(&self, g: usize, d: &[f64]) -> [F8; 3] {
        self.group_combination::<M>(g, d, [[0.0; LANES]; 3])
    }

    /// `start + W_j v` for the eight contact points of group `g`, `[c][lane]`.
    #[inline(always)]
    fn group_combination<M: Madd>(&self, g: usize, v: &[f64], start: [F8; 3]) -> [F8; 3] {
        let mut x = start;
        for (wi, &vi) in self.group_basis(g).chunks_exact(3 * LANES).zip(v) {
            for c in 0..3 {
                x[c] = M::madd8_splat(vi, lanes_at(wi, c * LANES), x[c]);
            }
        }
        x
    }
}

/// The cubature points' deformation gradients as the linear-tet gradient of
/// vertex values (the `"mesh"` strain): `F_k = I + sum_a u_{v_a} grad N_a^T`,
/// `u_v = W_v q`, the tet's four vertices v_a and shape gradients.
#[derive(Debug, Clone, Copy)]
pub struct VertexStrainInputs<'a> {
    /// Basis rows `W_v` at the mesh vertices, V x 3 x n.
    pub vertex_basis: &'a [f64],
    /// The four vertices of each cubature point's tet, K x 4 (indices into the V rows).
    pub tet_vertices: &'a [usize],
    /// Gradients of the tet's four linear shape functions, K x 4 x 3, 1/m.
    pub shape_gradients: &'a [f64],
}

/// [`VertexStrainInputs`] packed for the points of [`CubatureLayout`], in its
/// order: the rows `W_v` of the vertices that those tets use (renumbered), and
/// per group of LANES points their vertices `[a][lane]` and shape gradients
/// `[a][j][lane]` (padding lanes: vertex 0, zero gradients).
///
/// **Why.** `G_k` holds 9 n values per point; the vertex rows hold 3 n per
/// vertex, and the cubature tets of a mesh share their vertices (a tet mesh has
/// about five tets per vertex). So `u = W q` over the used vertices, F from
/// four of them per point, and the gradient `sum_v W_v^T f_v` from the
/// points' vertex forces take a fraction of the multiply-adds of `G_k q` and
/// `G_k^T P_k`, in f64 rows that fit in cache where the f32 Jacobians did
/// not (measured: docs/results.md section 8, "Solver choices, measured").
#[derive(Debug, Clone)]
pub(super) struct VertexLayout {
    /// `W_v` of the used vertices, U x 3 x n row-major.
    pub(super) basis: Vec<f64>,
    pub(super) tets: Vec<u32>,
    pub(super) grads: Vec<f64>,
}

impl VertexLayout {
    /// Packs the vertex data of the kept points (`kept`, in packing order) of
    /// the K given, after checking shapes, indices and finiteness; they must
    /// reproduce the given Jacobians (K x 9 x n) to a relative 1e-9 of their
    /// largest entry.
    pub(super) fn new(inp: &VertexStrainInputs<'_>, jacobians: &[f64], kept: &[usize], k: usize, n: usize) -> Result<Self> {
        if !inp.vertex_basis.len().is_multiple_of(3 * n) {
            return Err(LicromError::shape("cubature_vertex_basis", format!("(V, 3, {n})"), format!("{} values", inp.vertex_basis.len())));
        }
        let n_vertices = inp.vertex_basis.len() / (3 * n);
        if inp.tet_vertices.len() != 4 * k {
            return Err(LicromError::shape("cubature_tet_vertices", format!("({k}, 4)"), format!("{} values", inp.tet_vertices.len())));
        }
        if inp.shape_gradients.len() != 12 * k {
            return Err(LicromError::shape("cubature_shape_gradients", format!("({k}, 4, 3)"), format!("{} values", inp.shape_gradients.len())));
        }
        check_finite("cubature_vertex_basis", inp.vertex_basis)?;
        check_finite("cubature_shape_gradients", inp.shape_gradients)?;
        if let Some(v) = inp.tet_vertices.iter().find(|&&v| v >= n_vertices) {
            return Err(LicromError::invalid(
                "cubature_tet_vertices",
                format!("must be below the {n_vertices} rows of cubature_vertex_basis, found {v}"),
            ));
        }
        let scale = jacobians.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        for p in 0..k {
            for a in 0..9 {
                let (i, j) = (a / 3, a % 3);
                for c in 0..n {
                    let g: f64 = (0..4)
                        .map(|t| inp.vertex_basis[(3 * inp.tet_vertices[4 * p + t] + i) * n + c] * inp.shape_gradients[12 * p + 3 * t + j])
                        .sum();
                    if (g - jacobians[9 * n * p + a * n + c]).abs() > 1e-9 * scale {
                        return Err(LicromError::invalid(
                            "cubature_vertex_basis",
                            format!("with cubature_tet_vertices and cubature_shape_gradients must reproduce cubature_jacobians; point {p} differs"),
                        ));
                    }
                }
            }
        }
        // The used vertices, renumbered in order of first use.
        let mut local = vec![u32::MAX; n_vertices];
        let mut used = Vec::new();
        for &p in kept {
            for &v in &inp.tet_vertices[4 * p..4 * p + 4] {
                if local[v] == u32::MAX {
                    local[v] = used.len() as u32;
                    used.push(v);
                }
            }
        }
        let basis = used.iter().flat_map(|&v| inp.vertex_basis[3 * n * v..3 * n * (v + 1)].iter().copied()).collect();
        let groups = kept.len().div_ceil(LANES);
        let mut tets = vec![0u32; groups * 4 * LANES];
        let mut grads = vec![0.0; groups * 12 * LANES];
        for (slot, &p) in kept.iter().enumerate() {
            let (g, l) = (slot / LANES, slot % LANES);
            for t in 0..4 {
                tets[(g * 4 + t) * LANES + l] = local[inp.tet_vertices[4 * p + t]];
                for j in 0..3 {
                    grads[(g * 12 + 3 * t + j) * LANES + l] = inp.shape_gradients[12 * p + 3 * t + j];
                }
            }
        }
        Ok(Self { basis, tets, grads })
    }

    /// Number of vertices used.
    pub(super) fn n_vertices(&self, n: usize) -> usize {
        self.basis.len() / (3 * n)
    }

    /// `u_v = W_v q` of every used vertex, three values each, into `u`: one
    /// matrix-vector product (faer's ran 2x faster than 8-lane dot products
    /// per vertex on the like-shaped product of the body frame's inertia).
    pub(super) fn displacements(&self, q: &[f64], n: usize, u: &mut [f64]) {
        let rows = self.basis.len() / n;
        product_by_rows(
            MatRef::from_row_major_slice(&self.basis, rows, n),
            MatRef::from_column_major_slice(q, n, 1),
            MatMut::from_column_major_slice_mut(u, rows, 1),
            Accum::Replace,
        );
    }

    /// `W^T f` over the used vertices (`f` three values each) into `out` (n).
    pub(super) fn pull_back(&self, f: &[f64], n: usize, out: &mut [f64]) {
        let rows = self.basis.len() / n;
        product_by_rows(
            MatRef::from_row_major_slice(&self.basis, rows, n).transpose(),
            MatRef::from_column_major_slice(f, rows, 1),
            MatMut::from_column_major_slice_mut(out, n, 1),
            Accum::Replace,
        );
    }

    /// `F = I + sum_t u_t grad_t^T` of group `g` of cubature points (row-major
    /// components, eight points a lane each), from its tets' vertex
    /// displacements `u_of(v)`.
    #[inline(always)]
    pub(super) fn group_deformation<M: Madd>(&self, g: usize, u_of: impl Fn(usize) -> [f64; 3]) -> [F8; 9] {
        let tets = &self.tets[g * 4 * LANES..(g + 1) * 4 * LANES];
        let grads = &self.grads[g * 12 * LANES..(g + 1) * 12 * LANES];
        let mut f = [[0.0; LANES]; 9];
        for a in [0, 4, 8] {
            f[a] = [1.0; LANES];
        }
        for (t, vs) in tets.chunks_exact(LANES).enumerate() {
            let mut u = [[0.0; LANES]; 3];
            for (l, &v) in vs.iter().enumerate() {
                let uv = u_of(v as usize);
                for i in 0..3 {
                    u[i][l] = uv[i];
                }
            }
            for i in 0..3 {
                for j in 0..3 {
                    f[3 * i + j] = M::madd8(&u[i], lanes_at(grads, (3 * t + j) * LANES), f[3 * i + j]);
                }
            }
        }
        f
    }
}
