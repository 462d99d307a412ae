"""What every reduced simulation shares: its sampling of the mesh, a step and its failure rule, batches.

:class:`ReducedSim` is the base class of the world-frame :class:`licrom.reduced.world.WorldFrameSim`
and the body-frame :class:`licrom.reduced.body.BodyFrameSim`: each holds its native core
(``_core``, a ``licrom._core.ReducedCore`` or ``BodyFrameCore``) and steps it the same way.
Calling ``ReducedSim(...)`` itself gives one of the two, chosen by
:func:`licrom.reduced.factory.reduced_sim`, so ``isinstance(sim, ReducedSim)`` holds for either.
:func:`sampling` picks the cubature and contact points of either, :func:`step_many` steps
many of either kind in one call, spread over Rust threads without the GIL.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .. import _core
from ..errors import ConfigError, LicromWarning, SolverError
from ..geometry.mesh import Mesh
from ..records.trajectory import DeferredFrames, Trajectory
from ..scene.scene import Scene
from ..stepping import RunRecord, check_field, check_run_arguments
from ..subspace.basis import vertex_strain_form
from ..subspace.cubature import ContactPoints, Cubature
from ..validity import CONTACT_TOLERANCE, cubature_min_det, first_touch, penetration, warn_frames, with_steps
from .error_estimate import ErrorMonitor, warn_estimate, warn_resolution

__all__ = ["CUBATURES", "ReducedSim", "mesh_and_scene", "native_inputs", "sampling", "step_many", "use_second_thread"]

_DEFAULT_CUBATURE_POINTS = 1000

# Python ints are at most this in the native core (a signed 64-bit integer).
_MAX_INT = 2**63 - 1
# Bytes step_many holds per step and simulation for its results (native record, Python objects, arrays), an upper estimate.
_STEP_RESULT_BYTES = 160


def _max_batch_steps(n_sims: int) -> int:
    """The most steps one step_many call can record for ``n_sims`` simulations within this machine's memory."""
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):
        memory = 2**40
    return min(_MAX_INT, memory // (_STEP_RESULT_BYTES * max(n_sims, 1)))


def use_second_thread(on: bool) -> None:
    """Let each reduced step put half of its large products on a second core (the default where there are two or more).

    The products of the basis rows with the coordinates (and back) are split by their outputs, so a step is the same,
    bit for bit, with or without the second thread; at r = 250 it takes about 30 % less time (docs/results.md
    section 66). Turn it off where the cores are taken already: several processes stepping at once, or your own
    threads. :func:`step_many` keeps each simulation's products on the thread that steps it.

    Args:
        on: True to allow the second thread, False to step on the calling thread alone.

    Raises:
        ConfigError: ``on`` is not a bool.
    """
    if not isinstance(on, (bool, np.bool_)):
        raise ConfigError(f"on must be True or False, got {on!r}")
    _core.set_second_thread(bool(on))


def step_many(sims: Sequence[Any], steps: int = 1, threads: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step many independent reduced simulations at once, spread over cores (Rust threads, no GIL).

    Each simulation (any :class:`ReducedSim`: a :class:`~licrom.reduced.world.WorldFrameSim` or a :class:`~licrom.reduced.body.BodyFrameSim`,
    of any models, both kinds in one call if need be) takes ``steps`` steps exactly as a loop
    of ``step_or_record`` would: the states are the same, bit for bit, for any ``threads``.
    A failed step follows the simulation's ``scene.solver.on_failure``: ``"record"`` goes on
    from the last iterate; ``"raise"`` stops that simulation at the start of the failed step,
    the others take all their steps, and then the first failure is raised.

    Args:
        sims: the simulations, each at most once.
        steps: steps of each simulation, an integer >= 0 whose per-step results fit in memory.
        threads: threads to spread the simulations over, 1..2**63 - 1 (default: every core).

    Returns:
        ``(iterations, residuals, converged)``, each of shape ``(len(sims), steps)``.

    Raises:
        ConfigError: a simulation given twice or not a reduced simulation, bad ``steps`` or ``threads``.
        ConcurrencyError: a simulation is busy in another thread (named ``sims[i]``).
        SolverError: a step failed in a simulation with ``on_failure == "raise"``; the message
            names it (``sims[i]``) and its step.
    """
    steps, _ = check_run_arguments(steps, 1)
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                or not 1 <= threads <= _MAX_INT):
        raise ConfigError(f"threads must be None (every core) or an integer in 1..{_MAX_INT} (2**63 - 1), got {threads!r}")
    try:
        sims = list(sims)
    except TypeError:
        raise ConfigError(f"sims must be a sequence of ReducedSim or BodyFrameSim objects, got {type(sims).__name__}") from None
    most = _max_batch_steps(len(sims))
    if steps > most:
        raise ConfigError(f"steps must be an integer in 0..{most} for {len(sims)} simulation(s), got {steps!r}: the "
                          f"per-step results ({_STEP_RESULT_BYTES} bytes a step and simulation) must fit in this "
                          f"machine's memory; step in chunks")
    for i, sim in enumerate(sims):
        if not isinstance(getattr(sim, "_core", None), (_core.ReducedCore, _core.BodyFrameCore)):
            raise ConfigError(f"sims[{i}] must be a ReducedSim or BodyFrameSim, got {type(sim).__name__}")
    outcomes = _core.step_many([sim._core for sim in sims], steps, None if threads is None else int(threads),
                               [sim.scene.solver.on_failure == "record" for sim in sims])
    failure = None
    for i, (sim, (iterations, _, _, err)) in enumerate(zip(sims, outcomes)):
        for _ in iterations:  # one addition per step, as step() does
            sim.time += sim.scene.dt
        if err is not None and failure is None:
            failure = (i, len(iterations), err)
    if failure is not None:
        i, k, err = failure
        message = f"sims[{i}], at its step {k + 1} of {steps}: {err}"
        if isinstance(err, SolverError):
            raise SolverError(message, iterations=err.iterations, residual=err.residual, step_index=k) from err
        raise type(err)(message) from err
    return (np.array([o[0] for o in outcomes], dtype=np.int64).reshape(len(sims), steps),
            np.array([o[1] for o in outcomes], dtype=np.float64).reshape(len(sims), steps),
            np.array([o[2] for o in outcomes], dtype=bool).reshape(len(sims), steps))


CUBATURES = ("fitted", "naive", "full")
"""Cubatures by name: the model's fitted one (:meth:`licrom.Model.cubature_for`), the report's naive
random tets (:meth:`Cubature.naive`, 1000 tets) and every tet (:meth:`Cubature.full`)."""


def _model_behind(basis: Any) -> Any:
    """The trained model behind ``basis`` (itself, or a BodyFrameBasis' ``learned``), or None."""
    return next((o for o in (basis, getattr(basis, "learned", None)) if callable(getattr(o, "cubature_for", None))), None)


def warn_off_resolution(basis: Any, mesh: Mesh, what: str) -> None:
    """:func:`~licrom.reduced.error_estimate.warn_resolution` where ``basis`` is (or holds) a trained model run on a mesh
    other than its own."""
    model = _model_behind(basis)
    if model is not None and model.mesh is not mesh:
        warn_resolution(model.mesh, mesh, what, stacklevel=5)


def _fitted_cubature(basis: Any, mesh: Mesh) -> Cubature | None:
    """The fitted cubature on ``mesh`` of the model behind ``basis``, if it has one."""
    model = _model_behind(basis)
    return None if model is None else model.cubature_for(mesh)


def mesh_and_scene(who: str, mesh: Mesh | None, scene: Scene | None, basis: Any, mesh_from: str, scene_from: Sequence[Any]) -> tuple[Mesh, Scene]:
    """The mesh and scene a reduced simulation ``who`` runs: those given, else the basis' ``mesh`` and the first
    ``default_scene`` stored by one of ``scene_from`` (the basis, or also the model behind it).

    Raises:
        ConfigError: no mesh or scene given or stored (the message says to pass one or to use ``mesh_from``,
            what stores a mesh), or a scene that is not a :class:`~licrom.Scene`.
    """
    if mesh is None:
        mesh = getattr(basis, "mesh", None)
        if mesh is None:
            raise ConfigError(f"{who} needs a mesh: pass mesh=... or {mesh_from} that stores one")
    if scene is None:
        scene = next((s for s in (getattr(o, "default_scene", None) for o in scene_from) if s is not None), None)
        if scene is None:
            raise ConfigError(f"{who} needs a scene: pass scene=... or a trained model that stores one")
    if not isinstance(scene, Scene):
        raise ConfigError(f"scene must be a licrom.Scene, got {type(scene).__name__}")
    return mesh, scene


def sampling(mesh: Mesh, cubature: Cubature | str | None, contact_points: ContactPoints | None, basis: Any = None) -> tuple[Cubature, ContactPoints]:
    """The reduced simulations' cubature and contact points, checked against the mesh.

    ``cubature`` is a :class:`Cubature`, a name of :data:`CUBATURES`, or None: the fitted
    cubature of the model behind ``basis`` when it has one (models trained since format 3),
    else the naive scheme with 1000 tets (a :class:`~licrom.errors.LicromWarning` says so for
    a model without one). Contact points default to :meth:`ContactPoints.default`.

    Raises:
        ConfigError: an unknown name, ``"fitted"`` for a basis without a fitted cubature, or
            tets / vertices that do not belong to ``mesh``.
    """
    if cubature is None or isinstance(cubature, str):
        if cubature is not None and cubature not in CUBATURES:
            raise ConfigError(f"cubature must be a licrom.Cubature or one of {CUBATURES}, got {cubature!r}")
        fitted = _fitted_cubature(basis, mesh) if cubature in (None, "fitted") else None
        if cubature == "fitted" and fitted is None:
            raise ConfigError("cubature='fitted' needs a trained model that stores a fitted cubature (format version 3); "
                              "fit one with licrom.Cubature.for_model(model, runs)")
        if cubature is None and fitted is None and _model_behind(basis) is not None:
            warnings.warn("this model stores no fitted cubature (saved before model format 3): using "
                          f"{_DEFAULT_CUBATURE_POINTS} naive random tets, which can double the error; fit one with "
                          "licrom.Cubature.for_model(model, runs) or retrain", LicromWarning, stacklevel=3)
        cubature = fitted if fitted is not None else Cubature.full(mesh) if cubature == "full" else Cubature.naive(mesh, _DEFAULT_CUBATURE_POINTS)
    if not isinstance(cubature, Cubature):
        raise ConfigError(f"cubature must be a licrom.Cubature or one of {CUBATURES}, got {type(cubature).__name__}")
    contact_points = contact_points if contact_points is not None else ContactPoints.default(mesh)
    if not isinstance(contact_points, ContactPoints):
        raise ConfigError(f"contact_points must be a licrom.subspace.cubature.ContactPoints or None, got {type(contact_points).__name__}")
    if cubature.count and (int(cubature.tets.max()) >= mesh.n_tets or int(cubature.tets.min()) < 0):
        raise ConfigError(f"cubature tets do not belong to this mesh (index out of range: accepted 0 to {mesh.n_tets - 1})")
    if contact_points.count and (int(contact_points.indices.max()) >= mesh.n_vertices or int(contact_points.indices.min()) < 0):
        raise ConfigError("contact points do not belong to this mesh (index out of range: accepted 0 to "
                          f"{mesh.n_vertices - 1})")
    return cubature, contact_points


def native_inputs(sim: ReducedSim, strain: str, contact_rest: np.ndarray) -> dict[str, Any]:
    """The keyword arguments both native systems (``ReducedCore``, ``BodyFrameCore``) take alike,
    read by one reader in the bindings: the elastic cubature term of ``sim``'s strain Jacobians
    (``sim._jacobians``), its contact points with their rest positions ``contact_rest`` (the mesh's,
    or the body frame's), and the scene's contact and time stepping."""
    scene, idx = sim.scene, sim.contact_points.indices
    mu, lam = scene.material.snh_parameters
    return {
        "cubature_jacobians": sim._jacobians,
        "cubature_weights": np.ascontiguousarray(sim.cubature.weights, dtype=np.float64),
        "mu": mu,
        "lam": lam,
        "contact_basis": np.ascontiguousarray(sim._values[idx]),
        "contact_rest": np.ascontiguousarray(contact_rest[idx]),
        "contact_areas": np.ascontiguousarray(sim.contact_points.areas, dtype=np.float64),
        "planes": scene.plane_array(),
        "normal_stiffness": scene.contact.normal_stiffness,
        "normal_damping": scene.contact.normal_damping,
        "friction_stiffness": scene.contact.friction_stiffness,
        "dt": scene.dt,
        "tolerance": scene.solver.reduced_tolerance,
        "max_iterations": scene.solver.max_iterations,
        "integrator": scene.integrator,
        "viscosity": scene.material.viscosity,
        **vertex_strain_form(sim.mesh, sim.cubature.tets, strain, sim._values),
    }


class _CallPicksTheFrame(type):
    """Metaclass of :class:`ReducedSim`: calling the base class itself calls the factory.

    ``ReducedSim(...)`` returns :func:`licrom.reduced.factory.reduced_sim` of the same
    arguments (an object built by its own class, initialised once); calling a subclass
    (``WorldFrameSim(...)``, ``BodyFrameSim(...)``) builds that class as usual.
    """

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        if cls is ReducedSim:
            from .factory import reduced_sim

            return reduced_sim(*args, **kwargs)
        return super().__call__(*args, **kwargs)


class ReducedSim(metaclass=_CallPicksTheFrame):
    """A reduced simulation: the base class of every kind, and the call that makes one.

    ``ReducedSim(model)`` runs a trained model on the mesh and default scene stored in it;
    ``ReducedSim(basis, mesh, scene)`` runs any basis on any mesh of the object. The call
    returns :func:`licrom.reduced.factory.reduced_sim` of its arguments (see there for
    them): a :class:`~licrom.reduced.world.WorldFrameSim`, or a
    :class:`~licrom.reduced.body.BodyFrameSim` for a body-frame model. Both are instances of
    this class, which holds what they share: ``step``, ``step_or_record``,
    ``contact_forces`` and :meth:`step_many`.

    Threads: a step runs without the GIL, so separate simulations step in parallel in
    separate threads. One simulation serves one thread at a time: a call (step, state,
    probe) while another thread's call on it runs raises
    :class:`~licrom.errors.ConcurrencyError` at once rather than waiting (guard a shared
    simulation with a ``threading.Lock`` to serialise it on purpose).

    Attributes:
        basis: the subspace.
        mesh: the simulated mesh.
        scene: the scene.
        cubature: the cubature tets and weights.
        contact_points: where contact acts.
        time: simulated time, s.
    """

    basis: Any
    mesh: Mesh
    scene: Scene
    cubature: Cubature
    contact_points: ContactPoints
    time: float
    _core: Any
    _values: np.ndarray
    _jacobians: np.ndarray
    _monitor: ErrorMonitor

    step_many = staticmethod(step_many)
    use_second_thread = staticmethod(use_second_thread)

    @property
    def n_modes(self) -> int:
        """Number of reduced coordinates k (a body-frame simulation's rigid motion not counted)."""
        return self._core.n_dofs

    @property
    def q(self) -> np.ndarray:
        """(k,) reduced coordinates (a body-frame simulation's modal coordinates)."""
        return self._core.q

    @property
    def qdot(self) -> np.ndarray:
        """(k,) their velocities, per second."""
        return self._core.qdot

    def _check_field(self, name: str, a: np.ndarray) -> np.ndarray:
        return check_field(name, a, self.mesh.n_vertices)

    def _trajectory(self, rec: RunRecord, positions: Iterable[np.ndarray], displacements: np.ndarray | DeferredFrames,
                    velocities: np.ndarray | DeferredFrames, qs: np.ndarray, record_every: int, what: str, info: dict[str, Any]) -> Trajectory:
        """The :class:`Trajectory` of a run that ``run`` recorded: its frames' (f, n, 3) ``positions`` (in blocks of
        frames, read once, in order), ``displacements`` and ``velocities`` (arrays, or one :class:`DeferredFrames` for
        both) and (f, k) ``qs``, with each frame's smallest ``det F`` at the cubature points and deepest penetration into
        a plane, and the online error estimate; each warns, as ``what``, where it leaves its range, at the caller of
        ``run``. Its ``info`` holds the source, the sampling and ``info``."""
        min_det_f = cubature_min_det(self._jacobians, qs)
        planes = self.scene.plane_array()
        depths: list[float] = []
        start = None
        for block in positions:
            touch = None if start is not None else first_touch(block, planes, CONTACT_TOLERANCE * self.mesh.size)
            start = start if touch is None else len(depths) + touch
            depths += [penetration(x, planes) for x in block]
        min_det_f, depth = with_steps(min_det_f, np.array(depths), rec.between)
        arrays = rec.arrays()
        warn_frames(arrays["times"], min_det_f, depth, self.mesh.size, what, rec.trailing, stacklevel=4)
        parts = self._monitor.components(record_every * np.arange(len(qs)), None if start is None else record_every * start)
        estimate = np.hypot(parts["residual"], parts["cubature"])
        terms = {name: float(part[-1]) if len(part) else 0.0 for name, part in parts.items()}
        warn_estimate(estimate, what, stacklevel=4, terms=terms)
        return Trajectory(
            rest_positions=self.mesh.vertices,
            tets=self.mesh.tets,
            displacements=displacements,
            velocities=velocities,
            scene=self.scene,
            min_det_f=min_det_f,
            penetration=depth,
            error_estimate=estimate,
            **arrays,
            info={
                "source": "reduced",
                "n_modes": int(self.n_modes),
                "cubature": self.cubature.scheme,
                "cubature_points": int(self.cubature.count),
                "contact_points": int(self.contact_points.count),
                # The run-level estimate's two terms (licrom.reduced.error_estimate): outside the subspace and the cubature's.
                "error_estimate_terms": terms,
                **info,
            },
        )

    def step(self) -> tuple[int, float]:
        """Advance one time step; return (Newton iterations, final residual in m/s).

        Raises:
            SolverError: no convergence within ``scene.solver.max_iterations`` (the state
                is left at the start of the step).
        """
        result = self._core.step()
        self.time += self.scene.dt
        return result

    def step_or_record(self) -> tuple[int, float, bool]:
        """One step; a failure raises, or with ``scene.solver.on_failure == "record"`` is recorded as
        unconverged and the simulation goes on from the last iterate. A step that met NaN or inf
        raises either way: it left no finite iterate to go on from.

        Returns:
            ``(iterations, residual in m/s, converged)``.
        """
        try:
            its, res = self.step()
            return its, res, True
        except SolverError as exc:
            if self.scene.solver.on_failure == "raise":
                raise
            try:
                self._core.accept_last_iterate()
            except ConfigError:
                raise exc from None
            self.time += self.scene.dt
            return self.scene.solver.max_iterations, float(np.nan if exc.residual is None else exc.residual), False

    def contact_forces(self) -> np.ndarray:
        """(C, 3) contact + friction force at each contact point over the last step, N."""
        return self._core.contact_forces()
