//! Many reduced simulations stepped at once, on threads, without the GIL.

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard, TryLockError};

use licrom_core::batch::{self, BatchItem, OnFailure, Stepper};
use licrom_core::body_frame::solver::BodyFrameSolver;
use licrom_core::solver::ReducedSolver;
use pyo3::exceptions::PyBaseException;
use pyo3::prelude::*;

use crate::body_frame::BodyFrameCore;
use crate::errors::{detached, error, from_core, Kind};
use crate::reduced::ReducedCore;

/// A simulation of either kind, held exclusively for the call.
enum Held<'a> {
    World(MutexGuard<'a, ReducedSolver>),
    Body(MutexGuard<'a, BodyFrameSolver>),
}

impl Held<'_> {
    fn stepper(&mut self) -> &mut dyn Stepper {
        match self {
            Held::World(solver) => &mut **solver,
            Held::Body(solver) => &mut **solver,
        }
    }
}

/// The solver behind `lock`, or a `ConcurrencyError` naming `sims[i]` when another
/// thread is using it.
fn hold<'a, T>(py: Python<'_>, i: usize, lock: &'a Mutex<T>) -> PyResult<MutexGuard<'a, T>> {
    match lock.try_lock() {
        Ok(guard) => Ok(guard),
        // A panic in an earlier call already reached its caller as an exception.
        Err(TryLockError::Poisoned(poisoned)) => Ok(poisoned.into_inner()),
        Err(TryLockError::WouldBlock) => {
            Err(error(py, Kind::Concurrency, format!("sims[{i}] is busy in another thread (a step or evaluation is running there)")))
        }
    }
}

fn held<'a>(py: Python<'_>, i: usize, sim: &'a Bound<'_, PyAny>) -> PyResult<Held<'a>> {
    if let Ok(core) = sim.cast::<ReducedCore>() {
        return hold(py, i, &core.get().inner).map(Held::World);
    }
    if let Ok(core) = sim.cast::<BodyFrameCore>() {
        return hold(py, i, &core.get().inner).map(Held::Body);
    }
    let type_name = sim.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
    Err(error(py, Kind::Config, format!("sims[{i}] must be a ReducedCore or a BodyFrameCore, got {type_name}")))
}

/// Step each simulation ``steps`` times, spread over ``threads`` threads (None: every core), the GIL released.
///
/// The simulations are independent (each owns its model and buffers); each takes its
/// steps exactly as a loop of ``step`` calls would, so the states do not depend on
/// ``threads``. A simulation whose ``record_failures`` flag is set takes the last iterate
/// of a step that fails (``accept_last_iterate``) and goes on; otherwise it stops at the
/// start of that step. Returns, per simulation, ``(iterations, residuals, converged,
/// error)``: one entry per step taken (a failed step: its iterations, its residual or NaN,
/// False) and the licrom exception that stopped it, or None.
///
/// Raises ConfigError for a simulation given twice, an object of another type,
/// ``steps < 0`` or ``threads < 1``; ConcurrencyError for a simulation busy in another
/// thread; ShapeError for ``record_failures`` of another length than ``sims``.
#[pyfunction]
#[pyo3(signature = (sims, steps, threads, record_failures))]
#[allow(clippy::type_complexity)]
pub fn step_many(
    py: Python<'_>,
    sims: Vec<Bound<'_, PyAny>>,
    steps: i64,
    threads: Option<i64>,
    record_failures: Vec<bool>,
) -> PyResult<Vec<(Vec<usize>, Vec<f64>, Vec<bool>, Option<Py<PyBaseException>>)>> {
    if steps < 0 {
        return Err(error(py, Kind::Config, format!("steps must be an integer >= 0, got {steps}")));
    }
    let threads = match threads {
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
        Some(t) if t >= 1 => t as usize,
        Some(t) => return Err(error(py, Kind::Config, format!("threads must be None (every core) or an integer >= 1, got {t}"))),
    };
    if record_failures.len() != sims.len() {
        return Err(error(
            py,
            Kind::Shape,
            format!("record_failures must hold one flag per simulation ({}), got {}", sims.len(), record_failures.len()),
        ));
    }
    let mut seen = HashMap::with_capacity(sims.len());
    for (i, sim) in sims.iter().enumerate() {
        if let Some(first) = seen.insert(sim.as_ptr(), i) {
            return Err(error(py, Kind::Config, format!("sims[{first}] and sims[{i}] are the same simulation; each may appear once")));
        }
    }
    let mut held = sims.iter().enumerate().map(|(i, sim)| held(py, i, sim)).collect::<PyResult<Vec<_>>>()?;
    let mut items: Vec<BatchItem<'_>> = held
        .iter_mut()
        .zip(&record_failures)
        .map(|(b, &record)| BatchItem { sim: b.stepper(), on_failure: if record { OnFailure::Record } else { OnFailure::Stop } })
        .collect();
    let steps = steps as usize;
    let outcomes = detached(py, || batch::step_many(&mut items, steps, threads))?;
    Ok(outcomes
        .into_iter()
        .map(|o| {
            let iterations = o.steps.iter().map(|s| s.iterations).collect();
            let residuals = o.steps.iter().map(|s| s.residual).collect();
            let converged = o.steps.iter().map(|s| s.converged).collect();
            (iterations, residuals, converged, o.error.map(|e| from_core(py, e).into_value(py)))
        })
        .collect())
}

/// Whether one simulation's step may hand half of its large products (the basis
/// rows times the coordinates, and back) to a second thread; on by default where
/// the machine has two cores or more. Steps are the same, bit for bit, either way.
#[pyfunction]
pub fn set_second_thread(on: bool) {
    licrom_core::second_thread::set_enabled(on);
}
