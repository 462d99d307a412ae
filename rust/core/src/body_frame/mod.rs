//! The reduced model in the body frame (floating frame of reference): rigid
//! motion exact and nonlinear, learned modes in the body.
//!
//! **Kinematics.** `x_v = c + R y_v(q)`, `y_v = Xbar_v + W_v q`,
//! `Xbar_v = X_v - X_com`, with every column of W mass-orthogonal to the six
//! rigid modes (`sum m W_v = 0`, `sum m Xbar_v x W_v = 0`), so that c is the
//! centre of mass. Units: c in m, q as the modes (W in m per unit of q).
//!
//! **Energy of one backward-Euler step**, from the current pose `(c, R, q)`
//! (time t) and the previous one (t - 1), with the predicted positions
//! `xt_v = 2 x^t_v - x^{t-1}_v + h^2 g` (so that the vertex velocities
//! `(x^t - x^{t-1})/h` are exact, as in the full-space solver). A BDF2 step
//! ([`crate::integrator`]) is the same with h replaced by its effective step
//! h' = 2h/3 and `xt_v - h'^2 g` the weighted sum of the vertex positions of
//! four poses ([`Integrator::target_weights`]), so every sum over vertices
//! below stays one over the poses' moments:
//!
//! - inertia `1/(2h^2) sum_v m_v |c + R y_v - xt_v|^2`. With `sum m y = 0` it
//!   splits into `M/(2h^2) |c - ct|^2`, `ct = 2c^t - c^{t-1} + h^2 g`, and
//!   `1/(2h^2) [q^T Mqq q + 2 b.q - 2 tr(R^T B(q))]` plus a constant, from the
//!   mass moments `J = sum m Xbar Xbar^T`, `P_k = sum m W^k Xbar^T`,
//!   `Q_kl = sum m W^k W^l^T`: `Mqq_kl = tr Q_kl`, `b_k = tr P_k`,
//!   `B(q) = B0 + sum_k q_k B_k` with, per step,
//!   `B0 = 2R^t (J + sum_l q^t_l P_l) - R^{t-1} (J + sum_l q^{t-1}_l P_l)` and
//!   `B_k = 2R^t (P_k^T + sum_l q^t_l Q_lk) - R^{t-1} (P_k^T + sum_l q^{t-1}_l Q_lk)`
//!   ([`inertia`]). Cost O(9 n^2) per step and O(9 n) per evaluation,
//!   independent of the mesh;
//! - elastic `sum_k w_k Psi(I + G_k q)` (`Psi(R F) = Psi(F)` removes R): the
//!   world-frame model's [`ElasticTerm`], evaluated beside the modal mass term
//!   `q^T Mqq q/(2h^2)` in one pass (the modal part);
//! - contact and friction at the contact points ([`contact`]), with the
//!   normal force lagged at time t and the slip measured from the anchor
//!   positions (those at time t for backward Euler, `(4 x^t - x^{t-1})/3` for BDF2).
//!
//! **Variables** of the Newton iteration are `(dc, omega, dq)` (3 + 3 + n),
//! the rotation moving as `R <- exp([omega]x) R`; gradients and Hessians are
//! those of the pulled-back function at omega = 0. The energy reported leaves
//! out the constant of the step (`tr J` and `sum m |a_v|^2` terms), so only its
//! differences within a step carry meaning.

pub mod contact;
pub mod inertia;
pub mod rotation;
pub mod solver;
pub mod synthetic;

#[cfg(test)]
mod tests;

use nalgebra::{Matrix3, Vector3};

use crate::contact_points::ContactInputs;
use crate::dense::offset_rows_dot;
use crate::error::{check_finite, check_positive, Result};
use crate::integrator::Integrator;
use crate::reduced::{ElasticInputs, ElasticModel, ElasticTerm, ElasticWorkspace, StrainAnchor};
use crate::simd::{dispatch, Madd, WithMadd};
use crate::validity::Validity;
use contact::{BodyContactHessian, BodyContacts, ContactOut, ContactRows, ContactStart, ContactTerms};
use inertia::{InertiaTarget, MassMoments};

