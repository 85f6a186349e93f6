"""The ``detect_jumps`` step: the read at which a pixel's charge stepped (cosmic rays).

One step and its helpers: ``step`` is the step (its function, `Step` class,
kernel and hook); ``search`` the numerics of the search; ``events`` the reads
off for most pixels (read events) told from cosmic rays; ``telegraph`` the
pixels that flip down and back up, told from cosmic rays.  The
per-pixel read noise and gain come from ``reduce/steps/pixel_maps``, a helper
shared with ``fit_ramp``.
"""
