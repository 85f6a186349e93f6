"""Readout design: the schedule of least forecast band power within a frame-time budget.

The public entry is ``search.design_readout`` (``spherex-reduce
design-readout``).  ``file`` reads DESIGN.yaml (what is searched, for which
noise), ``row_orders`` builds the families of read orders, and ``search`` runs
the search, its report and the paired Monte Carlo, each candidate judged by
the forecast (`spherex_reduce.analysis.forecast`).
"""
