//! Tests of the body-frame model: derivatives against finite differences,
//! moments against sums over vertices, physics against analytic results.

use nalgebra::{Matrix3, Vector3};

use super::rotation::{exp_map, log_map};
use super::solver::{BodyFrameSettings, BodyFrameSolver};
use super::synthetic::{body_block, BodyBlock};
use super::*;
use crate::contact::Plane;
use crate::contact_points::ContactInputs;
use crate::integrator::Integrator;
use crate::synthetic::BlockScene;
use crate::testing::{check_pushed_out, fd_gradient, fd_jacobian, rel_err, Rng};
use crate::LicromError;

mod step_start;

fn block(learned_modes: usize, cubature_points: usize, contact_points: usize, affine: bool) -> BodyBlock {
    let scene = BlockScene { learned_modes, cubature_points, contact_points, normal_damping: 5.0e3, ..Default::default() };
    body_block(&scene, affine).unwrap()
}

pub(super) fn random_rotation(rng: &mut Rng, angle: f64) -> Matrix3<f64> {
    exp_map(&(Vector3::new(rng.uniform(), rng.uniform(), rng.uniform()).normalize() * angle))
}

pub(super) fn random_pose(rng: &mut Rng, n: usize, q_scale: f64) -> Pose {
    Pose { center: Vector3::new(rng.uniform(), rng.uniform(), rng.uniform()), rotation: random_rotation(rng, 2.0), q: rng.vec(n, q_scale) }
}

/// `pose (+) x` for x = (dc, omega, dq).
fn moved(pose: &Pose, x: &[f64]) -> Pose {
    let mut out = pose.clone();
    out.retract(pose, x, 1.0);
    out
}

/// Checks the gradient against central differences of the energy, and the
/// exact Hessian against the symmetrised Jacobian of the gradient (the
/// Jacobian of the left-trivialised gradient differs from the Hessian of the
/// pulled-back function only by an antisymmetric omega-omega block).
fn check_derivatives(sys: &BodyFrameSystem, start: &BodyStart, pose: &Pose, what: &str) {
    let big = 6 + sys.n_modes();
    let mut ws = sys.workspace();
    sys.evaluate(start, pose, true, &mut ws);
    let grad = ws.grad.clone();
    let zero = vec![0.0; big];
    let fd = fd_gradient(|x| sys.energy(start, &moved(pose, x)), &zero, 1e-7);
    assert!(rel_err(&grad, &fd, 1e-6) < 1e-6, "{what}: gradient vs FD {}\n{grad:?}\n{fd:?}", rel_err(&grad, &fd, 1e-6));
    let mut hess = vec![0.0; big * big];
    sys.hessian(start, pose, BodyHessian::Exact, &mut ws, &mut hess);
    let jac = fd_jacobian(
        |x| {
            let mut w = sys.workspace();
            sys.evaluate(start, &moved(pose, x), true, &mut w);
            w.grad
        },
        &zero,
        1e-8,
    );
    let sym: Vec<f64> = (0..big * big).map(|i| 0.5 * (jac[i / big][i % big] + jac[i % big][i / big])).collect();
    assert!(rel_err(&hess, &sym, 1e-6) < 2e-6, "{what}: Hessian vs FD {}", rel_err(&hess, &sym, 1e-6));
    // The solver's matrix is positive definite.
    sys.hessian(start, pose, BodyHessian::GaussNewton, &mut ws, &mut hess);
    assert!(crate::cholesky::Cholesky::factor(&hess, big).is_ok(), "{what}: Gauss-Newton Hessian not positive definite");
}

