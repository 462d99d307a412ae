//! Checks of the reduced system: derivatives against finite differences,
//! the lane-packed assembly against naive sums, the incremental contact
//! Hessian against a fresh one.

use nalgebra::Vector3;

use super::*;
use crate::dense::rows_dot;
use crate::simd::Separate;
use crate::synthetic::{BlockModel, BlockScene};
use crate::testing::{fd_gradient, fd_jacobian, rel_err, tet_shape_gradients, Rng};

fn small_block(learned_modes: usize, cubature_points: usize, contact_points: usize) -> BlockModel {
    BlockScene { learned_modes, cubature_points, contact_points, normal_damping: 5.0e3, seed: 3, ..Default::default() }.build().unwrap()
}

/// Start of a step of a block that rests sunk in the ground, slides along x
/// and is slightly deformed.
fn sliding_start(model: &BlockModel, sys: &ReducedSystem) -> (StepStart, Vec<f64>, Vec<f64>) {
    let (mut q, qdot) = model.resting_state(0.2);
    let mut rng = Rng::new(4);
    for qi in q.iter_mut().skip(12) {
        *qi += 2e-3 * rng.uniform();
    }
    for qi in q.iter_mut().take(9) {
        *qi += 1e-2 * rng.uniform();
    }
    let mut start = sys.step_start();
    sys.begin_step(&q, &qdot, None, &mut start);
    (start, q, qdot)
}

/// `F = I + G q` of one point from its row-major 9 x n Jacobian `g`.
fn deformation_gradient(g: &[f64], q: &[f64]) -> nalgebra::Matrix3<f64> {
    let mut f = rows_dot::<Separate, 9>(g, q);
    for a in [0, 4, 8] {
        f[a] += 1.0;
    }
    crate::material::mat3_row_major(&f)
}

/// Friction regime of every contact point at q: (sticking, slipping) counts.
fn regimes(model: &BlockModel, sys: &ReducedSystem, start: &StepStart, q: &[f64]) -> (usize, usize) {
    let s = &model.scene;
    let (mut stick, mut slip) = (0, 0);
    for j in 0..sys.n_contacts() {
        let fn_lag = start.normal_force[j];
        if fn_lag == 0.0 {
            continue;
        }
        let x = sys.contact_position::<Separate>(j, q);
        let dx = x - Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
        let c = model.terms.contact_areas[j] * s.friction_stiffness / s.dt;
        if c * (dx.x * dx.x + dx.y * dx.y).sqrt() <= s.friction * fn_lag {
            stick += 1;
        } else {
            slip += 1;
        }
    }
    (stick, slip)
}

#[test]
fn gradient_and_exact_hessian_match_finite_differences() {
    let model = small_block(3, 7, 9);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let mut ws = sys.workspace();
    let n = sys.n_dofs();
    let mut rng = Rng::new(8);
    // Slipping everywhere: near the inertial target, sunk a bit deeper (damping on).
    let mut slipping: Vec<f64> = (0..n).map(|i| q0[i] + model.scene.dt * qdot[i] + 1e-5 * rng.uniform()).collect();
    slipping[11] -= 1e-5;
    // Sticking everywhere: nearly at the start, approaching the ground (damping
    // on, and clear of its kink at zero normal speed).
    let mut sticking: Vec<f64> = (0..n).map(|i| q0[i] + 1e-9 * rng.uniform()).collect();
    sticking[11] -= 1e-7;
    assert_eq!(regimes(&model, &sys, &start, &slipping).0, 0);
    assert_eq!(regimes(&model, &sys, &start, &sticking).1, 0);
    assert!(regimes(&model, &sys, &start, &sticking).0 > 0);
    for q in [slipping, sticking] {
        sys.assemble(&start, &q, Hessian::Split, &mut ws);
        let fd = fd_gradient(|x| sys.energy(&start, x), &q, 1e-8);
        assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
        let mut hess = vec![0.0; n * n];
        ws.exact_hessian(&mut hess);
        let fd_h: Vec<f64> = fd_jacobian(
            |x| {
                let mut w = sys.workspace();
                sys.assemble(&start, x, Hessian::None, &mut w);
                w.grad
            },
            &q,
            1e-9,
        )
        .into_iter()
        .flatten()
        .collect();
        assert!(rel_err(&hess, &fd_h, 1e-6) < 1e-5, "Hessian vs FD: {}", rel_err(&hess, &fd_h, 1e-6));
    }
}

