"""Deterministic procedural tet meshes: a box, a sphere and a "cheese" (a block with spherical holes).

All three come from one mesher: a regular grid is cut into cubes, each cube into six
Kuhn tets (a conforming Freudenthal triangulation), cubes whose centre lies inside the
shape are kept, and boundary vertices are moved onto the curved surface where that
does not flatten a tet. ``resolution`` is the number of cells along the longest side;
tets grow with its cube (the cheese reaches 100k tets at about ``resolution=42``).

Sizes are checked before anything is allocated: a ``resolution`` whose mesh (about
``_BYTES_PER_TET`` bytes per tet while meshing) would not fit in the memory limit of
:mod:`licrom._limits` (a fraction of the physical memory, or ``LICROM_MEMORY_LIMIT``), and
a hole count that cannot be placed, give a :class:`~licrom.errors.ConfigError`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from decimal import Decimal
from fractions import Fraction

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .._limits import check_memory, format_size
from ..errors import ConfigError
from .mesh import Mesh

__all__ = ["PROCEDURAL", "CheeseHoles", "box", "cheese", "sphere"]

Sdf = Callable[[np.ndarray], np.ndarray]

# Kuhn decomposition of the unit cube: one tet per permutation of the axes, each a
# monotone path from corner (0,0,0) to corner (1,1,1). Corners are encoded as bits x + 2y + 4z.
_KUHN = np.array(
    [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]],
    dtype=np.int64,
)
# A snapped tet may keep no less than this fraction of its grid volume.
_MIN_VOLUME_FRACTION = 0.15
# Peak bytes per tet while meshing (grid indices, tets, the face-connectivity graph, snapping, the Mesh):
# 1.7-1.9 kB measured for box, sphere and cheese at resolution 20-60, rounded up.
_BYTES_PER_TET = 2048
# Bytes per grid cell before the cells outside the shape are dropped (indices, centres, signed distances),
# and per cell and hole (the cheese's distances to every hole, float64).
_BYTES_PER_CELL = 96
_BYTES_PER_CELL_HOLE = 32


def _check_resolution(resolution: int, minimum: int) -> int:
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < minimum:
        raise ConfigError(f"resolution must be an integer >= {minimum} (cells along the longest side), got {resolution!r}")
    return int(resolution)


def _check_memory(shape: str, extent: np.ndarray, resolution: int, fill: float, holes: int = 0) -> None:
    """Refuse a ``resolution`` whose mesh would not fit in memory, before the grid is made.

    ``fill``: the fraction of the bounding box's cells the shape keeps (1 for a box; its tets, 6 per kept cell).
    """
    # Exact in Python ints (the grid of _grid_mesh): 2**70 gives a ConfigError, not an overflow.
    ratio = extent / extent.max()
    cells = [max(1, round(Fraction(float(x)) * resolution)) for x in ratio]
    n_cells = cells[0] * cells[1] * cells[2]
    tets = 6 * n_cells * Fraction(fill)
    estimate = int(n_cells * (_BYTES_PER_CELL + _BYTES_PER_CELL_HOLE * holes) + tets * _BYTES_PER_TET)
    with_holes = f" and {holes} holes" if holes else ""
    grid = " x ".join(format_size(n) for n in cells)
    check_memory("resolution", resolution, estimate, f"a {shape} of about {Decimal(int(tets)):.3g} tets from a {grid} grid"
                 f"{with_holes}, {_BYTES_PER_TET} bytes per tet while meshing")


def _check_size(size: float | tuple[float, float, float]) -> np.ndarray:
    s = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,)).copy()
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ConfigError(f"size must be positive lengths in m (one number or three), got {size!r}")
    return s


def _signed_volumes(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b, c, d = (v[t[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def _grid_mesh(sdf: Sdf, lower: np.ndarray, upper: np.ndarray, resolution: int, snap: bool) -> Mesh:
    extent = upper - lower
    cells = np.maximum(1, np.round(extent / extent.max() * resolution)).astype(np.int64)
    spacing = extent / cells
    nx, ny, nz = cells
    ix, iy, iz = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    ix, iy, iz = ix.ravel(), iy.ravel(), iz.ravel()
    centres = lower + (np.stack([ix, iy, iz], axis=1) + 0.5) * spacing
    keep = sdf(centres) < 0.0
    ix, iy, iz = ix[keep], iy[keep], iz[keep]

    def vid(i: np.ndarray, j: np.ndarray, k: np.ndarray) -> np.ndarray:
        return (i * (ny + 1) + j) * (nz + 1) + k

    corners = np.stack(
        [vid(ix + (b & 1), iy + ((b >> 1) & 1), iz + ((b >> 2) & 1)) for b in range(8)], axis=1
    )
    tets = corners[:, _KUHN].reshape(-1, 4)

    # Keep the largest face-connected piece (a hole can cut off a sliver of cells).
    n_grid = (nx + 1) * (ny + 1) * (nz + 1)
    rows = np.repeat(np.arange(len(tets)), 4)
    incidence = coo_matrix((np.ones(rows.size), (rows, tets.ravel())), shape=(len(tets), n_grid)).tocsr()
    _, labels = connected_components(incidence @ incidence.T, directed=False)
    tets = tets[labels == np.bincount(labels).argmax()]

    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(-1, 4)
    i, rem = np.divmod(used, (ny + 1) * (nz + 1))
    j, k = np.divmod(rem, nz + 1)
    verts = lower + np.stack([i, j, k], axis=1) * spacing

    vol = _signed_volumes(verts, tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    if snap:
        verts = _snap_to_surface(sdf, verts, tets, np.abs(vol), float(spacing.min()))
    return Mesh(verts, tets, fix_orientation=False)


def _snap_to_surface(sdf: Sdf, verts: np.ndarray, tets: np.ndarray, grid_volume: np.ndarray, h: float) -> np.ndarray:
    """Move boundary vertices onto the zero level set, backing off where a tet would flatten."""
    faces = tets[:, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]].reshape(-1, 3)
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    boundary = np.unique(faces[counts[inv.ravel()] == 1])
    p = verts[boundary]
    eps = 1e-4 * h
    grad = np.stack(
        [(sdf(p + eps * e) - sdf(p - eps * e)) / (2 * eps) for e in np.eye(3)], axis=1
    )
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    move = np.zeros_like(verts)
    move[boundary] = -sdf(p)[:, None] * grad
    # Never move more than a cell; a larger move means the gradient is unreliable there.
    too_far = np.linalg.norm(move, axis=1) > h
    move[too_far] = 0.0
    scale = np.ones(len(verts))
    for _ in range(12):
        moved = verts + scale[:, None] * move
        bad = _signed_volumes(moved, tets) < _MIN_VOLUME_FRACTION * grid_volume
        if not bad.any():
            return moved
        scale[np.unique(tets[bad])] *= 0.5
    scale[np.unique(tets[_signed_volumes(verts + scale[:, None] * move, tets) < _MIN_VOLUME_FRACTION * grid_volume])] = 0.0
    return verts + scale[:, None] * move


def _box_sdf(half: np.ndarray, centre: np.ndarray) -> Sdf:
    def sdf(p: np.ndarray) -> np.ndarray:
        q = np.abs(p - centre) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    return sdf


def box(size: float | tuple[float, float, float] = 0.1, resolution: int = 8) -> Mesh:
    """An axis-aligned box centred at the origin.

    Args:
        size: edge lengths in m (one number for a cube, or three).
        resolution: cells along the longest edge (>= 1).
    """
    s = _check_size(size)
    res = _check_resolution(resolution, 1)
    _check_memory("box", s, res, 1.0)
    return _grid_mesh(_box_sdf(s / 2, np.zeros(3)), -s / 2, s / 2, res, snap=False)


def sphere(radius: float = 0.05, resolution: int = 12) -> Mesh:
    """A ball centred at the origin, its boundary vertices snapped onto the sphere.

    Args:
        radius: radius in m.
        resolution: cells across the diameter (>= 4).
    """
    r = float(_check_size(radius)[0])
    res = _check_resolution(resolution, 4)
    _check_memory("sphere", np.ones(3), res, np.pi / 6)  # the cells whose centre is in the ball
    sdf: Sdf = lambda p: np.linalg.norm(p, axis=1) - r  # noqa: E731
    return _grid_mesh(sdf, np.full(3, -r), np.full(3, r), res, snap=True)


@dataclass(frozen=True)
class CheeseHoles:
    """Spherical holes of a cheese block.

    Attributes:
        count: number of holes.
        min_radius: smallest hole radius as a fraction of the block's shortest side.
        max_radius: largest hole radius as a fraction of the block's shortest side.
        seed: random seed of the hole layout (the mesh is deterministic for a seed).
    """

    count: int = 10
    min_radius: float = 0.12
    max_radius: float = 0.22
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.count, bool) or not isinstance(self.count, (int, np.integer)) or self.count < 0:
            raise ConfigError(f"CheeseHoles.count must be an integer >= 0, got {self.count!r}")
        if not 0 < self.min_radius <= self.max_radius < 0.5:
            raise ConfigError(
                f"CheeseHoles radii must satisfy 0 < min_radius <= max_radius < 0.5 (fractions of the shortest side), "
                f"got {self.min_radius}, {self.max_radius}"
            )

    def most(self, size: np.ndarray) -> int:
        """An upper bound of the holes that fit in a block of ``size`` (m): a larger count can never be placed.

        Hole centres keep ``(2 min_radius + 0.1) x`` the shortest side apart, so balls of half that
        diameter around them are disjoint, inside the block grown by that radius: their volumes bound the count.
        """
        gap = 2 * self.min_radius + 0.1  # x the shortest side
        # In units of the gap (no overflow for tiny or huge blocks); a block too long for a float gets 2**62.
        with np.errstate(over="ignore"):
            grown = (size / size.min() - 0.6 * self.min_radius + gap) / gap  # centres stay 0.3 r inside each face
            return int(min(np.prod(grown) / (np.pi / 6), 2.0**62))

    def layout(self, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hole centres (k, 3) and radii (k,) in m for a block of ``size`` centred at the origin.

        Raises:
            ConfigError: more holes than can fit (:meth:`most`, at once), or fewer placed than ``count``
                in ``200 count`` random tries (naming how many were placed).
        """
        size = np.asarray(size, dtype=np.float64)
        most = self.most(size)
        block = " x ".join(f"{x:g}" for x in size)
        if self.count > most:
            raise ConfigError(f"CheeseHoles.count must be at most {most} for a {block} m block (holes of radius >= min_radius="
                              f"{self.min_radius} x its shortest side, {0.1 * size.min():g} m apart, cannot fit more), got {format_size(self.count)}")
        rng = np.random.default_rng(self.seed)
        short = float(size.min())
        centres = np.empty((self.count, 3))
        radii = np.empty(self.count)
        k = 0
        tries = 200 * max(self.count, 1)
        for _ in range(tries):
            if k == self.count:
                break
            r = short * rng.uniform(self.min_radius, self.max_radius)
            # Centres may sit slightly outside the block so some holes open onto its faces.
            c = rng.uniform(-size / 2 + 0.3 * r, size / 2 - 0.3 * r)
            if np.all(np.linalg.norm(c - centres[:k], axis=1) > r + radii[:k] + 0.1 * short):
                centres[k], radii[k] = c, r
                k += 1
        if k < self.count:
            raise ConfigError(f"CheeseHoles.count={self.count}: only {k} holes could be placed in the {block} m block (seed "
                              f"{self.seed}, {tries} random tries); ask for at most {k}, smaller holes (min_radius, max_radius) "
                              "or another seed")
        return centres, radii