#[test]
fn moments_match_sums_over_vertices() {
    let b = block(3, 0, 0, true);
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    let n = b.n;
    let h = b.scene.dt;
    let mut rng = Rng::new(11);
    let (cur, prev) = (random_pose(&mut rng, n, 0.05), random_pose(&mut rng, n, 0.05));
    let mut start = sys.step_start();
    sys.begin_step(&[&cur, &prev], &mut start);
    let y = |pose: &Pose, v: usize| {
        let w = &b.vertex_basis[3 * n * v..3 * n * (v + 1)];
        b.vertices[v] + Vector3::from_fn(|c, _| (0..n).map(|k| w[c * n + k] * pose.q[k]).sum())
    };
    let mut b0 = Matrix3::zeros();
    let mut bk = vec![Matrix3::zeros(); n];
    for (v, m) in b.masses.iter().enumerate() {
        let a = 2.0 * cur.rotation * y(&cur, v) - prev.rotation * y(&prev, v);
        b0 += a * b.vertices[v].transpose() * *m;
        let w = &b.vertex_basis[3 * n * v..3 * n * (v + 1)];
        for (k, bk) in bk.iter_mut().enumerate() {
            *bk += a * Vector3::new(w[k], w[n + k], w[2 * n + k]).transpose() * *m;
        }
    }
    assert!((start.inertia.b0 - b0).amax() < 1e-12 * b0.amax());
    for k in 0..n {
        assert!((start.inertia.bk[k] - bk[k]).amax() < 1e-12 * b0.amax(), "B_{k}");
    }
    // The whole inertia (no cubature, no contact) against the sum over vertices,
    // up to the constant of the step.
    let g = sys.gravity();
    let brute = |pose: &Pose| -> f64 {
        (0..b.masses.len())
            .map(|v| {
                let xt = 2.0 * (cur.center + cur.rotation * y(&cur, v)) - (prev.center + prev.rotation * y(&prev, v)) + g * (h * h);
                0.5 * b.masses[v] * (pose.center + pose.rotation * y(pose, v) - xt).norm_squared() / (h * h)
            })
            .sum()
    };
    let (p1, p2) = (random_pose(&mut rng, n, 0.05), random_pose(&mut rng, n, 0.05));
    let d_sys = sys.energy(&start, &p1) - sys.energy(&start, &p2);
    let d_brute = brute(&p1) - brute(&p2);
    assert!((d_sys - d_brute).abs() < 1e-10 * d_brute.abs(), "{d_sys} vs {d_brute}");
    // The Gauss-Newton inertia against `sum_v m_v Jv^T Jv`, `Jv = [I, -[R y_v]x, R W_v]`
    // with the rotation of the pose and `y_v` of the step's start (its modal block
    // `Mqq` is the elastic system's).
    let big = 6 + n;
    let mut gn = vec![0.0; big * big];
    start.inertia.add_gauss_newton(sys.moments(), &p1, 1.0, &mut gn);
    let mut brute_gn = vec![0.0; big * big];
    for (v, m) in b.masses.iter().enumerate() {
        let w = &b.vertex_basis[3 * n * v..3 * n * (v + 1)];
        let jv = nalgebra::DMatrix::from_fn(3, big, |i, c| match c {
            0..3 => f64::from(u8::from(i == c)),
            3..6 => -super::rotation::skew(&(p1.rotation * y(&cur, v)))[(i, c - 3)],
            _ => (p1.rotation * Vector3::new(w[c - 6], w[n + c - 6], w[2 * n + c - 6]))[i],
        });
        let jtj = jv.transpose() * jv * *m;
        for r in 0..big {
            for c in 0..big {
                if r < 6 || c < 6 {
                    brute_gn[r * big + c] += jtj[(r, c)];
                }
            }
        }
    }
    assert!(rel_err(&gn, &brute_gn, 0.0) < 1e-12, "Gauss-Newton inertia: {}", rel_err(&gn, &brute_gn, 0.0));
    // Orthogonality to the rigid modes makes c the centre of mass.
    for k in 0..n {
        let (mut lin, mut ang) = (Vector3::zeros(), Vector3::zeros());
        for (v, m) in b.masses.iter().enumerate() {
            let w = &b.vertex_basis[3 * n * v..3 * n * (v + 1)];
            let wk = Vector3::new(w[k], w[n + k], w[2 * n + k]);
            lin += wk * *m;
            ang += b.vertices[v].cross(&wk) * *m;
        }
        assert!(lin.norm() < 1e-14 && ang.norm() < 1e-14, "mode {k} carries momentum");
    }
}

#[test]
fn inertia_and_elastic_derivatives_match_finite_differences() {
    let mut rng = Rng::new(3);
    // Inertia alone, then with the elastic energy.
    for cubature in [0, 9] {
        let b = block(3, cubature, 0, true);
        let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
        let (cur, prev) = (random_pose(&mut rng, b.n, 0.02), random_pose(&mut rng, b.n, 0.02));
        let mut start = sys.step_start();
        sys.begin_step(&[&cur, &prev], &mut start);
        check_derivatives(&sys, &start, &random_pose(&mut rng, b.n, 0.05), &format!("{cubature} cubature points"));
    }
}

