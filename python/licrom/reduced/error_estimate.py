"""Online error estimate of a reduced run: how far its state is from the full equations.

A reduced simulation satisfies the backward-Euler equations only inside its subspace. At a
small fixed sample of vertices, the full-space residual of the reconstructed state

    ``r_v = m_v (x_t - 2 x_{t-1} + x_{t-2}) / h^2 - m_v g - f_v(x_t)``

(BDF2: ``m_v (x_t - (24 x_{t-1} - 22 x_{t-2} + 8 x_{t-3} - x_{t-4}) / 9) / h'^2`` with
``h' = 2h/3``, :data:`TARGET_WEIGHTS`) (inertia, gravity, elastic force of the vertex's one-ring tets; contact acts only on a
vertex inside a plane, and such a sample is left out of that frame) is zero for the full
solution. Divided by a block of the vertex's own stiffness it becomes a displacement,
``du_v = B_v^-1 r_v`` with ``B_v = K_vv^(2/3) (K_vv + m_v/h'^2 I)^(1/3)`` (``K_vv`` the linear-elastic
block at rest, :data:`INERTIA_EXPONENT`): between the static correction (``K_vv``) and the one a
full-space Jacobi sweep of the step would make (``K_vv + m_v/h'^2``), so that its scale holds from
h = 10 ms down to the converged steps of 0.5-1 ms. The estimate compares it with the body's non-rigid deformation ``u`` (its body-frame
displacement) the way :func:`licrom.analysis.compare.nonrigid_error` compares the reduced run with
the full one, from the run's first contact on:

    ``e(t) = ERROR_SCALE * sqrt(sum_{s<=t} M/M_S sum_v m_v |du_v(s)|^2 / sum_{s<=t} |u(s)|_M^2)``

over every ``stride``-th step s (:func:`residual_stride`, at least :data:`ERROR_STRIDE`; ``M/M_S``: total mass over
the sample's, so the sample stands for the body). It is recorded per frame in ``Trajectory.error_estimate``,
and its last value is the run-level estimate; an :class:`~licrom.errors.AccuracyWarning`
is issued once per run when it passes :data:`ERROR_THRESHOLD`. ``step()`` and
``step_many()`` alone do not compute it: it is a property of a run.

Why a residual at vertices outside the solve: the reduced solver's own residual is zero by
construction (it is projected onto the subspace); the full-space residual sees what the
subspace cannot represent. The sample is spread over the body by farthest-point sampling,
which puts most of it on the surface, and that is where it must be: a smooth deformation the
subspace misses leaves unbalanced traction on the free surface (the natural boundary
condition), while at interior vertices only its divergence shows, smaller by the element
size over the deformation's wavelength. With interior vertices alone, the raw ratio on the
cheese (all 32 of its interior vertices) stayed at 3-4 % for true errors of 38-103 %
(r = 2..8); with the surface included it follows them (13-19 % at r = 2). Samples
inside a plane, now or at the start of the step (friction is lagged), feel contact forces
that are not modelled, and are left out of that frame. (Counting them, with the solvers' contact
and friction force in their residual and its curvature in their block, was measured and not kept:
it ranked POD subspaces better and the defaults' learned models worse, reading a tipped box's clean
runs 4.8x high, docs/results.md section 40.) The sample's basis rows, one-ring shape gradients and
volumes are taken once; an evaluated step costs one product with the basis
rows of the rings' vertices and one pass over the ring tets, both in the core
(``licrom._core.ResidualEstimate``, which also keeps the sample positions of the steps before).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from .. import _core
from ..errors import AccuracyWarning, ConfigError
from ..geometry.mesh import Mesh
from ..geometry.points import farthest_points
from ..scene.scene import Scene
from .cubature_error import CubatureError

__all__ = ["EFFECTIVE_STEP", "ERROR_SCALE", "ERROR_STRIDE", "ERROR_THRESHOLD", "INERTIA_EXPONENT", "MIN_EVALUATIONS",
           "RESIDUAL_SHARE", "RESOLUTION_REACH", "SAMPLE_COUNT", "TARGET_WEIGHTS",
           "ErrorMonitor", "normalising_inverse", "residual_stride", "sample_vertices",
           "warn_estimate", "warn_resolution"]

TARGET_WEIGHTS = {"backward_euler": (2.0, -1.0), "bdf2": (24 / 9, -22 / 9, 8 / 9, -1 / 9)}
"""Each integrator's predicted position ``xt - h'^2 g`` as weights of the positions of the steps before, newest
first (``rust/core/src/integrator.rs``, ``Integrator::target_weights``)."""

EFFECTIVE_STEP = {"backward_euler": 1.0, "bdf2": 2 / 3}
"""Each integrator's effective step ``h'`` over the time step h."""

SAMPLE_COUNT = 48
"""Vertices where the residual is evaluated."""

ERROR_STRIDE = 10
"""Fewest steps between two evaluations of the residual, and the step of a run's first evaluation. The run-level
estimate is a sum over the run, so every tenth step measures it as well as every step, at a tenth of the cost (on the
864-tet cheese at r = 60, every tet cubature: 5 % of the step's work). Where a step is cheap against an evaluation
(few modes, few cubature tets), :func:`residual_stride` takes more steps between them."""

MIN_EVALUATIONS = 20
"""Evaluations of the residual a run of known length gets at least, where :data:`ERROR_STRIDE` allows, so that a short
run's value rests on more than a few (the README's 100-step quickstart, evaluated every 40th step from step 10, read
10.8 %, every 10th 10.2 %, for a true 6.4 %; docs/results.md section 56); a short run's estimate costs little in all."""