#[test]
fn projected_assembly_matches_naive_sum() {
    let model = small_block(5, 11, 13);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let n = sys.n_dofs();
    let h = model.scene.dt;
    let q: Vec<f64> = (0..n).map(|i| q0[i] + h * qdot[i] + if i >= 12 { 0.02 } else { 0.0 }).collect();
    let mut ws = sys.workspace();
    sys.assemble(&start, &q, Hessian::Split, &mut ws);

    let mut naive: Vec<f64> = model.mass.iter().map(|m| m / (h * h)).collect();
    // The system holds the Jacobians in single precision: that rounding is its model.
    let stored: Vec<f64> = model.terms.cubature_jacobians.iter().map(|&v| f64::from(v as f32)).collect();
    for (g, w) in stored.chunks_exact(9 * n).zip(&model.terms.cubature_weights) {
        let f = deformation_gradient(g, &q);
        let hp = model.terms.material.projected_hessian(&f);
        for r in 0..n {
            for c in 0..n {
                let mut s = 0.0;
                for a in 0..9 {
                    for b in 0..9 {
                        s += g[a * n + r] * hp[(a, b)] * g[b * n + c];
                    }
                }
                naive[r * n + c] += w * s;
            }
        }
    }
    for j in 0..sys.n_contacts() {
        let x = sys.contact_position::<Separate>(j, &q);
        let xp = Vector3::from_column_slice(&start.x_prev[3 * j..3 * j + 3]);
        let hc = sys.points.model().evaluate(&sys.points.planes()[0], sys.areas[j], start.normal_force[j], &x, &xp).hessian.matrix();
        let wj = &model.terms.contact_basis[3 * n * j..3 * n * (j + 1)];
        for r in 0..n {
            for c in 0..n {
                naive[r * n + c] +=
                    (0..3).flat_map(|a| (0..3).map(move |b| (a, b))).map(|(a, b)| wj[a * n + r] * hc[(a, b)] * wj[b * n + c]).sum::<f64>();
            }
        }
    }
    assert!(rel_err(&ws.hess, &naive, 1e-9) < 1e-11, "assembly error {}", rel_err(&ws.hess, &naive, 1e-9));
}

#[test]
fn incremental_contact_hessian_matches_a_fresh_one() {
    let model = small_block(4, 9, 40);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let n = sys.n_dofs();
    let h = model.scene.dt;
    let mut ws = sys.workspace();
    let mut exact = sys.contact_hessian_state(false);
    let mut fresh = vec![0.0; n * n];
    let mut rng = Rng::new(21);
    // A walk through slipping, sticking, lifted and sunk states.
    for step in 0..30 {
        let s = [1.0, 0.0, 1e-3, 0.5][step % 4];
        let mut q: Vec<f64> = (0..n).map(|i| q0[i] + s * h * qdot[i] + 1e-6 * rng.uniform()).collect();
        q[11] += [0.0, -2e-5, 3e-4, 1e-5][step % 4];
        sys.evaluate(&start, &q, true, &mut ws);
        sys.update_contact_hessian(&mut ws, &mut exact);
        sys.contact_hessian(&start, &q, &mut ws, &mut fresh);
        assert!(rel_err(exact.matrix(), &fresh, 1e-9) < 1e-10, "step {step}: {}", rel_err(exact.matrix(), &fresh, 1e-9));
    }
}

