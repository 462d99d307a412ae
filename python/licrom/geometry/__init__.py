"""Geometry: tetrahedral meshes (:mod:`.mesh`), procedural ones (:mod:`.meshes`), surfaces filled with tets (:mod:`.surface`)
and well-spread subsets of point sets (:mod:`.points`).

The layer above the foundation: it knows meshes, not physics.
"""
