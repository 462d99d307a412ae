//! Contact and friction at the contact points of the body-frame model.
//!
//! Point j sits at `x_j = c + R (Xbar_j + W_j q)`; its energy, gradient and
//! PSD Hessian in x come from [`ContactModel::evaluate`](crate::contact::ContactModel::evaluate) (the model of the
//! world-frame and full simulations), pulled back to `(c, omega, q)` through
//! `Jc = [I, -[p]x, R W_j]`, `p = R y_j`: gradient `[f; p x f; W_j^T R^T f]`,
//! Gauss-Newton Hessian `Jc^T H_x Jc` and, for the exact Hessian, the
//! geometric terms `sym(f p^T) - (f.p) I` (omega-omega) and `(R W_j^k) x f`
//! (omega-q_k). Points that cannot touch a plane and carry no lagged normal
//! force are culled by a lower bound on their gap, from the step's start or
//! the points' reference positions ([`ContactStart`]).
//!
//! **Incremental Hessian.** `Jc = R A_j T^T` with `A_j = [I, -[y_j]x, W_j]`
//! and `T = diag(R, R, I)`, so the Gauss-Newton contact Hessian is
//! `T S T^T` with `S = sum_j A_j^T (R^T H_x R) A_j`: the rotation of the body
//! moves out of the sum into the cheap congruence by T, and S depends on the
//! pose only through the points' terms seen from the body (`R^T d`) and their
//! body positions `y_j`. [`BodyContactHessian`] keeps S up to date as the
//! world-frame solver keeps its contact Hessian: the rows of the points whose
//! terms changed by more than the lag of [`crate::contact::RankOneTerms::close_to`],
//! or whose `y_j` moved by more than [`LEVER_SLACK`] of its length, are taken
//! out and put in again; the others cost nothing.
//!
//! **Stick switch**: friction's correction of a Newton direction
//! ([`crate::contact::ContactModel::stick_switch`]) with the points' motion
//! `Jc (dc, omega, dq)` and its rows `sqrt(c) d^T Jc`.

use nalgebra::{Matrix3, Vector3};

use super::Pose;
use crate::contact::{RankOneTerms, CURVATURE_SLACK, DIRECTION_COS};
use crate::contact_points::{ContactInputs, ContactPoints};
use crate::dense::{add_gram, rows_dot, IncrementalGram};
use crate::error::Result;
use crate::simd::{dispatch, Madd, Separate, WithMadd};
use crate::validity::Validity;

mod start;
pub use start::{ContactStart, REFERENCE_SLACK};

/// The incremental contact Hessian keeps a point's rows while its body
/// position `y_j` has moved by less than this share of its length since they
/// were formed: the rows' rotational part `y_j x d` is then off by at most as
/// much, the lag the world-frame solver allows its terms.
pub const LEVER_SLACK: f64 = 0.1;

/// The contact points with non-zero area (the kept points of
/// [`ContactPoints`]), with their rest positions, basis rows and areas in
/// the order kept (slot s).
#[derive(Debug, Clone)]
pub struct BodyContacts {
    n: usize,
    /// Which points carry area, the planes and the contact model.
    points: ContactPoints,
    rest: Vec<Vector3<f64>>,
    /// `W_j`, 3 x n row-major per kept point.
    basis: Vec<f64>,
    /// `|W_j|_2` (largest singular value), m per unit of q: `|W_j q| <= reach |q|`.
    reach: Vec<f64>,
    /// The largest of `reach`.
    max_reach: f64,
    /// Largest distance of a point's rest position from their centroid, m.
    extent: f64,
    areas: Vec<f64>,
}

/// Scratch for rows of the Hessian (N = 6 + n wide, row-major): the
/// Gauss-Newton rows `sqrt(coef) d^T Jc` of an evaluation, the rows put in
/// (`rows`) and taken out (`out`) by an incremental update, the stick switch's.
#[derive(Debug, Clone)]
pub struct ContactRows {
    rows: Vec<f64>,
    out: Vec<f64>,
    /// Rows of the last evaluation that asked for them.
    pub(super) count: usize,
}

