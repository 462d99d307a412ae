//! The online error estimate's residual: the full model's equations of motion
//! at a fixed sample of vertices, at the reduced state.
//!
//! For sample s (lumped mass `m_s`, position `x_s` now, positions `x_s^i` at
//! the integrator's history, newest first, with its target weights `w_i` and
//! effective step h), with `f_s` the elastic force of its one ring
//! ([`VertexForces`]) and g gravity:
//!
//! `r_s = m_s (x_s - sum_i w_i x_s^i) / h^2 - m_s g - f_s`
//! (`f_s` with the material damping's force where the material has one: its
//! anchor from the states' q, kept from the steps before),
//! `du_s = B_s^-1 r_s` (`B_s^-1` the caller's 3 x 3 normalising block of the
//! sample, from its own stiffness and the step's inertia: licrom's
//! `error_estimate.normalising_inverse`),
//!
//! and the step's value is `M sum_s m_s |du_s|^2 / sum_s m_s` over the samples
//! that no plane touches now or at the step's start (contact forces are not
//! part of the residual; friction is lagged from the start), M the body's
//! mass. Positions are `x = c + R (rest + W q)` (world-frame models: c = 0,
//! R = I). The Python side (`python/licrom/reduced/error_estimate.py`) turns
//! these values into the run's estimate.
//!
//! It runs every few steps of every reduced run: as a dozen numpy calls after
//! a solver step (cold caches) it took 0.18 ms of a 0.2-0.5 ms step, and the
//! sample positions kept on the steps before 0.07 ms each. At r = 250 an
//! evaluation still took a settled step from 0.33 to 0.6 ms, so it is spread:
//! the damping reads the near vertices at the one or two states before the
//! step, and told how far the evaluation is ([`ResidualEstimate::record`]'s
//! `before`) the steps that record those states form them; the evaluation
//! itself is begun on its step ([`ResidualEstimate::prepare`]: the state's
//! near positions) and finished on the next ([`ResidualEstimate::finish`]).

use nalgebra::{Matrix3, Vector3};

use crate::error::{check_finite, check_output, check_positive, LicromError, Result};
use crate::reconstruction::Reconstruction;
use crate::vertex_forces::VertexForces;

/// Borrowed inputs of a [`ResidualEstimate`], for s samples among u near
/// vertices (the corners of the samples' ring tets) and n reduced coordinates.
#[derive(Debug, Clone, Copy)]
pub struct EstimateInputs<'a> {
    /// Basis rows of the near vertices, u x 3 x n (row-major).
    pub near_basis: &'a [f64],
    /// Rest term of their positions (`X` or `Xbar`), u x 3, m.
    pub near_rest: &'a [f64],
    /// Each sample's index among the near vertices, s.
    pub own: &'a [usize],
    /// Lumped masses of the samples, s, kg (> 0).
    pub masses: &'a [f64],
    /// Inverse normalising blocks `B_s^-1`, s x 3 x 3 (row-major), 1/(N/m).
    pub normaliser: &'a [f64],
    /// Gravity, m/s^2.
    pub gravity: [f64; 3],
    /// Contact planes `(n, d)` (`n . x + d >= 0` outside), p x 4.
    pub planes: &'a [f64],
    /// The integrator's target weights, newest first (2 or 4 of them).
    pub target: &'a [f64],
    /// The integrator's effective step, s (> 0).
    pub step: f64,
    /// The body's mass M, kg (> 0).
    pub total_mass: f64,
    /// The material's Kelvin-Voigt viscosity eta, Pa s (>= 0).
    pub viscosity: f64,
}

/// A rigid placement `x = c + R y` (body-frame models) or none (world frame).
pub type Placement<'a> = Option<(&'a Vector3<f64>, &'a Matrix3<f64>)>;

/// A [`Placement`] kept.
type OwnedPlacement = Option<(Vector3<f64>, Matrix3<f64>)>;

