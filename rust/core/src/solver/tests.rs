//! Checks of the reduced solver against analytic trajectories, against each
//! other (lagged, plain and prefactored) and on bad input.

use super::*;
use crate::synthetic::{BlockModel, BlockScene};
use crate::testing::check_pushed_out;

fn solver(model: &BlockModel, kind: SolverKind, tolerance: f64, max_iterations: usize) -> ReducedSolver {
    let system = ReducedSystem::new(&model.inputs()).unwrap();
    let settings = SolverSettings::new(model.total_mass, tolerance, max_iterations, kind);
    ReducedSolver::new(system, settings).unwrap()
}

fn block(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
    BlockScene { learned_modes, cubature_points, contact_points, normal_damping: 2.0e3, seed: 5, ..Default::default() }.build().unwrap()
}

/// |grad| relative to the size of the inertial and gravity terms.
fn relative_gradient(s: &mut ReducedSolver) -> f64 {
    let q = s.q.clone();
    let last = s.last.get().expect("a step was taken");
    s.system.assemble(last, &q, Hessian::None, &mut s.ws);
    let g: f64 = s.ws.grad.iter().map(|g| g * g).sum::<f64>().sqrt();
    let f: f64 = s.system.gravity().iter().map(|g| g * g).sum::<f64>().sqrt();
    g / f
}

#[test]
fn newton_converges_to_a_stationary_point_while_sliding() {
    let model = block(8, 60, 50);
    let mut s = solver(&model, SolverKind::Newton, 1e-9, 50);
    let (q, qdot) = model.resting_state(0.5);
    s.set_state(&q, &qdot).unwrap();
    for _ in 0..20 {
        let report = s.step().unwrap();
        // The step in which the block comes to rest (slip to stick) is the hardest.
        assert!(report.residual < 1e-9 && report.iterations <= 20, "{report:?}");
        assert!(relative_gradient(&mut s) < 1e-6, "gradient at the solution: {}", relative_gradient(&mut s));
    }
    // Friction decelerates the block: mu g = 4.9 m/s^2 for 0.2 s takes 0.98 m/s,
    // more than it had, so it has stopped sliding (up to the stick creep).
    assert!(s.qdot()[9].abs() < 0.05, "still sliding at {} m/s", s.qdot()[9]);
    let mut forces = vec![0.0; 3 * 50];
    s.contact_forces(&mut forces).unwrap();
    let total_z: f64 = forces.chunks_exact(3).map(|f| f[2]).sum();
    assert!((total_z - model.total_mass * 9.81).abs() < 0.05 * model.total_mass * 9.81, "ground carries {total_z} N");
}

#[test]
fn lagged_and_plain_newton_reach_the_same_solution() {
    let model = block(8, 60, 50);
    let (q, qdot) = model.resting_state(0.5);
    let mut lagged = solver(&model, SolverKind::Newton, 1e-10, 50);
    let system = ReducedSystem::new(&model.inputs()).unwrap();
    let settings =
        SolverSettings { elastic_hessian: ElasticHessian::EveryIteration, ..SolverSettings::new(model.total_mass, 1e-10, 50, SolverKind::Newton) };
    let mut plain = ReducedSolver::new(system, settings).unwrap();
    lagged.set_state(&q, &qdot).unwrap();
    plain.set_state(&q, &qdot).unwrap();
    let n = model.n_dofs();
    for _ in 0..15 {
        lagged.step().unwrap();
        plain.step().unwrap();
        let d: Vec<f64> = lagged.q().iter().zip(plain.q()).map(|(x, y)| x - y).collect();
        let dmd: f64 = (0..n).map(|i| d[i] * (0..n).map(|j| model.mass[i * n + j] * d[j]).sum::<f64>()).sum();
        let gap = (dmd / model.total_mass).sqrt() / model.scene.dt;
        assert!(gap < 1e-8, "solutions differ by {gap} m/s");
    }
    assert!(lagged.stats().elastic_hessians < plain.stats().elastic_hessians / 2, "{:?} vs {:?}", lagged.stats(), plain.stats());
}

