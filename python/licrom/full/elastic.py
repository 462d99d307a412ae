"""Stable Neo-Hookean elasticity per tet: energy, gradient and Hessian (analytic eigensystem, PSD-projected or exact).

The same energy as ``rust/core/src/material.rs`` (the reduced model's cubature term)."""

from __future__ import annotations

import warp as wp

from .device import MODE_ENERGY, MODE_GRADIENT, MODE_HESSIAN, Assembly, f64, mat33d, vec3d

__all__ = ['Tets', 'add_tet_gradient', 'deformation_gradient', 'tet_kernel']


@wp.struct
class Tets:
    """The mesh's tets: corner indices, inverse rest shape matrices ``Dm^-1`` and rest volumes."""

    ids: wp.array(dtype=wp.vec4i)
    dminv: wp.array(dtype=mat33d)
    vol: wp.array(dtype=f64)


@wp.func
def deformation_gradient(x: wp.array(dtype=vec3d), ids: wp.vec4i, dmi: mat33d):
    """``F = Ds Dm^-1`` of the tet with corners ``ids``."""
    x0 = x[ids[0]]
    return wp.matrix_from_cols(x[ids[1]] - x0, x[ids[2]] - x0, x[ids[3]] - x0) * dmi


@wp.func
def add_tet_gradient(out: Assembly, ids: wp.vec4i, g: mat33d):
    """Adds a tet's gradient to its corners: ``g``'s columns at corners 1..3, minus their sum at corner 0."""
    gt = wp.transpose(g)
    wp.atomic_add(out.grad, ids[0], -(gt[0] + gt[1] + gt[2]))
    wp.atomic_add(out.grad, ids[1], gt[0])
    wp.atomic_add(out.grad, ids[2], gt[1])
    wp.atomic_add(out.grad, ids[3], gt[2])


@wp.func
def log1p_(x: f64):
    # log(1 + x) without cancellation for small x (Goldberg's trick).
    u = f64(1.0) + x
    if u == f64(1.0):
        return x
    return wp.log(u) * x / (u - f64(1.0))


@wp.func
def mode_apply(m: int, y: vec3d, qt: mat33d):
    # The m-th eigenmode of the stable Neo-Hookean Hessian in the SVD frame, applied to y:
    # 0-2 scaling (columns of the 3x3 eigenvector matrix, rows of qt), 3-5 twist, 6-8 flip.
    r = f64(0.70710678118654752440)
    zero = f64(0.0)
    if m < 3:
        return wp.cw_mul(qt[m], y)
    if m == 3:
        return vec3d(zero, r * y[2], -r * y[1])
    if m == 4:
        return vec3d(r * y[2], zero, -r * y[0])
    if m == 5:
        return vec3d(r * y[1], -r * y[0], zero)
    if m == 6:
        return vec3d(zero, r * y[2], r * y[1])
    if m == 7:
        return vec3d(r * y[2], zero, r * y[0])
    return vec3d(r * y[1], r * y[0], zero)


