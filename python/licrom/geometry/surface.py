"""Triangle surfaces (``.obj``, ``.stl``, ``.ply``, ``.off``) and their tetrahedralisation.

A surface is read with meshio and filled with tets by fTetWild (Hu, Schneider, Wang, Zorin
and Panozzo 2020, "Fast Tetrahedral Meshing in the Wild", through ``pytetwild``), the
mesher the report used. fTetWild works on imperfect input (holes, self-intersections,
duplicate faces): the boundary of its tet mesh stays within an envelope of the surface
(``epsilon``) instead of matching it exactly, and the tets are optimised for shape.

fTetWild is C++ that crashes the process (a segmentation fault, ``std::bad_alloc``) on some
inputs, which no ``except`` can catch: :func:`tetrahedralize` checks what it hands over
(finite, of a size in metres fTetWild handles, not flat along any axis, enclosing a volume, a
tet count that fits in memory) and runs fTetWild in a child process, so that what slips
through still ends as a :class:`~licrom.errors.MeshError`.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import signal
import subprocess
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, FileFormatError, LicromWarning, MeshError, MissingDependencyError
from .mesh import Mesh

__all__ = ["SURFACE_SUFFIXES", "Surface", "TetrahedralizeParams", "tetrahedralize"]

SURFACE_SUFFIXES = (".obj", ".stl", ".ply", ".off")
"""File suffixes read as triangle surfaces."""

# Bounding-box diagonal (m, after scaling) fTetWild is given. fTetWild's geometric tests use
# absolute tolerances (1e-8 and its powers): a 0.1 m ball scaled to a 2e-6 m diagonal crashes
# it, so the floor keeps a factor 50 from that; the ceiling is the plane offsets' 1e6 m.
_MIN_SIZE = 1.0e-4
_MAX_SIZE = 1.0e6
# Each axis's extent must be at least this fraction of the diagonal: a zero or 1e-12 thick
# box crashes fTetWild, and anything thinner than its envelope (epsilon) yields no tets anyway.
_MIN_RELATIVE_EXTENT = 1.0e-6
# A closed surface encloses no volume when its signed volume is within this fraction of the
# sum of the magnitudes it is summed from (round-off).
_MIN_RELATIVE_VOLUME = 1.0e-9
# fTetWild's tets: a regular tet of edge l holds l^3 / (6 sqrt 2), about l^3 / 8.5; on a ball
# it made 0.83 of that count, and peaked at 1.5 to 2 KiB of memory per tet it output.
_TETS_PER_EDGE_CUBE = 6.0 * math.sqrt(2.0)
_BYTES_PER_TET = 2048


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
        """Length of the bounding-box diagonal in m (inf when it overflows)."""
        with np.errstate(over="ignore"):
            extent = self.vertices.max(axis=0) - self.vertices.min(axis=0)
        return math.hypot(*extent.tolist())  # hypot: no overflow of the squares for coordinates like 1e300

    @property
    def is_closed(self) -> bool:
        """True when every edge is shared by exactly two triangles (a watertight surface)."""
        edges = np.sort(self.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        return bool((counts == 2).all())

    @property
    def enclosed_volume(self) -> float:
        """Volume enclosed by the surface in m^3 (divergence theorem; meaningful when closed)."""
        return _volume(self.vertices, self.faces)[0]


def _volume(vertices: np.ndarray, faces: np.ndarray) -> tuple[float, float]:
    """``(volume, noise)``: the absolute volume (m^3) the triangles enclose, and the round-off scale of that sum.

    Computed about the centre of the bounding box in units of its diagonal, so coordinates of
    1e300 or 1e-300 neither overflow nor underflow before the result itself does.
    """
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    with np.errstate(over="ignore"):
        size = math.hypot(*(hi - lo).tolist())
    if not 0.0 < size < math.inf:
        return 0.0, 0.0
    x = (vertices - (0.5 * lo + 0.5 * hi)) / size
    a, b, c = (x[faces[:, i]] for i in range(3))
    terms = np.einsum("ij,ij->i", a, np.cross(b, c))
    cube = size * size * size  # a float product: inf or 0 where it leaves the range, not an OverflowError
    return abs(float(terms.sum())) / 6.0 * cube, float(np.abs(terms).sum()) / 6.0 * cube


def _edges(faces: np.ndarray) -> tuple[int, int]:
    """``(open, non_manifold)``: the number of edges that belong to one triangle only, and to three or more."""
    edges = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts == 1).sum()), int((counts > 2).sum())


def _capped_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Volume (m^3) of an open surface with each hole capped by a fan from the hole's centroid."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    directed = faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    _, inverse, counts = np.unique(np.sort(directed, axis=1), axis=0, return_inverse=True, return_counts=True)
    rim = directed[counts[inverse.ravel()] == 1]
    if len(rim) == 0:
        return _volume(vertices, faces)[0]
    n = len(vertices)
    graph = coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, hole = connected_components(graph, directed=False)
    holes, which = np.unique(hole[rim[:, 0]], return_inverse=True)
    centroids = np.stack([vertices[np.unique(rim[which == h])].mean(axis=0) for h in range(len(holes))])
    caps = np.column_stack([rim[:, 1], rim[:, 0], n + which])  # reversed rim edges: the caps face outward
    return _volume(np.concatenate([vertices, centroids]), np.concatenate([faces, caps]))[0]


def _difference(surface: Surface, scale: float, mesh: Mesh) -> str:
    """How the tets of an open surface differ from it: volume, and bounds (a sentence)."""
    used = surface.vertices[np.unique(surface.faces)] * scale
    lo, hi = used.min(axis=0), used.max(axis=0)
    mlo, mhi = mesh.bounds
    outside = np.concatenate([lo - mlo, mhi - hi])
    capped = _capped_volume(surface.vertices * scale, surface.faces)
    change = f" ({100 * (mesh.volume / capped - 1):+.1f} %)" if capped > 0 else ""
    return (f"the tets hold {mesh.volume:.4g} m^3 against {capped:.4g} m^3 inside the surface with its holes capped flat{change}; "
            f"their bounds [{', '.join(f'{x:.4g}' for x in mlo)}] .. [{', '.join(f'{x:.4g}' for x in mhi)}] m against the surface's "
            f"[{', '.join(f'{x:.4g}' for x in lo)}] .. [{', '.join(f'{x:.4g}' for x in hi)}] m "
            f"(up to {max(0.0, float(outside.max())):.3g} m beyond them, {max(0.0, float(-outside.min())):.3g} m short of them)")


def _check_input(surface: Surface, params: TetrahedralizeParams, allow_open: bool) -> np.ndarray:
    """The scaled vertices fTetWild is given, after every check that keeps it from crashing.

    Raises:
        MeshError: coordinates that overflow once scaled, a size outside [_MIN_SIZE, _MAX_SIZE],
            an axis of (almost) no extent, an open surface without ``allow_open``, or no enclosed volume.
        ConfigError: the tets would not fit in memory (see :mod:`licrom._limits`).
    """
    from .._limits import format_bytes, memory_limit

    with np.errstate(over="ignore", under="ignore"):
        vertices = surface.vertices * params.scale
    used = vertices[np.unique(surface.faces)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    with np.errstate(over="ignore", invalid="ignore"):  # inf - inf: the size check below names it
        extent = hi - lo
    size = math.hypot(*extent.tolist()) if np.isfinite(vertices).all() else math.inf
    scaled = f" (after scale {params.scale:g})" if params.scale != 1 else ""
    if not _MIN_SIZE <= size <= _MAX_SIZE:
        what = "overflows" if size == math.inf else f"is {size:.3g} m"
        raise MeshError(f"the surface's bounding-box diagonal{scaled} {what}; fTetWild meshes surfaces of "
                        f"{_MIN_SIZE:g} m to {_MAX_SIZE:g} m: give coordinates in m, or set the scale "
                        "(TetrahedralizeParams.scale, --scale) that takes them there")
    # The extent along the principal axes, not x, y, z alone: a tilted sheet is as flat as a level one.
    centred = (used - used.mean(axis=0)) / size
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    across = np.ptp(centred @ axes.T, axis=0) * size
    if across[-1] < _MIN_RELATIVE_EXTENT * size:
        direction = ", ".join(f"{x:.3g}" for x in axes[-1] + 0.0)  # + 0.0: no -0
        raise MeshError(f"the surface is flat: its extent along [{direction}] is {across[-1]:.3g} m, under "
                        f"{_MIN_RELATIVE_EXTENT:g} of its {size:.3g} m diagonal (a sheet, a line or a point encloses no solid)")
    if not surface.is_closed:
        holes, non_manifold = _edges(surface.faces)
        if not allow_open:
            raise MeshError(f"the surface is not closed ({holes} edges belong to one triangle only, {non_manifold} to three or "
                            "more): fTetWild would fill it into a solid of another shape (its bounds and volume change). "
                            "Close the surface, or pass allow_open=True (--allow-open) to mesh it anyway")
        volume = float(np.prod(extent))  # an open surface encloses no definite volume: take its box
    else:
        volume, noise = _volume(vertices, surface.faces)
        if not volume > _MIN_RELATIVE_VOLUME * noise:
            raise MeshError(f"the closed surface encloses no volume ({volume:.3g} m^3, within round-off of zero): "
                            "its triangles cancel out (a doubled or folded sheet)")
    edge = params.edge_length * size
    # A layer one edge thick around the surface: fTetWild refines there to follow it.
    area = float(np.linalg.norm(np.cross(vertices[surface.faces[:, 1]] - vertices[surface.faces[:, 0]],
                                         vertices[surface.faces[:, 2]] - vertices[surface.faces[:, 0]]), axis=1).sum()) / 2
    with np.errstate(all="ignore"):  # numpy floats: a tiny edge gives inf tets, not a ZeroDivisionError
        tets = float(_TETS_PER_EDGE_CUBE * (np.float64(volume) / np.float64(edge) ** 3 + np.float64(area) / np.float64(edge) ** 2))
    limit, source = memory_limit()
    if tets * _BYTES_PER_TET > limit:
        fits = (_TETS_PER_EDGE_CUBE * volume * _BYTES_PER_TET / limit) ** (1 / 3) / size
        needs = (f"about {tets:.3g} tets, {format_bytes(int(tets * _BYTES_PER_TET))}" if math.isfinite(tets)
                 else "more tets and bytes than a float counts")
        raise ConfigError(f"TetrahedralizeParams.edge_length={params.edge_length!r} (--edge-length; a {edge:.3g} m edge) needs {needs} "
                          f"of fTetWild's memory at {format_bytes(_BYTES_PER_TET)} a tet, over the memory limit of {format_bytes(limit)} "
                          f"({source}); an edge length of about {fits:.2g} or more fits")
    return vertices


# Runs fTetWild in a child process: arguments in argv (JSON), arrays in and out as .npy files in
# its working directory; a Python exception becomes error.json and exit status 3.
_CHILD = """
import json, sys
try:
    import numpy as np
    import pytetwild
    kwargs = json.loads(sys.argv[1])
    vertices, tets = pytetwild.tetrahedralize(np.load("vertices.npy"), np.load("faces.npy"), **kwargs)
    np.save("out_vertices.npy", np.asarray(vertices))
    np.save("out_tets.npy", np.asarray(tets))
