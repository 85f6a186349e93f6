"""The ``detect_jumps`` step: the read at which a pixel's charge stepped (cosmic rays).

``step`` is the step (its function, `Step` class, kernel and hook); ``search``
the numerics of the search.
"""
