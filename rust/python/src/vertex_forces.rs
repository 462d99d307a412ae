//! Elastic forces of the full model at a sample of vertices.

use licrom_core::vertex_forces::{RingInputs, VertexForces as CoreVertexForces};
use licrom_core::StableNeoHookean;
use numpy::PyArrayDyn;
use pyo3::prelude::*;

use crate::arrays::{read, read_indices, write, Dim};
use crate::errors::call_core;

/// Elastic force ``f_v = -sum_t V_t P(F_t) g_{t,v}`` (N) on each of S sample vertices
/// from the positions of the corners of their T one-ring tets, with
/// ``F_t = sum_a y_a g_{t,a}^T`` and the stable Neo-Hookean stress P (``snh_pk1``).
///
/// Args:
///     n_points: number of points whose positions ``forces`` takes.
///     n_samples: number of sample vertices S.
///     corners: (T, 4) int64 point indices of each ring tet's corners, below ``n_points``.
///     gradients: (T, 4, 3) shape gradients of the corners in 1/m.
///     volumes: (T,) rest volumes in m^3, > 0.
///     owners: (T,) int64 the sample (below ``n_samples``) whose ring each tet is in.
///     own_corners: (T,) int64 which corner (0-3) of its tet that sample is.
///     mu: stable Neo-Hookean parameter mu in Pa.
///     lam: stable Neo-Hookean parameter lambda in Pa.
#[pyclass(module = "licrom._core", frozen)]
pub struct VertexForces {
    pub(crate) inner: CoreVertexForces,
}

#[pymethods]
impl VertexForces {
    #[new]
    #[pyo3(signature = (n_points, n_samples, corners, gradients, volumes, owners, own_corners, mu, lam))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        n_points: usize,
        n_samples: usize,
        corners: &Bound<'_, PyAny>,
        gradients: &Bound<'_, PyAny>,
        volumes: &Bound<'_, PyAny>,
        owners: &Bound<'_, PyAny>,
        own_corners: &Bound<'_, PyAny>,
        mu: f64,
        lam: f64,
    ) -> PyResult<Self> {
        let material = call_core(py, || StableNeoHookean::new(mu, lam))?;
        let volumes = read(volumes, "volumes", &[Dim::Any("T")])?;
        let t = volumes.shape[0];
        let corners = read_indices(corners, "corners", &[Dim::Is(t), Dim::Is(4)])?;
        let gradients = read(gradients, "gradients", &[Dim::Is(t), Dim::Is(4), Dim::Is(3)])?;
        let owners = read_indices(owners, "owners", &[Dim::Is(t)])?;
        let own_corners = read_indices(own_corners, "own_corners", &[Dim::Is(t)])?;
        let rings = RingInputs { corners: &corners, gradients: &gradients.data, volumes: &volumes.data, owners: &owners, own_corners: &own_corners };
        let inner = call_core(py, || CoreVertexForces::new(n_points, n_samples, &rings, material))?;
        Ok(Self { inner })
    }

    /// (S, 3) forces in N from (n_points, 3) ``positions`` in m.
    fn forces<'py>(&self, py: Python<'py>, positions: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
        let positions = read(positions, "positions", &[Dim::Is(self.inner.n_points()), Dim::Is(3)])?;
        let mut out = vec![0.0; 3 * self.inner.n_samples()];
        call_core(py, || self.inner.forces(&positions.data, &mut out))?;
        write(py, out, &[self.inner.n_samples(), 3])
    }
}