/// Borrowed description of a body-frame model; arrays row-major (C order).
#[derive(Debug, Clone, Copy)]
pub struct BodyFrameInputs<'a> {
    /// Total mass M, kg.
    pub total_mass: f64,
    /// `J = sum m Xbar Xbar^T`, 3 x 3, kg m^2.
    pub inertia_moments: &'a [f64],
    /// `P_k = sum m W^k Xbar^T`, n x 3 x 3.
    pub mode_moments: &'a [f64],
    /// `Q_kl = sum m W^k W^l^T`, n x n x 3 x 3.
    pub mode_products: &'a [f64],
    /// Gravity acceleration, m/s^2.
    pub gravity: [f64; 3],
    /// The elastic term.
    pub elastic: ElasticInputs<'a>,
    /// The contact points (rest positions relative to the centre of mass,
    /// Xbar_j) and planes.
    pub contact: ContactInputs<'a>,
    /// Time step h, s.
    pub dt: f64,
    /// The time integrator ([`crate::integrator`]).
    pub integrator: Integrator,
}

/// Position of the body: centre of mass c (m), rotation R, modal coordinates q.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Centre of mass, m.
    pub center: Vector3<f64>,
    /// Rotation from the body frame to the world.
    pub rotation: Matrix3<f64>,
    /// Modal coordinates, n.
    pub q: Vec<f64>,
}

impl Pose {
    /// At the origin, unrotated and undeformed.
    pub fn rest(n: usize) -> Self {
        Self { center: Vector3::zeros(), rotation: Matrix3::identity(), q: vec![0.0; n] }
    }

    /// `self = base (+) alpha dir`: c and q moved along dir, R turned by
    /// `exp(alpha [omega]x)`; dir is `(dc, omega, dq)`.
    pub fn retract(&mut self, base: &Pose, dir: &[f64], alpha: f64) {
        self.center = base.center + Vector3::new(dir[0], dir[1], dir[2]) * alpha;
        self.rotation = rotation::exp_map(&(Vector3::new(dir[3], dir[4], dir[5]) * alpha)) * base.rotation;
        for ((q, b), d) in self.q.iter_mut().zip(&base.q).zip(&dir[6..]) {
            *q = b + alpha * d;
        }
    }

    /// The direction `(dc, omega, dq)` (into `out`, 6 + n) with
    /// `self = base (+) dir`, omega the shortest turn.
    pub fn difference(&self, base: &Pose, out: &mut [f64]) {
        out[..3].copy_from_slice((self.center - base.center).as_slice());
        out[3..6].copy_from_slice(rotation::log_map(&(self.rotation * base.rotation.transpose())).as_slice());
        for ((o, a), b) in out[6..].iter_mut().zip(&self.q).zip(&base.q) {
            *o = a - b;
        }
    }

    /// Copies `other` without allocating.
    pub fn assign(&mut self, other: &Pose) {
        self.center = other.center;
        self.rotation = other.rotation;
        self.q.copy_from_slice(&other.q);
    }
}

/// What a step needs from its start: the inertial target and the contact
/// points' positions and lagged normal forces.
#[derive(Debug, Clone)]
pub struct BodyStart {
    inertia: InertiaTarget,
    contact: ContactStart,
    /// The material damping's anchor strain, from `q_n` and `q_{n-1}` alone ([`StrainAnchor`]).
    strain: StrainAnchor,
}

impl BodyStart {
    /// Takes from `last`, the start of the step just taken, what the next
    /// step's start reuses: the inertia's mode products of the poses its
    /// history repeats, the damping's `C(q_n)` and the contact points' body
    /// positions at q_n (the solver alternates two starts, keeping the last
    /// one for the contact forces).
    fn take_kept(&mut self, last: &mut BodyStart) {
        self.inertia.take_held(&mut last.inertia);
        self.strain.keep_last(&last.strain);
        self.contact.keep_start(&last.contact);
    }
}

/// Which Hessian [`BodyFrameSystem::hessian`] assembles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyHessian {
    /// Positive definite: Gauss-Newton inertia and contact, PSD-projected elastic.
    GaussNewton,
    /// The exact Hessian of the pulled-back energy (may be indefinite).
    Exact,
}

/// Preallocated scratch of the evaluations.
#[derive(Debug, Clone)]
pub struct BodyWorkspace {
    /// Gradient of the last evaluation with gradient, 6 + n.
    pub grad: Vec<f64>,
    elastic: Option<ElasticWorkspace>,
    /// Elastic energy (or its model's) of the last evaluation, J.
    elastic_energy: f64,
    rows: ContactRows,
    /// The contact points' terms of the last evaluation with gradient.
    terms: ContactTerms,
    /// n x n scratch for the elastic Hessian, and for the modal block.
    square: Vec<f64>,
    block: Vec<f64>,
    /// Smallest `det F` at the cubature points and deepest contact penetration
    /// of the last [`BodyFrameSystem::evaluate`] with gradient.
    pub validity: Validity,
}