RESIDUAL_SHARE = 0.06
"""Share of a reduced run's time the residual may take by :func:`residual_stride`'s model (dimensionless): with the
cubature term's 3 % (:data:`licrom.reduced.cubature_error.COST_SHARE`) and the Python call after every step the
estimate stays within issue 23's 10 % of the steps. Fewer evaluations make the run-level value noisier where the
error is small: on the converged cheese's 19 runs (docs/results.md section 56) 4 % (every 22nd step at r = 250) ranked
them at rho 0.84, 6 % (every 15th) at 0.94 and every 10th step at 0.93, with the same flags."""


def residual_stride(n_cubature: int, k: int) -> int:
    """Steps between two evaluations of the residual so that it costs about :data:`RESIDUAL_SHARE` of the steps, and at
    least :data:`ERROR_STRIDE`, from a cost model fitted to runs on this project's 2-core machine (one thread; the
    run's step times against the extra time of a step that evaluates, with the states recorded before it, in the run,
    where the evaluation finds the caches cold; ``benches/estimate_cost.py`` measures the whole run's share):

    | model (mesh, k, cubature tets) | evaluation | step | model's evaluation, step | stride |
    |---|---|---|---|---|
    | the demo's 864-tet cheese, 18, 73 | 0.043 ms | 0.018 ms | 0.043, 0.018 ms | 40 |
    | the converged 1638-tet cheese, 126, 715 | 0.15 ms | 0.16-0.22 ms | 0.15, 0.14 ms | 19 |
    | the same at 256, 908 | 0.28-0.30 ms | 0.32-0.34 ms | 0.28, 0.33 ms | 15 |

    An evaluation costs a fixed part (the Python calls, one per state recorded) and products with the basis rows of
    the sample's rings, ``k`` wide, three for a damped BDF2 scene (the state and the damping's two before); a step a
    fixed part and products with the cubature's vertex rows, ``K k``. The step's model is fitted to the first and last
    rows and puts the middle one's step low, so that its stride is longer than it needs.
    """
    ratio = (25.0 + 1.0 * k) / (16.2 + 1.35e-3 * n_cubature * k)
    return max(ERROR_STRIDE, math.ceil(ratio / RESIDUAL_SHARE))


INERTIA_EXPONENT = 1.0 / 3.0
"""How much of the one-step inertia ``m/h'^2`` the residual's normalising block takes (dimensionless).

The block is ``K^(1 - a) (K + m/h'^2)^a``: a = 0 is the static stiffness, a = 1 one Jacobi sweep of the step.
At h = 10 ms ``m/h'^2`` is 5-7 % of ``K`` on these meshes and ``a`` hardly matters; at the converged steps of
section 12 (BDF2 at 1 ms, the ball 0.5 ms, with the material's damping) it is 7-20x ``K``, and there, on the 45
validation runs at each step (``experiments/error_estimate_validation.py --converged``), a = 1 read the true error
6.7 times low (median) and a = 0 2.5 times high; a = 1/3 reads it at 1.0 times at both steps with the same
:data:`ERROR_SCALE`. The residual grows as h shrinks for the same error of the run; a third of the inertia keeps
the estimate's scale across time steps."""

