"""The application: the ``licrom`` command (:mod:`.commands`) and its demo (:mod:`.demo`).

The top layer; it may import any other.
"""