impl BodyWorkspace {
    /// Elastic energy (J) of the last [`BodyFrameSystem::evaluate`].
    pub fn elastic_energy(&self) -> f64 {
        self.elastic_energy
    }

    /// Elastic part (n) of the q-gradient of the last [`BodyFrameSystem::evaluate`] with gradient into `out`.
    pub fn elastic_gradient(&self, out: &mut [f64]) {
        match &self.elastic {
            Some(e) => out.copy_from_slice(e.gradient()),
            None => out.fill(0.0),
        }
    }
}

/// Validated, owned body-frame model.
#[derive(Debug, Clone)]
pub struct BodyFrameSystem {
    n: usize,
    /// The integrator's effective step h' (the time step for backward Euler), s.
    h: f64,
    /// The time step, s.
    time_step: f64,
    integrator: Integrator,
    gravity: Vector3<f64>,
    moments: MassMoments,
    /// The elastic term (none for a rigid body, n = 0).
    elastic: Option<ElasticTerm>,
    /// q = 0, the expansion point of the modal mass term `q^T Mqq q/(2h^2)`, n.
    origin: Vec<f64>,
    contacts: BodyContacts,
}

impl BodyFrameSystem {
    /// Validates and copies the inputs. With n = 0 (a rigid body) there is no
    /// elastic part.
    pub fn new(inp: &BodyFrameInputs<'_>) -> Result<Self> {
        let moments = MassMoments::new(inp.total_mass, inp.inertia_moments, inp.mode_moments, inp.mode_products)?;
        let n = moments.n_modes();
        check_finite("gravity", &inp.gravity)?;
        check_positive("dt", inp.dt)?;
        let h = inp.integrator.effective_step(inp.dt);
        let contacts = BodyContacts::new(n, &inp.contact, h)?;
        let elastic = if n == 0 { None } else { Some(ElasticTerm::new(&inp.elastic, n, h)?) };
        Ok(Self {
            n,
            h,
            time_step: inp.dt,
            integrator: inp.integrator,
            gravity: Vector3::from(inp.gravity),
            moments,
            elastic,
            origin: vec![0.0; n],
            contacts,
        })
    }

    /// Number of modes n (the Newton system has 6 + n unknowns).
    pub fn n_modes(&self) -> usize {
        self.n
    }

    /// Number of contact points C.
    pub fn n_contacts(&self) -> usize {
        self.contacts.len()
    }

    /// Time step h, s.
    pub fn dt(&self) -> f64 {
        self.time_step
    }

    /// The integrator's effective step h' (h for backward Euler, 2h/3 for BDF2), s.
    pub fn effective_step(&self) -> f64 {
        self.h
    }

    /// The time integrator.
    pub fn integrator(&self) -> Integrator {
        self.integrator
    }

    /// Total mass M, kg.
    pub fn total_mass(&self) -> f64 {
        self.moments.total
    }

    /// Gravity acceleration, m/s^2.
    pub fn gravity(&self) -> Vector3<f64> {
        self.gravity
    }

    /// The mass moments.
    pub fn moments(&self) -> &MassMoments {
        &self.moments
    }

    /// Zeroed start-of-step buffers.
    pub fn step_start(&self) -> BodyStart {
        BodyStart {
            inertia: InertiaTarget::new(self.n),
            contact: self.contacts.start(),
            strain: self.elastic.as_ref().map(ElasticTerm::strain_anchor).unwrap_or_default(),
        }
    }

    /// Buffers for the evaluations.
    pub fn workspace(&self) -> BodyWorkspace {
        BodyWorkspace {
            grad: vec![0.0; 6 + self.n],
            elastic: self.elastic.as_ref().map(ElasticTerm::workspace),
            elastic_energy: 0.0,
            rows: self.contacts.rows(),
            terms: self.contacts.terms(),
            square: vec![0.0; self.n * self.n],
            block: vec![0.0; self.n * self.n],
            validity: Validity::default(),
        }
    }

