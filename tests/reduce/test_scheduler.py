"""quiet_dask_logs: what an interrupted dask run's event loops log stays out of the output."""

import asyncio
import logging

import pytest

from spherex_reduce.reduce.scheduler import EVENT_LOOP_LOGGERS, quiet_dask_logs


@pytest.fixture
def restored_levels():
    pytest.importorskip("distributed")  # its loggers exist before their levels are kept
    names = [*EVENT_LOOP_LOGGERS, *(n for n in logging.root.manager.loggerDict
                                    if n.split(".")[0] in ("distributed", *EVENT_LOOP_LOGGERS))]
    levels = {n: logging.getLogger(n).level for n in names}
    yield
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


def _boom():
    raise RuntimeError("cancelled while the loop closes")


def _failing_callback_logs(caplog):
    """Run an event loop whose callback raises (as dask's ``sync`` cancel did when a
    batch was interrupted); the records asyncio's handler logged."""
    caplog.clear()
    loop = asyncio.new_event_loop()
    try:
        loop.call_soon(_boom)
        loop.call_soon(loop.stop)
        loop.run_forever()
    finally:
        loop.close()
    return [r for r in caplog.records if r.name == "asyncio"]


def test_an_event_loop_callback_error_is_silenced_only_once_quieted(caplog, restored_levels):
    caplog.set_level(logging.WARNING)
    logging.getLogger("asyncio").setLevel(logging.NOTSET)
    assert [r.levelname for r in _failing_callback_logs(caplog)] == ["ERROR"]
    quiet_dask_logs()
    assert _failing_callback_logs(caplog) == []
    assert logging.getLogger("distributed.scheduler").getEffectiveLevel() == logging.CRITICAL


def _tornado_callback_logs(caplog):
    """The same on tornado's IOLoop (dask's client loop): the records it logged."""
    from tornado.ioloop import IOLoop

    caplog.clear()
    loop = IOLoop(make_current=False)
    try:
        loop.add_callback(_boom)
        loop.add_callback(loop.stop)
        loop.start()
    finally:
        loop.close()
    return [r for r in caplog.records if r.name.split(".")[0] == "tornado"]


def test_tornados_callback_error_is_silenced_though_dask_sets_its_level(caplog,
                                                                         restored_levels):
    """distributed's own logging configuration sets ``tornado.application`` to ERROR, so
    silencing ``tornado`` alone left its "Exception in callback" line: a batch interrupted
    on dask printed it as a second line (CI, 2026-12-01)."""
    caplog.set_level(logging.WARNING)
    logging.getLogger("tornado.application").setLevel(logging.ERROR)  # (distributed's)
    assert [r.levelname for r in _tornado_callback_logs(caplog)] == ["ERROR"]
    quiet_dask_logs()
    assert _tornado_callback_logs(caplog) == []
