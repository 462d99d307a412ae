"""Analysis: full against reduced, run on one scene and measured (:mod:`.compare`), and how far a scene's own full
run moves when its inputs move a little (:mod:`.sensitivity`).

Above both simulations, which it runs side by side.
"""