    /// Fills `start` for a step from the poses `history`, newest first: the
    /// current one (time t), then t - 1, ...; backward Euler reads two, BDF2
    /// four ([`Integrator::target_weights`]).
    ///
    /// # Panics
    /// If `history` holds fewer poses than the integrator reads.
    pub fn begin_step(&self, history: &[&Pose], start: &mut BodyStart) {
        start.inertia.begin(&self.moments, history, self.integrator, &self.gravity, self.h);
        let w = self.integrator.history();
        self.contacts.begin(history[0], (w != 0.0).then(|| (history[1], w)), &mut start.contact);
        if let Some(elastic) = &self.elastic {
            elastic.set_anchor(&history[0].q, (w != 0.0).then(|| (&history[1].q[..], w)), &mut start.strain);
        }
    }

    /// The step's energy at `pose` (J, without the step's constant); with
    /// `with_gradient` its gradient in `(c, omega, q)` into `ws.grad` and the
    /// contact points' terms (for [`Self::update_contact_hessian`] and
    /// [`Self::stick_switch`]) into `ws`.
    pub fn evaluate(&self, start: &BodyStart, pose: &Pose, with_gradient: bool, ws: &mut BodyWorkspace) -> f64 {
        self.evaluate_with(start, pose, None, with_gradient, ws)
    }

    /// [`Self::evaluate`] with the elastic energy replaced by a quadratic
    /// `model` in q (inertia, gravity and contact exact; the
    /// [`crate::solver`]'s contact model): no pass over the cubature points.
    /// The elastic energy and gradient of `ws` are then not set.
    pub fn evaluate_model(&self, start: &BodyStart, pose: &Pose, model: &ElasticModel<'_>, with_gradient: bool, ws: &mut BodyWorkspace) -> f64 {
        self.evaluate_with(start, pose, Some(model), with_gradient, ws)
    }

    fn evaluate_with(&self, start: &BodyStart, pose: &Pose, model: Option<&ElasticModel<'_>>, with_gradient: bool, ws: &mut BodyWorkspace) -> f64 {
        let mut e = 0.0;
        if let (Some(elastic), Some(ews)) = (&self.elastic, ws.elastic.as_mut()) {
            let grad = with_gradient.then_some(&mut ws.grad[6..]);
            let ews = (with_gradient && model.is_none()).then_some(ews);
            let (modal, elastic_energy) = dispatch(ModalKernel { sys: self, elastic, q: &pose.q, strain: &start.strain, model, grad, ws: ews });
            e += modal;
            ws.elastic_energy = elastic_energy;
        }
        if with_gradient {
            ws.grad[..6].fill(0.0);
        }
        let grad = with_gradient.then_some(&mut ws.grad[..]);
        e += start.inertia.energy(&self.moments, pose, self.h, grad);
        let out = ContactOut {
            grad: with_gradient.then_some(&mut ws.grad[..]),
            rows: None,
            geometric: None,
            terms: with_gradient.then_some(&mut ws.terms),
            depth: with_gradient.then_some(&mut ws.validity.depth),
        };
        e += self.contacts.evaluate(&start.contact, pose, out);
        if with_gradient && model.is_none() {
            ws.validity.min_det = ws.elastic.as_ref().map_or(f64::INFINITY, ElasticWorkspace::min_det);
        }
        e
    }

    /// The modal part `q^T Mqq q/(2h^2) + elastic(q)` (J), the elastic energy
    /// replaced by `model` where given, and the elastic (or model) energy;
    /// with `grad`, the modal part's gradient into it (n); with `ws`, the
    /// elastic gradient and smallest `det F` into that.
    #[inline(always)]
    fn modal_impl<M: Madd>(
        &self,
        elastic: &ElasticTerm,
        q: &[f64],
        strain: &StrainAnchor,
        model: Option<&ElasticModel<'_>>,
        mut grad: Option<&mut [f64]>,
        ws: Option<&mut ElasticWorkspace>,
    ) -> (f64, f64) {
        let inv_h2 = 1.0 / (self.h * self.h);
        let mut inertia = 0.0;
        offset_rows_dot::<M>(self.moments.mode_mass(), q, &self.origin, |i, md| {
            inertia = M::madd(q[i], md, inertia);
            if let Some(g) = grad.as_deref_mut() {
                g[i] = md * inv_h2;
            }
        });
        let elastic_energy = match model {
            Some(m) => m.evaluate::<M>(q, grad),
            None => match ws {
                Some(ws) => {
                    let e = elastic.evaluate_impl::<M>(q, Some(strain), Some(&mut *ws));
                    for (g, e) in grad.into_iter().flatten().zip(ws.gradient()) {
                        *g += e;
                    }
                    e
                }
                None => elastic.evaluate_impl::<M>(q, Some(strain), None),
            },
        };
        (0.5 * inertia * inv_h2 + elastic_energy, elastic_energy)
    }

