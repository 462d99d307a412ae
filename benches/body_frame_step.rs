//! The body-frame step beside the world-frame step on the same synthetic block.
//!
//! Scene of the world-frame `reduced_step` bench (`licrom_core::synthetic`: a
//! 10 cm block, E = 1e5 Pa, h = 10 ms, mu = 0.5, k_n = 2e6, k_f = 1e6,
//! tolerance 1e-6 m/s): the block sunk to its resting depth on level ground,
//! sliding at 0.3 m/s along x, learned modes excited by about 1 mm; K = 1000
//! cubature points, C = 1000 contact points on the bottom face (all in contact
//! and slipping). For r in {20, 60} learned modes:
//!
//! - `world/r{r}`: the world-frame solver, 12 affine + r modes;
//! - `body/r{r}`: the body-frame solver ([`licrom_core::body_frame`]), 6
//!   symmetric affine + r modes plus the exact rigid motion (c, R).
//!
//! Every measured iteration sets the state again and takes one step (a cold
//! start), as in `reduced_step`.
//!
//! `body_frame_landing`: the realistic case of `reduced_step`'s `landing`. The
//! block, turned 30 degrees about y, dropped from 1 cm onto a 20 degree
//! incline (mu = 0.5, k_n = k_f = 1e7), C = 1000 contact points over all six
//! faces, K = 1000; each measured iteration runs the 80 steps (0.8 s) from the
//! drop and reports the mean time per step, for both solvers at r in {20, 60}.
//!
//! The iteration counts and the solvers' work counters are printed first.

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use licrom_core::body_frame::solver::{BodyFrameSettings, BodyFrameSolver};
use licrom_core::body_frame::synthetic::body_block;
use licrom_core::body_frame::{BodyFrameSystem, Pose};
use licrom_core::reduced::ReducedSystem;
use licrom_core::solver::{ReducedSolver, SolverKind, SolverSettings};
use licrom_core::synthetic::BlockScene;

const SLIDING_SPEED: f64 = 0.3;
const TOLERANCE: f64 = 1e-6;
const CUBATURE: usize = 1000;
const CONTACTS: usize = 1000;
const LANDING_STEPS: usize = 80;

/// Excitation of learned mode i, about 1 mm (the pattern of `reduced_step`).
fn excitation(i: usize) -> f64 {
    1e-3 * ((i * 7) % 5) as f64 / 4.0
}

fn scene(learned_modes: usize) -> BlockScene {
    BlockScene { learned_modes, cubature_points: CUBATURE, contact_points: CONTACTS, ..Default::default() }
}

fn body_frame_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("body_frame_step");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    for r in [20, 60] {
        let id = format!("world/r{r}_K{CUBATURE}_C{CONTACTS}");
        let mut setup = None;
        group.bench_function(BenchmarkId::from_parameter(&id), |b| {
            let (s, q, qdot) = setup.get_or_insert_with(|| {
                let m = scene(r).build().expect("valid synthetic scene");
                let (mut q, qdot) = m.resting_state(SLIDING_SPEED);
                for (i, qi) in q.iter_mut().enumerate().skip(12) {
                    *qi = excitation(i);
                }
                let system = ReducedSystem::new(&m.inputs()).expect("valid system");
                let mut s =
                    ReducedSolver::new(system, SolverSettings::new(m.total_mass, TOLERANCE, 500, SolverKind::Newton)).expect("valid settings");
                s.set_state(&q, &qdot).expect("state");
                let report = s.step().expect("the benchmark step converges");
                eprintln!("{id}: {} iterations, residual {:.1e} m/s; {:?}", report.iterations, report.residual, s.stats());
                (s, q, qdot)
            });
            b.iter(|| {
                s.set_state(q, qdot).expect("state");
                black_box(s.step().expect("converges"))
            })
        });
        let id = format!("body/r{r}_K{CUBATURE}_C{CONTACTS}");
        let mut setup = None;
        group.bench_function(BenchmarkId::from_parameter(&id), |b| {
            let (s, pose) = setup.get_or_insert_with(|| {
                let m = body_block(&scene(r), true).expect("valid synthetic scene");
                let (center, rotation) = m.resting_pose();
                let q = (0..m.n).map(|i| if i >= 6 { excitation(i + 6) } else { 0.0 }).collect();
                let pose = Pose { center, rotation, q };
                let system = BodyFrameSystem::new(&m.inputs()).expect("valid system");
                let mut s = BodyFrameSolver::new(system, BodyFrameSettings { tolerance: TOLERANCE, max_iterations: 500 }).expect("valid settings");
                s.set_state(&pose, &[SLIDING_SPEED, 0.0, 0.0], &[0.0; 3], &vec![0.0; m.n]).expect("state");
                let report = s.step().expect("the benchmark step converges");
                eprintln!("{id}: {} iterations, residual {:.1e} m/s; {:?}", report.iterations, report.residual, s.stats());
                (s, pose)
            });
            let n = pose.q.len();
            let qdot = vec![0.0; n];
            b.iter(|| {
                s.set_state(pose, &[SLIDING_SPEED, 0.0, 0.0], &[0.0; 3], &qdot).expect("state");
                black_box(s.step().expect("converges"))
            })
        });
    }
    group.finish();
}

