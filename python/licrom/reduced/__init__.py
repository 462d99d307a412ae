"""Reduced simulation: the Rust core stepped in a subspace.

:mod:`.base` holds what every reduced simulation shares (the base class :class:`~licrom.reduced.base.ReducedSim`,
sampling, stepping, batches); :mod:`.world` the world-frame simulation, :mod:`.body` the body-frame one;
:mod:`.factory` the one function that picks between them; :mod:`.error_estimate` the online error estimate.
"""