/// The residual at a vertex sample, with the sample positions of the steps
/// the integrator reads kept from step to step.
#[derive(Debug, Clone)]
pub struct ResidualEstimate {
    n: usize,
    /// Positions of the near vertices and of the samples (None without modes: the rest term).
    near_points: Option<Reconstruction>,
    near_rest: Vec<f64>,
    sample_points: Option<Reconstruction>,
    sample_rest: Vec<f64>,
    forces: VertexForces,
    own: Vec<usize>,
    masses: Vec<f64>,
    normaliser: Vec<Matrix3<f64>>,
    gravity: Vector3<f64>,
    planes: Vec<(Vector3<f64>, f64)>,
    target: Vec<f64>,
    h2: f64,
    total_mass: f64,
    /// Sample positions (s x 3 each) of the last `target.len()` states, newest first.
    history: Vec<Vec<f64>>,
    /// The material damping's `kappa = eta/h'` (0 without), its history weight
    /// w, the q of the last two states (newest first) and how many are known.
    kappa: f64,
    weight: f64,
    q_history: [Vec<f64>; 2],
    q_known: usize,
    /// The near vertices' body-frame positions at those two states, where
    /// formed when they were recorded (`near_known`).
    near_history: [Vec<f64>; 2],
    near_known: [bool; 2],
    /// The near vertices' body-frame positions at the state being recorded or evaluated.
    near: Vec<f64>,
    /// The placement of the state whose evaluation [`ResidualEstimate::prepare`]
    /// began, until [`ResidualEstimate::finish`] (None: none begun), and its q.
    pending: Option<OwnedPlacement>,
    pending_q: Vec<f64>,
    samples: Vec<f64>,
    force: Vec<f64>,
}

/// `rest + W q` by `points`, or the rest term where there are no modes.
fn body_positions(points: &Option<Reconstruction>, rest: &[f64], q: &[f64], out: &mut [f64]) -> Result<()> {
    match points {
        Some(points) => points.positions(q, out),
        None => {
            out.copy_from_slice(rest);
            Ok(())
        }
    }
}

impl ResidualEstimate {
    /// From the inputs and the ring forces of the samples (its points the near
    /// vertices, its samples these), after checking shapes, indices and values.
    pub fn new(inputs: &EstimateInputs<'_>, forces: VertexForces) -> Result<Self> {
        let EstimateInputs { near_basis, near_rest, own, masses, normaliser, gravity, planes, target, step, total_mass, viscosity } = *inputs;
        crate::error::check_non_negative("viscosity", viscosity)?;
        let (u, s) = (forces.n_points(), forces.n_samples());
        if near_rest.len() != 3 * u {
            return Err(LicromError::shape("near_rest", format!("({u}, 3)"), format!("{} values", near_rest.len())));
        }
        let n = if u == 0 { 0 } else { near_basis.len() / (3 * u) };
        if near_basis.len() != 3 * u * n {
            return Err(LicromError::shape("near_basis", format!("({u}, 3, n)"), format!("{} values", near_basis.len())));
        }
        for (name, len, shape) in [("own", own.len(), s), ("masses", masses.len(), s), ("normaliser", normaliser.len(), 9 * s)] {
            if len != shape {
                return Err(LicromError::shape(name, format!("({s}, ...)"), format!("{len} values")));
            }
        }
        if !planes.len().is_multiple_of(4) {
            return Err(LicromError::shape("planes", "(p, 4)", format!("{} values", planes.len())));
        }
        if !matches!(target.len(), 2 | 4) {
            return Err(LicromError::invalid("target", format!("must hold 2 or 4 weights, got {}", target.len())));
        }
        if let Some(&bad) = own.iter().find(|&&i| i >= u) {
            return Err(LicromError::invalid("own", format!("indices must be below the {u} near vertices, got {bad}")));
        }
        for (name, values) in
            [("near_basis", near_basis), ("near_rest", near_rest), ("normaliser", normaliser), ("planes", planes), ("target", target)]
        {
            check_finite(name, values)?;
        }
        check_finite("gravity", &gravity)?;
        if let Some(&m) = masses.iter().find(|&&m| !(m.is_finite() && m > 0.0)) {
            return Err(LicromError::invalid("masses", format!("must be finite and > 0, got {m}")));
        }
        check_positive("step", step)?;
        check_positive("total_mass", total_mass)?;
        let sample_basis: Vec<f64> = own.iter().flat_map(|&v| &near_basis[3 * n * v..3 * n * (v + 1)]).copied().collect();
        let sample_rest: Vec<f64> = own.iter().flat_map(|&v| &near_rest[3 * v..3 * v + 3]).copied().collect();
        let points = |basis: Vec<f64>, rest: &[f64]| (n > 0).then(|| Reconstruction::new(basis, rest.to_vec(), n)).transpose();
        Ok(Self {
            n,
            near_points: points(near_basis.to_vec(), near_rest)?,
            near_rest: near_rest.to_vec(),
            sample_points: points(sample_basis, &sample_rest)?,
            sample_rest,
            forces,
            own: own.to_vec(),
            masses: masses.to_vec(),
            normaliser: normaliser.chunks_exact(9).map(Matrix3::from_row_slice).collect(),
            gravity: Vector3::from(gravity),
            planes: planes.chunks_exact(4).map(|p| (Vector3::new(p[0], p[1], p[2]), p[3])).collect(),
            target: target.to_vec(),
            h2: step * step,
            total_mass,
            history: vec![vec![0.0; 3 * s]; target.len()],
            kappa: viscosity / step,
            // BDF2's target has four weights: its strain anchor (4 E_n - E_{n-1})/3.
            weight: if target.len() == 4 { 1.0 / 3.0 } else { 0.0 },
            q_history: [vec![0.0; n], vec![0.0; n]],
            q_known: 0,
            near_history: [vec![0.0; 3 * u], vec![0.0; 3 * u]],
            near_known: [false; 2],
            near: vec![0.0; 3 * u],
            pending: None,
            pending_q: vec![0.0; n],
            samples: vec![0.0; 3 * s],
            force: vec![0.0; 3 * s],
        })
    }

