"""licrom: fast reduced-order simulation of elastic solids in frictional contact.

Full-space ground truth (:class:`FullSim`, warp), learned continuous subspaces
(:class:`Model`, torch) and a Rust reduced runtime (:class:`ReducedSim`).
Heavy dependencies (torch, warp) load only when the class that needs them is
first used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from . import errors

# ``compare`` (the function of :mod:`licrom.analysis.compare`) is numpy-only, so it loads at once.
from .analysis.compare import compare

# The exception family, named here for type checkers; ``__all__`` takes it from ``errors.__all__``.
from .errors import (
    AccuracyWarning,
    ConcurrencyError,
    ConfigError,
    FileFormatError,
    InternalError,
    LicromError,
    LicromWarning,
    MeshError,
    MissingDependencyError,
    OutputError,
    PhysicsWarning,
    ShapeError,
    SolverError,
)
from .geometry.mesh import Mesh, MeshQuality
from .records.trajectory import Trajectory
from .scene.scene import ContactParams, InitialState, Material, Plane, Scene, SolverParams

__version__ = "0.1.0"

# Public names that live in modules with heavy imports, loaded on first access:
# name -> (module, attribute), attribute None for a public module itself.
_LAZY: dict[str, tuple[str, str | None]] = {
    "meshes": (".geometry.meshes", None),
    "render": (".viz.render", None),
    "export": (".records.export", None),
    "FullSim": (".full", "FullSim"),
    "generate_dataset": (".data.dataset", "generate_dataset"),
    "report_dataset_spec": (".data.presets", "report_dataset_spec"),
    "load_scene": (".data.scene_file", "load_scene"),
    "SceneFile": (".data.scene_file", "SceneFile"),
    "Surface": (".geometry.surface", "Surface"),
    "TetrahedralizeParams": (".geometry.surface", "TetrahedralizeParams"),
    "tetrahedralize": (".geometry.surface", "tetrahedralize"),
    "AffineBasis": (".subspace.basis", "AffineBasis"),
    "MeshBasis": (".subspace.basis", "MeshBasis"),
    "StackedBasis": (".subspace.basis", "StackedBasis"),
    "Cubature": (".subspace.cubature", "Cubature"),
    "ReducedSim": (".reduced.base", "ReducedSim"),
    "BodyFrameBasis": (".subspace.body_basis", "BodyFrameBasis"),
    "BodyFrameSim": (".reduced.body", "BodyFrameSim"),
    "Model": (".learn.model", "Model"),
    "ModelConfig": (".learn.model", "ModelConfig"),
    "train": (".learn.training", "train"),
    "TrainConfig": (".learn.training", "TrainConfig"),
}

__all__ = [
    *(name for name in errors.__all__ if name != "require_optional"),
    "Mesh",
    "MeshQuality",
    "Material",
    "Plane",
    "ContactParams",
    "SolverParams",
    "InitialState",
    "Scene",
    "Trajectory",
    "compare",
    *_LAZY,
]


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'licrom' has no attribute {name!r}")
    module, attribute = _LAZY[name]
    mod = importlib.import_module(module, __name__)
    value = mod if attribute is None else getattr(mod, attribute)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # pragma: no cover
    from .data.dataset import generate_dataset
    from .data.presets import report_dataset_spec
    from .data.scene_file import SceneFile, load_scene
    from .full import FullSim
    from .geometry import meshes
    from .geometry.surface import Surface, TetrahedralizeParams, tetrahedralize
    from .learn.model import Model, ModelConfig
    from .learn.training import TrainConfig, train
    from .records import export
    from .reduced.base import ReducedSim
    from .reduced.body import BodyFrameSim
    from .subspace.basis import AffineBasis, MeshBasis, StackedBasis
    from .subspace.body_basis import BodyFrameBasis
    from .subspace.cubature import Cubature
    from .viz import render
