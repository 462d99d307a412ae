//! Many independent reduced simulations stepped at once, spread over threads.
//!
//! Each simulation owns its model, state and buffers, so the simulations share
//! nothing: [`step_many`] hands whole simulations to worker threads (the next
//! one to the first free thread, as their steps differ in cost), and each
//! simulation takes its steps exactly as it would alone. The results are
//! therefore the same, bit for bit, for any number of threads.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use crate::body_frame::solver::BodyFrameSolver;
use crate::error::{LicromError, Result};
use crate::second_thread;
use crate::solver::ReducedSolver;

/// A simulation that [`step_many`] can step: one time step, and the
/// continuation from the last iterate of a step that did not converge.
pub trait Stepper: Send {
    /// Advances one time step; returns (iterations, residual in m/s).
    fn step_once(&mut self) -> Result<(usize, f64)>;
    /// Takes the last iterate of a step that just failed to converge as the state.
    fn accept_last_iterate(&mut self) -> Result<()>;
}

impl Stepper for ReducedSolver {
    fn step_once(&mut self) -> Result<(usize, f64)> {
        self.step().map(|r| (r.iterations, r.residual))
    }

    fn accept_last_iterate(&mut self) -> Result<()> {
        ReducedSolver::accept_last_iterate(self)
    }
}

impl Stepper for BodyFrameSolver {
    fn step_once(&mut self) -> Result<(usize, f64)> {
        self.step().map(|r| (r.iterations, r.residual))
    }

    fn accept_last_iterate(&mut self) -> Result<()> {
        BodyFrameSolver::accept_last_iterate(self)
    }
}

/// What a simulation does when a step fails to converge (a step that diverges,
/// NaN or inf, stops it either way).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OnFailure {
    /// Stop this simulation, its state at the start of the failed step.
    Stop,
    /// Record the step as unconverged, take its last iterate and go on.
    Record,
}

/// One simulation of a batch and its failure policy.
pub struct BatchItem<'a> {
    /// The simulation.
    pub sim: &'a mut dyn Stepper,
    /// What it does on a failed step.
    pub on_failure: OnFailure,
}

/// One step of one simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepOutcome {
    /// Iterations of the step (for a failed step: as far as it went).
    pub iterations: usize,
    /// Final convergence measure, m/s (NaN when a step diverged).
    pub residual: f64,
    /// Whether the step converged.
    pub converged: bool,
}

/// The steps one simulation took, and the error that stopped it, if any.
#[derive(Debug, Clone, Default)]
pub struct SimOutcome {
    /// One entry per step taken (recorded failures included).
    pub steps: Vec<StepOutcome>,
    /// The error that stopped the simulation before it took all its steps.
    pub error: Option<LicromError>,
}

/// Steps `item` `steps` times, as a loop of single steps would.
fn run_one(item: &mut BatchItem<'_>, steps: usize) -> SimOutcome {
    let mut out = SimOutcome { steps: Vec::with_capacity(steps), error: None };
    for _ in 0..steps {
        match item.sim.step_once() {
            Ok((iterations, residual)) => out.steps.push(StepOutcome { iterations, residual, converged: true }),
            Err(e) => {
                let failed = match e {
                    LicromError::NotConverged { iterations, residual } => StepOutcome { iterations, residual, converged: false },
                    // NaN or inf (a divergence) leaves no finite iterate to go on from:
                    // it stops the simulation whatever `on_failure` says.
                    _ => {
                        out.error = Some(e);
                        break;
                    }
                };
                if item.on_failure == OnFailure::Stop {
                    out.error = Some(e);
                    break;
                }
                if let Err(e) = item.sim.accept_last_iterate() {
                    out.error = Some(e);
                    break;
                }
                out.steps.push(failed);
            }
        }
    }
    out
}

