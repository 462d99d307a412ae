//! The online error estimate's residual at a vertex sample.

use licrom_core::residual_estimate::{EstimateInputs, ResidualEstimate as CoreResidualEstimate};
use nalgebra::{Matrix3, Vector3};
use pyo3::prelude::*;

use crate::arrays::{read, read_indices, Dim};
use crate::errors::{call_core, error, Kind};
use crate::vertex_forces::VertexForces;

/// The full model's residual at S sample vertices of a reduced state, with the sample
/// positions of the steps the integrator reads kept from call to call
/// (``rust/core/src/residual_estimate.rs`` has the formulas).
///
/// Args:
///     forces: the ring forces of the samples, over the U near vertices.
///     near_basis: (U, 3, n) basis rows of the near vertices.
///     near_rest: (U, 3) rest term of their positions in m.
///     own: (S,) int64 each sample's index among the near vertices.
///     masses: (S,) lumped masses in kg, > 0.
///     normaliser: (S, 3, 3) inverse normalising blocks in m/N (residual force to displacement).
///     gravity: (3,) gravity in m/s^2.
///     planes: (P, 4) contact planes ``(n, d)``, outside where ``n . x + d >= 0``.
///     target: (L,) the integrator's target weights, newest first (L = 2 or 4).
///     step: the integrator's effective step in s, > 0.
///     total_mass: the body's mass in kg, > 0.
///     viscosity: the material's Kelvin-Voigt viscosity in Pa s, >= 0 (default 0): the force of its
///         damping joins the elastic one, its anchor from the recorded states before the step.
#[pyclass(module = "licrom._core")]
pub struct ResidualEstimate {
    inner: CoreResidualEstimate,
}

/// A rigid placement `(c, R)`, owned.
type Pose = (Vector3<f64>, Matrix3<f64>);

/// `q` and the placement `(c, R)` from optional (3,) and (3, 3) arrays (both or neither).
fn state(
    py: Python<'_>,
    q: &Bound<'_, PyAny>,
    center: Option<&Bound<'_, PyAny>>,
    rotation: Option<&Bound<'_, PyAny>>,
) -> PyResult<(Vec<f64>, Option<Pose>)> {
    let q = read(q, "q", &[Dim::Any("n")])?.data;
    let pose = match (center, rotation) {
        (Some(c), Some(r)) => {
            let c = read(c, "center", &[Dim::Is(3)])?;
            let r = read(r, "rotation", &[Dim::Is(3), Dim::Is(3)])?;
            Some((Vector3::from_column_slice(&c.data), Matrix3::from_row_slice(&r.data)))
        }
        (None, None) => None,
        _ => return Err(error(py, Kind::Config, "center and rotation are given together (body-frame models) or not at all (world frame)")),
    };
    Ok((q, pose))
}

