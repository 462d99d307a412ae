"""Point sets: well-spread subsets by farthest-point sampling.

One sampler for every place that spreads a few choices over many candidates: contact points over a
surface (:meth:`licrom.subspace.cubature.ContactPoints.subset`), the error estimate's sample vertices
(:func:`licrom.reduced.error_estimate.sample_vertices`) and the training runs the dynamics check replays
(:func:`licrom.learn.training.dynamics.check_dynamics`).
"""

from __future__ import annotations

import numpy as np

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
    """
    points = np.asarray(points, dtype=np.float64)
    start = int(np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1))) if first is None else int(first)
    chosen = [start]
    dist = np.linalg.norm(points - points[start], axis=1)
    for _ in range(count - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(points - points[nxt], axis=1))
    return np.array(chosen)
