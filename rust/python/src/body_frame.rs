//! The body-frame simulation state and its solver.

use std::collections::HashMap;

use licrom_core::body_frame::rotation::is_rotation;
use licrom_core::body_frame::solver::{BodyFrameSettings, BodyFrameSolver, ROTATION_TOLERANCE};
use licrom_core::body_frame::{BodyFrameInputs, BodyFrameSystem, Pose};
use licrom_core::integrator::Integrator;
use nalgebra::Matrix3;
use numpy::PyArrayDyn;
use pyo3::prelude::*;
use std::sync::Mutex;

use crate::arrays::{count, read, write, Dim};
use crate::errors::{call_core, detached, error, exclusive, CoreResultExt, Kind};
use crate::inputs::{ContactArrays, ElasticArrays, VertexArgs};
use crate::reduced::stats_dict;

/// Body-frame reduced model, pose history and time stepper of one simulation.
///
/// Positions ``x_v = c + R (Xbar_v + W_v q)``, every column of W mass-orthogonal to
/// the rigid modes. Each step minimises the backward-Euler energy over
/// ``(c, R, q)``: inertia exact from the mass moments, elastic energy
/// ``sum_k w_k Psi(I + G_k q)``, contact and friction at the contact points as in
/// :class:`ReducedCore`, with the lagged normal force and the slip measured from
/// the positions at the start of the step. Newton on ``(dc, omega, dq)`` with
/// ``R <- exp([omega]x) R``; convergence measure ``r`` (m/s) as in ReducedCore.
///
/// Args:
///     total_mass: M in kg, > 0.
///     inertia_moments: (3, 3) ``J = sum m Xbar Xbar^T`` in kg m^2, symmetric positive definite.
///     mode_moments: (n, 3, 3) ``P_k = sum m W^k Xbar^T``.
///     mode_products: (n, n, 3, 3) ``Q_kl = sum m W^k W^l^T`` (``Q_kl = Q_lk^T``).
///     gravity: (3,) gravity acceleration in m/s^2.
///     cubature_jacobians: (K, 9, n) ``G_k = d vec(F) / dq`` at the cubature points.
///     cubature_weights: (K,) weights w_k >= 0 in m^3.
///     mu: SNH shear parameter in Pa, > 0.
///     lam: SNH volume parameter in Pa, > 0.
///     contact_basis: (C, 3, n) basis rows W_j at the contact points.
///     contact_rest: (C, 3) ``Xbar_j`` of the contact points in m.
///     contact_areas: (C,) boundary area a_j >= 0 carried by each contact point in m^2.
///     planes: (P, 5) rows ``[nx, ny, nz, d, friction]``.
///     normal_stiffness: k_n in N/m^3, >= 0.
///     normal_damping: k_d in N s/m^3, >= 0.
///     friction_stiffness: k_f in N s/m^3, >= 0.
///     dt: time step h in s, > 0.
///     tolerance: convergence threshold on r in m/s, > 0.
///     max_iterations: Newton directions allowed per step, >= 1.
///     integrator: ``"backward_euler"`` (default) or ``"bdf2"`` (second order: the same
///         minimisation with the anchor ``(4 x_n - x_{n-1})/3``, anchor velocity
///         ``(4 v_n - v_{n-1})/3`` and effective step ``2h/3``; a new state gets the
///         history of a free fall). See ``rust/core/src/integrator.rs``.
///     cubature_vertex_basis: (V, 3, n) basis rows ``W_v`` at the mesh vertices, with
///         ``cubature_tet_vertices`` (K, 4) int64, the vertices of each cubature point's
///         tet, and ``cubature_shape_gradients`` (K, 4, 3), its shape functions' gradients
///         in 1/m: the Jacobians in vertex form, ``G_k = sum_a W_{v_a} (x) grad N_a``
///         (the ``"mesh"`` strain). All three or none; they must reproduce
///         ``cubature_jacobians``. The energy and gradient then go through the vertices
///         where that is cheaper (``3 V_used < 9 K``), the Hessian through ``G_k``.
///     viscosity: Kelvin-Voigt viscosity eta in Pa s, >= 0 (default 0: no material damping):
///         ``w_k eta/(2h') |E(F_k) - E(F_k at the step's anchor)|^2`` added at each cubature
///         point, E the Green strain (``rust/core/src/reduced/elastic.rs``).
///
/// n, K, C and P may be zero (n = 0: a rigid body).
///
/// One thread at a time: a call while another thread's call runs (a step releases the
/// GIL) raises :class:`ConcurrencyError` instead of waiting.
#[pyclass(module = "licrom._core", frozen)]
pub struct BodyFrameCore {
    pub(crate) inner: Mutex<BodyFrameSolver>,
    n: usize,
}

