"""The paper's figures and the demo: simulate, measure, draw, judge.

The public entries are ``reproduce.make_figures`` (``spherex-reduce
figures``) and ``demo.run_demo`` (``spherex-reduce demo``).  ``paper`` (one
function per figure of the paper), ``reproduce`` (all of them: PNGs, numbers
and a Markdown report), ``report`` (claims and verdicts), ``forecast`` (Figs.
6-9 as forecast curves over Monte Carlo points), ``plots`` (P(k), 2-D FFT and
PSD-fit figures) and ``demo`` (the demo's products).
"""
