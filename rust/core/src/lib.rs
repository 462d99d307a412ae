//! Numerics of licrom: stable Neo-Hookean elasticity, penalty contact with implicit
//! Coulomb friction, and the reduced (subspace) implicit time step.
//!
//! Units are SI throughout. No Python types live here; the bindings validate
//! arrays and map [`LicromError`] to exceptions.
//!
//! **Where things live.** The material ([`material`]: stable Neo-Hookean energy,
//! stress, Hessian eigensystem, on [`svd3`]) and the contact point model
//! ([`contact`]: penalty, damping and the Coulomb friction potential of one
//! point against one plane) are per point; [`contact_points`] is the set of
//! contact points both reduced models share (inputs, validation, the points
//! with area, planes and model). [`reduced`] sums them into the
//! incremental potential of one step in reduced coordinates: inertia in
//! `reduced/mod.rs`, the elastic term over the cubature points in
//! `reduced/elastic.rs` ([`reduced::ElasticTerm`]), contact and
//! friction (gradient, incremental Hessian, the stick switch) in
//! `reduced/contact.rs`, the lane packing in `reduced/layout.rs`. [`solver`]
//! minimises it: the outer iteration in `solver/mod.rs`, the Newton matrix in
//! `solver/direction.rs`, the contact model and friction's stick correction in
//! `solver/contact_model.rs`, the line search in [`solver::line_search`](mod@solver::line_search).
//! [`body_frame`] is the reduced model in the body frame (`x = c + R (Xbar + W q)`):
//! the same elastic term, contact and friction pulled back through the rotation,
//! the same line search. The full-space simulation of the same physics (per tet
//! and per vertex, on the GPU with warp) is `python/licrom/full_sim/`: `elastic.py`,
//! `contact.py` (friction and the stick switch) follow the same formulas, and
//! its Newton iteration calls this line search (`licrom._core.line_search`).

// Indexed loops over fixed lane counts and small matrices are the form the
// vectoriser handles best in the hot kernels; iterator chains would hide it.
#![allow(clippy::needless_range_loop)]

pub mod batch;
pub mod body_frame;
pub mod cholesky;
pub mod contact;
pub mod contact_points;
mod dense;
pub mod error;
pub mod integrator;
pub mod material;
pub mod real;
pub mod reconstruction;
pub mod reduced;
pub mod residual_estimate;
pub mod second_thread;
mod simd;
pub mod solver;
pub mod svd3;
pub mod synthetic;
pub mod validity;
pub mod vertex_forces;

#[cfg(test)]
mod testing;

pub use error::{LicromError, Result};
pub use material::StableNeoHookean;
