"""Set-up of each worker process of an embedded dask LocalCluster (a dask *preload*).

`~spherex_reduce.reduce.scheduler.map_on_dask` starts its
`~distributed.LocalCluster` with this module as the workers' preload, so that
every worker process, and each one dask starts again after a worker died:

- ignores ``SIGINT``: Ctrl-C reaches the whole process group, and the command
  (which stops the cluster, workers included) is the one to handle it; a
  worker would print its own traceback.  It starts with ``SIGINT`` and
  ``SIGTERM`` blocked (`~spherex_reduce.reduce.scheduler.signals_held`), so a
  Ctrl-C while it starts is not seen either; ``SIGTERM`` is unblocked again
  (``kill`` ends a worker at once, as any process);
- keeps dask.distributed's logs quiet (`~spherex_reduce.reduce.scheduler.quiet_dask_logs`):
  a worker stopped mid-task logs warnings of its own to the terminal, which
  the command's one-line contract does not allow.  Failures still reach the
  command as the task's error.
"""

import signal

from .scheduler import HELD_SIGNALS, quiet_dask_logs

__all__ = ["dask_setup"]


def dask_setup(worker):
    """Called by dask in the worker process as it starts (see the module docstring)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, HELD_SIGNALS)
    quiet_dask_logs()
