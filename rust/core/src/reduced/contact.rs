//! The contact term `sum_j,p C_jp(x_j(q))` of the reduced model: penalty,
//! damping and lagged Coulomb friction of the point model in
//! [`crate::contact`], mapped through the basis rows `W_j`.
//!
//! Energy and gradient are formed eight points at a time (see
//! [`super::layout`]), only for points that touch a plane or carry a lagged
//! normal force. The Hessian part is the product of the square-root factors of
//! the points' rank-one terms times `W_j`, kept up to date incrementally by
//! [`ContactHessian`]. The stick switch ([`ReducedSystem::stick_switch`]) is
//! friction's correction of a Newton direction (used by the solver's contact
//! model, [`crate::solver`]).

use faer::Accum;
use nalgebra::Vector3;

use crate::contact::{RankOneTerms, CURVATURE_SLACK, DIRECTION_COS};
use crate::dense::{add_gram, combine_rows, mirror_lower, rows_dot, syrk_rows, IncrementalGram};
use crate::real::LANES;
use crate::simd::{dispatch, lane_sum, Madd, Separate, WithMadd};

use super::layout::lanes_at;
use super::{ReducedSystem, StepStart, Workspace};

/// A contact point whose gap, from its normal row, is above this (m) is
/// skipped unless it carries a lagged normal force; its exact gap (from its
/// position) decides everything else. The margin covers the round-off between
/// the two ways of computing the gap.
const CULL_MARGIN: f64 = 1e-9;

/// The contact part of the Hessian, kept up to date incrementally by
/// [`ReducedSystem::update_contact_hessian`].
#[derive(Debug, Clone)]
pub struct ContactHessian {
    /// The terms in the matrix, per contact point with area and plane.
    used: Vec<RankOneTerms>,
    gram: IncrementalGram,
    /// Keep terms that changed by less than [`CURVATURE_SLACK`] (else only equal ones).
    lagged: bool,
}

impl ContactHessian {
    /// The matrix (n x n, full symmetric, PSD up to round-off).
    pub fn matrix(&self) -> &[f64] {
        self.gram.matrix()
    }

    /// Forms the matrix from scratch at the next update.
    pub fn invalidate(&mut self) {
        self.gram.invalidate();
    }
}

impl ReducedSystem {
    /// The contact part of [`Self::begin_step`]: normal forces lagged at q, and
    /// the anchor positions (at `start.q`, set before) of the points that carry one.
    #[inline(always)]
    pub(super) fn begin_contacts<M: Madd>(&self, q: &[f64], start: &mut StepStart) {
        let n_planes = self.points.planes().len();
        start.normal_force.fill(0.0);
        let k = self.points.model().normal_stiffness;
        for (g, slots) in self.points.kept().chunks(LANES).enumerate() {
            let mut engaged = 0u32;
            for p in 0..n_planes {
                let gap = self.contacts.group_gap::<M>(g, p, q);
                for (l, &j) in slots.iter().enumerate() {
                    // As `ContactModel::lagged_normal_force`.
                    let f = self.areas[j] * k * (-gap[l]).max(0.0);
                    start.normal_force[j * n_planes + p] = f;
                    if f > 0.0 {
                        engaged |= 1 << l;
                    }
                }
            }
            // Only points with a lagged normal force use their anchor position.
            for (l, &j) in slots.iter().enumerate() {
                if engaged & (1 << l) != 0 {
                    let x = self.contact_position::<M>(j, &start.q);
                    start.x_prev[3 * j..3 * j + 3].copy_from_slice(x.as_slice());
                }
            }
        }
    }

    /// Position of contact point `j` at `q`, m.
    #[inline(always)]
    pub(super) fn contact_position<M: Madd>(&self, j: usize, q: &[f64]) -> Vector3<f64> {
        let n = self.n;
        let w = &self.contact_basis[3 * n * j..3 * n * (j + 1)];
        let x0 = &self.contact_rest[3 * j..3 * j + 3];
        let wq = rows_dot::<M, 3>(w, q);
        Vector3::new(x0[0] + wq[0], x0[1] + wq[1], x0[2] + wq[2])
    }

    /// Contact energy and, with `ws`, its gradient (added to `ws.grad`), the
    /// Hessian terms and displacements of the points (into `ws`). Points that
    /// touch no plane and carry no lagged normal force contribute nothing: eight
    /// gaps at a time find them from the normal rows alone; the positions and
    /// the gradient of the others are formed eight points at a time too.
    #[inline(always)]
    pub(super) fn contact_energy_impl<M: Madd>(&self, start: &StepStart, q: &[f64], mut ws: Option<&mut Workspace>) -> f64 {
        let n_planes = self.points.planes().len();
        let mut e = 0.0;
        if let Some(ws) = ws.as_deref_mut() {
            ws.validity.depth = 0.0;
        }
        if n_planes == 0 {
            return e;
        }
        if let Some(ws) = ws.as_deref_mut() {
            ws.contact_lane_grad.fill([0.0; LANES]);
        }
        let mut any_force = false;
        for (g, slots) in self.points.kept().chunks(LANES).enumerate() {
            let mut active = 0u32;
            for p in 0..n_planes {
                let gap = self.contacts.group_gap::<M>(g, p, q);
                if let Some(ws) = ws.as_deref_mut() {
                    gap[..slots.len()].iter().for_each(|&d| ws.validity.take_gap(d));
                }
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
            let x = self.contacts.group_positions::<M>(g, q);
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
                for (p, plane) in self.points.planes().iter().enumerate() {
                    let c = self.points.model().evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &xj, &xp);
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
                let w = self.contacts.group_basis(g);
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
                *g += lane_sum(a);
            }
        }
        e
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
        let n_planes = self.points.planes().len();
        let mut rows = 0;
        if n_planes == 0 {
            return 0;
        }
        for &j in self.points.kept() {
            let x = self.contact_position::<M>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let mut count = 0;
            for (p, plane) in self.points.planes().iter().enumerate() {
                let e = self.points.model().evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp);
                count = e.hessian.write_factors(&mut ws.contact_coef, count);
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
            used: vec![RankOneTerms::default(); self.points.kept().len() * self.points.planes().len()],
            gram: IncrementalGram::new(self.n),
            lagged,
        }
    }