except BaseException as exc:
    with open("error.json", "w") as fh:
        json.dump({"type": type(exc).__name__, "module": getattr(exc, "name", None), "message": str(exc)}, fh)
    sys.exit(3)
"""


def _ftetwild(vertices: np.ndarray, faces: np.ndarray, kwargs: dict) -> tuple[np.ndarray, np.ndarray]:
    """``pytetwild.tetrahedralize(vertices, faces, **kwargs)`` in a child process, bit for bit its result.

    A crash of the C++ code (a signal, ``std::bad_alloc``) ends the child, not this process.

    Raises:
        MeshError: fTetWild crashed, ran out of memory or raised.
        MissingDependencyError: pytetwild cannot be imported.
    """
    with tempfile.TemporaryDirectory(prefix="licrom-ftetwild-") as scratch:
        # The scratch directory is also fTetWild's working directory: it writes a debug
        # file ("__tracked_surface.stl") there.
        work = Path(scratch)
        np.save(work / "vertices.npy", np.ascontiguousarray(vertices, dtype=np.float64))
        np.save(work / "faces.npy", np.ascontiguousarray(faces, dtype=np.int32))
        done = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(kwargs)], cwd=work, stdin=subprocess.DEVNULL,
                              capture_output=True, check=False)
        said = " ".join(done.stderr.decode(errors="replace").split()[-40:])
        if done.returncode < 0:
            try:
                name = signal.Signals(-done.returncode).name
            except ValueError:
                name = f"signal {-done.returncode}"
            why = signal.strsignal(-done.returncode) or name
            hint = (", most likely by the out-of-memory killer: use a larger edge length" if name == "SIGKILL" else
                    "; fTetWild crashes on some valid surfaces too: another edge length or epsilon may mesh it")
            raise MeshError(f"fTetWild crashed on this surface: killed by {name} ({why}){hint}"
                            + (f"; it printed: {said}" if said else ""))
        if done.returncode == 3 and (work / "error.json").is_file():
            error = json.loads((work / "error.json").read_text())
            if error["type"] == "MemoryError":
                raise MeshError(f"fTetWild ran out of memory ({error['message'] or 'MemoryError'}): use a larger edge length")
            if error["type"] in ("ModuleNotFoundError", "ImportError"):
                raise MissingDependencyError(f"tetrahedralising needs the package '{error['module'] or 'pytetwild'}' "
                                             f"({error['message']}); install it with: pip install pytetwild")
            raise MeshError(f"the tetrahedraliser failed: {error['type']}: {error['message']}")
        if done.returncode != 0:
            raise MeshError(f"fTetWild's process exited with status {done.returncode}" + (f"; it printed: {said}" if said else ""))
        return np.load(work / "out_vertices.npy"), np.load(work / "out_tets.npy")


def tetrahedralize(surface: Surface, params: TetrahedralizeParams = TetrahedralizeParams(), *, allow_open: bool = False) -> Mesh:
    """Fill a surface with tets (fTetWild); return the tet mesh in m, every tet positively oriented.

    fTetWild is not deterministic: two calls give slightly different meshes, so save the
    result (:meth:`Mesh.save`) and simulate the saved mesh. It runs in a child process, so
    that a crash of its C++ code ends as a MeshError instead of ending this process.

    Args:
        surface: the closed surface to fill.
        params: the mesher's settings.
        allow_open: mesh a surface that is not closed (holes, open edges) anyway. fTetWild then
            fills the region its envelope closes off, a solid of another shape: a
            :class:`~licrom.errors.LicromWarning` says how its volume and bounds differ from the surface.

    Raises:
        ConfigError: ``params`` is not a :class:`TetrahedralizeParams`, ``allow_open`` not a bool, or
            the tets would not fit in memory (the message names the edge length that fits).
        MeshError: the scaled surface is out of fTetWild's range (a bounding-box diagonal outside
            1e-4 .. 1e6 m, or overflowing), flat along an axis, open (without ``allow_open``) or
            enclosing no volume; or the mesher crashed, failed or produced no tets.
    """
    if not isinstance(params, TetrahedralizeParams):
        raise ConfigError(f"params must be a TetrahedralizeParams, got {type(params).__name__}")
    if not isinstance(allow_open, bool):
        raise ConfigError(f"allow_open must be True or False, got {allow_open!r}")
    vertices = _check_input(surface, params, allow_open)
    vertices, tets = _ftetwild(vertices, surface.faces, {
        "edge_length_fac": params.edge_length, "epsilon": params.epsilon, "stop_energy": params.stop_energy,
        "num_opt_iter": params.max_iterations, "optimize": params.max_iterations > 0, "coarsen": params.coarsen, "quiet": True,
    })
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
    mesh = Mesh(vertices, tets, fix_orientation=False)
    if not surface.is_closed:
        warnings.warn(LicromWarning(f"the open surface was meshed into a solid of another shape: {_difference(surface, params.scale, mesh)}"),
                      stacklevel=2)
    return mesh
