"""Analysis: full against reduced, run on one scene and measured (:mod:`.compare`).

Above both simulations, which it runs side by side.
"""
