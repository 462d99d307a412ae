//! Preallocated buffers of the evaluations, sized once per system.

use crate::contact::RankOneTerms;
use crate::real::LANES;
use crate::validity::Validity;

use super::{ElasticWorkspace, ReducedSystem};

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
    /// The elastic term's buffers.
    pub(super) elastic: ElasticWorkspace,
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
}

impl Workspace {
    /// The elastic part of the gradient of the last [`ReducedSystem::evaluate`]
    /// with gradient into `out` (n).
    pub fn elastic_gradient(&self, out: &mut [f64]) {
        out.copy_from_slice(self.elastic.gradient());
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
        let points = self.points.kept().len();
        let n_planes = self.points.planes().len();
        let contact_rows = 3 * points * n_planes;
        Workspace {
            grad: vec![0.0; n],
            hess: vec![0.0; n * n],
            hess_clamped: vec![0.0; n * n],
            has_clamped: false,
            elastic_energy: 0.0,
            validity: Validity::default(),
            contact_hess: vec![0.0; n * n],
            elastic: self.elastic.workspace(),
            contact_rows: vec![0.0; contact_rows * n],
            contact_rows_out: vec![0.0; contact_rows * n],
            contact_coef: vec![[0.0; 3]; 3 * n_planes],
            contact_coef_out: vec![[0.0; 3]; 3 * n_planes],
            contact_terms: vec![RankOneTerms::default(); points * n_planes],
            contact_dx: vec![[0.0; 3]; points],
            contact_lane_grad: vec![[0.0; LANES]; n],
        }
    }
}
