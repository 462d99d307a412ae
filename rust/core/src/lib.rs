//! Numerics of licrom: stable Neo-Hookean elasticity, penalty contact with implicit
//! Coulomb friction, and the reduced (subspace) implicit time step.
//!
//! Units are SI throughout. No Python types live here; the bindings validate
//! arrays and map [`LicromError`] to exceptions.

// Indexed loops over fixed lane counts and small matrices are the form the
// vectoriser handles best in the hot kernels; iterator chains would hide it.
#![allow(clippy::needless_range_loop)]

pub mod body_frame;
pub mod cholesky;
pub mod contact;
mod dense;
pub mod error;
pub mod material;
pub mod real;
pub mod reconstruction;
pub mod reduced;
mod simd;
pub mod solver;
pub mod svd3;
pub mod synthetic;

#[cfg(test)]
mod testing;

pub use error::{LicromError, Result};
pub use material::StableNeoHookean;
