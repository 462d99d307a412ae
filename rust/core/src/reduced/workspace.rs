//! Preallocated buffers of the evaluations, sized once per system.

use crate::contact::RankOneTerms;
use crate::real::LANES;
use crate::validity::Validity;

use super::ReducedSystem;

/// Preallocated buffers of the evaluation, sized once per system.
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Gradient, n.
    pub grad: Vec<f64>,
    /// Projected Hessian (elastic negative eigenvalues clamped to zero): n x n,
    /// symmetric positive definite.
    pub hess: Vec<f64>,
    /// What the clamping removed, PSD: the exact Hessian is `hess - hess_clamped`
    /// (filled by [`super::Hessian::Split`] only).
    pub hess_clamped: Vec<f64>,
    /// Whether some elastic eigenvalue was clamped (set by [`super::Hessian::Split`]).
    pub has_clamped: bool,
    /// Elastic energy of the last evaluation, J.
    pub elastic_energy: f64,
    /// Smallest `det F` at the cubature points and deepest contact penetration
    /// of the last evaluation with gradient.
    pub validity: Validity,
    /// Contact part of the Hessian (scratch of [`ReducedSystem::assemble`]).
    pub(super) contact_hess: Vec<f64>,
    /// Elastic square-root rows of `chunk` groups of cubature points at a time,
    /// column-major with column stride `row_stride`:
    /// positive ones in `rows`, clamped ones in `clamped_rows`.
    pub(super) rows: Vec<f64>,
    pub(super) clamped_rows: Vec<f64>,
    pub(super) row_stride: usize,
    pub(super) chunk: usize,
    /// Contact square-root rows, row-major, up to 3 per point and plane (and
    /// the rows taken out by an incremental update).
    pub(super) contact_rows: Vec<f64>,
    pub(super) contact_rows_out: Vec<f64>,
    pub(super) contact_coef: Vec<[f64; 3]>,
    pub(super) contact_coef_out: Vec<[f64; 3]>,
    /// Hessian terms of every contact point with area and plane, and the
    /// displacement `x - x_prev` of every evaluated one, from the last
    /// [`ReducedSystem::evaluate`] with gradient.
    pub(super) contact_terms: Vec<RankOneTerms>,
    pub(super) contact_dx: Vec<[f64; 3]>,
    /// Per-lane partial sums of the contact gradient, n.
    pub(super) contact_lane_grad: Vec<[f64; LANES]>,
    /// Per-lane partial sums of the elastic gradient: one per varying column
    /// of G, then the nine components of `sum_k w_k P_k` (for the constant ones).
    pub(super) lane_grad: Vec<[f64; LANES]>,
    /// The elastic part of the gradient of the last evaluation with gradient, n.
    pub(super) elastic_grad: Vec<f64>,
    /// Vertex displacements `u_v` and vertex forces of the vertex form of the
    /// cubature (3 per used vertex; empty without it).
    pub(super) vertex_u: Vec<f64>,
    pub(super) vertex_force: Vec<f64>,
}

impl Workspace {
    /// The elastic part of the gradient of the last [`ReducedSystem::evaluate`]
    /// with gradient into `out` (n).
    pub fn elastic_gradient(&self, out: &mut [f64]) {
        out.copy_from_slice(&self.elastic_grad);
    }

    /// The exact Hessian `hess - hess_clamped` into `out` (n x n).
    pub fn exact_hessian(&self, out: &mut [f64]) {
        for ((o, a), b) in out.iter_mut().zip(&self.hess).zip(&self.hess_clamped) {
            *o = a - b;
        }
    }
}

impl ReducedSystem {
    /// Buffers for [`Self::assemble`] and the other evaluations.
    pub fn workspace(&self) -> Workspace {
        let n = self.n;
        // Chunks of rows of about 256 KiB: they stay in cache between being
        // written and being multiplied.
        let chunk = (256 * 1024 / (9 * LANES * 8 * n)).clamp(1, self.cubature.groups().max(1));
        let row_stride = 9 * LANES * chunk;
        let points = self.contacts.points.len();
        let n_planes = self.planes.len();
        let contact_rows = 3 * points * n_planes;
        let vertices = self.vertices.as_ref().map_or(0, |v| 3 * v.n_vertices(n));
        Workspace {
            grad: vec![0.0; n],
            hess: vec![0.0; n * n],
            hess_clamped: vec![0.0; n * n],
            has_clamped: false,
            elastic_energy: 0.0,
            validity: Validity::default(),
            contact_hess: vec![0.0; n * n],
            rows: vec![0.0; row_stride * n],
            clamped_rows: vec![0.0; row_stride * n],
            row_stride,
            chunk,
            contact_rows: vec![0.0; contact_rows * n],
            contact_rows_out: vec![0.0; contact_rows * n],
            contact_coef: vec![[0.0; 3]; 3 * n_planes],
            contact_coef_out: vec![[0.0; 3]; 3 * n_planes],
            contact_terms: vec![RankOneTerms::default(); points * n_planes],
            contact_dx: vec![[0.0; 3]; points],
            contact_lane_grad: vec![[0.0; LANES]; n],
            lane_grad: vec![[0.0; LANES]; self.cubature.var_cols.len() + 9],
            elastic_grad: vec![0.0; n],
            vertex_u: vec![0.0; vertices],
            vertex_force: vec![0.0; vertices],
        }
    }
}