/// Row-major values of a 3x3 matrix.
/// A pose as numpy arrays: centre, rotation, modal coordinates.
type PoseArrays<'py> = (Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>, Bound<'py, PyArrayDyn<f64>>);

fn row_major(m: &Matrix3<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

impl BodyFrameCore {
    /// A validated pose from numpy arrays.
    fn pose(
        &self,
        py: Python<'_>,
        solver: &BodyFrameSolver,
        center: &Bound<'_, PyAny>,
        rotation: &Bound<'_, PyAny>,
        q: &Bound<'_, PyAny>,
    ) -> PyResult<Pose> {
        let center = read(center, "center", &[Dim::Is(3)])?;
        let rotation = read(rotation, "rotation", &[Dim::Is(3), Dim::Is(3)])?;
        let q = read(q, "q", &[Dim::Is(self.n)])?;
        if !is_rotation(&Matrix3::from_row_slice(&rotation.data), ROTATION_TOLERANCE) {
            return Err(error(py, Kind::Shape, format!("rotation must be a rotation matrix (orthonormal, determinant +1, to {ROTATION_TOLERANCE})")));
        }
        call_core(py, || solver.make_pose(&center.data, &rotation.data, &q.data))
    }
}

#[pymethods]
impl BodyFrameCore {
    #[new]
    #[pyo3(signature = (
        total_mass, inertia_moments, mode_moments, mode_products, gravity, cubature_jacobians, cubature_weights,
        mu, lam, contact_basis, contact_rest, contact_areas, planes, normal_stiffness, normal_damping,
        friction_stiffness, dt, tolerance, max_iterations, cubature_vertex_basis = None, cubature_tet_vertices = None,
        cubature_shape_gradients = None, integrator = "backward_euler", viscosity = 0.0
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        total_mass: f64,
        inertia_moments: &Bound<'_, PyAny>,
        mode_moments: &Bound<'_, PyAny>,
        mode_products: &Bound<'_, PyAny>,
        gravity: &Bound<'_, PyAny>,
        cubature_jacobians: &Bound<'_, PyAny>,
        cubature_weights: &Bound<'_, PyAny>,
        mu: f64,
        lam: f64,
        contact_basis: &Bound<'_, PyAny>,
        contact_rest: &Bound<'_, PyAny>,
        contact_areas: &Bound<'_, PyAny>,
        planes: &Bound<'_, PyAny>,
        normal_stiffness: f64,
        normal_damping: f64,
        friction_stiffness: f64,
        dt: f64,
        tolerance: f64,
        max_iterations: &Bound<'_, PyAny>,
        cubature_vertex_basis: Option<&Bound<'_, PyAny>>,
        cubature_tet_vertices: Option<&Bound<'_, PyAny>>,
        cubature_shape_gradients: Option<&Bound<'_, PyAny>>,
        integrator: &str,
        viscosity: f64,
    ) -> PyResult<Self> {
        let integrator: Integrator = integrator.parse().py_err(py)?;
        let max_iterations = count(max_iterations, "max_iterations")?;
        let j = read(inertia_moments, "inertia_moments", &[Dim::Is(3), Dim::Is(3)])?;
        let p = read(mode_moments, "mode_moments", &[Dim::Any("n"), Dim::Is(3), Dim::Is(3)])?;
        let n = p.shape[0];
        let q = read(mode_products, "mode_products", &[Dim::Is(n), Dim::Is(n), Dim::Is(3), Dim::Is(3)])?;
        let g = read(gravity, "gravity", &[Dim::Is(3)])?;
        let vertex = VertexArgs { basis: cubature_vertex_basis, tets: cubature_tet_vertices, grads: cubature_shape_gradients };
        let elastic = ElasticArrays::read(py, cubature_jacobians, cubature_weights, vertex, (mu, lam, viscosity), n)?;
        let stiffness = (normal_stiffness, normal_damping, friction_stiffness);
        let contact = ContactArrays::read(py, [contact_basis, contact_rest, contact_areas, planes], stiffness, n)?;
        let inputs = BodyFrameInputs {
            total_mass,
            inertia_moments: &j.data,
            mode_moments: &p.data,
            mode_products: &q.data,
            gravity: [g.data[0], g.data[1], g.data[2]],
            elastic: elastic.inputs(),
            contact: contact.inputs(),
            dt,
            integrator,
        };
        let settings = BodyFrameSettings { tolerance, max_iterations };
        let inner = detached(py, || BodyFrameSystem::new(&inputs).and_then(|system| BodyFrameSolver::new(system, settings)))?;
        Ok(Self { n: inner.system().n_modes(), inner: Mutex::new(inner) })
    }

    /// Number of modes n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.n
    }

    /// Replace the state: pose, velocity of the centre of mass (m/s), angular velocity in the world frame
    /// (rad/s) and modal velocities (per second). The pose k steps back becomes
    /// ``(c - k h v, exp(-k h [w]x) R, q - k h qdot)`` (k = 1, 2, 3; BDF2: ``c - k h v + (k h)^2 g / 2``,
    /// the history of a free fall, its start).
    ///
    /// Raises:
    ///     ShapeError: wrong shapes, NaN/inf, or ``rotation`` not orthonormal with
    ///         determinant +1 (to 1e-8).
    #[allow(clippy::too_many_arguments)]
    fn set_state(
        &self,
        py: Python<'_>,
        center: &Bound<'_, PyAny>,
        rotation: &Bound<'_, PyAny>,
        q: &Bound<'_, PyAny>,
        velocity: &Bound<'_, PyAny>,
        angular_velocity: &Bound<'_, PyAny>,
        qdot: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let mut solver = exclusive(py, &self.inner)?;
        let pose = self.pose(py, &solver, center, rotation, q)?;
        let v = read(velocity, "velocity", &[Dim::Is(3)])?;
        let w = read(angular_velocity, "angular_velocity", &[Dim::Is(3)])?;
        let qdot = read(qdot, "qdot", &[Dim::Is(self.n)])?;
        call_core(py, || solver.set_state(&pose, &v.data, &w.data, &qdot.data))
    }

    /// Replace the poses one, two and three steps back (nearest first; centres (3, 3), rotations
    /// (3, 3, 3), q (3, n)) after :meth:`set_state`: the history BDF2 reads; velocities then read from it.
    ///
    /// Raises:
    ///     ShapeError: wrong shapes, NaN/inf, or a rotation that is not orthonormal with
    ///         determinant +1 (to 1e-8).
    fn set_history(&self, py: Python<'_>, centers: &Bound<'_, PyAny>, rotations: &Bound<'_, PyAny>, q: &Bound<'_, PyAny>) -> PyResult<()> {
        let mut solver = exclusive(py, &self.inner)?;
        let c = read(centers, "centers", &[Dim::Is(3), Dim::Is(3)])?;
        let r = read(rotations, "rotations", &[Dim::Is(3), Dim::Is(3), Dim::Is(3)])?;
        let q = read(q, "q", &[Dim::Is(3), Dim::Is(self.n)])?;
        let n = self.n;
        let pose = |k: usize| solver.make_pose(&c.data[3 * k..3 * k + 3], &r.data[9 * k..9 * k + 9], &q.data[n * k..n * (k + 1)]);
        let earlier = call_core(py, || Ok([pose(0)?, pose(1)?, pose(2)?]))?;
        call_core(py, || solver.set_history(earlier))
    }

    /// Work counters since construction or :meth:`reset_stats`, as
    /// :meth:`ReducedCore.stats` (the same solver machinery: contact model, stick
    /// correction, lagged elastic Hessian).
    fn stats(&self, py: Python<'_>) -> PyResult<HashMap<&'static str, usize>> {
        Ok(stats_dict(exclusive(py, &self.inner)?.stats()))
    }

    /// After a step that did not converge, take its last iterate as the new pose.
    fn accept_last_iterate(&self, py: Python<'_>) -> PyResult<()> {
        let mut solver = exclusive(py, &self.inner)?;
        call_core(py, || solver.accept_last_iterate())
    }

    /// (3,) centre of mass in m.
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let center = exclusive(py, &self.inner)?.pose().center.as_slice().to_vec();
        write(py, center, &[3])
    }

    /// (3, 3) rotation from the body frame to the world.
    #[getter]
    fn rotation<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let rotation = row_major(&exclusive(py, &self.inner)?.pose().rotation);
        write(py, rotation, &[3, 3])
    }

    /// (n,) modal coordinates.
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = exclusive(py, &self.inner)?.pose().q.clone();
        write(py, q, &[self.n])
    }

    /// ``(c, R, q)`` (shapes (3,), (3, 3), (n,)) of the pose ``steps_back`` (1, 2 or 3) steps before
    /// the current one: the history the integrator reads.
    ///
    /// Raises:
    ///     ConfigError: ``steps_back`` is not 1, 2 or 3.
    fn previous_pose<'py>(&self, py: Python<'py>, steps_back: usize) -> PyResult<PoseArrays<'py>> {
        let solver = exclusive(py, &self.inner)?;
        let pose = call_core(py, || solver.previous_pose(steps_back))?;
        let (center, rotation, q) = (pose.center.as_slice().to_vec(), row_major(&pose.rotation), pose.q.clone());
        drop(solver);
        Ok((write(py, center, &[3])?, write(py, rotation, &[3, 3])?, write(py, q, &[self.n])?))
    }

    /// (3,) ``(c - c_prev) / h`` in m/s (BDF2: ``(3 c - 4 c_prev + c_prev2) / (2h)``).
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let velocity = exclusive(py, &self.inner)?.velocity().as_slice().to_vec();
        write(py, velocity, &[3])
    }

    /// (3,) ``log(R R_prev^T) / h`` in rad/s (world frame; BDF2: ``(3 w_1 - w_2) / (2h)``
    /// with ``w_k`` the turns ``log(R R_prev^T)`` of the last two steps).
    #[getter]
    fn angular_velocity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let angular_velocity = exclusive(py, &self.inner)?.angular_velocity().as_slice().to_vec();
        write(py, angular_velocity, &[3])
    }

    /// (n,) ``(q - q_prev) / h`` per second (BDF2: ``(3 q - 4 q_prev + q_prev2) / (2h)``).
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut out = vec![0.0; self.n];
        exclusive(py, &self.inner)?.qdot(&mut out);
        write(py, out, &[self.n])
    }

    /// (C, 3) contact + friction force on each contact point over the last step in N; zeros before any step.
    fn contact_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let solver = exclusive(py, &self.inner)?;
        let c = solver.system().n_contacts();
        let mut out = vec![0.0; 3 * c];
        call_core(py, || solver.contact_forces(&mut out))?;
        write(py, out, &[c, 3])
    }

    /// Energy in J at the pose of a step from the current state, up to a constant of the step.
    fn energy(&self, py: Python<'_>, center: &Bound<'_, PyAny>, rotation: &Bound<'_, PyAny>, q: &Bound<'_, PyAny>) -> PyResult<f64> {
        let mut guard = exclusive(py, &self.inner)?;
        let pose = self.pose(py, &guard, center, rotation, q)?;
        let solver = &mut *guard;
        detached(py, || solver.energy(&pose))
    }

    /// (6 + n,) gradient in ``(c, omega, q)`` at the pose (omega: left rotation increment).
    fn gradient<'py>(
        &self,
        py: Python<'py>,
        center: &Bound<'py, PyAny>,
        rotation: &Bound<'py, PyAny>,
        q: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut guard = exclusive(py, &self.inner)?;
        let pose = self.pose(py, &guard, center, rotation, q)?;
        let solver = &mut *guard;
        let grad = detached(py, || solver.gradient(&pose).map(<[f64]>::to_vec))?;
        write(py, grad, &[6 + self.n])
    }

    /// (6 + n, 6 + n) Hessian at the pose: exact, or the solver's positive definite one.
    #[pyo3(signature = (center, rotation, q, exact = true))]
    fn hessian<'py>(
        &self,
        py: Python<'py>,
        center: &Bound<'py, PyAny>,
        rotation: &Bound<'py, PyAny>,
        q: &Bound<'py, PyAny>,
        exact: bool,
    ) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut guard = exclusive(py, &self.inner)?;
        let pose = self.pose(py, &guard, center, rotation, q)?;
        let big = 6 + self.n;
        let solver = &mut *guard;
        let hess = detached(py, || solver.hessian(&pose, exact).map(<[f64]>::to_vec))?;
        write(py, hess, &[big, big])
    }
}

solver_methods!(BodyFrameCore);
