"""Kelvin-Voigt material damping per tet: energy, gradient and Hessian of its term in the incremental potential.

The dissipation potential is ``eta/2 |dE/dt|^2`` per unit volume on the rate of the Green strain
``E(F) = (F^T F - I)/2``, read, like friction, from the step's anchor: ``dE/dt = (E(F) - E(F_a))/h'``. Its
term in the incremental potential (whose gradient is the viscous force) is, per tet,

``eta V / (2 h') |D|^2``,  ``D = E(F) - E(F_a) = (F^T F - F_a^T F_a)/2``,

with gradient ``c F D`` in F (``c = eta V / h'``). Rotation invariant: a rigid motion, a spin included, is
not damped. The Hessian is ``c (dD/dF)^T (dD/dF) + c D : d2D/dF2``; the first part (Gauss-Newton) is
positive semi-definite and is what Newton uses, the second (``c (n_a . D n_b) I`` per vertex pair) vanishes
at the anchor and is added for the exact Hessian only. The reduced models evaluate the same term at their
cubature points (``rust/core/src/reduced/elastic.rs``).
"""

from __future__ import annotations

import warp as wp

from .device import MODE_ENERGY, MODE_GRADIENT, MODE_RAW_HESSIAN, Assembly, f64, mat33d, vec3d
from .elastic import Tets, add_tet_gradient, deformation_gradient

__all__ = ["damping_kernel"]


@wp.func
def _block(na: vec3d, nb: vec3d, F: mat33d, FFt: mat33d, D: mat33d, c: f64, exact: bool):
    # d2/dx_a dx_b of (c/2)|D|^2 for the vertex pair (a, b) with shape gradients n_a, n_b: the Gauss-Newton part
    # c/2 ((n_a . n_b) F F^T + (F n_b)(F n_a)^T), plus c (n_a . D n_b) I for the exact Hessian.
    h = f64(0.5) * c * (wp.dot(na, nb) * FFt + wp.outer(F * nb, F * na))
    if exact:
        h += c * wp.dot(na, D * nb) * wp.identity(n=3, dtype=f64)
    return h


@wp.kernel
def damping_kernel(x: wp.array(dtype=vec3d), x_anchor: wp.array(dtype=vec3d), tets: Tets, eta_over_h: f64, mode: int, out: Assembly):
    """The damping term of every tet at ``x`` against the anchor ``x_anchor``; ``eta_over_h`` is ``eta / h'`` (Pa)."""
    t = wp.tid()
    ids = tets.ids[t]
    dmi = tets.dminv[t]
    F = deformation_gradient(x, ids, dmi)
    Fa = deformation_gradient(x_anchor, ids, dmi)
    D = f64(0.5) * (wp.transpose(F) * F - wp.transpose(Fa) * Fa)
    c = eta_over_h * tets.vol[t]
    wp.atomic_add(out.energy, t % out.energy.shape[0], f64(0.5) * c * wp.ddot(D, D))
    if mode == MODE_ENERGY:
        return
    add_tet_gradient(out, ids, c * (F * D) * wp.transpose(dmi))
    if mode == MODE_GRADIENT:
        return
    exact = mode == MODE_RAW_HESSIAN
    n1 = dmi[0]
    n2 = dmi[1]
    n3 = dmi[2]
    n0 = -(n1 + n2 + n3)
    FFt = F * wp.transpose(F)
    wp.atomic_add(out.values, out.slots[t, 0], _block(n0, n0, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 1], _block(n0, n1, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 2], _block(n0, n2, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 3], _block(n0, n3, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 4], _block(n1, n0, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 5], _block(n1, n1, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 6], _block(n1, n2, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 7], _block(n1, n3, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 8], _block(n2, n0, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 9], _block(n2, n1, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 10], _block(n2, n2, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 11], _block(n2, n3, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 12], _block(n3, n0, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 13], _block(n3, n1, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 14], _block(n3, n2, F, FFt, D, c, exact))
    wp.atomic_add(out.values, out.slots[t, 15], _block(n3, n3, F, FFt, D, c, exact))