    /// Energy alone (J), allocating its scratch: for tests and probes.
    pub fn energy(&self, start: &BodyStart, pose: &Pose) -> f64 {
        self.evaluate(start, pose, false, &mut self.workspace())
    }

    /// The modal block `Mqq/h^2 + K_el` at q into `out` (n x n, full
    /// symmetric): K_el PSD-projected, or exact (possibly indefinite).
    pub fn elastic_block(&self, q: &[f64], exact: bool, ws: &mut BodyWorkspace, out: &mut [f64]) {
        let (Some(el), Some(ews)) = (&self.elastic, ws.elastic.as_mut()) else {
            return;
        };
        let mut clamped = std::mem::take(&mut ws.square);
        el.hessian(q, ews, out, exact.then_some(&mut clamped[..]));
        let h2 = self.h * self.h;
        for (i, (o, m)) in out.iter_mut().zip(self.moments.mode_mass()).enumerate() {
            *o += m / h2 - if exact { clamped[i] } else { 0.0 };
        }
        ws.square = clamped;
    }

    /// The PSD-projected elastic Hessian `K_el` at q into `out` (n x n, full symmetric).
    pub fn elastic_stiffness(&self, q: &[f64], ws: &mut BodyWorkspace, out: &mut [f64]) {
        if let (Some(el), Some(ews)) = (&self.elastic, ws.elastic.as_mut()) {
            el.hessian(q, ews, out, None);
        }
    }

    /// The modal mass matrix `Mqq` (n x n, kg; empty for n = 0).
    pub fn mode_mass(&self) -> &[f64] {
        self.moments.mode_mass()
    }

    /// `out` zeroed but for the modal block `block` (n x n).
    fn place_block(&self, block: &[f64], out: &mut [f64]) {
        let n = self.n;
        let big = 6 + n;
        out.fill(0.0);
        for r in 0..n {
            out[(6 + r) * big + 6..(6 + r) * big + big].copy_from_slice(&block[r * n..(r + 1) * n]);
        }
    }

    /// The Hessian at `pose` into `out` ((6 + n)^2, full symmetric), contact
    /// terms formed from all points: for probes and tests.
    pub fn hessian(&self, start: &BodyStart, pose: &Pose, kind: BodyHessian, ws: &mut BodyWorkspace, out: &mut [f64]) {
        let h2 = self.h * self.h;
        let mut block = std::mem::take(&mut ws.block);
        self.elastic_block(&pose.q, kind == BodyHessian::Exact, ws, &mut block);
        self.place_block(&block, out);
        ws.block = block;
        let geometric = match kind {
            BodyHessian::GaussNewton => {
                start.inertia.add_gauss_newton(&self.moments, pose, 1.0 / h2, out);
                None
            }
            BodyHessian::Exact => {
                start.inertia.add_exact_hessian(&self.moments, pose, self.h, out);
                Some(&mut out[..])
            }
        };
        let out_c = ContactOut { grad: None, rows: Some(&mut ws.rows), geometric, terms: None, depth: None };
        self.contacts.evaluate(&start.contact, pose, out_c);
        self.contacts.add_rows(&ws.rows, ws.rows.count, out);
    }

    /// Whether the model has contact points with area and planes (contact and
    /// friction terms can be non-zero).
    pub fn has_contact(&self) -> bool {
        self.contacts.any()
    }

    /// An empty incremental contact Hessian for this system.
    pub fn contact_hessian_state(&self) -> BodyContactHessian {
        self.contacts.hessian_state()
    }

    /// Brings `state` to the contact terms of the last [`Self::evaluate`] (or
    /// [`Self::evaluate_model`]) with gradient ([`contact`]'s incremental
    /// Hessian). Returns the rows changed.
    pub fn update_contact_hessian(&self, ws: &mut BodyWorkspace, state: &mut BodyContactHessian) -> usize {
        self.contacts.update_hessian(&ws.terms, &mut ws.rows, state)
    }

