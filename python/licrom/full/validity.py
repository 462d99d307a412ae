"""What the valid range of the physics needs from every step (:mod:`licrom.validity`):
the smallest tet ``det F`` and the smallest gap of a vertex to a plane, reduced on the
device into ``parts`` partial minima (as the energy's partial sums, both rows starting at
+inf), so that checking every step costs one pass over the tets and vertices and no copy
of the state."""

from __future__ import annotations

import warp as wp

from .contact import Contacts, gap
from .device import f64, vec3d
from .elastic import Tets, deformation_gradient

__all__ = ["depth_kernel", "tet_det_kernel"]


@wp.kernel
def tet_det_kernel(x: wp.array(dtype=vec3d), tets: Tets, out: wp.array2d(dtype=f64)):
    """``out[0, t % parts] = min det F`` over the tets."""
    t = wp.tid()
    wp.atomic_min(out, 0, t % out.shape[1], wp.determinant(deformation_gradient(x, tets.ids[t], tets.dminv[t])))


@wp.kernel
def depth_kernel(x: wp.array(dtype=vec3d), c: Contacts, out: wp.array2d(dtype=f64)):
    """``out[1, v % parts] = min`` over the planes of the vertices' gaps (negative inside), m."""
    v = wp.tid()
    for p in range(c.normals.shape[0]):
        wp.atomic_min(out, 1, v % out.shape[1], gap(c, p, x[v]))