fn landing_scene(learned_modes: usize) -> BlockScene {
    BlockScene { incline: 20.0, contact_on_all_faces: true, normal_stiffness: 1e7, friction_stiffness: 1e7, ..scene(learned_modes) }
}

/// Mean time per step of `LANDING_STEPS` steps after `reset()`.
fn time_landing(iters: u64, mut reset: impl FnMut(), mut step: impl FnMut()) -> Duration {
    let mut total = Duration::ZERO;
    for _ in 0..iters {
        reset();
        let t = Instant::now();
        for _ in 0..LANDING_STEPS {
            step();
        }
        total += t.elapsed() / LANDING_STEPS as u32;
    }
    total
}

fn body_frame_landing(c: &mut Criterion) {
    let mut group = c.benchmark_group("body_frame_landing");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(2));
    for r in [20, 60] {
        let id = format!("world/r{r}_K{CUBATURE}_C{CONTACTS}");
        let mut setup = None;
        group.bench_function(BenchmarkId::from_parameter(&id), |b| {
            let (s, q, qdot) = setup.get_or_insert_with(|| {
                let m = landing_scene(r).build().expect("valid synthetic scene");
                let (q, qdot) = m.dropped_state(30.0, 0.01);
                let system = ReducedSystem::new(&m.inputs()).expect("valid system");
                let mut s =
                    ReducedSolver::new(system, SolverSettings::new(m.total_mass, TOLERANCE, 500, SolverKind::Newton)).expect("valid settings");
                s.set_state(&q, &qdot).expect("state");
                let its: usize = (0..LANDING_STEPS).map(|_| s.step().expect("the landing converges").iterations).sum();
                eprintln!("{id}: {its} iterations over {LANDING_STEPS} steps; {:?}", s.stats());
                (s, q, qdot)
            });
            b.iter_custom(|iters| {
                let s = std::cell::RefCell::new(&mut *s);
                time_landing(
                    iters,
                    || s.borrow_mut().set_state(q, qdot).expect("state"),
                    || {
                        black_box(s.borrow_mut().step().expect("converges"));
                    },
                )
            })
        });
        let id = format!("body/r{r}_K{CUBATURE}_C{CONTACTS}");
        let mut setup = None;
        group.bench_function(BenchmarkId::from_parameter(&id), |b| {
            let (s, pose) = setup.get_or_insert_with(|| {
                let m = body_block(&landing_scene(r), true).expect("valid synthetic scene");
                // Turned 30 degrees about y, lowest corner 1 cm above the plane.
                let (sin, cos) = 30.0_f64.to_radians().sin_cos();
                let rotation = nalgebra::Matrix3::new(cos, 0.0, sin, 0.0, 1.0, 0.0, -sin, 0.0, cos);
                let normal = m.terms.planes[0].normal();
                let half = m.scene.size / 2.0;
                let lowest = (0..8)
                    .map(|k| {
                        normal
                            .dot(&(rotation * nalgebra::Vector3::new([-half, half][k & 1], [-half, half][(k >> 1) & 1], [-half, half][(k >> 2) & 1])))
                    })
                    .fold(f64::INFINITY, f64::min);
                let pose = Pose { center: normal * (0.01 - lowest), rotation, q: vec![0.0; m.n] };
                let system = BodyFrameSystem::new(&m.inputs()).expect("valid system");
                let mut s = BodyFrameSolver::new(system, BodyFrameSettings { tolerance: TOLERANCE, max_iterations: 500 }).expect("valid settings");
                s.set_state(&pose, &[0.0; 3], &[0.0; 3], &vec![0.0; m.n]).expect("state");
                let its: usize = (0..LANDING_STEPS).map(|_| s.step().expect("the landing converges").iterations).sum();
                eprintln!("{id}: {its} iterations over {LANDING_STEPS} steps; {:?}", s.stats());
                (s, pose)
            });
            let qdot = vec![0.0; pose.q.len()];
            b.iter_custom(|iters| {
                let s = std::cell::RefCell::new(&mut *s);
                time_landing(
                    iters,
                    || s.borrow_mut().set_state(pose, &[0.0; 3], &[0.0; 3], &qdot).expect("state"),
                    || {
                        black_box(s.borrow_mut().step().expect("converges"));
                    },
                )
            })
        });
    }
    group.finish();
}

criterion_group!(benches, body_frame_step, body_frame_landing);
criterion_main!(benches);