#[test]
fn a_block_dropped_on_an_incline_lands_and_comes_to_rest() {
    // Turned 30 degrees about y above a 20 degree incline: it lands on an edge,
    // rocks and stops (tan 20 < mu = 0.5); stiff contact as in the cheese scene.
    let model = BlockScene { seed: 7, ..BlockScene::landing(6, 80, 120) }.build().unwrap();
    let mut s = solver(&model, SolverKind::Newton, 1e-6, 50);
    let (q, qdot) = model.dropped_state(30.0, 0.01);
    s.set_state(&q, &qdot).unwrap();
    let mut iterations = 0;
    for _ in 0..150 {
        let report = s.step().unwrap();
        assert!(report.iterations <= 15, "{report:?}");
        iterations += report.iterations;
    }
    assert!(iterations < 3 * 150, "{iterations} iterations in 150 steps");
    // At rest on the plane (up to the stick creep and a last rocking).
    let speed = (s.qdot()[9].powi(2) + s.qdot()[10].powi(2) + s.qdot()[11].powi(2)).sqrt();
    assert!(speed < 1e-3, "still moving at {speed} m/s");
}

#[test]
fn steps_after_set_state_are_those_of_a_new_solver() {
    // A landing (contact Hessian built and updated) leaves nothing behind that a
    // run from a state set afterwards would see.
    let model = BlockScene { learned_modes: 4, cubature_points: 60, contact_points: 50, incline: 20.0, ..Default::default() }.build().unwrap();
    let (q, qdot) = model.dropped_state(30.0, 0.002);
    let run = |s: &mut ReducedSolver| -> Vec<f64> {
        s.set_state(&q, &qdot).unwrap();
        for _ in 0..12 {
            s.step().unwrap();
        }
        s.q().to_vec()
    };
    let fresh = run(&mut solver(&model, SolverKind::Newton, 1e-8, 100));
    let mut reused = solver(&model, SolverKind::Newton, 1e-8, 100);
    run(&mut reused);
    assert_eq!(run(&mut reused), fresh);
}

#[test]
fn prefactored_reaches_the_newton_solution() {
    let model = block(6, 40, 30);
    let (q, qdot) = model.resting_state(0.3);
    let mut newton = solver(&model, SolverKind::Newton, 1e-10, 50);
    // Its matrix lacks the elastic stiffness away from rest: linear convergence,
    // and a floor where energy differences drop below round-off.
    let mut pre = solver(&model, SolverKind::Prefactored, 1e-7, 500);
    newton.set_state(&q, &qdot).unwrap();
    pre.set_state(&q, &qdot).unwrap();
    newton.step().unwrap();
    pre.step().unwrap();
    assert_eq!(pre.stats().elastic_hessians, 1, "K(rest) only");
    // Distance between the solutions as a velocity, like the convergence measure.
    let n = model.n_dofs();
    let d: Vec<f64> = newton.q().iter().zip(pre.q()).map(|(x, y)| x - y).collect();
    let dmd: f64 = (0..n).map(|i| d[i] * (0..n).map(|j| model.mass[i * n + j] * d[j]).sum::<f64>()).sum();
    let gap = (dmd / model.total_mass).sqrt() / model.scene.dt;
    assert!(gap < 1e-5, "prefactored solution differs by {gap} m/s");
}

