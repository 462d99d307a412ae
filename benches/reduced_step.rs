//! Benchmarks of the reduced step and of its per-point kernels.
//!
//! Two scenes on the synthetic block of `licrom_core::synthetic` (10 cm,
//! E = 1e5 Pa, h = 10 ms, mu = 0.5), each over r in {8, 20, 64} learned modes
//! (+12 affine: n in {20, 32, 76}), K in {100, 1000, 5000} cubature points,
//! both solvers, tolerance 1e-6 m/s:
//!
//! - `reduced_step`: one step from a given state (a cold start: free-fall
//!   initial guess, elastic Hessian assembled first): the block sunk to its
//!   resting depth on level ground (k_n = 2e6, k_f = 1e6), sliding at 0.3 m/s
//!   and slightly deformed; C in {0, 1000} contact points on its bottom face,
//!   all in contact and slipping. Every measured iteration restores that state.
//! - `landing`: the realistic case. The block, turned 30 degrees about y, is
//!   dropped from 1 cm onto a 20 degree incline with mu = 0.5 and the cheese
//!   scene's stiffnesses (k_n = k_f = 1e7): it lands on an edge, tips flat,
//!   slides and comes to rest (tan 20 < 0.5). C = 1000 contact points over all
//!   six faces (a sixth of them on the face it ends up on). Each measured
//!   iteration runs the 80 steps (0.8 s) from the drop and reports the mean
//!   time per step, for both solvers (the prefactored one factors its matrix
//!   again when the contact terms change and may finish a step with Newton:
//!   its factorizations and fallbacks are printed).
//!
//! The iteration counts of every configuration are printed first, since the
//! time per step is roughly (iterations x cost per iteration).

use std::hint::black_box;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use licrom_core::cholesky::Cholesky;
use licrom_core::reduced::{Hessian, ReducedSystem};
use licrom_core::solver::{ReducedSolver, SolverKind, SolverSettings};
use licrom_core::synthetic::{BlockModel, BlockScene};
use licrom_core::StableNeoHookean;
use nalgebra::Matrix3;

const SLIDING_SPEED: f64 = 0.3;
const LANDING_STEPS: usize = 80;

/// The sliding-block state: resting depth, sliding, learned modes excited by 1 mm.
fn state(model: &BlockModel) -> (Vec<f64>, Vec<f64>) {
    let (mut q, qdot) = model.resting_state(SLIDING_SPEED);
    for (i, qi) in q.iter_mut().enumerate().skip(12) {
        *qi = 1e-3 * ((i * 7) % 5) as f64 / 4.0;
    }
    (q, qdot)
}

fn model(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
    BlockScene { learned_modes, cubature_points, contact_points, ..Default::default() }.build().expect("valid synthetic scene")
}

fn landing_model(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
    BlockScene::landing(learned_modes, cubature_points, contact_points).build().expect("valid synthetic scene")
}

fn solver(model: &BlockModel, kind: SolverKind) -> ReducedSolver {
    let system = ReducedSystem::new(&model.inputs()).expect("valid system");
    ReducedSolver::new(system, SolverSettings::new(model.total_mass, 1e-6, 500, kind)).expect("valid settings")
}

fn kind_name(kind: SolverKind) -> &'static str {
    match kind {
        SolverKind::Newton => "newton",
        SolverKind::Prefactored => "prefactored",
    }
}

fn reduced_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("reduced_step");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    for r in [8, 20, 64] {
        for k in [100, 1000, 5000] {
            for contacts in [0, 1000] {
                for kind in [SolverKind::Newton, SolverKind::Prefactored] {
                    let id = format!("{}/n{}_K{}_C{}", kind_name(kind), 12 + r, k, contacts);
                    // Set up inside the closure: criterion only calls it when the id
                    // passes the command-line filter.
                    let mut setup = None;
                    group.bench_function(BenchmarkId::from_parameter(&id), |b| {
                        let (s, q, qdot) = setup.get_or_insert_with(|| {
                            let m = model(r, k, contacts);
                            let (q, qdot) = state(&m);
                            let mut s = solver(&m, kind);
                            s.set_state(&q, &qdot).expect("state");
                            let report = s.step().expect("the benchmark step converges");
                            eprintln!("{id}: {} iterations, residual {:.1e} m/s", report.iterations, report.residual);
                            (s, q, qdot)
                        });
                        b.iter(|| {
                            s.set_state(q, qdot).expect("state");
                            black_box(s.step().expect("converges"))
                        })
                    });
                }
            }
        }
    }
    group.finish();
}