/// The material damping in the body frame: a function of q alone (any c and R of the pose or of its
/// history give the same term), zero where q stays put, its gradient against finite differences.
#[test]
fn material_damping_depends_on_q_alone_and_matches_finite_differences() {
    let mut rng = Rng::new(5);
    let scene =
        BlockScene { learned_modes: 3, cubature_points: 9, contact_points: 0, integrator: Integrator::Bdf2, viscosity: 400.0, ..Default::default() };
    let b = body_block(&scene, true).unwrap();
    let plain = body_block(&BlockScene { viscosity: 0.0, ..scene }, true).unwrap();
    let (sys, sys_plain) = (BodyFrameSystem::new(&b.inputs()).unwrap(), BodyFrameSystem::new(&plain.inputs()).unwrap());
    let damping = |history: &[Pose], pose: &Pose| {
        let history: Vec<&Pose> = history.iter().collect();
        let (mut start, mut start_plain) = (sys.step_start(), sys_plain.step_start());
        sys.begin_step(&history, &mut start);
        sys_plain.begin_step(&history, &mut start_plain);
        sys.energy(&start, pose) - sys_plain.energy(&start_plain, pose)
    };
    // A history that only moves rigidly: no strain rate at its q.
    let q_still = rng.vec(b.n, 0.02);
    let still: Vec<Pose> = (0..4).map(|_| Pose { q: q_still.clone(), ..random_pose(&mut rng, b.n, 0.0) }).collect();
    let at_rest = Pose { q: q_still.clone(), ..random_pose(&mut rng, b.n, 0.0) };
    assert!(damping(&still, &at_rest).abs() < 1e-12, "no strain rate: {}", damping(&still, &at_rest));
    // A deforming history: the same term for any c and R of the poses.
    let history: Vec<Pose> = (0..4).map(|_| random_pose(&mut rng, b.n, 0.02)).collect();
    let pose = random_pose(&mut rng, b.n, 0.05);
    let moved_history: Vec<Pose> = history.iter().map(|p| Pose { q: p.q.clone(), ..random_pose(&mut rng, b.n, 0.0) }).collect();
    let turned = Pose { q: pose.q.clone(), ..random_pose(&mut rng, b.n, 0.0) };
    let d = damping(&history, &pose);
    assert!(d > 0.0 && (damping(&moved_history, &turned) - d).abs() < 1e-9 * d, "{d} vs {} moved", damping(&moved_history, &turned));
    let history: Vec<&Pose> = history.iter().collect();
    let mut start = sys.step_start();
    sys.begin_step(&history, &mut start);
    let mut ws = sys.workspace();
    sys.evaluate(&start, &pose, true, &mut ws);
    let fd = fd_gradient(|x| sys.energy(&start, &moved(&pose, x)), &vec![0.0; 6 + b.n], 1e-7);
    assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-6, "gradient vs FD {}", rel_err(&ws.grad, &fd, 1e-6));
    let mut hess = vec![0.0; (6 + b.n) * (6 + b.n)];
    sys.hessian(&start, &pose, BodyHessian::GaussNewton, &mut ws, &mut hess);
    assert!(crate::cholesky::Cholesky::factor(&hess, 6 + b.n).is_ok(), "Gauss-Newton Hessian not positive definite");
}

/// A block with contact points on its bottom face over a level plane, whose
/// step starts `depth` (m) in the ground and moves by `slide` (m, along x) and
/// `sink` (m, down) with a small turn and deformation.
fn contact_case(depth: f64, slide: f64, sink: f64) -> (BodyBlock, BodyFrameSystem, BodyStart, Pose) {
    let b = block(2, 7, 12, true);
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    let mut rng = Rng::new(5);
    let cur = Pose { center: Vector3::new(0.01, 0.02, b.scene.size / 2.0 - depth), rotation: Matrix3::identity(), q: vec![0.0; b.n] };
    let mut start = sys.step_start();
    sys.begin_step(&[&cur, &cur], &mut start);
    let mut pose = cur.clone();
    pose.center += Vector3::new(slide, 0.3 * slide, -sink);
    pose.rotation = exp_map(&Vector3::new(0.0, 0.0, 1e-3 * slide / b.scene.size));
    pose.q = rng.vec(b.n, 1e-3 * slide.max(sink) / b.scene.size);
    (b, sys, start, pose)
}

/// Tangential force on each point with a lagged normal force, relative to its Coulomb limit.
fn coulomb_ratios(b: &BodyBlock, sys: &BodyFrameSystem, start: &BodyStart, pose: &Pose) -> Vec<f64> {
    let c = sys.n_contacts();
    let mut forces = vec![0.0; 3 * c];
    sys.contact_forces(start, pose, &mut forces);
    (0..c)
        .filter(|&j| start.contact.normal_force[j] > 0.0)
        .map(|j| (forces[3 * j].powi(2) + forces[3 * j + 1].powi(2)).sqrt() / (b.scene.friction * start.contact.normal_force[j]))
        .collect()
}

#[test]
fn contact_derivatives_match_finite_differences() {
    // Penalty only: not in contact at the start, sunk at the trial pose.
    let (_, sys, start, pose) = contact_case(-1e-4, 1e-4, 3e-4);
    assert!(start.contact.normal_force.iter().all(|f| *f == 0.0));
    let mut forces = vec![0.0; 3 * sys.n_contacts()];
    sys.contact_forces(&start, &pose, &mut forces);
    assert!(forces.chunks_exact(3).filter(|f| f[2] > 0.0).count() >= 2, "no point pushed out of the ground");
    check_derivatives(&sys, &start, &pose, "penalty");
    // In contact, sinking (damping on) and sticking.
    let (b, sys, start, pose) = contact_case(4e-4, 1e-7, 1e-6);
    let ratios = coulomb_ratios(&b, &sys, &start, &pose);
    assert!(!ratios.is_empty() && ratios.iter().all(|r| *r < 0.99), "not sticking: {ratios:?}");
    check_derivatives(&sys, &start, &pose, "damping and stick");
    // In contact and slipping.
    let (b, sys, start, pose) = contact_case(4e-4, 1e-3, 1e-6);
    let ratios = coulomb_ratios(&b, &sys, &start, &pose);
    assert!(!ratios.is_empty() && ratios.iter().all(|r| (r - 1.0).abs() < 1e-9), "not slipping: {ratios:?}");
    check_derivatives(&sys, &start, &pose, "slip");
}

