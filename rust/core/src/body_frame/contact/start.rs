//! What a step of the body-frame contact model reads from its start
//! ([`ContactStart`]): the points' lagged normal forces and anchor positions,
//! and the bounds that cull the points that cannot touch a plane.
//!
//! A point's gap is bounded from below through its body position `y` at some
//! q' and `|W_j (q - q')| <= |W_j|_2 |q - q'|`. Within a step q' is the step's
//! start, where the point has a position there; else the points' reference
//! `q_ref`, at which every point's position is kept (formed in one pass, again
//! when the body has deformed by more than [`REFERENCE_SLACK`] of its extent
//! since); else the rest shape (q' = 0).

use nalgebra::{Matrix3, Vector3};

use super::BodyContacts;
use crate::body_frame::Pose;
use crate::contact::Plane;
use crate::simd::{dispatch, Madd, WithMadd};

/// The points' reference body positions are formed again when the bound they
/// give has grown to this share of the points' extent (when
/// `max_j |W_j|_2 |q - q_ref|` exceeds `REFERENCE_SLACK x extent`). Every point
/// within that distance of a plane then goes on to its position at each step's
/// start. A pass over all points at every start (the |q| bound culled almost
/// none of a deformed body's) was a third of the body-frame step on the
/// 120k-tet cheese's 2000 contact points (profiled, r = 120); with the
/// reference, only the points near a plane cost (a slack of 0.2 or 0.5 was
/// measured no faster).
pub const REFERENCE_SLACK: f64 = 0.05;

/// Positions at the start of a step and lagged normal forces (per kept point and plane).
///
/// Also the body positions `y_s` at the start of the step's q (`q_start`) of
/// the points that might touch then (`has_y`). Within a step q moves little,
/// so `|W_s (q - q_start)|` bounds a point's gap much more tightly than
/// `|W_s q|`, and fewer points go on to their positions (measured:
/// docs/results.md section 8, "Solver choices, measured").
#[derive(Debug, Clone)]
pub struct ContactStart {
    pub(in crate::body_frame) x_prev: Vec<Vector3<f64>>,
    pub(in crate::body_frame) normal_force: Vec<f64>,
    y_start: Vec<Vector3<f64>>,
    has_y: Vec<bool>,
    q_start: Vec<f64>,
    /// Every point's body position at `q_ref` (empty `q_ref`: none yet), the
    /// culling's bound between starts (see [`REFERENCE_SLACK`]).
    y_ref: Vec<Vector3<f64>>,
    q_ref: Vec<f64>,
}

/// How far q is from the three places a gap is bounded from: the step's
/// start, the points' reference (none without one) and the rest shape.
pub(super) struct GapBounds {
    start: f64,
    reference: Option<f64>,
    rest: f64,
}

/// `|a - b|`.
fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

impl ContactStart {
    /// Keeps `other`'s points' body positions at its start pose and at its
    /// reference, for a start that alternates with it.
    pub(in crate::body_frame) fn keep_start(&mut self, other: &ContactStart) {
        self.y_start.clone_from(&other.y_start);
        self.has_y.clone_from(&other.has_y);
        self.q_start.clone_from(&other.q_start);
        self.y_ref.clone_from(&other.y_ref);
        self.q_ref.clone_from(&other.q_ref);
    }

    /// `|q - q_ref|`, or none without a reference.
    fn reference_distance(&self, q: &[f64]) -> Option<f64> {
        (!self.q_ref.is_empty()).then(|| distance(q, &self.q_ref))
    }

    /// The distances of `q` that bound the gaps within the step.
    pub(super) fn gap_bounds(&self, q: &[f64]) -> GapBounds {
        GapBounds { start: distance(q, &self.q_start), reference: self.reference_distance(q), rest: q.iter().map(|v| v * v).sum::<f64>().sqrt() }
    }
}

#[cfg(test)]
impl ContactStart {
    /// The same start without the points' start and reference positions:
    /// every gap is then bounded through `|q|` alone.
    pub(in crate::body_frame) fn without_start_positions(&self) -> Self {
        let mut out = self.clone();
        out.has_y.fill(false);
        out.q_ref.clear();
        out
    }
}

impl BodyContacts {
    /// Zeroed start-of-step buffers.
    pub fn start(&self) -> ContactStart {
        let c = self.rest.len();
        ContactStart {
            x_prev: vec![Vector3::zeros(); c],
            normal_force: vec![0.0; c * self.points.planes().len()],
            y_start: vec![Vector3::zeros(); c],
            has_y: vec![false; c],
            q_start: vec![0.0; self.n],
            y_ref: vec![Vector3::zeros(); c],
            q_ref: Vec::new(),
        }
    }