#[test]
fn affine_free_fall_matches_backward_euler_point_mass() {
    // A single cubature point, no contact: the affine modes carry a rigid
    // translation exactly, so the block must follow the discrete BE trajectory.
    let model = BlockScene { learned_modes: 0, cubature_points: 1, contact_points: 0, ..Default::default() }.build().unwrap();
    let mut s = solver(&model, SolverKind::Newton, 1e-12, 20);
    let h = model.scene.dt;
    let mut q = vec![0.0; 12];
    q[9..12].copy_from_slice(&[0.1, -0.2, 1.0]);
    let mut v = [0.3, 0.0, 1.5];
    let mut qdot = vec![0.0; 12];
    qdot[9..12].copy_from_slice(&v);
    s.set_state(&q, &qdot).unwrap();
    let mut x = [0.1, -0.2, 1.0];
    for _ in 0..25 {
        s.step().unwrap();
        v[2] -= 9.81 * h;
        for i in 0..3 {
            x[i] += h * v[i];
        }
        for i in 0..3 {
            assert!((s.q()[9 + i] - x[i]).abs() < 1e-12, "position {i}: {} vs {}", s.q()[9 + i], x[i]);
            assert!((s.qdot()[9 + i] - v[i]).abs() < 1e-10, "velocity {i}");
        }
        assert!(s.q()[..9].iter().all(|a| a.abs() < 1e-12), "the block deformed");
    }
}

#[test]
fn empty_cubature_contacts_and_planes_work() {
    let mut model = BlockScene { learned_modes: 2, cubature_points: 0, contact_points: 0, ..Default::default() }.build().unwrap();
    model.terms.planes.clear();
    let mut s = solver(&model, SolverKind::Newton, 1e-9, 10);
    let report = s.step().unwrap();
    assert!(report.iterations >= 1);
    let mut forces = [];
    s.contact_forces(&mut forces).unwrap();
    let mut p = solver(&model, SolverKind::Prefactored, 1e-9, 10);
    p.step().unwrap();
    assert!(s.q().iter().zip(p.q()).all(|(a, b)| (a - b).abs() < 1e-12));
}

#[test]
fn non_convergence_leaves_the_state_and_can_be_accepted() {
    let model = block(4, 20, 20);
    let mut s = solver(&model, SolverKind::Newton, 1e-14, 1);
    let (q, qdot) = model.resting_state(0.5);
    s.set_state(&q, &qdot).unwrap();
    match s.step() {
        Err(LicromError::NotConverged { iterations: 1, residual }) => assert!(residual > 1e-14),
        other => panic!("expected non-convergence, got {other:?}"),
    }
    assert_eq!(s.q(), q.as_slice());
    assert_eq!(s.qdot(), qdot.as_slice());
    s.accept_last_iterate().unwrap();
    assert_ne!(s.q(), q.as_slice());
    assert!(s.accept_last_iterate().is_err());
}

#[test]
fn probes_and_state_are_validated() {
    let model = block(1, 5, 4);
    let mut s = solver(&model, SolverKind::Newton, 1e-8, 10);
    assert!(matches!(s.set_state(&[0.0; 3], &[0.0; 13]), Err(LicromError::ShapeMismatch { .. })));
    let mut bad = vec![0.0; 13];
    bad[2] = f64::INFINITY;
    assert!(matches!(s.set_state(&bad, &[0.0; 13]), Err(LicromError::NonFinite { .. })));
    assert!(s.energy(&[0.0; 13]).unwrap().is_finite());
    assert_eq!(s.gradient(&[0.0; 13]).unwrap().len(), 13);
    assert_eq!(s.hessian(&[0.0; 13], false).unwrap().len(), 169);
    assert!("gauss-seidel".parse::<SolverKind>().is_err());
    let system = ReducedSystem::new(&model.inputs()).unwrap();
    let settings = SolverSettings::new(1.0, 1e-6, 0, SolverKind::Newton);
    assert!(ReducedSolver::new(system, settings).is_err());
}

#[test]
fn probes_out_of_double_range_are_errors() {
    let model = block(1, 5, 4);
    let mut s = solver(&model, SolverKind::Newton, 1e-8, 10);
    let huge = [1e200; 13];
    let overflow = |r: &Result<()>| matches!(r, Err(LicromError::Overflow { input: "q", .. }));
    assert!(overflow(&s.energy(&huge).map(|_| ())));
    assert!(overflow(&s.gradient(&huge).map(|_| ())));
    assert!(overflow(&s.hessian(&huge, true).map(|_| ())));
    assert!(overflow(&s.hessian(&huge, false).map(|_| ())));
    // A state so far out that the step's energy overflows is a divergence.
    s.set_state(&huge, &[0.0; 13]).unwrap();
    assert!(matches!(s.step(), Err(LicromError::Diverged { .. })));
}

