"""Full-space ground truth: implicit FEM with penalty contact and implicit Coulomb friction (warp).

Each time step minimises the incremental potential of backward Euler,

    E(x) = 1/(2 h^2) (x - x~)^T M (x - x~) + sum_t V_t Psi(F_t(x)) + sum_{j,p} C_jp(x_j),
    x~ = x_t + h v_t + h^2 g,                 v_{t+1} = (x_{t+1} - x_t) / h,

with stable Neo-Hookean elasticity and, at each contact point j and plane p, a
normal penalty, optional normal damping and a friction dissipation potential whose
gradient is the force ``|f_t| = min(k_f |v_t|, mu f_n)`` with the normal force
``f_n`` lagged from the start of the step (see ``DESIGN.md`` and :class:`FullSim`).

The minimiser is found by Newton's method:

- Hessian: per-element PSD projection through the analytic eigensystem of the stable
  Neo-Hookean energy (Smith, de Goes and Kim 2019; ``wp.svd3``/``wp.eig3``), contact and
  friction blocks (PSD by construction), lumped mass; assembled by atomic adds straight
  into 3x3 blocks of a block-CSR pattern built once per mesh.
- Linear solves: conjugate gradients with a block-Jacobi (3x3) preconditioner, three fused
  kernels per iteration, relative tolerance ``min(0.25, sqrt(|g| / |g_0|))`` (Eisenstat-Walker).
- Friction makes the energy nearly non-smooth where stiff sticking meets slip. When a Newton
  step would carry slipping contact points through the stick region, the step is solved
  again with those points modelled as sticking and taken if it decreases ``E`` in full.
- Line search: Armijo sufficient decrease on ``E``; a full step that overshoots the line
  minimum is refined by safeguarded secant steps on the directional derivative.
- Initial iterate: ``x_t + h v_t + h^2 a`` with ``a`` the previous step's acceleration
  (``g`` on the first step, where this is ``x~``). The minimiser does not depend on it;
  sticking contacts start in the stick region, so Newton needs far fewer iterations.

A step has converged when the mass-weighted RMS length of the Newton step divided by ``h``,
``sqrt(dx^T M dx / m_total) / h``, is below ``scene.solver.tolerance`` (m/s): the measure the
reduced solver uses, invariant under a change of basis. All kernels run in float64, on the
CPU or on a CUDA device, with the same code.
"""

import math
import re
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from .errors import ConfigError, ShapeError, SolverError
from .mesh import Mesh
from .scene import Scene
from .trajectory import Trajectory

__all__ = ["FullSim", "StepStats", "ENERGY_TERMS", "ACCEPTED_DEVICES"]

ACCEPTED_DEVICES = ("cpu", "cuda", "cuda:N")
"""Device names :class:`FullSim` accepts (``cuda:N`` is the N-th CUDA device)."""

ENERGY_TERMS = ("inertia", "elastic", "penalty", "damping", "friction")
"""Terms of the incremental potential, for :meth:`FullSim.energy` and friends."""

# Energies and dot products are reduced through this many partial sums: one on the CPU
# (sequential, deterministic), many on a GPU (spreads the atomic additions).
_PARTIALS = {"cpu": 1, "cuda": 256}
_CG_CHUNK = 12  # CG iterations per CUDA graph launch on a GPU (a multiple of 3)
_ARMIJO = 1.0e-4  # sufficient-decrease constant of the line search
_MAX_HALVINGS = 40  # line-search step halvings before giving up
_MAX_SECANT = 8  # secant steps locating an overshot line minimum
_CURVATURE = 0.5  # |phi'(alpha)| <= this * |phi'(0)| accepts a step
_MAX_FORCING = 0.25  # loosest relative tolerance of the linear solves
_MIN_FORCING = 1.0e-10  # tightest relative tolerance of the linear solves

# Evaluation modes of the kernels.
_MODE_ENERGY, _MODE_GRADIENT, _MODE_HESSIAN, _MODE_RAW_HESSIAN = 0, 1, 2, 3

if wp.config.log_level <= wp.LOG_INFO:  # no banner or module-load chatter on stdout
    wp.config.log_level = wp.LOG_WARNING

_initialised = False


def _warp() -> Any:
    """Initialise warp once and return it."""
    global _initialised
    if not _initialised:
        wp.init()
        _initialised = True
    return wp


def _resolve_device(device: Any) -> str:
    """Check a device name against the accepted ones and the devices present."""
    if not isinstance(device, str) or not re.fullmatch(r"cpu|cuda|cuda:\d+", device):
        raise ConfigError(f"device must be one of {', '.join(ACCEPTED_DEVICES)} (N = 0, 1, ...), got {device!r}")
    if device == "cpu":
        return device
    wp = _warp()
    count = wp.get_cuda_device_count()
    if count == 0:
        raise ConfigError(f"device {device!r} requested but no CUDA device is available here; use device='cpu'")
    if device != "cuda" and int(device.split(":")[1]) >= count:
        raise ConfigError(f"device {device!r} does not exist: {count} CUDA device(s) available (cuda:0..cuda:{count - 1})")
    return device