ERROR_SCALE = 4.0
"""Factor from the displacement ratio to the non-rigid error (dimensionless).

A vertex's own block sees a smooth missing deformation only at the element scale, so the raw
ratio is low: measured by ``experiments/error_estimate_validation.py`` (body-frame POD(r),
r = 2..60, on the held-out cheese, box and sphere runs of ``body_frame_experiments.py``,
a softer cheese and a finer cheese mesh; 45 runs), the true non-rigid error was 4.1 times
the raw ratio (median; middle half 3.0-5.8 times). With the block of :data:`INERTIA_EXPONENT`,
the estimate over the true error is 1.00 at h = 10 ms (middle half 0.71-1.36) and 1.05 on the
same 45 runs at a converged truth (``--converged``; 0.74-1.39)."""

ERROR_THRESHOLD = 0.10
"""Run-level estimate above which :class:`~licrom.errors.AccuracyWarning` is issued (dimensionless): the 10 % non-rigid
target itself, so that the warning says "this run misses the target".

Judged against the rule "flag every run above 15 % true error, at most one false alarm in five flags" (flagged / above
15 %, false alarms / flags), on the runs whose estimates carry the cubature term (docs/results.md section 50):

| threshold | converged cheese, 19 runs (section 49) | its 9 default runs | demo model, 42 runs (section 48) |
|---|---|---|---|
| 12 % | 4 / 4, 1 / 5 | 0 / 0, 0 / 0 | 24 / 24, 1 / 25 |
| 10 % | 4 / 4, 1 / 5 | 0 / 0, 0 / 0 | 24 / 24, 9 / 33 |
| 8 % | 4 / 4, 5 / 9 | 0 / 0, 4 / 4 | 24 / 24, 12 / 36 |
| 7 % | 4 / 4, 5 / 9 | 0 / 0, 4 / 4 | 24 / 24, 14 / 38 |

It was 7 % (section 29) while the estimate read two kinds of run low: a fit of few cubature tets, whose error lies
inside the subspace where the residual cannot see it (the cubature term now reads it: the naive runs read 1.1-1.4x
their true error, section 49), and the box's tumbles at r = 120 (15.9-30.5 % true read 7.1-9.4 %). Trained at the
defaults' r = 250, the box's tumbles read 2.0-3.6 % for 5.1-23.7 % true (within 3x their noise floors), which no
threshold catches, and on those defaults' 44 runs 7 % and 10 % flag the same 4 of the 5 above 15 % with no false
alarm (section 29). At 7 % the converged cheese's other-mesh runs (7.6-8.0 % true, read 8.3-8.9 %) and the README's
quickstart run (8.1 % true, read 9.0 %) warned of a miss they did not make. What 10 % gives up: on the 45 POD(r)
runs at a converged truth (every tet, so no cubature term) it flags 34 of the 35 above 15 % (7 %: 35), and a chaotic
run reads low at any threshold: a residual sees what the subspace misses, not how far nearby trajectories diverge."""


