//! `ReducedSolver::step` and `BodyFrameSolver::step` must not allocate once
//! warm: this test binary counts heap allocations with a wrapping global
//! allocator, per thread, so that neither the other test nor the harness
//! reporting a finished one counts against a test.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use licrom_core::body_frame::solver::{BodyFrameSettings, BodyFrameSolver};
use licrom_core::body_frame::synthetic::body_block;
use licrom_core::body_frame::{BodyFrameSystem, Pose};
use licrom_core::reduced::ReducedSystem;
use licrom_core::solver::{ReducedSolver, SolverKind, SolverSettings};
use licrom_core::synthetic::BlockScene;

struct Counting;

thread_local! {
    // Const-initialised and without a destructor: usable from the allocator at any time.
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

/// Allocations made so far by the calling thread.
fn allocations() -> usize {
    ALLOCATIONS.with(Cell::get)
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steps_do_not_allocate() {
    for kind in [SolverKind::Newton, SolverKind::Prefactored] {
        let model = BlockScene { learned_modes: 6, cubature_points: 40, contact_points: 30, ..Default::default() }.build().unwrap();
        let system = ReducedSystem::new(&model.inputs()).unwrap();
        let settings = SolverSettings::new(model.total_mass, 1e-6, 500, kind);
        let mut solver = ReducedSolver::new(system, settings).unwrap();
        let (q, qdot) = model.resting_state(0.3);
        solver.set_state(&q, &qdot).unwrap();
        // The first step may fill lazily created buffers (matrix-product packing).
        solver.step().unwrap();
        let mut forces = vec![0.0; 3 * 30];
        let before = allocations();
        for _ in 0..5 {
            solver.set_state(&q, &qdot).unwrap();
            solver.step().unwrap();
        }
        solver.contact_forces(&mut forces).unwrap();
        assert_eq!(allocations() - before, 0, "{kind:?} allocated while stepping");
    }
}

#[test]
fn body_frame_steps_do_not_allocate() {
    // With material damping: the step start's anchor strain is formed too.
    let scene = BlockScene { learned_modes: 6, cubature_points: 40, contact_points: 30, viscosity: 50.0, ..Default::default() };
    let model = body_block(&scene, true).unwrap();
    let system = BodyFrameSystem::new(&model.inputs()).unwrap();
    let mut solver = BodyFrameSolver::new(system, BodyFrameSettings { tolerance: 1e-6, max_iterations: 500 }).unwrap();
    let (center, rotation) = model.resting_pose();
    let pose = Pose { center, rotation, q: vec![0.0; model.n] };
    let qdot = vec![0.0; model.n];
    // Sliding on, and coming to rest within a step (friction's stick switch).
    let states = [([0.3, 0.0, 0.0], [0.0, 0.5, 0.0]), ([0.02, 0.0, 0.0], [0.0; 3])];
    // The first steps may fill lazily created buffers (matrix-product packing).
    for (v, w) in &states {
        solver.set_state(&pose, v, w, &qdot).unwrap();
        solver.step().unwrap();
    }
    solver.reset_stats();
    let mut forces = vec![0.0; 3 * 30];
    let before = allocations();
    for _ in 0..3 {
        for (v, w) in &states {
            solver.set_state(&pose, v, w, &qdot).unwrap();
            solver.step().unwrap();
        }
    }
    solver.contact_forces(&mut forces).unwrap();
    assert_eq!(allocations() - before, 0, "the body-frame solver allocated while stepping");
    // Those steps went through the contact model and the stick correction.
    let stats = solver.stats();
    assert!(stats.model_evaluations > 0 && stats.stick_solves > 0, "{stats:?}");
}