/// Mean time per step of the landing trajectory (see the module documentation).
fn landing(c: &mut Criterion) {
    let mut group = c.benchmark_group("landing");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(2));
    for r in [8, 20, 64] {
        for k in [100, 1000, 5000] {
            for kind in [SolverKind::Newton, SolverKind::Prefactored] {
                let contacts = 1000;
                let id = format!("{}/n{}_K{}_C{}", kind_name(kind), 12 + r, k, contacts);
                let mut setup = None;
                group.bench_function(BenchmarkId::from_parameter(&id), |b| {
                    let (s, q, qdot) = setup.get_or_insert_with(|| {
                        let m = landing_model(r, k, contacts);
                        let (q, qdot) = m.dropped_state(30.0, 0.01);
                        let mut s = solver(&m, kind);
                        s.set_state(&q, &qdot).expect("state");
                        let its: Vec<usize> = (0..LANDING_STEPS).map(|_| s.step().expect("the landing converges").iterations).collect();
                        let stats = s.stats();
                        eprintln!(
                            "{id}: {} iterations over {LANDING_STEPS} steps (max {}), {} elastic Hessians, {} factorizations, {} fallbacks, {} stick steps",
                            its.iter().sum::<usize>(),
                            its.iter().max().unwrap_or(&0),
                            stats.elastic_hessians,
                            stats.factorizations,
                            stats.fallbacks,
                            stats.stick_steps
                        );
                        (s, q, qdot)
                    });
                    b.iter_custom(|iters| {
                        let mut total = Duration::ZERO;
                        for _ in 0..iters {
                            s.set_state(q, qdot).expect("state");
                            let t = Instant::now();
                            for _ in 0..LANDING_STEPS {
                                black_box(s.step().expect("converges"));
                            }
                            total += t.elapsed() / LANDING_STEPS as u32;
                        }
                        total
                    })
                });
            }
        }
    }
    group.finish();
}

/// Cost of one Newton iteration's pieces at the headline size n = 32, K = 1000,
/// C = 1000 (sliding block: every contact point in contact).
fn newton_pieces(c: &mut Criterion) {
    let m = model(20, 1000, 1000);
    let sys = ReducedSystem::new(&m.inputs()).expect("valid system");
    let n = sys.n_dofs();
    let (q, qdot) = state(&m);
    let mut start = sys.step_start();
    sys.begin_step(&q, &qdot, None, &mut start);
    let trial: Vec<f64> = q.iter().zip(&qdot).map(|(x, v)| x + m.scene.dt * v).collect();
    let mut ws = sys.workspace();
    let mut hess = vec![0.0; n * n];
    let mut clamped = vec![0.0; n * n];
    let mut group = c.benchmark_group("newton_pieces_n32_K1000_C1000");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    group.bench_function("energy", |b| b.iter(|| black_box(sys.evaluate(&start, black_box(&trial), false, &mut ws))));
    group.bench_function("energy_and_gradient", |b| b.iter(|| black_box(sys.evaluate(&start, black_box(&trial), true, &mut ws))));
    group.bench_function("elastic_hessian_projected", |b| b.iter(|| sys.elastic_hessian(black_box(&trial), &mut ws, &mut hess, None)));
    group.bench_function("elastic_hessian_split", |b| b.iter(|| sys.elastic_hessian(black_box(&trial), &mut ws, &mut hess, Some(&mut clamped))));
    group.bench_function("contact_hessian", |b| b.iter(|| sys.contact_hessian(&start, black_box(&trial), &mut ws, &mut hess)));
    sys.assemble(&start, &trial, Hessian::Projected, &mut ws);
    let mut chol = Cholesky::new(n);
    let mut rhs = vec![0.0; n];
    group.bench_function("cholesky_factor_and_solve", |b| {
        b.iter(|| {
            chol.factor_shifted(black_box(&ws.hess), 0.0, &ws.hess).expect("SPD");
            rhs.copy_from_slice(&ws.grad);
            chol.solve_in_place(&mut rhs);
        })
    });
    group.bench_function("gradient_and_projected_hessian", |b| b.iter(|| sys.assemble(&start, black_box(&trial), Hessian::Projected, &mut ws)));
    // The same with a material damping (Kelvin-Voigt, 400 Pa s): its stress per point, and six more Hessian rows.
    let damped = BlockScene { learned_modes: 20, cubature_points: 1000, contact_points: 1000, viscosity: 400.0, ..Default::default() }
        .build()
        .expect("valid synthetic scene");
    let sys = ReducedSystem::new(&damped.inputs()).expect("valid system");
    let mut start = sys.step_start();
    sys.begin_step(&q, &qdot, None, &mut start);
    let mut ws = sys.workspace();
    group.bench_function("energy_and_gradient_damped", |b| b.iter(|| black_box(sys.evaluate(&start, black_box(&trial), true, &mut ws))));
    group.bench_function("elastic_hessian_projected_damped", |b| b.iter(|| sys.elastic_hessian(black_box(&trial), &mut ws, &mut hess, None)));
    group.finish();
}