#[test]
fn contact_model_matches_the_energy_to_second_order() {
    let model = small_block(3, 11, 9);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let n = sys.n_dofs();
    let q: Vec<f64> = (0..n).map(|i| q0[i] + model.scene.dt * qdot[i]).collect();
    let mut ws = sys.workspace();
    let e = sys.evaluate(&start, &q, true, &mut ws);
    let mut g_el = vec![0.0; n];
    ws.elastic_gradient(&mut g_el);
    let grad = ws.grad.clone();
    let e_el = ws.elastic_energy;
    let mut k_el = vec![0.0; n * n];
    let mut clamped = vec![0.0; n * n];
    sys.elastic_hessian(&q, &mut ws, &mut k_el, Some(&mut clamped));
    for (k, c) in k_el.iter_mut().zip(&clamped) {
        *k -= c;
    }
    let m = ElasticModel { origin: &q, energy: e_el, gradient: &g_el, hessian: &k_el };
    // Same value and gradient at the expansion point.
    assert!((sys.evaluate_model(&start, &q, &m, true, &mut ws) - e).abs() < 1e-14 * e.abs().max(1.0));
    assert!(rel_err(&ws.grad, &grad, 1e-9) < 1e-12);
    // Its gradient is that of its energy, and it follows E to second order.
    let mut rng = Rng::new(5);
    let dir: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
    let at = |t: f64| -> Vec<f64> { q.iter().zip(&dir).map(|(x, d)| x + t * 1e-4 * d).collect() };
    let p = at(1.0);
    sys.evaluate_model(&start, &p, &m, true, &mut ws);
    let fd = fd_gradient(|x| sys.evaluate_model(&start, x, &m, false, &mut sys.workspace()), &p, 1e-8);
    assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "model gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
    let mut gap = |t: f64| {
        let x = at(t);
        (sys.evaluate(&start, &x, false, &mut ws) - sys.evaluate_model(&start, &x, &m, false, &mut ws)).abs()
    };
    // Third order: halving the step divides the gap by about 8.
    let (g1, g2) = (gap(1.0), gap(0.5));
    assert!(g2 < g1 / 5.0 || g1 < 1e-15, "model gap {g1} -> {g2}");
}

#[test]
fn stick_switch_flags_points_carried_through_the_stick_region() {
    let model = small_block(2, 5, 16);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let n = sys.n_dofs();
    let h = model.scene.dt;
    // Slipping along +x; a step that reverses the slip switches every
    // slipping point, one that carries it on switches none.
    let q: Vec<f64> = (0..n).map(|i| q0[i] + h * qdot[i]).collect();
    assert!(regimes(&model, &sys, &start, &q).1 > 0);
    let mut ws = sys.workspace();
    let mut rhs = vec![0.0; n];
    let mut back = vec![0.0; n];
    back[9] = -2.0 * h * qdot[9];
    sys.evaluate(&start, &q, true, &mut ws);
    let rows = sys.stick_switch(&start, &back, &mut ws, &mut rhs);
    assert_eq!(rows, 2 * regimes(&model, &sys, &start, &q).1);
    assert!(rhs[9] > 0.0, "stick force minus slip force opposes the slip");
    let mut on = vec![0.0; n];
    on[9] = 0.5 * h * qdot[9];
    let mut rhs = vec![0.0; n];
    assert_eq!(sys.stick_switch(&start, &on, &mut ws, &mut rhs), 0);
    assert!(rhs.iter().all(|r| *r == 0.0));
}

#[test]
fn rigid_rotation_has_zero_elastic_energy_and_force() {
    let model = small_block(2, 20, 0);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let n = sys.n_dofs();
    let r = nalgebra::Rotation3::from_euler_angles(0.7, -0.4, 1.9).into_inner();
    let mut q = vec![0.0; n];
    for i in 0..3 {
        for j in 0..3 {
            q[3 * j + i] = r[(i, j)] - if i == j { 1.0 } else { 0.0 };
        }
    }
    q[9..12].copy_from_slice(&[0.3, -0.1, 0.5]);
    let mut start = sys.step_start();
    sys.begin_step(&q, &vec![0.0; n], None, &mut start);
    // With q = qtilde the inertia vanishes: what is left is -f.q + elastic.
    let gravity_work: f64 = model.gravity_force.iter().zip(&q).map(|(f, x)| f * x).sum();
    let elastic = sys.energy(&start, &q) + gravity_work;
    assert!(elastic.abs() < 1e-12 * model.terms.material.mu() * model.scene.size.powi(3), "elastic energy {elastic}");
    let mut ws = sys.workspace();
    sys.assemble(&start, &q, Hessian::None, &mut ws);
    let force_scale = model.terms.material.mu() * model.scene.size.powi(3) * 100.0;
    for (g, f) in ws.grad.iter().zip(&model.gravity_force) {
        assert!((g + f).abs() < 1e-10 * force_scale, "elastic force {}", g + f);
    }
}