/// What an evaluation with gradient leaves for the Hessian and the stick
/// switch: the Hessian terms of each kept point and plane with their
/// directions seen from the body (`R^T d`; none where the point was culled),
/// and, for the points evaluated, their body position `y_j` and displacement
/// `x_j - x_prev` (m).
#[derive(Debug, Clone)]
pub struct ContactTerms {
    terms: Vec<RankOneTerms>,
    y: Vec<Vector3<f64>>,
    dx: Vec<Vector3<f64>>,
}

/// The contact part `T S T^T` of the Newton matrix (see the module
/// documentation), S kept up to date incrementally.
#[derive(Debug, Clone)]
pub struct BodyContactHessian {
    /// The terms (seen from the body) and body positions in S, per kept point and plane / point.
    used: Vec<RankOneTerms>,
    used_y: Vec<Vector3<f64>>,
    gram: IncrementalGram,
}

impl BodyContactHessian {
    /// S, N x N full symmetric.
    pub fn body_matrix(&self) -> &[f64] {
        self.gram.matrix()
    }

    /// Forms S from scratch at the next update (after a new state, so that the
    /// steps after it depend on the state alone).
    pub fn invalidate(&mut self) {
        self.gram.invalidate();
    }
}

/// What an evaluation computes besides the energy.
pub(super) struct ContactOut<'a> {
    /// Gradient to add to (N).
    pub grad: Option<&'a mut [f64]>,
    /// Rows of the Gauss-Newton Hessian, and the dense N x N matrix that gets
    /// the geometric terms (exact Hessian only).
    pub rows: Option<&'a mut ContactRows>,
    pub geometric: Option<&'a mut [f64]>,
    /// The points' terms, for the incremental Hessian and the stick switch.
    pub terms: Option<&'a mut ContactTerms>,
    /// Deepest penetration of an engaged point into a plane, m (set, not added to).
    pub depth: Option<&'a mut f64>,
}

/// `out += T S T^T` for `T = diag(R, R, I)` (N x N, full symmetric) in the
/// rows and columns of c and omega; the modal block of `T S T^T` is S's own
/// (the caller adds it in its pass over that block).
pub fn add_rotated_rigid(s: &[f64], r: &Matrix3<f64>, big: usize, out: &mut [f64]) {
    for a in [0, 3] {
        for j in 6..big {
            let v = r * Vector3::new(s[a * big + j], s[(a + 1) * big + j], s[(a + 2) * big + j]);
            for k in 0..3 {
                out[(a + k) * big + j] += v[k];
                out[j * big + a + k] += v[k];
            }
        }
        for b in [0, 3] {
            let m = r * Matrix3::from_fn(|i, j| s[(a + i) * big + b + j]) * r.transpose();
            for i in 0..3 {
                for j in 0..3 {
                    out[(a + i) * big + b + j] += m[(i, j)];
                }
            }
        }
    }
}

/// Largest singular value of the 3 x n row-major `w`: the square root of the
/// largest eigenvalue of `w w^T`. It bounds `|w q|` by up to sqrt(3) more
/// tightly than the Frobenius norm, and the bound decides which points are
/// evaluated at all.
fn spectral_norm(w: &[f64], n: usize) -> f64 {
    let gram = Matrix3::from_fn(|a, b| (0..n).map(|i| w[a * n + i] * w[b * n + i]).sum::<f64>());
    gram.symmetric_eigenvalues().max().max(0.0).sqrt()
}

impl BodyContacts {
    /// Validated contact points of a model with n modes ([`ContactPoints::new`],
    /// rest positions Xbar_j), the contact model with the effective step `h` (s).
    pub fn new(n: usize, inp: &ContactInputs<'_>, h: f64) -> Result<Self> {
        let points = ContactPoints::new(inp, n, h)?;
        let rows = |j: usize| &inp.basis[3 * n * j..3 * n * (j + 1)];
        let kept = points.kept();
        let rest: Vec<Vector3<f64>> = kept.iter().map(|&j| Vector3::from_column_slice(&inp.rest[3 * j..3 * j + 3])).collect();
        let centroid = rest.iter().sum::<Vector3<f64>>() / rest.len().max(1) as f64;
        let reach: Vec<f64> = kept.iter().map(|&j| spectral_norm(rows(j), n)).collect();
        Ok(Self {
            n,
            basis: kept.iter().flat_map(|&j| rows(j).iter().copied()).collect(),
            max_reach: reach.iter().fold(0.0, |m: f64, &r| m.max(r)),
            extent: rest.iter().fold(0.0, |m: f64, y| m.max((y - centroid).norm())),
            rest,
            reach,
            areas: kept.iter().map(|&j| inp.areas[j]).collect(),
            points,
        })
    }