# --- kernels ------------------------------------------------------------------------
f64 = wp.float64
vec3d = wp.vec3d
mat33d = wp.mat33d


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
def tet_kernel(
    x: wp.array(dtype=vec3d),
    tets: wp.array(dtype=wp.vec4i),
    dminv: wp.array(dtype=mat33d),
    vol: wp.array(dtype=f64),
    slots: wp.array2d(dtype=wp.int32),
    mu: f64,
    lam: f64,
    alpha: f64,
    mode: int,
    energy: wp.array(dtype=f64),
    grad: wp.array(dtype=vec3d),
    values: wp.array(dtype=mat33d),
):
    t = wp.tid()
    ids = tets[t]
    x0 = x[ids[0]]
    ds = wp.matrix_from_cols(x[ids[1]] - x0, x[ids[2]] - x0, x[ids[3]] - x0)
    dmi = dminv[t]
    v = vol[t]
    F = ds * dmi
    one = f64(1.0)
    half = f64(0.5)
    # Energy relative to the rest state, written in E = F - I so that it has no
    # cancellation near rest: Psi(F) - Psi(I).
    E = F - wp.identity(n=3, dtype=f64)
    tr = E[0, 0] + E[1, 1] + E[2, 2]
    ic3 = wp.ddot(E, E) + f64(2.0) * tr  # I_C - 3
    jm1 = tr + half * (tr * tr - wp.ddot(E, wp.transpose(E))) + wp.determinant(E)  # J - 1
    psi = half * mu * ic3 + half * lam * jm1 * (jm1 + f64(2.0) * (one - alpha)) - half * mu * log1p_(ic3 * f64(0.25))
    wp.atomic_add(energy, t % energy.shape[0], v * psi)
    if mode == 0:
        return
    ic1 = ic3 + f64(4.0)  # I_C + 1
    J = jm1 + one
    psi2 = mu * (one - one / ic1)  # 2 dPsi/dI_C
    psi3 = lam * (J - alpha)  # dPsi/dJ
    ft = wp.transpose(F)
    cof = wp.matrix_from_cols(wp.cross(ft[1], ft[2]), wp.cross(ft[2], ft[0]), wp.cross(ft[0], ft[1]))
    P = psi2 * F + psi3 * cof
    g = v * P * wp.transpose(dmi)  # columns: gradient at vertices 1..3
    gt = wp.transpose(g)
    wp.atomic_add(grad, ids[0], -(gt[0] + gt[1] + gt[2]))
    wp.atomic_add(grad, ids[1], gt[0])
    wp.atomic_add(grad, ids[2], gt[1])
    wp.atomic_add(grad, ids[3], gt[2])
    if mode == 1:
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
    if mode == 2:
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
    wp.atomic_add(values, slots[t, 0], h00)
    wp.atomic_add(values, slots[t, 1], h01)
    wp.atomic_add(values, slots[t, 2], h02)
    wp.atomic_add(values, slots[t, 3], h03)
    wp.atomic_add(values, slots[t, 4], wp.transpose(h01))
    wp.atomic_add(values, slots[t, 5], h11)
    wp.atomic_add(values, slots[t, 6], h12)
    wp.atomic_add(values, slots[t, 7], h13)
    wp.atomic_add(values, slots[t, 8], wp.transpose(h02))
    wp.atomic_add(values, slots[t, 9], wp.transpose(h12))
    wp.atomic_add(values, slots[t, 10], h22)
    wp.atomic_add(values, slots[t, 11], h23)
    wp.atomic_add(values, slots[t, 12], wp.transpose(h03))
    wp.atomic_add(values, slots[t, 13], wp.transpose(h13))
    wp.atomic_add(values, slots[t, 14], wp.transpose(h23))
    wp.atomic_add(values, slots[t, 15], h33)


@wp.kernel
def inertia_kernel(
    x: wp.array(dtype=vec3d),
    x_tilde: wp.array(dtype=vec3d),
    mass: wp.array(dtype=f64),
    inv_h2: f64,
    mode: int,
    diag_slots: wp.array(dtype=wp.int32),
    energy: wp.array(dtype=f64),
    grad: wp.array(dtype=vec3d),
    values: wp.array(dtype=mat33d),
):
    i = wp.tid()
    k = mass[i] * inv_h2
    d = x[i] - x_tilde[i]
    wp.atomic_add(energy, i % energy.shape[0], f64(0.5) * k * wp.dot(d, d))
    if mode == 0:
        return
    wp.atomic_add(grad, i, k * d)
    if mode >= 2:
        wp.atomic_add(values, diag_slots[i], k * wp.identity(n=3, dtype=f64))


@wp.kernel
def contact_kernel(
    x: wp.array(dtype=vec3d),
    x_start: wp.array(dtype=vec3d),
    points: wp.array(dtype=wp.int32),
    areas: wp.array(dtype=f64),
    normals: wp.array(dtype=vec3d),
    offsets: wp.array(dtype=f64),
    frictions: wp.array(dtype=f64),
    fn_lag: wp.array2d(dtype=f64),
    kn: f64,
    kd: f64,
    kf: f64,
    h: f64,
    terms: int,
    mode: int,
    diag_slots: wp.array(dtype=wp.int32),
    energy: wp.array(dtype=f64),
    grad: wp.array(dtype=vec3d),
    values: wp.array(dtype=mat33d),
    forces: wp.array(dtype=vec3d),
):
    # mode 0 energy, 1 +gradient, 2/3 +Hessian, 4 force only (written to forces[j]).
    j = wp.tid()
    a = areas[j]
    vi = points[j]
    xj = x[vi]
    dx = xj - x_start[vi]
    zero = f64(0.0)
    e = zero
    gj = vec3d()
    hj = mat33d()
    for p in range(normals.shape[0]):
        n = normals[p]
        gap = wp.dot(n, xj) + offsets[p]
        if (terms & 1) != 0 and gap < zero:
            e += f64(0.5) * a * kn * gap * gap
            gj += (a * kn * gap) * n
            hj += (a * kn) * wp.outer(n, n)
        fn = fn_lag[j, p]
        if fn > zero:
            dn = wp.dot(n, dx)
            if (terms & 2) != 0 and dn < zero and kd > zero:
                # a k_d h / 2 min(v_n, 0)^2 with v_n = dn / h
                e += f64(0.5) * a * kd * dn * dn / h
                gj += (a * kd * dn / h) * n
                hj += (a * kd / h) * wp.outer(n, n)
            cap = frictions[p] * fn
            if (terms & 4) != 0 and cap > zero:
                T = wp.identity(n=3, dtype=f64) - wp.outer(n, n)
                delta = dx - dn * n
                slip = wp.length(delta)
                stick = a * kf / h
                if stick * slip <= cap:
                    e += f64(0.5) * stick * slip * slip
                    gj += stick * delta
                    hj += stick * T
                else:
                    tdir = delta / slip
                    e += cap * slip - f64(0.5) * cap * cap / stick
                    gj += cap * tdir
                    hj += (cap / slip) * (T - wp.outer(tdir, tdir))
    if mode == 4:
        forces[j] = -gj
        return
    wp.atomic_add(energy, j % energy.shape[0], e)
    if mode == 0:
        return
    wp.atomic_add(grad, vi, gj)
    if mode >= 2:
        wp.atomic_add(values, diag_slots[vi], hj)


