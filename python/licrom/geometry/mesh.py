"""Tetrahedral meshes: validation, geometry, boundary, masses, quality, file I/O."""

from __future__ import annotations

import contextlib
import io
import math
import warnings
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError, FileFormatError, MeshError, MissingDependencyError, ShapeError

__all__ = ["Mesh", "MeshQuality", "check_points"]

# Outward-facing triangles of a positively oriented tet (a, b, c, d): det[b-a, c-a, d-a] > 0.
_TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
# A tet whose volume is below this fraction of (mean edge length)^3 is degenerate.
_DEGENERATE_RELATIVE_VOLUME = 1e-10
_TET_FORMATS = ".mesh, .msh, .vtu, .vtk, .xdmf, .med, .inp (anything meshio reads with tetra cells)"
# The suffixes Mesh.save writes: meshio formats that hold tets (checked by a write and read back).
# Surface formats (.stl, .ply, .obj, .off, ...) would drop the tets.
_SAVE_SUFFIXES = (".mesh", ".meshb", ".msh", ".vtu", ".vtk", ".xdmf", ".xmf", ".med", ".inp", ".avs", ".bdf", ".nas", ".fem",
                  ".dat", ".tec", ".ele", ".node", ".f3grid", ".mdpa", ".post", ".dato", ".su2", ".vol", ".xml", ".e", ".exo", ".ex2")
# meshio imports these for some formats only; they are not licrom dependencies.
_FORMAT_PACKAGES = {".xdmf": "h5py", ".xmf": "h5py", ".med": "h5py", ".h5m": "h5py", ".hmf": "h5py", ".cgns": "h5py",
                    ".e": "netCDF4", ".exo": "netCDF4", ".ex2": "netCDF4"}


# meshio readers that call readline() for ever at the end of a truncated file, and the mode they open it in.
_LOOPING_READERS = {"tecplot": "r", "mdpa": "rb"}
# A reader that has read past the end of the file this many times is looping.
_MAX_READS_AT_END = 100