/// Steps of a block dropped 1 cm onto a 20 degree incline, turned 30 degrees:
/// it lands on an edge, tips flat and slides (contact on all faces, the cheese
/// scene's stiffnesses). Returns the final state and the stats.
fn landing(kind: SolverKind, steps: usize) -> (Vec<f64>, SolverStats) {
    let model = BlockScene::landing(4, 60, 120).build().unwrap();
    let mut s = solver(&model, kind, 1e-6, 100);
    let (q, qdot) = model.dropped_state(30.0, 0.01);
    s.set_state(&q, &qdot).unwrap();
    for step in 0..steps {
        if let Err(e) = s.step() {
            panic!("{kind:?} failed at step {step}: {e}");
        }
    }
    (s.q().to_vec(), s.stats())
}

#[test]
fn prefactored_converges_through_a_landing() {
    let (qn, newton) = landing(SolverKind::Newton, 40);
    let (qp, pre) = landing(SolverKind::Prefactored, 40);
    // The same trajectory (to the tolerance of the steps, 1e-6 m/s over 40 steps of 10 ms).
    let gap = qn.iter().zip(&qp).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(gap < 1e-5, "prefactored and Newton differ by {gap}");
    // Most steps finish without Newton's help (while the block is turned on its
    // edge, K(rest) is a poor model: a few fall back), and the matrix was
    // factored again as contact terms changed.
    assert!(pre.fallbacks <= 5, "{pre:?}");
    assert!(pre.factorizations > 2 * pre.steps, "{pre:?}");
    assert!(newton.fallbacks == 0);
}

#[test]
fn a_slow_prefactored_step_falls_back_to_newton() {
    // Turned 90 degrees with learned modes excited, K(rest) is far from the
    // Hessian: steps that need more than the budget finish with Newton.
    let model = block(6, 40, 30);
    let mut s = solver(&model, SolverKind::Prefactored, 1e-9, 100);
    let n = model.n_dofs();
    let mut q = vec![0.0; n];
    // x -> (z, y, -x) about the origin, lifted clear of the plane.
    q[0] = -1.0;
    q[2] = -1.0;
    q[6] = 1.0;
    q[8] = -1.0;
    q[11] = 0.5;
    for qi in q.iter_mut().skip(12) {
        *qi = 2e-2;
    }
    let mut qdot = vec![0.0; n];
    qdot[4] = 2.0;
    s.set_state(&q, &qdot).unwrap();
    let report = s.step().unwrap();
    assert!(report.iterations > PREFACTORED_BUDGET, "{report:?}");
    assert_eq!(s.stats().fallbacks, 1);
    // The fall-back step reaches the Newton solution.
    let mut newton = solver(&model, SolverKind::Newton, 1e-9, 100);
    newton.set_state(&q, &qdot).unwrap();
    newton.step().unwrap();
    let gap = newton.q().iter().zip(s.q()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    assert!(gap < 1e-8, "{gap}");
}

#[test]
fn every_step_reports_the_smallest_det_and_the_deepest_penetration() {
    // Started 1 cm inside the ground: pushed out over the first steps.
    let model = block(4, 60, 50);
    let (q, qdot) = model.dropped_state(0.0, -0.01);
    let mut s = solver(&model, SolverKind::Newton, 1e-10, 100);
    s.set_state(&q, &qdot).unwrap();
    check_pushed_out(&model.terms, || {
        s.step().unwrap();
        (s.validity(), s.q().to_vec(), nalgebra::Vector3::zeros(), nalgebra::Matrix3::identity())
    });
}
