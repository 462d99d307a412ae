//! The state of a body-frame solver: its pose, the poses before it that the
//! time integrator reads ([`crate::integrator`]), the velocities read from
//! them, and setting them from outside (a new state, or a history of poses).

use nalgebra::{Matrix3, Vector3};

use super::{reorthonormalize, BodyFrameSolver, ROTATION_TOLERANCE};
use crate::body_frame::rotation::{exp_map, is_rotation, log_map};
use crate::body_frame::Pose;
use crate::error::{check_finite, LicromError, Result};
use crate::integrator::Integrator;

impl BodyFrameSolver {
    /// The pose `steps_back` (1, 2 or 3) steps before the current one: the
    /// history the integrator reads (after a new state, see [`Self::set_state`]).
    pub fn previous_pose(&self, steps_back: usize) -> Result<&Pose> {
        match steps_back {
            1 => Ok(&self.prev),
            2 => Ok(&self.prev2),
            3 => Ok(&self.prev3),
            other => Err(LicromError::invalid("steps_back", format!("must be 1, 2 or 3, got {other}"))),
        }
    }

    /// Velocity of the centre of mass, m/s: the integrator's
    /// ([`crate::integrator::Integrator::velocity_weights`]), `(c - c')/h` for
    /// backward Euler.
    pub fn velocity(&self) -> Vector3<f64> {
        let [a, b, c] = self.system.integrator().velocity_weights();
        (self.pose.center * a + self.prev.center * b + self.prev2.center * c) / self.system.dt()
    }

    /// Angular velocity in the world frame, rad/s: the integrator's from the
    /// turns `log(R R'^T)` of the last steps, `log(R R'^T) / h` for backward Euler.
    pub fn angular_velocity(&self) -> Vector3<f64> {
        // Weights (a, b, c) summing to zero: a (x - x') + (a + b) (x' - x'').
        let [a, b, _] = self.system.integrator().velocity_weights();
        let turn = log_map(&(self.pose.rotation * self.prev.rotation.transpose())) * a;
        let earlier = if a + b != 0.0 { log_map(&(self.prev.rotation * self.prev2.rotation.transpose())) * (a + b) } else { Vector3::zeros() };
        (turn + earlier) / self.system.dt()
    }

    /// Modal velocities into `out` (n), per second, as [`Self::velocity`].
    pub fn qdot(&self, out: &mut [f64]) {
        let h = self.system.dt();
        let [a, b, c] = self.system.integrator().velocity_weights();
        for (i, o) in out.iter_mut().enumerate() {
            *o = (a * self.pose.q[i] + b * self.prev.q[i] + c * self.prev2.q[i]) / h;
        }
    }

    fn check_vector(&self, name: &str, v: &[f64], len: usize) -> Result<()> {
        if v.len() != len {
            return Err(LicromError::shape(name, format!("({len},)"), format!("{} values", v.len())));
        }
        check_finite(name, v)
    }

    /// Checks the parts of a pose (`rotation` row-major 3 x 3, a rotation to
    /// [`ROTATION_TOLERANCE`]); returns the rotation made exactly orthonormal.
    fn check_pose(&self, center: &[f64], rotation: &[f64], q: &[f64]) -> Result<Matrix3<f64>> {
        self.check_vector("center", center, 3)?;
        self.check_vector("rotation", rotation, 9)?;
        self.check_vector("q", q, self.system.n_modes())?;
        let r = Matrix3::from_row_slice(rotation);
        if !is_rotation(&r, ROTATION_TOLERANCE) {
            return Err(LicromError::invalid("rotation", format!("must be orthonormal with determinant +1 (to {ROTATION_TOLERANCE})")));
        }
        Ok(reorthonormalize(&r))
    }

    /// A validated pose from its parts (see [`Self::set_state`]).
    pub fn make_pose(&self, center: &[f64], rotation: &[f64], q: &[f64]) -> Result<Pose> {
        let r = self.check_pose(center, rotation, q)?;
        Ok(Pose { center: Vector3::from_column_slice(center), rotation: r, q: q.to_vec() })
    }

    /// Replaces the state: pose and velocities (m/s, world angular velocity in
    /// rad/s, modal per second). The pose k steps back becomes
    /// `(c - k h v, exp(-k h [w]x) R, q - k h qdot)` (k = 1, 2, 3), with BDF2
    /// `c - k h v + (k h)^2 g/2` (a free fall, its start). Contact forces read zero until
    /// the next step, which starts with fresh elastic and contact Hessians, so
    /// that the steps from here depend on the state alone (the same as a new
    /// solver's, bit for bit).
    pub fn set_state(&mut self, pose: &Pose, velocity: &[f64], angular_velocity: &[f64], qdot: &[f64]) -> Result<()> {
        let n = self.system.n_modes();
        let rotation = self.check_pose(pose.center.as_slice(), pose.rotation.transpose().as_slice(), &pose.q)?;
        self.check_vector("velocity", velocity, 3)?;
        self.check_vector("angular_velocity", angular_velocity, 3)?;
        self.check_vector("qdot", qdot, n)?;
        let h = self.system.dt();
        let (v, w) = (Vector3::from_column_slice(velocity), Vector3::from_column_slice(angular_velocity));
        // BDF2 starts from the history of a free fall ([`crate::integrator`]); backward Euler reads one pose
        // back, whose difference to the current one is its velocity.
        let g = if self.system.integrator() == Integrator::Bdf2 { self.system.gravity() } else { Vector3::zeros() };
        // Checked at the farthest pose back, before anything changes: the nearer ones are then finite too.
        let far = 3.0 * h;
        let far_q_finite = pose.q.iter().zip(qdot).all(|(q, v)| (q - far * v).is_finite());
        let far_center = pose.center - v * far + g * (0.5 * far * far);
        if !(far_q_finite && far_center.iter().chain(exp_map(&(w * -far)).iter()).all(|v| v.is_finite())) {
            return Err(LicromError::Overflow { what: "the previous poses (pose - k dt x velocity)", input: "the velocities" });
        }
        for (k, earlier) in [&mut self.prev, &mut self.prev2, &mut self.prev3].into_iter().enumerate() {
            let back = h * (k + 1) as f64;
            earlier.center = pose.center - v * back + g * (0.5 * back * back);
            earlier.rotation = exp_map(&(w * -back)) * rotation;
            for ((p, q), v) in earlier.q.iter_mut().zip(&pose.q).zip(qdot) {
                *p = q - back * v;
            }
        }
        self.pose.assign(pose);
        self.pose.rotation = rotation;
        self.has_last = false;
        self.has_failed = false;
        self.has_prev2 = false;
        self.elastic_valid = false;
        self.newton_factor = false;
        self.contact.invalidate();
        Ok(())
    }

    /// Replaces the poses one, two and three steps back (`earlier`, nearest
    /// first) after [`Self::set_state`]: the history BDF2 reads, for a caller
    /// that has it as positions (the full simulation's start, fitted by poses)
    /// rather than as the velocities' extrapolation. Velocities then read from
    /// these poses.
    pub fn set_history(&mut self, earlier: [Pose; 3]) -> Result<()> {
        for pose in &earlier {
            self.check_pose(pose.center.as_slice(), pose.rotation.transpose().as_slice(), &pose.q)?;
        }
        let [p1, p2, p3] = earlier;
        (self.prev, self.prev2, self.prev3) = (p1, p2, p3);
        Ok(())
    }
}
