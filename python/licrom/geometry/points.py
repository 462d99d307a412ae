"""Point sets: well-spread subsets by farthest-point sampling.

One sampler for every place that spreads a few choices over many candidates: contact points over a
surface (:meth:`licrom.subspace.cubature.ContactPoints.subset`), the error estimate's sample vertices
(:func:`licrom.reduced.error_estimate.sample_vertices`) and the training runs the dynamics check replays
(:func:`licrom.learn.training.dynamics.check_dynamics`).
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError, ShapeError

__all__ = ["farthest_points"]


def farthest_points(points: np.ndarray, count: int, first: int | None = None) -> np.ndarray:
    """Indices of ``count`` well-spread rows of ``points``, in the order they were chosen.

    Greedy farthest-point sampling: each next row is the one farthest (Euclidean) from those chosen so far.

    Args:
        points: (p, d) candidates.
        count: rows chosen, 1 <= count <= p.
        first: the row to start from (default: the one nearest the centroid).

    Returns:
        (count,) distinct row indices.

    Raises:
        ShapeError: ``points`` not a (p, d) array of finite values with p >= 1.
        ConfigError: ``count`` not an integer in [1, p], or ``first`` not a row index.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or len(points) < 1 or not np.all(np.isfinite(points)):
        raise ShapeError(f"farthest_points needs a (p, d) array of finite values with p >= 1, got shape {points.shape}")
    for name, value, low, high in (("count", count, 1, len(points)), ("first", first, 0, len(points) - 1)):
        if name == "first" and value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
            raise ConfigError(f"farthest_points: {name} must be an integer in [{low}, {high}], got {value!r}")
    start = int(np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1))) if first is None else int(first)
    chosen = [start]
    dist = np.linalg.norm(points - points[start], axis=1)
    for _ in range(count - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return np.array(chosen)