    /// Number of samples s.
    pub fn n_samples(&self) -> usize {
        self.own.len()
    }

    /// States the residual reads before the step (2 or 4).
    pub fn history_length(&self) -> usize {
        self.target.len()
    }

    /// Begins a run from the sample positions (`history_length` x s x 3, m) of
    /// the states before it, oldest first (the current state last).
    pub fn start(&mut self, positions: &[f64]) -> Result<()> {
        let (l, s) = (self.history_length(), self.n_samples());
        if positions.len() != 3 * s * l {
            return Err(LicromError::shape("history", format!("({l}, {s}, 3)"), format!("{} values", positions.len())));
        }
        check_finite("history", positions)?;
        for (kept, given) in self.history.iter_mut().zip(positions.chunks_exact(3 * s).rev()) {
            kept.copy_from_slice(given);
        }
        self.q_known = 0;
        self.near_known = [false; 2];
        self.pending = None;
        Ok(())
    }

    /// States before an evaluation whose near vertices the damping reads: 1,
    /// or 2 for BDF2 (0 without damping).
    fn damping_states(&self) -> usize {
        match (self.kappa > 0.0, self.weight != 0.0) {
            (false, _) => 0,
            (true, false) => 1,
            (true, true) => 2,
        }
    }

    /// `q` becomes the newest state's q of the damping's history, with the
    /// near positions in `self.near` where `near` (they are those of `q`).
    fn push_q(&mut self, q: &[f64], near: bool) {
        if self.kappa > 0.0 {
            self.q_history.swap(0, 1);
            self.q_history[0].copy_from_slice(q);
            self.q_known = (self.q_known + 1).min(2);
            self.near_history.swap(0, 1);
            self.near_known.swap(0, 1);
            if near {
                self.near_history[0].copy_from_slice(&self.near);
            }
            self.near_known[0] = near;
        }
    }

    /// Keeps the sample positions at `q` (and `placement`) as the newest state.
    ///
    /// `before`: steps from this one to the next evaluation, where known. The
    /// states the damping's anchor will read (1 and, for BDF2, 2 steps before)
    /// also keep their near vertices' positions, formed here rather than by
    /// the evaluation.
    pub fn record(&mut self, q: &[f64], placement: Placement<'_>, before: Option<usize>) -> Result<()> {
        self.check_state(q, placement)?;
        self.check_not_pending()?;
        let keep_near = before.is_some_and(|b| (1..=self.damping_states()).contains(&b));
        if keep_near {
            body_positions(&self.near_points, &self.near_rest, q, &mut self.near)?;
        }
        body_positions(&self.sample_points, &self.sample_rest, q, &mut self.samples)?;
        for x in self.samples.chunks_exact_mut(3) {
            let y = placed(Vector3::from_column_slice(x), placement);
            x.copy_from_slice(y.as_slice());
        }
        check_output("the sample positions", "q", &self.samples)?;
        self.push_samples();
        self.push_q(q, keep_near);
        Ok(())
    }

    /// `samples` becomes the newest state of the history, the oldest is dropped.
    fn push_samples(&mut self) {
        let mut oldest = self.history.pop().expect("a history of 2 or 4 states");
        oldest.copy_from_slice(&self.samples);
        self.history.insert(0, oldest);
    }