    /// Number of contact points given.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether no contact point was given.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Whether any contact term can be non-zero (points with area and planes).
    pub fn any(&self) -> bool {
        self.points.any()
    }

    /// Row scratch for the Hessian (up to three rows per point and plane).
    pub fn rows(&self) -> ContactRows {
        let len = 3 * self.rest.len() * self.points.planes().len() * (6 + self.n);
        ContactRows { rows: vec![0.0; len], out: vec![0.0; len], count: 0 }
    }

    /// Buffers for the terms of an evaluation.
    pub fn terms(&self) -> ContactTerms {
        let c = self.rest.len();
        ContactTerms {
            terms: vec![RankOneTerms::default(); c * self.points.planes().len()],
            y: vec![Vector3::zeros(); c],
            dx: vec![Vector3::zeros(); c],
        }
    }

    /// An empty incremental contact Hessian, formed at its first update.
    pub fn hessian_state(&self) -> BodyContactHessian {
        let c = self.rest.len();
        BodyContactHessian {
            used: vec![RankOneTerms::default(); c * self.points.planes().len()],
            used_y: vec![Vector3::zeros(); c],
            gram: IncrementalGram::new(6 + self.n),
        }
    }

    /// `W_s v` of kept point `s` (v: n).
    #[inline(always)]
    fn mode_motion<M: Madd>(&self, s: usize, v: &[f64]) -> Vector3<f64> {
        let n = self.n;
        Vector3::from(rows_dot::<M, 3>(&self.basis[3 * n * s..3 * n * (s + 1)], v))
    }

    /// Contact energy (J) at `pose`, with the parts of `out` requested.
    pub(super) fn evaluate(&self, start: &ContactStart, pose: &Pose, out: ContactOut<'_>) -> f64 {
        dispatch(EvaluateKernel { contacts: self, start, pose, out })
    }

    #[inline(always)]
    fn evaluate_impl<M: Madd>(&self, start: &ContactStart, pose: &Pose, mut out: ContactOut<'_>) -> f64 {
        let n = self.n;
        let big = 6 + n;
        let n_planes = self.points.planes().len();
        let r = &pose.rotation;
        let rt = r.transpose();
        let bounds = start.gap_bounds(&pose.q);
        if let Some(rows) = out.rows.as_deref_mut() {
            rows.count = 0;
        }
        let mut energy = 0.0;
        let mut validity = Validity::default();
        let track = out.depth.is_some();
        for s in 0..self.rest.len() {
            // Lower bound of each gap; a plane is skipped where it cannot be
            // reached and the point carries no lagged force against it.
            let forces = &start.normal_force[s * n_planes..(s + 1) * n_planes];
            let engaged = self
                .points
                .planes()
                .iter()
                .zip(forces)
                .any(|(plane, &f)| f > 0.0 || self.may_touch_in_step(plane, &pose.center, &rt, s, start, &bounds));
            if !engaged {
                if let Some(terms) = out.terms.as_deref_mut() {
                    for t in &mut terms.terms[s * n_planes..(s + 1) * n_planes] {
                        t.len = 0;
                    }
                }
                continue;
            }
            let y = self.rest[s] + self.mode_motion::<M>(s, &pose.q);
            let p = r * y;
            let x = pose.center + p;
            let mut f = Vector3::zeros();
            for (k, (plane, &fn_lag)) in self.points.planes().iter().zip(forces).enumerate() {
                if track {
                    validity.take_gap(plane.gap(&x));
                }
                let e = self.points.model().evaluate(plane, self.areas[s], fn_lag, &x, &start.x_prev[s]);
                energy += e.energy;
                f += e.gradient;
                if let Some(rows) = out.rows.as_deref_mut() {
                    for t in 0..e.hessian.len {
                        let d = e.hessian.dir[t] * e.hessian.coef[t].sqrt();
                        self.world_row::<M>(s, &p, &rt, &d, &mut rows.rows[rows.count * big..(rows.count + 1) * big]);
                        rows.count += 1;
                    }
                }
                if let Some(terms) = out.terms.as_deref_mut() {
                    terms.terms[s * n_planes + k] = e.hessian.rotated(&rt);
                }
            }
            if let Some(terms) = out.terms.as_deref_mut() {
                terms.y[s] = y;
                terms.dx[s] = x - start.x_prev[s];
            }
            if f == Vector3::zeros() {
                continue;
            }
            if let Some(g) = out.grad.as_deref_mut() {
                let pf = p.cross(&f);
                for i in 0..3 {
                    g[i] += f[i];
                    g[3 + i] += pf[i];
                }
                self.pull_back::<M>(s, &(rt * f), &mut g[6..], true);
            }
            if let Some(h) = out.geometric.as_deref_mut() {
                let fp = f * p.transpose();
                let ww = 0.5 * (fp + fp.transpose()) - Matrix3::identity() * f.dot(&p);
                for i in 0..3 {
                    for j in 0..3 {
                        h[(3 + i) * big + 3 + j] += ww[(i, j)];
                    }
                }
                let w = &self.basis[3 * n * s..3 * n * (s + 1)];
                for k in 0..n {
                    let rw = r * Vector3::new(w[k], w[n + k], w[2 * n + k]);
                    let v = rw.cross(&f);
                    for i in 0..3 {
                        h[(3 + i) * big + 6 + k] += v[i];
                        h[(6 + k) * big + 3 + i] += v[i];
                    }
                }
            }
        }
        if let Some(depth) = out.depth {
            *depth = validity.depth;
        }
        energy
    }