/// A turned block with an edge in the ground, slipping there: its step start
/// and a pose moved from it (turned, slid and deformed).
fn turned_case() -> (BodyBlock, BodyFrameSystem, BodyStart, Pose) {
    let b = block(3, 11, 60, true);
    let b = BodyBlock { scene: b.scene, ..body_block(&BlockScene { contact_on_all_faces: true, ..b.scene }, true).unwrap() };
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    let mut rng = Rng::new(9);
    let r = random_rotation(&mut rng, 0.4);
    let mut heights: Vec<f64> =
        (0..b.terms.contact_rest.len() / 3).map(|j| (r * Vector3::from_column_slice(&b.terms.contact_rest[3 * j..3 * j + 3])).z).collect();
    heights.sort_by(f64::total_cmp);
    // The third lowest point 5 mm deep.
    let cur = Pose { center: Vector3::new(0.0, 0.0, -heights[2] - 5e-3), rotation: r, q: rng.vec(b.n, 1e-3) };
    let mut prev = cur.clone();
    prev.center += Vector3::new(-5e-3, 2e-3, 1e-3);
    let mut start = sys.step_start();
    sys.begin_step(&[&cur, &prev], &mut start);
    assert!(start.contact.normal_force.iter().filter(|f| **f > 0.0).count() >= 3);
    let mut pose = cur.clone();
    pose.retract(&cur, &[4e-3, -1e-3, -1e-4, 0.02, -0.01, 0.03, 1e-3, 0.0, -1e-3, 2e-3, 0.0, 0.0, 1e-3, -2e-3, 1e-3], 1.0);
    (b, sys, start, pose)
}

#[test]
fn total_derivatives_match_finite_differences_on_a_turned_block() {
    let (_, sys, start, pose) = turned_case();
    check_derivatives(&sys, &start, &pose, "turned block");
}

#[test]
fn contact_points_are_skipped_only_where_they_cannot_touch() {
    // Within a step each gap is bounded from the point's position at the step
    // start, or at the points' reference q, through the largest singular value
    // of W_j. At the bound's worst case (the body turned so that W_j's top left
    // singular vector is the plane's normal, and dq along the top right one) a
    // point that starts above the plane and ends 1 um in it must be evaluated:
    // the energy and gradient are those of the bound through |q| alone. A bound
    // 1 % too tight skips the point and fails here. Two starts: one that forms
    // the reference at its own q (the point has no start position and is
    // bounded from the reference), and one begun after a start further along
    // dq, whose reference it keeps (loose enough that the point gets a start
    // position, and is bounded from that).
    let (b, sys, _, _) = turned_case();
    let (n, plane) = (b.n, &b.terms.planes[0]);
    let mut ws = sys.workspace();
    for j in (0..sys.n_contacts()).step_by(7) {
        let w = nalgebra::DMatrix::from_row_slice(3, n, &b.terms.contact_basis[3 * n * j..3 * n * (j + 1)]);
        let svd = w.clone().svd(true, true);
        let k = svd.singular_values.imax();
        let sigma = svd.singular_values[k];
        let u = Vector3::from_iterator(svd.u.as_ref().unwrap().column(k).iter().copied());
        let v: Vec<f64> = svd.v_t.as_ref().unwrap().row(k).iter().copied().collect();
        let rotation = nalgebra::Rotation3::rotation_between(&u, &plane.normal()).unwrap().into_inner();
        let s = 0.004; // small enough that the kept reference (0.3 s back) is not formed again
        let q: Vec<f64> = v.iter().map(|vi| s * vi).collect();
        let y = Vector3::from_column_slice(&b.terms.contact_rest[3 * j..3 * j + 3]) + &w * nalgebra::DVector::from_column_slice(&q);
        let g0 = 0.5 * sigma * s;
        let center = plane.normal() * (g0 - plane.gap(&(rotation * y)));
        let cur = Pose { center, rotation, q };
        let t = (g0 + 1e-6) / sigma;
        let along = |d: f64| moved(&cur, &[0.0; 6].into_iter().chain(v.iter().map(|vi| d * vi)).collect::<Vec<f64>>());
        let pose = along(-t);
        let x_j = pose.center
            + pose.rotation
                * (Vector3::from_column_slice(&b.terms.contact_rest[3 * j..3 * j + 3]) + &w * nalgebra::DVector::from_column_slice(&pose.q));
        assert!(g0 > 1e-5 && (plane.gap(&x_j) + 1e-6).abs() < 1e-9, "point {j}: start gap {g0}, end gap {}", plane.gap(&x_j));
        let mut own = sys.step_start();
        sys.begin_step(&[&cur, &cur], &mut own);
        let mut kept = sys.step_start();
        let before = along(-0.3 * s);
        sys.begin_step(&[&before, &before], &mut kept);
        sys.begin_step(&[&cur, &cur], &mut kept);
        for (start, which) in [(own, "its own reference"), (kept, "a kept reference")] {
            let loose = BodyStart { contact: start.contact.without_start_positions(), ..start.clone() };
            let e = sys.evaluate(&start, &pose, true, &mut ws);
            let grad = ws.grad.clone();
            let e_loose = sys.evaluate(&loose, &pose, true, &mut ws);
            assert!(rel_err(&[e], &[e_loose], 1e-300) < 1e-14, "energy {e} against {e_loose} with point {j} pushed in ({which})");
            assert!(rel_err(&grad, &ws.grad, 1e-300) < 1e-14, "gradient with point {j} pushed in ({which})");
        }
    }
}

