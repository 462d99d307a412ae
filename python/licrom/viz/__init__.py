"""Pictures: filmstrips, animations and plots (:mod:`.render`), the report of a run (:mod:`.report`) and the plotting back end (:mod:`._plot`).

Above the analysis whose metrics they draw.
"""
