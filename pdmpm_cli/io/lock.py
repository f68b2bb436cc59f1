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


def check_folder(folder: str | os.PathLike[str]) -> None:
    """InputError unless `folder` is a folder this process may write in, or one it can make: not a file, not under
    a file, not in a folder without write permission (as root, permissions do not stop writes)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: is a file, not a folder; give a folder for the outputs with --out")
    parent = folder.absolute()
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(f"{folder}: {parent} is a file, so no folder can be made in it; choose another --out")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{folder}: no permission to write in {parent}; choose another --out, or allow writing "
                         f"there (chmod u+w)")


def check_free(folder: str | os.PathLike[str]) -> None:
    """InputError if a run holds `folder` now (a probe: the lock is released at once)."""
    try:
        fd = os.open(Path(folder) / LOCK_NAME, os.O_RDONLY)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise _busy(Path(folder), os.read(fd, 4096).decode("utf-8", "replace")) from None
    finally:
        os.close(fd)


def _busy(folder: Path, holder: str) -> InputError:
    return InputError(f"{folder}: another pdmpm run is writing to this folder ({_describe(holder)}); wait for it to "
                      f"finish or stop it, or choose another folder with --out")


class OutputLock:
    """Exclusive use of an output folder (created if missing); a context manager."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK_NAME
        self._fd: int | None = None

    def acquire(self) -> None:
        check_folder(self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self._lock()
        except OSError as error:
            raise InputError(f"{self.folder}: cannot write in this folder ({error.strerror}); choose another "
                             f"--out") from None

    def _lock(self) -> None:
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 4096).decode("utf-8", "replace")
                os.close(fd)
                raise _busy(self.folder, holder) from None
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the previous holder removed the file we opened: lock the new one
        self._fd = fd
        holder = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}
        try:
            os.ftruncate(fd, 0)
            os.write(fd, json.dumps(holder).encode("utf-8"))
        except OSError:
            self.release()
            raise

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