#[test]
fn contact_model_matches_the_energy_to_second_order() {
    let (b, sys, start, pose) = turned_case();
    let (n, big) = (b.n, 6 + b.n);
    let mut ws = sys.workspace();
    let e = sys.evaluate(&start, &pose, true, &mut ws);
    let grad = ws.grad.clone();
    let mut g_el = vec![0.0; n];
    ws.elastic_gradient(&mut g_el);
    let e_el = ws.elastic_energy();
    // The exact elastic Hessian: the exact block less Mqq/h^2.
    let mut k_el = vec![0.0; n * n];
    sys.elastic_block(&pose.q, true, &mut ws, &mut k_el);
    let h2 = b.scene.dt * b.scene.dt;
    k_el.iter_mut().zip(sys.mode_mass()).for_each(|(k, m)| *k -= m / h2);
    let m = ElasticModel { origin: &pose.q, energy: e_el, gradient: &g_el, hessian: &k_el };
    // Same value and gradient at the expansion point.
    assert!((sys.evaluate_model(&start, &pose, &m, true, &mut ws) - e).abs() < 1e-12 * e.abs().max(1.0));
    assert!(rel_err(&ws.grad, &grad, 1e-9) < 1e-12);
    // Its gradient is that of its value (rotation terms included), and it
    // follows the energy to second order.
    let mut rng = Rng::new(5);
    let dir: Vec<f64> = (0..big).map(|i| rng.uniform() * if (3..6).contains(&i) { 1e-2 } else { 1e-3 }).collect();
    let at = |t: f64| moved(&pose, &dir.iter().map(|d| t * d).collect::<Vec<_>>());
    let p = at(1.0);
    sys.evaluate_model(&start, &p, &m, true, &mut ws);
    let fd = fd_gradient(|x| sys.evaluate_model(&start, &moved(&p, x), &m, false, &mut sys.workspace()), &vec![0.0; big], 1e-7);
    assert!(rel_err(&ws.grad, &fd, 1e-6) < 1e-6, "model gradient vs FD: {}", rel_err(&ws.grad, &fd, 1e-6));
    let mut gap = |t: f64| {
        let x = at(t);
        (sys.evaluate(&start, &x, false, &mut ws) - sys.evaluate_model(&start, &x, &m, false, &mut ws)).abs()
    };
    // Third order: halving the step divides the gap by about 8.
    let (g1, g2) = (gap(1.0), gap(0.5));
    assert!(g1 > 0.0 && g2 < g1 / 5.0, "model gap {g1} -> {g2}");
}

#[test]
fn incremental_contact_hessian_follows_the_full_one() {
    let (b, sys, start, base) = turned_case();
    let big = 6 + b.n;
    let mut ws = sys.workspace();
    let mut state = sys.contact_hessian_state();
    let mut k_el = vec![0.0; b.n * b.n];
    let (mut newton, mut metric, mut full) = (vec![0.0; big * big], vec![0.0; big * big], vec![0.0; big * big]);
    let mut check = |pose: &Pose, ws: &mut BodyWorkspace, state: &mut BodyContactHessian| {
        sys.evaluate(&start, pose, true, ws);
        let changed = sys.update_contact_hessian(ws, state);
        sys.elastic_stiffness(&pose.q, ws, &mut k_el);
        sys.newton_matrix(&start, pose, &k_el, state, &mut newton, &mut metric);
        sys.hessian(&start, pose, BodyHessian::GaussNewton, ws, &mut full);
        (changed, rel_err(&newton, &full, 0.0), crate::cholesky::Cholesky::factor(&newton, big).is_ok())
    };
    let mut rng = Rng::new(13);
    // Tilts of 0.2 rad about horizontal axes, alternately to either side (with
    // slides and deformations), turn every contact term seen from the body by
    // more than the lag: every row is replaced and the result is exact, though
    // the turn of the body moved out of the sum (T S T^T). Replacing every row
    // costs more than forming the matrix anew, which is done: the rows changed
    // are those of a matrix formed from scratch, none taken out.
    let mut last = base.clone();
    for step in 0..12 {
        let a = 0.4 * step as f64;
        let side = if step % 2 == 0 { 0.2 } else { -0.2 };
        let mut x: Vec<f64> = rng.vec(big, 1e-3);
        x[3..6].copy_from_slice(&[side * a.cos(), side * a.sin(), 0.1 * rng.uniform()]);
        last = moved(&base, &x);
        let (changed, err, _) = check(&last, &mut ws, &mut state);
        let scratch = sys.update_contact_hessian(&mut ws, &mut sys.contact_hessian_state());
        assert!(changed > 0 && changed == scratch && err < 1e-10, "step {step}: {changed} rows changed ({scratch} from scratch), error {err}");
    }
    // Moves within the lag keep the rows; the matrix stays close (within the
    // 10 % lag of a curvature) and positive definite.
    for (scale, bound) in [(1e-9, 1e-6), (1e-5, 0.1)] {
        let pose = moved(&last, &rng.vec(big, scale));
        let (changed, err, definite) = check(&pose, &mut ws, &mut state);
        assert!((scale > 1e-9 || changed == 0) && err < bound && definite, "moved by {scale}: {changed} rows changed, error {err}");
    }
}