#[test]
fn invalid_inputs_are_rejected() {
    let model = small_block(1, 3, 2);
    let mut inp = model.inputs();
    let short = &model.mass[..model.mass.len() - 1];
    inp.mass = short;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::ShapeMismatch { .. })));

    let n = model.n_dofs();
    let mut asym = model.mass.clone();
    asym[1] += 1.0;
    let mut inp = model.inputs();
    inp.mass = &asym;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::SingularMass { .. })));

    let mut indefinite = model.mass.clone();
    indefinite[n + 1] = -1.0;
    let mut inp = model.inputs();
    inp.mass = &indefinite;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::SingularMass { .. })));

    let mut weights = model.terms.cubature_weights.clone();
    weights[0] = -1.0;
    let mut inp = model.inputs();
    inp.elastic.cubature_weights = &weights;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::InvalidParameter { .. })));

    let mut nan = model.terms.contact_rest.clone();
    nan[2] = f64::NAN;
    let mut inp = model.inputs();
    inp.contact.rest = &nan;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::NonFinite { .. })));

    let mut inp = model.inputs();
    inp.dt = 0.0;
    assert!(matches!(ReducedSystem::new(&inp), Err(LicromError::InvalidParameter { .. })));
}

#[test]
fn elastic_term_alone_matches_its_part_of_e_and_finite_differences() {
    let model = small_block(3, 11, 9);
    let sys = ReducedSystem::new(&model.inputs()).unwrap();
    let (start, q0, _) = sliding_start(&model, &sys);
    let n = sys.n_dofs();
    let q: Vec<f64> = q0.iter().enumerate().map(|(i, x)| x + if i >= 12 { 0.01 } else { 0.0 }).collect();
    let mut ws = sys.workspace();
    sys.evaluate(&start, &q, true, &mut ws);
    let (e_part, mut g_part) = (ws.elastic_energy, vec![0.0; n]);
    ws.elastic_gradient(&mut g_part);
    let e = sys.elastic(&q, true, &mut ws);
    assert!(e > 0.0 && (e - e_part).abs() <= 1e-14 * e, "{e} vs {e_part}");
    assert!(rel_err(&ws.grad, &g_part, 1e-12) < 1e-14, "gradient vs E's elastic part: {}", rel_err(&ws.grad, &g_part, 1e-12));
    assert_eq!(sys.elastic(&q, false, &mut sys.workspace()), e);
    let fd = fd_gradient(|x| sys.elastic(x, false, &mut sys.workspace()), &q, 1e-8);
    assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
}

