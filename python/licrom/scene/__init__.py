"""Scenes: what is simulated around a mesh (:mod:`.scene`: material, planes, contact, solver, initial state) and where the object is placed on a plane (:mod:`.placement`).

Above geometry; every simulation reads a scene.
"""
