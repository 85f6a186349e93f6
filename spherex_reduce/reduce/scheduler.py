"""Where sweep cells run: dask scheduler addresses checked, clients and local clusters.

`check_scheduler` refuses, within seconds, an address where no dask scheduler
answers; `quiet_dask_logs` keeps dask.distributed's logs out of the output;
`signals_held` keeps an interrupt from cutting a cluster's start or stop
short.
"""

import asyncio
import concurrent.futures
import contextlib
import logging
import signal
import sys
import threading

from ..core.errors import ConfigError
from ..core.limits import MAX_WORKERS, check_count

__all__ = ["HELD_SIGNALS", "check_scheduler", "dask_client", "map_on_dask", "quiet_dask_logs",
           "signals_held"]


#: loggers of the event loops dask's client and workers run on: when a run is interrupted
#: (Ctrl-C to the process group: the workers die with the client), their loops log
#: "Exception in callback" errors of dask's own ``sync`` machinery being torn down
EVENT_LOOP_LOGGERS = ("asyncio", "tornado")


def quiet_dask_logs(level=logging.CRITICAL):
    """Raise the level of dask.distributed's loggers, and of the event loops' it runs on
    (`EVENT_LOOP_LOGGERS`); by default, silence them.

    They log every connection at INFO and, when a worker dies or a run is
    interrupted, warnings and errors of their own (a task rescheduled, a worker
    restarted, a callback of the client's loop cancelled); what matters reaches the
    command as a task's result or error.
    """
    import distributed  # noqa: F401  (creates its loggers)

    # every logger under them: distributed's own configuration sets some children's level
    # (tornado.application at ERROR, whose "Exception in callback ... sync.<locals>.cancel"
    # an interrupted batch printed as a second line)
    families = {"distributed", *EVENT_LOOP_LOGGERS}
    for name in list(logging.root.manager.loggerDict):
        if name.split(".")[0] in families:
            logging.getLogger(name).setLevel(level)
    for name in EVENT_LOOP_LOGGERS:
        logging.getLogger(name).setLevel(level)


def check_scheduler(address, timeout=5.0, name="scheduler"):
    """Refuse, within ``timeout`` seconds, a dask scheduler address that is not reachable.

    ``None`` (an embedded cluster) and ``"serial"`` pass.  Otherwise the address
    must parse as a dask address, and a dask scheduler must answer there: dask's
    own client waits 30 s, or for ever on a server that accepts and stays silent.

    Parameters
    ----------
    address : str or None
        E.g. ``"tcp://host:8786"``.
    timeout : float
        Seconds to wait for the connection.
    name : str
        How the message names the setting (the CLI passes ``"--scheduler"``).

    Raises
    ------
    ConfigError
        Naming the address and the reason.

    Examples
    --------
    >>> from spherex_reduce.reduce.scheduler import check_scheduler
    >>> check_scheduler("serial")
    >>> check_scheduler("not a url")
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: scheduler 'not a url': not a dask ...
    """
    if address is None or address == "serial":
        return
    from distributed.comm import parse_address, parse_host_port

    try:
        scheme, loc = parse_address(address)
        port = parse_host_port(loc)[1] if scheme in ("tcp", "tls") else None
        if any(c.isspace() for c in address) or (scheme in ("tcp", "tls") and not port):
            raise ValueError("no host:port")
    except (ValueError, TypeError):
        raise ConfigError(f"{name} {address!r}: not a dask scheduler address (e.g. "
                          "tcp://host:8786, or 'serial')") from None
    try:
        with concurrent.futures.ThreadPoolExecutor(1) as pool:  # also under a running loop
            reply = pool.submit(asyncio.run, _identity(address, timeout)).result()
    except Exception as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ConfigError(f"{name} {address}: no dask scheduler answered within {timeout:g} s "
                          f"({reason})") from None
    if not (isinstance(reply, dict) and reply.get("type") == "Scheduler"):
        raise ConfigError(f"{name} {address}: answered, but is not a dask scheduler")


async def _identity(address, timeout):
    """The ``identity`` reply of the dask server at ``address``, within ``timeout`` seconds."""
    from distributed.comm import connect

    async def ask():
        comm = await connect(address, timeout=timeout)
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    return await asyncio.wait_for(ask(), timeout)