#[pymethods]
impl ResidualEstimate {
    #[new]
    #[pyo3(signature = (forces, near_basis, near_rest, own, masses, normaliser, gravity, planes, target, step, total_mass, viscosity = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        forces: PyRef<'_, VertexForces>,
        near_basis: &Bound<'_, PyAny>,
        near_rest: &Bound<'_, PyAny>,
        own: &Bound<'_, PyAny>,
        masses: &Bound<'_, PyAny>,
        normaliser: &Bound<'_, PyAny>,
        gravity: &Bound<'_, PyAny>,
        planes: &Bound<'_, PyAny>,
        target: &Bound<'_, PyAny>,
        step: f64,
        total_mass: f64,
        viscosity: f64,
    ) -> PyResult<Self> {
        let u = forces.inner.n_points();
        let s = forces.inner.n_samples();
        let near_rest = read(near_rest, "near_rest", &[Dim::Is(u), Dim::Is(3)])?;
        let near_basis = read(near_basis, "near_basis", &[Dim::Is(u), Dim::Is(3), Dim::Any("n")])?;
        let own = read_indices(own, "own", &[Dim::Is(s)])?;
        let masses = read(masses, "masses", &[Dim::Is(s)])?;
        let normaliser = read(normaliser, "normaliser", &[Dim::Is(s), Dim::Is(3), Dim::Is(3)])?;
        let gravity = read(gravity, "gravity", &[Dim::Is(3)])?;
        let planes = read(planes, "planes", &[Dim::Any("P"), Dim::Is(4)])?;
        let target = read(target, "target", &[Dim::Any("L")])?;
        let inputs = EstimateInputs {
            near_basis: &near_basis.data,
            near_rest: &near_rest.data,
            own: &own,
            masses: &masses.data,
            normaliser: &normaliser.data,
            gravity: [gravity.data[0], gravity.data[1], gravity.data[2]],
            planes: &planes.data,
            target: &target.data,
            step,
            total_mass,
            viscosity,
        };
        let inner = call_core(py, || CoreResidualEstimate::new(&inputs, forces.inner.clone()))?;
        Ok(Self { inner })
    }

    /// Number of sample vertices S.
    #[getter]
    fn n_samples(&self) -> usize {
        self.inner.n_samples()
    }

    /// States the residual reads before the step (2 or 4).
    #[getter]
    fn history_length(&self) -> usize {
        self.inner.history_length()
    }

    /// Begins a run from the (L, S, 3) sample positions (m) of the states before it, oldest first.
    fn start(&mut self, py: Python<'_>, history: &Bound<'_, PyAny>) -> PyResult<()> {
        let history = read(history, "history", &[Dim::Is(self.inner.history_length()), Dim::Is(self.inner.n_samples()), Dim::Is(3)])?;
        call_core(py, || self.inner.start(&history.data))
    }

    /// Keeps the sample positions at ``q`` (placed by ``center``, ``rotation`` for body-frame models) as the newest state.
    /// ``before``: steps from this one to the next evaluation, where known; the states the material damping will read
    /// (1 and, for BDF2, 2 steps before) then keep their near vertices' positions, formed here rather than there.
    #[pyo3(signature = (q, center=None, rotation=None, before=None))]
    fn record(
        &mut self,
        py: Python<'_>,
        q: &Bound<'_, PyAny>,
        center: Option<&Bound<'_, PyAny>>,
        rotation: Option<&Bound<'_, PyAny>>,
        before: Option<usize>,
    ) -> PyResult<()> {
        let (q, pose) = state(py, q, center, rotation)?;
        call_core(py, || self.inner.record(&q, pose.as_ref().map(|(c, r)| (c, r)), before))
    }

    /// Begins the evaluation of ``q`` (placed by ``center``, ``rotation`` for body-frame models): its near vertices'
    /// positions; :meth:`finish` ends it (a run does so on the next step, so that the halves' costs fall on two steps).
    #[pyo3(signature = (q, center=None, rotation=None))]
    fn prepare(
        &mut self,
        py: Python<'_>,
        q: &Bound<'_, PyAny>,
        center: Option<&Bound<'_, PyAny>>,
        rotation: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let (q, pose) = state(py, q, center, rotation)?;
        call_core(py, || self.inner.prepare(&q, pose.as_ref().map(|(c, r)| (c, r))))
    }

    /// The residual value (see :meth:`evaluate`) of the state :meth:`prepare` began, which becomes the newest state.
    fn finish(&mut self, py: Python<'_>) -> PyResult<f64> {
        call_core(py, || self.inner.finish())
    }

    /// The step's residual value ``M sum m |du|^2 / sum m`` (kg m^2) over the samples no plane touches, at
    /// ``q`` (placed by ``center``, ``rotation`` for body-frame models), which becomes the newest state.
    #[pyo3(signature = (q, center=None, rotation=None))]
    fn evaluate(
        &mut self,
        py: Python<'_>,
        q: &Bound<'_, PyAny>,
        center: Option<&Bound<'_, PyAny>>,
        rotation: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<f64> {
        let (q, pose) = state(py, q, center, rotation)?;
        call_core(py, || self.inner.evaluate(&q, pose.as_ref().map(|(c, r)| (c, r))))
    }
}