    /// The step's value `M sum m |du|^2 / sum m` over the free samples (0
    /// where none is free) at `q` (and `placement`), which becomes the newest
    /// state: [`Self::prepare`] and [`Self::finish`] at once.
    pub fn evaluate(&mut self, q: &[f64], placement: Placement<'_>) -> Result<f64> {
        self.prepare(q, placement)?;
        self.finish()
    }

    /// Begins the evaluation of `q` (and `placement`): its near vertices'
    /// positions. A run finishes it on the next step, so that the two halves'
    /// costs fall on two steps.
    pub fn prepare(&mut self, q: &[f64], placement: Placement<'_>) -> Result<()> {
        self.check_state(q, placement)?;
        self.check_not_pending()?;
        body_positions(&self.near_points, &self.near_rest, q, &mut self.near)?;
        self.pending_q.copy_from_slice(q);
        self.pending = Some(placement.map(|(c, r)| (*c, *r)));
        Ok(())
    }

    /// The value of the state [`Self::prepare`] began (see [`Self::evaluate`]),
    /// which becomes the newest state; an error where none was begun.
    pub fn finish(&mut self) -> Result<f64> {
        let owned = self.pending.take().ok_or_else(|| LicromError::invalid("finish", "no evaluation was prepared"))?;
        let placement = owned.as_ref().map(|(c, r)| (c, r));
        // The damping's anchor needs the states before the step (1, or 2 for BDF2); until they are
        // recorded (a run's first steps, where the stride is shorter than the history) it is left out.
        let needed = self.damping_states();
        if needed > 0 && self.q_known >= needed {
            // C is rotation invariant: the body-frame positions give the anchor of any placement.
            for i in 0..needed {
                if !self.near_known[i] {
                    body_positions(&self.near_points, &self.near_rest, &self.q_history[i], &mut self.near_history[i])?;
                    self.near_known[i] = true;
                }
            }
            let previous = (needed == 2).then(|| (&self.near_history[1][..], self.weight));
            self.forces.damped_forces(&self.near, self.kappa, &self.near_history[0], previous, &mut self.force)?;
        } else {
            self.forces.forces(&self.near, &mut self.force)?;
        }
        let (mut sum, mut counted) = (0.0, 0.0);
        for (s, &v) in self.own.iter().enumerate() {
            let x = placed(Vector3::from_column_slice(&self.near[3 * v..3 * v + 3]), placement);
            let f = Vector3::from_column_slice(&self.force[3 * s..3 * s + 3]);
            // F(c + R y) = R F(y) and P(R F) = R P(F): the forces turn with R.
            let f = placement.map_or(f, |(_, r)| r * f);
            let before = Vector3::from_column_slice(&self.history[0][3 * s..3 * s + 3]);
            let predicted = self
                .target
                .iter()
                .zip(&self.history)
                .fold(Vector3::zeros(), |acc, (w, h)| acc + *w * Vector3::from_column_slice(&h[3 * s..3 * s + 3]));
            let m = self.masses[s];
            let residual = m * (x - predicted) / self.h2 - m * self.gravity - f;
            let du = self.normaliser[s] * residual;
            if self.planes.iter().all(|(normal, offset)| normal.dot(&x).min(normal.dot(&before)) + offset >= 0.0) {
                sum += m * du.norm_squared();
                counted += m;
            }
            self.samples[3 * s..3 * s + 3].copy_from_slice(x.as_slice());
        }
        self.push_samples();
        let q = std::mem::take(&mut self.pending_q); // no copy: handed back below
        self.push_q(&q, true);
        self.pending_q = q;
        let value = if counted > 0.0 { self.total_mass * sum / counted } else { 0.0 };
        check_output("the residual", "q", &[value])?;
        Ok(value)
    }

    fn check_not_pending(&self) -> Result<()> {
        match self.pending {
            Some(_) => Err(LicromError::invalid("state", "an evaluation was prepared and not finished")),
            None => Ok(()),
        }
    }

    fn check_state(&self, q: &[f64], placement: Placement<'_>) -> Result<()> {
        if q.len() != self.n {
            return Err(LicromError::shape("q", format!("({},)", self.n), format!("{} values", q.len())));
        }
        check_finite("q", q)?;
        if let Some((c, r)) = placement {
            check_finite("center", c.as_slice())?;
            check_finite("rotation", r.as_slice())?;
        }
        Ok(())
    }
}

