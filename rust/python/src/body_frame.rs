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
use crate::errors::{error, exclusive, CoreResultExt, Kind};
use crate::inputs::{ContactArrays, ElasticArrays, VertexArgs};
use crate::reduced::stats_dict;

/// Body-frame model, pose history and solver of one simulation.
///
/// One thread at a time: a call while another thread's call runs (a step releases the
/// GIL) raises `ConcurrencyError` instead of waiting.
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
        solver.make_pose(&center.data, &rotation.data, &q.data).py_err(py)
    }
}

#[pymethods]
impl BodyFrameCore {
    #[new]
    #[pyo3(signature = (
        total_mass, inertia_moments, mode_moments, mode_products, gravity, cubature_jacobians, cubature_weights,
        mu, lam, contact_basis, contact_rest, contact_areas, planes, normal_stiffness, normal_damping,
        friction_stiffness, dt, tolerance, max_iterations, cubature_vertex_basis = None, cubature_tet_vertices = None,
        cubature_shape_gradients = None, integrator = "backward_euler"
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
    ) -> PyResult<Self> {
        let integrator: Integrator = integrator.parse().py_err(py)?;
        let max_iterations = count(max_iterations, "max_iterations")?;
        let j = read(inertia_moments, "inertia_moments", &[Dim::Is(3), Dim::Is(3)])?;
        let p = read(mode_moments, "mode_moments", &[Dim::Any("n"), Dim::Is(3), Dim::Is(3)])?;
        let n = p.shape[0];
        let q = read(mode_products, "mode_products", &[Dim::Is(n), Dim::Is(n), Dim::Is(3), Dim::Is(3)])?;
        let g = read(gravity, "gravity", &[Dim::Is(3)])?;
        let vertex = VertexArgs { basis: cubature_vertex_basis, tets: cubature_tet_vertices, grads: cubature_shape_gradients };
        let elastic = ElasticArrays::read(py, cubature_jacobians, cubature_weights, vertex, (mu, lam), n)?;
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
        let inner = py.detach(|| BodyFrameSystem::new(&inputs).and_then(|system| BodyFrameSolver::new(system, settings))).py_err(py)?;
        Ok(Self { n: inner.system().n_modes(), inner: Mutex::new(inner) })
    }

    /// Number of modes n.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.n
    }

    /// Replaces the state: pose, velocity of the centre of mass (m/s), angular
    /// velocity in the world frame (rad/s) and modal velocities (per second).
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
        solver.set_state(&pose, &v.data, &w.data, &qdot.data).py_err(py)
    }

    /// Replaces the poses one, two and three steps back (centres (3, 3),
    /// rotations (3, 3, 3), q (3, n); nearest first), after `set_state`.
    fn set_history(&self, py: Python<'_>, centers: &Bound<'_, PyAny>, rotations: &Bound<'_, PyAny>, q: &Bound<'_, PyAny>) -> PyResult<()> {
        let mut solver = exclusive(py, &self.inner)?;
        let c = read(centers, "centers", &[Dim::Is(3), Dim::Is(3)])?;
        let r = read(rotations, "rotations", &[Dim::Is(3), Dim::Is(3), Dim::Is(3)])?;
        let q = read(q, "q", &[Dim::Is(3), Dim::Is(self.n)])?;
        let n = self.n;
        let pose = |k: usize| solver.make_pose(&c.data[3 * k..3 * k + 3], &r.data[9 * k..9 * k + 9], &q.data[n * k..n * (k + 1)]);
        let earlier = [pose(0).py_err(py)?, pose(1).py_err(py)?, pose(2).py_err(py)?];
        solver.set_history(earlier).py_err(py)
    }

    /// Advances one step; returns (iterations, residual in m/s).
    fn step(&self, py: Python<'_>) -> PyResult<(usize, f64)> {
        let mut guard = exclusive(py, &self.inner)?;
        let solver = &mut *guard;
        let report = py.detach(|| solver.step()).py_err(py)?;
        Ok((report.iterations, report.residual))
    }

    /// Work counters since construction (or the last `reset_stats`), as
    /// `ReducedCore.stats`.
    fn stats(&self, py: Python<'_>) -> PyResult<HashMap<&'static str, usize>> {
        Ok(stats_dict(exclusive(py, &self.inner)?.stats()))
    }

    /// `(min det F, depth)` of the last step: the smallest `det F` at the
    /// cubature points (inf without any) and the deepest penetration of a
    /// contact point into a plane (m, >= 0), at its accepted iterate.
    fn validity(&self, py: Python<'_>) -> PyResult<(f64, f64)> {
        let v = exclusive(py, &self.inner)?.validity();
        Ok((v.min_det, v.depth))
    }

    /// Zeroes the work counters.
    fn reset_stats(&self, py: Python<'_>) -> PyResult<()> {
        exclusive(py, &self.inner)?.reset_stats();
        Ok(())
    }

    /// Takes the last iterate of a step that just failed to converge as the state.
    fn accept_last_iterate(&self, py: Python<'_>) -> PyResult<()> {
        exclusive(py, &self.inner)?.accept_last_iterate().py_err(py)
    }

    /// Centre of mass (3,), m.
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let center = exclusive(py, &self.inner)?.pose().center.as_slice().to_vec();
        write(py, center, &[3])
    }

    /// Rotation (3, 3) from the body frame to the world.
    #[getter]
    fn rotation<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let rotation = row_major(&exclusive(py, &self.inner)?.pose().rotation);
        write(py, rotation, &[3, 3])
    }

    /// Modal coordinates (n,).
    #[getter]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let q = exclusive(py, &self.inner)?.pose().q.clone();
        write(py, q, &[self.n])
    }

    /// The pose `steps_back` steps before the current one (1, 2 or 3): the
    /// history the integrator reads ((3,) centre, (3, 3) rotation, (n,) q).
    fn previous_pose<'py>(&self, py: Python<'py>, steps_back: usize) -> PyResult<PoseArrays<'py>> {
        let solver = exclusive(py, &self.inner)?;
        let pose = solver.previous_pose(steps_back).py_err(py)?;
        let (center, rotation, q) = (pose.center.as_slice().to_vec(), row_major(&pose.rotation), pose.q.clone());
        drop(solver);
        Ok((write(py, center, &[3])?, write(py, rotation, &[3, 3])?, write(py, q, &[self.n])?))
    }

    /// Velocity of the centre of mass (3,), m/s.
    #[getter]
    fn velocity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let velocity = exclusive(py, &self.inner)?.velocity().as_slice().to_vec();
        write(py, velocity, &[3])
    }

    /// Angular velocity in the world frame (3,), rad/s.
    #[getter]
    fn angular_velocity<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let angular_velocity = exclusive(py, &self.inner)?.angular_velocity().as_slice().to_vec();
        write(py, angular_velocity, &[3])
    }

    /// Modal velocities (n,), per second.
    #[getter]
    fn qdot<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let mut out = vec![0.0; self.n];
        exclusive(py, &self.inner)?.qdot(&mut out);
        write(py, out, &[self.n])
    }

    /// Contact forces (C, 3) in N at the current state over the last step.
    fn contact_forces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let solver = exclusive(py, &self.inner)?;
        let c = solver.system().n_contacts();
        let mut out = vec![0.0; 3 * c];
        solver.contact_forces(&mut out).py_err(py)?;
        write(py, out, &[c, 3])
    }

    /// Energy (J) at the pose of a step from the current state, up to the
    /// step's constant.
    fn energy(&self, py: Python<'_>, center: &Bound<'_, PyAny>, rotation: &Bound<'_, PyAny>, q: &Bound<'_, PyAny>) -> PyResult<f64> {
        let mut guard = exclusive(py, &self.inner)?;
        let pose = self.pose(py, &guard, center, rotation, q)?;
        let solver = &mut *guard;
        py.detach(|| solver.energy(&pose)).py_err(py)
    }

    /// Gradient (6 + n,) in (c, omega, q) at the pose, omega the left rotation increment.
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
        let grad = py.detach(|| solver.gradient(&pose).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, grad, &[6 + self.n])
    }

    /// Hessian (6 + n, 6 + n) at the pose: exact, or the solver's positive definite one.
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
        let hess = py.detach(|| solver.hessian(&pose, exact).map(<[f64]>::to_vec)).py_err(py)?;
        write(py, hess, &[big, big])
    }
}
