"""Triangle surfaces (``.obj``, ``.stl``, ``.ply``, ``.off``) and their tetrahedralisation.

A surface is read with meshio and filled with tets by fTetWild (Hu, Schneider, Wang, Zorin
and Panozzo 2020, "Fast Tetrahedral Meshing in the Wild", through ``pytetwild``), the
mesher the report used. fTetWild works on imperfect input (holes, self-intersections,
duplicate faces): the boundary of its tet mesh stays within an envelope of the surface
(``epsilon``) instead of matching it exactly, and the tets are optimised for shape.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import tempfile
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ConfigError, FileFormatError, MeshError
from .mesh import Mesh

__all__ = ["SURFACE_SUFFIXES", "Surface", "TetrahedralizeParams", "tetrahedralize"]

SURFACE_SUFFIXES = (".obj", ".stl", ".ply", ".off")
"""File suffixes read as triangle surfaces."""


@dataclass(frozen=True)
class TetrahedralizeParams:
    """Settings of the tetrahedraliser (fTetWild).

    Attributes:
        edge_length: target tet edge length as a fraction of the surface's bounding-box
            diagonal, in (0, 1] (fTetWild's default 0.05; 0.1 gives a coarse mesh).
        epsilon: envelope: the largest distance of the tet mesh's boundary from the
            surface, as a fraction of the bounding-box diagonal, in (0, 0.1]. Larger is
            coarser and faster near fine surface detail.
        stop_energy: optimisation stops once the worst tet's conformal AMIPS energy is
            below this (> 3, the energy of a regular tet; lower is better shaped and slower).
        max_iterations: optimisation passes, an integer >= 0.
        coarsen: remove as many tets as the quality allows.
        scale: factor applied to the surface coordinates first, > 0 (e.g. 0.001 for a
            surface modelled in mm; licrom works in m).
    """

    edge_length: float = 0.05
    epsilon: float = 1.0e-3
    stop_energy: float = 10.0
    max_iterations: int = 80
    coarsen: bool = False
    scale: float = 1.0

    def __post_init__(self) -> None:
        checks = (
            ("edge_length", 0.0, 1.0, "(0, 1] (a fraction of the bounding-box diagonal)"),
            ("epsilon", 0.0, 0.1, "(0, 0.1] (a fraction of the bounding-box diagonal)"),
            ("stop_energy", 3.0, math.inf, "(3, inf)"),
            ("scale", 0.0, math.inf, "(0, inf)"),
        )
        for name, lo, hi, accepted in checks:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo < value <= hi or not math.isfinite(value):
                raise ConfigError(f"TetrahedralizeParams.{name} must be in {accepted}, got {value!r}")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) or self.max_iterations < 0:
            raise ConfigError(f"TetrahedralizeParams.max_iterations must be an integer >= 0, got {self.max_iterations!r}")


class Surface:
    """A triangle surface: the boundary of a solid to be filled with tets.

    Args:
        vertices: (n, 3) positions in m.
        faces: (f, 3) vertex indices of the triangles.

    Raises:
        MeshError: wrong shapes, non-finite coordinates, indices out of range, or no triangles.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise MeshError(f"a surface needs (n, 3) vertices and at least one (f, 3) triangle, got {v.shape} and {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            raise MeshError(f"surface faces must be integer vertex indices, got dtype {f.dtype}")
        if not np.isfinite(v).all():
            raise MeshError("surface vertices hold NaN or inf")
        if f.min() < 0 or f.max() >= len(v):
            raise MeshError(f"surface face index out of range: indices must be in [0, {len(v) - 1}], found {int(f.min())}..{int(f.max())}")
        self.vertices = v
        self.faces = f.astype(np.int64)

    def __repr__(self) -> str:
        return f"Surface(n_vertices={len(self.vertices)}, n_faces={len(self.faces)}, closed={self.is_closed})"

    @classmethod
    def load(cls, path: str | Path) -> Surface:
        """Read the triangles (quads are split in two) of a surface file with meshio.

        Raises:
            FileFormatError: missing or unreadable file, or one without triangles or quads.
            MeshError: invalid triangles (see :class:`Surface`).
        """
        import meshio

        p = Path(path)
        if not p.is_file():
            raise FileFormatError(f"surface file not found: '{p}'")
        chatter = io.StringIO()
        try:
            # meshio prints and exits on some corrupt files; keep both away from the user.
            with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter), warnings.catch_warnings():
                # meshio's binary-STL size probe overflows on ASCII files, harmlessly.
                warnings.simplefilter("ignore", RuntimeWarning)
                m = meshio.read(p)
        except (Exception, SystemExit) as exc:  # meshio raises many types on foreign or corrupt files
            detail = " ".join(chatter.getvalue().split()).removeprefix("Error: ") or f"{type(exc).__name__}: {exc}"
            raise FileFormatError(f"cannot read surface '{p}': {detail}. Accepted: {', '.join(SURFACE_SUFFIXES)}") from None
        blocks = []
        for c in m.cells:
            if c.type == "triangle":
                blocks.append(c.data)
            elif c.type == "quad":
                blocks += [c.data[:, [0, 1, 2]], c.data[:, [0, 2, 3]]]
        if not blocks:
            kinds = sorted({c.type for c in m.cells}) or ["none"]
            raise FileFormatError(f"surface '{p}' holds no triangles or quads (cell types: {', '.join(kinds)})")
        try:
            return cls(np.asarray(m.points, dtype=np.float64)[:, :3], np.concatenate(blocks))
        except MeshError as exc:
            raise MeshError(f"surface '{p}': {exc}") from None

    @property
    def size(self) -> float:
        """Length of the bounding-box diagonal in m."""
        return float(np.linalg.norm(self.vertices.max(axis=0) - self.vertices.min(axis=0)))

    @property
    def is_closed(self) -> bool:
        """True when every edge is shared by exactly two triangles (a watertight surface)."""
        edges = np.sort(self.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        return bool((counts == 2).all())

    @property
    def enclosed_volume(self) -> float:
        """Volume enclosed by the surface in m^3 (divergence theorem; meaningful when closed)."""
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return abs(float(np.einsum("ij,ij->", a, np.cross(b, c)))) / 6.0


@contextlib.contextmanager
def _working_directory(path: str) -> Iterator[None]:
    previous = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(previous)


def tetrahedralize(surface: Surface, params: TetrahedralizeParams = TetrahedralizeParams()) -> Mesh:
    """Fill a surface with tets (fTetWild); return the tet mesh in m, every tet positively oriented.

    fTetWild is not deterministic: two calls give slightly different meshes, so save the
    result (:meth:`Mesh.save`) and simulate the saved mesh.

    Raises:
        ConfigError: ``params`` is not a :class:`TetrahedralizeParams`.
        MeshError: the mesher failed or produced no tets (a surface that encloses nothing).
    """
    import pytetwild

    if not isinstance(params, TetrahedralizeParams):
        raise ConfigError(f"params must be a TetrahedralizeParams, got {type(params).__name__}")
    if surface.size <= 0.0:
        raise MeshError("the surface has zero extent (all its vertices coincide)")
    try:
        with tempfile.TemporaryDirectory() as scratch, _working_directory(scratch):
            # fTetWild writes a debug file ("__tracked_surface.stl") into the working directory.
            vertices, tets = pytetwild.tetrahedralize(
                surface.vertices * params.scale, surface.faces.astype(np.int32), edge_length_fac=params.edge_length,
                epsilon=params.epsilon, stop_energy=params.stop_energy, num_opt_iter=params.max_iterations,
                optimize=params.max_iterations > 0, coarsen=params.coarsen, quiet=True,
            )
    except (RuntimeError, ValueError) as exc:
        raise MeshError(f"the tetrahedraliser failed: {exc}") from exc
    tets = np.asarray(tets, dtype=np.int64)
    if len(tets) == 0:
        raise MeshError("the tetrahedraliser produced no tets: the surface encloses no volume at this edge length and epsilon")
    vertices = np.asarray(vertices, dtype=np.float64)
    # fTetWild writes its tets with the opposite orientation to licrom's: flip them here
    # rather than let Mesh re-orient them with a warning.
    a, b, c, d = (vertices[tets[:, i]] for i in range(4))
    inverted = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    tets[inverted] = tets[inverted][:, [0, 2, 1, 3]]
    used = np.unique(tets)
    if len(used) < len(vertices):
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        vertices, tets = vertices[used], remap[tets]
    return Mesh(vertices, tets, fix_orientation=False)