/// `c + R y` for a placement, y without one.
fn placed(y: Vector3<f64>, placement: Placement<'_>) -> Vector3<f64> {
    placement.map_or(y, |(c, r)| c + r * y)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::StableNeoHookean;
    use crate::testing::{rel_err, tet_shape_gradients, Rng};
    use crate::vertex_forces::RingInputs;

    /// One tet (0, 0, 0), x, y, z with its corner 3 as the sample, one mode
    /// moving the sample along x; masses 2 kg, normalising blocks a I.
    fn one_tet(planes: &[f64]) -> ResidualEstimate {
        one_tet_damped(planes, 0.0)
    }

    fn one_tet_damped(planes: &[f64], viscosity: f64) -> ResidualEstimate {
        one_tet_integrated(planes, viscosity, &[2.0, -1.0])
    }

    /// [`one_tet_damped`] with the integrator's target weights (4 of them: BDF2).
    fn one_tet_integrated(planes: &[f64], viscosity: f64, target: &[f64]) -> ResidualEstimate {
        let points = [Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()];
        let (grads, volumes) = tet_shape_gradients(&points, &[[0, 1, 2, 3]]);
        let rings = RingInputs { corners: &[0, 1, 2, 3], gradients: &grads, volumes: &volumes, owners: &[0], own_corners: &[3] };
        let forces = VertexForces::new(4, 1, &rings, StableNeoHookean::new(3.0e4, 5.0e4).unwrap()).unwrap();
        let mut basis = vec![0.0; 12];
        basis[9] = 1.0;
        let rest: Vec<f64> = points.iter().flat_map(|p| p.iter().copied()).collect();
        let normaliser = (Matrix3::identity() * 1e-3).transpose().as_slice().to_vec();
        let inputs = EstimateInputs {
            near_basis: &basis,
            near_rest: &rest,
            own: &[3],
            masses: &[2.0],
            normaliser: &normaliser,
            gravity: [0.0, 0.0, -9.81],
            planes,
            target,
            step: 0.01,
            total_mass: 5.0,
            viscosity,
        };
        ResidualEstimate::new(&inputs, forces).unwrap()
    }

    /// The material damping enters once the state before the step is recorded (a run's first
    /// evaluation without it leaves it out): the sample moved 1 cm along x from there.
    #[test]
    fn the_damping_force_enters_once_the_previous_state_is_known() {
        let value = |viscosity: f64, record: bool| {
            let mut est = one_tet_damped(&[], viscosity);
            est.start(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]).unwrap();
            if record {
                est.record(&[0.0], None, None).unwrap();
            }
            est.evaluate(&[0.01], None).unwrap()
        };
        assert_eq!(value(400.0, false), value(0.0, false));
        assert_eq!(value(0.0, true), value(0.0, false));
        assert!(value(400.0, true) != value(0.0, true));
    }

    /// The near positions of the damping's states formed on the steps that
    /// record them (told the evaluation's distance) give the value formed at
    /// the evaluation, to the bit, for backward Euler and BDF2.
    #[test]
    fn near_positions_kept_when_recorded_give_the_same_value() {
        for target in [&[2.0, -1.0][..], &[2.2, -1.4, 0.3, -0.1]] {
            let mut rng = Rng::new(7);
            let states: Vec<Vec<f64>> = (0..4).map(|_| rng.vec(1, 0.05)).collect();
            let value = |viscosity: f64, told: bool| {
                let mut est = one_tet_integrated(&[], viscosity, target);
                let history: Vec<f64> = (0..target.len()).flat_map(|_| [0.0, 0.0, 1.0]).collect();
                est.start(&history).unwrap();
                for (i, q) in states[..3].iter().enumerate() {
                    est.record(q, None, told.then_some(3 - i)).unwrap();
                }
                let kept = est.near_known;
                (est.evaluate(&states[3], None).unwrap(), kept)
            };
            let (told, kept) = value(400.0, true);
            let (untold, none) = value(400.0, false);
            assert_eq!(told, untold, "{target:?}");
            assert_eq!(kept, [true, target.len() == 4], "{target:?}: the states the damping reads, and no more");
            assert_eq!(none, [false, false]);
            assert!(told != value(0.0, true).0, "the damping enters");
        }
    }

    /// An evaluation begun on one step and finished on the next gives the
    /// value of one made at once, and the calls out of order are errors.
    #[test]
    fn a_prepared_evaluation_finishes_to_the_same_value() {
        let (c, r) = (Vector3::new(0.1, -0.2, 0.3), nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.4).into_inner());
        let run = |split: bool| {
            let mut est = one_tet_integrated(&[], 400.0, &[2.2, -1.4, 0.3, -0.1]);
            est.start(&[0.0, 0.0, 1.0].repeat(4)).unwrap();
            est.record(&[0.01], Some((&c, &r)), Some(2)).unwrap();
            est.record(&[0.02], Some((&c, &r)), Some(1)).unwrap();
            let value = if split {
                est.prepare(&[0.04], Some((&c, &r))).unwrap();
                assert!(est.record(&[0.0], None, None).is_err() && est.prepare(&[0.0], None).is_err());
                est.finish().unwrap()
            } else {
                est.evaluate(&[0.04], Some((&c, &r))).unwrap()
            };
            assert!(est.finish().is_err(), "nothing left to finish");
            (value, est.history.clone(), est.q_history.clone())
        };
        assert_eq!(run(true), run(false));
    }

    #[test]
    fn at_rest_the_residual_is_the_weight() {
        let mut est = one_tet(&[]);
        est.start(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]).unwrap();
        // At rest and not moving: no elastic force, no inertia; du = J (-m g), the value M m |du|^2 / m.
        let value = est.evaluate(&[0.0], None).unwrap();
        let du = 1e-3 * 2.0 * 9.81;
        assert!((value - 5.0 * du * du).abs() < 1e-12 * value, "{value}");
    }

    #[test]
    fn the_residual_is_inertia_weight_and_elastic_force_at_placed_positions() {
        let mut est = one_tet(&[]);
        // The sample was at z = 1 two steps ago and one step ago: predicted (0, 0, 1).
        est.start(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]).unwrap();
        let (c, r) = (Vector3::new(0.1, -0.2, 0.3), nalgebra::Rotation3::from_axis_angle(&Vector3::z_axis(), 0.4).into_inner());
        let q = [0.05];
        let value = est.evaluate(&q, Some((&c, &r))).unwrap();
        // By hand: the ring's force in the body frame, turned by R; the sample at c + R (z + 0.05 x).
        let mut force = vec![0.0; 3];
        let y = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.05, 0.0, 1.0];
        est.forces.forces(&y, &mut force).unwrap();
        let f = r * Vector3::from_column_slice(&force);
        let x = c + r * Vector3::new(0.05, 0.0, 1.0);
        let residual: Vector3<f64> = 2.0 * (x - Vector3::new(0.0, 0.0, 1.0)) / 1e-4 - 2.0 * Vector3::new(0.0, 0.0, -9.81) - f;
        let du = 1e-3 * residual;
        assert!(f.norm() > 1.0, "the deformed tet pushes back");
        assert!(rel_err(&[value], &[5.0 * du.norm_squared()], 0.0) < 1e-12, "{value}");
        // The evaluated state is the newest of the history.
        assert!(rel_err(&est.history[0], x.as_slice(), 0.0) < 1e-15);
        let mut rng = Rng::new(3);
        let q2 = rng.vec(1, 0.1);
        est.record(&q2, None, None).unwrap();
        assert_eq!(est.history[1], x.as_slice().to_vec());
        assert!(rel_err(&est.history[0], &[q2[0], 0.0, 1.0], 0.0) < 1e-15);
    }

    #[test]
    fn samples_touching_a_plane_are_left_out() {
        // The plane z >= 0.5 holds the sample (z = 1); z >= 2 does not.
        for (plane, free) in [([0.0, 0.0, 1.0, -0.5], true), ([0.0, 0.0, 1.0, -2.0], false)] {
            let mut est = one_tet(&plane);
            est.start(&[0.0, 0.0, 1.0, 0.0, 0.0, 1.0]).unwrap();
            let value = est.evaluate(&[0.0], None).unwrap();
            assert_eq!(value > 0.0, free, "{plane:?}: {value}");
        }
    }

    #[test]
    fn bad_input_is_rejected() {
        let mut est = one_tet(&[]);
        assert!(matches!(est.start(&[0.0; 3]), Err(LicromError::ShapeMismatch { .. })));
        assert!(matches!(est.evaluate(&[0.0, 1.0], None), Err(LicromError::ShapeMismatch { .. })));
        assert!(est.evaluate(&[f64::NAN], None).is_err());
        assert!(est.record(&[0.0], Some((&Vector3::new(f64::INFINITY, 0.0, 0.0), &Matrix3::identity())), None).is_err());
    }
}
