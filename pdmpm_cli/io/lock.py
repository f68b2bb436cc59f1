"""One run per output folder: ``OUTDIR/.pdmpm.lock``, held with ``flock`` for the whole run.

The kernel releases an flock when its process dies, however it dies, so a run killed with SIGKILL never
blocks the next one (``--resume``) and no stale-pid guessing is needed. The file names its holder (pid,
host, start time) for the message another run gets. It is removed on release; a run that opened the old
file just before that notices the file it locked is gone and tries again.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
from datetime import datetime, timezone
from pathlib import Path

from pdmpm_cli.errors import InputError

LOCK_NAME = ".pdmpm.lock"


class OutputLock:
    """Exclusive use of an output folder (created if missing); a context manager."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 4096).decode("utf-8", "replace")
                os.close(fd)
                raise InputError(f"{self.folder}: another pdmpm run is writing to this folder ({_describe(holder)}); "
                                 f"wait for it to finish or stop it, or choose another folder with --out") from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the previous holder removed the file we opened: lock the new one
        holder = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps(holder).encode("utf-8"))
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            self.path.unlink(missing_ok=True)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _describe(text: str) -> str:
    try:
        h = json.loads(text)
        return f"pid {h['pid']} on {h['host']}, started {h['started']}"
    except (ValueError, KeyError, TypeError):
        return "it is just starting"