@wp.kernel
def stick_kernel(
    x: wp.array(dtype=vec3d),
    x_start: wp.array(dtype=vec3d),
    y: wp.array(dtype=vec3d),
    points: wp.array(dtype=wp.int32),
    areas: wp.array(dtype=f64),
    normals: wp.array(dtype=vec3d),
    frictions: wp.array(dtype=f64),
    fn_lag: wp.array2d(dtype=f64),
    kf: f64,
    h: f64,
    diag_slots: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33d),
    rhs: wp.array(dtype=vec3d),
    count: wp.array(dtype=wp.int32),
):
    # A slipping contact point whose Newton step (-y) would carry its slip through the
    # stick region is modelled as sticking for a second solve: its slip Hessian and
    # friction gradient are replaced by the stick ones, so the step brings its slip to ~0.
    j = wp.tid()
    a = areas[j]
    vi = points[j]
    dx = x[vi] - x_start[vi]
    yj = y[vi]
    zero = f64(0.0)
    for p in range(normals.shape[0]):
        n = normals[p]
        cap = frictions[p] * fn_lag[j, p]
        if cap > zero and a > zero:
            delta = dx - wp.dot(n, dx) * n
            slip = wp.length(delta)
            stick = a * kf / h
            if stick * slip > cap:
                tdir = delta / slip
                moved = delta - (yj - wp.dot(n, yj) * n)
                if wp.dot(tdir, moved) < cap / stick:
                    T = wp.identity(n=3, dtype=f64) - wp.outer(n, n)
                    wp.atomic_add(values, diag_slots[vi], stick * T - (cap / slip) * (T - wp.outer(tdir, tdir)))
                    wp.atomic_add(rhs, vi, stick * delta - cap * tdir)
                    wp.atomic_add(count, 0, 1)


@wp.kernel
def lagged_normal_kernel(
    x: wp.array(dtype=vec3d),
    points: wp.array(dtype=wp.int32),
    areas: wp.array(dtype=f64),
    normals: wp.array(dtype=vec3d),
    offsets: wp.array(dtype=f64),
    kn: f64,
    fn_lag: wp.array2d(dtype=f64),
):
    j, p = wp.tid()
    gap = wp.dot(normals[p], x[points[j]]) + offsets[p]
    fn_lag[j, p] = areas[j] * kn * wp.max(-gap, f64(0.0))


@wp.kernel
def predict_kernel(
    x: wp.array(dtype=vec3d),
    v: wp.array(dtype=vec3d),
    v_prev: wp.array(dtype=vec3d),
    h: f64,
    gravity: vec3d,
    extrapolate: f64,
    x_start: wp.array(dtype=vec3d),
    x_tilde: wp.array(dtype=vec3d),
    x_out: wp.array(dtype=vec3d),
):
    # x~ = x + h v + h^2 g. The Newton iterate starts from x + h v + h^2 a, with a the
    # acceleration of the previous step (extrapolate = 1) or gravity (extrapolate = 0).
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    xt = xi + h * vi + (h * h) * gravity
    x_start[i] = xi
    x_tilde[i] = xt
    x_out[i] = xt + extrapolate * (h * (vi - v_prev[i]) - (h * h) * gravity)


@wp.kernel
def diag_kernel(
    values: wp.array(dtype=mat33d),
    diag_slots: wp.array(dtype=wp.int32),
    grad: wp.array(dtype=vec3d),
    inv_diag: wp.array(dtype=mat33d),
    partials: wp.array(dtype=f64),
):
    # Inverse diagonal blocks (block-Jacobi preconditioner) and |grad|^2.
    i = wp.tid()
    inv_diag[i] = wp.inverse(values[diag_slots[i]])
    gi = grad[i]
    wp.atomic_add(partials, i % partials.shape[0], wp.dot(gi, gi))


@wp.func
def partial_sum(scal: wp.array3d(dtype=f64), row: int, q: int):
    s = f64(0.0)
    for j in range(scal.shape[2]):
        s += scal[row, q, j]
    return s


# Preconditioned conjugate gradients on the BSR Hessian, block-Jacobi preconditioner.
# scal[row, q, part]: partial sums of q = 0: p.Ap, 1: r.z, 2: r.r, in a ring of three rows
# (iteration k reads row k % 3, writes row (k + 1) % 3, clears row (k + 2) % 3).
@wp.kernel
def pcg_init_kernel(
    b: wp.array(dtype=vec3d),
    inv_diag: wp.array(dtype=mat33d),
    x: wp.array(dtype=vec3d),
    r: wp.array(dtype=vec3d),
    p: wp.array(dtype=vec3d),
    scal: wp.array3d(dtype=f64),
):
    i = wp.tid()
    bi = b[i]
    zi = inv_diag[i] * bi
    x[i] = vec3d()
    r[i] = bi
    p[i] = zi
    part = i % scal.shape[2]
    wp.atomic_add(scal, 0, 1, part, wp.dot(bi, zi))
    wp.atomic_add(scal, 0, 2, part, wp.dot(bi, bi))


@wp.kernel
def pcg_matvec_kernel(
    offsets: wp.array(dtype=wp.int32),
    columns: wp.array(dtype=wp.int32),
    values: wp.array(dtype=mat33d),
    p: wp.array(dtype=vec3d),
    ap: wp.array(dtype=vec3d),
    scal: wp.array3d(dtype=f64),
    k: int,
):
    i = wp.tid()
    s = vec3d()
    for blk in range(offsets[i], offsets[i + 1]):
        s += values[blk] * p[columns[blk]]
    ap[i] = s
    wp.atomic_add(scal, k % 3, 0, i % scal.shape[2], wp.dot(p[i], s))


@wp.kernel
def pcg_update_kernel(
    inv_diag: wp.array(dtype=mat33d),
    x: wp.array(dtype=vec3d),
    r: wp.array(dtype=vec3d),
    z: wp.array(dtype=vec3d),
    p: wp.array(dtype=vec3d),
    ap: wp.array(dtype=vec3d),
    scal: wp.array3d(dtype=f64),
    k: int,
):
    i = wp.tid()
    row = k % 3
    pap = partial_sum(scal, row, 0)
    alpha = f64(0.0)
    if pap > f64(0.0):
        alpha = partial_sum(scal, row, 1) / pap
    x[i] = x[i] + alpha * p[i]
    ri = r[i] - alpha * ap[i]
    r[i] = ri
    zi = inv_diag[i] * ri
    z[i] = zi
    part = i % scal.shape[2]
    nxt = (k + 1) % 3
    wp.atomic_add(scal, nxt, 1, part, wp.dot(ri, zi))
    wp.atomic_add(scal, nxt, 2, part, wp.dot(ri, ri))


@wp.kernel
def pcg_direction_kernel(z: wp.array(dtype=vec3d), p: wp.array(dtype=vec3d), scal: wp.array3d(dtype=f64), k: int):
    i = wp.tid()
    rz_old = partial_sum(scal, k % 3, 1)
    beta = f64(0.0)
    if rz_old > f64(0.0):
        beta = partial_sum(scal, (k + 1) % 3, 1) / rz_old
    p[i] = z[i] + beta * p[i]
    if i < scal.shape[2]:
        clear = (k + 2) % 3
        scal[clear, 0, i] = f64(0.0)
        scal[clear, 1, i] = f64(0.0)
        scal[clear, 2, i] = f64(0.0)


