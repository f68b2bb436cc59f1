"""Ctrl-C and SIGTERM: a run stops between two substeps, with its frames and checkpoints kept.

An exception raised by a signal handler surfaces wherever the interpreter happens to be, also inside a Numba
dispatcher, which turns it into a SystemError traceback. While a simulation polls (`polling`), the handler only
records the signal and `check`, called between substeps, raises it; otherwise (loading, sampling, rendering) it
raises at once. A second signal during a stop raises at once too.
"""

import signal
from contextlib import contextmanager


class Terminated(KeyboardInterrupt):
    """SIGTERM (a batch system ending a job, `kill`): handled as Ctrl-C is."""


_state = {"polling": False, "pending": None}


def _stop(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _handler(signum, frame):
    if _state["polling"] and _state["pending"] is None:
        _state["pending"] = signum
        return
    raise _stop(signum)


def install() -> None:
    signal.signal(signal.SIGINT, _handler)
    signal.signal(signal.SIGTERM, _handler)


@contextmanager
def polling():
    """Within this block a signal waits for `check`."""
    _state["polling"], _state["pending"] = True, None
    try:
        yield
    finally:
        _state["polling"] = False


def check() -> None:
    """Raise the signal that arrived since the last check (KeyboardInterrupt, or Terminated for SIGTERM)."""
    signum = _state["pending"]
    if signum is not None:
        _state["polling"] = False
        raise _stop(signum)
