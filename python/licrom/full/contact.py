"""Contact and friction per contact point: normal penalty, normal damping and the implicit Coulomb friction
dissipation potential, with the normal force lagged from the start of the step.

The same model as ``rust/core/src/contact.rs`` (the reduced models); see ``docs/design.md``."""

from __future__ import annotations

import warp as wp

from .device import MODE_ENERGY, MODE_FORCES, MODE_HESSIAN, Assembly, f64, mat33d, vec3d

__all__ = ['Contacts', 'contact_kernel', 'lagged_normal_kernel', 'stick_kernel']


@wp.struct
class Contacts:
    """The contact model of a simulation: the contact points (vertex index and boundary area of each), the
    planes (unit normal, offset and friction coefficient of each), the normal force of each point on each
    plane lagged from the start of the step (``fn_lag[j, p]``, written by :func:`lagged_normal_kernel`) and
    the scene's normal stiffness ``kn``, normal damping ``kd`` and friction stiffness ``kf``."""

    points: wp.array(dtype=wp.int32)
    areas: wp.array(dtype=f64)
    normals: wp.array(dtype=vec3d)
    offsets: wp.array(dtype=f64)
    frictions: wp.array(dtype=f64)
    fn_lag: wp.array2d(dtype=f64)
    kn: f64
    kd: f64
    kf: f64


@wp.func
def gap(c: Contacts, p: int, x: vec3d):
    """Signed distance of ``x`` to plane ``p``, negative inside."""
    return wp.dot(c.normals[p], x) + c.offsets[p]


@wp.func
def tangential(n: vec3d, v: vec3d):
    """The part of ``v`` along the plane of unit normal ``n``."""
    return v - wp.dot(n, v) * n


@wp.func
def stick_terms(stick: f64, delta: vec3d, T: mat33d):
    """Friction gradient and Hessian of a sticking point with slip ``delta`` (``stick = a k_f / h``, ``T`` the tangential projector)."""
    return stick * delta, stick * T


@wp.func
def slip_terms(cap: f64, tdir: vec3d, slip: f64, T: mat33d):
    """Friction gradient and Hessian of a slipping point: the force ``cap = mu f_n`` along the slip direction ``tdir``, slip length ``slip``."""
    return cap * tdir, (cap / slip) * (T - wp.outer(tdir, tdir))


@wp.kernel
def contact_kernel(x: wp.array(dtype=vec3d), x_start: wp.array(dtype=vec3d), c: Contacts, h: f64, terms: int, mode: int, out: Assembly, forces: wp.array(dtype=vec3d)):
    # mode 0 energy, 1 +gradient, 2/3 +Hessian, 4 force only (written to forces[j]).
    j = wp.tid()
    a = c.areas[j]
    vi = c.points[j]
    xj = x[vi]
    dx = xj - x_start[vi]
    zero = f64(0.0)
    e = zero
    gj = vec3d()
    hj = mat33d()
    for p in range(c.normals.shape[0]):
        n = c.normals[p]
        g = gap(c, p, xj)
        if (terms & 1) != 0 and g < zero:
            e += f64(0.5) * a * c.kn * g * g
            gj += (a * c.kn * g) * n
            hj += (a * c.kn) * wp.outer(n, n)
        fn = c.fn_lag[j, p]
        if fn > zero:
            dn = wp.dot(n, dx)
            if (terms & 2) != 0 and dn < zero and c.kd > zero:
                # a k_d h / 2 min(v_n, 0)^2 with v_n = dn / h
                e += f64(0.5) * a * c.kd * dn * dn / h
                gj += (a * c.kd * dn / h) * n
                hj += (a * c.kd / h) * wp.outer(n, n)
            cap = c.frictions[p] * fn
            if (terms & 4) != 0 and cap > zero:
                T = wp.identity(n=3, dtype=f64) - wp.outer(n, n)
                delta = tangential(n, dx)
                slip = wp.length(delta)
                stick = a * c.kf / h
                if stick * slip <= cap:
                    e += f64(0.5) * stick * slip * slip
                    gf, hf = stick_terms(stick, delta, T)
                    gj += gf
                    hj += hf
                else:
                    e += cap * slip - f64(0.5) * cap * cap / stick
                    gf, hf = slip_terms(cap, delta / slip, slip, T)
                    gj += gf
                    hj += hf
    if mode == MODE_FORCES:
        forces[j] = -gj
        return
    wp.atomic_add(out.energy, j % out.energy.shape[0], e)
    if mode == MODE_ENERGY:
        return
    wp.atomic_add(out.grad, vi, gj)
    if mode >= MODE_HESSIAN:
        wp.atomic_add(out.values, out.diag_slots[vi], hj)


@wp.kernel
def stick_kernel(x: wp.array(dtype=vec3d), x_start: wp.array(dtype=vec3d), y: wp.array(dtype=vec3d), c: Contacts, h: f64, out: Assembly,
                 rhs: wp.array(dtype=vec3d), count: wp.array(dtype=wp.int32)):
    # A slipping contact point whose Newton step (-y) would carry its slip through the
    # stick region is modelled as sticking for a second solve: its slip Hessian and
    # friction gradient are replaced by the stick ones, so the step brings its slip to ~0.
    j = wp.tid()
    a = c.areas[j]
    vi = c.points[j]
    dx = x[vi] - x_start[vi]
    yj = y[vi]
    zero = f64(0.0)
    for p in range(c.normals.shape[0]):
        n = c.normals[p]
        cap = c.frictions[p] * c.fn_lag[j, p]
        if cap > zero and a > zero:
            delta = tangential(n, dx)
            slip = wp.length(delta)
            stick = a * c.kf / h
            if stick * slip > cap:
                tdir = delta / slip
                moved = delta - tangential(n, yj)
                if wp.dot(tdir, moved) < cap / stick:
                    T = wp.identity(n=3, dtype=f64) - wp.outer(n, n)
                    g_stick, h_stick = stick_terms(stick, delta, T)
                    g_slip, h_slip = slip_terms(cap, tdir, slip, T)
                    wp.atomic_add(out.values, out.diag_slots[vi], h_stick - h_slip)
                    wp.atomic_add(rhs, vi, g_stick - g_slip)
                    wp.atomic_add(count, 0, 1)


@wp.kernel
def lagged_normal_kernel(x: wp.array(dtype=vec3d), c: Contacts):
    j, p = wp.tid()
    c.fn_lag[j, p] = c.areas[j] * c.kn * wp.max(-gap(c, p, x[c.points[j]]), f64(0.0))