@wp.kernel
def stats_kernel(
    grad: wp.array(dtype=vec3d),
    y: wp.array(dtype=vec3d),
    mass: wp.array(dtype=f64),
    partials: wp.array2d(dtype=f64),
):
    # partials[0]: grad . y, partials[1]: y^T M y
    i = wp.tid()
    yi = y[i]
    slot = i % partials.shape[1]
    wp.atomic_add(partials, 0, slot, wp.dot(grad[i], yi))
    wp.atomic_add(partials, 1, slot, mass[i] * wp.dot(yi, yi))


@wp.kernel
def axpy_kernel(x: wp.array(dtype=vec3d), y: wp.array(dtype=vec3d), a: f64, out: wp.array(dtype=vec3d)):
    i = wp.tid()
    out[i] = x[i] + a * y[i]


@wp.kernel
def velocity_kernel(
    x: wp.array(dtype=vec3d), x_start: wp.array(dtype=vec3d), inv_h: f64, v: wp.array(dtype=vec3d), v_prev: wp.array(dtype=vec3d)
):
    i = wp.tid()
    v_prev[i] = v[i]
    v[i] = inv_h * (x[i] - x_start[i])


class _Kernels:
    pass


_KERNELS = _Kernels()
for _name, _obj in list(globals().items()):
    if isinstance(_obj, wp.Kernel):
        setattr(_KERNELS, _name, _obj)


@dataclass(frozen=True)
class StepStats:
    """What the last :meth:`FullSim.step` did.

    Attributes:
        iterations: Newton directions computed.
        residual: final convergence measure ``sqrt(dx^T M dx / m_total) / h`` in m/s.
        converged: whether the residual met ``scene.solver.tolerance``.
        linear_iterations: conjugate-gradient iterations summed over the Newton iterations.
        energy_evaluations: incremental-potential evaluations of the line searches.
        seconds: wall time of the step, s.
    """

    iterations: int
    residual: float
    converged: bool
    linear_iterations: int
    energy_evaluations: int
    seconds: float