    /// The lagged normal forces of the points at `pose`, and the anchor
    /// positions of those that might touch a plane (the only ones that use
    /// them): at `pose`, or `x + w (x - x_prev)` with `anchor = (prev, w)`
    /// (BDF2's, [`crate::integrator`]).
    pub fn begin(&self, pose: &Pose, anchor: Option<(&Pose, f64)>, start: &mut ContactStart) {
        dispatch(BeginKernel { contacts: self, pose, anchor, start })
    }

    #[inline(always)]
    fn begin_impl<M: Madd>(&self, pose: &Pose, anchor: Option<(&Pose, f64)>, start: &mut ContactStart) {
        let n_planes = self.points.planes().len();
        let rt = pose.rotation.transpose();
        let ref_dist = match start.reference_distance(&pose.q) {
            Some(d) if self.max_reach * d <= REFERENCE_SLACK * self.extent => d,
            _ => {
                for (s, y) in start.y_ref.iter_mut().enumerate() {
                    *y = self.rest[s] + self.mode_motion::<M>(s, &pose.q);
                }
                start.q_ref.clone_from(&pose.q);
                0.0
            }
        };
        // The previous pose is usually the last call's: its points' body positions are then kept ones.
        let kept = anchor.is_some_and(|(prev, _)| start.q_start == prev.q);
        start.q_start.copy_from_slice(&pose.q);
        for s in 0..self.rest.len() {
            let forces = &mut start.normal_force[s * n_planes..(s + 1) * n_planes];
            forces.fill(0.0);
            let had_y = kept && start.has_y[s];
            start.has_y[s] = self.points.planes().iter().any(|plane| self.may_touch(plane, &pose.center, &rt, s, &start.y_ref[s], ref_dist));
            if !start.has_y[s] {
                continue;
            }
            // At the reference's own q the point's position is the reference's, by the same products.
            let y = if ref_dist == 0.0 { start.y_ref[s] } else { self.rest[s] + self.mode_motion::<M>(s, &pose.q) };
            let y_prev = had_y.then(|| start.y_start[s]);
            start.y_start[s] = y;
            let x = pose.center + pose.rotation * y;
            start.x_prev[s] = match anchor {
                Some((prev, w)) => {
                    x + w * (x - prev.center - prev.rotation * y_prev.unwrap_or_else(|| self.rest[s] + self.mode_motion::<M>(s, &prev.q)))
                }
                None => x,
            };
            for (f, plane) in forces.iter_mut().zip(self.points.planes()) {
                *f = self.points.model().lagged_normal_force(plane, self.areas[s], &x);
            }
        }
    }

    /// Whether point s may touch `plane` for the body at `center` turned by
    /// `rt^T`: its gap bounded from below through its body position `y` at some
    /// q' and `|W_s (q - q')| <= |W_s|_2 |q - q'|` (`dist` = |q - q'|).
    #[inline(always)]
    fn may_touch(&self, plane: &Plane, center: &Vector3<f64>, rt: &Matrix3<f64>, s: usize, y: &Vector3<f64>, dist: f64) -> bool {
        plane.gap(center) + (rt * plane.normal()).dot(y) - self.reach[s] * dist < 0.0
    }

    /// [`Self::may_touch`] within a step: from the point's start position where
    /// it has one, else from its reference position, else from its rest
    /// position (q' = 0).
    #[inline(always)]
    pub(super) fn may_touch_in_step(
        &self,
        plane: &Plane,
        center: &Vector3<f64>,
        rt: &Matrix3<f64>,
        s: usize,
        start: &ContactStart,
        bounds: &GapBounds,
    ) -> bool {
        match (start.has_y[s], bounds.reference) {
            (true, _) => self.may_touch(plane, center, rt, s, &start.y_start[s], bounds.start),
            (false, Some(ref_dist)) => self.may_touch(plane, center, rt, s, &start.y_ref[s], ref_dist),
            (false, None) => self.may_touch(plane, center, rt, s, &self.rest[s], bounds.rest),
        }
    }
}

struct BeginKernel<'a> {
    contacts: &'a BodyContacts,
    pose: &'a Pose,
    anchor: Option<(&'a Pose, f64)>,
    start: &'a mut ContactStart,
}

impl WithMadd for BeginKernel<'_> {
    type Output = ();
    #[inline(always)]
    fn run<M: Madd>(self) {
        self.contacts.begin_impl::<M>(self.pose, self.anchor, self.start)
    }
}
