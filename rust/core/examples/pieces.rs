//! Loops one evaluation kernel for profiling: `pieces [eval|grad|hess|contact] [reps]`.
use licrom_core::reduced::ReducedSystem;
use licrom_core::synthetic::BlockScene;
use std::hint::black_box;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let what = args.get(1).map(String::as_str).unwrap_or("grad");
    let reps: usize = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(2000);
    let k: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(1000);
    let c: usize = args.get(4).map(|s| s.parse().unwrap()).unwrap_or(1000);
    let m = BlockScene { learned_modes: 20, cubature_points: k, contact_points: c, ..Default::default() }.build().unwrap();
    let sys = ReducedSystem::new(&m.inputs()).unwrap();
    let n = sys.n_dofs();
    let (mut q, qdot) = m.resting_state(0.3);
    for (i, qi) in q.iter_mut().enumerate().skip(12) {
        *qi = 1e-3 * ((i * 7) % 5) as f64 / 4.0;
    }
    let mut start = sys.step_start();
    sys.begin_step(&q, &qdot, None, &mut start);
    let trial: Vec<f64> = q.iter().zip(&qdot).map(|(x, v)| x + m.scene.dt * v).collect();
    let mut ws = sys.workspace();
    let mut hess = vec![0.0; n * n];
    let t = std::time::Instant::now();
    for _ in 0..reps {
        match what {
            "eval" => {
                black_box(sys.evaluate(&start, black_box(&trial), false, &mut ws));
            }
            "grad" => {
                black_box(sys.evaluate(&start, black_box(&trial), true, &mut ws));
            }
            "hess" => {
                sys.elastic_hessian(black_box(&trial), &mut ws, &mut hess, None);
            }
            "contact" => sys.contact_hessian(&start, black_box(&trial), &mut ws, &mut hess),
            _ => panic!("unknown piece"),
        }
    }
    println!("{what}: {:.1} us", t.elapsed().as_secs_f64() * 1e6 / reps as f64);
}
