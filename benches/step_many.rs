//! Many reduced scenes at once: `licrom_core::batch::step_many` on 1, 2, ...
//! threads against stepping the same scenes one by one in a loop.
//!
//! Scenes: `SCENES` copies of the `landing` block of `reduced_step` (10 cm,
//! E = 1e5 Pa, h = 10 ms, r = 20 learned modes + 12 affine, K = 1000 cubature
//! points, C = 1000 contact points over all six faces, k_n = k_f = 1e7) on a
//! 20 degree incline with mu = 0.5, each dropped from its own height and turned
//! by its own angle, so that the scenes differ in cost as a batch of real scenes
//! would. Each measured iteration puts every scene back at its drop and takes
//! `STEPS` steps of each (they land, tip and slide). Throughput is reported in
//! scene steps per second (criterion's elements/s).
//!
//! - `loop`: every scene in turn on this thread (what a Python loop does);
//! - `threads{t}`: one `step_many` call on t threads, for t = 1, 2, 4, ... up to
//!   the cores available.
//!
//! The results are the same, bit for bit, whatever the thread count (checked
//! here once before timing).

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use licrom_core::batch::{step_many, BatchItem, OnFailure, Stepper};
use licrom_core::reduced::ReducedSystem;
use licrom_core::solver::{ReducedSolver, SolverKind, SolverSettings};
use licrom_core::synthetic::{BlockModel, BlockScene};

const SCENES: usize = 8;
const STEPS: usize = 20;
const TOLERANCE: f64 = 1e-6;

fn landing_model() -> BlockModel {
    BlockScene::landing(20, 1000, 1000).build().expect("valid synthetic scene")
}

/// A state `(q, qdot)`.
type State = (Vec<f64>, Vec<f64>);

/// The scenes' solvers and their drop states.
fn scenes(model: &BlockModel) -> (Vec<ReducedSolver>, Vec<State>) {
    let states: Vec<_> = (0..SCENES).map(|i| model.dropped_state(20.0 + 20.0 * i as f64 / SCENES as f64, 0.002 + 0.001 * i as f64)).collect();
    let solvers = (0..SCENES)
        .map(|_| {
            let system = ReducedSystem::new(&model.inputs()).expect("valid system");
            ReducedSolver::new(system, SolverSettings::new(model.total_mass, TOLERANCE, 500, SolverKind::Newton)).expect("valid settings")
        })
        .collect();
    (solvers, states)
}

fn reset(solvers: &mut [ReducedSolver], states: &[State]) {
    for (s, (q, qdot)) in solvers.iter_mut().zip(states) {
        s.set_state(q, qdot).expect("state");
    }
}

fn batched(solvers: &mut [ReducedSolver], threads: usize) {
    let mut items: Vec<BatchItem<'_>> = solvers.iter_mut().map(|s| BatchItem { sim: s as &mut dyn Stepper, on_failure: OnFailure::Stop }).collect();
    for outcome in step_many(&mut items, STEPS, threads).expect("threads >= 1") {
        assert!(outcome.error.is_none(), "the benchmark scenes converge");
    }
}

fn thread_counts() -> Vec<usize> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut counts = vec![1];
    while counts[counts.len() - 1] * 2 <= cores.min(SCENES) {
        counts.push(counts[counts.len() - 1] * 2);
    }
    if cores == 1 {
        counts.push(2); // the overhead of threads on one core
    }
    counts
}

fn step_many_bench(c: &mut Criterion) {
    let model = landing_model();
    let (mut solvers, states) = scenes(&model);
    // Same states for every thread count, bit for bit, as the loop's.
    reset(&mut solvers, &states);
    for s in &mut solvers {
        for _ in 0..STEPS {
            s.step().expect("the benchmark scenes converge");
        }
    }
    let expected: Vec<Vec<f64>> = solvers.iter().map(|s| s.q().to_vec()).collect();
    for threads in thread_counts() {
        reset(&mut solvers, &states);
        batched(&mut solvers, threads);
        assert!(solvers.iter().zip(&expected).all(|(s, q)| s.q() == &q[..]), "batched states differ from the loop's");
    }
    eprintln!("step_many: {SCENES} scenes x {STEPS} steps; thread counts {:?}", thread_counts());

    let mut group = c.benchmark_group("step_many");
    group.sample_size(10).warm_up_time(Duration::from_millis(500)).measurement_time(Duration::from_secs(3));
    group.throughput(Throughput::Elements((SCENES * STEPS) as u64));
    group.bench_function(BenchmarkId::from_parameter("loop"), |b| {
        b.iter(|| {
            reset(&mut solvers, &states);
            for s in &mut solvers {
                for _ in 0..STEPS {
                    black_box(s.step().expect("converges"));
                }
            }
        })
    });
    for threads in thread_counts() {
        group.bench_function(BenchmarkId::from_parameter(format!("threads{threads}")), |b| {
            b.iter(|| {
                reset(&mut solvers, &states);
                batched(&mut solvers, threads);
            })
        });
    }
    group.finish();
}

criterion_group!(benches, step_many_bench);
criterion_main!(benches);