/// The six tets of a unit cube (vertex i at the corner of bits x, y, z of i,
/// the corners moved by up to 0.1) on its diagonal 0-7, their shape
/// gradients (K x 4 x 3) and random basis rows at the 8 vertices (8 x 3 x n).
fn cube_tets(rng: &mut Rng, n: usize) -> (Vec<usize>, Vec<f64>, Vec<f64>) {
    let corners: Vec<Vector3<f64>> =
        (0..8).map(|i| Vector3::new((i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64) + Vector3::from_vec(rng.vec(3, 0.1))).collect();
    let tets = [[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]];
    let (grads, _) = tet_shape_gradients(&corners, &tets);
    (tets.iter().flatten().copied().collect(), grads, rng.vec(8 * 3 * n, 0.05))
}

#[test]
fn vertex_form_of_the_cubature_matches_its_jacobians_and_finite_differences() {
    let model = small_block(3, 11, 9);
    let n = model.n_dofs();
    let mut rng = Rng::new(21);
    let (tet_vertices, shape_gradients, vertex_basis) = cube_tets(&mut rng, n);
    // G_k = sum_a W_{v_a} (x) grad N_a, row 3 i + j of the 9.
    let k = tet_vertices.len() / 4;
    let mut jacobians = vec![0.0; k * 9 * n];
    for p in 0..k {
        for a in 0..9 {
            for c in 0..n {
                jacobians[9 * n * p + a * n + c] =
                    (0..4).map(|t| vertex_basis[(3 * tet_vertices[4 * p + t] + a / 3) * n + c] * shape_gradients[12 * p + 3 * t + a % 3]).sum();
            }
        }
    }
    // One point of zero weight, dropped by both forms.
    let weights: Vec<f64> = (0..k).map(|p| if p == 2 { 0.0 } else { 1e-3 * (1.0 + 0.1 * p as f64) }).collect();
    let vertex_strain = VertexStrainInputs { vertex_basis: &vertex_basis, tet_vertices: &tet_vertices, shape_gradients: &shape_gradients };
    let base = ReducedInputs {
        elastic: ElasticInputs { cubature_jacobians: &jacobians, cubature_weights: &weights, ..model.inputs().elastic },
        ..model.inputs()
    };
    let by_points = ReducedSystem::new(&base).unwrap();
    let by_vertices =
        ReducedSystem::new(&ReducedInputs { elastic: ElasticInputs { vertex_strain: Some(vertex_strain), ..base.elastic }, ..base }).unwrap();
    assert!(by_points.elastic.vertices.is_none() && by_vertices.elastic.vertices.is_some(), "8 vertices for 5 points: the vertex form is cheaper");
    let q = rng.vec(n, 0.3);
    let (mut ws_p, mut ws_v) = (by_points.workspace(), by_vertices.workspace());
    let e_p = by_points.elastic(&q, true, &mut ws_p);
    let e_v = by_vertices.elastic(&q, true, &mut ws_v);
    // The Jacobians are held in f32 (relative 6e-8), the vertex rows in f64.
    assert!(e_v > 0.0 && (e_v - e_p).abs() < 1e-6 * e_v, "energy {e_v} vs {e_p}");
    assert!(rel_err(&ws_v.grad, &ws_p.grad, 1e-9) < 1e-6, "gradient vs the Jacobians': {}", rel_err(&ws_v.grad, &ws_p.grad, 1e-9));
    let mut g_el = vec![0.0; n];
    ws_v.elastic_gradient(&mut g_el);
    assert_eq!(g_el, ws_v.grad);
    // Without a workspace the vertex displacements are formed per point, by the same products.
    assert_eq!(by_vertices.elastic(&q, false, &mut by_vertices.workspace()), e_v);
    let fd = fd_gradient(|x| by_vertices.elastic(x, false, &mut by_vertices.workspace()), &q, 1e-7);
    assert!(rel_err(&ws_v.grad, &fd, 1e-6) < 1e-6, "gradient vs FD: {}", rel_err(&ws_v.grad, &fd, 1e-6));
    // Through E too: the same total gradient as the Jacobians give, and E's elastic part.
    let (start, _, _) = sliding_start(&model, &by_points);
    by_points.evaluate(&start, &q, true, &mut ws_p);
    by_vertices.evaluate(&start, &q, true, &mut ws_v);
    assert!(rel_err(&ws_v.grad, &ws_p.grad, 1e-9) < 1e-6 && (ws_v.elastic_energy - e_v).abs() <= 1e-14 * e_v);
    // With damping each system forms its step start's anchor strain C(q_n) its own way (the vertex
    // form through the vertices); the damped energies and gradients at q then agree as the plain ones do.
    let damped = |vs: Option<VertexStrainInputs>| {
        ReducedSystem::new(&ReducedInputs { elastic: ElasticInputs { viscosity: 50.0, vertex_strain: vs, ..base.elastic }, ..base }).unwrap()
    };
    let (damped_p, damped_v) = (damped(None), damped(Some(vertex_strain)));
    let (start_p, _, _) = sliding_start(&model, &damped_p);
    let (start_v, _, _) = sliding_start(&model, &damped_v);
    damped_p.evaluate(&start_p, &q, true, &mut ws_p);
    damped_v.evaluate(&start_v, &q, true, &mut ws_v);
    // The damping's energy: each damped elastic term less the plain one of the same form.
    let damping_p = ws_p.elastic_energy - by_points.elastic(&q, false, &mut by_points.workspace());
    let damping_v = ws_v.elastic_energy - by_vertices.elastic(&q, false, &mut by_vertices.workspace());
    assert!(damping_v > 1e-4 * ws_v.elastic_energy, "the damping counts: {damping_v} of {}", ws_v.elastic_energy);
    assert!((damping_v - damping_p).abs() < 1e-5 * damping_v, "damping energy {damping_v} vs {damping_p}");
    assert!(rel_err(&ws_v.grad, &ws_p.grad, 1e-9) < 1e-6, "damped gradient vs the Jacobians': {}", rel_err(&ws_v.grad, &ws_p.grad, 1e-9));
}

#[test]
fn vertex_form_that_does_not_reproduce_the_jacobians_is_rejected() {
    let model = small_block(3, 11, 9);
    let n = model.n_dofs();
    let mut rng = Rng::new(22);
    let (tet_vertices, shape_gradients, vertex_basis) = cube_tets(&mut rng, n);
    let jacobians = rng.vec(6 * 9 * n, 0.05);
    let weights = vec![1e-3; 6];
    let inputs = |vertex_basis: &'_ [f64], tet_vertices: &'_ [usize]| {
        let vs = VertexStrainInputs { vertex_basis, tet_vertices, shape_gradients: &shape_gradients };
        let elastic = ElasticInputs { cubature_jacobians: &jacobians, cubature_weights: &weights, vertex_strain: Some(vs), ..model.inputs().elastic };
        ReducedSystem::new(&ReducedInputs { elastic, ..model.inputs() })
    };
    let err = inputs(&vertex_basis, &tet_vertices).unwrap_err().to_string();
    assert!(err.contains("cubature_vertex_basis") && err.contains("reproduce"), "{err}");
    let mut far = tet_vertices.clone();
    far[5] = 8;
    let err = inputs(&vertex_basis, &far).unwrap_err().to_string();
    assert!(err.contains("cubature_tet_vertices") && err.contains("8"), "{err}");
    let err = inputs(&vertex_basis[..10], &tet_vertices).unwrap_err().to_string();
    assert!(err.contains("cubature_vertex_basis"), "{err}");
}

/// The material damping's energy `sum_p w_p eta/h |(F^T F - F_a^T F_a)/2|^2 / 2` at `q` anchored at `qa`, summed
/// point by point (Jacobians as stored, in f32).
fn naive_damping_energy(model: &BlockModel, q: &[f64], qa: &[f64], eta: f64) -> f64 {
    let n = q.len();
    let stored: Vec<f64> = model.terms.cubature_jacobians.iter().map(|&v| f64::from(v as f32)).collect();
    stored
        .chunks_exact(9 * n)
        .zip(&model.terms.cubature_weights)
        .map(|(g, w)| {
            let (f, fa) = (deformation_gradient(g, q), deformation_gradient(g, qa));
            let d = 0.5 * (f.transpose() * f - fa.transpose() * fa);
            w * eta / model.scene.dt * 0.5 * d.norm_squared()
        })
        .sum()
}

/// A block scene with material damping (viscosity `eta`) and its undamped twin, started sliding, at a random `q` near
/// the damped run's next step: the two energies differ by the naive damping sum, checked here.
struct DampedPair {
    sys: ReducedSystem,
    plain: ReducedSystem,
    start: StepStart,
    plain_start: StepStart,
    q0: Vec<f64>,
    q: Vec<f64>,
}

fn damped_pair_matching_the_naive_sum(learned_modes: usize, cubature_points: usize, eta: f64) -> DampedPair {
    let damped_scene =
        BlockScene { learned_modes, cubature_points, contact_points: 9, normal_damping: 5.0e3, seed: 3, viscosity: eta, ..Default::default() };
    let model = damped_scene.build().unwrap();
    let plain_model = BlockScene { viscosity: 0.0, ..damped_scene }.build().unwrap();
    let (sys, plain) = (ReducedSystem::new(&model.inputs()).unwrap(), ReducedSystem::new(&plain_model.inputs()).unwrap());
    let (start, q0, qdot) = sliding_start(&model, &sys);
    let (plain_start, _, _) = sliding_start(&plain_model, &plain);
    let mut rng = Rng::new(12);
    let q: Vec<f64> = (0..sys.n_dofs()).map(|i| q0[i] + model.scene.dt * qdot[i] + 0.02 * rng.uniform()).collect();
    // Energy: the difference is the naive sum over the points (Jacobians as stored, in f32).
    let naive = naive_damping_energy(&model, &q, &q0, eta);
    let diff = sys.energy(&start, &q) - plain.energy(&plain_start, &q);
    assert!(naive > 0.0 && (diff - naive).abs() < 1e-10 * naive, "damping energy {diff} vs naive {naive}");
    DampedPair { sys, plain, start, plain_start, q0, q }
}

/// Affine modes alone on one cubature point: every column of the Jacobians is constant over the points, so the
/// packed groups are empty; the damping's anchor is still formed (it once panicked) and its energy is the naive one.
#[test]
fn material_damping_with_every_column_constant_matches_a_naive_sum() {
    damped_pair_matching_the_naive_sum(0, 1, 400.0);
}

/// The material damping `sum_k w_k kappa/2 |D_k|^2` (`kappa = eta/h`, `D = (F^T F - C_a)/2`): its energy
/// against a naive sum, its gradient against finite differences, its Hessian rows against finite
/// differences at the anchor (where the Gauss-Newton part is the whole Hessian), and the vertex form
/// against the Jacobians.
#[test]
fn material_damping_matches_a_naive_sum_and_finite_differences() {
    let DampedPair { sys, plain, start, plain_start, q0, q } = damped_pair_matching_the_naive_sum(3, 7, 400.0);
    assert!(sys.elastic.damped() && !plain.elastic.damped());
    // Gradient of the whole E against finite differences.
    let mut ws = sys.workspace();
    sys.assemble(&start, &q, Hessian::Projected, &mut ws);
    let fd = fd_gradient(|x| sys.energy(&start, x), &q, 1e-8);
    assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-5, "gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
    // At the anchor the damping's Hessian is its Gauss-Newton part: the assembled difference against FD of the gradients' difference.
    let at = q0.clone();
    let (mut wd, mut wp) = (sys.workspace(), plain.workspace());
    sys.assemble(&start, &at, Hessian::Projected, &mut wd);
    plain.assemble(&plain_start, &at, Hessian::Projected, &mut wp);
    let hess_diff: Vec<f64> = wd.hess.iter().zip(&wp.hess).map(|(a, b)| a - b).collect();
    let fd_h: Vec<f64> = fd_jacobian(
        |x| {
            let (mut a, mut b) = (sys.workspace(), plain.workspace());
            sys.assemble(&start, x, Hessian::None, &mut a);
            plain.assemble(&plain_start, x, Hessian::None, &mut b);
            a.grad.iter().zip(&b.grad).map(|(u, v)| u - v).collect()
        },
        &at,
        1e-7,
    )
    .into_iter()
    .flatten()
    .collect();
    let scale = hess_diff.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0 && rel_err(&hess_diff, &fd_h, 1e-6) < 1e-5, "damping Hessian vs FD: {}", rel_err(&hess_diff, &fd_h, 1e-6));
    // The elastic energy alone leaves the damping out.
    assert_eq!(sys.elastic(&q, false, &mut sys.workspace()), plain.elastic(&q, false, &mut plain.workspace()));
}

#[test]
fn negative_or_nonfinite_viscosity_is_rejected() {
    for eta in [-1.0, f64::NAN, f64::INFINITY] {
        let model = small_block(2, 5, 4);
        let inputs = model.inputs();
        let elastic = ElasticInputs { viscosity: eta, ..inputs.elastic };
        let err = ReducedSystem::new(&ReducedInputs { elastic, ..inputs }).unwrap_err().to_string();
        assert!(err.contains("viscosity"), "{err}");
    }
}
