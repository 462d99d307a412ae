//! Contact and friction at the contact points of the body-frame model.
//!
//! Point j sits at `x_j = c + R (Xbar_j + W_j q)`; its energy, gradient and
//! PSD Hessian in x come from [`ContactModel::evaluate`] (the model of the
//! world-frame and full simulations), pulled back to `(c, omega, q)` through
//! `Jc = [I, -[p]x, R W_j]`, `p = R y_j`: gradient `[f; p x f; W_j^T R^T f]`,
//! Gauss-Newton Hessian `Jc^T H_x Jc` and, for the exact Hessian, the
//! geometric terms `sym(f p^T) - (f.p) I` (omega-omega) and `(R W_j^k) x f`
//! (omega-q_k). Points that cannot touch a plane and carry no lagged normal
//! force are culled by a bound on their gap: `|W_j q| <= |W_j|_F |q|`.

use faer::linalg::matmul::triangular::{matmul as triangular_matmul, BlockStructure};
use faer::{Accum, MatMut, MatRef, Par};
use nalgebra::{Matrix3, Vector3};

use super::Pose;
use crate::contact::{ContactModel, Plane};
use crate::error::{check_finite, LicromError, Result};

/// The contact points with non-zero area, their basis rows and the planes.
#[derive(Debug, Clone)]
pub struct BodyContacts {
    n: usize,
    /// Number of contact points given (zero areas included).
    total: usize,
    /// Index of each kept point among those given.
    index: Vec<usize>,
    rest: Vec<Vector3<f64>>,
    /// `W_j`, 3 x n row-major per kept point.
    basis: Vec<f64>,
    /// `|W_j|_F`, m per unit of q.
    reach: Vec<f64>,
    areas: Vec<f64>,
    planes: Vec<Plane>,
    model: ContactModel,
}

/// Positions at the start of a step and lagged normal forces (per kept point and plane).
#[derive(Debug, Clone)]
pub struct ContactStart {
    pub(super) x_prev: Vec<Vector3<f64>>,
    pub(super) normal_force: Vec<f64>,
}

/// Scratch for the Gauss-Newton rows `sqrt(coef) d^T Jc`, N wide, row-major.
#[derive(Debug, Clone)]
pub struct ContactRows {
    rows: Vec<f64>,
    count: usize,
}

/// What an evaluation computes besides the energy.
pub(super) struct ContactOut<'a> {
    /// Gradient to add to (N).
    pub grad: Option<&'a mut [f64]>,
    /// Rows of the Gauss-Newton Hessian, and the dense N x N matrix that gets
    /// the geometric terms (exact Hessian only).
    pub rows: Option<&'a mut ContactRows>,
    pub geometric: Option<&'a mut [f64]>,
}

impl BodyContacts {
    /// Validated contact points: `basis` C x 3 x n, `rest` (Xbar_j) C x 3,
    /// `areas` C (>= 0).
    pub fn new(n: usize, basis: &[f64], rest: &[f64], areas: &[f64], planes: &[Plane], model: ContactModel) -> Result<Self> {
        let c = areas.len();
        if basis.len() != 3 * n * c {
            return Err(LicromError::shape("contact_basis", format!("({c}, 3, {n})"), format!("{} values", basis.len())));
        }
        if rest.len() != 3 * c {
            return Err(LicromError::shape("contact_rest", format!("({c}, 3)"), format!("{} values", rest.len())));
        }
        check_finite("contact_basis", basis)?;
        check_finite("contact_rest", rest)?;
        check_finite("contact_areas", areas)?;
        if let Some(a) = areas.iter().find(|a| **a < 0.0) {
            return Err(LicromError::invalid("contact_areas", format!("must be >= 0, found {a}")));
        }
        let index: Vec<usize> = (0..c).filter(|&j| areas[j] > 0.0).collect();
        let rows = |j: usize| &basis[3 * n * j..3 * n * (j + 1)];
        Ok(Self {
            n,
            total: c,
            rest: index.iter().map(|&j| Vector3::from_column_slice(&rest[3 * j..3 * j + 3])).collect(),
            basis: index.iter().flat_map(|&j| rows(j).iter().copied()).collect(),
            reach: index.iter().map(|&j| rows(j).iter().map(|w| w * w).sum::<f64>().sqrt()).collect(),
            areas: index.iter().map(|&j| areas[j]).collect(),
            index,
            planes: planes.to_vec(),
            model,
        })
    }

    /// Number of contact points given.
    pub fn len(&self) -> usize {
        self.total
    }

    /// Whether no contact point was given.
    pub fn is_empty(&self) -> bool {
        self.total == 0
    }

    /// Zeroed start-of-step buffers.
    pub fn start(&self) -> ContactStart {
        ContactStart { x_prev: vec![Vector3::zeros(); self.rest.len()], normal_force: vec![0.0; self.rest.len() * self.planes.len()] }
    }

    /// Row scratch for the Hessian (up to three rows per point and plane).
    pub fn rows(&self) -> ContactRows {
        ContactRows { rows: vec![0.0; 3 * self.rest.len() * self.planes.len() * (6 + self.n)], count: 0 }
    }

    /// `y_j = Xbar_j + W_j q` of kept point `s`.
    #[inline]
    fn body_point(&self, s: usize, q: &[f64]) -> Vector3<f64> {
        let n = self.n;
        let w = &self.basis[3 * n * s..3 * n * (s + 1)];
        let mut y = self.rest[s];
        for c in 0..3 {
            y[c] += w[c * n..(c + 1) * n].iter().zip(q).map(|(a, b)| a * b).sum::<f64>();
        }
        y
    }

