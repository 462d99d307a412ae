//! The arrays that `ReducedCore` and `BodyFrameCore` share: the elastic term
//! (cubature, its vertex form, material) and the contact points with their
//! planes, read and checked once for both.

use licrom_core::contact::Plane;
use licrom_core::contact_points::ContactInputs;
use licrom_core::reduced::{ElasticInputs, VertexStrainInputs};
use licrom_core::StableNeoHookean;
use nalgebra::Vector3;
use pyo3::prelude::*;

use crate::arrays::{read, read_indices, Array, Dim};
use crate::errors::{call_core, error, Kind};

/// The elastic term's arguments for n reduced coordinates: `cubature_jacobians`
/// K x 9 x n, `cubature_weights` K, the vertex form ([`VertexForm`]) and the
/// material `(mu, lam, viscosity)`.
pub(crate) struct ElasticArrays {
    jacobians: Array,
    weights: Array,
    vertex_form: Option<VertexForm>,
    material: StableNeoHookean,
    viscosity: f64,
}

/// The arguments of the cubature's vertex form.
pub(crate) struct VertexArgs<'a, 'py> {
    pub basis: Option<&'a Bound<'py, PyAny>>,
    pub tets: Option<&'a Bound<'py, PyAny>>,
    pub grads: Option<&'a Bound<'py, PyAny>>,
}

impl ElasticArrays {
    pub(crate) fn read(
        py: Python<'_>,
        jacobians: &Bound<'_, PyAny>,
        weights: &Bound<'_, PyAny>,
        vertex: VertexArgs<'_, '_>,
        (mu, lam, viscosity): (f64, f64, f64),
        n: usize,
    ) -> PyResult<Self> {
        let material = call_core(py, || StableNeoHookean::new(mu, lam))?;
        let weights = read(weights, "cubature_weights", &[Dim::Any("K")])?;
        let k = weights.shape[0];
        let jacobians = read(jacobians, "cubature_jacobians", &[Dim::Is(k), Dim::Is(9), Dim::Is(n)])?;
        let vertex_form = VertexForm::read(vertex, k, n)?;
        Ok(Self { jacobians, weights, vertex_form, material, viscosity })
    }

    pub(crate) fn inputs(&self) -> ElasticInputs<'_> {
        ElasticInputs {
            cubature_jacobians: &self.jacobians.data,
            cubature_weights: &self.weights.data,
            vertex_strain: self.vertex_form.as_ref().map(VertexForm::inputs),
            material: self.material,
            viscosity: self.viscosity,
        }
    }
}

/// The contact arguments for n reduced coordinates: `contact_basis` C x 3 x n,
/// `contact_rest` C x 3, `contact_areas` C, `planes` P x 5 (normal, offset,
/// friction) and the stiffnesses `(k_n, k_d, k_f)`.
pub(crate) struct ContactArrays {
    basis: Array,
    rest: Array,
    areas: Array,
    planes: Vec<Plane>,
    stiffness: (f64, f64, f64),
}

impl ContactArrays {
    pub(crate) fn read(py: Python<'_>, [basis, rest, areas, planes]: [&Bound<'_, PyAny>; 4], stiffness: (f64, f64, f64), n: usize) -> PyResult<Self> {
        let areas = read(areas, "contact_areas", &[Dim::Any("C")])?;
        let c = areas.shape[0];
        let basis = read(basis, "contact_basis", &[Dim::Is(c), Dim::Is(3), Dim::Is(n)])?;
        let rest = read(rest, "contact_rest", &[Dim::Is(c), Dim::Is(3)])?;
        let planes = read(planes, "planes", &[Dim::Any("P"), Dim::Is(5)])?;
        let planes = call_core(py, || {
            planes.data.chunks_exact(5).map(|p| Plane::new(Vector3::new(p[0], p[1], p[2]), p[3], p[4])).collect::<Result<Vec<_>, _>>()
        })?;
        Ok(Self { basis, rest, areas, planes, stiffness })
    }

    pub(crate) fn inputs(&self) -> ContactInputs<'_> {
        let (normal_stiffness, normal_damping, friction_stiffness) = self.stiffness;
        ContactInputs {
            basis: &self.basis.data,
            rest: &self.rest.data,
            areas: &self.areas.data,
            planes: &self.planes,
            normal_stiffness,
            normal_damping,
            friction_stiffness,
        }
    }
}

/// The cubature Jacobians in vertex form (`cubature_vertex_basis` V x 3 x n,
/// `cubature_tet_vertices` K x 4, `cubature_shape_gradients` K x 4 x 3): all
/// three or none.
struct VertexForm {
    basis: Array,
    tets: Vec<usize>,
    grads: Array,
}

impl VertexForm {
    fn read(args: VertexArgs<'_, '_>, k: usize, n: usize) -> PyResult<Option<Self>> {
        match (args.basis, args.tets, args.grads) {
            (None, None, None) => Ok(None),
            (Some(basis), Some(tets), Some(grads)) => Ok(Some(Self {
                basis: read(basis, "cubature_vertex_basis", &[Dim::Any("V"), Dim::Is(3), Dim::Is(n)])?,
                tets: read_indices(tets, "cubature_tet_vertices", &[Dim::Is(k), Dim::Is(4)])?,
                grads: read(grads, "cubature_shape_gradients", &[Dim::Is(k), Dim::Is(4), Dim::Is(3)])?,
            })),
            (basis, tets, grads) => {
                let py = basis.or(tets).or(grads).map(|o| o.py()).expect("one of the three is given");
                Err(error(
                    py,
                    Kind::Config,
                    "cubature_vertex_basis, cubature_tet_vertices and cubature_shape_gradients go together: give all three or none".to_string(),
                ))
            }
        }
    }

    fn inputs(&self) -> VertexStrainInputs<'_> {
        VertexStrainInputs { vertex_basis: &self.basis.data, tet_vertices: &self.tets, shape_gradients: &self.grads.data }
    }
}