class FullSim:
    """Full-space simulation of one mesh in one scene (the ground truth).

    Args:
        mesh: the tet mesh (rest shape).
        scene: material, planes, contact stiffnesses, time step, gravity, solver settings
            and initial state (applied on construction).
        device: ``"cpu"``, ``"cuda"`` or ``"cuda:N"``.
        contact_points: where contact acts: ``None`` for every boundary vertex with its share
            of the boundary area, or ``(indices, areas)`` (or an object with ``indices`` and
            ``areas`` attributes, such as ``licrom.cubature.ContactPoints``).

    Raises:
        ConfigError: unknown device, or bad contact points.
        ShapeError: contact-point arrays of the wrong shape.
    """

    def __init__(self, mesh: Mesh, scene: Scene, device: str = "cpu", contact_points: Any = None) -> None:
        if not isinstance(mesh, Mesh):
            raise ConfigError(f"mesh must be a licrom.Mesh, got {type(mesh).__name__}")
        if not isinstance(scene, Scene):
            raise ConfigError(f"scene must be a licrom.Scene, got {type(scene).__name__}")
        self.device = _resolve_device(device)
        self.mesh = mesh
        self.scene = scene
        idx, areas = self._check_contact_points(contact_points)
        wp = _warp()
        dev = self.device
        n = mesh.n_vertices
        self._n = n
        self._masses = mesh.vertex_masses(scene.material.density)
        self._total_mass = float(self._masses.sum())
        self._contact_idx = idx
        self._contact_areas = areas
        mu, lam = scene.material.snh_parameters
        self._mu, self._lam = float(mu), float(lam)
        self._alpha = 1.0 + 0.75 * self._mu / self._lam
        h = scene.dt
        self._h = h
        planes = scene.plane_array()

        f64 = wp.float64
        # Static data.
        self._tets = wp.array(mesh.tets.astype(np.int32), dtype=wp.vec4i, device=dev)
        self._dminv = wp.array(mesh.shape_matrix_inverses, dtype=wp.mat33d, device=dev)
        self._vol = wp.array(mesh.rest_volumes, dtype=f64, device=dev)
        self._mass = wp.array(self._masses, dtype=f64, device=dev)
        self._points = wp.array(idx.astype(np.int32), dtype=wp.int32, device=dev)
        self._areas = wp.array(areas, dtype=f64, device=dev)
        self._normals = wp.array(planes[:, :3].reshape(-1, 3), dtype=wp.vec3d, device=dev)
        self._offsets = wp.array(planes[:, 3].copy(), dtype=f64, device=dev)
        self._frictions = wp.array(planes[:, 4].copy(), dtype=f64, device=dev)
        self._n_planes = len(planes)
        self._fn_lag = wp.zeros((max(len(idx), 1), max(self._n_planes, 1)), dtype=f64, device=dev)
        self._forces = wp.zeros(max(len(idx), 1), dtype=wp.vec3d, device=dev)

        # Sparsity pattern of the Hessian: one 3x3 block per vertex pair sharing a tet.
        self._build_pattern()

        # State and work arrays.
        vec = lambda: wp.zeros(n, dtype=wp.vec3d, device=dev)  # noqa: E731
        self._x = vec()
        self._v = vec()
        self._v_prev = vec()
        self._have_prev = False
        self._x_start = vec()
        self._x_tilde = vec()
        self._x_trial = vec()
        self._grad = vec()
        self._y = vec()
        self._inv_diag = wp.zeros(n, dtype=wp.mat33d, device=dev)
        parts = _PARTIALS["cpu" if dev == "cpu" else "cuda"]
        self._cg_graphs: dict[tuple[int, int], Any] = {}
        self._energy = wp.zeros(parts, dtype=f64, device=dev)
        self._gnorm = wp.zeros(parts, dtype=f64, device=dev)
        self._stats = wp.zeros((2, parts), dtype=f64, device=dev)
        self._y_alt = vec()
        self._rhs = vec()
        self._count = wp.zeros(1, dtype=wp.int32, device=dev)
        self._stick_correction = True
        self._cg_r = vec()
        self._cg_z = vec()
        self._cg_p = vec()
        self._cg_ap = vec()
        self._cg_scal = wp.zeros((3, 3, parts), dtype=f64, device=dev)

        self.time = 0.0
        self._step_index = 0
        self._has_forces = False
        self.last_stats: StepStats | None = None
        positions, velocities = scene.initial.apply(mesh.vertices, self._masses)
        self.set_state(positions, velocities)

    # --- setup -------------------------------------------------------------------------
    def _check_contact_points(self, contact_points: Any) -> tuple[np.ndarray, np.ndarray]:
        mesh = self.mesh
        if contact_points is None:
            return np.asarray(mesh.boundary_vertices, dtype=np.int64), np.asarray(mesh.boundary_vertex_areas, dtype=np.float64)
        if hasattr(contact_points, "indices") and hasattr(contact_points, "areas"):
            raw_idx, raw_areas = contact_points.indices, contact_points.areas
        else:
            try:
                raw_idx, raw_areas = contact_points
            except (TypeError, ValueError):
                raise ConfigError("contact_points must be None or a pair (indices, areas)") from None
        idx = np.asarray(raw_idx)
        areas = np.asarray(raw_areas)
        if idx.ndim != 1 or areas.ndim != 1 or len(idx) != len(areas):
            raise ShapeError(f"contact_points indices and areas must be 1-d arrays of equal length, got shapes {idx.shape} and {areas.shape}")
        if len(idx) and not np.issubdtype(idx.dtype, np.integer):
            raise ShapeError(f"contact_points indices must be integers, got dtype {idx.dtype}")
        idx = idx.astype(np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
            raise ConfigError(f"contact_points indices must be vertex indices in [0, {mesh.n_vertices - 1}], found {idx.min()}..{idx.max()}")
        if len(np.unique(idx)) != len(idx):
            raise ConfigError("contact_points indices must not repeat a vertex")
        try:
            areas = areas.astype(np.float64)
        except (TypeError, ValueError):
            raise ShapeError(f"contact_points areas must be real numbers, got dtype {areas.dtype}") from None
        if not np.all(np.isfinite(areas)) or np.any(areas < 0):
            raise ConfigError("contact_points areas must be finite and >= 0 (m^2)")
        return idx, areas

    def _build_pattern(self) -> None:
        """Block-sparse (3x3) pattern of the Hessian, fixed for the mesh: a block per vertex pair sharing a tet.

        Rows are sorted, columns sorted within a row (block CSR). Each tet knows the
        slots of its 16 blocks and each vertex the slot of its diagonal block, so
        assembly writes straight into the values array; the pattern is reused by every
        Newton iteration of every step.
        """
        n = self._n
        tets = self.mesh.tets
        rows = np.repeat(tets, 4, axis=1).ravel()  # pairs (a, b) in the order a-major, b-minor
        cols = np.tile(tets, (1, 4)).ravel()
        keys = rows * n + cols
        unique, slot = np.unique(keys, return_inverse=True)
        r = unique // n
        c = (unique % n).astype(np.int32)
        diag = np.searchsorted(unique, np.arange(n, dtype=np.int64) * (n + 1))
        offsets = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(np.int32)
        dev = self.device
        self._nnz = len(unique)
        self._offsets_dev = wp.array(offsets, dtype=wp.int32, device=dev)
        self._columns_dev = wp.array(c, dtype=wp.int32, device=dev)
        self._values = wp.zeros(self._nnz, dtype=wp.mat33d, device=dev)
        self._slots = wp.array(slot.reshape(-1, 16).astype(np.int32), dtype=wp.int32, device=dev)
        self._diag_slots = wp.array(diag.astype(np.int32), dtype=wp.int32, device=dev)
        self._pattern = (offsets, c)

    def _solve(self, tol: float, maxiter: int, b: Any = None, y: Any = None) -> int:
        """Solve ``H y = b`` (default: ``b`` the gradient) to relative residual ``tol`` by block-Jacobi PCG.

        Returns the number of iterations. ``y`` starts from zero, so every iterate is a
        descent direction of the incremental potential (along ``-y``).
        """
        k = _KERNELS
        dev = self.device
        n = self._n
        scal = self._cg_scal
        b = self._grad if b is None else b
        y = self._y if y is None else y
        scal.zero_()
        wp.launch(k.pcg_init_kernel, dim=n, device=dev, inputs=[b, self._inv_diag, y, self._cg_r, self._cg_p, scal])
        host = scal.numpy()
        bb = float(host[0, 2].sum())
        if not (bb > 0.0) or not math.isfinite(bb):
            return 0
        threshold = tol * tol * bb
        if dev != "cpu":
            return self._solve_graphed(b, y, threshold, maxiter)
        it = 0
        while it < maxiter:
            wp.launch(k.pcg_matvec_kernel, dim=n, device=dev,
                      inputs=[self._offsets_dev, self._columns_dev, self._values, self._cg_p, self._cg_ap, scal, it])
            wp.launch(k.pcg_update_kernel, dim=n, device=dev,
                      inputs=[self._inv_diag, y, self._cg_r, self._cg_z, self._cg_p, self._cg_ap, scal, it])
            wp.launch(k.pcg_direction_kernel, dim=n, device=dev, inputs=[self._cg_z, self._cg_p, scal, it])
            it += 1
            rr = float(scal.numpy()[it % 3, 2].sum())
            if not rr > threshold:  # also stops on NaN
                break
        return it

    def _solve_graphed(self, b: Any, y: Any, threshold: float, maxiter: int) -> int:
        """The PCG iterations on a GPU: chunks of iterations replayed as one CUDA graph.

        A chunk is a multiple of three iterations (the ring of partial sums), so one graph
        serves every chunk; the residual is read back between chunks. Iterating a little
        past the tolerance only makes the solve more accurate.
        """
        k = _KERNELS
        dev = self.device
        n = self._n
        scal = self._cg_scal
        key = (b.ptr, y.ptr)
        graph = self._cg_graphs.get(key)
        if graph is None:
            with wp.ScopedCapture(device=dev, force_module_load=False) as capture:
                for it in range(_CG_CHUNK):
                    wp.launch(k.pcg_matvec_kernel, dim=n, device=dev,
                              inputs=[self._offsets_dev, self._columns_dev, self._values, self._cg_p, self._cg_ap, scal, it])
                    wp.launch(k.pcg_update_kernel, dim=n, device=dev,
                              inputs=[self._inv_diag, y, self._cg_r, self._cg_z, self._cg_p, self._cg_ap, scal, it])
                    wp.launch(k.pcg_direction_kernel, dim=n, device=dev, inputs=[self._cg_z, self._cg_p, scal, it])
            graph = self._cg_graphs[key] = capture.graph
        it = 0
        while it < maxiter:
            wp.capture_launch(graph)
            it += _CG_CHUNK
            rr = float(scal.numpy()[0, 2].sum())  # _CG_CHUNK % 3 == 0: the next iteration reads row 0
            if not rr > threshold:
                break
        return it

    # --- state -------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        return self._n

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) float64 vertex positions in m (a copy)."""
        return self._x.numpy().astype(np.float64, copy=True)

    @property
    def velocities(self) -> np.ndarray:
        """(n, 3) float64 vertex velocities in m/s (a copy)."""
        return self._v.numpy().astype(np.float64, copy=True)

    @property
    def masses(self) -> np.ndarray:
        """(n,) lumped vertex masses in kg."""
        return self._masses.copy()

    @property
    def contact_indices(self) -> np.ndarray:
        """(C,) vertex index of each contact point."""
        return self._contact_idx.copy()

    @property
    def contact_areas(self) -> np.ndarray:
        """(C,) boundary area carried by each contact point, m^2."""
        return self._contact_areas.copy()

    def set_state(self, positions: np.ndarray | None = None, velocities: np.ndarray | None = None) -> None:
        """Set positions and/or velocities ((n, 3), m and m/s); an omitted one keeps its value.

        Raises:
            ShapeError: wrong shape, or NaN/inf values.
        """
        wp = _warp()
        if positions is not None:
            self._x.assign(wp.array(self._check_field("positions", positions), dtype=wp.vec3d, device=self.device))
        if velocities is not None:
            self._v.assign(wp.array(self._check_field("velocities", velocities), dtype=wp.vec3d, device=self.device))
        self._has_forces = False
        self._have_prev = False

    def _check_field(self, name: str, a: Any) -> np.ndarray:
        try:
            arr = np.asarray(a, dtype=np.float64)
        except (TypeError, ValueError):
            raise ShapeError(f"{name} must be a real (n, 3) array") from None
        if arr.shape != (self._n, 3):
            raise ShapeError(f"{name} must have shape ({self._n}, 3), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ShapeError(f"{name} hold NaN or inf")
        return np.ascontiguousarray(arr)

    # --- evaluation --------------------------------------------------------------------
    def _begin_step(self) -> None:
        """x_start = x, x~ = x + h v + h^2 g, lagged normal forces; the iterate starts at x~."""
        wp = _warp()
        k = _KERNELS
        dev = self.device
        h = self._h
        wp.launch(
            k.predict_kernel, dim=self._n, device=dev,
            inputs=[self._x, self._v, self._v_prev, wp.float64(h), wp.vec3d(*self.scene.gravity),
                    wp.float64(1.0 if self._have_prev else 0.0), self._x_start, self._x_tilde, self._x],
        )
        if len(self._contact_idx) and self._n_planes:
            wp.launch(
                k.lagged_normal_kernel, dim=(len(self._contact_idx), self._n_planes), device=dev,
                inputs=[self._x_start, self._points, self._areas, self._normals, self._offsets,
                        wp.float64(self.scene.contact.normal_stiffness), self._fn_lag],
            )

    def _evaluate(self, x: Any, mode: int, terms: int = 0b11111) -> None:
        """Accumulate the energy partials (and gradient / Hessian for mode >= 1 / 2) at ``x``.

        ``terms`` bits: 1 inertia, 2 elastic, 4 penalty, 8 damping, 16 friction.
        """
        wp = _warp()
        k = _KERNELS
        dev = self.device
        c = self.scene.contact
        self._energy.zero_()
        if mode >= 1:
            self._grad.zero_()
        if mode >= 2:
            self._values.zero_()
        values = self._values
        if terms & 1:
            wp.launch(
                k.inertia_kernel, dim=self._n, device=dev,
                inputs=[x, self._x_tilde, self._mass, wp.float64(1.0 / self._h**2), mode, self._diag_slots,
                        self._energy, self._grad, values],
            )
        if terms & 2:
            wp.launch(
                k.tet_kernel, dim=self.mesh.n_tets, device=dev,
                inputs=[x, self._tets, self._dminv, self._vol, self._slots, wp.float64(self._mu), wp.float64(self._lam),
                        wp.float64(self._alpha), mode, self._energy, self._grad, values],
            )
        contact_terms = terms >> 2
        if contact_terms and len(self._contact_idx) and self._n_planes:
            self._launch_contact(x, mode, contact_terms)

    def _launch_contact(self, x: Any, mode: int, contact_terms: int = 0b111) -> None:
        wp = _warp()
        c = self.scene.contact
        wp.launch(
            _KERNELS.contact_kernel, dim=len(self._contact_idx), device=self.device,
            inputs=[x, self._x_start, self._points, self._areas, self._normals, self._offsets, self._frictions,
                    self._fn_lag, wp.float64(c.normal_stiffness), wp.float64(c.normal_damping),
                    wp.float64(c.friction_stiffness), wp.float64(self._h), contact_terms, mode, self._diag_slots,
                    self._energy, self._grad, self._values, self._forces],
        )

    def _energy_value(self) -> float:
        return float(self._energy.numpy().sum())

    # --- stepping ----------------------------------------------------------------------
    def step(self) -> tuple[int, float]:
        """Advance one time step by minimising the incremental potential.

        Returns:
            ``(iterations, residual)``: Newton directions computed and the final convergence
            measure in m/s. :attr:`last_stats` holds more (linear iterations, timing).

        Raises:
            SolverError: no convergence within ``scene.solver.max_iterations``, or a NaN/inf,
                with ``scene.solver.on_failure == "raise"``; the state is then left unchanged.
                With ``"record"`` the last finite iterate is kept and ``last_stats.converged``
                is False.
        """
        k = _KERNELS
        dev = self.device
        n = self._n
        start = time.perf_counter()
        solver = self.scene.solver
        h = self._h
        self._begin_step()
        iterations = 0
        linear_iterations = 0
        evaluations = 0
        residual = math.inf
        converged = False
        failure = ""
        gnorm0 = None
        energy = None
        maxiter_cg = max(3 * n, 50)
        while iterations < solver.max_iterations:
            self._evaluate(self._x, _MODE_HESSIAN)
            self._gnorm.zero_()
            wp.launch(k.diag_kernel, dim=n, device=dev, inputs=[self._values, self._diag_slots, self._grad, self._inv_diag, self._gnorm])
            e0 = self._energy_value() if energy is None else energy
            gnorm = math.sqrt(float(self._gnorm.numpy().sum()))
            if not (math.isfinite(e0) and math.isfinite(gnorm)):
                failure = "the energy or its gradient is NaN or inf"
                break
            if gnorm0 is None:
                gnorm0 = gnorm
            forcing = _MAX_FORCING if gnorm0 == 0.0 else min(_MAX_FORCING, max(_MIN_FORCING, math.sqrt(gnorm / gnorm0)))
            linear_iterations += self._solve(forcing, maxiter_cg)
            iterations += 1
            self._stats.zero_()
            wp.launch(k.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y, self._mass, self._stats])
            st = self._stats.numpy().sum(axis=1)
            slope, ymy = float(st[0]), float(st[1])  # the direction is -y: slope of E along it is -g.y
            if not (math.isfinite(slope) and math.isfinite(ymy)):
                failure = "the Newton direction is NaN or inf"
                break
            residual = math.sqrt(max(ymy, 0.0) / self._total_mass) / h
            if residual < solver.tolerance:
                wp.launch(k.axpy_kernel, dim=n, device=dev, inputs=[self._x, self._y, wp.float64(-1.0), self._x])
                converged = True
                break
            alpha, accepted, evals = None, None, 0
            if self._stick_correction and len(self._contact_idx) and self._n_planes:
                its, stick_slope = self._stick_direction(forcing, maxiter_cg)
                linear_iterations += its
                if stick_slope is not None:
                    # Take the stick-corrected step only if it decreases E in full.
                    self._y, self._y_alt = self._y_alt, self._y
                    e1, _ = self._trial(1.0, False)
                    evals += 1
                    if math.isfinite(e1) and e1 <= e0 - _ARMIJO * stick_slope + 1e-13 * abs(e0):
                        alpha, accepted = 1.0, e1
                    else:
                        self._y, self._y_alt = self._y_alt, self._y
            if accepted is None:
                alpha, accepted, ls_evals = self._line_search(e0, slope)
                evals += ls_evals
            evaluations += evals
            if accepted is None:
                failure = "the line search found no decrease of the incremental potential"
                break
            self._x, self._x_trial = self._x_trial, self._x
            energy = accepted
        seconds = time.perf_counter() - start
        if not converged and not failure:
            failure = f"no convergence in {iterations} Newton iterations"
        if not converged and solver.on_failure == "raise":
            wp.copy(self._x, self._x_start)
            self._has_forces = False
            self.last_stats = StepStats(iterations, residual, False, linear_iterations, evaluations, seconds)
            err = SolverError(
                f"full-space step {self._step_index} (t = {self.time:.6g} s) failed: {failure}; "
                f"residual {residual:.3e} m/s, tolerance {solver.tolerance:.3e} m/s, "
                f"{iterations} iterations (max_iterations {solver.max_iterations})"
            )
            err.iterations = iterations  # type: ignore[attr-defined]
            err.residual = residual  # type: ignore[attr-defined]
            err.step_index = self._step_index  # type: ignore[attr-defined]
            raise err
        wp.launch(k.velocity_kernel, dim=n, device=dev, inputs=[self._x, self._x_start, wp.float64(1.0 / h), self._v, self._v_prev])
        self._have_prev = True
        if len(self._contact_idx) and self._n_planes:
            self._launch_contact(self._x, 4)
        self._has_forces = True
        self.time += h
        self._step_index += 1
        self.last_stats = StepStats(iterations, residual, converged, linear_iterations, evaluations, time.perf_counter() - start)
        return iterations, residual

    def _stick_direction(self, tol: float, maxiter: int) -> tuple[int, float | None]:
        """Newton direction with the contact points that the current step would carry through stick modelled as sticking.

        Slipping points whose slip the step ``-y`` would reverse or bring into the stick
        region get the stick Hessian and the stick gradient (pulling their slip to zero),
        and the system is solved again into ``_y_alt``. Friction makes the energy nearly
        non-smooth where stiff sticking meets slip; this anticipates the switch that the
        plain Newton step would overshoot.

        Returns (CG iterations, slope ``g . y_alt``), the slope None when no point switches
        or the new direction is not a descent direction of the true energy.
        """
        k = _KERNELS
        dev = self.device
        n = self._n
        c = self.scene.contact
        wp.copy(self._rhs, self._grad)
        self._count.zero_()
        wp.launch(
            k.stick_kernel, dim=len(self._contact_idx), device=dev,
            inputs=[self._x, self._x_start, self._y, self._points, self._areas, self._normals, self._frictions,
                    self._fn_lag, wp.float64(c.friction_stiffness), wp.float64(self._h), self._diag_slots,
                    self._values, self._rhs, self._count],
        )
        switched = int(self._count.numpy()[0])
        if switched == 0:
            return 0, None
        self._gnorm.zero_()
        wp.launch(k.diag_kernel, dim=n, device=dev, inputs=[self._values, self._diag_slots, self._grad, self._inv_diag, self._gnorm])
        its = self._solve(tol, maxiter, b=self._rhs, y=self._y_alt)
        self._stats.zero_()
        wp.launch(k.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y_alt, self._mass, self._stats])
        slope = float(self._stats.numpy()[0].sum())
        return its, (slope if math.isfinite(slope) and slope > 0.0 else None)

    def _trial(self, alpha: float, with_slope: bool) -> tuple[float, float]:
        """E and dE/dalpha at x - alpha y (the point is left in ``_x_trial``)."""
        k = _KERNELS
        dev = self.device
        n = self._n
        wp.launch(k.axpy_kernel, dim=n, device=dev, inputs=[self._x, self._y, wp.float64(-alpha), self._x_trial])
        self._evaluate(self._x_trial, _MODE_GRADIENT if with_slope else _MODE_ENERGY)
        e = self._energy_value()
        if not with_slope:
            return e, math.nan
        self._stats.zero_()
        wp.launch(k.stats_kernel, dim=n, device=dev, inputs=[self._grad, self._y, self._mass, self._stats])
        return e, -float(self._stats.numpy()[0].sum())

    def _line_search(self, e0: float, slope: float) -> tuple[float, float | None, int]:
        """Step length along ``-y`` from ``x``: Armijo sufficient decrease plus a curvature test.

        ``phi(a) = E(x - a y)``, ``phi'(0) = -slope < 0``. The full Newton step is taken
        when it decreases ``E`` enough and does not overshoot the minimum along the line
        by much (``phi'(1) <= c |phi'(0)|``). An overshoot, typical where friction switches
        between stick and slip, is bracketed and the line minimum located by safeguarded
        secant steps on ``phi'``; otherwise the step is halved until ``E`` decreases.

        Returns ``(alpha, E(x - alpha y), evaluations)``, with ``E`` None when no step
        decreases the energy; the accepted point is in ``_x_trial``.
        """
        d0 = -slope
        slack = 1e-13 * max(abs(e0), 1e-300)
        noise = 1e-10 * max(abs(e0), 1e-300)

        def ok(a: float, e: float, d: float = math.nan) -> bool:
            if not math.isfinite(e):
                return False
            if e <= e0 + _ARMIJO * a * d0 + slack:
                return True
            # Near convergence the decrease hides in the round-off of E (positions minus
            # positions); there a step at the line minimum (small phi') is accepted.
            return e <= e0 + noise and math.isfinite(d) and abs(d) <= _CURVATURE * abs(d0)

        evals = 1
        e1, d1 = self._trial(1.0, True)
        if ok(1.0, e1, d1) and d1 <= _CURVATURE * abs(d0):
            return 1.0, e1, evals
        hi = 1.0
        best: tuple[float, float] | None = (1.0, e1) if ok(1.0, e1, d1) else None
        if math.isfinite(d1) and d1 > 0.0:
            lo, dlo, dhi = 0.0, d0, d1
            for _ in range(_MAX_SECANT):
                width = hi - lo
                a = lo - dlo * width / (dhi - dlo)
                a = min(max(a, lo + 0.05 * width), hi - 0.05 * width)
                e, d = self._trial(a, True)
                evals += 1
                good = ok(a, e, d)
                if good and (best is None or e < best[1]):
                    best = (a, e)
                if good and abs(d) <= _CURVATURE * abs(d0):
                    return a, e, evals
                if good and d < 0.0:
                    lo, dlo = a, d
                elif math.isfinite(d) and d > 0.0:
                    hi, dhi = a, d
                else:
                    break
            if best is not None:
                if best[0] != a:
                    self._trial(best[0], False)
                    evals += 1
                return best[0], best[1], evals
        elif best is not None:
            return 1.0, e1, evals
        alpha = 0.5 * hi
        for _ in range(_MAX_HALVINGS):
            e, _ = self._trial(alpha, False)
            evals += 1
            if ok(alpha, e):
                return alpha, e, evals
            alpha *= 0.5
        return alpha, None, evals

    def contact_forces(self) -> np.ndarray:
        """(C, 3) contact + damping + friction force on each contact point at the end of the last step, N.

        Zero before the first step (and after :meth:`set_state`).
        """
        c = len(self._contact_idx)
        if not self._has_forces or not c or not self._n_planes:
            return np.zeros((c, 3))
        return self._forces.numpy()[:c].astype(np.float64, copy=True)

    def run(self, steps: int, record_every: int = 1, progress: bool = False) -> Trajectory:
        """Step ``steps`` times; record frame 0 (the current state) and every ``record_every``-th step.

        With ``scene.solver.on_failure == "record"``, unconverged steps are flagged in
        ``Trajectory.converged`` and the run goes on from the last iterate.

        Raises:
            ConfigError: bad ``steps`` or ``record_every``.
            SolverError: a step failed and ``on_failure == "raise"``.
        """
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
            raise ConfigError(f"steps must be an integer >= 0, got {steps!r}")
        if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
            raise ConfigError(f"record_every must be an integer >= 1, got {record_every!r}")
        rest = self.mesh.vertices
        disp = [self.positions - rest]
        vels = [self.velocities]
        times = [self.time]
        iterations, residuals, converged, seconds = [], [], [], []
        linear = 0
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=int(steps), desc="full", unit="step", leave=False)
        try:
            for s in range(1, int(steps) + 1):
                its, res = self.step()
                st = self.last_stats
                iterations.append(its)
                residuals.append(res)
                converged.append(st.converged)
                seconds.append(st.seconds)
                linear += st.linear_iterations
                if s % record_every == 0:
                    disp.append(self.positions - rest)
                    vels.append(self.velocities)
                    times.append(self.time)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(newton=its, cg=st.linear_iterations, refresh=False)
        finally:
            if bar is not None:
                bar.close()
        return Trajectory(
            rest_positions=rest,
            tets=self.mesh.tets,
            displacements=np.array(disp),
            velocities=np.array(vels),
            times=np.array(times),
            scene=self.scene,
            iterations=np.array(iterations, dtype=np.int32),
            residuals=np.array(residuals, dtype=np.float64),
            converged=np.array(converged, dtype=bool),
            step_seconds=np.array(seconds, dtype=np.float64),
            info={
                "source": "full",
                "device": self.device,
                "n_vertices": int(self._n),
                "n_tets": int(self.mesh.n_tets),
                "contact_points": int(len(self._contact_idx)),
                "record_every": int(record_every),
                "linear_iterations": int(linear),
                "unconverged_steps": int(len(converged) - int(np.sum(converged))),
            },
        )

    # --- inspection (tests, debugging) -------------------------------------------------
    def _terms_mask(self, terms: str | Iterable[str]) -> int:
        names = ENERGY_TERMS if terms == "all" else ((terms,) if isinstance(terms, str) else tuple(terms))
        mask = 0
        for t in names:
            if t not in ENERGY_TERMS:
                raise ConfigError(f"unknown energy term {t!r}; accepted: 'all' or any of {', '.join(ENERGY_TERMS)}")
            mask |= 1 << ENERGY_TERMS.index(t)
        return mask

    def _at(self, positions: np.ndarray | None) -> Any:
        """Prepare the step from the current state and return the warp array to evaluate at."""
        wp = _warp()
        x_now = self._x.numpy().copy()
        self._begin_step()  # overwrites self._x with x~; restore it
        self._x.assign(wp.array(x_now, dtype=wp.vec3d, device=self.device))
        pos = x_now if positions is None else self._check_field("positions", positions)
        self._x_trial.assign(wp.array(pos, dtype=wp.vec3d, device=self.device))
        return self._x_trial

    def energy(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all") -> float:
        """Incremental potential of a step from the current state, at ``positions`` (default: now), J.

        Elastic energy is measured from the rest state (``Psi(F) - Psi(I)``), which changes
        nothing but the constant.
        """
        x = self._at(positions)
        self._evaluate(x, _MODE_ENERGY, self._terms_mask(terms))
        return self._energy_value()

    def gradient(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all") -> np.ndarray:
        """(n, 3) gradient of :meth:`energy`, N."""
        x = self._at(positions)
        self._evaluate(x, _MODE_GRADIENT, self._terms_mask(terms))
        return self._grad.numpy().astype(np.float64, copy=True)

    def hessian(self, positions: np.ndarray | None = None, terms: str | Iterable[str] = "all", project: bool = True) -> Any:
        """(3n, 3n) ``scipy.sparse.csr_matrix`` Hessian of :meth:`energy` as assembled by Newton.

        With ``project=False`` the elastic part is the exact (unprojected) Hessian.
        """
        import scipy.sparse as sp

        x = self._at(positions)
        self._evaluate(x, _MODE_HESSIAN if project else _MODE_RAW_HESSIAN, self._terms_mask(terms))
        offsets, cols = self._pattern
        vals = self._values.numpy()
        return sp.bsr_matrix((vals, cols, offsets), shape=(3 * self._n, 3 * self._n)).tocsr()
