"""The ``detect_jumps`` step: the read at which a pixel's charge stepped (cosmic rays).

One step and its helper: ``step`` is the step (its function, `Step` class,
kernel and hook); ``search`` the numerics of the search (its helper).  The
per-pixel read noise and gain come from ``reduce/steps/pixel_maps``, a helper
shared with ``fit_ramp``.
"""
