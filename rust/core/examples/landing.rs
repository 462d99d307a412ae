//! A block dropped on an edge onto a 20 degree incline with mu = 0.5: it tips
//! flat, slides and comes to rest (tan 20 < 0.5). Prints the iterations and
//! time of every step and the solver's work counters.
//!
//! With `sliding` as sixth argument, it runs instead the cold step of the
//! `reduced_step` benchmark (sliding block on level ground, state restored
//! before every step) a few times.
//!
//! cargo run --release --example landing -- [learned_modes] [cubature] [contacts] [newton|prefactored] [lagged|every_iteration] [sliding]

use std::time::Instant;

use licrom_core::reduced::ReducedSystem;
use licrom_core::solver::{ReducedSolver, SolverSettings};
use licrom_core::synthetic::BlockScene;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_string());
    let r: usize = arg(1, "20").parse().expect("learned modes");
    let k: usize = arg(2, "1000").parse().expect("cubature points");
    let c: usize = arg(3, "1000").parse().expect("contact points");
    let kind = arg(4, "newton").parse().expect("solver");
    let elastic_hessian = arg(5, "lagged").parse().expect("elastic Hessian rule");
    if arg(6, "") == "sliding" {
        let model = BlockScene { learned_modes: r, cubature_points: k, contact_points: c, ..Default::default() }.build().expect("scene");
        let system = ReducedSystem::new(&model.inputs()).expect("system");
        let settings = SolverSettings { elastic_hessian, ..SolverSettings::new(model.total_mass, 1e-6, 500, kind) };
        let mut solver = ReducedSolver::new(system, settings).expect("solver");
        let (mut q, qdot) = model.resting_state(0.3);
        for (i, qi) in q.iter_mut().enumerate().skip(12) {
            *qi = 1e-3 * ((i * 7) % 5) as f64 / 4.0;
        }
        let repeats: usize = arg(7, "3").parse().expect("repeats");
        for _ in 0..repeats {
            solver.set_state(&q, &qdot).expect("state");
            let t = Instant::now();
            let report = solver.step().expect("step");
            println!("{report:?} {:.3} ms", t.elapsed().as_secs_f64() * 1e3);
        }
        println!("{:?}", solver.stats());
        return;
    }
    let scene = BlockScene::landing(r, k, c);
    let model = scene.build().expect("scene");
    let system = ReducedSystem::new(&model.inputs()).expect("system");
    let settings = SolverSettings { elastic_hessian, ..SolverSettings::new(model.total_mass, 1e-6, 500, kind) };
    let mut solver = ReducedSolver::new(system, settings).expect("solver");
    let (q, qdot) = model.dropped_state(30.0, 0.01);
    solver.set_state(&q, &qdot).expect("state");
    let mut total = 0.0;
    let mut iterations = Vec::new();
    let mut times = Vec::new();
    for _ in 0..80 {
        let t = Instant::now();
        let report = solver.step().expect("step");
        let dt = t.elapsed().as_secs_f64();
        total += dt;
        iterations.push(report.iterations);
        times.push(dt * 1e3);
    }
    println!("iterations {iterations:?}");
    println!("ms {:?}", times.iter().map(|t| (t * 100.0).round() / 100.0).collect::<Vec<_>>());
    let mut sorted = times.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "sum {} mean {:.3} ms median {:.3} ms; x {:?} v {:?}",
        iterations.iter().sum::<usize>(),
        total * 1e3 / 80.0,
        sorted[40],
        &solver.q()[9..12],
        &solver.qdot()[9..12]
    );
    println!("{:?}", solver.stats());
}