    /// `out (+)= W_s^T v` (n).
    #[inline(always)]
    fn pull_back<M: Madd>(&self, s: usize, v: &Vector3<f64>, out: &mut [f64], add: bool) {
        let n = self.n;
        let w = &self.basis[3 * n * s..3 * n * (s + 1)];
        let (wx, rest) = w.split_at(n);
        let (wy, wz) = rest.split_at(n);
        for (((o, a), b), c) in out.iter_mut().zip(wx).zip(wy).zip(wz) {
            let x = M::madd(*c, v.z, M::madd(*b, v.y, a * v.x));
            *o = if add { *o + x } else { x };
        }
    }

    /// The row `[d, p x d, W_s^T R^T d]` of a world-frame vector d at point s
    /// (`p = R y_s`, `rt` = R^T) into `row` (N).
    #[inline(always)]
    fn world_row<M: Madd>(&self, s: usize, p: &Vector3<f64>, rt: &Matrix3<f64>, d: &Vector3<f64>, row: &mut [f64]) {
        row[..3].copy_from_slice(d.as_slice());
        row[3..6].copy_from_slice(p.cross(d).as_slice());
        self.pull_back::<M>(s, &(rt * d), &mut row[6..], false);
    }

    /// The rows `[d, y x d, W_s^T d]` of the square-root factors of `terms`
    /// (directions seen from the body) at point s with body position y, into
    /// `out` from row `at` on; returns the row after them.
    #[inline(always)]
    fn body_rows<M: Madd>(&self, s: usize, y: &Vector3<f64>, terms: &RankOneTerms, out: &mut [f64], at: usize) -> usize {
        let big = 6 + self.n;
        let mut factors = [[0.0; 3]; 3];
        let count = terms.write_factors(&mut factors, 0);
        for (i, f) in factors[..count].iter().enumerate() {
            let d = Vector3::from(*f);
            let row = &mut out[(at + i) * big..(at + i + 1) * big];
            row[..3].copy_from_slice(d.as_slice());
            row[3..6].copy_from_slice(y.cross(&d).as_slice());
            self.pull_back::<M>(s, &d, &mut row[6..], false);
        }
        at + count
    }

