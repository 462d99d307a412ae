"""Scenes: what is simulated around a mesh (:mod:`.scene`: material, planes, contact, solver, initial state),
where the object is placed on a plane (:mod:`.placement`), and sweeps over frictions, slopes or planes and
initial states (:mod:`.sweep`: their order, count, default friction and held-out pairs).

Above geometry; every simulation reads a scene.
"""
