"""Contact and friction per contact point: normal penalty, normal damping and the implicit Coulomb friction
dissipation potential, with the normal force lagged from the start of the step.

The same model as ``rust/core/src/contact.rs`` (the reduced models); see ``docs/design.md``."""

from __future__ import annotations

import warp as wp

from .device import (
    MODE_ENERGY,
    MODE_FORCES,
    MODE_HESSIAN,
    f64,
    mat33d,
    vec3d,
)

__all__ = ['contact_kernel', 'lagged_normal_kernel', 'stick_kernel']


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
    if mode == MODE_FORCES:
        forces[j] = -gj
        return
    wp.atomic_add(energy, j % energy.shape[0], e)
    if mode == MODE_ENERGY:
        return
    wp.atomic_add(grad, vi, gj)
    if mode >= MODE_HESSIAN:
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

