"""Time-integration bookkeeping (backward Euler and BDF2): inertia term, predicted positions, velocities."""

from __future__ import annotations

import warp as wp

from .device import MODE_ENERGY, MODE_HESSIAN, Assembly, f64, vec3d

__all__ = ['axpy_kernel', 'inertia_kernel', 'predict_kernel', 'velocity_kernel']


@wp.kernel
def inertia_kernel(x: wp.array(dtype=vec3d), x_tilde: wp.array(dtype=vec3d), mass: wp.array(dtype=f64), inv_h2: f64, mode: int, out: Assembly):
    i = wp.tid()
    k = mass[i] * inv_h2
    d = x[i] - x_tilde[i]
    wp.atomic_add(out.energy, i % out.energy.shape[0], f64(0.5) * k * wp.dot(d, d))
    if mode == MODE_ENERGY:
        return
    wp.atomic_add(out.grad, i, k * d)
    if mode >= MODE_HESSIAN:
        wp.atomic_add(out.values, out.diag_slots[i], k * wp.identity(n=3, dtype=f64))


@wp.kernel
def predict_kernel(
    x: wp.array(dtype=vec3d),
    v: wp.array(dtype=vec3d),
    x_prev: wp.array(dtype=vec3d),
    v_prev: wp.array(dtype=vec3d),
    history: f64,
    h: f64,
    gravity: vec3d,
    extrapolate: f64,
    ramp: f64,
    x_now: wp.array(dtype=vec3d),
    x_start: wp.array(dtype=vec3d),
    x_tilde: wp.array(dtype=vec3d),
    x_out: wp.array(dtype=vec3d),
):
    # Anchor x_a = x + history (x - x_prev), v_a likewise, and x~ = x_a + h v_a + h^2 g with the effective
    # step h: backward Euler is history = 0 (x_a = x exactly); BDF2 is history = 1/3 with h = 2/3 of the
    # step, x_a = (4 x_n - x_{n-1}) / 3. x_now keeps x_n (lagged normal forces, restoring a failed step).
    # The Newton iterate starts from x~ + ramp (v - v_prev) - h^2 g with ramp = h^2 / (the real step), i.e.
    # with the acceleration of the previous step, (v - v_prev) / step, instead of gravity (extrapolate = 1),
    # or at x~ (extrapolate = 0).
    i = wp.tid()
    xi = x[i]
    vi = v[i]
    xa = xi + history * (xi - x_prev[i])
    va = vi + history * (vi - v_prev[i])
    xt = xa + h * va + (h * h) * gravity
    x_now[i] = xi
    x_start[i] = xa
    x_tilde[i] = xt
    x_out[i] = xt + extrapolate * (ramp * (vi - v_prev[i]) - (h * h) * gravity)


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