#[test]
fn stick_switch_turns_slipping_points_into_sticking_ones() {
    // Slipping along +x on level ground.
    let (b, sys, start, pose) = contact_case(4e-4, 1e-3, 1e-6);
    let big = 6 + b.n;
    let slipping = coulomb_ratios(&b, &sys, &start, &pose).len();
    assert!(slipping > 0);
    let mut ws = sys.workspace();
    sys.evaluate(&start, &pose, true, &mut ws);
    let grad = ws.grad.clone();
    // A direction that carries the slip on switches nothing.
    let mut on = vec![0.0; big];
    on[0] = 1e-4;
    let mut rhs = grad.clone();
    assert_eq!(sys.stick_switch(&start, &pose, &on, &mut ws, &mut rhs), 0);
    assert_eq!(rhs, grad);
    // One that reverses it (by a turn about z and a slide back) switches every
    // slipping point: gradient and Hessian become those of the same points
    // sticking, i.e. of the model with unbounded friction.
    let mut back = vec![0.0; big];
    back[0] = -2e-3;
    back[5] = 1e-3;
    let rows = sys.stick_switch(&start, &pose, &back, &mut ws, &mut rhs);
    assert_eq!(rows, 2 * slipping);
    let mut hess = vec![0.0; big * big];
    sys.hessian(&start, &pose, BodyHessian::GaussNewton, &mut ws, &mut hess);
    sys.stick_switch(&start, &pose, &back, &mut ws, &mut vec![0.0; big]);
    sys.add_switch_rows(&ws, rows, &mut hess);
    let planes: Vec<Plane> = b.terms.planes.iter().map(|p| Plane::new(p.normal(), p.offset(), 1e9).unwrap()).collect();
    let inputs = b.inputs();
    let sticky = BodyFrameSystem::new(&BodyFrameInputs { contact: ContactInputs { planes: &planes, ..inputs.contact }, ..inputs }).unwrap();
    // The step start does not depend on the friction coefficient.
    let mut sticky_ws = sticky.workspace();
    sticky.evaluate(&start, &pose, true, &mut sticky_ws);
    assert!(rel_err(&rhs, &sticky_ws.grad, 1e-9) < 1e-10, "switched gradient: {}", rel_err(&rhs, &sticky_ws.grad, 1e-9));
    let mut sticky_hess = vec![0.0; big * big];
    sticky.hessian(&start, &pose, BodyHessian::GaussNewton, &mut sticky_ws, &mut sticky_hess);
    assert!(rel_err(&hess, &sticky_hess, 0.0) < 1e-10, "switched Hessian: {}", rel_err(&hess, &sticky_hess, 0.0));
    check_derivatives(&sticky, &start, &pose, "sticking");
}

fn solver(b: &BodyBlock, tolerance: f64, max_iterations: usize) -> BodyFrameSolver {
    let sys = BodyFrameSystem::new(&b.inputs()).unwrap();
    BodyFrameSolver::new(sys, BodyFrameSettings { tolerance, max_iterations }).unwrap()
}

