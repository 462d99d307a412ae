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
//! Where the parts live: inertia and gravity, and the sum of the terms, here;
//! the packing of the per-point data in lanes in `layout.rs`; the elastic term
//! (energy, gradient, Hessian rows) in `elastic.rs`; the contact term (energy,
//! gradient, incremental Hessian, friction's stick switch) in `contact.rs`; the
//! buffers in `workspace.rs`.
//!
//! **Hessian.** It is assembled in parts, so that the solver can refresh them
//! at different rates: the elastic part (see `elastic.rs`) and the contact
//! part, kept up to date incrementally ([`ContactHessian`]).
//!
//! **Contact model.** [`ReducedSystem::evaluate_model`] is E with the elastic
//! energy replaced by a quadratic ([`ElasticModel`]): the solver minimises it
//! inside each Newton iteration (see [`crate::solver`]).

mod contact;
mod elastic;
mod layout;
mod workspace;

#[cfg(test)]
mod tests;

pub use contact::ContactHessian;
pub use elastic::{ElasticInputs, ElasticModel, ElasticTerm, ElasticWorkspace, StrainAnchor};
pub use workspace::Workspace;

use crate::contact_points::{ContactInputs, ContactPoints};
use crate::dense::{dot, offset_rows_dot};
use crate::error::{check_finite, check_positive, LicromError, Result};
use crate::integrator::Integrator;
use crate::simd::{dispatch, Madd, WithMadd};
use layout::ContactLayout;
pub use layout::VertexStrainInputs;

/// Borrowed description of a reduced model; all arrays row-major (C order).
#[derive(Debug, Clone, Copy)]
pub struct ReducedInputs<'a> {
    /// Reduced mass matrix `W^T M W`, n x n, symmetric positive definite, kg.
    pub mass: &'a [f64],
    /// Reduced gravity force `W^T M g`, n, N.
    pub gravity_force: &'a [f64],
    /// The elastic term.
    pub elastic: ElasticInputs<'a>,
    /// The contact points (rest positions X_j in the world) and planes.
    pub contact: ContactInputs<'a>,
    /// Time step h, s.
    pub dt: f64,
    /// The time integrator ([`crate::integrator`]).
    pub integrator: Integrator,
}

/// Validated, owned reduced model.
#[derive(Debug, Clone)]
pub struct ReducedSystem {
    n: usize,
    mass: Vec<f64>,
    gravity: Vec<f64>,
    elastic: ElasticTerm,
    /// Contact points as given: basis rows (C x 3 x n), rest positions (C x 3)
    /// and areas (C).
    contact_basis: Vec<f64>,
    contact_rest: Vec<f64>,
    areas: Vec<f64>,
    /// Which points carry area, the planes and the contact model (with the
    /// integrator's effective step h').
    points: ContactPoints,
    /// The contact points of non-zero area, packed by lanes.
    contacts: ContactLayout,
    integrator: Integrator,
    /// The time step h, s.
    time_step: f64,
}

/// Quantities fixed at the start of a step: the anchor `q_a`, the inertial
/// target `qt = q_a + h' qdot_a` ([`crate::integrator`]), the anchor strain
/// of the material damping ([`StrainAnchor`]), the contact points' anchor positions and
/// lagged normal forces.
#[derive(Debug, Clone)]
pub struct StepStart {
    q: Vec<f64>,
    qtilde: Vec<f64>,
    strain: StrainAnchor,
    x_prev: Vec<f64>,
    normal_force: Vec<f64>,
    /// `-f . qt`: the part of E that does not depend on q, left out of
    /// [`ReducedSystem::evaluate`] so that energy differences keep their digits.
    offset: f64,
}

impl StepStart {
    /// Keeps `last`'s damping `C(q_n)` (the start of the step just taken), for
    /// a solver that alternates two starts: the next step's `C(q_{n-1})`.
    pub(crate) fn keep_strain(&mut self, last: &StepStart) {
        self.strain.keep_last(&last.strain);
    }

