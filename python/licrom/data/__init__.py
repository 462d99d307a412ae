"""Data: scene files and their sweeps (:mod:`.scene_file`), the built-in presets (:mod:`.presets`) and data sets of full simulations (:mod:`.dataset`).

Above the full simulation, which a data set runs once per run of its sweep.
"""