/// Per-point material kernels on a batch of 1000 mildly deformed (some inverted) F:
/// one point at a time (`svd`, `eigensystem`, `projected_hessian`, `exact_hessian`,
/// `pk1`), and the eight-lane batched projection used on the hot path
/// (`projected_hessian_batched`, through the public batch helper).
fn snh_per_point(c: &mut Criterion) {
    let mat = StableNeoHookean::new(5.13e4, 8.97e4).expect("material");
    let fs: Vec<Matrix3<f64>> = (0..1000)
        .map(|i| {
            let t = i as f64 * 0.618;
            let mut f = Matrix3::new(
                1.0 + 0.2 * t.sin(),
                0.1 * (2.0 * t).cos(),
                0.05 * t.cos(),
                0.1 * (3.0 * t).sin(),
                1.0 - 0.15 * t.cos(),
                0.08 * (5.0 * t).sin(),
                0.02 * t.sin(),
                0.07 * (7.0 * t).cos(),
                1.0 + 0.1 * (11.0 * t).sin(),
            );
            if i % 10 == 0 {
                f.row_mut(2).neg_mut();
            }
            f
        })
        .collect();
    let mut group = c.benchmark_group("snh_1000_points");
    group.sample_size(10).warm_up_time(Duration::from_millis(300)).measurement_time(Duration::from_secs(1));
    group.bench_function("svd", |b| b.iter(|| fs.iter().map(|f| licrom_core::svd3::svd3(black_box(f)).s[2]).sum::<f64>()));
    group.bench_function("eigensystem", |b| b.iter(|| fs.iter().map(|f| mat.eigensystem(black_box(f)).values[0]).sum::<f64>()));
    group.bench_function("projected_hessian", |b| b.iter(|| fs.iter().map(|f| mat.projected_hessian(black_box(f))[(0, 0)]).sum::<f64>()));
    let flat: Vec<f64> = fs.iter().flat_map(|f| f.transpose().as_slice().to_vec()).collect();
    let mut out = vec![0.0; 81 * fs.len()];
    group.bench_function("projected_hessian_batched", |b| b.iter(|| mat.hessian_batch(black_box(&flat), true, &mut out).expect("valid batch")));
    group.bench_function("exact_hessian", |b| b.iter(|| fs.iter().map(|f| mat.hessian(black_box(f))[(0, 0)]).sum::<f64>()));
    group.bench_function("pk1", |b| b.iter(|| fs.iter().map(|f| mat.pk1(black_box(f))[(0, 0)]).sum::<f64>()));
    group.finish();
}

criterion_group!(benches, snh_per_point, newton_pieces, reduced_step, landing);
criterion_main!(benches);
