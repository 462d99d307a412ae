"""Geometry: tetrahedral meshes (:mod:`.mesh`), procedural ones (:mod:`.meshes`), surfaces filled with tets (:mod:`.surface`),
well-spread subsets of point sets (:mod:`.points`) and closest points on triangles (:mod:`.closest`).

The layer above the foundation: it knows meshes, not physics.
"""
