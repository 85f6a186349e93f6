"""The ``fit_ramp`` step: least-squares slopes of ramps.

One step and its helpers: ``step`` is the step (its function, `Step` class,
consumer and hook); the helpers are ``least_squares`` (the numerics of whole
ramps) and ``segments`` (ramps that are not whole: masked reads, saturation,
jumps).  The per-pixel read noise, gain and dark current come from
``reduce/steps/pixel_maps``, a helper shared with ``detect_jumps``.
"""
