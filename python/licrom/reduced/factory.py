"""The one place that picks the kind of reduced simulation: :func:`reduced_sim`.

``ReducedSim(...)`` calls it (see :class:`licrom.reduced.base.ReducedSim`), so one call runs
either kind of model and every simulation it returns is a ``ReducedSim``.
"""

from __future__ import annotations

from typing import Any

from ..errors import ConfigError
from ..geometry.mesh import Mesh
from ..scene.scene import Scene
from ..subspace.body_basis import BodyFrameBasis
from ..subspace.cubature import ContactPoints, Cubature
from .base import ReducedSim
from .body import BodyFrameSim
from .world import WorldFrameSim

__all__ = ["reduced_sim"]


def reduced_sim(
    basis: Any,
    mesh: Mesh | None = None,
    scene: Scene | None = None,
    cubature: Cubature | str | None = None,
    contact_points: ContactPoints | None = None,
    solver: str = "newton",
    strain: str = "mesh",
) -> ReducedSim:
    """The reduced simulation of a basis or trained model: what ``ReducedSim(...)`` returns.

    A body-frame model (``basis.frame == "body"``) gives a
    :class:`~licrom.reduced.body.BodyFrameSim` of ``BodyFrameBasis(mesh, learned=model)``
    (its mesh and default scene unless given; the ``"newton"`` solver only); anything else a
    :class:`~licrom.reduced.world.WorldFrameSim` of the same arguments.

    Args:
        basis: a basis (``n_modes``, ``values``, ``jacobians``) or a trained ``licrom.Model``.
        mesh: the mesh to simulate (default: the model's mesh).
        scene: the scene (default: the model's default scene).
        cubature: cubature tets and weights, or a name of :data:`~licrom.reduced.base.CUBATURES`
            (default: the model's fitted cubature), as in :class:`~licrom.reduced.world.WorldFrameSim`.
        contact_points: where contact acts (default: :meth:`~licrom.subspace.cubature.ContactPoints.default`).
        solver: ``"newton"`` or ``"prefactored"`` (world frame only), as in
            :class:`~licrom.reduced.world.WorldFrameSim`.
        strain: ``"mesh"`` or ``"field"``, see :func:`licrom.subspace.basis.strain_jacobians`.

    Returns:
        A :class:`~licrom.reduced.base.ReducedSim`: world-frame or body-frame as above.

    Raises:
        ConfigError: unknown solver (any but ``"newton"`` for a body-frame model), missing
            mesh/scene, singular reduced mass matrix.
        ShapeError: the basis returns arrays of the wrong shape or with NaN/inf.
    """
    if getattr(basis, "frame", "world") != "body":
        return WorldFrameSim(basis, mesh, scene, cubature=cubature, contact_points=contact_points, solver=solver, strain=strain)
    if solver != "newton":
        raise ConfigError(f"a body-frame model runs with the 'newton' solver only, got solver={solver!r}")
    mesh = basis.mesh if mesh is None else mesh
    scene = basis.default_scene if scene is None else scene
    body_basis = BodyFrameBasis(mesh, learned=basis, density=scene.material.density)
    return BodyFrameSim(body_basis, mesh=mesh, scene=scene, cubature=cubature, contact_points=contact_points, strain=strain)
