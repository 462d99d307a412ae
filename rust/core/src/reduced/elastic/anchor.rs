//! The material damping's anchor strain ([`StrainAnchor`]): the right
//! Cauchy-Green tensors `C = F^T F` at the step's start, extrapolated as the
//! integrator extrapolates, `C_a = (1 + w) C(q_n) - w C(q_{n-1})`, that the
//! damping measures the strain's rate against (see the elastic term's module
//! documentation). BDF2 reads `C(q_{n-1})`, which the step before formed as
//! its `C(q_n)`: it is kept, not formed again.

use crate::real::LANES;
use crate::simd::{dispatch, Madd, WithMadd, F8};

use super::{stored_displacement, ElasticTerm, SYM};

/// The anchor's right Cauchy-Green tensors `C_k` (`F_k^T F_k` extrapolated as the
/// integrator extrapolates), per cubature point of positive weight (six components, packed by lanes as the
/// points are): what the material damping measures the strain's rate against.
/// Empty for a term without damping.
#[derive(Debug, Clone, Default)]
pub struct StrainAnchor {
    c: Vec<F8>,
    /// `C(q)` of the last state set, and that state: the next step's previous
    /// state is this one, so BDF2's `C(q_prev)` is read from here, not formed
    /// again (one pass over the cubature Jacobians a step instead of two: a
    /// fifth of the body-frame step's time at n = 120-150, K = 716, profiled).
    last: Vec<F8>,
    last_q: Vec<f64>,
    /// Scratch for the used vertices' displacements (3 each) where F goes
    /// through the vertices, so that setting the anchor does not allocate.
    vertex_u: Vec<f64>,
}

/// Equal anchors: the same strains of the same state (the scratch aside).
impl PartialEq for StrainAnchor {
    fn eq(&self, other: &Self) -> bool {
        self.c == other.c && self.last == other.last && self.last_q == other.last_q
    }
}

impl StrainAnchor {
    /// Keeps `other`'s `C(q)` of its last state, for an anchor that alternates with it.
    pub(crate) fn keep_last(&mut self, other: &StrainAnchor) {
        self.last.clone_from(&other.last);
        self.last_q.clone_from(&other.last_q);
    }

    /// The six components of group `g` of cubature points.
    #[inline(always)]
    pub(super) fn group(&self, g: usize) -> &[F8] {
        &self.c[6 * g..6 * g + 6]
    }
}

impl ElasticTerm {
    /// A zeroed anchor of the right size (empty without damping).
    pub fn strain_anchor(&self) -> StrainAnchor {
        let len = if self.damped() { 6 * self.cubature.groups() } else { 0 };
        let vertices = match &self.vertices {
            Some(v) if self.damped() => 3 * v.n_vertices(self.n),
            _ => 0,
        };
        StrainAnchor { c: vec![[0.0; LANES]; len], last: vec![[0.0; LANES]; len], last_q: Vec::new(), vertex_u: vec![0.0; vertices] }
    }

    /// Sets `anchor` from the state `q` and, with a history weight w, the
    /// previous one: `C = (1 + w) C(q) - w C(q_prev)` (nothing without damping).
    pub fn set_anchor(&self, q: &[f64], previous: Option<(&[f64], f64)>, anchor: &mut StrainAnchor) {
        if self.damped() {
            dispatch(AnchorKernel { term: self, q, previous, anchor });
        }
    }

    #[inline(always)]
    fn set_anchor_impl<M: Madd>(&self, q: &[f64], previous: Option<(&[f64], f64)>, anchor: &mut StrainAnchor) {
        let kept = previous.is_some_and(|(p, _)| anchor.last_q == p);
        // C(q_prev) where it was not kept: into `c`, before `last` is overwritten with C(q).
        if let (Some((p, _)), false) = (previous, kept) {
            self.cauchy_green::<M>(p, &mut anchor.c, &mut anchor.vertex_u);
        } else if kept {
            std::mem::swap(&mut anchor.c, &mut anchor.last);
        }
        self.cauchy_green::<M>(q, &mut anchor.last, &mut anchor.vertex_u);
        anchor.last_q.clear();
        anchor.last_q.extend_from_slice(q);
        let w = previous.map_or(0.0, |(_, w)| w);
        for (out, now) in anchor.c.iter_mut().zip(&anchor.last) {
            for l in 0..LANES {
                out[l] = if previous.is_some() { (1.0 + w) * now[l] - w * out[l] } else { now[l] };
            }
        }
    }

    /// `C = F^T F` at `q` of every group of cubature points, six components each (the order of [`SYM`]):
    /// F formed as the energy forms it, through the vertices where the term has their form (on a mesh
    /// whose points share vertices that is several times cheaper than through the Jacobians, and this
    /// pass ran once a step: an eighth of the body-frame step's time at n = 120, K = 716, profiled).
    #[inline(always)]
    fn cauchy_green<M: Madd>(&self, q: &[f64], out: &mut [F8], u: &mut [f64]) {
        let cub = &self.cubature;
        match &self.vertices {
            Some(vertices) => {
                vertices.displacements(q, self.n, u);
                for (g, c) in out.chunks_exact_mut(6).enumerate() {
                    write_cauchy_green(&vertices.group_deformation::<M>(g, |v| stored_displacement(u, v)), c);
                }
            }
            None => {
                let f0 = cub.constant_deformation(q);
                // sliced by index, not chunked: with every column constant over the points (affine modes alone) a group is empty
                let len = cub.group_len();
                for (g, c) in out.chunks_exact_mut(6).enumerate() {
                    write_cauchy_green(&cub.group_deformation::<M>(&cub.packed[g * len..(g + 1) * len], q, &f0), c);
                }
            }
        }
    }
}

/// The six components of `F^T F` (the order of [`SYM`]) of a group of points.
#[inline(always)]
fn write_cauchy_green(f: &[F8; 9], c: &mut [F8]) {
    for (out, &(i, j)) in c.iter_mut().zip(&SYM) {
        for l in 0..LANES {
            out[l] = f[i][l] * f[j][l] + f[3 + i][l] * f[3 + j][l] + f[6 + i][l] * f[6 + j][l];
        }
    }
}

struct AnchorKernel<'a> {
    term: &'a ElasticTerm,
    q: &'a [f64],
    previous: Option<(&'a [f64], f64)>,
    anchor: &'a mut StrainAnchor,
}

impl WithMadd for AnchorKernel<'_> {
    type Output = ();
    #[inline(always)]
    fn run<M: Madd>(self) {
        self.term.set_anchor_impl::<M>(self.q, self.previous, self.anchor)
    }
}
