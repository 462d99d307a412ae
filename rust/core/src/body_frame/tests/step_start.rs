//! Tests of the start of a step: the inertia's target from the history's poses, and what a start
//! carried from the step before keeps (the inertia's `Y_k`, the damping's `C(q_{n-1})`, the contact
//! points' body positions) against a start formed afresh.

use nalgebra::Vector3;

use super::super::synthetic::body_block;
use super::super::*;
use super::{random_pose, random_rotation};
use crate::integrator::Integrator;
use crate::synthetic::BlockScene;
use crate::testing::{rel_err, Rng};

/// BDF2's inertia: the prediction from the moments of four poses, with the
/// effective step, against the sum over vertices of
/// `m/(2h'^2) |x - sum_i w_i x_i - h'^2 g|^2` (up to the step's constant).
#[test]
fn bdf2_inertia_matches_the_sum_over_vertices_of_four_poses() {
    let scene = BlockScene { learned_modes: 3, cubature_points: 0, contact_points: 0, integrator: Integrator::Bdf2, ..Default::default() };
    let b = body_block(&scene, true).unwrap();
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    let n = b.n;
    let h = Integrator::Bdf2.effective_step(b.scene.dt);
    assert_eq!(sys.effective_step(), h);
    let mut rng = Rng::new(12);
    let history: Vec<Pose> = (0..4).map(|_| random_pose(&mut rng, n, 0.05)).collect();
    let mut start = sys.step_start();
    sys.begin_step(&history.iter().collect::<Vec<_>>(), &mut start);
    let x = |pose: &Pose, v: usize| {
        let w = &b.vertex_basis[3 * n * v..3 * n * (v + 1)];
        pose.center + pose.rotation * (b.vertices[v] + Vector3::from_fn(|c, _| (0..n).map(|k| w[c * n + k] * pose.q[k]).sum()))
    };
    let g = sys.gravity();
    let weights = Integrator::Bdf2.target_weights();
    let brute = |pose: &Pose| -> f64 {
        (0..b.masses.len())
            .map(|v| {
                let xt = history.iter().zip(weights).fold(g * (h * h), |acc, (p, w)| acc + x(p, v) * w);
                0.5 * b.masses[v] * (x(pose, v) - xt).norm_squared() / (h * h)
            })
            .sum()
    };
    let (p1, p2) = (random_pose(&mut rng, n, 0.05), random_pose(&mut rng, n, 0.05));
    let d_sys = sys.energy(&start, &p1) - sys.energy(&start, &p2);
    let d_brute = brute(&p1) - brute(&p2);
    assert!((d_sys - d_brute).abs() < 1e-10 * d_brute.abs(), "{d_sys} vs {d_brute}");
}

/// A step's history repeats the poses of the step before, whose `Y_k` the
/// inertia target keeps: a target carried from step to step gives what a
/// fresh one does.
#[test]
fn inertia_target_carried_over_steps_matches_a_fresh_one() {
    for integrator in [Integrator::BackwardEuler, Integrator::Bdf2] {
        let scene = BlockScene { learned_modes: 5, cubature_points: 0, contact_points: 0, integrator, ..Default::default() };
        let b = body_block(&scene, true).unwrap();
        let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
        let big = 6 + b.n;
        let mut rng = Rng::new(13);
        let poses: Vec<Pose> = (0..8).map(|_| random_pose(&mut rng, b.n, 0.05)).collect();
        let mut ws = sys.workspace();
        let mut carried = sys.step_start();
        let (mut h_carried, mut h_fresh) = (vec![0.0; big * big], vec![0.0; big * big]);
        for t in 3..8 {
            let history: Vec<&Pose> = (0..4).map(|i| &poses[t - i]).collect();
            sys.begin_step(&history, &mut carried);
            let mut fresh = sys.step_start();
            sys.begin_step(&history, &mut fresh);
            let probe = random_pose(&mut rng, b.n, 0.05);
            let (e_carried, e_fresh) = (sys.energy(&carried, &probe), sys.energy(&fresh, &probe));
            assert!((e_carried - e_fresh).abs() <= 1e-12 * e_fresh.abs(), "{integrator:?} step {t}: {e_carried} vs {e_fresh}");
            sys.hessian(&carried, &probe, BodyHessian::GaussNewton, &mut ws, &mut h_carried);
            sys.hessian(&fresh, &probe, BodyHessian::GaussNewton, &mut ws, &mut h_fresh);
            assert!(rel_err(&h_carried, &h_fresh, 0.0) < 1e-12, "{integrator:?} step {t}: Gauss-Newton Hessian");
        }
    }
}

/// A step's start keeps from the step before what its history repeats: the
/// damping's `C(q_{n-1})` and the contact points' body positions at the
/// previous pose. With both, on a damped BDF2 block in sliding contact, the
/// carried start is the fresh one: the same anchor strain bit for bit, and the
/// same energy and gradient at a trial pose (the inertia's `Y_k`, summed in
/// another order when kept, to 1e-12).
#[test]
fn damped_contact_start_carried_over_steps_matches_a_fresh_one() {
    let scene = BlockScene {
        learned_modes: 4,
        cubature_points: 9,
        contact_points: 12,
        normal_damping: 5.0e3,
        integrator: Integrator::Bdf2,
        viscosity: 400.0,
        ..Default::default()
    };
    let b = body_block(&scene, true).unwrap();
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    let mut rng = Rng::new(17);
    let size = b.scene.size;
    let sunk = |rng: &mut Rng, x: f64| Pose {
        center: Vector3::new(x, 0.3 * x, size / 2.0 - 1e-3 - 2e-3 * rng.uniform()),
        rotation: random_rotation(rng, 1e-3),
        q: rng.vec(b.n, 1e-3),
    };
    let poses: Vec<Pose> = (0..8).map(|t| sunk(&mut rng, 2e-3 * t as f64)).collect();
    let mut carried = sys.step_start();
    let (mut ws_carried, mut ws_fresh) = (sys.workspace(), sys.workspace());
    let mut touching = 0;
    for t in 3..8 {
        let history: Vec<&Pose> = (0..4).map(|i| &poses[t - i]).collect();
        sys.begin_step(&history, &mut carried);
        let mut fresh = sys.step_start();
        sys.begin_step(&history, &mut fresh);
        assert_eq!(carried.strain, fresh.strain, "step {t}: anchor strain");
        let probe = sunk(&mut rng, 2e-3 * t as f64 + 1e-3);
        let e_carried = sys.evaluate(&carried, &probe, true, &mut ws_carried);
        let e_fresh = sys.evaluate(&fresh, &probe, true, &mut ws_fresh);
        assert!((e_carried - e_fresh).abs() <= 1e-12 * e_fresh.abs(), "step {t}: {e_carried} vs {e_fresh}");
        assert!(rel_err(&ws_carried.grad, &ws_fresh.grad, 0.0) < 1e-12, "step {t}: gradient");
        touching += usize::from(fresh.contact.normal_force.iter().any(|&f| f > 0.0));
        assert_eq!(carried.contact.normal_force, fresh.contact.normal_force, "step {t}: lagged normal forces");
    }
    assert!(touching >= 3, "in contact at {touching} of 5 steps");
}