    /// The first `count` rows in `rows`, row-major, N wide.
    pub(super) fn switch_rows<'a>(&self, rows: &'a ContactRows, count: usize) -> &'a [f64] {
        &rows.rows[..count * (6 + self.n)]
    }

    /// Adds `B^T B` of the first `count` rows in `rows` to the full symmetric `hess` (N x N).
    pub(super) fn add_rows(&self, rows: &ContactRows, count: usize, hess: &mut [f64]) {
        add_gram(hess, 6 + self.n, &rows.rows, count);
    }

    /// Brings `state` to the terms of the last evaluation with gradient
    /// (see the module documentation); `rows` is scratch. Returns the rows
    /// changed.
    pub fn update_hessian(&self, terms: &ContactTerms, rows: &mut ContactRows, state: &mut BodyContactHessian) -> usize {
        let (plus, minus, total) = dispatch(UpdateKernel { contacts: self, terms, rows: &mut *rows, state: &mut *state });
        state.gram.update(&rows.rows, plus, &rows.out, minus, total);
        plus + minus
    }

    /// The rows in and out of an incremental update; returns their counts and
    /// the rows in the matrix afterwards. Where the rows to take out and put in
    /// outnumber the rows of the matrix afterwards (the points switching between
    /// stick and slip while a landing settles), forming it from scratch costs
    /// less, and is done.
    #[inline(always)]
    fn update_rows_impl<M: Madd>(&self, terms: &ContactTerms, rows: &mut ContactRows, state: &mut BodyContactHessian) -> (usize, usize, usize) {
        let n_planes = self.points.planes().len();
        let kept = |s: usize, state: &BodyContactHessian| {
            let range = s * n_planes..(s + 1) * n_planes;
            let (new, old) = (&terms.terms[range.clone()], &state.used[range]);
            let has_rows = new.iter().any(|t| t.len > 0);
            new.iter().zip(old).all(|(a, b)| a.len == 0 && b.len == 0 || a.close_to(b, CURVATURE_SLACK, DIRECTION_COS))
                && (!has_rows || (terms.y[s] - state.used_y[s]).norm() <= LEVER_SLACK * state.used_y[s].norm())
        };
        let rows_of = |t: &[RankOneTerms]| t.iter().map(|t| t.len).sum::<usize>();
        let mut rebuild = state.gram.needs_rebuild();
        if !rebuild {
            let (mut changed, mut total) = (0, 0);
            for s in 0..self.rest.len() {
                let range = s * n_planes..(s + 1) * n_planes;
                if kept(s, state) {
                    total += rows_of(&state.used[range]);
                } else {
                    let new = rows_of(&terms.terms[range.clone()]);
                    changed += rows_of(&state.used[range]) + new;
                    total += new;
                }
            }
            if changed > total {
                state.gram.invalidate();
                rebuild = true;
            }
        }
        let (mut plus, mut minus, mut total) = (0, 0, 0);
        for s in 0..self.rest.len() {
            let range = s * n_planes..(s + 1) * n_planes;
            if !rebuild && kept(s, state) {
                total += rows_of(&state.used[range]);
                continue;
            }
            let y = terms.y[s];
            for (a, b) in terms.terms[range.clone()].iter().zip(&state.used[range.clone()]) {
                if !rebuild {
                    minus = self.body_rows::<M>(s, &state.used_y[s], b, &mut rows.out, minus);
                }
                plus = self.body_rows::<M>(s, &y, a, &mut rows.rows, plus);
                total += a.len;
            }
            state.used[range.clone()].copy_from_slice(&terms.terms[range]);
            state.used_y[s] = y;
        }
        (plus, minus, total)
    }

    /// Stick switch of the direction `dir` (`(dc, omega, dq)`) from `pose`, the
    /// point of the last evaluation with gradient (whose terms are `terms`):
    /// the rows of the Hessian change of every slipping point that `dir` would
    /// carry into the stick region go into `rows` (returns their number), and
    /// the change of the gradient `Jc^T (stick force - slip force)` is added to
    /// `rhs` (N).
    pub fn stick_switch(
        &self,
        start: &ContactStart,
        pose: &Pose,
        dir: &[f64],
        terms: &ContactTerms,
        rows: &mut ContactRows,
        rhs: &mut [f64],
    ) -> usize {
        dispatch(StickKernel { contacts: self, start, pose, dir, terms, rows, rhs })
    }

    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn stick_impl<M: Madd>(
        &self,
        start: &ContactStart,
        pose: &Pose,
        dir: &[f64],
        terms: &ContactTerms,
        rows: &mut ContactRows,
        rhs: &mut [f64],
    ) -> usize {
        let big = 6 + self.n;
        let n_planes = self.points.planes().len();
        let r = &pose.rotation;
        let rt = r.transpose();
        let (dc, w) = (Vector3::new(dir[0], dir[1], dir[2]), Vector3::new(dir[3], dir[4], dir[5]));
        let mut count = 0;
        for s in 0..self.rest.len() {
            // Slipping points carry a lagged normal force: they were evaluated.
            let forces = &start.normal_force[s * n_planes..(s + 1) * n_planes];
            let dx = terms.dx[s];
            if !self.points.planes().iter().zip(forces).any(|(plane, &f)| self.points.model().slips(plane, self.areas[s], f, &dx)) {
                continue;
            }
            let p = r * terms.y[s];
            let motion = dc + w.cross(&p) + r * self.mode_motion::<M>(s, &dir[6..]);
            let mut force = Vector3::zeros();
            for (plane, &f) in self.points.planes().iter().zip(forces) {
                if let Some(switch) = self.points.model().stick_switch(plane, self.areas[s], f, &dx, &motion) {
                    for d in &switch.factors {
                        self.world_row::<M>(s, &p, &rt, d, &mut rows.rows[count * big..(count + 1) * big]);
                        count += 1;
                    }
                    force += switch.force;
                }
            }
            if force != Vector3::zeros() {
                let pf = p.cross(&force);
                for i in 0..3 {
                    rhs[i] += force[i];
                    rhs[3 + i] += pf[i];
                }
                self.pull_back::<M>(s, &(rt * force), &mut rhs[6..], true);
            }
        }
        count
    }

    /// Contact force (N) on every given point at `pose` over the step that
    /// started at `start`: C x 3, zero for points without area.
    pub fn forces(&self, start: &ContactStart, pose: &Pose, out: &mut [f64]) {
        out.fill(0.0);
        let n_planes = self.points.planes().len();
        for (s, &j) in self.points.kept().iter().enumerate() {
            let x = pose.center + pose.rotation * (self.rest[s] + self.mode_motion::<Separate>(s, &pose.q));
            let mut f = Vector3::zeros();
            for (p, plane) in self.points.planes().iter().enumerate() {
                f -= self.points.model().evaluate(plane, self.areas[s], start.normal_force[s * n_planes + p], &x, &start.x_prev[s]).gradient;
            }
            out[3 * j..3 * j + 3].copy_from_slice(f.as_slice());
        }
    }
}

