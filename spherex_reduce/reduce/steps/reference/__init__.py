"""The ``correct_reference`` step and its strategies (paper §2.4, §4.3, §5.4).

One step and its helpers: ``step`` is the step (its function, `Step` class,
kernel and hook, which also registers the built-in strategies); the others are
helpers.  ``strategies`` holds the built-in strategies (mean, ACN, median) and
how a strategy is chosen; ``wiener`` the ``wiener`` strategy and
``noise_models`` the noise model it reads; ``strategy_checks`` checks what any
strategy (a plugin's too) returns; ``telegraph`` finds the telegraph reference
pixels the step leaves out.  A new built-in strategy goes beside them (a
plugin's registers itself, see the plugin guide).
"""
