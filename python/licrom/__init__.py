"""licrom: fast reduced-order simulation of elastic solids in frictional contact.

Full-space ground truth (:class:`FullSim`, warp), learned continuous subspaces
(:class:`Model`, torch) and a Rust reduced runtime (:class:`ReducedSim`).
Heavy dependencies (torch, warp) load only when the class that needs them is
first used.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# ``compare`` is a function named like its module: bound here, after the module has loaded,
# so that importing ``licrom.compare`` (which sets the package attribute to the module) cannot
# shadow it. The module is numpy-only, so this costs nothing.
from .compare import compare
from .errors import (
    AccuracyWarning,
    ConcurrencyError,
    ConfigError,
    FileFormatError,
    LicromError,
    LicromWarning,
    MeshError,
    MissingDependencyError,
    OutputError,
    PhysicsWarning,
    ShapeError,
    SolverError,
)
from .mesh import Mesh, MeshQuality
from .scene import ContactParams, InitialState, Material, Plane, Scene, SolverParams
from .trajectory import Trajectory

__version__ = "0.1.0"

# Public names that live in modules with heavy imports, loaded on first access:
# name -> (module, attribute), attribute None for a public module itself. Explicit, so that a
# function named like its module (``compare``) can never resolve to the module.
_LAZY: dict[str, tuple[str, str | None]] = {
    "meshes": (".meshes", None),
    "render": (".render", None),
    "export": (".export", None),
    "FullSim": (".full_sim", "FullSim"),
    "generate_dataset": (".dataset", "generate_dataset"),
    "report_dataset_spec": (".presets", "report_dataset_spec"),
    "load_scene": (".scene_file", "load_scene"),
    "SceneFile": (".scene_file", "SceneFile"),
    "Surface": (".surface", "Surface"),
    "TetrahedralizeParams": (".surface", "TetrahedralizeParams"),
    "tetrahedralize": (".surface", "tetrahedralize"),
    "AffineBasis": (".basis", "AffineBasis"),
    "MeshBasis": (".basis", "MeshBasis"),
    "StackedBasis": (".basis", "StackedBasis"),
    "Cubature": (".cubature", "Cubature"),
    "ReducedSim": (".reduced_sim", "ReducedSim"),
    "BodyFrameBasis": (".body_basis", "BodyFrameBasis"),
    "BodyFrameSim": (".body_frame", "BodyFrameSim"),
    "Model": (".model", "Model"),
    "ModelConfig": (".model", "ModelConfig"),
    "train": (".training", "train"),
    "TrainConfig": (".training", "TrainConfig"),
}

__all__ = [
    "LicromError",
    "MeshError",
    "ShapeError",
    "ConfigError",
    "SolverError",
    "FileFormatError",
    "OutputError",
    "ConcurrencyError",
    "MissingDependencyError",
    "LicromWarning",
    "PhysicsWarning",
    "AccuracyWarning",
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
    from . import export, meshes, render
    from .basis import AffineBasis, MeshBasis, StackedBasis
    from .body_basis import BodyFrameBasis
    from .body_frame import BodyFrameSim
    from .cubature import Cubature
    from .dataset import generate_dataset
    from .full_sim import FullSim
    from .model import Model, ModelConfig
    from .presets import report_dataset_spec
    from .reduced_sim import ReducedSim
    from .scene_file import SceneFile, load_scene
    from .surface import Surface, TetrahedralizeParams, tetrahedralize
    from .training import TrainConfig, train