/// Steps every simulation of `items` `steps` times on up to `threads` threads
/// (the calling thread included); returns one outcome per item, in order.
///
/// A simulation that fails stops alone (see [`OnFailure`]); the others take
/// all their steps.
///
/// # Errors
/// `threads` is zero.
pub fn step_many(items: &mut [BatchItem<'_>], steps: usize, threads: usize) -> Result<Vec<SimOutcome>> {
    if threads == 0 {
        return Err(LicromError::invalid("threads", "must be >= 1, got 0"));
    }
    let workers = threads.min(items.len());
    if workers <= 1 {
        return Ok(items.iter_mut().map(|item| run_one(item, steps)).collect());
    }
    // Each slot is taken by exactly one thread (the counter hands out every
    // index once), so its lock is never contended: it only proves that to the
    // compiler.
    let slots: Vec<Mutex<(&mut BatchItem<'_>, SimOutcome)>> = items.iter_mut().map(|item| Mutex::new((item, SimOutcome::default()))).collect();
    let next = AtomicUsize::new(0);
    // The workers have the cores: each step's products stay on its own thread.
    let work = || {
        second_thread::alone(|| loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(slot) = slots.get(i) else { break };
            let mut slot = slot.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            let (item, outcome) = &mut *slot;
            *outcome = run_one(item, steps);
        })
    };
    std::thread::scope(|scope| {
        for _ in 1..workers {
            scope.spawn(work);
        }
        work();
    });
    Ok(slots.into_iter().map(|slot| slot.into_inner().unwrap_or_else(|poisoned| poisoned.into_inner()).1).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body_frame::solver::BodyFrameSettings;
    use crate::body_frame::synthetic::body_block;
    use crate::body_frame::{BodyFrameSystem, Pose};
    use crate::reduced::ReducedSystem;
    use crate::solver::{SolverKind, SolverSettings};
    use crate::synthetic::BlockScene;

    fn scene() -> BlockScene {
        BlockScene { learned_modes: 3, cubature_points: 40, contact_points: 30, ..Default::default() }
    }

    /// World-frame blocks dropped with different tilts and heights; with one
    /// iteration allowed, blocks sliding on the ground instead (the free-fall
    /// guess of a drop would converge in one).
    fn world_sims(count: usize, max_iterations: usize) -> Vec<ReducedSolver> {
        let m = scene().build().unwrap();
        (0..count)
            .map(|i| {
                let system = ReducedSystem::new(&m.inputs()).unwrap();
                let mut s = ReducedSolver::new(system, SolverSettings::new(m.total_mass, 1e-6, max_iterations, SolverKind::Newton)).unwrap();
                let (q, qdot) = if max_iterations == 1 {
                    m.resting_state(0.3 + 0.1 * i as f64)
                } else {
                    m.dropped_state(10.0 * i as f64, 0.002 * (i + 1) as f64)
                };
                s.set_state(&q, &qdot).unwrap();
                s
            })
            .collect()
    }

    /// Body-frame blocks resting on the ground, sliding at different speeds.
    fn body_sims(count: usize) -> Vec<BodyFrameSolver> {
        let b = body_block(&scene(), true).unwrap();
        let (center, rotation) = b.resting_pose();
        (0..count)
            .map(|i| {
                let system = BodyFrameSystem::new(&b.inputs()).unwrap();
                let mut s = BodyFrameSolver::new(system, BodyFrameSettings { tolerance: 1e-6, max_iterations: 100 }).unwrap();
                let pose = Pose { center, rotation, q: vec![0.0; b.n] };
                s.set_state(&pose, &[0.1 * i as f64, 0.0, 0.0], &[0.0; 3], &vec![0.0; b.n]).unwrap();
                s
            })
            .collect()
    }

    fn batch<'a>(world: &'a mut [ReducedSolver], body: &'a mut [BodyFrameSolver], on_failure: OnFailure) -> Vec<BatchItem<'a>> {
        let mut items: Vec<BatchItem<'a>> = world.iter_mut().map(|s| BatchItem { sim: s as &mut dyn Stepper, on_failure }).collect();
        items.extend(body.iter_mut().map(|s| BatchItem { sim: s as &mut dyn Stepper, on_failure }));
        items
    }

    #[test]
    fn batched_steps_equal_single_steps_bit_for_bit() {
        let steps = 6;
        let (mut world_alone, mut body_alone) = (world_sims(3, 100), body_sims(2));
        let mut expected = Vec::new();
        for s in &mut world_alone {
            expected.push((0..steps).map(|_| s.step_once().unwrap()).collect::<Vec<_>>());
        }
        for s in &mut body_alone {
            expected.push((0..steps).map(|_| s.step_once().unwrap()).collect::<Vec<_>>());
        }
        assert!(expected.iter().flatten().any(|&(iterations, _)| iterations > 1), "the scenes need Newton iterations");
        for threads in [1, 2, 3] {
            let (mut world, mut body) = (world_sims(3, 100), body_sims(2));
            let outcomes = step_many(&mut batch(&mut world, &mut body, OnFailure::Stop), steps, threads).unwrap();
            for (outcome, alone) in outcomes.iter().zip(&expected) {
                assert!(outcome.error.is_none());
                let got: Vec<(usize, f64)> = outcome.steps.iter().map(|s| (s.iterations, s.residual)).collect();
                assert_eq!(&got, alone);
            }
            for (a, b) in world.iter().zip(&world_alone) {
                assert_eq!(a.q(), b.q());
                assert_eq!(a.qdot(), b.qdot());
            }
            for (a, b) in body.iter().zip(&body_alone) {
                assert_eq!(a.pose().center, b.pose().center);
                assert_eq!(a.pose().rotation, b.pose().rotation);
                assert_eq!(a.pose().q, b.pose().q);
            }
        }
    }

    #[test]
    fn a_failing_simulation_stops_alone_or_records_its_failure() {
        // One iteration is too few for a landing: every step fails.
        let mut world = world_sims(2, 1);
        let mut ok = world_sims(1, 100);
        let mut items = batch(&mut world, &mut [], OnFailure::Stop);
        items.push(BatchItem { sim: &mut ok[0], on_failure: OnFailure::Stop });
        let outcomes = step_many(&mut items, 3, 2).unwrap();
        for o in &outcomes[..2] {
            assert!(o.steps.is_empty());
            assert!(matches!(o.error, Some(LicromError::NotConverged { .. })));
        }
        assert_eq!(outcomes[2].steps.len(), 3);
        assert!(outcomes[2].error.is_none());

        let mut recorded = world_sims(1, 1);
        let outcomes = step_many(&mut batch(&mut recorded, &mut [], OnFailure::Record), 3, 2).unwrap();
        assert!(outcomes[0].error.is_none());
        assert_eq!(outcomes[0].steps.len(), 3);
        assert!(outcomes[0].steps.iter().all(|s| !s.converged && s.iterations == 1));
        // The same as a loop that takes the last iterate after each failure.
        let mut alone = world_sims(1, 1);
        for _ in 0..3 {
            assert!(alone[0].step_once().is_err());
            alone[0].accept_last_iterate().unwrap();
        }
        assert_eq!(recorded[0].q(), alone[0].q());
    }

    #[test]
    fn zero_threads_is_an_error_naming_the_argument() {
        let mut world = world_sims(1, 10);
        let err = step_many(&mut batch(&mut world, &mut [], OnFailure::Stop), 1, 0).unwrap_err();
        assert!(err.to_string().contains("threads"));
    }
}
