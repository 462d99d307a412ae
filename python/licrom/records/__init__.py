"""Records: trajectories of a run and their files (:mod:`.trajectory`), and their exports to VTU and USD (:mod:`.export`).

Above scenes: a record names the scene it ran.
"""