@wp.kernel
def tet_kernel(x: wp.array(dtype=vec3d), tets: Tets, mu: f64, lam: f64, alpha: f64, mode: int, out: Assembly):
    t = wp.tid()
    ids = tets.ids[t]
    dmi = tets.dminv[t]
    v = tets.vol[t]
    F = deformation_gradient(x, ids, dmi)
    one = f64(1.0)
    half = f64(0.5)
    # Energy relative to the rest state, written in E = F - I so that it has no
    # cancellation near rest: Psi(F) - Psi(I).
    E = F - wp.identity(n=3, dtype=f64)
    tr = E[0, 0] + E[1, 1] + E[2, 2]
    ic3 = wp.ddot(E, E) + f64(2.0) * tr  # I_C - 3
    jm1 = tr + half * (tr * tr - wp.ddot(E, wp.transpose(E))) + wp.determinant(E)  # J - 1
    psi = half * mu * ic3 + half * lam * jm1 * (jm1 + f64(2.0) * (one - alpha)) - half * mu * log1p_(ic3 * f64(0.25))
    wp.atomic_add(out.energy, t % out.energy.shape[0], v * psi)
    if mode == MODE_ENERGY:
        return
    ic1 = ic3 + f64(4.0)  # I_C + 1
    J = jm1 + one
    psi2 = mu * (one - one / ic1)  # 2 dPsi/dI_C
    psi3 = lam * (J - alpha)  # dPsi/dJ
    ft = wp.transpose(F)
    cof = wp.matrix_from_cols(wp.cross(ft[1], ft[2]), wp.cross(ft[2], ft[0]), wp.cross(ft[0], ft[1]))
    P = psi2 * F + psi3 * cof
    add_tet_gradient(out, ids, v * P * wp.transpose(dmi))
    if mode == MODE_GRADIENT:
        return
    # Exact Hessian, assembled directly per vertex pair (a, b) with shape gradients n_a:
    #   d2Psi = psi2 I + c vec(F) vec(F)^T + lam vec(C) vec(C)^T + psi3 d2J,   C = cof F,
    #   block_ab = V (psi2 (n_a . n_b) I + c (F n_a)(F n_b)^T + lam (C n_a)(C n_b)^T - psi3 [F (n_a x n_b)]_x)
    c = f64(2.0) * mu / (ic1 * ic1)
    n1 = dmi[0]
    n2 = dmi[1]
    n3 = dmi[2]
    n0 = -(n1 + n2 + n3)
    f0 = F * n0
    f1 = F * n1
    f2 = F * n2
    f3 = F * n3
    k0 = cof * n0
    k1 = cof * n1
    k2 = cof * n2
    k3 = cof * n3
    I3 = wp.identity(n=3, dtype=f64)
    cv = c * v
    lv = lam * v
    pv = psi2 * v
    jv = -psi3 * v
    h00 = pv * wp.dot(n0, n0) * I3 + cv * wp.outer(f0, f0) + lv * wp.outer(k0, k0)
    h11 = pv * wp.dot(n1, n1) * I3 + cv * wp.outer(f1, f1) + lv * wp.outer(k1, k1)
    h22 = pv * wp.dot(n2, n2) * I3 + cv * wp.outer(f2, f2) + lv * wp.outer(k2, k2)
    h33 = pv * wp.dot(n3, n3) * I3 + cv * wp.outer(f3, f3) + lv * wp.outer(k3, k3)
    h01 = pv * wp.dot(n0, n1) * I3 + cv * wp.outer(f0, f1) + lv * wp.outer(k0, k1) + jv * wp.skew(F * wp.cross(n0, n1))
    h02 = pv * wp.dot(n0, n2) * I3 + cv * wp.outer(f0, f2) + lv * wp.outer(k0, k2) + jv * wp.skew(F * wp.cross(n0, n2))
    h03 = pv * wp.dot(n0, n3) * I3 + cv * wp.outer(f0, f3) + lv * wp.outer(k0, k3) + jv * wp.skew(F * wp.cross(n0, n3))
    h12 = pv * wp.dot(n1, n2) * I3 + cv * wp.outer(f1, f2) + lv * wp.outer(k1, k2) + jv * wp.skew(F * wp.cross(n1, n2))
    h13 = pv * wp.dot(n1, n3) * I3 + cv * wp.outer(f1, f3) + lv * wp.outer(k1, k3) + jv * wp.skew(F * wp.cross(n1, n3))
    h23 = pv * wp.dot(n2, n3) * I3 + cv * wp.outer(f2, f3) + lv * wp.outer(k2, k3) + jv * wp.skew(F * wp.cross(n2, n3))
    if mode == MODE_HESSIAN:
        # PSD projection: remove the negative part of the analytic eigensystem (Smith et al. 2019).
        # With F = U diag(s) V^T (rotation-variant SVD), the 9 eigenpairs of d2Psi are
        # 3 twists psi2 + psi3 s_k, 3 flips psi2 - psi3 s_k, and the eigenpairs of the 3x3
        # Hessian A of Psi in the singular values (scaling modes).
        U = mat33d()
        s = vec3d()
        V = mat33d()
        wp.svd3(F, U, s, V)
        pi0 = s[1] * s[2]
        pi1 = s[0] * s[2]
        pi2 = s[0] * s[1]
        a00 = psi2 + c * s[0] * s[0] + lam * pi0 * pi0
        a11 = psi2 + c * s[1] * s[1] + lam * pi1 * pi1
        a22 = psi2 + c * s[2] * s[2] + lam * pi2 * pi2
        a01 = c * s[0] * s[1] + lam * pi0 * pi1 + psi3 * s[2]
        a02 = c * s[0] * s[2] + lam * pi0 * pi2 + psi3 * s[1]
        a12 = c * s[1] * s[2] + lam * pi1 * pi2 + psi3 * s[0]
        A = mat33d(a00, a01, a02, a01, a11, a12, a02, a12, a22)
        d = vec3d(f64(1.0), f64(1.0), f64(1.0))
        qt = wp.identity(n=3, dtype=f64)
        if a00 <= f64(0.0) or a00 * a11 - a01 * a01 <= f64(0.0) or wp.determinant(A) <= f64(0.0):
            Q = mat33d()
            wp.eig3(A, Q, d)
            qt = wp.transpose(Q)
        twist = vec3d(psi2 + psi3 * s[0], psi2 + psi3 * s[1], psi2 + psi3 * s[2])
        flip = vec3d(psi2 - psi3 * s[0], psi2 - psi3 * s[1], psi2 - psi3 * s[2])
        vt = wp.transpose(V)
        y0 = vt * n0
        y1 = vt * n1
        y2 = vt * n2
        y3 = vt * n3
        for m in range(9):
            ev = f64(0.0)
            if m < 3:
                ev = d[m]
            elif m < 6:
                ev = twist[m - 3]
            else:
                ev = flip[m - 6]
            if ev < f64(0.0):
                ev = -ev * v
                w0 = U * mode_apply(m, y0, qt)
                w1 = U * mode_apply(m, y1, qt)
                w2 = U * mode_apply(m, y2, qt)
                w3 = U * mode_apply(m, y3, qt)
                e0 = ev * w0
                e1 = ev * w1
                e2 = ev * w2
                h00 += wp.outer(e0, w0)
                h01 += wp.outer(e0, w1)
                h02 += wp.outer(e0, w2)
                h03 += wp.outer(e0, w3)
                h11 += wp.outer(e1, w1)
                h12 += wp.outer(e1, w2)
                h13 += wp.outer(e1, w3)
                h22 += wp.outer(e2, w2)
                h23 += wp.outer(e2, w3)
                h33 += wp.outer(ev * w3, w3)
    wp.atomic_add(out.values, out.slots[t, 0], h00)
    wp.atomic_add(out.values, out.slots[t, 1], h01)
    wp.atomic_add(out.values, out.slots[t, 2], h02)
    wp.atomic_add(out.values, out.slots[t, 3], h03)
    wp.atomic_add(out.values, out.slots[t, 4], wp.transpose(h01))
    wp.atomic_add(out.values, out.slots[t, 5], h11)
    wp.atomic_add(out.values, out.slots[t, 6], h12)
    wp.atomic_add(out.values, out.slots[t, 7], h13)
    wp.atomic_add(out.values, out.slots[t, 8], wp.transpose(h02))
    wp.atomic_add(out.values, out.slots[t, 9], wp.transpose(h12))
    wp.atomic_add(out.values, out.slots[t, 10], h22)
    wp.atomic_add(out.values, out.slots[t, 11], h23)
    wp.atomic_add(out.values, out.slots[t, 12], wp.transpose(h03))
    wp.atomic_add(out.values, out.slots[t, 13], wp.transpose(h13))
    wp.atomic_add(out.values, out.slots[t, 14], wp.transpose(h23))
    wp.atomic_add(out.values, out.slots[t, 15], h33)