#[test]
fn a_free_rigid_body_is_ballistic_and_spins_about_a_principal_axis() {
    // A rigid box 10 x 10 x 10 cm (n = 0): every axis is principal; z is turned
    // to a tilted axis so that the spin is not about a world axis.
    let b = block(0, 0, 0, false);
    assert_eq!(b.n, 0);
    let mut s = solver(&b, 1e-12, 20);
    let h = b.scene.dt;
    let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
    let spin = 20.0;
    let r0 = exp_map(&Vector3::new(0.2, 0.4, -0.1));
    let (c0, v0) = (Vector3::new(0.1, -0.2, 1.0), Vector3::new(0.3, 0.0, 1.5));
    s.set_state(&Pose { center: c0, rotation: r0, q: vec![] }, v0.as_slice(), (axis * spin).as_slice(), &[]).unwrap();
    // Backward Euler on SO(3) about a principal axis: the turn per step follows
    // d_{t+1} = atan2(sin d_t, 2 - cos d_t) (the polar factor of (2I - E^T) R J).
    let (mut c, mut v) = (c0, v0);
    let mut turn = spin * h;
    let mut angle = 0.0;
    for step in 0..50 {
        s.step().unwrap();
        v += s.system().gravity() * h;
        c += v * h;
        assert!((s.pose().center - c).norm() < 1e-12, "step {step}: centre off by {}", (s.pose().center - c).norm());
        turn = turn.sin().atan2(2.0 - turn.cos());
        angle += turn;
        let expected = exp_map(&(axis * angle)) * r0;
        assert!((s.pose().rotation - expected).amax() < 1e-10, "step {step}: rotation off by {}", (s.pose().rotation - expected).amax());
        let w = s.angular_velocity();
        assert!((w - axis * (turn / h)).norm() < 1e-8 * spin, "step {step}: angular velocity {w}");
    }
    // The spin is damped only at order (h w)^2 per step.
    assert!((s.angular_velocity().norm() - spin).abs() < 50.0 * (spin * h).powi(2) * spin);
}

#[test]
fn steps_after_set_state_are_those_of_a_new_solver() {
    // A slide down an incline (contact Hessian built and updated) leaves nothing
    // behind that a run from a state set afterwards would see.
    let scene = BlockScene { learned_modes: 3, cubature_points: 50, contact_points: 60, incline: 25.0, friction: 0.3, ..Default::default() };
    let b = body_block(&scene, true).unwrap();
    let (c, r) = b.resting_pose();
    let pose = Pose { center: c, rotation: r, q: vec![0.0; b.n] };
    let run = |s: &mut BodyFrameSolver| -> Pose {
        s.set_state(&pose, &[0.2, 0.0, 0.0], &[0.0, 0.5, 0.0], &vec![0.0; b.n]).unwrap();
        for _ in 0..12 {
            s.step().unwrap();
        }
        s.pose().clone()
    };
    let fresh = run(&mut solver(&b, 1e-8, 50));
    let mut reused = solver(&b, 1e-8, 50);
    run(&mut reused);
    let again = run(&mut reused);
    assert_eq!((again.center, again.rotation, &again.q), (fresh.center, fresh.rotation, &fresh.q));
}

/// Runs the block resting on an incline of `incline` degrees with Coulomb
/// coefficient `mu` for 0.6 s; returns the acceleration of its centre of mass
/// along the slope and the mean speed along the slope of the centre of its
/// bottom face (the slip: the block may rock on the penalty springs), both
/// between 0.2 s and 0.6 s.
fn incline_motion(incline: f64, mu: f64, affine: bool) -> (f64, f64) {
    let scene =
        BlockScene { learned_modes: 0, cubature_points: 50, contact_points: 200, incline, friction: mu, normal_damping: 3e4, ..Default::default() };
    let b = body_block(&scene, affine).unwrap();
    let mut s = solver(&b, 1e-8, 50);
    let (c, r) = b.resting_pose();
    s.set_state(&Pose { center: c, rotation: r, q: vec![0.0; b.n] }, &[0.0; 3], &[0.0; 3], &vec![0.0; b.n]).unwrap();
    let down = Vector3::new(incline.to_radians().cos(), 0.0, -incline.to_radians().sin());
    let bottom = Vector3::new(0.0, 0.0, -scene.size / 2.0);
    let mut samples = vec![];
    for step in 1..=60 {
        let report = s.step().unwrap();
        assert!(report.iterations <= 20, "{report:?}");
        if step == 20 || step == 60 {
            let pose = s.pose();
            samples.push((s.velocity().dot(&down), (pose.center + pose.rotation * bottom).dot(&down)));
        }
    }
    let span = 40.0 * scene.dt;
    ((samples[1].0 - samples[0].0) / span, (samples[1].1 - samples[0].1) / span)
}

#[test]
fn a_block_on_an_incline_sticks_or_slides_with_coulomb_acceleration() {
    let (incline, g) = (30.0_f64, 9.81);
    let (sin, cos) = incline.to_radians().sin_cos();
    for affine in [false, true] {
        let mu = 0.3;
        let (a, _) = incline_motion(incline, mu, affine);
        let expected = g * (sin - mu * cos);
        assert!((a - expected).abs() < 0.02 * expected, "affine {affine}: slides at {a} m/s^2, expected {expected}");
        // tan 30 = 0.577 < 0.7: it sticks. The rigid block rocks on the penalty
        // springs (period about 0.3 s), which moves its face centre by about a
        // millimetre; sliding at mu = 0.3 it would move at 1 m/s by then.
        let (_, slip) = incline_motion(incline, 0.7, affine);
        assert!(slip.abs() < 2e-3, "affine {affine}: slips at {slip} m/s while it should stick");
    }
}

