"""Full-space ground truth: implicit FEM with penalty contact and implicit Coulomb friction (warp).

Each time step minimises the incremental potential of backward Euler,

    E(x) = 1/(2 h^2) (x - x~)^T M (x - x~) + sum_t V_t Psi(F_t(x)) + sum_{j,p} C_jp(x_j),
    x~ = x_t + h v_t + h^2 g,                 v_{t+1} = (x_{t+1} - x_t) / h,

or, with ``scene.integrator == "bdf2"``, of BDF2, which is the same minimisation with the anchor
``x_a = (4 x_t - x_{t-1}) / 3`` in place of ``x_t``, ``v_a = (4 v_t - v_{t-1}) / 3`` in place of ``v_t`` and
``h' = 2h/3`` in place of ``h`` everywhere (inertia, friction and damping velocities ``(x - x_a) / h'``,
the velocity update, the convergence measure); after construction or ``set_state`` the state one step back is
that of a free fall (``x_t - h v_t + h^2 g / 2``, ``v_t - h g``), as in the reduced simulations. The normal force of friction is lagged from ``x_t`` in both. With
stable Neo-Hookean elasticity and, at each contact point j and plane p, a
normal penalty, optional normal damping and a friction dissipation potential whose
gradient is the force ``|f_t| = min(k_f |v_t|, mu f_n)`` with the normal force
``f_n`` lagged from the start of the step (see ``docs/design.md`` and :class:`FullSim`).

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
  (``g`` on the first step, where this is ``x~``; for BDF2 ``x_a + h' v_a + h'^2 a``). The minimiser does not depend on it;
  sticking contacts start in the stick region, so Newton needs far fewer iterations.

A step has converged when the mass-weighted RMS length of the Newton step divided by ``h`` (``h'``
for BDF2: it is the error of the velocity), ``sqrt(dx^T M dx / m_total) / h``, is below ``scene.solver.tolerance`` (m/s): the measure the
reduced solver uses, invariant under a change of basis. All kernels run in float64, on the
CPU or on a CUDA device, with the same code; by default on the first CUDA device when warp sees
one, else on the CPU (``FullSim.device`` says which, and the ``licrom.full`` logger tells it at
INFO level).

Where things live: :mod:`.elastic` (stable Neo-Hookean per tet), :mod:`.contact` (penalty,
damping and friction per contact point: the warp twin of ``rust/core/src/contact.rs``),
:mod:`.inertia` (time-integration bookkeeping), :mod:`.pcg` (the block-sparse Hessian and its
solve), :mod:`.device` (devices and evaluation modes) and :mod:`.sim` (:class:`FullSim`, the
Newton iteration, whose line search is the reduced solvers' own, ``licrom._core.line_search``).
"""

from .device import ACCEPTED_DEVICES, check_device_name, resolve_device
from .sim import ENERGY_TERMS, FullSim, StepStats

__all__ = ["ACCEPTED_DEVICES", "ENERGY_TERMS", "FullSim", "StepStats", "check_device_name", "resolve_device"]