def cheese(
    size: float | tuple[float, float, float] = (0.2, 0.12, 0.1),
    resolution: int = 12,
    holes: CheeseHoles = CheeseHoles(),
) -> Mesh:
    """A block with spherical holes, some opening onto its faces (like the report's cheese).

    Args:
        size: block edge lengths in m.
        resolution: cells along the longest edge (>= 4); about 1.5 * resolution^3 tets
            for the default size (12 -> ~2.5k tets, 42 -> ~110k tets).
        holes: hole count, radii and layout seed. Different seeds give different hole
            layouts of the same block.
    """
    s = _check_size(size)
    res = _check_resolution(resolution, 4)
    if not isinstance(holes, CheeseHoles):
        raise ConfigError(f"holes must be a CheeseHoles, got {type(holes).__name__}")
    if holes.count <= holes.most(s):  # else layout names the count, not the resolution
        _check_memory("cheese", s, res, 1.0, holes.count)
    centres, radii = holes.layout(s)
    block = _box_sdf(s / 2, np.zeros(3))

    def sdf(p: np.ndarray) -> np.ndarray:
        d = block(p)
        if len(radii):
            holes_d = (np.linalg.norm(p[:, None, :] - centres[None], axis=2) - radii).min(axis=1)
            d = np.maximum(d, -holes_d)
        return d

    return _grid_mesh(sdf, -s / 2, s / 2, res, snap=True)


PROCEDURAL = {"box": box, "sphere": sphere, "cheese": cheese}
