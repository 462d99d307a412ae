"""Backward-Euler bookkeeping: inertia term, predicted positions, velocities."""

from __future__ import annotations

import warp as wp

from .device import (
    MODE_ENERGY,
    MODE_HESSIAN,
    f64,
    mat33d,
    vec3d,
)

__all__ = ['axpy_kernel', 'inertia_kernel', 'predict_kernel', 'velocity_kernel']


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
    if mode == MODE_ENERGY:
        return
    wp.atomic_add(grad, i, k * d)
    if mode >= MODE_HESSIAN:
        wp.atomic_add(values, diag_slots[i], k * wp.identity(n=3, dtype=f64))



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