def dask_client(scheduler, workers):
    """A dask client for ``scheduler``, or for a new local cluster.

    Parameters
    ----------
    scheduler : str, `distributed.Client` or None
        A scheduler's address (checked first: `check_scheduler`), a client
        (used as it is), or None: a new ``LocalCluster`` of ``workers``
        single-threaded processes.
    workers : int or None
        Workers of a new local cluster (default 2).

    Returns
    -------
    client : `distributed.Client`
    cluster : `distributed.LocalCluster` or None
        The cluster made here, if any.
    owned : bool
        Whether the caller closes the client (and the cluster).

    Raises
    ------
    ConfigError
        The scheduler cannot be reached as a dask scheduler.

    Examples
    --------
    An address where no scheduler answers is refused:

    >>> from spherex_reduce.reduce.scheduler import dask_client
    >>> dask_client("no-such-host:1", None)
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: scheduler no-such-host:1: ...
    """
    from distributed import Client, LocalCluster

    if isinstance(scheduler, Client):
        return scheduler, None, False
    if scheduler:
        check_scheduler(scheduler)
        try:
            return Client(scheduler, timeout=10), None, True
        except (OSError, TimeoutError, ValueError, TypeError, MemoryError) as exc:
            # a closed port, a server that does not speak dask, an address that does not parse
            raise ConfigError(f"scheduler {scheduler}: cannot connect as a dask client "
                              f"({type(exc).__name__}: {exc})") from None
    workers = 2 if workers is None else check_count(workers, "workers", MAX_WORKERS)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0", preload=[f"{__package__}.dask_worker"])
    return Client(cluster), cluster, True


def map_on_dask(function, tasks, scheduler, workers, collect, failed):
    """Run ``function`` on every task on dask, handing each result over as it comes.

    ``scheduler`` and ``workers`` are as for the sweep: None and a number of
    worker processes for a new `~distributed.LocalCluster` (closed at the
    end), or a scheduler's address.  ``collect(task, result)`` is called in
    this process as each task finishes; a task whose worker died (e.g. out of
    memory) gets ``failed(task, exception)`` as its result instead, and the
    others go on.
    """
    from distributed import as_completed

    client, cluster, owned = None, None, False
    if scheduler is None:
        _start_resource_tracker()
    try:
        with signals_held():  # dask interrupted half-way through starting prints tracebacks
            client, cluster, owned = dask_client(scheduler, workers)
        futures = client.map(function, tasks, pure=False)
        task_of = {fut.key: task for fut, task in zip(futures, tasks, strict=True)}
        for fut in as_completed(futures):
            task = task_of[fut.key]
            try:
                result = fut.result()
            except Exception as exc:  # the worker died: report this task, go on
                result = failed(task, exc)
            collect(task, result)
            fut.release()
    finally:
        with signals_held():  # and half-way through stopping
            if owned:
                client.close()
            if cluster is not None:
                cluster.close()


def _start_resource_tracker():
    """Start multiprocessing's resource tracker, quietly, before a LocalCluster starts.

    The tracker (one process, started with the first worker process) removes
    what a worker killed outright leaves (semaphores); it then warns about them
    on stderr, which the one-line contract does not allow: it is started here
    with its warnings off.  Started by the cluster instead, it would also
    unblock the signals `signals_held` holds in the thread starting the
    workers.  Nothing is done if it already runs.
    """
    from multiprocessing import resource_tracker

    quiet = "ignore::UserWarning"  # the tracker's only warnings are about what it cleans up
    added = quiet not in sys.warnoptions
    if added:  # passed on to the tracker's command line (-W), as the interpreter's own
        sys.warnoptions.append(quiet)
    try:
        resource_tracker.ensure_running()
    finally:
        if added:
            sys.warnoptions.remove(quiet)


#: The signals `signals_held` holds back: an interrupt (Ctrl-C) and ``kill``'s default.
HELD_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM})


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM back for a ``with`` block (of the main thread); act on them after.

    A signal that arrives in the block is delivered when it ends (e.g. a
    `KeyboardInterrupt` then).  Threads started in the block, and the processes
    they start (a LocalCluster's event loop and its worker processes), keep the
    signals blocked: in this process they are handled by the main thread only;
    a worker process unblocks them when it is set up
    (`spherex_reduce.reduce.dask_worker`).  Elsewhere than on the main thread,
    or where signals cannot be blocked, the block runs as it is.

    Examples
    --------
    >>> from spherex_reduce.reduce.scheduler import signals_held
    >>> with signals_held():
    ...     pass  # start a cluster: Ctrl-C now waits until it has started
    """
    if threading.current_thread() is not threading.main_thread() or \
            not hasattr(signal, "pthread_sigmask"):
        yield
        return
    before = signal.pthread_sigmask(signal.SIG_BLOCK, HELD_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)
