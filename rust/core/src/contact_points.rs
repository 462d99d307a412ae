//! The set of contact points of a reduced model, as the world-frame
//! ([`crate::reduced`]) and body-frame ([`crate::body_frame`]) models share it:
//! their inputs, their validation, which of them carry area, the planes and
//! the contact model with the integrator's effective step.
//!
//! Point j carries the boundary area `a_j >= 0`; a point of zero area carries
//! no force, so each model packs only the kept points (`a_j > 0`). Their basis
//! rows `W_j` enter the two models differently (`x_j = X_j + W_j q` in the
//! world frame, `x_j = c + R (Xbar_j + W_j q)` in the body frame): each model
//! maps the per-point terms of [`crate::contact`] through its own Jacobian.

use crate::contact::{ContactModel, Plane};
use crate::error::{check_finite, LicromError, Result};

/// Borrowed description of the contact points; arrays row-major (C order).
#[derive(Debug, Clone, Copy)]
pub struct ContactInputs<'a> {
    /// Basis rows W_j at the C contact points, C x 3 x n.
    pub basis: &'a [f64],
    /// Rest positions of the contact points, C x 3, m: X_j in the world-frame
    /// model, Xbar_j (relative to the centre of mass) in the body-frame one.
    pub rest: &'a [f64],
    /// Boundary area a_j >= 0 carried by each contact point, C, m^2.
    pub areas: &'a [f64],
    /// Contact planes.
    pub planes: &'a [Plane],
    /// k_n, N/m^3.
    pub normal_stiffness: f64,
    /// k_d, N s/m^3.
    pub normal_damping: f64,
    /// k_f, N s/m^3.
    pub friction_stiffness: f64,
}

impl ContactInputs<'_> {
    /// The inputs without contact points or planes.
    pub const NONE: ContactInputs<'static> =
        ContactInputs { basis: &[], rest: &[], areas: &[], planes: &[], normal_stiffness: 0.0, normal_damping: 0.0, friction_stiffness: 0.0 };
}

/// The validated contact points: which carry area, the planes and the model.
#[derive(Debug, Clone)]
pub struct ContactPoints {
    /// Number of contact points given (zero areas included).
    total: usize,
    /// Indices of the points with a non-zero area among those given, in order.
    kept: Vec<usize>,
    planes: Vec<Plane>,
    model: ContactModel,
}

impl ContactPoints {
    /// Checks the shapes (for n reduced coordinates), finiteness and
    /// non-negative areas; the contact model takes the effective step `h` (s).
    pub fn new(inp: &ContactInputs<'_>, n: usize, h: f64) -> Result<Self> {
        let c = inp.areas.len();
        if inp.basis.len() != 3 * n * c {
            return Err(LicromError::shape("contact_basis", format!("({c}, 3, {n})"), format!("{} values", inp.basis.len())));
        }
        if inp.rest.len() != 3 * c {
            return Err(LicromError::shape("contact_rest", format!("({c}, 3)"), format!("{} values", inp.rest.len())));
        }
        check_finite("contact_basis", inp.basis)?;
        check_finite("contact_rest", inp.rest)?;
        check_finite("contact_areas", inp.areas)?;
        if let Some(a) = inp.areas.iter().find(|a| **a < 0.0) {
            return Err(LicromError::invalid("contact_areas", format!("must be >= 0, found {a}")));
        }
        let model = ContactModel::new(inp.normal_stiffness, inp.normal_damping, inp.friction_stiffness, h)?;
        Ok(Self { total: c, kept: (0..c).filter(|&j| inp.areas[j] > 0.0).collect(), planes: inp.planes.to_vec(), model })
    }

    /// Number of contact points given C.
    pub fn len(&self) -> usize {
        self.total
    }

    /// Whether no contact point was given.
    pub fn is_empty(&self) -> bool {
        self.total == 0
    }

    /// Indices of the points with a non-zero area, in order.
    pub fn kept(&self) -> &[usize] {
        &self.kept
    }

    /// The planes.
    pub fn planes(&self) -> &[Plane] {
        &self.planes
    }

    /// The contact model, with the integrator's effective step.
    pub fn model(&self) -> &ContactModel {
        &self.model
    }

    /// Whether any contact term can be non-zero (points with area and planes).
    pub fn any(&self) -> bool {
        !self.kept.is_empty() && !self.planes.is_empty()
    }
}
