"""The ``fit_ramp`` step: least-squares slopes of ramps.

``step`` is the step (its function, `Step` class, consumer and hook);
``least_squares`` the numerics of whole ramps; ``segments`` ramps that are not
whole (masked reads, saturation, jumps).
"""