    /// Positions of the points at `pose` and their lagged normal forces.
    pub fn begin(&self, pose: &Pose, start: &mut ContactStart) {
        let n_planes = self.planes.len();
        for s in 0..self.rest.len() {
            let x = pose.center + pose.rotation * self.body_point(s, &pose.q);
            start.x_prev[s] = x;
            for (p, plane) in self.planes.iter().enumerate() {
                start.normal_force[s * n_planes + p] = self.model.lagged_normal_force(plane, self.areas[s], &x);
            }
        }
    }

    /// Contact energy (J) at `pose`, with the parts of `out` requested.
    pub(super) fn evaluate(&self, start: &ContactStart, pose: &Pose, mut out: ContactOut<'_>) -> f64 {
        let n = self.n;
        let big = 6 + n;
        let n_planes = self.planes.len();
        let r = &pose.rotation;
        let q_norm = pose.q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if let Some(rows) = out.rows.as_deref_mut() {
            rows.count = 0;
        }
        let mut energy = 0.0;
        for s in 0..self.rest.len() {
            // Lower bound of each gap; a plane is skipped where it cannot be
            // reached and the point carries no lagged force against it.
            let forces = &start.normal_force[s * n_planes..(s + 1) * n_planes];
            let engaged = self.planes.iter().zip(forces).any(|(plane, &f)| {
                f > 0.0 || plane.gap(&pose.center) + (r.transpose() * plane.normal()).dot(&self.rest[s]) - self.reach[s] * q_norm < 0.0
            });
            if !engaged {
                continue;
            }
            let p = r * self.body_point(s, &pose.q);
            let x = pose.center + p;
            let mut f = Vector3::zeros();
            for (plane, &fn_lag) in self.planes.iter().zip(forces) {
                let e = self.model.evaluate(plane, self.areas[s], fn_lag, &x, &start.x_prev[s]);
                energy += e.energy;
                f += e.gradient;
                if let Some(rows) = out.rows.as_deref_mut() {
                    for t in 0..e.hessian.len {
                        let d = e.hessian.dir[t] * e.hessian.coef[t].sqrt();
                        let row = &mut rows.rows[rows.count * big..(rows.count + 1) * big];
                        row[..3].copy_from_slice(d.as_slice());
                        row[3..6].copy_from_slice(p.cross(&d).as_slice());
                        self.pull_back(s, &(r.transpose() * d), &mut row[6..], false);
                        rows.count += 1;
                    }
                }
            }
            if f == Vector3::zeros() {
                continue;
            }
            if let Some(g) = out.grad.as_deref_mut() {
                let pf = p.cross(&f);
                for i in 0..3 {
                    g[i] += f[i];
                    g[3 + i] += pf[i];
                }
                self.pull_back(s, &(r.transpose() * f), &mut g[6..], true);
            }
            if let Some(h) = out.geometric.as_deref_mut() {
                let fp = f * p.transpose();
                let ww = 0.5 * (fp + fp.transpose()) - Matrix3::identity() * f.dot(&p);
                for i in 0..3 {
                    for j in 0..3 {
                        h[(3 + i) * big + 3 + j] += ww[(i, j)];
                    }
                }
                let w = &self.basis[3 * n * s..3 * n * (s + 1)];
                for k in 0..n {
                    let rw = r * Vector3::new(w[k], w[n + k], w[2 * n + k]);
                    let v = rw.cross(&f);
                    for i in 0..3 {
                        h[(3 + i) * big + 6 + k] += v[i];
                        h[(6 + k) * big + 3 + i] += v[i];
                    }
                }
            }
        }
        energy
    }

    /// `out (+)= W_s^T v` (n).
    #[inline]
    fn pull_back(&self, s: usize, v: &Vector3<f64>, out: &mut [f64], add: bool) {
        let n = self.n;
        let w = &self.basis[3 * n * s..3 * n * (s + 1)];
        for (i, o) in out.iter_mut().enumerate() {
            let x = w[i] * v.x + w[n + i] * v.y + w[2 * n + i] * v.z;
            *o = if add { *o + x } else { x };
        }
    }

    /// Adds `B^T B` of the rows of the last evaluation to the full symmetric `hess` (N x N).
    pub(super) fn add_rows(&self, rows: &ContactRows, hess: &mut [f64]) {
        let big = 6 + self.n;
        if rows.count == 0 {
            return;
        }
        let b = MatRef::from_row_major_slice(&rows.rows[..rows.count * big], rows.count, big);
        let a = MatMut::from_column_major_slice_mut(hess, big, big);
        // Lower triangle only, then mirrored: hess is symmetric before and after.
        triangular_matmul(
            a,
            BlockStructure::TriangularLower,
            Accum::Add,
            b.transpose(),
            BlockStructure::Rectangular,
            b,
            BlockStructure::Rectangular,
            1.0,
            Par::Seq,
        );
        for c in 0..big {
            for r in c + 1..big {
                hess[r * big + c] = hess[c * big + r];
            }
        }
    }

    /// Contact force (N) on every given point at `pose` over the step that
    /// started at `start`: C x 3, zero for points without area.
    pub fn forces(&self, start: &ContactStart, pose: &Pose, out: &mut [f64]) {
        out.fill(0.0);
        let n_planes = self.planes.len();
        for (s, &j) in self.index.iter().enumerate() {
            let x = pose.center + pose.rotation * self.body_point(s, &pose.q);
            let mut f = Vector3::zeros();
            for (p, plane) in self.planes.iter().enumerate() {
                f -= self.model.evaluate(plane, self.areas[s], start.normal_force[s * n_planes + p], &x, &start.x_prev[s]).gradient;
            }
            out[3 * j..3 * j + 3].copy_from_slice(f.as_slice());
        }
    }
}
