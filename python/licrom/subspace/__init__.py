"""Subspaces: the affine modes (:mod:`.affine`), bases and their projector (:mod:`.basis`),
body-frame modes (:mod:`.body_basis`), and the cubature and contact points they are sampled at
(:mod:`.cubature`).

Above geometry and scenes; below the reduced simulation that steps in a subspace.
"""