def normalising_inverse(stiffness: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """(s, 3, 3) inverse of ``K^(1 - a) (K + m/h'^2 I)^a`` (:data:`INERTIA_EXPONENT` ``a``) for each vertex's
    (s, 3, 3) stiffness block ``K`` (N/m) and (s,) one-step inertia ``m/h'^2`` (N/m)."""
    lam, vec = np.linalg.eigh(stiffness)
    scale = lam ** (INERTIA_EXPONENT - 1.0) * (lam + inertia[:, None]) ** -INERTIA_EXPONENT
    return np.einsum("sij,sj,skj->sik", vec, scale, vec)


def sample_vertices(mesh: Mesh, count: int) -> np.ndarray:
    """(s,) ``count`` vertices spread over the body and its surface (farthest-point sampling)."""
    return np.sort(farthest_points(mesh.vertices, count))


class ErrorMonitor:
    """The full-space residual at a fixed vertex sample of a reduced simulation, every few steps of a run.

    Positions of the sample are ``x = c + R (rest + W q)`` (world-frame models: ``c = 0``,
    ``R = I``, ``rest = X``; body-frame models: ``rest = Xbar``). A run calls :meth:`start`,
    then :meth:`after_step` after each step, :meth:`finish` after the last, then :meth:`components`, whose two terms added in quadrature
    (the residual sees the error outside the subspace, the cubature's term the error inside it) are the estimate.

    Args:
        mesh: the simulated mesh.
        values: (n, 3, k) basis values at every vertex.
        rest: (n, 3) the rest term of the positions (``X`` or ``Xbar``), m.
        scene: the scene (material, gravity, dt, integrator, planes).
        count: sample size (all vertices on meshes with fewer).
        stride: steps between two evaluations, an integer >= 1 (the first at step ``min(stride, ERROR_STRIDE)``, so
            that every run of that many steps has one).
        cubature_error: the cubature's term (:mod:`licrom.reduced.cubature_error`), evaluated with the residual about
            every ``cubature_error.stride`` steps and at the end of a run; None: the residual alone.

    Attributes:
        vertices: (s,) the sample vertices.
        near: (u,) the corners of their one-ring tets (the samples included).
        stride: steps between two evaluations.

    Raises:
        ConfigError: ``count`` or ``stride`` not an integer >= 1.
    """

    def __init__(self, mesh: Mesh, values: np.ndarray, rest: np.ndarray, scene: Scene, count: int = SAMPLE_COUNT,
                 stride: int = ERROR_STRIDE, cubature_error: CubatureError | None = None) -> None:
        for name, value in (("sample count", count), ("stride", stride)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ConfigError(f"the error estimate's {name} must be an integer >= 1, got {value!r}")
        self.vertices = sample_vertices(mesh, min(int(count), mesh.n_vertices))
        self.stride = int(stride)
        k = values.shape[2]
        tets = mesh.tets
        owner, ring = np.nonzero((tets[None] == self.vertices[:, None, None]).any(axis=2))  # (sample, tet) of each ring entry
        self.near, local = np.unique(np.concatenate([tets[ring].ravel(), self.vertices]), return_inverse=True)
        corners = local[: 4 * len(ring)].reshape(-1, 4)
        self._own = local[4 * len(ring):]
        own_corner = (tets[ring] == self.vertices[owner, None]).argmax(axis=1)
        grads = mesh.shape_gradients[ring]  # (T, 4, 3)
        own_grad = grads[np.arange(len(ring)), own_corner]
        volumes = mesh.rest_volumes[ring]
        self._forces = _core.VertexForces(len(self.near), len(self.vertices), corners, np.ascontiguousarray(grads), volumes, owner,
                                          own_corner, *scene.material.snh_parameters)
        self._sample_basis = np.ascontiguousarray(values[self.vertices].reshape(3 * len(self.vertices), k))
        self._sample_rest = np.ascontiguousarray(rest[self.vertices])
        masses = mesh.vertex_masses(scene.material.density)
        self._m = masses[self.vertices]
        self._total_mass = float(masses.sum())
        h = scene.dt * EFFECTIVE_STEP[scene.integrator]
        self._target = np.array(TARGET_WEIGHTS[scene.integrator])
        mu, lam = scene.material.lame
        gg = own_grad[:, :, None] * own_grad[:, None, :]
        block = volumes[:, None, None] * (mu * np.einsum("tkk->t", gg)[:, None, None] * np.eye(3) + (mu + lam) * gg)
        stiffness = np.zeros((len(self.vertices), 3, 3))
        np.add.at(stiffness, owner, block)
        normaliser = normalising_inverse(stiffness, self._m / h**2)
        # The residual in the core: as a dozen numpy calls after each solver step it cost a third of a step.
        self._residual = _core.ResidualEstimate(self._forces, np.ascontiguousarray(values[self.near]), np.ascontiguousarray(rest[self.near]),
                                                self._own, self._m, normaliser, np.asarray(scene.gravity, dtype=np.float64),
                                                np.ascontiguousarray(scene.plane_array()[:, :4]), self._target, h, self._total_mass,
                                                scene.material.viscosity)
        self._cubature_error = cubature_error
        self._step = 0
        self._run_stride = self.stride  # this run's (start)
        self._next = min(self.stride, ERROR_STRIDE)  # the step of the next evaluation
        # (step, q, deformation) of an evaluation begun and not finished
        self._pending: tuple[int, np.ndarray, Callable[[np.ndarray], float]] | None = None
        self._evaluations: list[tuple[int, float, float]] = []
        self._cubature_evaluations: list[tuple[int, float, float]] = []

    def sample_positions(self, q: np.ndarray, center: np.ndarray | None = None, rotation: np.ndarray | None = None) -> np.ndarray:
        """(s, 3) world positions of the sample vertices, m."""
        y = self._sample_rest + (self._sample_basis @ q).reshape(-1, 3)
        return y if rotation is None else center + y @ rotation.T

    def elastic_forces(self, near_positions: np.ndarray) -> np.ndarray:
        """(s, 3) elastic force ``-dE/dx_v`` on each sample vertex, N, from (u, 3) positions of
        the vertices ``near`` (the samples' one-ring tets' corners)."""
        return self._forces.forces(near_positions)

    @property
    def history_length(self) -> int:
        """States the residual reads before the step: 2 (backward Euler) or 4 (BDF2)."""
        return len(self._target)

    def start(self, history: list[np.ndarray], steps: int | None = None) -> None:
        """Begin a run from the (s, 3) sample positions of the last :attr:`history_length` states, oldest first
        (the current state last); ``steps``: the run's length, if known, which shortens the stride to give the run
        about :data:`MIN_EVALUATIONS` evaluations (not below :data:`ERROR_STRIDE`)."""
        if len(history) != self.history_length:
            raise ConfigError(f"the error estimate needs {self.history_length} states to start from, got {len(history)}")
        self._residual.start(np.stack(history))
        self._step = 0
        self._run_stride = self.stride if steps is None else min(self.stride, max(ERROR_STRIDE, steps // MIN_EVALUATIONS))
        self._next = min(self._run_stride, ERROR_STRIDE)
        self._pending = None
        self._evaluations = []
        self._cubature_evaluations = []

    def after_step(self, state: Callable[[], tuple[np.ndarray, np.ndarray | None, np.ndarray | None]],
                   deformation: Callable[[np.ndarray], float]) -> None:
        """Count a step; keep the sample positions of the steps before an evaluation that the residual
        reads (:attr:`history_length`), and evaluate every ``stride``-th step (the first at ``min(stride, ERROR_STRIDE)``):
        begun on that step (the state's positions) and finished on the next (its forces, residual and deformation), so
        that no step carries the whole evaluation (docs/results.md section 58).

        Args:
            state: ``(q, c, R)`` now (``c``, ``R`` None for world-frame models); called only when needed.
            deformation: ``|u|_M^2`` (kg m^2) of the non-rigid deformation of the body at ``q``.
        """
        self._step += 1
        wait = self._next - self._step
        if wait > self.history_length and self._pending is None:  # most steps, as small models' steps take microseconds
            return
        if self._pending is not None:
            self._finish_evaluation()
            if wait > self.history_length:
                return
        q, center, rotation = state()
        if wait:
            self._residual.record(q, center, rotation, wait)
            return
        self._next += self._run_stride
        cubature = self._cubature_error
        if cubature is not None and (len(self._evaluations) + 1) % max(1, round(cubature.stride / self._run_stride)) == 0:
            self._cubature_evaluations.append((self._step, cubature.displacement(q), deformation(q)))
        self._residual.prepare(q, center, rotation)
        self._pending = (self._step, q, deformation)

    def _finish_evaluation(self) -> None:
        step, q, deformation = self._pending
        self._pending = None
        self._evaluations.append((step, self._residual.finish(), deformation(q)))

    def finish(self, q: np.ndarray, deformation: Callable[[np.ndarray], float]) -> None:
        """End a run at ``q``: the cubature's term once more at the last step, unless it was evaluated there, so that
        a run shorter than its stride has a value (one evaluation a run); an evaluation begun on the last step is
        finished."""
        if self._pending is not None:
            self._finish_evaluation()
        cubature = self._cubature_error
        if cubature is not None and self._step and (not self._cubature_evaluations or self._cubature_evaluations[-1][0] != self._step):
            self._cubature_evaluations.append((self._step, cubature.displacement(q), deformation(q)))

    def components(self, frame_steps: np.ndarray, start_step: int | None) -> dict[str, np.ndarray]:
        """(f,) running value of each term of the estimate at each frame, from the evaluations since the last
        :meth:`start`: ``"residual"``, ``ERROR_SCALE * sqrt(sum M/M_S sum_v m_v |du_v|^2 / sum |u|_M^2)``, and
        ``"cubature"``, ``sqrt(sum |W dq|_M^2 / sum |u|_M^2)`` (:mod:`licrom.reduced.cubature_error`; zero without
        that term), each over its evaluated steps from ``start_step`` (the first contact; None: every step) up to each
        frame's step; zero where none is counted yet or nothing has deformed.

        Args:
            frame_steps: (f,) the step of each frame (0 for the state the run started from).
            start_step: the first step counted.
        """
        return {"residual": ERROR_SCALE * _running_ratio(self._evaluations, frame_steps, start_step),
                "cubature": _running_ratio(self._cubature_evaluations, frame_steps, start_step)}


def _running_ratio(evaluations: list[tuple[int, float, float]], frame_steps: np.ndarray, start_step: int | None) -> np.ndarray:
    """(f,) ``sqrt(sum error / sum size)`` of the ``(step, error, size)`` evaluations from ``start_step`` up to each
    frame's step; zero where none is counted yet or the sizes sum to zero."""
    out = np.zeros(len(frame_steps))
    if not evaluations:
        return out
    steps, error, size = (np.array(a) for a in zip(*evaluations))
    keep = steps >= (0 if start_step is None else start_step)
    if not keep.any():  # every evaluation before the first contact (a run recorded at few frames)
        return out
    steps, num, den = steps[keep], np.cumsum(error[keep]), np.cumsum(size[keep])
    last = np.searchsorted(steps, frame_steps, side="right") - 1
    ok = (last >= 0) & (den[last] > 0)
    out[ok] = np.sqrt(num[last[ok]] / den[last[ok]])
    return out


RESOLUTION_REACH = 8.0
"""How many times more (or fewer) tets than its training mesh a model's mesh may have before a simulation warns that
its online estimate is unchecked there (dimensionless). Checked on the converged cheese's r = 250 model: on meshes of
0.53x, 1.7x and 4.2x the training mesh's tets it read 8-26 % for 7-23 %, flagging every run above 15 %; on one of 73x,
6-9 % for 13-38 %, flagging none (docs/results.md sections 56, 60 and 61)."""


def warn_resolution(training: Mesh, mesh: Mesh, what: str, stacklevel: int = 3) -> None:
    """Warn (:class:`~licrom.errors.AccuracyWarning`) where ``mesh`` has more than :data:`RESOLUTION_REACH` times more
    or fewer tets than ``training``, the mesh the model was trained on: there the estimate may read low."""
    ratio = mesh.n_tets / training.n_tets
    if max(ratio, 1.0 / ratio) > RESOLUTION_REACH:
        warnings.warn(
            f"{what}: the model was trained on {training.n_tets} tets and runs on {mesh.n_tets} ({ratio:.3g}x); its online "
            f"error estimate is checked within {RESOLUTION_REACH:g}x of the training mesh's tets (on a mesh 73x finer it read "
            "6-9 % for errors of 13-38 %: docs/results.md section 60): compare with a full run on this mesh "
            "(licrom.compare) before relying on Trajectory.error_estimate",
            AccuracyWarning,
            stacklevel=stacklevel,
        )


def warn_estimate(estimate: np.ndarray, what: str, stacklevel: int = 3, terms: dict[str, float] | None = None) -> None:
    """Warn (:class:`~licrom.errors.AccuracyWarning`) once when the run-level estimate (the last
    frame's) passes :data:`ERROR_THRESHOLD`; ``stacklevel`` as in :func:`warnings.warn` (3: the caller's caller).
    ``terms``: the run-level :meth:`ErrorMonitor.components`, named in the message with the remedy of the larger."""
    if len(estimate) and estimate[-1] > ERROR_THRESHOLD:
        parts, cause = "", "the subspace misses this motion; use more modes, or retrain with runs like this scene"
        if terms is not None:
            parts = f" (outside the subspace {100 * terms['residual']:.3g} %, the cubature's {100 * terms['cubature']:.3g} %)"
            if terms["cubature"] > terms["residual"]:
                cause = "the cubature misintegrates the subspace's forces; use more cubature tets (cubature='full' is exact) or refit it"
        warnings.warn(
            f"{what}: estimated non-rigid error {100 * estimate[-1]:.3g} %{parts} exceeds the threshold "
            f"{100 * ERROR_THRESHOLD:.0f} % (Trajectory.error_estimate, licrom.reduced.error_estimate): {cause}",
            AccuracyWarning,
            stacklevel=stacklevel,
        )