    /// The step's anchor `q_a` (the state's q for backward Euler): the
    /// velocity after the step is `(q - q_a)/h'`.
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

impl ReducedSystem {
    /// Validates and copies the inputs: consistent sizes, finite values,
    /// non-negative weights and areas, symmetric positive definite mass.
    pub fn new(inp: &ReducedInputs<'_>) -> Result<Self> {
        let n = inp.gravity_force.len();
        if n == 0 {
            return Err(LicromError::shape("gravity_force", "(n,) with n >= 1", "0 values"));
        }
        if inp.mass.len() != n * n {
            return Err(LicromError::shape("mass", format!("({n}, {n})"), format!("{} values", inp.mass.len())));
        }
        check_finite("mass", inp.mass)?;
        check_finite("gravity_force", inp.gravity_force)?;
        check_positive("dt", inp.dt)?;
        let elastic = ElasticTerm::new(&inp.elastic, n, inp.integrator.effective_step(inp.dt))?;
        let points = ContactPoints::new(&inp.contact, n, inp.integrator.effective_step(inp.dt))?;
        let c = &inp.contact;
        Ok(Self {
            n,
            mass: symmetrized_spd(inp.mass, n)?,
            gravity: inp.gravity_force.to_vec(),
            elastic,
            contact_basis: c.basis.to_vec(),
            contact_rest: c.rest.to_vec(),
            areas: c.areas.to_vec(),
            contacts: ContactLayout::new(c.basis, c.rest, points.kept(), c.planes, n),
            points,
            integrator: inp.integrator,
            time_step: inp.dt,
        })
    }

    /// Number of reduced coordinates n.
    pub fn n_dofs(&self) -> usize {
        self.n
    }

    /// Number of cubature points K.
    pub fn n_cubature(&self) -> usize {
        self.elastic.n_cubature()
    }

    /// The elastic term.
    pub fn elastic_term(&self) -> &ElasticTerm {
        &self.elastic
    }

    /// Number of contact points C.
    pub fn n_contacts(&self) -> usize {
        self.points.len()
    }

    /// The effective step h' of the step's minimisation, s: the time step h
    /// for backward Euler, 2h/3 for BDF2 ([`crate::integrator`]).
    pub fn dt(&self) -> f64 {
        self.points.model().dt
    }

    /// The time step h, s.
    pub fn time_step(&self) -> f64 {
        self.time_step
    }

    /// The time integrator.
    pub fn integrator(&self) -> Integrator {
        self.integrator
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
        self.points.any()
    }

    /// Zeroed start-of-step buffers for this system.
    pub fn step_start(&self) -> StepStart {
        let c = self.n_contacts();
        StepStart {
            q: vec![0.0; self.n],
            qtilde: vec![0.0; self.n],
            strain: self.elastic.strain_anchor(),
            x_prev: vec![0.0; 3 * c],
            normal_force: vec![0.0; c * self.points.planes().len()],
            offset: 0.0,
        }
    }

    /// Fills `start` for a step from state `(q, qdot)` after `previous`
    /// (`(q, qdot)` one step earlier; BDF2 needs it, backward Euler ignores it):
    /// anchor, inertial target, the contact points' anchor positions and the
    /// normal forces lagged at q. Lengths must be n.
    pub fn begin_step(&self, q: &[f64], qdot: &[f64], previous: Option<(&[f64], &[f64])>, start: &mut StepStart) {
        dispatch(BeginKernel { sys: self, q, qdot, previous, start })
    }

