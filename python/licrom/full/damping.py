"""Kelvin-Voigt material damping per tet: energy, gradient and Hessian of its term in the incremental potential.

The dissipation potential is ``eta/2 |dE/dt|^2`` per unit volume on the rate of the Green strain
``E(F) = (F^T F - I)/2``, read with the integrator's own formula, ``dE/dt = (E(F) - E_a)/h'``: the anchor
strain is ``E_a = E(F_n)`` for backward Euler and ``(4 E(F_n) - E(F_{n-1}))/3`` for BDF2 (``h' = 2h/3``), so
``3 E_{n+1} - 4 E_n + E_{n-1} = 2h dE/dt``. Strains, not positions, are extrapolated: the anchor is the same
in every frame, and the body-frame model computes it from its modal coordinates alone. The term in the
incremental potential (whose gradient is the viscous force) is, per tet,

``eta V / (2 h') |D|^2``,  ``D = E(F) - E_a = (F^T F - C_a)/2``,  ``C_a = 2 E_a + I``,

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

__all__ = ["anchor_kernel", "damping_kernel"]


@wp.kernel
def anchor_kernel(x_now: wp.array(dtype=vec3d), x_prev: wp.array(dtype=vec3d), tets: Tets, history: f64, c_anchor: wp.array(dtype=mat33d)):
    """``C_a = (1 + w) F_n^T F_n - w F_{n-1}^T F_{n-1}`` of every tet at the start of a step (``w`` the
    integrator's history weight: 0 for backward Euler, 1/3 for BDF2)."""
    t = wp.tid()
    ids = tets.ids[t]
    dmi = tets.dminv[t]
    Fn = deformation_gradient(x_now, ids, dmi)
    c = wp.transpose(Fn) * Fn
    if history != f64(0.0):
        Fp = deformation_gradient(x_prev, ids, dmi)
        c = (f64(1.0) + history) * c - history * (wp.transpose(Fp) * Fp)
    c_anchor[t] = c


@wp.func
def _block(na: vec3d, nb: vec3d, F: mat33d, FFt: mat33d, D: mat33d, c: f64, exact: bool):
    # d2/dx_a dx_b of (c/2)|D|^2 for the vertex pair (a, b) with shape gradients n_a, n_b: the Gauss-Newton part
    # c/2 ((n_a . n_b) F F^T + (F n_b)(F n_a)^T), plus c (n_a . D n_b) I for the exact Hessian.
    h = f64(0.5) * c * (wp.dot(na, nb) * FFt + wp.outer(F * nb, F * na))
    if exact:
        h += c * wp.dot(na, D * nb) * wp.identity(n=3, dtype=f64)
    return h


@wp.kernel
def damping_kernel(x: wp.array(dtype=vec3d), c_anchor: wp.array(dtype=mat33d), tets: Tets, eta_over_h: f64, mode: int, out: Assembly):
    """The damping term of every tet at ``x`` against its anchor ``C_a`` (:func:`anchor_kernel`); ``eta_over_h``
    is ``eta / h'`` (Pa)."""
    t = wp.tid()
    ids = tets.ids[t]
    dmi = tets.dminv[t]
    F = deformation_gradient(x, ids, dmi)
    D = f64(0.5) * (wp.transpose(F) * F - c_anchor[t])
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
