"""Closest points on triangles, for many points at once.

The region test of Ericson, *Real-Time Collision Detection* (2005), section 5.1.5: the point is
compared with the triangle's Voronoi regions (three vertices, three edges, the face) by dot
products, and projected onto the one it lies in. Used by :meth:`licrom.Mesh.nearest_surface_points`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["closest_points_on_triangles"]


def closest_points_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """The point of triangle ``(a, b, c)`` nearest ``p``, row by row.

    Args:
        p: (n, 3) points, m.
        a: (n, 3) the triangles' first corners, m (broadcast against ``p``, as are ``b`` and ``c``).
        b: (n, 3) their second corners, m.
        c: (n, 3) their third corners, m.

    Returns:
        (n, 3) nearest points, each on its triangle (corners, edges and interior included).
    """
    p, a, b, c = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (p, a, b, c)))
    ab, ac, ap, bp, cp = b - a, c - a, p - a, p - b, p - c

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ni->n", u, v)

    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
        # Only read where its region holds, where den > 0; elsewhere any finite value does.
        return (num / np.where(den != 0.0, den, 1.0))[:, None]

    total = va + vb + vc
    face = a + ab * ratio(vb, total) + ac * ratio(vc, total)
    regions = [  # first match wins, as in the book's order of tests
        ((d1 <= 0) & (d2 <= 0), a),
        ((d3 >= 0) & (d4 <= d3), b),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * ratio(d1, d1 - d3)),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * ratio(d2, d2 - d6)),
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * ratio(d4 - d3, (d4 - d3) + (d5 - d6))),
    ]
    out = face
    for mask, point in reversed(regions):
        out = np.where(mask[:, None], point, out)
    return out