    #[inline(always)]
    fn begin_impl<M: Madd>(&self, q: &[f64], qdot: &[f64], previous: Option<(&[f64], &[f64])>, start: &mut StepStart) {
        let h = self.dt();
        let w = self.integrator.history();
        start.q.copy_from_slice(q);
        start.qtilde.copy_from_slice(qdot);
        if let (Some((q_prev, qdot_prev)), true) = (previous, w != 0.0) {
            for i in 0..self.n {
                start.q[i] += w * (q[i] - q_prev[i]);
                start.qtilde[i] += w * (qdot[i] - qdot_prev[i]);
            }
        }
        for (t, qa) in start.qtilde.iter_mut().zip(&start.q) {
            *t = qa + h * *t;
        }
        start.offset = -dot::<M>(&self.gravity, &start.qtilde);
        self.elastic.set_anchor(q, previous.filter(|_| w != 0.0).map(|(q_prev, _)| (q_prev, w)), &mut start.strain);
        self.begin_contacts::<M>(q, start);
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

    /// Energy (shifted as in [`Self::evaluate`]) and the elastic energy; with
    /// `ws`, the gradient into `ws.grad`.
    #[inline(always)]
    fn evaluate_impl<M: Madd>(&self, start: &StepStart, q: &[f64], model: Option<&ElasticModel<'_>>, mut ws: Option<&mut Workspace>) -> (f64, f64) {
        let inv_h2 = 1.0 / (self.dt() * self.dt());
        // Inertia and gravity, relative to the inertial target.
        let mut inertia = 0.0;
        let mut work = 0.0;
        offset_rows_dot::<M>(&self.mass, q, &start.qtilde, |i, md| {
            let d = q[i] - start.qtilde[i];
            inertia = M::madd(d, md, inertia);
            work = M::madd(self.gravity[i], d, work);
            if let Some(ws) = ws.as_deref_mut() {
                ws.grad[i] = md * inv_h2 - self.gravity[i];
            }
        });
        let mut e = 0.5 * inertia * inv_h2 - work;
        let elastic_energy = match (model, ws.as_deref_mut()) {
            (Some(m), ws) => m.evaluate::<M>(q, ws.map(|ws| &mut ws.grad[..])),
            (None, ws) => self.elastic_impl::<M>(q, Some(&start.strain), ws),
        };
        e += elastic_energy;
        (e + self.contact_energy_impl::<M>(start, q, ws), elastic_energy)
    }

    /// The elastic energy `sum_k w_k Psi(F_k(q))` alone (J), without the
    /// material damping, and, with `with_gradient`, its gradient into `ws.grad`.
    pub fn elastic(&self, q: &[f64], with_gradient: bool, ws: &mut Workspace) -> f64 {
        if !with_gradient {
            return self.elastic.evaluate(q, None, None);
        }
        let e = self.elastic.evaluate(q, None, Some(&mut ws.elastic));
        ws.grad.copy_from_slice(ws.elastic.gradient());
        e
    }

    /// Elastic energy (with the damping's against `strain`) and, with `ws`, its
    /// gradient added to `ws.grad` (and kept in `ws`) and the smallest `det F`
    /// into `ws.validity`.
    #[inline(always)]
    fn elastic_impl<M: Madd>(&self, q: &[f64], strain: Option<&StrainAnchor>, ws: Option<&mut Workspace>) -> f64 {
        let Some(ws) = ws else {
            return self.elastic.evaluate_impl::<M>(q, strain, None);
        };
        let e = self.elastic.evaluate_impl::<M>(q, strain, Some(&mut ws.elastic));
        ws.validity.min_det = ws.elastic.min_det();
        for (g, e) in ws.grad.iter_mut().zip(ws.elastic.gradient()) {
            *g += e;
        }
        e
    }

    /// Elastic part of the Hessian at `q` ([`ElasticTerm::hessian`]).
    pub fn elastic_hessian(&self, q: &[f64], ws: &mut Workspace, projected: &mut [f64], clamped: Option<&mut [f64]>) -> bool {
        self.elastic.hessian(q, &mut ws.elastic, projected, clamped)
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

struct BeginKernel<'a> {
    sys: &'a ReducedSystem,
    q: &'a [f64],
    qdot: &'a [f64],
    previous: Option<(&'a [f64], &'a [f64])>,
    start: &'a mut StepStart,
}

impl WithMadd for BeginKernel<'_> {
    type Output = ();
    #[inline(always)]
    fn run<M: Madd>(self) {
        self.sys.begin_impl::<M>(self.q, self.qdot, self.previous, self.start)
    }
}

/// The symmetrised mass matrix (n >= 1), after checking symmetry (to a relative 1e-8, the
/// round-off of `W^T M W` computed in any order) and positive definiteness.
pub(crate) fn symmetrized_spd(mass: &[f64], n: usize) -> Result<Vec<f64>> {
    let scale = mass.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut sym = vec![0.0; n * n];
    for r in 0..n {
        for c in 0..n {
            let (a, b) = (mass[r * n + c], mass[c * n + r]);
            if (a - b).abs() > 1e-8 * scale {
                return Err(LicromError::SingularMass { reason: format!("entries ({r}, {c}) and ({c}, {r}) differ: {a} vs {b}") });
            }
            sym[r * n + c] = 0.5 * (a + b);
        }
    }
    check_positive("mass scale", scale).map_err(|_| LicromError::SingularMass { reason: "it is zero".into() })?;
    crate::cholesky::Cholesky::factor(&sym, n)
        .map_err(|index| LicromError::SingularMass { reason: format!("Cholesky pivot {index} is not positive") })?;
    Ok(sym)
}
