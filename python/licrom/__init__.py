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
from .errors import ConcurrencyError, ConfigError, FileFormatError, LicromError, MeshError, OutputError, ShapeError, SolverError
from .mesh import Mesh, MeshQuality
from .scene import ContactParams, InitialState, Material, Plane, Scene, SolverParams
from .trajectory import Trajectory

__version__ = "0.1.0"

# Public names that live in modules with heavy imports, loaded on first access.
_LAZY = {
    "meshes": ".meshes",
    "FullSim": ".full_sim",
    "generate_dataset": ".dataset",
    "report_dataset_spec": ".dataset",
    "AffineBasis": ".basis",
    "MeshBasis": ".basis",
    "StackedBasis": ".basis",
    "Cubature": ".cubature",
    "ReducedSim": ".reduced_sim",
    "BodyFrameBasis": ".body_frame",
    "BodyFrameSim": ".body_frame",
    "Model": ".model",
    "ModelConfig": ".model",
    "train": ".training",
    "TrainConfig": ".training",
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
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'licrom' has no attribute {name!r}")
    mod = importlib.import_module(module, __name__)
    value = mod if name == module.lstrip(".") else getattr(mod, name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # pragma: no cover
    from . import meshes
    from .basis import AffineBasis, MeshBasis, StackedBasis
    from .body_frame import BodyFrameBasis, BodyFrameSim
    from .cubature import Cubature
    from .dataset import generate_dataset, report_dataset_spec
    from .full_sim import FullSim
    from .model import Model, ModelConfig
    from .reduced_sim import ReducedSim
    from .training import TrainConfig, train
