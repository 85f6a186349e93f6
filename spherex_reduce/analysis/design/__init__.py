"""Readout design: the schedule of least forecast band power within a frame-time budget.

``file`` reads DESIGN.yaml (what is searched, for which noise), ``row_orders``
builds the families of read orders, and ``search`` runs the search, its
report and the paired Monte Carlo (``spherex-reduce design-readout``).
"""
