//! `ReducedSolver::step` and `BodyFrameSolver::step` must not allocate once
//! warm: this test binary counts heap allocations with a wrapping global
//! allocator, and its tests take turns so that one does not count the other's.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use licrom_core::body_frame::solver::{BodyFrameSettings, BodyFrameSolver};
use licrom_core::body_frame::synthetic::body_block;
use licrom_core::body_frame::{BodyFrameSystem, Pose};
use licrom_core::reduced::ReducedSystem;
use licrom_core::solver::{ReducedSolver, SolverKind, SolverSettings};
use licrom_core::synthetic::BlockScene;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

static SERIAL: Mutex<()> = Mutex::new(());

#[test]
fn steps_do_not_allocate() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
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
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        for _ in 0..5 {
            solver.set_state(&q, &qdot).unwrap();
            solver.step().unwrap();
        }
        solver.contact_forces(&mut forces).unwrap();
        assert_eq!(ALLOCATIONS.load(Ordering::Relaxed) - before, 0, "{kind:?} allocated while stepping");
    }
}

#[test]
fn body_frame_steps_do_not_allocate() {
    let _turn = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let scene = BlockScene { learned_modes: 6, cubature_points: 40, contact_points: 30, ..Default::default() };
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
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    for _ in 0..3 {
        for (v, w) in &states {
            solver.set_state(&pose, v, w, &qdot).unwrap();
            solver.step().unwrap();
        }
    }
    solver.contact_forces(&mut forces).unwrap();
    assert_eq!(ALLOCATIONS.load(Ordering::Relaxed) - before, 0, "the body-frame solver allocated while stepping");
    // Those steps went through the contact model and the stick correction.
    let stats = solver.stats();
    assert!(stats.model_evaluations > 0 && stats.stick_solves > 0, "{stats:?}");
}