#[test]
fn failed_steps_leave_the_state_and_bad_inputs_are_rejected() {
    let b = block(2, 10, 20, true);
    let mut s = solver(&b, 1e-14, 1);
    let (c, r) = b.resting_pose();
    let pose = Pose { center: c, rotation: r, q: vec![1e-3; b.n] };
    s.set_state(&pose, &[0.5, 0.0, 0.0], &[0.0, 1.0, 0.0], &vec![0.1; b.n]).unwrap();
    let before = s.pose().clone();
    assert!(matches!(s.step(), Err(LicromError::NotConverged { iterations: 1, .. })));
    assert_eq!(s.pose(), &before);
    s.accept_last_iterate().unwrap();
    assert_ne!(s.pose(), &before);
    assert!(s.accept_last_iterate().is_err());
    // Not a rotation, wrong lengths, non-finite values.
    let mut bad = pose.clone();
    bad.rotation[(0, 0)] += 1e-6;
    assert!(matches!(s.set_state(&bad, &[0.0; 3], &[0.0; 3], &vec![0.0; b.n]), Err(LicromError::InvalidParameter { .. })));
    let mut mirrored = pose.clone();
    mirrored.rotation = -Matrix3::<f64>::identity();
    assert!(s.set_state(&mirrored, &[0.0; 3], &[0.0; 3], &vec![0.0; b.n]).is_err());
    assert!(matches!(s.set_state(&pose, &[0.0; 2], &[0.0; 3], &vec![0.0; b.n]), Err(LicromError::ShapeMismatch { .. })));
    assert!(matches!(s.set_state(&pose, &[f64::NAN, 0.0, 0.0], &[0.0; 3], &vec![0.0; b.n]), Err(LicromError::NonFinite { .. })));
    let mut inp = b.inputs();
    let short = &b.mode_products[1..];
    inp.mode_products = short;
    assert!(matches!(BodyFrameSystem::new(&inp), Err(LicromError::ShapeMismatch { .. })));
    let mut inp = b.inputs();
    let flat = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0];
    inp.inertia_moments = &flat;
    assert!(matches!(BodyFrameSystem::new(&inp), Err(LicromError::InvalidParameter { .. })));
    let mut inp = b.inputs();
    inp.dt = -1.0;
    assert!(BodyFrameSystem::new(&inp).is_err());
    // Probes at a pose whose energy overflows fail instead of returning inf or NaN.
    let far = Pose { center: Vector3::new(0.0, 0.0, 1e200), rotation: r, q: vec![1e200; b.n] };
    assert!(matches!(s.energy(&far), Err(LicromError::Overflow { .. })));
    assert!(matches!(s.gradient(&far), Err(LicromError::Overflow { .. })));
    assert!(matches!(s.hessian(&far, true), Err(LicromError::Overflow { .. })));
    // A previous pose `pose - dt x velocity` that overflows is refused.
    let mut inp = b.inputs();
    inp.dt = 1e300;
    let mut far = BodyFrameSolver::new(BodyFrameSystem::new(&inp).unwrap(), BodyFrameSettings { tolerance: 1e-6, max_iterations: 5 }).unwrap();
    assert!(matches!(far.set_state(&pose, &[1e10, 0.0, 0.0], &[0.0; 3], &vec![0.0; b.n]), Err(LicromError::Overflow { .. })));
    // Velocities come back as given.
    s.set_state(&pose, &[0.5, 0.0, -0.2], &[0.0, 1.0, 0.3], &vec![0.1; b.n]).unwrap();
    assert!((s.velocity() - Vector3::new(0.5, 0.0, -0.2)).norm() < 1e-12);
    assert!((s.angular_velocity() - Vector3::new(0.0, 1.0, 0.3)).norm() < 1e-10);
    assert!((log_map(&s.pose().rotation) - log_map(&r)).norm() < 1e-12);
}

#[test]
fn every_step_reports_the_smallest_det_and_the_deepest_penetration() {
    // A deforming block started 1 cm inside an incline: pushed out while it turns and slides.
    let scene = BlockScene { learned_modes: 3, cubature_points: 50, contact_points: 60, incline: 25.0, friction: 0.3, ..Default::default() };
    let b = body_block(&scene, true).unwrap();
    let (c, r) = b.resting_pose();
    let normal = b.terms.planes[0].normal();
    let mut s = solver(&b, 1e-10, 100);
    let pose = Pose { center: c - normal * 0.01, rotation: r, q: vec![0.0; b.n] };
    s.set_state(&pose, &[0.2, 0.0, 0.0], &[0.0, 0.5, 0.0], &vec![0.0; b.n]).unwrap();
    check_pushed_out(&b.terms, || {
        s.step().unwrap();
        let p = s.pose();
        (s.validity(), p.q.clone(), p.center, p.rotation)
    });
}