def check_points(points: Any, name: str = "points") -> np.ndarray:
    """``points`` as a (p, 3) float64 array of finite positions, m: where a basis or a model is evaluated.

    Raises:
        ShapeError: another shape, or NaN/inf.
    """
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ShapeError(f"{name} must have shape (p, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ShapeError(f"{name} holds NaN or inf")
    return x


class _EndGuard:
    """A file for meshio that raises EOFError once a reader keeps reading at its end (a loop on a truncated file)."""

    def __init__(self, f) -> None:
        self._f = f
        self._at_end = 0

    def _count(self, data):
        if not data:
            self._at_end += 1
            if self._at_end > _MAX_READS_AT_END:
                raise EOFError(f"the reader kept reading at the end of the file ({_MAX_READS_AT_END} times): it ends too soon")
        return data

    def readline(self, *args):
        return self._count(self._f.readline(*args))

    def read(self, *args):
        return self._count(self._f.read(*args))

    def __getattr__(self, name):  # tell, seek, fileno (numpy's fromfile) ...: the file's own
        return getattr(self._f, name)


def _read(meshio, p: Path):
    """``meshio.read(p)``, guarded against the readers that loop for ever on truncated files."""
    formats = meshio.extension_to_filetypes.get(p.suffix.lower(), [])
    if len(formats) == 1 and formats[0] in _LOOPING_READERS:
        with open(p, _LOOPING_READERS[formats[0]]) as f:
            return meshio.read(_EndGuard(f), file_format=formats[0])
    return meshio.read(p)


def _missing_package(p: Path, exc: ImportError | None = None) -> MissingDependencyError | None:
    """The MissingDependencyError for a file whose meshio format needs a package that is not installed; else None."""
    import importlib.util

    package = exc.name if exc is not None and exc.name else _FORMAT_PACKAGES.get(p.suffix.lower())
    if package is None or (exc is None and importlib.util.find_spec(package) is not None):
        return None
    package = package.split(".")[0]
    return MissingDependencyError(f"meshio needs the optional package '{package}' for '{p.name}' ({p.suffix} files), and it is not "
                                  f"installed; install it with: pip install {package} (or use .msh, .vtu or .mesh)")


@dataclass(frozen=True)
class MeshQuality:
    """Tet quality summary.

    Attributes:
        min_dihedral_deg: smallest dihedral angle over all tets, degrees.
        max_dihedral_deg: largest dihedral angle over all tets, degrees.
        min_volume: smallest tet volume, m^3.
        max_volume: largest tet volume, m^3.
        mean_edge_length: mean tet edge length, m.
    """

    min_dihedral_deg: float
    max_dihedral_deg: float
    min_volume: float
    max_volume: float
    mean_edge_length: float


class Mesh:
    """A linear tetrahedral mesh of a solid in its rest configuration.

    Args:
        vertices: (n, 3) rest positions in m.
        tets: (m, 4) vertex indices.
        fix_orientation: re-orient inverted tets (with a warning) instead of refusing them.

    Raises:
        ShapeError: wrong array shapes or dtypes.
        MeshError: non-finite coordinates, indices out of range, repeated vertices in a tet,
            zero-volume tets, unreferenced vertices, or inverted tets with ``fix_orientation=False``.
    """

    def __init__(self, vertices: np.ndarray, tets: np.ndarray, *, fix_orientation: bool = True) -> None:
        v = np.asarray(vertices)
        t = np.asarray(tets)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 4:
            raise ShapeError(f"mesh vertices must have shape (n, 3) with n >= 4, got {v.shape}")
        if not np.issubdtype(v.dtype, np.number) or np.iscomplexobj(v):
            raise ShapeError(f"mesh vertices must be real numbers, got dtype {v.dtype}")
        if t.ndim != 2 or t.shape[1] != 4 or t.shape[0] < 1:
            raise ShapeError(f"mesh tets must have shape (m, 4) (four vertex indices per tet), got {t.shape}")
        if not np.issubdtype(t.dtype, np.integer):
            raise ShapeError(f"mesh tets must be integers, got dtype {t.dtype}")
        v = np.ascontiguousarray(v, dtype=np.float64)
        t = np.ascontiguousarray(t, dtype=np.int64)
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():
            raise MeshError(f"mesh has {int(bad.sum())} vertices with NaN or inf coordinates (first: vertex {int(np.argmax(bad))})")
        if t.min() < 0 or t.max() >= len(v):
            raise MeshError(f"tet vertex index out of range: indices must be in [0, {len(v) - 1}], found {int(t.min())}..{int(t.max())}")
        srt = np.sort(t, axis=1)
        rep = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
        if rep.any():
            raise MeshError(f"{int(rep.sum())} tets repeat a vertex (first: tet {int(np.argmax(rep))} = {t[np.argmax(rep)].tolist()})")
        used = np.zeros(len(v), dtype=bool)
        used[t.ravel()] = True
        if not used.all():
            raise MeshError(
                f"{int((~used).sum())} vertices belong to no tet; they would carry no mass. "
                "Remove them (Mesh.load does so automatically)"
            )
        vol = _signed_volumes(v, t)
        edge = np.linalg.norm(v[t[:, _TET_EDGES[:, 0]]] - v[t[:, _TET_EDGES[:, 1]]], axis=2).mean(axis=1)
        degenerate = np.abs(vol) <= _DEGENERATE_RELATIVE_VOLUME * edge**3
        if degenerate.any():
            i = int(np.argmax(degenerate))
            raise MeshError(
                f"{int(degenerate.sum())} tets have (near) zero volume (first: tet {i} = {t[i].tolist()}, volume {vol[i]:.3e} m^3); "
                "every tet must have positive volume"
            )
        inverted = vol < 0
        if inverted.any():
            if not fix_orientation:
                raise MeshError(f"{int(inverted.sum())} tets are inverted (negative volume; first: tet {int(np.argmax(inverted))})")
            warnings.warn(f"re-oriented {int(inverted.sum())} inverted tets (swapped two vertices)", stacklevel=2)
            t[inverted] = t[inverted][:, [0, 2, 1, 3]]
            vol = np.abs(vol)
        v.setflags(write=False)
        t.setflags(write=False)
        vol.setflags(write=False)
        self._vertices = v
        self._tets = t
        self._volumes = vol

    # --- basic data --------------------------------------------------------------------
    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float64 rest positions in m (read-only)."""
        return self._vertices

    @property
    def tets(self) -> np.ndarray:
        """(m, 4) int64 vertex indices, positively oriented (read-only)."""
        return self._tets

    @property
    def n_vertices(self) -> int:
        return len(self._vertices)

    @property
    def n_tets(self) -> int:
        return len(self._tets)

    @property
    def rest_volumes(self) -> np.ndarray:
        """(m,) rest volume of each tet in m^3."""
        return self._volumes

    def __repr__(self) -> str:
        return f"Mesh(n_vertices={self.n_vertices}, n_tets={self.n_tets}, n_boundary_faces={len(self.boundary_faces)})"

    # --- derived geometry --------------------------------------------------------------
    @cached_property
    def shape_matrix_inverses(self) -> np.ndarray:
        """(m, 3, 3) inverse rest shape matrices ``Dm^-1``, ``Dm = [X1-X0, X2-X0, X3-X0]``.

        The deformation gradient of a tet is ``F = Ds Dm^-1`` with ``Ds`` built from
        deformed positions the same way.
        """
        x = self._vertices[self._tets]
        dm = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)
        out = np.linalg.inv(dm)
        out.setflags(write=False)
        return out

    @cached_property
    def shape_gradients(self) -> np.ndarray:
        """(m, 4, 3) gradients of the four linear shape functions of each tet, in 1/m."""
        dmi = self.shape_matrix_inverses
        g = np.empty((self.n_tets, 4, 3))
        g[:, 1:, :] = dmi  # rows of Dm^-1 are the gradients of N1, N2, N3
        g[:, 0, :] = -dmi.sum(axis=1)
        g.setflags(write=False)
        return g

    @cached_property
    def centroids(self) -> np.ndarray:
        """(m, 3) tet centroids in m."""
        c = self._vertices[self._tets].mean(axis=1)
        c.setflags(write=False)
        return c

    @cached_property
    def boundary_faces(self) -> np.ndarray:
        """(f, 3) boundary triangles, oriented with outward normals."""
        faces = self._tets[:, _TET_FACES].reshape(-1, 3)
        key = np.sort(faces, axis=1)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        out = np.ascontiguousarray(faces[counts[inv.ravel()] == 1])
        out.setflags(write=False)
        return out

    @cached_property
    def boundary_vertices(self) -> np.ndarray:
        """(b,) sorted indices of the vertices on the boundary surface."""
        out = np.unique(self.boundary_faces)
        out.setflags(write=False)
        return out

    @cached_property
    def boundary_vertex_areas(self) -> np.ndarray:
        """(b,) boundary area carried by each boundary vertex (a third of each adjacent triangle), m^2.

        Aligned with :attr:`boundary_vertices`; sums to the surface area.
        """
        f = self.boundary_faces
        x = self._vertices
        area = 0.5 * np.linalg.norm(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]), axis=1)
        per_vertex = np.zeros(self.n_vertices)
        np.add.at(per_vertex, f.ravel(), np.repeat(area / 3.0, 3))
        out = per_vertex[self.boundary_vertices]
        out.setflags(write=False)
        return out

    @property
    def surface_area(self) -> float:
        """Total boundary area in m^2."""
        return float(self.boundary_vertex_areas.sum())

    @property
    def volume(self) -> float:
        """Total volume in m^3."""
        return float(self._volumes.sum())

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(lower, upper)`` of the rest shape, m."""
        return self._vertices.min(axis=0), self._vertices.max(axis=0)

    @property
    def size(self) -> float:
        """Length of the bounding-box diagonal in m (the object's size)."""
        lo, hi = self.bounds
        return float(np.linalg.norm(hi - lo))

    def vertex_masses(self, density: float) -> np.ndarray:
        """(n,) lumped masses ``m_v = sum_t rho V_t / 4`` in kg for a density in kg/m^3.

        Raises:
            ConfigError: ``density`` is not a finite real number > 0.
        """
        if isinstance(density, bool) or not isinstance(density, (int, float, np.integer, np.floating)) \
                or not math.isfinite(density) or density <= 0:
            raise ConfigError(f"density must be a finite number > 0 (kg/m^3), got {density!r}")
        m = np.zeros(self.n_vertices)
        np.add.at(m, self._tets.ravel(), np.repeat(density * self._volumes / 4.0, 4))
        return m

    def deformation_gradients(self, positions: np.ndarray) -> np.ndarray:
        """(m, 3, 3) deformation gradients ``F = Ds Dm^-1`` for deformed ``positions`` (n, 3)."""
        x = np.asarray(positions, dtype=np.float64)
        if x.shape != self._vertices.shape:
            raise ShapeError(f"positions must have shape {self._vertices.shape}, got {x.shape}")
        p = x[self._tets]
        ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
        return ds @ self.shape_matrix_inverses

    @cached_property
    def _centroid_tree(self) -> Any:
        """A k-d tree of the tet centroids (:meth:`locate`)."""
        from scipy.spatial import cKDTree

        return cKDTree(self.centroids)

    @cached_property
    def _face_tree(self) -> Any:
        """A k-d tree of the boundary triangles' centroids (:meth:`nearest_surface_points`)."""
        from scipy.spatial import cKDTree

        return cKDTree(self._vertices[self.boundary_faces].mean(axis=1))

    def nearest_surface_points(self, points: np.ndarray, candidates: int = 16) -> np.ndarray:
        """The point of the boundary surface nearest each point (inside or outside the mesh).

        Args:
            points: (p, 3) positions in m in the rest configuration.
            candidates: boundary triangles examined per point, those with the nearest centroids, an
                integer >= 1 (capped at the triangle count).

        Returns:
            (p, 3) points on the boundary surface, m.

        Raises:
            ShapeError: ``points`` is not (p, 3) or holds NaN or inf.
            ConfigError: ``candidates`` is not an integer >= 1.
        """
        from .closest import closest_points_on_triangles

        pts = check_points(points)
        cand = _nearest_rows(self._face_tree, pts, candidates, "Mesh.nearest_surface_points", "boundary triangles examined per point")
        k = cand.shape[1]
        corners = self._vertices[self.boundary_faces[cand]]  # (p, k, 3, 3)
        near = closest_points_on_triangles(np.repeat(pts, k, axis=0), *(corners[:, :, i].reshape(-1, 3) for i in range(3))).reshape(len(pts), k, 3)
        best = np.argmin(((near - pts[:, None]) ** 2).sum(axis=2), axis=1)
        return near[np.arange(len(pts)), best]

    def locate(self, points: np.ndarray, candidates: int = 12) -> tuple[np.ndarray, np.ndarray]:
        """Find the tet holding each point and its barycentric coordinates.

        Points outside the mesh (or within round-off of a face) get the nearest
        candidate tet, with barycentric coordinates clamped to it and renormalised.

        Args:
            points: (p, 3) positions in m in the rest configuration.
            candidates: nearest tet centroids examined per point, an integer >= 1 (capped at the tet count).

        Returns:
            ``(tets, bary)``: (p,) tet indices and (p, 4) barycentric coordinates.

        Raises:
            ShapeError: ``points`` is not (p, 3) or holds NaN or inf.
            ConfigError: ``candidates`` is not an integer >= 1.
        """
        pts = check_points(points)
        cand = _nearest_rows(self._centroid_tree, pts, candidates, "Mesh.locate", "nearest tets examined per point")
        x0 = self._vertices[self._tets[cand, 0]]  # (p, k, 3)
        b123 = np.einsum("pkij,pkj->pki", self.shape_matrix_inverses[cand], pts[:, None, :] - x0)
        bary = np.concatenate([1.0 - b123.sum(axis=2, keepdims=True), b123], axis=2)  # (p, k, 4)
        worst = bary.min(axis=2)
        pick = np.argmax(worst, axis=1)  # the candidate the point is most inside of
        rows = np.arange(len(pts))
        b = np.clip(bary[rows, pick], 0.0, None)
        return cand[rows, pick], b / b.sum(axis=1, keepdims=True)

    def quality(self) -> MeshQuality:
        """Dihedral angles, volumes and edge length of the tets."""
        x = self._vertices[self._tets]
        normals = []
        for face in _TET_FACES:
            n = np.cross(x[:, face[1]] - x[:, face[0]], x[:, face[2]] - x[:, face[0]])
            normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
        # Each edge is shared by the two faces that do not contain the opposite edge's ends.
        angles = []
        for a, b in _TET_EDGES:
            fa, fb = [i for i, face in enumerate(_TET_FACES) if a in face and b in face]
            cos = -(normals[fa] * normals[fb]).sum(axis=1)
            angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        ang = np.stack(angles, axis=1)
        edge = np.linalg.norm(x[:, _TET_EDGES[:, 0]] - x[:, _TET_EDGES[:, 1]], axis=2)
        return MeshQuality(
            min_dihedral_deg=float(ang.min()),
            max_dihedral_deg=float(ang.max()),
            min_volume=float(self._volumes.min()),
            max_volume=float(self._volumes.max()),
            mean_edge_length=float(edge.mean()),
        )

    # --- files -------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | Path, *, fix_orientation: bool = True) -> Mesh:
        """Read a tet mesh with meshio (``.mesh``, ``.msh``, ``.vtu`` and the other tet formats).

        Vertices that belong to no tet (geometry points some meshers write) are dropped
        with a warning.

        Raises:
            FileFormatError: the file is missing, unreadable or holds no tetrahedra.
            MeshError: the tets are invalid (see :class:`Mesh`).
            MissingDependencyError: the format needs a package meshio imports on demand (``h5py`` for
                ``.xdmf`` and ``.med``, ``netCDF4`` for Exodus), and it is not installed.
        """
        import meshio

        from .._io import existing_file

        p = existing_file(path, "mesh")
        missing = _missing_package(p)
        if missing is not None:
            raise missing
        chatter = io.StringIO()
        try:
            # meshio prints and calls sys.exit() on some corrupt files; keep both away from the user.
            with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
                m = _read(meshio, p)
        except ImportError as exc:  # a format whose package meshio imports on demand
            missing = _missing_package(p, exc)
            raise (missing or FileFormatError(f"cannot read mesh '{p}': {exc}")) from exc
        except meshio.ReadError as exc:
            raise FileFormatError(f"cannot read mesh '{p}': {exc}. Accepted formats: {_TET_FORMATS}") from exc
        except (Exception, SystemExit) as exc:  # meshio raises many types on truncated or corrupt files
            detail = " ".join(chatter.getvalue().split()).removeprefix("Error: ") or f"{type(exc).__name__}: {exc}"
            raise FileFormatError(f"cannot read mesh '{p}' (truncated or corrupt?): {detail}") from None
        blocks = [np.asarray(c.data) for c in m.cells if c.type == "tetra"]
        if not sum(len(b) for b in blocks):
            kinds = sorted({c.type for c in m.cells if len(c.data)}) or ["none"]
            raise FileFormatError(f"mesh '{p}' holds no tetrahedra (cell types: {', '.join(kinds)}); licrom needs a tet mesh")
        try:
            tets = np.concatenate([b.reshape(-1, 4) for b in blocks]).astype(np.int64)
            pts = np.asarray(m.points, dtype=np.float64)
        except (ValueError, TypeError) as exc:  # tets of another arity, or points that are not numbers
            raise FileFormatError(f"cannot read mesh '{p}' (truncated or corrupt?): {exc}") from None
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise FileFormatError(f"mesh '{p}' has points of shape {pts.shape}; licrom needs 3D points")
        if tets.size and (tets.min() < 0 or tets.max() >= len(pts)):
            raise MeshError(f"mesh '{p}': tet vertex index out of range: indices must be in [0, {len(pts) - 1}], found {int(tets.min())}..{int(tets.max())}")
        used = np.zeros(len(pts), dtype=bool)
        used[tets.ravel()] = True
        if not used.all():
            warnings.warn(f"mesh '{p}': dropped {int((~used).sum())} vertices that belong to no tet", stacklevel=2)
            remap = np.cumsum(used) - 1
            pts, tets = pts[used], remap[tets]
        try:
            return cls(pts, tets, fix_orientation=fix_orientation)
        except (ShapeError, MeshError) as exc:  # a file's content is a mesh problem, whatever its arrays' shapes
            raise MeshError(f"mesh '{p}': {exc}") from None

    def save(self, path: str | Path) -> None:
        """Write the mesh with meshio; the format follows the file extension. The write is atomic.

        Raises:
            FileFormatError: an extension that meshio does not know, or whose format cannot hold tets
                (``.stl``, ``.ply``, ``.obj``, ...); the message lists the accepted ones.
            MissingDependencyError: the format needs a package meshio imports on demand (``h5py`` for
                ``.xdmf`` and ``.med``, ``netCDF4`` for Exodus), and it is not installed.
            OutputError: the file cannot be written (see :func:`licrom._io.atomic_path`).
        """
        import meshio

        from .._io import atomic_path

        p = Path(path)
        formats = meshio.extension_to_filetypes.get(p.suffix.lower())
        if not formats:
            raise FileFormatError(f"cannot write a mesh to '{p}': unknown file extension '{p.suffix}'. "
                                  f"Accepted: {', '.join(_SAVE_SUFFIXES)}")
        if p.suffix.lower() not in _SAVE_SUFFIXES:
            raise FileFormatError(f"cannot write a mesh to '{p}': a {p.suffix} file cannot hold tets (meshio would drop them). "
                                  f"Accepted: {', '.join(_SAVE_SUFFIXES)}")
        missing = _missing_package(p)
        if missing is not None:
            raise missing
        # .msh is Gmsh's format to most people (meshio would pick ANSYS, its first match).
        file_format = "gmsh" if "gmsh" in formats else formats[0]
        mesh = meshio.Mesh(self._vertices, [("tetra", self._tets)])
        with atomic_path(p) as tmp:
            try:
                meshio.write(tmp, mesh, file_format=file_format)
            except ImportError as exc:  # a package that _FORMAT_PACKAGES does not know of
                raise (_missing_package(p, exc) or FileFormatError(f"cannot write a mesh to '{p}': {exc}")) from exc
            except (KeyError, ValueError, meshio.ReadError, meshio.WriteError) as exc:
                detail = str(exc).replace(str(tmp), str(p))  # the user's path, not the temporary one beside it
                raise FileFormatError(f"cannot write a mesh to '{p}': {detail}. Accepted formats: {_TET_FORMATS}") from exc

    # --- comparison --------------------------------------------------------------------
    def same_as(self, other: Mesh) -> bool:
        """True when both meshes have identical vertices and tets."""
        return (
            self.n_vertices == other.n_vertices
            and self.n_tets == other.n_tets
            and np.array_equal(self._tets, other._tets)
            and np.array_equal(self._vertices, other._vertices)
        )


def _nearest_rows(tree: Any, points: np.ndarray, candidates: Any, method: str, meaning: str) -> np.ndarray:
    """(p, k) indices of the ``candidates`` rows of ``tree`` nearest each of ``points`` (k capped at the tree's size).

    Raises:
        ConfigError: ``candidates`` is not an integer >= 1 (``method`` and the ``meaning`` of the count named).
    """
    if isinstance(candidates, (bool, np.bool_)) or not isinstance(candidates, (int, np.integer)) or candidates < 1:
        raise ConfigError(f"{method} candidates must be an integer >= 1 ({meaning}), got {candidates!r}")
    k = min(int(candidates), tree.n)
    _, rows = tree.query(points, k=k)
    return rows.reshape(len(points), k)


def _signed_volumes(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c, d = (v[t[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0

