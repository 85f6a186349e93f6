"""The commands that learn a detector's noise from its darks: ``fit-noise`` (one α, β, γ
fit of the reference and phantom streams) and ``characterize`` (every stream term the
simulator models, as a scene)."""