struct EvaluateKernel<'a> {
    contacts: &'a BodyContacts,
    start: &'a ContactStart,
    pose: &'a Pose,
    out: ContactOut<'a>,
}

impl WithMadd for EvaluateKernel<'_> {
    type Output = f64;
    #[inline(always)]
    fn run<M: Madd>(self) -> f64 {
        self.contacts.evaluate_impl::<M>(self.start, self.pose, self.out)
    }
}

struct UpdateKernel<'a> {
    contacts: &'a BodyContacts,
    terms: &'a ContactTerms,
    rows: &'a mut ContactRows,
    state: &'a mut BodyContactHessian,
}

impl WithMadd for UpdateKernel<'_> {
    type Output = (usize, usize, usize);
    #[inline(always)]
    fn run<M: Madd>(self) -> (usize, usize, usize) {
        self.contacts.update_rows_impl::<M>(self.terms, self.rows, self.state)
    }
}

struct StickKernel<'a> {
    contacts: &'a BodyContacts,
    start: &'a ContactStart,
    pose: &'a Pose,
    dir: &'a [f64],
    terms: &'a ContactTerms,
    rows: &'a mut ContactRows,
    rhs: &'a mut [f64],
}

impl WithMadd for StickKernel<'_> {
    type Output = usize;
    #[inline(always)]
    fn run<M: Madd>(self) -> usize {
        self.contacts.stick_impl::<M>(self.start, self.pose, self.dir, self.terms, self.rows, self.rhs)
    }
}