    /// The solver's positive definite matrix at `pose` into `out` ((6 + n)^2,
    /// full symmetric): the Gauss-Newton inertia, `Mqq/h^2` and the elastic
    /// Hessian `stiffness` (n x n, possibly of an earlier pose) in the modal
    /// block, and the contact part of `contact` (brought up to date by
    /// [`Self::update_contact_hessian`]); and its inertia part, the
    /// Gauss-Newton inertia over all vertices (with `Mqq`) over h^2, into
    /// `metric` (positive definite: the solver's convergence metric).
    pub fn newton_matrix(
        &self,
        start: &BodyStart,
        pose: &Pose,
        stiffness: &[f64],
        contact: &BodyContactHessian,
        out: &mut [f64],
        metric: &mut [f64],
    ) {
        let n = self.n;
        let big = 6 + n;
        let inv_h2 = 1.0 / (self.h * self.h);
        let s = contact.body_matrix();
        // Rows and columns of c and omega: the Gauss-Newton inertia, then in `out` the rotated contact part.
        for (r, row) in metric.chunks_exact_mut(big).enumerate() {
            row[..if r < 6 { big } else { 6 }].fill(0.0);
        }
        start.inertia.add_gauss_newton(&self.moments, pose, inv_h2, metric);
        for (r, (o, m)) in out.chunks_exact_mut(big).zip(metric.chunks_exact(big)).enumerate() {
            let rigid = if r < 6 { big } else { 6 };
            o[..rigid].copy_from_slice(&m[..rigid]);
        }
        contact::add_rotated_rigid(s, &pose.rotation, big, out);
        // The modal block in one pass: `Mqq/h^2` in both, `+ K_el + S_qq` in `out`.
        for r in 0..n {
            let at = (6 + r) * big + 6;
            let (mass, k) = (&self.mode_mass()[r * n..(r + 1) * n], &stiffness[r * n..(r + 1) * n]);
            let (o, m, sq) = (&mut out[at..at + n], &mut metric[at..at + n], &s[at..at + n]);
            for c in 0..n {
                let mc = mass[c] * inv_h2;
                m[c] = mc;
                o[c] = mc + k[c] + sq[c];
            }
        }
    }

    /// Friction's stick switch of the direction `dir` from `pose`, the point of
    /// the last evaluation with gradient ([`contact`]): returns the number of
    /// switch rows (for [`Self::add_switch_rows`]) and adds the change of the
    /// gradient to `rhs` (6 + n).
    pub fn stick_switch(&self, start: &BodyStart, pose: &Pose, dir: &[f64], ws: &mut BodyWorkspace, rhs: &mut [f64]) -> usize {
        self.contacts.stick_switch(&start.contact, pose, dir, &ws.terms, &mut ws.rows, rhs)
    }

    /// The first `count` switch rows B of [`Self::stick_switch`], row-major,
    /// 6 + n wide: the switched matrix is the Newton matrix plus `B^T B`.
    pub fn switch_rows<'a>(&self, ws: &'a BodyWorkspace, count: usize) -> &'a [f64] {
        self.contacts.switch_rows(&ws.rows, count)
    }

    /// Adds the product of the first `count` switch rows of
    /// [`Self::stick_switch`] to the full symmetric `hess`.
    pub fn add_switch_rows(&self, ws: &BodyWorkspace, count: usize, hess: &mut [f64]) {
        self.contacts.add_rows(&ws.rows, count, hess);
    }

    /// Contact forces (N) on the C points at `pose` over the step that started
    /// at `start`, C x 3.
    pub fn contact_forces(&self, start: &BodyStart, pose: &Pose, out: &mut [f64]) {
        self.contacts.forces(&start.contact, pose, out);
    }
}

struct ModalKernel<'a> {
    sys: &'a BodyFrameSystem,
    elastic: &'a ElasticTerm,
    q: &'a [f64],
    strain: &'a StrainAnchor,
    model: Option<&'a ElasticModel<'a>>,
    grad: Option<&'a mut [f64]>,
    ws: Option<&'a mut ElasticWorkspace>,
}

impl WithMadd for ModalKernel<'_> {
    type Output = (f64, f64);
    #[inline(always)]
    fn run<M: Madd>(self) -> (f64, f64) {
        self.sys.modal_impl::<M>(self.elastic, self.q, self.strain, self.model, self.grad, self.ws)
    }
}
