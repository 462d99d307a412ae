"""Geometry: tetrahedral meshes (:mod:`.mesh`), procedural ones (:mod:`.meshes`) and surfaces filled with tets (:mod:`.surface`).

The layer above the foundation: it knows meshes, not physics.
"""
