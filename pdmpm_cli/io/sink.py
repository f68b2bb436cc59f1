"""Frame output off the simulation's critical path: one background thread feeds all writers.

The simulation hands each frame to :meth:`FrameSink.submit`, which copies the arrays (the solver
keeps mutating its own) and queues them; at most two frames wait, so a slow disk throttles the
simulation instead of filling memory. :meth:`FrameSink.call` queues other work (a checkpoint) in
the same order. A writer failure is raised in the simulation thread on the next ``submit`` or on
``close``.
"""

from __future__ import annotations

import queue
import re
import threading
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from pdmpm_cli.errors import OutputError, PdmpmError

_QUEUE_SIZE = 2
_STOP = None


class FrameWriter(Protocol):
    def write_frame(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None: ...

    def close(self) -> None: ...


def check_order(path, closed: bool, last_index: int, index: int) -> None:
    """A writer takes frames in increasing order until it is closed; ValueError otherwise."""
    if closed:
        raise ValueError(f"{path}: writer is closed")
    if index <= last_index:
        raise ValueError(f"frame index {index} out of order: the last frame written was {last_index}")


class FrameWriteError(OutputError):
    """Writing or closing an output failed; the original exception is the ``__cause__``."""

    exit_code = 1


def _describe(writer: FrameWriter) -> str:
    path = getattr(writer, "path", None)
    return f"{path}:" if path is not None else type(writer).__name__


def _reason(exc: BaseException) -> str:
    """What went wrong, in words: our own message, or an OSError's message and file."""
    if isinstance(exc, PdmpmError):
        return str(exc)
    if isinstance(exc, OSError) and exc.strerror:
        return f"{exc.strerror}: {exc.filename}" if exc.filename else exc.strerror
    found = re.search(r"error message = '([^']*)'", str(exc))  # HDF5's report of a failed system call
    if found:
        return f"{found[1].lower()} (inside HDF5: {str(exc).split(' (')[0]})"
    return f"{type(exc).__name__}: {exc}"


class FrameSink:
    """Owns the writers and one thread that writes queued frames to each of them in order."""

    def __init__(self, writers: Sequence[FrameWriter]) -> None:
        self._writers = list(writers)
        self._queue: queue.Queue[tuple | None] = queue.Queue(_QUEUE_SIZE)
        self._error: FrameWriteError | None = None
        self._error_raised = False
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="pdmpm-frame-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while (item := self._queue.get()) is not _STOP:
            if self._error is not None:
                continue  # after a failure, later frames are dropped so outputs stay in order
            if len(item) == 2:
                what, job = item
                try:
                    job()
                except BaseException as exc:
                    self._error = FrameWriteError(f"{what} failed: {_reason(exc)}")
                    self._error.__cause__ = exc
                continue
            index, time, fields = item
            for writer in self._writers:
                try:
                    writer.write_frame(index, time, fields)
                except BaseException as exc:
                    reason = _reason(exc).removeprefix(f"{getattr(writer, 'path', None)}: ")
                    self._error = FrameWriteError(f"{_describe(writer)} failed writing frame {index}: {reason}")
                    self._error.__cause__ = exc
                    break

    def _raise_pending(self) -> None:
        """Raise a writer failure once; the caller then stops submitting and closes."""
        if self._error is not None and not self._error_raised:
            self._error_raised = True
            raise self._error

    def submit(self, index: int, time: float, fields: dict[str, np.ndarray]) -> None:
        """Queue a copy of one frame; blocks while two frames are already waiting."""
        if self._closed:
            raise ValueError("FrameSink is closed")
        self._raise_pending()
        copies = {name: np.array(value, copy=True) for name, value in fields.items()}
        self._queue.put((index, float(time), copies))

    def call(self, what: str, job: Callable[[], None]) -> None:
        """Run ``job`` on the writer thread once every frame submitted before it is written (a checkpoint
        must not name a frame that is not on disk yet); a failure is reported as ``what`` failed."""
        if self._closed:
            raise ValueError("FrameSink is closed")
        self._raise_pending()
        self._queue.put((what, job))

    def close(self) -> None:
        """Write the queued frames, close every writer (even after a failure), join the thread."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(_STOP)
        self._thread.join()
        close_error: FrameWriteError | None = None
        for writer in self._writers:
            try:
                writer.close()
            except BaseException as exc:
                if close_error is None:
                    close_error = FrameWriteError(f"{_describe(writer)} failed to close: {_reason(exc)}")
                    close_error.__cause__ = exc
        self._raise_pending()
        if close_error is not None:
            raise close_error

    def __enter__(self) -> FrameSink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