    /// Brings `state` to the contact terms of the last [`Self::evaluate`] with
    /// gradient: the rows of the points whose terms changed are taken out of the
    /// matrix and their new rows put in, so that a contact state that does not
    /// change (sticking, resting) costs nothing ([`IncrementalGram`]). Returns
    /// the rows changed.
    pub fn update_contact_hessian(&self, ws: &mut Workspace, state: &mut ContactHessian) -> usize {
        let rebuild = state.gram.needs_rebuild();
        let (plus, minus, rows) = dispatch(ContactUpdateKernel { sys: self, ws: &mut *ws, state: &mut *state, rebuild });
        state.gram.update(&ws.contact_rows, plus, &ws.contact_rows_out, minus, rows);
        plus + minus
    }

    /// Rows in and out of an incremental update; returns their counts and the
    /// rows in the matrix afterwards.
    #[inline(always)]
    fn update_contact_impl<M: Madd>(&self, ws: &mut Workspace, state: &mut ContactHessian, rebuild: bool) -> (usize, usize, usize) {
        let n = self.n;
        let n_planes = self.points.planes().len();
        let (slack, cos) = if state.lagged { (CURVATURE_SLACK, DIRECTION_COS) } else { (1.0, 1.0) };
        let (mut plus, mut minus, mut rows) = (0, 0, 0);
        for (slot, &j) in self.points.kept().iter().enumerate() {
            let (mut count_in, mut count_out) = (0, 0);
            for p in 0..n_planes {
                let k = slot * n_planes + p;
                let (new, old) = (ws.contact_terms[k], state.used[k]);
                if !rebuild && (new.len == 0 && old.len == 0 || new.close_to(&old, slack, cos)) {
                    rows += old.len;
                    continue;
                }
                if !rebuild {
                    count_out = old.write_factors(&mut ws.contact_coef_out, count_out);
                }
                count_in = new.write_factors(&mut ws.contact_coef, count_in);
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
    /// added to `rhs` ([`crate::contact::ContactModel::stick_switch`]). Returns
    /// the number of rows; [`Self::add_switch_rows`] adds
    /// their product to a Hessian.
    pub fn stick_switch(&self, start: &StepStart, dir: &[f64], ws: &mut Workspace, rhs: &mut [f64]) -> usize {
        dispatch(StickKernel { sys: self, start, dir, ws, rhs })
    }

    /// The first `count` switch rows B of [`Self::stick_switch`], row-major, n
    /// wide: the switched matrix is the Newton matrix plus `B^T B`.
    pub fn switch_rows<'a>(&self, ws: &'a Workspace, count: usize) -> &'a [f64] {
        &ws.contact_rows[..count * self.n]
    }

    /// Adds the product of the first `count` switch rows of [`Self::stick_switch`]
    /// to the full symmetric `hess`.
    pub fn add_switch_rows(&self, ws: &Workspace, count: usize, hess: &mut [f64]) {
        add_gram(hess, self.n, &ws.contact_rows, count);
    }

    #[inline(always)]
    fn stick_impl<M: Madd>(&self, start: &StepStart, dir: &[f64], ws: &mut Workspace, rhs: &mut [f64]) -> usize {
        let n = self.n;
        let n_planes = self.points.planes().len();
        let mut rows = 0;
        for (g, slots) in self.points.kept().chunks(LANES).enumerate() {
            // Slipping points (all carry a lagged normal force, so they were
            // evaluated and their displacement kept).
            let mut slipping = 0u32;
            for (l, &j) in slots.iter().enumerate() {
                let dx = Vector3::from(ws.contact_dx[g * LANES + l]);
                for (p, plane) in self.points.planes().iter().enumerate() {
                    if self.points.model().slips(plane, self.areas[j], start.normal_force[j * n_planes + p], &dx) {
                        slipping |= 1 << l;
                    }
                }
            }
            if slipping == 0 {
                continue;
            }
            // Their motion along the direction, eight at a time.
            let wd = self.contacts.group_motion::<M>(g, dir);
            for (l, &j) in slots.iter().enumerate() {
                if slipping & (1 << l) == 0 {
                    continue;
                }
                let dx = Vector3::from(ws.contact_dx[g * LANES + l]);
                let wd = Vector3::new(wd[0][l], wd[1][l], wd[2][l]);
                let mut count = 0;
                let mut force = Vector3::zeros();
                for (p, plane) in self.points.planes().iter().enumerate() {
                    if let Some(switch) = self.points.model().stick_switch(plane, self.areas[j], start.normal_force[j * n_planes + p], &dx, &wd) {
                        for f in switch.factors {
                            ws.contact_coef[count] = [f.x, f.y, f.z];
                            count += 1;
                        }
                        force += switch.force;
                    }
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
        let n_planes = self.points.planes().len();
        for j in 0..self.n_contacts() {
            let x = self.contact_position::<Separate>(j, q);
            let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
            let mut f = Vector3::zeros();
            for (p, plane) in self.points.planes().iter().enumerate() {
                f -= self.points.model().evaluate(plane, self.areas[j], start.normal_force[j * n_planes + p], &x, &xp).gradient;
            }
            out[3 * j..3 * j + 3].copy_from_slice(f.as_slice());
        }
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
